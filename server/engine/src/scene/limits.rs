//! The scene's `[limits]`: what the trainee's hand meets (the force it pushes with, the
//! torque it twists with, the length left unsupported outside the sheath, the length that
//! stays outside), and its checks.

use serde::{Deserialize, Serialize};

use super::field::range;
use crate::error::Result;

/// How far past its limit a hand's force may end a step before the step is taken again (a
/// share of the limit; see the world's force guard, `World::step_within_force_limits`).
pub const FORCE_OVERSHOOT: f64 = 0.02;

/// The physical limits of a push. The force limit of a device is the smaller of the
/// operator's and the Euler buckling load of its proximal shaft over the unsupported length
/// between the hand and the sheath's valve (clamped at both ends): about 1.9 N for a 0.014"
/// micro-guidewire over 30 mm, so that wire buckles outside before the hand's 10 N. The
/// twist a hand puts in is bounded the same way, by the torque its fingers roll a torque
/// device (or a catheter's hub) with before they slip.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LimitsSpec {
    /// The most a hand pushes with (N).
    pub push_force_n: f64,
    /// The most torque a hand twists with (N·m): 0.1 N·m, a pinch of 25 N between thumb and
    /// index finger (half a maximal tip pinch of ~50 N) rolling a torque device of 4 mm
    /// radius with a glove's friction of ~0.5 on both sides (2·μ·F·r): a strength, as the
    /// 10 N push is, not what a twist usually takes.
    pub twist_torque_nm: f64,
    /// Length of device unsupported between the hand and the sheath's valve (mm).
    pub unsupported_mm: f64,
    /// Length of device that stays outside the access: sheath, valve, hub and grip (mm).
    pub outside_mm: f64,
}

impl Default for LimitsSpec {
    fn default() -> Self {
        Self {
            push_force_n: 10.0,
            twist_torque_nm: 0.1,
            unsupported_mm: 30.0,
            outside_mm: 150.0,
        }
    }
}

impl LimitsSpec {
    /// Checks the push force and the lengths.
    pub(super) fn validate(&self) -> Result<()> {
        let l = self;
        range("limits.push_force_n", l.push_force_n, 0.1, 10_000.0)?;
        range("limits.twist_torque_nm", l.twist_torque_nm, 1e-4, 10.0)?;
        range("limits.unsupported_mm", l.unsupported_mm, 5.0, 500.0)?;
        range("limits.outside_mm", l.outside_mm, 0.0, 2000.0)?;
        Ok(())
    }
}
