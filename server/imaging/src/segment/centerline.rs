//! From a pruned voxel skeleton to the vessel graph: branch points that lie closer than a
//! radius are merged, branches are oriented away from the access end, their voxel chains are
//! trimmed where the end's inscribed sphere reaches the tip, smoothed, moved to the middle
//! of the lumen by cross-sections cast in the image, and given the equal-area radius of each
//! cross-section.

use std::collections::VecDeque;

use nalgebra::{Point3, Vector3};
use rustc_hash::FxHashMap;

use super::blur::{self, BlurCorrection};
use super::skeleton::{Adjacency, branches};
use crate::error::{ImagingError, Result};
use crate::volume::ScalarVolume;
use cathlab_anatomy::components::UnionFind;
use cathlab_anatomy::graph::{BranchSpec, Side, VesselGraph, VesselKind};

/// Rays per cross-section.
const RAYS: usize = 24;

/// How centerlines are refined in the image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CenterlineSettings {
    /// Image value of the tissue around the vessels; the wall of a cross-section is where
    /// the image falls half-way from its centre value to this (full width at half maximum).
    pub background_value: f64,
    /// Centerline point spacing (m).
    pub point_spacing_m: f64,
    /// Cross-section refinement passes.
    pub refinement_passes: usize,
    /// Undo the blur's shrinking of half-maximum radii ([`BlurCorrection`]) with the
    /// branch's median edge σ.
    pub correct_blur: bool,
}

/// What cross-sections are cast in: an image, or the exact wall of a surface.
pub trait Intensity: Sync {
    /// The value at `p` (m): bright in the lumen, dark outside.
    fn value(&self, p: &Point3<f64>) -> f64;
    /// Distance between samples along a ray (m); crossings are interpolated linearly.
    fn ray_step(&self) -> f64;
}

impl Intensity for ScalarVolume {
    fn value(&self, p: &Point3<f64>) -> f64 {
        self.sample(p)
    }

    fn ray_step(&self) -> f64 {
        0.25 * self.spacing_m.min()
    }
}

/// One cross-section: where its middle is and its equal-area radius.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CrossSection {
    /// The area centroid of the wall points' polygon (m); `None` when rays ran into another vessel or out of
    /// the lumen, so that the middle cannot be trusted.
    pub centre: Option<Point3<f64>>,
    /// Radius (m): of the circle with the section's area when every ray found the wall,
    /// else the median wall distance of the rays that did. The polygon of `RAYS` wall
    /// points is scaled to the circle through them, so a round section gives its radius.
    pub radius: f64,
    /// The median over the rays of the wall's blur σ (m), from how far the image falls
    /// across the voxel either side of the wall ([`blur::edge_sigma`]); `None` where no ray
    /// could tell (a wall sharper than the samples, or rays too short).
    pub edge_sigma: Option<f64>,
}

