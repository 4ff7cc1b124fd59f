//! The imaging chain: polyenergetic transmission against hand-computed Beer–Lambert, Poisson
//! noise statistics and seeding, blur, window/level, pulse rates, last-image hold, the
//! background cache, DSA and roadmap.

use std::sync::Arc;

use cathlab_xray::detector::{self, DetectorSettings, expose, gaussian_blur};
use cathlab_xray::layers::{ContrastTube, DeviceAppearance, Layers};
use cathlab_xray::spectrum::{EnergyBin, MaterialAttenuation, MaterialPaths, Spectrum};
use cathlab_xray::{
    CArm, CpuRenderer, DetectorGeometry, Fluoroscope, FluoroscopeSettings, ImagingMode, PathImage,
    PulseRate, Scene, Volume, XrayError,
};
use nalgebra::{Point3, Vector3};

fn geometry(size: u32) -> DetectorGeometry {
    DetectorGeometry {
        width_px: size,
        height_px: size,
        field_of_view_m: 0.2,
        collimation: (1.0, 1.0),
    }
}

#[test]
fn polyenergetic_transmission_is_the_weighted_sum_of_beer_lambert_per_bin() {
    let spectrum = Spectrum::default();
    let paths = MaterialPaths {
        water: 0.15,
        bone: 0.01,
        iodine: 0.002,
        nitinol: 0.0005,
        platinum: 0.0001,
    };
    let by_hand = |mu: MaterialAttenuation| {
        (-(mu.water * (0.15 - 0.01 - 0.0005 - 0.0001)
            + mu.cortical_bone * 0.01
            + mu.iodine_300 * 0.002
            + mu.nitinol * 0.0005
            + mu.platinum * 0.0001))
            .exp()
    };
    let expected =
        0.5 * by_hand(MaterialAttenuation::KEV_60) + 0.5 * by_hand(MaterialAttenuation::KEV_80);
    assert!((spectrum.transmission(&paths) / expected - 1.0).abs() < 1e-12);
    // Beam hardening: the effective μ of water falls with depth in a two-bin beam.
    let mu_eff = |depth: f64| {
        -spectrum
            .transmission(&MaterialPaths {
                water: depth,
                ..MaterialPaths::default()
            })
            .ln()
            / depth
    };
    assert!(mu_eff(0.01) > mu_eff(0.2) && mu_eff(0.2) > 18.4 && mu_eff(0.01) < 20.6);
    // Bad spectra are refused by name.
    let err = Spectrum::new(vec![EnergyBin {
        kev: 60.0,
        weight: f64::NAN,
        attenuation: MaterialAttenuation::KEV_60,
    }])
    .unwrap_err();
    assert!(err.to_string().contains("bin 0 weight"), "{err}");
    assert!(Spectrum::monoenergetic(70.0).is_err());
}

#[test]
fn quantum_noise_is_poisson_seeded_and_reproducible() {
    let g = geometry(256);
    let n0 = 400.0;
    let t = (-1.0f64).exp();
    let transmitted = vec![t as f32; 256 * 256];
    let settings = DetectorSettings {
        photons_per_pixel: n0,
        noise: true,
        blur_sigma_px: 0.0,
        seed: 7,
        ..DetectorSettings::default()
    };
    let a = expose(&transmitted, &g, &settings, 3);
    let counts: Vec<f64> = a.iter().map(|&l| n0 * (-f64::from(l)).exp()).collect();
    let n = counts.len() as f64;
    let mean = counts.iter().sum::<f64>() / n;
    let var = counts.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let expected = n0 * t;
    println!("counts: mean {mean:.2} (expected {expected:.2}), variance {var:.2}");
    // Mean within 4 standard errors, variance within 3 % of the mean (Poisson).
    assert!(
        (mean - expected).abs() < 4.0 * (expected / n).sqrt(),
        "{mean}"
    );
    assert!((var / expected - 1.0).abs() < 0.03, "{var}");
    // Counts are integers.
    assert!(
        counts
            .iter()
            .all(|c| (c - c.round()).abs() < 1e-3 * c.max(1.0))
    );
    // Same seed and frame: identical; another frame: different.
    assert_eq!(a, expose(&transmitted, &g, &settings, 3));
    assert_ne!(a, expose(&transmitted, &g, &settings, 4));
    // Without noise the log transform returns the line integral exactly.
    let clean = expose(
        &transmitted,
        &g,
        &DetectorSettings {
            noise: false,
            ..settings
        },
        0,
    );
    assert!(clean.iter().all(|&l| (f64::from(l) - 1.0).abs() < 1e-6));
}

