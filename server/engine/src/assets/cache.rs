//! The asset cache: one copy of every anatomy, CT volume and loaded scene for all sessions,
//! bounded by bytes (least recently used first out, nothing a session holds), and the files
//! a scene may name (inside the data roots, MetaImage data files included).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use cathlab_anatomy::real::Anatomy;
use cathlab_xray::Volume;
use parking_lot::Mutex;

use super::disk::DiskCache;
use super::errors::scene_error;
use super::scene_assets::SceneAssets;
use crate::error::{EngineError, Result};
use crate::scene::{AnatomySpec, CtSpec, SceneSpec};

/// Bytes the asset cache may hold by default (2 GiB).
pub const DEFAULT_ASSET_BUDGET_BYTES: usize = 2 << 30;
/// Default most bytes the disk cache of built anatomies keeps (8 GiB).
pub const DEFAULT_DISK_CACHE_BYTES: u64 = 8 << 30;

/// A cached asset: the value, what it costs, and when it was last used.
pub(super) struct Cached<T> {
    pub(super) value: Arc<T>,
    bytes: usize,
    pub(super) used: u64,
}

/// What one scene's load made that the cache did not have: kept only if the whole scene
/// loads, so that a scene failing late leaves nothing behind.
#[derive(Default)]
pub(super) struct Staged {
    pub(super) anatomy: Option<(String, Arc<Anatomy>)>,
    pub(super) volume: Option<(String, Arc<Volume>)>,
}

/// Loads scenes, keeping one copy of every anatomy and volume for all sessions. The cache is
/// bounded by bytes: past its budget, the least recently used scenes and assets that no
/// session holds are dropped. A scene that fails to load keeps nothing.
pub struct AssetCache {
    pub(super) anatomies: Mutex<HashMap<String, Cached<Anatomy>>>,
    pub(super) volumes: Mutex<HashMap<String, Cached<Volume>>>,
    scenes: Mutex<HashMap<String, Cached<SceneAssets>>>,
    budget_bytes: usize,
    /// Most bytes one scene's anatomy and CT may take, counted as built (none by default).
    max_scene_bytes: usize,
    clock: AtomicU64,
    /// Directories scene files may name files in (canonical); empty: anywhere.
    roots: Vec<PathBuf>,
    /// Where anatomies that take long to build are kept between runs (none: not kept).
    pub(super) disk: Option<DiskCache>,
}

impl Default for AssetCache {
    fn default() -> Self {
        Self::with_budget(DEFAULT_ASSET_BUDGET_BYTES)
    }
}

impl std::fmt::Debug for AssetCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AssetCache")
            .field("anatomies", &self.anatomies.lock().len())
            .field("volumes", &self.volumes.lock().len())
            .field("bytes", &self.bytes())
            .field("budget_bytes", &self.budget_bytes)
            .finish()
    }
}

impl AssetCache {
    /// An empty cache that holds at most `budget_bytes` of assets no session uses.
    pub fn with_budget(budget_bytes: usize) -> Self {
        Self {
            anatomies: Mutex::new(HashMap::new()),
            volumes: Mutex::new(HashMap::new()),
            scenes: Mutex::new(HashMap::new()),
            budget_bytes,
            max_scene_bytes: usize::MAX,
            clock: AtomicU64::new(0),
            roots: Vec::new(),
            disk: None,
        }
    }

    /// Keeps built anatomies (the neuro phantom's surface and query grid: tens of seconds; an
    /// imported surface with its circle of Willis, a CT's segmentation: seconds) in `dir`,
    /// under a key made of the hash of the code that builds them, their parameters and the
    /// SHA-256 of the files they are built from, and reads them back in later loads and runs.
    /// The directory holds at most [`DEFAULT_DISK_CACHE_BYTES`]
    /// ([`AssetCache::with_disk_cache_limit`] sets another).
    pub fn with_disk_cache(mut self, dir: &Path) -> Self {
        self.disk = Some(DiskCache::new(dir, DEFAULT_DISK_CACHE_BYTES));
        self
    }

