//! CT volumes: Hounsfield units stored as 16-bit integers on a regular grid with spacing,
//! origin and direction in patient LPS coordinates; MetaImage (`.mha`/`.mhd`, raw or zlib)
//! and NIfTI-1 (`.nii`, `.nii.gz`) readers; trilinear sampling and ray-marched line
//! integrals.

use std::io::Read;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Point3, Vector3};

use crate::error::{Result, XrayError, require_finite, require_positive};

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
        for (axis, &n) in dims.iter().enumerate() {
            if n == 0 {
                return Err(XrayError::OutOfRange {
                    what: format!("volume size along axis {axis}"),
                    range: "at least 1 voxel",
                    value: 0.0,
                });
            }
        }
        for axis in 0..3 {
            require_positive(
                || format!("voxel spacing along axis {axis} (m)"),
                spacing_m[axis],
            )?;
            require_finite(
                || format!("volume origin component {axis} (m)"),
                origin_m[axis],
            )?;
        }
        let orthonormal = (direction.transpose() * direction - Matrix3::identity())
            .abs()
            .max();
        if orthonormal.is_nan() || orthonormal >= 1e-4 {
            return Err(XrayError::OutOfRange {
                what: "volume direction matrix: largest deviation of DᵀD from I".into(),
                range: "below 1e-4 (orthonormal)",
                value: orthonormal,
            });
        }
        let count = dims[0] * dims[1] * dims[2];
        if hu.len() != count {
            return Err(XrayError::OutOfRange {
                what: "voxel count".into(),
                range: "the product of the dimensions",
                value: hu.len() as f64,
            });
        }
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

fn bad(file: &Path, reason: impl Into<String>) -> XrayError {
    XrayError::BadVolume {
        file: file.to_owned(),
        reason: reason.into(),
    }
}

fn read_file(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|source| XrayError::Io {
        file: path.to_owned(),
        source,
    })
}

/// Element types of MetaImage and NIfTI voxels.
#[derive(Debug, Clone, Copy)]
enum Element {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    F32,
    F64,
}

impl Element {
    fn size(self) -> usize {
        match self {
            Element::U8 | Element::I8 => 1,
            Element::U16 | Element::I16 => 2,
            Element::U32 | Element::I32 | Element::F32 => 4,
            Element::F64 => 8,
        }
    }

    fn decode(self, bytes: &[u8], big_endian: bool) -> f64 {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(bytes);
                if big_endian {
                    <$t>::from_be_bytes(a) as f64
                } else {
                    <$t>::from_le_bytes(a) as f64
                }
            }};
        }
        match self {
            Element::U8 => f64::from(bytes[0]),
            Element::I8 => f64::from(bytes[0] as i8),
            Element::U16 => num!(u16, 2),
            Element::I16 => num!(i16, 2),
            Element::U32 => num!(u32, 4),
            Element::I32 => num!(i32, 4),
            Element::F32 => num!(f32, 4),
            Element::F64 => num!(f64, 8),
        }
    }
}

/// Decodes `count` voxels as HU (`slope`·value + `intercept`); NaN voxels become air.
fn decode_voxels(
    file: &Path,
    data: &[u8],
    count: usize,
    element: Element,
    big_endian: bool,
    slope: f64,
    intercept: f64,
) -> Result<Vec<i16>> {
    let size = element.size();
    if data.len() < count * size {
        return Err(bad(
            file,
            format!(
                "truncated voxel data: {} bytes for {count} voxels of {size} bytes",
                data.len()
            ),
        ));
    }
    Ok(data[..count * size]
        .chunks_exact(size)
        .map(|b| {
            let v = slope * element.decode(b, big_endian) + intercept;
            if v.is_finite() {
                to_hu(v)
            } else {
                AIR_HU as i16
            }
        })
        .collect())
}

