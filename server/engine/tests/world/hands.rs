//! The hands: the target metric against the autopilot, push limits (the hand, the Euler
//! load, the hub), a catheter pushed past the wire's tip, and an exchange drawn back through
//! the catheter, replaced, or cancelled by a push.

use cathlab_engine::*;

use super::{assets, default_text, scenes};

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

/// The largest torque (N·m) the hand felt, the twist it ended at (rad) and the twist holds
/// reported, for the default wire pushed 250 mm into the arch and then twisted at two turns a
/// second for 3 s while pushed on, under a hand twisting with at most `torque_nm`.
fn twisted_hard(torque_nm: f64) -> (f64, f64, usize) {
    let text = default_text() + &format!("\n[limits]\ntwist_torque_nm = {torque_nm}\n");
    let mut world = World::new(assets(&text)).unwrap();
    world.apply(1, &Command::PushVelocity(0.1)).unwrap();
    for _ in 0..1250 {
        world.step().unwrap();
    }
    world
        .apply(2, &Command::TwistRate(4.0 * std::f64::consts::PI))
        .unwrap();
    world.apply(3, &Command::PushVelocity(0.02)).unwrap();
    world.take_events();
    let mut largest: f64 = 0.0;
    let mut holds = 0;
    for _ in 0..1500 {
        world.step().unwrap();
        largest = largest.max(world.snapshot().axial_reaction().1.abs());
        holds += world
            .take_events()
            .iter()
            .filter(|e| e.kind == EventKind::Limit && e.message.starts_with("twist held"))
            .count();
    }
    (largest, world.snapshot().twist_rad, holds)
}

#[test]
fn a_twist_is_held_at_the_hands_torque() {
    let (free, free_twist, free_holds) = twisted_hard(10.0);
    println!(
        "free: largest torque {:.3} mN·m, twist {free_twist:.1} rad",
        free * 1e3
    );
    assert_eq!(free_holds, 0);
    let limit = free / 4.0;
    let (held, held_twist, holds) = twisted_hard(limit);
    println!(
        "limit {:.3} mN·m: largest {:.3} mN·m, twist {held_twist:.1} rad, {holds} hold(s) reported",
        limit * 1e3,
        held * 1e3
    );
    // One step's rise past the limit at most, then held and given back.
    assert!(held <= 1.25 * limit, "{held} against {limit}");
    assert!(holds >= 1);
    assert!(
        held_twist < free_twist - 1.0,
        "{held_twist} vs {free_twist}"
    );
}

/// A push held at its hand's limit is stepped once a step, not taken again: a wire pushed
/// at full speed into the LCCA's dead end (the attack suite's push, at the governor's lowest
/// level as a loaded server runs it). Regression: the hand's stiffness was learnt from the
/// force's change since the last step over the step's small move, which the force's drift as
/// the device settles made tiny or negative, so the next first try overshot and every held
/// step cost two or three solves (the attack test's CI run missed 150 steps).
#[test]
fn a_push_held_at_its_limit_is_stepped_once() {
    let mut world = World::new(assets(&default_text())).unwrap();
    world.apply(1, &Command::PushVelocity(0.5)).unwrap();
    let (mut held, mut retakes) = (0u64, 0u64);
    for step in 0..6000 {
        if step == 1500 {
            world.apply(2, &Command::Fidelity(3)).unwrap();
        }
        let before = world.metrics().force_retakes;
        world.step().unwrap();
        let snapshot = world.snapshot();
        if step >= 2000
            && snapshot.instruments[0].axial_force_n >= 0.95 * snapshot.push_force_limit_n
        {
            held += 1;
            retakes += world.metrics().force_retakes - before;
        }
    }
    let snapshot = world.snapshot();
    println!(
        "at its limit in {held} of the last 4000 steps, {retakes} retakes; inserted {:.0} mm, hand {:.2} N",
        snapshot.inserted_m * 1e3,
        snapshot.instruments[0].axial_force_n
    );
    assert!(held > 1000, "{held}");
    assert!(retakes * 5 < held, "{retakes} retakes in {held} held steps");
}

