//! PLY surfaces (Stanford polygon files), ASCII and binary little/big endian: the `vertex`
//! element's x, y, z and the `face` element's vertex index list (fan-triangulated); other
//! elements and properties are skipped.

use std::path::Path;

use nalgebra::Point3;

use super::{LengthUnit, check_plausible_extent, parse_error, read_bytes};
use crate::error::{AnatomyError, Result};
use crate::mesh::TriangleMesh;

/// Most vertices or faces a PLY file may declare.
pub const MAX_ELEMENTS: usize = 50_000_000;

#[derive(Clone, Copy, PartialEq)]
enum Format {
    Ascii,
    Little,
    Big,
}

#[derive(Clone, Copy, Debug)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

enum Property {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

/// A cursor over the body: tokens for ASCII, bytes for binary.
struct Body<'a> {
    format: Format,
    bytes: &'a [u8],
    at: usize,
    file: &'a str,
}

impl Body<'_> {
    fn next(&mut self, kind: Scalar) -> Result<f64> {
        if self.format == Format::Ascii {
            let rest = &self.bytes[self.at..];
            let start = rest
                .iter()
                .position(|b| !b.is_ascii_whitespace())
                .ok_or_else(|| parse_error(self.file, "PLY body ends early"))?;
            let len = rest[start..]
                .iter()
                .position(u8::is_ascii_whitespace)
                .unwrap_or(rest.len() - start);
            self.at += start + len;
            let token = std::str::from_utf8(&rest[start..start + len]).unwrap_or("?");
            return token
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| parse_error(self.file, format!("PLY: {token:?} is not a number")));
        }
        let n = kind.size();
        let raw = self
            .bytes
            .get(self.at..self.at + n)
            .ok_or_else(|| parse_error(self.file, "PLY body ends early"))?;
        self.at += n;
        let mut b = [0u8; 8];
        b[..n].copy_from_slice(raw);
        if self.format == Format::Big {
            b[..n].reverse();
        }
        let v = match kind {
            Scalar::I8 => f64::from(b[0] as i8),
            Scalar::U8 => f64::from(b[0]),
            Scalar::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            Scalar::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            Scalar::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::F64 => f64::from_le_bytes(b),
        };
        if v.is_finite() {
            Ok(v)
        } else {
            Err(parse_error(self.file, "PLY: a non-finite value"))
        }
    }
}

fn header(bytes: &[u8], file: &str) -> Result<(Format, Vec<Element>, usize)> {
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or_else(|| parse_error(file, "not a PLY file: no end_header"))?;
    let body = end
        + 10
        + bytes[end + 10..]
            .iter()
            .position(|&b| b == b'\n')
            .map(|p| p + 1)
            .unwrap_or(0);
    let text = String::from_utf8_lossy(&bytes[..end]);
    let mut lines = text.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(parse_error(
            file,
            "not a PLY file: the first line is not `ply`",
        ));
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (n, line) in lines.enumerate() {
        let words: Vec<&str> = line.split_whitespace().collect();
        let bad = |what: &str| AnatomyError::Parse {
            file: file.to_owned(),
            line: Some(n + 2),
            message: what.to_owned(),
        };
        match words.as_slice() {
            ["format", f, ..] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::Little,
                    "binary_big_endian" => Format::Big,
                    other => return Err(bad(&format!("unknown PLY format {other:?}"))),
                })
            }
            ["element", name, count] => {
                let count: usize = count
                    .parse()
                    .ok()
                    .filter(|&c| c <= MAX_ELEMENTS)
                    .ok_or_else(|| {
                        bad(&format!("element count {count:?} (at most {MAX_ELEMENTS})"))
                    })?;
                elements.push(Element {
                    name: (*name).to_owned(),
                    count,
                    properties: Vec::new(),
                });
            }
            ["property", "list", count, item, name] => {
                let (Some(c), Some(i)) = (Scalar::parse(count), Scalar::parse(item)) else {
                    return Err(bad("unknown list property type"));
                };
                elements
                    .last_mut()
                    .ok_or_else(|| bad("property before any element"))?
                    .properties
                    .push(Property::List((*name).to_owned(), c, i));
            }
            ["property", kind, name] => {
                let kind = Scalar::parse(kind)
                    .ok_or_else(|| bad(&format!("unknown property type {kind:?}")))?;
                elements
                    .last_mut()
                    .ok_or_else(|| bad("property before any element"))?
                    .properties
                    .push(Property::Scalar((*name).to_owned(), kind));
            }
            _ => {} // comment, obj_info, blank
        }
    }
    let format = format.ok_or_else(|| parse_error(file, "PLY header has no format line"))?;
    Ok((format, elements, body))
}