/// Reads a MetaImage volume (`.mha` with the data inline, or `.mhd` with a separate data
/// file), raw or zlib-compressed, in mm, converted to m.
pub fn read_metaimage(path: &Path) -> Result<Volume> {
    let bytes = read_file(path)?;
    let mut fields: Vec<(String, String)> = Vec::new();
    let mut offset = 0;
    loop {
        let Some(end) = bytes[offset..].iter().position(|&b| b == b'\n') else {
            return Err(bad(path, "header ends before ElementDataFile"));
        };
        let line = String::from_utf8_lossy(&bytes[offset..offset + end])
            .trim()
            .to_owned();
        offset += end + 1;
        if line.is_empty() {
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            return Err(bad(path, format!("header line without '=': {line:?}")));
        };
        let (key, value) = (key.trim().to_owned(), value.trim().to_owned());
        let done = key == "ElementDataFile";
        fields.push((key, value));
        if done {
            break;
        }
        if offset >= bytes.len() {
            return Err(bad(path, "header ends before ElementDataFile"));
        }
    }
    let get = |key: &str| {
        fields
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    };
    let numbers = |key: &str, n: usize| -> Result<Vec<f64>> {
        let value = get(key).ok_or_else(|| bad(path, format!("missing {key}")))?;
        let v: Vec<f64> = value
            .split_whitespace()
            .map(str::parse::<f64>)
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| bad(path, format!("{key}: expected {n} numbers, got {value:?}")))?;
        if v.len() != n || v.iter().any(|x| !x.is_finite()) {
            return Err(bad(
                path,
                format!("{key}: expected {n} finite numbers, got {value:?}"),
            ));
        }
        Ok(v)
    };
    if get("NDims") != Some("3") {
        return Err(XrayError::Unsupported {
            file: path.to_owned(),
            what: format!(
                "NDims {:?} (only 3-D volumes)",
                get("NDims").unwrap_or("missing")
            ),
        });
    }
    let dims = numbers("DimSize", 3)?;
    if dims.iter().any(|&d| !(d >= 1.0 && d.fract() == 0.0)) {
        return Err(bad(path, "DimSize: expected 3 positive integers"));
    }
    let dims = [dims[0] as usize, dims[1] as usize, dims[2] as usize];
    // The first of several synonymous header keys that is present.
    let first_of = |keys: &[&'static str]| keys.iter().copied().find(|k| get(k).is_some());
    let spacing = match first_of(&["ElementSpacing", "ElementSize"]) {
        Some(key) => numbers(key, 3)?,
        None => vec![1.0; 3],
    };
    if let Some(axis) = spacing.iter().position(|&s| s <= 0.0) {
        return Err(bad(
            path,
            format!(
                "ElementSpacing: axis {axis} is {} (must be > 0)",
                spacing[axis]
            ),
        ));
    }
    let origin = match first_of(&["Offset", "Origin", "Position"]) {
        Some(key) => numbers(key, 3)?,
        None => vec![0.0; 3],
    };
    let direction = match first_of(&["TransformMatrix", "Rotation", "Orientation"]) {
        // MetaImage stores the direction cosines column by column.
        Some(key) => Matrix3::from_column_slice(&numbers(key, 9)?),
        None => Matrix3::identity(),
    };
    let element = match get("ElementType") {
        Some("MET_UCHAR") => Element::U8,
        Some("MET_CHAR") => Element::I8,
        Some("MET_USHORT") => Element::U16,
        Some("MET_SHORT") => Element::I16,
        Some("MET_UINT") => Element::U32,
        Some("MET_INT") => Element::I32,
        Some("MET_FLOAT") => Element::F32,
        Some("MET_DOUBLE") => Element::F64,
        other => {
            return Err(XrayError::Unsupported {
                file: path.to_owned(),
                what: format!("ElementType {}", other.unwrap_or("(missing)")),
            });
        }
    };
    if get("ElementNumberOfChannels").is_some_and(|c| c != "1") {
        return Err(XrayError::Unsupported {
            file: path.to_owned(),
            what: "multi-channel voxels".into(),
        });
    }
    let big_endian = matches!(
        get("BinaryDataByteOrderMSB").or(get("ElementByteOrderMSB")),
        Some("True") | Some("true")
    );
    let compressed = matches!(get("CompressedData"), Some("True") | Some("true"));
    let data_file = get("ElementDataFile").unwrap_or("LOCAL");
    let (raw, source): (Vec<u8>, PathBuf) = if data_file == "LOCAL" {
        (bytes[offset..].to_vec(), path.to_owned())
    } else {
        let other = path.parent().unwrap_or(Path::new(".")).join(data_file);
        (read_file(&other)?, other)
    };
    let count = dims[0] * dims[1] * dims[2];
    let data = if compressed {
        let mut out = Vec::with_capacity(count * element.size());
        flate2::read::ZlibDecoder::new(raw.as_slice())
            .read_to_end(&mut out)
            .map_err(|e| bad(&source, format!("zlib data: {e}")))?;
        out
    } else {
        raw
    };
    let hu = decode_voxels(&source, &data, count, element, big_endian, 1.0, 0.0)?;
    Volume::new(
        dims,
        Vector3::new(spacing[0], spacing[1], spacing[2]) * 1e-3,
        Vector3::new(origin[0], origin[1], origin[2]) * 1e-3,
        direction,
        hu,
    )
    .map_err(|e| bad(path, e.to_string()))
}

