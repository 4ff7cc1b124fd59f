//! Decimation of closed surfaces to the triangles they need: half-edge collapses in order of
//! their quadric error (Garland & Heckbert 1997), each kept vertex an original one, accepted
//! only while every original vertex merged into the pair stays within a tolerance of the new
//! triangles around the kept one, the surface stays a closed 2-manifold (the link
//! condition) and no triangle folds over.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use nalgebra::{Matrix4, Point3, Vector3, Vector4};

use crate::lumen::closest_on_triangle;
use crate::mesh::TriangleMesh;

/// What decimation did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decimation {
    /// Triangles before.
    pub triangles_before: usize,
    /// Triangles after.
    pub triangles_after: usize,
}

/// Largest turn of a triangle's normal a collapse may cause (cosine): 45°.
const MAX_FOLD_COS: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// One candidate collapse of `from` onto `to`, valid while both vertices' stamps match.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    cost: f64,
    from: u32,
    to: u32,
    stamps: (u32, u32),
}

impl PartialEq for Candidate {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        // A min-heap on cost, ties broken by the vertices for determinism.
        other
            .cost
            .total_cmp(&self.cost)
            .then_with(|| other.from.cmp(&self.from))
            .then_with(|| other.to.cmp(&self.to))
    }
}

struct State<'a> {
    triangles: Vec<[u32; 3]>,
    alive: Vec<bool>,
    faces_of: Vec<Vec<u32>>,
    quadrics: Vec<Matrix4<f64>>,
    stamps: Vec<u32>,
    removed: Vec<bool>,
    /// The original vertices each vertex stands for (itself and those collapsed into it).
    absorbed: Vec<Vec<u32>>,
    /// Squared tolerance (m²).
    limit: f64,
    /// The original surface (its vertices are the decimated one's too) and each vertex's
    /// original triangles.
    original: &'a TriangleMesh,
    original_faces_of: Vec<Vec<u32>>,
}

