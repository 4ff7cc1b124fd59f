//! A session's assessment report, computed by replaying its recorded commands (replay is bit
//! exact, so the report describes what the trainee did, step for step): samples of the tip,
//! the hands, wall forces by vessel class, imaging, contrast and dose; the scene's phases and
//! the errors committed; the scores and their verdicts against the scene's expert benchmark;
//! and replay frames (an X-ray image and every instrument's path) at regular moments.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use cathlab_anatomy::VesselKind;
use cathlab_assessment::{
    Counts, EventRecord, MetricValue, Phase, PhaseSpec, ProcedureError, Sample, Trace, Verdict,
    VesselClass, detect_errors, detect_phases, judge, summarize,
};
use cathlab_xray::{CpuRenderer, Fluoroscope, ImagingMode, Layers};
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use crate::assets::SceneAssets;
use crate::error::{EngineError, Result};
use crate::imaging::{Encoding, carm_of, encode_frame, fluoroscope_settings, layers_of};
use crate::session::CommandRecord;
use crate::world::{Command, Mode, Snapshot, World};

/// Version of the report's layout (stored reports of another version are computed again).
pub const REPORT_VERSION: u32 = 1;

/// How densely a report samples and renders.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReportOptions {
    /// Samples a simulated second (Hz).
    pub sample_hz: f64,
    /// Wall forces are classified every this many steps; a sample holds the largest since the
    /// last.
    pub force_every_steps: u64,
    /// Simulated time between replay frames (s).
    pub frame_every_s: f64,
    /// Side of a replay frame (pixels).
    pub frame_px: u32,
    /// Most replay frames (a longer session spaces them further).
    pub max_frames: usize,
    /// Side of the images the dose follows the trainee's exposures with (pixels): the
    /// exposure control's measuring field needs few.
    pub dose_px: u32,
}

impl Default for ReportOptions {
    fn default() -> Self {
        Self {
            sample_hz: 10.0,
            force_every_steps: 10,
            frame_every_s: 1.0,
            frame_px: 192,
            max_frames: 600,
            dose_px: 32,
        }
    }
}

/// A replay frame: the moment, each instrument's centerline and the X-ray image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplayFrame {
    /// Simulated time (s).
    pub time_s: f64,
    /// Step.
    pub step: u64,
    /// Each instrument's centerline, outermost first (LPS, mm; at most 96 points each).
    pub instruments: Vec<Vec<[f32; 3]>>,
    /// The fluoroscopy image at that moment (PNG, 8-bit grey); kept apart from the JSON.
    #[serde(skip)]
    pub png: Vec<u8>,
}

/// A session's assessment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionReport {
    /// [`REPORT_VERSION`].
    pub version: u32,
    /// The scene's name.
    pub scene: String,
    /// Simulated time the session lasted (s).
    pub duration_s: f64,
    /// The scores.
    pub metrics: Vec<MetricValue>,
    /// The scores against the scene's expert benchmark.
    pub verdicts: Vec<Verdict>,
    /// The scene's phases as they happened.
    pub phases: Vec<Phase>,
    /// The errors committed.
    pub errors: Vec<ProcedureError>,
    /// The session's events.
    pub events: Vec<EventRecord>,
    /// The samples (charts, CSV).
    pub samples: Vec<Sample>,
    /// Replay frames, in time order.
    pub frames: Vec<ReplayFrame>,
}

/// The class of a vessel kind: aortic (and access), cervical (neck) or intracranial. The
/// internal carotid counts as cervical over its whole length: the graph does not split the
/// petrous and cavernous segments off.
pub fn vessel_class(kind: VesselKind) -> VesselClass {
    match kind {
        VesselKind::Aorta | VesselKind::Brachiocephalic | VesselKind::Other => VesselClass::Aortic,
        VesselKind::Subclavian
        | VesselKind::CommonCarotid
        | VesselKind::InternalCarotid
        | VesselKind::ExternalCarotid
        | VesselKind::Vertebral => VesselClass::Cervical,
        VesselKind::Basilar
        | VesselKind::AnteriorCerebral
        | VesselKind::MiddleCerebral
        | VesselKind::PosteriorCerebral
        | VesselKind::AnteriorCommunicating
        | VesselKind::PosteriorCommunicating => VesselClass::Intracranial,
    }
}

fn class_index(class: VesselClass) -> usize {
    VesselClass::ALL
        .iter()
        .position(|c| *c == class)
        .unwrap_or(0)
}

