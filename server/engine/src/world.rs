//! A session's deterministic world: the navigated device, optional flow and contrast, the
//! imaging state the trainee controls, and the metrics. No threads and no wall clock: the same
//! scene and the same commands at the same steps give the same state, bit for bit, which is
//! what replay relies on.

use std::sync::Arc;

use cathlab_hemo::reperfusion::{occluded_territory, reperfusion};
use cathlab_hemo::{Contrast, ContrastSettings, FlowSolution, FlowSolver, Injection};
use cathlab_physics::{Effort, Insertion, Navigation, NavigationSettings, Refinement, Twist};
use cathlab_xray::{ContrastTube, DeviceAppearance, PulseRate};
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::assets::{SceneAssets, SharedWall};
use crate::error::{EngineError, Result};
use crate::metrics::{Event, EventKind, Metrics, ReperfusionMetric};

mod operator;
use crate::strand::{HandReaction, Strand};

/// A trainee's or bridge's command, in SI units, as recorded.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Command {
    /// Push/pull speed (m/s).
    PushVelocity(f64),
    /// Inserted length to move to (m).
    PushTarget(f64),
    /// Twist rate (rad/s).
    TwistRate(f64),
    /// Twist angle to move to (rad).
    TwistTarget(f64),
    /// Both speeds at once (haptic bridge): push (m/s), twist (rad/s).
    Setpoints {
        /// Push/pull speed (m/s).
        push_m_s: f64,
        /// Twist rate (rad/s).
        twist_rad_s: f64,
    },
    /// Withdraw the device and insert the scene's device with this index (one-device scenes).
    SelectDevice(u32),
    /// Drive one instrument of a coaxial stack (index 0 the outermost). The plain push and
    /// twist commands drive the innermost (what a one-hand client steers).
    Instrument {
        /// Instrument index, outermost first.
        index: u32,
        /// What its hand does.
        drive: Drive,
    },
    /// Exchange instrument `index` of a stack (not the outermost), withdrawn to the hub of
    /// the one around it, for entry `catalogue` of the built-in device catalogue (its index
    /// in [`crate::scene::catalogue`]'s entries).
    Exchange {
        /// Instrument index, outermost first.
        index: u32,
        /// Catalogue entry index.
        catalogue: u32,
    },
    /// As [`Command::Exchange`], for spare `spare` of the scene's back table.
    ExchangeSpare {
        /// Instrument index, outermost first.
        index: u32,
        /// Index among the scene's spares.
        spare: u32,
    },
    /// Load entry `catalogue` of the built-in device catalogue into the innermost instrument
    /// of a stack, as its new innermost, its tip at that one's hub (a microcatheter into a
    /// distal-access catheter); at most [`crate::scene::MAX_STACK`] instruments.
    Load {
        /// Catalogue entry index.
        catalogue: u32,
    },
    /// As [`Command::Load`], for spare `spare` of the scene's back table.
    LoadSpare {
        /// Index among the scene's spares.
        spare: u32,
    },
    /// Withdraw the innermost instrument of a stack to the hub of the one around it and take
    /// it out (the access wire once the guide is up); not the outermost.
    Unload,
    /// Fluoroscopy pedal down or up.
    Fluoroscopy(bool),
    /// Pulse rate.
    PulseRate(PulseRate),
    /// Start (true) or end a DSA run.
    Dsa(bool),
    /// Roadmap on or off.
    Roadmap(bool),
    /// C-arm angles (deg).
    CArm {
        /// LAO + / RAO −.
        primary_deg: f64,
        /// CRA + / CAU −.
        secondary_deg: f64,
    },
    /// The overload governor's effort level: 0 is the scene's fidelity, up to
    /// [`MAX_FIDELITY_LEVEL`] does less work a step (see [`fidelity_effort`]). Issued by the
    /// session's physics loop, recorded like any command so that replays agree.
    Fidelity(u8),
    /// Inject contrast through the device tip: volume (mL) at a rate (mL/s).
    Inject {
        /// Volume (mL).
        volume_ml: f64,
        /// Rate (mL/s).
        rate_ml_s: f64,
    },
    /// Back to the scene's start.
    Reset,
    /// Aspiration through the distal-access catheter on or off.
    Aspiration(bool),
    /// Unsheathe the stent retriever: its hand holds while the microcatheter around it is
    /// drawn back past the stent's proximal end.
    DeployStent,
    /// Retrieve: the stent retriever and its microcatheter pulled back together at
    /// [`RETRIEVE_SPEED_M_S`]; they stop when the pass ends.
    RetrieveStent,
    /// Demonstration on (true) or off: the scene's scripted two-hand operator drives the
    /// stack until the target is reached (a push, twist or exchange by the trainee takes
    /// over). Its commands are not recorded; the world replays them from this one.
    Demonstrate(bool),
}

/// Speed of the retrieve command's pull (m/s): the slow, steady withdrawal taught.
pub const RETRIEVE_SPEED_M_S: f64 = 3e-3;

impl Command {
    /// The push and the twist of an operator's command (the autopilot's, a scripted one's),
    /// as the two commands a hand receives.
    pub fn from_operator(command: &cathlab_physics::Command) -> [Command; 2] {
        [
            match command.insertion {
                Insertion::Velocity(v) => Command::PushVelocity(v),
                Insertion::Target(x) => Command::PushTarget(x),
            },
            match command.twist {
                Twist::Rate(w) => Command::TwistRate(w),
                Twist::Target(a) => Command::TwistTarget(a),
            },
        ]
    }
}

/// What one hand does to its instrument, in SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Drive {
    /// Push/pull speed (m/s).
    PushVelocity(f64),
    /// Inserted length to move to (m).
    PushTarget(f64),
    /// Twist rate (rad/s).
    TwistRate(f64),
    /// Twist angle to move to (rad).
    TwistTarget(f64),
    /// Both speeds at once (haptic bridge): push (m/s), twist (rad/s).
    Setpoints {
        /// Push/pull speed (m/s).
        push_m_s: f64,
        /// Twist rate (rad/s).
        twist_rad_s: f64,
    },
}

/// One instrument now, for clients and the renderer (LPS, SI units).
#[derive(Debug, Clone, PartialEq)]
pub struct InstrumentState {
    /// The device's name.
    pub name: String,
    /// Its catalogue identifier (empty for a scene's own device).
    pub catalogue_id: String,
    /// Centerline from the entry to its tip (m); empty while withdrawn inside the one around
    /// it.
    pub nodes: Vec<Vector3<f64>>,
    /// Inserted length beyond the entry point (m; negative: inside the one around it).
    pub inserted_m: f64,
    /// Twist at the entry (rad).
    pub twist_rad: f64,
    /// Tip position (m); `None` while withdrawn proximal of the entry.
    pub tip: Option<Vector3<f64>>,
    /// Axial force its hand feels (N, positive when it resists a push).
    pub axial_force_n: f64,
    /// Torque its hand feels about the entry axis (N·m).
    pub torque_nm: f64,
    /// What held its push back in the last step.
    pub push_limit: PushLimit,
    /// Its push force limit (N).
    pub push_force_limit_n: f64,
    /// How it looks on X-ray.
    pub look: DeviceAppearance,
}

/// What the monitor is asked to show.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Live fluoroscopy.
    Fluoroscopy,
    /// A DSA run.
    Subtraction,
    /// Roadmap over live fluoroscopy.
    Roadmap,
}

/// The imaging state the trainee controls.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Imaging {
    /// Pedal down.
    pub pedal: bool,
    /// Pulse rate.
    pub pulse_rate: PulseRate,
    /// Mode.
    pub mode: Mode,
    /// LAO + / RAO − (deg).
    pub primary_deg: f64,
    /// CRA + / CAU − (deg).
    pub secondary_deg: f64,
    /// Counts DSA runs: a change tells the renderer to take a new mask.
    pub dsa_run: u32,
    /// The pose of the last DSA run (roadmap needs the same pose).
    pub dsa_pose: Option<(f64, f64)>,
}

/// A wall contact for clients (LPS, m and N).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallContact {
    /// Point on the device centerline (m).
    pub position: Vector3<f64>,
    /// Force of the wall on the device (N).
    pub force: Vector3<f64>,
}

/// The world after a step, for clients and the renderer (LPS, SI units).
#[derive(Debug, Clone)]
pub struct Snapshot {
    /// Steps taken.
    pub step: u64,
    /// Simulated time (s).
    pub time_s: f64,
    /// Sequence number of the last command applied.
    pub last_seq: u64,
    /// Node positions, base to tip (m).
    pub nodes: Vec<Vector3<f64>>,
    /// Unit tangent at the tip.
    pub tip_direction: Vector3<f64>,
    /// Inserted length (m).
    pub inserted_m: f64,
    /// Twist at the entry (rad).
    pub twist_rad: f64,
    /// Active wall contacts.
    pub contacts: Vec<WallContact>,
    /// Proximal reaction: force (N) and moment (N·m).
    pub proximal: [f64; 6],
    /// The scene's device index in use.
    pub active_device: u32,
    /// Imaging state.
    pub imaging: Imaging,
    /// Contrast-filled vessel pieces (LPS), shared until contrast next moves.
    pub contrast: Arc<Vec<ContrastTube>>,
    /// Metrics so far.
    pub metrics: Metrics,
    /// What held the push back in the last step, if anything.
    pub push_limit: PushLimit,
    /// The active device's push force limit (N).
    pub push_force_limit_n: f64,
    /// The overload governor's level (0: the scene's fidelity).
    pub fidelity_level: u8,
    /// Every instrument, outermost first (one for a one-device scene).
    pub instruments: Vec<InstrumentState>,
}

