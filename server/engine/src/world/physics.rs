//! The physics stage of a step: each instrument's operator command held back where a limit
//! stops its push (the hand's force, the device's buckling load or length, the governor's
//! speed cap), the strand stepped, and a diverged step (an error, a non-finite tip, a tip
//! or any node of any instrument through the wall) reset to the device's start, reported and
//! counted.

use cathlab_physics::Insertion;
use nalgebra::Point3;

use super::World;
use super::fidelity::fidelity_effort;
use super::hand::{LIMIT_REARM_S, PushLimit, start_hands};
use super::tips::{MAX_ESCAPE_M, tracked_tip};
use crate::error::Result;
use crate::metrics::EventKind;
use crate::strand::Strand;

impl World {
    /// Steps the strand with every hand's command within its limits (the operators' commands
    /// are put back after the step); a diverged step puts the device back at its start,
    /// reports it and counts it, and the world stays usable.
    pub(super) fn step_physics(&mut self, dt: f64) -> Result<()> {
        let operators: Vec<cathlab_physics::Command> = (0..self.strand.len())
            .map(|i| self.strand.command(i))
            .collect();
        let mut limited = Vec::with_capacity(operators.len());
        for (i, operator) in operators.iter().enumerate() {
            let command = self.limited_command(i, *operator, dt);
            if let Some(command) = command {
                self.strand.set_command(i, command)?;
            }
            limited.push(command.is_some());
        }
        let outcome = self.strand.step();
        for (i, operator) in operators.iter().enumerate() {
            if limited[i] {
                self.strand.set_command(i, *operator)?;
            }
        }
        let diverged = match outcome {
            Ok(()) => {
                let tip = self.strand.leading_tip();
                let escaped = self
                    .strand
                    .wall()
                    .0
                    .lumen
                    .query(&Point3::from(tip))
                    .signed_distance
                    > MAX_ESCAPE_M;
                if !tip.iter().all(|v| v.is_finite()) {
                    Some("non-finite tip position".to_owned())
                } else if escaped {
                    Some("the tip left the vessel".to_owned())
                } else {
                    // Every node of every instrument, with its own outer radius.
                    let depth = self.strand.max_penetration_m();
                    if depth.is_nan() || depth > MAX_ESCAPE_M {
                        Some(format!("a node passed the wall by {:.1} mm", depth * 1e3))
                    } else {
                        self.metrics.deepest_penetration_m =
                            self.metrics.deepest_penetration_m.max(depth);
                        None
                    }
                }
            }
            Err(e) => Some(e.to_string()),
        };
        if let Some(reason) = diverged {
            self.metrics.divergence_resets += 1;
            self.restart_device(self.active_device)?;
            self.event(
                EventKind::Divergence,
                format!("physics diverged ({reason}); the device was put back at its start"),
            );
        }
        Ok(())
    }

    /// The command this step runs instead of the operator's for instrument `index` when a
    /// limit holds its push back (None: the operator's). The force limit looks at the last
    /// step's proximal reaction: a push (or a pull) that met it holds the instrument where it
    /// is (the hand pushes or pulls no harder), so it moves only as fast as the force allows.
    /// Reports each new hold once.
    fn limited_command(
        &mut self,
        index: usize,
        operator: cathlab_physics::Command,
        dt: f64,
    ) -> Option<cathlab_physics::Command> {
        let inserted = self.strand.inserted_m(index);
        let advance = match operator.insertion {
            Insertion::Velocity(v) => v * dt,
            Insertion::Target(x) => x - inserted,
        };
        let hand = &self.hands[index];
        let force = hand.reaction.axial_force_n;
        let limits = hand.limits;
        let cap = fidelity_effort(self.fidelity).1;
        let pulled_too_hard = advance < 0.0 && -force >= limits.pull_force_n;
        let (limit, insertion) = if pulled_too_hard {
            (PushLimit::Force, Some(Insertion::Velocity(0.0)))
        } else if advance <= 0.0 {
            (PushLimit::None, None)
        } else if inserted + advance > limits.max_inserted_m {
            (
                PushLimit::Length,
                Some(Insertion::Target(limits.max_inserted_m.max(inserted))),
            )
        } else if force >= limits.force_n {
            (PushLimit::Force, Some(Insertion::Velocity(0.0)))
        } else if let Some(cap) = cap
            && advance > cap * dt
        {
            (PushLimit::None, Some(Insertion::Velocity(cap)))
        } else {
            (PushLimit::None, None)
        };
        let now = self.metrics.procedure_time_s;
        let hand = &mut self.hands[index];
        let mut report = None;
        if limit == PushLimit::None {
            if hand.push_limit != PushLimit::None {
                hand.push_free_since_s = now;
            }
            if now - hand.push_free_since_s >= LIMIT_REARM_S {
                hand.limit_armed = true;
            }
        } else if hand.limit_armed {
            hand.limit_armed = false;
            report = Some(limit);
        }
        hand.push_limit = limit;
        if let Some(limit) = report {
            let name = self
                .strand
                .device(index)
                .map_or_else(String::new, |d| d.name.clone());
            let message = match limit {
                PushLimit::Force if pulled_too_hard => format!(
                    "pull held at {:.1} N: the hand's limit is {:.0} N",
                    -force, limits.pull_force_n
                ),
                PushLimit::Force if limits.buckling => format!(
                    "push held at {force:.1} N: the {name} buckles outside the sheath at {:.1} N",
                    limits.force_n
                ),
                PushLimit::Force => format!(
                    "push held at {force:.1} N: the hand's limit is {:.0} N",
                    limits.force_n
                ),
                _ => format!(
                    "the {name} is in to its hub: {:.0} mm inserted, {:.0} mm outside",
                    limits.max_inserted_m * 1e3,
                    self.assets.spec.limits.outside_mm
                ),
            };
            self.event(EventKind::Limit, message);
        }
        insertion.map(|insertion| cathlab_physics::Command {
            insertion,
            twist: operator.twist,
        })
    }

    /// Back to the scene's start with device `index` of a one-device scene (a stack scene: its
    /// stack), the hands afresh; an injection under way stops.
    pub(super) fn restart_device(&mut self, index: usize) -> Result<()> {
        self.strand = Strand::start(&self.assets, index)?;
        self.exchanging = None;
        self.active_device = index;
        self.hands = start_hands(&self.assets, index);
        self.previous_instruments.clear();
        self.strand.set_effort(fidelity_effort(self.fidelity).0)?;
        self.previous_tip = tracked_tip(&self.assets, &self.strand);
        if let Some(hemo) = &mut self.hemo
            && hemo.injection.is_some()
        {
            hemo.injection = None;
            self.update_injection()?;
        }
        Ok(())
    }
}
