//! 3D Slicer Markups JSON (`.mrk.json`) curves with a per-point `Radius` measurement, as VMTK
//! centerline extraction in Slicer writes them; LPS or RAS coordinates, declared units.

use std::path::Path;

use nalgebra::Point3;
use serde_json::Value;

use super::{LengthUnit, check_plausible_extent, parse_error, read_bytes, utf8};
use crate::error::{AnatomyError, Result};

/// A centerline curve read from a file.
#[derive(Debug, Clone, PartialEq)]
pub struct Centerline {
    /// The curve's name (the markup's `name`, else the file stem).
    pub name: String,
    /// Points in LPS (m).
    pub points: Vec<Point3<f64>>,
    /// Lumen radius per point (m).
    pub radii: Vec<f64>,
}

/// Parses every curve markup in a Markups JSON document. `default_name` names unnamed curves.
pub fn parse(bytes: &[u8], default_name: &str, file: &str) -> Result<Vec<Centerline>> {
    let text = utf8(bytes, file)?;
    let doc: Value = serde_json::from_str(text).map_err(|e| AnatomyError::Parse {
        file: file.to_owned(),
        line: Some(e.line()),
        message: e.to_string(),
    })?;
    let markups = doc
        .get("markups")
        .and_then(Value::as_array)
        .ok_or_else(|| parse_error(file, "no \"markups\" array"))?;
    let mut curves = Vec::new();
    for (m, markup) in markups.iter().enumerate() {
        let kind = markup.get("type").and_then(Value::as_str).unwrap_or("");
        if kind != "Curve" && kind != "ClosedCurve" {
            continue;
        }
        let unit = match markup.get("coordinateUnits") {
            None => LengthUnit::Mm,
            Some(Value::String(u)) => LengthUnit::parse(u, file)?,
            Some(other) => {
                return Err(AnatomyError::Units {
                    file: file.to_owned(),
                    message: format!("markup {m}: coordinateUnits is {other}, not a string"),
                });
            }
        };
        let flip = match markup
            .get("coordinateSystem")
            .and_then(Value::as_str)
            .unwrap_or("LPS")
        {
            "LPS" => false,
            "RAS" => true,
            other => {
                return Err(parse_error(
                    file,
                    format!("markup {m}: coordinateSystem {other:?} (expected LPS or RAS)"),
                ));
            }
        };
        let points_json = markup
            .get("controlPoints")
            .and_then(Value::as_array)
            .ok_or_else(|| parse_error(file, format!("markup {m}: no controlPoints array")))?;
        let mut points = Vec::with_capacity(points_json.len());
        for (i, cp) in points_json.iter().enumerate() {
            let position = cp
                .get("position")
                .and_then(Value::as_array)
                .filter(|a| a.len() == 3)
                .ok_or_else(|| {
                    parse_error(file, format!("markup {m} point {i}: no 3-element position"))
                })?;
            let mut c = [0.0; 3];
            for (k, v) in position.iter().enumerate() {
                c[k] = v.as_f64().filter(|x| x.is_finite()).ok_or_else(|| {
                    parse_error(
                        file,
                        format!("markup {m} point {i}: coordinate {k} is {v}, not a finite number"),
                    )
                })? * unit.metres();
            }
            if flip {
                c[0] = -c[0];
                c[1] = -c[1];
            }
            points.push(Point3::from(c));
        }
        let radius_values = markup
            .get("measurements")
            .and_then(Value::as_array)
            .and_then(|ms| {
                ms.iter()
                    .find(|x| x.get("name").and_then(Value::as_str) == Some("Radius"))
            })
            .and_then(|r| r.get("controlPointValues"))
            .and_then(Value::as_array)
            .ok_or_else(|| {
                parse_error(
                    file,
                    format!("markup {m}: no \"Radius\" measurement with controlPointValues"),
                )
            })?;
        if radius_values.len() != points.len() {
            return Err(parse_error(
                file,
                format!(
                    "markup {m}: {} radius values for {} control points",
                    radius_values.len(),
                    points.len()
                ),
            ));
        }
        let mut radii = Vec::with_capacity(points.len());
        for (i, v) in radius_values.iter().enumerate() {
            let r = v
                .as_f64()
                .filter(|x| x.is_finite() && *x > 0.0)
                .ok_or_else(|| {
                    parse_error(
                        file,
                        format!("markup {m}: radius {i} is {v}, not a positive number"),
                    )
                })?;
            radii.push(r * unit.metres());
        }
        if points.len() < 2 {
            return Err(AnatomyError::Empty {
                file: file.to_owned(),
                message: format!(
                    "markup {m} has {} control points (a curve needs 2)",
                    points.len()
                ),
            });
        }
        let extent = points
            .iter()
            .map(|p| (p - points[0]).norm())
            .fold(0.0, f64::max);
        check_plausible_extent(file, unit, extent)?;
        let name = markup
            .get("name")
            .and_then(Value::as_str)
            .filter(|n| !n.is_empty())
            .unwrap_or(default_name)
            .to_owned();
        curves.push(Centerline {
            name,
            points,
            radii,
        });
    }
    if curves.is_empty() {
        return Err(AnatomyError::Empty {
            file: file.to_owned(),
            message: "no Curve markups".into(),
        });
    }
    Ok(curves)
}

/// Loads a `.mrk.json` file; unnamed curves take the file name up to the first dot.
pub fn load(path: &Path) -> Result<Vec<Centerline>> {
    let stem = path
        .file_name()
        .and_then(|n| n.to_str())
        .and_then(|n| n.split('.').next())
        .unwrap_or("curve")
        .to_owned();
    parse(&read_bytes(path)?, &stem, &path.display().to_string())
}
