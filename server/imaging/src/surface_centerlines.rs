//! Centerlines of a vessel surface: the closed lumen is voxelized (parity fill along z), the
//! segmentation's own skeleton (TEASAR from the access, spur pruning) gives the branches,
//! and its cross-section refinement, cast against the exact surface rather than the voxels,
//! centres them and gives their radii: one branch per segment between branch points, named
//! `vessel_00`, `vessel_01`, … breadth-first from the access end.

use cathlab_anatomy::{Lumen, VesselGraph};
use nalgebra::{Matrix3, Point3, Vector3};

use crate::error::{ImagingError, Result};
use crate::segment::centerline::{CenterlineSettings, Intensity, vessel_graph};
use crate::segment::edt::distance_to;
use crate::segment::skeleton::{SkeletonSettings, prune_spurs, teasar_from_root};
use crate::volume::ScalarVolume;

/// How a surface is turned into centerlines.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceCenterlineSettings {
    /// Voxel edge (m); by default the finest that keeps the grid within `max_voxels`, and no
    /// finer than 0.2 mm.
    pub voxel_m: Option<f64>,
    /// Most voxels in the grid (memory: about 20 bytes each).
    pub max_voxels: usize,
    /// Skeleton growth and pruning.
    pub skeleton: SkeletonSettings,
    /// Cross-section refinement passes.
    pub refinement_passes: usize,
    /// Only this box of the surface (m, the surface's frame: lowest and highest corner); the
    /// vessels it cuts end at its faces. `None`: the whole surface.
    pub region: Option<[Point3<f64>; 2]>,
}

impl Default for SurfaceCenterlineSettings {
    fn default() -> Self {
        Self {
            voxel_m: None,
            max_voxels: 32_000_000,
            skeleton: SkeletonSettings::default(),
            refinement_passes: 2,
            region: None,
        }
    }
}

/// Centerlines and what they were computed on.
#[derive(Debug, Clone)]
pub struct SurfaceCenterlines {
    /// The vessel graph, landmark `access` at the root end.
    pub graph: VesselGraph,
    /// The voxelized lumen (1 inside, 0 outside).
    pub image: ScalarVolume,
    /// The voxel edge used (m).
    pub voxel_m: f64,
}

/// The lumen of `lumen` on a grid of voxel `h` over its bounding box (plus two voxels): 1
/// for voxel centres inside by parity along z columns, else 0.
pub fn voxelize(lumen: &Lumen, h: f64) -> Result<ScalarVolume> {
    voxelize_within(lumen, h, None)
}

/// The surface's bounding box, within `region` where one is given (m); `None` when they do
/// not overlap.
fn clipped_box(lumen: &Lumen, region: Option<[Point3<f64>; 2]>) -> Option<[Point3<f64>; 2]> {
    let (mut lo, mut hi) = lumen.mesh().bounding_box();
    if let Some([a, b]) = region {
        for axis in 0..3 {
            lo[axis] = lo[axis].max(a[axis].min(b[axis]));
            hi[axis] = hi[axis].min(a[axis].max(b[axis]));
        }
    }
    (0..3).all(|a| lo[a] < hi[a]).then_some([lo, hi])
}

/// [`voxelize`] over the part of the surface's bounding box inside `region` (m): the parity
/// of each column still counts every crossing of the whole surface, so a vessel cut by the
/// box is filled up to the box's face.
pub fn voxelize_within(
    lumen: &Lumen,
    h: f64,
    region: Option<[Point3<f64>; 2]>,
) -> Result<ScalarVolume> {
    let mesh = lumen.mesh();
    let [lo, hi] = clipped_box(lumen, region).ok_or_else(|| {
        ImagingError::Segmentation("the region does not overlap the surface".into())
    })?;
    let origin = lo.coords - Vector3::repeat(2.0 * h);
    let dims = [0, 1, 2].map(|a| ((hi[a] - lo[a]) / h).ceil() as usize + 5);
    let (nx, ny, nz) = (dims[0], dims[1], dims[2]);
    // Column centres slightly off the grid's lattice, so that rays through vertices and
    // edges of axis-aligned synthetic surfaces are unlikely.
    let jitter = [0.173_205_08e-3 * h, 0.141_421_36e-3 * h];
    let column_xy = |i: usize, j: usize| {
        (
            origin.x + i as f64 * h + jitter[0],
            origin.y + j as f64 * h + jitter[1],
        )
    };
    let mut crossings: Vec<Vec<f64>> = vec![Vec::new(); nx * ny];
    for t in &mesh.triangles {
        let [a, b, c] = mesh.corners(t);
        let min_x = a.x.min(b.x).min(c.x);
        let max_x = a.x.max(b.x).max(c.x);
        let min_y = a.y.min(b.y).min(c.y);
        let max_y = a.y.max(b.y).max(c.y);
        let i0 = ((min_x - origin.x) / h).floor().max(0.0) as usize;
        let i1 = (((max_x - origin.x) / h).ceil() as usize).min(nx - 1);
        let j0 = ((min_y - origin.y) / h).floor().max(0.0) as usize;
        let j1 = (((max_y - origin.y) / h).ceil() as usize).min(ny - 1);
        let area = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        if area == 0.0 {
            continue; // edge-on to the rays
        }
        for j in j0..=j1 {
            for i in i0..=i1 {
                let (x, y) = column_xy(i, j);
                let w0 = ((b.x - x) * (c.y - y) - (c.x - x) * (b.y - y)) / area;
                let w1 = ((c.x - x) * (a.y - y) - (a.x - x) * (c.y - y)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0 {
                    crossings[j * nx + i].push(w0 * a.z + w1 * b.z + w2 * c.z);
                }
            }
        }
    }
    let mut values = vec![0.0_f32; nx * ny * nz];
    for (column, zs) in crossings.iter_mut().enumerate() {
        zs.sort_by(f64::total_cmp);
        let (i, j) = (column % nx, column / nx);
        for pair in zs.chunks_exact(2) {
            let k0 = ((pair[0] - origin.z) / h).ceil().max(0.0) as usize;
            let k1 = ((pair[1] - origin.z) / h).floor();
            if k1 < 0.0 {
                continue;
            }
            for k in k0..=(k1 as usize).min(nz - 1) {
                values[(k * ny + j) * nx + i] = 1.0;
            }
        }
    }
    ScalarVolume::new(
        dims,
        Vector3::repeat(h),
        origin,
        Matrix3::identity(),
        values,
    )
}

/// The exact wall of a surface as an image for cross-sections: 1 deeper than one ray step
/// inside, 0 as far outside, linear between, so that a crossing interpolated between two
/// samples is the wall itself.
pub struct SurfaceWalls<'a> {
    lumen: &'a Lumen,
    step: f64,
}

