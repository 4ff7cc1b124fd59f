//! The medial axis of a segmented lumen: a TEASAR skeleton (Sato et al. 2000) — shortest
//! paths from a root through a penalty field that keeps them near the middle of the vessel
//! (the Euclidean distance to the wall), each new path grown from the voxel farthest from
//! the root that no earlier path's rolling ball has covered — then branches between end
//! and branch points, and pruning of spurs that stand out of their parent less than a few
//! of their own radii.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rustc_hash::FxHashMap;

use crate::error::{ImagingError, Result};

/// Skeleton voxels (linear indices) and their neighbours on the skeleton.
pub type Adjacency = FxHashMap<usize, Vec<usize>>;

/// How the TEASAR skeleton is grown and pruned.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkeletonSettings {
    /// A path covers every lumen voxel within `scale · r + constant` of each of its voxels,
    /// r the distance to the wall there: larger values find fewer, longer branches.
    pub invalidation_scale: f64,
    /// See `invalidation_scale` (m).
    pub invalidation_constant_m: f64,
    /// A terminal branch is a spur, and pruned, when it stands out of its parent's lumen by
    /// less than this many of its own radii.
    pub spur_aspect: f64,
    /// ... or by less than this length (m).
    pub spur_min_length_m: f64,
}

impl Default for SkeletonSettings {
    fn default() -> Self {
        Self {
            invalidation_scale: 1.5,
            invalidation_constant_m: 1.5e-3,
            spur_aspect: 2.0,
            spur_min_length_m: 2.0e-3,
        }
    }
}

/// The lumen voxels in compact numbering with their 26 neighbours.
struct Grid {
    dims: [usize; 3],
    spacing: [f64; 3],
    /// Linear index → compact index (u32::MAX outside the lumen).
    compact: Vec<u32>,
    /// Compact index → linear index.
    voxels: Vec<usize>,
    offsets: Vec<([isize; 3], f64)>,
}

impl Grid {
    fn new(mask: &[bool], dims: [usize; 3], spacing: [f64; 3]) -> Self {
        let mut compact = vec![u32::MAX; mask.len()];
        let mut voxels = Vec::new();
        for (n, &m) in mask.iter().enumerate() {
            if m {
                compact[n] = voxels.len() as u32;
                voxels.push(n);
            }
        }
        let mut offsets = Vec::with_capacity(26);
        for dk in -1isize..=1 {
            for dj in -1isize..=1 {
                for di in -1isize..=1 {
                    if (di, dj, dk) != (0, 0, 0) {
                        let len = ((di as f64 * spacing[0]).powi(2)
                            + (dj as f64 * spacing[1]).powi(2)
                            + (dk as f64 * spacing[2]).powi(2))
                        .sqrt();
                        offsets.push(([di, dj, dk], len));
                    }
                }
            }
        }
        Self {
            dims,
            spacing,
            compact,
            voxels,
            offsets,
        }
    }

    fn ijk(&self, n: usize) -> [isize; 3] {
        let (nx, ny) = (self.dims[0], self.dims[1]);
        [
            (n % nx) as isize,
            ((n / nx) % ny) as isize,
            (n / (nx * ny)) as isize,
        ]
    }

    fn linear(&self, p: [isize; 3]) -> Option<usize> {
        if (0..3).all(|a| p[a] >= 0 && (p[a] as usize) < self.dims[a]) {
            Some(p[0] as usize + self.dims[0] * (p[1] as usize + self.dims[1] * p[2] as usize))
        } else {
            None
        }
    }