/// The default phases of a scene that names none: one per vessel of the route, in order,
/// then "at target" once it is reached.
pub fn default_phases(assets: &SceneAssets) -> Vec<PhaseSpec> {
    let graph = &assets.anatomy.graph;
    let mut phases: Vec<PhaseSpec> = Vec::new();
    for leg in &assets.route.legs {
        let Some(branch) = graph.branches.get(leg.branch) else {
            continue;
        };
        let name = branch.name.replace('_', " ");
        if phases
            .iter()
            .any(|p| p.vessel.as_deref() == Some(&branch.name))
        {
            continue;
        }
        phases.push(PhaseSpec {
            name: if phases.is_empty() {
                format!("access: {name}")
            } else {
                format!("navigation: {name}")
            },
            vessel: (!phases.is_empty()).then(|| branch.name.clone()),
            ..PhaseSpec::default()
        });
    }
    phases.push(PhaseSpec {
        name: "at target".into(),
        event: Some("reached".into()),
        ..PhaseSpec::default()
    });
    phases
}

/// Follows the trainee's imaging with a fluoroscope (mode, pulse rate, exposures), as the
/// session's render loop does: the same pulses, the same exposure control, the same dose.
struct ImagingFollower {
    fluoroscope: Fluoroscope,
    mode: Mode,
    dsa_run: u32,
    pulse_rate: cathlab_xray::PulseRate,
}

impl ImagingFollower {
    fn new(assets: &SceneAssets, px: u32) -> Result<Self> {
        let mut settings = fluoroscope_settings(assets);
        // The same quanta per mm² on the fewer, larger pixels (what exposure control off
        // doses by; on, it aims for a detector dose, whatever the pixels).
        let d = &assets.carm.detector;
        let pixels_per_pixel = f64::from(d.width_px) * f64::from(d.height_px) / f64::from(px * px);
        settings.detector.photons_per_pixel *= pixels_per_pixel;
        settings.dose.max_photons_per_pixel *= pixels_per_pixel;
        let pulse_rate = settings.pulse_rate;
        Ok(Self {
            fluoroscope: Fluoroscope::new(Box::new(CpuRenderer::default()), settings)?,
            mode: Mode::Fluoroscopy,
            dsa_run: 0,
            pulse_rate,
        })
    }

    /// Brings the fluoroscope to the snapshot's imaging and exposes if a pulse is due.
    fn follow(&mut self, assets: &SceneAssets, snapshot: &Snapshot, px: u32) -> Result<bool> {
        let carm = small_carm(assets, snapshot, px);
        let imaging = snapshot.imaging;
        if imaging.pulse_rate != self.pulse_rate {
            self.fluoroscope.set_pulse_rate(imaging.pulse_rate);
            self.pulse_rate = imaging.pulse_rate;
        }
        if imaging.mode != self.mode || imaging.dsa_run != self.dsa_run {
            let wanted = match imaging.mode {
                Mode::Fluoroscopy => ImagingMode::Fluoroscopy,
                Mode::Subtraction => ImagingMode::Subtraction,
                Mode::Roadmap => ImagingMode::Roadmap,
            };
            // A refused mode (a roadmap without a run) leaves the old one, as live.
            let _ = self.fluoroscope.set_mode(wanted, &carm);
            self.mode = imaging.mode;
            self.dsa_run = imaging.dsa_run;
        }
        let exposing = imaging.pedal || imaging.mode == Mode::Subtraction;
        if !(exposing && self.fluoroscope.pulse_due(snapshot.time_s)) {
            return Ok(false);
        }
        let layers = layers_of(assets, snapshot)?;
        let shot = cathlab_xray::Scene {
            volume: &assets.volume,
            carm: &carm,
            layers: &layers,
        };
        Ok(self
            .fluoroscope
            .update(snapshot.time_s, exposing, shot)?
            .is_some())
    }
}

/// The scene's C-arm at the snapshot's angles with a `px`-pixel square detector (the same
/// field: the dose per exposure does not depend on the pixel count).
fn small_carm(assets: &SceneAssets, snapshot: &Snapshot, px: u32) -> cathlab_xray::CArm {
    let mut carm = carm_of(assets, snapshot);
    carm.detector.width_px = px;
    carm.detector.height_px = px;
    carm
}

