//! The lumen as an implicit function of a vessel graph: tapered tubes along each branch,
//! flat-capped at open ends, smoothly blended where branches meet; negative inside, close to
//! a signed distance (m).

use nalgebra::{Point3, Vector3};
use rustc_hash::FxHashMap;

use crate::error::{Result, require_range};
use crate::graph::VesselGraph;

#[derive(Debug, Clone, Copy)]
struct Segment {
    a: Point3<f64>,
    b: Point3<f64>,
    radius_a: f64,
    radius_b: f64,
    branch: u32,
    /// Plane of a flat cap that clips this segment: point on the plane and the unit normal
    /// pointing into the vessel.
    cap: Option<(Point3<f64>, Vector3<f64>)>,
}

/// Value of the field at a point, with the radius of the vessel that defines it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldSample {
    /// Approximate signed distance to the lumen wall (m), negative inside.
    pub value: f64,
    /// Smallest radius (m) among the vessels whose walls pass within the query's band.
    pub local_radius: f64,
    /// Largest radius (m) among those vessels (bounds how much blending can shift the value).
    pub largest_local_radius: f64,
}

/// The implicit lumen of a vessel graph.
#[derive(Debug, Clone)]
pub struct LumenField {
    segments: Vec<Segment>,
    cells: FxHashMap<(i32, i32, i32), Vec<u32>>,
    inverse_cell: f64,
    /// Smooth-union width as a fraction of the smaller radius at a junction.
    blend_fraction: f64,
    /// Distance beyond which values are reported as this bound (m), positive.
    far_value: f64,
    smallest_radius: f64,
    largest_radius: f64,
}

