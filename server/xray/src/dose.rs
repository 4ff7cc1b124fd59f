//! Patient dose of the imaging chain: the detector air kerma each mode aims for (automatic
//! exposure control, as an angio system's generator sets its tube output from the signal
//! behind the patient), the quanta per pixel that gives, and the reference air kerma and
//! kerma–area product (DAP) accumulated exposure by exposure, as the system's dose display
//! shows them.
//!
//! Air kerma from photon fluence: `K = Φ · E · (μen/ρ)air`, summed over the beam's energy
//! bins (their weights are photon fractions). `(μen/ρ)air` is NIST's table (Hubbell &
//! Seltzer, NIST Standard Reference Database 126), interpolated log–log.

use crate::error::{Result, XrayError};
use crate::geometry::CArm;
use crate::spectrum::Spectrum;

/// Distance from the isocenter towards the source of the interventional reference point (m),
/// where the reference air kerma is stated (IEC 60601-2-43).
pub const REFERENCE_POINT_FROM_ISOCENTER_M: f64 = 0.15;

/// One joule per kiloelectronvolt.
const JOULES_PER_KEV: f64 = 1.602_176_634e-16;

/// Mass energy-absorption coefficient of dry air (NIST SRD 126): (keV, cm²/g).
const AIR_MU_EN_OVER_RHO: [(f64, f64); 12] = [
    (10.0, 4.742),
    (15.0, 1.334),
    (20.0, 0.5389),
    (30.0, 0.1537),
    (40.0, 0.06833),
    (50.0, 0.04098),
    (60.0, 0.03041),
    (80.0, 0.02407),
    (100.0, 0.02325),
    (150.0, 0.02496),
    (200.0, 0.02672),
    (300.0, 0.02872),
];

/// Mass energy-absorption coefficient of air at `kev` (m²/kg), interpolated log–log in
/// NIST's table (10–300 keV; clamped outside).
pub fn air_mass_energy_absorption_m2_per_kg(kev: f64) -> f64 {
    let table = &AIR_MU_EN_OVER_RHO;
    let kev = kev.clamp(table[0].0, table[table.len() - 1].0);
    let i = table
        .windows(2)
        .position(|w| kev <= w[1].0)
        .unwrap_or(table.len() - 2);
    let ((e0, m0), (e1, m1)) = (table[i], table[i + 1]);
    let t = (kev / e0).ln() / (e1 / e0).ln();
    // cm²/g → m²/kg is × 0.1.
    0.1 * (m0.ln() + t * (m1 / m0).ln()).exp()
}

/// Photon fluence per air kerma of `spectrum` (quanta per mm² per µGy): the conversion an
/// exposure's quanta per pixel and its air kerma share.
pub fn quanta_per_mm2_per_ugy(spectrum: &Spectrum) -> f64 {
    // Kerma per unit fluence (Gy·m²): Σ w E (μen/ρ).
    let gray_m2: f64 = spectrum
        .bins()
        .iter()
        .map(|b| b.weight * b.kev * JOULES_PER_KEV * air_mass_energy_absorption_m2_per_kg(b.kev))
        .sum();
    // Per µGy and per mm²: (1e-6 Gy) / (gray_m2 Gy·m²) quanta per m², × 1e-6 m² per mm².
    1e-12 / gray_m2
}

/// How each mode doses: the air kerma per frame the exposure control aims for at the
/// detector, behind the patient.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DoseSettings {
    /// Whether exposure control sets each frame's quanta from the signal behind the patient;
    /// off, every frame uses `DetectorSettings::photons_per_pixel` with nothing in the beam.
    pub automatic: bool,
    /// Detector air kerma per fluoroscopy pulse (µGy). Flat-panel fluoroscopy typically
    /// aims for a few tens of nGy per pulse (0.03 here, a low-dose setting).
    pub fluoroscopy_detector_ugy: f64,
    /// Detector air kerma per DSA frame (µGy). DSA and cine frames take 1–10 µGy, about a
    /// hundred times a fluoroscopy pulse, which is why subtracted images are clean (2.5 here).
    pub subtraction_detector_ugy: f64,
    /// Most quanta per pixel with nothing in the beam that the tube can give (the generator's
    /// limit): behind very thick parts the detector gets less than it aims for.
    pub max_photons_per_pixel: f64,
}

impl Default for DoseSettings {
    fn default() -> Self {
        Self {
            automatic: false,
            fluoroscopy_detector_ugy: 0.03,
            subtraction_detector_ugy: 2.5,
            max_photons_per_pixel: 1e8,
        }
    }
}

