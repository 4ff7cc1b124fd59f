//! Generated lumen surfaces: closed oriented manifolds with the expected topology, volume and
//! radius, and wall queries that match the analytic tube and torus.

use std::f64::consts::PI;

use cathlab_anatomy::Lumen;
use cathlab_anatomy::phantom::{
    ArchType, NeuroPhantomParams, neuro_phantom, straight_tube, torus_segment, y_bifurcation,
};
use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};
use nalgebra::{Point3, Vector3};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

const R: f64 = 2e-3;

#[test]
fn straight_tube_is_a_closed_sphere_with_the_right_volume_and_radius() {
    let length = 40e-3;
    let mesh = lumen_surface(
        &straight_tube(R, length).unwrap(),
        &SurfaceSettings::default(),
    )
    .unwrap();
    let topology = mesh.topology();
    assert!(topology.is_closed_oriented_manifold(), "{topology:?}");
    assert_eq!(
        topology.euler_characteristic, 2,
        "a capped tube is a sphere"
    );
    assert_eq!(topology.components, 1);
    let volume = mesh.enclosed_volume();
    let exact = PI * R * R * length;
    println!("tube volume / (pi r^2 L) = {:.5}", volume / exact);
    assert!(
        (volume / exact - 1.0).abs() < 0.01,
        "volume ratio {}",
        volume / exact
    );
    // Away from the caps every vertex lies within 5 % of the radius from the axis.
    let worst = mesh
        .vertices
        .iter()
        .filter(|p| p.z > 2.0 * R && p.z < length - 2.0 * R)
        .map(|p| ((p.x.hypot(p.y)) - R).abs() / R)
        .fold(0.0, f64::max);
    println!("largest radial deviation away from the caps: {worst:.2e} r");
    assert!(worst < 0.05, "radial deviation {worst}");
}

#[test]
fn y_bifurcation_and_torus_are_closed_spheres() {
    for graph in [
        y_bifurcation(3e-3, 2e-3, 20e-3, 20e-3, 0.5).unwrap(),
        torus_segment(15e-3, R, 2.0).unwrap(),
    ] {
        let mesh = lumen_surface(&graph, &SurfaceSettings::default()).unwrap();
        let t = mesh.topology();
        assert!(t.is_closed_oriented_manifold(), "{t:?}");
        assert_eq!((t.euler_characteristic, t.components), (2, 1));
        assert!(mesh.enclosed_volume() > 0.0, "faces point out of the lumen");
    }
}

/// Samples points around the centre curve of a phantom and compares the mesh queries with
/// the exact distance and normal of the ideal tube.
fn check_queries(lumen: &Lumen, sample: impl Fn(&mut StdRng) -> (Point3<f64>, Point3<f64>)) {
    let mut rng = StdRng::seed_from_u64(7);
    let (mut worst_distance, mut worst_normal) = (0.0f64, 0.0f64);
    for _ in 0..5000 {
        let (p, axis_point) = sample(&mut rng);
        let q = lumen.query(&p);
        let rho = (p - axis_point).norm();
        worst_distance = worst_distance.max((q.signed_distance - (rho - R)).abs() / R);
        if rho > 0.5 * R {
            worst_normal = worst_normal.max((q.outward_normal - (p - axis_point) / rho).norm());
        }
        if (rho - R).abs() > 0.01 * R {
            assert_eq!(q.inside(), rho < R, "inside test at {rho} from the axis");
        }
    }
    println!("worst distance error {worst_distance:.4} r, worst normal error {worst_normal:.4}");
    assert!(worst_distance < 0.01, "distance error {worst_distance} r");
    assert!(worst_normal < 0.01, "normal error {worst_normal}");
}

fn ring_offset(rng: &mut StdRng, u: Vector3<f64>, v: Vector3<f64>) -> Vector3<f64> {
    let rho = 1.3 * R * rng.random_range(0.0..1.0);
    let theta = rng.random_range(0.0..2.0 * PI);
    (u * theta.cos() + v * theta.sin()) * rho
}

#[test]
fn tube_queries_match_the_analytic_distance_and_normal() {
    let length = 40e-3;
    let lumen = Lumen::new(
        lumen_surface(
            &straight_tube(R, length).unwrap(),
            &SurfaceSettings::default(),
        )
        .unwrap(),
        "tube",
    )
    .unwrap();
    check_queries(&lumen, |rng| {
        let axis = Point3::new(0.0, 0.0, rng.random_range(0.2 * length..0.8 * length));
        (axis + ring_offset(rng, Vector3::x(), Vector3::y()), axis)
    });
}

#[test]
fn torus_queries_match_the_analytic_distance_and_normal() {
    let major = 15e-3;
    let lumen = Lumen::new(
        lumen_surface(
            &torus_segment(major, R, 2.0).unwrap(),
            &SurfaceSettings::default(),
        )
        .unwrap(),
        "torus",
    )
    .unwrap();
    check_queries(&lumen, |rng| {
        let phi: f64 = rng.random_range(0.3..1.7);
        let radial = Vector3::new(phi.cos(), phi.sin(), 0.0);
        let axis = Point3::from(radial * major);
        (axis + ring_offset(rng, radial, Vector3::z()), axis)
    });
}

#[test]
fn full_neuro_phantom_surface_is_closed_with_one_handle_per_vessel_loop() {
    let graph = neuro_phantom(&NeuroPhantomParams {
        arch: ArchType::II,
        ..Default::default()
    })
    .unwrap();
    let coarse = SurfaceSettings {
        cells_per_radius: 1.5,
        smoothing_iterations: 1,
        ..Default::default()
    };
    let mesh = lumen_surface(&graph, &coarse).unwrap();
    let t = mesh.topology();
    assert!(t.is_closed_oriented_manifold(), "{t:?}");
    assert_eq!(t.components, 1);
    // Loops: vertebrobasilar with the subclavians and arch, and the circle of Willis.
    assert_eq!(graph.cycle_rank(), 4);
    assert_eq!(t.genus(), graph.cycle_rank() as i64, "{t:?}");
}
