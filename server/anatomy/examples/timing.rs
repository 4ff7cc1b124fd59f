//! scratch timing
use cathlab_anatomy::Lumen;
use cathlab_anatomy::io::{LengthUnit, obj};
use nalgebra::Point3;
fn main() {
    let mesh = obj::load(
        std::path::Path::new("../../data/anatomy/arch-to-cow/vessels.obj"),
        LengthUnit::Mm,
    )
    .unwrap();
    println!("{:?}", mesh.topology());
    println!(
        "volume {} ml area {}",
        mesh.enclosed_volume() * 1e6,
        mesh.surface_area()
    );
    let t = std::time::Instant::now();
    let cs: f64 = std::env::var("CELL")
        .map(|v| v.parse().unwrap())
        .unwrap_or(0.002);
    let lumen = Lumen::new(mesh, "x")
        .unwrap()
        .with_grid(cathlab_anatomy::lumen::GridSettings {
            cell_size: Some(cs),
            band: 0.003,
        })
        .unwrap();
    println!("build {:?}", t.elapsed());
    let (lo, hi) = lumen.mesh().bounding_box();
    // random points near surface vertices
    let mut pts = Vec::new();
    let mut s = 12345u64;
    let mut rnd = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s as f64 / u64::MAX as f64) - 0.5
    };
    for i in 0..200000 {
        let v = lumen.mesh().vertices[i % lumen.mesh().vertices.len()];
        pts.push(v + nalgebra::Vector3::new(rnd(), rnd(), rnd()) * 0.004);
    }
    let t = std::time::Instant::now();
    let mut acc = 0.0;
    for p in &pts {
        acc += lumen.query_bvh(p).signed_distance;
    }
    let dt = t.elapsed().as_secs_f64();
    println!("bvh {:.0} queries/s  ({acc})", pts.len() as f64 / dt);
    if std::env::var("SORT").is_ok() {
        pts.sort_by(|a, b| {
            ((a.x * 500.0).floor(), (a.y * 500.0).floor(), a.z)
                .partial_cmp(&((b.x * 500.0).floor(), (b.y * 500.0).floor(), b.z))
                .unwrap()
        });
    }
    let t = std::time::Instant::now();
    let mut acc = 0.0;
    for p in &pts {
        acc += lumen.query(p).signed_distance;
    }
    let dt = t.elapsed().as_secs_f64();
    println!("grid {:.0} queries/s  ({acc})", pts.len() as f64 / dt);
    let mut worst: f64 = 0.0;
    for p in &pts {
        let a = lumen.query(p);
        let b = lumen.query_bvh(p);
        worst = worst.max((a.signed_distance - b.signed_distance).abs());
    }
    println!("max diff {worst:e}");
    let c: Vec<_> = pts.iter().map(|p| lumen.grid_candidates(p)).collect();
    let fb = c.iter().filter(|x| x.is_none()).count();
    let mean = c.iter().flatten().sum::<usize>() as f64 / (c.len() - fb) as f64;
    println!(
        "fallback {fb} mean cand {mean} bytes {}",
        lumen.grid_bytes()
    );
    let _ = (lo, hi, Point3::<f64>::origin());
}
