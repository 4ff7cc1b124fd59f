//! The imaging chain's dose and processing stages against hand computations: air kerma per
//! photon fluence from NIST's table, exposure control, dose accumulation at the reference
//! point, recursive filtering's noise reduction, DSA mask averaging, and the contrast-to-noise
//! of a 3 mm iodine vessel and of a 0.014" wire in each mode.

use std::sync::Arc;

use cathlab_xray::dose::{self, REFERENCE_POINT_FROM_ISOCENTER_M};
use cathlab_xray::layers::{ContrastTube, DeviceAppearance, Layers};
use cathlab_xray::spectrum::Spectrum;
use cathlab_xray::{
    CArm, CpuRenderer, DetectorGeometry, Fluoroscope, FluoroscopeSettings, Frame, ImagingMode,
    Scene, Volume,
};
use nalgebra::{Point3, Vector3};

/// A 20 cm water slab filling the field (the volume is 24 cm wide; HU 0 inside), seen by a
/// `size`² detector over 12 cm.
fn slab() -> Arc<Volume> {
    Arc::new(
        Volume::from_fn([60; 3], Vector3::repeat(4e-3), Vector3::zeros(), 1, |p| {
            if p.coords.y.abs() < 0.1 { 0.0 } else { -1000.0 }
        })
        .unwrap(),
    )
}

fn carm(size: u32) -> CArm {
    CArm {
        detector: DetectorGeometry {
            width_px: size,
            height_px: size,
            field_of_view_m: 0.12,
            collimation: (1.0, 1.0),
        },
        ..CArm::default()
    }
}

fn chain(settings: FluoroscopeSettings) -> Fluoroscope {
    Fluoroscope::new(Box::new(CpuRenderer::default()), settings).unwrap()
}

fn settings(noise: bool) -> FluoroscopeSettings {
    let mut s = FluoroscopeSettings::default();
    s.detector.noise = noise;
    s.detector.blur_sigma_px = 0.0;
    s.dose.automatic = true;
    s
}

fn shoot(chain: &mut Fluoroscope, volume: &Arc<Volume>, carm: &CArm, layers: &Layers) -> Frame {
    chain
        .expose(
            0.0,
            Scene {
                volume,
                carm,
                layers,
            },
        )
        .unwrap()
}

/// Median of the central half of `values` (the exposure control's measuring field).
fn central_median(values: &[f32], size: usize) -> f64 {
    let mut v: Vec<f32> = (size / 4..size - size / 4)
        .flat_map(|r| values[r * size + size / 4..r * size + size - size / 4].to_vec())
        .collect();
    let n = v.len();
    f64::from(*v.select_nth_unstable_by(n / 2, f32::total_cmp).1)
}

fn mean_var(x: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let n = x.clone().count() as f64;
    let mean = x.clone().sum::<f64>() / n;
    let var = x.map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var)
}

/// Quanta per mm² per µGy by hand: 1 / Σ w·E·(μen/ρ)air with NIST's 60 and 80 keV values
/// (0.03041 and 0.02407 cm²/g).
fn quanta_by_hand(bins: &[(f64, f64, f64)]) -> f64 {
    let gray_m2: f64 = bins
        .iter()
        .map(|(w, kev, cm2_per_g)| w * kev * 1.602_176_634e-16 * cm2_per_g * 0.1)
        .sum();
    1e-12 / gray_m2
}

#[test]
fn air_kerma_per_fluence_follows_nist() {
    let mono = dose::quanta_per_mm2_per_ugy(&Spectrum::monoenergetic(60.0).unwrap());
    // 60 keV: 9.6131e-15 J × 0.003041 m²/kg = 2.9233e-17 Gy·m² → 34,208 per mm² per µGy.
    assert!((mono / 34_208.0 - 1.0).abs() < 1e-4, "{mono}");
    let two = dose::quanta_per_mm2_per_ugy(&Spectrum::default());
    let hand = quanta_by_hand(&[(0.5, 60.0, 0.03041), (0.5, 80.0, 0.02407)]);
    assert!((two / hand - 1.0).abs() < 1e-12, "{two} vs {hand}");
    // Log–log interpolation between table points, and the table's own points.
    let mid = dose::air_mass_energy_absorption_m2_per_kg(70.0);
    let expected = 0.1
        * (0.03041f64.ln()
            + (70f64 / 60.0).ln() / (80f64 / 60.0).ln() * (0.02407f64 / 0.03041).ln())
        .exp();
    assert!((mid / expected - 1.0).abs() < 1e-12);
    assert!((dose::air_mass_energy_absorption_m2_per_kg(100.0) - 0.002325).abs() < 1e-12);
    println!(
        "fluence per air kerma: 60 keV {mono:.0}, default two-bin beam {two:.0} quanta/(mm²·µGy)"
    );
}

