//! The session manager: the scene catalog, the asset cache shared by all sessions, and the
//! running sessions by id.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use parking_lot::{Mutex, RwLock};

use crate::assets::{AssetCache, SceneAssets};
use crate::error::{EngineError, Result};
use crate::imaging::SharedRenderer;
use crate::scene::{SceneCatalog, SceneFormat, SceneSpec};
use crate::session::{Recorder, Session, SessionContext, SessionSettings};
use crate::telemetry::EngineMetrics;

/// Engine configuration.
#[derive(Debug, Clone)]
pub struct EngineSettings {
    /// Directory of scene files; inline scenes resolve relative paths from here too.
    pub scenes_dir: PathBuf,
    /// Session thread knobs.
    pub session: SessionSettings,
    /// Most sessions running at once.
    pub max_sessions: usize,
    /// Most replays running at once (each takes a core while it runs, niced below live
    /// physics).
    pub max_replays: usize,
    /// Bytes the shared scene assets may hold beyond what running sessions use; a scene
    /// estimated larger is refused before anything loads.
    pub asset_budget_bytes: usize,
    /// Directories whose files scenes may name; empty: the scenes directory and `data`
    /// beside it.
    pub data_roots: Vec<PathBuf>,
    /// Where anatomies that take long to build are kept between runs (none: rebuilt).
    pub asset_disk_cache: Option<PathBuf>,
    /// Most bytes the disk cache's files take together.
    pub asset_disk_cache_bytes: u64,
}

/// Where a session's scene comes from.
#[derive(Debug, Clone)]
pub enum SceneSource {
    /// A catalog scene by name.
    Named(String),
    /// A scene text.
    Inline(String, SceneFormat),
}

/// Sessions and what they share.
pub struct Engine {
    settings: EngineSettings,
    catalog: SceneCatalog,
    assets: AssetCache,
    sessions: RwLock<HashMap<String, Arc<Session>>>,
    /// Sessions admitted and still loading, and replays running: counted with the running
    /// sessions under this lock, so that concurrent requests cannot pass a limit together.
    admitted: Arc<Mutex<Admitted>>,
    context: SessionContext,
}

/// What holds a place besides the running sessions.
#[derive(Debug, Default)]
struct Admitted {
    loading: usize,
    replays: usize,
}

/// A place among the sessions, held while one loads; given back if the load fails.
struct Admission<'a> {
    engine: &'a Engine,
    kept: bool,
}

impl Drop for Admission<'_> {
    fn drop(&mut self) {
        if !self.kept {
            self.engine.admitted.lock().loading -= 1;
        }
    }
}

/// A place among the replays, given back when dropped (the replay ended or was abandoned).
#[derive(Debug)]
pub struct ReplayPermit {
    admitted: Arc<Mutex<Admitted>>,
}

impl Drop for ReplayPermit {
    fn drop(&mut self) {
        self.admitted.lock().replays -= 1;
    }
}

impl std::fmt::Debug for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Engine")
            .field("scenes", &self.catalog.scenes().len())
            .field("sessions", &self.sessions.read().len())
            .finish_non_exhaustive()
    }
}

impl Engine {
    /// Reads the scene catalog; sessions will record to `recorder` and render on `renderer`.
    pub fn new(
        settings: EngineSettings,
        recorder: Arc<dyn Recorder>,
        renderer: SharedRenderer,
        metrics: EngineMetrics,
    ) -> Result<Self> {
        let catalog = SceneCatalog::read_dir(&settings.scenes_dir)?;
        let roots = if settings.data_roots.is_empty() {
            [
                settings.scenes_dir.clone(),
                settings.scenes_dir.join("../data"),
            ]
            .into_iter()
            .filter(|d| d.is_dir())
            .collect()
        } else {
            settings.data_roots.clone()
        };
        let mut assets = AssetCache::with_budget(settings.asset_budget_bytes)
            .with_max_scene_bytes(settings.asset_budget_bytes)
            .with_roots(&roots)?;
        if let Some(dir) = &settings.asset_disk_cache {
            assets = assets
                .with_disk_cache(dir)
                .with_disk_cache_limit(settings.asset_disk_cache_bytes);
        }
        // A catalog scene naming a missing file, or one outside the data roots, stops the
        // server at start rather than a trainee at CreateSession.
        for (spec, file) in catalog.scenes() {
            let base = file.parent().unwrap_or(Path::new("."));
            assets.check_files(spec, base).map_err(|e| match e {
                EngineError::Scene { path, reason } => EngineError::Scene {
                    path: format!("{}: {path}", file.display()),
                    reason,
                },
                other => other,
            })?;
        }
        Ok(Self {
            context: SessionContext {
                recorder,
                renderer,
                metrics,
                settings: settings.session,
            },
            settings,
            catalog,
            assets,
            sessions: RwLock::new(HashMap::new()),
            admitted: Arc::default(),
        })
    }