/// Every `n`-th point of a polyline and its last (LPS m → mm), at most `most`.
fn thin(points: &[nalgebra::Vector3<f64>], most: usize) -> Vec<[f32; 3]> {
    let n = points.len().div_ceil(most.max(2) - 1).max(1);
    let mut out: Vec<[f32; 3]> = points
        .iter()
        .step_by(n)
        .map(|p| [p.x as f32 * 1e3, p.y as f32 * 1e3, p.z as f32 * 1e3])
        .collect();
    if !points.len().saturating_sub(1).is_multiple_of(n)
        && let Some(p) = points.last()
    {
        out.push([p.x as f32 * 1e3, p.y as f32 * 1e3, p.z as f32 * 1e3]);
    }
    out
}

/// What the autopilot's run says about an expert: its time, fluoroscopy, dose, path,
/// smoothness and forces; not its imaging (it takes no contrast, DSA or roadmap), nor its
/// errors, idle time or time above force thresholds (judged by hand-set limits: a scripted
/// operator's exploratory stray is no expert's standard), nor what it scores zero on.
pub fn is_expert_metric(key: &str, value: f64) -> bool {
    let excluded = [
        "contrast_ml",
        "injections",
        "dsa_runs",
        "roadmaps",
        "errors",
        "passed_inner_tip",
        "idle_time_s",
    ];
    value != 0.0 && !excluded.contains(&key) && !key.starts_with("time_above_force")
}

/// A scripted expert run of a stack scene, as a recording: fluoroscopy on and the scene's
/// two-hand autopilot demonstrating from the start, fluoroscopy off when the target is
/// reached. Returns the commands and the last step (the target reached, the demonstration
/// given up, or `max_steps`).
pub fn expert_run(assets: Arc<SceneAssets>, max_steps: u64) -> Result<(Vec<CommandRecord>, u64)> {
    let mut commands = vec![
        CommandRecord {
            ordinal: 0,
            step: 0,
            seq: 1,
            command: Command::Fluoroscopy(true),
        },
        CommandRecord {
            ordinal: 1,
            step: 0,
            seq: 2,
            command: Command::Demonstrate(true),
        },
    ];
    let mut world = World::new(assets)?;
    for c in &commands {
        world.apply(c.seq, &c.command)?;
    }
    while world.step_index() < max_steps
        && world.metrics().target_reached_at_s.is_none()
        && world.demonstrating()
    {
        world.step()?;
    }
    let end = world.step_index();
    commands.push(CommandRecord {
        ordinal: 2,
        step: end,
        seq: 3,
        command: Command::Fluoroscopy(false),
    });
    Ok((commands, end + 1))
}