/// What holds a push back: the force the hand or the device can push with, or the device's
/// length (its hub at the sheath).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PushLimit {
    /// Nothing: the device advances as commanded.
    #[default]
    None,
    /// The proximal force reached the limit: the hand cannot push harder, or the device
    /// would buckle outside the sheath.
    Force,
    /// The device is in to its hub.
    Length,
}

/// The push limits of one device in a scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceLimits {
    /// The most the proximal end is pushed with (N).
    pub force_n: f64,
    /// Whether that is the device's buckling load (else the hand's strength).
    pub buckling: bool,
    /// The most that can be inserted (m): the device's length less what stays outside.
    pub max_inserted_m: f64,
}

impl DeviceLimits {
    /// The limits of `device` under `limits`: the force is the smaller of the hand's and the
    /// Euler load of the proximal shaft over the unsupported length, clamped at both ends
    /// (effective length half of it): P = π²·EI / (L/2)².
    /// `along_route_m` is the route not simulated before the entry point (m), which the
    /// device also fills.
    pub fn of(
        device: &cathlab_physics::Device,
        limits: &crate::scene::LimitsSpec,
        along_route_m: f64,
    ) -> Self {
        let ei = device
            .sections
            .first()
            .map_or(0.0, |s| s.beam_properties().bending_stiffness_nm2);
        let effective = 0.5 * limits.unsupported_mm * 1e-3;
        let buckling = std::f64::consts::PI.powi(2) * ei / (effective * effective);
        Self {
            force_n: buckling.min(limits.push_force_n),
            buckling: buckling < limits.push_force_n,
            max_inserted_m: device.length_m() - limits.outside_mm * 1e-3 - along_route_m,
        }
    }
}

impl Snapshot {
    /// Tip position (m, LPS).
    pub fn tip(&self) -> Vector3<f64> {
        self.nodes.last().copied().unwrap_or_else(Vector3::zeros)
    }

    /// The proximal reaction along the device axis at the entry (the first element's
    /// direction): the force resisting a push (N, positive when the device pushes back on
    /// the hand) and the torque about the axis (N·m).
    pub fn axial_reaction(&self) -> (f64, f64) {
        let axis = match self.nodes.as_slice() {
            [a, b, ..] => (b - a).try_normalize(1e-12),
            _ => None,
        };
        let Some(axis) = axis else {
            return (0.0, 0.0);
        };
        let p = &self.proximal;
        let force = Vector3::new(p[0], p[1], p[2]).dot(&axis);
        let torque = Vector3::new(p[3], p[4], p[5]).dot(&axis);
        (force, torque)
    }
}

/// Flow and contrast of a scene that has them.
struct Hemo {
    solver: FlowSolver,
    contrast: Contrast,
    agent_mg_per_ml: f64,
    /// Volume left to inject (m³) and rate (m³/s), while injecting.
    injection: Option<(f64, f64)>,
    steps_since_contrast: u32,
    tubes: Arc<Vec<ContrastTube>>,
    /// Whether any iodine is in the vessels (contrast steps only then).
    active: bool,
    /// The power injector's program (mL, mL/s): the last injection's, run again when a DSA
    /// run fires it.
    program: (f64, f64),
    /// When the injector linked to the current DSA run fires (procedure time, s).
    linked_at_s: Option<f64>,
    /// The flow with every vessel open and no injection: what reperfusion is measured
    /// against.
    open_flow: FlowSolution,
    /// The outlets the clots cut off (empty without clots), on the grading network.
    territory: Vec<usize>,
    /// A scene with collaterals: the network without them and its open flow, on which
    /// eTICI grades the antegrade reperfusion (the collaterals' retrograde filling does not
    /// count).
    grading: Option<(FlowSolver, FlowSolution)>,
    /// The flow with the clots now and no injection (pressures across a clot).
    flow_now: FlowSolution,
}

/// The power injector's program before any injection: 6 mL at 4 mL/s, a selective
/// common-carotid run through a 5 F catheter.
const DEFAULT_INJECTOR_PROGRAM: (f64, f64) = (6.0, 4.0);

/// Delay from the start of a DSA run to the linked injection (s): the mask frames come first.
pub const LINKED_INJECTION_DELAY_S: f64 = 0.5;

/// Threshold below which contrast cells are not drawn (mg/mL).
const CONTRAST_DRAW_THRESHOLD: f64 = 1.0;

/// One session's simulation.
pub struct World {
    assets: Arc<SceneAssets>,
    strand: Strand,
    /// One per instrument, outermost first.
    hands: Vec<Hand>,
    active_device: usize,
    imaging: Imaging,
    hemo: Option<Hemo>,
    metrics: Metrics,
    step: u64,
    last_seq: u64,
    previous_tip: Vector3<f64>,
    events: Vec<Event>,
    proximal: [f64; 6],
    fidelity: u8,
    /// Each instrument's tip (None: withdrawn) and inserted length after the last step.
    previous_instruments: Vec<(Option<Vector3<f64>>, f64)>,
    /// An exchange under way: the instrument (and those inside it) being withdrawn to the
    /// hub of the one around it, then replaced.
    exchanging: Option<PendingExchange>,
    /// The thrombectomy of a clotted scene with flow.
    procedure: Option<crate::thrombectomy::Procedure>,
    /// The scene's scripted operator, while it demonstrates.
    demonstration: Option<operator::SceneOperator>,
    /// The world applies its own operator's commands (they do not end a demonstration).
    operating: bool,
}

/// A device a client chose: an entry of the built-in catalogue or a spare of the scene.
#[derive(Debug, Clone, Copy)]
enum Chosen {
    Catalogue(u32),
    Spare(u32),
}

/// An exchange (or an unloading) waiting for its instrument to be withdrawn.
#[derive(Debug, Clone)]
struct PendingExchange {
    index: usize,
    /// The device that takes its place, its look and the name it goes by; `None`: the
    /// instrument is taken out.
    replacement: Option<(cathlab_physics::Device, DeviceAppearance, String)>,
}

/// One instrument's hand: its device's look and limits, and what held its push back.
#[derive(Debug, Clone)]
struct Hand {
    catalogue_id: String,
    look: DeviceAppearance,
    limits: DeviceLimits,
    push_limit: PushLimit,
    /// Whether the next time a limit holds the push back is reported (re-armed after the push
    /// has been free for `LIMIT_REARM_S`).
    limit_armed: bool,
    push_free_since_s: f64,
    reaction: HandReaction,
}

impl Hand {
    fn new(
        catalogue_id: String,
        device: &cathlab_physics::Device,
        look: DeviceAppearance,
        spec: &crate::scene::SceneSpec,
    ) -> Self {
        Self {
            catalogue_id,
            look,
            limits: DeviceLimits::of(device, &spec.limits, spec.start.along_route_mm * 1e-3),
            push_limit: PushLimit::None,
            limit_armed: true,
            push_free_since_s: 0.0,
            reaction: HandReaction::default(),
        }
    }
}

/// The hands of the scene's start: the active device's, or one per stack instrument.
fn start_hands(assets: &SceneAssets, active: usize) -> Vec<Hand> {
    if assets.spec.stack.is_empty() {
        let (device, look) = &assets.devices[active];
        return vec![Hand::new(String::new(), device, look.clone(), &assets.spec)];
    }
    assets
        .spec
        .stack
        .iter()
        .zip(&assets.devices)
        .map(|(entry, (device, look))| {
            Hand::new(entry.device.clone(), device, look.clone(), &assets.spec)
        })
        .collect()
}

/// The lowest fidelity the overload governor may set.
pub const MAX_FIDELITY_LEVEL: u8 = 3;

/// What a fidelity level allows a step: the physics' effort, a cap on the push speed (m/s),
/// and a description for the event.
pub fn fidelity_effort(level: u8) -> (Effort, Option<f64>, &'static str) {
    match level {
        0 => (Effort::FULL, None, "the scene's fidelity"),
        1 => (
            Effort {
                max_substep_depth: 1,
                max_detection_rounds: 2,
                ..Effort::FULL
            },
            None,
            "one sub-step halving, two detection rounds",
        ),
        2 => (
            Effort {
                max_substep_depth: 0,
                max_detection_rounds: 1,
                max_sweeps: 60,
                polish: true,
                refinement_scale: 2.0,
            },
            None,
            "no sub-steps, one detection round, 60 contact sweeps, refinement halved",
        ),
        _ => (
            Effort {
                max_substep_depth: 0,
                max_detection_rounds: 1,
                max_sweeps: 20,
                polish: false,
                refinement_scale: 4.0,
            },
            Some(0.03),
            "no sub-steps, one detection round, 20 contact sweeps, refinement quartered, \
             pushes slowed to 30 mm/s",
        ),
    }
}

/// How long a push must go unhindered before the next limit it meets is reported again (s).
const LIMIT_REARM_S: f64 = 0.5;

impl std::fmt::Debug for World {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("World")
            .field("scene", &self.assets.spec.name)
            .field("step", &self.step)
            .finish_non_exhaustive()
    }
}

/// The navigation settings of a scene's fidelity.
pub(crate) fn navigation_settings(assets: &SceneAssets) -> NavigationSettings {
    let q = &assets.spec.fidelity;
    let mut settings = NavigationSettings {
        time_step_s: assets.spec.time_step_s(),
        tip_element_m: q.tip_element_mm * 1e-3,
        shaft_element_m: q.shaft_element_mm * 1e-3,
        refinement: q.refine.then(Refinement::default),
        ..NavigationSettings::default()
    };
    settings.contact.tolerance = q.contact_tolerance;
    settings
}

