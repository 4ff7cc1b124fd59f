//! Triangle surfaces: storage, topology checks (closed, manifold, oriented), volume and normals.

use std::collections::HashMap;

use nalgebra::{Point3, Vector3};

use crate::components::count_components;
use crate::error::{AnatomyError, Result};

/// An indexed triangle surface. Coordinates in metres, patient LPS frame; triangles are
/// counter-clockwise seen from outside the lumen, so face normals point out of the lumen.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriangleMesh {
    /// Vertex positions (m).
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
    /// Known unit outward normals per vertex (for example the implicit surface's gradient);
    /// empty when unknown, in which case angle-weighted normals are used.
    pub normals: Vec<Vector3<f64>>,
}

/// What a topology check found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MeshTopology {
    /// Vertices referenced by at least one triangle.
    pub used_vertices: usize,
    /// Distinct undirected edges.
    pub edges: usize,
    /// Triangles.
    pub faces: usize,
    /// Edges used by exactly one triangle (holes).
    pub boundary_edges: usize,
    /// Edges used by three or more triangles.
    pub non_manifold_edges: usize,
    /// Edges used twice in the same direction (neighbouring faces disagree on orientation).
    pub misoriented_edges: usize,
    /// Triangles with a repeated vertex index.
    pub degenerate_faces: usize,
    /// Vertices whose triangles do not form a single fan (pinched, "bow-tie" vertices).
    pub non_manifold_vertices: usize,
    /// Edge-connected components.
    pub components: usize,
    /// Euler characteristic V − E + F over used vertices.
    pub euler_characteristic: i64,
}

impl MeshTopology {
    /// True when every edge is shared by exactly two consistently oriented faces and every
    /// vertex is a single fan: a closed, oriented 2-manifold.
    pub fn is_closed_oriented_manifold(&self) -> bool {
        self.faces > 0
            && self.boundary_edges == 0
            && self.non_manifold_edges == 0
            && self.misoriented_edges == 0
            && self.degenerate_faces == 0
            && self.non_manifold_vertices == 0
    }

    /// Total genus for a closed manifold: components − χ/2 summed over components.
    pub fn genus(&self) -> i64 {
        self.components as i64 - self.euler_characteristic / 2
    }
}