/// Assesses a recorded session: replays `commands` on `assets` to `end_step` (abandoned with
/// [`EngineError::Cancelled`] once `cancel` is set), sampling, following the imaging for the
/// dose and rendering replay frames.
pub fn assess(
    assets: Arc<SceneAssets>,
    commands: &[CommandRecord],
    end_step: u64,
    options: &ReportOptions,
    cancel: &AtomicBool,
) -> Result<SessionReport> {
    let dt = assets.spec.time_step_s();
    let sample_every = ((1.0 / (options.sample_hz * dt)).round() as u64).max(1);
    let duration = end_step as f64 * dt;
    let frame_every_s = options
        .frame_every_s
        .max(duration / options.max_frames.max(1) as f64);
    let frame_every = ((frame_every_s / dt).round() as u64).max(1);
    let mut world = World::new(assets.clone())?;
    let mut dose = ImagingFollower::new(&assets, options.dose_px)?;
    // Replay frames: noise-free and unfiltered (no lag from the recursive filter).
    let mut frame_settings = fluoroscope_settings(&assets);
    frame_settings.detector.noise = false;
    frame_settings.recursive_weight = 1.0;
    let mut frames_chain = Fluoroscope::new(Box::new(CpuRenderer::default()), frame_settings)?;
    let graph = &assets.anatomy.graph;
    let depth = RouteDepth::new(&assets);
    let mut samples = Vec::new();
    let mut frames = Vec::new();
    let mut events = Vec::new();
    let mut forces = [0.0f64; 3];
    let mut next_command = 0;
    let mut counts = Counts::default();
    loop {
        let step = world.step_index();
        // The step's commands first: a sample shows the state the step runs with.
        while next_command < commands.len() && commands[next_command].step == step {
            let c = &commands[next_command];
            world.apply(c.seq, &c.command)?;
            match c.command {
                Command::Inject { .. } => counts.injections += 1,
                Command::Roadmap(true) => counts.roadmaps += 1,
                _ => {}
            }
            next_command += 1;
        }
        if step.is_multiple_of(options.force_every_steps.max(1))
            || step.is_multiple_of(sample_every)
        {
            let mut now = [0.0f64; 3];
            for (p, f) in world.wall_contacts() {
                let class = graph
                    .nearest(&p)
                    .and_then(|l| graph.branches.get(l.branch))
                    .map_or(VesselClass::Aortic, |b| vessel_class(b.kind));
                now[class_index(class)] += f;
            }
            for (a, b) in forces.iter_mut().zip(now) {
                *a = a.max(b);
            }
        }
        let sample_due = step.is_multiple_of(sample_every) || step == end_step;
        let frame_due = step.is_multiple_of(frame_every) || step == end_step;
        // The dose follows every exposure (a pulse is due at its own times).
        let needs_snapshot = sample_due || frame_due || {
            let imaging = world.imaging();
            (imaging.pedal || imaging.mode == Mode::Subtraction)
                && dose.fluoroscope.pulse_due(world.metrics().procedure_time_s)
        };
        if needs_snapshot {
            let snapshot = world.snapshot();
            dose.follow(&assets, &snapshot, options.dose_px)?;
            if sample_due {
                samples.push(sample_of(&world, &snapshot, &depth, forces, &dose));
                forces = [0.0; 3];
            }
            if frame_due {
                frames.push(replay_frame(
                    &assets,
                    &snapshot,
                    &mut frames_chain,
                    options.frame_px,
                )?);
            }
        }
        if step >= end_step {
            break;
        }
        if cancel.load(Ordering::Relaxed) {
            return Err(EngineError::Cancelled(format!(
                "report abandoned at step {step} of {end_step}"
            )));
        }
        world.step()?;
        for e in world.take_events() {
            events.push(EventRecord {
                time_s: e.time_s,
                kind: e.kind.as_str().into(),
                message: e.message,
            });
        }
    }
    let metrics = *world.metrics();
    counts.dsa_runs = metrics.dsa_runs;
    counts.target_reached_at_s = events
        .iter()
        .find(|e| e.kind == "target_reached")
        .map(|e| e.time_s);
    let spec = &assets.spec.assessment;
    let trace = Trace::new(samples).map_err(|e| EngineError::InvalidArgument {
        field: "session".into(),
        reason: format!("too short to assess: {e}"),
    })?;
    let assessment = |e: cathlab_assessment::AssessmentError| EngineError::InvalidArgument {
        field: "assessment".into(),
        reason: e.to_string(),
    };
    let phase_specs = if spec.phases.is_empty() {
        default_phases(&assets)
    } else {
        spec.phases.clone()
    };
    let phases = detect_phases(&trace, &events, &phase_specs).map_err(assessment)?;
    let errors = detect_errors(&trace, &spec.errors).map_err(assessment)?;
    let scores = summarize(&trace, &counts, &errors, &spec.errors).map_err(assessment)?;
    let verdicts = judge(&scores, &spec.expert, &spec.benchmark).map_err(assessment)?;
    Ok(SessionReport {
        version: REPORT_VERSION,
        scene: assets.spec.name.clone(),
        duration_s: trace.duration_s(),
        metrics: scores,
        verdicts,
        phases,
        errors,
        events,
        samples: trace.samples().to_vec(),
        frames,
    })
}

/// How far past either end of a route leg a tip still counts as on the route (m).
pub const ON_ROUTE_SLACK_M: f64 = 5e-3;

/// How deep a point of the vessel tree lies off the route: the length along the vessels
/// from the nearest route point (m).
struct RouteDepth {
    /// Each node's depth (m).
    nodes: Vec<f64>,
    /// The route's legs: branch and the stretch of arc length it takes (m).
    legs: Vec<(usize, f64, f64)>,
    /// Each branch's start node, end node and length (m).
    branches: Vec<(usize, usize, f64)>,
}

