//! The disk cache of built assets: an anatomy that takes seconds to build (the neuro
//! phantom's surface and query grid, a surface imported with its circle of Willis, a CT's
//! segmentation) and a synthetic CT (a second of sampling the body phantom) are written once
//! to a directory and read back by later loads, in this process or another. Its key is the hash of the code that builds it (made by the build script from
//! the source), its parameters and the SHA-256 of the files it is built from, so a cached
//! file can never be stale; a file missing, damaged or stored for another key is rebuilt,
//! never trusted. The directory is kept within a size, the least recently used files going
//! first.

use std::hash::{DefaultHasher, Hash, Hasher};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime};

use sha2::{Digest, Sha256};

use cathlab_anatomy::real::Anatomy;
use cathlab_xray::Volume;

use crate::error::Result;

/// Hash of the source that builds cached assets (see `build.rs`).
const CODE_HASH: &str = env!("CATHLAB_ASSET_CODE_HASH");
/// Largest cached file read back (bytes): past it, the anatomy is rebuilt instead.
const MAX_FILE_BYTES: u64 = 8 << 30;

/// Most bytes of input files hashed for one key: past it, the anatomy is not cached.
const MAX_HASHED_BYTES: u64 = 4 << 30;
/// Most files of an anatomy folder hashed for one key (and folder depth).
const MAX_HASHED_FILES: usize = 10_000;
const MAX_HASHED_DEPTH: usize = 8;

/// A directory of built anatomies.
#[derive(Debug, Clone)]
pub(super) struct DiskCache {
    dir: PathBuf,
    /// Most bytes its files may take together; the least recently used go first.
    pub(super) max_bytes: u64,
}

impl DiskCache {
    pub(super) fn new(dir: &Path, max_bytes: u64) -> Self {
        Self {
            dir: dir.to_owned(),
            max_bytes,
        }
    }

    /// The file for an asset of `kind` (`anatomy`, `volume`) under `key`: the code's hash,
    /// then the parameters' (the full key is inside).
    fn file_of(&self, kind: &str, key: &str) -> PathBuf {
        let mut h = DefaultHasher::new();
        key.hash(&mut h);
        self.dir.join(format!(
            "{kind}-{}-{:016x}.bin",
            &CODE_HASH[..16],
            h.finish()
        ))
    }

    /// The CT volume stored under `key`, or `build`'s, then stored (see [`Self::cached`]).
    pub(super) fn volume(
        &self,
        key: &str,
        build: impl FnOnce() -> Result<Volume>,
    ) -> Result<Volume> {
        self.cached(
            "volume",
            key,
            |bytes, full_key, _| decode_volume(bytes, full_key),
            |volume, full_key| Some(encode_volume(volume, full_key)),
            build,
        )
    }

    /// The anatomy stored under `key`, or `build`'s, then stored (see [`Self::cached`]); an
    /// implicit wall, rebuilt in milliseconds, is never stored.
    pub(super) fn anatomy(
        &self,
        key: &str,
        build: impl FnOnce() -> Result<Anatomy>,
    ) -> Result<Anatomy> {
        self.cached(
            "anatomy",
            key,
            |bytes, full_key, file| {
                cathlab_anatomy::stored::decode(bytes, full_key, &file.display().to_string())
                    .map_err(|e| e.to_string())
            },
            cathlab_anatomy::stored::encode,
            build,
        )
    }