#[test]
fn blur_conserves_signal_and_collimation_blacks_out_the_edges() {
    let (w, h) = (40, 30);
    let mut image = vec![0.0f32; w * h];
    image[15 * w + 20] = 1.0;
    gaussian_blur(&mut image, w, h, 1.5);
    let total: f32 = image.iter().sum();
    assert!((total - 1.0).abs() < 1e-5, "{total}");
    // Symmetric, peaked at the impulse, second moment σ² along a row.
    let row = &image[15 * w..16 * w];
    let sum: f32 = row.iter().sum();
    let var: f32 = row
        .iter()
        .enumerate()
        .map(|(u, x)| x * (u as f32 - 20.0).powi(2))
        .sum::<f32>()
        / sum;
    assert!((var - 2.25).abs() < 0.05, "{var}");
    assert!((image[15 * w + 19] - image[15 * w + 21]).abs() < 1e-7);
    let mut g = geometry(64);
    g.collimation = (0.5, 1.0);
    let values = expose(&vec![0.5; 64 * 64], &g, &DetectorSettings::default(), 0);
    // Half the width open: columns 16..=47 see the beam.
    assert!(values[0].is_nan() && values[15].is_nan() && !values[16].is_nan());
    assert!(!values[32 * 64 + 32].is_nan() && values[32 * 64 + 63].is_nan());
    let grey = detector::encode_8bit(&values, 6.0, 3.5);
    assert_eq!(grey[32 * 64], 0);
}

#[test]
fn window_level_maps_attenuation_to_darker_grey_in_8_and_16_bits() {
    let values = [0.0f32, 0.5, 3.5, 6.5, 7.0, f32::NAN];
    let g8 = detector::encode_8bit(&values, 6.0, 3.5);
    let g16 = detector::encode_16bit(&values, 6.0, 3.5);
    assert_eq!(g8, vec![255, 255, 128, 0, 0, 0]);
    assert_eq!(g16[2], 32768);
    assert!(g16.windows(2).take(4).all(|p| p[0] >= p[1]));
}

/// A 48³ water cube in air, with an iodine tube and a wire across it.
struct Bench {
    volume: Arc<Volume>,
    carm: CArm,
    contrast: Layers,
    wire: Layers,
}

fn bench() -> Bench {
    let volume = Arc::new(
        Volume::from_fn([48; 3], Vector3::repeat(2e-3), Vector3::zeros(), 1, |p| {
            if p.coords.amax() < 0.04 { 0.0 } else { -1000.0 }
        })
        .unwrap(),
    );
    let carm = CArm {
        detector: geometry(64),
        ..CArm::default()
    };
    let mut contrast = Layers::new();
    contrast
        .add_contrast(
            &[ContrastTube {
                start: Point3::new(-0.03, 0.0, 0.01),
                end: Point3::new(0.03, 0.0, 0.01),
                start_radius_m: 3e-3,
                end_radius_m: 3e-3,
                concentration_mg_per_ml: 300.0,
            }],
            1.0,
        )
        .unwrap();
    // The wire runs down pixel column 32 (through the pixel centres at the isocenter).
    let on_column = |v: f64| {
        let ray = carm.ray(32.0, v);
        ray.origin + ray.direction * carm.source_to_isocenter_m
    };
    let mut wire = Layers::new();
    wire.add_device(
        &[on_column(8.0), on_column(56.0)],
        &DeviceAppearance::guidewire_035(),
    )
    .unwrap();
    Bench {
        volume,
        carm,
        contrast,
        wire,
    }
}

