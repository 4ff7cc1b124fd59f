//! VTK XML PolyData (`.vtp`): points, polygons (fan-triangulated) and lines (centerlines
//! with an optional per-point radius array, as VMTK writes them). Data arrays in `ascii`,
//! inline `binary` (base64) or `appended` (raw or base64) format, UInt32 or UInt64 headers,
//! uncompressed or zlib-compressed (VTK's and ParaView's defaults); LZ4 and LZMA are refused
//! by name.

use std::path::Path;

use base64::Engine as _;
use nalgebra::Point3;

use super::slicer::Centerline;
use super::{LengthUnit, check_plausible_extent, parse_error, read_bytes, utf8};
use crate::error::{AnatomyError, Result};
use crate::mesh::TriangleMesh;

/// Point-data array names read as the lumen radius, in order of preference.
pub const RADIUS_ARRAY_NAMES: [&str; 3] = ["MaximumInscribedSphereRadius", "Radius", "radius"];

/// What a `.vtp` file held.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PolyData {
    /// The polygons as a triangle surface, if there were any.
    pub surface: Option<TriangleMesh>,
    /// Each polyline with its radius array (empty radii when the file has none).
    pub lines: Vec<Centerline>,
}

/// What one file's arrays may still take (bytes): what its blocks inflate to and the f64
/// values decoded from them are both charged, so that neither a compression bomb nor many
/// arrays (a 1-byte type decodes to 8) passes [`super::limits::ReadLimits::max_inflated_bytes`].
struct Budget(std::cell::Cell<u64>);

impl Budget {
    fn new() -> Self {
        Self(std::cell::Cell::new(
            super::limits::read_limits().max_inflated_bytes,
        ))
    }

    /// Takes `bytes` from the budget, or names the array that would pass it.
    fn charge(&self, bytes: u64, name: &str, file: &str) -> Result<()> {
        let left = self.0.get();
        if bytes > left {
            return Err(parse_error(
                file,
                format!(
                    "array {name}: {}{bytes} bytes would pass the {} a file's arrays may take \
                     (max_inflated_bytes)",
                    super::limits::REFUSED,
                    super::limits::read_limits().max_inflated_bytes
                ),
            ));
        }
        self.0.set(left - bytes);
        Ok(())
    }

    fn left(&self) -> u64 {
        self.0.get()
    }
}

/// How a file's binary arrays are stored: header word width, compression, appended data.
#[derive(Clone, Copy)]
struct Encoding<'a> {
    /// Header words are UInt64 (else UInt32).
    header_u64: bool,
    /// Blocks are zlib-compressed (`compressor="vtkZLibDataCompressor"`).
    zlib: bool,
    /// The `<AppendedData>` section: its bytes after the `_` marker, and whether they are
    /// base64 text (else raw).
    appended: Appended<'a>,
    /// What this file's arrays may still take.
    budget: &'a Budget,
}

/// The bytes of an `<AppendedData>` section after its `_` marker, and whether they are base64.
type Appended<'a> = Option<(&'a [u8], bool)>;

/// Decodes base64 four characters at a time, so that separately padded blocks (VTK encodes a
/// header and its data apart) decode as one stream; whitespace is skipped.
fn base64_groups(text: &[u8], name: &str, file: &str) -> Result<Vec<u8>> {
    let mut out = Vec::with_capacity(text.len() / 4 * 3);
    let mut group = Vec::with_capacity(4);
    for &c in text.iter().filter(|c| !c.is_ascii_whitespace()) {
        group.push(c);
        if group.len() == 4 {
            let decoded = base64::engine::general_purpose::STANDARD
                .decode(&group)
                .map_err(|e| parse_error(file, format!("array {name}: bad base64: {e}")))?;
            out.extend_from_slice(&decoded);
            group.clear();
        }
    }
    if !group.is_empty() {
        return Err(parse_error(
            file,
            format!("array {name}: base64 text ends mid-group"),
        ));
    }
    Ok(out)
}