    /// The asset of `kind` stored under `key` (read back by `decode`, which checks the full
    /// key inside), or `build`'s, then stored as `encode` writes it (`None`: not stored).
    /// Reading and writing never fail the load: a file that cannot be read is rebuilt, one
    /// that cannot be written is logged.
    fn cached<T>(
        &self,
        kind: &str,
        key: &str,
        decode: impl FnOnce(&[u8], &str, &Path) -> std::result::Result<T, String>,
        encode: impl FnOnce(&T, &str) -> Option<Vec<u8>>,
        build: impl FnOnce() -> Result<T>,
    ) -> Result<T> {
        let full_key = format!("{CODE_HASH}:{key}");
        let file = self.file_of(kind, key);
        let started = Instant::now();
        let read = read_bytes(&file)
            .and_then(|bytes| bytes.map(|b| decode(&b, &full_key, &file)).transpose());
        match read {
            Ok(Some(asset)) => {
                // Its time of use, for the eviction order.
                if let Ok(f) = std::fs::OpenOptions::new().write(true).open(&file) {
                    let _ = f.set_modified(SystemTime::now());
                }
                tracing::info!(
                    file = %file.display(),
                    seconds = started.elapsed().as_secs_f64(),
                    "{kind} read from the disk cache"
                );
                return Ok(asset);
            }
            Ok(None) => {}
            Err(reason) => tracing::warn!(
                file = %file.display(),
                %reason,
                "cached {kind} refused; building it again"
            ),
        }
        let asset = build()?;
        if let Some(bytes) = encode(&asset, &full_key)
            && let Err(e) = self.store(&file, &bytes)
        {
            tracing::warn!(file = %file.display(), error = %e, "cannot write the disk cache");
        }
        Ok(asset)
    }

    /// Writes beside the file and renames it into place (a reader sees the whole file or
    /// none), then removes the files other code stored (they can never be read again) and,
    /// past the size limit, the least recently used of this code's.
    fn store(&self, file: &Path, bytes: &[u8]) -> std::io::Result<()> {
        std::fs::create_dir_all(&self.dir)?;
        let partial = file.with_extension(format!("partial-{}", std::process::id()));
        std::fs::write(&partial, bytes)?;
        std::fs::rename(&partial, file)?;
        // This code's files, most recently used first.
        let mut kept: Vec<(SystemTime, u64, PathBuf)> = Vec::new();
        for entry in std::fs::read_dir(&self.dir)?.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            let Some(rest) = ["anatomy-", "volume-"]
                .iter()
                .find_map(|kind| name.strip_prefix(kind))
            else {
                continue;
            };
            if !name.ends_with(".bin") {
                continue;
            }
            if !rest.starts_with(&CODE_HASH[..16]) {
                let _ = std::fs::remove_file(entry.path());
            } else if let Ok(meta) = entry.metadata() {
                let used = meta.modified().unwrap_or(SystemTime::UNIX_EPOCH);
                kept.push((used, meta.len(), entry.path()));
            }
        }
        kept.sort_by_key(|k| std::cmp::Reverse(k.0));
        let mut total = bytes.len() as u64;
        for (_, len, path) in kept {
            if path == file {
                continue;
            }
            total += len;
            if total > self.max_bytes {
                tracing::info!(file = %path.display(), "least recently used asset removed from the disk cache");
                let _ = std::fs::remove_file(&path);
            }
        }
        tracing::info!(file = %file.display(), bytes = bytes.len(), "asset stored in the disk cache");
        Ok(())
    }
}

/// A cached file's bytes; `Ok(None)` when there is none.
fn read_bytes(file: &Path) -> std::result::Result<Option<Vec<u8>>, String> {
    let meta = match std::fs::metadata(file) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e.to_string()),
    };
    if !meta.is_file() || meta.len() > MAX_FILE_BYTES {
        return Err(format!(
            "not a regular file of at most {MAX_FILE_BYTES} bytes"
        ));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    std::fs::File::open(file)
        .and_then(|f| f.take(MAX_FILE_BYTES).read_to_end(&mut bytes))
        .map_err(|e| e.to_string())?;
    Ok(Some(bytes))
}

/// First bytes of a stored CT volume.
const VOLUME_MAGIC: &[u8; 8] = b"CLCTVOL1";

