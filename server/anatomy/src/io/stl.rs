//! STL surfaces, binary and ASCII; coincident corners are welded (bit-exact) into an
//! indexed mesh. Export writes binary STL.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::Point3;

use super::{LengthUnit, check_plausible_extent, parse_xyz, read_bytes, utf8};
use crate::error::{AnatomyError, Result};
use crate::mesh::TriangleMesh;

/// Parses STL (binary when the size matches the header's triangle count, else ASCII).
pub fn parse(bytes: &[u8], unit: LengthUnit, file: &str) -> Result<TriangleMesh> {
    let corners = if is_binary(bytes) {
        parse_binary(bytes, file)?
    } else {
        parse_ascii(bytes, file)?
    };
    if corners.is_empty() {
        return Err(AnatomyError::Empty {
            file: file.to_owned(),
            message: "no facets".into(),
        });
    }
    let mut index: HashMap<[u64; 3], u32> = HashMap::new();
    let mut vertices = Vec::new();
    let mut triangles = Vec::with_capacity(corners.len() / 3);
    for facet in corners.chunks_exact(3) {
        let mut tri = [0u32; 3];
        for (k, c) in facet.iter().enumerate() {
            let key = [c[0].to_bits(), c[1].to_bits(), c[2].to_bits()];
            tri[k] = *index.entry(key).or_insert_with(|| {
                vertices.push(Point3::new(c[0], c[1], c[2]) * unit.metres());
                (vertices.len() - 1) as u32
            });
        }
        triangles.push(tri);
    }
    let mesh = TriangleMesh::new(vertices, triangles, file)?;
    let (lo, hi) = mesh.bounding_box();
    check_plausible_extent(file, unit, (hi - lo).amax())?;
    Ok(mesh)
}

/// Loads an STL file whose coordinates are in `unit`.
pub fn load(path: &Path, unit: LengthUnit) -> Result<TriangleMesh> {
    parse(&read_bytes(path)?, unit, &path.display().to_string())
}

fn is_binary(bytes: &[u8]) -> bool {
    if bytes.len() < 84 {
        return false;
    }
    let count = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64;
    84 + 50 * count == bytes.len() as u64
}

fn parse_binary(bytes: &[u8], file: &str) -> Result<Vec<[f64; 3]>> {
    let count = (bytes.len() - 84) / 50;
    let mut corners = Vec::with_capacity(count * 3);
    for f in 0..count {
        let record = &bytes[84 + 50 * f..84 + 50 * (f + 1)];
        for k in 0..3 {
            let mut c = [0.0; 3];
            for (axis, value) in c.iter_mut().enumerate() {
                let at = 12 + 12 * k + 4 * axis;
                let raw = f32::from_le_bytes([
                    record[at],
                    record[at + 1],
                    record[at + 2],
                    record[at + 3],
                ]);
                if !raw.is_finite() {
                    return Err(AnatomyError::Parse {
                        file: file.to_owned(),
                        line: None,
                        message: format!("facet {f} corner {k} has a non-finite coordinate"),
                    });
                }
                *value = f64::from(raw);
            }
            corners.push(c);
        }
    }
    Ok(corners)
}

fn parse_ascii(bytes: &[u8], file: &str) -> Result<Vec<[f64; 3]>> {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    if !bytes[start..].starts_with(b"solid") {
        let declared = (bytes.len() >= 84)
            .then(|| u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]))
            .map(|n| {
                format!(
                    " (the header declares {n} facets = {} bytes, the file has {})",
                    84 + 50 * u64::from(n),
                    bytes.len()
                )
            })
            .unwrap_or_default();
        return Err(AnatomyError::Parse {
            file: file.to_owned(),
            line: None,
            message: format!(
                "neither binary STL (truncated or padded{declared}) nor ASCII STL (no leading 'solid')"
            ),
        });
    }
    let text = utf8(bytes, file)?;
    let mut corners = Vec::new();
    let mut in_facet = 0usize;
    let mut ended = false;
    for (number, raw) in text.lines().enumerate() {
        let line = Some(number + 1);
        let mut tokens = raw.split_whitespace();
        match tokens.next() {
            Some("vertex") => {
                let c = parse_xyz(&mut tokens, file, line)?;
                corners.push(c);
                in_facet += 1;
            }
            Some("endfacet") => {
                if in_facet != 3 {
                    return Err(AnatomyError::Parse {
                        file: file.to_owned(),
                        line,
                        message: format!("facet with {in_facet} vertices (STL facets have 3)"),
                    });
                }
                in_facet = 0;
            }
            Some("endsolid") => ended = true,
            _ => {}
        }
    }
    if !ended || in_facet != 0 {
        return Err(AnatomyError::Parse {
            file: file.to_owned(),
            line: None,
            message: "truncated: no 'endsolid' after the last facet".into(),
        });
    }
    Ok(corners)
}

/// Binary STL of `mesh` with coordinates in `unit`.
pub fn to_binary(mesh: &TriangleMesh, unit: LengthUnit) -> Vec<u8> {
    let scale = 1.0 / unit.metres();
    let mut out = Vec::with_capacity(84 + 50 * mesh.triangles.len());
    let mut header = [0u8; 80];
    let title = b"cathlab lumen surface";
    header[..title.len()].copy_from_slice(title);
    out.extend_from_slice(&header);
    out.extend_from_slice(&(mesh.triangles.len() as u32).to_le_bytes());
    for t in &mesh.triangles {
        let p = mesh.corners(t);
        let n = (p[1] - p[0])
            .cross(&(p[2] - p[0]))
            .try_normalize(0.0)
            .unwrap_or_default();
        for v in [n.x, n.y, n.z] {
            out.extend_from_slice(&(v as f32).to_le_bytes());
        }
        for c in p {
            for v in [c.x, c.y, c.z] {
                out.extend_from_slice(&((v * scale) as f32).to_le_bytes());
            }
        }
        out.extend_from_slice(&[0, 0]);
    }
    out
}