impl World {
    /// The scene's start: its first device inserted, pedal up, the scene's C-arm pose.
    pub fn new(assets: Arc<SceneAssets>) -> Result<Self> {
        let strand = Strand::start(&assets, 0)?;
        let mut reperfusion = None;
        let hemo = match &assets.network {
            None => None,
            Some(network) => {
                let mut solver = FlowSolver::new(network.clone())?;
                let open_flow = solver.solve(None)?;
                let flow = if assets.clots.is_empty() {
                    open_flow.clone()
                } else {
                    solver.set_occlusions(&assets.clots)?;
                    solver.solve(None)?
                };
                let mut grading = match &assets.grading_network {
                    None => None,
                    Some(n) => {
                        let mut g = FlowSolver::new(n.clone())?;
                        let open = g.solve(None)?;
                        g.set_occlusions(&assets.clots)?;
                        Some((g, open))
                    }
                };
                let (graded_open, graded_now) = match &mut grading {
                    None => (open_flow.clone(), flow.clone()),
                    Some((g, open)) => (open.clone(), g.solve(None)?),
                };
                let territory = if assets.clots.is_empty() {
                    Vec::new()
                } else {
                    occluded_territory(&graded_open, &graded_now)?
                };
                let mut contrast = Contrast::new(
                    network,
                    ContrastSettings {
                        cell_length: assets.spec.fidelity.contrast_cell_mm * 1e-3,
                        ..ContrastSettings::default()
                    },
                )?;
                contrast.set_flow(network, &flow)?;
                reperfusion = reperfusion_metric(&graded_open, &graded_now, &territory)?;
                Some(Hemo {
                    solver,
                    contrast,
                    agent_mg_per_ml: assets
                        .spec
                        .flow
                        .as_ref()
                        .map_or(300.0, |f| f.agent_mg_per_ml),
                    injection: None,
                    steps_since_contrast: 0,
                    tubes: Arc::new(Vec::new()),
                    active: false,
                    program: DEFAULT_INJECTOR_PROGRAM,
                    linked_at_s: None,
                    open_flow,
                    territory,
                    grading,
                    flow_now: flow,
                })
            }
        };
        let rate = assets.spec.fluoroscopy.pulse_rate;
        let pulse_rate = if rate < 10.0 {
            PulseRate::Hz7_5
        } else if rate > 20.0 {
            PulseRate::Hz30
        } else {
            PulseRate::Hz15
        };
        let tip = tracked_tip(&assets, &strand);
        let target_remaining_m = assets.remaining_to_target_m(&Point3::from(tip));
        let hands = start_hands(&assets, 0);
        let procedure = match (&assets.network, assets.clots.is_empty()) {
            (Some(network), false) => {
                let legs: Vec<(usize, f64, f64)> = assets
                    .route
                    .legs
                    .iter()
                    .map(|l| (l.branch, l.from_arc, l.to_arc))
                    .collect();
                let reds: Vec<f64> = assets
                    .spec
                    .clots
                    .iter()
                    .map(|c| c.red_cell_fraction)
                    .collect();
                Some(crate::thrombectomy::Procedure::new(
                    &assets.clots,
                    &reds,
                    network,
                    &legs,
                ))
            }
            _ => None,
        };
        Ok(Self {
            imaging: Imaging {
                pedal: false,
                pulse_rate,
                mode: Mode::Fluoroscopy,
                primary_deg: assets.spec.carm.primary_deg,
                secondary_deg: assets.spec.carm.secondary_deg,
                dsa_run: 0,
                dsa_pose: None,
            },
            assets,
            strand,
            hands,
            active_device: 0,
            hemo,
            metrics: Metrics {
                target_remaining_m,
                reperfusion,
                ..Metrics::default()
            },
            step: 0,
            last_seq: 0,
            previous_tip: tip,
            events: Vec::new(),
            proximal: [0.0; 6],
            fidelity: 0,
            previous_instruments: Vec::new(),
            exchanging: None,
            procedure,
            demonstration: None,
            operating: false,
        })
    }

    /// The scene.
    pub fn assets(&self) -> &Arc<SceneAssets> {
        &self.assets
    }

    /// The sequence number of the last command applied.
    pub fn last_seq(&self) -> u64 {
        self.last_seq
    }

    /// The overload governor's level in force.
    pub fn fidelity_level(&self) -> u8 {
        self.fidelity
    }

    /// Steps taken.
    pub fn step_index(&self) -> u64 {
        self.step
    }

    /// The navigated device of a one-device scene (read-only: scripted drivers look at it to
    /// choose commands); `None` for a stack.
    pub fn navigation(&self) -> Option<&Navigation<SharedWall>> {
        self.strand.navigation()
    }

    /// What the hands hold: one device or the stack.
    pub fn strand(&self) -> &Strand {
        &self.strand
    }

    /// Metrics so far.
    pub fn metrics(&self) -> &Metrics {
        &self.metrics
    }

    /// Events since the last call.
    pub fn take_events(&mut self) -> Vec<Event> {
        std::mem::take(&mut self.events)
    }

    fn event(&mut self, kind: EventKind, message: impl Into<String>) {
        self.events.push(Event {
            step: self.step,
            time_s: self.metrics.procedure_time_s,
            kind,
            message: message.into(),
        });
    }

