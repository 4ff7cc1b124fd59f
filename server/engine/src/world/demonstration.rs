//! Scripted operators driving the world as a trainee would: the scene's two-hand operator
//! while it demonstrates (its decision taken before each step, the first stage of
//! [`World::step`]), and the drivers that follow the one-device autopilot or the two-hand
//! operator to the target, applying their commands as recorded ones.

use cathlab_physics::two_hands::TwoHands;
use cathlab_physics::{Insertion, Twist};

use super::World;
use super::command::{Command, Drive};
use super::operator::{SceneOperator, Stage};
use crate::error::{EngineError, Result};
use crate::metrics::EventKind;

impl World {
    /// The demonstration's next decision, before a step; ends it at the target.
    pub(super) fn demonstrate(&mut self) -> Result<()> {
        let Some(mut hands) = self.demonstration.take() else {
            return Ok(());
        };
        let done = if self.metrics.target_reached_at_s.is_some() {
            true
        } else {
            // Its commands carry the last client sequence number, which they leave as it is.
            let keep = self.last_seq;
            let mut seq = keep;
            self.operating = true;
            let going = self.operate_scene(&mut hands, &mut seq);
            self.operating = false;
            self.last_seq = keep;
            !going?
        };
        if done {
            self.hold_all()?;
            if hands.stalled() && self.metrics.target_reached_at_s.is_none() {
                self.event(
                    EventKind::Device,
                    "demonstration stopped short of the target: the leading instrument \
                     stalled (pushed in without getting further) and every hand holds",
                );
            } else {
                self.event(EventKind::Device, "demonstration done: every hand holds");
            }
        } else {
            self.demonstration = Some(hands);
        }
        Ok(())
    }

    /// The scene's scripted operator from where the stack is (see [`SceneOperator::start`]).
    pub(super) fn scene_operator(&self) -> Result<SceneOperator> {
        SceneOperator::start(&self.assets, &self.strand)
    }

    /// One decision of the scene's operator, its commands numbered from `seq`. False when it
    /// is done.
    fn operate_scene(&mut self, op: &mut SceneOperator, seq: &mut u64) -> Result<bool> {
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
                                    drive: Drive::PushTarget(tip),
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

    /// One decision of the operator `hands`, applied as commands numbered from `seq`
    /// (exchanges at once, then the next decision). False when it is done.
    fn operate(
        &mut self,
        hands: &mut cathlab_physics::two_hands::TwoHands<'static>,
        seq: &mut u64,
    ) -> Result<bool> {
        use cathlab_physics::two_hands::TwoHandAction;
        loop {
            let Some(stack) = self.strand.stack() else {
                return Err(EngineError::FailedPrecondition(
                    "the two-hand autopilot drives a stack".into(),
                ));
            };
            match hands.next(stack)? {
                TwoHandAction::Done => return Ok(false),
                TwoHandAction::Drive(commands) => {
                    for (index, command) in commands {
                        let push = match command.insertion {
                            Insertion::Velocity(v) => Drive::PushVelocity(v),
                            Insertion::Target(x) => Drive::PushTarget(x),
                        };
                        let twist = match command.twist {
                            Twist::Rate(w) => Drive::TwistRate(w),
                            Twist::Target(a) => Drive::TwistTarget(a),
                        };
                        for drive in [push, twist] {
                            let index = index as u32;
                            self.apply(*seq, &Command::Instrument { index, drive })?;
                            *seq += 1;
                        }
                    }
                    return Ok(true);
                }
                TwoHandAction::Exchange(index, device) => {
                    let index = index as u32;
                    let spare = self.assets.spares.iter().position(|(d, _)| *d == device);
                    let catalogue = crate::scene::catalogue()
                        .entries()
                        .iter()
                        .position(|e| e.device == device);
                    let command = match (spare, catalogue) {
                        (Some(spare), _) => Command::ExchangeSpare {
                            index,
                            spare: spare as u32,
                        },
                        (None, Some(catalogue)) => Command::Exchange {
                            index,
                            catalogue: catalogue as u32,
                        },
                        (None, None) => {
                            return Err(EngineError::FailedPrecondition(format!(
                                "the autopilot's new wire \"{}\" is neither a spare nor in \
                                 the catalogue",
                                device.name
                            )));
                        }
                    };
                    self.apply(*seq, &command)?;
                    *seq += 1;
                }
                TwoHandAction::Replace(_) => {
                    return Err(EngineError::FailedPrecondition(
                        "the scene's autopilot adds no instruments".into(),
                    ));
                }
            }
        }
    }

    /// Every hand holds still.
    pub(super) fn hold_all(&mut self) -> Result<()> {
        for i in 0..self.strand.len() {
            self.drive(i, Drive::PushVelocity(0.0))?;
            self.drive(i, Drive::TwistRate(0.0))?;
        }
        Ok(())
    }

    /// Drives the world with `pilot` (a scripted trainee) for at most `max_steps` steps; its
    /// commands are applied as recorded commands numbered from `first_seq`. Returns the step
    /// index at which the autopilot found the target reached, or `None` if it did not.
    pub fn follow_autopilot(
        &mut self,
        pilot: &mut cathlab_physics::autopilot::Autopilot,
        max_steps: usize,
        first_seq: u64,
    ) -> Result<Option<u64>> {
        use cathlab_physics::autopilot::AutopilotPhase;
        let mut seq = first_seq;
        for _ in 0..max_steps {
            let Some(navigation) = self.strand.navigation() else {
                return Err(EngineError::FailedPrecondition(
                    "the one-device autopilot drives a one-device scene; a stack has two hands"
                        .into(),
                ));
            };
            let command = pilot.command(navigation);
            if pilot.phase() == AutopilotPhase::Reached {
                return Ok(Some(self.step_index()));
            }
            let [push, twist] = Command::from_operator(&command);
            self.apply(seq, &push)?;
            self.apply(seq + 1, &twist)?;
            seq += 2;
            self.step()?;
        }
        Ok(None)
    }

    /// Drives a stack scene with its scripted two-hand operator (the scene's `autopilot`) for
    /// at most `max_steps` steps; the hands' commands are applied as recorded commands
    /// numbered from `first_seq` (a wire exchange as an exchange for the scene's device or
    /// its catalogue entry). Returns the step at which the target was reached, or `None` if
    /// it was not.
    pub fn follow_two_hands(&mut self, max_steps: usize, first_seq: u64) -> Result<Option<u64>> {
        let mut hands = self.scene_operator()?;
        let mut seq = first_seq;
        for _ in 0..max_steps {
            if self.metrics.target_reached_at_s.is_some() {
                return Ok(Some(self.step));
            }
            if !self.operate_scene(&mut hands, &mut seq)? {
                break;
            }
            self.step()?;
        }
        Ok(self.metrics.target_reached_at_s.map(|_| self.step))
    }
}
