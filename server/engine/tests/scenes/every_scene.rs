//! Every scene in `scenes/` loads and runs; every stack scene's scripted two-hand operator
//! (its `[autopilot]`) takes the scene's target instrument to the target through recorded
//! commands, with no divergence. The fluoroscopy of each stack where it arrives (every
//! instrument, hollow catheters with the devices inside them visible, marker bands) is held
//! to a golden image in `tests/golden/` (noise off; mean difference ≤ 0.5 grey level, 99.9 %
//! of pixels within 2); `CATHLAB_BLESS=1` rewrites them after a deliberate change.

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

use cathlab_engine::*;

use super::{load, scenes};

#[test]
fn every_scene_loads_and_every_two_hand_autopilot_reaches_its_target() {
    let catalog = SceneCatalog::read_dir(&scenes()).unwrap();
    // The scenes two at a time (their loads one at a time, through the binary's cache), on
    // threads of their own: not rayon's, whose workers, waiting inside a load's parallel
    // loops, could take up another scene and block on the cache that load holds.
    let next = AtomicUsize::new(0);
    let coaxial: Vec<String> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..2)
            .map(|_| {
                scope.spawn(|| {
                    let mut ran = Vec::new();
                    while let Some((spec, _)) = catalog.scenes().get(next.fetch_add(1, Relaxed)) {
                        ran.extend(run(spec));
                    }
                    ran
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|w| w.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
            .collect()
    });
    for name in [
        "arch_to_cow_basilar",
        "arch_to_cow_lcca_coaxial",
        "arch_to_cow_rva_coaxial",
        "neuro_phantom_m1",
        "stroke_m1_from_access",
    ] {
        assert!(coaxial.iter().any(|n| n == name), "{name} was run");
    }
}

/// Loads `spec` and runs a step; if it has a scripted operator, runs it to the target and
/// checks the run and its image, returning the scene's name.
fn run(spec: &SceneSpec) -> Option<String> {
    let started = std::time::Instant::now();
    let assets = load(spec).unwrap();
    let loaded_s = started.elapsed().as_secs_f64();
    let mut world = World::new(assets).unwrap();
    world.step().unwrap();
    if spec.autopilot.is_none() {
        println!("{}: loaded in {loaded_s:.1} s, one step run", spec.name);
        return None;
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
    // The innermost leads (after an access stage, of the instruments loaded then).
    assert_eq!(m.leading_instrument as usize, world.strand().len() - 1);
    golden(&spec.name, world.assets(), &s);
    Some(spec.name.clone())
}

/// Holds the noiseless fluoroscopy of `snapshot` to `tests/golden/{name}.png`.
fn golden(name: &str, assets: &SceneAssets, snapshot: &Snapshot) {
    let frame = cathlab_engine::imaging::expose_snapshot_with(assets, snapshot, false).unwrap();
    let grey = frame.to_8bit();
    let (w, h) = (frame.width, frame.height);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("tests/golden/{name}.png"));
    if std::env::var_os("CATHLAB_BLESS").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        image::GrayImage::from_raw(w, h, grey.clone())
            .unwrap()
            .save(&path)
            .unwrap();
    }
    let reference = image::open(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (bless with CATHLAB_BLESS=1)", path.display()))
        .to_luma8();
    assert_eq!(reference.dimensions(), (w, h), "{name}: golden image size");
    let (mean, far) = cathlab_xray::golden::difference(&grey, &reference.into_raw());
    println!(
        "  golden {name}: mean |Δ| {mean:.3} grey levels, {:.3} % beyond 2",
        far * 100.0
    );
    assert!(
        cathlab_xray::golden::within_tolerance((mean, far)),
        "{name}: the fluoroscopy of the stack differs from its golden image"
    );
}
