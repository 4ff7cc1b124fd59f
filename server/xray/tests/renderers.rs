//! The two renderers: the CPU reference against exact sphere chords through the whole
//! projection path, and the wgpu renderer against the CPU one on the same scenes (line
//! integrals within 1e-3). GPU tests skip only when no adapter exists and
//! `CATHLAB_REQUIRE_GPU` is unset.

use std::sync::Arc;

use cathlab_xray::layers::{ContrastTube, DeviceAppearance, Layers};
use cathlab_xray::spectrum::MaterialAttenuation;
use cathlab_xray::{CArm, CpuRenderer, GpuRenderer, MarchSettings, PathImage, Renderer, Volume};
use nalgebra::{Point3, Vector3};

/// 128³ voxels of 1 mm: a water ball of radius 50 mm holding a bone ball of radius 25 mm
/// off-centre, in air.
fn balls() -> Arc<Volume> {
    let bone_centre = Vector3::new(0.012, -0.008, 0.004);
    Arc::new(
        Volume::from_fn([128; 3], Vector3::repeat(1e-3), Vector3::zeros(), 4, |p| {
            if (p.coords - bone_centre).norm() < 0.025 {
                1913.0
            } else if p.coords.norm() < 0.05 {
                0.0
            } else {
                -1000.0
            }
        })
        .unwrap(),
    )
}

/// The aorta file's intensities are not HU (tissue ≈ 250, contrast-filled lumen ≈ 2000):
/// calibrated so that tissue is 40 HU and the lumen 400 HU, as in the scene files.
const AORTA_HU_SLOPE: f64 = 0.2057;
const AORTA_HU_INTERCEPT: f64 = -11.4;

fn carm(size: u32, primary: f64, secondary: f64) -> CArm {
    let mut c = CArm {
        primary_deg: primary,
        secondary_deg: secondary,
        ..CArm::default()
    };
    c.detector.width_px = size;
    c.detector.height_px = size;
    c.detector.field_of_view_m = 0.2;
    c
}

/// Exact chord of a ray through a ball.
fn ball_chord(origin: &Point3<f64>, d: &Vector3<f64>, centre: &Vector3<f64>, r: f64) -> f64 {
    let w = origin.coords - centre;
    let b = w.dot(d);
    let disc = b * b - (w.norm_squared() - r * r);
    if disc > 0.0 { 2.0 * disc.sqrt() } else { 0.0 }
}

#[test]
fn cpu_background_matches_exact_ball_chords_within_half_a_percent() {
    let volume = balls();
    let c = carm(64, 30.0, 20.0);
    let image = CpuRenderer::default()
        .project_volume(&volume, &c, &MarchSettings::default())
        .unwrap();
    let grid = c.ray_grid();
    let bone_centre = Vector3::new(0.012, -0.008, 0.004);
    let mu = MaterialAttenuation::KEV_60.channel_coefficients();
    let mut worst: f64 = 0.0;
    let mut checked = 0;
    for v in 0..64 {
        for u in 0..64 {
            let ray = grid.ray(f64::from(u), f64::from(v));
            let water = ball_chord(&ray.origin, &ray.direction, &Vector3::zeros(), 0.05);
            let bone = ball_chord(&ray.origin, &ray.direction, &bone_centre, 0.025);
            // Rays within 0.8 radius of the water ball's centre and 3 voxels off the bone
            // ball's rim: near-tangent rays run far through the phantom's partial-volume
            // shell, where the blurred surface is not the sharp ball (a voxelization effect).
            let miss = |centre: &Vector3<f64>| {
                let w = ray.origin.coords - centre;
                (w - ray.direction * w.dot(&ray.direction)).norm()
            };
            if miss(&Vector3::zeros()) > 0.8 * 0.05 || (miss(&bone_centre) - 0.025).abs() < 3e-3 {
                continue;
            }
            let i = (v * 64 + u) as usize;
            let exact = mu[0] * water + mu[1] * bone;
            let got =
                mu[0] * f64::from(image.channels[0][i]) + mu[1] * f64::from(image.channels[1][i]);
            worst = worst.max((got / exact - 1.0).abs());
            checked += 1;
        }
    }
    println!("balls at LAO 30 CRA 20: {checked} rays, worst relative error {worst:.2e}");
    assert!(checked > 500);
    assert!(worst < 5e-3, "{worst}");
}