    /// Applies a command at the current step boundary; `seq` is the client's sequence number.
    /// A command that cannot apply (roadmap without a DSA run at this pose, injection without
    /// flow, a device index out of range) changes nothing and says why.
    pub fn apply(&mut self, seq: u64, command: &Command) -> Result<()> {
        let innermost = self.strand.len() - 1;
        self.cancel_exchange_if_pushed(command);
        if !self.operating
            && self.demonstration.is_some()
            && matches!(
                command,
                Command::PushVelocity(_)
                    | Command::PushTarget(_)
                    | Command::TwistRate(_)
                    | Command::TwistTarget(_)
                    | Command::Setpoints { .. }
                    | Command::Instrument { .. }
                    | Command::Exchange { .. }
                    | Command::ExchangeSpare { .. }
                    | Command::Load { .. }
                    | Command::LoadSpare { .. }
                    | Command::Unload
                    | Command::SelectDevice(_)
                    | Command::Reset
            )
        {
            self.demonstration = None;
            self.event(
                EventKind::Device,
                "demonstration ended: the trainee took over",
            );
        }
        match *command {
            Command::PushVelocity(v) => self.drive(innermost, Drive::PushVelocity(v))?,
            Command::PushTarget(x) => self.drive(innermost, Drive::PushTarget(x))?,
            Command::TwistRate(w) => self.drive(innermost, Drive::TwistRate(w))?,
            Command::TwistTarget(a) => self.drive(innermost, Drive::TwistTarget(a))?,
            Command::Setpoints {
                push_m_s,
                twist_rad_s,
            } => self.drive(
                innermost,
                Drive::Setpoints {
                    push_m_s,
                    twist_rad_s,
                },
            )?,
            Command::Instrument { index, drive } => {
                self.strand.check(index as usize, "instrument")?;
                self.drive(index as usize, drive)?;
            }
            Command::Exchange { index, catalogue } => {
                let (device, look, id) = self.chosen(Chosen::Catalogue(catalogue), "exchange")?;
                self.exchange(index, &device, look, id)?;
            }
            Command::ExchangeSpare { index, spare } => {
                let (device, look, id) = self.chosen(Chosen::Spare(spare), "exchange")?;
                self.exchange(index, &device, look, id)?;
            }
            Command::Load { catalogue } => {
                let (device, look, id) = self.chosen(Chosen::Catalogue(catalogue), "load")?;
                self.load(&device, look, id)?;
            }
            Command::LoadSpare { spare } => {
                let (device, look, id) = self.chosen(Chosen::Spare(spare), "load")?;
                self.load(&device, look, id)?;
            }
            Command::Unload => self.unload()?,
            Command::SelectDevice(_) if !self.assets.spec.stack.is_empty() => {
                return Err(EngineError::FailedPrecondition(
                    "a coaxial scene exchanges instruments (withdraw one to its hub, then \
                     exchange it); it has no devices to select"
                        .into(),
                ));
            }
            Command::SelectDevice(index) => {
                let index = index as usize;
                if index >= self.assets.devices.len() {
                    return Err(EngineError::InvalidArgument {
                        field: "select_device".into(),
                        reason: format!(
                            "{index} is not a device of this scene (it has {})",
                            self.assets.devices.len()
                        ),
                    });
                }
                self.restart_device(index)?;
                let name = self.assets.devices[index].0.name.clone();
                self.event(
                    EventKind::Device,
                    format!("device {index} ({name}) inserted"),
                );
            }
            Command::Fluoroscopy(on) => {
                if on != self.imaging.pedal {
                    self.imaging.pedal = on;
                    self.event(
                        EventKind::Imaging,
                        if on {
                            "fluoroscopy on"
                        } else {
                            "fluoroscopy off"
                        },
                    );
                }
            }
            Command::PulseRate(rate) => self.imaging.pulse_rate = rate,
            Command::Dsa(start) => {
                if start {
                    self.imaging.mode = Mode::Subtraction;
                    self.imaging.dsa_run += 1;
                    self.imaging.dsa_pose =
                        Some((self.imaging.primary_deg, self.imaging.secondary_deg));
                    self.metrics.dsa_runs += 1;
                    let run = self.imaging.dsa_run;
                    self.event(EventKind::Imaging, format!("DSA run {run} started"));
                    // The injector is linked to the run: it fires after the mask.
                    let at = self.metrics.procedure_time_s + LINKED_INJECTION_DELAY_S;
                    if let Some(hemo) = &mut self.hemo {
                        hemo.linked_at_s = Some(at);
                    }
                } else if self.imaging.mode == Mode::Subtraction {
                    if let Some(hemo) = &mut self.hemo {
                        hemo.linked_at_s = None;
                    }
                    self.imaging.mode = Mode::Fluoroscopy;
                    self.event(EventKind::Imaging, "DSA run ended");
                }
            }
            Command::Roadmap(on) => {
                if on {
                    let pose = (self.imaging.primary_deg, self.imaging.secondary_deg);
                    if self.imaging.dsa_pose != Some(pose) {
                        return Err(EngineError::FailedPrecondition(
                            "roadmap needs a DSA run at the current C-arm pose".into(),
                        ));
                    }
                    self.imaging.mode = Mode::Roadmap;
                    self.event(EventKind::Imaging, "roadmap on");
                } else if self.imaging.mode == Mode::Roadmap {
                    self.imaging.mode = Mode::Fluoroscopy;
                    self.event(EventKind::Imaging, "roadmap off");
                }
            }
            Command::CArm {
                primary_deg,
                secondary_deg,
            } => {
                self.imaging.primary_deg = primary_deg;
                self.imaging.secondary_deg = secondary_deg;
                if self.imaging.mode == Mode::Roadmap
                    && self.imaging.dsa_pose != Some((primary_deg, secondary_deg))
                {
                    self.imaging.mode = Mode::Fluoroscopy;
                    self.event(EventKind::Imaging, "roadmap off: the C-arm moved");
                }
            }
            Command::Inject {
                volume_ml,
                rate_ml_s,
            } => {
                let Some(hemo) = &mut self.hemo else {
                    return Err(EngineError::FailedPrecondition(
                        "this scene has no blood flow: contrast cannot be injected".into(),
                    ));
                };
                hemo.injection = Some((volume_ml * 1e-6, rate_ml_s * 1e-6));
                hemo.program = (volume_ml, rate_ml_s);
                // An injection by hand during a DSA run replaces the linked one.
                hemo.linked_at_s = None;
                self.update_injection()?;
                self.event(
                    EventKind::Contrast,
                    format!("{volume_ml:.1} mL of contrast at {rate_ml_s:.1} mL/s"),
                );
            }
            Command::Fidelity(level) => {
                let level = level.min(MAX_FIDELITY_LEVEL);
                if level != self.fidelity {
                    let (effort, _, what) = fidelity_effort(level);
                    self.strand.set_effort(effort)?;
                    let message = if level > self.fidelity {
                        format!(
                            "the server is overloaded: fidelity lowered to level {level} of \
                             {MAX_FIDELITY_LEVEL} ({what})"
                        )
                    } else {
                        format!("fidelity raised to level {level} ({what})")
                    };
                    self.fidelity = level;
                    self.event(EventKind::Overload, message);
                }
            }
            Command::Aspiration(on) => {
                let Some(procedure) = &mut self.procedure else {
                    return Err(EngineError::FailedPrecondition(
                        "the scene has no clot to aspirate".into(),
                    ));
                };
                procedure.set_aspiration(on);
                self.event(
                    EventKind::Thrombectomy,
                    if on { "suction on" } else { "suction off" },
                );
            }
            Command::DeployStent => {
                let (k, spec) = self.stent_instrument()?;
                let tip = |i: usize| self.strand.tip_position(i).map(Point3::from);
                let (Some(stent_tip), Some(mc_tip)) = (tip(k), tip(k - 1)) else {
                    return Err(EngineError::FailedPrecondition(
                        "the stent retriever is not in the patient".into(),
                    ));
                };
                let arc = |p: &Point3<f64>| {
                    crate::thrombectomy::route_arc(
                        &self.assets.route_samples,
                        crate::assets::ROUTE_SPACING_M,
                        p,
                    )
                };
                let stent_proximal = arc(&stent_tip) - spec.from_tip_m - spec.length_m;
                let back = arc(&mc_tip) - stent_proximal + 1e-3;
                if back <= 0.0 {
                    return Err(EngineError::FailedPrecondition(
                        "the stent is already unsheathed".into(),
                    ));
                }
                let target = self.strand.inserted_m(k - 1) - back;
                self.drive(k, Drive::PushVelocity(0.0))?;
                self.drive(k - 1, Drive::PushTarget(target))?;
                self.event(
                    EventKind::Thrombectomy,
                    format!(
                        "deploying: the microcatheter drawn back {:.1} mm over the held stent",
                        back * 1e3
                    ),
                );
            }
            Command::Demonstrate(on) => {
                if !on {
                    if self.demonstration.take().is_some() {
                        self.hold_all()?;
                        self.event(EventKind::Device, "demonstration stopped");
                    }
                } else if self.demonstration.is_none() {
                    self.demonstration = Some(self.scene_operator()?);
                    self.event(
                        EventKind::Device,
                        "demonstration: the scene's operator drives to the target",
                    );
                }
            }
            Command::RetrieveStent => {
                let (k, _) = self.stent_instrument()?;
                self.drive(k, Drive::PushVelocity(-RETRIEVE_SPEED_M_S))?;
                self.drive(k - 1, Drive::PushVelocity(-RETRIEVE_SPEED_M_S))?;
                self.event(
                    EventKind::Thrombectomy,
                    format!(
                        "retrieving: stent and microcatheter pulled back at {:.0} mm/s",
                        RETRIEVE_SPEED_M_S * 1e3
                    ),
                );
            }
            Command::Reset => {
                self.restart_device(self.active_device)?;
                // A new attempt: the target is to be reached again.
                self.metrics.operator_resets += 1;
                self.metrics.target_reached_at_s = None;
                self.metrics.attempt_started_at_s = self.metrics.procedure_time_s;
                self.event(EventKind::Reset, "scene reset: a new attempt");
            }
        }
        self.last_seq = seq;
        Ok(())
    }

    /// The stack's stent retriever (its index, not the outermost) and its stent.
    fn stent_instrument(&self) -> Result<(usize, cathlab_physics::StentSpec)> {
        let catalogue = crate::scene::catalogue();
        self.hands
            .iter()
            .enumerate()
            .skip(1)
            .find_map(|(i, h)| {
                catalogue
                    .get(&h.catalogue_id)
                    .and_then(|e| e.stent)
                    .map(|s| (i, s))
            })
            .ok_or_else(|| {
                EngineError::FailedPrecondition(
                    "no stent retriever in the stack (exchange the microwire for one)".into(),
                )
            })
    }

    /// The thrombectomy's figures, when the scene has a clot.
    pub fn procedure(&self) -> Option<&crate::thrombectomy::Procedure> {
        self.procedure.as_ref()
    }

    /// Steps the thrombectomy: instruments on the route, passes, clots into the flow.
    fn step_procedure(&mut self, dt: f64) -> Result<()> {
        let (Some(procedure), Some(hemo)) = (&mut self.procedure, &self.hemo) else {
            return Ok(());
        };
        let catalogue = crate::scene::catalogue();
        let assets = &self.assets;
        let views: Vec<crate::thrombectomy::InstrumentView> = (0..self.strand.len())
            .map(|i| {
                let entry = catalogue.get(&self.hands[i].catalogue_id);
                let tip = self.strand.tip_position(i).map_or(0.0, |t| {
                    crate::thrombectomy::route_arc(
                        &assets.route_samples,
                        crate::assets::ROUTE_SPACING_M,
                        &Point3::from(t),
                    )
                });
                let section = self
                    .strand
                    .device(i)
                    .and_then(|d| d.sections.last())
                    .map(|s| s.cross_section);
                crate::thrombectomy::InstrumentView {
                    kind: entry.map(|e| e.kind),
                    stent: entry.and_then(|e| e.stent),
                    tip_arc_m: tip,
                    inserted_m: self.strand.inserted_m(i),
                    outer_diameter_m: section.map_or(0.0, |c| 2.0 * c.outer_radius_m),
                    bore_m: section.map_or(0.0, |c| 2.0 * c.inner_radius_m),
                    axial_force_n: self.hands[i].reaction.axial_force_n,
                }
            })
            .collect();
        let outcome = procedure.step(
            &views,
            dt,
            &assets.route_samples,
            &assets.route_radii,
            crate::assets::ROUTE_SPACING_M,
            hemo.solver.network(),
            &hemo.flow_now,
            &hemo.open_flow,
        );
        // The clot's resistance on the tips crossing it, for the next step (a one-device
        // scene records the crossing but does not load its beam).
        if self.strand.stack().is_some() {
            for (k, &load) in procedure.tip_loads().iter().enumerate() {
                self.strand.set_tip_load(k, load)?;
            }
        }
        let figures = procedure.figures();
        self.metrics.thrombectomy = Some(crate::metrics::ThrombectomyMetric {
            passes: figures.passes,
            first_pass_effect: figures.first_pass_effect,
            emboli: figures.emboli,
            crossing_force_n: figures.crossing_force_n,
            peak_crossing_force_n: figures.peak_crossing_force_n,
            grip_n: figures.grip_n,
            aspiration: procedure.aspiration(),
            reperfused_at_s: self.metrics.thrombectomy.and_then(|t| t.reperfused_at_s),
        });
        for message in outcome.messages {
            self.event(EventKind::Thrombectomy, message);
        }
        if outcome.pass_ended {
            for i in 0..self.strand.len() {
                if matches!(self.strand.command(i).insertion, Insertion::Velocity(v) if v < 0.0) {
                    self.drive(i, Drive::PushVelocity(0.0))?;
                }
            }
        }
        if let Some(occlusions) = outcome.occlusions {
            self.replace_clots(&occlusions, false)?;
        }
        if let (Some(t), Some(r)) = (&mut self.metrics.thrombectomy, &self.metrics.reperfusion)
            && t.reperfused_at_s.is_none()
            && r.etici.successful()
        {
            t.reperfused_at_s = Some(self.metrics.procedure_time_s);
        }
        Ok(())
    }

