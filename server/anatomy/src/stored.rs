//! The stored form of a built anatomy (its vessel graph, lumen surface and query grid) as
//! bytes, for the server's disk cache of built assets: a damaged, truncated or foreign file
//! is refused with the reason, never trusted.
//!
//! Layout (little-endian): magic, format version, the key it was stored under, the graph as
//! JSON, the surface (vertices, triangles, known normals), the grid (origin, cell size,
//! block dimensions and table, cells, candidates and their bounds), then a CRC-32 of all
//! that precedes it. The per-triangle tables (normals, neighbours, BVH) are rebuilt on
//! reading: they cost seconds, the grid tens of seconds.

use nalgebra::{Point3, Vector3};

use crate::error::{AnatomyError, Result};
use crate::graph::VesselGraph;
use crate::lumen::{CellEntry, CellGrid, Lumen};
use crate::mesh::TriangleMesh;
use crate::real::Anatomy;

const MAGIC: &[u8; 8] = b"CLANATMY";
/// Version of the layout; a file of another version is refused.
pub const FORMAT_VERSION: u32 = 1;

/// `anatomy` as bytes, stored under `key` (what identifies how it was built); `None` for an
/// anatomy whose wall is its graph's implicit lumen (rebuilt in milliseconds, never stored).
pub fn encode(anatomy: &Anatomy, key: &str) -> Option<Vec<u8>> {
    let mesh = anatomy.lumen.mesh();
    let grid = anatomy.lumen.grid()?;
    let mut out = Vec::with_capacity(
        64 + mesh.vertices.len() * 48
            + mesh.triangles.len() * 12
            + grid.block_of.len() * 4
            + grid.cells.len() * 12
            + grid.candidates.len() * 8,
    );
    out.extend_from_slice(MAGIC);
    put_u32(&mut out, FORMAT_VERSION);
    put_bytes(&mut out, key.as_bytes());
    // The graph's own JSON form (exact: shortest round-tripping decimals), read back through
    // its checks, which rebuild what it derives (arc lengths).
    put_bytes(&mut out, anatomy.graph.to_json().as_bytes());
    put_u64(&mut out, mesh.vertices.len() as u64);
    for v in &mesh.vertices {
        v.iter().for_each(|&c| put_f64(&mut out, c));
    }
    put_u64(&mut out, mesh.triangles.len() as u64);
    for t in &mesh.triangles {
        t.iter().for_each(|&i| put_u32(&mut out, i));
    }
    put_u64(&mut out, mesh.normals.len() as u64);
    for n in &mesh.normals {
        n.iter().for_each(|&c| put_f64(&mut out, c));
    }
    grid.origin.iter().for_each(|&c| put_f64(&mut out, c));
    put_f64(&mut out, grid.inverse_cell);
    grid.blocks
        .iter()
        .for_each(|&b| put_u64(&mut out, b as u64));
    put_u64(&mut out, grid.block_of.len() as u64);
    grid.block_of.iter().for_each(|&b| put_u32(&mut out, b));
    put_u64(&mut out, grid.cells.len() as u64);
    for c in &grid.cells {
        put_u32(&mut out, c.start);
        put_u32(&mut out, c.count);
        put_f32(&mut out, c.far_bound);
    }
    put_u64(&mut out, grid.candidates.len() as u64);
    grid.candidates.iter().for_each(|&t| put_u32(&mut out, t));
    grid.candidate_bounds
        .iter()
        .for_each(|&b| put_f32(&mut out, b));
    let crc = crc32fast::hash(&out);
    put_u32(&mut out, crc);
    Some(out)
}

