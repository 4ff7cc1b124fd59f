//! Voxel bytes shared by the MetaImage and NIfTI readers: reading a file within the
//! configured limits, element types and their decoding with slope and intercept, the
//! readers' error.

use std::path::Path;

use crate::error::{ImagingError, Result};

pub(crate) fn bad(file: &Path, reason: impl Into<String>) -> ImagingError {
    ImagingError::BadVolume {
        file: file.to_owned(),
        reason: reason.into(),
    }
}

pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>> {
    cathlab_anatomy::io::limits::read_regular_file(path).map_err(|source| ImagingError::Io {
        file: path.to_owned(),
        source,
    })
}

/// Element types of MetaImage and NIfTI voxels.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Element {
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
    pub(crate) fn size(self) -> usize {
        match self {
            Element::U8 | Element::I8 => 1,
            Element::U16 | Element::I16 => 2,
            Element::U32 | Element::I32 | Element::F32 => 4,
            Element::F64 => 8,
        }
    }

    pub(crate) fn decode(self, bytes: &[u8], big_endian: bool) -> f64 {
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
pub(crate) fn decode_voxels(
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
