//! Route-following autopilot: turns a path through the vessel graph into push/pull/twist
//! commands, the way a scripted trainee would steer a shaped tip — push, turn the tip's bend
//! towards where the route goes next, and back off and re-aim when the tip strays into a
//! side branch. Deterministic: the same anatomy and settings give the same commands.

use cathlab_anatomy::graph::{VesselGraph, VesselPath};
use nalgebra::{Point3, Vector3};

use crate::error::{PhysicsError, Result, require_positive};
use crate::navigation::{Command, Insertion, Navigation, Twist};
use crate::wall::Wall;

/// What the autopilot needs of a device it steers: where its tip is and points, which way its
/// shaped tip bends, and the operator's twist and insertion. Implemented by [`Navigation`] and
/// by one instrument of a coaxial [`crate::stack::Stack`].
pub trait Steered {
    /// Tip position (m).
    fn tip_position(&self) -> Vector3<f64>;
    /// Unit tangent where the shaped tip starts (or at the tip if straight).
    fn tip_axis(&self) -> Vector3<f64>;
    /// Unit world direction the shaped tip bends to, across the device; `None` if straight.
    fn tip_bend_direction(&self) -> Option<Vector3<f64>>;
    /// Twist at the entry point (rad).
    fn twist_rad(&self) -> f64;
    /// Inserted length (m).
    fn inserted_m(&self) -> f64;
}

impl<W: Wall> Steered for Navigation<W> {
    fn tip_position(&self) -> Vector3<f64> {
        Navigation::tip_position(self)
    }
    fn tip_axis(&self) -> Vector3<f64> {
        Navigation::tip_axis(self)
    }
    fn tip_bend_direction(&self) -> Option<Vector3<f64>> {
        Navigation::tip_bend_direction(self)
    }
    fn twist_rad(&self) -> f64 {
        Navigation::twist_rad(self)
    }
    fn inserted_m(&self) -> f64 {
        Navigation::inserted_m(self)
    }
}

/// How the autopilot drives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AutopilotSettings {
    /// Push (and back-off) speed at the entry point (m/s).
    pub push_speed_m_s: f64,
    /// How far ahead along the route the tip's bend is aimed (m): the bend turns towards the
    /// route's direction there. Shorter for tight, tortuous routes.
    pub lookahead_m: f64,
    /// Pull-back distance after straying into a side branch (m).
    pub retreat_m: f64,
    /// A tip nearer to an off-route branch than to the route counts as strayed only once it
    /// is this far along that branch (m): junction regions are shared by their branches.
    pub stray_depth_m: f64,
    /// Target reached when the tip is this far along the path's last branch (m).
    pub reach_m: f64,
    /// Spacing of the route samples (m).
    pub route_spacing_m: f64,
}

impl Default for AutopilotSettings {
    fn default() -> Self {
        Self {
            push_speed_m_s: 0.02,
            lookahead_m: 0.02,
            retreat_m: 0.015,
            stray_depth_m: 0.01,
            reach_m: 0.05,
            route_spacing_m: 1e-3,
        }
    }
}

/// What the autopilot is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AutopilotPhase {
    /// Pushing along the route.
    Advancing,
    /// Pulling back out of a side branch.
    Retreating,
    /// The tip is `reach_m` into the target branch; the command holds still.
    Reached,
}

/// Re-aim offsets tried on successive retries (rad): straight at the route, then a quarter
/// turn either way, then the opposite side.
const RETRY_AIM_OFFSETS_RAD: [f64; 4] = [
    0.0,
    std::f64::consts::FRAC_PI_2,
    -std::f64::consts::FRAC_PI_2,
    std::f64::consts::PI,
];

/// Steers a [`Navigation`] along a [`VesselPath`].
#[derive(Debug, Clone)]
pub struct Autopilot<'g> {
    graph: GraphHandle<'g>,
    path: VesselPath,
    /// Route samples (position, lumen radius), m.
    route: Vec<(Point3<f64>, f64)>,
    settings: AutopilotSettings,
    phase: AutopilotPhase,
    twist_target_rad: f64,
    retreat_until_m: f64,
    retries: usize,
}

/// The vessel graph a scripted operator follows: borrowed, or shared (for an operator that
/// lives as long as a session's world).
#[derive(Debug, Clone)]
pub enum GraphHandle<'g> {
    /// Borrowed for `'g`.
    Borrowed(&'g VesselGraph),
    /// Shared.
    Shared(std::sync::Arc<VesselGraph>),
}

impl std::ops::Deref for GraphHandle<'_> {
    type Target = VesselGraph;

    fn deref(&self) -> &VesselGraph {
        match self {
            GraphHandle::Borrowed(g) => g,
            GraphHandle::Shared(g) => g,
        }
    }
}

impl<'g> Autopilot<'g> {
    /// Follows `path` from `start_along_m` metres along it (0: its start; more to begin, for
    /// example, with a guide catheter parked in the aortic arch).
    pub fn new(
        graph: &'g VesselGraph,
        path: VesselPath,
        start_along_m: f64,
        settings: AutopilotSettings,
    ) -> Result<Self> {
        Self::with_graph(GraphHandle::Borrowed(graph), path, start_along_m, settings)
    }

