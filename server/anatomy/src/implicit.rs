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
    index: SegmentCells,
    /// Smooth-union width as a fraction of the smaller radius at a junction.
    blend_fraction: f64,
    /// Distance beyond which values are reported as this bound (m), positive.
    far_value: f64,
    smallest_radius: f64,
    largest_radius: f64,
}

/// Cells of a uniform grid, each listing the segments that can define the field in it.
#[derive(Debug, Clone, Default)]
struct SegmentCells {
    /// Cells per metre.
    inverse_cell: f64,
    /// Per listed cell, its range of `lists`.
    cells: FxHashMap<(i32, i32, i32), (u32, u32)>,
    lists: Vec<u32>,
}

impl SegmentCells {
    #[inline]
    fn key(inverse_cell: f64, x: &Point3<f64>) -> (i32, i32, i32) {
        (
            (x.x * inverse_cell).floor() as i32,
            (x.y * inverse_cell).floor() as i32,
            (x.z * inverse_cell).floor() as i32,
        )
    }

    /// The flat form of per-cell lists, cells in key order (so that the build is the same
    /// whatever order the lists were made in).
    fn from_lists(inverse_cell: f64, lists: FxHashMap<(i32, i32, i32), Vec<u32>>) -> Self {
        let mut keys: Vec<_> = lists.into_iter().collect();
        keys.sort_unstable_by_key(|(k, _)| *k);
        let mut flat = Vec::with_capacity(keys.iter().map(|(_, l)| l.len()).sum());
        let mut cells = FxHashMap::default();
        cells.reserve(keys.len());
        for (key, list) in keys {
            cells.insert(key, (flat.len() as u32, list.len() as u32));
            flat.extend(list);
        }
        Self {
            inverse_cell,
            cells,
            lists: flat,
        }
    }

    #[inline]
    fn list(&self, x: &Point3<f64>) -> Option<&[u32]> {
        let &(start, count) = self.cells.get(&Self::key(self.inverse_cell, x))?;
        Some(&self.lists[start as usize..(start + count) as usize])
    }

    /// Heap bytes (the map counted at its capacity).
    fn bytes(&self) -> usize {
        self.cells.capacity() * (std::mem::size_of::<((i32, i32, i32), (u32, u32))>() + 1)
            + self.lists.capacity() * std::mem::size_of::<u32>()
    }
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
            index: SegmentCells::from_lists(inverse_cell, cells),
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
    #[inline]
    fn cell_list(&self, x: &Point3<f64>) -> Option<&[u32]> {
        self.index.list(x)
    }

    /// Heap bytes held (segments and cell index).
    pub fn memory_bytes(&self) -> usize {
        self.segments.capacity() * std::mem::size_of::<Segment>() + self.index.bytes()
    }

    /// Listed cells, listed segments and the cell edge (m) of the index, for reports.
    pub fn index_summary(&self) -> (usize, usize, f64) {
        (
            self.index.cells.len(),
            self.index.lists.len(),
            1.0 / self.index.inverse_cell,
        )
    }

