//! Image stages around the detector: X-ray scatter from the patient and the anti-scatter grid
//! that removes most of it (before exposure), and unsharp-mask edge enhancement of the
//! displayed image (after).

use crate::detector::gaussian_blur;
use crate::error::{Result, XrayError};

/// Scatter from the patient and the anti-scatter grid in front of the detector.
///
/// The detector sees `Tp·T + Ts·SPR·(K ⊛ T)` of the unattenuated beam: T the primary
/// transmission, K a normalised Gaussian kernel (scatter is a broad, low-frequency fog), SPR
/// the scatter-to-primary ratio at the patient's exit before the grid, Tp and Ts the grid's
/// primary and scatter transmissions. A vessel's contrast falls by about `1 + SPR·Ts/Tp`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScatterSettings {
    /// Scatter-to-primary ratio before the grid. Head and neck at angiographic field sizes
    /// scatter about as much as they transmit (1).
    pub scatter_to_primary: f64,
    /// σ of the scatter kernel on the detector (m): a few centimetres.
    pub kernel_sigma_m: f64,
    /// Primary transmission of the grid (a 10:1 grid: about 0.7).
    pub grid_primary_transmission: f64,
    /// Scatter transmission of the grid (a 10:1 grid: about 0.1).
    pub grid_scatter_transmission: f64,
}

impl Default for ScatterSettings {
    fn default() -> Self {
        Self {
            scatter_to_primary: 1.0,
            kernel_sigma_m: 0.03,
            grid_primary_transmission: 0.7,
            grid_scatter_transmission: 0.1,
        }
    }
}

impl ScatterSettings {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<()> {
        let checks = [
            (
                "scatter-to-primary ratio",
                self.scatter_to_primary,
                (0.0..=20.0).contains(&self.scatter_to_primary),
            ),
            (
                "scatter kernel σ (m)",
                self.kernel_sigma_m,
                self.kernel_sigma_m > 0.0 && self.kernel_sigma_m <= 1.0,
            ),
            (
                "grid primary transmission",
                self.grid_primary_transmission,
                self.grid_primary_transmission > 0.0 && self.grid_primary_transmission <= 1.0,
            ),
            (
                "grid scatter transmission",
                self.grid_scatter_transmission,
                (0.0..=1.0).contains(&self.grid_scatter_transmission),
            ),
        ];
        for (what, value, ok) in checks {
            if !(value.is_finite() && ok) {
                return Err(XrayError::OutOfRange {
                    what: what.into(),
                    range: "finite, 0 ≤ SPR ≤ 20, 0 < σ ≤ 1 m, 0 < Tp ≤ 1, 0 ≤ Ts ≤ 1",
                    value,
                });
            }
        }
        Ok(())
    }

    /// Scatter-to-primary ratio behind the grid.
    pub fn residual_scatter_to_primary(&self) -> f64 {
        self.scatter_to_primary * self.grid_scatter_transmission / self.grid_primary_transmission
    }
}

/// Side of the coarse grid the scatter fog is computed on (pixels): the kernel is centimetres
/// wide, so a 64-pixel grid resolves it and costs nothing next to a frame.
const SCATTER_GRID_PX: usize = 64;

/// Adds scatter and the grid to a `width × height` transmission image on a detector of
/// `pixel_pitch_m` pixels, in place.
pub fn add_scatter(
    transmitted: &mut [f32],
    width: u32,
    height: u32,
    pixel_pitch_m: f64,
    settings: &ScatterSettings,
) {
    let (w, h) = (width as usize, height as usize);
    let factor = (w.max(h) / SCATTER_GRID_PX).max(1);
    let (cw, ch) = (w.div_ceil(factor), h.div_ceil(factor));
    // Box-average onto the coarse grid.
    let mut coarse = vec![0.0f32; cw * ch];
    let mut counts = vec![0.0f32; cw * ch];
    for v in 0..h {
        for u in 0..w {
            let c = (v / factor) * cw + u / factor;
            coarse[c] += transmitted[v * w + u];
            counts[c] += 1.0;
        }
    }
    for (c, n) in coarse.iter_mut().zip(&counts) {
        *c /= n;
    }
    let sigma_coarse = settings.kernel_sigma_m / (pixel_pitch_m * factor as f64);
    gaussian_blur(&mut coarse, cw, ch, sigma_coarse);
    let tp = settings.grid_primary_transmission as f32;
    let fog = (settings.grid_scatter_transmission * settings.scatter_to_primary) as f32;
    // Bilinear back onto the pixels (coarse cell centres at (i + ½)·factor − ½).
    let sample = |x: f64, n: usize| {
        let x = x.clamp(0.0, (n - 1) as f64);
        let i = (x.floor() as usize).min(n.saturating_sub(2));
        (i, (x - i as f64) as f32)
    };
    for v in 0..h {
        let y = (v as f64 + 0.5) / factor as f64 - 0.5;
        let (j, fy) = if ch > 1 { sample(y, ch) } else { (0, 0.0) };
        for u in 0..w {
            let x = (u as f64 + 0.5) / factor as f64 - 0.5;
            let (i, fx) = if cw > 1 { sample(x, cw) } else { (0, 0.0) };
            let at = |a: usize, b: usize| coarse[(b.min(ch - 1)) * cw + a.min(cw - 1)];
            let s = (1.0 - fy) * ((1.0 - fx) * at(i, j) + fx * at(i + 1, j))
                + fy * ((1.0 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1));
            let t = &mut transmitted[v * w + u];
            *t = tp * *t + fog * s;
        }
    }
}

/// Unsharp-mask edge enhancement in place: `x + amount·(x − G_σ ⊛ x)`, which sharpens
/// vessel and device edges and, for white noise, multiplies the variance by
/// `Σ h² = (1 + a)² − 2a(1 + a)·g₀ + a²·Σ g²` (h the filter, g the Gaussian's taps, g₀ its
/// centre). NaN pixels (collimated) stay NaN and do not spread.
pub fn unsharp_mask(values: &mut [f32], width: u32, height: u32, sigma_px: f64, amount: f64) {
    if amount == 0.0 || sigma_px <= 0.0 {
        return;
    }
    let (w, h) = (width as usize, height as usize);
    let mut blurred: Vec<f32> = values
        .iter()
        .map(|v| if v.is_finite() { *v } else { 0.0 })
        .collect();
    gaussian_blur(&mut blurred, w, h, sigma_px);
    let a = amount as f32;
    for (v, b) in values.iter_mut().zip(&blurred) {
        if v.is_finite() {
            *v += a * (*v - b);
        }
    }
}
