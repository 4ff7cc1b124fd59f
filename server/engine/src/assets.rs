//! What sessions on the same scene share, loaded once: the anatomy (lumen surface and vessel
//! graph), the CT volume, the flow network, the devices and the start pose. Sessions hold
//! `Arc`s to these; nothing here is copied per session.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use cathlab_anatomy::real::{Anatomy, load_arch_to_cow};
use cathlab_anatomy::{Lumen, VesselGraph, VesselPath};
use cathlab_hemo::{
    ClotComposition, FlowNetwork, GraphFlowSettings, InletCondition, MMHG, Occlusion,
    network_from_graph,
};
use cathlab_physics::autopilot::{Autopilot, AutopilotSettings};
use cathlab_physics::{Device, Wall, WallProbe, presets};
use cathlab_xray::phantom::BodyPhantom;
use cathlab_xray::scene::ARCH_TO_COW_TO_LPS;
use cathlab_xray::{CArm, DetectorGeometry, DeviceAppearance, Volume};
use nalgebra::{Matrix3, Point3, Vector3};
use parking_lot::Mutex;

use crate::error::{EngineError, Result};
use crate::scene::{AnatomySpec, CtSpec, DeviceSpec, SceneSpec};

/// The anatomy's lumen as the device's wall, shared between sessions.
#[derive(Debug, Clone)]
pub struct SharedWall(pub Arc<Anatomy>);

impl Wall for SharedWall {
    fn probe(&self, point: &Vector3<f64>, search_m: f64) -> Option<WallProbe> {
        let lumen: &Lumen = &self.0.lumen;
        lumen.probe(point, search_m)
    }
}

/// A scene loaded and ready for sessions.
pub struct SceneAssets {
    /// The scene.
    pub spec: SceneSpec,
    /// Vessels and wall, in the anatomy's own frame (m).
    pub anatomy: Arc<Anatomy>,
    /// Rotation from the anatomy's frame to patient LPS.
    pub to_lps: Matrix3<f64>,
    /// The CT (LPS).
    pub volume: Arc<Volume>,
    /// The selectable devices and how each looks on X-ray; for a coaxial scene, the stack's
    /// instruments at the start, outermost first.
    pub devices: Vec<(Device, DeviceAppearance)>,
    /// The back table of a stack scene: devices an instrument may be exchanged for, besides
    /// the catalogue's.
    pub spares: Vec<(Device, DeviceAppearance)>,
    /// Entry point and direction (anatomy frame, m).
    pub entry: (Vector3<f64>, Vector3<f64>),
    /// Route from the access point to the target.
    pub route: VesselPath,
    /// The target branch's index in the graph.
    pub target_branch: usize,
    /// The route sampled every [`ROUTE_SPACING_M`] (anatomy frame, m).
    pub route_samples: Vec<Point3<f64>>,
    /// The vessel's radius at each route sample (m).
    pub route_radii: Vec<f64>,
    /// How far along the route the target counts as reached (m): the route up to the target
    /// branch plus `target.reach_mm`.
    pub goal_along_m: f64,
    /// The target: the route's last `target.reach_mm` before the goal, every 2 mm (LPS, m).
    pub target_path_lps: Vec<Point3<f64>>,
    /// The C-arm at the start.
    pub carm: CArm,
    /// The flow network (vessel i = graph branch i; pial collaterals, when the scene has
    /// them, after the branches), when the scene has flow.
    pub network: Option<FlowNetwork>,
    /// The network without its collaterals, when it has some: eTICI grades the antegrade
    /// reperfusion on it.
    pub grading_network: Option<FlowNetwork>,
    /// The scene's clots, checked against the graph (vessel i = graph branch i).
    pub clots: Vec<Occlusion>,
}

/// Spacing of the route samples (m).
pub const ROUTE_SPACING_M: f64 = 1e-3;

impl SceneAssets {
    /// How far the tip at `tip` (anatomy frame, m) still has to go along the route to reach
    /// the target (m; 0 once past it): the goal's distance along the route less the nearest
    /// route sample's.
    pub fn remaining_to_target_m(&self, tip: &Point3<f64>) -> f64 {
        (self.goal_along_m - self.along_route_m(tip)).max(0.0)
    }

