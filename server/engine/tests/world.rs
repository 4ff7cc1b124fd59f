//! The engine on the real arch-to-cow scene: scene errors name their field, the world is
//! deterministic (digests), a live threaded session replays bit for bit from what it
//! recorded, a coarse scene that really diverges is reset and reported, frames encode.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use cathlab_engine::session::{Ack, SessionContext};
use cathlab_engine::*;

fn scenes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

fn default_text() -> String {
    std::fs::read_to_string(scenes().join("arch_to_cow_lcca.toml")).unwrap()
}

fn cache() -> &'static AssetCache {
    static CACHE: OnceLock<AssetCache> = OnceLock::new();
    CACHE.get_or_init(AssetCache::default)
}

fn assets(text: &str) -> Arc<SceneAssets> {
    let spec = SceneSpec::parse(text, SceneFormat::Toml).unwrap();
    cache().load(&spec, &scenes()).unwrap()
}

/// The coarse, loose scene that diverges when pushed and twisted hard: 100 Hz steps, 10 mm
/// tip and 50 mm shaft elements, no refinement, contact tolerance 0.5.
pub fn coarse_text() -> String {
    default_text().replace(
        "step_rate_hz = 500",
        "step_rate_hz = 100\ntip_element_mm = 10\nshaft_element_mm = 50\n\
         contact_tolerance = 0.5\nrefine = false",
    )
}

/// The coarse scene with a 180° hook over 10 mm: one coarse element bent by 180°, which
/// diverges when pushed and twisted hard. (The 90°-over-30 mm wire stopped diverging once
/// elements took the exact mean of the rest curvature instead of its mid-point value.)
/// Its hand pushes through anything: the 10 N default holds the push back before the hook
/// breaks the coarse elements (as in the server's diverging-session test).
fn fragile_text() -> String {
    coarse_text()
        .replace("bend_deg = 90.0", "bend_deg = 180.0")
        .replace("bend_length_mm = 30.0", "bend_length_mm = 10.0")
        + "\n[limits]\npush_force_n = 10000.0\nunsupported_mm = 5.0\n"
}

/// The default scene with `stack` (TOML `[[stack]]` tables, outermost first) instead of its
/// selectable devices.
fn stack_text(stack: &[(&str, f64)]) -> String {
    let text = default_text();
    let from = text.find("[[devices]]").unwrap();
    let to = text.find("[start]").unwrap();
    let tables: String = stack
        .iter()
        .map(|(id, mm)| format!("[[stack]]\ndevice = \"{id}\"\ninserted_mm = {mm}\n\n"))
        .collect();
    format!("{}{tables}{}", &text[..from], &text[to..])
}