/// A CT volume as stored: the magic, the full key (length, UTF-8), the dimensions (3 × u64),
/// spacing, origin (3 × f64 each, m) and direction (9 × f64, column-major), then the HU
/// (i16), all little-endian, then the SHA-256 of everything before it.
fn encode_volume(volume: &Volume, full_key: &str) -> Vec<u8> {
    let mut out = Vec::with_capacity(160 + full_key.len() + 2 * volume.hu.len());
    out.extend_from_slice(VOLUME_MAGIC);
    out.extend_from_slice(&(full_key.len() as u64).to_le_bytes());
    out.extend_from_slice(full_key.as_bytes());
    for d in volume.dims {
        out.extend_from_slice(&(d as u64).to_le_bytes());
    }
    for v in volume
        .spacing_m
        .iter()
        .chain(volume.origin_m.iter())
        .chain(volume.direction.iter())
    {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for h in &volume.hu {
        out.extend_from_slice(&h.to_le_bytes());
    }
    let digest = Sha256::digest(&out);
    out.extend_from_slice(&digest);
    out
}

/// The volume [`encode_volume`] stored under `full_key`, checked: its digest, its key, and
/// the grid ([`Volume::new`]).
fn decode_volume(bytes: &[u8], full_key: &str) -> std::result::Result<Volume, String> {
    let body = bytes
        .len()
        .checked_sub(32)
        .filter(|&n| n >= VOLUME_MAGIC.len())
        .ok_or("too short for a stored CT volume")?;
    if Sha256::digest(&bytes[..body]).as_slice() != &bytes[body..] {
        return Err("its digest does not match (damaged)".into());
    }
    let mut at = 0;
    let mut take = |n: usize| -> std::result::Result<&[u8], String> {
        let slice = bytes[..body]
            .get(at..at + n)
            .ok_or("truncated stored CT volume")?;
        at += n;
        Ok(slice)
    };
    if take(VOLUME_MAGIC.len())? != VOLUME_MAGIC {
        return Err("not a stored CT volume".into());
    }
    let u64_at = |b: &[u8]| u64::from_le_bytes(b.try_into().unwrap_or([0; 8]));
    let key_len = usize::try_from(u64_at(take(8)?)).map_err(|e| e.to_string())?;
    if key_len != full_key.len() || take(key_len)? != full_key.as_bytes() {
        return Err("stored under another key".into());
    }
    let mut dims = [0usize; 3];
    for d in &mut dims {
        *d = usize::try_from(u64_at(take(8)?)).map_err(|e| e.to_string())?;
    }
    let mut reals = [0.0f64; 15];
    for r in &mut reals {
        *r = f64::from_le_bytes(take(8)?.try_into().unwrap_or([0; 8]));
    }
    let count = dims
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .ok_or("dimensions overflow")?;
    let raw = take(count.checked_mul(2).ok_or("dimensions overflow")?)?;
    if at != body {
        return Err("trailing bytes in a stored CT volume".into());
    }
    let hu = raw
        .chunks_exact(2)
        .map(|c| i16::from_le_bytes([c[0], c[1]]))
        .collect();
    Volume::new(
        dims,
        nalgebra::Vector3::new(reals[0], reals[1], reals[2]),
        nalgebra::Vector3::new(reals[3], reals[4], reals[5]),
        nalgebra::Matrix3::from_column_slice(&reals[6..15]),
        hu,
    )
    .map_err(|e| e.to_string())
}

/// The SHA-256 (hex) of the files an anatomy is built from: each path a file, or a folder
/// whose files are hashed by their names relative to it, in order (none: the hash of nothing,
/// for an anatomy built from its parameters alone). `None` (the anatomy is then
/// built, not cached) when one cannot be read or they are too many or too large to hash.
pub(super) fn content_hash(paths: &[&Path]) -> Option<String> {
    fn walk(
        path: &Path,
        name: &Path,
        depth: usize,
        hasher: &mut Sha256,
        budget: &mut (u64, usize),
    ) -> Option<()> {
        let meta = std::fs::metadata(path).ok()?;
        if meta.is_dir() {
            if depth >= MAX_HASHED_DEPTH {
                return None;
            }
            let mut entries: Vec<_> = std::fs::read_dir(path)
                .ok()?
                .map(|e| e.map(|e| e.file_name()))
                .collect::<std::io::Result<_>>()
                .ok()?;
            entries.sort();
            for entry in entries {
                walk(
                    &path.join(&entry),
                    &name.join(&entry),
                    depth + 1,
                    hasher,
                    budget,
                )?;
            }
            return Some(());
        }
        // Only regular files are read (a FIFO or a device is never opened).
        if !meta.is_file() {
            return None;
        }
        budget.1 += 1;
        budget.0 = budget.0.checked_sub(meta.len())?;
        if budget.1 > MAX_HASHED_FILES {
            return None;
        }
        hasher.update(name.to_string_lossy().as_bytes());
        hasher.update([0]);
        hasher.update(meta.len().to_le_bytes());
        let mut file = std::fs::File::open(path).ok()?;
        let copied = std::io::copy(&mut (&mut file).take(meta.len()), hasher).ok()?;
        (copied == meta.len()).then_some(())
    }
    let mut hasher = Sha256::new();
    let mut budget = (MAX_HASHED_BYTES, 0);
    for path in paths {
        hasher.update(b"\x01");
        walk(path, Path::new(""), 0, &mut hasher, &mut budget)?;
    }
    Some(format!("{:x}", hasher.finalize()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use cathlab_anatomy::Lumen;
    use cathlab_anatomy::lumen::GridSettings;
    use cathlab_anatomy::phantom::y_bifurcation;
    use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};

    fn build(builds: &mut usize) -> Result<Anatomy> {
        *builds += 1;
        let graph = y_bifurcation(3e-3, 2e-3, 20e-3, 15e-3, 0.5)?;
        let surface = SurfaceSettings {
            cells_per_radius: 1.5,
            ..SurfaceSettings::default()
        };
        let grid = GridSettings {
            cell_size: Some(1e-3),
            band: 2e-3,
        };
        let lumen = Lumen::with_grid_settings(lumen_surface(&graph, &surface)?, "y", grid)?;
        Ok(Anatomy { graph, lumen })
    }

    #[test]
    fn built_once_then_read_back_and_a_damaged_file_is_rebuilt() {
        let dir = std::env::temp_dir().join(format!("cathlab-disk-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let cache = DiskCache::new(&dir, u64::MAX);
        let mut builds = 0;
        let first = cache.anatomy("y", || build(&mut builds)).unwrap();
        let again = cache.anatomy("y", || build(&mut builds)).unwrap();
        assert_eq!(builds, 1, "the second load reads the file");
        assert_eq!(first.lumen.mesh(), again.lumen.mesh());
        assert_eq!(first.graph, again.graph);
        // Another parameter: another file.
        cache.anatomy("y2", || build(&mut builds)).unwrap();
        assert_eq!(builds, 2);
        // A damaged file is rebuilt (and replaced).
        let file = cache.file_of("anatomy", "y");
        let mut bytes = std::fs::read(&file).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x40;
        std::fs::write(&file, &bytes).unwrap();
        cache.anatomy("y", || build(&mut builds)).unwrap();
        assert_eq!(builds, 3);
        cache.anatomy("y", || build(&mut builds)).unwrap();
        assert_eq!(builds, 3, "the rebuilt file was stored");
        // Files another build of the code stored are removed when this one stores.
        let stale = dir.join("anatomy-0000000000000000-0000000000000000.bin");
        std::fs::write(&stale, b"old").unwrap();
        cache.anatomy("y3", || build(&mut builds)).unwrap();
        assert!(!stale.exists());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_ct_volume_is_built_once_read_back_exactly_and_a_damaged_one_rebuilt() {
        let dir = std::env::temp_dir().join(format!("cathlab-disk-ct-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let cache = DiskCache::new(&dir, u64::MAX);
        let mut builds = 0;
        let build = |builds: &mut usize| -> Result<Volume> {
            *builds += 1;
            let direction = nalgebra::Rotation3::from_euler_angles(0.1, -0.2, 0.3).into_inner();
            Ok(Volume::new(
                [5, 4, 3],
                nalgebra::Vector3::new(1e-3, 1.5e-3, 2e-3),
                nalgebra::Vector3::new(-0.01, 0.02, 0.3),
                direction,
                (0..60).map(|v| (v * 997 % 4000 - 1000) as i16).collect(),
            )?)
        };
        let first = cache.volume("ct", || build(&mut builds)).unwrap();
        let again = cache.volume("ct", || build(&mut builds)).unwrap();
        assert_eq!(builds, 1, "the second load reads the file");
        assert_eq!(first, again, "read back bit for bit");
        cache.volume("ct2", || build(&mut builds)).unwrap();
        assert_eq!(builds, 2, "another key, another file");
        // One flipped bit anywhere: refused and rebuilt.
        let file = cache.file_of("volume", "ct");
        let mut bytes = std::fs::read(&file).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x01;
        std::fs::write(&file, &bytes).unwrap();
        assert!(decode_volume(&bytes, &format!("{CODE_HASH}:ct")).is_err());
        cache.volume("ct", || build(&mut builds)).unwrap();
        assert_eq!(builds, 3);
        // Stored under another key (a file renamed into place): refused.
        let other = std::fs::read(cache.file_of("volume", "ct2")).unwrap();
        assert!(decode_volume(&other, &format!("{CODE_HASH}:ct")).is_err());
        // Truncated: refused, never a panic.
        for n in [0, 7, 20, other.len() - 33] {
            assert!(decode_volume(&other[..n], &format!("{CODE_HASH}:ct2")).is_err());
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_least_recently_used_files_go_past_the_limit() {
        let dir = std::env::temp_dir().join(format!("cathlab-disk-lru-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut builds = 0;
        let one = {
            let cache = DiskCache::new(&dir, u64::MAX);
            cache.anatomy("a", || build(&mut builds)).unwrap();
            std::fs::metadata(cache.file_of("anatomy", "a"))
                .unwrap()
                .len()
        };
        // Room for two files: a third removes the least recently used.
        let cache = DiskCache::new(&dir, 2 * one + one / 2);
        std::thread::sleep(std::time::Duration::from_millis(20));
        cache.anatomy("b", || build(&mut builds)).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        // "a" read again: now more recently used than "b".
        cache.anatomy("a", || build(&mut builds)).unwrap();
        assert_eq!(builds, 2);
        std::thread::sleep(std::time::Duration::from_millis(20));
        cache.anatomy("c", || build(&mut builds)).unwrap();
        assert!(cache.file_of("anatomy", "a").exists() && cache.file_of("anatomy", "c").exists());
        assert!(
            !cache.file_of("anatomy", "b").exists(),
            "the least recently used file is removed"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_content_hash_follows_every_byte_and_name_of_the_inputs() {
        let dir = std::env::temp_dir().join(format!("cathlab-disk-hash-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("folder/inner")).unwrap();
        std::fs::write(dir.join("folder/a.obj"), b"v 0 0 0").unwrap();
        std::fs::write(dir.join("folder/inner/b.json"), b"{}").unwrap();
        std::fs::write(dir.join("single.stl"), b"solid").unwrap();
        let folder = dir.join("folder");
        let single = dir.join("single.stl");
        let first = content_hash(&[&folder, &single]).unwrap();
        assert_eq!(first.len(), 64);
        assert_eq!(content_hash(&[&folder, &single]).unwrap(), first);
        // One byte, a renamed file, the order of the inputs: each another key.
        std::fs::write(dir.join("folder/inner/b.json"), b"{ }").unwrap();
        let changed = content_hash(&[&folder, &single]).unwrap();
        assert_ne!(changed, first);
        std::fs::rename(
            dir.join("folder/inner/b.json"),
            dir.join("folder/inner/c.json"),
        )
        .unwrap();
        assert_ne!(content_hash(&[&folder, &single]).unwrap(), changed);
        assert_ne!(
            content_hash(&[&single, &folder]).unwrap(),
            content_hash(&[&folder, &single]).unwrap()
        );
        // A missing input: not cached.
        assert_eq!(content_hash(&[&dir.join("missing.stl")]), None);
        // A FIFO in a folder is never opened (it would block): not cached.
        let made = std::process::Command::new("mkfifo")
            .arg(dir.join("folder/pipe"))
            .status();
        if made.is_ok_and(|s| s.success()) {
            assert_eq!(content_hash(&[&folder]), None);
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
