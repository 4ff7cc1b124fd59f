//! A session's scores: every metric as a named value with its unit and which way is better
//! (what reports, CSV exports and learning curves list), and the verdict of each against the
//! scene's expert benchmark.
//!
//! Time, fluoroscopy time, dose, contrast and the numbers of injections, DSA runs and
//! roadmaps are the validated endovascular metrics of simulator studies (Van Herzeele et al.,
//! Eur J Vasc Endovasc Surg 2007; Patel et al., J Vasc Surg 2006); path length, smoothness and
//! force are defined in [`crate::motion`], [`crate::smoothness`] and [`crate::force`].

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::error::{AssessmentError, Result};
use crate::force::class_forces;
use crate::motion::{idle_time_s, path_ratio, tip_path_length_m, tip_speeds};
use crate::procedure::{ErrorThresholds, ProcedureError};
use crate::smoothness::sparc;
use crate::trace::{Trace, VesselClass};

/// Which way a metric is better.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Better {
    /// Less is better (time, dose, force).
    Lower,
    /// More is better (spectral arc length: nearer 0 is smoother).
    Higher,
}

/// One metric's value.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricValue {
    /// Stable key (`fluoroscopy_time_s`), as in CSV exports and benchmarks.
    pub key: String,
    /// Name for people.
    pub label: String,
    /// Unit (`s`, `mGy`, `N`; empty for a count or a ratio).
    pub unit: String,
    /// The value.
    pub value: f64,
    /// Which way is better.
    pub better: Better,
}

/// What the samples do not hold: counted from the commands and events.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Counts {
    /// Contrast injections.
    pub injections: u32,
    /// DSA runs.
    pub dsa_runs: u32,
    /// Roadmaps taken.
    pub roadmaps: u32,
    /// When the target was first reached (s), if it was.
    pub target_reached_at_s: Option<f64>,
}

fn metric(key: &str, label: &str, unit: &str, value: f64, better: Better) -> MetricValue {
    MetricValue {
        key: key.into(),
        label: label.into(),
        unit: unit.into(),
        value,
        better,
    }
}

/// Every metric of a session, in a fixed order (metrics that do not apply, such as the time
/// to target of a session that never reached it, are left out).
pub fn summarize(
    trace: &Trace,
    counts: &Counts,
    errors: &[ProcedureError],
    thresholds: &ErrorThresholds,
) -> Result<Vec<MetricValue>> {
    use Better::*;
    let s = trace.samples();
    let last = &s[s.len() - 1];
    let fluoroscopy_s: f64 = s
        .windows(2)
        .filter(|w| w[0].fluoroscopy)
        .map(|w| w[1].time_s - w[0].time_s)
        .sum();
    let mut out = vec![metric(
        "procedure_time_s",
        "Procedure time",
        "s",
        trace.duration_s(),
        Lower,
    )];
    if let Some(t) = counts.target_reached_at_s {
        out.push(metric("time_to_target_s", "Time to target", "s", t, Lower));
    }
    out.extend([
        metric(
            "fluoroscopy_time_s",
            "Fluoroscopy time",
            "s",
            fluoroscopy_s,
            Lower,
        ),
        metric(
            "air_kerma_mgy",
            "Reference air kerma",
            "mGy",
            last.air_kerma_mgy,
            Lower,
        ),
        metric(
            "kap_gy_cm2",
            "Kerma–area product",
            "Gy·cm²",
            last.kap_gy_cm2,
            Lower,
        ),
        metric(
            "contrast_ml",
            "Contrast volume",
            "mL",
            last.contrast_ml,
            Lower,
        ),
        metric(
            "injections",
            "Injections",
            "",
            f64::from(counts.injections),
            Lower,
        ),
        metric(
            "dsa_runs",
            "DSA runs",
            "",
            f64::from(counts.dsa_runs),
            Lower,
        ),
        metric(
            "roadmaps",
            "Roadmaps",
            "",
            f64::from(counts.roadmaps),
            Lower,
        ),
        metric(
            "tip_path_m",
            "Tip path length",
            "m",
            tip_path_length_m(trace),
            Lower,
        ),
    ]);
    if let Some(r) = path_ratio(trace) {
        out.push(metric("path_ratio", "Path ratio", "", r, Lower));
    }
    let (speeds, dt) = tip_speeds(trace);
    if let Ok(value) = sparc(&speeds, dt) {
        out.push(metric(
            "sparc",
            "Smoothness (spectral arc length)",
            "",
            value,
            Higher,
        ));
    }
    out.push(metric(
        "idle_time_s",
        "Idle time",
        "s",
        idle_time_s(trace),
        Lower,
    ));
    for f in class_forces(trace, &thresholds.forces)? {
        let (key, label) = match f.class {
            VesselClass::Aortic => ("aortic", "aortic"),
            VesselClass::Cervical => ("cervical", "neck"),
            VesselClass::Intracranial => ("intracranial", "intracranial"),
        };
        out.extend([
            metric(
                &format!("peak_force_{key}_n"),
                &format!("Peak wall force, {label}"),
                "N",
                f.peak_n,
                Lower,
            ),
            metric(
                &format!("force_impulse_{key}_n_s"),
                &format!("Wall force impulse, {label}"),
                "N·s",
                f.impulse_n_s,
                Lower,
            ),
            metric(
                &format!("time_above_force_{key}_s"),
                &format!("Time above the force threshold, {label}"),
                "s",
                f.time_above_s,
                Lower,
            ),
        ]);
    }
    out.extend([
        metric(
            "passed_inner_tip",
            "Outer instrument past the inner one's tip",
            "",
            f64::from(last.passed_inner_tip),
            Lower,
        ),
        metric("errors", "Errors", "", errors.len() as f64, Lower),
    ]);
    Ok(out)
}