#[test]
fn exposure_control_puts_each_modes_kerma_behind_the_patient() {
    let (volume, carm) = (slab(), carm(64));
    let mut chain = chain(settings(false));
    let q = dose::quanta_per_mm2_per_ugy(&Spectrum::default());
    let pixel_mm2 = (carm.detector.pixel_pitch_m() * 1e3).powi(2);
    let mut aims = Vec::new();
    for (mode, aim) in [
        (ImagingMode::Fluoroscopy, 0.03),
        (ImagingMode::Subtraction, 2.5),
    ] {
        chain.set_mode(mode, &carm).unwrap();
        let frame = shoot(&mut chain, &volume, &carm, &Layers::new());
        let exposure = chain.dose().last_exposure.unwrap();
        // Without noise a fluoroscopy frame is −ln T exactly (a DSA frame is subtracted: take
        // the fluoroscopy frame of the same pose); the detector gets N0·T quanta.
        let values = match mode {
            ImagingMode::Subtraction => chain_clean_fluoro(&volume, &carm),
            _ => frame.values.clone(),
        };
        let t = (-central_median(&values, 64)).exp();
        let behind_ugy = exposure.photons_per_pixel * t / (q * pixel_mm2);
        println!(
            "{mode:?}: {:.0} quanta per pixel unattenuated, transmission {t:.4}, {behind_ugy:.4} µGy behind the patient (aim {aim})",
            exposure.photons_per_pixel
        );
        assert!(
            (behind_ugy / aim - 1.0).abs() < 1e-5,
            "{behind_ugy} vs {aim}"
        );
        aims.push(exposure.photons_per_pixel);
    }
    assert!((aims[1] / aims[0] - 2.5 / 0.03).abs() < 1e-6);
}

/// The noise-free fluoroscopy frame of the slab (−ln T per pixel).
fn chain_clean_fluoro(volume: &Arc<Volume>, carm: &CArm) -> Vec<f32> {
    let mut c = chain(settings(false));
    shoot(&mut c, volume, carm, &Layers::new()).values
}

#[test]
fn dose_accumulates_at_the_reference_point_as_computed_by_hand() {
    let (volume, carm) = (slab(), carm(32));
    let mut s = settings(true);
    s.dose.automatic = false;
    s.detector.photons_per_pixel = 5000.0;
    let mut chain = chain(s);
    for _ in 0..10 {
        shoot(&mut chain, &volume, &carm, &Layers::new());
    }
    chain.set_mode(ImagingMode::Subtraction, &carm).unwrap();
    for _ in 0..3 {
        shoot(&mut chain, &volume, &carm, &Layers::new());
    }
    let tally = chain.dose();
    // By hand: 5000 quanta on a (120 mm / 32)² pixel, free in air at the detector, then the
    // inverse square from 1.2 m to the reference point 0.8 − 0.15 = 0.65 m from the source.
    let q = quanta_by_hand(&[(0.5, 60.0, 0.03041), (0.5, 80.0, 0.02407)]);
    let detector_ugy = 5000.0 / (q * (120.0f64 / 32.0).powi(2));
    let reference_mgy =
        detector_ugy * (1.2f64 / (0.8 - REFERENCE_POINT_FROM_ISOCENTER_M)).powi(2) * 1e-3;
    // DAP: detector kerma × 12 cm × 12 cm, in Gy·cm².
    let dap = detector_ugy * 1e-6 * 144.0;
    println!(
        "13 exposures: {:.6} mGy at the reference point (hand {:.6}), {:.7} Gy·cm² (hand {:.7})",
        tally.reference_air_kerma_mgy,
        13.0 * reference_mgy,
        tally.kerma_area_product_gy_cm2,
        13.0 * dap
    );
    assert!((tally.reference_air_kerma_mgy / (13.0 * reference_mgy) - 1.0).abs() < 1e-9);
    assert!((tally.kerma_area_product_gy_cm2 / (13.0 * dap) - 1.0).abs() < 1e-9);
    assert_eq!(
        (tally.fluoroscopy_exposures, tally.subtraction_exposures),
        (10, 3)
    );
}

