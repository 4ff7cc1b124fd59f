//! Patient-specific anatomy from CT angiography: edge-preserving diffusion, a threshold
//! from a seed in a contrast-filled vessel, morphological opening and closing, the seed's
//! connected component, a TEASAR skeleton with inscribed-sphere radii and spur pruning,
//! centerlines refined in the image, the vessel graph, and a smooth watertight lumen
//! surface; exports to JSON, VTP, OBJ and STL. `cathlab segment` runs it from the command
//! line.

pub mod blur;
pub mod centerline;
pub mod edt;
pub mod export;
pub mod filter;
pub mod mask;
pub mod phantom;
pub mod skeleton;

use std::time::Instant;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use crate::error::{ImagingError, Result};
use crate::volume::ScalarVolume;
use cathlab_anatomy::decimate::decimate;
use cathlab_anatomy::graph::VesselGraph;
use cathlab_anatomy::mesh::TriangleMesh;
use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};
use centerline::CenterlineSettings;
use skeleton::SkeletonSettings;

/// Where segmentation starts: a point inside a contrast-filled vessel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Seed {
    /// A patient position (m, LPS).
    Position(Point3<f64>),
    /// A voxel index (i, j, k).
    Voxel([usize; 3]),
}

/// The settings of the whole pipeline. Lengths in metres; `None` picks from the data.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentSettings {
    /// Perona–Malik diffusion steps (0: no filtering).
    pub diffusion_iterations: usize,
    /// The diffusion's edge threshold in units of the estimated noise σ.
    pub diffusion_edge_sigmas: f64,
    /// Lumen threshold (image units) everywhere; by default half-way between the tissue and
    /// the local lumen value (see `local_window_m`).
    pub threshold: Option<f64>,
    /// Values above this are not lumen (e.g. bone); none by default.
    pub upper_threshold: Option<f64>,
    /// Radius of the opening's ball (m); by default one finest voxel spacing.
    pub open_radius_m: Option<f64>,
    /// Radius of the closing's ball (m); by default one finest voxel spacing.
    pub close_radius_m: Option<f64>,
    /// Half-width of the box around the seed where the first, global threshold is chosen (m).
    pub threshold_window_m: f64,
    /// Half-width of the box over which the local lumen value is the brightest value (m);
    /// 0 for one threshold everywhere.
    pub local_window_m: f64,
    /// Where between the tissue (0) and the local lumen value (1) the automatic threshold is.
    pub local_fraction: f64,
    /// The automatic threshold stays this many noise σ (of the filtered image) above the
    /// tissue value.
    pub floor_sigmas: f64,
    /// Skeleton growth and pruning.
    pub skeleton: SkeletonSettings,
    /// Centerline point spacing (m); by default the finest voxel spacing.
    pub point_spacing_m: Option<f64>,
    /// Cross-section refinement passes.
    pub refinement_passes: usize,
    /// Undo the scanner's blur in the measured radii ([`blur::BlurCorrection`]).
    pub correct_blur: bool,
    /// The lumen surface.
    pub surface: SurfaceSettings,
    /// The surface is decimated to stay within this distance of the polygonised one (m);
    /// `None` keeps every triangle.
    pub decimate_tolerance_m: Option<f64>,
}

impl Default for SegmentSettings {
    fn default() -> Self {
        Self {
            diffusion_iterations: 8,
            diffusion_edge_sigmas: 3.0,
            threshold: None,
            upper_threshold: None,
            open_radius_m: None,
            close_radius_m: None,
            threshold_window_m: 0.04,
            local_window_m: 0.015,
            local_fraction: 0.4,
            floor_sigmas: 4.0,
            skeleton: SkeletonSettings::default(),
            point_spacing_m: None,
            refinement_passes: 2,
            correct_blur: true,
            surface: SurfaceSettings {
                cells_per_radius: 2.0,
                min_cell: 2.5e-4,
                max_cell: 2e-3,
                ..SurfaceSettings::default()
            },
            decimate_tolerance_m: Some(0.1e-3),
        }
    }
}

