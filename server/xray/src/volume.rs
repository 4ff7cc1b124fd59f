//! CT volumes: Hounsfield units stored as 16-bit integers on a regular grid with spacing,
//! origin and direction in patient LPS coordinates; MetaImage (`.mha`/`.mhd`, raw or zlib)
//! and NIfTI-1 (`.nii`, `.nii.gz`) readers; trilinear sampling and ray-marched line
//! integrals.

use std::path::{Path, PathBuf};

use cathlab_imaging::ScalarVolume;

use nalgebra::{Matrix3, Point3, Vector3};

use crate::error::{Result, XrayError, require_finite};

/// Hounsfield units outside the volume (air).
pub const AIR_HU: f64 = -1000.0;

/// A CT volume. Voxel (i, j, k) is at `origin + direction · (i·sx, j·sy, k·sz)`; `hu` runs
/// with i fastest.
#[derive(Debug, Clone, PartialEq)]
pub struct Volume {
    /// Voxels along each index axis.
    pub dims: [usize; 3],
    /// Voxel spacing along each index axis (m).
    pub spacing_m: Vector3<f64>,
    /// Patient position of voxel (0, 0, 0) (m, LPS).
    pub origin_m: Vector3<f64>,
    /// Columns: the unit directions of the index axes in patient coordinates.
    pub direction: Matrix3<f64>,
    /// Hounsfield units, clamped to the i16 range (16 bits per voxel).
    pub hu: Vec<i16>,
}

impl Volume {
    /// Builds and checks a volume.
    pub fn new(
        dims: [usize; 3],
        spacing_m: Vector3<f64>,
        origin_m: Vector3<f64>,
        direction: Matrix3<f64>,
        hu: Vec<i16>,
    ) -> Result<Self> {
        cathlab_imaging::volume::check_grid(dims, &spacing_m, &origin_m, &direction, hu.len())
            .map_err(XrayError::InvalidVolume)?;
        Ok(Self {
            dims,
            spacing_m,
            origin_m,
            direction,
            hu,
        })
    }

    /// An axis-aligned volume centred on `center_m`, HU from `f` at each voxel centre
    /// averaged over `supersample`³ sub-points (partial-volume effect, as a scanner sees it).
    pub fn from_fn(
        dims: [usize; 3],
        spacing_m: Vector3<f64>,
        center_m: Vector3<f64>,
        supersample: usize,
        f: impl Fn(&Point3<f64>) -> f64 + Sync,
    ) -> Result<Self> {
        use rayon::prelude::*;
        let extent = Vector3::new(
            (dims[0] - 1) as f64 * spacing_m.x,
            (dims[1] - 1) as f64 * spacing_m.y,
            (dims[2] - 1) as f64 * spacing_m.z,
        );
        let origin = center_m - extent * 0.5;
        let s = supersample.max(1);
        let hu: Vec<i16> = (0..dims[0] * dims[1] * dims[2])
            .into_par_iter()
            .map(|n| {
                let (i, j, k) = (
                    n % dims[0],
                    (n / dims[0]) % dims[1],
                    n / (dims[0] * dims[1]),
                );
                let mut sum = 0.0;
                for a in 0..s {
                    for b in 0..s {
                        for c in 0..s {
                            let off = |q: usize| (q as f64 + 0.5) / s as f64 - 0.5;
                            let p = origin
                                + Vector3::new(
                                    (i as f64 + off(a)) * spacing_m.x,
                                    (j as f64 + off(b)) * spacing_m.y,
                                    (k as f64 + off(c)) * spacing_m.z,
                                );
                            sum += f(&Point3::from(p));
                        }
                    }
                }
                to_hu(sum / (s * s * s) as f64)
            })
            .collect();
        Self::new(dims, spacing_m, origin, Matrix3::identity(), hu)
    }

