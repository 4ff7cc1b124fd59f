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
    /// Stalled: this much pushed in (m, forward motion summed) without the tip getting 1 mm
    /// further along the route and without straying (the device prolapses or buckles behind
    /// a bend it cannot take). The pilot pulls this length back out and tries again at the
    /// next aim.
    pub stall_slack_m: f64,
    /// After this many stalls the pilot gives up and holds ([`AutopilotPhase::Stalled`]).
    pub max_stalls: usize,
    /// How many of the re-aim offsets the retries go round (4: straight, a quarter turn
    /// either way, the opposite side; up to 8: the eighth turns between).
    pub aims: usize,
    /// After straying, back out as far as the tip went into the side branch before the
    /// `retreat_m`, not `retreat_m` alone: a tip 17 mm into a branch then leaves it, where
    /// pulled back 15 mm it stayed in and every aim tried took the same branch again.
    pub retreat_out_of_branch: bool,
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
            stall_slack_m: 0.15,
            max_stalls: 3,
            aims: 4,
            retreat_out_of_branch: false,
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
    /// Stalled `max_stalls` times: given up, the command holds still.
    Stalled,
}

/// Re-aim offsets tried on successive retries (rad): straight at the route, then a quarter
/// turn either way, then the opposite side; then the eighth turns between (the first
/// [`AutopilotSettings::aims`] of them are used).
const RETRY_AIM_OFFSETS_RAD: [f64; 8] = [
    0.0,
    std::f64::consts::FRAC_PI_2,
    -std::f64::consts::FRAC_PI_2,
    std::f64::consts::PI,
    std::f64::consts::FRAC_PI_4,
    -std::f64::consts::FRAC_PI_4,
    3.0 * std::f64::consts::FRAC_PI_4,
    -3.0 * std::f64::consts::FRAC_PI_4,
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
    /// Furthest route sample the tip has been nearest to.
    furthest: Option<usize>,
    /// Pushed in since (forward motion only, m), and the inserted length last seen (m).
    pushed_since_m: f64,
    last_inserted_m: Option<f64>,
    stalls: usize,
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
        require_positive(|| "stall_slack_m".into(), settings.stall_slack_m)?;
        if !(1..=RETRY_AIM_OFFSETS_RAD.len()).contains(&settings.aims) {
            return Err(PhysicsError::OutOfRange {
                what: "autopilot aims".into(),
                range: "1 to 8",
                value: settings.aims as f64,
            });
        }
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
            furthest: None,
            pushed_since_m: 0.0,
            last_inserted_m: None,
            stalls: 0,
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

    /// How many times the tip strayed into a side branch or stalled and was pulled back.
    pub fn retries(&self) -> usize {
        self.retries
    }

    /// How many times the device stalled (pushed `stall_slack_m` in without progress).
    pub fn stalls(&self) -> usize {
        self.stalls
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
        if matches!(
            self.phase,
            AutopilotPhase::Reached | AutopilotPhase::Stalled
        ) {
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
            let offset = RETRY_AIM_OFFSETS_RAD[self.retries % self.settings.aims];
            self.twist_target_rad = navigation.twist_rad() + error + offset;
        }

        // Strayed: nearest to an off-route branch, past its junction, outside the route lumen.
        let on_route = self.path.legs.iter().any(|l| l.branch == location.branch);
        let strayed =
            !on_route && distance > radius && location.arc_length > self.settings.stray_depth_m;
        if strayed && self.phase == AutopilotPhase::Advancing {
            // The stray rule handles this try: what was pushed into the side branch is no
            // stall.
            self.pushed_since_m = 0.0;
            self.phase = AutopilotPhase::Retreating;
            let into_branch = if self.settings.retreat_out_of_branch {
                location.arc_length
            } else {
                0.0
            };
            self.retreat_until_m = navigation.inserted_m() - into_branch - self.settings.retreat_m;
            self.retries += 1;
        }
        // Stalled: pushed in `stall_slack_m` (forward motion summed) since the tip last got a
        // millimetre further along or strayed.
        let inserted = navigation.inserted_m();
        if let Some(last) = self.last_inserted_m {
            self.pushed_since_m += (inserted - last).max(0.0);
        }
        self.last_inserted_m = Some(inserted);
        let step = ((1e-3 / self.settings.route_spacing_m).ceil() as usize).max(1);
        if self.furthest.is_none_or(|best| index >= best + step) {
            self.furthest = Some(index);
            self.pushed_since_m = 0.0;
        }
        if self.phase == AutopilotPhase::Advancing
            && self.pushed_since_m > self.settings.stall_slack_m
        {
            self.stalls += 1;
            self.pushed_since_m = 0.0;
            if self.stalls >= self.settings.max_stalls {
                self.phase = AutopilotPhase::Stalled;
                return hold(navigation);
            }
            // Pull what was pushed in for nothing back out, and try the next aim.
            self.retries += 1;
            self.phase = AutopilotPhase::Retreating;
            self.retreat_until_m = inserted - self.settings.stall_slack_m;
        }
        if self.phase == AutopilotPhase::Retreating && inserted <= self.retreat_until_m {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::navigation::Insertion;
    use cathlab_anatomy::phantom::y_bifurcation;

    /// A device whose tip runs along `route` (1 mm samples) with its insertion up to
    /// `wall_m` and no further (the rest of what is pushed in piles up behind it).
    struct Stuck {
        route: Vec<Point3<f64>>,
        inserted: f64,
        wall_m: f64,
    }

    impl Steered for Stuck {
        fn tip_position(&self) -> Vector3<f64> {
            let i = (self.inserted.clamp(0.0, self.wall_m) * 1e3) as usize;
            self.route[i.min(self.route.len() - 1)].coords
        }
        fn tip_axis(&self) -> Vector3<f64> {
            Vector3::z()
        }
        fn tip_bend_direction(&self) -> Option<Vector3<f64>> {
            None
        }
        fn twist_rad(&self) -> f64 {
            0.0
        }
        fn inserted_m(&self) -> f64 {
            self.inserted
        }
    }

    /// Drives `device` at the commanded speed for at most `steps` steps of 1 ms; the deepest
    /// it was pushed in (m).
    fn drive(pilot: &mut Autopilot, device: &mut Stuck, steps: usize) -> f64 {
        let mut peak = device.inserted;
        for _ in 0..steps {
            let command = pilot.command(device);
            if let Insertion::Velocity(v) = command.insertion {
                device.inserted += v * 1e-3;
            }
            peak = peak.max(device.inserted);
            if matches!(
                pilot.phase(),
                AutopilotPhase::Stalled | AutopilotPhase::Reached
            ) {
                break;
            }
        }
        peak
    }

    #[test]
    fn aims_outside_one_to_eight_are_a_typed_error() {
        let graph = y_bifurcation(3e-3, 2e-3, 20e-3, 15e-3, 0.5).unwrap();
        let path = graph.path_to(&graph.landmarks["access"], "left").unwrap();
        for aims in [0, 9] {
            let settings = AutopilotSettings {
                aims,
                ..AutopilotSettings::default()
            };
            let error = Autopilot::new(&graph, path.clone(), 0.0, settings).unwrap_err();
            assert!(error.to_string().contains("aims"), "{error}");
        }
        for aims in [1, 8] {
            let settings = AutopilotSettings {
                aims,
                ..AutopilotSettings::default()
            };
            assert!(Autopilot::new(&graph, path.clone(), 0.0, settings).is_ok());
        }
    }

    #[test]
    fn a_device_that_stops_advancing_is_pulled_back_and_given_up_after_its_stalls() {
        let graph = y_bifurcation(3e-3, 2e-3, 20e-3, 15e-3, 0.5).unwrap();
        let path = graph.path_to(&graph.landmarks["access"], "left").unwrap();
        let route: Vec<Point3<f64>> = graph
            .sample_path(&path, 1e-3)
            .into_iter()
            .map(|(p, _)| p)
            .collect();
        let settings = AutopilotSettings {
            reach_m: 0.01,
            ..AutopilotSettings::default()
        };
        let mut pilot = Autopilot::new(&graph, path.clone(), 0.0, settings).unwrap();
        // Stuck 10 mm in: each try pushes the stall slack (60 mm) past the furthest point,
        // pulls back the retreat distance (15 mm) behind where it was, and tries again; the
        // third stall gives up.
        let mut device = Stuck {
            route: route.clone(),
            inserted: 0.0,
            wall_m: 0.01,
        };
        let peak = drive(&mut pilot, &mut device, 100_000);
        assert_eq!(pilot.phase(), AutopilotPhase::Stalled);
        assert_eq!(pilot.stalls(), settings.max_stalls);
        assert_eq!(pilot.retries(), settings.max_stalls - 1);
        assert!(
            (peak - (0.01 + settings.stall_slack_m)).abs() < 2e-3,
            "pushed {peak} m in"
        );
        // Given up, it holds.
        assert_eq!(pilot.command(&device).insertion, Insertion::Velocity(0.0));
        // A device that keeps advancing never stalls: it reaches the target.
        let mut pilot = Autopilot::new(&graph, path, 0.0, settings).unwrap();
        let mut free = Stuck {
            route,
            inserted: 0.0,
            wall_m: 1.0,
        };
        drive(&mut pilot, &mut free, 100_000);
        assert_eq!(pilot.phase(), AutopilotPhase::Reached);
        assert_eq!(pilot.stalls(), 0);
    }
}