impl DoseSettings {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<()> {
        for (what, value) in [
            (
                "fluoroscopy detector air kerma (µGy)",
                self.fluoroscopy_detector_ugy,
            ),
            (
                "DSA detector air kerma (µGy)",
                self.subtraction_detector_ugy,
            ),
            ("most photons per pixel", self.max_photons_per_pixel),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(XrayError::OutOfRange {
                    what: format!("dose {what}"),
                    range: "finite and > 0",
                    value,
                });
            }
        }
        Ok(())
    }
}

/// What the automatic exposure control measures: the median transmitted fraction over the
/// central half of the field (its measuring field), or `None` if nothing there transmits.
pub fn measuring_field_transmission(transmitted: &[f32], width: u32, height: u32) -> Option<f64> {
    let mut sample: Vec<f32> = crate::detector::measuring_field(transmitted, width, height)
        .filter(|t| t.is_finite() && *t > 0.0)
        .collect();
    if sample.is_empty() {
        return None;
    }
    let n = sample.len();
    Some(f64::from(
        *sample.select_nth_unstable_by(n / 2, f32::total_cmp).1,
    ))
}

/// Quanta per pixel with nothing in the beam that put `detector_ugy` behind a patient
/// transmitting `transmission` (the exposure control's setting), capped at the tube's limit.
pub fn controlled_photons_per_pixel(
    detector_ugy: f64,
    transmission: f64,
    pixel_pitch_m: f64,
    quanta_per_mm2_per_ugy: f64,
    max_photons_per_pixel: f64,
) -> f64 {
    let pixel_mm2 = (pixel_pitch_m * 1e3).powi(2);
    (detector_ugy * quanta_per_mm2_per_ugy * pixel_mm2 / transmission.max(1e-12))
        .min(max_photons_per_pixel)
}

/// Dose of one exposure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExposureDose {
    /// Quanta per pixel with nothing in the beam.
    pub photons_per_pixel: f64,
    /// Air kerma free in air at the interventional reference point (mGy).
    pub reference_air_kerma_mgy: f64,
    /// Kerma–area product of the collimated beam (Gy·cm²).
    pub kerma_area_product_gy_cm2: f64,
}

impl ExposureDose {
    /// The dose of an exposure of `photons_per_pixel` (nothing in the beam) through `carm`'s
    /// collimated field: the free-in-air kerma at the detector, scaled by the inverse square
    /// to the reference point; the DAP is that kerma times the open field on the detector (the
    /// product is the same in every plane).
    pub fn of(photons_per_pixel: f64, carm: &CArm, quanta_per_mm2_per_ugy: f64) -> Self {
        let d = &carm.detector;
        let pitch_mm = d.pixel_pitch_m() * 1e3;
        let detector_ugy = photons_per_pixel / (quanta_per_mm2_per_ugy * pitch_mm * pitch_mm);
        let reference_m = carm.source_to_isocenter_m - REFERENCE_POINT_FROM_ISOCENTER_M;
        let inverse_square = (carm.source_to_image_m / reference_m).powi(2);
        let open_m2 = d.field_of_view_m * d.collimation.0 * d.field_of_view_m * d.collimation.1;
        Self {
            photons_per_pixel,
            reference_air_kerma_mgy: detector_ugy * inverse_square * 1e-3,
            // µGy·m² = 1e-6 Gy × 1e4 cm².
            kerma_area_product_gy_cm2: detector_ugy * open_m2 * 1e-2,
        }
    }
}

/// Dose accumulated over a procedure, as the system's dose display shows it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DoseTally {
    /// Cumulative air kerma at the interventional reference point (mGy).
    pub reference_air_kerma_mgy: f64,
    /// Cumulative kerma–area product (Gy·cm²).
    pub kerma_area_product_gy_cm2: f64,
    /// Fluoroscopy and roadmap pulses.
    pub fluoroscopy_exposures: u64,
    /// DSA frames.
    pub subtraction_exposures: u64,
    /// The latest exposure.
    pub last_exposure: Option<ExposureDose>,
}

impl DoseTally {
    /// Adds one exposure.
    pub fn add(&mut self, dose: &ExposureDose, subtraction: bool) {
        self.reference_air_kerma_mgy += dose.reference_air_kerma_mgy;
        self.kerma_area_product_gy_cm2 += dose.kerma_area_product_gy_cm2;
        self.last_exposure = Some(*dose);
        if subtraction {
            self.subtraction_exposures += 1;
        } else {
            self.fluoroscopy_exposures += 1;
        }
    }
}
