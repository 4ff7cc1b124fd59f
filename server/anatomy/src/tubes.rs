//! A light surface of a vessel graph for display: each branch a tube of rings along its
//! centerline, at its radii, with outward normals. The tubes overlap where branches meet and
//! stay open at their ends: a picture of the lumen, not a wall to query (for that, the graph's
//! implicit lumen, [`crate::field_wall`]). Milliseconds where a watertight surface takes
//! seconds.

use nalgebra::{Point3, Vector3};

use crate::graph::VesselGraph;
use crate::mesh::TriangleMesh;

/// The tubes of `graph`'s branches, `sides` vertices round each ring (at least 3), one ring at
/// each centerline point (m).
pub fn tube_mesh(graph: &VesselGraph, sides: usize) -> TriangleMesh {
    let sides = sides.max(3);
    let mut mesh = TriangleMesh::default();
    for branch in &graph.branches {
        let n = branch.points.len();
        if n < 2 {
            continue;
        }
        // Frames carried along the centerline without twist (parallel transport).
        let tangent = |i: usize| -> Vector3<f64> {
            let (a, b) = (
                branch.points[i.saturating_sub(1)],
                branch.points[(i + 1).min(n - 1)],
            );
            (b - a).try_normalize(0.0).unwrap_or_else(Vector3::z)
        };
        let first = tangent(0);
        let mut across = first.cross(&Vector3::x());
        if across.norm() < 0.1 {
            across = first.cross(&Vector3::y());
        }
        let mut across = across.normalize();
        let base = mesh.vertices.len() as u32;
        for i in 0..n {
            let t = tangent(i);
            across = (across - t * across.dot(&t))
                .try_normalize(0.0)
                .unwrap_or(across);
            let other = t.cross(&across);
            for k in 0..sides {
                let angle = std::f64::consts::TAU * k as f64 / sides as f64;
                let outward = across * angle.cos() + other * angle.sin();
                let centre: Point3<f64> = branch.points[i];
                mesh.vertices.push(centre + outward * branch.radii[i]);
                mesh.normals.push(outward);
            }
        }
        let at = |ring: usize, k: usize| base + (ring * sides + k % sides) as u32;
        for ring in 0..n - 1 {
            for k in 0..sides {
                let (a, b) = (at(ring, k), at(ring, k + 1));
                let (c, d) = (at(ring + 1, k), at(ring + 1, k + 1));
                // Counter-clockwise seen from outside: outward normals.
                mesh.triangles.push([a, b, d]);
                mesh.triangles.push([a, d, c]);
            }
        }
    }
    mesh
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phantom::straight_tube;

    #[test]
    fn a_straight_tube_is_rings_at_its_radius_facing_out() {
        let graph = straight_tube(2e-3, 30e-3).unwrap();
        let mesh = tube_mesh(&graph, 12);
        let branch = &graph.branches[0];
        assert_eq!(mesh.vertices.len(), branch.points.len() * 12);
        assert_eq!(mesh.triangles.len(), (branch.points.len() - 1) * 24);
        let (a, b) = (branch.points[0], branch.points[branch.points.len() - 1]);
        let axis = (b - a).normalize();
        for (v, n) in mesh.vertices.iter().zip(&mesh.normals) {
            let off = (v - a) - axis * (v - a).dot(&axis);
            assert!((off.norm() - 2e-3).abs() < 1e-12, "{}", off.norm());
            assert!((off.normalize() - n).norm() < 1e-9);
        }
        for t in &mesh.triangles {
            let [p, q, r] = mesh.corners(t);
            let face = (q - p).cross(&(r - p));
            let centre = Point3::from((p.coords + q.coords + r.coords) / 3.0);
            let off = (centre - a) - axis * (centre - a).dot(&axis);
            assert!(face.dot(&off) > 0.0, "a triangle faces in");
        }
    }
}