    /// How far along the route the route sample nearest to `point` (anatomy frame, m) lies
    /// (m).
    pub fn along_route_m(&self, point: &Point3<f64>) -> f64 {
        let nearest = self
            .route_samples
            .iter()
            .enumerate()
            .min_by(|a, b| {
                (a.1 - point)
                    .norm_squared()
                    .total_cmp(&(b.1 - point).norm_squared())
            })
            .map_or(0, |(i, _)| i);
        nearest as f64 * ROUTE_SPACING_M
    }
}

impl SceneAssets {
    /// The scene's scripted two-hand operator as the physics takes it, if it has one.
    pub fn two_hand_plan(&self) -> Result<Option<cathlab_physics::two_hands::TwoHandPlan>> {
        use cathlab_physics::autopilot::AutopilotSettings;
        use cathlab_physics::two_hands::{Finish, TwoHandPlan};
        let Some(a) = &self.spec.autopilot else {
            return Ok(None);
        };
        let settings = |lookahead_mm: f64, reach_mm: f64| AutopilotSettings {
            push_speed_m_s: a.push_speed_mm_s * 1e-3,
            lookahead_m: lookahead_mm * 1e-3,
            reach_m: reach_mm * 1e-3,
            ..AutopilotSettings::default()
        };
        let exchange = match &a.exchange {
            None => None,
            Some(x) => {
                let graph = &self.anatomy.graph;
                let mut along = 0.0;
                let mut found = false;
                for leg in &self.route.legs {
                    if graph.branches[leg.branch].name == x.branch {
                        found = true;
                        break;
                    }
                    along += (leg.to_arc - leg.from_arc).abs();
                }
                if !found {
                    return Err(scene_error(
                        "autopilot.exchange.branch",
                        format!("'{}' is not on the route to the target", x.branch),
                    ));
                }
                let device = match x.spare {
                    Some(k) => self.spares[k].0.clone(),
                    None => crate::scene::catalogue()
                        .device(&x.device)
                        .map_err(|e| scene_error("autopilot.exchange.device", e))?,
                };
                Some((
                    along + x.into_mm * 1e-3,
                    device,
                    settings(x.lookahead_mm, x.wire_reach_mm),
                ))
            }
        };
        if let Some(x) = &a.access {
            let graph = &self.anatomy.graph;
            let legs = &self.route.legs;
            let at = legs
                .iter()
                .position(|leg| graph.branches[leg.branch].name == x.branch);
            if at.is_none_or(|k| k + 1 >= legs.len()) {
                return Err(scene_error(
                    "autopilot.access.branch",
                    format!(
                        "'{}' is not on the route before the target's branch",
                        x.branch.chars().take(64).collect::<String>()
                    ),
                ));
            }
        }
        Ok(Some(TwoHandPlan {
            catheter_lag_m: a.catheter_lag_mm * 1e-3,
            catheter_track_m: a.catheter_track_mm * 1e-3,
            exchange,
            autopilot: settings(a.lookahead_mm, a.wire_reach_mm),
            finish: Finish::TrackCatheter,
            outer_parks_m: a
                .park_along_mm
                .iter()
                .map(|mm| (mm - self.spec.start.along_route_mm) * 1e-3)
                .collect(),
        }))
    }
}

impl std::fmt::Debug for SceneAssets {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneAssets")
            .field("scene", &self.spec.name)
            .field("volume_dims", &self.volume.dims)
            .finish_non_exhaustive()
    }
}

impl SceneAssets {
    /// A point of the anatomy's frame in LPS.
    pub fn point_to_lps(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.to_lps * p
    }
}

/// Bytes the asset cache may hold by default (2 GiB).
pub const DEFAULT_ASSET_BUDGET_BYTES: usize = 2 << 30;

/// A cached asset: the value, what it costs, and when it was last used.
struct Cached<T> {
    value: Arc<T>,
    bytes: usize,
    used: u64,
}

/// What one scene's load made that the cache did not have: kept only if the whole scene
/// loads, so that a scene failing late leaves nothing behind.
#[derive(Default)]
struct Staged {
    anatomy: Option<(String, Arc<Anatomy>)>,
    volume: Option<(String, Arc<Volume>)>,
}

