//! Wall force by vessel class.
//!
//! - **Peak wall force** (N): the largest total contact force in a class over the session.
//! - **Force impulse** (N·s): ∫ F dt per class (trapezoidal over the samples): how hard and
//!   how long the devices pressed on the wall.
//! - **Time above threshold** (s): time a class's total force exceeds its threshold, with
//!   linear interpolation of the crossing inside an interval. Contact force on the wall as a
//!   criterion of perforation risk during device introduction follows Takashima et al.,
//!   J Biomech Sci Eng 2022 (simulation of the accidents in the Japanese Society for
//!   Neuroendovascular Therapy's survey). No study gives one threshold per vessel class:
//!   the defaults ([`ForceThresholds::default`]: 1.0 N aortic, 0.5 N cervical, 0.2 N
//!   intracranial) are this project's choice, and a scene may set its own.

use serde::{Deserialize, Serialize};

use crate::error::{AssessmentError, Result};
use crate::trace::{Trace, VesselClass};

/// Force above which time counts, per vessel class (N).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ForceThresholds {
    /// Aorta and access (N).
    pub aortic_n: f64,
    /// Neck vessels (N).
    pub cervical_n: f64,
    /// Intracranial vessels (N).
    pub intracranial_n: f64,
}

impl Default for ForceThresholds {
    fn default() -> Self {
        Self {
            aortic_n: 1.0,
            cervical_n: 0.5,
            intracranial_n: 0.2,
        }
    }
}

impl ForceThresholds {
    /// The threshold of `class` (N).
    pub fn of(&self, class: VesselClass) -> f64 {
        match class {
            VesselClass::Aortic => self.aortic_n,
            VesselClass::Cervical => self.cervical_n,
            VesselClass::Intracranial => self.intracranial_n,
        }
    }

    /// Checks that every threshold is finite and > 0.
    pub fn validate(&self) -> Result<()> {
        positive_settings([
            ("aortic force threshold (N)", self.aortic_n),
            ("cervical force threshold (N)", self.cervical_n),
            ("intracranial force threshold (N)", self.intracranial_n),
        ])
    }
}

/// Checks that every named setting is finite and > 0; the first that is not is named.
pub(crate) fn positive_settings<const N: usize>(settings: [(&'static str, f64); N]) -> Result<()> {
    for (what, value) in settings {
        if !(value.is_finite() && value > 0.0) {
            return Err(AssessmentError::Setting {
                what,
                value,
                range: "finite and > 0",
            });
        }
    }
    Ok(())
}

/// A vessel class's wall force figures.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ClassForce {
    /// The class.
    pub class: VesselClass,
    /// Largest total force (N).
    pub peak_n: f64,
    /// ∫ F dt (N·s).
    pub impulse_n_s: f64,
    /// Time above the class's threshold (s).
    pub time_above_s: f64,
}

fn index(class: VesselClass) -> usize {
    VesselClass::ALL
        .iter()
        .position(|c| *c == class)
        .unwrap_or(0)
}

/// Time within one interval where the linearly interpolated force `a` → `b` exceeds `t`
/// (as a fraction of the interval).
fn fraction_above(a: f64, b: f64, t: f64) -> f64 {
    match (a > t, b > t) {
        (true, true) => 1.0,
        (false, false) => 0.0,
        (true, false) => (a - t) / (a - b),
        (false, true) => (b - t) / (b - a),
    }
}

/// The wall force figures of every class.
pub fn class_forces(trace: &Trace, thresholds: &ForceThresholds) -> Result<Vec<ClassForce>> {
    thresholds.validate()?;
    let s = trace.samples();
    Ok(VesselClass::ALL
        .iter()
        .map(|&class| {
            let k = index(class);
            let t = thresholds.of(class);
            let mut out = ClassForce {
                class,
                peak_n: s.iter().map(|x| x.wall_force_n[k]).fold(0.0, f64::max),
                impulse_n_s: 0.0,
                time_above_s: 0.0,
            };
            for w in s.windows(2) {
                let dt = w[1].time_s - w[0].time_s;
                let (a, b) = (w[0].wall_force_n[k], w[1].wall_force_n[k]);
                out.impulse_n_s += 0.5 * (a + b) * dt;
                out.time_above_s += fraction_above(a, b, t) * dt;
            }
            out
        })
        .collect())
}
