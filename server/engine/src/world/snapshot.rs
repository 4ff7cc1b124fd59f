//! What the world shows after a step, for clients and the renderer (patient LPS, SI units):
//! the snapshot, each instrument's state, the imaging state the trainee controls and the
//! wall contacts.

use std::sync::Arc;

use cathlab_xray::{ContrastTube, DeviceAppearance, PulseRate};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::hand::PushLimit;
use crate::metrics::Metrics;

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
