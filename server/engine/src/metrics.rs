//! What instructors grade by, accumulated step by step in simulated time, and the events a
//! session reports (divergence, target reached, imaging and device changes).

use serde::{Deserialize, Serialize};

pub use cathlab_hemo::reperfusion::Etici;

/// Per-session training metrics (SI units unless the name says otherwise).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// Simulated time since the start (s).
    pub procedure_time_s: f64,
    /// Simulated time with the fluoroscopy pedal down (s).
    pub fluoroscopy_time_s: f64,
    /// Digital subtraction runs started.
    pub dsa_runs: u32,
    /// Contrast agent injected (mL).
    pub contrast_volume_ml: f64,
    /// Largest single wall contact force (N).
    pub max_wall_force_n: f64,
    /// Mean total wall force over steps with any wall contact (N).
    pub mean_wall_force_n: f64,
    /// Distance travelled by the tip (m).
    pub tip_path_length_m: f64,
    /// Simulated time at which the target was reached in the current attempt (s); a reset
    /// starts a new attempt.
    pub target_reached_at_s: Option<f64>,
    /// Simulated time at which the current attempt started (s): 0, or the last reset.
    pub attempt_started_at_s: f64,
    /// Resets the operator asked for.
    pub operator_resets: u32,
    /// How far the tip still has to go along the route to the target (m).
    pub target_remaining_m: f64,
    /// Physics steps taken.
    pub steps: u64,
    /// Physics resets after divergence.
    pub divergence_resets: u32,
    /// Deepest any node of any instrument has passed the wall after a step that was kept
    /// (m): each instrument's own outer radius past the lumen surface.
    #[serde(default)]
    pub deepest_penetration_m: f64,
    /// The largest axial force any element of the strand's beam model carried after a step
    /// that was kept (N, either way; a nested stack's outermost chain): a sanity bound on the
    /// model's own state, which a wire pushed and pulled within the hands' strength keeps
    /// near that strength.
    #[serde(default)]
    pub peak_element_force_n: f64,
    /// Solves the hands' force guard took again because a step left a hand past its limit
    /// (a step costs one solve more for each): a push held at its limit should cost none
    /// most steps, its first try scaled by the stiffness the hand learnt.
    #[serde(default)]
    pub force_retakes: u64,
    /// Sum of total wall force over contact steps (N), for the mean.
    pub wall_force_sum_n: f64,
    /// Steps with wall contact.
    pub wall_contact_steps: u64,
    /// Per instrument of a stack, outermost first (the first `instrument_count`; one for a
    /// one-device scene).
    pub instruments: [InstrumentMetrics; MAX_INSTRUMENTS],
    /// How many instruments `instruments` describes.
    pub instrument_count: u8,
    /// The instrument whose tip leads now (index, outermost first).
    pub leading_instrument: u8,
    /// How often the lead passed from one instrument to another.
    pub lead_changes: u32,
    /// How often an instrument was pushed past the tip of the one inside it while that one
    /// led (the catheter overtaking the wire's tip: the wire no longer guides it, a classic
    /// error).
    pub passed_inner_tip: u32,
    /// The reperfusion of the territory the scene's clots cut off, from the flow solution
    /// (none in a scene without clots).
    pub reperfusion: Option<ReperfusionMetric>,
    /// The thrombectomy's figures, in a scene with a clot.
    pub thrombectomy: Option<ThrombectomyMetric>,
}

/// How much of an occluded territory the flow reaches again.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReperfusionMetric {
    /// Reperfused fraction of the territory (0–1), weighted by the outlets' open flows.
    pub fraction: f64,
    /// Its expanded TICI grade.
    pub etici: Etici,
}

/// Most instruments metrics are kept for (a stack's most).
pub const MAX_INSTRUMENTS: usize = 4;

/// One instrument's figures.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct InstrumentMetrics {
    /// Distance its tip travelled (m).
    pub tip_path_length_m: f64,
    /// Simulated time its hand moved it (s).
    pub moving_time_s: f64,
    /// Largest axial force its hand felt either way (N).
    pub peak_axial_force_n: f64,
    /// Largest torque its hand felt either way (N·m).
    #[serde(default)]
    pub peak_torque_nm: f64,
}

impl Metrics {
    /// Adds one step's wall forces: the largest single contact force and their total (N).
    pub fn add_wall_forces(&mut self, largest_n: f64, total_n: f64) {
        self.max_wall_force_n = self.max_wall_force_n.max(largest_n);
        if total_n > 0.0 {
            self.wall_force_sum_n += total_n;
            self.wall_contact_steps += 1;
            self.mean_wall_force_n = self.wall_force_sum_n / self.wall_contact_steps as f64;
        }
    }
}

/// A thrombectomy's figures.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ThrombectomyMetric {
    /// Passes made (stent retriever or aspiration).
    pub passes: u32,
    /// The first pass took the clot out with no fragment lost.
    pub first_pass_effect: bool,
    /// Fragments lodged downstream.
    pub emboli: u32,
    /// Force the clot's stiffness asks of the first tip to cross it (N).
    pub crossing_force_n: f64,
    /// Largest axial force on a hand while its tip was in a clot (N).
    pub peak_crossing_force_n: f64,
    /// The deployed stent's grip on the clot (N), 0 when none is engaged.
    pub grip_n: f64,
    /// Suction on.
    pub aspiration: bool,
    /// When the reperfusion first reached eTICI 2b or better (procedure time, s).
    pub reperfused_at_s: Option<f64>,
}

/// Kinds of session events.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    /// The physics diverged and the device was put back at its start.
    Divergence,
    /// The tip reached the target.
    TargetReached,
    /// Imaging changed (pedal, DSA run, roadmap) or could not.
    Imaging,
    /// Contrast agent was injected.
    Contrast,
    /// The device was changed.
    Device,
    /// The trainee reset the scene.
    Reset,
    /// The session closed.
    Closed,
    /// A limit held the push back: the force the hand or device can push with, or the
    /// device's length.
    Limit,
    /// The server lowered (or restored) the session's fidelity to keep its step rate.
    Overload,
    /// A step of the thrombectomy: stent deployed, suction, a pass's outcome, an embolus.
    Thrombectomy,
}

impl EventKind {
    /// Lower-case name, as on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            EventKind::Divergence => "divergence",
            EventKind::TargetReached => "target_reached",
            EventKind::Imaging => "imaging",
            EventKind::Contrast => "contrast",
            EventKind::Device => "device",
            EventKind::Reset => "reset",
            EventKind::Closed => "closed",
            EventKind::Limit => "limit",
            EventKind::Overload => "overload",
            EventKind::Thrombectomy => "thrombectomy",
        }
    }
}

/// Something that happened in a session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Event {
    /// Step at which it happened.
    pub step: u64,
    /// Simulated time (s).
    pub time_s: f64,
    /// What kind.
    pub kind: EventKind,
    /// Human-readable detail.
    pub message: String,
}
