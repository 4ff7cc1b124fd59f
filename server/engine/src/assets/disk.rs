//! The disk cache of built assets: an anatomy that takes tens of seconds to build (the neuro
//! phantom's surface and query grid) is written once to a directory and read back by later
//! loads, in this process or another. Its key is the hash of the code that builds it (made
//! by the build script from the source) and its parameters, so a cached file can never be
//! stale; a file missing, damaged or stored for another key is rebuilt, never trusted.

use std::hash::{DefaultHasher, Hash, Hasher};
use std::path::{Path, PathBuf};
use std::time::Instant;

use cathlab_anatomy::real::Anatomy;

use crate::error::Result;

/// Hash of the source that builds cached assets (see `build.rs`).
const CODE_HASH: &str = env!("CATHLAB_ASSET_CODE_HASH");
/// Largest cached file read back (bytes): past it, the anatomy is rebuilt instead.
const MAX_FILE_BYTES: u64 = 8 << 30;

/// A directory of built anatomies.
#[derive(Debug, Clone)]
pub(super) struct DiskCache {
    dir: PathBuf,
}

impl DiskCache {
    pub(super) fn new(dir: &Path) -> Self {
        Self {
            dir: dir.to_owned(),
        }
    }

    /// The file for `key`: the code's hash, then the parameters' (the full key is inside).
    fn file(&self, key: &str) -> PathBuf {
        let mut h = DefaultHasher::new();
        key.hash(&mut h);
        self.dir.join(format!(
            "anatomy-{}-{:016x}.bin",
            &CODE_HASH[..16],
            h.finish()
        ))
    }

    /// The anatomy stored under `key`, or `build`'s, then stored. Reading and writing never
    /// fail the load: a file that cannot be read is rebuilt, one that cannot be written is
    /// logged.
    pub(super) fn anatomy(
        &self,
        key: &str,
        build: impl FnOnce() -> Result<Anatomy>,
    ) -> Result<Anatomy> {
        let full_key = format!("{CODE_HASH}:{key}");
        let file = self.file(key);
        let started = Instant::now();
        match self.read(&file, &full_key) {
            Ok(Some(anatomy)) => {
                tracing::info!(
                    file = %file.display(),
                    seconds = started.elapsed().as_secs_f64(),
                    "anatomy read from the disk cache"
                );
                return Ok(anatomy);
            }
            Ok(None) => {}
            Err(reason) => tracing::warn!(
                file = %file.display(),
                %reason,
                "cached anatomy refused; building it again"
            ),
        }
        let anatomy = build()?;
        if let Err(e) = self.write(&file, &full_key, &anatomy) {
            tracing::warn!(file = %file.display(), error = %e, "cannot write the disk cache");
        }
        Ok(anatomy)
    }

    /// `Ok(None)` when there is no file.
    fn read(&self, file: &Path, full_key: &str) -> std::result::Result<Option<Anatomy>, String> {
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
        let bytes = std::fs::read(file).map_err(|e| e.to_string())?;
        cathlab_anatomy::stored::decode(&bytes, full_key, &file.display().to_string())
            .map(Some)
            .map_err(|e| e.to_string())
    }

    /// Writes beside the file and renames it into place (a reader sees the whole file or
    /// none), then removes the files other code stored (they can never be read again).
    fn write(&self, file: &Path, full_key: &str, anatomy: &Anatomy) -> std::io::Result<()> {
        std::fs::create_dir_all(&self.dir)?;
        let bytes = cathlab_anatomy::stored::encode(anatomy, full_key);
        let partial = file.with_extension(format!("partial-{}", std::process::id()));
        std::fs::write(&partial, &bytes)?;
        std::fs::rename(&partial, file)?;
        let current = format!("anatomy-{}-", &CODE_HASH[..16]);
        for entry in std::fs::read_dir(&self.dir)?.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.starts_with("anatomy-") && name.ends_with(".bin") && !name.starts_with(&current)
            {
                let _ = std::fs::remove_file(entry.path());
            }
        }
        tracing::info!(file = %file.display(), bytes = bytes.len(), "anatomy stored in the disk cache");
        Ok(())
    }
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
        let cache = DiskCache::new(&dir);
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
        let file = cache.file("y");
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
}
