//! The scene's scripted operator, stage by stage: when the scene has an access stage, the
//! stack brought up from the access to a branch, its wire taken out and the instruments that
//! lead on loaded; then the two-hand drive to the target. This module holds the operator and
//! where it starts; the world's demonstration (`demonstration.rs`) runs its stages.

use std::sync::Arc;

use cathlab_physics::two_hands::{Finish, TwoHands};

use crate::assets::SceneAssets;
use crate::error::{EngineError, Result};
use crate::strand::Strand;

/// The scene's operator: a stage and the two hands that drive it.
pub(super) struct SceneOperator {
    pub(super) stage: Stage,
    pub(super) hands: TwoHands<'static>,
    /// The scene's vessel graph, cloned once for every stage's hands.
    pub(super) graph: Arc<cathlab_anatomy::VesselGraph>,
}

/// Where the operator is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Stage {
    /// Up from the access to the access branch.
    Access,
    /// `unloaded` of the instruments to take out asked out (each withdrawn step by step
    /// before the next), then `loaded` of the devices to load are in.
    Swap { unloaded: usize, loaded: usize },
    /// The loaded instruments run up inside the catheter around them to its tip.
    Advance,
    /// The two-hand drive to the scene's target.
    Target,
}

impl SceneOperator {
    /// Whether the operator gave up short of the target (the leading wire stalled; the
    /// hands of a stage that finished never did).
    pub(super) fn stalled(&self) -> bool {
        self.hands.stalled()
    }

    /// The scene's scripted operator from where `strand` is: the access stage while the
    /// stack is still the scene's own (same instruments), else the drive to the target.
    pub(super) fn start(assets: &SceneAssets, strand: &Strand) -> Result<SceneOperator> {
        let plan = assets.two_hand_plan()?.ok_or_else(|| {
            EngineError::FailedPrecondition("this scene has no two-hand autopilot".into())
        })?;
        if strand.stack().is_none() {
            return Err(EngineError::FailedPrecondition(
                "the two-hand autopilot drives a stack".into(),
            ));
        }
        let graph = Arc::new(assets.anatomy.graph.clone());
        let start = assets.spec.start.along_route_mm * 1e-3;
        let access = assets
            .spec
            .autopilot
            .as_ref()
            .and_then(|a| a.access.as_ref());
        match access {
            Some(access) if strand.len() == assets.spec.stack.len() => {
                // The route up to (and into) the access branch.
                let mut path = assets.route.clone();
                let at = path
                    .legs
                    .iter()
                    .position(|leg| assets.anatomy.graph.branches[leg.branch].name == access.branch)
                    .ok_or_else(|| {
                        EngineError::FailedPrecondition(format!(
                            "{} is not on the scene's route",
                            access.branch
                        ))
                    })?;
                path.legs.truncate(at + 1);
                path.length = path
                    .legs
                    .iter()
                    .map(|l| (l.to_arc - l.from_arc).abs())
                    .sum();
                let mut plan = plan;
                plan.autopilot.reach_m = access.into_mm * 1e-3;
                plan.autopilot.lookahead_m = access.lookahead_mm * 1e-3;
                plan.catheter_lag_m = access.catheter_lag_mm * 1e-3;
                plan.finish = Finish::TrackCatheter;
                Ok(SceneOperator {
                    stage: Stage::Access,
                    hands: TwoHands::shared(graph.clone(), path, start, plan)?,
                    graph,
                })
            }
            _ => Ok(SceneOperator {
                stage: Stage::Target,
                hands: TwoHands::shared(graph.clone(), assets.route.clone(), start, plan)?,
                graph,
            }),
        }
    }
}
