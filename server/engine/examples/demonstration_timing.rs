//! Step times of a stack scene's demonstration, window by window: the scene's scripted
//! operator drives (through its access stage, when the scene has one) while every
//! `World::step` is timed; each window of 1,000 steps prints its p50, p99 and worst step and
//! where the instruments are, and the world's events, until the target is reached (and one window more, hands still).
//! With a speed after the scene (mm/s), the innermost instrument is pushed at that speed
//! instead, as `cathlab-load` pushes it, for 40 windows, each window also printing the hands'
//! forces: how a step's cost grows with the device's length in the vessels. `LEVEL_AT_WINDOW=N`
//! drops the governor's fidelity to its lowest level from window N on.
//!
//! `cargo run --release -p cathlab-engine --example demonstration_timing -- scenes/stroke_m1_from_access.toml`
//! `cargo run --release -p cathlab-engine --example demonstration_timing -- scenes/stroke_m1_thrombectomy.toml 15`

use std::path::Path;
use std::time::Instant;

use cathlab_engine::world::MAX_FIDELITY_LEVEL;
use cathlab_engine::{AssetCache, Command, SceneFormat, SceneSpec, World};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let Some(scene) = std::env::args().nth(1) else {
        return Err("usage: demonstration_timing SCENE.toml [PUSH_MM_S]".into());
    };
    let push_mm_s: Option<f64> = std::env::args().nth(2).map(|s| s.parse()).transpose()?;
    let path = Path::new(&scene);
    let spec = SceneSpec::parse(&std::fs::read_to_string(path)?, SceneFormat::Toml)?;
    let assets = AssetCache::default().load(&spec, path.parent().unwrap_or(Path::new(".")))?;
    let graph = assets.anatomy.graph.clone();
    let from_lps = assets.to_lps.transpose();
    let mut world = World::new(assets)?;
    match push_mm_s {
        Some(v) => world.apply(1, &Command::PushVelocity(v * 1e-3))?,
        None => world.apply(1, &Command::Demonstrate(true))?,
    }
    let started = Instant::now();
    let mut after = 0;
    let windows = if push_mm_s.is_some() { 40 } else { 100 };
    for window in 0..windows {
        if let Ok(at) = std::env::var("LEVEL_AT_WINDOW")
            && window == at.parse::<usize>()?
        {
            world.apply(0, &Command::Fidelity(MAX_FIDELITY_LEVEL))?;
        }
        let mut ms: Vec<f64> = (0..1000)
            .map(|_| {
                let t = Instant::now();
                world.step().map(|_| t.elapsed().as_secs_f64() * 1e3)
            })
            .collect::<Result<_, _>>()?;
        ms.sort_by(f64::total_cmp);
        let snapshot = world.snapshot();
        let inserted: Vec<f64> = snapshot
            .instruments
            .iter()
            .map(|i| (i.inserted_m * 1e3).round())
            .collect();
        let tips: Vec<String> = snapshot
            .instruments
            .iter()
            .filter_map(|i| i.tip)
            .filter_map(|t| graph.nearest(&(from_lps * t).into()))
            .map(|l| {
                format!(
                    "{}@{:.0}",
                    graph.branches[l.branch].name,
                    l.arc_length * 1e3
                )
            })
            .collect();
        let forces: Vec<f64> = snapshot
            .instruments
            .iter()
            .map(|i| (i.axial_force_n * 100.0).round() / 100.0)
            .collect();
        println!(
            "steps {:>6}: p50 {:.2} ms, p99 {:.2} ms, worst {:.2} ms; inserted {inserted:?} mm; hands {forces:?} N; tips {}",
            (window + 1) * 1000,
            ms[500],
            ms[990],
            ms[999],
            tips.join(" ")
        );
        for e in world.take_events() {
            println!("    {:.2} s {:?}: {}", e.time_s, e.kind, e.message);
        }
        if push_mm_s.is_none() && world.metrics().target_reached_at_s.is_some() {
            after += 1;
            if after == 2 {
                break;
            }
        }
    }
    let m = world.metrics();
    println!(
        "target reached at {:.1} s simulated; {} steps in {:.1} s wall",
        m.target_reached_at_s.unwrap_or(f64::NAN),
        world.step_index(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