    /// Most bytes the disk cache's files may take together (bytes); past it the least
    /// recently used are removed when another is stored.
    pub fn with_disk_cache_limit(mut self, max_bytes: u64) -> Self {
        if let Some(disk) = &mut self.disk {
            disk.max_bytes = max_bytes;
        }
        self
    }

    /// Refuses a scene whose anatomy and CT, as built, take more than `bytes` (what was read,
    /// not the estimate made before loading); it keeps nothing.
    pub fn with_max_scene_bytes(mut self, bytes: usize) -> Self {
        self.max_scene_bytes = bytes;
        self
    }

    /// Confines the files scenes may name to `roots` (each must exist).
    pub fn with_roots(mut self, roots: &[PathBuf]) -> Result<Self> {
        self.roots = roots
            .iter()
            .map(|r| {
                r.canonicalize().map_err(|source| EngineError::Io {
                    file: r.clone(),
                    source,
                })
            })
            .collect::<Result<_>>()?;
        Ok(self)
    }

    /// The file `path` (relative to `base`) names, canonical, if it exists inside the data
    /// roots; a MetaImage header's data file must be inside them too. The errors name
    /// `field` and never the server's paths.
    pub(super) fn resolve(&self, base: &Path, path: &Path, field: &str) -> Result<PathBuf> {
        let joined = if path.is_absolute() {
            path.to_owned()
        } else {
            base.join(path)
        };
        let inside =
            |p: &Path| self.roots.is_empty() || self.roots.iter().any(|r| p.starts_with(r));
        // One answer for "missing" and "outside": the error tells nothing of files outside.
        let refused = || scene_error(field, "names no file in the server's data directories");
        let canonical = joined.canonicalize().map_err(|e| {
            // Out of file descriptors is the server's state, not the scene's fault: said as
            // what it is (EMFILE, ENFILE).
            if matches!(e.raw_os_error(), Some(24) | Some(23)) {
                tracing::error!("{field}: out of file descriptors: {e}");
                EngineError::Exhausted(
                    "the server is out of file descriptors; try again shortly".into(),
                )
            } else {
                refused()
            }
        })?;
        if !inside(&canonical) {
            return Err(refused());
        }
        if let Some(data) = metaimage_data_file(&canonical) {
            let dir = canonical.parent().unwrap_or(Path::new("/"));
            let ok = dir
                .join(&data)
                .canonicalize()
                .is_ok_and(|d| inside(&d) && !data.contains('%') && data != "LIST");
            if !ok {
                return Err(scene_error(
                    field,
                    "its MetaImage data file (ElementDataFile) is missing or outside the server's data directories",
                ));
            }
        }
        Ok(canonical)
    }

    /// Checks that every file `spec` names (relative to `base`) exists inside the data roots,
    /// MetaImage data files included, without loading anything; the error names the field.
    pub fn check_files(&self, spec: &SceneSpec, base: &Path) -> Result<()> {
        match &spec.anatomy {
            AnatomySpec::ArchToCow { dir, .. } => {
                self.resolve(base, dir, "anatomy.dir")?;
            }
            AnatomySpec::CtSegmentation { volume, .. } => {
                self.resolve(base, volume, "anatomy.volume")?;
            }
            AnatomySpec::Surface {
                file, centerlines, ..
            } => {
                self.resolve(base, file, "anatomy.file")?;
                if let Some(c) = centerlines {
                    self.resolve(base, c, "anatomy.centerlines")?;
                }
            }
            AnatomySpec::NeuroPhantom { .. } => {}
        }
        if let CtSpec::File { path, .. } = &spec.ct {
            self.resolve(base, path, "ct.path")?;
        }
        Ok(())
    }

    /// Bytes held by the cached anatomies and volumes.
    pub fn bytes(&self) -> usize {
        self.anatomies
            .lock()
            .values()
            .map(|c| c.bytes)
            .sum::<usize>()
            + self.volumes.lock().values().map(|c| c.bytes).sum::<usize>()
    }

    /// How many anatomies, volumes and scenes are cached.
    pub fn counts(&self) -> (usize, usize, usize) {
        (
            self.anatomies.lock().len(),
            self.volumes.lock().len(),
            self.scenes.lock().len(),
        )
    }

