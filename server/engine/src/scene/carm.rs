//! The scene's `[carm]`: the C-arm at the start (angles, distances, field of view,
//! isocenter), and its checks.

use serde::{Deserialize, Serialize};

use super::field::range;
use crate::error::Result;

/// The C-arm at the start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CArmSpec {
    /// LAO + / RAO − (deg).
    #[serde(default)]
    pub primary_deg: f64,
    /// CRA + / CAU − (deg).
    #[serde(default)]
    pub secondary_deg: f64,
    /// Source–image distance (mm).
    #[serde(default = "default_sid_mm")]
    pub source_to_image_mm: f64,
    /// Source–isocenter distance (mm).
    #[serde(default = "default_sod_mm")]
    pub source_to_isocenter_mm: f64,
    /// Field of view at the detector (mm).
    #[serde(default = "default_fov_mm")]
    pub field_of_view_mm: f64,
    /// Branch the isocenter sits on (the target branch when empty).
    #[serde(default)]
    pub isocenter_branch: String,
    /// Fraction along that branch, 0–1.
    #[serde(default = "default_isocenter_at")]
    pub isocenter_at: f64,
}

fn default_sid_mm() -> f64 {
    1200.0
}
fn default_sod_mm() -> f64 {
    800.0
}
fn default_fov_mm() -> f64 {
    300.0
}
fn default_isocenter_at() -> f64 {
    0.0
}

impl Default for CArmSpec {
    fn default() -> Self {
        Self {
            primary_deg: 0.0,
            secondary_deg: 0.0,
            source_to_image_mm: default_sid_mm(),
            source_to_isocenter_mm: default_sod_mm(),
            field_of_view_mm: default_fov_mm(),
            isocenter_branch: String::new(),
            isocenter_at: default_isocenter_at(),
        }
    }
}

impl CArmSpec {
    /// Checks the angles, the distances and the field of view.
    pub(super) fn validate(&self) -> Result<()> {
        let c = self;
        range("carm.primary_deg", c.primary_deg, -120.0, 120.0)?;
        range("carm.secondary_deg", c.secondary_deg, -60.0, 60.0)?;
        range(
            "carm.source_to_image_mm",
            c.source_to_image_mm,
            500.0,
            2000.0,
        )?;
        range(
            "carm.source_to_isocenter_mm",
            c.source_to_isocenter_mm,
            200.0,
            c.source_to_image_mm - 50.0,
        )?;
        range("carm.field_of_view_mm", c.field_of_view_mm, 50.0, 500.0)?;
        range("carm.isocenter_at", c.isocenter_at, 0.0, 1.0)?;
        Ok(())
    }
}
