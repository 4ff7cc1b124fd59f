//! Commands applied at a step boundary: each [`Command`] to the hand, the imaging state, the
//! injector, the governor's fidelity, the thrombectomy's hands or the demonstration it
//! concerns, and one hand's [`Drive`] to its instrument's operator command.

use cathlab_physics::{Insertion, Twist};
use nalgebra::Point3;

use super::World;
use super::command::{Command, Drive, RETRIEVE_SPEED_M_S};
use super::exchange::Chosen;
use super::fidelity::{MAX_FIDELITY_LEVEL, fidelity_effort};
use super::hemo::LINKED_INJECTION_DELAY_S;
use super::snapshot::Mode;
use crate::error::{EngineError, Result};
use crate::metrics::EventKind;

impl World {
    /// Applies a command at the current step boundary; `seq` is the client's sequence number.
    /// A command that cannot apply (roadmap without a DSA run at this pose, injection without
    /// flow, a device index out of range) changes nothing and says why.
    pub fn apply(&mut self, seq: u64, command: &Command) -> Result<()> {
        let innermost = self.strand.len() - 1;
        self.cancel_exchange_if_pushed(command);
        if !self.operating
            && self.demonstration.is_some()
            && matches!(
                command,
                Command::PushVelocity(_)
                    | Command::PushTarget(_)
                    | Command::TwistRate(_)
                    | Command::TwistTarget(_)
                    | Command::Setpoints { .. }
                    | Command::Instrument { .. }
                    | Command::Exchange { .. }
                    | Command::ExchangeSpare { .. }
                    | Command::Load { .. }
                    | Command::LoadSpare { .. }
                    | Command::Unload
                    | Command::SelectDevice(_)
                    | Command::Reset
            )
        {
            self.demonstration = None;
            self.event(
                EventKind::Device,
                "demonstration ended: the trainee took over",
            );
        }
        match *command {
            Command::PushVelocity(v) => self.drive(innermost, Drive::PushVelocity(v))?,
            Command::PushTarget(x) => self.drive(innermost, Drive::PushTarget(x))?,
            Command::TwistRate(w) => self.drive(innermost, Drive::TwistRate(w))?,
            Command::TwistTarget(a) => self.drive(innermost, Drive::TwistTarget(a))?,
            Command::Setpoints {
                push_m_s,
                twist_rad_s,
            } => self.drive(
                innermost,
                Drive::Setpoints {
                    push_m_s,
                    twist_rad_s,
                },
            )?,
            Command::Instrument { index, drive } => {
                self.strand.check(index as usize, "instrument")?;
                self.drive(index as usize, drive)?;
            }
            Command::Exchange { index, catalogue } => {
                let (device, look, id) = self.chosen(Chosen::Catalogue(catalogue), "exchange")?;
                self.exchange(index, &device, look, id)?;
            }
            Command::ExchangeSpare { index, spare } => {
                let (device, look, id) = self.chosen(Chosen::Spare(spare), "exchange")?;
                self.exchange(index, &device, look, id)?;
            }
            Command::Load { catalogue } => {
                let (device, look, id) = self.chosen(Chosen::Catalogue(catalogue), "load")?;
                self.load(&device, look, id)?;
            }
            Command::LoadSpare { spare } => {
                let (device, look, id) = self.chosen(Chosen::Spare(spare), "load")?;
                self.load(&device, look, id)?;
            }
            Command::Unload => self.unload()?,
            Command::SelectDevice(_) if !self.assets.spec.stack.is_empty() => {
                return Err(EngineError::FailedPrecondition(
                    "a coaxial scene exchanges instruments (withdraw one to its hub, then \
                     exchange it); it has no devices to select"
                        .into(),
                ));
            }
            Command::SelectDevice(index) => {
                let index = index as usize;
                if index >= self.assets.devices.len() {
                    return Err(EngineError::InvalidArgument {
                        field: "select_device".into(),
                        reason: format!(
                            "{index} is not a device of this scene (it has {})",
                            self.assets.devices.len()
                        ),
                    });
                }
                self.restart_device(index)?;
                let name = self.assets.devices[index].0.name.clone();
                self.event(
                    EventKind::Device,
                    format!("device {index} ({name}) inserted"),
                );
            }
            Command::Fluoroscopy(on) => {
                if on != self.imaging.pedal {
                    self.imaging.pedal = on;
                    self.event(
                        EventKind::Imaging,
                        if on {
                            "fluoroscopy on"
                        } else {
                            "fluoroscopy off"
                        },
                    );
                }
            }
            Command::PulseRate(rate) => self.imaging.pulse_rate = rate,
            Command::Dsa(start) => {
                if start {
                    self.imaging.mode = Mode::Subtraction;
                    self.imaging.dsa_run += 1;
                    self.imaging.dsa_pose =
                        Some((self.imaging.primary_deg, self.imaging.secondary_deg));
                    self.metrics.dsa_runs += 1;
                    let run = self.imaging.dsa_run;
                    self.event(EventKind::Imaging, format!("DSA run {run} started"));
                    // The injector is linked to the run: it fires after the mask.
                    let at = self.metrics.procedure_time_s + LINKED_INJECTION_DELAY_S;
                    if let Some(hemo) = &mut self.hemo {
                        hemo.linked_at_s = Some(at);
                    }
                } else if self.imaging.mode == Mode::Subtraction {
                    if let Some(hemo) = &mut self.hemo {
                        hemo.linked_at_s = None;
                    }
                    self.imaging.mode = Mode::Fluoroscopy;
                    self.event(EventKind::Imaging, "DSA run ended");
                }
            }
            Command::Roadmap(on) => {
                if on {
                    let pose = (self.imaging.primary_deg, self.imaging.secondary_deg);
                    if self.imaging.dsa_pose != Some(pose) {
                        return Err(EngineError::FailedPrecondition(
                            "roadmap needs a DSA run at the current C-arm pose".into(),
                        ));
                    }
                    self.imaging.mode = Mode::Roadmap;
                    self.event(EventKind::Imaging, "roadmap on");
                } else if self.imaging.mode == Mode::Roadmap {
                    self.imaging.mode = Mode::Fluoroscopy;
                    self.event(EventKind::Imaging, "roadmap off");
                }
            }
            Command::CArm {
                primary_deg,
                secondary_deg,
            } => {
                self.imaging.primary_deg = primary_deg;
                self.imaging.secondary_deg = secondary_deg;
                if self.imaging.mode == Mode::Roadmap
                    && self.imaging.dsa_pose != Some((primary_deg, secondary_deg))
                {
                    self.imaging.mode = Mode::Fluoroscopy;
                    self.event(EventKind::Imaging, "roadmap off: the C-arm moved");
                }
            }
            Command::Inject {
                volume_ml,
                rate_ml_s,
            } => {
                let Some(hemo) = &mut self.hemo else {
                    return Err(EngineError::FailedPrecondition(
                        "this scene has no blood flow: contrast cannot be injected".into(),
                    ));
                };
                hemo.injection = Some((volume_ml * 1e-6, rate_ml_s * 1e-6));
                hemo.program = (volume_ml, rate_ml_s);
                // An injection by hand during a DSA run replaces the linked one.
                hemo.linked_at_s = None;
                self.update_injection()?;
                self.event(
                    EventKind::Contrast,
                    format!("{volume_ml:.1} mL of contrast at {rate_ml_s:.1} mL/s"),
                );
            }
            Command::Fidelity(level) => {
                let level = level.min(MAX_FIDELITY_LEVEL);
                if level != self.fidelity {
                    let (effort, _, what) = fidelity_effort(level);
                    self.strand.set_effort(effort)?;
                    let message = if level > self.fidelity {
                        format!(
                            "the server is overloaded: fidelity lowered to level {level} of \
                             {MAX_FIDELITY_LEVEL} ({what})"
                        )
                    } else {
                        format!("fidelity raised to level {level} ({what})")
                    };
                    self.fidelity = level;
                    self.event(EventKind::Overload, message);
                }
            }
            Command::Aspiration(on) => {
                let Some(procedure) = &mut self.procedure else {
                    return Err(EngineError::FailedPrecondition(
                        "the scene has no clot to aspirate".into(),
                    ));
                };
                procedure.set_aspiration(on);
                self.event(
                    EventKind::Thrombectomy,
                    if on { "suction on" } else { "suction off" },
                );
            }
            Command::DeployStent => {
                let (k, spec) = self.stent_instrument()?;
                let tip = |i: usize| self.strand.tip_position(i).map(Point3::from);
                let (Some(stent_tip), Some(mc_tip)) = (tip(k), tip(k - 1)) else {
                    return Err(EngineError::FailedPrecondition(
                        "the stent retriever is not in the patient".into(),
                    ));
                };
                let arc = |p: &Point3<f64>| {
                    crate::thrombectomy::route_arc(
                        &self.assets.route_samples,
                        crate::assets::ROUTE_SPACING_M,
                        p,
                    )
                };
                let stent_proximal = arc(&stent_tip) - spec.from_tip_m - spec.length_m;
                let back = arc(&mc_tip) - stent_proximal + 1e-3;
                if back <= 0.0 {
                    return Err(EngineError::FailedPrecondition(
                        "the stent is already unsheathed".into(),
                    ));
                }
                let target = self.strand.inserted_m(k - 1) - back;
                self.drive(k, Drive::PushVelocity(0.0))?;
                self.drive(k - 1, Drive::PushTarget(target))?;
                self.event(
                    EventKind::Thrombectomy,
                    format!(
                        "deploying: the microcatheter drawn back {:.1} mm over the held stent",
                        back * 1e3
                    ),
                );
            }
            Command::Demonstrate(on) => {
                if !on {
                    if self.demonstration.take().is_some() {
                        self.hold_all()?;
                        self.event(EventKind::Device, "demonstration stopped");
                    }
                } else if self.demonstration.is_none() {
                    self.demonstration = Some(self.scene_operator()?);
                    self.event(
                        EventKind::Device,
                        "demonstration: the scene's operator drives to the target",
                    );
                }
            }
            Command::RetrieveStent => {
                let (k, _) = self.stent_instrument()?;
                self.drive(k, Drive::PushVelocity(-RETRIEVE_SPEED_M_S))?;
                self.drive(k - 1, Drive::PushVelocity(-RETRIEVE_SPEED_M_S))?;
                self.event(
                    EventKind::Thrombectomy,
                    format!(
                        "retrieving: stent and microcatheter pulled back at {:.0} mm/s",
                        RETRIEVE_SPEED_M_S * 1e3
                    ),
                );
            }
            Command::Reset => {
                self.restart_device(self.active_device)?;
                // A new attempt: the target is to be reached again.
                self.metrics.operator_resets += 1;
                self.metrics.target_reached_at_s = None;
                self.metrics.attempt_started_at_s = self.metrics.procedure_time_s;
                self.event(EventKind::Reset, "scene reset: a new attempt");
            }
        }
        self.last_seq = seq;
        Ok(())
    }

