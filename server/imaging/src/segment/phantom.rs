//! Synthetic CT angiography of a vessel graph with known centerlines and radii: the lumen's
//! partial-volume occupancy of every voxel, a lumen and a tissue value, Gaussian blur (the
//! scanner's point spread) and Gaussian noise. The reference for segmentation accuracy.

use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;

use super::filter::gaussian_blur;
use crate::error::Result;
use crate::volume::ScalarVolume;
use cathlab_anatomy::graph::{BranchSpec, Side, VesselGraph, VesselKind};

/// How the synthetic CT looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticCt {
    /// Value of contrast-filled lumen (HU).
    pub lumen: f64,
    /// Value of the surrounding tissue (HU).
    pub tissue: f64,
    /// Point-spread σ (voxels).
    pub blur_voxels: f64,
    /// Noise σ (HU).
    pub noise: f64,
    /// Noise seed.
    pub seed: u64,
}

impl Default for SyntheticCt {
    fn default() -> Self {
        Self {
            lumen: 400.0,
            tissue: 40.0,
            blur_voxels: 0.7,
            noise: 20.0,
            seed: 1,
        }
    }
}

/// The fraction of each voxel of `dims` voxels of `spacing_m` (voxel (0, 0, 0) at
/// `origin_m`) that `graph`'s lumen occupies (round tubes along each branch, radius
/// interpolated between the points, round caps at the ends), linear across one voxel at
/// the wall: the phantom before blur and noise, and the truth its segmentation's volume is
/// measured against (the sum times the voxel volume is the lumen volume in the grid's box,
/// to second order in the spacing).
pub fn occupancy(
    graph: &VesselGraph,
    origin_m: Vector3<f64>,
    dims: [usize; 3],
    spacing_m: f64,
) -> Vec<f32> {
    let (nx, ny, nz) = (dims[0], dims[1], dims[2]);
    let plane = nx * ny;
    let h = spacing_m;
    // Signed distance to the union of tapered segments, evaluated only near them.
    let mut signed = vec![f32::INFINITY; nx * ny * nz];
    let segments: Vec<(Point3<f64>, Point3<f64>, f64, f64)> = graph
        .branches
        .iter()
        .flat_map(|b| {
            (0..b.points.len() - 1)
                .map(move |i| (b.points[i], b.points[i + 1], b.radii[i], b.radii[i + 1]))
        })
        .collect();
    let index = |p: f64, o: f64| ((p - o) / h).floor() as isize;
    signed
        .par_chunks_mut(plane)
        .enumerate()
        .for_each(|(k, slab)| {
            let z = origin_m.z + k as f64 * h;
            for (a, b, ra, rb) in &segments {
                let reach = ra.max(*rb) + 2.0 * h;
                if z < a.z.min(b.z) - reach || z > a.z.max(b.z) + reach {
                    continue;
                }
                let axis = b - a;
                let len2 = axis.norm_squared().max(f64::MIN_POSITIVE);
                let i0 = index(a.x.min(b.x) - reach, origin_m.x).max(0) as usize;
                let i1 =
                    (index(a.x.max(b.x) + reach, origin_m.x) + 1).clamp(0, nx as isize) as usize;
                let j0 = index(a.y.min(b.y) - reach, origin_m.y).max(0) as usize;
                let j1 =
                    (index(a.y.max(b.y) + reach, origin_m.y) + 1).clamp(0, ny as isize) as usize;
                for j in j0..j1 {
                    for i in i0..i1 {
                        let p =
                            Point3::from(origin_m + Vector3::new(i as f64, j as f64, k as f64) * h);
                        let t = ((p - a).dot(&axis) / len2).clamp(0.0, 1.0);
                        let d = (p - (a + axis * t)).norm() - (ra + (rb - ra) * t);
                        let cell = &mut slab[i + nx * j];
                        *cell = cell.min(d as f32);
                    }
                }
            }
        });
    // Occupancy of a voxel by the lumen, linear across one voxel at the wall.
    signed
        .par_iter_mut()
        .for_each(|d| *d = (0.5 - f64::from(*d) / h).clamp(0.0, 1.0) as f32);
    signed
}

