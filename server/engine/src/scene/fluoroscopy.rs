//! The scene's `[fluoroscopy]`: pulse rate, exposure, image processing and noise, and its
//! checks.

use cathlab_xray::FluoroscopeSettings;
use serde::{Deserialize, Serialize};

use super::field::{range, scene_error, yes};
use crate::error::Result;

/// Fluoroscopy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FluoroscopySpec {
    /// Pulses per second: 7.5, 15 or 30.
    #[serde(default = "default_pulse_rate")]
    pub pulse_rate: f64,
    /// Mean quanta per pixel with nothing in the beam, when exposure control is off.
    #[serde(default = "default_photons")]
    pub photons_per_pixel: f64,
    /// Automatic exposure control: each mode's detector dose behind the patient (0.03 µGy a
    /// fluoroscopy pulse, 2.5 µGy a DSA frame) sets the quanta; off, `photons_per_pixel`.
    #[serde(default = "yes")]
    pub automatic_exposure: bool,
    /// Recursive filter weight of live images, 0 < α ≤ 1 (1 is off).
    #[serde(default = "default_recursive_weight")]
    pub recursive_weight: f64,
    /// Exposures averaged into a DSA run's mask (1–16).
    #[serde(default = "default_mask_frames")]
    pub dsa_mask_frames: u32,
    /// Scatter-to-primary ratio of the patient before the anti-scatter grid (a 10:1 grid:
    /// primary 0.7, scatter 0.1 transmitted); 0 is primary radiation only.
    #[serde(default = "default_scatter_to_primary")]
    pub scatter_to_primary: f64,
    /// Edge enhancement of live images (unsharp mask, σ 2 px): how much of the difference is
    /// added back; 0 is off.
    #[serde(default = "default_edge_enhancement")]
    pub edge_enhancement: f64,
    /// Quantum noise.
    #[serde(default = "yes")]
    pub noise: bool,
    /// Noise seed.
    #[serde(default = "default_seed")]
    pub seed: u64,
}

fn default_pulse_rate() -> f64 {
    15.0
}
fn default_photons() -> f64 {
    2000.0
}
fn default_recursive_weight() -> f64 {
    FluoroscopeSettings::angio_suite().recursive_weight
}
fn default_mask_frames() -> u32 {
    FluoroscopeSettings::angio_suite().mask_frames
}
fn default_scatter_to_primary() -> f64 {
    FluoroscopeSettings::angio_suite()
        .scatter
        .map_or(0.0, |s| s.scatter_to_primary)
}
fn default_edge_enhancement() -> f64 {
    FluoroscopeSettings::angio_suite()
        .edge_enhancement
        .map_or(0.0, |e| e.amount)
}
fn default_seed() -> u64 {
    1
}

impl Default for FluoroscopySpec {
    fn default() -> Self {
        Self {
            pulse_rate: default_pulse_rate(),
            photons_per_pixel: default_photons(),
            automatic_exposure: true,
            recursive_weight: default_recursive_weight(),
            dsa_mask_frames: default_mask_frames(),
            scatter_to_primary: default_scatter_to_primary(),
            edge_enhancement: default_edge_enhancement(),
            noise: true,
            seed: default_seed(),
        }
    }
}

impl FluoroscopySpec {
    /// Checks the pulse rate (7.5, 15 or 30), the quanta, the filter, the mask and the
    /// image processing.
    pub(super) fn validate(&self) -> Result<()> {
        let f = self;
        if ![7.5, 15.0, 30.0].contains(&f.pulse_rate) {
            return Err(scene_error(
                "fluoroscopy.pulse_rate",
                format!("{} is not one of 7.5, 15, 30", f.pulse_rate),
            ));
        }
        range(
            "fluoroscopy.photons_per_pixel",
            f.photons_per_pixel,
            1.0,
            1e7,
        )?;
        range(
            "fluoroscopy.recursive_weight",
            f.recursive_weight,
            0.05,
            1.0,
        )?;
        range(
            "fluoroscopy.dsa_mask_frames",
            f64::from(f.dsa_mask_frames),
            1.0,
            16.0,
        )?;
        range(
            "fluoroscopy.scatter_to_primary",
            f.scatter_to_primary,
            0.0,
            10.0,
        )?;
        range("fluoroscopy.edge_enhancement", f.edge_enhancement, 0.0, 3.0)?;
        Ok(())
    }
}