/// Loads scenes, keeping one copy of every anatomy and volume for all sessions. The cache is
/// bounded by bytes: past its budget, the least recently used scenes and assets that no
/// session holds are dropped. A scene that fails to load keeps nothing.
pub struct AssetCache {
    anatomies: Mutex<HashMap<String, Cached<Anatomy>>>,
    volumes: Mutex<HashMap<String, Cached<Volume>>>,
    scenes: Mutex<HashMap<String, Cached<SceneAssets>>>,
    budget_bytes: usize,
    /// Most bytes one scene's anatomy and CT may take, counted as built (none by default).
    max_scene_bytes: usize,
    clock: AtomicU64,
    /// Directories scene files may name files in (canonical); empty: anywhere.
    roots: Vec<PathBuf>,
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

fn scene_error(path: &str, reason: impl std::fmt::Display) -> EngineError {
    EngineError::Scene {
        path: path.into(),
        reason: reason.to_string(),
    }
}

/// The physics device and X-ray appearance of a preset.
pub fn device_of(spec: &DeviceSpec) -> (Device, DeviceAppearance) {
    match spec {
        DeviceSpec::Guidewire035 => (presets::guidewire_035(), DeviceAppearance::guidewire_035()),
        DeviceSpec::Guidewire035Shaped {
            bend_deg,
            bend_length_mm,
        } => (
            presets::guidewire_035_shaped(bend_deg.to_radians(), bend_length_mm * 1e-3),
            DeviceAppearance::guidewire_035(),
        ),
        DeviceSpec::Microwire014 => (
            presets::micro_guidewire_014(),
            DeviceAppearance::microwire_014(),
        ),
        DeviceSpec::Catheter5f => (
            presets::diagnostic_catheter_5f(),
            DeviceAppearance::catheter_5f(),
        ),
    }
}

/// How a catalogue device looks on X-ray: its distal section's outer and lumen radii, a shaft
/// of its kind (a wire's solid nitinol or steel core; a catheter's braid or coil, or its
/// barium-loaded jacket, as a fraction of metal in its wall) and its catalogue markers in
/// platinum.
pub fn appearance_of_entry(entry: &cathlab_physics::CatalogueEntry) -> DeviceAppearance {
    use cathlab_physics::DeviceKind;
    use cathlab_xray::LayerMaterial;
    use cathlab_xray::layers::DeviceBand;
    let (outer_radius_m, inner_radius_m) = entry.device.sections.last().map_or((0.0, 0.0), |s| {
        (
            s.cross_section.outer_radius_m,
            s.cross_section.inner_radius_m,
        )
    });
    let fill = match entry.kind {
        DeviceKind::Guidewire | DeviceKind::Microwire | DeviceKind::StentRetriever => 1.0,
        DeviceKind::Catheter => 0.15,
        DeviceKind::Guide | DeviceKind::Sheath | DeviceKind::DistalAccess => 0.2,
        DeviceKind::Microcatheter => 0.1,
    };
    DeviceAppearance {
        outer_radius_m,
        inner_radius_m,
        material: LayerMaterial::Nitinol,
        fill,
        bands: entry
            .markers
            .iter()
            .map(|m| DeviceBand {
                from_tip_m: m.from_tip_m,
                length_m: m.length_m,
                material: LayerMaterial::Platinum,
                fill: m.fill,
            })
            .collect(),
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
        }
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
    fn resolve(&self, base: &Path, path: &Path, field: &str) -> Result<PathBuf> {
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

    fn tick(&self) -> u64 {
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

    fn anatomy(
        &self,
        spec: &AnatomySpec,
        base: &Path,
        staged: &mut Staged,
    ) -> Result<(Arc<Anatomy>, Matrix3<f64>)> {
        // The file the anatomy names, resolved (and checked) once.
        let file = match spec {
            AnatomySpec::ArchToCow { dir, .. } => Some(self.resolve(base, dir, "anatomy.dir")?),
            AnatomySpec::CtSegmentation { volume, .. } => {
                Some(self.resolve(base, volume, "anatomy.volume")?)
            }
            AnatomySpec::Surface { file, .. } => Some(self.resolve(base, file, "anatomy.file")?),
            AnatomySpec::NeuroPhantom { .. } => None,
        };
        let surface_centerlines = match spec {
            AnatomySpec::Surface {
                centerlines: Some(c),
                ..
            } => Some(self.resolve(base, c, "anatomy.centerlines")?),
            _ => None,
        };
        let shown = file.as_deref().unwrap_or(Path::new("")).display();
        let (key, to_lps) = match spec {
            AnatomySpec::ArchToCow {
                circle_of_willis, ..
            } => (
                format!("arch_to_cow:{shown}:{circle_of_willis}"),
                Matrix3::from_fn(|r, c| ARCH_TO_COW_TO_LPS[r][c]),
            ),
            AnatomySpec::NeuroPhantom { seed, tortuosity } => {
                (format!("neuro:{seed}:{tortuosity}"), Matrix3::identity())
            }
            AnatomySpec::CtSegmentation { seed_voxel, .. } => (
                format!("segmentation:{shown}:{seed_voxel:?}"),
                Matrix3::identity(),
            ),
            AnatomySpec::Surface {
                unit,
                placement,
                access,
                names,
                voxel_mm,
                ..
            } => (
                format!(
                    "surface:{shown}:{:?}:{unit:?}:{placement:?}:{access:?}:{names:?}:{voxel_mm:?}",
                    surface_centerlines.as_deref().map(Path::display)
                ),
                Matrix3::identity(),
            ),
        };
        if let Some(found) = self.anatomies.lock().get_mut(&key) {
            found.used = self.tick();
            return Ok((found.value.clone(), to_lps));
        }
        let anatomy = match spec {
            AnatomySpec::ArchToCow {
                circle_of_willis, ..
            } => {
                let dir = file.as_deref().unwrap_or(Path::new(""));
                if *circle_of_willis {
                    arch_to_cow_with_circle(dir)?
                } else {
                    load_arch_to_cow(dir).map_err(|e| unreadable("anatomy.dir", dir, e))?
                }
            }
            AnatomySpec::NeuroPhantom { seed, tortuosity } => {
                use cathlab_anatomy::phantom::{NeuroPhantomParams, neuro_phantom};
                use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};
                let graph = neuro_phantom(&NeuroPhantomParams {
                    seed: *seed,
                    tortuosity: *tortuosity,
                    ..NeuroPhantomParams::default()
                })?;
                // Two cells per radius and a 1 mm query grid: about 1 M triangles and 30 s
                // to load; the surface's defaults (3 per radius, a grid of a quarter of the
                // median edge over the whole body) take 2 M triangles and 9 GB.
                let mesh = lumen_surface(
                    &graph,
                    &SurfaceSettings {
                        cells_per_radius: 2.0,
                        ..SurfaceSettings::default()
                    },
                )?;
                let lumen = Lumen::with_grid_settings(
                    mesh,
                    "neuro phantom",
                    cathlab_imaging::case::contact_grid(),
                )?;
                Anatomy { graph, lumen }
            }
            AnatomySpec::Surface {
                unit,
                placement,
                access,
                names,
                voxel_mm,
                ..
            } => {
                use cathlab_imaging::case::{SurfaceCase, load_surface_case};
                let path = file.unwrap_or_default();
                let case = SurfaceCase {
                    surface: path.clone(),
                    unit: *unit,
                    placement: *placement,
                    centerlines: surface_centerlines,
                    access: *access,
                    names: names.clone(),
                    voxel_m: voxel_mm.map(|v| v * 1e-3),
                    max_voxels:
                        cathlab_imaging::surface_centerlines::SurfaceCenterlineSettings::default()
                            .max_voxels,
                };
                let loaded = load_surface_case(&case).map_err(|e| match e {
                    cathlab_imaging::ImagingError::Case { field, reason } => scene_error(
                        &format!("anatomy.{}", field.trim_start_matches("anatomy.")),
                        reason,
                    ),
                    other => unreadable("anatomy.file", &path, other),
                })?;
                for end in &loaded.open_ends {
                    tracing::info!(
                        file = %path.display(),
                        end = end.index,
                        centre_mm = ?(end.centre.coords * 1e3).as_slice(),
                        radius_mm = end.radius_m * 1e3,
                        "open end capped"
                    );
                }
                loaded.anatomy
            }
            AnatomySpec::CtSegmentation { seed_voxel, .. } => {
                use cathlab_imaging::segment::{Seed, SegmentSettings, segment};
                let path = file.unwrap_or_default();
                let ct = cathlab_imaging::ScalarVolume::load(&path)
                    .map_err(|e| unreadable("anatomy.volume", &path, e))?;
                let result = segment(&ct, &Seed::Voxel(*seed_voxel), &SegmentSettings::default())
                    .map_err(|e| scene_error("anatomy.seed_voxel", e))?;
                // A segmented surface is finely meshed over a large box: the default grid
                // (a quarter of the median edge) would take gigabytes; 1 mm cells suffice.
                let lumen = Lumen::with_grid_settings(
                    result.surface,
                    &path.display().to_string(),
                    cathlab_imaging::case::contact_grid(),
                )?;
                Anatomy {
                    graph: result.graph,
                    lumen,
                }
            }
        };
        let anatomy = Arc::new(anatomy);
        staged.anatomy = Some((key, anatomy.clone()));
        Ok((anatomy, to_lps))
    }

    fn volume(
        &self,
        spec: &CtSpec,
        base: &Path,
        anatomy_key: &str,
        phantom: impl FnOnce() -> cathlab_xray::Result<BodyPhantom>,
        staged: &mut Staged,
    ) -> Result<Arc<Volume>> {
        // The CT file, resolved (and checked) once.
        let file = match spec {
            CtSpec::File { path, .. } => Some(self.resolve(base, path, "ct.path")?),
            CtSpec::Phantom { .. } => None,
        };
        let key = match spec {
            CtSpec::Phantom { spacing_mm } => format!("phantom:{spacing_mm}:{anatomy_key}"),
            CtSpec::File {
                hu_slope,
                hu_intercept,
                ..
            } => format!(
                "file:{}:{hu_slope}:{hu_intercept}",
                file.as_deref().unwrap_or(Path::new("")).display()
            ),
        };
        if let Some(found) = self.volumes.lock().get_mut(&key) {
            found.used = self.tick();
            return Ok(found.value.clone());
        }
        let volume = match spec {
            CtSpec::Phantom { spacing_mm } => phantom()?
                .volume(spacing_mm * 1e-3)
                .map_err(|e| scene_error("ct.spacing_mm", e))?,
            CtSpec::File {
                hu_slope,
                hu_intercept,
                ..
            } => {
                let path = file.unwrap_or_default();
                let mut v = Volume::load(&path).map_err(|e| unreadable("ct.path", &path, e))?;
                v.rescale(*hu_slope, *hu_intercept)?;
                v
            }
        };
        let volume = Arc::new(volume);
        staged.volume = Some((key, volume.clone()));
        Ok(volume)
    }

    fn build(&self, spec: &SceneSpec, base: &Path, staged: &mut Staged) -> Result<SceneAssets> {
        // A CT file does not depend on the anatomy: it is read first, so that a file its
        // reader refuses (a bomb, a wrong header) fails before the anatomy is built.
        let file_ct = match &spec.ct {
            CtSpec::File { .. } => Some(self.volume(
                &spec.ct,
                base,
                "",
                || unreachable!("a CT file is not the phantom"),
                staged,
            )?),
            CtSpec::Phantom { .. } => None,
        };
        let (anatomy, to_lps) = self.anatomy(&spec.anatomy, base, staged)?;
        let graph = &anatomy.graph;
        // A target given by a point near a vessel's end becomes that branch's name.
        let mut resolved = spec.clone();
        if let (true, Some(p)) = (spec.target.branch.is_empty(), spec.target.end_near_mm) {
            let lps = nalgebra::Vector3::from(p) * 1e-3;
            let local = Point3::from(to_lps.transpose() * lps);
            resolved.target.branch = cathlab_imaging::case::branch_at_end(graph, &local)
                .ok_or_else(|| scene_error("target.end_near_mm", "the vessels have no free end"))?;
        }
        let spec = &resolved;
        let target_branch = graph
            .branch_id(&spec.target.branch)
            .map_err(|e| scene_error("target.branch", e))?;
        let access = graph
            .landmarks
            .get("access")
            .copied()
            .ok_or_else(|| scene_error("anatomy", "the anatomy has no access landmark"))?;
        let route = graph
            .path_to(&access, &spec.target.branch)
            .map_err(|e| scene_error("target.branch", e))?;
        let target_length = graph.branches[target_branch].length();
        if spec.target.reach_mm * 1e-3 > target_length {
            return Err(scene_error(
                "target.reach_mm",
                format!(
                    "{} mm is beyond the end of {} ({:.1} mm long)",
                    spec.target.reach_mm,
                    spec.target.branch,
                    target_length * 1e3
                ),
            ));
        }
        let along = spec.start.along_route_mm * 1e-3;
        if along >= route.length {
            return Err(scene_error(
                "start.along_route_mm",
                format!(
                    "{} mm is beyond the route's {:.1} mm",
                    spec.start.along_route_mm,
                    route.length * 1e3
                ),
            ));
        }
        let pilot = Autopilot::new(graph, route.clone(), along, AutopilotSettings::default())?;
        let entry = pilot.entry();
        let devices: Vec<_> = if spec.stack.is_empty() {
            spec.devices.iter().map(device_of).collect()
        } else {
            spec.stack
                .iter()
                .enumerate()
                .map(|(i, entry)| entry.resolve(i))
                .collect::<Result<_>>()?
        };
        for (i, (device, _)) in devices.iter().enumerate() {
            if spec.stack.is_empty() && spec.start.inserted_mm * 1e-3 > device.length_m() {
                return Err(scene_error(
                    &format!("devices[{i}]"),
                    "shorter than start.inserted_mm",
                ));
            }
        }
        let spares = spec
            .spares
            .iter()
            .enumerate()
            .map(|(i, spare)| spare.resolve(i))
            .collect::<Result<Vec<_>>>()?;
        let anatomy_key = format!("{:?}", spec.anatomy);
        let volume = match file_ct {
            Some(volume) => volume,
            None => self.volume(
                &spec.ct,
                base,
                &anatomy_key,
                || BodyPhantom::around_graph(graph, &to_lps),
                staged,
            )?,
        };
        let iso_name = if spec.carm.isocenter_branch.is_empty() {
            &spec.target.branch
        } else {
            &spec.carm.isocenter_branch
        };
        let iso_branch = graph
            .branch(iso_name)
            .map_err(|e| scene_error("carm.isocenter_branch", e))?;
        let isocenter = to_lps
            * iso_branch
                .point_at(spec.carm.isocenter_at * iso_branch.length())
                .coords;
        let c = &spec.carm;
        let px = spec.fidelity.frame_px;
        let carm = CArm {
            primary_deg: c.primary_deg,
            secondary_deg: c.secondary_deg,
            source_to_image_m: c.source_to_image_mm * 1e-3,
            source_to_isocenter_m: c.source_to_isocenter_mm * 1e-3,
            isocenter_m: isocenter,
            detector: DetectorGeometry {
                width_px: px,
                height_px: px,
                field_of_view_m: c.field_of_view_mm * 1e-3,
                collimation: (1.0, 1.0),
            },
        };
        carm.validate().map_err(|e| scene_error("carm", e))?;
        let network = match &spec.flow {
            None => None,
            Some(flow) => {
                graph
                    .branch_id(&flow.inlet_branch)
                    .map_err(|e| scene_error("flow.inlet_branch", e))?;
                let settings = GraphFlowSettings {
                    inlet_branch: flow.inlet_branch.clone(),
                    inlet: InletCondition::Pressure(flow.pressure_mmhg * MMHG),
                    ..GraphFlowSettings::default()
                };
                let network =
                    network_from_graph(graph, &settings).map_err(|e| scene_error("flow", e))?;
                Some(match &flow.collaterals {
                    None => (network, None),
                    Some(c) => {
                        let donors: Vec<&str> = c.donors.iter().map(String::as_str).collect();
                        let (with, _) = cathlab_hemo::with_pial_collaterals(
                            &network,
                            &c.recipient,
                            &donors,
                            cathlab_hemo::CollateralStatus {
                                supply_fraction: c.supply_fraction,
                            },
                        )
                        .map_err(|e| scene_error("flow.collaterals", e))?;
                        (with, Some(network))
                    }
                })
            }
        };
        let (network, grading_network) = match network {
            Some((n, g)) => (Some(n), g),
            None => (None, None),
        };
        let clots = scene_clots(spec, graph)?;
        let (route_samples, route_radii): (Vec<Point3<f64>>, Vec<f64>) = graph
            .sample_path(&route, ROUTE_SPACING_M)
            .into_iter()
            .unzip();
        let goal_along_m = route
            .legs
            .iter()
            .take_while(|leg| leg.branch != target_branch)
            .map(|leg| (leg.to_arc - leg.from_arc).abs())
            .sum::<f64>()
            + spec.target.reach_mm * 1e-3;
        let goal = (goal_along_m / ROUTE_SPACING_M).round() as usize;
        let reach = (spec.target.reach_mm * 1e-3 / ROUTE_SPACING_M).round() as usize;
        let target_path_lps = route_samples
            .get(goal.saturating_sub(reach)..=goal.min(route_samples.len().saturating_sub(1)))
            .unwrap_or_default()
            .iter()
            .step_by(2)
            .map(|p| Point3::from(to_lps * p.coords))
            .collect();
        let assets = SceneAssets {
            target_path_lps,
            spec: spec.clone(),
            anatomy,
            to_lps,
            volume,
            devices,
            spares,
            entry,
            route,
            target_branch,
            route_samples,
            route_radii,
            goal_along_m,
            carm,
            network,
            grading_network,
            clots,
        };
        // The scripted operator's plan (its exchange's branch on the route, its device) is
        // checked now, not when someone first runs it.
        assets.two_hand_plan()?;
        Ok(assets)
    }
}

/// How far the given curves of the arch-to-cow anatomy are cut back for the computed circle
/// of Willis to continue them (m): below the carotids' communicating segments.
const CIRCLE_TRIM_M: f64 = 20e-3;

/// The arch-to-cow anatomy with its circle of Willis computed from the surface and named.
fn arch_to_cow_with_circle(dir: &Path) -> Result<Anatomy> {
    use cathlab_anatomy::real::load_arch_to_cow_trimmed;
    use cathlab_imaging::circle_of_willis::{CircleInflows, CircleSettings, circle_of_willis};
    let (mut anatomy, ends) = load_arch_to_cow_trimmed(dir, CIRCLE_TRIM_M)
        .map_err(|e| unreadable("anatomy.dir", dir, e))?;
    let circle = CircleInflows::arch_to_cow(&ends)
        .and_then(|inflows| circle_of_willis(&anatomy.lumen, &inflows, &CircleSettings::default()))
        .map_err(|e| scene_error("anatomy.circle_of_willis", e))?;
    for branch in circle.branches {
        anatomy
            .graph
            .add_branch(branch)
            .map_err(|e| unreadable("anatomy.dir", dir, e))?;
    }
    anatomy.graph.landmarks.extend(circle.landmarks);
    Ok(anatomy)
}

/// A file a scene named could not be read: the detail goes to the log, the client hears only
/// which field (never the server's paths or the file's contents).
fn unreadable(field: &str, path: &Path, e: impl std::fmt::Display) -> EngineError {
    tracing::warn!(field, path = %path.display(), "scene file unreadable: {e}");
    // A reader's limit says which limit and by how much (no path, no contents): the caller
    // learns why; anything else stays in the log (no echo of a file's contents).
    let text = e.to_string();
    match text.find(cathlab_anatomy::io::limits::REFUSED) {
        Some(at) => scene_error(field, &text[at..]),
        None => scene_error(
            field,
            "cannot be read as what the field names (the server's log has the detail)",
        ),
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

/// The scene's clots as occlusions of the flow network's vessels (branch i = vessel i), each
/// checked: a known branch, a stretch inside it, a red-cell fraction in [0, 1], and a scene
/// with flow.
fn scene_clots(spec: &SceneSpec, graph: &VesselGraph) -> Result<Vec<Occlusion>> {
    spec.clots
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let field = |name: &str| format!("clots[{i}].{name}");
            if spec.flow.is_none() {
                return Err(scene_error(
                    &field("branch"),
                    "a clot needs the scene's [flow] (it acts on the blood flow)",
                ));
            }
            let vessel = graph
                .branch_id(&c.branch)
                .map_err(|e| scene_error(&field("branch"), e))?;
            let length = graph.branches[vessel].length();
            let composition = ClotComposition {
                red_cell_fraction: c.red_cell_fraction,
            };
            composition
                .validate()
                .map_err(|e| scene_error(&field("red_cell_fraction"), e))?;
            let (from, to) = (c.from_mm * 1e-3, (c.from_mm + c.length_mm) * 1e-3);
            if !(c.from_mm.is_finite() && from >= 0.0 && from < length) {
                return Err(scene_error(
                    &field("from_mm"),
                    format!(
                        "{} mm is not within the branch's {:.1} mm",
                        c.from_mm,
                        length * 1e3
                    ),
                ));
            }
            if !(c.length_mm.is_finite() && c.length_mm > 0.0 && to <= length) {
                return Err(scene_error(
                    &field("length_mm"),
                    format!(
                        "{} mm from {} mm does not fit in the branch's {:.1} mm",
                        c.length_mm,
                        c.from_mm,
                        length * 1e3
                    ),
                ));
            }
            Ok(Occlusion {
                vessel,
                from_arc: from,
                to_arc: to,
                permeability_m2: composition.permeability_m2(),
            })
        })
        .collect()
}
