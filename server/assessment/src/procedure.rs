//! Procedure phases and errors, detected from what the simulation recorded (the samples and
//! the session's events), not from which buttons were pressed.
//!
//! **Phases** are the scene's: each starts the first time its condition holds after the phase
//! before it started (the leading tip enters a named vessel, gets so far along the route, or
//! an event happens), and ends when the next phase that is reached starts. A phase never
//! reached is listed without times. The thrombectomy procedure's phases follow the Delphi
//! consensus of Crossley et al. (J NeuroIntervent Surg 2019: 10 phases, 46 steps, 56 errors);
//! a scene names the ones its anatomy and devices allow.
//!
//! **Errors** ([`ErrorKind`]) are detected against [`ErrorThresholds`]: a tip deep in a
//! branch the route does not take, force above the intracranial threshold in an intracranial
//! vessel, fluoroscopy with no hand moving, contrast over the scene's budget, and an outer
//! instrument advanced past the tip of the one that should lead it.

use serde::{Deserialize, Serialize};

use crate::error::{AssessmentError, Result};
use crate::force::ForceThresholds;
use crate::motion::{IDLE_SPEED_M_S, IDLE_TWIST_RAD_S, idle_intervals};
use crate::trace::{Sample, Trace, VesselClass};

/// What starts a phase (at most one condition; none: the session's start).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhaseSpec {
    /// The phase's name ("arch navigation").
    pub name: String,
    /// Starts when the leading tip first enters a vessel whose name contains this text
    /// (case-insensitive).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vessel: Option<String>,
    /// Starts when the leading tip first gets this far along the route (mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub along_route_mm: Option<f64>,
    /// Starts when an event whose message contains this text first happens
    /// (case-insensitive).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub event: Option<String>,
}

impl PhaseSpec {
    /// Checks the phase: a name, at most one condition, a finite distance.
    pub fn validate(&self) -> Result<()> {
        let conditions = usize::from(self.vessel.is_some())
            + usize::from(self.along_route_mm.is_some())
            + usize::from(self.event.is_some());
        if self.name.trim().is_empty() {
            return Err(AssessmentError::Spec("a phase has no name".into()));
        }
        if conditions > 1 {
            return Err(AssessmentError::Spec(format!(
                "phase `{}` names {conditions} start conditions; at most one of vessel, \
                 along_route_mm and event",
                self.name
            )));
        }
        if let Some(d) = self.along_route_mm
            && !(d.is_finite() && d >= 0.0)
        {
            return Err(AssessmentError::Spec(format!(
                "phase `{}`: along_route_mm is {d}, must be finite and ≥ 0",
                self.name
            )));
        }
        Ok(())
    }
}

/// A session event as the assessment reads it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EventRecord {
    /// Simulated time (s).
    pub time_s: f64,
    /// Its kind (`target_reached`, `imaging`, `thrombectomy`, …).
    pub kind: String,
    /// What happened, in words.
    pub message: String,
}

/// A phase as detected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Phase {
    /// The scene's name for it.
    pub name: String,
    /// When it started (s); none if never reached.
    pub start_s: Option<f64>,
    /// When it ended (s): the next reached phase's start or the session's end.
    pub end_s: Option<f64>,
}

impl Phase {
    /// Its duration (s), if reached.
    pub fn duration_s(&self) -> Option<f64> {
        Some(self.end_s? - self.start_s?)
    }
}

fn contains(haystack: &str, needle: &str) -> bool {
    haystack.to_lowercase().contains(&needle.to_lowercase())
}

