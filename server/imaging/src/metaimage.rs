//! MetaImage volumes (`.mha` with the data inline, `.mhd` with a separate data file), raw or
//! zlib-compressed: the reader and the writer.

use std::path::{Path, PathBuf};

use cathlab_anatomy::io::limits;
use nalgebra::{Matrix3, Vector3};

use crate::error::{ImagingError, Result};
use crate::volume::ScalarVolume;
use crate::voxels::{Element, bad, decode_voxels, read_file};

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

impl ScalarVolume {
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