/// Casts `RAYS` rays from `p` in the plane normal to `tangent` and finds where the image
/// falls half-way from its value at `p` to `background_value` (linear between samples
/// [`Intensity::ray_step`] apart), up to `max_length` (m). `None` if the centre is not
/// brighter than the background or fewer than three quarters of the rays find the wall.
pub fn cross_section(
    image: &dyn Intensity,
    p: &Point3<f64>,
    tangent: &Vector3<f64>,
    background_value: f64,
    max_length: f64,
) -> Option<CrossSection> {
    let t = tangent.try_normalize(1e-12)?;
    let helper = if t.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let u = t.cross(&helper).normalize();
    let v = t.cross(&u);
    let step = image.ray_step();
    let centre_value = image.value(p);
    if centre_value <= background_value {
        return None;
    }
    let wall_value = 0.5 * (centre_value + background_value);
    let mut lengths = [f64::NAN; RAYS];
    for (r, length) in lengths.iter_mut().enumerate() {
        let angle = std::f64::consts::TAU * r as f64 / RAYS as f64;
        let d = u * angle.cos() + v * angle.sin();
        let (mut previous, mut s) = (centre_value, 0.0);
        while s < max_length {
            let next_s = s + step;
            let value = image.value(&(p + d * next_s));
            if value < wall_value {
                *length = s + step * (previous - wall_value) / (previous - value);
                break;
            }
            previous = value;
            s = next_s;
        }
    }
    let mut found: Vec<f64> = lengths.iter().copied().filter(|l| l.is_finite()).collect();
    if found.len() * 4 < RAYS * 3 {
        return None;
    }
    // How far the image falls across a voxel either side of each wall point, as a fraction
    // of the contrast: the edge's blur.
    let width = 4.0 * step;
    let contrast = centre_value - background_value;
    let mut sigmas: Vec<f64> = (0..RAYS)
        .filter(|&r| lengths[r].is_finite() && lengths[r] > width)
        .filter_map(|r| {
            let angle = std::f64::consts::TAU * r as f64 / RAYS as f64;
            let d = u * angle.cos() + v * angle.sin();
            let inner = image.value(&(p + d * (lengths[r] - width)));
            let outer = image.value(&(p + d * (lengths[r] + width)));
            blur::edge_sigma((inner - outer) / contrast, width)
        })
        .collect();
    let edge_sigma = if sigmas.len() * 2 >= RAYS {
        middle(&mut sigmas)
    } else {
        None
    };
    found.sort_by(f64::total_cmp);
    let median = found[found.len() / 2];
    let whole = found.len() == RAYS && found[RAYS - 1] < 1.5 * median;
    if !whole {
        return Some(CrossSection {
            centre: None,
            radius: median,
            edge_sigma,
        });
    }
    // The section is the polygon of the wall points, a fan of triangles around `p`: its
    // area gives the radius and its area centroid the middle (the plain mean of the wall
    // points would move an off-centre `p` only half-way to the middle).
    let sector = (std::f64::consts::TAU / RAYS as f64).sin();
    let wall = |r: usize| {
        let angle = std::f64::consts::TAU * r as f64 / RAYS as f64;
        (u * angle.cos() + v * angle.sin()) * lengths[r % RAYS]
    };
    let mut area = 0.0;
    let mut moment = Vector3::zeros();
    for r in 0..RAYS {
        let a = 0.5 * lengths[r] * lengths[(r + 1) % RAYS] * sector;
        area += a;
        moment += (wall(r) + wall(r + 1)) * (a / 3.0);
    }
    // A regular polygon inscribed in a circle of radius R has area R²·n·sin(2π/n)/2.
    let inscribed = RAYS as f64 * sector / std::f64::consts::TAU;
    Some(CrossSection {
        centre: Some(p + moment / area),
        radius: (area / (std::f64::consts::PI * inscribed)).sqrt(),
        edge_sigma,
    })
}

/// The median (upper middle) of `values`, reordering them; `None` when empty.
fn middle(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mid = values.len() / 2;
    Some(*values.select_nth_unstable_by(mid, f64::total_cmp).1)
}

fn tangents(points: &[Point3<f64>]) -> Vec<Vector3<f64>> {
    let n = points.len();
    (0..n)
        .map(|i| points[(i + 1).min(n - 1)] - points[i.saturating_sub(1)])
        .collect()
}

/// Laplacian smoothing with fixed end points.
fn smooth_points(points: &mut [Point3<f64>], passes: usize) {
    for _ in 0..passes {
        let copy = points.to_vec();
        for i in 1..points.len().saturating_sub(1) {
            points[i] = Point3::from(
                (copy[i - 1].coords + copy[i].coords * 2.0 + copy[i + 1].coords) * 0.25,
            );
        }
    }
}

