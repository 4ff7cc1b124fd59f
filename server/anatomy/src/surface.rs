//! Watertight lumen surfaces from a vessel graph: the implicit lumen is sampled on an octree
//! refined to the local vessel radius, each leaf cube is split into tetrahedra that match
//! across cubes of any size, the zero level is extracted tetrahedron by tetrahedron, and the
//! vertices are projected onto the implicit surface and relaxed tangentially.
//!
//! Why this is a closed 2-manifold: the leaf cubes' tetrahedra form a conforming mesh (each
//! cube face is triangulated from its own centre over the corners and the edge midpoints
//! that are corners of some leaf, the same rule on both sides of the face), no sample value
//! is zero, and the surface stays away from the sampled box; the zero set of a piecewise
//! linear function on such a mesh is a closed, oriented 2-manifold.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};

use crate::error::{AnatomyError, Result, require_positive, require_range};
use crate::graph::VesselGraph;
use crate::implicit::LumenField;
use crate::mesh::TriangleMesh;

/// How finely and smoothly a lumen surface is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceSettings {
    /// Leaf cubes near the wall are at most `local radius / cells_per_radius` wide.
    pub cells_per_radius: f64,
    /// Smallest leaf cube (m).
    pub min_cell: f64,
    /// Largest cube (m).
    pub max_cell: f64,
    /// Width of the smooth union where branches meet, as a fraction of the smaller radius.
    pub blend_fraction: f64,
    /// Tangential relaxation passes after projection onto the implicit surface.
    pub smoothing_iterations: usize,
}

impl Default for SurfaceSettings {
    fn default() -> Self {
        Self {
            cells_per_radius: 3.0,
            min_cell: 5e-5,
            max_cell: 4e-3,
            blend_fraction: 0.5,
            smoothing_iterations: 2,
        }
    }
}

type Key = [i32; 3];

/// Leaf cubes whose corners are sampled together (in parallel) ahead of the march.
const SAMPLE_BLOCK: usize = 8192;

/// Builds the lumen surface of `graph` (outward-facing triangles, metres).
pub fn lumen_surface(graph: &VesselGraph, settings: &SurfaceSettings) -> Result<TriangleMesh> {
    require_positive("cells_per_radius", settings.cells_per_radius)?;
    require_positive("min_cell", settings.min_cell)?;
    require_positive("max_cell", settings.max_cell)?;
    require_range(
        "blend_fraction",
        settings.blend_fraction,
        0.0,
        1.0,
        "between 0 and 1",
    )?;
    let margin = 1.5 * settings.max_cell;
    let field = LumenField::new(graph, settings.blend_fraction, margin)?;
    let (smallest, _) = field.radius_range();
    let finest = (smallest / settings.cells_per_radius).max(settings.min_cell);
    let mut lo = Point3::from(Vector3::repeat(f64::INFINITY));
    let mut hi = Point3::from(Vector3::repeat(f64::NEG_INFINITY));
    for b in &graph.branches {
        for (p, r) in b.points.iter().zip(&b.radii) {
            lo = lo.inf(&(p - Vector3::repeat(r + finest)));
            hi = hi.sup(&(p + Vector3::repeat(r + finest)));
        }
    }
    Polygonizer::new(&field, lo, hi, finest, settings)?.run()
}

struct Polygonizer<'a> {
    field: &'a LumenField,
    settings: SurfaceSettings,
    origin: Point3<f64>,
    /// Metres per lattice unit; the finest cube is two units wide.
    unit: f64,
    root_level: u32,
    roots: [i32; 3],
    corners: FxHashSet<Key>,
    values: FxHashMap<Key, f64>,
}

impl<'a> Polygonizer<'a> {
    fn new(
        field: &'a LumenField,
        lo: Point3<f64>,
        hi: Point3<f64>,
        finest: f64,
        settings: &SurfaceSettings,
    ) -> Result<Self> {
        let unit = finest / 2.0;
        let mut root_level = 0;
        while finest * f64::from(1u32 << root_level) < settings.max_cell && root_level < 20 {
            root_level += 1;
        }
        let root_edge = finest * f64::from(1u32 << root_level);
        // One root cube of padding keeps the surface off the sampled box.
        let origin = lo - Vector3::repeat(root_edge);
        let extent = (hi - origin) + Vector3::repeat(root_edge);
        let roots = extent.map(|e| (e / root_edge).ceil() as i32);
        let lattice_span = f64::from(roots.max()) * f64::from(1u32 << (root_level + 1));
        if lattice_span > f64::from(i32::MAX / 4) || roots.iter().any(|&r| r <= 0) {
            return Err(AnatomyError::InvalidParameter {
                name: "min_cell",
                value: settings.min_cell,
                requirement: "large enough for the anatomy's extent",
            });
        }
        Ok(Self {
            field,
            settings: *settings,
            origin,
            unit,
            root_level,
            roots: [roots.x, roots.y, roots.z],
            corners: FxHashSet::default(),
            values: FxHashMap::default(),
        })
    }