/// The data bytes of one binary block (VTK's layout: a header of UInt32 or UInt64 words, then
/// the data, raw or as zlib-compressed blocks) at the start of `bytes`.
/// `width` is the array's value size (bytes): the block is charged to the file's budget with
/// the f64 values it will decode to, before anything is inflated.
fn block_data(
    bytes: &[u8],
    enc: &Encoding<'_>,
    width: usize,
    name: &str,
    file: &str,
) -> Result<Vec<u8>> {
    let with_values = |n: usize| (n as u64).saturating_add(((n / width) as u64).saturating_mul(8));
    let width = if enc.header_u64 { 8 } else { 4 };
    let truncated = || parse_error(file, format!("array {name}: truncated binary block"));
    let word = |i: usize| -> Result<usize> {
        let w = bytes
            .get(i * width..(i + 1) * width)
            .ok_or_else(truncated)?;
        let value = if enc.header_u64 {
            u64::from_le_bytes(w.try_into().unwrap_or([0; 8]))
        } else {
            u64::from(u32::from_le_bytes(w.try_into().unwrap_or([0; 4])))
        };
        usize::try_from(value).map_err(|_| truncated())
    };
    if !enc.zlib {
        let declared = word(0)?;
        enc.budget.charge(with_values(declared), name, file)?;
        return width
            .checked_add(declared)
            .and_then(|end| bytes.get(width..end))
            .map(<[u8]>::to_vec)
            .ok_or_else(|| {
                parse_error(
                    file,
                    format!(
                        "array {name}: truncated ({declared} bytes declared, {} present)",
                        bytes.len().saturating_sub(width)
                    ),
                )
            });
    }
    let blocks = word(0)?;
    let block_size = word(1)?;
    let last_size = word(2)?;
    let full = if blocks == 0 {
        0
    } else {
        (blocks - 1)
            .checked_mul(block_size)
            .and_then(|n| {
                n.checked_add(if last_size == 0 {
                    block_size
                } else {
                    last_size
                })
            })
            .filter(|&n| with_values(n) <= enc.budget.left())
            .ok_or_else(|| {
                parse_error(
                    file,
                    format!(
                        "array {name}: {}{blocks} blocks of {block_size} bytes would pass the \
                         {} bytes a file's arrays may take (max_inflated_bytes)",
                        super::limits::REFUSED,
                        super::limits::read_limits().max_inflated_bytes
                    ),
                )
            })?
    };
    enc.budget.charge(with_values(full), name, file)?;
    let mut at = width
        .checked_mul(blocks.checked_add(3).ok_or_else(truncated)?)
        .ok_or_else(truncated)?;
    // Grown as blocks inflate (each to its declared size at most), never reserved from the
    // header's word.
    let mut out = Vec::new();
    for b in 0..blocks {
        let size = word(3 + b)?;
        let compressed = bytes
            .get(at..at.checked_add(size).ok_or_else(truncated)?)
            .ok_or_else(truncated)?;
        at += size;
        let expected = if b + 1 == blocks && last_size != 0 {
            last_size
        } else {
            block_size
        };
        let before = out.len();
        use std::io::Read as _;
        flate2::read::ZlibDecoder::new(compressed)
            .take(expected as u64 + 1)
            .read_to_end(&mut out)
            .map_err(|e| parse_error(file, format!("array {name}: block {b}: zlib: {e}")))?;
        if out.len() - before != expected {
            return Err(parse_error(
                file,
                format!(
                    "array {name}: {}block {b} inflates to {} bytes, the header says {expected}",
                    super::limits::REFUSED,
                    out.len() - before
                ),
            ));
        }
    }
    Ok(out)
}

