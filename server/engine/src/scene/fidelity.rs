//! The scene's `[fidelity]`: accuracy against cost (step rate, element lengths, contact
//! tolerance, refinement, detector size, contrast cells), and its checks.

use serde::{Deserialize, Serialize};

use super::field::{range, yes};
use crate::error::Result;

/// Accuracy against cost.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FidelitySpec {
    /// Physics steps per second (100–2000).
    #[serde(default = "default_step_rate")]
    pub step_rate_hz: f64,
    /// Element length near the tip (mm).
    #[serde(default = "default_tip_element_mm")]
    pub tip_element_mm: f64,
    /// Element length along the shaft (mm).
    #[serde(default = "default_shaft_element_mm")]
    pub shaft_element_mm: f64,
    /// Contact solve's relative force tolerance.
    #[serde(default = "default_contact_tolerance")]
    pub contact_tolerance: f64,
    /// Contact solver: `gauss_seidel` (the paper's projected Gauss–Seidel, the default) or
    /// `newton` (semismooth Newton on the Delassus matrix).
    #[serde(default)]
    pub contact_solver: ContactSolver,
    /// Refine elements where the device bends or touches.
    #[serde(default = "yes")]
    pub refine: bool,
    /// Skip the physics while every hand is still and the devices have come to rest
    /// ([`cathlab_physics::Sleep`]'s defaults: a 100-step window over which no node's mean
    /// position drifted 5 µm);
    /// any command, load or exchange wakes them.
    #[serde(default = "yes")]
    pub sleep_at_rest: bool,
    /// Let the wall's friction resist the slide through the entry, so that a device drawn
    /// round bends feels the capstan law ([`cathlab_physics::NavigationSettings`]'s
    /// `slide_friction`). Off by default until the scenes' scripted runs are tuned with it.
    #[serde(default)]
    pub slide_friction: bool,
    /// Cap a step on the motion the last contact forces leave, not on the free motion, so
    /// that the wall's forces are not scaled with the springback it holds
    /// ([`cathlab_physics::NavigationSettings`]'s `cap_with_held_contacts`). Off by default
    /// until the scenes' scripted runs are tuned with it.
    #[serde(default)]
    pub cap_with_held_contacts: bool,
    /// Let a stack's inner instruments slide through the ones around them with their own
    /// axial strain, so that each hand feels its own instrument's load and a hand that gives
    /// way unloads it ([`cathlab_physics::NavigationSettings`]'s `axial_slide`). Off by
    /// default until the scenes' scripted runs are tuned with it.
    #[serde(default)]
    pub axial_slide: bool,
    /// Detector size (pixels, square).
    #[serde(default = "default_frame_px")]
    pub frame_px: u32,
    /// Contrast cell length (mm).
    #[serde(default = "default_cell_mm")]
    pub contrast_cell_mm: f64,
    /// Contrast advances every this many physics steps.
    #[serde(default = "default_contrast_every")]
    pub contrast_every_steps: u32,
}

/// The scene's contact solver (see [`cathlab_physics::ContactMethod`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ContactSolver {
    /// Semismooth Newton on the Delassus matrix.
    Newton,
    /// Projected Gauss–Seidel with the active-set polish of the normal forces (the default
    /// until Newton is faster on the bundled scenes).
    #[default]
    GaussSeidel,
}

impl From<ContactSolver> for cathlab_physics::ContactMethod {
    fn from(solver: ContactSolver) -> Self {
        match solver {
            ContactSolver::Newton => Self::Newton,
            ContactSolver::GaussSeidel => Self::GaussSeidel,
        }
    }
}

fn default_step_rate() -> f64 {
    500.0
}
fn default_tip_element_mm() -> f64 {
    1.5
}
fn default_shaft_element_mm() -> f64 {
    5.0
}
fn default_contact_tolerance() -> f64 {
    1e-3
}
fn default_frame_px() -> u32 {
    512
}
fn default_cell_mm() -> f64 {
    0.5
}
fn default_contrast_every() -> u32 {
    10
}

impl Default for FidelitySpec {
    fn default() -> Self {
        Self {
            step_rate_hz: default_step_rate(),
            tip_element_mm: default_tip_element_mm(),
            shaft_element_mm: default_shaft_element_mm(),
            contact_tolerance: default_contact_tolerance(),
            contact_solver: ContactSolver::default(),
            refine: true,
            sleep_at_rest: true,
            slide_friction: false,
            cap_with_held_contacts: false,
            axial_slide: false,
            frame_px: default_frame_px(),
            contrast_cell_mm: default_cell_mm(),
            contrast_every_steps: default_contrast_every(),
        }
    }
}

impl FidelitySpec {
    /// Checks every knob's range.
    pub(super) fn validate(&self) -> Result<()> {
        let q = self;
        range("fidelity.step_rate_hz", q.step_rate_hz, 100.0, 2000.0)?;
        range("fidelity.tip_element_mm", q.tip_element_mm, 0.25, 10.0)?;
        range(
            "fidelity.shaft_element_mm",
            q.shaft_element_mm,
            q.tip_element_mm,
            50.0,
        )?;
        range("fidelity.contact_tolerance", q.contact_tolerance, 1e-8, 0.5)?;
        range("fidelity.frame_px", q.frame_px as f64, 64.0, 2048.0)?;
        range("fidelity.contrast_cell_mm", q.contrast_cell_mm, 0.1, 5.0)?;
        range(
            "fidelity.contrast_every_steps",
            q.contrast_every_steps as f64,
            1.0,
            100.0,
        )?;
        Ok(())
    }
}