fn layers() -> Layers {
    let mut layers = Layers::new();
    let wire: Vec<Point3<f64>> = (0..60)
        .map(|i| {
            let s = i as f64 * 0.002;
            Point3::new(0.03 * (s * 30.0).sin(), 0.01 * (s * 10.0).cos(), -0.06 + s)
        })
        .collect();
    layers
        .add_device(&wire, &DeviceAppearance::guidewire_035())
        .unwrap();
    layers
        .add_device(&wire[..30], &DeviceAppearance::catheter_5f())
        .unwrap();
    let tubes: Vec<ContrastTube> = (0..40)
        .map(|i| {
            let s = i as f64 * 0.003;
            let at = |s: f64| Point3::new(-0.04 + 0.02 * (s * 12.0).cos(), 0.0, -0.06 + s);
            ContrastTube {
                start: at(s),
                end: at(s + 0.003),
                start_radius_m: 0.003 - 0.01 * s,
                end_radius_m: 0.003 - 0.01 * (s + 0.003),
                concentration_mg_per_ml: 300.0 * (1.0 - s * 5.0).max(0.1),
            }
        })
        .collect();
    layers.add_contrast(&tubes, 1.0).unwrap();
    layers
}

/// Largest difference in 60 keV line integral between two path images.
fn line_integral_difference(a: &PathImage, b: &PathImage, coefficients: &[f64]) -> (f64, f64) {
    let mut worst: f64 = 0.0;
    let mut largest: f64 = 0.0;
    for i in 0..a.len() {
        let l = |img: &PathImage| -> f64 {
            img.channels
                .iter()
                .zip(coefficients)
                .map(|(c, mu)| mu * f64::from(c[i]))
                .sum()
        };
        let (x, y) = (l(a), l(b));
        worst = worst.max((x - y).abs());
        largest = largest.max(x.abs());
    }
    (worst, largest)
}

#[test]
fn gpu_and_cpu_agree_to_1e3_in_line_integral() {
    let Some(mut gpu) = GpuRenderer::if_available().unwrap() else {
        return;
    };
    let mu = MaterialAttenuation::KEV_60.channel_coefficients();
    // Background: the balls, and the real aorta CT, at oblique poses.
    let aorta = {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/ct/aorta.mha");
        let mut v = Volume::load(&path).unwrap();
        v.rescale(AORTA_HU_SLOPE, AORTA_HU_INTERCEPT).unwrap();
        Arc::new(v)
    };
    let aorta_centre = aorta.position_of(&Vector3::from(aorta.dims.map(|n| (n - 1) as f64 / 2.0)));
    for (volume, mut pose) in [
        (balls(), carm(128, 30.0, 20.0)),
        (balls(), carm(128, -45.0, -30.0)),
        (aorta.clone(), carm(128, 0.0, 0.0)),
        (aorta.clone(), carm(128, 60.0, 15.0)),
    ] {
        if Arc::ptr_eq(&volume, &aorta) {
            pose.isocenter_m = aorta_centre.coords;
            pose.detector.field_of_view_m = 0.4;
        }
        let settings = MarchSettings::default();
        let cpu = CpuRenderer::default()
            .project_volume(&volume, &pose, &settings)
            .unwrap();
        let got = gpu.project_volume(&volume, &pose, &settings).unwrap();
        let (worst, largest) = line_integral_difference(&cpu, &got, &mu[..2]);
        println!(
            "background {:?} at {}/{}: worst |ΔL| {worst:.2e} (largest L {largest:.2})",
            volume.dims, pose.primary_deg, pose.secondary_deg
        );
        assert!(largest > 1.0, "something is in view");
        assert!(worst < 1e-3, "{worst}");
    }
    // Layers: wire, catheter and contrast, at two poses. A pixel whose ray grazes a surface
    // is ill-conditioned: there the chord changes by more than 1e-3 in L when the ray moves
    // by f32's resolution near the patient (~10 nm). Such a pixel agrees when the GPU value
    // lies within 1e-3 of the exact values for the ray moved by up to 30 nm.
    let layers = layers();
    for pose in [carm(256, 0.0, 0.0), carm(256, 35.0, -25.0)] {
        let cpu = CpuRenderer::default()
            .project_layers(&layers, &pose)
            .unwrap();
        let got = gpu.project_layers(&layers, &pose).unwrap();
        let (worst, largest) = line_integral_difference(&cpu, &got, &mu[2..]);
        let grid = pose.ray_grid();
        let mut grazing = 0;
        for i in 0..cpu.len() {
            let l = |img: &PathImage| -> f64 {
                (0..3)
                    .map(|c| mu[2 + c] * f64::from(img.channels[c][i]))
                    .sum()
            };
            let (x, y) = (l(&cpu), l(&got));
            if (x - y).abs() <= 1e-3 {
                continue;
            }
            let ray = grid.ray((i % 256) as f64, (i / 256) as f64);
            let side = ray.direction.cross(&Vector3::z()).normalize();
            let up = ray.direction.cross(&side);
            let moved: Vec<f64> = (-3..=3)
                .flat_map(|a| (-3..=3).map(move |b| (a, b)))
                .map(|(a, b)| {
                    let origin = ray.origin + (side * f64::from(a) + up * f64::from(b)) * 1e-8;
                    let p = layers.paths_along(&origin, &ray.direction);
                    (0..3).map(|c| mu[2 + c] * p[c]).sum()
                })
                .collect();
            let (lo, hi) = moved
                .iter()
                .fold((f64::MAX, f64::MIN), |(lo, hi), &m| (lo.min(m), hi.max(m)));
            assert!(
                y >= lo - 1e-3 && y <= hi + 1e-3,
                "pixel {i}: gpu {y}, exact {x}, exact within 30 nm {lo}..{hi}"
            );
            grazing += 1;
        }
        println!(
            "layers at {}/{}: worst |ΔL| {worst:.2e} (largest L {largest:.2}); {grazing} grazing \
             pixels beyond 1e-3, each within 1e-3 of the exact value 30 nm away",
            pose.primary_deg, pose.secondary_deg
        );
        assert!(largest > 1.0, "the layers are in view");
        assert!(grazing <= cpu.len() / 10_000, "{grazing} grazing pixels");
    }
    // The last volume stays uploaded: its 16-bit voxels and one byte per air brick.
    let bricks = cathlab_xray::volume::AirBricks::of(&aorta);
    assert_eq!(
        gpu.device_memory_bytes(),
        aorta.memory_bytes() + bricks.air.len()
    );
}