/// The force guard in a four-instrument stack under the random operator (the stroke scene,
/// seed 1, 14 s). Two regressions. (1) A push loads a hand's torque as well as its force: at
/// 8.156 s the guide's curved tip met a wall as it was pushed and its hand's torque, the
/// contact's lever arm about the entry axis, rose from 51 to 153 mN·m in one step under a
/// 100 mN·m limit (the twist guard looked only at twists, a step late); now the step is
/// taken again with its moves scaled to the share the torque allows. (2) From 11 s the
/// guide's hand sat past its 10 N while it was pulled back and the microcatheter pushed
/// through it: every move was held, the guide's relieving pull too, and the guide's force
/// crept to 11.4 N with 1,898 of 7,000 steps taken again; now the moves that relieve a hand
/// past its limit are kept in a try of their own before everything is held. (3) Seed 2, at
/// 16.378 s: the guide held at its 10 N while the microwire was pulled back through it at
/// 136 mm/s crept 0.01–0.02 N a step, to 10.21 N with everything held; now a hand held past
/// its limit gives way in a try before everything is held.
#[test]
fn a_stack_under_the_random_operator_keeps_its_hands_within_their_strength() {
    for (seed, seconds) in [(1, 14.0), (2, 16.5)] {
        a_stack_under_the_random_operator(seed, seconds);
    }
}

fn a_stack_under_the_random_operator(seed: u64, seconds: f64) {
    let text = std::fs::read_to_string(scenes().join("stroke_m1_thrombectomy.toml")).unwrap();
    let mut world = World::new(assets(&text)).unwrap();
    let report = cathlab_engine::stress::run(
        &mut world,
        &cathlab_engine::stress::StressSettings::new(seed, seconds),
    );
    let limit = world.assets().spec.limits.twist_torque_nm;
    println!(
        "seed {seed}: largest force {:.2} N, torque {:.1} mN·m under {:.0} mN·m; {} of {} steps taken again",
        report.worst_hand_force_n,
        report.worst_hand_torque_nm * 1e3,
        limit * 1e3,
        report.force_retakes,
        report.steps
    );
    assert!(report.sound(), "{:?}", report.first_failure);
    assert!(
        report.worst_hand_torque_nm <= 1.1 * limit + 1e-9,
        "{} N·m against {limit} N·m",
        report.worst_hand_torque_nm
    );
    assert!(
        report.hands_within_limits(),
        "{:?}: {} N",
        report.limit_passed_at,
        report.worst_hand_force_n
    );
    assert!(
        report.force_retakes * 10 < report.steps,
        "{} of {} steps taken again",
        report.force_retakes,
        report.steps
    );
}

/// A long random-operator run can be watched and stopped (`stress::run_while`, the bench's
/// `STRESS_PROGRESS` and `STRESS_STOP`): asked after every step, in order, it stops where
/// told, and its report covers the steps it took, no more.
#[test]
fn a_stress_run_stops_where_it_is_told_and_reports_what_it_ran() {
    let text = std::fs::read_to_string(scenes().join("arch_to_cow_lcca.toml")).unwrap();
    let mut world = World::new(assets(&text)).unwrap();
    let dt = world.assets().spec.time_step_s();
    let mut asked = Vec::new();
    let report = cathlab_engine::stress::run_while(
        &mut world,
        &cathlab_engine::stress::StressSettings::new(3, 10.0),
        |_, report| {
            asked.push(report.steps);
            report.steps < 120
        },
    );
    assert_eq!(asked, (1..=120).collect::<Vec<u64>>());
    assert_eq!(report.steps, 120);
    assert_eq!(report.step_s.len(), 120);
    assert!((report.simulated_s - 120.0 * dt).abs() < 1e-12);
    assert!(!report.failed_so_far() && report.sound(), "{report:?}");
}