    /// Applies `drive` to instrument `index` (checked).
    fn drive(&mut self, index: usize, drive: Drive) -> Result<()> {
        let current = self.strand.command(index);
        let (insertion, twist) = match drive {
            Drive::PushVelocity(v) => (Insertion::Velocity(v), current.twist),
            Drive::PushTarget(x) => (Insertion::Target(x), current.twist),
            Drive::TwistRate(w) => (current.insertion, Twist::Rate(w)),
            Drive::TwistTarget(a) => (current.insertion, Twist::Target(a)),
            Drive::Setpoints {
                push_m_s,
                twist_rad_s,
            } => (Insertion::Velocity(push_m_s), Twist::Rate(twist_rad_s)),
        };
        self.strand
            .set_command(index, cathlab_physics::Command { insertion, twist })
    }

    /// Exchanges stack instrument `index` for `device` (its look and the name it goes by):
    /// at once when it (and everything inside it) is withdrawn to the hub of the one around
    /// it; otherwise it is first drawn back there at the hand's top speed, step by step (the
    /// trainee sees it come out), and replaced when it arrives. A push on a withdrawing
    /// instrument cancels the exchange.
    fn exchange(
        &mut self,
        index: u32,
        device: &cathlab_physics::Device,
        look: DeviceAppearance,
        id: String,
    ) -> Result<()> {
        let index = index as usize;
        self.strand.check(index, "exchange.instrument")?;
        let Some(stack) = self.strand.stack() else {
            return Err(EngineError::FailedPrecondition(
                "a one-device scene selects devices; only a coaxial stack exchanges them".into(),
            ));
        };
        stack
            .check_exchange(index, device)
            .map_err(|e| EngineError::FailedPrecondition(e.to_string()))?;
        let name = stack
            .device(index)
            .map(|d| d.name.clone())
            .unwrap_or_default();
        self.exchanging = Some(PendingExchange {
            index,
            replacement: Some((device.clone(), look, id.clone())),
        });
        if !self.finish_exchange()? {
            self.event(
                EventKind::Device,
                format!("instrument {index}: withdrawing {name} for an exchange with {id}"),
            );
        }
        Ok(())
    }

    /// Drives the instruments of a pending exchange back toward the hub (each step, as the
    /// hub of the one around each moves with it).
    fn withdraw_for_exchange(&mut self) -> Result<()> {
        let Some(pending) = &self.exchanging else {
            return Ok(());
        };
        let index = pending.index;
        for k in index..self.strand.len() {
            if let Some((lo, _)) = self.strand.stack().and_then(|s| s.inserted_range_m(k)) {
                self.drive(k, Drive::PushTarget(lo))?;
            }
        }
        Ok(())
    }

    /// Replaces the instrument of a pending exchange when it (and everything inside it) is
    /// at the hub; whether it did.
    fn finish_exchange(&mut self) -> Result<bool> {
        let Some(pending) = &self.exchanging else {
            return Ok(false);
        };
        let Some(stack) = self.strand.stack_mut() else {
            self.exchanging = None;
            return Ok(false);
        };
        // Asked each step of the withdrawal, without cloning the device or re-checking its fit.
        if stack.still_inserted(pending.index).is_some() {
            return Ok(false);
        }
        let index = pending.index;
        let Some((device, look, id)) = pending.replacement.clone() else {
            let device = stack
                .pop_instrument()
                .map_err(|e| EngineError::FailedPrecondition(e.to_string()))?;
            self.exchanging = None;
            let hand = self.hands.pop().map(|h| h.catalogue_id).unwrap_or_default();
            let was = if hand.is_empty() { device.name } else { hand };
            self.event(
                EventKind::Device,
                format!("instrument {index}: {was} taken out"),
            );
            return Ok(true);
        };
        stack
            .exchange(index, device.clone())
            .map_err(|e| EngineError::FailedPrecondition(e.to_string()))?;
        self.exchanging = None;
        let old = std::mem::replace(
            &mut self.hands[index],
            Hand::new(id.clone(), &device, look, &self.assets.spec),
        );
        let was = if old.catalogue_id.is_empty() {
            "the scene's device".to_owned()
        } else {
            old.catalogue_id
        };
        self.event(
            EventKind::Device,
            format!("instrument {index}: {was} exchanged for {id}"),
        );
        Ok(true)
    }

    /// The device a client chose for an exchange or a load (`what`, naming the field): a
    /// catalogue entry or a spare of the scene, with its look and the name it goes by.
    fn chosen(
        &self,
        choice: Chosen,
        what: &str,
    ) -> Result<(cathlab_physics::Device, DeviceAppearance, String)> {
        match choice {
            Chosen::Catalogue(k) => {
                let entries = crate::scene::catalogue().entries();
                let entry =
                    entries
                        .get(k as usize)
                        .ok_or_else(|| EngineError::InvalidArgument {
                            field: format!("{what}.device"),
                            reason: format!(
                                "catalogue entry {k} does not exist (the catalogue has {})",
                                entries.len()
                            ),
                        })?;
                let look = crate::assets::appearance_of_entry(entry);
                Ok((entry.device.clone(), look, entry.id.clone()))
            }
            Chosen::Spare(k) => {
                let spares = &self.assets.spares;
                let (device, look) =
                    spares
                        .get(k as usize)
                        .ok_or_else(|| EngineError::InvalidArgument {
                            field: format!("{what}.spare"),
                            reason: format!(
                                "spare {k} does not exist (the scene has {})",
                                spares.len()
                            ),
                        })?;
                let label = self.assets.spec.spares[k as usize].label();
                Ok((device.clone(), look.clone(), label))
            }
        }
    }

    /// Loads `device` (its look and the name it goes by) into the stack's innermost
    /// instrument as the new innermost, its tip at that one's hub.
    fn load(
        &mut self,
        device: &cathlab_physics::Device,
        look: DeviceAppearance,
        id: String,
    ) -> Result<()> {
        if self.exchanging.is_some() {
            return Err(EngineError::FailedPrecondition(
                "an exchange or unloading is under way; load once it is done".into(),
            ));
        }
        let Some(stack) = self.strand.stack_mut() else {
            return Err(EngineError::FailedPrecondition(
                "a one-device scene selects devices; only a coaxial stack loads them".into(),
            ));
        };
        let outer = stack
            .device(stack.len() - 1)
            .map(|d| d.name.clone())
            .unwrap_or_default();
        stack
            .push_instrument(device.clone())
            .map_err(|e| EngineError::FailedPrecondition(e.to_string()))?;
        let index = self.hands.len();
        self.hands
            .push(Hand::new(id.clone(), device, look, &self.assets.spec));
        self.event(
            EventKind::Device,
            format!("instrument {index}: {id} loaded into {outer}"),
        );
        Ok(())
    }

    /// Withdraws the innermost instrument to the hub of the one around it (step by step, as
    /// for an exchange) and takes it out; a push on it cancels.
    fn unload(&mut self) -> Result<()> {
        if self.exchanging.is_some() {
            return Err(EngineError::FailedPrecondition(
                "an exchange or unloading is under way; take out once it is done".into(),
            ));
        }
        let Some(stack) = self.strand.stack() else {
            return Err(EngineError::FailedPrecondition(
                "a one-device scene has nothing to take out of a stack".into(),
            ));
        };
        let index = stack.len() - 1;
        if index == 0 {
            return Err(EngineError::FailedPrecondition(
                "the outermost instrument cannot be taken out".into(),
            ));
        }
        let name = stack
            .device(index)
            .map(|d| d.name.clone())
            .unwrap_or_default();
        self.exchanging = Some(PendingExchange {
            index,
            replacement: None,
        });
        if !self.finish_exchange()? {
            self.event(
                EventKind::Device,
                format!("instrument {index}: withdrawing {name} to take it out"),
            );
        }
        Ok(())
    }

    /// A push (a non-zero speed or a target) on an instrument being withdrawn for an exchange
    /// takes it back: the exchange is cancelled. Zero speeds (a still hand, a keep-alive) and
    /// twists do not.
    fn cancel_exchange_if_pushed(&mut self, command: &Command) {
        let Some(pending) = &self.exchanging else {
            return;
        };
        let pushes = |drive: &Drive| match *drive {
            Drive::PushVelocity(v) => v != 0.0,
            Drive::PushTarget(_) => true,
            Drive::Setpoints { push_m_s, .. } => push_m_s != 0.0,
            Drive::TwistRate(_) | Drive::TwistTarget(_) => false,
        };
        let innermost = self.strand.len() - 1;
        let taken = match *command {
            Command::PushVelocity(v) => (v != 0.0).then_some(innermost),
            Command::PushTarget(_) => Some(innermost),
            Command::Setpoints { push_m_s, .. } => (push_m_s != 0.0).then_some(innermost),
            Command::Instrument { index, drive } if pushes(&drive) => Some(index as usize),
            _ => None,
        };
        if let Some(k) = taken.filter(|k| *k >= pending.index) {
            let index = pending.index;
            self.exchanging = None;
            self.event(
                EventKind::Device,
                format!("instrument {index}: exchange cancelled (instrument {k} pushed)"),
            );
        }
    }