    fn position(&self, k: &Key) -> Point3<f64> {
        self.origin + Vector3::new(f64::from(k[0]), f64::from(k[1]), f64::from(k[2])) * self.unit
    }

    /// Refines the octree; returns active leaves as (min corner, edge in lattice units).
    fn build_tree(&mut self) -> Vec<(Key, i32)> {
        let root_edge = 2i32 << self.root_level;
        let mut stack: Vec<(Key, i32)> = Vec::new();
        for k in 0..self.roots[2] {
            for j in 0..self.roots[1] {
                for i in 0..self.roots[0] {
                    stack.push(([i * root_edge, j * root_edge, k * root_edge], root_edge));
                }
            }
        }
        let mut active = Vec::new();
        while let Some((o, e)) = stack.pop() {
            let half = e / 2;
            let center = self.position(&[o[0] + half, o[1] + half, o[2] + half]);
            let half_diagonal = 0.5 * f64::from(e) * self.unit * 3f64.sqrt();
            let sample = self.field.sample(&center, 2.0 * half_diagonal);
            let near_wall = sample.value.abs() <= 1.25 * half_diagonal;
            // Where branches blend, the field may jump by up to a quarter of the blend width;
            // cubes that close are marched even if they need no refinement, so that no sign
            // change inside a skipped cube can leave a hole.
            let slack =
                0.25 * self.settings.blend_fraction * sample.largest_local_radius + 2.0 * self.unit;
            let march = sample.value.abs() <= 1.25 * half_diagonal + slack;
            let edge_m = f64::from(e) * self.unit;
            if near_wall && e > 2 && edge_m > sample.local_radius / self.settings.cells_per_radius {
                for dz in 0..2 {
                    for dy in 0..2 {
                        for dx in 0..2 {
                            stack.push((
                                [o[0] + dx * half, o[1] + dy * half, o[2] + dz * half],
                                half,
                            ));
                        }
                    }
                }
                continue;
            }
            for dz in 0..2 {
                for dy in 0..2 {
                    for dx in 0..2 {
                        self.corners
                            .insert([o[0] + dx * e, o[1] + dy * e, o[2] + dz * e]);
                    }
                }
            }
            if march {
                active.push((o, e));
            }
        }
        active
    }

    fn edge_points(&self, a: Key, b: Key, out: &mut Vec<Key>) {
        let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let len = d[0].abs() + d[1].abs() + d[2].abs();
        let mid = [a[0] + d[0] / 2, a[1] + d[1] / 2, a[2] + d[2] / 2];
        if len >= 2 && len % 2 == 0 && self.corners.contains(&mid) {
            self.edge_points(a, mid, out);
            self.edge_points(mid, b, out);
        } else {
            out.push(a);
        }
    }

    /// Triangles (face centre, q_i, q_i+1) covering the square p00 + [0,1]u + [0,1]v.
    fn face_triangles(&self, p00: Key, u: Key, v: Key, out: &mut Vec<[Key; 3]>) {
        let add = |a: Key, b: Key| [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
        let half = |a: Key| [a[0] / 2, a[1] / 2, a[2] / 2];
        let size = u[0].abs() + u[1].abs() + u[2].abs();
        let center = add(p00, half(add(u, v)));
        if size >= 4 && self.corners.contains(&center) {
            let (hu, hv) = (half(u), half(v));
            for (a, b) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let corner = add(
                    add(p00, [hu[0] * a, hu[1] * a, hu[2] * a]),
                    [hv[0] * b, hv[1] * b, hv[2] * b],
                );
                self.face_triangles(corner, hu, hv, out);
            }
            return;
        }
        let p10 = add(p00, u);
        let p11 = add(p10, v);
        let p01 = add(p00, v);
        let mut ring = Vec::with_capacity(8);
        self.edge_points(p00, p10, &mut ring);
        self.edge_points(p10, p11, &mut ring);
        self.edge_points(p11, p01, &mut ring);
        self.edge_points(p01, p00, &mut ring);
        for i in 0..ring.len() {
            out.push([center, ring[i], ring[(i + 1) % ring.len()]]);
        }
    }

    /// The field at lattice point `k`, never zero (nor so close that crossings collapse
    /// onto it).
    fn sample_value(&self, k: &Key) -> f64 {
        let v = self.field.value(&self.position(k));
        let snap = 0.02 * self.unit;
        if v.abs() < snap { snap } else { v }
    }

    fn value(&mut self, k: &Key) -> f64 {
        if let Some(v) = self.values.get(k) {
            return *v;
        }
        let v = self.sample_value(k);
        self.values.insert(*k, v);
        v
    }

