//! The real arch-to-circle-of-Willis anatomy (data/anatomy/arch-to-cow): the surface is a
//! closed manifold, the centerlines lie inside it, paths reach the four targets, and the
//! grid and BVH backends give identical answers.

use std::path::PathBuf;
use std::sync::OnceLock;

use cathlab_anatomy::io::{LengthUnit, obj, slicer};
use cathlab_anatomy::lumen::Proximity;
use cathlab_anatomy::real::{Anatomy, load_arch_to_cow};
use nalgebra::Vector3;
use proptest::prelude::*;

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow")
}

fn anatomy() -> &'static Anatomy {
    static ANATOMY: OnceLock<Anatomy> = OnceLock::new();
    ANATOMY.get_or_init(|| load_arch_to_cow(&data_dir()).expect("bundled anatomy loads"))
}

#[test]
fn surface_is_a_closed_manifold_of_genus_four() {
    let mesh = obj::load(&data_dir().join("vessels.obj"), LengthUnit::Mm).unwrap();
    let t = mesh.topology();
    assert!(t.is_closed_oriented_manifold(), "{t:?}");
    assert_eq!(
        (t.components, t.euler_characteristic, t.genus()),
        (1, -6, 4)
    );
}

#[test]
fn centerlines_lie_inside_the_surface() {
    let lumen = &anatomy().lumen;
    let (mut inside, mut total, mut worst_outside) = (0, 0, 0.0f64);
    for name in ["LCCA", "LVA", "RCCA", "RVA"] {
        let file = data_dir().join(format!("centerlines/{name}.mrk.json"));
        for curve in slicer::load(&file).unwrap() {
            for p in &curve.points {
                let q = lumen.query(p);
                total += 1;
                if q.inside() {
                    inside += 1;
                } else {
                    worst_outside = worst_outside.max(q.signed_distance);
                }
            }
        }
    }
    let fraction = inside as f64 / total as f64;
    println!(
        "{inside}/{total} centerline points inside; worst outside by {:.2} mm",
        worst_outside * 1e3
    );
    assert!(fraction > 0.99, "only {fraction} inside");
    assert!(
        worst_outside < 1e-3,
        "a centerline point is {worst_outside} m outside the wall"
    );
}

#[test]
fn paths_reach_the_four_targets_from_the_aortic_access() {
    let graph = &anatomy().graph;
    let access = graph.landmarks["access"];
    for target in ["LCCA", "RCCA", "LVA", "RVA"] {
        let path = graph.path_to(&access, target).unwrap();
        let last = path.legs.last().unwrap();
        assert_eq!(graph.branches[last.branch].name, target);
        assert_eq!(graph.branches[path.legs[0].branch].name, "descending_aorta");
        // Every sampled point of the route lies inside the lumen.
        for (p, _) in graph.sample_path(&path, 2e-3) {
            let d = anatomy().lumen.query(&p).signed_distance;
            assert!(d < 2.5e-3, "{target}: route leaves the lumen by {d} m");
        }
        println!("route to {target}: {:.1} mm", path.length * 1e3);
        assert!(
            path.length > 0.3 && path.length < 0.5,
            "{target}: {} m",
            path.length
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    #[test]
    fn grid_queries_equal_bvh_queries(vertex in 0usize..1786, dx in -6e-3f64..6e-3, dy in -6e-3f64..6e-3, dz in -6e-3f64..6e-3) {
        let lumen = &anatomy().lumen;
        let p = lumen.mesh().vertices[vertex % lumen.mesh().vertices.len()] + Vector3::new(dx, dy, dz);
        let fast = lumen.query(&p);
        let reference = lumen.query_bvh(&p);
        prop_assert!((fast.signed_distance - reference.signed_distance).abs() < 1e-12);
        prop_assert!((fast.closest_wall_point - reference.closest_wall_point).norm() < 1e-9
            || (fast.signed_distance.abs() - (p - reference.closest_wall_point).norm()).abs() < 1e-12);
        match lumen.proximity(&p, 1e-3) {
            Proximity::Near(q) => prop_assert!(q.signed_distance.abs() <= 1e-3),
            Proximity::Far { inside } => {
                prop_assert!(reference.signed_distance.abs() > 1e-3);
                prop_assert_eq!(inside, reference.inside());
            }
        }
    }
}

/// The same surface meshed 16 times finer (57k triangles), built with the default grid:
/// queries stay exact.
fn fine_lumen() -> &'static cathlab_anatomy::Lumen {
    static LUMEN: OnceLock<cathlab_anatomy::Lumen> = OnceLock::new();
    LUMEN.get_or_init(|| {
        let mesh = obj::load(&data_dir().join("vessels.obj"), LengthUnit::Mm)
            .unwrap()
            .subdivided()
            .subdivided();
        cathlab_anatomy::Lumen::new(mesh, "vessels.obj ×16").unwrap()
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]
    #[test]
    fn grid_queries_on_a_finely_meshed_surface_equal_bvh_queries(vertex in 0usize..28000, dx in -4e-3f64..4e-3, dy in -4e-3f64..4e-3, dz in -4e-3f64..4e-3) {
        let lumen = fine_lumen();
        let p = lumen.mesh().vertices[vertex % lumen.mesh().vertices.len()] + Vector3::new(dx, dy, dz);
        let fast = lumen.query(&p);
        let reference = lumen.query_bvh(&p);
        prop_assert!((fast.signed_distance - reference.signed_distance).abs() < 1e-12);
        match lumen.proximity(&p, 2e-3) {
            Proximity::Near(q) => prop_assert!((q.signed_distance - reference.signed_distance).abs() < 1e-12),
            Proximity::Far { inside } => {
                prop_assert!(reference.signed_distance.abs() > 2e-3);
                prop_assert_eq!(inside, reference.inside());
            }
        }
    }
}