    /// The command this step runs instead of the operator's for instrument `index` when a
    /// limit holds its push back (None: the operator's). The force limit looks at the last
    /// step's proximal reaction: a push that met it holds the instrument where it is (the hand
    /// pushes no harder), so it advances only as fast as the force allows. Reports each new
    /// hold once.
    fn limited_command(
        &mut self,
        index: usize,
        operator: cathlab_physics::Command,
        dt: f64,
    ) -> Option<cathlab_physics::Command> {
        let inserted = self.strand.inserted_m(index);
        let advance = match operator.insertion {
            Insertion::Velocity(v) => v * dt,
            Insertion::Target(x) => x - inserted,
        };
        let hand = &self.hands[index];
        let force = hand.reaction.axial_force_n;
        let limits = hand.limits;
        let cap = fidelity_effort(self.fidelity).1;
        let (limit, insertion) = if advance <= 0.0 {
            (PushLimit::None, None)
        } else if inserted + advance > limits.max_inserted_m {
            (
                PushLimit::Length,
                Some(Insertion::Target(limits.max_inserted_m.max(inserted))),
            )
        } else if force >= limits.force_n {
            (PushLimit::Force, Some(Insertion::Velocity(0.0)))
        } else if let Some(cap) = cap
            && advance > cap * dt
        {
            (PushLimit::None, Some(Insertion::Velocity(cap)))
        } else {
            (PushLimit::None, None)
        };
        let now = self.metrics.procedure_time_s;
        let hand = &mut self.hands[index];
        let mut report = None;
        if limit == PushLimit::None {
            if hand.push_limit != PushLimit::None {
                hand.push_free_since_s = now;
            }
            if now - hand.push_free_since_s >= LIMIT_REARM_S {
                hand.limit_armed = true;
            }
        } else if hand.limit_armed {
            hand.limit_armed = false;
            report = Some(limit);
        }
        hand.push_limit = limit;
        if let Some(limit) = report {
            let name = self
                .strand
                .device(index)
                .map_or_else(String::new, |d| d.name.clone());
            let message = match limit {
                PushLimit::Force if limits.buckling => format!(
                    "push held at {force:.1} N: the {name} buckles outside the sheath at {:.1} N",
                    limits.force_n
                ),
                PushLimit::Force => format!(
                    "push held at {force:.1} N: the hand's limit is {:.0} N",
                    limits.force_n
                ),
                _ => format!(
                    "the {name} is in to its hub: {:.0} mm inserted, {:.0} mm outside",
                    limits.max_inserted_m * 1e3,
                    self.assets.spec.limits.outside_mm
                ),
            };
            self.event(EventKind::Limit, message);
        }
        insertion.map(|insertion| cathlab_physics::Command {
            insertion,
            twist: operator.twist,
        })
    }

    fn restart_device(&mut self, index: usize) -> Result<()> {
        self.strand = Strand::start(&self.assets, index)?;
        self.exchanging = None;
        self.active_device = index;
        self.hands = start_hands(&self.assets, index);
        self.previous_instruments.clear();
        self.strand.set_effort(fidelity_effort(self.fidelity).0)?;
        self.previous_tip = tracked_tip(&self.assets, &self.strand);
        if let Some(hemo) = &mut self.hemo
            && hemo.injection.is_some()
        {
            hemo.injection = None;
            self.update_injection()?;
        }
        Ok(())
    }

    /// Re-solves the flow for the current injection (at the device tip) or none.
    /// Fires the injector linked to the DSA run when its time has come.
    fn fire_linked_injection(&mut self) -> Result<()> {
        let now = self.metrics.procedure_time_s;
        let Some(hemo) = &mut self.hemo else {
            return Ok(());
        };
        if hemo.linked_at_s.is_none_or(|at| now < at) {
            return Ok(());
        }
        hemo.linked_at_s = None;
        let (volume_ml, rate_ml_s) = hemo.program;
        hemo.injection = Some((volume_ml * 1e-6, rate_ml_s * 1e-6));
        match self.update_injection() {
            Ok(()) => self.event(
                EventKind::Contrast,
                format!("injector linked to the DSA run: {volume_ml:.1} mL at {rate_ml_s:.1} mL/s"),
            ),
            Err(e) => {
                if let Some(hemo) = &mut self.hemo {
                    hemo.injection = None;
                }
                self.event(
                    EventKind::Contrast,
                    format!("linked injection not given: {e}"),
                );
            }
        }
        Ok(())
    }

    /// Replaces the clots in the flow (vessel i = graph branch i; an empty slice reopens
    /// every vessel) and re-solves the flow that carries the contrast.
    pub fn set_clots(&mut self, clots: &[cathlab_hemo::Occlusion]) -> Result<()> {
        self.replace_clots(clots, true)
    }

    /// As [`World::set_clots`]; with `new_territory` false the territory whose reperfusion
    /// is graded stays the scene's (emboli and bypass channels do not redefine it).
    fn replace_clots(
        &mut self,
        clots: &[cathlab_hemo::Occlusion],
        new_territory: bool,
    ) -> Result<()> {
        let Some(hemo) = &mut self.hemo else {
            return Err(EngineError::FailedPrecondition(
                "the scene has no flow for clots to act on".into(),
            ));
        };
        hemo.solver.set_occlusions(clots)?;
        let now = hemo.solver.solve(None)?;
        hemo.flow_now = now.clone();
        // Graded on the network without collaterals, when the scene has them.
        let (open, now) = match &mut hemo.grading {
            None => (hemo.open_flow.clone(), now),
            Some((g, open)) => {
                g.set_occlusions(clots)?;
                (open.clone(), g.solve(None)?)
            }
        };
        if new_territory && !clots.is_empty() {
            // New clots cut off their own territory; removing them keeps the old one, whose
            // reperfusion is then measured.
            let cut = occluded_territory(&open, &now)?;
            if !cut.is_empty() {
                hemo.territory = cut;
            }
        }
        self.metrics.reperfusion = reperfusion_metric(&open, &now, &hemo.territory)?;
        self.update_injection()
    }

    /// The flow with the clots now and no injection (vessel i = graph branch i, then any
    /// collaterals), when the scene has flow.
    pub fn flow_now(&self) -> Option<&FlowSolution> {
        self.hemo.as_ref().map(|h| &h.flow_now)
    }

    /// The clots in the flow now.
    pub fn clots(&self) -> Vec<cathlab_hemo::Occlusion> {
        self.hemo
            .as_ref()
            .map_or_else(Vec::new, |h| h.solver.occlusions().copied().collect())
    }

    fn update_injection(&mut self) -> Result<()> {
        let tip = Point3::from(injection_tip(&self.strand));
        let graph = &self.assets.anatomy.graph;
        let Some(hemo) = &mut self.hemo else {
            return Ok(());
        };
        let injection = match hemo.injection {
            Some((_, rate)) => {
                let location = graph.nearest(&tip).ok_or_else(|| {
                    EngineError::FailedPrecondition("the tip is not near any vessel".into())
                })?;
                Some(Injection {
                    vessel: location.branch,
                    arc: location.arc_length,
                    rate,
                    concentration: hemo.agent_mg_per_ml,
                })
            }
            None => None,
        };
        let solution = hemo.solver.solve(injection.as_ref())?;
        hemo.contrast.set_flow(hemo.solver.network(), &solution)?;
        hemo.active |= injection.is_some();
        Ok(())
    }

    /// Drives the world with `pilot` (a scripted trainee) for at most `max_steps` steps; its
    /// commands are applied as recorded commands numbered from `first_seq`. Returns the step
    /// index at which the autopilot found the target reached, or `None` if it did not.
    pub fn follow_autopilot(
        &mut self,
        pilot: &mut cathlab_physics::autopilot::Autopilot,
        max_steps: usize,
        first_seq: u64,
    ) -> Result<Option<u64>> {
        use cathlab_physics::autopilot::AutopilotPhase;
        let mut seq = first_seq;
        for _ in 0..max_steps {
            let Some(navigation) = self.strand.navigation() else {
                return Err(EngineError::FailedPrecondition(
                    "the one-device autopilot drives a one-device scene; a stack has two hands"
                        .into(),
                ));
            };
            let command = pilot.command(navigation);
            if pilot.phase() == AutopilotPhase::Reached {
                return Ok(Some(self.step_index()));
            }
            let [push, twist] = Command::from_operator(&command);
            self.apply(seq, &push)?;
            self.apply(seq + 1, &twist)?;
            seq += 2;
            self.step()?;
        }
        Ok(None)
    }

    /// Drives a stack scene with its scripted two-hand operator (the scene's `autopilot`) for
    /// at most `max_steps` steps; the hands' commands are applied as recorded commands
    /// numbered from `first_seq` (a wire exchange as an exchange for the scene's device or
    /// its catalogue entry). Returns the step at which the target was reached, or `None` if
    /// it was not.
    pub fn follow_two_hands(&mut self, max_steps: usize, first_seq: u64) -> Result<Option<u64>> {
        let mut hands = self.scene_operator()?;
        let mut seq = first_seq;
        for _ in 0..max_steps {
            if self.metrics.target_reached_at_s.is_some() {
                return Ok(Some(self.step));
            }
            if !self.operate_scene(&mut hands, &mut seq)? {
                break;
            }
            self.step()?;
        }
        Ok(self.metrics.target_reached_at_s.map(|_| self.step))
    }

