//! The recorded samples a session is assessed from: time, the leading tip, how far along the
//! route to the target it is, each hand's insertion and twist, and the wall force in each
//! vessel class.

use serde::{Deserialize, Serialize};

use crate::error::{AssessmentError, Result};

/// Where a wall force acts, by the kind of vessel: thresholds differ (an intracranial
/// artery tolerates far less than the aorta).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum VesselClass {
    /// Aorta, arch and its great vessels' origins, iliac and femoral access.
    Aortic,
    /// Neck: common, internal (cervical) and external carotids, vertebrals, subclavians.
    Cervical,
    /// Inside the skull: the carotid siphon onwards, the basilar, the circle of Willis and
    /// its branches.
    Intracranial,
}

impl VesselClass {
    /// Every class, in the order of [`Sample::wall_force_n`].
    pub const ALL: [VesselClass; 3] = [Self::Aortic, Self::Cervical, Self::Intracranial];
}

/// One moment of a session.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// Simulated time (s).
    pub time_s: f64,
    /// Position of the leading instrument's tip (m).
    pub tip_m: [f64; 3],
    /// How far along the route to the target the leading tip is (m).
    pub along_route_m: f64,
    /// Each instrument's inserted length (m), outermost first.
    pub inserted_m: Vec<f64>,
    /// Each instrument's twist at the hand (rad), outermost first.
    pub twist_rad: Vec<f64>,
    /// Total wall contact force in each vessel class (N), in [`VesselClass::ALL`] order.
    pub wall_force_n: [f64; 3],
    /// The X-ray tube is exposing (fluoroscopy pedal down or a DSA run).
    #[serde(default)]
    pub fluoroscopy: bool,
    /// Contrast agent injected so far (mL).
    #[serde(default)]
    pub contrast_ml: f64,
    /// Cumulative air kerma at the interventional reference point (mGy).
    #[serde(default)]
    pub air_kerma_mgy: f64,
    /// Cumulative kerma–area product (Gy·cm²).
    #[serde(default)]
    pub kap_gy_cm2: f64,
    /// How far the leading tip is off the route, into a branch the route does not take (m;
    /// 0 on the route).
    #[serde(default)]
    pub off_route_m: f64,
    /// The vessel the leading tip is in (its branch's name).
    #[serde(default)]
    pub vessel: String,
    /// The vessel's class.
    #[serde(default)]
    pub vessel_class: Option<VesselClass>,
    /// Times so far an instrument passed the tip of the one inside it while that one led.
    #[serde(default)]
    pub passed_inner_tip: u32,
}

/// A session's samples, in time order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Trace {
    samples: Vec<Sample>,
}

impl Trace {
    /// Checks the samples: at least two, time strictly increasing, every value finite, the
    /// one twist per insertion (the number of instruments may change: a stack's loads and
    /// unloads), forces not negative.
    pub fn new(samples: Vec<Sample>) -> Result<Self> {
        if samples.len() < 2 {
            return Err(AssessmentError::Samples(format!(
                "{} sample(s); at least 2 are needed",
                samples.len()
            )));
        }
        for (i, s) in samples.iter().enumerate() {
            let finite = s.time_s.is_finite()
                && s.along_route_m.is_finite()
                && s.tip_m.iter().all(|v| v.is_finite())
                && s.inserted_m.iter().all(|v| v.is_finite())
                && s.twist_rad.iter().all(|v| v.is_finite())
                && s.wall_force_n.iter().all(|v| v.is_finite() && *v >= 0.0)
                && [s.contrast_ml, s.air_kerma_mgy, s.kap_gy_cm2, s.off_route_m]
                    .iter()
                    .all(|v| v.is_finite() && *v >= 0.0);
            if !finite {
                return Err(AssessmentError::Samples(format!(
                    "sample {i} has a value that is not finite (or a negative force, dose, \
                     volume or distance)"
                )));
            }
            // A stack's loads and unloads change the number of instruments; each sample
            // has one twist per insertion.
            if s.inserted_m.len() != s.twist_rad.len() || s.inserted_m.is_empty() {
                return Err(AssessmentError::Samples(format!(
                    "sample {i} has {} insertions and {} twists; one of each per instrument",
                    s.inserted_m.len(),
                    s.twist_rad.len()
                )));
            }
            if i > 0 && s.time_s <= samples[i - 1].time_s {
                return Err(AssessmentError::Samples(format!(
                    "sample {i} is at {} s, not after sample {} at {} s",
                    s.time_s,
                    i - 1,
                    samples[i - 1].time_s
                )));
            }
        }
        Ok(Self { samples })
    }

    /// The samples.
    pub fn samples(&self) -> &[Sample] {
        &self.samples
    }

    /// Time from the first sample to the last (s).
    pub fn duration_s(&self) -> f64 {
        self.samples[self.samples.len() - 1].time_s - self.samples[0].time_s
    }
}
