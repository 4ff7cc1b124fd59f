//! How much the file readers may read and allocate: the most bytes one file may have, the
//! most bytes a compressed stream (zlib, gzip, VTK blocks) may inflate to, and the most voxels
//! a volume may hold. Every reader of this crate and of the imaging crate checks these before
//! it allocates, so a crafted header (a 150-byte MetaImage declaring 10¹⁵ voxels) or a
//! decompression bomb is refused with an error naming the field, never an abort.
//!
//! The limits are process-wide: a server sets them once from its configuration
//! ([`set_read_limits`]); tools and tests use the defaults.

use std::io::Read;
use std::path::Path;
use std::sync::RwLock;

/// Bounds on what a file reader may read and allocate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReadLimits {
    /// Most bytes one file may have (bytes).
    pub max_file_bytes: u64,
    /// Most bytes a compressed stream may inflate to (bytes).
    pub max_inflated_bytes: u64,
    /// Most voxels one volume (or DICOM series) may hold.
    pub max_voxels: u64,
}

/// The default limits: files and inflated data up to 2 GiB, volumes up to 2²⁸ voxels
/// (1 GiB as `f32`; a 512×512×1024 CT is 2²⁸).
pub const DEFAULT_READ_LIMITS: ReadLimits = ReadLimits {
    max_file_bytes: 2 << 30,
    max_inflated_bytes: 2 << 30,
    max_voxels: 1 << 28,
};

impl Default for ReadLimits {
    fn default() -> Self {
        DEFAULT_READ_LIMITS
    }
}

/// How every refusal by a limit begins: what follows it names the limit and numbers, never
/// a path or the file's contents, so that a server may pass it on to a client.
pub const REFUSED: &str = "refused: ";

static LIMITS: RwLock<ReadLimits> = RwLock::new(DEFAULT_READ_LIMITS);

/// Sets the limits every reader of this process checks from now on.
pub fn set_read_limits(limits: ReadLimits) {
    *LIMITS
        .write()
        .unwrap_or_else(std::sync::PoisonError::into_inner) = limits;
}

/// The limits in force.
pub fn read_limits() -> ReadLimits {
    *LIMITS
        .read()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn refused(message: String) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        format!("{REFUSED}{message}"),
    )
}

/// Reads a whole regular file of at most `max_file_bytes` (a device such as `/dev/zero`, a
/// FIFO or a directory is refused before it is opened; a file that grows while it is read
/// stops at the limit).
pub fn read_regular_file(path: &Path) -> std::io::Result<Vec<u8>> {
    let limit = read_limits().max_file_bytes;
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{REFUSED}not a regular file"),
        ));
    }
    if meta.len() > limit {
        return Err(refused(format!(
            "{} bytes, more than the {limit} a file may have (max_file_bytes)",
            meta.len()
        )));
    }
    let mut out = Vec::new();
    std::fs::File::open(path)?
        .take(limit + 1)
        .read_to_end(&mut out)?;
    if out.len() as u64 > limit {
        return Err(refused(format!(
            "grew past the {limit} bytes a file may have (max_file_bytes) while it was read"
        )));
    }
    Ok(out)
}

/// Reads a whole regular file as UTF-8 text, bounded as [`read_regular_file`].
pub fn read_regular_text(path: &Path) -> std::io::Result<String> {
    String::from_utf8(read_regular_file(path)?).map_err(|_| refused("not UTF-8 text".to_owned()))
}

/// Inflates `compressed` (a reader of zlib or gzip data, already wrapped in its decoder) to
/// exactly `declared` bytes when the header declares a size, else to whatever it holds; in
/// both cases to at most `max_inflated_bytes`. The error says which bound was passed.
pub fn inflate_bounded(compressed: impl Read, declared: Option<u64>) -> Result<Vec<u8>, String> {
    let cap = read_limits().max_inflated_bytes;
    if let Some(d) = declared
        && d > cap
    {
        return Err(format!(
            "{REFUSED}declares {d} bytes, more than the {cap} compressed data may inflate to \
             (max_inflated_bytes)"
        ));
    }
    let bound = declared.unwrap_or(cap).min(cap);
    let mut out = Vec::new();
    compressed
        .take(bound + 1)
        .read_to_end(&mut out)
        .map_err(|e| e.to_string())?;
    if out.len() as u64 > bound {
        return Err(match declared {
            Some(d) if d <= cap => {
                format!("{REFUSED}inflates past the {d} bytes its header declares")
            }
            _ => format!(
                "{REFUSED}inflates past {cap} bytes, the most compressed data may inflate to \
                 (max_inflated_bytes)"
            ),
        });
    }
    Ok(out)
}

/// The number of voxels of a volume of `dims`, checked against overflow and `max_voxels`
/// before anything is allocated. The error names the product and the limit.
pub fn checked_voxels(dims: &[u64]) -> Result<usize, String> {
    let limit = read_limits().max_voxels;
    let product = dims.iter().try_fold(1u64, |n, &d| n.checked_mul(d));
    match product {
        Some(n) if n <= limit => usize::try_from(n).map_err(|_| format!("{n} voxels")),
        Some(n) => Err(format!(
            "{REFUSED}{} is {n} voxels, more than the {limit} a volume may hold (max_voxels)",
            dims.iter()
                .map(u64::to_string)
                .collect::<Vec<_>>()
                .join("×")
        )),
        None => Err(format!(
            "{REFUSED}{} voxels overflow a 64-bit count (at most {limit}, max_voxels)",
            dims.iter()
                .map(u64::to_string)
                .collect::<Vec<_>>()
                .join("×")
        )),
    }
}

/// The size in bytes of `count` elements of `size` bytes, checked against overflow.
pub fn checked_bytes(count: usize, size: usize) -> Result<u64, String> {
    count
        .checked_mul(size)
        .map(|n| n as u64)
        .ok_or_else(|| format!("{count} elements of {size} bytes overflow"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_counts_are_checked_for_overflow_and_the_limit() {
        assert_eq!(checked_voxels(&[2, 3, 4]), Ok(24));
        let huge = checked_voxels(&[100_000, 100_000, 100_000]).unwrap_err();
        assert!(
            huge.contains("max_voxels") && huge.contains("100000×100000×100000"),
            "{huge}"
        );
        let wraps = checked_voxels(&[1 << 32, 1 << 32, 1]).unwrap_err();
        assert!(wraps.contains("overflow"), "{wraps}");
    }

    #[test]
    fn inflation_stops_at_the_declared_size_and_at_the_cap() {
        use std::io::Write as _;
        let mut encoder =
            flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        encoder.write_all(&vec![0u8; 10_000]).unwrap();
        let compressed = encoder.finish().unwrap();
        let inflate = |declared| {
            inflate_bounded(
                flate2::read::ZlibDecoder::new(compressed.as_slice()),
                declared,
            )
        };
        assert_eq!(inflate(Some(10_000)).unwrap().len(), 10_000);
        assert_eq!(inflate(None).unwrap().len(), 10_000);
        let past = inflate(Some(100)).unwrap_err();
        assert!(past.contains("declares"), "{past}");
        let cap = inflate(Some(u64::MAX)).unwrap_err();
        assert!(cap.contains("max_inflated_bytes"), "{cap}");
    }

    #[test]
    fn only_regular_files_are_read() {
        let error = read_regular_file(Path::new("/dev/zero")).unwrap_err();
        assert_eq!(error.to_string(), "refused: not a regular file");
        let dir = std::env::temp_dir();
        assert!(read_regular_file(&dir).is_err());
    }
}