/// How a scene judges scores: the expert values (from scripted expert runs) and how far from
/// them still passes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BenchmarkSpec {
    /// A lower-is-better metric passes up to the expert value × this factor (a higher-is-
    /// better one down to the expert value less |expert| × (factor − 1)).
    pub pass_factor: f64,
    /// Limits set by hand, by metric key, in place of the factor's.
    pub limits: BTreeMap<String, f64>,
}

impl Default for BenchmarkSpec {
    fn default() -> Self {
        Self {
            pass_factor: 1.5,
            limits: BTreeMap::new(),
        }
    }
}

impl BenchmarkSpec {
    /// Checks the factor (finite, ≥ 1) and the limits (finite).
    pub fn validate(&self) -> Result<()> {
        if !(self.pass_factor.is_finite() && self.pass_factor >= 1.0) {
            return Err(AssessmentError::Setting {
                what: "benchmark pass factor",
                value: self.pass_factor,
                range: "finite and ≥ 1",
            });
        }
        if let Some((key, value)) = self.limits.iter().find(|(_, v)| !v.is_finite()) {
            return Err(AssessmentError::Spec(format!(
                "benchmark limit of `{key}` is {value}, must be finite"
            )));
        }
        Ok(())
    }
}

/// One metric against its benchmark.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    /// The metric's key.
    pub key: String,
    /// The trainee's value.
    pub value: f64,
    /// The expert's value, if the scene has one.
    pub expert: Option<f64>,
    /// The pass limit.
    pub limit: f64,
    /// Whether the value is within the expert range.
    pub within: bool,
}

/// Each metric that has an expert value or a hand-set limit, judged.
pub fn judge(
    metrics: &[MetricValue],
    expert: &BTreeMap<String, f64>,
    spec: &BenchmarkSpec,
) -> Result<Vec<Verdict>> {
    spec.validate()?;
    Ok(metrics
        .iter()
        .filter_map(|m| {
            let e = expert.get(&m.key).copied();
            let limit = spec.limits.get(&m.key).copied().or_else(|| {
                e.map(|e| match m.better {
                    Better::Lower => e * spec.pass_factor,
                    Better::Higher => e - e.abs() * (spec.pass_factor - 1.0),
                })
            })?;
            let within = match m.better {
                Better::Lower => m.value <= limit,
                Better::Higher => m.value >= limit,
            };
            Some(Verdict {
                key: m.key.clone(),
                value: m.value,
                expert: e,
                limit,
                within,
            })
        })
        .collect())
}