/// Reads one `<DataArray>` as f64 values.
fn read_array(node: roxmltree::Node<'_, '_>, enc: &Encoding<'_>, file: &str) -> Result<Vec<f64>> {
    let name = node.attribute("Name").unwrap_or("(unnamed)");
    let kind = node.attribute("type").unwrap_or("Float32");
    let format = node.attribute("format").unwrap_or("ascii");
    // The array's own text, around child elements such as VTK's <InformationKey>.
    let text: String = node
        .children()
        .filter(|c| c.is_text())
        .filter_map(|c| c.text())
        .collect();
    let width = match kind {
        "Float32" | "Int32" | "UInt32" => Some(4),
        "Float64" | "Int64" | "UInt64" => Some(8),
        "Int8" | "UInt8" => Some(1),
        "Int16" | "UInt16" => Some(2),
        _ => None,
    };
    let unsupported = || parse_error(file, format!("array {name}: unsupported type {kind}"));
    let body = match format {
        "ascii" => {
            enc.budget
                .charge(text.split_whitespace().count() as u64 * 8, name, file)?;
            return text
                .split_whitespace()
                .map(|t| {
                    t.parse::<f64>()
                        .ok()
                        .filter(|v| v.is_finite())
                        .ok_or_else(|| {
                            parse_error(file, format!("array {name}: {t:?} is not a finite number"))
                        })
                })
                .collect();
        }
        "binary" => block_data(
            &base64_groups(text.as_bytes(), name, file)?,
            enc,
            width.ok_or_else(unsupported)?,
            name,
            file,
        )?,
        "appended" => {
            let (data, base64) = enc.appended.ok_or_else(|| {
                parse_error(
                    file,
                    format!("array {name}: appended, but no <AppendedData>"),
                )
            })?;
            let offset: usize = node
                .attribute("offset")
                .and_then(|o| o.trim().parse().ok())
                .filter(|&o| o <= data.len())
                .ok_or_else(|| parse_error(file, format!("array {name}: missing or bad offset")))?;
            if base64 {
                block_data(
                    &base64_groups(&data[offset..], name, file)?,
                    enc,
                    width.ok_or_else(unsupported)?,
                    name,
                    file,
                )?
            } else {
                block_data(
                    &data[offset..],
                    enc,
                    width.ok_or_else(unsupported)?,
                    name,
                    file,
                )?
            }
        }
        other => {
            return Err(parse_error(
                file,
                format!("array {name}: unknown format {other:?}"),
            ));
        }
    };
    let width = width.ok_or_else(unsupported)?;
    if body.len() % width != 0 {
        return Err(parse_error(
            file,
            format!(
                "array {name}: {} bytes is not a whole number of {kind}",
                body.len()
            ),
        ));
    }
    body.chunks_exact(width)
        .map(|c| {
            let v = match kind {
                "Float32" => f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
                "Int32" => f64::from(i32::from_le_bytes([c[0], c[1], c[2], c[3]])),
                "UInt32" => f64::from(u32::from_le_bytes([c[0], c[1], c[2], c[3]])),
                "Float64" => f64::from_le_bytes(c.try_into().unwrap_or([0; 8])),
                "Int64" => i64::from_le_bytes(c.try_into().unwrap_or([0; 8])) as f64,
                "UInt64" => u64::from_le_bytes(c.try_into().unwrap_or([0; 8])) as f64,
                "Int8" => f64::from(c[0] as i8),
                "UInt8" => f64::from(c[0]),
                "Int16" => f64::from(i16::from_le_bytes([c[0], c[1]])),
                _ => f64::from(u16::from_le_bytes([c[0], c[1]])),
            };
            if v.is_finite() {
                Ok(v)
            } else {
                Err(parse_error(file, format!("array {name}: non-finite value")))
            }
        })
        .collect()
}

/// Splits a file at its `<AppendedData>` section (whose raw bytes need not be text): the XML
/// before it, closed again, and the section's bytes after the `_` marker with whether they
/// are base64.
fn split_appended<'a>(bytes: &'a [u8], file: &str) -> Result<(Vec<u8>, Appended<'a>)> {
    let find = |hay: &[u8], needle: &[u8]| hay.windows(needle.len()).position(|w| w == needle);
    let Some(start) = find(bytes, b"<AppendedData") else {
        return Ok((bytes.to_vec(), None));
    };
    let tag_end = start
        + find(&bytes[start..], b">")
            .ok_or_else(|| parse_error(file, "<AppendedData> tag is not closed"))?;
    let tag = String::from_utf8_lossy(&bytes[start..tag_end]);
    let base64 = !tag.contains("\"raw\"");
    let marker = tag_end
        + find(&bytes[tag_end..], b"_")
            .ok_or_else(|| parse_error(file, "<AppendedData> has no '_' marker"))?;
    let end = bytes
        .windows(b"</AppendedData>".len())
        .rposition(|w| w == b"</AppendedData>")
        .filter(|&e| e > marker)
        .unwrap_or(bytes.len());
    let mut xml = bytes[..start].to_vec();
    xml.extend_from_slice(b"</VTKFile>");
    Ok((xml, Some((&bytes[marker + 1..end], base64))))
}

fn child<'a, 'i>(node: roxmltree::Node<'a, 'i>, tag: &str) -> Option<roxmltree::Node<'a, 'i>> {
    node.children().find(|c| c.has_tag_name(tag))
}

fn named_array<'a, 'i>(
    node: roxmltree::Node<'a, 'i>,
    name: &str,
) -> Option<roxmltree::Node<'a, 'i>> {
    node.children()
        .find(|c| c.has_tag_name("DataArray") && c.attribute("Name") == Some(name))
}