/// Resamples a polyline (with a value per point) at uniform arc length, about `spacing`
/// apart, keeping both ends.
fn resample(points: &[Point3<f64>], values: &[f64], spacing: f64) -> (Vec<Point3<f64>>, Vec<f64>) {
    let mut arc = vec![0.0];
    for w in points.windows(2) {
        arc.push(arc[arc.len() - 1] + (w[1] - w[0]).norm());
    }
    let total = arc[arc.len() - 1];
    let count = ((total / spacing).round() as usize).max(1);
    let mut out_p = Vec::with_capacity(count + 1);
    let mut out_v = Vec::with_capacity(count + 1);
    let mut seg = 0;
    for s in 0..=count {
        let at = total * s as f64 / count as f64;
        while seg + 2 < arc.len() && arc[seg + 1] < at {
            seg += 1;
        }
        let span = arc[seg + 1] - arc[seg];
        let f = if span > 0.0 {
            ((at - arc[seg]) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out_p.push(points[seg] + (points[seg + 1] - points[seg]) * f);
        out_v.push(values[seg] + (values[seg + 1] - values[seg]) * f);
    }
    (out_p, out_v)
}

fn median_filter(values: &[f64], half: usize) -> Vec<f64> {
    (0..values.len())
        .map(|i| {
            let lo = i.saturating_sub(half);
            let hi = (i + half + 1).min(values.len());
            let mut w = values[lo..hi].to_vec();
            w.sort_by(f64::total_cmp);
            w[w.len() / 2]
        })
        .collect()
}

/// Builds the vessel graph of a pruned skeleton. `image` is the voxel grid of the skeleton,
/// `walls` what the cross-sections are cast in (the filtered image itself, or a surface),
/// `dbf` the wall distance per voxel (m), `root` the access end's voxel. Branches are named `vessel_00`, `vessel_01`, … in breadth-first order from
/// the access end, which is the landmark `access`.
pub fn vessel_graph(
    image: &ScalarVolume,
    walls: &dyn Intensity,
    adjacency: &Adjacency,
    dbf: &[f32],
    root: usize,
    settings: &CenterlineSettings,
) -> Result<VesselGraph> {
    let voxel_branches = branches(adjacency);
    let correction = settings.correct_blur.then(BlurCorrection::new);
    if voxel_branches.iter().all(|b| b.voxels.len() < 2) {
        return Err(ImagingError::Segmentation(
            "the skeleton has no branch longer than a voxel".into(),
        ));
    }
    let position = |n: usize| {
        let [i, j, k] = image.ijk(n);
        image.position_of(&Vector3::new(i as f64, j as f64, k as f64))
    };
    let degree = |v: usize| adjacency.get(&v).map_or(0, Vec::len);
    let length = |chain: &[usize]| -> f64 {
        chain
            .windows(2)
            .map(|w| (position(w[1]) - position(w[0])).norm())
            .sum()
    };
    // Nodes, and branch points joined by a branch shorter than their radius merged.
    let mut node_ids: FxHashMap<usize, usize> = FxHashMap::default();
    let mut node_voxels = Vec::new();
    for b in &voxel_branches {
        for v in [b.voxels[0], b.voxels[b.voxels.len() - 1]] {
            node_ids.entry(v).or_insert_with(|| {
                node_voxels.push(v);
                node_voxels.len() - 1
            });
        }
    }
    let mut clusters = UnionFind::new(node_voxels.len());
    let mut kept = Vec::new();
    for b in &voxel_branches {
        let (a, z) = (b.voxels[0], b.voxels[b.voxels.len() - 1]);
        let internal = degree(a) >= 3 && degree(z) >= 3;
        if internal && length(&b.voxels) < f64::from(dbf[a].max(dbf[z])) {
            clusters.union(node_ids[&a], node_ids[&z]);
        } else {
            kept.push(b);
        }
    }
    let mut cluster_sum: FxHashMap<usize, (Vector3<f64>, usize)> = FxHashMap::default();
    for (id, &v) in node_voxels.iter().enumerate() {
        let c = clusters.find(id);
        let e = cluster_sum.entry(c).or_insert((Vector3::zeros(), 0));
        e.0 += position(v).coords;
        e.1 += 1;
    }
    let cluster_of = |v: usize, uf: &mut UnionFind| uf.find(node_ids[&v]);
    // Breadth-first orientation from the access end.
    let root_node = if node_ids.contains_key(&root) {
        root
    } else {
        *node_ids.keys().min_by_key(|&&v| degree(v)).unwrap_or(&root)
    };
    let root_cluster = cluster_of(root_node, &mut clusters);
    let ends: Vec<(usize, usize)> = kept
        .iter()
        .map(|b| {
            (
                cluster_of(b.voxels[0], &mut clusters),
                cluster_of(b.voxels[b.voxels.len() - 1], &mut clusters),
            )
        })
        .collect();
    let mut cluster_degree: FxHashMap<usize, usize> = FxHashMap::default();
    for &(a, z) in &ends {
        *cluster_degree.entry(a).or_default() += 1;
        *cluster_degree.entry(z).or_default() += 1;
    }
    let mut visited_branch = vec![false; kept.len()];
    let mut order = Vec::new();
    let mut queue = VecDeque::from([root_cluster]);
    let mut seen = vec![root_cluster];
    while let Some(c) = queue.pop_front() {
        for (i, &(a, z)) in ends.iter().enumerate() {
            if visited_branch[i] || (a != c && z != c) {
                continue;
            }
            visited_branch[i] = true;
            let forward = a == c;
            order.push((i, forward));
            let other = if forward { z } else { a };
            if !seen.contains(&other) {
                seen.push(other);
                queue.push_back(other);
            }
        }
    }
    let node_position = |c: usize| {
        let (sum, count) = cluster_sum[&c];
        Point3::from(sum / count as f64)
    };
    let h = image.spacing_m.min();
    let mut graph = VesselGraph::new();
    let mut access = None;
    let mut index = 0;
    for &(b, forward) in &order {
        let mut chain = kept[b].voxels.clone();
        let (mut start, mut end) = ends[b];
        if !forward {
            chain.reverse();
            std::mem::swap(&mut start, &mut end);
        }
        let free_start = cluster_degree[&start] == 1;
        let free_end = cluster_degree[&end] == 1;
        let mut points: Vec<Point3<f64>> = chain.iter().map(|&v| position(v)).collect();
        let mut radii: Vec<f64> = chain.iter().map(|&v| f64::from(dbf[v])).collect();
        if !free_start {
            points[0] = node_position(start);
        }
        let last = points.len() - 1;
        if !free_end {
            points[last] = node_position(end);
        }
        // A free end's inscribed sphere reaches the tip: the medial axis is not defined in
        // the last radius.
        for (free, reverse) in [(free_start, false), (free_end, true)] {
            if !free || points.len() < 3 {
                continue;
            }
            if reverse {
                points.reverse();
                radii.reverse();
            }
            // The skeleton may end on the rim of a flat end (a cap, the volume's edge), where
            // the wall distance is small: trim by the largest radius met so far, and half
            // as much again.
            let tip = points[0];
            let mut cut = 0;
            let mut radius: f64 = 0.0;
            while cut + 2 < points.len() && {
                radius = radius.max(radii[cut]);
                (points[cut] - tip).norm() < 1.5 * radius
            } {
                cut += 1;
            }
            points.drain(..cut);
            radii.drain(..cut);
            if reverse {
                points.reverse();
                radii.reverse();
            }
        }
        smooth_points(&mut points, 3);
        let (mut points, wall_distance) = resample(&points, &radii, settings.point_spacing_m);
        let fixed_start = !free_start;
        let fixed_end = !free_end;
        let mut sections = vec![None; points.len()];
        for _ in 0..settings.refinement_passes.max(1) {
            let tangent = tangents(&points);
            for i in 0..points.len() {
                let max_length = 2.0 * wall_distance[i] + 3.0 * h;
                sections[i] = cross_section(
                    walls,
                    &points[i],
                    &tangent[i],
                    settings.background_value,
                    max_length,
                );
            }
            for i in 0..points.len() {
                let pinned = (i == 0 && fixed_start) || (i + 1 == points.len() && fixed_end);
                if let Some(CrossSection {
                    centre: Some(c), ..
                }) = sections[i]
                    && !pinned
                {
                    points[i] = c;
                }
            }
            smooth_points(&mut points, 1);
        }
        // At a free end the last cross-sections may meet the end itself (a flat cap, the
        // volume's edge) and leave the points off-centre: such a tail is dropped.
        let uncentred = |i: usize| sections[i].is_none_or(|s: CrossSection| s.centre.is_none());
        let mut first = 0;
        let mut last = points.len();
        if free_end {
            while last > first + 2 && uncentred(last - 1) {
                last -= 1;
            }
        }
        if free_start {
            while first + 2 < last && uncentred(first) {
                first += 1;
            }
        }
        let points: Vec<Point3<f64>> = points[first..last].to_vec();
        let sections: Vec<Option<CrossSection>> = sections[first..last].to_vec();
        let wall_distance: Vec<f64> = wall_distance[first..last].to_vec();
        // The branch's blur: the median of its sections' edge σ.
        let mut sigmas: Vec<f64> = sections
            .iter()
            .flatten()
            .filter_map(|s| s.edge_sigma)
            .collect();
        let sigma = middle(&mut sigmas).unwrap_or(0.0);
        let mut raw_radii: Vec<f64> = (0..points.len())
            .map(|i| {
                sections[i].map_or((wall_distance[i] - 0.5 * h).max(0.5 * h), |s| {
                    correction
                        .as_ref()
                        .map_or(s.radius, |c| c.true_radius(s.radius, sigma))
                })
            })
            .collect();
        // Where a section is not whole (its rays ran into a branch point, a neighbour, the
        // volume's edge) or lies in a branch point's inscribed sphere (where it cuts the
        // other vessels too), its radius measures more than this vessel: take it from the
        // whole sections either side, linearly by arc position, or the nearest one at the
        // ends.
        let inside_junction = |i: usize| {
            (!free_start && (points[i] - points[0]).norm() < wall_distance[0])
                || (!free_end && {
                    let l = points.len() - 1;
                    (points[i] - points[l]).norm() < wall_distance[l]
                })
        };
        let whole: Vec<usize> = (0..points.len())
            .filter(|&i| sections[i].is_some_and(|s| s.centre.is_some()) && !inside_junction(i))
            .collect();
        if !whole.is_empty() {
            let known = raw_radii.clone();
            for (i, radius) in raw_radii.iter_mut().enumerate() {
                let k = whole.partition_point(|&w| w < i);
                *radius = match (k.checked_sub(1).map(|k| whole[k]), whole.get(k)) {
                    (_, Some(&next)) if next == i => continue,
                    (Some(before), Some(&after)) => {
                        let t = (i - before) as f64 / (after - before) as f64;
                        known[before] + t * (known[after] - known[before])
                    }
                    (Some(before), None) => known[before],
                    (None, Some(&after)) => known[after],
                    (None, None) => continue,
                };
            }
        }
        let mut radii = median_filter(&raw_radii, 2);
        for _ in 0..2 {
            let copy = radii.clone();
            for i in 1..radii.len().saturating_sub(1) {
                radii[i] = 0.25 * (copy[i - 1] + 2.0 * copy[i] + copy[i + 1]);
            }
        }
        // Drop points that coincide after refinement.
        let mut keep_p = vec![points[0]];
        let mut keep_r = vec![radii[0]];
        for i in 1..points.len() {
            if (points[i] - keep_p[keep_p.len() - 1]).norm() > 1e-3 * h {
                keep_p.push(points[i]);
                keep_r.push(radii[i]);
            } else if i + 1 == points.len() {
                let l = keep_p.len() - 1;
                keep_p[l] = points[i];
            }
        }
        if keep_p.len() < 2 {
            continue;
        }
        // A leaf that, trimmed, does not leave its parent's lumen is a corner of a rough
        // end, not a vessel.
        let kept_length: f64 = keep_p.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        let leaf = free_end && !free_start && index > 0;
        if leaf && kept_length < keep_r[0] {
            continue;
        }
        if index == 0 {
            access = Some(keep_p[0]);
        }
        graph.add_branch(BranchSpec {
            name: format!("vessel_{index:02}"),
            kind: VesselKind::Other,
            side: Side::Midline,
            points: keep_p,
            radii: keep_r,
        })?;
        index += 1;
    }
    if let Some(a) = access {
        graph.landmarks.insert("access".into(), a);
    }
    Ok(graph)
}
