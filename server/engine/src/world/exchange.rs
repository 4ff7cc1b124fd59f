//! Exchanges, loads and unloads of a stack's instruments: the device chosen (a catalogue
//! entry or a spare), the instrument withdrawn to the hub of the one around it step by step
//! (the second stage of [`World::step`]), then replaced or taken out; a push cancels.

use cathlab_xray::DeviceAppearance;

use super::World;
use super::command::{Command, Drive};
use super::hand::{Hand, PendingExchange};
use crate::error::{EngineError, Result};
use crate::metrics::EventKind;

/// A device a client chose: an entry of the built-in catalogue or a spare of the scene.
#[derive(Debug, Clone, Copy)]
pub(super) enum Chosen {
    Catalogue(u32),
    Spare(u32),
}

impl World {
    /// An exchange under way: replaced once withdrawn (after the last step), else drawn on
    /// back.
    pub(super) fn advance_exchange(&mut self) -> Result<()> {
        if !self.finish_exchange()? {
            self.withdraw_for_exchange()?;
        }
        Ok(())
    }

    /// Exchanges stack instrument `index` for `device` (its look and the name it goes by):
    /// at once when it (and everything inside it) is withdrawn to the hub of the one around
    /// it; otherwise it is first drawn back there at the hand's top speed, step by step (the
    /// trainee sees it come out), and replaced when it arrives. A push on a withdrawing
    /// instrument cancels the exchange.
    pub(super) fn exchange(
        &mut self,
        index: u32,
        device: &cathlab_physics::Device,
        look: DeviceAppearance,
        id: String,
    ) -> Result<()> {
        let index = index as usize;
        self.strand.check(index, "exchange.instrument")?;
        let Some(stack) = self.strand.stack() else {
            return Err(EngineError::FailedPrecondition(
                "a one-device scene selects devices; only a coaxial stack exchanges them".into(),
            ));
        };
        stack
            .check_exchange(index, device)
            .map_err(|e| EngineError::FailedPrecondition(e.to_string()))?;
        let name = stack
            .device(index)
            .map(|d| d.name.clone())
            .unwrap_or_default();
        self.exchanging = Some(PendingExchange {
            index,
            replacement: Some((device.clone(), look, id.clone())),
        });
        if !self.finish_exchange()? {
            self.event(
                EventKind::Device,
                format!("instrument {index}: withdrawing {name} for an exchange with {id}"),
            );
        }
        Ok(())
    }

    /// Drives the instruments of a pending exchange back toward the hub (each step, as the
    /// hub of the one around each moves with it).
    fn withdraw_for_exchange(&mut self) -> Result<()> {
        let Some(pending) = &self.exchanging else {
            return Ok(());
        };
        let index = pending.index;
        for k in index..self.strand.len() {
            if let Some((lo, _)) = self.strand.stack().and_then(|s| s.inserted_range_m(k)) {
                self.drive(k, Drive::PushTarget(lo))?;
            }
        }
        Ok(())
    }

    /// Replaces the instrument of a pending exchange when it (and everything inside it) is
    /// at the hub; whether it did.
    fn finish_exchange(&mut self) -> Result<bool> {
        let Some(pending) = &self.exchanging else {
            return Ok(false);
        };
        let Some(stack) = self.strand.stack_mut() else {
            self.exchanging = None;
            return Ok(false);
        };
        // Asked each step of the withdrawal, without cloning the device or re-checking its fit.
        if stack.still_inserted(pending.index).is_some() {
            return Ok(false);
        }
        let index = pending.index;
        let Some((device, look, id)) = pending.replacement.clone() else {
            let device = stack
                .pop_instrument()
                .map_err(|e| EngineError::FailedPrecondition(e.to_string()))?;
            self.exchanging = None;
            let hand = self.hands.pop().map(|h| h.catalogue_id).unwrap_or_default();
            let was = if hand.is_empty() { device.name } else { hand };
            self.event(
                EventKind::Device,
                format!("instrument {index}: {was} taken out"),
            );
            return Ok(true);
        };
        stack
            .exchange(index, device.clone())
            .map_err(|e| EngineError::FailedPrecondition(e.to_string()))?;
        self.exchanging = None;
        let old = std::mem::replace(
            &mut self.hands[index],
            Hand::new(id.clone(), &device, look, &self.assets.spec),
        );
        let was = if old.catalogue_id.is_empty() {
            "the scene's device".to_owned()
        } else {
            old.catalogue_id
        };
        self.event(
            EventKind::Device,
            format!("instrument {index}: {was} exchanged for {id}"),
        );
        Ok(true)
    }