impl State<'_> {
    fn error(&self, q: &Matrix4<f64>, p: &Point3<f64>) -> f64 {
        let h = Vector4::new(p.x, p.y, p.z, 1.0);
        (h.transpose() * q * h)[(0, 0)].max(0.0)
    }

    fn neighbours(&self, v: u32) -> Vec<u32> {
        let mut out: Vec<u32> = self.faces_of[v as usize]
            .iter()
            .flat_map(|&f| self.triangles[f as usize])
            .filter(|&w| w != v)
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    }

    fn normal(&self, t: &[u32; 3], moved: u32, to: &Point3<f64>) -> Vector3<f64> {
        let p = |k: usize| {
            if t[k] == moved {
                *to
            } else {
                self.original.vertices[t[k] as usize]
            }
        };
        (p(1) - p(0)).cross(&(p(2) - p(0)))
    }

    /// Triangle `f` with `from` moved onto `to`.
    fn collapsed(&self, f: u32, from: u32, to: u32) -> [u32; 3] {
        self.triangles[f as usize].map(|w| if w == from { to } else { w })
    }

    fn candidate(&self, from: u32, to: u32) -> Candidate {
        let q = self.quadrics[from as usize] + self.quadrics[to as usize];
        Candidate {
            cost: self.error(&q, &self.original.vertices[to as usize]),
            from,
            to,
            stamps: (self.stamps[from as usize], self.stamps[to as usize]),
        }
    }

    /// Whether collapsing `from` onto `to` keeps a closed manifold without folds.
    fn allowed(&self, from: u32, to: u32) -> bool {
        let shared: Vec<u32> = self.faces_of[from as usize]
            .iter()
            .copied()
            .filter(|&f| self.triangles[f as usize].contains(&to))
            .collect();
        if shared.len() != 2 {
            return false;
        }
        // The link condition: the two vertices' common neighbours are exactly the two
        // opposite corners of the faces on the edge.
        let opposite: Vec<u32> = shared
            .iter()
            .map(|&f| {
                *self.triangles[f as usize]
                    .iter()
                    .find(|&&w| w != from && w != to)
                    .expect("a triangle has three distinct corners")
            })
            .collect();
        let a = self.neighbours(from);
        let b = self.neighbours(to);
        let common = a.iter().filter(|w| b.binary_search(w).is_ok()).count();
        if common != 2 || opposite[0] == opposite[1] {
            return false;
        }
        // An opposite corner with three faces would be left with two (a fin).
        if opposite
            .iter()
            .any(|&o| self.faces_of[o as usize].len() <= 3)
        {
            return false;
        }
        // No remaining face of `from` may fold or collapse.
        let to_point = self.original.vertices[to as usize];
        let folds = self.faces_of[from as usize]
            .iter()
            .filter(|f| !shared.contains(f))
            .any(|&f| {
                let t = self.triangles[f as usize];
                let before = self.normal(&t, u32::MAX, &to_point);
                let after = self.normal(&t, from, &to_point);
                let (nb, na) = (before.norm(), after.norm());
                !(na > 1e-3 * nb && before.dot(&after) > MAX_FOLD_COS * nb * na)
            });
        if folds {
            return false;
        }
        // The invariant: every original vertex lies within the tolerance of the triangles
        // around the vertex it was merged into. The collapse changes the triangles around
        // `to` (which takes `from`'s vertices too) and around each neighbour of `from`.
        let fan: Vec<[u32; 3]> = self.faces_of[from as usize]
            .iter()
            .chain(&self.faces_of[to as usize])
            .filter(|f| !shared.contains(f))
            .map(|&f| self.collapsed(f, from, to))
            .collect();
        let corners = |t: &[u32; 3]| t.map(|w| self.original.vertices[w as usize]);
        let within = |groups: &[&[u32]], star: &[[u32; 3]]| {
            groups.iter().flat_map(|g| g.iter()).all(|&v| {
                let p = self.original.vertices[v as usize];
                star.iter().any(|t| {
                    let [a, b, c] = corners(t);
                    let (q, _) = closest_on_triangle(&p, &a, &b, &c);
                    (p - q).norm_squared() <= self.limit
                })
            })
        };
        if !within(
            &[&self.absorbed[from as usize], &self.absorbed[to as usize]],
            &fan,
        ) {
            return false;
        }
        let neighbours_hold = self
            .neighbours(from)
            .into_iter()
            .filter(|&w| w != to)
            .all(|w| {
                let star: Vec<[u32; 3]> = self.faces_of[w as usize]
                    .iter()
                    .filter(|f| !shared.contains(f))
                    .map(|&f| self.collapsed(f, from, to))
                    .collect();
                within(&[&self.absorbed[w as usize]], &star)
            });
        if !neighbours_hold {
            return false;
        }
        // And the middle of each new triangle and of its edges stays within it of the
        // original triangles around the nearest original vertex its corners stand for (an
        // upper bound on the distance to the original surface).
        fan.iter().all(|t| {
            let [a, b, c] = corners(t);
            let stands_for: Vec<u32> = t
                .iter()
                .map(|&w| if w == to { from } else { w })
                .chain([to])
                .flat_map(|w| self.absorbed[w as usize].iter().copied())
                .collect();
            [
                (a.coords + b.coords + c.coords) / 3.0,
                (a.coords + b.coords) * 0.5,
                (b.coords + c.coords) * 0.5,
                (c.coords + a.coords) * 0.5,
            ]
            .into_iter()
            .all(|x| {
                let x = Point3::from(x);
                let nearest = stands_for.iter().min_by(|&&u, &&v| {
                    (self.original.vertices[u as usize] - x)
                        .norm_squared()
                        .total_cmp(&(self.original.vertices[v as usize] - x).norm_squared())
                });
                nearest.is_some_and(|&v| {
                    self.original_faces_of[v as usize].iter().any(|&f| {
                        let [a, b, c] = self.original.corners(&self.original.triangles[f as usize]);
                        let (q, _) = closest_on_triangle(&x, &a, &b, &c);
                        (x - q).norm_squared() <= self.limit
                    })
                })
            })
        })
    }

    fn collapse(&mut self, from: u32, to: u32) {
        let faces = std::mem::take(&mut self.faces_of[from as usize]);
        for f in faces {
            let t = self.triangles[f as usize];
            if t.contains(&to) {
                self.alive[f as usize] = false;
                for w in t {
                    if w != from {
                        self.faces_of[w as usize].retain(|&g| g != f);
                    }
                }
            } else {
                for w in &mut self.triangles[f as usize] {
                    if *w == from {
                        *w = to;
                    }
                }
                self.faces_of[to as usize].push(f);
            }
        }
        let q = self.quadrics[from as usize];
        self.quadrics[to as usize] += q;
        let merged = std::mem::take(&mut self.absorbed[from as usize]);
        self.absorbed[to as usize].extend(merged);
        self.removed[from as usize] = true;
        self.stamps[to as usize] += 1;
        for w in self.neighbours(to) {
            self.stamps[w as usize] += 1;
        }
    }
}

