//! Every scene in `scenes/` loads and runs; every stack scene's scripted two-hand operator
//! (its `[autopilot]`) takes the scene's target instrument to the target through recorded
//! commands, with no divergence.

use std::path::Path;

use cathlab_engine::*;

#[test]
fn every_scene_loads_and_every_two_hand_autopilot_reaches_its_target() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let catalog = SceneCatalog::read_dir(&dir).unwrap();
    let cache = AssetCache::default();
    let mut coaxial = Vec::new();
    for (spec, file) in catalog.scenes() {
        let base = file.parent().unwrap();
        let started = std::time::Instant::now();
        let assets = cache.load(spec, base).unwrap();
        let loaded_s = started.elapsed().as_secs_f64();
        let mut world = World::new(assets).unwrap();
        world.step().unwrap();
        if spec.autopilot.is_none() {
            println!("{}: loaded in {loaded_s:.1} s, one step run", spec.name);
            continue;
        }
        let started = std::time::Instant::now();
        let reached = world.follow_two_hands(40_000, 1).unwrap();
        let wall_s = started.elapsed().as_secs_f64();
        let m = world.metrics();
        let s = world.snapshot();
        println!(
            "{}: loaded in {loaded_s:.1} s; target {} reached at step {reached:?} ({:.2} s simulated, {wall_s:.1} s wall), {} divergence resets, inserted {:?} mm",
            spec.name,
            spec.target.branch,
            m.target_reached_at_s.unwrap_or(f64::NAN),
            m.divergence_resets,
            s.instruments
                .iter()
                .map(|i| (i.inserted_m * 1e4).round() / 10.0)
                .collect::<Vec<_>>()
        );
        assert!(
            reached.is_some(),
            "{}: the target was not reached",
            spec.name
        );
        println!(
            "  per instrument (tip path mm, moving s, peak hand N): {:?}; lead changes {}, inner tips passed {}",
            m.instruments[..m.instrument_count as usize]
                .iter()
                .map(|i| (
                    (i.tip_path_length_m * 1e3).round(),
                    (i.moving_time_s * 100.0).round() / 100.0,
                    (i.peak_axial_force_n * 100.0).round() / 100.0
                ))
                .collect::<Vec<_>>(),
            m.lead_changes,
            m.passed_inner_tip
        );
        assert_eq!(m.divergence_resets, 0, "{}", spec.name);
        // The scripted operator keeps the catheter behind the wire's tip.
        assert_eq!(m.passed_inner_tip, 0, "{}", spec.name);
        assert_eq!(m.leading_instrument as usize, spec.stack.len() - 1);
        coaxial.push(spec.name.clone());
    }
    for name in [
        "arch_to_cow_lcca_coaxial",
        "arch_to_cow_rva_coaxial",
        "neuro_phantom_m1",
    ] {
        assert!(coaxial.iter().any(|n| n == name), "{name} was run");
    }
}