/// Per-pixel noise of `frame` against the noise-free `clean` (no structure left).
fn noise_variance(frame: &[f32], clean: &[f32]) -> f64 {
    mean_var(frame.iter().zip(clean).map(|(a, b)| f64::from(a - b))).1
}

#[test]
fn recursive_filtering_divides_the_noise_variance_of_a_still_scene() {
    let (volume, carm) = (slab(), carm(128));
    let clean = chain_clean_fluoro(&volume, &carm);
    let mut ratios = Vec::new();
    for alpha in [0.5, 0.25] {
        let mut plain = chain(settings(true));
        let mut s = settings(true);
        s.recursive_weight = alpha;
        let mut filtered = chain(s);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for _ in 0..60 {
            a = shoot(&mut plain, &volume, &carm, &Layers::new()).values;
            b = shoot(&mut filtered, &volume, &carm, &Layers::new()).values;
        }
        let ratio = noise_variance(&b, &clean) / noise_variance(&a, &clean);
        let expected = alpha / (2.0 - alpha);
        println!("α = {alpha}: variance ratio {ratio:.4}, expected α/(2 − α) = {expected:.4}");
        // 16,384 pixels: the variance estimate's relative error is ~1 %.
        assert!(
            (ratio / expected - 1.0).abs() < 0.05,
            "{ratio} vs {expected}"
        );
        ratios.push(ratio);
    }
    assert!(ratios[1] < ratios[0]);
}

#[test]
fn a_dsa_mask_averaged_over_k_frames_cuts_the_subtraction_noise() {
    let (volume, carm) = (slab(), carm(128));
    let mut variances = Vec::new();
    for k in [1, 4] {
        let mut s = settings(true);
        s.mask_frames = k;
        let mut c = chain(s);
        c.set_mode(ImagingMode::Subtraction, &carm).unwrap();
        for i in 0..k {
            let opening = shoot(&mut c, &volume, &carm, &Layers::new());
            assert!(
                opening.values.iter().all(|v| *v == 0.0),
                "mask frame {i} shows empty"
            );
        }
        let live = shoot(&mut c, &volume, &carm, &Layers::new());
        variances.push(mean_var(live.values.iter().map(|v| f64::from(*v))).1);
    }
    // Live noise σ² plus the mask's σ²/k: (1 + 1/4) / (1 + 1).
    let ratio = variances[1] / variances[0];
    println!("subtraction noise variance, mask of 4 against 1: {ratio:.4} (expected 0.625)");
    assert!((ratio / 0.625 - 1.0).abs() < 0.05, "{ratio}");
}