/// Splits a VTK cell array (connectivity + offsets) into cells with valid point indices.
fn cells(
    section: roxmltree::Node<'_, '_>,
    enc: &Encoding<'_>,
    points: usize,
    what: &str,
    file: &str,
) -> Result<Vec<Vec<u32>>> {
    let connectivity = named_array(section, "connectivity")
        .ok_or_else(|| parse_error(file, format!("{what}: no connectivity array")))?;
    let offsets = named_array(section, "offsets")
        .ok_or_else(|| parse_error(file, format!("{what}: no offsets array")))?;
    let connectivity = read_array(connectivity, enc, file)?;
    let offsets = read_array(offsets, enc, file)?;
    let mut out = Vec::with_capacity(offsets.len());
    let mut begin = 0usize;
    for (c, &end) in offsets.iter().enumerate() {
        if end.fract() != 0.0 || end < begin as f64 || end > connectivity.len() as f64 {
            return Err(parse_error(
                file,
                format!("{what}: offset {c} = {end} is out of range"),
            ));
        }
        let end = end as usize;
        let mut cell = Vec::with_capacity(end - begin);
        for &i in &connectivity[begin..end] {
            if i.fract() != 0.0 || i < 0.0 || i >= points as f64 {
                return Err(parse_error(
                    file,
                    format!("{what}: cell {c} refers to point {i} of {points}"),
                ));
            }
            cell.push(i as u32);
        }
        out.push(cell);
        begin = end;
    }
    Ok(out)
}

/// Parses a PolyData document whose coordinates are in `unit`.
pub fn parse(bytes: &[u8], unit: LengthUnit, file: &str) -> Result<PolyData> {
    let (xml, appended) = split_appended(bytes, file)?;
    let text = utf8(&xml, file)?;
    let doc = roxmltree::Document::parse(text).map_err(|e| AnatomyError::Parse {
        file: file.to_owned(),
        line: Some(e.pos().row as usize),
        message: format!("not well-formed XML: {e}"),
    })?;
    let root = doc.root_element();
    if !root.has_tag_name("VTKFile") || root.attribute("type") != Some("PolyData") {
        return Err(parse_error(file, "not a VTKFile of type PolyData"));
    }
    let zlib = match root.attribute("compressor") {
        None => false,
        Some("vtkZLibDataCompressor") => true,
        Some(c) => {
            return Err(parse_error(
                file,
                format!(
                    "compressor {c} is not supported; save uncompressed or with zlib \
                     (vtkZLibDataCompressor)"
                ),
            ));
        }
    };
    let budget = Budget::new();
    let enc = Encoding {
        header_u64: root.attribute("header_type") == Some("UInt64"),
        zlib,
        appended,
        budget: &budget,
    };
    let piece = child(root, "PolyData")
        .and_then(|p| child(p, "Piece"))
        .ok_or_else(|| parse_error(file, "no PolyData/Piece element"))?;
    let points_node = child(piece, "Points")
        .and_then(|p| child(p, "DataArray"))
        .ok_or_else(|| parse_error(file, "no Points/DataArray"))?;
    let flat = read_array(points_node, &enc, file)?;
    if flat.len() % 3 != 0 || flat.is_empty() {
        return Err(AnatomyError::Empty {
            file: file.to_owned(),
            message: format!(
                "{} point coordinates (need a positive multiple of 3)",
                flat.len()
            ),
        });
    }
    let points: Vec<Point3<f64>> = flat
        .chunks_exact(3)
        .map(|c| Point3::new(c[0], c[1], c[2]) * unit.metres())
        .collect();
    let (lo, hi) = points
        .iter()
        .fold((points[0], points[0]), |(lo, hi), p| (lo.inf(p), hi.sup(p)));
    check_plausible_extent(file, unit, (hi - lo).amax())?;
    let mut data = PolyData::default();
    if let Some(polys) = child(piece, "Polys") {
        let mut triangles = Vec::new();
        for (c, cell) in cells(polys, &enc, points.len(), "Polys", file)?
            .iter()
            .enumerate()
        {
            if cell.len() < 3 {
                return Err(parse_error(
                    file,
                    format!("Polys: polygon {c} has {} points", cell.len()),
                ));
            }
            for k in 1..cell.len() - 1 {
                triangles.push([cell[0], cell[k], cell[k + 1]]);
            }
        }
        if !triangles.is_empty() {
            data.surface = Some(TriangleMesh::new(points.clone(), triangles, file)?);
        }
    }
    if let Some(lines) = child(piece, "Lines") {
        let radius = child(piece, "PointData").and_then(|pd| {
            RADIUS_ARRAY_NAMES
                .iter()
                .find_map(|name| named_array(pd, name))
        });
        let radius = match radius {
            Some(node) => {
                let values = read_array(node, &enc, file)?;
                if values.len() != points.len() {
                    return Err(parse_error(
                        file,
                        format!(
                            "radius array has {} values for {} points",
                            values.len(),
                            points.len()
                        ),
                    ));
                }
                if let Some(v) = values.iter().find(|v| **v <= 0.0) {
                    return Err(parse_error(file, format!("radius {v} is not positive")));
                }
                values.iter().map(|r| r * unit.metres()).collect()
            }
            None => Vec::new(),
        };
        for (c, cell) in cells(lines, &enc, points.len(), "Lines", file)?
            .iter()
            .enumerate()
        {
            if cell.len() < 2 {
                return Err(parse_error(
                    file,
                    format!("Lines: line {c} has {} points", cell.len()),
                ));
            }
            data.lines.push(Centerline {
                name: format!("line_{c}"),
                points: cell.iter().map(|&i| points[i as usize]).collect(),
                radii: if radius.is_empty() {
                    Vec::new()
                } else {
                    cell.iter().map(|&i| radius[i as usize]).collect()
                },
            });
        }
    }
    if data.surface.is_none() && data.lines.is_empty() {
        return Err(AnatomyError::Empty {
            file: file.to_owned(),
            message: "no polygons and no lines".into(),
        });
    }
    Ok(data)
}

