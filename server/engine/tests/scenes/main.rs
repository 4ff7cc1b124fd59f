//! The scenes in the engine, in one test binary so that the neuro phantom's anatomy and CT
//! (about half a minute to build), which the stroke scenes use, are built once: every scene
//! in `scenes/` loads and its scripted operator arrives (`every_scene`), a clot in the scene
//! (`clot`), the stroke case end to end (`case`, the thrombectomy) and a stack's access
//! stage (`access`). (libtest starts tests in name order: the two long cases come second
//! and third, beside the access stage, not last.)

mod access;
mod case;
mod clot;
mod every_scene;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use cathlab_engine::{AssetCache, Result, SceneAssets, SceneSpec};

/// The scene directory.
fn scenes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

/// Loads `spec` (paths from the scene directory) through the binary's one cache, one load
/// at a time: the first builds the shared anatomy and CT, the others find them.
fn load(spec: &SceneSpec) -> Result<Arc<SceneAssets>> {
    static CACHE: OnceLock<Mutex<AssetCache>> = OnceLock::new();
    // The neuro phantom's anatomy is kept on disk for the other suites that load it.
    let cache = CACHE
        .get_or_init(|| {
            let disk = Path::new(env!("CARGO_TARGET_TMPDIR")).join("asset-cache");
            Mutex::new(AssetCache::default().with_disk_cache(&disk))
        })
        .lock();
    cache
        .unwrap_or_else(|e| e.into_inner())
        .load(spec, &scenes())
}