    /// As [`Autopilot::new`], on a graph handle.
    pub fn with_graph(
        graph: GraphHandle<'g>,
        path: VesselPath,
        start_along_m: f64,
        settings: AutopilotSettings,
    ) -> Result<Self> {
        require_positive(|| "push_speed_m_s".into(), settings.push_speed_m_s)?;
        require_positive(|| "lookahead_m".into(), settings.lookahead_m)?;
        require_positive(|| "retreat_m".into(), settings.retreat_m)?;
        require_positive(|| "route_spacing_m".into(), settings.route_spacing_m)?;
        if !(0.0..path.length).contains(&start_along_m) {
            return Err(PhysicsError::OutOfRange {
                what: "autopilot start along the path (m)".into(),
                range: "from 0 to below the path length",
                value: start_along_m,
            });
        }
        let mut route = graph.sample_path(&path, settings.route_spacing_m);
        let skip = (start_along_m / settings.route_spacing_m) as usize;
        route.drain(..skip.min(route.len().saturating_sub(12)));
        Ok(Self {
            graph,
            path,
            route,
            settings,
            phase: AutopilotPhase::Advancing,
            twist_target_rad: 0.0,
            retreat_until_m: 0.0,
            retries: 0,
        })
    }

    /// Entry point and direction for [`Navigation::new`]: the route's first sample and its
    /// direction over the next 10 samples.
    pub fn entry(&self) -> (Vector3<f64>, Vector3<f64>) {
        route_entry(&self.route)
    }

    /// The path it follows.
    pub fn path(&self) -> &VesselPath {
        &self.path
    }

    /// Current phase.
    pub fn phase(&self) -> AutopilotPhase {
        self.phase
    }

    /// How many times the tip strayed into a side branch and was pulled back.
    pub fn retries(&self) -> usize {
        self.retries
    }

    /// Looks at the device and returns the next command.
    pub fn command(&mut self, navigation: &impl Steered) -> Command {
        let tip = navigation.tip_position();
        let tip_point = Point3::from(tip);
        let Some(location) = self.graph.nearest(&tip_point) else {
            return hold(navigation);
        };
        let target = self.path.legs.last().map(|leg| leg.branch);
        if Some(location.branch) == target && location.arc_length >= self.settings.reach_m {
            self.phase = AutopilotPhase::Reached;
        }
        if self.phase == AutopilotPhase::Reached {
            return hold(navigation);
        }
        let (index, distance) = self
            .route
            .iter()
            .enumerate()
            .map(|(i, (p, _))| (i, (p - tip_point).norm()))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((0, 0.0));
        let radius = self.route[index].1;

        // Aim the bend at the route's direction `lookahead` ahead.
        let samples_ahead = (self.settings.lookahead_m / self.settings.route_spacing_m) as usize;
        let a = (index + samples_ahead).min(self.route.len().saturating_sub(6));
        let heading = (self.route[(a + 5).min(self.route.len() - 1)].0 - self.route[a].0)
            .try_normalize(1e-12)
            .unwrap_or_else(Vector3::zeros);
        let axis = navigation.tip_axis();
        let wanted = heading - axis * heading.dot(&axis);
        if let Some(bend) = navigation.tip_bend_direction()
            && wanted.norm() > 0.05
        {
            let error = bend.cross(&wanted).dot(&axis).atan2(bend.dot(&wanted));
            let offset = RETRY_AIM_OFFSETS_RAD[self.retries % RETRY_AIM_OFFSETS_RAD.len()];
            self.twist_target_rad = navigation.twist_rad() + error + offset;
        }

        // Strayed: nearest to an off-route branch, past its junction, outside the route lumen.
        let on_route = self.path.legs.iter().any(|l| l.branch == location.branch);
        let strayed =
            !on_route && distance > radius && location.arc_length > self.settings.stray_depth_m;
        if strayed && self.phase == AutopilotPhase::Advancing {
            self.phase = AutopilotPhase::Retreating;
            self.retreat_until_m = navigation.inserted_m() - self.settings.retreat_m;
            self.retries += 1;
        }
        if self.phase == AutopilotPhase::Retreating
            && navigation.inserted_m() <= self.retreat_until_m
        {
            self.phase = AutopilotPhase::Advancing;
        }
        let speed = match self.phase {
            AutopilotPhase::Retreating => -self.settings.push_speed_m_s,
            _ => self.settings.push_speed_m_s,
        };
        Command {
            insertion: Insertion::Velocity(speed),
            twist: Twist::Target(self.twist_target_rad),
        }
    }
}

/// Holds the device where it is.
fn hold(navigation: &impl Steered) -> Command {
    Command {
        insertion: Insertion::Velocity(0.0),
        twist: Twist::Target(navigation.twist_rad()),
    }
}

/// Entry point (m) and unit direction of a sampled route (non-empty): its first sample and
/// its direction over the next 10 samples.
pub fn route_entry(route: &[(Point3<f64>, f64)]) -> (Vector3<f64>, Vector3<f64>) {
    let start = route[0].0;
    let ahead = route[10.min(route.len() - 1)].0;
    (start.coords, (ahead - start).normalize())
}
