//! Smoothness of motion by the spectral arc length (SPARC; Balasubramanian, Melendez-Calderon,
//! Roby-Brami and Burdet, "On the analysis of movement smoothness", J NeuroEng Rehabil 12:112,
//! 2015), used for tip-path smoothness in endovascular skill assessment.
//!
//! The speed profile v(t), sampled every Δt, is zero-padded to N = 2^(⌈log₂ n⌉ + 4) samples;
//! its Fourier magnitude is normalised by its largest value, M(f) = |V(f)| / max |V|. The
//! spectrum is kept from f = 0 up to the cut-off f_c (10 Hz), and then to the last
//! frequency where M ≥ 0.05 (the adaptive cut-off f_a). SPARC is minus the arc length of
//! that curve with frequency scaled to the kept band:
//!
//! SPARC = −Σᵢ √( ((fᵢ₊₁ − fᵢ) / f_a)² + (Mᵢ₊₁ − Mᵢ)² )
//!
//! A single smooth movement scores about −1.4 to −1.6; every stop, restart and tremor
//! lengthens the spectrum's arc and makes it more negative.

use rustfft::FftPlannerScalar;
use rustfft::num_complex::Complex;

use crate::error::{AssessmentError, Result};

/// SPARC's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SparcSettings {
    /// Zero padding: the FFT length is 2^(⌈log₂ n⌉ + `pad_level`).
    pub pad_level: u32,
    /// Highest frequency considered (Hz).
    pub cutoff_hz: f64,
    /// Normalised magnitude below which the spectrum's tail is dropped.
    pub amplitude_threshold: f64,
}

impl Default for SparcSettings {
    fn default() -> Self {
        Self {
            pad_level: 4,
            cutoff_hz: 10.0,
            amplitude_threshold: 0.05,
        }
    }
}

/// The spectral arc length of the speed profile `speed` sampled every `dt_s` seconds, with
/// the published settings.
pub fn sparc(speed: &[f64], dt_s: f64) -> Result<f64> {
    sparc_with(speed, dt_s, &SparcSettings::default())
}

/// [`sparc`] with explicit settings.
pub fn sparc_with(speed: &[f64], dt_s: f64, settings: &SparcSettings) -> Result<f64> {
    if speed.len() < 2 {
        return Err(AssessmentError::Samples(format!(
            "a speed profile of {} sample(s); at least 2 are needed",
            speed.len()
        )));
    }
    if !(dt_s.is_finite() && dt_s > 0.0) {
        return Err(AssessmentError::Setting {
            what: "sampling interval (s)",
            value: dt_s,
            range: "finite and > 0",
        });
    }
    if !(settings.cutoff_hz.is_finite() && settings.cutoff_hz > 0.0) {
        return Err(AssessmentError::Setting {
            what: "cut-off frequency (Hz)",
            value: settings.cutoff_hz,
            range: "finite and > 0",
        });
    }
    if !(settings.amplitude_threshold > 0.0 && settings.amplitude_threshold < 1.0) {
        return Err(AssessmentError::Setting {
            what: "amplitude threshold",
            value: settings.amplitude_threshold,
            range: "between 0 and 1",
        });
    }
    if settings.pad_level > 8 {
        return Err(AssessmentError::Setting {
            what: "pad level",
            value: f64::from(settings.pad_level),
            range: "at most 8",
        });
    }
    if let Some(i) = speed.iter().position(|v| !v.is_finite()) {
        return Err(AssessmentError::Samples(format!(
            "speed sample {i} is not finite"
        )));
    }
    let bits = (speed.len() as f64).log2().ceil() as u32 + settings.pad_level;
    let n = 1_usize << bits;
    let mut buffer: Vec<Complex<f64>> = speed
        .iter()
        .map(|&v| Complex::new(v, 0.0))
        .chain(std::iter::repeat(Complex::new(0.0, 0.0)))
        .take(n)
        .collect();
    // The scalar planner: a power-of-two transform of a session's speeds takes microseconds
    // either way, and the SIMD planners' code took 17 of this crate's 18 s of build (-O3).
    FftPlannerScalar::new()
        .plan_fft_forward(n)
        .process(&mut buffer);
    let magnitude: Vec<f64> = buffer.iter().map(|c| c.norm()).collect();
    let largest = magnitude.iter().copied().fold(0.0, f64::max);
    if largest == 0.0 {
        return Err(AssessmentError::Samples(
            "the speed is zero throughout: no movement to assess".into(),
        ));
    }
    let df = 1.0 / (n as f64 * dt_s);
    // Within the cut-off (and below Nyquist), then up to the last bin above the threshold.
    let within = ((settings.cutoff_hz / df).floor() as usize).min(n / 2);
    let spectrum: Vec<f64> = magnitude[..=within].iter().map(|m| m / largest).collect();
    let first = spectrum
        .iter()
        .position(|&m| m >= settings.amplitude_threshold)
        .unwrap_or(0);
    let last = spectrum
        .iter()
        .rposition(|&m| m >= settings.amplitude_threshold)
        .unwrap_or(first);
    if last <= first {
        return Err(AssessmentError::Samples(
            "the speed's spectrum has one bin above the threshold: sample longer or finer".into(),
        ));
    }
    let band = (last - first) as f64 * df;
    Ok(-spectrum[first..=last]
        .windows(2)
        .map(|w| ((df / band).powi(2) + (w[1] - w[0]).powi(2)).sqrt())
        .sum::<f64>())
}
