//! A scene loaded and ready for sessions (anatomy, CT, devices, entry, route, target, C-arm,
//! flow network, clots), the lumen as the devices' wall, and the scene's scripted two-hand
//! operator as the physics takes it.

use std::sync::Arc;

use cathlab_anatomy::real::Anatomy;
use cathlab_anatomy::{Lumen, VesselPath};
use cathlab_hemo::{FlowNetwork, Occlusion};
use cathlab_physics::{Device, Wall, WallProbe};
use cathlab_xray::{CArm, DeviceAppearance, Volume};
use nalgebra::{Matrix3, Point3, Vector3};

use super::errors::scene_error;
use crate::error::Result;
use crate::scene::SceneSpec;

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