#[test]
fn a_3_mm_iodine_vessel_has_the_hand_computed_contrast_to_noise_in_each_mode() {
    let (volume, carm) = (slab(), carm(128));
    // A 3 mm vessel of contrast diluted to 150 mgI/mL, across the field at the isocenter.
    let vessel = vessel_layer();
    let q = dose::quanta_per_mm2_per_ugy(&Spectrum::default());
    let pixel_mm2 = (carm.detector.pixel_pitch_m() * 1e3).powi(2);
    // Hand contrast on the two rows either side of the vessel's centre line (pixel centres
    // at ±0.5 px, ±0.3125 mm at the isocenter after the 1.5× magnification): the chord of the
    // 1.5 mm radius there, at half the tabulated 300 mg/mL coefficients, behind 20 cm of water
    // in the two-bin beam (60 and 80 keV, μ water 20.6 / 18.4, iodine 227 / 105 1/m).
    let offset =
        0.5 * carm.detector.pixel_pitch_m() * carm.source_to_isocenter_m / carm.source_to_image_m;
    let iodine = 0.5 * 2.0 * (1.5e-3f64.powi(2) - offset * offset).sqrt();
    let t = |iodine: f64| -> f64 {
        [(0.5f64, 20.6f64, 227.0f64), (0.5, 18.4, 105.0)]
            .iter()
            .map(|(w, mu_w, mu_i)| w * (-mu_w * 0.2 - mu_i * iodine).exp())
            .sum()
    };
    let contrast_by_hand = -(t(iodine) / t(0.0)).ln();
    // The vessel's centre row: it runs along the image's u axis through v = centre.
    let centre = [63usize, 64];
    for (mode, aim, extra_noise) in [
        (ImagingMode::Fluoroscopy, 0.03, 1.0),
        (ImagingMode::Subtraction, 2.5, 2.0),
    ] {
        let mut c = chain(settings(true));
        c.set_mode(mode, &carm).unwrap();
        if mode == ImagingMode::Subtraction {
            shoot(&mut c, &volume, &carm, &Layers::new());
        }
        let frame = shoot(&mut c, &volume, &carm, &vessel);
        let row = |v: usize| {
            frame.values[v * 128 + 16..v * 128 + 112]
                .iter()
                .map(|x| f64::from(*x))
        };
        let on: Vec<f64> = centre.iter().flat_map(|&v| row(v)).collect();
        let (on_mean, _) = mean_var(on.iter().copied());
        let background: Vec<f64> = (16..40).chain(88..112).flat_map(row).collect();
        let (off_mean, off_var) = mean_var(background.iter().copied());
        let measured = (on_mean - off_mean).abs() / off_var.sqrt();
        // Noise by hand: Poisson, 1/√N per pixel in the log image with N = aim·q·A behind
        // the patient; a subtraction adds the mask's equal variance.
        let quanta = aim * q * pixel_mm2;
        let by_hand = contrast_by_hand * (quanta / extra_noise).sqrt();
        println!(
            "{mode:?} ({aim} µGy per frame, {quanta:.0} quanta per pixel): 3 mm vessel CNR {measured:.2}, by hand {by_hand:.2}"
        );
        assert!(
            (measured / by_hand - 1.0).abs() < 0.1,
            "{measured} vs {by_hand}"
        );
    }
}

#[test]
fn a_0014_inch_wire_has_the_hand_computed_contrast_to_noise_in_fluoroscopy() {
    let (volume, carm) = (slab(), carm(128));
    // The microwire runs down pixel column 64 through the pixel centres at the isocenter, its
    // platinum-coiled 30 mm at the far end; rows 4–76 see the nitinol shaft only.
    let mut wire = Layers::new();
    wire.add_device(
        &wire_down_column(&carm, 64.0),
        &DeviceAppearance::microwire_014(),
    )
    .unwrap();
    // Hand contrast on the column: the centre ray crosses the full 0.356 mm of nitinol, which
    // displaces water (μ nitinol 760 / 380 1/m at 60 / 80 keV).
    let d = 2.0 * 0.178e-3;
    let t = |nitinol: f64| -> f64 {
        [(0.5f64, 20.6f64, 760.0f64), (0.5, 18.4, 380.0)]
            .iter()
            .map(|(w, mu_w, mu_n)| w * (-mu_w * 0.2 - (mu_n - mu_w) * nitinol).exp())
            .sum()
    };
    let contrast_by_hand = -(t(d) / t(0.0)).ln();
    let q = dose::quanta_per_mm2_per_ugy(&Spectrum::default());
    let quanta = 0.03 * q * (carm.detector.pixel_pitch_m() * 1e3).powi(2);
    let by_hand = contrast_by_hand * quanta.sqrt();
    // Eight pulses, to bring the on-wire mean's sampling error to ~1 %.
    let mut c = chain(settings(true));
    let frames: Vec<Frame> = (0..8)
        .map(|_| shoot(&mut c, &volume, &carm, &wire))
        .collect();
    let at = |f: &Frame, u: usize, v: usize| f64::from(f.values[v * 128 + u]);
    let (on, _) = mean_var(frames.iter().flat_map(|f| (4..76).map(|v| at(f, 64, v))));
    let (off, var) = mean_var(frames.iter().flat_map(|f| {
        (4..76)
            .flat_map(|v| (20..44).chain(84..108).map(move |u| (u, v)))
            .map(|(u, v)| at(f, u, v))
    }));
    let measured = (on - off) / var.sqrt();
    println!(
        "0.014\" wire in fluoroscopy (0.03 µGy per pulse): CNR {measured:.2} on its column, by hand {by_hand:.2}"
    );
    assert!(
        (measured / by_hand - 1.0).abs() < 0.1,
        "{measured} vs {by_hand}"
    );
}