    /// Reads a volume, choosing the format by extension: `.mha`, `.mhd`, `.nii`, `.nii.gz`.
    pub fn load(path: &Path) -> Result<Self> {
        let name = path.to_string_lossy().to_ascii_lowercase();
        if name.ends_with(".mha") || name.ends_with(".mhd") {
            read_metaimage(path)
        } else if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            read_nifti(path)
        } else {
            Err(XrayError::Unsupported {
                file: path.to_owned(),
                what: "volume format (expected .mha, .mhd, .nii or .nii.gz)".into(),
            })
        }
    }

    /// Bytes held by the voxels.
    pub fn memory_bytes(&self) -> usize {
        self.hu.len() * std::mem::size_of::<i16>()
    }

    /// Continuous voxel index of a patient point.
    pub fn index_of(&self, p: &Point3<f64>) -> Vector3<f64> {
        (self.direction.transpose() * (p.coords - self.origin_m)).component_div(&self.spacing_m)
    }

    /// Patient position of a continuous voxel index.
    pub fn position_of(&self, index: &Vector3<f64>) -> Point3<f64> {
        Point3::from(self.origin_m + self.direction * index.component_mul(&self.spacing_m))
    }

    /// HU of voxel (i, j, k).
    pub fn voxel(&self, i: usize, j: usize, k: usize) -> i16 {
        self.hu[i + self.dims[0] * (j + self.dims[1] * k)]
    }

    /// Trilinear HU at a continuous index; air beyond the outermost voxel centres.
    pub fn sample_index(&self, x: &Vector3<f64>) -> f64 {
        let [nx, ny, nz] = self.dims;
        let inside = |v: f64, n: usize| v >= 0.0 && v <= (n - 1) as f64;
        if !(inside(x.x, nx) && inside(x.y, ny) && inside(x.z, nz)) {
            return AIR_HU;
        }
        let base = |v: f64, n: usize| (v.floor() as usize).min(n.saturating_sub(2));
        let (i, j, k) = (base(x.x, nx), base(x.y, ny), base(x.z, nz));
        let (fx, fy, fz) = (x.x - i as f64, x.y - j as f64, x.z - k as f64);
        let (i1, j1, k1) = (
            (i + 1).min(nx - 1),
            (j + 1).min(ny - 1),
            (k + 1).min(nz - 1),
        );
        let v = |a, b, c| f64::from(self.voxel(a, b, c));
        let c00 = v(i, j, k) * (1.0 - fx) + v(i1, j, k) * fx;
        let c10 = v(i, j1, k) * (1.0 - fx) + v(i1, j1, k) * fx;
        let c01 = v(i, j, k1) * (1.0 - fx) + v(i1, j, k1) * fx;
        let c11 = v(i, j1, k1) * (1.0 - fx) + v(i1, j1, k1) * fx;
        let c0 = c00 * (1.0 - fy) + c10 * fy;
        let c1 = c01 * (1.0 - fy) + c11 * fy;
        c0 * (1.0 - fz) + c1 * fz
    }

    /// The parameter interval (m along a unit `direction` from `origin`) inside the box of
    /// voxel centres; `None` if the ray misses it.
    pub fn clip(&self, origin: &Point3<f64>, direction: &Vector3<f64>) -> Option<(f64, f64)> {
        let (o, d) = self.index_ray(origin, direction);
        self.clip_index(&o, &d)
    }

    /// A ray in continuous voxel indices: origin, and index change per metre along it.
    fn index_ray(
        &self,
        origin: &Point3<f64>,
        direction: &Vector3<f64>,
    ) -> (Vector3<f64>, Vector3<f64>) {
        (
            self.index_of(origin),
            (self.direction.transpose() * direction).component_div(&self.spacing_m),
        )
    }

    /// [`Self::clip`] for a ray already in voxel indices.
    fn clip_index(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<(f64, f64)> {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for axis in 0..3 {
            let hi = (self.dims[axis] - 1) as f64;
            if d[axis].abs() < 1e-300 {
                if o[axis] < 0.0 || o[axis] > hi {
                    return None;
                }
            } else {
                let (a, b) = ((0.0 - o[axis]) / d[axis], (hi - o[axis]) / d[axis]);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        (t0 < t1).then_some((t0, t1))
    }

    /// ∫ μ(HU(x)) dx along the ray (unit `direction`), by the trapezoid rule with samples at
    /// most `step_m` apart over the clipped interval; μ in 1/m gives a dimensionless result.
    pub fn line_integral(
        &self,
        origin: &Point3<f64>,
        direction: &Vector3<f64>,
        step_m: f64,
        mu: impl Fn(f64) -> f64,
    ) -> f64 {
        let Some(march) = self.march(origin, direction, step_m) else {
            return 0.0;
        };
        let mut sum = 0.0;
        for s in 0..march.samples {
            sum += march.weight(s) * mu(self.sample_index(&march.index_at(s)));
        }
        sum
    }

    /// The trapezoid-rule samples of a ray (unit `direction`) through the box of voxel
    /// centres, at most `step_m` apart; `None` if it misses. The GPU renderer marches the
    /// same samples.
    pub fn march(
        &self,
        origin: &Point3<f64>,
        direction: &Vector3<f64>,
        step_m: f64,
    ) -> Option<RayMarch> {
        let (o, d) = self.index_ray(origin, direction);
        let (t0, t1) = self.clip_index(&o, &d)?;
        let n = ((t1 - t0) / step_m).ceil().max(1.0);
        let h = (t1 - t0) / n;
        Some(RayMarch {
            start_index: o + d * t0,
            step_index: d * h,
            step_m: h,
            samples: n as usize + 1,
            last_index: Vector3::from(self.dims.map(|n| (n - 1) as f64)),
        })
    }

    /// The affine map from patient position (m) to continuous voxel index:
    /// `index = matrix · p + offset`.
    pub fn index_transform(&self) -> (Matrix3<f64>, Vector3<f64>) {
        let inverse_spacing = Matrix3::from_diagonal(&self.spacing_m.map(|s| 1.0 / s));
        let matrix = inverse_spacing * self.direction.transpose();
        (matrix, -(matrix * self.origin_m))
    }

    /// Smallest voxel spacing (m).
    pub fn min_spacing_m(&self) -> f64 {
        self.spacing_m.min()
    }

    /// Maps every voxel through `slope · value + intercept` (rounded, clamped to i16): for
    /// files whose values are not Hounsfield units (HU + 1024, rescaled intensities).
    pub fn rescale(&mut self, slope: f64, intercept: f64) -> Result<()> {
        require_finite(|| "HU rescale slope".into(), slope)?;
        require_finite(|| "HU rescale intercept".into(), intercept)?;
        for v in &mut self.hu {
            *v = to_hu(slope * f64::from(*v) + intercept);
        }
        Ok(())
    }
}

/// Side of an air brick (voxels).
pub const AIR_BRICK: usize = 8;

/// Which 8³ bricks of a volume are pure air, for empty-space skipping. Brick b is air when
/// every voxel from 8b to 8b + 9 along each axis (the brick and the voxels a trilinear
/// sample inside its closed box can touch) is at or below −1000 HU: every sample there
/// contributes exactly nothing, so skipping them leaves the line integrals unchanged.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AirBricks {
    /// Bricks along each axis.
    pub dims: [usize; 3],
    /// 1 for an air brick, 0 otherwise, x fastest.
    pub air: Vec<u8>,
}

impl AirBricks {
    /// Classifies the bricks of `volume`.
    pub fn of(volume: &Volume) -> Self {
        use rayon::prelude::*;
        let n = volume.dims;
        let dims = n.map(|d| d.div_ceil(AIR_BRICK));
        let air = (0..dims[0] * dims[1] * dims[2])
            .into_par_iter()
            .map(|b| {
                let idx = [
                    b % dims[0],
                    (b / dims[0]) % dims[1],
                    b / (dims[0] * dims[1]),
                ];
                let range =
                    |a: usize| idx[a] * AIR_BRICK..(idx[a] * AIR_BRICK + AIR_BRICK + 2).min(n[a]);
                let all_air = range(2).all(|k| {
                    range(1).all(|j| range(0).all(|i| f64::from(volume.voxel(i, j, k)) <= AIR_HU))
                });
                u8::from(all_air)
            })
            .collect();
        Self { dims, air }
    }

    /// When sample `x` of `march` lies in an air brick: how many samples, `x`'s included,
    /// lie in that brick's closed box and may be skipped (each adds nothing); else `None`.
    #[inline]
    pub fn air_run(&self, march: &RayMarch, x: &Vector3<f64>) -> Option<usize> {
        let brick = [0, 1, 2].map(|a| ((x[a] / AIR_BRICK as f64) as usize).min(self.dims[a] - 1));
        if self.air[brick[0] + self.dims[0] * (brick[1] + self.dims[1] * brick[2])] == 0 {
            return None;
        }
        let mut t_exit = f64::INFINITY;
        for (a, b) in brick.into_iter().enumerate() {
            let d = march.step_index[a];
            let lo = (b * AIR_BRICK) as f64;
            if d > 1e-300 {
                t_exit = t_exit.min((lo + AIR_BRICK as f64 - x[a]) / d);
            } else if d < -1e-300 {
                t_exit = t_exit.min((lo - x[a]) / d);
            }
        }
        Some(if t_exit.is_finite() {
            t_exit.max(0.0) as usize + 1
        } else {
            march.samples
        })
    }
}

/// Evenly spaced samples along a ray in voxel-index space, ends included (trapezoid rule).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayMarch {
    /// Continuous index of the first sample.
    pub start_index: Vector3<f64>,
    /// Index change from one sample to the next.
    pub step_index: Vector3<f64>,
    /// Distance between samples (m).
    pub step_m: f64,
    /// Number of samples (at least 2).
    pub samples: usize,
    /// The volume's largest index per axis: samples are clamped into the box of voxel
    /// centres, so that rounding at the clipped ends never reads air.
    pub last_index: Vector3<f64>,
}

