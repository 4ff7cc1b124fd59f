//! Wavefront OBJ surfaces: `v` and `f` records (polygons fan-triangulated, `v/vt/vn` and
//! negative indices accepted); everything else is ignored. Export writes `v` and `f` only.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::Point3;

use super::{LengthUnit, check_plausible_extent, parse_xyz, read_bytes, utf8};
use crate::error::{AnatomyError, Result};
use crate::mesh::TriangleMesh;

/// Parses OBJ text whose coordinates are in `unit`; `file` names the source in errors.
pub fn parse(bytes: &[u8], unit: LengthUnit, file: &str) -> Result<TriangleMesh> {
    let text = utf8(bytes, file)?;
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for (number, raw) in text.lines().enumerate() {
        let line = Some(number + 1);
        let mut tokens = raw.split_whitespace();
        match tokens.next() {
            Some("v") => {
                let c = parse_xyz(&mut tokens, file, line)?;
                vertices.push(Point3::from(c) * unit.metres());
            }
            Some("f") => {
                let mut corners = Vec::with_capacity(4);
                for token in tokens {
                    let index_text = token.split('/').next().unwrap_or("");
                    let index: i64 = index_text.parse().map_err(|_| AnatomyError::Parse {
                        file: file.to_owned(),
                        line,
                        message: format!("face index {token:?} is not an integer"),
                    })?;
                    let resolved = if index > 0 {
                        index - 1
                    } else {
                        vertices.len() as i64 + index
                    };
                    if index == 0 || resolved < 0 || resolved >= vertices.len() as i64 {
                        return Err(AnatomyError::Parse {
                            file: file.to_owned(),
                            line,
                            message: format!(
                                "face index {index} out of range ({} vertices so far)",
                                vertices.len()
                            ),
                        });
                    }
                    corners.push(resolved as u32);
                }
                if corners.len() < 3 {
                    return Err(AnatomyError::Parse {
                        file: file.to_owned(),
                        line,
                        message: format!(
                            "face with {} vertices (at least 3 needed)",
                            corners.len()
                        ),
                    });
                }
                for k in 1..corners.len() - 1 {
                    triangles.push([corners[0], corners[k], corners[k + 1]]);
                }
            }
            _ => {}
        }
    }
    if vertices.is_empty() || triangles.is_empty() {
        return Err(AnatomyError::Empty {
            file: file.to_owned(),
            message: format!("{} vertices and {} faces", vertices.len(), triangles.len()),
        });
    }
    let mesh = TriangleMesh::new(vertices, triangles, file)?;
    let (lo, hi) = mesh.bounding_box();
    check_plausible_extent(file, unit, (hi - lo).amax())?;
    Ok(mesh)
}

/// Loads an OBJ file whose coordinates are in `unit`.
pub fn load(path: &Path, unit: LengthUnit) -> Result<TriangleMesh> {
    parse(&read_bytes(path)?, unit, &path.display().to_string())
}

/// OBJ text of `mesh` with coordinates written in `unit`.
pub fn to_string(mesh: &TriangleMesh, unit: LengthUnit) -> String {
    let mut out = String::with_capacity(mesh.vertices.len() * 40 + mesh.triangles.len() * 24);
    let _ = writeln!(out, "# cathlab lumen surface, units: {unit:?}");
    let scale = 1.0 / unit.metres();
    for p in &mesh.vertices {
        let _ = writeln!(out, "v {} {} {}", p.x * scale, p.y * scale, p.z * scale);
    }
    for t in &mesh.triangles {
        let _ = writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    out
}
