//! NIfTI-1 volumes (`.nii`, `.nii.gz`): the reader, with gzip inflated no further than the
//! header says it needs.

use std::io::Read;
use std::path::Path;

use cathlab_anatomy::io::limits;
use nalgebra::{Matrix3, Vector3};

use crate::error::{ImagingError, Result};
use crate::volume::ScalarVolume;
use crate::voxels::{Element, bad, decode_voxels, read_file};

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