    /// One decision of the operator `hands`, applied as commands numbered from `seq`
    /// (exchanges at once, then the next decision). False when it is done.
    fn operate(
        &mut self,
        hands: &mut cathlab_physics::two_hands::TwoHands<'static>,
        seq: &mut u64,
    ) -> Result<bool> {
        use cathlab_physics::two_hands::TwoHandAction;
        loop {
            let Some(stack) = self.strand.stack() else {
                return Err(EngineError::FailedPrecondition(
                    "the two-hand autopilot drives a stack".into(),
                ));
            };
            match hands.next(stack)? {
                TwoHandAction::Done => return Ok(false),
                TwoHandAction::Drive(commands) => {
                    for (index, command) in commands {
                        let push = match command.insertion {
                            Insertion::Velocity(v) => Drive::PushVelocity(v),
                            Insertion::Target(x) => Drive::PushTarget(x),
                        };
                        let twist = match command.twist {
                            Twist::Rate(w) => Drive::TwistRate(w),
                            Twist::Target(a) => Drive::TwistTarget(a),
                        };
                        for drive in [push, twist] {
                            let index = index as u32;
                            self.apply(*seq, &Command::Instrument { index, drive })?;
                            *seq += 1;
                        }
                    }
                    return Ok(true);
                }
                TwoHandAction::Exchange(index, device) => {
                    let index = index as u32;
                    let spare = self.assets.spares.iter().position(|(d, _)| *d == device);
                    let catalogue = crate::scene::catalogue()
                        .entries()
                        .iter()
                        .position(|e| e.device == device);
                    let command = match (spare, catalogue) {
                        (Some(spare), _) => Command::ExchangeSpare {
                            index,
                            spare: spare as u32,
                        },
                        (None, Some(catalogue)) => Command::Exchange {
                            index,
                            catalogue: catalogue as u32,
                        },
                        (None, None) => {
                            return Err(EngineError::FailedPrecondition(format!(
                                "the autopilot's new wire \"{}\" is neither a spare nor in \
                                 the catalogue",
                                device.name
                            )));
                        }
                    };
                    self.apply(*seq, &command)?;
                    *seq += 1;
                }
                TwoHandAction::Replace(_) => {
                    return Err(EngineError::FailedPrecondition(
                        "the scene's autopilot adds no instruments".into(),
                    ));
                }
            }
        }
    }

    /// Every hand holds still.
    fn hold_all(&mut self) -> Result<()> {
        for i in 0..self.strand.len() {
            self.drive(i, Drive::PushVelocity(0.0))?;
            self.drive(i, Drive::TwistRate(0.0))?;
        }
        Ok(())
    }

    /// The demonstration's next decision, before a step; ends it at the target.
    fn demonstrate(&mut self) -> Result<()> {
        let Some(mut hands) = self.demonstration.take() else {
            return Ok(());
        };
        let done = if self.metrics.target_reached_at_s.is_some() {
            true
        } else {
            // Its commands carry the last client sequence number, which they leave as it is.
            let keep = self.last_seq;
            let mut seq = keep;
            self.operating = true;
            let going = self.operate_scene(&mut hands, &mut seq);
            self.operating = false;
            self.last_seq = keep;
            !going?
        };
        if done {
            self.hold_all()?;
            if hands.stalled() && self.metrics.target_reached_at_s.is_none() {
                self.event(
                    EventKind::Device,
                    "demonstration stopped short of the target: the leading instrument \
                     stalled (pushed in without getting further) and every hand holds",
                );
            } else {
                self.event(EventKind::Device, "demonstration done: every hand holds");
            }
        } else {
            self.demonstration = Some(hands);
        }
        Ok(())
    }

    /// Advances one physics step (and contrast every few steps). Divergence puts the device
    /// back at its start, reports it and counts it; the world stays usable.
    pub fn step(&mut self) -> Result<()> {
        let dt = self.assets.spec.time_step_s();
        self.demonstrate()?;
        // An exchange under way: replaced once withdrawn (after the last step), else drawn
        // on back.
        if !self.finish_exchange()? {
            self.withdraw_for_exchange()?;
        }
        let operators: Vec<cathlab_physics::Command> = (0..self.strand.len())
            .map(|i| self.strand.command(i))
            .collect();
        let mut limited = Vec::with_capacity(operators.len());
        for (i, operator) in operators.iter().enumerate() {
            let command = self.limited_command(i, *operator, dt);
            if let Some(command) = command {
                self.strand.set_command(i, command)?;
            }
            limited.push(command.is_some());
        }
        let outcome = self.strand.step();
        for (i, operator) in operators.iter().enumerate() {
            if limited[i] {
                self.strand.set_command(i, *operator)?;
            }
        }
        let diverged = match outcome {
            Ok(()) => {
                let tip = self.strand.leading_tip();
                let escaped = self
                    .strand
                    .wall()
                    .0
                    .lumen
                    .query(&Point3::from(tip))
                    .signed_distance
                    > MAX_ESCAPE_M;
                if !tip.iter().all(|v| v.is_finite()) {
                    Some("non-finite tip position".to_owned())
                } else if escaped {
                    Some("the tip left the vessel".to_owned())
                } else {
                    None
                }
            }
            Err(e) => Some(e.to_string()),
        };
        if let Some(reason) = diverged {
            self.metrics.divergence_resets += 1;
            self.restart_device(self.active_device)?;
            self.event(
                EventKind::Divergence,
                format!("physics diverged ({reason}); the device was put back at its start"),
            );
        }
        self.step += 1;
        self.metrics.steps = self.step;
        self.metrics.procedure_time_s = self.step as f64 * dt;
        if self.imaging.pedal {
            self.metrics.fluoroscopy_time_s += dt;
        }
        // Wall forces and the tip's path.
        if let Some(contacts) = self.strand.last_contacts() {
            let mut largest: f64 = 0.0;
            let mut total = 0.0;
            for f in &contacts.response.forces {
                let n = f.norm();
                largest = largest.max(n);
                total += n;
            }
            self.metrics.add_wall_forces(largest, total);
        }
        let tip = tracked_tip(&self.assets, &self.strand);
        self.metrics.tip_path_length_m += (tip - self.previous_tip).norm();
        self.previous_tip = tip;
        self.metrics.target_remaining_m = self.assets.remaining_to_target_m(&Point3::from(tip));
        if self.metrics.target_reached_at_s.is_none() {
            let graph = &self.assets.anatomy.graph;
            if let Some(location) = graph.nearest(&Point3::from(tip))
                && location.branch == self.assets.target_branch
                && location.arc_length >= self.assets.spec.target.reach_mm * 1e-3
            {
                self.metrics.target_reached_at_s = Some(self.metrics.procedure_time_s);
                let name = self.assets.spec.target.branch.clone();
                let who = match self.assets.spec.target.instrument {
                    Some(i) if !self.assets.spec.stack.is_empty() => self
                        .strand
                        .device(i)
                        .map_or_else(|| "tip".to_owned(), |d| format!("{}'s tip", d.name)),
                    _ => "tip".to_owned(),
                };
                self.event(
                    EventKind::TargetReached,
                    format!("the {who} reached {name}"),
                );
            }
        }
        let (wrench, reactions) = self.strand.reactions();
        self.proximal = wrench;
        for (hand, reaction) in self.hands.iter_mut().zip(reactions) {
            hand.reaction = reaction;
        }
        self.instrument_metrics(dt);
        self.step_procedure(dt)?;
        self.step_contrast(dt)?;
        Ok(())
    }

    /// Per-instrument and stack metrics after a step.
    fn instrument_metrics(&mut self, dt: f64) {
        let n = self.strand.len().min(crate::metrics::MAX_INSTRUMENTS);
        let now: Vec<(Option<Vector3<f64>>, f64)> = (0..n)
            .map(|i| (self.strand.tip_position(i), self.strand.inserted_m(i)))
            .collect();
        // A restart or an exchange of the stack's shape starts the comparison afresh.
        let comparable = self.previous_instruments.len() == n;
        let m = &mut self.metrics;
        m.instrument_count = n as u8;
        for (i, (tip, inserted)) in now.iter().enumerate() {
            let figures = &mut m.instruments[i];
            figures.peak_axial_force_n = figures
                .peak_axial_force_n
                .max(self.hands[i].reaction.axial_force_n.abs());
            if !comparable {
                continue;
            }
            let (before_tip, before) = self.previous_instruments[i];
            if let (Some(a), Some(b)) = (before_tip, tip) {
                figures.tip_path_length_m += (b - a).norm();
            }
            if (inserted - before).abs() > 1e-9 {
                figures.moving_time_s += dt;
            }
        }
        let leading = self.strand.leading().min(n.saturating_sub(1)) as u8;
        if comparable && leading != m.leading_instrument {
            m.lead_changes += 1;
        }
        m.leading_instrument = leading;
        let mut passed = Vec::new();
        if comparable {
            for k in 1..n {
                let (_, inner_before) = self.previous_instruments[k];
                let (_, outer_before) = self.previous_instruments[k - 1];
                let (inner, outer) = (now[k].1, now[k - 1].1);
                // The inner one led beyond the entry; the outer one advanced past its tip.
                if inner_before > outer_before
                    && inner_before > 0.0
                    && outer >= inner
                    && outer > outer_before
                {
                    m.passed_inner_tip += 1;
                    passed.push(k);
                }
            }
        }
        self.previous_instruments = now;
        for k in passed {
            let name = |i: usize| {
                self.strand
                    .device(i)
                    .map_or_else(|| format!("instrument {i}"), |d| d.name.clone())
            };
            let message = format!(
                "the {} passed the tip of the {}: it no longer follows it",
                name(k - 1),
                name(k)
            );
            self.event(EventKind::Limit, message);
        }
    }

