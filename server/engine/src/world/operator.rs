//! The scene's scripted operator, stage by stage: when the scene has an access stage, the
//! stack brought up from the access to a branch, its wire taken out and the instruments that
//! lead on loaded; then the two-hand drive to the target.

use std::sync::Arc;

use cathlab_physics::two_hands::{Finish, TwoHands};

use super::{Command, EngineError, Result, World};

/// The scene's operator: a stage and the two hands that drive it.
pub(super) struct SceneOperator {
    stage: Stage,
    hands: TwoHands<'static>,
    /// The scene's vessel graph, cloned once for every stage's hands.
    graph: Arc<cathlab_anatomy::VesselGraph>,
}

/// Where the operator is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
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
}

impl World {
    /// The scene's scripted operator from where the stack is: the access stage while the
    /// stack is still the scene's own (same instruments), else the drive to the target.
    pub(super) fn scene_operator(&self) -> Result<SceneOperator> {
        let assets = &self.assets;
        let plan = assets.two_hand_plan()?.ok_or_else(|| {
            EngineError::FailedPrecondition("this scene has no two-hand autopilot".into())
        })?;
        if self.strand.stack().is_none() {
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
            Some(access) if self.strand.len() == assets.spec.stack.len() => {
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

    /// One decision of the scene's operator, its commands numbered from `seq`. False when it
    /// is done.
    pub(super) fn operate_scene(&mut self, op: &mut SceneOperator, seq: &mut u64) -> Result<bool> {
        loop {
            match op.stage {
                Stage::Access => {
                    if self.operate(&mut op.hands, seq)? {
                        return Ok(true);
                    }
                    if op.hands.stalled() {
                        return Ok(false); // short of the access branch: no swap
                    }
                    op.stage = Stage::Swap {
                        unloaded: 0,
                        loaded: 0,
                    };
                }
                Stage::Swap { unloaded, loaded } => {
                    // Each instrument is drawn back step by step until it is out.
                    if self.exchanging.is_some() {
                        return Ok(true);
                    }
                    let access = self
                        .assets
                        .spec
                        .autopilot
                        .as_ref()
                        .and_then(|a| a.access.clone())
                        .ok_or_else(|| {
                            EngineError::FailedPrecondition("the scene has no access stage".into())
                        })?;
                    if unloaded < access.unload {
                        self.hold_all()?;
                        self.apply(*seq, &Command::Unload)?;
                        *seq += 1;
                        op.stage = Stage::Swap {
                            unloaded: unloaded + 1,
                            loaded,
                        };
                        return Ok(true);
                    }
                    if let Some(id) = access.load.get(loaded) {
                        let entries = crate::scene::catalogue().entries();
                        let catalogue =
                            entries.iter().position(|e| e.id == *id).ok_or_else(|| {
                                EngineError::FailedPrecondition(format!(
                                    "{id} is not in the catalogue"
                                ))
                            })?;
                        self.apply(
                            *seq,
                            &Command::Load {
                                catalogue: catalogue as u32,
                            },
                        )?;
                        *seq += 1;
                        op.stage = Stage::Swap {
                            unloaded,
                            loaded: loaded + 1,
                        };
                        continue;
                    }
                    op.stage = Stage::Advance;
                }
                Stage::Advance => {
                    let n = self.strand.len();
                    let loaded = self
                        .assets
                        .spec
                        .autopilot
                        .as_ref()
                        .and_then(|a| a.access.as_ref())
                        .map_or(0, |a| a.load.len());
                    let around = n.saturating_sub(loaded + 1);
                    let tip = self.strand.inserted_m(around);
                    let behind = (around + 1..n).any(|k| self.strand.inserted_m(k) < tip - 0.5e-3);
                    if behind {
                        for k in around + 1..n {
                            self.apply(
                                *seq,
                                &Command::Instrument {
                                    index: k as u32,
                                    drive: super::Drive::PushTarget(tip),
                                },
                            )?;
                            *seq += 1;
                        }
                        return Ok(true);
                    }
                    let assets = &self.assets;
                    let plan = assets.two_hand_plan()?.ok_or_else(|| {
                        EngineError::FailedPrecondition(
                            "this scene has no two-hand autopilot".into(),
                        )
                    })?;
                    op.hands = TwoHands::shared(
                        op.graph.clone(),
                        assets.route.clone(),
                        assets.spec.start.along_route_mm * 1e-3,
                        plan,
                    )?;
                    op.stage = Stage::Target;
                }
                Stage::Target => return self.operate(&mut op.hands, seq),
            }
        }
    }
}