    /// The tetrahedra of leaf cube (o, e) as (face centre, q_i, q_i+1) fans; each with the
    /// cube's centre is one tetrahedron.
    fn cube_fan(&self, o: Key, e: i32, fan: &mut Vec<[Key; 3]>) {
        fan.clear();
        for axis in 0..3 {
            let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut u = [0; 3];
            let mut v = [0; 3];
            u[a1] = e;
            v[a2] = e;
            for side in 0..2 {
                let mut p00 = o;
                p00[axis] += side * e;
                self.face_triangles(p00, u, v, fan);
            }
        }
    }

    /// Evaluates, in parallel, the field at every corner of the tetrahedra of `leaves` not yet
    /// sampled (the field is a pure function of position, so the surface is the same as when
    /// they are sampled one by one as the march reaches them).
    fn sample_corners(&mut self, leaves: &[(Key, i32)]) {
        let mut keys = Vec::new();
        let mut fan = Vec::new();
        for &(o, e) in leaves {
            let half = e / 2;
            let center = [o[0] + half, o[1] + half, o[2] + half];
            self.cube_fan(o, e, &mut fan);
            keys.push(center);
            for t in &fan {
                keys.extend_from_slice(t);
            }
        }
        keys.sort_unstable();
        keys.dedup();
        keys.retain(|k| !self.values.contains_key(k));
        let values: Vec<f64> = keys.par_iter().map(|k| self.sample_value(k)).collect();
        self.values.extend(keys.into_iter().zip(values));
    }

    fn run(mut self) -> Result<TriangleMesh> {
        let active = self.build_tree();
        if std::env::var_os("CATHLAB_SURFACE_STATS").is_some() {
            eprintln!(
                "surface: {} marched cubes, {} leaf corners",
                active.len(),
                self.corners.len()
            );
        }
        let mut vertices: Vec<Point3<f64>> = Vec::new();
        let mut crossing: FxHashMap<(Key, Key), u32> = FxHashMap::default();
        let mut triangles: Vec<[u32; 3]> = Vec::new();
        let mut fan = Vec::new();
        for (i, &(o, e)) in active.iter().enumerate() {
            // The next block of leaves' corners sampled at once, in parallel.
            if i % SAMPLE_BLOCK == 0 {
                let end = (i + SAMPLE_BLOCK).min(active.len());
                self.sample_corners(&active[i..end]);
            }
            let half = e / 2;
            let center = [o[0] + half, o[1] + half, o[2] + half];
            self.cube_fan(o, e, &mut fan);
            for &[fc, q0, q1] in &fan {
                let mut tet = [center, fc, q0, q1];
                if orientation(&tet) < 0 {
                    tet.swap(2, 3);
                }
                let values = [
                    self.value(&tet[0]),
                    self.value(&tet[1]),
                    self.value(&tet[2]),
                    self.value(&tet[3]),
                ];
                self.march(&tet, &values, &mut vertices, &mut crossing, &mut triangles);
            }
        }
        drop(crossing);
        let mut mesh = TriangleMesh {
            vertices,
            triangles,
            normals: Vec::new(),
        };
        if mesh.triangles.is_empty() {
            return Err(AnatomyError::InvalidGraph(
                "the lumen surface is empty".into(),
            ));
        }
        self.relax(&mut mesh);
        let step = 0.05 * self.unit;
        mesh.normals = mesh
            .vertices
            .par_iter()
            .map(|p| {
                self.field
                    .gradient(p, step)
                    .try_normalize(1e-12)
                    .unwrap_or_else(Vector3::z)
            })
            .collect();
        mesh.require_closed_manifold("generated lumen surface")?;
        Ok(mesh)
    }

