//! Decimation of lumen surfaces: far fewer triangles, still a closed oriented 2-manifold of
//! the same topology (spheres, a torus, the neuro phantom's loops), within the tolerance of
//! the original surface measured both ways (original vertices to the decimated surface, and
//! the decimated surface's vertices, edge midpoints and face centres to the original), and a
//! tube still within the tolerance of its analytic radius.

use cathlab_anatomy::decimate::decimate;
use cathlab_anatomy::mesh::TriangleMesh;
use cathlab_anatomy::phantom::{
    ArchType, NeuroPhantomParams, neuro_phantom, straight_tube, torus_segment, y_bifurcation,
};
use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};
use cathlab_anatomy::{Lumen, VesselGraph};
use nalgebra::Point3;

/// Largest distance from the points of `a` (vertices, edge midpoints, face centres) to the
/// surface `b` (m).
fn one_way(a: &TriangleMesh, b: &Lumen) -> f64 {
    let mut worst: f64 = 0.0;
    for t in &a.triangles {
        let [p, q, r] = a.corners(t);
        let points = [
            p,
            Point3::from((p.coords + q.coords) * 0.5),
            Point3::from((p.coords + q.coords + r.coords) / 3.0),
        ];
        for x in points {
            worst = worst.max(b.query(&x).signed_distance.abs());
        }
    }
    worst
}

fn check(name: &str, mesh: TriangleMesh, tolerance: f64) -> TriangleMesh {
    let before = mesh.topology();
    let (small, report) = decimate(&mesh, tolerance);
    let after = small.topology();
    let original = Lumen::new(mesh.clone(), name).unwrap();
    let decimated = Lumen::new(small.clone(), name).unwrap();
    let there = one_way(&small, &original);
    let back = mesh
        .vertices
        .iter()
        .map(|p| decimated.query(p).signed_distance.abs())
        .fold(0.0, f64::max);
    let volume = small.enclosed_volume() / mesh.enclosed_volume() - 1.0;
    println!(
        "{name}: {} → {} triangles ({:.1}×), distance decimated→original {:.4} mm, \
         original→decimated {:.4} mm (tolerance {:.3} mm), volume {:+.3} %",
        report.triangles_before,
        report.triangles_after,
        report.triangles_before as f64 / report.triangles_after as f64,
        there * 1e3,
        back * 1e3,
        tolerance * 1e3,
        volume * 100.0
    );
    assert!(after.is_closed_oriented_manifold(), "{name}: {after:?}");
    assert_eq!(
        (after.euler_characteristic, after.components),
        (before.euler_characteristic, before.components),
        "{name}"
    );
    assert!(
        report.triangles_after * 3 < report.triangles_before,
        "{name}"
    );
    assert_eq!(small.normals.len(), small.vertices.len(), "{name}");
    assert!(there <= tolerance && back <= tolerance, "{name}");
    small
}

/// The tolerance every decimation below is held to (m).
const TOLERANCE: f64 = 0.05e-3;

/// [`check`] on `graph`'s lumen surface at the default settings.
fn check_default(name: &str, graph: &VesselGraph) -> TriangleMesh {
    check(
        name,
        lumen_surface(graph, &SurfaceSettings::default()).unwrap(),
        TOLERANCE,
    )
}

// One test per surface, so that the test harness runs them side by side.

#[test]
fn a_decimated_tube_stays_closed_and_on_its_analytic_wall() {
    let r = 2e-3;
    let tube = check_default("tube", &straight_tube(r, 40e-3).unwrap());
    // Away from the caps the tube's vertices stay on the analytic wall.
    let worst = tube
        .vertices
        .iter()
        .filter(|p| p.z > 2.0 * r && p.z < 40e-3 - 2.0 * r)
        .map(|p| (p.x.hypot(p.y) - r).abs())
        .fold(0.0, f64::max);
    assert!(worst <= TOLERANCE, "tube radius off by {worst} m");
}

#[test]
fn a_decimated_bifurcation_stays_closed_and_within_tolerance() {
    check_default(
        "y bifurcation",
        &y_bifurcation(3e-3, 2e-3, 20e-3, 20e-3, 0.5).unwrap(),
    );
}

#[test]
fn a_decimated_torus_keeps_its_hole_and_stays_within_tolerance() {
    check_default("torus", &torus_segment(15e-3, 2e-3, 2.0).unwrap());
}

#[test]
fn the_decimated_neuro_phantom_keeps_its_loops_and_stays_within_tolerance() {
    let phantom = neuro_phantom(&NeuroPhantomParams {
        arch: ArchType::II,
        ..Default::default()
    })
    .unwrap();
    let coarse = SurfaceSettings {
        cells_per_radius: 1.5,
        smoothing_iterations: 1,
        ..Default::default()
    };
    let small = check(
        "neuro phantom",
        lumen_surface(&phantom, &coarse).unwrap(),
        TOLERANCE,
    );
    assert_eq!(small.topology().genus(), phantom.cycle_rank() as i64);
}
