//! Open ends: the loops of an open tube VTK wrote (`tests/data/vtk`) are found at the
//! centerline's ends with the tube's radii, capped into a closed oriented surface whose
//! volume is the tube's; a closed surface has none; pinched boundaries are named.

use cathlab_anatomy::capping::{cap_open_ends, open_ends};
use cathlab_anatomy::io::{LengthUnit, obj, vtp};
use cathlab_anatomy::{Lumen, TriangleMesh};
use nalgebra::Point3;

fn fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/vtk")
        .join(name)
}

#[test]
fn an_open_tube_has_two_ends_where_its_centerline_ends_and_caps_into_a_closed_lumen() {
    let tube = vtp::load(&fixture("tube_binary_zlib.vtp"), LengthUnit::Mm)
        .unwrap()
        .surface
        .unwrap();
    let line = &vtp::load(&fixture("centerline_binary_zlib.vtp"), LengthUnit::Mm)
        .unwrap()
        .lines[0];
    assert!(tube.topology().boundary_edges > 0);
    let (capped, ends) = cap_open_ends(&tube, "tube").unwrap();
    assert_eq!(ends.len(), 2);
    let n = line.points.len();
    // Largest first: the 3 mm inlet, then the 2 mm outlet.
    let (first, last) = (&ends[0], &ends[1]);
    // A 16-sided polygon's vertices lie on the circle of the tube's radius.
    assert!((first.radius_m - 3e-3).abs() < 1e-6, "{}", first.radius_m);
    assert!((last.radius_m - 2e-3).abs() < 1e-6, "{}", last.radius_m);
    assert!((first.centre - line.points[0]).norm() < 1e-6);
    assert!((last.centre - line.points[n - 1]).norm() < 1e-6);
    // Normals point out of the vessel: backwards at the start, forwards at the end.
    let t0 = (line.points[1] - line.points[0]).normalize();
    let t1 = (line.points[n - 1] - line.points[n - 2]).normalize();
    assert!(first.normal.dot(&t0) < -0.99, "{}", first.normal.dot(&t0));
    assert!(last.normal.dot(&t1) > 0.99, "{}", last.normal.dot(&t1));
    // The capped surface is a closed oriented sphere enclosing the tube's volume.
    let topology = capped.topology();
    assert!(topology.is_closed_oriented_manifold(), "{topology:?}");
    assert_eq!(topology.genus(), 0);
    let polygon = 16.0 / (2.0 * std::f64::consts::PI) * (2.0 * std::f64::consts::PI / 16.0).sin();
    let exact: f64 = line
        .points
        .windows(2)
        .zip(line.radii.windows(2))
        .map(|(p, r)| {
            let h = (p[1] - p[0]).norm();
            std::f64::consts::PI * h * (r[0] * r[0] + r[0] * r[1] + r[1] * r[1]) / 3.0
        })
        .sum::<f64>()
        * polygon;
    let volume = capped.enclosed_volume().abs();
    println!("capped tube volume / frustums = {:.4}", volume / exact);
    assert!((volume / exact - 1.0).abs() < 0.03, "{}", volume / exact);
    Lumen::new(capped, "capped tube").unwrap();
    // Faces pointing into the lumen: the same ends, the normals still pointing out.
    let mut inward = tube.clone();
    inward.flip();
    let flipped = open_ends(&inward, "inward tube").unwrap();
    assert!(flipped[0].normal.dot(&t0) < -0.99 && flipped[1].normal.dot(&t1) > 0.99);
}

#[test]
fn a_closed_surface_has_no_open_ends() {
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let mesh = obj::load(&dir.join("vessels.obj"), LengthUnit::Mm).unwrap();
    let (capped, ends) = cap_open_ends(&mesh, "arch").unwrap();
    assert!(ends.is_empty());
    assert_eq!(capped.triangles.len(), mesh.triangles.len());
}

#[test]
fn a_pinched_boundary_is_named() {
    // Two triangles meeting at one vertex (a bow-tie): that vertex is on two boundaries.
    let v = |x: f64, y: f64| Point3::new(x * 1e-3, y * 1e-3, 0.0);
    let mesh = TriangleMesh::new(
        vec![
            v(0.0, 0.0),
            v(1.0, 0.0),
            v(0.0, 1.0),
            v(-1.0, 0.0),
            v(0.0, -1.0),
        ],
        vec![[0, 1, 2], [0, 3, 4]],
        "bowtie",
    )
    .unwrap();
    let err = open_ends(&mesh, "bowtie").unwrap_err().to_string();
    assert!(err.contains("bowtie") && err.contains("vertex 0"), "{err}");
}