/// Loads a `.vtp` file whose coordinates are in `unit`.
pub fn load(path: &Path, unit: LengthUnit) -> Result<PolyData> {
    parse(&read_bytes(path)?, unit, &path.display().to_string())
}

/// VTK XML PolyData text (ASCII arrays, coordinates in `unit`) holding `surface`'s triangles
/// as polygons and each of `lines` as a polyline with a `Radius` point array (in `unit`;
/// written only when there is no surface, whose points have no radius). The inverse of
/// [`parse`].
pub fn to_string(surface: Option<&TriangleMesh>, lines: &[Centerline], unit: LengthUnit) -> String {
    use std::fmt::Write as _;
    let scale = 1.0 / unit.metres();
    let surface_points = surface.map_or(0, |m| m.vertices.len());
    let line_points: usize = lines.iter().map(|l| l.points.len()).sum();
    let triangles = surface.map_or(0, |m| m.triangles.len());
    let mut out = String::new();
    let _ = writeln!(
        out,
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\">\n<PolyData>\n<Piece NumberOfPoints=\"{}\" NumberOfVerts=\"0\" NumberOfLines=\"{}\" NumberOfStrips=\"0\" NumberOfPolys=\"{}\">",
        surface_points + line_points,
        lines.len(),
        triangles
    );
    if surface.is_none() {
        out.push_str("<PointData Scalars=\"Radius\">\n<DataArray type=\"Float64\" Name=\"Radius\" format=\"ascii\">\n");
        for l in lines {
            for r in &l.radii {
                let _ = write!(out, "{} ", r * scale);
            }
        }
        out.push_str("\n</DataArray>\n</PointData>\n");
    }
    out.push_str(
        "<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n",
    );
    let mut point = |p: &Point3<f64>| {
        let _ = writeln!(out, "{} {} {}", p.x * scale, p.y * scale, p.z * scale);
    };
    if let Some(m) = surface {
        m.vertices.iter().for_each(&mut point);
    }
    for l in lines {
        l.points.iter().for_each(&mut point);
    }
    out.push_str("</DataArray>\n</Points>\n");
    let cells = |out: &mut String, tag: &str, groups: Vec<Vec<usize>>| {
        let _ = writeln!(
            out,
            "<{tag}>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">"
        );
        for g in &groups {
            for i in g {
                let _ = write!(out, "{i} ");
            }
        }
        out.push_str(
            "\n</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n",
        );
        let mut end = 0;
        for g in &groups {
            end += g.len();
            let _ = write!(out, "{end} ");
        }
        let _ = writeln!(out, "\n</DataArray>\n</{tag}>");
    };
    let mut first = surface_points;
    let line_groups = lines
        .iter()
        .map(|l| {
            let g: Vec<usize> = (first..first + l.points.len()).collect();
            first += l.points.len();
            g
        })
        .collect();
    cells(&mut out, "Lines", line_groups);
    let polys = surface.map_or_else(Vec::new, |m| {
        m.triangles
            .iter()
            .map(|t| t.iter().map(|&i| i as usize).collect())
            .collect()
    });
    cells(&mut out, "Polys", polys);
    out.push_str("</Piece>\n</PolyData>\n</VTKFile>\n");
    out
}