fn chain(noise: bool) -> Fluoroscope {
    let mut settings = FluoroscopeSettings::default();
    settings.detector.noise = noise;
    settings.detector.blur_sigma_px = 0.0;
    Fluoroscope::new(Box::new(CpuRenderer::default()), settings).unwrap()
}

#[test]
fn pulses_come_at_the_set_rate_and_the_last_image_is_held() {
    let b = bench();
    let empty = Layers::new();
    let scene = Scene {
        volume: &b.volume,
        carm: &b.carm,
        layers: &empty,
    };
    for (rate, expected) in [
        (PulseRate::Hz7_5, 8),
        (PulseRate::Hz15, 15),
        (PulseRate::Hz30, 30),
    ] {
        let mut f = chain(false);
        f.set_pulse_rate(rate);
        let mut new = 0;
        // 1 s of 1 kHz ticks with the pedal down.
        for k in 0..1000 {
            let t = k as f64 * 1e-3;
            if let Some(frame) = f.update(t, true, scene).unwrap()
                && !frame.held
                && (frame.time_s - t).abs() < 1e-12
            {
                new += 1;
            }
        }
        assert_eq!(f.stats().exposures, expected, "{rate:?}");
        assert_eq!(new, expected);
        // The background was projected once for all those pulses.
        assert_eq!(f.stats().background_renders, 1);
        // Pedal up: the last image stays, held, and nothing is exposed.
        let held = f.update(1.5, false, scene).unwrap().unwrap();
        assert!(held.held);
        assert_eq!(f.stats().exposures, expected);
    }
    // Nothing to hold before the first exposure.
    assert!(chain(false).update(0.0, false, scene).unwrap().is_none());
}

#[test]
fn the_background_is_rendered_again_only_when_the_pose_or_volume_changes() {
    let b = bench();
    let mut f = chain(true);
    let empty = Layers::new();
    let mut carm = b.carm;
    for (k, change) in ["same", "same", "pose", "same", "volume"]
        .iter()
        .enumerate()
    {
        let volume = if *change == "volume" {
            Arc::new((*b.volume).clone())
        } else {
            b.volume.clone()
        };
        if *change == "pose" {
            carm.primary_deg += 10.0;
        }
        f.expose(
            k as f64,
            Scene {
                volume: &volume,
                carm: &carm,
                layers: &empty,
            },
        )
        .unwrap();
    }
    assert_eq!(f.stats().background_renders, 3);
}

/// Value of the frame at the detector pixel onto which `p` projects.
fn at(frame: &cathlab_xray::Frame, carm: &CArm, p: Point3<f64>) -> f32 {
    let uv = carm.project(&p).unwrap();
    frame.values[uv.y.round() as usize * frame.width as usize + uv.x.round() as usize]
}

