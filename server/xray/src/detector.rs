//! The flat-panel detector: polyenergetic Beer–Lambert exposure of the path images, seeded
//! quantum (Poisson) noise at a dose, scintillator blur, the log transform, collimation and
//! window/level to 8- and 16-bit grey.

use rand::SeedableRng;
use rand::rngs::SmallRng;
use rand_distr::{Distribution, Poisson};
use rayon::prelude::*;

use crate::error::{Result, XrayError};
use crate::geometry::DetectorGeometry;
use crate::render::PathImage;
use crate::spectrum::{MaterialPaths, Spectrum};

/// Detector and display settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorSettings {
    /// Mean quanta per pixel per frame with nothing in the beam: the dose setting. About
    /// 2,000 for fluoroscopy at 0.5 mm pixels (~30 nGy per frame), 20,000 for DSA runs.
    pub photons_per_pixel: f64,
    /// Whether to draw quantum noise (off for golden images).
    pub noise: bool,
    /// Gaussian blur of scintillator and focal spot, σ in pixels (0: none).
    pub blur_sigma_px: f64,
    /// Window width in line-integral units (−ln of transmission).
    pub window: f64,
    /// Window centre in line-integral units.
    pub level: f64,
    /// Seed of the noise; frame k draws from (seed, k) whatever the thread count.
    pub seed: u64,
    /// Automatic window/level (as a fluoroscope's automatic brightness control): the window
    /// spans the 1st to 99th percentile of the central half of the image; `window` and
    /// `level` are ignored.
    pub auto_window: bool,
}

impl Default for DetectorSettings {
    fn default() -> Self {
        Self {
            photons_per_pixel: 2000.0,
            noise: true,
            blur_sigma_px: 0.7,
            window: 6.0,
            level: 3.5,
            seed: 1,
            auto_window: false,
        }
    }
}

impl DetectorSettings {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<()> {
        let checks = [
            (
                "photons per pixel",
                self.photons_per_pixel,
                self.photons_per_pixel > 0.0,
            ),
            (
                "blur σ (pixels)",
                self.blur_sigma_px,
                (0.0..=20.0).contains(&self.blur_sigma_px),
            ),
            ("window width", self.window, self.window > 0.0),
            ("window level", self.level, true),
        ];
        for (what, value, ok) in checks {
            if !(value.is_finite() && ok) {
                return Err(XrayError::OutOfRange {
                    what: format!("detector {what}"),
                    range: "finite and in range (photons > 0, 0 ≤ σ ≤ 20 px, window > 0)",
                    value,
                });
            }
        }
        Ok(())
    }
}

/// Transmitted fraction of each pixel, `Σ_E w_E exp(−L_E)`, from the background and layer
/// path images (either may be absent).
pub fn transmission(
    spectrum: &Spectrum,
    background: Option<&PathImage>,
    layers: Option<&PathImage>,
    width: u32,
    height: u32,
) -> Vec<f32> {
    let n = (width * height) as usize;
    fn plane(image: Option<&PathImage>, c: usize) -> Option<&[f32]> {
        image.map(|i| &i.channels[c][..])
    }
    let planes: [Option<&[f32]>; 5] = [
        plane(background, 0),
        plane(background, 1),
        plane(layers, 0),
        plane(layers, 1),
        plane(layers, 2),
    ];
    (0..n)
        .into_par_iter()
        .with_min_len(4096)
        .map(|i| {
            let path = |c: usize| planes[c].map_or(0.0, |p| f64::from(p[i]));
            spectrum.transmission(&MaterialPaths {
                water: path(0),
                bone: path(1),
                iodine: path(2),
                nitinol: path(3),
                platinum: path(4),
            }) as f32
        })
        .collect()
}

/// One exposure: expected quanta `N0·T`, Poisson noise drawn per row from (seed, frame,
/// row), blur, then the log transform `−ln(N / N0)`. Pixels outside the collimated field
/// get NaN (no signal); the encoders show them black.
pub fn expose(
    transmitted: &[f32],
    geometry: &DetectorGeometry,
    settings: &DetectorSettings,
    frame: u64,
) -> Vec<f32> {
    let (w, h) = (geometry.width_px as usize, geometry.height_px as usize);
    let n0 = settings.photons_per_pixel;
    let mut counts: Vec<f32> = vec![0.0; w * h];
    counts
        .par_chunks_mut(w)
        .zip(transmitted.par_chunks(w))
        .enumerate()
        .for_each(|(v, (row, t))| {
            let mut rng = SmallRng::seed_from_u64(mix(settings.seed, frame, v as u64));
            for (count, &t) in row.iter_mut().zip(t) {
                let mean = n0 * f64::from(t);
                *count = if settings.noise && mean > 0.0 {
                    Poisson::new(mean).map_or(mean, |p| p.sample(&mut rng)) as f32
                } else {
                    mean as f32
                };
            }
        });
    if settings.blur_sigma_px > 0.0 {
        gaussian_blur(&mut counts, w, h, settings.blur_sigma_px);
    }
    let (cu, cv) = geometry.center_px();
    let (half_u, half_v) = (
        0.5 * geometry.collimation.0 * w as f64,
        0.5 * geometry.collimation.1 * h as f64,
    );
    counts.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        let open_v = (v as f64 - cv).abs() <= half_v;
        for (u, c) in row.iter_mut().enumerate() {
            *c = if open_v && (u as f64 - cu).abs() <= half_u {
                // Half a quantum floors empty pixels (a log of zero is no image).
                -(f64::from(*c).max(0.5) / n0).ln() as f32
            } else {
                f32::NAN
            };
        }
    });
    counts
}

