//! Centerlines through a lumen surface: a shortest-path tree over the lumen's interior voxels,
//! weighted to stay near the middle of the vessel, from one access point to several targets.
//! Used to join imported centerlines (which start inside the arch's branches) to an access
//! point in the aorta.

use std::collections::BinaryHeap;

use nalgebra::{Point3, Vector3};

use crate::error::{AnatomyError, Result, require_positive};
use crate::lumen::Lumen;

/// A centerline polyline with radii (m), from the access point to one or more targets.
#[derive(Debug, Clone, PartialEq)]
pub struct TreeChain {
    /// Points (m) from the proximal end.
    pub points: Vec<Point3<f64>>,
    /// Distance to the wall at each point (m).
    pub radii: Vec<f64>,
    /// Indices of the targets whose paths run through this chain.
    pub serves: Vec<usize>,
}

#[derive(PartialEq)]
struct Entry(f64, usize);
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Entry {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        other.0.total_cmp(&self.0)
    }
}

/// Centred paths inside `lumen` from `access` to each target, as a tree of chains split
/// where paths part. `voxel` (m) is the search grid's spacing.
pub fn lumen_path_tree(
    lumen: &Lumen,
    access: &Point3<f64>,
    targets: &[Point3<f64>],
    voxel: f64,
) -> Result<Vec<TreeChain>> {
    require_positive("voxel", voxel)?;
    let pad = 0.03;
    let mut lo = *access;
    let mut hi = *access;
    for t in targets {
        lo = lo.inf(t);
        hi = hi.sup(t);
    }
    let lo = lo - Vector3::repeat(pad);
    let hi = hi + Vector3::repeat(pad);
    let dims = ((hi - lo) / voxel).map(|v| v.ceil() as usize + 1);
    let count = dims.x * dims.y * dims.z;
    if count > 40_000_000 {
        return Err(AnatomyError::InvalidParameter {
            name: "voxel",
            value: voxel,
            requirement: "coarse enough for at most 4e7 voxels over the search box",
        });
    }
    let lattice = |v: usize| {
        let (i, j, k) = (v % dims.x, (v / dims.x) % dims.y, v / (dims.x * dims.y));
        (i as i64, j as i64, k as i64)
    };
    // The voxel at lattice coordinates, if inside the search box.
    let voxel_at = |i: i64, j: i64, k: i64| -> Option<usize> {
        let inside = (0..dims.x as i64).contains(&i)
            && (0..dims.y as i64).contains(&j)
            && (0..dims.z as i64).contains(&k);
        inside.then(|| (k as usize * dims.y + j as usize) * dims.x + i as usize)
    };
    let position = |v: usize| {
        let (i, j, k) = lattice(v);
        lo + Vector3::new(i as f64, j as f64, k as f64) * voxel
    };
    // Depth inside the lumen per voxel (0 outside).
    let depth: Vec<f32> = (0..count)
        .map(|v| {
            let d = -lumen.query(&position(v)).signed_distance;
            if d > 0.25 * voxel { d as f32 } else { 0.0 }
        })
        .collect();
    let snap = |p: &Point3<f64>, what: &str| -> Result<usize> {
        let c = ((p - lo) / voxel).map(|v| v.round() as i64);
        let mut best: Option<(f64, usize)> = None;
        let reach = (0.01 / voxel).ceil() as i64;
        for dk in -reach..=reach {
            for dj in -reach..=reach {
                for di in -reach..=reach {
                    let Some(v) = voxel_at(c.x + di, c.y + dj, c.z + dk) else {
                        continue;
                    };
                    if depth[v] > 0.0 {
                        let d = (position(v) - p).norm();
                        if best.is_none_or(|b| d < b.0) {
                            best = Some((d, v));
                        }
                    }
                }
            }
        }
        best.map(|b| b.1).ok_or_else(|| AnatomyError::NoPath {
            from: "lumen".into(),
            to: format!("{what} (no lumen voxel within 10 mm)"),
        })
    };
    let source = snap(access, "the access point")?;
    let goals: Vec<usize> = targets
        .iter()
        .enumerate()
        .map(|(i, t)| snap(t, &format!("target {i}")))
        .collect::<Result<_>>()?;
    // Dijkstra with cost length / depth², which keeps paths centred.
    let mut cost = vec![f64::INFINITY; count];
    let mut previous = vec![usize::MAX; count];
    let mut heap = BinaryHeap::new();
    cost[source] = 0.0;
    heap.push(Entry(0.0, source));
    while let Some(Entry(c, v)) = heap.pop() {
        if c > cost[v] {
            continue;
        }
        let (i, j, k) = lattice(v);
        for dk in -1i64..=1 {
            for dj in -1i64..=1 {
                for di in -1i64..=1 {
                    if (di, dj, dk) == (0, 0, 0) {
                        continue;
                    }
                    let Some(w) = voxel_at(i + di, j + dj, k + dk) else {
                        continue;
                    };
                    let d = f64::from(depth[w]);
                    if d <= 0.0 {
                        continue;
                    }
                    let step = voxel * ((di * di + dj * dj + dk * dk) as f64).sqrt();
                    let next = c + step / (d * d);
                    if next < cost[w] {
                        cost[w] = next;
                        previous[w] = v;
                        heap.push(Entry(next, w));
                    }
                }
            }
        }
    }
    // Paths (source first), then split into chains where they part.
    let mut paths = Vec::new();
    for (t, &g) in goals.iter().enumerate() {
        if !cost[g].is_finite() {
            return Err(AnatomyError::NoPath {
                from: "the access point".into(),
                to: format!("target {t}: not connected through the lumen"),
            });
        }
        let mut path = vec![g];
        while let Some(&last) = path.last() {
            if last == source {
                break;
            }
            path.push(previous[last]);
        }
        path.reverse();
        paths.push(path);
    }
    let mut chains = Vec::new();
    split_chains(&paths, (0..paths.len()).collect(), 0, &mut chains);
    Ok(chains
        .into_iter()
        .map(|(voxels, serves)| {
            let raw: Vec<Point3<f64>> = voxels.iter().map(|&v| position(v)).collect();
            let points = smooth(&raw, 3);
            let radii = points
                .iter()
                .map(|p| (-lumen.query(p).signed_distance).max(0.25 * voxel))
                .collect();
            TreeChain {
                points,
                radii,
                serves,
            }
        })
        .collect())
}

