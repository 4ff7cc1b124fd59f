//! Changing a stack's instruments: loading a new innermost one at the hub of the one around
//! it, removing it once withdrawn, and exchanging an inner instrument for another device.

use super::instrument::{Instrument, MAX_INSTRUMENTS, around, check_fit, inserted_range};
use super::state::Stack;
use crate::device::Device;
use crate::error::{PhysicsError, Result};
use crate::wall::Wall;

impl<W: Wall> Stack<W> {
    /// Adds `device` as the new innermost instrument, its tip at the hub of the one around it
    /// (to be pushed in), as an operator loads a microwire into a microcatheter.
    pub fn push_instrument(&mut self, device: Device) -> Result<()> {
        self.stillness.wake();
        if self.instruments.len() >= MAX_INSTRUMENTS {
            return Err(PhysicsError::OutOfRange {
                what: "number of instruments in a stack".into(),
                range: "1 to 4",
                value: (self.instruments.len() + 1) as f64,
            });
        }
        device.validate()?;
        let outer = self.instruments.last().expect("a stack has an instrument");
        check_fit(&outer.device, &device)?;
        let (lo, _) = inserted_range(
            Some((outer.hand_m, outer.length_m)),
            device.length_m(),
            self.settings.tip_element_m,
        );
        let (speed, rate) = (outer.max_insertion_speed_m_s, outer.max_twist_rate_rad_s);
        self.instruments
            .push(Instrument::new(device, lo, 0.0, speed, rate));
        Ok(())
    }

    /// Removes the innermost instrument (not the only one), which must be withdrawn to the hub
    /// of the one around it; returns its device.
    pub fn pop_instrument(&mut self) -> Result<Device> {
        self.stillness.wake();
        let index = self.instruments.len() - 1;
        if index == 0 {
            return Err(PhysicsError::Stack(
                "the outermost instrument cannot be removed".into(),
            ));
        }
        let instrument = &self.instruments[index];
        let (lo, _) = inserted_range(
            around(&self.instruments, index),
            instrument.length_m,
            self.settings.tip_element_m,
        );
        if instrument.hand_m > lo + 1e-12 {
            return Err(PhysicsError::Stack(format!(
                "instrument {index} \"{}\" is still inserted {:.1} mm beyond the hub of the one around it; withdraw it before removing it",
                instrument.device.name,
                (instrument.hand_m - lo) * 1e3
            )));
        }
        Ok(self.instruments.pop().expect("checked above").device)
    }

    /// Whether instrument `index` may be exchanged for `device` once withdrawn: not the
    /// outermost, a valid device that fits the one around it and the one inside it.
    pub fn check_exchange(&self, index: usize, device: &Device) -> Result<()> {
        self.check_index(index)?;
        if index == 0 {
            return Err(PhysicsError::Stack(
                "the outermost instrument cannot be exchanged".into(),
            ));
        }
        device.validate()?;
        check_fit(&self.instruments[index - 1].device, device)?;
        if let Some(inner) = self.instruments.get(index + 1) {
            check_fit(device, &inner.device)?;
        }
        Ok(())
    }

    /// The first instrument from `index` inward still inserted beyond the hub of the one
    /// around it, and by how much (m); `None` when all are withdrawn (an exchange may go on).
    pub fn still_inserted(&self, index: usize) -> Option<(usize, f64)> {
        self.instruments
            .iter()
            .enumerate()
            .skip(index)
            .find_map(|(k, instrument)| {
                let (lo, _) = inserted_range(
                    around(&self.instruments, k),
                    instrument.length_m,
                    self.settings.tip_element_m,
                );
                (instrument.hand_m > lo + 1e-12).then_some((k, instrument.hand_m - lo))
            })
    }

    /// Replaces instrument `index` (not the outermost) by `device`, as an operator exchanges a
    /// wire: allowed only while it, and everything inside it, is withdrawn to the hub of the
    /// instrument around it. The new device starts there, untwisted.
    pub fn exchange(&mut self, index: usize, device: Device) -> Result<()> {
        self.stillness.wake();
        self.check_exchange(index, &device)?;
        if let Some((k, beyond_m)) = self.still_inserted(index) {
            return Err(PhysicsError::Stack(format!(
                "instrument {k} \"{}\" is still inserted {:.1} mm beyond the hub of the one around it; withdraw it before exchanging",
                self.instruments[k].device.name,
                beyond_m * 1e3
            )));
        }
        let (lo, _) = inserted_range(
            around(&self.instruments, index),
            device.length_m(),
            self.settings.tip_element_m,
        );
        let old = &self.instruments[index];
        self.instruments[index] = Instrument::new(
            device,
            lo,
            0.0,
            old.max_insertion_speed_m_s,
            old.max_twist_rate_rad_s,
        );
        Ok(())
    }
}
