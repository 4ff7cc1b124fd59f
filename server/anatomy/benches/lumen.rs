//! Wall-query throughput on the real arch-to-cow surface, one core: the narrow-band grid and
//! parry's BVH, for queries in random order and in device-like order (along centerlines).

use std::hint::black_box;
use std::path::Path;

use cathlab_anatomy::Lumen;
use cathlab_anatomy::io::{LengthUnit, obj, slicer};
use cathlab_anatomy::lumen::Proximity;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::{Point3, Vector3};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

const DATA: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../data/anatomy/arch-to-cow"
);

fn queries(c: &mut Criterion) {
    let mesh = obj::load(&Path::new(DATA).join("vessels.obj"), LengthUnit::Mm).unwrap();
    let lumen = Lumen::new(mesh, "vessels.obj").unwrap();
    let mut rng = StdRng::seed_from_u64(3);
    // Device-like: points along the four centerlines, jittered within the local radius.
    let mut along = Vec::new();
    for name in ["LCCA", "LVA", "RCCA", "RVA"] {
        for curve in
            slicer::load(&Path::new(DATA).join(format!("centerlines/{name}.mrk.json"))).unwrap()
        {
            for (w, r) in curve.points.windows(2).zip(&curve.radii) {
                for k in 0..25 {
                    let p = w[0] + (w[1] - w[0]) * (k as f64 / 25.0);
                    let j = Vector3::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                    );
                    along.push(p + j * (*r * 0.8));
                }
            }
        }
    }
    let mut shuffled: Vec<Point3<f64>> = along.clone();
    for i in (1..shuffled.len()).rev() {
        shuffled.swap(i, rng.random_range(0..=i));
    }
    let mut group = c.benchmark_group("lumen_point_query");
    group.throughput(Throughput::Elements(along.len() as u64));
    for (order, points) in [("along_vessels", &along), ("random_order", &shuffled)] {
        group.bench_function(format!("grid_{order}"), |b| {
            b.iter(|| {
                points
                    .iter()
                    .map(|p| lumen.query(black_box(p)).signed_distance)
                    .sum::<f64>()
            })
        });
        // Contact detection asks only whether the wall is within 1 mm (device radius + margin).
        group.bench_function(format!("grid_proximity_1mm_{order}"), |b| {
            b.iter(|| {
                points
                    .iter()
                    .filter(|p| matches!(lumen.proximity(black_box(p), 1e-3), Proximity::Near(_)))
                    .count()
            })
        });
        group.bench_function(format!("bvh_{order}"), |b| {
            b.iter(|| {
                points
                    .iter()
                    .map(|p| lumen.query_bvh(black_box(p)).signed_distance)
                    .sum::<f64>()
            })
        });
    }
    group.finish();
    println!(
        "grid memory: {:.1} MB, {} queries per iteration",
        lumen.grid_bytes() as f64 / 1e6,
        along.len()
    );
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = queries
}
criterion_main!(benches);