/// Splits paths that share prefixes into chains; `from` is where the group's shared part
/// starts. Chains include their first voxel (the junction) so that they connect.
fn split_chains(
    paths: &[Vec<usize>],
    group: Vec<usize>,
    from: usize,
    out: &mut Vec<(Vec<usize>, Vec<usize>)>,
) {
    let mut end = from;
    loop {
        let next = end + 1;
        let first = paths[group[0]].get(next);
        if first.is_none() || group.iter().any(|&p| paths[p].get(next) != first) {
            break;
        }
        end = next;
    }
    let chain: Vec<usize> = paths[group[0]][from..=end].to_vec();
    if chain.len() >= 2 {
        out.push((chain, group.clone()));
    }
    let mut subgroups: Vec<(usize, Vec<usize>)> = Vec::new();
    for &p in &group {
        if let Some(&v) = paths[p].get(end + 1) {
            match subgroups.iter_mut().find(|(key, _)| *key == v) {
                Some((_, g)) => g.push(p),
                None => subgroups.push((v, vec![p])),
            }
        }
    }
    for (_, g) in subgroups {
        split_chains(paths, g, end, out);
    }
}

/// Moving average over `half_window` points each side, keeping the end points.
fn smooth(points: &[Point3<f64>], half_window: usize) -> Vec<Point3<f64>> {
    let n = points.len();
    (0..n)
        .map(|i| {
            if i == 0 || i + 1 == n {
                return points[i];
            }
            let w = half_window.min(i).min(n - 1 - i);
            let sum: Vector3<f64> = points[i - w..=i + w].iter().map(|p| p.coords).sum();
            Point3::from(sum / (2 * w + 1) as f64)
        })
        .collect()
}