/// The phases of `specs` in `trace` and `events`.
pub fn detect_phases(
    trace: &Trace,
    events: &[EventRecord],
    specs: &[PhaseSpec],
) -> Result<Vec<Phase>> {
    for spec in specs {
        spec.validate()?;
    }
    let samples = trace.samples();
    let end = samples[samples.len() - 1].time_s;
    let mut from = samples[0].time_s;
    let mut starts = Vec::with_capacity(specs.len());
    for spec in specs {
        let start = if let Some(vessel) = &spec.vessel {
            samples
                .iter()
                .find(|s| s.time_s >= from && contains(&s.vessel, vessel))
                .map(|s| s.time_s)
        } else if let Some(mm) = spec.along_route_mm {
            samples
                .iter()
                .find(|s| s.time_s >= from && s.along_route_m * 1e3 >= mm)
                .map(|s| s.time_s)
        } else if let Some(text) = &spec.event {
            events
                .iter()
                .find(|e| e.time_s >= from && contains(&e.message, text))
                .map(|e| e.time_s)
        } else {
            Some(from)
        };
        if let Some(t) = start {
            from = t;
        }
        starts.push(start);
    }
    Ok(specs
        .iter()
        .enumerate()
        .map(|(i, spec)| {
            let end_s = starts[i].map(|_| {
                starts[i + 1..]
                    .iter()
                    .flatten()
                    .next()
                    .copied()
                    .unwrap_or(end)
            });
            Phase {
                name: spec.name.clone(),
                start_s: starts[i],
                end_s,
            }
        })
        .collect())
}

/// Where an error's thresholds lie.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ErrorThresholds {
    /// Depth of the leading tip into a branch off the route that counts as an error (mm).
    pub off_route_mm: f64,
    /// Wall force per vessel class (N); the intracranial one is an error, all count time
    /// above.
    pub forces: ForceThresholds,
    /// Fluoroscopy with no hand moving for this long is an error (s).
    pub idle_fluoroscopy_s: f64,
    /// Contrast the scene allows (mL).
    pub contrast_budget_ml: f64,
}

impl Default for ErrorThresholds {
    fn default() -> Self {
        Self {
            off_route_mm: 15.0,
            forces: ForceThresholds::default(),
            idle_fluoroscopy_s: 5.0,
            contrast_budget_ml: 60.0,
        }
    }
}

impl ErrorThresholds {
    /// Checks every threshold: finite and > 0.
    pub fn validate(&self) -> Result<()> {
        self.forces.validate()?;
        crate::force::positive_settings([
            ("off-route depth (mm)", self.off_route_mm),
            ("idle fluoroscopy time (s)", self.idle_fluoroscopy_s),
            ("contrast budget (mL)", self.contrast_budget_ml),
        ])
    }
}

/// Kinds of procedure errors.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorKind {
    /// The leading tip went deeper than the threshold into a branch the route does not take.
    OffRoute,
    /// Wall force above the intracranial threshold in an intracranial vessel.
    IntracranialForce,
    /// Fluoroscopy on while no hand moved, for longer than the threshold.
    IdleFluoroscopy,
    /// More contrast than the scene's budget.
    ContrastOverBudget,
    /// An outer instrument advanced past the tip of the one inside it (a catheter without its
    /// wire's lead).
    UnsupportedAdvance,
}

impl ErrorKind {
    /// Every kind.
    pub const ALL: [ErrorKind; 5] = [
        Self::OffRoute,
        Self::IntracranialForce,
        Self::IdleFluoroscopy,
        Self::ContrastOverBudget,
        Self::UnsupportedAdvance,
    ];

    /// Lower-case name, as in reports.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::OffRoute => "off_route",
            Self::IntracranialForce => "intracranial_force",
            Self::IdleFluoroscopy => "idle_fluoroscopy",
            Self::ContrastOverBudget => "contrast_over_budget",
            Self::UnsupportedAdvance => "unsupported_advance",
        }
    }
}

/// One error as detected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProcedureError {
    /// What kind.
    pub kind: ErrorKind,
    /// When it began (s).
    pub start_s: f64,
    /// When it ended (s; the start for a one-off error).
    pub end_s: f64,
    /// The vessel the leading tip was in.
    pub vessel: String,
    /// What happened, in words, with the figure that made it an error.
    pub detail: String,
}

