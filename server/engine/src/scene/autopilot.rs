//! The scene's `[autopilot]`: a stack scene's scripted two-hand operator, with its optional
//! wire exchange or access stage; and its checks against the stack, the spares and the start.

use serde::{Deserialize, Serialize};

use super::devices::catalogue;
use super::field::{range, scene_error};
use super::spares::SpareSpec;
use super::stack::{MAX_STACK, StackEntry};
use super::start::StartSpec;
use super::target::default_reach_mm;
use crate::error::Result;

/// A stack scene's scripted operator: the wire (innermost instrument) is steered along the
/// route, the catheter around it follows, anything around that holds; at the target the
/// catheter is tracked over the wire. See [`cathlab_physics::two_hands`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AutopilotSpec {
    /// Push speed (mm/s), 1–100.
    #[serde(default = "default_autopilot_speed")]
    pub push_speed_mm_s: f64,
    /// How far ahead along the route the wire's bend is aimed (mm), 1–100.
    #[serde(default = "default_lookahead_mm")]
    pub lookahead_mm: f64,
    /// The wire is there when its tip is this far into the target branch (mm), 1–500.
    #[serde(default = "default_reach_mm")]
    pub wire_reach_mm: f64,
    /// How far behind the wire's tip the catheter follows (mm), 5–500.
    #[serde(default = "default_lag_mm")]
    pub catheter_lag_mm: f64,
    /// At the target, how far behind the wire's tip the catheter is tracked (mm), 1–500.
    #[serde(default = "default_track_mm")]
    pub catheter_track_mm: f64,
    /// A wire exchange on the way.
    #[serde(default)]
    pub exchange: Option<ExchangeSpec>,
    /// Where the instruments around the catheter park, outermost first: distance along the
    /// route of each one's tip (mm, beyond the start, within the route). While the wire
    /// leads they follow the catheter, each a further `catheter_lag_mm` behind, until there.
    /// Empty: they hold where the stack places them.
    #[serde(default)]
    pub park_along_mm: Vec<f64>,
    /// An access stage first: the stack brought up from the access to a branch on the
    /// route, then its wire taken out and the instruments that lead on loaded.
    #[serde(default)]
    pub access: Option<AccessSpec>,
}

/// The access stage of the scripted operator: the stack's wire leads (the catheter around it
/// following, the instruments around that following to their parks) until its tip is
/// `into_mm` along `branch`; the catheter is tracked over it to `catheter_track_mm` behind
/// its tip; the wire is withdrawn and taken out and the catalogue devices `load` are loaded,
/// outermost first; then the operator drives them to the target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccessSpec {
    /// A branch on the route, before the target's.
    pub branch: String,
    /// How far into it the wire's tip goes (mm), 1–500.
    pub into_mm: f64,
    /// How many of the stack's innermost instruments come out before the loading (the
    /// access wire, and the diagnostic catheter it went up in), 1 to all but the outermost.
    #[serde(default = "default_unload")]
    pub unload: usize,
    /// Catalogue identifiers loaded once those are out, outermost first.
    pub load: Vec<String>,
    /// How far ahead along the route the access wire's bend is aimed (mm), 1–100.
    #[serde(default = "default_lookahead_mm")]
    pub lookahead_mm: f64,
    /// How far behind the access wire's tip the catheter follows (mm), 5–500.
    #[serde(default = "default_lag_mm")]
    pub catheter_lag_mm: f64,
}

/// A wire exchange of the scripted operator: once the wire's tip is `into_mm` along
/// `branch`, the catheter is tracked over it and parked, the wire withdrawn to the hub and
/// exchanged for `device`, which leads on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExchangeSpec {
    /// A branch on the route.
    pub branch: String,
    /// How far into it (mm), 0–500.
    pub into_mm: f64,
    /// The new wire: a catalogue identifier, or empty with `spare`.
    #[serde(default)]
    pub device: String,
    /// The new wire: one of the scene's `spares` (index).
    #[serde(default)]
    pub spare: Option<usize>,
    /// How far ahead the new wire's bend is aimed (mm), 1–100.
    #[serde(default = "default_lookahead_mm")]
    pub lookahead_mm: f64,
    /// The new wire is there when its tip is this far into the target branch (mm), 1–500.
    #[serde(default = "default_reach_mm")]
    pub wire_reach_mm: f64,
}

fn default_autopilot_speed() -> f64 {
    20.0
}
fn default_lookahead_mm() -> f64 {
    20.0
}
fn default_unload() -> usize {
    1
}
fn default_lag_mm() -> f64 {
    50.0
}
fn default_track_mm() -> f64 {
    15.0
}