/// Images `graph`'s lumen (round tubes along each branch, radius interpolated between the
/// points, round caps at the ends) on an axis-aligned grid of `dims` voxels of `spacing_m`
/// whose voxel (0, 0, 0) is at `origin_m`.
pub fn synthetic_cta(
    graph: &VesselGraph,
    origin_m: Vector3<f64>,
    dims: [usize; 3],
    spacing_m: f64,
    look: &SyntheticCt,
) -> Result<ScalarVolume> {
    let plane = dims[0] * dims[1];
    let mut values: Vec<f32> = occupancy(graph, origin_m, dims, spacing_m)
        .par_iter()
        .map(|&o| (look.tissue + (look.lumen - look.tissue) * f64::from(o)) as f32)
        .collect();
    gaussian_blur(&mut values, dims, [look.blur_voxels; 3]);
    if look.noise > 0.0 {
        values
            .par_chunks_mut(plane)
            .enumerate()
            .for_each(|(k, slab)| {
                let mut rng = rand::rngs::StdRng::seed_from_u64(look.seed ^ (k as u64) << 20);
                let mut pending = None;
                for v in slab.iter_mut() {
                    let g = match pending.take() {
                        Some(g) => g,
                        None => {
                            // Box–Muller: two normal deviates from two uniforms.
                            let u1: f64 = rng.random::<f64>().max(1e-300);
                            let u2: f64 = rng.random();
                            let r = (-2.0 * u1.ln()).sqrt();
                            let theta = std::f64::consts::TAU * u2;
                            pending = Some(r * theta.sin());
                            r * theta.cos()
                        }
                    };
                    *v += (look.noise * g) as f32;
                }
            });
    }
    ScalarVolume::new(
        dims,
        Vector3::repeat(spacing_m),
        origin_m,
        nalgebra::Matrix3::identity(),
        values,
    )
}

/// A quadratic Bézier branch from `a` to `b` bowed by `bow` (mm), radius from `ra` to `rb`
/// (mm), all lengths multiplied by `scale`, sampled at 61 points.
fn bezier(
    name: &str,
    a: [f64; 3],
    b: [f64; 3],
    bow: [f64; 3],
    radii: [f64; 2],
    scale: f64,
) -> BranchSpec {
    let (a, b) = (Vector3::from(a), Vector3::from(b));
    let c = (a + b) * 0.5 + Vector3::from(bow);
    let n = 60;
    let (mut points, mut r) = (Vec::new(), Vec::new());
    for i in 0..=n {
        let t = i as f64 / n as f64;
        let p = a * (1.0 - t).powi(2) + c * 2.0 * t * (1.0 - t) + b * t * t;
        points.push(Point3::from(p * scale * 1e-3));
        r.push((radii[0] + (radii[1] - radii[0]) * t) * scale * 1e-3);
    }
    BranchSpec {
        name: name.into(),
        kind: VesselKind::Other,
        side: Side::Midline,
        points,
        radii: r,
    }
}

/// The segmentation reference tree in a cube of `60·scale` mm (corner at the origin): a
/// curved trunk (radius 4 → 3.5 mm) that enters through the bottom face, a side branch
/// (1.6 → 1.4 mm) that ends inside, and a bifurcation into two daughters (3 → 2.5 and
/// 2.6 → 2 mm) that leave through the top face; every length times `scale`.
pub fn reference_tree(scale: f64) -> Result<VesselGraph> {
    let mut g = VesselGraph::new();
    for spec in [
        bezier(
            "trunk_lower",
            [30.0, 30.0, -3.0],
            [31.0, 29.0, 20.0],
            [3.0, 0.0, 0.0],
            [4.0, 3.7],
            scale,
        ),
        bezier(
            "trunk_upper",
            [31.0, 29.0, 20.0],
            [30.0, 30.0, 35.0],
            [-2.0, 1.0, 0.0],
            [3.7, 3.5],
            scale,
        ),
        bezier(
            "daughter_a",
            [30.0, 30.0, 35.0],
            [12.0, 36.0, 63.0],
            [-2.0, 0.0, 6.0],
            [3.0, 2.5],
            scale,
        ),
        bezier(
            "daughter_b",
            [30.0, 30.0, 35.0],
            [50.0, 24.0, 63.0],
            [3.0, 0.0, 5.0],
            [2.6, 2.0],
            scale,
        ),
        bezier(
            "side",
            [31.0, 29.0, 20.0],
            [52.0, 44.0, 15.0],
            [0.0, 3.0, 4.0],
            [1.6, 1.4],
            scale,
        ),
    ] {
        g.add_branch(spec)?;
    }
    Ok(g)
}
