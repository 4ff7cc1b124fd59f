//! Every metric against hand-computed values on small recorded sessions, and the spectral
//! arc length against the analytic spectrum of a Gaussian speed profile.

use cathlab_assessment::force::{ForceThresholds, class_forces};
use cathlab_assessment::motion::{idle_time_s, path_ratio, tip_path_length_m, tip_speeds};
use cathlab_assessment::smoothness::sparc;
use cathlab_assessment::{AssessmentError, Sample, Trace, VesselClass};
use proptest::prelude::*;

fn sample(time_s: f64, tip_m: [f64; 3], along_route_m: f64, inserted_m: f64) -> Sample {
    Sample {
        time_s,
        tip_m,
        along_route_m,
        inserted_m: vec![inserted_m],
        twist_rad: vec![0.0],
        wall_force_n: [0.0; 3],
        ..Sample::default()
    }
}

/// The tip goes 3 mm along x, then 4 mm along y (a 3-4-5 corner), then back 4 mm; the
/// route runs along x, so only the first 3 mm are gained.
#[test]
fn path_length_and_ratio_of_a_corner_and_back() {
    let trace = Trace::new(vec![
        sample(0.0, [0.0, 0.0, 0.0], 0.0, 0.0),
        sample(1.0, [3e-3, 0.0, 0.0], 3e-3, 3e-3),
        sample(2.0, [3e-3, 4e-3, 0.0], 3e-3, 7e-3),
        sample(3.0, [3e-3, 0.0, 0.0], 3e-3, 11e-3),
    ])
    .unwrap();
    assert!((tip_path_length_m(&trace) - 11e-3).abs() < 1e-15);
    assert!((path_ratio(&trace).unwrap() - 11.0 / 3.0).abs() < 1e-12);
    // No progress, no ratio.
    let still = Trace::new(vec![
        sample(0.0, [0.0; 3], 0.0, 0.0),
        sample(1.0, [0.5e-3, 0.0, 0.0], 0.5e-3, 0.5e-3),
    ])
    .unwrap();
    assert_eq!(path_ratio(&still), None);
}

/// Hands still for 2 s of a 5 s session: 1 s at the start, 1 s in the middle; a twist at
/// 0.1 rad/s counts as moving, a drift of 0.2 mm/s as still.
#[test]
fn idle_time_counts_the_intervals_with_every_hand_still() {
    let mut samples = vec![
        sample(0.0, [0.0; 3], 0.0, 0.0),
        sample(1.0, [0.0; 3], 0.0, 0.2e-3), // drift 0.2 mm/s: still
        sample(2.0, [0.0; 3], 0.0, 5e-3),   // pushed
        sample(3.0, [0.0; 3], 0.0, 5e-3),   // still
        sample(4.0, [0.0; 3], 0.0, 5e-3),   // twisted (below)
        sample(5.0, [0.0; 3], 0.0, 9e-3),   // pushed
    ];
    samples[4].twist_rad = vec![0.1];
    let trace = Trace::new(samples).unwrap();
    assert!((idle_time_s(&trace) - 2.0).abs() < 1e-12);
}

/// Forces sampled at 1 s: intracranial 0 → 0.4 → 0.4 → 0 N. Above 0.2 N from 0.5 s to
/// 2.5 s: 2 s; impulse 0.2 + 0.4 + 0.2 = 0.8 N·s; peak 0.4 N. The aorta never passes 1 N.
#[test]
fn wall_force_by_class_peak_impulse_and_time_above_threshold() {
    let forces = [
        [0.3, 0.0, 0.0],
        [0.9, 0.0, 0.4],
        [0.2, 0.0, 0.4],
        [0.0, 0.0, 0.0],
    ];
    let trace = Trace::new(
        forces
            .iter()
            .enumerate()
            .map(|(i, f)| Sample {
                wall_force_n: *f,
                ..sample(i as f64, [0.0; 3], 0.0, 0.0)
            })
            .collect(),
    )
    .unwrap();
    let classes = class_forces(&trace, &ForceThresholds::default()).unwrap();
    let of = |c: VesselClass| *classes.iter().find(|x| x.class == c).unwrap();
    let intracranial = of(VesselClass::Intracranial);
    assert!((intracranial.peak_n - 0.4).abs() < 1e-15);
    assert!((intracranial.impulse_n_s - 0.8).abs() < 1e-12);
    assert!((intracranial.time_above_s - 2.0).abs() < 1e-12);
    let aortic = of(VesselClass::Aortic);
    assert!((aortic.impulse_n_s - (0.6 + 0.55 + 0.1)).abs() < 1e-12);
    assert_eq!(aortic.time_above_s, 0.0);
    assert_eq!(of(VesselClass::Cervical).peak_n, 0.0);
    let bad = ForceThresholds {
        intracranial_n: -1.0,
        ..ForceThresholds::default()
    };
    assert!(matches!(
        class_forces(&trace, &bad),
        Err(AssessmentError::Setting { .. })
    ));
}