    /// The device a client chose for an exchange or a load (`what`, naming the field): a
    /// catalogue entry or a spare of the scene, with its look and the name it goes by.
    pub(super) fn chosen(
        &self,
        choice: Chosen,
        what: &str,
    ) -> Result<(cathlab_physics::Device, DeviceAppearance, String)> {
        match choice {
            Chosen::Catalogue(k) => {
                let entries = crate::scene::catalogue().entries();
                let entry =
                    entries
                        .get(k as usize)
                        .ok_or_else(|| EngineError::InvalidArgument {
                            field: format!("{what}.device"),
                            reason: format!(
                                "catalogue entry {k} does not exist (the catalogue has {})",
                                entries.len()
                            ),
                        })?;
                let look = crate::scene::appearance_of_entry(entry);
                Ok((entry.device.clone(), look, entry.id.clone()))
            }
            Chosen::Spare(k) => {
                let spares = &self.assets.spares;
                let (device, look) =
                    spares
                        .get(k as usize)
                        .ok_or_else(|| EngineError::InvalidArgument {
                            field: format!("{what}.spare"),
                            reason: format!(
                                "spare {k} does not exist (the scene has {})",
                                spares.len()
                            ),
                        })?;
                let label = self.assets.spec.spares[k as usize].label();
                Ok((device.clone(), look.clone(), label))
            }
        }
    }

    /// Loads `device` (its look and the name it goes by) into the stack's innermost
    /// instrument as the new innermost, its tip at that one's hub.
    pub(super) fn load(
        &mut self,
        device: &cathlab_physics::Device,
        look: DeviceAppearance,
        id: String,
    ) -> Result<()> {
        if self.exchanging.is_some() {
            return Err(EngineError::FailedPrecondition(
                "an exchange or unloading is under way; load once it is done".into(),
            ));
        }
        let Some(stack) = self.strand.stack_mut() else {
            return Err(EngineError::FailedPrecondition(
                "a one-device scene selects devices; only a coaxial stack loads them".into(),
            ));
        };
        let outer = stack
            .device(stack.len() - 1)
            .map(|d| d.name.clone())
            .unwrap_or_default();
        stack
            .push_instrument(device.clone())
            .map_err(|e| EngineError::FailedPrecondition(e.to_string()))?;
        let index = self.hands.len();
        self.hands
            .push(Hand::new(id.clone(), device, look, &self.assets.spec));
        self.event(
            EventKind::Device,
            format!("instrument {index}: {id} loaded into {outer}"),
        );
        Ok(())
    }

    /// Withdraws the innermost instrument to the hub of the one around it (step by step, as
    /// for an exchange) and takes it out; a push on it cancels.
    pub(super) fn unload(&mut self) -> Result<()> {
        if self.exchanging.is_some() {
            return Err(EngineError::FailedPrecondition(
                "an exchange or unloading is under way; take out once it is done".into(),
            ));
        }
        let Some(stack) = self.strand.stack() else {
            return Err(EngineError::FailedPrecondition(
                "a one-device scene has nothing to take out of a stack".into(),
            ));
        };
        let index = stack.len() - 1;
        if index == 0 {
            return Err(EngineError::FailedPrecondition(
                "the outermost instrument cannot be taken out".into(),
            ));
        }
        let name = stack
            .device(index)
            .map(|d| d.name.clone())
            .unwrap_or_default();
        self.exchanging = Some(PendingExchange {
            index,
            replacement: None,
        });
        if !self.finish_exchange()? {
            self.event(
                EventKind::Device,
                format!("instrument {index}: withdrawing {name} to take it out"),
            );
        }
        Ok(())
    }

    /// A push (a non-zero speed or a target) on an instrument being withdrawn for an exchange
    /// takes it back: the exchange is cancelled. Zero speeds (a still hand, a keep-alive) and
    /// twists do not.
    pub(super) fn cancel_exchange_if_pushed(&mut self, command: &Command) {
        let Some(pending) = &self.exchanging else {
            return;
        };
        let pushes = |drive: &Drive| match *drive {
            Drive::PushVelocity(v) => v != 0.0,
            Drive::PushTarget(_) => true,
            Drive::Setpoints { push_m_s, .. } => push_m_s != 0.0,
            Drive::TwistRate(_) | Drive::TwistTarget(_) => false,
        };
        let innermost = self.strand.len() - 1;
        let taken = match *command {
            Command::PushVelocity(v) => (v != 0.0).then_some(innermost),
            Command::PushTarget(_) => Some(innermost),
            Command::Setpoints { push_m_s, .. } => (push_m_s != 0.0).then_some(innermost),
            Command::Instrument { index, drive } if pushes(&drive) => Some(index as usize),
            _ => None,
        };
        if let Some(k) = taken.filter(|k| *k >= pending.index) {
            let index = pending.index;
            self.exchanging = None;
            self.event(
                EventKind::Device,
                format!("instrument {index}: exchange cancelled (instrument {k} pushed)"),
            );
        }
    }
}