impl<'a> SurfaceWalls<'a> {
    /// The walls of `lumen`, sampled every `step` (m) along a ray.
    pub fn new(lumen: &'a Lumen, step: f64) -> Self {
        Self { lumen, step }
    }
}

impl Intensity for SurfaceWalls<'_> {
    fn value(&self, p: &Point3<f64>) -> f64 {
        let d = self.lumen.query(p).signed_distance;
        (0.5 - 0.5 * d / self.step).clamp(0.0, 1.0)
    }

    fn ray_step(&self) -> f64 {
        self.step
    }
}

/// Computes the centerlines of `lumen` from the `access` point (m, the surface's frame: an
/// open end's centre, or any point in the access vessel near its end).
pub fn centerlines_from_surface(
    lumen: &Lumen,
    access: &Point3<f64>,
    settings: &SurfaceCenterlineSettings,
) -> Result<SurfaceCenterlines> {
    let [lo, hi] = clipped_box(lumen, settings.region).ok_or_else(|| {
        ImagingError::Segmentation("the region does not overlap the surface".into())
    })?;
    let extent = hi - lo;
    let h = match settings.voxel_m {
        Some(h) if h.is_finite() && h > 0.0 => h,
        Some(h) => {
            return Err(ImagingError::Segmentation(format!(
                "voxel size {h} m must be finite and > 0"
            )));
        }
        None => {
            let box_volume = (extent.x + 5e-4) * (extent.y + 5e-4) * (extent.z + 5e-4);
            (box_volume / settings.max_voxels as f64).cbrt().max(2e-4)
        }
    };
    let voxels: f64 = (0..3).map(|a| extent[a] / h + 5.0).product();
    if voxels > settings.max_voxels as f64 {
        return Err(ImagingError::Segmentation(format!(
            "a {:.0}×{:.0}×{:.0} mm surface at {:.2} mm voxels needs {voxels:.0} voxels, more \
             than {}; choose larger voxels",
            extent.x * 1e3,
            extent.y * 1e3,
            extent.z * 1e3,
            h * 1e3,
            settings.max_voxels
        )));
    }
    let image = voxelize_within(lumen, h, settings.region)?;
    let dims = image.dims;
    let mask: Vec<bool> = image.values.iter().map(|&v| v >= 0.5).collect();
    // The root: the lumen voxel nearest the access point, within ten voxels.
    let centre = image.index_of(access).map(f64::round);
    let reach = 10_i64;
    let mut root = None;
    let mut best = f64::INFINITY;
    for dk in -reach..=reach {
        for dj in -reach..=reach {
            for di in -reach..=reach {
                let ijk = [
                    centre[0] as i64 + di,
                    centre[1] as i64 + dj,
                    centre[2] as i64 + dk,
                ];
                if (0..3).any(|a| ijk[a] < 0 || ijk[a] >= dims[a] as i64) {
                    continue;
                }
                let n = image.linear(ijk[0] as usize, ijk[1] as usize, ijk[2] as usize);
                if !mask[n] {
                    continue;
                }
                let p =
                    image.position_of(&Vector3::new(ijk[0] as f64, ijk[1] as f64, ijk[2] as f64));
                let d = (p - access).norm();
                if d < best {
                    best = d;
                    root = Some(n);
                }
            }
        }
    }
    let root = root.ok_or_else(|| {
        ImagingError::Segmentation(format!(
            "the access point ({:.1}, {:.1}, {:.1}) mm is not within {reach} voxels ({:.1} mm) \
             of the lumen",
            access.x * 1e3,
            access.y * 1e3,
            access.z * 1e3,
            reach as f64 * h * 1e3
        ))
    })?;
    // Only the lumen connected to the access counts.
    let connected = crate::segment::mask::component_of(&mask, dims, root);
    let background: Vec<bool> = connected.iter().map(|&m| !m).collect();
    let dbf = distance_to(&background, dims, [h; 3]);
    drop(background);
    let mut skeleton = teasar_from_root(&connected, &dbf, dims, [h; 3], root, &settings.skeleton)?;
    prune_spurs(
        &mut skeleton.adjacency,
        &dbf,
        dims,
        [h; 3],
        skeleton.root,
        &settings.skeleton,
    );
    let walls = SurfaceWalls {
        lumen,
        step: 0.25 * h,
    };
    let graph = vessel_graph(
        &image,
        &walls,
        &skeleton.adjacency,
        &dbf,
        skeleton.root,
        &CenterlineSettings {
            background_value: 0.0,
            point_spacing_m: h,
            refinement_passes: settings.refinement_passes,
            // The surface is the wall itself: nothing blurred it.
            correct_blur: false,
        },
    )?;
    Ok(SurfaceCenterlines {
        graph,
        image,
        voxel_m: h,
    })
}