impl RouteDepth {
    fn new(assets: &SceneAssets) -> Self {
        let graph = &assets.anatomy.graph;
        let mut nodes = vec![f64::INFINITY; graph.nodes.len()];
        let mut legs = Vec::new();
        for leg in &assets.route.legs {
            let Some(b) = graph.branches.get(leg.branch) else {
                continue;
            };
            let (lo, hi) = (leg.from_arc.min(leg.to_arc), leg.from_arc.max(leg.to_arc));
            legs.push((leg.branch, lo, hi));
            if let Some(d) = nodes.get_mut(b.start) {
                *d = d.min(lo);
            }
            if let Some(d) = nodes.get_mut(b.end) {
                *d = d.min((b.length() - hi).max(0.0));
            }
        }
        // Bellman–Ford over the branches (vessel graphs are small).
        for _ in 0..graph.nodes.len() {
            let mut changed = false;
            for b in &graph.branches {
                let (s, e, len) = (b.start, b.end, b.length());
                if s >= nodes.len() || e >= nodes.len() {
                    continue;
                }
                if nodes[s] + len < nodes[e] {
                    nodes[e] = nodes[s] + len;
                    changed = true;
                }
                if nodes[e] + len < nodes[s] {
                    nodes[s] = nodes[e] + len;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        let branches = graph
            .branches
            .iter()
            .map(|b| (b.start, b.end, b.length()))
            .collect();
        Self {
            nodes,
            legs,
            branches,
        }
    }

    /// The depth of the point at `arc` (m) along `branch` (m; 0 on the route).
    fn of(&self, branch: usize, arc: f64) -> f64 {
        let mut depth = f64::INFINITY;
        for &(b, lo, hi) in &self.legs {
            if b == branch {
                if arc >= lo - ON_ROUTE_SLACK_M && arc <= hi + ON_ROUTE_SLACK_M {
                    return 0.0;
                }
                depth = depth.min(if arc < lo { lo - arc } else { arc - hi });
            }
        }
        if let Some(&(start, end, len)) = self.branches.get(branch) {
            let node = |n: usize| self.nodes.get(n).copied().unwrap_or(f64::INFINITY);
            depth = depth
                .min(node(start) + arc)
                .min(node(end) + (len - arc).max(0.0));
        }
        // A component the route does not reach holds no tip.
        if depth.is_finite() { depth } else { 0.0 }
    }
}

fn sample_of(
    world: &World,
    snapshot: &Snapshot,
    depth: &RouteDepth,
    forces: [f64; 3],
    dose: &ImagingFollower,
) -> Sample {
    let assets = world.assets();
    let tip = Point3::from(world.leading_tip());
    let graph = &assets.anatomy.graph;
    let location = graph.nearest(&tip);
    let branch = location.and_then(|l| graph.branches.get(l.branch));
    let off_route_m = location.map_or(0.0, |l| depth.of(l.branch, l.arc_length));
    let tally = dose.fluoroscope.dose();
    let metrics = &snapshot.metrics;
    Sample {
        time_s: snapshot.time_s,
        tip_m: [tip.x, tip.y, tip.z],
        along_route_m: assets.along_route_m(&tip),
        inserted_m: snapshot.instruments.iter().map(|i| i.inserted_m).collect(),
        twist_rad: snapshot.instruments.iter().map(|i| i.twist_rad).collect(),
        wall_force_n: forces,
        fluoroscopy: snapshot.imaging.pedal || snapshot.imaging.mode == Mode::Subtraction,
        contrast_ml: metrics.contrast_volume_ml,
        air_kerma_mgy: tally.reference_air_kerma_mgy,
        kap_gy_cm2: tally.kerma_area_product_gy_cm2,
        off_route_m,
        vessel: branch.map_or_else(String::new, |b| b.name.clone()),
        vessel_class: branch.map(|b| vessel_class(b.kind)),
        passed_inner_tip: metrics.passed_inner_tip,
    }
}

fn replay_frame(
    assets: &SceneAssets,
    snapshot: &Snapshot,
    chain: &mut Fluoroscope,
    px: u32,
) -> Result<ReplayFrame> {
    // A plain fluoroscopy exposure of the moment, noise-free, whatever the trainee's pedal:
    // the reviewer sees where the devices were even when the trainee did not look.
    let carm = small_carm(assets, snapshot, px);
    let layers = layers_of(assets, snapshot).unwrap_or_else(|_| Layers::new());
    let frame = chain.expose(
        snapshot.time_s,
        cathlab_xray::Scene {
            volume: &assets.volume,
            carm: &carm,
            layers: &layers,
        },
    )?;
    let (png, _, _) = encode_frame(&frame, Encoding::Png, 0, 0)?;
    Ok(ReplayFrame {
        time_s: snapshot.time_s,
        step: snapshot.step,
        instruments: snapshot
            .instruments
            .iter()
            .map(|i| thin(&i.nodes, 96))
            .collect(),
        png,
    })
}