    /// The same field with a finer index for many point queries: cells of edge `cell` (m),
    /// each listing only the segments that can define the field somewhere in it.
    ///
    /// A segment's value varies across a cell by at most its Lipschitz constant (1 plus its
    /// taper's slope) times the cell's half diagonal, which bounds it from its value at the
    /// cell's centre. A segment is kept when its lower bound is within its branch's least
    /// upper bound (it can be the branch's minimum somewhere in the cell), and a branch when
    /// its lower bound is within K of the least upper bound of all, K the widest blend among
    /// the cell's vessels (past it, a branch leaves every union it enters unchanged, whatever
    /// the order). A segment beyond the far value plus the graph's widest blend everywhere in
    /// a cell is not considered there, and a cell where the union cannot come below the far
    /// value is not listed. Values and gradients below the far value are those of the
    /// field over all segments (a unit test compares them), in a fraction of the time.
    pub fn with_fine_index(mut self, cell: f64) -> Result<Self> {
        let cell = crate::error::require_positive("cell", cell)?;
        let inverse_cell = 1.0 / cell;
        let half_diagonal = 0.5 * cell * 3f64.sqrt();
        // Past this everywhere in a cell, a segment changes no value below the far value,
        // whatever vessels are blended after it.
        let relevant = self.far_value + self.blend_fraction * self.largest_radius;
        let mut branch_ranges: Vec<std::ops::Range<usize>> = Vec::new();
        for (s, seg) in self.segments.iter().enumerate() {
            match branch_ranges.last_mut() {
                Some(r) if self.segments[r.start].branch == seg.branch => r.end = s + 1,
                _ => branch_ranges.push(s..s + 1),
            }
        }
        type Key = (i32, i32, i32);
        /// One branch in one cell: its least upper bound, least lower bound, largest radius
        /// and the segments that can hold its minimum there.
        struct InCell {
            upper: f64,
            lower: f64,
            radius: f64,
            segments: Vec<(u32, f64)>,
        }
        let per_branch: Vec<Vec<(Key, InCell)>> = {
            use rayon::prelude::*;
            branch_ranges
                .par_iter()
                .map(|range| {
                    let mut cells: FxHashMap<Key, InCell> = FxHashMap::default();
                    for s in range.clone() {
                        let seg = &self.segments[s];
                        let length = (seg.b - seg.a).norm().max(f64::MIN_POSITIVE);
                        let spread =
                            (1.0 + (seg.radius_b - seg.radius_a).abs() / length) * half_diagonal;
                        let radius = seg.radius_a.max(seg.radius_b);
                        let reach = radius + relevant + spread;
                        let lo = ((seg.a.inf(&seg.b) - Vector3::repeat(reach)) * inverse_cell)
                            .map(f64::floor);
                        let hi = ((seg.a.sup(&seg.b) + Vector3::repeat(reach)) * inverse_cell)
                            .map(f64::floor);
                        for k in lo.z as i32..=hi.z as i32 {
                            for j in lo.y as i32..=hi.y as i32 {
                                for i in lo.x as i32..=hi.x as i32 {
                                    let centre = Point3::new(
                                        (f64::from(i) + 0.5) * cell,
                                        (f64::from(j) + 0.5) * cell,
                                        (f64::from(k) + 0.5) * cell,
                                    );
                                    let (value, _) = Self::segment_value(seg, &centre);
                                    let (lower, upper) = (value - spread, value + spread);
                                    if lower > relevant {
                                        continue;
                                    }
                                    let e = cells.entry((i, j, k)).or_insert_with(|| InCell {
                                        upper: f64::INFINITY,
                                        lower: f64::INFINITY,
                                        radius: 0.0,
                                        segments: Vec::new(),
                                    });
                                    e.radius = e.radius.max(radius);
                                    if lower > e.upper {
                                        continue;
                                    }
                                    if upper < e.upper {
                                        e.upper = upper;
                                        e.segments.retain(|&(_, l)| l <= upper);
                                    }
                                    e.lower = e.lower.min(lower);
                                    e.segments.push((s as u32, lower));
                                }
                            }
                        }
                    }
                    cells.into_iter().collect()
                })
                .collect()
        };
        // Per cell: the least upper and lower bounds of all branches, the widest blend among
        // them and how many there are.
        let mut bounds: FxHashMap<Key, (f64, f64, f64, usize)> = FxHashMap::default();
        for (key, b) in per_branch.iter().flatten() {
            let e = bounds
                .entry(*key)
                .or_insert((f64::INFINITY, f64::INFINITY, 0.0, 0));
            *e = (
                e.0.min(b.upper),
                e.1.min(b.lower),
                e.2.max(self.blend_fraction * b.radius),
                e.3 + 1,
            );
        }
        let mut lists: FxHashMap<Key, Vec<u32>> = FxHashMap::default();
        for (key, b) in per_branch.iter().flatten() {
            let (least_upper, least_lower, widest_blend, branches) = bounds[key];
            // Each union lowers the least value by at most a quarter of its width: a cell
            // whose every value stays past the far value is left out.
            let floor = least_lower - 0.25 * widest_blend * (branches - 1) as f64;
            if floor <= self.far_value && b.lower <= least_upper + widest_blend {
                lists
                    .entry(*key)
                    .or_default()
                    .extend(b.segments.iter().map(|e| e.0));
            }
        }
        for list in lists.values_mut() {
            list.sort_unstable();
        }
        self.index = SegmentCells::from_lists(inverse_cell, lists);
        Ok(self)
    }