/// Reads a NIfTI-1 volume (`.nii`, or gzip-compressed `.nii.gz`), either byte order, with
/// the sform (or qform) affine; NIfTI's RAS+ world is turned into DICOM LPS.
pub fn read_nifti(path: &Path) -> Result<Volume> {
    let file_bytes = read_file(path)?;
    let bytes = if file_bytes.starts_with(&[0x1f, 0x8b]) {
        let mut out = Vec::new();
        flate2::read::GzDecoder::new(file_bytes.as_slice())
            .read_to_end(&mut out)
            .map_err(|e| bad(path, format!("gzip data: {e}")))?;
        out
    } else {
        file_bytes
    };
    if bytes.len() < 348 {
        return Err(bad(
            path,
            format!(
                "{} bytes, shorter than the 348-byte NIfTI-1 header",
                bytes.len()
            ),
        ));
    }
    let big_endian = match (
        i32::from_le_bytes(bytes[0..4].try_into().unwrap_or_default()),
        i32::from_be_bytes(bytes[0..4].try_into().unwrap_or_default()),
    ) {
        (348, _) => false,
        (_, 348) => true,
        _ => return Err(bad(path, "sizeof_hdr is not 348: not a NIfTI-1 file")),
    };
    let i16_at = |o: usize| {
        let a = [bytes[o], bytes[o + 1]];
        if big_endian {
            i16::from_be_bytes(a)
        } else {
            i16::from_le_bytes(a)
        }
    };
    let f32_at = |o: usize| {
        let a = [bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]];
        f64::from(if big_endian {
            f32::from_be_bytes(a)
        } else {
            f32::from_le_bytes(a)
        })
    };
    let magic = &bytes[344..348];
    if magic != b"n+1\0" {
        return Err(XrayError::Unsupported {
            file: path.to_owned(),
            what: "NIfTI magic (only single-file n+1 is read)".into(),
        });
    }
    let ndim = i16_at(40);
    if !(3..=4).contains(&ndim) || (ndim == 4 && i16_at(48) > 1) {
        return Err(XrayError::Unsupported {
            file: path.to_owned(),
            what: format!("dimensionality {ndim} (only 3-D volumes)"),
        });
    }
    let dims = [i16_at(42), i16_at(44), i16_at(46)];
    if let Some(axis) = dims.iter().position(|&d| d < 1) {
        return Err(bad(
            path,
            format!("dim[{}] is {} (must be ≥ 1)", axis + 1, dims[axis]),
        ));
    }
    let dims = dims.map(|d| d as usize);
    let element = match i16_at(70) {
        2 => Element::U8,
        4 => Element::I16,
        8 => Element::I32,
        16 => Element::F32,
        64 => Element::F64,
        256 => Element::I8,
        512 => Element::U16,
        768 => Element::U32,
        other => {
            return Err(XrayError::Unsupported {
                file: path.to_owned(),
                what: format!("datatype code {other}"),
            });
        }
    };
    let pixdim = [f32_at(80), f32_at(84), f32_at(88)];
    if let Some(axis) = pixdim.iter().position(|&s| !(s > 0.0 && s.is_finite())) {
        return Err(bad(
            path,
            format!("pixdim[{}] is {} (must be > 0)", axis + 1, pixdim[axis]),
        ));
    }
    let unit_m = match bytes[123] & 0x07 {
        1 => 1.0,
        3 => 1e-6,
        _ => 1e-3,
    };
    let vox_offset = f32_at(108);
    if vox_offset.is_nan() || vox_offset < 348.0 {
        return Err(bad(
            path,
            format!("vox_offset {vox_offset} (must be ≥ 348)"),
        ));
    }
    let (slope, intercept) = match (f32_at(112), f32_at(116)) {
        (s, i) if s != 0.0 && s.is_finite() && i.is_finite() => (s, i),
        _ => (1.0, 0.0),
    };
    // Affine from voxel index to RAS (mm): sform if set, else the pixdim scaling.
    let affine = if i16_at(254) > 0 {
        let row = |o: usize| [f32_at(o), f32_at(o + 4), f32_at(o + 8), f32_at(o + 12)];
        [row(280), row(296), row(312)]
    } else {
        [
            [pixdim[0], 0.0, 0.0, 0.0],
            [0.0, pixdim[1], 0.0, 0.0],
            [0.0, 0.0, pixdim[2], 0.0],
        ]
    };
    let ras_to_lps = Matrix3::from_diagonal(&Vector3::new(-1.0, -1.0, 1.0));
    let columns = ras_to_lps * Matrix3::from_fn(|r, c| affine[r][c]);
    let spacing = Vector3::new(
        columns.column(0).norm(),
        columns.column(1).norm(),
        columns.column(2).norm(),
    );
    if spacing.iter().any(|&s| s.is_nan() || s <= 0.0) {
        return Err(bad(path, "sform has a zero column (zero voxel spacing)"));
    }
    let direction = Matrix3::from_columns(&[
        columns.column(0) / spacing.x,
        columns.column(1) / spacing.y,
        columns.column(2) / spacing.z,
    ]);
    let origin = ras_to_lps * Vector3::new(affine[0][3], affine[1][3], affine[2][3]);
    let count = dims[0] * dims[1] * dims[2];
    let start = vox_offset as usize;
    let data = bytes.get(start..).unwrap_or(&[]);
    let hu = decode_voxels(path, data, count, element, big_endian, slope, intercept)?;
    Volume::new(dims, spacing * unit_m, origin * unit_m, direction, hu)
        .map_err(|e| bad(path, e.to_string()))
}
