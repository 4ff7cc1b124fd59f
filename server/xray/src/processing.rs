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

/// Pixel-shift registration of a DSA mask to a live frame: the translation `(dx, dy)`
/// (pixels) for which `live(u, v) ≈ mask(u − dx, v − dy)`. Least squares of the zero-mean
/// difference over the central half of the image (every other pixel; non-finite ones
/// skipped), searched over whole pixels within `±max_px`, then refined to a fraction of a
/// pixel by a parabola through the best shift and its neighbours on each axis. Contrast and
/// devices in the live frame bias it little: they are sparse, and the zero-mean difference
/// ignores a uniform change of dose.
pub fn register_shift(
    mask: &[f32],
    live: &[f32],
    width: usize,
    height: usize,
    max_px: i32,
) -> (f64, f64) {
    let (w, h) = (width as i32, height as i32);
    let cost = |sx: i32, sy: i32| -> f64 {
        let (mut sum, mut sum2, mut n) = (0.0f64, 0.0f64, 0usize);
        for v in (h / 4..3 * h / 4).step_by(2) {
            let mv = v - sy;
            if !(0..h).contains(&mv) {
                continue;
            }
            for u in (w / 4..3 * w / 4).step_by(2) {
                let mu = u - sx;
                if !(0..w).contains(&mu) {
                    continue;
                }
                let d = f64::from(live[(v * w + u) as usize] - mask[(mv * w + mu) as usize]);
                if d.is_finite() {
                    sum += d;
                    sum2 += d * d;
                    n += 1;
                }
            }
        }
        if n < 16 {
            f64::INFINITY
        } else {
            (sum2 - sum * sum / n as f64) / n as f64
        }
    };
    let mut best = (0, 0, cost(0, 0));
    for sy in -max_px..=max_px {
        for sx in -max_px..=max_px {
            let c = cost(sx, sy);
            if c < best.2 {
                best = (sx, sy, c);
            }
        }
    }
    let (bx, by, c0) = best;
    if !c0.is_finite() {
        return (0.0, 0.0);
    }
    // A parabola through (−1, c−), (0, c0), (1, c+): its vertex, within half a pixel.
    let vertex = |minus: f64, plus: f64| {
        let curvature = minus + plus - 2.0 * c0;
        if curvature > 0.0 && minus.is_finite() && plus.is_finite() {
            (0.5 * (minus - plus) / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    (
        f64::from(bx) + vertex(cost(bx - 1, by), cost(bx + 1, by)),
        f64::from(by) + vertex(cost(bx, by - 1), cost(bx, by + 1)),
    )
}

/// `image` moved by `(dx, dy)` pixels: `out(u, v) = image(u − dx, v − dy)`, bilinear, the
/// edges held.
pub fn shift_image(image: &[f32], width: usize, height: usize, dx: f64, dy: f64) -> Vec<f32> {
    let at = |u: f64, v: f64| -> f32 {
        let u = u.clamp(0.0, (width - 1) as f64);
        let v = v.clamp(0.0, (height - 1) as f64);
        let (u0, v0) = (u.floor() as usize, v.floor() as usize);
        let (u1, v1) = ((u0 + 1).min(width - 1), (v0 + 1).min(height - 1));
        let (fu, fv) = ((u - u0 as f64) as f32, (v - v0 as f64) as f32);
        let row = |r: usize| image[r * width + u0] * (1.0 - fu) + image[r * width + u1] * fu;
        row(v0) * (1.0 - fv) + row(v1) * fv
    };
    (0..width * height)
        .map(|i| at((i % width) as f64 - dx, (i / width) as f64 - dy))
        .collect()
}
