//! Imaging: frames encode to every format alike, a DSA run fires the linked injector after
//! its mask, a wire shows through the hollow catheter around it, and contrast injected after
//! an idle spell moves as it would at once.

use cathlab_engine::*;

use super::{assets, default_text, scenes};

#[test]
fn frames_encode_to_every_format_consistently() {
    let a = assets(&default_text());
    let world = World::new(a.clone()).unwrap();
    let snapshot = world.snapshot();
    let frame = cathlab_engine::imaging::expose_snapshot(&a, &snapshot).unwrap();
    let (raw, w, h) = encode_frame(&frame, Encoding::Raw8, 0, 0).unwrap();
    assert_eq!((w, h, raw.len()), (512, 512, 512 * 512));
    assert_eq!(raw, frame.to_8bit());
    let (png, ..) = encode_frame(&frame, Encoding::Png, 0, 0).unwrap();
    let decoded = image::load_from_memory(&png).unwrap().to_luma8().into_raw();
    assert_eq!(decoded, raw, "PNG is lossless");
    let (jpeg, ..) = encode_frame(&frame, Encoding::Jpeg(90), 0, 0).unwrap();
    let decoded = image::load_from_memory(&jpeg)
        .unwrap()
        .to_luma8()
        .into_raw();
    let mean_error = decoded
        .iter()
        .zip(&raw)
        .map(|(a, b)| (*a as f64 - *b as f64).abs())
        .sum::<f64>()
        / raw.len() as f64;
    assert!(
        mean_error < 3.0,
        "JPEG q90 mean error {mean_error} grey levels"
    );
    let (small, w, h) = encode_frame(&frame, Encoding::Raw16, 128, 128).unwrap();
    assert_eq!((w, h, small.len()), (128, 128, 128 * 128 * 2));
    // Downsizing keeps the mean grey (a triangle filter averages).
    let mean16 = small
        .chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]) as f64)
        .sum::<f64>()
        / (128.0 * 128.0);
    let full16: Vec<u16> = frame.to_16bit();
    let full_mean = full16.iter().map(|&v| v as f64).sum::<f64>() / full16.len() as f64;
    assert!(
        (mean16 - full_mean).abs() < 0.01 * 65535.0,
        "{mean16} vs {full_mean}"
    );
}

#[test]
fn a_dsa_run_fires_the_linked_injector_after_its_mask_and_not_once_stopped() {
    let a = assets(&default_text());
    let dt = a.spec.time_step_s();
    let delay_steps = (cathlab_engine::world::LINKED_INJECTION_DELAY_S / dt).ceil() as u64;
    // Run 1: DSA held for a second, no injection asked for.
    let mut world = World::new(a.clone()).unwrap();
    world.apply(1, &Command::Dsa(true)).unwrap();
    for _ in 0..delay_steps - 2 {
        world.step().unwrap();
    }
    assert_eq!(
        world.metrics().contrast_volume_ml,
        0.0,
        "nothing before the mask is done"
    );
    for _ in 0..delay_steps {
        world.step().unwrap();
    }
    let injected = world.metrics().contrast_volume_ml;
    let events = world.take_events();
    println!(
        "linked injection: {injected:.2} mL after {:.2} s; {:?}",
        world.metrics().procedure_time_s,
        events.iter().map(|e| e.message.clone()).collect::<Vec<_>>()
    );
    assert!(injected > 0.0);
    assert!(
        events
            .iter()
            .any(|e| e.kind == EventKind::Contrast && e.message.contains("linked"))
    );
    // Run 2: the run stopped before the injector's time: no contrast.
    let mut stopped = World::new(a).unwrap();
    stopped.apply(1, &Command::Dsa(true)).unwrap();
    stopped.step().unwrap();
    stopped.apply(2, &Command::Dsa(false)).unwrap();
    for _ in 0..2 * delay_steps {
        stopped.step().unwrap();
    }
    assert_eq!(stopped.metrics().contrast_volume_ml, 0.0);
}

#[test]
fn a_wire_shows_through_the_hollow_catheter_around_it() {
    use nalgebra::{Point3, Vector3};
    let text = std::fs::read_to_string(scenes().join("arch_to_cow_lcca_coaxial.toml")).unwrap();
    let assets = assets(&text);
    let mut world = World::new(assets.clone()).unwrap();
    world.step().unwrap();
    let snapshot = world.snapshot();
    // 5 mm beyond the entry: inside the catheter (10 mm in), 25 mm from the wire's tip, so
    // within its 30 mm platinum coil.
    let nodes = &snapshot.instruments[0].nodes;
    let (mut walked, mut at, mut tangent) = (0.0, nodes[0], Vector3::x());
    for w in nodes.windows(2) {
        let d = (w[1] - w[0]).norm();
        if walked + d >= 0.005 {
            tangent = (w[1] - w[0]) / d;
            at = w[0] + tangent * (0.005 - walked);
            break;
        }
        walked += d;
    }
    let across = tangent.cross(&Vector3::z()).normalize();
    let origin = Point3::from(at - across * 0.02);
    let paths = |s: &Snapshot| {
        cathlab_engine::imaging::layers_of(&assets, s)
            .unwrap()
            .paths_along(&origin, &across)
    };
    let both = paths(&snapshot);
    let mut catheter_only = snapshot.clone();
    catheter_only.instruments.truncate(1);
    let alone = paths(&catheter_only);
    let c = &snapshot.instruments[0].look;
    let w = &snapshot.instruments[1].look;
    // Through the axis: the catheter's braid in its wall twice, and the wire's coil across.
    let wall = 2.0 * (c.outer_radius_m - c.inner_radius_m) * c.fill;
    assert!((alone[1] - wall).abs() < 0.05 * wall, "{alone:?} {wall}");
    assert_eq!(alone[2], 0.0);
    let coil = 2.0 * w.outer_radius_m * w.bands[0].fill;
    assert!((both[2] - coil).abs() < 0.05 * coil, "{both:?} {coil}");
    assert!(
        (both[1] - alone[1]).abs() < 1e-12,
        "the coil replaces the core there"
    );
}

/// Regression: the contrast's steps were counted while no contrast moved, so the first
/// update after an idle spell advected the new bolus over the whole spell (after two minutes
/// of a stroke case, past the CFL limit: the session stopped). The same injection after
/// 1,000 idle steps draws the same contrast as at once.
#[test]
fn an_injection_after_an_idle_spell_moves_as_one_at_once() {
    let assets = assets(&default_text());
    let drawn = |idle: usize| {
        let mut world = World::new(assets.clone()).unwrap();
        for _ in 0..idle {
            world.step().unwrap();
        }
        world
            .apply(
                1,
                &Command::Inject {
                    volume_ml: 2.0,
                    rate_ml_s: 4.0,
                },
            )
            .unwrap();
        for _ in 0..40 {
            world.step().unwrap();
        }
        let s = world.snapshot();
        let length: f64 = s.contrast.iter().map(|t| (t.end - t.start).norm()).sum();
        (s.contrast.len(), length)
    };
    let (now_tubes, now_length) = drawn(0);
    let (later_tubes, later_length) = drawn(1000);
    println!(
        "at once: {now_tubes} tubes, {now_length:.4} m; after 2 s idle: {later_tubes}, {later_length:.4} m"
    );
    assert!(now_length > 0.0, "the bolus is drawn");
    assert!(
        (later_length - now_length).abs() <= 1e-9 + 1e-6 * now_length,
        "{later_length} m after idling, {now_length} m at once"
    );
}