/// The analytic SPARC of a Gaussian speed profile v(t) = exp(−t²/2σ²): its normalised
/// spectrum is M(f) = exp(−2π²σ²f²), the adaptive cut-off f_a where M = 0.05, and the arc
/// ∫₀^f_a √(1/f_a² + M′(f)²) df by Simpson's rule.
fn gaussian_sparc_reference(sigma: f64) -> f64 {
    let pi2 = std::f64::consts::PI.powi(2);
    let fa = (20.0_f64.ln() / (2.0 * pi2 * sigma * sigma)).sqrt();
    let integrand = |f: f64| {
        let m = (-2.0 * pi2 * sigma * sigma * f * f).exp();
        let dm = -4.0 * pi2 * sigma * sigma * f * m;
        ((1.0 / fa).powi(2) + dm * dm).sqrt()
    };
    let n = 100_000;
    let h = fa / n as f64;
    let mut sum = integrand(0.0) + integrand(fa);
    for i in 1..n {
        sum += integrand(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    -sum * h / 3.0
}

fn gaussian(t: f64, centre: f64, sigma: f64) -> f64 {
    (-(t - centre).powi(2) / (2.0 * sigma * sigma)).exp()
}

#[test]
fn sparc_of_a_gaussian_speed_matches_its_analytic_spectrum() {
    for sigma in [0.15, 0.2, 0.4] {
        let dt = 0.002;
        let n = (12.0 * sigma / dt) as usize;
        let speed: Vec<f64> = (0..n)
            .map(|i| gaussian(i as f64 * dt, 6.0 * sigma, sigma))
            .collect();
        let ours = sparc(&speed, dt).unwrap();
        let reference = gaussian_sparc_reference(sigma);
        println!("σ = {sigma} s: SPARC {ours:.4}, analytic {reference:.4}");
        assert!((ours - reference).abs() < 0.005, "{ours} vs {reference}");
        // The amplitude scale does not matter.
        let scaled: Vec<f64> = speed.iter().map(|v| 7.0 * v).collect();
        assert!((sparc(&scaled, dt).unwrap() - ours).abs() < 1e-9);
    }
}

/// One movement against the same distance in two submovements (a stop in between), and
/// with a 6 Hz tremor on top: each is less smooth.
#[test]
fn sparc_falls_with_submovements_and_tremor() {
    let dt = 0.002;
    let n = 2000;
    let t = |i: usize| i as f64 * dt;
    let one: Vec<f64> = (0..n).map(|i| gaussian(t(i), 2.0, 0.3)).collect();
    let two: Vec<f64> = (0..n)
        .map(|i| 0.5 * (gaussian(t(i), 1.4, 0.2) + gaussian(t(i), 2.6, 0.2)))
        .collect();
    let tremor: Vec<f64> = one
        .iter()
        .enumerate()
        .map(|(i, v)| v * (1.0 + 0.3 * (2.0 * std::f64::consts::PI * 6.0 * t(i)).sin()))
        .collect();
    let (a, b, c) = (
        sparc(&one, dt).unwrap(),
        sparc(&two, dt).unwrap(),
        sparc(&tremor, dt).unwrap(),
    );
    println!("one {a:.3}, two submovements {b:.3}, tremor {c:.3}");
    assert!(b < a - 1.0 && c < a - 0.3);
    assert!(matches!(
        sparc(&[0.0; 100], dt),
        Err(AssessmentError::Samples(_))
    ));
}

#[test]
fn bad_samples_are_named() {
    let ok = sample(0.0, [0.0; 3], 0.0, 0.0);
    let cases = [
        (vec![ok.clone()], "1 sample"),
        (vec![ok.clone(), ok.clone()], "not after sample 0"),
        (
            vec![
                ok.clone(),
                Sample {
                    inserted_m: vec![0.0, 0.0],
                    twist_rad: vec![0.0],
                    ..sample(1.0, [0.0; 3], 0.0, 0.0)
                },
            ],
            "2 insertions and 1 twists",
        ),
        (
            vec![ok.clone(), sample(1.0, [f64::NAN, 0.0, 0.0], 0.0, 0.0)],
            "not finite",
        ),
    ];
    for (samples, message) in cases {
        match Trace::new(samples) {
            Err(AssessmentError::Samples(m)) => assert!(m.contains(message), "{m}"),
            other => panic!("{message}: {other:?}"),
        }
    }
}

proptest! {
    /// A tip that only ever advances along a straight route has a path ratio of 1; any
    /// sideways wobble makes it larger. The speeds integrate back to the path length.
    #[test]
    fn path_ratio_is_one_for_straight_progress_and_more_with_wobble(
        steps in prop::collection::vec((0.0f64..2e-3, -1e-3f64..1e-3), 2..50)
    ) {
        let mut x = 0.0;
        let mut straight = vec![sample(0.0, [0.0; 3], 0.0, 0.0)];
        let mut wobbly = straight.clone();
        for (i, (dx, dy)) in steps.iter().enumerate() {
            x += dx + 1e-4;
            let t = (i + 1) as f64 * 0.1;
            straight.push(sample(t, [x, 0.0, 0.0], x, x));
            wobbly.push(sample(t, [x, *dy, 0.0], x, x));
        }
        let straight = Trace::new(straight).unwrap();
        let wobbly = Trace::new(wobbly).unwrap();
        if let (Some(a), Some(b)) = (path_ratio(&straight), path_ratio(&wobbly)) {
            prop_assert!((a - 1.0).abs() < 1e-9);
            prop_assert!(b >= a - 1e-12);
        }
        let (speeds, dt) = tip_speeds(&wobbly);
        let integrated: f64 = speeds.iter().map(|v| v * dt).sum();
        prop_assert!((integrated - tip_path_length_m(&wobbly)).abs() < 1e-12);
    }
}