    /// Lumen neighbours of compact voxel `c` with the step length (m).
    fn neighbours(&self, c: u32) -> impl Iterator<Item = (u32, f64)> + '_ {
        let p = self.ijk(self.voxels[c as usize]);
        self.offsets.iter().filter_map(move |(d, len)| {
            let n = self.linear([p[0] + d[0], p[1] + d[1], p[2] + d[2]])?;
            let m = self.compact[n];
            (m != u32::MAX).then_some((m, *len))
        })
    }

    /// Dijkstra from `source`: the cost, the predecessor and the plain length (m) along
    /// the cheapest path of every voxel. `weight(a, b, length)` prices a step.
    fn shortest_paths(
        &self,
        source: u32,
        weight: impl Fn(u32, u32, f64) -> f64,
    ) -> (Vec<u32>, Vec<f64>) {
        let n = self.voxels.len();
        let mut cost = vec![f64::INFINITY; n];
        let mut parent = vec![u32::MAX; n];
        let mut along = vec![f64::INFINITY; n];
        let mut heap = BinaryHeap::new();
        cost[source as usize] = 0.0;
        along[source as usize] = 0.0;
        heap.push(Reverse((Ordered(0.0), source)));
        while let Some(Reverse((Ordered(c), v))) = heap.pop() {
            if c > cost[v as usize] {
                continue;
            }
            for (m, len) in self.neighbours(v) {
                let next = c + weight(v, m, len);
                if next < cost[m as usize] {
                    cost[m as usize] = next;
                    parent[m as usize] = v;
                    along[m as usize] = along[v as usize] + len;
                    heap.push(Reverse((Ordered(next), m)));
                }
            }
        }
        (parent, along)
    }

    /// Marks every lumen voxel within `radius` (m) of compact voxel `c` as covered.
    fn cover_ball(&self, c: u32, radius: f64, covered: &mut [bool]) {
        let p = self.ijk(self.voxels[c as usize]);
        let reach = [0, 1, 2].map(|a| (radius / self.spacing[a]).floor() as isize);
        let r2 = radius * radius;
        for dk in -reach[2]..=reach[2] {
            let z2 = (dk as f64 * self.spacing[2]).powi(2);
            for dj in -reach[1]..=reach[1] {
                let yz2 = z2 + (dj as f64 * self.spacing[1]).powi(2);
                if yz2 > r2 {
                    continue;
                }
                for di in -reach[0]..=reach[0] {
                    if yz2 + (di as f64 * self.spacing[0]).powi(2) > r2 {
                        continue;
                    }
                    if let Some(n) = self.linear([p[0] + di, p[1] + dj, p[2] + dk]) {
                        let m = self.compact[n];
                        if m != u32::MAX {
                            covered[m as usize] = true;
                        }
                    }
                }
            }
        }
    }
}