impl AutopilotSpec {
    /// Checks the operator's knobs, its access stage or wire exchange, and its parks, against
    /// the scene's `stack`, `spares` and `start`.
    pub(super) fn validate(
        &self,
        stack: &[StackEntry],
        spares: &[SpareSpec],
        start: &StartSpec,
    ) -> Result<()> {
        let a = self;
        if stack.len() < 2 {
            return Err(scene_error(
                "autopilot",
                "the two-hand autopilot needs a stack of at least a catheter and a wire",
            ));
        }
        range("autopilot.push_speed_mm_s", a.push_speed_mm_s, 1.0, 100.0)?;
        range("autopilot.lookahead_mm", a.lookahead_mm, 1.0, 100.0)?;
        range("autopilot.wire_reach_mm", a.wire_reach_mm, 1.0, 500.0)?;
        range("autopilot.catheter_lag_mm", a.catheter_lag_mm, 5.0, 500.0)?;
        range(
            "autopilot.catheter_track_mm",
            a.catheter_track_mm,
            1.0,
            500.0,
        )?;
        if let Some(x) = &a.access {
            range("autopilot.access.into_mm", x.into_mm, 1.0, 500.0)?;
            range("autopilot.access.lookahead_mm", x.lookahead_mm, 1.0, 100.0)?;
            range(
                "autopilot.access.catheter_lag_mm",
                x.catheter_lag_mm,
                5.0,
                500.0,
            )?;
            if x.unload == 0 || x.unload >= stack.len() {
                return Err(scene_error(
                    "autopilot.access.unload",
                    format!(
                        "{} of a stack of {}: 1 to all but the outermost",
                        x.unload,
                        stack.len()
                    ),
                ));
            }
            let kept = stack.len() - x.unload;
            let count = kept + x.load.len();
            if x.load.is_empty() || !(2..=MAX_STACK).contains(&count) {
                return Err(scene_error(
                    "autopilot.access.load",
                    format!(
                        "{} devices to load after the access wire: the stack would hold \
                         {count} (2 to {MAX_STACK})",
                        x.load.len()
                    ),
                ));
            }
            let mut outer = stack[kept - 1].resolve(kept - 1)?.0;
            for (k, id) in x.load.iter().enumerate() {
                let field = format!("autopilot.access.load[{k}]");
                let device = catalogue()
                    .device(id)
                    .map_err(|e| scene_error(&field, e.to_string()))?;
                cathlab_physics::stack::check_fit(&outer, &device)
                    .map_err(|e| scene_error(&field, format!("does not fit: {e}")))?;
                outer = device;
            }
            if a.exchange.is_some() {
                return Err(scene_error(
                    "autopilot.access",
                    "an access stage and a wire exchange do not go together",
                ));
            }
        }
        // With an access stage, the stack the operator drives to the target is the one
        // after the loading.
        let driven = match &a.access {
            Some(x) => (stack.len().saturating_sub(x.unload) + x.load.len()).max(stack.len()),
            None => stack.len(),
        };
        if a.park_along_mm.len() > driven - 2 {
            return Err(scene_error(
                "autopilot.park_along_mm",
                format!(
                    "{} parks for {} instruments around the catheter",
                    a.park_along_mm.len(),
                    driven - 2
                ),
            ));
        }
        for (k, &mm) in a.park_along_mm.iter().enumerate() {
            range(
                &format!("autopilot.park_along_mm[{k}]"),
                mm,
                start.along_route_mm,
                start.along_route_mm + 2000.0,
            )?;
        }
        if let Some(x) = &a.exchange {
            range("autopilot.exchange.into_mm", x.into_mm, 0.0, 500.0)?;
            range(
                "autopilot.exchange.lookahead_mm",
                x.lookahead_mm,
                1.0,
                100.0,
            )?;
            range(
                "autopilot.exchange.wire_reach_mm",
                x.wire_reach_mm,
                1.0,
                500.0,
            )?;
            match (x.spare, x.device.is_empty()) {
                (Some(k), true) if k < spares.len() => {}
                (Some(k), true) => {
                    return Err(scene_error(
                        "autopilot.exchange.spare",
                        format!("{k} is not a spare (the scene has {})", spares.len()),
                    ));
                }
                (None, false) => {
                    catalogue().get(&x.device).ok_or_else(|| {
                        scene_error(
                            "autopilot.exchange.device",
                            format!(
                                "'{}' is not in the device catalogue",
                                x.device.chars().take(64).collect::<String>()
                            ),
                        )
                    })?;
                }
                _ => {
                    return Err(scene_error(
                        "autopilot.exchange",
                        "name the new wire by `device` (catalogue) or `spare`, one of them",
                    ));
                }
            }
        }
        Ok(())
    }
}