/// What the pipeline measured and found (lengths in mm, for people).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SegmentationReport {
    /// The seed voxel.
    pub seed_voxel: [usize; 3],
    /// Estimated image noise σ (image units).
    pub noise_sigma: f64,
    /// Median lumen value (image units).
    pub lumen_value: f64,
    /// Median value of the tissue just outside the lumen (image units).
    pub background_value: f64,
    /// Smallest and largest lumen threshold used over the lumen (image units).
    pub threshold_range: [f64; 2],
    /// Voxels in the segmented lumen.
    pub lumen_voxels: usize,
    /// Lumen volume (mL).
    pub lumen_volume_ml: f64,
    /// Spurs pruned from the skeleton.
    pub spurs_pruned: usize,
    /// Branches of the vessel graph.
    pub branches: usize,
    /// End points (nodes with one branch).
    pub end_points: usize,
    /// Branch points (nodes with three or more branches).
    pub branch_points: usize,
    /// Total centerline length (mm).
    pub total_length_mm: f64,
    /// Smallest, median and largest centerline radius (mm).
    pub radius_mm: [f64; 3],
    /// Lumen surface vertices.
    pub surface_vertices: usize,
    /// Lumen surface triangles.
    pub surface_triangles: usize,
    /// Triangles of the polygonised surface before decimation.
    pub polygonised_triangles: usize,
    /// Whether the surface is a closed, oriented 2-manifold.
    pub surface_watertight: bool,
    /// Wall-clock seconds per stage, in order.
    pub stage_seconds: Vec<(String, f64)>,
}

impl SegmentationReport {
    /// The stage timings as one line: `diffusion 0.28 s, threshold and morphology 0.81 s, …`.
    pub fn stages_text(&self) -> String {
        self.stage_seconds
            .iter()
            .map(|(stage, seconds)| format!("{stage} {seconds:.2} s"))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// The result: the vessel graph, its lumen surface, the lumen mask and the report.
#[derive(Debug, Clone)]
pub struct Segmentation {
    /// Centerlines with radii, joined at branch points; landmark `access` at the root end.
    pub graph: VesselGraph,
    /// The smooth watertight lumen surface built from the graph.
    pub surface: TriangleMesh,
    /// The segmented lumen (1 inside, 0 outside) on the input grid.
    pub mask: ScalarVolume,
    /// Figures.
    pub report: SegmentationReport,
}

fn median(mut values: Vec<f32>) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mid = values.len() / 2;
    Some(f64::from(
        *values.select_nth_unstable_by(mid, f32::total_cmp).1,
    ))
}

/// The seed as a voxel, checked to lie in the volume.
pub fn seed_voxel(volume: &ScalarVolume, seed: &Seed) -> Result<[usize; 3]> {
    let index = match seed {
        Seed::Voxel(v) => Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64),
        Seed::Position(p) => volume.index_of(p).map(f64::round),
    };
    let inside = (0..3).all(|a| index[a] >= 0.0 && index[a] <= (volume.dims[a] - 1) as f64);
    if !inside {
        return Err(ImagingError::Segmentation(format!(
            "the seed (voxel {:.0}, {:.0}, {:.0}) is outside the volume of {}×{}×{} voxels",
            index[0], index[1], index[2], volume.dims[0], volume.dims[1], volume.dims[2]
        )));
    }
    Ok([index[0] as usize, index[1] as usize, index[2] as usize])
}

struct Stages(Vec<(String, f64)>, Instant);
impl Stages {
    fn lap(&mut self, name: &str) {
        let now = Instant::now();
        self.0
            .push((name.to_owned(), now.duration_since(self.1).as_secs_f64()));
        self.1 = now;
    }
}