    /// The exact value (m) and gradient (–) of the nearest wall over every segment, a hard
    /// minimum without the cell index: for points beyond the far value (a device gone
    /// through the wall), where the indexed field reports only a bound.
    pub fn nearest_wall(&self, x: &Point3<f64>) -> (f64, Vector3<f64>) {
        self.segments
            .iter()
            .map(|seg| {
                let (d, _, g, _) = Self::segment_value_gradient(seg, x);
                (d, g)
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap_or((f64::INFINITY, Vector3::zeros()))
    }

    /// Per branch among `list`, the smallest segment value `eval` gives at `x` with what it
    /// gave beside it (branches in a cell are few: past 16, the farthest is replaced, a hard
    /// min); sorted nearest first, in `out`, of which the count is returned.
    fn branch_minima<E: Copy>(
        &self,
        list: &[u32],
        eval: impl Fn(u32, &Segment) -> (f64, E),
        out: &mut [(u32, f64, E); 16],
    ) -> usize {
        let mut used = 0;
        for &s in list {
            let seg = &self.segments[s as usize];
            let (d, extra) = eval(s, seg);
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
        let used = self.branch_minima(list, |_, seg| Self::segment_value(seg, x), &mut per_branch);
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
        match self.cell_list(x) {
            Some(list) => self.value_gradient_of(list, x),
            None => (self.far_value, Vector3::zeros()),
        }
    }

    /// [`LumenField::value_gradient`] over the segments `list` names.
    fn value_gradient_of(&self, list: &[u32], x: &Point3<f64>) -> (f64, Vector3<f64>) {
        // The same per-branch minimum as `sample` (by value alone), then the gradients of the
        // branches' nearest segments.
        let mut nearest = [(u32::MAX, f64::INFINITY, 0u32); 16];
        let used = self.branch_minima(
            list,
            |s, seg| (Self::segment_value(seg, x).0, s),
            &mut nearest,
        );
        let mut per_branch = [(0.0, (0.0, Vector3::zeros(), Vector3::zeros())); 16];
        for (out, &(_, _, s)) in per_branch.iter_mut().zip(&nearest[..used]) {
            let (d, r, g, gr) = Self::segment_value_gradient(&self.segments[s as usize], x);
            *out = (d, (r, g, gr));
        }
        let branches = &per_branch[..used];
        let (mut value, (mut radius, mut gradient, mut grad_radius)) = branches[0];
        for &(e_value, (e_radius, e_gradient, e_grad_radius)) in branches.iter().skip(1) {
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

#[cfg(test)]
mod fine_index_tests {
    use super::*;
    use crate::phantom::{NeuroPhantomParams, neuro_phantom, y_bifurcation};
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    /// The fine index against the field over every segment (each branch's nearest segment,
    /// the 16 nearest branches): equal, value and gradient, at random points inside the
    /// lumen and up to 1 mm outside, for two cell sizes. Farther out, where only the far
    /// value matters, the field over every segment lets a vessel too far to change the union
    /// narrow a later blend (its radius is carried along the sorted union), which the index,
    /// listing only vessels that can change it, does not: counted, not compared.
    #[test]
    fn the_fine_index_gives_the_field_over_every_segment() {
        let graphs = [
            y_bifurcation(4e-3, 3e-3, 30e-3, 25e-3, 0.5).unwrap(),
            neuro_phantom(&NeuroPhantomParams::default()).unwrap(),
        ];
        let mut rng = StdRng::seed_from_u64(11);
        for graph in &graphs {
            let coarse = LumenField::new(graph, 0.5, 3e-3).unwrap();
            for cell in [0.7e-3, 1.5e-3] {
                let fine = coarse.clone().with_fine_index(cell).unwrap();
                let (mut compared, mut beyond) = (0, 0);
                for _ in 0..10_000 {
                    let b = &graph.branches[rng.random_range(0..graph.branches.len())];
                    let s = rng.random_range(0.0..b.length());
                    let direction = Vector3::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                    );
                    let x =
                        b.point_at(s) + direction * (b.radius_at(s) * rng.random_range(0.0..1.6));
                    let mut nearest: Vec<(f64, u32)> =
                        vec![(f64::INFINITY, 0); graph.branches.len()];
                    for (k, seg) in coarse.segments.iter().enumerate() {
                        let d = LumenField::segment_value(seg, &x).0;
                        let e = &mut nearest[seg.branch as usize];
                        if d < e.0 {
                            *e = (d, k as u32);
                        }
                    }
                    nearest.sort_by(|p, q| p.0.total_cmp(&q.0));
                    let list: Vec<u32> = nearest.iter().take(16).map(|e| e.1).collect();
                    let (w, h) = coarse.value_gradient_of(&list, &x);
                    if w > 1e-3 {
                        beyond += 1;
                        continue;
                    }
                    let (v, g) = fine.value_gradient(&x);
                    assert!(
                        (v - w).abs() < 1e-12 && (g - h).norm() < 1e-9,
                        "cell {cell} at {x:?}: {v} {g:?} against {w} {h:?}"
                    );
                    compared += 1;
                }
                println!(
                    "cell {} mm: {compared} points compared, {beyond} beyond 1 mm; index {:?}",
                    cell * 1e3,
                    fine.index_summary()
                );
                assert!(compared > 7000, "{compared}");
            }
        }
    }
}
