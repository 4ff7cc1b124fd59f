//! scratch
use cathlab_anatomy::phantom::*;
use cathlab_anatomy::surface::*;
fn main() {
    let g = neuro_phantom(&NeuroPhantomParams::default()).unwrap();
    println!(
        "branches {} length {:.0} mm cycles {}",
        g.branches.len(),
        g.total_length() * 1e3,
        g.cycle_rank()
    );
    let access = g.landmarks["access"];
    for t in [
        "left_common_carotid",
        "right_vertebral",
        "left_middle_cerebral",
        "basilar",
    ] {
        println!("{t}: {:.0} mm", g.path_to(&access, t).unwrap().length * 1e3);
    }
    let cpr: f64 = std::env::var("CPR")
        .map(|v| v.parse().unwrap())
        .unwrap_or(3.0);
    let t = std::time::Instant::now();
    let m = lumen_surface(
        &g,
        &SurfaceSettings {
            cells_per_radius: cpr,
            ..Default::default()
        },
    );
    match m {
        Ok(m) => {
            let topo = m.topology();
            println!(
                "surface {:?} tris {} genus {} comps {} in {:?}",
                topo.is_closed_oriented_manifold(),
                m.triangles.len(),
                topo.genus(),
                topo.components,
                t.elapsed()
            );
        }
        Err(e) => println!("{e} {:?}", t.elapsed()),
    }
}
