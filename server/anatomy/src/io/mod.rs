//! Anatomy file formats: surfaces (OBJ, STL, PLY, VTK PolyData), centerlines (3D Slicer markups,
//! SWC) and the JSON vessel graph; units, and loading by file extension.

pub mod limits;
pub mod obj;
pub mod ply;
pub mod slicer;
pub mod stl;
pub mod swc;
pub mod vtp;

use std::path::Path;

use crate::error::{AnatomyError, Result};

/// A length unit that a file declares or that the caller assumes for it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LengthUnit {
    /// Metres.
    M,
    /// Centimetres.
    Cm,
    /// Millimetres (medical imaging's default).
    Mm,
    /// Micrometres (common in SWC morphology files).
    Um,
}

impl LengthUnit {
    /// Metres per unit.
    pub fn metres(self) -> f64 {
        match self {
            LengthUnit::M => 1.0,
            LengthUnit::Cm => 1e-2,
            LengthUnit::Mm => 1e-3,
            LengthUnit::Um => 1e-6,
        }
    }

    /// Parses a unit name as files spell it ("mm", "cm", "m", "um", "µm", "micron").
    pub fn parse(name: &str, file: &str) -> Result<Self> {
        match name.trim().to_ascii_lowercase().as_str() {
            "m" | "meter" | "metre" | "meters" | "metres" => Ok(LengthUnit::M),
            "cm" | "centimeter" | "centimetre" => Ok(LengthUnit::Cm),
            "mm" | "millimeter" | "millimetre" => Ok(LengthUnit::Mm),
            "um" | "µm" | "micron" | "microns" | "micrometer" | "micrometre" => Ok(LengthUnit::Um),
            other => Err(AnatomyError::Units {
                file: file.to_owned(),
                message: format!("unknown length unit {other:?} (expected m, cm, mm or um)"),
            }),
        }
    }
}

/// Largest and smallest plausible extents of a vascular anatomy (m).
const PLAUSIBLE_EXTENT_M: (f64, f64) = (1e-3, 2.5);

/// Fails when the anatomy's largest extent (already in metres) is implausible, which is how a
/// wrong declared unit shows (a 400 mm arch read as metres spans 400 m).
pub fn check_plausible_extent(file: &str, unit: LengthUnit, extent_m: f64) -> Result<()> {
    let (lo, hi) = PLAUSIBLE_EXTENT_M;
    if extent_m.is_finite() && (lo..=hi).contains(&extent_m) {
        return Ok(());
    }
    Err(AnatomyError::Units {
        file: file.to_owned(),
        message: format!(
            "with unit {unit:?} the anatomy spans {extent_m:.3e} m; vascular anatomy spans \
             {lo} m to {hi} m, so the declared or assumed unit is wrong"
        ),
    })
}

/// Loads a surface, choosing the format by extension: `.obj`, `.stl`, `.ply`, `.vtp` (its
/// polygons).
pub fn load_surface(path: &Path, unit: LengthUnit) -> Result<crate::mesh::TriangleMesh> {
    let name = path.to_string_lossy().to_ascii_lowercase();
    let shown = path.display().to_string();
    if name.ends_with(".obj") {
        obj::load(path, unit)
    } else if name.ends_with(".stl") {
        stl::load(path, unit)
    } else if name.ends_with(".ply") {
        ply::load(path, unit)
    } else if name.ends_with(".vtp") {
        vtp::load(path, unit)?
            .surface
            .ok_or_else(|| AnatomyError::Empty {
                file: shown,
                message: "no polygons (a surface is needed, not only lines)".into(),
            })
    } else {
        Err(AnatomyError::Parse {
            file: shown,
            line: None,
            message: "unknown surface format (expected .obj, .stl, .ply or .vtp)".into(),
        })
    }
}

/// Reads a whole regular file within [`limits::read_limits`], mapping failure to
/// [`AnatomyError::Io`].
pub(crate) fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    limits::read_regular_file(path).map_err(|source| AnatomyError::Io {
        file: path.to_owned(),
        source,
    })
}

/// Parses one finite float, naming the file, line and field on failure.
pub(crate) fn parse_f64(token: &str, file: &str, line: Option<usize>, what: &str) -> Result<f64> {
    let value: f64 = token.parse().map_err(|_| AnatomyError::Parse {
        file: file.to_owned(),
        line,
        message: format!("{what}: {token:?} is not a number"),
    })?;
    if !value.is_finite() {
        return Err(AnatomyError::Parse {
            file: file.to_owned(),
            line,
            message: format!("{what} is {token} (not finite)"),
        });
    }
    Ok(value)
}

/// A parse error for the whole file (no line number).
pub(crate) fn parse_error(file: &str, message: impl Into<String>) -> AnatomyError {
    AnatomyError::Parse {
        file: file.to_owned(),
        line: None,
        message: message.into(),
    }
}

/// Parses the next three tokens as finite x, y, z coordinates.
pub(crate) fn parse_xyz<'t>(
    tokens: &mut impl Iterator<Item = &'t str>,
    file: &str,
    line: Option<usize>,
) -> Result<[f64; 3]> {
    let mut c = [0.0; 3];
    for (k, value) in c.iter_mut().enumerate() {
        let token = tokens.next().ok_or_else(|| AnatomyError::Parse {
            file: file.to_owned(),
            line,
            message: "vertex with fewer than 3 coordinates".into(),
        })?;
        *value = parse_f64(token, file, line, ["x", "y", "z"][k])?;
    }
    Ok(c)
}

/// The file's text, or a parse error if it is not UTF-8.
pub(crate) fn utf8<'a>(bytes: &'a [u8], file: &str) -> Result<&'a str> {
    std::str::from_utf8(bytes).map_err(|e| AnatomyError::Parse {
        file: file.to_owned(),
        line: None,
        message: format!("not UTF-8 text (byte {})", e.valid_up_to()),
    })
}