/// Quadratic smooth minimum of width `k` (Quilez); never above `min(a, b)`, at most `k/4` below.
#[inline]
fn smooth_min(a: f64, b: f64, k: f64) -> f64 {
    if k <= 0.0 {
        return a.min(b);
    }
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

impl LumenField {
    /// Builds the field of `graph`. `blend_fraction` (0–1) sets how wide the fillet is where
    /// branches meet, as a fraction of the smaller radius; `margin` (m) is how far outside the
    /// walls values are exact (beyond, a positive lower bound is returned).
    pub fn new(graph: &VesselGraph, blend_fraction: f64, margin: f64) -> Result<Self> {
        require_range(
            "blend_fraction",
            blend_fraction,
            0.0,
            1.0,
            "between 0 and 1",
        )?;
        crate::error::require_positive("margin", margin)?;
        if graph.branches.is_empty() {
            return Err(crate::error::AnatomyError::InvalidGraph(
                "no branches".into(),
            ));
        }
        let mut degree = vec![0usize; graph.nodes.len()];
        for b in &graph.branches {
            degree[b.start] += 1;
            degree[b.end] += 1;
        }
        let mut segments = Vec::new();
        let mut smallest = f64::INFINITY;
        let mut largest: f64 = 0.0;
        for (id, b) in graph.branches.iter().enumerate() {
            let n = b.points.len();
            let start_cap = (degree[b.start] == 1).then(|| (b.points[0], b.direction_at(0.0)));
            let end_cap =
                (degree[b.end] == 1).then(|| (b.points[n - 1], -b.direction_at(b.length())));
            for i in 0..n - 1 {
                let (a, c) = (b.points[i], b.points[i + 1]);
                // A cap clips every segment that reaches within two radii of its plane's point.
                let near = |cap: Option<(Point3<f64>, Vector3<f64>)>, r: f64| {
                    cap.filter(|(p, _)| (a - p).norm().min((c - p).norm()) <= 2.0 * r)
                };
                let cap = near(start_cap, b.radii[0]).or(near(end_cap, b.radii[n - 1]));
                segments.push(Segment {
                    a,
                    b: c,
                    radius_a: b.radii[i],
                    radius_b: b.radii[i + 1],
                    branch: id as u32,
                    cap,
                });
                smallest = smallest.min(b.radii[i]).min(b.radii[i + 1]);
                largest = largest.max(b.radii[i]).max(b.radii[i + 1]);
            }
        }
        let cell = (largest * 0.5).max(4.0 * smallest);
        let inverse_cell = 1.0 / cell;
        let mut cells: FxHashMap<(i32, i32, i32), Vec<u32>> = FxHashMap::default();
        for (s, seg) in segments.iter().enumerate() {
            let reach = seg.radius_a.max(seg.radius_b) + margin;
            let lo = seg.a.inf(&seg.b) - Vector3::repeat(reach);
            let hi = seg.a.sup(&seg.b) + Vector3::repeat(reach);
            let (i0, i1) = (
                (lo * inverse_cell).map(f64::floor),
                (hi * inverse_cell).map(f64::floor),
            );
            for k in i0.z as i32..=i1.z as i32 {
                for j in i0.y as i32..=i1.y as i32 {
                    for i in i0.x as i32..=i1.x as i32 {
                        cells.entry((i, j, k)).or_default().push(s as u32);
                    }
                }
            }
        }
        let far_value = margin - 0.25 * blend_fraction * largest;
        Ok(Self {
            segments,
            cells,
            inverse_cell,
            blend_fraction,
            far_value: far_value.max(0.5 * margin),
            smallest_radius: smallest,
            largest_radius: largest,
        })
    }

    /// Smallest and largest vessel radius (m).
    pub fn radius_range(&self) -> (f64, f64) {
        (self.smallest_radius, self.largest_radius)
    }

    /// Distance beyond which the field reports a positive lower bound instead of the value (m).
    pub fn far_value(&self) -> f64 {
        self.far_value
    }

    #[inline]
    fn segment_value(seg: &Segment, x: &Point3<f64>) -> (f64, f64) {
        let ab = seg.b - seg.a;
        let t = ((x - seg.a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
        let r = seg.radius_a + (seg.radius_b - seg.radius_a) * t;
        let mut d = (x - (seg.a + ab * t)).norm() - r;
        if let Some((p, n)) = seg.cap {
            d = d.max(-(x - p).dot(&n));
        }
        (d, r)
    }

    /// The segments listed in `x`'s cell (`None`: no wall near).
    fn cell_list(&self, x: &Point3<f64>) -> Option<&[u32]> {
        let key = (
            (x.x * self.inverse_cell).floor() as i32,
            (x.y * self.inverse_cell).floor() as i32,
            (x.z * self.inverse_cell).floor() as i32,
        );
        self.cells.get(&key).map(Vec::as_slice)
    }

    /// Per branch among `list`, the smallest segment value `eval` gives at `x` with what it
    /// gave beside it (branches in a cell are few: past 16, the farthest is replaced, a hard
    /// min); sorted nearest first, in `out`, of which the count is returned.
    fn branch_minima<E: Copy>(
        &self,
        list: &[u32],
        eval: impl Fn(&Segment) -> (f64, E),
        out: &mut [(u32, f64, E); 16],
    ) -> usize {
        let mut used = 0;
        for &s in list {
            let seg = &self.segments[s as usize];
            let (d, extra) = eval(seg);
            if let Some(e) = out[..used].iter_mut().find(|e| e.0 == seg.branch) {
                if d < e.1 {
                    *e = (seg.branch, d, extra);
                }
            } else if used < out.len() {
                out[used] = (seg.branch, d, extra);
                used += 1;
            } else if let Some(e) = out.iter_mut().max_by(|p, q| p.1.total_cmp(&q.1))
                && d < e.1
            {
                *e = (seg.branch, d, extra);
            }
        }
        out[..used].sort_by(|p, q| p.1.total_cmp(&q.1));
        used
    }

    /// The field at `x`; `band` (m) widens the set of vessels whose radius counts as local.
    pub fn sample(&self, x: &Point3<f64>, band: f64) -> FieldSample {
        let Some(list) = self.cell_list(x) else {
            return FieldSample {
                value: self.far_value,
                local_radius: self.largest_radius,
                largest_local_radius: self.largest_radius,
            };
        };
        let mut per_branch = [(u32::MAX, f64::INFINITY, 0.0); 16];
        let used = self.branch_minima(list, |seg| Self::segment_value(seg, x), &mut per_branch);
        let branches = &per_branch[..used];
        let (mut value, mut radius) = (branches[0].1, branches[0].2);
        for e in branches.iter().skip(1) {
            value = smooth_min(value, e.1, self.blend_fraction * radius.min(e.2));
            radius = radius.min(e.2);
        }
        let value = value.min(self.far_value);
        let reach = value + band;
        let (local_radius, largest_local_radius) = if band > 0.0 {
            list.iter()
                .map(|&s| Self::segment_value(&self.segments[s as usize], x))
                .filter(|(d, _)| *d <= reach)
                .fold((f64::INFINITY, 0.0f64), |(lo, hi), (_, r)| {
                    (lo.min(r), hi.max(r))
                })
        } else {
            (radius, radius)
        };
        FieldSample {
            value,
            local_radius: if local_radius.is_finite() {
                local_radius
            } else {
                branches[0].2
            },
            largest_local_radius: largest_local_radius.max(branches[0].2),
        }
    }

    /// The field value at `x` (m).
    #[inline]
    pub fn value(&self, x: &Point3<f64>) -> f64 {
        self.sample(x, 0.0).value
    }

    /// A segment's value (m), radius there (m), value gradient (–) and radius gradient (–)
    /// at `x`: the tapered tube's |x − c(t)| − r(t), whose gradient is the unit offset from
    /// the axis less the taper's slope along the axis (where t is not clamped at an end), or
    /// the cap's plane where it clips deeper.
    #[inline]
    fn segment_value_gradient(
        seg: &Segment,
        x: &Point3<f64>,
    ) -> (f64, f64, Vector3<f64>, Vector3<f64>) {
        let ab = seg.b - seg.a;
        let length2 = ab.norm_squared();
        let raw = (x - seg.a).dot(&ab) / length2;
        let t = raw.clamp(0.0, 1.0);
        let r = seg.radius_a + (seg.radius_b - seg.radius_a) * t;
        let offset = x - (seg.a + ab * t);
        let distance = offset.norm();
        let mut g = if distance > 0.0 {
            offset / distance
        } else {
            Vector3::zeros()
        };
        let grad_r = if raw > 0.0 && raw < 1.0 {
            ab * ((seg.radius_b - seg.radius_a) / length2)
        } else {
            Vector3::zeros()
        };
        g -= grad_r;
        let mut d = distance - r;
        if let Some((p, n)) = seg.cap {
            let plane = -(x - p).dot(&n);
            if plane > d {
                d = plane;
                g = -n;
            }
        }
        (d, r, g, grad_r)
    }

    /// The field at `x` (m) and its gradient (–), exact where the field is smooth: the same
    /// per-branch minimum and smooth union as [`LumenField::sample`], each union weighting
    /// its two gradients by the polynomial's derivative. Beyond the cells with walls, the far
    /// value and a zero gradient.
    pub fn value_gradient(&self, x: &Point3<f64>) -> (f64, Vector3<f64>) {
        let Some(list) = self.cell_list(x) else {
            return (self.far_value, Vector3::zeros());
        };
        // The same per-branch minimum as `sample`, each with its radius and the gradients.
        let mut per_branch = [(
            u32::MAX,
            f64::INFINITY,
            (0.0, Vector3::zeros(), Vector3::zeros()),
        ); 16];
        let used = self.branch_minima(
            list,
            |seg| {
                let (d, r, g, gr) = Self::segment_value_gradient(seg, x);
                (d, (r, g, gr))
            },
            &mut per_branch,
        );
        let branches = &per_branch[..used];
        let (mut value, (mut radius, mut gradient, mut grad_radius)) =
            (branches[0].1, branches[0].2);
        for &(_, e_value, (e_radius, e_gradient, e_grad_radius)) in branches.iter().skip(1) {
            let (smaller, grad_smaller) = if radius <= e_radius {
                (radius, grad_radius)
            } else {
                (e_radius, e_grad_radius)
            };
            let k = self.blend_fraction * smaller;
            // smooth_min(a, b, k) = min(a, b) − k h²/4, h = max(k − |a − b|, 0)/k: its
            // derivative is 1 − h/2 on the smaller argument, h/2 on the larger, and
            // −h²/4 − h|a − b|/(2k) on k (the blend's width follows the tapering radius).
            let delta = (value - e_value).abs();
            let h = if k > 0.0 {
                (k - delta).max(0.0) / k
            } else {
                0.0
            };
            let w_value = if value <= e_value {
                1.0 - 0.5 * h
            } else {
                0.5 * h
            };
            let d_k = if h > 0.0 {
                -0.25 * h * h - 0.5 * h * delta / k
            } else {
                0.0
            };
            gradient = gradient * w_value
                + e_gradient * (1.0 - w_value)
                + grad_smaller * (self.blend_fraction * d_k);
            value = smooth_min(value, e_value, k);
            (radius, grad_radius) = (smaller, grad_smaller);
        }
        if value >= self.far_value {
            return (self.far_value, Vector3::zeros());
        }
        (value, gradient)
    }

    /// Central-difference gradient with step `h` (m).
    pub fn gradient(&self, x: &Point3<f64>, h: f64) -> Vector3<f64> {
        let mut g = Vector3::zeros();
        for k in 0..3 {
            let mut e = Vector3::zeros();
            e[k] = h;
            g[k] = (self.value(&(x + e)) - self.value(&(x - e))) / (2.0 * h);
        }
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phantom::{NeuroPhantomParams, neuro_phantom, y_bifurcation};
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    /// The analytic gradient against central differences at random points near the walls of
    /// a bifurcation and the neuro phantom, wherever the field is smooth there (its forward and
    /// backward differences agree: not on a kink between two segments or a cap's edge).
    #[test]
    fn the_analytic_gradient_is_the_fields_own_where_it_is_smooth() {
        let graphs = [
            y_bifurcation(4e-3, 3e-3, 30e-3, 25e-3, 0.5).unwrap(),
            neuro_phantom(&NeuroPhantomParams::default()).unwrap(),
        ];
        let mut rng = StdRng::seed_from_u64(5);
        let h = 1e-9;
        let (mut compared, mut kinks) = (0, 0);
        for graph in &graphs {
            let field = LumenField::new(graph, 0.5, 3e-3).unwrap();
            for _ in 0..4000 {
                let b = &graph.branches[rng.random_range(0..graph.branches.len())];
                let s = rng.random_range(0.0..b.length());
                let radius = b.radius_at(s);
                let direction = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                let x = b.point_at(s) + direction * (radius * rng.random_range(0.3..1.4));
                let (value, gradient) = field.value_gradient(&x);
                assert!((value - field.value(&x)).abs() < 1e-15, "{value}");
                if value >= field.far_value() {
                    continue;
                }
                let mut smooth = true;
                let mut numeric = Vector3::zeros();
                for k in 0..3 {
                    let mut e = Vector3::zeros();
                    e[k] = h;
                    let (up, mid, down) = (field.value(&(x + e)), value, field.value(&(x - e)));
                    let (forward, backward) = ((up - mid) / h, (mid - down) / h);
                    smooth &= (forward - backward).abs() < 1e-4;
                    numeric[k] = (up - down) / (2.0 * h);
                }
                if !smooth {
                    kinks += 1;
                    continue;
                }
                compared += 1;
                assert!(
                    (gradient - numeric).norm() < 1e-5,
                    "at {x:?}: analytic {gradient:?}, numeric {numeric:?}"
                );
            }
        }
        println!("{compared} points compared, {kinks} on kinks skipped");
        assert!(compared > 7000, "{compared}");
    }
}