/// f64 with a total order, for the priority queue.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Ordered(f64);
impl Eq for Ordered {}
impl PartialOrd for Ordered {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Ordered {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// A grown skeleton: its voxels' adjacency and the root (linear indices).
#[derive(Debug, Clone)]
pub struct Skeleton {
    /// Skeleton voxel → neighbouring skeleton voxels.
    pub adjacency: Adjacency,
    /// The root: the lumen voxel farthest (along the lumen) from the seed.
    pub root: usize,
}

/// Grows the TEASAR skeleton of the connected lumen `mask` from `seed` (linear index):
/// `dbf` is the distance to the wall (m) per voxel.
pub fn teasar(
    mask: &[bool],
    dbf: &[f32],
    dims: [usize; 3],
    spacing: [f64; 3],
    seed: usize,
    settings: &SkeletonSettings,
) -> Result<Skeleton> {
    let grid = Grid::new(mask, dims, spacing);
    let seed_c = *grid
        .compact
        .get(seed)
        .filter(|&&c| c != u32::MAX)
        .ok_or_else(|| ImagingError::Segmentation("the seed is not in the lumen mask".into()))?;
    // The root is the voxel farthest from the seed along the lumen: an end of a vessel.
    let (_, from_seed) = grid.shortest_paths(seed_c, |_, _, len| len);
    let root = (0..from_seed.len())
        .filter(|&c| from_seed[c].is_finite())
        .max_by(|&a, &b| from_seed[a].total_cmp(&from_seed[b]))
        .unwrap_or(seed_c as usize) as u32;
    grow(&grid, dbf, root, settings)
}

/// Grows the TEASAR skeleton of the connected lumen `mask` from a given `root` voxel (linear
/// index, an end of a vessel: the access): `dbf` is the distance to the wall (m) per voxel.
pub fn teasar_from_root(
    mask: &[bool],
    dbf: &[f32],
    dims: [usize; 3],
    spacing: [f64; 3],
    root: usize,
    settings: &SkeletonSettings,
) -> Result<Skeleton> {
    let grid = Grid::new(mask, dims, spacing);
    let root_c = *grid
        .compact
        .get(root)
        .filter(|&&c| c != u32::MAX)
        .ok_or_else(|| ImagingError::Segmentation("the root is not in the lumen mask".into()))?;
    grow(&grid, dbf, root_c, settings)
}

/// TEASAR from the compact voxel `root`.
fn grow(grid: &Grid, dbf: &[f32], root: u32, settings: &SkeletonSettings) -> Result<Skeleton> {
    let spacing = grid.spacing;
    // Steps are priced by (h/r)⁴: a path off the middle by δ pays about 4δ/r more per unit
    // length, the same pull towards the centre in vessels of every size.
    let h = spacing.iter().cloned().fold(f64::INFINITY, f64::min);
    let penalty: Vec<f64> = grid
        .voxels
        .iter()
        .map(|&n| (h / f64::from(dbf[n]).max(0.5 * h)).powi(4))
        .collect();
    let (parent, along) = grid.shortest_paths(root, |a, b, len| {
        len * 0.5 * (penalty[a as usize] + penalty[b as usize])
    });
    let mut order: Vec<u32> = (0..grid.voxels.len() as u32)
        .filter(|&c| along[c as usize].is_finite())
        .collect();
    order.sort_by(|&a, &b| along[b as usize].total_cmp(&along[a as usize]));
    let mut covered = vec![false; grid.voxels.len()];
    let mut on_skeleton = vec![false; grid.voxels.len()];
    on_skeleton[root as usize] = true;
    let mut adjacency = Adjacency::default();
    adjacency.insert(grid.voxels[root as usize], Vec::new());
    for &target in &order {
        if covered[target as usize] {
            continue;
        }
        let mut path = vec![target];
        let mut at = target;
        while !on_skeleton[at as usize] {
            at = parent[at as usize];
            path.push(at);
        }
        for pair in path.windows(2) {
            let (a, b) = (grid.voxels[pair[0] as usize], grid.voxels[pair[1] as usize]);
            adjacency.entry(a).or_default().push(b);
            adjacency.entry(b).or_default().push(a);
        }
        for &c in &path {
            let r = f64::from(dbf[grid.voxels[c as usize]]);
            grid.cover_ball(
                c,
                settings.invalidation_scale * r + settings.invalidation_constant_m,
                &mut covered,
            );
            on_skeleton[c as usize] = true;
        }
    }
    Ok(Skeleton {
        adjacency,
        root: grid.voxels[root as usize],
    })
}

/// A chain of skeleton voxels between two nodes (voxels whose degree is not 2).
#[derive(Debug, Clone, PartialEq)]
pub struct VoxelBranch {
    /// Linear indices from one node to the other, both included.
    pub voxels: Vec<usize>,
}

/// Splits a tree-shaped skeleton into branches between its end and branch points.
pub fn branches(adjacency: &Adjacency) -> Vec<VoxelBranch> {
    let is_node = |v: &usize| adjacency.get(v).is_some_and(|n| n.len() != 2);
    let mut nodes: Vec<usize> = adjacency.keys().copied().filter(is_node).collect();
    nodes.sort_unstable();
    let mut out = Vec::new();
    for &start in &nodes {
        for &first in &adjacency[&start] {
            let mut chain = vec![start, first];
            let (mut previous, mut at) = (start, first);
            while !is_node(&at) {
                let next = adjacency[&at]
                    .iter()
                    .copied()
                    .find(|&n| n != previous)
                    .unwrap_or(previous);
                previous = at;
                at = next;
                chain.push(at);
            }
            // Each branch is walked from both of its ends: keep one.
            if (start, chain[1]) <= (at, chain[chain.len() - 2]) {
                out.push(VoxelBranch { voxels: chain });
            }
        }
    }
    if nodes.is_empty() && !adjacency.is_empty() {
        // A single voxel (or a closed loop, which TEASAR never makes).
        let &v = adjacency.keys().min().unwrap_or(&0);
        out.push(VoxelBranch { voxels: vec![v] });
    }
    out
}

/// Prunes spurs: terminal branches (one end free, the other a branch point) that stand out
/// of the parent's lumen — their length less the wall distance at the branch point — by
/// less than `spur_aspect` of their own radius (the median wall distance of the part
/// outside the parent) or less than `spur_min_length_m`. Repeats until none is left; the
/// branch holding `keep` (the root) is never pruned. Returns how many were pruned.
pub fn prune_spurs(
    adjacency: &mut Adjacency,
    dbf: &[f32],
    dims: [usize; 3],
    spacing: [f64; 3],
    keep: usize,
    settings: &SkeletonSettings,
) -> usize {
    let position = |n: usize| {
        let (nx, ny) = (dims[0], dims[1]);
        [
            (n % nx) as f64 * spacing[0],
            ((n / nx) % ny) as f64 * spacing[1],
            (n / (nx * ny)) as f64 * spacing[2],
        ]
    };
    let distance = |a: usize, b: usize| {
        let (p, q) = (position(a), position(b));
        ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
    };
    let mut pruned = 0;
    loop {
        let all = branches(adjacency);
        if all.len() <= 1 {
            return pruned;
        }
        let degree = |v: usize| adjacency.get(&v).map_or(0, Vec::len);
        let mut spurs = Vec::new();
        for b in &all {
            let (first, last) = (b.voxels[0], b.voxels[b.voxels.len() - 1]);
            // The chain from the branch point to the free end.
            let (junction, chain): (usize, Vec<usize>) = match (degree(first), degree(last)) {
                (1, d) if d >= 3 => (last, b.voxels.iter().rev().copied().collect()),
                (d, 1) if d >= 3 => (first, b.voxels.clone()),
                _ => continue,
            };
            if chain.contains(&keep) {
                continue;
            }
            let length: f64 = chain.windows(2).map(|w| distance(w[0], w[1])).sum();
            let parent_radius = f64::from(dbf[junction]);
            let protrusion = length - parent_radius;
            let mut outside: Vec<f32> = chain
                .iter()
                .filter(|&&v| distance(v, junction) > parent_radius)
                .map(|&v| dbf[v])
                .collect();
            let own_radius = if outside.is_empty() {
                0.0
            } else {
                let mid = outside.len() / 2;
                f64::from(*outside.select_nth_unstable_by(mid, f32::total_cmp).1)
            };
            if outside.is_empty()
                || protrusion < settings.spur_aspect * own_radius
                || protrusion < settings.spur_min_length_m
            {
                spurs.push(chain);
            }
        }
        if spurs.is_empty() {
            return pruned;
        }
        for chain in spurs {
            // chain runs from the junction to the tip: drop all but the junction.
            let junction = chain[0];
            if let Some(n) = adjacency.get_mut(&junction) {
                n.retain(|&v| v != chain[1]);
            }
            for &v in &chain[1..] {
                adjacency.remove(&v);
            }
            pruned += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straight rod along i: the skeleton is one branch down its middle.
    #[test]
    fn a_rod_has_one_centred_branch() {
        let dims = [40, 11, 11];
        let mask: Vec<bool> = (0..40 * 121)
            .map(|n| {
                let (i, j, k) = (n % 40, (n / 40) % 11, n / 440);
                (2..38).contains(&i) && (j as f64 - 5.0).powi(2) + (k as f64 - 5.0).powi(2) <= 16.0
            })
            .collect();
        let background: Vec<bool> = mask.iter().map(|m| !m).collect();
        let dbf = crate::segment::edt::distance_to(&background, dims, [1.0; 3]);
        let settings = SkeletonSettings {
            invalidation_constant_m: 1.5,
            spur_min_length_m: 2.0,
            ..Default::default()
        };
        let mut s = teasar(
            &mask,
            &dbf,
            dims,
            [1.0; 3],
            20 + 40 * (5 + 11 * 5),
            &settings,
        )
        .unwrap();
        prune_spurs(&mut s.adjacency, &dbf, dims, [1.0; 3], s.root, &settings);
        let b = branches(&s.adjacency);
        assert_eq!(b.len(), 1, "{b:?}");
        // Away from the ends, every skeleton voxel is on the axis.
        for &v in &b[0].voxels {
            let (i, j, k) = (v % 40, (v / 40) % 11, v / 440);
            if (8..32).contains(&i) {
                assert_eq!((j, k), (5, 5), "voxel {i} {j} {k}");
            }
        }
    }
}