#[test]
fn a_stack_is_checked_against_the_catalogue_and_the_fit_of_each_instrument() {
    let catheter = ("catheter-5f-vertebral", 40.0);
    let wire = ("guidewire-035-angled-hydrophilic", 60.0);
    let good = stack_text(&[("guide-6f-071-90", 20.0), catheter, wire]);
    let spec = SceneSpec::parse(&good, SceneFormat::Toml).unwrap();
    assert_eq!(spec.stack.len(), 3);
    assert!(spec.devices.is_empty());
    let cases = [
        (
            stack_text(&[catheter, ("guidewire-099", 60.0)]),
            "stack[1].device",
            "not in the device catalogue",
        ),
        (
            // A 0.035" wire in a 0.017" microcatheter.
            stack_text(&[("microcatheter-017-150", 40.0), wire]),
            "stack[1].device",
            "does not fit",
        ),
        (
            // The wire's tip behind the catheter's hub.
            stack_text(&[catheter, ("guidewire-035-angled-hydrophilic", -2000.0)]),
            "stack[1].inserted_mm",
            "outside",
        ),
        (
            // Past its own hub.
            stack_text(&[catheter, ("guidewire-035-angled-hydrophilic", 1600.0)]),
            "stack[1].inserted_mm",
            "outside",
        ),
        (
            // Within its own length less what stays outside (1,350 mm), but its hub would
            // pass the catheter's: the 1,500 mm wire reaches at most 540 mm beyond the entry
            // in a 1,000 mm catheter inserted 40 mm.
            stack_text(&[catheter, ("guidewire-035-angled-hydrophilic", 600.0)]),
            "stack[1].inserted_mm",
            "outside",
        ),
        (
            stack_text(&[("catheter-5f-vertebral", f64::INFINITY)]),
            "stack[0].inserted_mm",
            "outside",
        ),
        (
            stack_text(&[("sheath-088-90", 20.0); 5]),
            "stack",
            "at most 4",
        ),
        (
            good.replace(
                "[start]",
                "[[devices]]\npreset = \"catheter_5f\"\n\n[start]",
            ),
            "stack",
            "not both",
        ),
        (stack_text(&[]), "devices", "or a `stack`"),
    ];
    for (text, path, reason) in cases {
        match SceneSpec::parse(&text, SceneFormat::Toml) {
            Err(EngineError::Scene { path: p, reason: r }) => {
                assert_eq!(p, path, "{r}");
                assert!(r.contains(reason), "{reason}: got {r}");
            }
            other => panic!("{path}: {other:?}"),
        }
    }
    // The good one loads and runs: three instruments, outermost first, each where the scene
    // put it, the inner two inside the guide.
    let assets = cache().load(&spec, &scenes()).unwrap();
    let mut world = World::new(assets).unwrap();
    world.step().unwrap();
    let s = world.snapshot();
    let inserted: Vec<f64> = s.instruments.iter().map(|i| i.inserted_m).collect();
    assert_eq!(s.instruments.len(), 3);
    for (got, want) in inserted.iter().zip([0.020, 0.040, 0.060]) {
        assert!((got - want).abs() < 1e-9, "{inserted:?}");
    }
    assert_eq!(s.instruments[1].catalogue_id, "catheter-5f-vertebral");
    // Each instrument's centerline ends at its tip; the tips 20 mm apart along the strand
    // (the straight distance within a few mm of that: the strand starts in the instruments'
    // composite rest shape, the catheter's and the wire's shaped tips).
    for i in s.instruments.windows(2) {
        let gap = i[1].tip.unwrap() - i[0].tip.unwrap();
        assert!((gap.norm() - 0.020).abs() < 3e-3, "{}", gap.norm());
        assert_eq!(i[0].nodes.last().copied(), i[0].tip);
    }
    // A command for a fourth instrument is refused, naming it.
    let missing = Command::Instrument {
        index: 3,
        drive: Drive::PushVelocity(0.01),
    };
    match world.apply(1, &missing) {
        Err(EngineError::InvalidArgument { field, reason }) => {
            assert_eq!(field, "instrument");
            assert!(reason.contains("instrument 3"), "{reason}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn scene_errors_name_the_field_and_the_reason() {
    let cases = [
        (
            default_text().replace("step_rate_hz = 500", "step_rate_hz = \"fast\""),
            "fidelity.step_rate_hz",
            "invalid type",
        ),
        (
            default_text().replace("step_rate_hz = 500", "step_rate_hz = 5"),
            "fidelity.step_rate_hz",
            "outside",
        ),
        (
            default_text().replace("bend_deg = 90.0", "bend_deg = 90.0\nstiffness = 1"),
            "devices[0]",
            "unknown field",
        ),
        (
            default_text().replace("preset = \"catheter_5f\"", "preset = \"catheter_9f\""),
            "devices[2]",
            "unknown variant",
        ),
        (
            default_text().replace("pulse_rate = 15", "pulse_rate = 12"),
            "fluoroscopy.pulse_rate",
            "not one of",
        ),
        ("not = [toml".to_owned(), "(document)", ""),
    ];
    // The imaging chain's knobs, each out of its range.
    let chain = [
        ("recursive_weight = 0.0", "fluoroscopy.recursive_weight"),
        ("dsa_mask_frames = 40", "fluoroscopy.dsa_mask_frames"),
        (
            "scatter_to_primary = -1.0",
            "fluoroscopy.scatter_to_primary",
        ),
        ("edge_enhancement = nan", "fluoroscopy.edge_enhancement"),
    ]
    .map(|(line, path)| {
        (
            default_text().replace("pulse_rate = 15", &format!("pulse_rate = 15\n{line}")),
            path,
            "",
        )
    });
    let cases: Vec<(String, &str, &str)> = cases.into_iter().chain(chain).collect();
    for (text, path, reason) in cases {
        match SceneSpec::parse(&text, SceneFormat::Toml) {
            Err(EngineError::Scene { path: p, reason: r }) => {
                assert!(p.contains(path), "{path}: got {p} ({r})");
                assert!(r.contains(reason), "{reason}: got {r}");
            }
            other => panic!("{path}: {other:?}"),
        }
    }
    // JSON works the same way.
    let spec = SceneSpec::parse(&default_text(), SceneFormat::Toml).unwrap();
    let mut json: serde_json::Value = serde_json::to_value(&spec).unwrap();
    json["carm"]["primary_deg"] = serde_json::json!(500.0);
    match SceneSpec::parse(&json.to_string(), SceneFormat::Json) {
        Err(EngineError::Scene { path, .. }) => assert_eq!(path, "carm.primary_deg"),
        other => panic!("{other:?}"),
    }
    // A branch the anatomy lacks is named when the scene loads.
    let missing = default_text().replace("branch = \"LCCA\"", "branch = \"LMCA\"");
    let spec = SceneSpec::parse(&missing, SceneFormat::Toml).unwrap();
    match cache().load(&spec, &scenes()) {
        Err(EngineError::Scene { path, reason }) => {
            assert_eq!(path, "target.branch");
            assert!(reason.contains("LMCA"), "{reason}");
        }
        other => panic!("{other:?}"),
    }
}

fn drive(world: &mut World, script: &[(u64, Command)], steps: u64) -> Vec<u64> {
    let mut digests = Vec::new();
    let mut next = 0;
    for _ in 0..steps {
        while next < script.len() && script[next].0 == world.step_index() {
            world.apply(next as u64 + 1, &script[next].1).unwrap();
            next += 1;
        }
        world.step().unwrap();
        digests.push(world.digest());
    }
    digests
}

#[test]
fn the_world_is_deterministic_and_commands_change_it() {
    let a = assets(&default_text());
    let script = [
        (0, Command::PushVelocity(0.03)),
        (50, Command::TwistRate(3.0)),
        (120, Command::Fluoroscopy(true)),
        (
            150,
            Command::Inject {
                volume_ml: 1.0,
                rate_ml_s: 4.0,
            },
        ),
        (250, Command::PushVelocity(-0.01)),
    ];
    let first = drive(&mut World::new(a.clone()).unwrap(), &script, 400);
    let second = drive(&mut World::new(a.clone()).unwrap(), &script, 400);
    assert_eq!(first, second);
    // The same commands one step later give another history from that step on.
    let mut shifted = script;
    shifted[1].0 += 1;
    let third = drive(&mut World::new(a).unwrap(), &shifted, 400);
    assert_eq!(first[..50], third[..50]);
    assert_ne!(first[51..], third[51..]);
}

/// Keeps what a session records, in memory.
#[derive(Default)]
struct MemoryRecorder {
    commands: Mutex<Vec<CommandRecord>>,
    checkpoints: Mutex<Vec<Checkpoint>>,
    events: Mutex<Vec<Event>>,
}

impl Recorder for MemoryRecorder {
    fn command(&self, _: &str, record: CommandRecord, ack: Option<Ack>) {
        self.commands.lock().unwrap().push(record);
        if let Some(ack) = ack {
            let _ = ack.send(Ok(record));
        }
    }
    fn checkpoint(&self, _: &str, c: Checkpoint) {
        self.checkpoints.lock().unwrap().push(c);
    }
    fn event(&self, _: &str, e: &Event) {
        self.events.lock().unwrap().push(e.clone());
    }
}

fn start(text: &str, recorder: Arc<MemoryRecorder>) -> Arc<Session> {
    Session::start(
        "0123456789abcdef".into(),
        "test".into(),
        assets(text),
        SessionContext {
            recorder,
            renderer: SharedRenderer::new(Box::new(cathlab_xray::CpuRenderer::default())),
            metrics: EngineMetrics::default(),
            settings: SessionSettings {
                checkpoint_every_steps: 100,
                ..SessionSettings::default()
            },
        },
    )
    .unwrap()
}

#[test]
fn a_live_threaded_session_replays_bit_for_bit() {
    let recorder = Arc::new(MemoryRecorder::default());
    let session = start(&default_text(), recorder.clone());
    let commands = [
        Command::PushVelocity(0.03),
        Command::TwistRate(2.0),
        Command::Inject {
            volume_ml: 1.0,
            rate_ml_s: 5.0,
        },
        Command::CArm {
            primary_deg: 20.0,
            secondary_deg: -5.0,
        },
        Command::PushVelocity(0.0),
    ];
    for (i, c) in commands.iter().enumerate() {
        session.send(i as u64 + 1, *c, None).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(150));
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    session.close();
    let recorded = recorder.commands.lock().unwrap().clone();
    let checkpoints = recorder.checkpoints.lock().unwrap().clone();
    // The overload governor's fidelity changes (under load) are recorded too.
    let operator = recorded
        .iter()
        .filter(|c| !matches!(c.command, Command::Fidelity(_)))
        .count();
    assert_eq!(operator, commands.len());
    assert!(checkpoints.len() >= 5, "{} checkpoints", checkpoints.len());
    let outcome = replay(session.assets().clone(), &recorded, &checkpoints).unwrap();
    assert_eq!(outcome.commands, commands.len());
    assert_eq!(outcome.matched, outcome.checkpoints);
    assert_eq!(outcome.checkpoints, checkpoints.len());
    // A changed record no longer matches: replay really compares.
    let mut altered = recorded.clone();
    let second = recorded
        .iter()
        .position(|c| c.command == commands[1])
        .unwrap();
    altered[second].step += 1;
    let broken = replay(session.assets().clone(), &altered, &checkpoints).unwrap();
    assert!(broken.matched < broken.checkpoints);
}

#[test]
fn a_diverging_world_is_reset_reported_and_stays_finite() {
    let mut world = World::new(assets(&fragile_text())).unwrap();
    world.apply(1, &Command::PushVelocity(0.5)).unwrap();
    world.apply(2, &Command::TwistRate(30.0)).unwrap();
    let mut divergences = Vec::new();
    for _ in 0..600 {
        world.step().unwrap();
        let snapshot = world.snapshot();
        assert!(
            snapshot
                .nodes
                .iter()
                .all(|p| p.iter().all(|v| v.is_finite()))
        );
        divergences.extend(
            world
                .take_events()
                .into_iter()
                .filter(|e| e.kind == EventKind::Divergence),
        );
    }
    println!("{divergences:?}");
    assert!(!divergences.is_empty(), "the coarse scene did not diverge");
    assert_eq!(
        world.metrics().divergence_resets as usize,
        divergences.len()
    );
    assert!(divergences[0].message.contains("diverged"));
    // The default fidelity takes the same abuse without diverging.
    let mut sound = World::new(assets(&default_text())).unwrap();
    sound.apply(1, &Command::PushVelocity(0.5)).unwrap();
    sound.apply(2, &Command::TwistRate(30.0)).unwrap();
    for _ in 0..1000 {
        sound.step().unwrap();
    }
    assert_eq!(sound.metrics().divergence_resets, 0);
}

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
fn the_target_metric_agrees_with_an_autopilot_that_reaches_the_lcca() {
    use cathlab_physics::autopilot::Autopilot;
    let a = assets(&default_text());
    let mut world = World::new(a.clone()).unwrap();
    let plan =
        cathlab_physics::scenarios::ArchToCowPlan::for_target(&a.anatomy.graph, "LCCA").unwrap();
    // The autopilot of the scene's route, told the scene's reach.
    let autopilot = || {
        Autopilot::new(
            &a.anatomy.graph,
            a.route.clone(),
            0.0,
            cathlab_physics::autopilot::AutopilotSettings {
                reach_m: a.spec.target.reach_mm * 1e-3,
                ..plan.autopilot
            },
        )
        .unwrap()
    };
    let mut pilot = autopilot();
    let start_tip = world.snapshot().tip();
    let start_remaining = world.metrics().target_remaining_m;
    let pilot_reached = world
        .follow_autopilot(&mut pilot, plan.max_steps, 1)
        .unwrap();
    let reached_step = pilot_reached.expect("the autopilot reaches the LCCA");
    let at = world
        .metrics()
        .target_reached_at_s
        .expect("the world saw the target reached");
    let dt = a.spec.time_step_s();
    // The world checks after each step, the autopilot before the next: the same step.
    assert!(
        (at / dt - reached_step as f64).abs() < 1.5,
        "world {at} s = step {}, autopilot step {reached_step}",
        at / dt
    );
    let events = world.take_events();
    assert!(events.iter().any(|e| e.kind == EventKind::TargetReached));
    // The distance to go, along the route: from the start to the goal, then about nothing.
    let remaining = world.metrics().target_remaining_m;
    // The tip starts `inserted_mm` beyond the entry, straight along the route's start.
    let expected = a.goal_along_m - (a.spec.start.along_route_mm + a.spec.start.inserted_mm) * 1e-3;
    println!(
        "to go: {:.1} mm at the start (route {:.1} mm), {:.1} mm when reached",
        start_remaining * 1e3,
        expected * 1e3,
        remaining * 1e3
    );
    assert!(
        (start_remaining - expected).abs() < 0.002,
        "{start_remaining} vs {expected}"
    );
    assert!(remaining < 0.003, "{remaining}");
    let m = world.metrics();
    println!(
        "LCCA reached at {at:.2} s; tip path {:.0} mm, wall force max {:.3} N mean {:.4} N",
        m.tip_path_length_m * 1e3,
        m.max_wall_force_n,
        m.mean_wall_force_n
    );
    // The path is at least the displacement, and the wire rubbed the wall on the way.
    let displacement = (world.snapshot().tip() - start_tip).norm();
    assert!(
        m.tip_path_length_m >= displacement && displacement > 0.1,
        "path {} m, displacement {displacement} m",
        m.tip_path_length_m
    );
    assert!(m.max_wall_force_n > 0.0 && m.mean_wall_force_n > 0.0);

    // Reset starts a new attempt: the target is to be reached again, and the reset counts.
    let reset_at = world.metrics().procedure_time_s;
    world.apply(1, &Command::Reset).unwrap();
    let m = world.metrics();
    assert_eq!(m.operator_resets, 1);
    assert_eq!(m.target_reached_at_s, None);
    assert_eq!(m.attempt_started_at_s, reset_at);
    let mut again = autopilot();
    world
        .follow_autopilot(&mut again, plan.max_steps, 1)
        .unwrap()
        .expect("the second attempt reaches the LCCA");
    let m = world.metrics();
    let second = m.target_reached_at_s.expect("reached again") - m.attempt_started_at_s;
    println!("second attempt: reached {second:.3} s after the reset (first {at:.3} s)");
    // The device restarts where it started: the same run, the same time to the target.
    assert!((second - at).abs() < 2.0 * dt, "{second} vs {at}");
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
fn the_asset_cache_keeps_nothing_of_a_failed_scene_and_stays_within_its_budget() {
    // A scene that fails after its anatomy and CT are built (an unknown isocenter branch).
    let cache = AssetCache::default();
    let bad = default_text().replace("isocenter_branch = \"LCCA\"", "isocenter_branch = \"nope\"");
    assert_ne!(bad, default_text());
    let spec = SceneSpec::parse(&bad, SceneFormat::Toml).unwrap();
    let error = cache.load(&spec, &scenes()).unwrap_err().to_string();
    assert!(error.contains("carm.isocenter_branch"), "{error}");
    assert_eq!(
        cache.counts(),
        (0, 0, 0),
        "the failed scene left assets behind"
    );
    assert_eq!(cache.bytes(), 0);
    // A budget smaller than one scene: a scene in use stays, one no session holds goes when
    // the next is loaded.
    let small = AssetCache::with_budget(1);
    let first = small
        .load(
            &SceneSpec::parse(&default_text(), SceneFormat::Toml).unwrap(),
            &scenes(),
        )
        .unwrap();
    let one_scene = small.bytes();
    assert!(one_scene > 1 << 20, "{one_scene} bytes");
    assert_eq!(small.counts(), (1, 1, 1), "in use, so kept");
    drop(first);
    let coarser = default_text().replace("spacing_mm = 2.0", "spacing_mm = 3.0");
    let second = small
        .load(
            &SceneSpec::parse(&coarser, SceneFormat::Toml).unwrap(),
            &scenes(),
        )
        .unwrap();
    println!(
        "one scene: {:.1} MiB; after a second with the first unused: {:?}, {:.1} MiB",
        one_scene as f64 / (1 << 20) as f64,
        small.counts(),
        small.bytes() as f64 / (1 << 20) as f64
    );
    assert_eq!(
        small.counts(),
        (1, 1, 1),
        "the unused scene and its CT went"
    );
    assert!(Arc::strong_count(&second) >= 1);
}

#[test]
fn push_force_limits_are_the_hand_or_the_euler_load_outside_the_sheath() {
    use cathlab_engine::scene::LimitsSpec;
    use cathlab_engine::world::DeviceLimits;
    use cathlab_physics::presets;
    let limits = LimitsSpec::default();
    // Euler, clamped at both ends over 30 mm: P = 4π²·E·(πr⁴/4) / L², by hand.
    let euler = |e_pa: f64, r_m: f64| {
        let inertia = std::f64::consts::PI * r_m.powi(4) / 4.0;
        4.0 * std::f64::consts::PI.powi(2) * e_pa * inertia / 0.03f64.powi(2)
    };
    let micro = DeviceLimits::of(&presets::micro_guidewire_014(), &limits, 0.0);
    let expected = euler(55e9, 0.014 * 0.0254 / 2.0);
    assert!(micro.buckling && (micro.force_n - expected).abs() < 1e-9 * expected);
    assert!((1.5..2.5).contains(&micro.force_n), "{}", micro.force_n);
    let wire = DeviceLimits::of(&presets::guidewire_035(), &limits, 0.0);
    assert!(!wire.buckling && wire.force_n == 10.0, "{wire:?}");
    assert!((wire.max_inserted_m - (presets::guidewire_035().length_m() - 0.15)).abs() < 1e-12);
}

#[test]
fn a_push_stops_at_the_hub_and_says_so() {
    // 1.1 m of the 1.5 m wire stays outside: it goes in 400 mm at most.
    let text = default_text() + "\n[limits]\noutside_mm = 1100.0\npush_force_n = 100.0\n";
    let mut world = World::new(assets(&text)).unwrap();
    let max = world.assets().devices[0].0.length_m() - 1.1;
    world.apply(1, &Command::PushVelocity(0.15)).unwrap();
    let mut events = Vec::new();
    for _ in 0..1500 {
        world.step().unwrap();
        events.extend(world.take_events());
        assert!(world.navigation().unwrap().inserted_m() <= max + 1e-12);
    }
    let snapshot = world.snapshot();
    println!(
        "inserted {:.3} mm of at most {:.3} mm; events {:?}",
        snapshot.inserted_m * 1e3,
        max * 1e3,
        events.iter().map(|e| &e.message).collect::<Vec<_>>()
    );
    assert!((snapshot.inserted_m - max).abs() < 1e-9);
    assert_eq!(
        snapshot.push_limit,
        cathlab_engine::world::PushLimit::Length
    );
    let hub: Vec<_> = events
        .iter()
        .filter(|e| e.kind == EventKind::Limit && e.message.contains("in to its hub"))
        .collect();
    assert_eq!(hub.len(), 1, "reported once while held: {events:?}");
    // Pulling back frees it; the next push to the hub is reported again.
    world.apply(2, &Command::PushVelocity(-0.05)).unwrap();
    for _ in 0..400 {
        world.step().unwrap();
    }
    assert_eq!(
        world.snapshot().push_limit,
        cathlab_engine::world::PushLimit::None
    );
    world.apply(3, &Command::PushVelocity(0.15)).unwrap();
    for _ in 0..400 {
        world.step().unwrap();
    }
    let again = world
        .take_events()
        .into_iter()
        .filter(|e| e.kind == EventKind::Limit)
        .count();
    assert_eq!(again, 1);
}

#[test]
fn lower_fidelity_does_less_and_caps_the_push_and_replays() {
    let assets = assets(&default_text());
    let script = [
        (0, Command::PushVelocity(0.15)),
        (0, Command::Fidelity(3)),
        (200, Command::Fidelity(0)),
    ];
    let mut world = World::new(assets.clone()).unwrap();
    let start = world.navigation().unwrap().inserted_m();
    let digests = drive(&mut world, &script[..2], 200);
    // Level 3 pushes at 30 mm/s at most: 200 steps of 2 ms.
    let capped = world.navigation().unwrap().inserted_m() - start;
    assert!((capped - 0.03 * 0.4).abs() < 1e-9, "{capped}");
    assert_eq!(world.fidelity_level(), 3);
    drive(&mut world, &script[2..], 1);
    assert_eq!(world.fidelity_level(), 0);
    let overload: Vec<_> = world
        .take_events()
        .into_iter()
        .filter(|e| e.kind == EventKind::Overload)
        .collect();
    assert_eq!(overload.len(), 2, "{overload:?}");
    // The same script again gives the same digests.
    let mut again = World::new(assets).unwrap();
    assert_eq!(drive(&mut again, &script[..2], 200), digests);
}

#[test]
fn the_governor_lowers_fidelity_under_load_and_raises_it_when_calm() {
    use cathlab_engine::session::Governor;
    let mut governor = Governor::new(500.0);
    // Steps at 90 % of their period: the level drops one at a time, 50 steps apart.
    let mut changes = Vec::new();
    for step in 0..400 {
        if let Some(level) = governor.update(0.9, 0.0) {
            changes.push((step, level));
        }
    }
    assert_eq!(
        changes.iter().map(|c| c.1).collect::<Vec<_>>(),
        [1, 2, 3],
        "{changes:?}"
    );
    assert!(changes.windows(2).all(|w| w[1].0 - w[0].0 >= 50));
    // A backlog lowers it at once, without waiting for the average.
    let mut sudden = Governor::new(500.0);
    assert_eq!(sudden.update(0.1, 6.0), Some(1));
    // One stall of 24 periods (just short of dropping the backlog) in a scene whose steps take
    // 65 % of their period: one level down, then the loop catches up (0.35 periods a step)
    // and the level stays (it used to go on down while the backlog shrank).
    let mut stalled = Governor::new(500.0);
    let mut behind: f64 = 24.0;
    let mut levels = Vec::new();
    for _ in 0..400 {
        levels.extend(stalled.update(0.65, behind));
        behind = (behind - 0.35).max(0.0);
    }
    assert_eq!(levels, [1]);
    // A backlog that keeps growing lowers it step by step.
    let mut falling = Governor::new(500.0);
    let mut levels = Vec::new();
    for step in 0..400 {
        levels.extend(falling.update(0.6, 6.0 + step as f64 * 0.2));
    }
    assert_eq!(levels, [1, 2, 3]);
    // Calm for 5 s (2,500 steps) raises it by one.
    let mut raised = Vec::new();
    for step in 0..6000 {
        if let Some(level) = governor.update(0.1, 0.0) {
            raised.push((step, level));
        }
    }
    assert_eq!(
        raised.iter().map(|c| c.1).collect::<Vec<_>>(),
        [2, 1],
        "{raised:?}"
    );
    assert!(raised[0].0 >= 2500);
}

#[test]
fn a_bad_guidance_or_limits_table_is_named() {
    for (extra, field) in [
        ("\n[guidance]\ntarget_marker = \"yes\"\n", "guidance"),
        ("\n[guidance]\nhints = true\n", "guidance"),
        ("\n[limits]\npush_force_n = -1.0\n", "limits.push_force_n"),
        ("\n[limits]\noutside_mm = 1e9\n", "limits.outside_mm"),
    ] {
        let error = SceneSpec::parse(&(default_text() + extra), SceneFormat::Toml)
            .expect_err(extra)
            .to_string();
        assert!(error.contains(field), "{extra:?}: {error}");
    }
}

#[test]
fn pushing_the_catheter_past_the_wire_tip_is_counted_and_reported() {
    let text = std::fs::read_to_string(scenes().join("arch_to_cow_lcca_coaxial.toml")).unwrap();
    let mut world = World::new(assets(&text)).unwrap();
    let drive = |index, v| Command::Instrument {
        index,
        drive: Drive::PushVelocity(v),
    };
    // The wire leads (30 mm against the catheter's 10); the left hand pushes the catheter
    // 40 mm at 40 mm/s while the wire is held.
    world.apply(1, &drive(0, 0.04)).unwrap();
    for _ in 0..500 {
        world.step().unwrap();
    }
    let m = *world.metrics();
    assert_eq!(m.instrument_count, 2);
    assert_eq!(m.passed_inner_tip, 1, "{m:?}");
    assert_eq!(m.leading_instrument, 0);
    assert_eq!(m.lead_changes, 1);
    let events = world.take_events();
    assert!(
        events
            .iter()
            .any(|e| e.message.contains("passed the tip of the")),
        "{events:?}"
    );
    // Only the catheter moved: its tip travelled about 40 mm, the wire's little.
    let [catheter, wire, ..] = m.instruments;
    assert!((catheter.moving_time_s - 1.0).abs() < 0.01, "{catheter:?}");
    assert_eq!(wire.moving_time_s, 0.0);
    assert!(catheter.tip_path_length_m > 0.03, "{catheter:?}");
    assert!(catheter.peak_axial_force_n > 0.0);
    // The wire pushed out again takes the lead back; withdrawing the catheter behind it is no
    // pass.
    world.apply(2, &drive(0, -0.04)).unwrap();
    world.apply(3, &drive(1, 0.04)).unwrap();
    for _ in 0..500 {
        world.step().unwrap();
    }
    let m = *world.metrics();
    assert_eq!(m.passed_inner_tip, 1);
    assert_eq!(m.leading_instrument, 1);
    assert_eq!(m.lead_changes, 2);
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

#[test]
fn an_exchange_withdraws_the_wire_through_the_catheter_then_replaces_it_and_a_push_cancels_it() {
    let text = std::fs::read_to_string(scenes().join("arch_to_cow_lcca_coaxial.toml")).unwrap();
    let mut world = World::new(assets(&text)).unwrap();
    let catalogue = cathlab_engine::scene::catalogue().entries();
    let j_tip = catalogue
        .iter()
        .position(|e| e.id == "guidewire-035-j-3mm")
        .unwrap() as u32;
    let guide = catalogue
        .iter()
        .position(|e| e.id == "guide-6f-071-90")
        .unwrap() as u32;
    // A guide catheter does not fit in a 5 F catheter: refused at once, nothing starts.
    let refused = world
        .apply(
            1,
            &Command::Exchange {
                index: 1,
                catalogue: guide,
            },
        )
        .unwrap_err();
    assert!(
        refused.to_string().contains("fit") || refused.to_string().contains("lumen"),
        "{refused}"
    );
    // A spare the scene does not have, and a catalogue entry that does not exist, are named.
    let missing = world
        .apply(1, &Command::ExchangeSpare { index: 1, spare: 5 })
        .unwrap_err();
    assert!(
        missing.to_string().contains("spare 5 does not exist"),
        "{missing}"
    );
    let missing = world
        .apply(
            1,
            &Command::Exchange {
                index: 1,
                catalogue: 9999,
            },
        )
        .unwrap_err();
    assert!(
        missing.to_string().contains("catalogue entry 9999"),
        "{missing}"
    );
    // The wire is 20 mm out of the catheter: the exchange draws it back through it first.
    world
        .apply(
            2,
            &Command::Exchange {
                index: 1,
                catalogue: j_tip,
            },
        )
        .unwrap();
    let started = world.take_events();
    assert!(
        started.iter().any(|e| e.message.contains("withdrawing")),
        "{started:?}"
    );
    // A push on the wire takes it back: the exchange is cancelled.
    world.step().unwrap();
    world
        .apply(
            3,
            &Command::Instrument {
                index: 1,
                drive: Drive::PushVelocity(0.01),
            },
        )
        .unwrap();
    assert!(
        world
            .take_events()
            .iter()
            .any(|e| e.message.contains("cancelled")),
        "a push cancels the exchange"
    );
    let before = world.snapshot().instruments[1].inserted_m;
    for _ in 0..50 {
        world.step().unwrap();
    }
    assert!(
        world.snapshot().instruments[1].inserted_m > before,
        "the wire advanced again"
    );
    // Again, left alone: withdrawn at the hand's top speed, then replaced at the hub.
    world
        .apply(
            4,
            &Command::Exchange {
                index: 1,
                catalogue: j_tip,
            },
        )
        .unwrap();
    let mut steps = 0;
    while world.snapshot().instruments[1].catalogue_id != "guidewire-035-j-3mm" {
        world.step().unwrap();
        steps += 1;
        assert!(steps < 20_000, "the exchange never finished");
    }
    let s = world.snapshot();
    let catheter = &s.instruments[0];
    let wire = &s.instruments[1];
    println!(
        "exchange: {steps} steps ({:.1} s); the new wire starts at {:.0} mm (catheter at {:.0} mm)",
        steps as f64 * 0.002,
        wire.inserted_m * 1e3,
        catheter.inserted_m * 1e3
    );
    assert!(wire.name.contains("J-tip"), "{}", wire.name);
    assert!(
        wire.tip.is_none(),
        "the new wire waits at the catheter's hub, outside the body"
    );
    assert!(
        world
            .take_events()
            .iter()
            .any(|e| e.message.contains("exchanged for guidewire-035-j-3mm")),
        "the exchange is reported"
    );
    // Pushed in, the new wire comes out of the catheter.
    world
        .apply(
            5,
            &Command::Instrument {
                index: 1,
                drive: Drive::PushTarget(catheter.inserted_m + 0.01),
            },
        )
        .unwrap();
    for _ in 0..10_000 {
        world.step().unwrap();
    }
    let wire = &world.snapshot().instruments[1];
    assert!(
        wire.tip.is_some() && wire.inserted_m > catheter.inserted_m,
        "{:.3} m",
        wire.inserted_m
    );
}

/// Each case's scene (a changed copy of `base`) fails to load with an error naming the
/// field path it starts with.
fn assert_scene_errors(base: &str, cases: &[(String, &str)]) {
    for (text, path) in cases {
        assert_ne!(text, base, "{path}: the case changed the scene");
        let outcome = SceneSpec::parse(text, SceneFormat::Toml)
            .and_then(|spec| cache().load(&spec, &scenes()).map(|_| ()));
        match outcome {
            Err(EngineError::Scene { path: p, reason }) => {
                println!("{p}: {reason}");
                assert!(p.starts_with(path), "{path}: got {p} ({reason})");
                assert!(!reason.is_empty());
            }
            other => panic!("{path}: {other:?}"),
        }
    }
}

#[test]
fn a_stack_scene_names_bad_spares_autopilot_and_target_instrument() {
    let rva = std::fs::read_to_string(scenes().join("arch_to_cow_rva_coaxial.toml")).unwrap();
    let cases = [
        (
            rva.replace("bend_length_mm = 10.0 }", "bend_length_mm = -3.0 }"),
            "spares[0].custom.bend_length_mm",
        ),
        (
            rva.replace("[[spares]]\ncustom = { preset = \"guidewire_035_shaped\", bend_deg = 90.0, bend_length_mm = 10.0 }", "[[spares]]\ndevice = \"guidewire-9000\""),
            "spares[0]",
        ),
        (rva.replace("lookahead_mm = 50.0", "lookahead_mm = 0.0"), "autopilot.lookahead_mm"),
        (
            rva.replace("catheter_lag_mm = 50.0", "catheter_lag_mm = nan"),
            "autopilot.catheter_lag_mm",
        ),
        (rva.replace("spare = 0", "spare = 3"), "autopilot.exchange.spare"),
        (rva.replace("into_mm = 45.0", "into_mm = 45.0\nspeed = 2"), "autopilot.exchange"),
        (rva.replace("instrument = 0", "instrument = 2"), "target.instrument"),
        (
            rva.replace("branch = \"arch_to_RCCA+RVA\"", "branch = \"nowhere\""),
            "autopilot.exchange.branch",
        ),
    ];
    assert_scene_errors(&rva, &cases);
}

#[test]
fn an_access_stage_names_its_bad_fields() {
    let access = std::fs::read_to_string(scenes().join("stroke_m1_from_access.toml")).unwrap();
    let loads =
        "load = [\"distal-access-058-115\", \"microcatheter-021-160\", \"microwire-014-angled\"]";
    let cases = [
        (access.replace("into_mm = 40.0", "into_mm = 0.0"), "autopilot.access.into_mm"),
        (access.replace("unload = 2", "unload = 3"), "autopilot.access.unload"),
        (
            access.replace(loads, "load = [\"guide-6f-071-90\"]"),
            "autopilot.access.load[0]",
        ),
        (
            access.replace(loads, "load = [\"nowhere-1\"]"),
            "autopilot.access.load[0]",
        ),
        (
            access.replace(
                loads,
                "load = [\"distal-access-058-115\", \"microcatheter-021-160\", \"microwire-014-angled\", \"microwire-014-j\"]",
            ),
            "autopilot.access.load",
        ),
        (
            access.replace("park_along_mm = [305.0, 317.0]", "park_along_mm = [305.0, 317.0, 330.0]"),
            "autopilot.park_along_mm",
        ),
        (
            access.replace("park_along_mm = [305.0, 317.0]", "park_along_mm = [5.0, 317.0]"),
            "autopilot.park_along_mm[0]",
        ),
        (
            access.replace(
                "branch = \"left_internal_carotid\"\ninto_mm",
                "branch = \"left_middle_cerebral\"\ninto_mm",
            ),
            "autopilot.access.branch",
        ),
        (
            access.replace(
                "branch = \"left_internal_carotid\"\ninto_mm",
                "branch = \"nowhere\"\ninto_mm",
            ),
            "autopilot.access.branch",
        ),
    ];
    assert_scene_errors(&access, &cases);
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

/// An anatomy folder whose vertebral curve is missing cannot give the circle of Willis its
/// four inflows: the scene is refused naming `anatomy.circle_of_willis`, and the same folder
/// without the circle still loads.
#[test]
fn a_circle_of_willis_without_its_four_inflows_is_refused_by_name() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let dir = std::env::temp_dir().join(format!("cathlab-cow-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("centerlines")).unwrap();
    std::fs::copy(data.join("vessels.obj"), dir.join("vessels.obj")).unwrap();
    for curve in ["LCCA", "RCCA", "RVA"] {
        let name = format!("centerlines/{curve}.mrk.json");
        std::fs::copy(data.join(&name), dir.join(&name)).unwrap();
    }
    let base = std::fs::read_to_string(scenes().join("arch_to_cow_basilar.toml")).unwrap();
    let text = base
        .replace(
            "dir = \"../data/anatomy/arch-to-cow\"",
            &format!("dir = {:?}", dir.display().to_string()),
        )
        .replace("branch = \"LVA\"", "branch = \"RVA\"");
    assert_scene_errors(&base, &[(text.clone(), "anatomy.circle_of_willis")]);
    let without = text
        .replace("circle_of_willis = true", "circle_of_willis = false")
        .replace(
            "isocenter_branch = \"basilar\"",
            "isocenter_branch = \"RVA\"",
        )
        .replace("branch = \"basilar\"", "branch = \"RVA\"")
        .replace(
            "branch = \"RVA\"\ninto_mm",
            "branch = \"arch_to_RCCA+RVA\"\ninto_mm",
        )
        .replace("into_mm = 120.0", "into_mm = 10.0");
    let spec = SceneSpec::parse(&without, SceneFormat::Toml).unwrap();
    if let Err(e) = cache().load(&spec, &scenes()) {
        panic!("without the circle: {e}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