    pub(super) fn tick(&self) -> u64 {
        self.clock.fetch_add(1, Ordering::Relaxed)
    }

    /// Loads `spec` (relative paths from `base`), reusing whatever an identical scene or an
    /// identical anatomy/CT loaded before.
    pub fn load(&self, spec: &SceneSpec, base: &Path) -> Result<Arc<SceneAssets>> {
        let key = format!(
            "{}|{}",
            base.display(),
            serde_json::to_string(spec).unwrap_or_default()
        );
        let now = self.tick();
        if let Some(found) = self.scenes.lock().get_mut(&key) {
            found.used = now;
            return Ok(found.value.clone());
        }
        let mut staged = Staged::default();
        let assets = Arc::new(self.build(spec, base, &mut staged)?);
        // What was actually read and built, not the estimate made before: a scene whose
        // assets pass the budget is refused (and keeps nothing).
        let built = staged
            .anatomy
            .as_ref()
            .map_or(0, |(_, a)| a.lumen.memory_bytes())
            + staged.volume.as_ref().map_or(0, |(_, v)| v.memory_bytes());
        if built > self.max_scene_bytes {
            return Err(EngineError::Scene {
                path: "scene".into(),
                reason: format!(
                    "its anatomy and CT take {} MiB, more than the {} MiB the server's asset \
                     budget allows (asset_cache_mib)",
                    built >> 20,
                    self.max_scene_bytes >> 20
                ),
            });
        }
        if let Some((k, anatomy)) = staged.anatomy {
            let bytes = anatomy.lumen.memory_bytes();
            self.anatomies.lock().insert(
                k,
                Cached {
                    value: anatomy,
                    bytes,
                    used: now,
                },
            );
        }
        if let Some((k, volume)) = staged.volume {
            let bytes = volume.memory_bytes();
            self.volumes.lock().insert(
                k,
                Cached {
                    value: volume,
                    bytes,
                    used: now,
                },
            );
        }
        self.scenes.lock().insert(
            key,
            Cached {
                value: assets.clone(),
                bytes: 0,
                used: now,
            },
        );
        self.evict();
        Ok(assets)
    }

    /// Drops the least recently used scenes, then assets, that nothing else holds, until the
    /// cache is within its budget (or everything left is in use).
    fn evict(&self) {
        fn oldest_unused<T>(map: &HashMap<String, Cached<T>>) -> Option<(String, u64)> {
            map.iter()
                .filter(|(_, c)| Arc::strong_count(&c.value) == 1)
                .min_by_key(|(_, c)| c.used)
                .map(|(k, c)| (k.clone(), c.used))
        }
        while self.bytes() > self.budget_bytes {
            let scene = oldest_unused(&self.scenes.lock());
            if let Some((k, _)) = scene {
                self.scenes.lock().remove(&k);
                continue;
            }
            let anatomy = oldest_unused(&self.anatomies.lock());
            let volume = oldest_unused(&self.volumes.lock());
            match (anatomy, volume) {
                (Some((a, ta)), Some((_, tv))) if ta <= tv => {
                    self.anatomies.lock().remove(&a);
                }
                (_, Some((v, _))) => {
                    self.volumes.lock().remove(&v);
                }
                (Some((a, _)), None) => {
                    self.anatomies.lock().remove(&a);
                }
                (None, None) => break,
            }
        }
    }
}

/// The `ElementDataFile` of a MetaImage header (`None` for `LOCAL` data or a file that is not
/// a `.mhd` header).
fn metaimage_data_file(header: &Path) -> Option<String> {
    let is_mhd = header
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mhd"));
    if !is_mhd {
        return None;
    }
    let mut text = Vec::new();
    use std::io::Read;
    std::fs::File::open(header)
        .ok()?
        .take(64 << 10)
        .read_to_end(&mut text)
        .ok()?;
    String::from_utf8_lossy(&text).lines().find_map(|line| {
        let (key, value) = line.split_once('=')?;
        (key.trim() == "ElementDataFile" && value.trim() != "LOCAL")
            .then(|| value.trim().to_owned())
    })
}