/// Runs the whole pipeline on `volume` from `seed`.
pub fn segment(
    volume: &ScalarVolume,
    seed: &Seed,
    settings: &SegmentSettings,
) -> Result<Segmentation> {
    let mut stages = Stages(Vec::new(), Instant::now());
    let dims = volume.dims;
    let spacing = [volume.spacing_m.x, volume.spacing_m.y, volume.spacing_m.z];
    let h = volume.spacing_m.min();
    let seed_ijk = seed_voxel(volume, seed)?;
    let seed_n = volume.linear(seed_ijk[0], seed_ijk[1], seed_ijk[2]);
    // Non-finite voxels (NaN padding) count as the lowest finite value.
    let lowest = volume
        .values
        .iter()
        .filter(|v| v.is_finite())
        .fold(f32::INFINITY, |a, &b| a.min(b));
    if !lowest.is_finite() {
        return Err(ImagingError::Segmentation(
            "the volume holds no finite value".into(),
        ));
    }
    let clean = volume.with_values(
        volume
            .values
            .par_iter()
            .map(|&v| if v.is_finite() { v } else { lowest })
            .collect(),
    )?;
    let noise = filter::noise_sigma(&clean);
    let filtered = if settings.diffusion_iterations > 0 && noise > 0.0 {
        clean.with_values(filter::anisotropic_diffusion(
            &clean,
            settings.diffusion_iterations,
            settings.diffusion_edge_sigmas * noise,
        ))?
    } else {
        clean
    };
    stages.lap("diffusion");

    // The lumen value at the seed: median of its 3×3×3 neighbourhood.
    let around = |centre: [usize; 3], half: [usize; 3]| {
        let mut out = Vec::new();
        for k in centre[2].saturating_sub(half[2])..=(centre[2] + half[2]).min(dims[2] - 1) {
            for j in centre[1].saturating_sub(half[1])..=(centre[1] + half[1]).min(dims[1] - 1) {
                for i in centre[0].saturating_sub(half[0])..=(centre[0] + half[0]).min(dims[0] - 1)
                {
                    out.push(filtered.values[volume.linear(i, j, k)]);
                }
            }
        }
        out
    };
    let seed_value = median(around(seed_ijk, [1, 1, 1])).unwrap_or(0.0);
    let upper = settings.upper_threshold.unwrap_or(f64::INFINITY);
    let open_r = settings.open_radius_m.unwrap_or(h);
    let close_r = settings.close_radius_m.unwrap_or(h);
    let lumen_where = |threshold: &(dyn Fn(usize) -> f64 + Sync)| -> Vec<bool> {
        let mut m: Vec<bool> = filtered
            .values
            .par_iter()
            .enumerate()
            .map(|(n, &v)| f64::from(v) >= threshold(n) && f64::from(v) <= upper)
            .collect();
        if close_r > 0.0 {
            m = mask::close(&m, dims, spacing, close_r);
        }
        if open_r > 0.0 {
            m = mask::open(&m, dims, spacing, open_r);
        }
        mask::fill_holes(&mask::component_of(&m, dims, seed_n), dims)
    };
    // First pass: one threshold (given, or Otsu's near the seed).
    let first = match settings.threshold {
        Some(t) => t,
        None => {
            let half = [0, 1, 2].map(|a| (settings.threshold_window_m / spacing[a]) as usize);
            mask::otsu_threshold(&around(seed_ijk, half)).ok_or_else(|| {
                ImagingError::Segmentation("the volume is uniform near the seed".into())
            })?
        }
    };
    if seed_value < first || seed_value > upper {
        return Err(ImagingError::Segmentation(format!(
            "the seed's value {seed_value:.1} is outside the lumen range \
             [{first:.1}, {upper:.1}]: is the seed inside a contrast-filled vessel?"
        )));
    }
    let mut lumen = lumen_where(&|_| first);
    // Lumen and tissue values: the median of the lumen's core and of a shell around it.
    let (lumen_value, background_value) = {
        let distance_out = edt::distance_to(&lumen, dims, spacing);
        let background: Vec<bool> = lumen.par_iter().map(|&m| !m).collect();
        let distance_in = edt::distance_to(&background, dims, spacing);
        let shell: Vec<f32> = (0..lumen.len())
            .filter(|&n| {
                let d = f64::from(distance_out[n]);
                d > 1.5 * h && d <= 4.0 * h
            })
            .map(|n| filtered.values[n])
            .collect();
        let core: Vec<f32> = (0..lumen.len())
            .filter(|&n| f64::from(distance_in[n]) >= 2.0 * h)
            .map(|n| filtered.values[n])
            .collect();
        (
            median(core).unwrap_or(seed_value),
            median(shell).unwrap_or(first),
        )
    };
    // Second pass: between the tissue and the local lumen value (the brightest
    // value within `local_window_m`, smoothed), so that a bolus that fades along the vessel
    // is followed; never closer to the tissue than `floor_sigmas` noise σ.
    let mut threshold_range = [first, first];
    if settings.threshold.is_none() {
        // The threshold applies to the filtered image, whose noise is what a false lumen
        // voxel must stand out of.
        let filtered_noise = filter::noise_sigma(&filtered);
        let floor = background_value + settings.floor_sigmas * filtered_noise;
        let threshold_map: Vec<f32> = if settings.local_window_m > 0.0 {
            let clipped: Vec<f32> = filtered
                .values
                .par_iter()
                .map(|&v| v.min(upper as f32))
                .collect();
            let half = [0, 1, 2].map(|a| (settings.local_window_m / spacing[a]).round() as usize);
            let mut level = filter::box_maximum(&clipped, dims, half);
            drop(clipped);
            filter::gaussian_blur(&mut level, dims, half.map(|w| 0.5 * w as f64));
            level
                .par_iter()
                .map(|&l| {
                    let l = f64::from(l);
                    (background_value + settings.local_fraction * (l - background_value)).max(floor)
                        as f32
                })
                .collect()
        } else {
            let t = background_value + settings.local_fraction * (lumen_value - background_value);
            vec![t.max(floor) as f32; lumen.len()]
        };
        if f64::from(threshold_map[seed_n]) <= seed_value {
            lumen = lumen_where(&|n| f64::from(threshold_map[n]));
            threshold_range = lumen
                .par_iter()
                .zip(&threshold_map)
                .filter(|(m, _)| **m)
                .map(|(_, &t)| [f64::from(t), f64::from(t)])
                .reduce(
                    || [f64::INFINITY, f64::NEG_INFINITY],
                    |a, b| [a[0].min(b[0]), a[1].max(b[1])],
                );
        }
    }
    let lumen_voxels = lumen.iter().filter(|&&m| m).count();
    if lumen_voxels < 8 {
        return Err(ImagingError::Segmentation(format!(
            "only {lumen_voxels} lumen voxels around the seed at threshold {first:.1}"
        )));
    }
    stages.lap("threshold and morphology");

    let background: Vec<bool> = lumen.par_iter().map(|&m| !m).collect();
    let dbf = edt::distance_to(&background, dims, spacing);
    drop(background);
    stages.lap("distance transform");
    let mut skeleton = skeleton::teasar(&lumen, &dbf, dims, spacing, seed_n, &settings.skeleton)?;
    let spurs_pruned = skeleton::prune_spurs(
        &mut skeleton.adjacency,
        &dbf,
        dims,
        spacing,
        skeleton.root,
        &settings.skeleton,
    );
    stages.lap("skeleton");
    let graph = centerline::vessel_graph(
        &filtered,
        &filtered,
        &skeleton.adjacency,
        &dbf,
        skeleton.root,
        &CenterlineSettings {
            background_value,
            point_spacing_m: settings.point_spacing_m.unwrap_or(h),
            refinement_passes: settings.refinement_passes,
            correct_blur: settings.correct_blur,
        },
    )?;
    stages.lap("centerlines");
    let surface = lumen_surface(&graph, &settings.surface)?;
    let polygonised_triangles = surface.triangles.len();
    stages.lap("surface");
    let surface = match settings.decimate_tolerance_m {
        Some(tolerance) => decimate(&surface, tolerance).0,
        None => surface,
    };
    let topology = surface.topology();
    stages.lap("decimation");

    let degree = graph.node_degrees();
    let mut radii: Vec<f32> = graph
        .branches
        .iter()
        .flat_map(|b| b.radii.iter().map(|&r| r as f32))
        .collect();
    radii.sort_by(f32::total_cmp);
    let voxel_volume = spacing[0] * spacing[1] * spacing[2];
    let report = SegmentationReport {
        seed_voxel: seed_ijk,
        noise_sigma: noise,
        lumen_value,
        background_value,
        threshold_range,
        lumen_voxels,
        lumen_volume_ml: lumen_voxels as f64 * voxel_volume * 1e6,
        spurs_pruned,
        branches: graph.branches.len(),
        end_points: degree.iter().filter(|&&d| d == 1).count(),
        branch_points: degree.iter().filter(|&&d| d >= 3).count(),
        total_length_mm: graph.total_length() * 1e3,
        radius_mm: [
            f64::from(radii[0]) * 1e3,
            f64::from(radii[radii.len() / 2]) * 1e3,
            f64::from(radii[radii.len() - 1]) * 1e3,
        ],
        surface_vertices: surface.vertices.len(),
        surface_triangles: surface.triangles.len(),
        polygonised_triangles,
        surface_watertight: topology.is_closed_oriented_manifold(),
        stage_seconds: stages.0,
    };
    let mask = volume.with_values(lumen.iter().map(|&m| f32::from(u8::from(m))).collect())?;
    Ok(Segmentation {
        graph,
        surface,
        mask,
        report,
    })
}