    fn step_contrast(&mut self, dt: f64) -> Result<()> {
        self.fire_linked_injection()?;
        let every = self.assets.spec.fidelity.contrast_every_steps;
        let to_lps = self.assets.to_lps;
        let Some(hemo) = &mut self.hemo else {
            return Ok(());
        };
        // Injected volume counts every step; the flow changes when the bolus is done.
        let mut finished = false;
        if let Some((left, rate)) = &mut hemo.injection {
            let dv = (*rate * dt).min(*left);
            *left -= dv;
            self.metrics.contrast_volume_ml += dv * 1e6;
            finished = *left <= 0.0;
        }
        // Steps count only while contrast moves: the first sub-step after an idle spell
        // spans one period, not the whole spell (which broke the CFL limit after minutes).
        if hemo.active {
            hemo.steps_since_contrast += 1;
        } else {
            hemo.steps_since_contrast = 0;
        }
        if hemo.active && hemo.steps_since_contrast >= every {
            let span = hemo.steps_since_contrast as f64 * dt;
            hemo.steps_since_contrast = 0;
            hemo.contrast.step(span)?;
            let network = hemo.solver.network();
            let tubes: Vec<ContrastTube> = hemo
                .contrast
                .segments(network, CONTRAST_DRAW_THRESHOLD)
                .into_iter()
                .map(|s| ContrastTube {
                    start: Point3::from(to_lps * s.start.coords),
                    end: Point3::from(to_lps * s.end.coords),
                    start_radius_m: s.start_radius,
                    end_radius_m: s.end_radius,
                    concentration_mg_per_ml: s.concentration,
                })
                .collect();
            hemo.active = hemo.injection.is_some() || !tubes.is_empty();
            hemo.tubes = Arc::new(tubes);
        }
        if finished {
            hemo.injection = None;
            self.update_injection()?;
        }
        Ok(())
    }

    /// Whether the scene's scripted operator is driving (a demonstration under way).
    pub fn demonstrating(&self) -> bool {
        self.demonstration.is_some()
    }

    /// The imaging state the trainee set.
    pub fn imaging(&self) -> Imaging {
        self.imaging
    }

    /// The leading tip (anatomy frame, m).
    pub fn leading_tip(&self) -> Vector3<f64> {
        self.strand.leading_tip()
    }

    /// The wall contacts of the last step in the anatomy's frame: where on the device
    /// centerline (m) and the force's magnitude (N); forceless contacts left out.
    pub fn wall_contacts(&self) -> Vec<(Point3<f64>, f64)> {
        self.contact_forces()
            .into_iter()
            .map(|(p, f)| (Point3::from(p), f.norm()))
            .collect()
    }

    /// The last step's wall contacts with a force, in the anatomy's frame: the point on the
    /// device centerline (m) and the wall's force on the device (N).
    fn contact_forces(&self) -> Vec<(Vector3<f64>, Vector3<f64>)> {
        let Some(step) = self.strand.last_contacts() else {
            return Vec::new();
        };
        let positions = self.strand.model().positions();
        step.contacts
            .iter()
            .zip(&step.response.forces)
            .filter(|(_, f)| f.norm() > 0.0)
            .filter_map(|(c, f)| {
                let a = positions.get(c.element)?;
                let b = positions.get(c.element + 1)?;
                Some((a + (b - a) * c.t, *f))
            })
            .collect()
    }

    /// The world now, for clients and the renderer (LPS).
    pub fn snapshot(&self) -> Snapshot {
        let to_lps = self.assets.to_lps;
        let model = self.strand.model();
        let positions = model.positions();
        let nodes: Vec<Vector3<f64>> = positions.iter().map(|p| to_lps * p).collect();
        let tip_direction = model
            .rotations()
            .last()
            .map(|q| to_lps * (q * Vector3::x()))
            .unwrap_or_else(Vector3::x);
        let contacts = match self.strand.last_contacts() {
            Some(_) => self
                .contact_forces()
                .into_iter()
                .map(|(p, f)| WallContact {
                    position: to_lps * p,
                    force: to_lps * f,
                })
                .collect(),
            None => Vec::new(),
        };
        let p = &self.proximal;
        let force = to_lps * Vector3::new(p[0], p[1], p[2]);
        let moment = to_lps * Vector3::new(p[3], p[4], p[5]);
        let instruments: Vec<InstrumentState> = self
            .hands
            .iter()
            .enumerate()
            .map(|(i, hand)| InstrumentState {
                name: self
                    .strand
                    .device(i)
                    .map_or_else(String::new, |d| d.name.clone()),
                catalogue_id: hand.catalogue_id.clone(),
                nodes: self.strand.polyline(i).iter().map(|p| to_lps * p).collect(),
                inserted_m: self.strand.inserted_m(i),
                twist_rad: self.strand.twist_rad(i),
                tip: self.strand.tip_position(i).map(|p| to_lps * p),
                axial_force_n: hand.reaction.axial_force_n,
                torque_nm: hand.reaction.torque_nm,
                push_limit: hand.push_limit,
                push_force_limit_n: hand.limits.force_n,
                look: hand.look.clone(),
            })
            .collect();
        let innermost = self.hands.len() - 1;
        Snapshot {
            step: self.step,
            time_s: self.metrics.procedure_time_s,
            last_seq: self.last_seq,
            nodes,
            tip_direction,
            inserted_m: self.strand.inserted_m(innermost),
            twist_rad: self.strand.twist_rad(innermost),
            contacts,
            proximal: [force.x, force.y, force.z, moment.x, moment.y, moment.z],
            active_device: self.active_device as u32,
            imaging: self.imaging,
            contrast: self
                .hemo
                .as_ref()
                .map(|h| h.tubes.clone())
                .unwrap_or_default(),
            metrics: self.metrics,
            push_limit: self.hands[innermost].push_limit,
            push_force_limit_n: self.hands[innermost].limits.force_n,
            fidelity_level: self.fidelity,
            instruments,
        }
    }

    /// A 64-bit digest of the whole simulated state (positions, frames, material points,
    /// controls, contrast, imaging, metrics): equal digests mean bit-identical states.
    pub fn digest(&self) -> u64 {
        let mut h = Fnv1a::default();
        h.u64(self.step);
        h.u64(self.last_seq);
        h.u64(self.active_device as u64);
        self.strand.digest_into(|values| h.f64s(values));
        h.f64s(&self.proximal);
        for hand in &self.hands {
            h.f64s(&[hand.reaction.axial_force_n, hand.reaction.torque_nm]);
            h.u64(hand.catalogue_id.len() as u64);
        }
        if let Some(hemo) = &self.hemo {
            h.f64s(&[
                hemo.linked_at_s.unwrap_or(-1.0),
                hemo.program.0,
                hemo.program.1,
            ]);
            for v in 0..hemo.solver.network().vessels.len() {
                h.f64s(hemo.contrast.concentration(v));
            }
        }
        let i = &self.imaging;
        h.u64(i.pedal as u64 | (i.dsa_run as u64) << 8);
        h.f64s(&[i.primary_deg, i.secondary_deg]);
        let m = &self.metrics;
        h.f64s(&[
            m.procedure_time_s,
            m.fluoroscopy_time_s,
            m.contrast_volume_ml,
            m.max_wall_force_n,
            m.wall_force_sum_n,
            m.tip_path_length_m,
            m.target_reached_at_s.unwrap_or(-1.0),
            m.attempt_started_at_s,
        ]);
        h.u64(m.divergence_resets as u64 | (m.operator_resets as u64) << 32);
        h.finish()
    }
}

/// The tip the target and the path metrics follow: the scene's `target.instrument` of a stack
/// (while it is beyond the entry), else the leading tip (anatomy frame, m).
fn tracked_tip(assets: &SceneAssets, strand: &Strand) -> Vector3<f64> {
    assets
        .spec
        .target
        .instrument
        .filter(|_| !assets.spec.stack.is_empty())
        .and_then(|i| strand.tip_position(i))
        .unwrap_or_else(|| strand.leading_tip())
}

/// Where contrast leaves the devices: the tip of the innermost instrument with a lumen that is
/// beyond the entry (contrast goes in at its hub, around any wire inside), else the leading
/// tip (anatomy frame, m).
/// The reperfusion of `territory` in the flow `now` (no injection) against `open`, for the
/// metrics; none while no clot has cut anything off.
fn reperfusion_metric(
    open: &FlowSolution,
    now: &FlowSolution,
    territory: &[usize],
) -> Result<Option<ReperfusionMetric>> {
    if territory.is_empty() {
        return Ok(None);
    }
    let r = reperfusion(open, now, territory)?;
    Ok(Some(ReperfusionMetric {
        fraction: r.fraction,
        etici: r.grade,
    }))
}

fn injection_tip(strand: &Strand) -> Vector3<f64> {
    (0..strand.len())
        .rev()
        .filter(|&i| {
            strand.device(i).is_some_and(|d| {
                d.sections
                    .last()
                    .is_some_and(|s| s.cross_section.inner_radius_m > 0.0)
            })
        })
        .find_map(|i| strand.tip_position(i))
        .unwrap_or_else(|| strand.leading_tip())
}

/// A tip farther than this outside the lumen surface (m) counts as divergence: the device has
/// gone through the wall, which the contact solver never allows on a sound step.
pub const MAX_ESCAPE_M: f64 = 3e-3;

/// FNV-1a over the bytes of integers and floats (bit patterns, so −0 ≠ +0 and NaNs count).
#[derive(Debug, Clone, Copy)]
struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv1a {
    fn u64(&mut self, v: u64) {
        for b in v.to_le_bytes() {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }
    fn f64s(&mut self, values: &[f64]) {
        for v in values {
            self.u64(v.to_bits());
        }
    }
    fn finish(self) -> u64 {
        self.0
    }
}
