//! Open ends of a vessel surface: boundary loops found, measured (centre, outward normal,
//! radius) and closed with flat caps, as surfaces exported from 3D Slicer, VMTK or SOFA
//! examples arrive open where the vessels were clipped.

use std::collections::HashMap;

use nalgebra::{Point3, Vector3};
use serde::Serialize;

use crate::error::{AnatomyError, Result};
use crate::mesh::TriangleMesh;

/// Most open ends a surface may have (a vessel tree's inlet and outlets).
pub const MAX_OPEN_ENDS: usize = 256;

/// One open end (a boundary loop) of a surface.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OpenEnd {
    /// Its place in the list: ends are ordered by radius, largest first.
    pub index: usize,
    /// Centroid of the loop's vertices (m, the surface's frame).
    pub centre: Point3<f64>,
    /// Unit normal of the loop's plane, pointing out of the vessel (whichever way the
    /// surface's faces are oriented).
    pub normal: Vector3<f64>,
    /// Mean distance of the loop's vertices from its centre (m).
    pub radius_m: f64,
    /// The loop's vertex indices, in the order the surface's faces give its edges.
    #[serde(skip)]
    pub loop_vertices: Vec<u32>,
}

/// Finds the boundary loops of `mesh`. Fails naming the defect when the boundary is not a
/// set of simple loops (an edge used by three faces, a vertex where two loops touch).
pub fn open_ends(mesh: &TriangleMesh, source: &str) -> Result<Vec<OpenEnd>> {
    // Directed edges as the faces use them; an edge used once is on the boundary.
    let mut uses: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.triangles.len() * 3);
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *uses.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    if let Some(((a, b), n)) = uses.iter().find(|(_, n)| **n > 2) {
        return Err(AnatomyError::NotManifold {
            file: source.to_owned(),
            message: format!("edge {a}–{b} is shared by {n} faces"),
        });
    }
    // Boundary edges keep the faces' direction a → b; the cap runs them b → a.
    let mut next: HashMap<u32, u32> = HashMap::new();
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if uses[&(a.min(b), a.max(b))] == 1 && next.insert(a, b).is_some() {
                return Err(AnatomyError::NotManifold {
                    file: source.to_owned(),
                    message: format!(
                        "vertex {a} is on two open ends at once (the boundary pinches there)"
                    ),
                });
            }
        }
    }
    let mut starts: Vec<u32> = next.keys().copied().collect();
    starts.sort_unstable();
    let mut seen = std::collections::HashSet::new();
    let mut ends = Vec::new();
    for start in starts {
        if seen.contains(&start) {
            continue;
        }
        let mut loop_vertices = vec![start];
        seen.insert(start);
        let mut at = start;
        loop {
            let Some(&b) = next.get(&at) else {
                return Err(AnatomyError::NotManifold {
                    file: source.to_owned(),
                    message: format!(
                        "the open boundary through vertex {at} does not close into a loop \
                         (faces disagree on orientation there)"
                    ),
                });
            };
            if b == start {
                break;
            }
            if !seen.insert(b) {
                return Err(AnatomyError::NotManifold {
                    file: source.to_owned(),
                    message: format!("the open boundary crosses itself at vertex {b}"),
                });
            }
            loop_vertices.push(b);
            at = b;
        }
        if loop_vertices.len() < 3 {
            return Err(AnatomyError::NotManifold {
                file: source.to_owned(),
                message: format!("an open end of {} vertices", loop_vertices.len()),
            });
        }
        ends.push(measure(mesh, loop_vertices));
        if ends.len() > MAX_OPEN_ENDS {
            return Err(AnatomyError::NotManifold {
                file: source.to_owned(),
                message: format!(
                    "more than {MAX_OPEN_ENDS} open ends: this is a torn surface, not a vessel \
                     tree with clipped ends"
                ),
            });
        }
    }
    // The normals follow the faces' orientation; for a surface whose faces point into the
    // lumen (its volume, caps included, negative) they are turned to point out of it.
    let mut volume = 0.0;
    let mut add = |a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>| {
        volume += a.coords.dot(&b.coords.cross(&c.coords)) / 6.0;
    };
    for t in &mesh.triangles {
        let [a, b, c] = mesh.corners(t);
        add(&a, &b, &c);
    }
    for end in &ends {
        let n = end.loop_vertices.len();
        for k in 0..n {
            let a = mesh.vertices[end.loop_vertices[k] as usize];
            let b = mesh.vertices[end.loop_vertices[(k + 1) % n] as usize];
            add(&b, &a, &end.centre);
        }
    }
    if volume < 0.0 {
        for end in &mut ends {
            end.normal = -end.normal;
        }
    }
    ends.sort_by(|a, b| b.radius_m.total_cmp(&a.radius_m));
    for (i, end) in ends.iter_mut().enumerate() {
        end.index = i;
    }
    Ok(ends)
}

/// Centre, outward normal and radius of a loop whose edges run as the faces give them.
fn measure(mesh: &TriangleMesh, loop_vertices: Vec<u32>) -> OpenEnd {
    let points: Vec<Point3<f64>> = loop_vertices
        .iter()
        .map(|&v| mesh.vertices[v as usize])
        .collect();
    let centre =
        Point3::from(points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / points.len() as f64);
    // Faces run the boundary a → b counter-clockwise seen from outside the lumen, so the
    // loop's own area vector (a → b order) points into the vessel; the cap runs b → a and
    // its normal, out of the vessel, is the opposite.
    let area: Vector3<f64> = (0..points.len())
        .map(|k| (points[k] - centre).cross(&(points[(k + 1) % points.len()] - centre)))
        .sum();
    let normal = (-area).try_normalize(0.0).unwrap_or_else(Vector3::z);
    let radius_m = points.iter().map(|p| (p - centre).norm()).sum::<f64>() / points.len() as f64;
    OpenEnd {
        index: 0,
        centre,
        normal,
        radius_m,
        loop_vertices,
    }
}

/// Closes every open end of `mesh` with a flat fan around its centre (one new vertex per
/// end) and returns the closed surface with the ends it capped. For a surface whose faces
/// point outward the caps do too; a closed surface comes back unchanged with no ends.
pub fn cap_open_ends(mesh: &TriangleMesh, source: &str) -> Result<(TriangleMesh, Vec<OpenEnd>)> {
    let ends = open_ends(mesh, source)?;
    let mut capped = mesh.clone();
    capped.normals.clear();
    for end in &ends {
        let c = capped.vertices.len() as u32;
        capped.vertices.push(end.centre);
        let n = end.loop_vertices.len();
        for k in 0..n {
            let (a, b) = (end.loop_vertices[k], end.loop_vertices[(k + 1) % n]);
            capped.triangles.push([b, a, c]);
        }
    }
    Ok((capped, ends))
}
