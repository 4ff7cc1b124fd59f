//! Checking a folder of scenes without serving them (`cathlab-server --check-scenes DIR`):
//! every scene file is parsed, its files resolved inside the data roots, its assets built,
//! every node of every instrument found inside the lumen at the start, and the scene
//! stepped for [`CHECK_SECONDS`] with the hands still: a target reached at time zero or a
//! divergence fails it. Each gets a line, ok or the error naming the field.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::assets::AssetCache;
use crate::error::Result;
use crate::scene::field::scene_error;
use crate::scene::{SceneSpec, scene_files};
use crate::world::World;

/// Simulated time each scene is stepped for with the hands still (s).
pub const CHECK_SECONDS: f64 = 0.5;

/// How far any instrument's node may lie past the wall at the start (m): a device placed
/// outside its vessel is a broken scene, not a contact to resolve.
pub const START_PENETRATION_LIMIT_M: f64 = 0.1e-3;

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
    let loaded_s = started.elapsed().as_secs_f64();
    let mut world = World::new(assets.clone())?;
    let path = if spec.stack.is_empty() {
        "start.inserted_mm"
    } else {
        "stack"
    };
    let depth = world.strand().max_penetration_m();
    if depth > START_PENETRATION_LIMIT_M {
        return Err(scene_error(
            path,
            format!(
                "the devices start {:.2} mm outside the lumen (their deepest node; at most \
                 {:.1} mm): start them less far in, or inside a straight stretch",
                depth * 1e3,
                START_PENETRATION_LIMIT_M * 1e3
            ),
        ));
    }
    let steps = (CHECK_SECONDS / assets.spec.time_step_s()).ceil() as usize;
    for _ in 0..steps.max(1) {
        world.step()?;
        if let Some(at) = world.metrics().target_reached_at_s
            && at <= assets.spec.time_step_s() + 1e-9
        {
            return Err(scene_error(
                "target",
                format!(
                    "reached at {at:.3} s, before anything moved: the devices start at the \
                     target ({:.0} mm along the vessels)",
                    assets.route.length * 1e3
                ),
            ));
        }
        if world.metrics().divergence_resets > 0 {
            let reason = world
                .take_events()
                .into_iter()
                .rev()
                .find(|e| e.kind == crate::metrics::EventKind::Divergence)
                .map_or_else(|| "the physics diverged".to_owned(), |e| e.message);
            return Err(scene_error(
                path,
                format!(
                    "step {} of {steps} with the hands still: {reason}",
                    world.step_index()
                ),
            ));
        }
    }
    Ok(format!(
        "{}: {} branches, target {} {:.0} mm along the vessels, {} device(s) inside (deepest \
         {:.3} mm), loaded in {loaded_s:.1} s, {CHECK_SECONDS} s stepped",
        spec.name,
        assets.anatomy.graph.branches.len(),
        assets.spec.target.branch,
        assets.route.length * 1e3,
        assets.devices.len(),
        depth * 1e3,
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