#[test]
fn dsa_keeps_only_the_contrast_and_roadmap_shows_vessels_white_and_devices_dark() {
    let b = bench();
    let mut f = chain(false);
    let shot = |layers| Scene {
        volume: &b.volume,
        carm: &b.carm,
        layers,
    };
    // A roadmap needs a DSA run first.
    let err = f.set_mode(ImagingMode::Roadmap, &b.carm).unwrap_err();
    assert!(matches!(err, XrayError::Unavailable(_)), "{err}");
    f.set_mode(ImagingMode::Subtraction, &b.carm).unwrap();
    let empty = Layers::new();
    let mask = f.expose(0.0, shot(&empty)).unwrap();
    assert!(
        mask.values.iter().all(|&v| v == 0.0),
        "the mask subtracts to zero"
    );
    let dsa = f.expose(0.5, shot(&b.contrast)).unwrap();
    // Off the vessel the water cube is gone; on it, the iodine's own attenuation remains:
    // −ln of the transmission ratio through 6 mm of iodine-300 behind 80 mm of water.
    let off = at(&dsa, &b.carm, Point3::new(0.0, 0.0, -0.02));
    let on = at(&dsa, &b.carm, Point3::new(0.0, 0.0, 0.01));
    // That pixel's ray: its exact iodine chord, and 80 mm of water across the cube.
    let uv = b.carm.project(&Point3::new(0.0, 0.0, 0.01)).unwrap();
    let ray = b.carm.ray(uv.x.round(), uv.y.round());
    let spectrum = Spectrum::default();
    let water = MaterialPaths {
        water: 0.08 / ray.direction.y.abs(),
        ..MaterialPaths::default()
    };
    let with_iodine = MaterialPaths {
        iodine: b.contrast.paths_along(&ray.origin, &ray.direction)[0],
        ..water
    };
    let expected = (spectrum.transmission(&water) / spectrum.transmission(&with_iodine)).ln();
    println!("DSA: {on:.5} on the vessel (Beer–Lambert by hand {expected:.5}), {off:.1e} off it");
    assert!(off.abs() < 1e-6);
    assert!(
        (f64::from(on) / expected - 1.0).abs() < 1e-3,
        "{on} vs {expected}"
    );
    // Roadmap at the same pose: live fluoroscopy with the wire, minus mask and vessel map.
    f.set_mode(ImagingMode::Roadmap, &b.carm).unwrap();
    let road = f.expose(1.0, shot(&b.wire)).unwrap();
    let vessel = at(&road, &b.carm, Point3::new(0.02, 0.0, 0.01));
    let device = road.values[40 * 64 + 32];
    let background = at(&road, &b.carm, Point3::new(0.02, 0.0, -0.02));
    println!("roadmap: vessel {vessel:.3}, device {device:.3}, background {background:.1e}");
    let depth = FluoroscopeSettings::default()
        .roadmap_vessel_depth
        .min(expected);
    assert!(
        (f64::from(vessel) + depth).abs() < 1e-5,
        "vessels white (negative): {vessel}"
    );
    assert!(device > 0.3, "devices dark (positive)");
    assert!(background.abs() < 1e-6);
    assert_eq!(road.window.1, 0.0, "subtracted images are centred on grey");
    // Moving the C-arm invalidates the roadmap.
    let mut moved = b.carm;
    moved.primary_deg = 20.0;
    f.set_mode(ImagingMode::Fluoroscopy, &moved).unwrap();
    assert!(f.set_mode(ImagingMode::Roadmap, &moved).is_err());
}

#[test]
fn bad_detector_and_chain_settings_are_refused_by_name() {
    let mut settings = FluoroscopeSettings::default();
    settings.detector.photons_per_pixel = 0.0;
    let err = Fluoroscope::new(Box::new(CpuRenderer::default()), settings)
        .err()
        .unwrap();
    assert!(err.to_string().contains("photons per pixel"), "{err}");
    let mut settings = FluoroscopeSettings::default();
    settings.march.step_voxels = f64::NAN;
    let err = Fluoroscope::new(Box::new(CpuRenderer::default()), settings)
        .err()
        .unwrap();
    assert!(err.to_string().contains("ray-march step"), "{err}");
    let b = bench();
    let mut f = chain(false);
    let mut carm = b.carm;
    carm.detector.width_px = 0;
    let empty = Layers::new();
    let err = f
        .expose(
            0.0,
            Scene {
                volume: &b.volume,
                carm: &carm,
                layers: &empty,
            },
        )
        .unwrap_err();
    assert!(err.to_string().contains("width"), "{err}");
    let err = f
        .update(
            f64::NAN,
            true,
            Scene {
                volume: &b.volume,
                carm: &b.carm,
                layers: &empty,
            },
        )
        .unwrap_err();
    assert!(err.to_string().contains("time"), "{err}");
    let _ = PathImage::zeros(1, 1, 1);
}