impl TriangleMesh {
    /// Builds a mesh, checking that every index is in range and every coordinate finite.
    pub fn new(vertices: Vec<Point3<f64>>, triangles: Vec<[u32; 3]>, source: &str) -> Result<Self> {
        if let Some(i) = vertices
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(AnatomyError::Parse {
                file: source.to_owned(),
                line: None,
                message: format!("vertex {i} has a non-finite coordinate"),
            });
        }
        let n = vertices.len();
        if let Some((t, tri)) = triangles
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&i| i as usize >= n))
        {
            return Err(AnatomyError::Parse {
                file: source.to_owned(),
                line: None,
                message: format!(
                    "triangle {t} refers to vertex {tri:?} but there are {n} vertices"
                ),
            });
        }
        if triangles.is_empty() {
            return Err(AnatomyError::Empty {
                file: source.to_owned(),
                message: "no triangles".into(),
            });
        }
        Ok(Self {
            vertices,
            triangles,
            normals: Vec::new(),
        })
    }

    /// The same surface with every triangle split into four at its edges' midpoints (the
    /// shape is unchanged; for tests and benchmarks of finely meshed surfaces).
    pub fn subdivided(&self) -> TriangleMesh {
        let mut vertices = self.vertices.clone();
        let mut midpoint: HashMap<(u32, u32), u32> = HashMap::new();
        let mut mid = |a: u32, b: u32, vertices: &mut Vec<Point3<f64>>| -> u32 {
            *midpoint.entry((a.min(b), a.max(b))).or_insert_with(|| {
                vertices.push(Point3::from(
                    (vertices[a as usize].coords + vertices[b as usize].coords) * 0.5,
                ));
                (vertices.len() - 1) as u32
            })
        };
        let mut triangles = Vec::with_capacity(self.triangles.len() * 4);
        for &[a, b, c] in &self.triangles {
            let (ab, bc, ca) = (
                mid(a, b, &mut vertices),
                mid(b, c, &mut vertices),
                mid(c, a, &mut vertices),
            );
            triangles.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
        }
        TriangleMesh {
            vertices,
            triangles,
            normals: Vec::new(),
        }
    }

    /// Edge, orientation, vertex-fan and component analysis.
    pub fn topology(&self) -> MeshTopology {
        // Undirected edge -> (uses, uses in the a<b direction).
        let mut edges: HashMap<(u32, u32), (u32, u32)> =
            HashMap::with_capacity(self.triangles.len() * 2);
        let mut degenerate = 0;
        let mut used = vec![false; self.vertices.len()];
        for t in &self.triangles {
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                degenerate += 1;
                continue;
            }
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                used[a as usize] = true;
                let e = edges.entry((a.min(b), a.max(b))).or_insert((0, 0));
                e.0 += 1;
                if a < b {
                    e.1 += 1;
                }
            }
        }
        let mut boundary = 0;
        let mut non_manifold = 0;
        let mut misoriented = 0;
        for &(uses, forward) in edges.values() {
            match uses {
                1 => boundary += 1,
                2 => {
                    if forward != 1 {
                        misoriented += 1
                    }
                }
                _ => non_manifold += 1,
            }
        }
        let components = self.face_components();
        let non_manifold_vertices = self.count_non_fan_vertices();
        let used_vertices = used.iter().filter(|&&u| u).count();
        let faces = self.triangles.len() - degenerate;
        MeshTopology {
            used_vertices,
            edges: edges.len(),
            faces,
            boundary_edges: boundary,
            non_manifold_edges: non_manifold,
            misoriented_edges: misoriented,
            degenerate_faces: degenerate,
            non_manifold_vertices,
            components,
            euler_characteristic: used_vertices as i64 - edges.len() as i64 + faces as i64,
        }
    }

    fn face_components(&self) -> usize {
        let edges = self
            .triangles
            .iter()
            .flat_map(|t| (0..3).map(move |k| (t[k] as usize, t[(k + 1) % 3] as usize)));
        count_components(self.vertices.len(), edges)
    }

    /// Counts vertices whose incident triangles do not form one connected fan.
    fn count_non_fan_vertices(&self) -> usize {
        // For each vertex, the opposite edges of its triangles must chain into one cycle or path.
        let mut incident: Vec<Vec<(u32, u32)>> = vec![Vec::new(); self.vertices.len()];
        for t in &self.triangles {
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                continue;
            }
            for k in 0..3 {
                incident[t[k] as usize].push((t[(k + 1) % 3], t[(k + 2) % 3]));
            }
        }
        let mut bad = 0;
        for fan in &incident {
            if fan.is_empty() {
                continue;
            }
            // The link vertices must be connected.
            let mut ids: Vec<u32> = fan.iter().flat_map(|&(a, b)| [a, b]).collect();
            ids.sort_unstable();
            ids.dedup();
            let index = |v: u32| ids.binary_search(&v).unwrap_or(0);
            let roots = count_components(ids.len(), fan.iter().map(|&(a, b)| (index(a), index(b))));
            if roots != 1 {
                bad += 1;
            }
        }
        bad
    }

    /// Fails with [`AnatomyError::NotManifold`] unless the surface is a closed, oriented
    /// 2-manifold; the message lists the defects.
    pub fn require_closed_manifold(&self, source: &str) -> Result<MeshTopology> {
        let t = self.topology();
        if t.is_closed_oriented_manifold() {
            return Ok(t);
        }
        Err(AnatomyError::NotManifold {
            file: source.to_owned(),
            message: format!(
                "{} boundary edges, {} edges in more than two faces, {} misoriented edges, \
                 {} degenerate faces, {} pinched vertices",
                t.boundary_edges,
                t.non_manifold_edges,
                t.misoriented_edges,
                t.degenerate_faces,
                t.non_manifold_vertices
            ),
        })
    }

    /// Signed enclosed volume (m³) by the divergence theorem; positive for outward-facing
    /// triangles of a closed surface.
    pub fn enclosed_volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                a.coords.dot(&b.coords.cross(&c.coords)) / 6.0
            })
            .sum()
    }

    /// Total area (m²).
    pub fn surface_area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    }

    /// Axis-aligned bounds (min, max), in metres.
    pub fn bounding_box(&self) -> (Point3<f64>, Point3<f64>) {
        let mut lo = Point3::from(Vector3::repeat(f64::INFINITY));
        let mut hi = Point3::from(Vector3::repeat(f64::NEG_INFINITY));
        for p in &self.vertices {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        (lo, hi)
    }

    /// The three corner positions of a triangle.
    pub fn corners(&self, t: &[u32; 3]) -> [Point3<f64>; 3] {
        [
            self.vertices[t[0] as usize],
            self.vertices[t[1] as usize],
            self.vertices[t[2] as usize],
        ]
    }

    /// The known vertex normals if present, else the angle-weighted ones.
    pub fn best_vertex_normals(&self) -> Vec<Vector3<f64>> {
        if self.normals.len() == self.vertices.len() {
            self.normals.clone()
        } else {
            self.vertex_normals()
        }
    }

    /// Angle-weighted vertex normals (unit, outward); zero for unused vertices.
    pub fn vertex_normals(&self) -> Vec<Vector3<f64>> {
        let mut normals = vec![Vector3::zeros(); self.vertices.len()];
        for t in &self.triangles {
            let p = self.corners(t);
            let n = (p[1] - p[0]).cross(&(p[2] - p[0]));
            let Some(n) = n.try_normalize(0.0) else {
                continue;
            };
            for k in 0..3 {
                let u = p[(k + 1) % 3] - p[k];
                let v = p[(k + 2) % 3] - p[k];
                let angle = u.cross(&v).norm().atan2(u.dot(&v));
                normals[t[k] as usize] += angle * n;
            }
        }
        for n in &mut normals {
            *n = n.try_normalize(0.0).unwrap_or_else(Vector3::zeros);
        }
        normals
    }

    /// Multiplies every coordinate by `factor` (unit conversion).
    pub fn scale(&mut self, factor: f64) {
        for p in &mut self.vertices {
            p.coords *= factor;
        }
    }

    /// Reverses every triangle's orientation.
    pub fn flip(&mut self) {
        for t in &mut self.triangles {
            t.swap(1, 2);
        }
        for n in &mut self.normals {
            *n = -*n;
        }
    }
}
