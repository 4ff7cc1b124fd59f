//! Checking a folder of scenes without serving them (`cathlab-server --check-scenes DIR`):
//! every scene file is parsed, its files resolved inside the data roots, its assets built
//! and one physics step run; each gets a line, ok or the error naming the field.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::assets::AssetCache;
use crate::error::Result;
use crate::scene::{SceneSpec, scene_files};
use crate::world::World;

/// One scene file's outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneCheck {
    /// The file.
    pub file: PathBuf,
    /// What loaded (branches, route, target, seconds), or why it failed.
    pub outcome: std::result::Result<String, String>,
}

impl SceneCheck {
    /// One line for people: `ok   name: …` or `FAIL file: …`.
    pub fn line(&self) -> String {
        match &self.outcome {
            Ok(summary) => format!("ok   {summary}"),
            Err(reason) => format!("FAIL {}: {reason}", self.file.display()),
        }
    }
}

/// The data roots a scene folder's files may lie in when none are configured: the folder
/// and `../data` beside it (as the server uses).
pub fn default_roots(dir: &Path) -> Vec<PathBuf> {
    [dir.to_owned(), dir.join("../data")]
        .into_iter()
        .filter(|d| d.is_dir())
        .collect()
}

fn check_one(file: &Path, roots: &[PathBuf], disk_cache: Option<&Path>) -> Result<String> {
    let started = Instant::now();
    let spec = SceneSpec::read(file)?;
    let base = file.parent().unwrap_or(Path::new("."));
    let mut cache = AssetCache::default().with_roots(roots)?;
    if let Some(dir) = disk_cache {
        cache = cache.with_disk_cache(dir);
    }
    cache.check_files(&spec, base)?;
    let assets = cache.load(&spec, base)?;
    let mut world = World::new(assets.clone())?;
    world.step()?;
    Ok(format!(
        "{}: {} branches, target {} {:.0} mm along the vessels, {} device(s), loaded in {:.1} s",
        spec.name,
        assets.anatomy.graph.branches.len(),
        assets.spec.target.branch,
        assets.route.length * 1e3,
        assets.devices.len(),
        started.elapsed().as_secs_f64()
    ))
}

/// Checks every `.toml` and `.json` scene in `dir` (sorted by name); `roots` confine the
/// files they name (empty: [`default_roots`]); anatomies that take long to build are kept in
/// `disk_cache` when given (`AssetCache::with_disk_cache`).
pub fn check_scenes(
    dir: &Path,
    roots: &[PathBuf],
    disk_cache: Option<&Path>,
) -> Result<Vec<SceneCheck>> {
    let files = scene_files(dir)?;
    let roots = if roots.is_empty() {
        default_roots(dir)
    } else {
        roots.to_vec()
    };
    Ok(files
        .into_iter()
        .map(|file| {
            let outcome = check_one(&file, &roots, disk_cache).map_err(|e| e.to_string());
            SceneCheck { file, outcome }
        })
        .collect())
}