#[test]
fn the_scatter_kernel_spreads_the_primary_without_gaining_or_losing_any() {
    use cathlab_xray::processing::{ScatterSettings, add_scatter};
    // A 4 × 4 mm bright square in the middle of a dark 128 mm field, 0.5 mm pixels; a 10 mm
    // kernel, no grid loss, SPR 1: the fog carries exactly the primary's energy once more.
    let n = 256usize;
    let mut t = vec![0.0f32; n * n];
    for v in 124..132 {
        for u in 124..132 {
            t[v * n + u] = 1.0;
        }
    }
    let primary: f64 = t.iter().map(|x| f64::from(*x)).sum();
    let settings = ScatterSettings {
        scatter_to_primary: 1.0,
        kernel_sigma_m: 0.01,
        grid_primary_transmission: 1.0,
        grid_scatter_transmission: 1.0,
    };
    let before = t.clone();
    add_scatter(&mut t, n as u32, n as u32, 0.5e-3, &settings);
    let fog: Vec<f64> = t
        .iter()
        .zip(&before)
        .map(|(a, b)| f64::from(a - b))
        .collect();
    let total: f64 = fog.iter().sum();
    // Its spread: the second moment about the centre along u, against σ² = (20 px)² plus the
    // square's own (8² − 1)/12 px².
    let c = 127.5;
    let second: f64 = fog
        .iter()
        .enumerate()
        .map(|(i, f)| f * ((i % n) as f64 - c).powi(2))
        .sum::<f64>()
        / total;
    let sigma = second.sqrt();
    let expected = (400.0f64 + 63.0 / 12.0).sqrt();
    println!(
        "scatter: fog energy {:.5} of the primary's; spread σ {sigma:.2} px (kernel and source {expected:.2})",
        total / primary
    );
    assert!((total / primary - 1.0).abs() < 1e-3, "{total} vs {primary}");
    assert!(
        (sigma / expected - 1.0).abs() < 0.1,
        "{sigma} vs {expected}"
    );
}

#[test]
fn scatter_behind_a_grid_lowers_a_vessels_contrast_by_the_residual_scatter() {
    use cathlab_xray::ScatterSettings;
    let (volume, carm) = (slab(), carm(128));
    let vessel = vessel_layer();
    let contrast = |scatter: Option<ScatterSettings>| {
        let mut s = settings(false);
        s.scatter = scatter;
        let frame = shoot(&mut chain(s), &volume, &carm, &vessel);
        let at = |v: usize| f64::from(frame.values[v * 128 + 64]);
        0.5 * (at(63) + at(64)) - at(30)
    };
    let primary = contrast(None);
    let grid = ScatterSettings::default();
    let r = grid.residual_scatter_to_primary();
    let with = contrast(Some(grid));
    // By hand, the fog over a thin vessel being the slab's: −ln((e^−c + r)/(1 + r)).
    let by_hand = -(((-primary).exp() + r) / (1.0 + r)).ln();
    let no_grid = contrast(Some(ScatterSettings {
        grid_primary_transmission: 1.0,
        grid_scatter_transmission: 1.0,
        ..grid
    }));
    println!(
        "vessel contrast: primary only {primary:.4}; SPR 1 behind a 10:1 grid {with:.4} (hand {by_hand:.4}, residual SPR {r:.3}); without the grid {no_grid:.4}"
    );
    assert!((with / by_hand - 1.0).abs() < 0.02, "{with} vs {by_hand}");
    assert!(no_grid < with && with < primary);
}

