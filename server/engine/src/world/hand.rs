//! One instrument's hand: its device's look, its push limits (the hand's strength, the Euler
//! load outside the sheath, the device's length) and twist limit (the hand's torque), what
//! held its push or twist back and what it feels; and an exchange waiting for its instrument
//! to be withdrawn.

use cathlab_xray::DeviceAppearance;
use serde::{Deserialize, Serialize};

use crate::assets::SceneAssets;
use crate::strand::HandReaction;

/// What holds a push back: the force the hand or the device can push with, or the device's
/// length (its hub at the sheath).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PushLimit {
    /// Nothing: the device advances as commanded.
    #[default]
    None,
    /// The proximal force reached the limit: the hand cannot push harder, or the device
    /// would buckle outside the sheath; or, pulling, the hand cannot pull harder.
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
    /// The most the proximal end is pulled with (N): the hand's strength.
    pub pull_force_n: f64,
    /// The most that can be inserted (m): the device's length less what stays outside.
    pub max_inserted_m: f64,
    /// The most torque the proximal end is twisted with (N·m): the hand's strength.
    pub torque_nm: f64,
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
            pull_force_n: limits.push_force_n,
            max_inserted_m: device.length_m() - limits.outside_mm * 1e-3 - along_route_m,
            torque_nm: limits.twist_torque_nm,
        }
    }
}

/// An exchange (or an unloading) waiting for its instrument to be withdrawn.
#[derive(Debug, Clone)]
pub(super) struct PendingExchange {
    pub(super) index: usize,
    /// The device that takes its place, its look and the name it goes by; `None`: the
    /// instrument is taken out.
    pub(super) replacement: Option<(cathlab_physics::Device, DeviceAppearance, String)>,
}

/// One instrument's hand: its device's look and limits, and what held its push back.
#[derive(Debug, Clone)]
pub(super) struct Hand {
    pub(super) catalogue_id: String,
    pub(super) look: DeviceAppearance,
    pub(super) limits: DeviceLimits,
    pub(super) push_limit: PushLimit,
    /// When a hold of the push is reported.
    pub(super) push_reports: HoldReports,
    /// Whether the hand's twist is held back (its torque at its strength).
    pub(super) twist_held: bool,
    /// When a hold of the twist is reported.
    pub(super) twist_reports: HoldReports,
    pub(super) reaction: HandReaction,
    /// How fast its force rose with its own instrument's advance in the last step the force
    /// guard watched (N/m; `None` before one, or where it fell): the share of a move that keeps
    /// the hand at its limit is predicted from it, so a push held at the limit steps once.
    pub(super) stiffness_n_per_m: Option<f64>,
    /// The force (N) at which its force limit last acted, and whether it gave way then or
    /// held (None: the limit did not act in the last step): a give that left the force larger
    /// is not repeated, a hold that did not lower it is not either.
    pub(super) limit_acted_at: Option<(f64, bool)>,
}

impl Hand {
    pub(super) fn new(
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
            push_reports: HoldReports::default(),
            twist_held: false,
            twist_reports: HoldReports::default(),
            reaction: HandReaction::default(),
            stiffness_n_per_m: None,
            limit_acted_at: None,
        }
    }
}

/// The hands of the scene's start: the active device's, or one per stack instrument.
pub(super) fn start_hands(assets: &SceneAssets, active: usize) -> Vec<Hand> {
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

/// How long a push or twist must go unhindered before the next limit it meets is reported
/// again (s).
const LIMIT_REARM_S: f64 = 0.5;

/// When a limit's hold of a push or a twist is reported: once per hold, and again only after
/// the hand has been free of it for [`LIMIT_REARM_S`].
#[derive(Debug, Clone, Copy)]
pub(super) struct HoldReports {
    /// Whether the next hold is reported.
    armed: bool,
    /// When the hand was last freed of a hold (s, procedure time).
    free_since_s: f64,
}

impl Default for HoldReports {
    fn default() -> Self {
        Self {
            armed: true,
            free_since_s: 0.0,
        }
    }
}

impl HoldReports {
    /// This step's hold (`held`, after `was_held` the step before) at procedure time `now_s`:
    /// whether to report it.
    pub(super) fn update(&mut self, was_held: bool, held: bool, now_s: f64) -> bool {
        if held {
            return std::mem::replace(&mut self.armed, false);
        }
        if was_held {
            self.free_since_s = now_s;
        }
        if now_s - self.free_since_s >= LIMIT_REARM_S {
            self.armed = true;
        }
        false
    }
}