/// The anatomy `bytes` hold, if they were stored under `key` by this format version and
/// arrive whole; `source` names them in errors. The surface is checked as when it was
/// built (a closed manifold) and the grid against it (no index past the surface).
pub fn decode(bytes: &[u8], key: &str, source: &str) -> Result<Anatomy> {
    let bad = |message: String| AnatomyError::Parse {
        file: source.to_owned(),
        line: None,
        message,
    };
    let Some((body, crc)) = bytes.split_last_chunk::<4>() else {
        return Err(bad("shorter than its checksum".into()));
    };
    if crc32fast::hash(body) != u32::from_le_bytes(*crc) {
        return Err(bad("checksum does not match (damaged or truncated)".into()));
    }
    let mut r = Reader { bytes: body };
    if r.take(MAGIC.len()).map_err(&bad)? != MAGIC {
        return Err(bad("not a stored anatomy".into()));
    }
    let version = r.u32().map_err(&bad)?;
    if version != FORMAT_VERSION {
        return Err(bad(format!(
            "format version {version}, this build reads {FORMAT_VERSION}"
        )));
    }
    let stored_key = r.bytes().map_err(&bad)?;
    if stored_key != key.as_bytes() {
        return Err(bad("stored for another key".into()));
    }
    let text = std::str::from_utf8(r.bytes().map_err(&bad)?)
        .map_err(|_| bad("graph: not UTF-8".into()))?;
    let graph = VesselGraph::from_json(text, source)?;
    let (mesh, grid) = read_surface(&mut r).map_err(&bad)?;
    if !r.bytes.is_empty() {
        return Err(bad(format!("{} bytes after the grid", r.bytes.len())));
    }
    let mut lumen = Lumen::prepared(mesh, source)?;
    lumen.set_grid(grid).map_err(bad)?;
    Ok(Anatomy { graph, lumen })
}

fn read_surface(r: &mut Reader) -> std::result::Result<(TriangleMesh, CellGrid), String> {
    let n = r.count(24)?;
    let vertices = (0..n)
        .map(|_| Ok(Point3::new(r.f64()?, r.f64()?, r.f64()?)))
        .collect::<std::result::Result<Vec<_>, String>>()?;
    let n = r.count(12)?;
    let triangles = (0..n)
        .map(|_| Ok([r.u32()?, r.u32()?, r.u32()?]))
        .collect::<std::result::Result<Vec<_>, String>>()?;
    if triangles
        .iter()
        .flatten()
        .any(|&i| i as usize >= vertices.len())
    {
        return Err("a triangle names a vertex past the surface".into());
    }
    let n = r.count(24)?;
    let normals = (0..n)
        .map(|_| Ok(Vector3::new(r.f64()?, r.f64()?, r.f64()?)))
        .collect::<std::result::Result<Vec<_>, String>>()?;
    if !normals.is_empty() && normals.len() != vertices.len() {
        return Err("normals do not match the vertices".into());
    }
    if !vertices.iter().all(|v| v.iter().all(|c| c.is_finite()))
        || !normals.iter().all(|v| v.iter().all(|c| c.is_finite()))
    {
        return Err("a vertex or normal is not finite".into());
    }
    let origin = Point3::new(r.f64()?, r.f64()?, r.f64()?);
    let inverse_cell = r.f64()?;
    let blocks = [r.u64()? as usize, r.u64()? as usize, r.u64()? as usize];
    let n = r.count(4)?;
    let block_of = (0..n)
        .map(|_| r.u32())
        .collect::<std::result::Result<_, _>>()?;
    let n = r.count(12)?;
    let cells = (0..n)
        .map(|_| {
            Ok(CellEntry {
                start: r.u32()?,
                count: r.u32()?,
                far_bound: r.f32()?,
            })
        })
        .collect::<std::result::Result<_, String>>()?;
    let n = r.count(8)?;
    let candidates = (0..n)
        .map(|_| r.u32())
        .collect::<std::result::Result<_, _>>()?;
    let candidate_bounds = (0..n)
        .map(|_| r.f32())
        .collect::<std::result::Result<_, _>>()?;
    Ok((
        TriangleMesh {
            vertices,
            triangles,
            normals,
        },
        CellGrid {
            origin,
            inverse_cell,
            blocks,
            block_of,
            cells,
            candidates,
            candidate_bounds,
        },
    ))
}

