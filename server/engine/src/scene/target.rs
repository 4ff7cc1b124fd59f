//! The scene's `[target]`: the branch the trainee steers to (by name or by a point near its
//! end), how far along it counts, and which instrument's tip; and its checks.

use serde::{Deserialize, Serialize};

use super::field::{range, scene_error};
use crate::error::Result;

/// The target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetSpec {
    /// Target branch name; or empty, with `end_near_mm`.
    #[serde(default)]
    pub branch: String,
    /// The target is the branch whose free end is nearest this LPS point (mm), when
    /// `branch` is empty.
    #[serde(default)]
    pub end_near_mm: Option<[f64; 3]>,
    /// Reached when the tip is this far along the branch (mm).
    #[serde(default = "default_reach_mm")]
    pub reach_mm: f64,
    /// In a stack, the instrument whose tip must get there (index, outermost first: the
    /// catheter, not just the wire ahead of it); by default whichever tip leads.
    #[serde(default)]
    pub instrument: Option<usize>,
}

pub(super) fn default_reach_mm() -> f64 {
    50.0
}

impl TargetSpec {
    /// Checks that the target is named by a branch or by a point near a vessel's end, not
    /// both.
    pub(super) fn validate(&self) -> Result<()> {
        match (self.branch.is_empty(), &self.end_near_mm) {
            (true, None) => {
                return Err(scene_error(
                    "target",
                    "name a `branch`, or give `end_near_mm` (an LPS point near a vessel's end)",
                ));
            }
            (false, Some(_)) => {
                return Err(scene_error(
                    "target",
                    "names a `branch` and gives `end_near_mm`; give one",
                ));
            }
            (true, Some(p)) => {
                for (a, c) in p.iter().enumerate() {
                    range(&format!("target.end_near_mm[{a}]"), *c, -5000.0, 5000.0)?;
                }
            }
            (false, None) => {}
        }
        Ok(())
    }

    /// Checks how far along the branch the target counts as reached.
    pub(super) fn validate_reach(&self) -> Result<()> {
        range("target.reach_mm", self.reach_mm, 0.0, 500.0)
    }
}