#[test]
fn edge_enhancement_multiplies_white_noise_variance_by_its_filters_energy() {
    use cathlab_xray::processing::unsharp_mask;
    let n = 256usize;
    // Uniform white noise from a 64-bit LCG.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut noise = || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((state >> 40) as f64 / (1u64 << 24) as f64 - 0.5) as f32
    };
    let image: Vec<f32> = (0..n * n).map(|_| noise()).collect();
    let (sigma, amount) = (2.0f64, 0.6f64);
    let mut sharpened = image.clone();
    unsharp_mask(&mut sharpened, n as u32, n as u32, sigma, amount);
    // The filter by hand: h = (1 + a)δ − a·g, g the separable Gaussian cut at 3σ.
    let radius = (3.0 * sigma).ceil() as i32;
    let taps: Vec<f64> = (-radius..=radius)
        .map(|i| (-(f64::from(i * i)) / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = taps.iter().sum();
    let g1: Vec<f64> = taps.iter().map(|t| t / sum).collect();
    let g0 = g1[radius as usize].powi(2);
    let g2 = g1.iter().map(|t| t * t).sum::<f64>().powi(2);
    let gain_by_hand =
        (1.0 + amount).powi(2) - 2.0 * amount * (1.0 + amount) * g0 + amount * amount * g2;
    // Away from the clamped edges.
    let inner = |img: &[f32]| {
        mean_var(
            (16..n - 16)
                .flat_map(|v| (16..n - 16).map(move |u| (u, v)))
                .map(|(u, v)| f64::from(img[v * n + u])),
        )
        .1
    };
    let gain = inner(&sharpened) / inner(&image);
    println!(
        "edge enhancement σ {sigma} px, amount {amount}: noise variance × {gain:.4} (hand {gain_by_hand:.4})"
    );
    assert!(
        (gain / gain_by_hand - 1.0).abs() < 0.03,
        "{gain} vs {gain_by_hand}"
    );
}

/// The 3 mm, 150 mgI/mL vessel across the field at the isocenter.
fn vessel_layer() -> Layers {
    let mut vessel = Layers::new();
    vessel
        .add_contrast(
            &[ContrastTube {
                start: Point3::new(-0.05, 0.0, 0.0),
                end: Point3::new(0.05, 0.0, 0.0),
                start_radius_m: 1.5e-3,
                end_radius_m: 1.5e-3,
                concentration_mg_per_ml: 150.0,
            }],
            1.0,
        )
        .unwrap();
    vessel
}

/// The ends of a wire down pixel column `u` of `carm` (through the pixel centres at the
/// isocenter), rows 0 to 127.
fn wire_down_column(carm: &CArm, u: f64) -> Vec<Point3<f64>> {
    [0.0, 127.0]
        .iter()
        .map(|&v| {
            let ray = carm.ray(u, v);
            ray.origin + ray.direction * carm.source_to_isocenter_m
        })
        .collect()
}

#[test]
fn the_roadmap_keeps_no_ghost_of_a_wire_that_moved_after_the_dsa_run() {
    let (volume, carm) = (slab(), carm(128));
    let mut s = settings(false);
    s.mask_frames = 3;
    let mut c = chain(s);
    // The DSA run: the wire down column 30 throughout, contrast after the mask.
    let mut wire_at_30 = Layers::new();
    wire_at_30
        .add_device(
            &wire_down_column(&carm, 30.0),
            &DeviceAppearance::guidewire_035(),
        )
        .unwrap();
    let mut with_contrast = vessel_layer();
    with_contrast
        .add_device(
            &wire_down_column(&carm, 30.0),
            &DeviceAppearance::guidewire_035(),
        )
        .unwrap();
    c.set_mode(ImagingMode::Subtraction, &carm).unwrap();
    for _ in 0..3 {
        shoot(&mut c, &volume, &carm, &wire_at_30);
    }
    let dsa = shoot(&mut c, &volume, &carm, &with_contrast);
    // Then the wire moves to column 90 and the roadmap goes on.
    c.set_mode(ImagingMode::Roadmap, &carm).unwrap();
    let mut wire_at_90 = Layers::new();
    wire_at_90
        .add_device(
            &wire_down_column(&carm, 90.0),
            &DeviceAppearance::guidewire_035(),
        )
        .unwrap();
    let roadmap = shoot(&mut c, &volume, &carm, &wire_at_90);
    let at = |f: &Frame, u: usize, v: usize| f.values[v * 128 + u];
    println!(
        "wire column in DSA {:.3}; roadmap at the old wire {:.5}, at the new wire {:.3}, on the vessel {:.3}",
        at(&dsa, 30, 20),
        at(&roadmap, 30, 20),
        at(&roadmap, 90, 20),
        at(&roadmap, 64, 63)
    );
    // The DSA frame shows the wire dark (its mask left it out); the roadmap shows the new
    // wire dark, the vessel white, and nothing where the wire was.
    assert!(at(&dsa, 30, 20) > 0.1);
    for v in [10, 20, 40, 100] {
        assert!(
            at(&roadmap, 30, v).abs() < 1e-4,
            "ghost at row {v}: {}",
            at(&roadmap, 30, v)
        );
    }
    assert!(at(&roadmap, 90, 20) > 0.1);
    assert!(at(&roadmap, 64, 63) < -0.1);
}

#[test]
fn the_roadmaps_vessel_map_is_clean_and_its_vessels_stand_out_of_the_noise() {
    let (volume, carm) = (slab(), carm(128));
    // The same noisy run twice, with and without contrast during the DSA frames: the roadmap
    // frames then differ by the vessel map exactly (same masks, same live noise).
    let roadmap = |contrast: bool| {
        let mut s = settings(true);
        s.mask_frames = 3;
        let mut c = chain(s);
        c.set_mode(ImagingMode::Subtraction, &carm).unwrap();
        for _ in 0..3 {
            shoot(&mut c, &volume, &carm, &Layers::new());
        }
        let run = if contrast {
            vessel_layer()
        } else {
            Layers::new()
        };
        for _ in 0..10 {
            shoot(&mut c, &volume, &carm, &run);
        }
        c.set_mode(ImagingMode::Roadmap, &carm).unwrap();
        shoot(&mut c, &volume, &carm, &Layers::new())
    };
    let (frame, empty) = (roadmap(true), roadmap(false));
    let row = |v: usize| {
        frame.values[v * 128 + 8..v * 128 + 120]
            .iter()
            .map(|x| f64::from(*x))
    };
    let (vessel, _) = mean_var([63, 64].iter().flat_map(|&v| row(v)));
    // The vessel projects 3.2 px either side of row 63.5; the background is well clear of it.
    let background_rows = (8..52).chain(76..120);
    let (background, var) = mean_var(background_rows.clone().flat_map(row));
    let ratio = (background - vessel) / var.sqrt();
    let in_map = |u: usize, v: usize| frame.values[v * 128 + u] != empty.values[v * 128 + u];
    let stray = background_rows
        .flat_map(|v| (0..128).map(move |u| (u, v)))
        .filter(|&(u, v)| in_map(u, v))
        .count();
    let on_vessel = (0..128).filter(|&u| in_map(u, 63) && in_map(u, 64)).count();
    println!(
        "roadmap: vessel {vessel:.3}, background {background:.4} ± {:.4}: contrast {ratio:.1}× the noise; vessel map on {on_vessel} of 128 columns, {stray} pixels of it off the vessel",
        var.sqrt()
    );
    assert!(ratio >= 5.0, "{ratio}");
    assert_eq!(stray, 0);
    assert_eq!(on_vessel, 128);
}

#[test]
fn motion_adaptive_recursion_keeps_the_noise_cut_and_leaves_no_lag_behind_a_moving_wire() {
    let (volume, carm) = (slab(), carm(128));
    let clean = chain_clean_fluoro(&volume, &carm);
    let configured = |adaptive: bool| {
        let mut s = settings(true);
        s.recursive_weight = 0.5;
        s.motion_adaptive = adaptive;
        chain(s)
    };
    // A still scene: the adaptive filter keeps most of the variance cut (1/3 at α = 0.5);
    // only noise beyond 2σ of the expected difference is let through, partly.
    let mut still = configured(true);
    let mut plain = chain(settings(true));
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for _ in 0..60 {
        a = shoot(&mut plain, &volume, &carm, &Layers::new()).values;
        b = shoot(&mut still, &volume, &carm, &Layers::new()).values;
    }
    let ratio = noise_variance(&b, &clean) / noise_variance(&a, &clean);
    println!("motion-adaptive, still scene: variance ratio {ratio:.3} (plain recursion 0.333)");
    assert!(ratio < 0.4, "{ratio}");
    // A 0.035" wire held down column 40 for 10 pulses, then moved to column 88.
    let wire_at = |u: f64| {
        let mut l = Layers::new();
        l.add_device(
            &wire_down_column(&carm, u),
            &DeviceAppearance::guidewire_035(),
        )
        .unwrap();
        l
    };
    let column = |f: &Frame, u: usize| -> f64 {
        (4..124)
            .map(|v| f64::from(f.values[v * 128 + u]))
            .sum::<f64>()
            / 120.0
    };
    let background = |f: &Frame| -> f64 {
        (4..124)
            .flat_map(|v| (60..70).map(move |u| (u, v)))
            .map(|(u, v)| f64::from(f.values[v * 128 + u]))
            .sum::<f64>()
            / 1200.0
    };
    let mut lags = Vec::new();
    for adaptive in [false, true] {
        let mut c = configured(adaptive);
        let mut held = shoot(&mut c, &volume, &carm, &wire_at(40.0));
        for _ in 0..9 {
            held = shoot(&mut c, &volume, &carm, &wire_at(40.0));
        }
        let contrast = column(&held, 40) - background(&held);
        let moved = shoot(&mut c, &volume, &carm, &wire_at(88.0));
        let ghost = (column(&moved, 40) - background(&moved)) / contrast;
        let shown = (column(&moved, 88) - background(&moved)) / contrast;
        println!(
            "{}: after the move the old position keeps {ghost:.3} of the wire, the new shows {shown:.3}",
            if adaptive {
                "motion-adaptive"
            } else {
                "plain recursion"
            }
        );
        lags.push((ghost, shown));
    }
    // Plain recursion at α = 0.5 lags by half: ghost 0.5, new position 0.5.
    assert!(
        (lags[0].0 - 0.5).abs() < 0.05 && (lags[0].1 - 0.5).abs() < 0.05,
        "{lags:?}"
    );
    assert!(lags[1].0 < 0.1 && lags[1].1 > 0.9, "{lags:?}");
}

/// Water with bony spheres (structure to register on), centred at `centre` (m).
fn bony(centre: Vector3<f64>) -> Arc<Volume> {
    let spheres = [
        (Vector3::new(-0.02, 0.0, 0.015), 0.012),
        (Vector3::new(0.018, 0.01, -0.02), 0.009),
        (Vector3::new(0.005, -0.02, 0.025), 0.007),
        (Vector3::new(-0.015, 0.02, -0.01), 0.01),
    ];
    Arc::new(
        Volume::from_fn([60; 3], Vector3::repeat(2e-3), centre, 2, |p| {
            let q = p.coords - centre;
            if q.y.abs() > 0.05 {
                -1000.0
            } else if spheres.iter().any(|(c, r)| (q - c).norm() < *r) {
                1200.0
            } else {
                0.0
            }
        })
        .unwrap(),
    )
}

#[test]
fn pixel_shift_registers_the_mask_after_the_patient_moved() {
    let carm = carm(128);
    // The patient moves 1.2 mm to the left after the mask: 1.92 pixels at the detector
    // (0.94 mm pixels, magnification 1.5), on the detector's u axis.
    let (eu, _) = carm.detector_axes();
    let moved = Vector3::new(1.2e-3, 0.0, 0.0);
    let expected = moved.dot(&eu) * carm.magnification() / carm.detector.pixel_pitch_m();
    let (before, after) = (bony(Vector3::zeros()), bony(moved));
    let mut residuals = Vec::new();
    for correct in [false, true] {
        let mut s = settings(true);
        s.mask_frames = 3;
        s.pixel_shift = correct;
        let mut c = chain(s);
        c.set_mode(ImagingMode::Subtraction, &carm).unwrap();
        for _ in 0..3 {
            shoot(&mut c, &before, &carm, &Layers::new());
        }
        let still = shoot(&mut c, &before, &carm, &Layers::new());
        // Contrast arriving in a still patient moves nothing (a regression: registering the
        // live frame itself let the iodine pull the mask off and printed bone edges into the
        // roadmap).
        shoot(&mut c, &before, &carm, &vessel_layer());
        assert_eq!(c.pixel_shift(), Some((0.0, 0.0)));
        let live = shoot(&mut c, &after, &carm, &Layers::new());
        let variance = |f: &Frame| mean_var(f.values.iter().map(|v| f64::from(*v))).1;
        let (noise, moved_residual) = (variance(&still), variance(&live));
        let shift = c.pixel_shift().unwrap();
        println!(
            "pixel shift {}: subtraction variance {noise:.2e} before the move, {moved_residual:.2e} after; shift found ({:.2}, {:.2}) px, expected ({expected:.2}, 0)",
            if correct { "on" } else { "off" },
            shift.0,
            shift.1
        );
        if correct {
            assert!(
                (shift.0 - expected).abs() < 0.2 && shift.1.abs() < 0.2,
                "{shift:?}"
            );
        }
        residuals.push(moved_residual / noise);
    }
    // Uncorrected, the spheres' edges stand out of the noise; corrected, they (nearly) vanish.
    assert!(residuals[0] > 3.0, "{residuals:?}");
    assert!(residuals[1] < 1.5, "{residuals:?}");
}
