//! Speed of the stroke case (`cargo bench -p cathlab-engine --bench thrombectomy`): the
//! scene `stroke_m1_thrombectomy` is driven to its stent retriever deployed across the
//! clot (crossed by the scene's operator, the distal-access catheter brought up, the
//! microwire exchanged for the stent, the microcatheter drawn back over it); then every
//! `World::step` is timed, 4 s with the stent engaged (the hands still) and through the
//! retrieval pass. A step at 500 Hz has 2 ms. `CATHLAB_STROKE_TOLERANCE` replaces the
//! scene's Gauss–Seidel tolerance (3e-3; 1e-3 is the default of other scenes). Without
//! `--bench` (as in `cargo test`) it loads the scene and times 50 steps of the crossing.

use std::path::Path;
use std::time::Instant;

use cathlab_engine::thrombectomy::StrokeScript;
use cathlab_engine::*;

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn report(label: &str, mut times: Vec<f64>) {
    times.sort_by(f64::total_cmp);
    let over = times.iter().filter(|&&t| t > 2.0).count();
    println!(
        "{label}: {} steps, p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms, {:.1} % over 2 ms",
        times.len(),
        percentile(&times, 0.5),
        percentile(&times, 0.99),
        times.last().copied().unwrap_or(0.0),
        100.0 * over as f64 / times.len().max(1) as f64
    );
}

fn timed(world: &mut World, steps: usize, until: impl Fn(&World) -> bool) -> Vec<f64> {
    let mut times = Vec::with_capacity(steps);
    for _ in 0..steps {
        if until(world) {
            break;
        }
        let t = Instant::now();
        world.step().expect("step");
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    times
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let text = std::fs::read_to_string(scenes.join("stroke_m1_thrombectomy.toml")).unwrap();
    let mut spec = SceneSpec::parse(&text, SceneFormat::Toml).unwrap();
    if let Some(t) = std::env::var("CATHLAB_STROKE_TOLERANCE")
        .ok()
        .and_then(|t| t.parse().ok())
    {
        spec.fidelity.contact_tolerance = t;
    }
    // The neuro phantom's anatomy as the tests keep it on disk (built once per checkout).
    let disk = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("asset-cache");
    let assets = AssetCache::default()
        .with_disk_cache(&disk)
        .load(&spec, &scenes)
        .unwrap();
    let mut world = World::new(assets).unwrap();
    let mut script = StrokeScript::new(&world, "left_middle_cerebral", 1).unwrap();
    if !full {
        script
            .apply(&mut world, Command::Demonstrate(true))
            .unwrap();
        report("crossing (smoke)", timed(&mut world, 50, |_| false));
        return;
    }
    assert!(script.cross(&mut world).unwrap(), "crossed");
    let m1 = script.branch_inserted_m;
    assert!(script.move_to(&mut world, 1, m1 - 8e-3, 6000).unwrap());
    assert!(script.bring_in(&mut world, "stent-retriever-4x20").unwrap());
    script.apply(&mut world, Command::DeployStent).unwrap();
    // Unsheathed at the hand's speed; then a second to settle.
    for _ in 0..5000 {
        world.step().unwrap();
    }
    let grip = world.metrics().thrombectomy.unwrap().grip_n;
    println!("stent deployed across the clot, grip {grip:.3} N");
    report(
        "stent engaged, hands still",
        timed(&mut world, 2000, |_| false),
    );
    script.apply(&mut world, Command::RetrieveStent).unwrap();
    report(
        "retrieval pass",
        timed(&mut world, 10_000, |w| {
            w.metrics().thrombectomy.is_some_and(|t| t.passes > 0)
        }),
    );
}
