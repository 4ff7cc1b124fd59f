//! The commands a world applies at its step boundaries, as recorded: what a trainee, a haptic
//! bridge or the session's overload governor asks, and what one hand does to its instrument.

use cathlab_physics::{Insertion, Twist};
use cathlab_xray::PulseRate;
use serde::{Deserialize, Serialize};

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
    /// [`MAX_FIDELITY_LEVEL`](super::fidelity::MAX_FIDELITY_LEVEL) does less work a step (see
    /// [`fidelity_effort`](super::fidelity::fidelity_effort)). Issued by the session's physics
    /// loop, recorded like any command so that replays agree.
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