    /// The scenes.
    pub fn catalog(&self) -> &SceneCatalog {
        &self.catalog
    }

    /// The server-wide metrics.
    pub fn metrics(&self) -> &EngineMetrics {
        &self.context.metrics
    }

    /// The scene a source names, with the directory its relative paths start from.
    pub fn scene(&self, source: &SceneSource) -> Result<(SceneSpec, PathBuf)> {
        match source {
            SceneSource::Named(name) => {
                let (spec, base) = self.catalog.get(name)?;
                Ok((spec.clone(), base))
            }
            SceneSource::Inline(text, format) => {
                let mut spec = SceneSpec::parse(text, *format)?;
                if spec.name.is_empty() {
                    spec.name = "inline".into();
                }
                Ok((spec, self.settings.scenes_dir.clone()))
            }
        }
    }

    /// Loads (or finds loaded) the assets of a scene.
    pub fn load(&self, spec: &SceneSpec, base: &Path) -> Result<Arc<SceneAssets>> {
        self.assets.load(spec, base)
    }

    /// Starts a session (loading the scene if no session has yet). Blocks while loading.
    pub fn create(
        &self,
        id: String,
        label: String,
        spec: &SceneSpec,
        base: &Path,
    ) -> Result<Arc<Session>> {
        let estimate = spec.estimated_bytes();
        if estimate > self.settings.asset_budget_bytes {
            return Err(EngineError::Exhausted(format!(
                "the scene needs about {} MiB of assets, over the server's budget of {} MiB",
                estimate >> 20,
                self.settings.asset_budget_bytes >> 20
            )));
        }
        self.assets.check_files(spec, base)?;
        let mut admission = self.admit()?;
        let assets = self.load(spec, base)?;
        let session = Session::start(id.clone(), label, assets, self.context.clone())?;
        let mut admitted = self.admitted.lock();
        self.sessions.write().insert(id, session.clone());
        admitted.loading -= 1;
        admission.kept = true;
        Ok(session)
    }

    /// Takes a place among the sessions, or says the server is full. Running and loading
    /// sessions are counted together under one lock.
    fn admit(&self) -> Result<Admission<'_>> {
        let mut admitted = self.admitted.lock();
        if self.sessions.read().len() + admitted.loading >= self.settings.max_sessions {
            return Err(EngineError::Exhausted(format!(
                "the server runs its maximum of {} sessions",
                self.settings.max_sessions
            )));
        }
        admitted.loading += 1;
        Ok(Admission {
            engine: self,
            kept: false,
        })
    }

    /// Takes a place among the replays, or says the server runs its maximum of them.
    pub fn replay_permit(&self) -> Result<ReplayPermit> {
        let mut admitted = self.admitted.lock();
        if admitted.replays >= self.settings.max_replays {
            return Err(EngineError::Exhausted(format!(
                "the server runs its maximum of {} replays at once; try again when one ends",
                self.settings.max_replays
            )));
        }
        admitted.replays += 1;
        Ok(ReplayPermit {
            admitted: self.admitted.clone(),
        })
    }

    /// Most replays at once (the settings' `max_replays`).
    pub fn max_replays(&self) -> usize {
        self.settings.max_replays
    }

    /// A running session.
    pub fn get(&self, id: &str) -> Result<Arc<Session>> {
        self.sessions
            .read()
            .get(id)
            .cloned()
            .ok_or_else(|| EngineError::NotFound(format!("session {id:?}")))
    }

    /// Every running session.
    pub fn sessions(&self) -> Vec<Arc<Session>> {
        self.sessions.read().values().cloned().collect()
    }

    /// Stops a session and forgets it.
    pub fn close(&self, id: &str) -> Result<Arc<Session>> {
        let session = self
            .sessions
            .write()
            .remove(id)
            .ok_or_else(|| EngineError::NotFound(format!("session {id:?}")))?;
        session.close();
        Ok(session)
    }

    /// Stops every session (graceful shutdown).
    pub fn shutdown(&self) {
        let all: Vec<_> = self.sessions.write().drain().map(|(_, s)| s).collect();
        for s in all {
            s.close();
        }
    }
}