impl RayMarch {
    /// Continuous index of sample `s`.
    #[inline]
    pub fn index_at(&self, s: usize) -> Vector3<f64> {
        (self.start_index + self.step_index * s as f64)
            .sup(&Vector3::zeros())
            .inf(&self.last_index)
    }

    /// Trapezoid weight of sample `s` (m).
    #[inline]
    pub fn weight(&self, s: usize) -> f64 {
        if s == 0 || s + 1 == self.samples {
            0.5 * self.step_m
        } else {
            self.step_m
        }
    }
}

fn to_hu(value: f64) -> i16 {
    value
        .round()
        .clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
}

/// The X-ray error for a volume the imaging readers rejected (same file, same words).
fn from_imaging(e: cathlab_imaging::ImagingError) -> XrayError {
    use cathlab_imaging::ImagingError as A;
    match e {
        A::Io { file, source } => XrayError::Io { file, source },
        A::BadVolume { file, reason } => XrayError::BadVolume { file, reason },
        A::UnsupportedVolume { file, what } => XrayError::Unsupported { file, what },
        other => XrayError::BadVolume {
            file: PathBuf::new(),
            reason: other.to_string(),
        },
    }
}

impl Volume {
    /// Converts a scalar volume (values in HU) to 16-bit HU; NaN voxels become air.
    pub fn from_scalar(scalar: ScalarVolume) -> Result<Self> {
        let hu = scalar
            .values
            .iter()
            .map(|&v| {
                if v.is_finite() {
                    to_hu(f64::from(v))
                } else {
                    AIR_HU as i16
                }
            })
            .collect();
        Volume::new(
            scalar.dims,
            scalar.spacing_m,
            scalar.origin_m,
            scalar.direction,
            hu,
        )
    }
}

/// Reads a MetaImage volume (`.mha` with the data inline, or `.mhd` with a separate data
/// file), raw or zlib-compressed, in mm, converted to m (see [`cathlab_imaging::volume`]).
pub fn read_metaimage(path: &Path) -> Result<Volume> {
    Volume::from_scalar(cathlab_imaging::read_metaimage(path).map_err(from_imaging)?)
}

/// Reads a NIfTI-1 volume (`.nii`, or gzip-compressed `.nii.gz`), RAS+ turned into LPS
/// (see [`cathlab_imaging::volume`]).
pub fn read_nifti(path: &Path) -> Result<Volume> {
    Volume::from_scalar(cathlab_imaging::read_nifti(path).map_err(from_imaging)?)
}
