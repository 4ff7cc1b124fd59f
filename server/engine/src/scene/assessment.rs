//! The scene's `[assessment]`: how its sessions are assessed (phases, error thresholds,
//! expert benchmark), and its checks.

use serde::{Deserialize, Serialize};

use super::field::scene_error;
use crate::error::Result;

/// How a scene's sessions are assessed (see `docs/assessment.md`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AssessmentSpec {
    /// The procedure's phases in order; none: one phase per vessel of the route, then "at
    /// target".
    pub phases: Vec<cathlab_assessment::PhaseSpec>,
    /// Where errors begin.
    pub errors: cathlab_assessment::ErrorThresholds,
    /// How far from the expert values still passes.
    pub benchmark: cathlab_assessment::BenchmarkSpec,
    /// The expert values by metric key, from the scripted expert run
    /// (`cargo run --release -p cathlab-engine --example expert_benchmark -- SCENE`).
    pub expert: std::collections::BTreeMap<String, f64>,
}

impl AssessmentSpec {
    /// Checks the phases, thresholds and benchmark, and that every expert value is finite.
    pub(super) fn validate(&self) -> Result<()> {
        let a = self;
        a.phases
            .iter()
            .try_for_each(|p| p.validate())
            .and_then(|()| a.errors.validate())
            .and_then(|()| a.benchmark.validate())
            .map_err(|e| scene_error("assessment", e.to_string()))?;
        if let Some((key, value)) = a.expert.iter().find(|(_, v)| !v.is_finite()) {
            return Err(scene_error(
                "assessment.expert",
                format!("`{key}` is {value}, must be finite"),
            ));
        }
        Ok(())
    }
}