/// Reads from the front of a byte slice; every read checks what is left first.
struct Reader<'a> {
    bytes: &'a [u8],
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> std::result::Result<&'a [u8], String> {
        if n > self.bytes.len() {
            return Err(format!(
                "truncated: {n} bytes wanted, {} left",
                self.bytes.len()
            ));
        }
        let (head, rest) = self.bytes.split_at(n);
        self.bytes = rest;
        Ok(head)
    }

    fn array<const N: usize>(&mut self) -> std::result::Result<[u8; N], String> {
        let mut a = [0; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }

    fn u32(&mut self) -> std::result::Result<u32, String> {
        self.array().map(u32::from_le_bytes)
    }

    fn u64(&mut self) -> std::result::Result<u64, String> {
        self.array().map(u64::from_le_bytes)
    }

    fn f32(&mut self) -> std::result::Result<f32, String> {
        self.array().map(f32::from_le_bytes)
    }

    fn f64(&mut self) -> std::result::Result<f64, String> {
        self.array().map(f64::from_le_bytes)
    }

    /// A count of items of `size` bytes each, refused if they cannot all be left (so nothing
    /// is allocated for items that are not there).
    fn count(&mut self, size: usize) -> std::result::Result<usize, String> {
        let n = self.u64()?;
        match usize::try_from(n).ok().and_then(|n| n.checked_mul(size)) {
            Some(bytes) if bytes <= self.bytes.len() => Ok(n as usize),
            _ => Err(format!(
                "a count of {n} items of {size} bytes with {} bytes left",
                self.bytes.len()
            )),
        }
    }

    /// A length-prefixed byte string.
    fn bytes(&mut self) -> std::result::Result<&'a [u8], String> {
        let n = self.count(1)?;
        self.take(n)
    }
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_u64(out: &mut Vec<u8>, v: u64) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f32(out: &mut Vec<u8>, v: f32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f64(out: &mut Vec<u8>, v: f64) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_bytes(out: &mut Vec<u8>, b: &[u8]) {
    put_u64(out, b.len() as u64);
    out.extend_from_slice(b);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lumen::GridSettings;
    use crate::phantom::y_bifurcation;
    use crate::surface::{SurfaceSettings, lumen_surface};

    fn built() -> Anatomy {
        let graph = y_bifurcation(3e-3, 2e-3, 20e-3, 15e-3, 0.5).unwrap();
        let surface = SurfaceSettings {
            cells_per_radius: 1.5,
            ..SurfaceSettings::default()
        };
        let mesh = lumen_surface(&graph, &surface).unwrap();
        let grid = GridSettings {
            cell_size: Some(1e-3),
            band: 2e-3,
        };
        let lumen = Lumen::with_grid_settings(mesh, "y", grid).unwrap();
        Anatomy { graph, lumen }
    }

    #[test]
    fn a_stored_anatomy_reads_back_equal_and_answers_the_same_queries() {
        let a = built();
        let bytes = encode(&a, "y:1").unwrap();
        let b = decode(&bytes, "y:1", "test").unwrap();
        assert_eq!(a.graph, b.graph);
        assert_eq!(a.lumen.mesh(), b.lumen.mesh());
        assert_eq!(a.lumen.grid(), b.lumen.grid());
        // Points through the grid's band and beyond it: the same answers, bit for bit.
        let (lo, hi) = a.lumen.mesh().bounding_box();
        for i in 0..2000 {
            let f = |k: u32| ((i * 7919 + k * 104_729) % 1000) as f64 / 1000.0;
            let p = lo + (hi - lo).component_mul(&Vector3::new(f(1), f(2), f(3)));
            assert_eq!(a.lumen.query(&p), b.lumen.query(&p), "{p}");
        }
    }

    #[test]
    fn damaged_truncated_foreign_or_stale_bytes_are_refused_by_name() {
        let bytes = encode(&built(), "y:1").unwrap();
        let err = |b: &[u8], key: &str| decode(b, key, "cache/y.bin").unwrap_err().to_string();
        assert!(err(&bytes, "y:2").contains("another key"));
        let mut flipped = bytes.clone();
        flipped[bytes.len() / 2] ^= 1;
        assert!(err(&flipped, "y:1").contains("checksum"));
        assert!(err(&bytes[..bytes.len() - 100], "y:1").contains("checksum"));
        assert!(err(&bytes[..2], "y:1").contains("checksum"));
        // Well-formed bytes of another format version (checksum redone): refused as such.
        let mut other = bytes[..bytes.len() - 4].to_vec();
        other[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
        let crc = crc32fast::hash(&other);
        other.extend_from_slice(&crc.to_le_bytes());
        assert!(err(&other, "y:1").contains("format version"));
        assert!(err(&other, "y:1").starts_with("cache/y.bin"));
    }

    #[test]
    fn a_grid_that_names_triangles_past_the_surface_is_refused() {
        let a = built();
        let mut bytes = encode(&a, "k").unwrap();
        // The last candidate (just before its bounds and the checksum) set past the surface.
        let n = a.lumen.grid().unwrap().candidates.len();
        let at = bytes.len() - 4 - 4 * n - 4;
        bytes[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        let body = bytes.len() - 4;
        let crc = crc32fast::hash(&bytes[..body]);
        bytes[body..].copy_from_slice(&crc.to_le_bytes());
        let e = decode(&bytes, "k", "t").unwrap_err().to_string();
        assert!(e.contains("triangle past the surface"), "{e}");
    }
}
