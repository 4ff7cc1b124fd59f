//! Scalar volumes on a regular grid (CT, masks, distance maps) with spacing, origin and
//! direction in patient LPS coordinates, and their file formats: MetaImage (`.mha`/`.mhd`,
//! raw or zlib) and NIfTI-1 (`.nii`, `.nii.gz`) readers, a MetaImage writer.

use std::io::Read;
use std::path::{Path, PathBuf};

use cathlab_anatomy::io::limits;
use nalgebra::{Matrix3, Point3, Vector3};

use crate::error::{ImagingError, Result};

/// A scalar volume. Voxel (i, j, k) is at `origin + direction · (i·sx, j·sy, k·sz)`;
/// `values` run with i fastest.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarVolume {
    /// Voxels along each index axis.
    pub dims: [usize; 3],
    /// Voxel spacing along each index axis (m).
    pub spacing_m: Vector3<f64>,
    /// Patient position of voxel (0, 0, 0) (m, LPS).
    pub origin_m: Vector3<f64>,
    /// Columns: the unit directions of the index axes in patient coordinates.
    pub direction: Matrix3<f64>,
    /// The voxel values (file units, e.g. HU), i fastest.
    pub values: Vec<f32>,
}

impl ScalarVolume {
    /// Builds and checks a volume: positive dimensions and spacings, finite origin,
    /// orthonormal direction, one value per voxel.
    pub fn new(
        dims: [usize; 3],
        spacing_m: Vector3<f64>,
        origin_m: Vector3<f64>,
        direction: Matrix3<f64>,
        values: Vec<f32>,
    ) -> Result<Self> {
        check_grid(dims, &spacing_m, &origin_m, &direction, values.len())
            .map_err(ImagingError::InvalidVolume)?;
        Ok(Self {
            dims,
            spacing_m,
            origin_m,
            direction,
            values,
        })
    }