/// Parses a PLY surface whose coordinates are in `unit`.
pub fn parse(bytes: &[u8], unit: LengthUnit, file: &str) -> Result<TriangleMesh> {
    let (format, elements, start) = header(bytes, file)?;
    let mut body = Body {
        format,
        bytes,
        at: start,
        file,
    };
    let mut vertices: Vec<Point3<f64>> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    for element in &elements {
        let is_vertex = element.name == "vertex";
        let is_face = element.name == "face";
        let position = |name: &str| {
            element
                .properties
                .iter()
                .position(|p| matches!(p, Property::Scalar(n, _) if n == name))
        };
        let xyz = [position("x"), position("y"), position("z")];
        if is_vertex && xyz.iter().any(Option::is_none) {
            return Err(parse_error(file, "PLY vertex element lacks x, y or z"));
        }
        for row in 0..element.count {
            let mut point = [0.0; 3];
            for (p, property) in element.properties.iter().enumerate() {
                match property {
                    Property::Scalar(_, kind) => {
                        let v = body.next(*kind)?;
                        if let Some(axis) = xyz.iter().position(|&a| a == Some(p)) {
                            point[axis] = v;
                        }
                    }
                    Property::List(name, count, item) => {
                        let n = body.next(*count)?;
                        if !(0.0..=1024.0).contains(&n) {
                            return Err(parse_error(
                                file,
                                format!("PLY {} {row}: a list of {n} items", element.name),
                            ));
                        }
                        let mut items = Vec::with_capacity(n as usize);
                        for _ in 0..n as usize {
                            items.push(body.next(*item)?);
                        }
                        if is_face && (name == "vertex_indices" || name == "vertex_index") {
                            if items.len() < 3 {
                                return Err(parse_error(
                                    file,
                                    format!("PLY face {row} has {} vertices", items.len()),
                                ));
                            }
                            let index = |v: f64| -> Result<u32> {
                                if v < 0.0 || v.fract() != 0.0 || v > f64::from(u32::MAX) {
                                    return Err(parse_error(
                                        file,
                                        format!("PLY face {row}: bad vertex index {v}"),
                                    ));
                                }
                                Ok(v as u32)
                            };
                            for k in 1..items.len() - 1 {
                                triangles.push([
                                    index(items[0])?,
                                    index(items[k])?,
                                    index(items[k + 1])?,
                                ]);
                            }
                        }
                    }
                }
            }
            if is_vertex {
                vertices.push(Point3::from(point) * unit.metres());
            }
        }
    }
    if triangles.is_empty() {
        return Err(AnatomyError::Empty {
            file: file.to_owned(),
            message: "no faces".into(),
        });
    }
    let mesh = TriangleMesh::new(vertices, triangles, file)?;
    let (lo, hi) = mesh.bounding_box();
    check_plausible_extent(file, unit, (hi - lo).amax())?;
    Ok(mesh)
}

/// Loads a PLY file whose coordinates are in `unit`.
pub fn load(path: &Path, unit: LengthUnit) -> Result<TriangleMesh> {
    parse(&read_bytes(path)?, unit, &path.display().to_string())
}
