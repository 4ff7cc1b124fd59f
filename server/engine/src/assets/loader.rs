//! How a scene's assets are built: the anatomy (imported, segmented from a CT, a surface or
//! the phantom), the CT volume, the devices and spares, the entry, route and target, the
//! C-arm, the flow network with its collaterals, and the clots, each checked and its errors
//! naming the scene's field.

use std::path::Path;
use std::sync::Arc;

use cathlab_anatomy::real::{Anatomy, load_arch_to_cow};
use cathlab_anatomy::{Lumen, VesselGraph};
use cathlab_hemo::{
    ClotComposition, GraphFlowSettings, InletCondition, MMHG, Occlusion, network_from_graph,
};
use cathlab_physics::autopilot::{Autopilot, AutopilotSettings};
use cathlab_xray::phantom::BodyPhantom;
use cathlab_xray::scene::ARCH_TO_COW_TO_LPS;
use cathlab_xray::{CArm, DetectorGeometry, Volume};
use nalgebra::{Matrix3, Point3};

use super::cache::{AssetCache, Staged};
use super::errors::{scene_error, unreadable};
use super::scene_assets::{ROUTE_SPACING_M, SceneAssets};
use crate::error::Result;
use crate::scene::{AnatomySpec, CtSpec, SceneSpec, device_of};

impl AssetCache {
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
        let build = || build_anatomy(spec, file.as_deref(), surface_centerlines.as_deref());
        // A generated anatomy builds faster than it reads back.
        let generated = matches!(spec, AnatomySpec::NeuroPhantom { .. });
        let anatomy = match &self.disk {
            // On disk under the parameters and the content of the files it is built from.
            Some(disk) if !generated => {
                let inputs: Vec<&Path> = file
                    .iter()
                    .chain(&surface_centerlines)
                    .map(|p| p.as_path())
                    .collect();
                match super::disk::content_hash(&inputs) {
                    Some(hash) => disk.anatomy(&format!("{key}:{hash}"), build)?,
                    None => build()?,
                }
            }
            _ => build()?,
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
            CtSpec::Phantom { spacing_mm } => {
                let build = || -> Result<Volume> {
                    phantom()?
                        .volume(spacing_mm * 1e-3)
                        .map_err(|e| scene_error("ct.spacing_mm", e))
                };
                match &self.disk {
                    // Built from the graph alone: on disk under its content.
                    Some(disk) => disk.volume(&key, build)?,
                    None => build()?,
                }
            }
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

    pub(super) fn build(
        &self,
        spec: &SceneSpec,
        base: &Path,
        staged: &mut Staged,
    ) -> Result<SceneAssets> {
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
        let anatomy_key = phantom_key(graph, &to_lps);
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

/// Builds the anatomy `spec` names from its resolved `file` (folder, surface or CT) and
/// surface `centerlines`.
fn build_anatomy(
    spec: &AnatomySpec,
    file: Option<&Path>,
    centerlines: Option<&Path>,
) -> Result<Anatomy> {
    Ok(match spec {
        AnatomySpec::ArchToCow {
            circle_of_willis, ..
        } => {
            let dir = file.unwrap_or(Path::new(""));
            if *circle_of_willis {
                arch_to_cow_with_circle(dir)?
            } else {
                load_arch_to_cow(dir).map_err(|e| unreadable("anatomy.dir", dir, e))?
            }
        }
        AnatomySpec::NeuroPhantom { seed, tortuosity } => {
            neuro_phantom_anatomy(*seed, *tortuosity)?
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
            let path = file.map(Path::to_path_buf).unwrap_or_default();
            let case = SurfaceCase {
                surface: path.clone(),
                unit: *unit,
                placement: *placement,
                centerlines: centerlines.map(Path::to_path_buf),
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
            let path = file.map(Path::to_path_buf).unwrap_or_default();
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
    })
}

/// The arch-to-cow anatomy with its circle of Willis computed from the surface and named.
/// The neuro phantom's anatomy: its graph is its lumen, so the wall is the graph's implicit
/// lumen (built in well under a second, about 10 MB), shown as tubes. Its triangulated
/// surface and query grid took 30 s and 1.5 GB for the same wall.
fn neuro_phantom_anatomy(seed: u64, tortuosity: f64) -> Result<Anatomy> {
    use cathlab_anatomy::field_wall::FieldWallSettings;
    use cathlab_anatomy::phantom::{NeuroPhantomParams, neuro_phantom};
    let graph = neuro_phantom(&NeuroPhantomParams {
        seed,
        tortuosity,
        ..NeuroPhantomParams::default()
    })?;
    let lumen = Lumen::implicit(&graph, &FieldWallSettings::default(), DISPLAY_SIDES)?;
    Ok(Anatomy { graph, lumen })
}

/// Vertices round each ring of a generated anatomy's displayed tubes.
const DISPLAY_SIDES: usize = 16;

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

/// What a synthetic CT is built from, as a key: the SHA-256 of the vessel graph (JSON) and of
/// the rotation into patient coordinates, so that neither a path nor a stale file can stand
/// for another anatomy's CT.
fn phantom_key(graph: &cathlab_anatomy::VesselGraph, to_lps: &Matrix3<f64>) -> String {
    use sha2::{Digest, Sha256};
    let mut hasher = Sha256::new();
    hasher.update(serde_json::to_vec(graph).unwrap_or_default());
    for v in to_lps.iter() {
        hasher.update(v.to_le_bytes());
    }
    format!("{:x}", hasher.finalize())
}
