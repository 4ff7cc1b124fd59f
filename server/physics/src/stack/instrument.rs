//! The instruments of a stack: what is put in ([`InstrumentSpec`]), each one's state, whether
//! one fits the lumen of another, and the range its inserted length may take inside the one
//! around it.

use crate::device::Device;
use crate::error::{PhysicsError, Result};
use crate::navigation::{Command, NavigationSettings};
use crate::section::BeamProperties;

/// Most instruments in one stack.
pub const MAX_INSTRUMENTS: usize = 4;

/// An instrument to put in a stack: the device, where it starts and how fast the operator's
/// hand may move it.
#[derive(Debug, Clone, PartialEq)]
pub struct InstrumentSpec {
    /// The device.
    pub device: Device,
    /// Initial inserted length (m): how far the tip lies beyond the entry point. The
    /// outermost instrument needs at least one tip element; an inner one may start inside the
    /// one around it (any value down to that one's hub).
    pub inserted_m: f64,
    /// Initial twist at the entry point (rad).
    pub twist_rad: f64,
    /// Largest insertion speed either way (m/s).
    pub max_insertion_speed_m_s: f64,
    /// Largest twist rate either way (rad/s).
    pub max_twist_rate_rad_s: f64,
}

impl InstrumentSpec {
    /// `device` inserted `inserted_m` (m), untwisted, with the speed limits of `settings`.
    pub fn new(device: Device, inserted_m: f64, settings: &NavigationSettings) -> Self {
        Self {
            device,
            inserted_m,
            twist_rad: 0.0,
            max_insertion_speed_m_s: settings.max_insertion_speed_m_s,
            max_twist_rate_rad_s: settings.max_twist_rate_rad_s,
        }
    }
}

/// One instrument's state.
#[derive(Debug, Clone)]
pub(super) struct Instrument {
    pub(super) device: Device,
    pub(super) length_m: f64,
    /// Material coordinate where the distal shaped part starts (m), if any.
    pub(super) shaped_from_m: Option<f64>,
    /// Where the tip lies: how far beyond the entry point the strand places the instrument's
    /// material (m). The hand's inserted length unless the instrument slides inside the one
    /// around it ([`NavigationSettings::axial_slide`]).
    pub(super) inserted_m: f64,
    /// The hand's inserted length (m): where the tip would lie with the instrument unstrained
    /// between the hand and its exit from the one around it. Commands, ranges and the
    /// reports are in it.
    pub(super) hand_m: f64,
    /// With [`NavigationSettings::axial_slide`]: how far the material lags the hand (m,
    /// positive: compressed), the slack of its length inside the ones around it; zero
    /// otherwise.
    pub(super) lag_m: f64,
    pub(super) twist_rad: f64,
    pub(super) command: Command,
    pub(super) max_insertion_speed_m_s: f64,
    pub(super) max_twist_rate_rad_s: f64,
    /// Identifier of the node at this instrument's tip while the tip is inside the strand
    /// (neither withdrawn nor leading).
    pub(super) tip_node: Option<u64>,
    /// Axial load on the tip (N, along its tangent, positive forward), from the next step
    /// on: what a clot asks of a tip crossing it.
    pub(super) tip_load_n: f64,
}

impl Instrument {
    /// `device` inserted `inserted_m` (m) and twisted `twist_rad` (rad), its hand's speed
    /// limits (m/s, rad/s), unstrained and still.
    pub(super) fn new(
        device: Device,
        inserted_m: f64,
        twist_rad: f64,
        max_insertion_speed_m_s: f64,
        max_twist_rate_rad_s: f64,
    ) -> Self {
        Self {
            length_m: device.length_m(),
            shaped_from_m: device.shaped_from_m(),
            inserted_m,
            hand_m: inserted_m,
            lag_m: 0.0,
            twist_rad,
            command: Command::default(),
            max_insertion_speed_m_s,
            max_twist_rate_rad_s,
            tip_node: None,
            tip_load_n: 0.0,
            device,
        }
    }
}

/// Checks that `inner` fits the lumen of `outer`: its largest outer diameter is smaller than
/// the smallest inner diameter of `outer`.
pub fn check_fit(outer: &Device, inner: &Device) -> Result<()> {
    let lumen = outer
        .sections
        .iter()
        .map(|s| 2.0 * s.cross_section.inner_radius_m)
        .fold(f64::INFINITY, f64::min);
    let diameter = inner
        .sections
        .iter()
        .map(|s| 2.0 * s.cross_section.outer_radius_m)
        .fold(0.0, f64::max);
    if diameter < lumen {
        Ok(())
    } else {
        Err(PhysicsError::StackFit {
            inner: inner.name.clone(),
            outer: outer.name.clone(),
            inner_diameter_mm: diameter * 1e3,
            lumen_mm: lumen * 1e3,
        })
    }
}

/// The instrument whose tip leads (largest inserted length; the innermost of equals).
pub(super) fn leader(instruments: &[Instrument]) -> usize {
    let mut best = 0;
    for (k, i) in instruments.iter().enumerate() {
        if i.inserted_m >= instruments[best].inserted_m {
            best = k;
        }
    }
    best
}

/// Range of the inserted length (m) of an instrument of `length_m` inside `outer` (inserted
/// length and length of the instrument directly around it, m): from the hub of the one directly around it to
/// where its own hub meets that hub; for the outermost, one tip element to its length.
pub fn inserted_range(outer: Option<(f64, f64)>, length_m: f64, tip_element_m: f64) -> (f64, f64) {
    match outer {
        None => (tip_element_m, length_m),
        Some((inserted_m, outer_length_m)) => {
            let hub = inserted_m - outer_length_m;
            (hub, hub + length_m)
        }
    }
}

/// The hand's inserted length and the length (m) of the instrument around instrument
/// `index`.
pub(super) fn around(instruments: &[Instrument], index: usize) -> Option<(f64, f64)> {
    index
        .checked_sub(1)
        .map(|k| (instruments[k].hand_m, instruments[k].length_m))
}

/// Section properties of `instrument` at path coordinate `sigma`.
pub(super) fn properties_at(instrument: &Instrument, sigma: f64) -> BeamProperties {
    let m = instrument.length_m - instrument.inserted_m + sigma;
    instrument.device.section_at(m).0.beam_properties()
}