    /// Reads a volume, choosing the format by extension: `.mha`, `.mhd`, `.nii`, `.nii.gz`;
    /// a folder (or a `.dcm` file) is read as one DICOM series (see [`crate::dicom`]).
    pub fn load(path: &Path) -> Result<Self> {
        let name = path.to_string_lossy().to_ascii_lowercase();
        if path.is_dir() || name.ends_with(".dcm") {
            crate::dicom::read_series(path, None)
        } else if name.ends_with(".mha") || name.ends_with(".mhd") {
            read_metaimage(path)
        } else if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            read_nifti(path)
        } else {
            Err(ImagingError::UnsupportedVolume {
                file: path.to_owned(),
                what: "volume format (expected .mha, .mhd, .nii, .nii.gz, .dcm or a DICOM folder)"
                    .into(),
            })
        }
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// Whether the volume has no voxels (never, for a checked volume).
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Linear index of voxel (i, j, k).
    pub fn linear(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// Voxel (i, j, k) of a linear index.
    pub fn ijk(&self, n: usize) -> [usize; 3] {
        let (nx, ny) = (self.dims[0], self.dims[1]);
        [n % nx, (n / nx) % ny, n / (nx * ny)]
    }

    /// Patient position (m) of a continuous voxel index.
    pub fn position_of(&self, index: &Vector3<f64>) -> Point3<f64> {
        Point3::from(self.origin_m + self.direction * index.component_mul(&self.spacing_m))
    }

    /// Continuous voxel index of a patient position (m).
    pub fn index_of(&self, p: &Point3<f64>) -> Vector3<f64> {
        (self.direction.transpose() * (p.coords - self.origin_m)).component_div(&self.spacing_m)
    }

    /// Trilinear value at a continuous voxel index, clamped to the volume's edge.
    pub fn sample_index(&self, x: &Vector3<f64>) -> f64 {
        let mut base = [0usize; 3];
        let mut frac = [0.0f64; 3];
        for a in 0..3 {
            let max = (self.dims[a] - 1) as f64;
            let c = x[a].clamp(0.0, max);
            let f = c.floor().min((max - 1.0).max(0.0));
            base[a] = f as usize;
            frac[a] = c - f;
        }
        let step = |a: usize| usize::from(self.dims[a] > 1);
        let mut sum = 0.0;
        for dk in 0..2 {
            for dj in 0..2 {
                for di in 0..2 {
                    let w = (if di == 1 { frac[0] } else { 1.0 - frac[0] })
                        * (if dj == 1 { frac[1] } else { 1.0 - frac[1] })
                        * (if dk == 1 { frac[2] } else { 1.0 - frac[2] });
                    if w == 0.0 {
                        continue;
                    }
                    let n = self.linear(
                        base[0] + di * step(0),
                        base[1] + dj * step(1),
                        base[2] + dk * step(2),
                    );
                    sum += w * f64::from(self.values[n]);
                }
            }
        }
        sum
    }

    /// Trilinear value at a patient position (m).
    pub fn sample(&self, p: &Point3<f64>) -> f64 {
        self.sample_index(&self.index_of(p))
    }

    /// The same grid with other values.
    pub fn with_values(&self, values: Vec<f32>) -> Result<Self> {
        Self::new(
            self.dims,
            self.spacing_m,
            self.origin_m,
            self.direction,
            values,
        )
    }

    /// Bytes held by the values.
    pub fn memory_bytes(&self) -> usize {
        self.values.len() * std::mem::size_of::<f32>()
    }

    /// Writes the volume as a zlib-compressed float32 MetaImage (`.mha`), in mm.
    pub fn write_metaimage(&self, path: &Path) -> Result<()> {
        use std::io::Write;
        let d = &self.direction;
        let mm = |v: f64| v * 1e3;
        let header = format!(
            "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n\
             CompressedData = True\nTransformMatrix = {} {} {} {} {} {} {} {} {}\n\
             Offset = {} {} {}\nElementSpacing = {} {} {}\nDimSize = {} {} {}\n\
             ElementType = MET_FLOAT\nElementDataFile = LOCAL\n",
            d[(0, 0)],
            d[(1, 0)],
            d[(2, 0)],
            d[(0, 1)],
            d[(1, 1)],
            d[(2, 1)],
            d[(0, 2)],
            d[(1, 2)],
            d[(2, 2)],
            mm(self.origin_m.x),
            mm(self.origin_m.y),
            mm(self.origin_m.z),
            mm(self.spacing_m.x),
            mm(self.spacing_m.y),
            mm(self.spacing_m.z),
            self.dims[0],
            self.dims[1],
            self.dims[2],
        );
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
        let io = |source| ImagingError::Io {
            file: path.to_owned(),
            source,
        };
        for v in &self.values {
            z.write_all(&v.to_le_bytes()).map_err(io)?;
        }
        let data = z.finish().map_err(io)?;
        let mut out = header.into_bytes();
        out.extend_from_slice(&data);
        std::fs::write(path, out).map_err(io)
    }
}

/// Checks a voxel grid: at least one voxel per axis, finite positive spacing (m), finite
/// origin (m), orthonormal direction, `count` = the number of voxels. The error says what
/// is wrong, in words.
pub fn check_grid(
    dims: [usize; 3],
    spacing_m: &Vector3<f64>,
    origin_m: &Vector3<f64>,
    direction: &Matrix3<f64>,
    count: usize,
) -> std::result::Result<(), String> {
    if let Some(axis) = dims.iter().position(|&n| n == 0) {
        return Err(format!("size along axis {axis} is 0 voxels"));
    }
    for axis in 0..3 {
        let s = spacing_m[axis];
        if !(s.is_finite() && s > 0.0) {
            return Err(format!(
                "voxel spacing along axis {axis} is {s} m (must be finite and > 0)"
            ));
        }
        if !origin_m[axis].is_finite() {
            return Err(format!("origin component {axis} is not finite"));
        }
    }
    let orthonormal = (direction.transpose() * direction - Matrix3::identity())
        .abs()
        .max();
    if orthonormal.is_nan() || orthonormal >= 1e-4 {
        return Err(format!(
            "direction matrix is not orthonormal (|DᵀD − I| = {orthonormal})"
        ));
    }
    let voxels = dims[0] * dims[1] * dims[2];
    if count != voxels {
        return Err(format!("{count} values for {voxels} voxels"));
    }
    Ok(())
}

fn bad(file: &Path, reason: impl Into<String>) -> ImagingError {
    ImagingError::BadVolume {
        file: file.to_owned(),
        reason: reason.into(),
    }
}

/// A gzip-compressed NIfTI file inflated no further than its header says it needs
/// (`vox_offset` + its voxels), within the configured limits: the 348-byte header is
/// inflated and checked first, then the voxels, and inflation stops there.
fn inflate_nifti(path: &Path, compressed: &[u8]) -> Result<Vec<u8>> {
    let gzip = |e: String| bad(path, format!("gzip data: {e}"));
    let mut decoder = flate2::read::GzDecoder::new(compressed);
    let mut out = Vec::new();
    (&mut decoder)
        .take(348)
        .read_to_end(&mut out)
        .map_err(|e| gzip(e.to_string()))?;
    if out.len() < 348 {
        return Ok(out); // the caller names the short header
    }
    let big_endian = i32::from_le_bytes([out[0], out[1], out[2], out[3]]) != 348;
    let i16_at = |o: usize| {
        let a = [out[o], out[o + 1]];
        if big_endian {
            i16::from_be_bytes(a)
        } else {
            i16::from_le_bytes(a)
        }
    };
    // Voxel sizes by datatype code; an unknown code is refused by the caller, counted at
    // the largest size here.
    let size: u64 = match i16_at(70) {
        2 | 256 => 1,
        4 | 512 => 2,
        8 | 16 | 768 => 4,
        _ => 8,
    };
    let dims = [42, 44, 46].map(|o| i16_at(o).max(1) as u64);
    let voxels = limits::checked_voxels(&dims).map_err(|e| bad(path, format!("dim: {e}")))?;
    let raw_offset = [out[108], out[109], out[110], out[111]];
    let vox_offset = f64::from(if big_endian {
        f32::from_be_bytes(raw_offset)
    } else {
        f32::from_le_bytes(raw_offset)
    });
    if !(vox_offset.is_finite() && (348.0..=1e9).contains(&vox_offset)) {
        return Err(bad(
            path,
            format!("vox_offset {vox_offset} (must be 348 to 10⁹)"),
        ));
    }
    let needed = (vox_offset as u64).saturating_add((voxels as u64).saturating_mul(size));
    let cap = limits::read_limits().max_inflated_bytes;
    if needed > cap {
        return Err(gzip(format!(
            "{}vox_offset + dim × datatype need {needed} bytes, more than the {cap} compressed \
             data may inflate to (max_inflated_bytes)",
            limits::REFUSED
        )));
    }
    // Anything after the voxels is not read: a bomb stops at the header's size.
    decoder
        .take(needed.saturating_sub(348))
        .read_to_end(&mut out)
        .map_err(|e| gzip(e.to_string()))?;
    Ok(out)
}

fn read_file(path: &Path) -> Result<Vec<u8>> {
    cathlab_anatomy::io::limits::read_regular_file(path).map_err(|source| ImagingError::Io {
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

/// Decodes `count` voxels as `slope`·value + `intercept` (NaN voxels stay NaN).
fn decode_voxels(
    file: &Path,
    data: &[u8],
    count: usize,
    element: Element,
    big_endian: bool,
    slope: f64,
    intercept: f64,
) -> Result<Vec<f32>> {
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
        .map(|b| (slope * element.decode(b, big_endian) + intercept) as f32)
        .collect())
}

/// Reads a MetaImage volume (`.mha` with the data inline, or `.mhd` with a separate data
/// file), raw or zlib-compressed, in mm, converted to m.
pub fn read_metaimage(path: &Path) -> Result<ScalarVolume> {
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
        return Err(ImagingError::UnsupportedVolume {
            file: path.to_owned(),
            what: format!(
                "NDims {:?} (only 3-D volumes)",
                get("NDims").unwrap_or("missing")
            ),
        });
    }
    let dims = numbers("DimSize", 3)?;
    // 2⁶³ and above are not exact integers a u64 holds.
    if dims
        .iter()
        .any(|&d| !(d >= 1.0 && d.fract() == 0.0 && d < 9.2e18))
    {
        return Err(bad(path, "DimSize: expected 3 positive integers"));
    }
    let dims = [dims[0] as u64, dims[1] as u64, dims[2] as u64];
    // Checked before anything is allocated: a 150-byte header may declare 10¹⁵ voxels.
    let count = limits::checked_voxels(&dims).map_err(|e| bad(path, format!("DimSize: {e}")))?;
    let dims = dims.map(|d| d as usize);
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
            return Err(ImagingError::UnsupportedVolume {
                file: path.to_owned(),
                what: format!("ElementType {}", other.unwrap_or("(missing)")),
            });
        }
    };
    if get("ElementNumberOfChannels").is_some_and(|c| c != "1") {
        return Err(ImagingError::UnsupportedVolume {
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
    let (raw, source): (std::borrow::Cow<'_, [u8]>, PathBuf) = if data_file == "LOCAL" {
        (bytes[offset..].into(), path.to_owned())
    } else {
        let other = path.parent().unwrap_or(Path::new(".")).join(data_file);
        (read_file(&other)?.into(), other)
    };
    let data = if compressed {
        // Inflated to the size the header declares, never past it or the configured cap.
        let declared = limits::checked_bytes(count, element.size()).map_err(|e| bad(path, e))?;
        limits::inflate_bounded(flate2::read::ZlibDecoder::new(&*raw), Some(declared))
            .map(std::borrow::Cow::Owned)
            .map_err(|e| bad(&source, format!("zlib data (CompressedData): {e}")))?
    } else {
        raw
    };
    let values = decode_voxels(&source, &data, count, element, big_endian, 1.0, 0.0)?;
    ScalarVolume::new(
        dims,
        Vector3::new(spacing[0], spacing[1], spacing[2]) * 1e-3,
        Vector3::new(origin[0], origin[1], origin[2]) * 1e-3,
        direction,
        values,
    )
    .map_err(|e| bad(path, e.to_string()))
}

/// Reads a NIfTI-1 volume (`.nii`, or gzip-compressed `.nii.gz`), either byte order, with
/// the sform (or qform) affine; NIfTI's RAS+ world is turned into DICOM LPS.
pub fn read_nifti(path: &Path) -> Result<ScalarVolume> {
    let file_bytes = read_file(path)?;
    let bytes = if file_bytes.starts_with(&[0x1f, 0x8b]) {
        inflate_nifti(path, &file_bytes)?
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
        return Err(ImagingError::UnsupportedVolume {
            file: path.to_owned(),
            what: "NIfTI magic (only single-file n+1 is read)".into(),
        });
    }
    let ndim = i16_at(40);
    if !(3..=4).contains(&ndim) || (ndim == 4 && i16_at(48) > 1) {
        return Err(ImagingError::UnsupportedVolume {
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
    let count = limits::checked_voxels(&dims.map(|d| d as u64))
        .map_err(|e| bad(path, format!("dim: {e}")))?;
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
            return Err(ImagingError::UnsupportedVolume {
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
    let start = vox_offset as usize;
    let data = bytes.get(start..).unwrap_or(&[]);
    let values = decode_voxels(path, data, count, element, big_endian, slope, intercept)?;
    ScalarVolume::new(dims, spacing * unit_m, origin * unit_m, direction, values)
        .map_err(|e| bad(path, e.to_string()))
}