/// Decimates the closed, oriented 2-manifold `mesh` by half-edge collapses while every
/// original vertex stays within `tolerance_m` (m) of the triangles around the vertex it was
/// merged into, and the middles of the new triangles and their edges within it of the
/// original triangles around the nearest original vertex; the result is a closed, oriented 2-manifold whose vertices are original vertices
/// (with their known normals, if the mesh has them).
pub fn decimate(mesh: &TriangleMesh, tolerance_m: f64) -> (TriangleMesh, Decimation) {
    let n = mesh.vertices.len();
    let mut state = State {
        triangles: mesh.triangles.clone(),
        alive: vec![true; mesh.triangles.len()],
        faces_of: vec![Vec::new(); n],
        quadrics: vec![Matrix4::zeros(); n],
        stamps: vec![0; n],
        removed: vec![false; n],
        absorbed: (0..n as u32).map(|v| vec![v]).collect(),
        limit: tolerance_m * tolerance_m,
        original: mesh,
        original_faces_of: Vec::new(),
    };
    for (f, t) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = mesh.corners(t);
        for &v in t {
            state.faces_of[v as usize].push(f as u32);
        }
        let Some(normal) = (b - a).cross(&(c - a)).try_normalize(0.0) else {
            continue;
        };
        let plane = Vector4::new(normal.x, normal.y, normal.z, -normal.dot(&a.coords));
        let q = plane * plane.transpose();
        for &v in t {
            state.quadrics[v as usize] += q;
        }
    }
    state.original_faces_of = state.faces_of.clone();
    // The quadric orders the collapses; the absorbed vertices decide them. A collapse whose
    // quadric error alone (a sum of squared plane distances) is far past the tolerance is
    // not worth queueing.
    let limit = 64.0 * tolerance_m * tolerance_m;
    let mut heap = BinaryHeap::new();
    // One entry per edge: its cheaper direction (the other is tried when that one is not
    // allowed).
    let push = |heap: &mut BinaryHeap<Candidate>, state: &State, a: u32, b: u32| {
        let (x, y) = (state.candidate(a, b), state.candidate(b, a));
        let c = if x.cost <= y.cost { x } else { y };
        if c.cost <= limit {
            heap.push(c);
        }
    };
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if a < b {
                push(&mut heap, &state, a, b);
            }
        }
    }
    while let Some(c) = heap.pop() {
        let (from, to) = (c.from as usize, c.to as usize);
        if state.removed[from]
            || state.removed[to]
            || c.stamps != (state.stamps[from], state.stamps[to])
        {
            continue;
        }
        let (from, to) = if state.allowed(c.from, c.to) {
            (c.from, c.to)
        } else if state.candidate(c.to, c.from).cost <= limit && state.allowed(c.to, c.from) {
            (c.to, c.from)
        } else {
            continue;
        };
        state.collapse(from, to);
        for w in state.neighbours(to) {
            push(&mut heap, &state, w, to);
        }
    }
    // Compact.
    let mut index = vec![u32::MAX; n];
    let mut vertices = Vec::new();
    let mut normals = Vec::new();
    let known = mesh.normals.len() == n;
    let triangles: Vec<[u32; 3]> = state
        .triangles
        .iter()
        .zip(&state.alive)
        .filter(|(_, alive)| **alive)
        .map(|(t, _)| {
            t.map(|v| {
                if index[v as usize] == u32::MAX {
                    index[v as usize] = vertices.len() as u32;
                    vertices.push(mesh.vertices[v as usize]);
                    if known {
                        normals.push(mesh.normals[v as usize]);
                    }
                }
                index[v as usize]
            })
        })
        .collect();
    let report = Decimation {
        triangles_before: mesh.triangles.len(),
        triangles_after: triangles.len(),
    };
    (
        TriangleMesh {
            vertices,
            triangles,
            normals,
        },
        report,
    )
}