    /// Applies `drive` to instrument `index` (checked).
    pub(super) fn drive(&mut self, index: usize, drive: Drive) -> Result<()> {
        let current = self.strand.command(index);
        let (insertion, twist) = match drive {
            Drive::PushVelocity(v) => (Insertion::Velocity(v), current.twist),
            Drive::PushTarget(x) => (Insertion::Target(x), current.twist),
            Drive::TwistRate(w) => (current.insertion, Twist::Rate(w)),
            Drive::TwistTarget(a) => (current.insertion, Twist::Target(a)),
            Drive::Setpoints {
                push_m_s,
                twist_rad_s,
            } => (Insertion::Velocity(push_m_s), Twist::Rate(twist_rad_s)),
        };
        self.strand
            .set_command(index, cathlab_physics::Command { insertion, twist })
    }

    /// The stack's stent retriever (its index, not the outermost) and its stent.
    fn stent_instrument(&self) -> Result<(usize, cathlab_physics::StentSpec)> {
        let catalogue = crate::scene::catalogue();
        self.hands
            .iter()
            .enumerate()
            .skip(1)
            .find_map(|(i, h)| {
                catalogue
                    .get(&h.catalogue_id)
                    .and_then(|e| e.stent)
                    .map(|s| (i, s))
            })
            .ok_or_else(|| {
                EngineError::FailedPrecondition(
                    "no stent retriever in the stack (exchange the microwire for one)".into(),
                )
            })
    }
}
