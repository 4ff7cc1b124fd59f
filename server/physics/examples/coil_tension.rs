//! Diagnostic of the hand forces the random operator found (issue 44): a wire pushed at
//! 50 mm/s into a tube closed 60 mm in, optionally twisted as it goes, coils; then the hand
//! holds. Prints the hand's axial force (N, positive when the wire pushes back) and torque
//! about the entry axis (N·m) every second of the push, then the force every half second of
//! the hold. `cargo run --release -p cathlab-physics --example coil_tension -- [push s] [tube
//! radius m]`, with `WIRE035=1` for the 0.035" guidewire (else the 0.014" microwire),
//! `TWIST=rad/s` for a twist while pushing, `PUSH_LIMIT=N` for a hand that holds its push at
//! N, and `PULL_TO=N` to pull back until the wire pulls on the hand with N before the hold.
//! Untwisted, the 0.035" wire's push rises to 75 N (no hand limit here) and relaxes to
//! ~1.2 N held; twisted at 6 rad/s it reaches 0.65 N·m and 800 N within 4 s and 27 kN by
//! 9 s: nothing here bounds the twist a hand puts in (the engine's hands hold it at their
//! torque strength, the scene's `limits.twist_torque_nm`).

use cathlab_physics::navigation::{Command, Insertion, Navigation, NavigationSettings, Twist};
use cathlab_physics::presets;
use cathlab_physics::wall::CappedTube;
use nalgebra::Vector3;

fn main() {
    let args: Vec<f64> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let push_s = args.first().copied().unwrap_or(6.0);
    let radius = args.get(1).copied().unwrap_or(8e-3);
    let twist: f64 = std::env::var("TWIST")
        .ok()
        .and_then(|t| t.parse().ok())
        .unwrap_or(0.0);
    let device = if std::env::var_os("WIRE035").is_some() {
        presets::guidewire_035()
    } else {
        presets::micro_guidewire_014()
    };
    let tube = CappedTube {
        start: Vector3::zeros(),
        axis: Vector3::x(),
        length_m: 0.06,
        radius_m: radius,
    };
    let mut nav = Navigation::new(
        device,
        tube,
        Vector3::zeros(),
        Vector3::x(),
        0.01,
        NavigationSettings::default(),
    )
    .expect("a wire in a tube");
    let command = |v: f64, w: f64| Command {
        insertion: Insertion::Velocity(v),
        twist: Twist::Rate(w),
    };
    let env = |name: &str| std::env::var(name).ok().and_then(|v| v.parse::<f64>().ok());
    // `PUSH_LIMIT=N`: the push held while the wire pushes back with N or more, as a hand.
    let push_limit = env("PUSH_LIMIT").unwrap_or(f64::INFINITY);
    for step in 0..(push_s * 500.0) as usize {
        let speed = if nav.proximal_reaction()[0] >= push_limit {
            0.0
        } else {
            0.05
        };
        nav.set_command(command(speed, twist)).expect("a command");
        nav.step().expect("a step");
        if step % 500 == 0 {
            let r = nav.proximal_reaction();
            println!(
                "push {:.1} s: inserted {:.0} mm, axial {:.3} N, torque {:.2e} N·m, {} elements",
                step as f64 / 500.0,
                nav.inserted_m() * 1e3,
                r[0],
                r[3],
                nav.model().element_count(),
            );
        }
    }
    // `PULL_TO=N`: then pulled back at 20 mm/s until the wire pulls on the hand with N.
    if let Some(tension) = env("PULL_TO") {
        nav.set_command(command(-0.02, 0.0)).expect("a command");
        let mut steps = 0;
        while nav.proximal_reaction()[0] > -tension && steps < 25_000 {
            nav.step().expect("a step");
            steps += 1;
        }
        println!(
            "pulled {:.1} s to {:.0} mm inserted: axial {:.3} N",
            steps as f64 / 500.0,
            nav.inserted_m() * 1e3,
            nav.proximal_reaction()[0]
        );
    }
    nav.set_command(command(0.0, 0.0)).expect("a command");
    for step in 0..5000 {
        nav.step().expect("a step");
        if step % 250 == 0 {
            let r = nav.proximal_reaction();
            println!(
                "held {:.1} s: axial {:.3} N, deepest {:.4} mm",
                step as f64 / 500.0,
                r[0],
                nav.max_penetration_m() * 1e3
            );
        }
    }
}
