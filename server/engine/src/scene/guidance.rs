//! The scene's `[guidance]`: what the trainee's page shows to guide (off for an assessment).

use serde::{Deserialize, Serialize};

/// What the trainee's page may show to guide; an instructor turns it off for assessment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GuidanceSpec {
    /// The target vessel outlined on the subtraction and roadmap images (the server sends
    /// the outline only when this is on).
    pub target_marker: bool,
    /// The remaining distance to the target in the HUD.
    pub target_distance: bool,
    /// Prompts: "hold F for fluoroscopy" and the target-reached banner.
    pub prompts: bool,
}

impl Default for GuidanceSpec {
    fn default() -> Self {
        Self {
            target_marker: true,
            target_distance: true,
            prompts: true,
        }
    }
}

impl GuidanceSpec {
    /// No guidance: an assessment.
    pub fn off() -> Self {
        Self {
            target_marker: false,
            target_distance: false,
            prompts: false,
        }
    }
}