#[test]
fn gpu_reports_bad_geometry_like_the_cpu() {
    let Some(mut gpu) = GpuRenderer::if_available().unwrap() else {
        return;
    };
    let mut pose = carm(64, 0.0, 0.0);
    pose.primary_deg = f64::NAN;
    let err = gpu
        .project_volume(&balls(), &pose, &MarchSettings::default())
        .unwrap_err();
    assert!(err.to_string().contains("primary angle"), "{err}");
}

#[test]
fn skipping_air_bricks_leaves_line_integrals_unchanged() {
    // The synthesized body: mostly air around a neck and a head.
    let landmarks = cathlab_xray::phantom::BodyLandmarks {
        circle_of_willis: Point3::new(0.0, 0.0, 0.05),
        arch_top_s: -0.05,
        bottom_s: -0.08,
        midline_l: 0.0,
        cervical_spine_p: 0.02,
        thoracic_spine_p: 0.04,
        aortic_knob_l: 0.035,
        lung_apex_s: -0.005,
        descending_aorta: None,
    };
    let body = cathlab_xray::phantom::BodyPhantom::new(landmarks);
    let volume = Arc::new(
        Volume::from_fn([96; 3], Vector3::repeat(3e-3), Vector3::zeros(), 1, |p| {
            body.hu(p)
        })
        .unwrap(),
    );
    let bricks = cathlab_xray::volume::AirBricks::of(&volume);
    let air = bricks.air.iter().filter(|&&a| a == 1).count();
    assert!(
        air * 5 > bricks.air.len(),
        "a fifth or more of the bricks are air"
    );
    let settings = MarchSettings::default();
    let model = settings.hu_model;
    for pose in [
        carm(48, 0.0, 0.0),
        carm(48, 40.0, 25.0),
        carm(48, -90.0, 0.0),
    ] {
        let image = CpuRenderer::default()
            .project_volume(&volume, &pose, &settings)
            .unwrap();
        let grid = pose.ray_grid();
        let step = settings.step_voxels * volume.min_spacing_m();
        for i in 0..image.len() {
            let ray = grid.ray((i % 48) as f64, (i / 48) as f64);
            // Every sample, no skipping.
            let water = volume.line_integral(&ray.origin, &ray.direction, step, |hu| {
                model.fractions(hu).0
            });
            let bone = volume.line_integral(&ray.origin, &ray.direction, step, |hu| {
                model.fractions(hu).1
            });
            assert!(
                (f64::from(image.channels[0][i]) - water).abs() <= 1e-6 * water.max(1e-3),
                "{i}"
            );
            assert!(
                (f64::from(image.channels[1][i]) - bone).abs() <= 1e-6 * bone.max(1e-3),
                "{i}"
            );
        }
    }
}
