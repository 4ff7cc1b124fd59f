//! A directory of scenes: its scene files, read and found by name.

use std::path::{Path, PathBuf};

use super::spec::SceneSpec;
use crate::error::{EngineError, Result};

/// Scenes found in a directory, by name.
#[derive(Debug, Clone, Default)]
pub struct SceneCatalog {
    scenes: Vec<(SceneSpec, PathBuf)>,
}

/// The scene files of `dir`: its `.toml` and `.json` files, sorted by name.
pub fn scene_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|source| EngineError::Io {
        file: dir.to_owned(),
        source,
    })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml" || e == "json"))
        .collect();
    files.sort();
    Ok(files)
}

impl SceneCatalog {
    /// Reads every `.toml` and `.json` scene in `dir` (sorted by name); a scene that does not
    /// parse is an error naming its file.
    pub fn read_dir(dir: &Path) -> Result<Self> {
        let scenes = scene_files(dir)?
            .into_iter()
            .map(|f| SceneSpec::read(&f).map(|s| (s, f)))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self { scenes })
    }

    /// The scenes with the files they came from.
    pub fn scenes(&self) -> &[(SceneSpec, PathBuf)] {
        &self.scenes
    }

    /// The scenes' names, in the catalogue's order.
    pub fn names(&self) -> Vec<&str> {
        self.scenes.iter().map(|(s, _)| s.name.as_str()).collect()
    }

    /// A scene by name, with the directory its relative paths start from.
    pub fn get(&self, name: &str) -> Result<(&SceneSpec, PathBuf)> {
        self.scenes
            .iter()
            .find(|(s, _)| s.name == name)
            .map(|(s, f)| (s, f.parent().unwrap_or(Path::new(".")).to_owned()))
            .ok_or_else(|| EngineError::NotFound(format!("scene {name:?}")))
    }
}