/// Stretches of consecutive samples (index ranges, inclusive) where `on` holds.
fn stretches(n: usize, on: impl Fn(usize) -> bool) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for i in 0..n {
        match (on(i), start) {
            (true, None) => start = Some(i),
            (false, Some(a)) => {
                out.push((a, i - 1));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(a) = start {
        out.push((a, n - 1));
    }
    out
}

/// One error of `kind` per stretch of samples whose `value` is above `limit`, told by the
/// stretch's peak sample (its vessel and `detail`).
fn over_limit(
    s: &[Sample],
    kind: ErrorKind,
    value: impl Fn(&Sample) -> f64,
    limit: f64,
    detail: impl Fn(&Sample) -> String,
) -> Vec<ProcedureError> {
    stretches(s.len(), |i| value(&s[i]) > limit)
        .into_iter()
        .map(|(a, b)| {
            let peak = (a..=b)
                .max_by(|&i, &j| value(&s[i]).total_cmp(&value(&s[j])))
                .unwrap_or(a);
            ProcedureError {
                kind,
                start_s: s[a].time_s,
                end_s: s[b].time_s,
                vessel: s[peak].vessel.clone(),
                detail: detail(&s[peak]),
            }
        })
        .collect()
}

/// The errors committed in `trace`.
pub fn detect_errors(trace: &Trace, thresholds: &ErrorThresholds) -> Result<Vec<ProcedureError>> {
    thresholds.validate()?;
    let s = trace.samples();
    let n = s.len();
    let mut errors = Vec::new();
    // Off the route.
    let limit_m = thresholds.off_route_mm * 1e-3;
    errors.extend(over_limit(
        s,
        ErrorKind::OffRoute,
        |x| x.off_route_m,
        limit_m,
        |x| {
            format!(
                "the tip went {:.0} mm off the route into {} (limit {:.0} mm)",
                x.off_route_m * 1e3,
                name_or_unnamed(&x.vessel),
                thresholds.off_route_mm
            )
        },
    ));
    // Force in an intracranial vessel.
    let k = VesselClass::ALL
        .iter()
        .position(|c| *c == VesselClass::Intracranial)
        .unwrap_or(2);
    let limit_n = thresholds.forces.intracranial_n;
    errors.extend(over_limit(
        s,
        ErrorKind::IntracranialForce,
        |x| x.wall_force_n[k],
        limit_n,
        |x| {
            format!(
                "{:.2} N on an intracranial wall (limit {limit_n:.2} N)",
                x.wall_force_n[k]
            )
        },
    ));
    // Fluoroscopy with no hand moving: intervals where both ends expose and nothing moved.
    let idle = idle_intervals(trace, IDLE_SPEED_M_S, IDLE_TWIST_RAD_S);
    for (a, b) in stretches(idle.len(), |i| {
        idle[i] && s[i].fluoroscopy && s[i + 1].fluoroscopy
    }) {
        let (start, end) = (s[a].time_s, s[b + 1].time_s);
        if end - start >= thresholds.idle_fluoroscopy_s {
            errors.push(ProcedureError {
                kind: ErrorKind::IdleFluoroscopy,
                start_s: start,
                end_s: end,
                vessel: s[a].vessel.clone(),
                detail: format!(
                    "{:.1} s of fluoroscopy with no hand moving (limit {:.1} s)",
                    end - start,
                    thresholds.idle_fluoroscopy_s
                ),
            });
        }
    }
    // Contrast over budget: once, when it is crossed.
    if let Some(over) = s
        .iter()
        .find(|x| x.contrast_ml > thresholds.contrast_budget_ml)
    {
        errors.push(ProcedureError {
            kind: ErrorKind::ContrastOverBudget,
            start_s: over.time_s,
            end_s: over.time_s,
            vessel: over.vessel.clone(),
            detail: format!(
                "contrast passed the budget of {:.0} mL ({:.0} mL in all)",
                thresholds.contrast_budget_ml,
                s[n - 1].contrast_ml
            ),
        });
    }
    // An outer instrument past the leading inner one's tip: each new count.
    for w in s.windows(2) {
        for _ in w[0].passed_inner_tip..w[1].passed_inner_tip {
            errors.push(ProcedureError {
                kind: ErrorKind::UnsupportedAdvance,
                start_s: w[1].time_s,
                end_s: w[1].time_s,
                vessel: w[1].vessel.clone(),
                detail: format!(
                    "an instrument was advanced past the tip of the one it follows, in {}",
                    name_or_unnamed(&w[1].vessel)
                ),
            });
        }
    }
    errors.sort_by(|a, b| a.start_s.total_cmp(&b.start_s));
    Ok(errors)
}

fn name_or_unnamed(vessel: &str) -> &str {
    if vessel.is_empty() {
        "an unnamed vessel"
    } else {
        vessel
    }
}