/// SplitMix64 of (seed, frame, row): independent streams per row and frame.
fn mix(seed: u64, frame: u64, row: u64) -> u64 {
    let mut z = seed
        .wrapping_add(frame.wrapping_mul(0x9E37_79B9_7F4A_7C15))
        .wrapping_add(row.wrapping_mul(0xD1B5_4A32_D192_ED03));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Separable Gaussian blur in place, kernel cut at 3σ, edges clamped.
pub fn gaussian_blur(image: &mut [f32], width: usize, height: usize, sigma: f64) {
    let radius = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> = {
        let k: Vec<f64> = (-radius..=radius)
            .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
            .collect();
        let total: f64 = k.iter().sum();
        k.iter().map(|x| (x / total) as f32).collect()
    };
    let clamp = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    // Rows.
    let mut tmp = vec![0.0f32; image.len()];
    tmp.par_chunks_mut(width)
        .zip(image.par_chunks(width))
        .for_each(|(out, row)| {
            for (u, o) in out.iter_mut().enumerate() {
                *o = kernel
                    .iter()
                    .enumerate()
                    .map(|(k, w)| w * row[clamp(u as isize + k as isize - radius, width)])
                    .sum();
            }
        });
    // Columns.
    image
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(v, out)| {
            for (k, w) in kernel.iter().enumerate() {
                let src = clamp(v as isize + k as isize - radius, height) * width;
                let row = &tmp[src..src + width];
                if k == 0 {
                    out.iter_mut().zip(row).for_each(|(o, r)| *o = w * r);
                } else {
                    out.iter_mut().zip(row).for_each(|(o, r)| *o += w * r);
                }
            }
        });
}

/// Grey level in [0, 1] of a line-integral value: more attenuation is darker, as on a
/// fluoroscopy monitor; NaN (collimated) is black.
#[inline]
pub fn grey(value: f32, window: f64, level: f64) -> f64 {
    if value.is_nan() {
        return 0.0;
    }
    (0.5 - (f64::from(value) - level) / window).clamp(0.0, 1.0)
}

/// Window width and centre spanning the 1st to 99th percentile of the finite values in the
/// central half of the image (the measuring field of a fluoroscope's automatic brightness
/// control); `None` when none is exposed.
pub fn auto_window(values: &[f32], width: u32, height: u32) -> Option<(f64, f64)> {
    let mut sample: Vec<f32> = measuring_field(values, width, height)
        .filter(|v| v.is_finite())
        .collect();
    if sample.is_empty() {
        return None;
    }
    let n = sample.len();
    let lo = *sample.select_nth_unstable_by(n / 100, f32::total_cmp).1;
    let hi = *sample
        .select_nth_unstable_by(n - 1 - n / 100, f32::total_cmp)
        .1;
    let width = f64::from(hi - lo).max(1e-3);
    Some((width, f64::from(lo) + 0.5 * width))
}

/// The values of the central half of a `width × height` image (half the width, half the
/// height): the measuring field of a fluoroscope's automatic brightness and exposure control.
pub fn measuring_field(values: &[f32], width: u32, height: u32) -> impl Iterator<Item = f32> + '_ {
    let (w, h) = (width as usize, height as usize);
    (h / 4..h - h / 4).flat_map(move |v| values[v * w + w / 4..v * w + w - w / 4].iter().copied())
}

/// Window/level to 8-bit grey.
pub fn encode_8bit(values: &[f32], window: f64, level: f64) -> Vec<u8> {
    values
        .par_iter()
        .with_min_len(4096)
        .map(|&x| (grey(x, window, level) * 255.0).round() as u8)
        .collect()
}

/// Window/level to 16-bit grey.
pub fn encode_16bit(values: &[f32], window: f64, level: f64) -> Vec<u16> {
    values
        .par_iter()
        .with_min_len(4096)
        .map(|&x| (grey(x, window, level) * 65535.0).round() as u16)
        .collect()
}