    fn march(
        &self,
        tet: &[Key; 4],
        values: &[f64; 4],
        vertices: &mut Vec<Point3<f64>>,
        crossing: &mut FxHashMap<(Key, Key), u32>,
        triangles: &mut Vec<[u32; 3]>,
    ) {
        let inside: Vec<usize> = (0..4).filter(|&i| values[i] < 0.0).collect();
        let mut vertex = |i: usize, j: usize| -> u32 {
            let (a, b) = if tet[i] < tet[j] { (i, j) } else { (j, i) };
            *crossing.entry((tet[a], tet[b])).or_insert_with(|| {
                let t = values[a] / (values[a] - values[b]);
                let (pa, pb) = (self.position(&tet[a]), self.position(&tet[b]));
                vertices.push(pa + (pb - pa) * t);
                (vertices.len() - 1) as u32
            })
        };
        // Even permutations of (0, 1, 2, 3) starting with each vertex / each pair.
        const SINGLE: [[usize; 4]; 4] = [[0, 1, 2, 3], [1, 0, 3, 2], [2, 0, 1, 3], [3, 0, 2, 1]];
        match inside.len() {
            1 => {
                let [i, j, k, l] = SINGLE[inside[0]];
                let t = [vertex(i, j), vertex(i, k), vertex(i, l)];
                triangles.push(t);
            }
            3 => {
                let outside = (0..4).find(|i| !inside.contains(i)).unwrap_or(0);
                let [i, j, k, l] = SINGLE[outside];
                let t = [vertex(i, j), vertex(i, l), vertex(i, k)];
                triangles.push(t);
            }
            2 => {
                let [a, b, c, d] = match (inside[0], inside[1]) {
                    (0, 1) => [0, 1, 2, 3],
                    (0, 2) => [0, 2, 3, 1],
                    (0, 3) => [0, 3, 1, 2],
                    (1, 2) => [1, 2, 0, 3],
                    (1, 3) => [1, 3, 2, 0],
                    _ => [2, 3, 0, 1],
                };
                let (ac, ad, bd, bc) = (vertex(a, c), vertex(a, d), vertex(b, d), vertex(b, c));
                triangles.push([ac, ad, bd]);
                triangles.push([ac, bd, bc]);
            }
            _ => {}
        }
    }

    /// Projects every vertex onto the implicit surface, then relaxes it tangentially,
    /// refusing any move that would fold a triangle.
    fn relax(&self, mesh: &mut TriangleMesh) {
        let n = mesh.vertices.len();
        let mut incident: Vec<Vec<u32>> = vec![Vec::new(); n];
        let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (f, t) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                incident[t[k] as usize].push(f as u32);
                let (a, b) = (t[k], t[(k + 1) % 3]);
                neighbours[a as usize].push(b);
                neighbours[b as usize].push(a);
            }
        }
        for list in &mut neighbours {
            list.sort_unstable();
            list.dedup();
        }
        let step = 0.05 * self.unit;
        let project = |x: Point3<f64>| -> Point3<f64> {
            let mut x = x;
            for _ in 0..2 {
                let g = self.field.gradient(&x, step);
                let g2 = g.norm_squared();
                if g2 < 1e-12 {
                    break;
                }
                x -= g * (self.field.value(&x) / g2);
            }
            x
        };
        let folds =
            |mesh: &TriangleMesh, v: usize, candidate: &Point3<f64>, normal: &Vector3<f64>| {
                incident[v].iter().any(|&f| {
                    let t = mesh.triangles[f as usize];
                    let p = t.map(|i| {
                        if i as usize == v {
                            *candidate
                        } else {
                            mesh.vertices[i as usize]
                        }
                    });
                    (p[1] - p[0]).cross(&(p[2] - p[0])).dot(normal) <= 0.0
                })
            };
        // Each vertex's projection depends on its own position only: computed in parallel,
        // then accepted in order (the fold check reads the neighbours as moved so far).
        let projected: Vec<(Point3<f64>, Vector3<f64>)> = mesh
            .vertices
            .par_iter()
            .map(|&x| {
                let candidate = project(x);
                (candidate, self.field.gradient(&candidate, step))
            })
            .collect();
        for (v, (candidate, normal)) in projected.into_iter().enumerate() {
            if !folds(mesh, v, &candidate, &normal) {
                mesh.vertices[v] = candidate;
            }
        }
        for _ in 0..self.settings.smoothing_iterations {
            #[allow(clippy::needless_range_loop)] // vertices move while their neighbours are read
            for v in 0..n {
                let x = mesh.vertices[v];
                let centroid = neighbours[v]
                    .iter()
                    .map(|&w| mesh.vertices[w as usize].coords)
                    .sum::<Vector3<f64>>()
                    / neighbours[v].len().max(1) as f64;
                let normal = self.field.gradient(&x, step);
                let Some(unit_normal) = normal.try_normalize(1e-12) else {
                    continue;
                };
                let shift = centroid - x.coords;
                let tangential = shift - unit_normal * shift.dot(&unit_normal);
                let candidate = project(x + tangential * 0.5);
                if !folds(mesh, v, &candidate, &normal) {
                    mesh.vertices[v] = candidate;
                }
            }
        }
    }
}

/// Sign of the determinant of the tetrahedron's edge vectors (exact on the lattice).
fn orientation(t: &[Key; 4]) -> i64 {
    let d = |i: usize| {
        [
            i64::from(t[i][0] - t[0][0]),
            i64::from(t[i][1] - t[0][1]),
            i64::from(t[i][2] - t[0][2]),
        ]
    };
    let (a, b, c) = (d(1), d(2), d(3));
    let det = a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
        + a[2] * (b[0] * c[1] - b[1] * c[0]);
    det.signum()
}
