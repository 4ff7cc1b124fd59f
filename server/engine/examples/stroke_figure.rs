//! The stroke case as digital subtraction angiograms, for the README: three runs of
//! `scenes/stroke_m1_thrombectomy.toml` side by side, each 6 mL of contrast (4 mL/s) injected through
//! the innermost catheter and the frame 2 s later less the same frame without contrast
//! (noise off, one grey scale): the occluded left M1 at the start (the injection from the
//! guide in the ICA), the stent retriever deployed across the clot (the bypass), and after
//! the retrieval. Prints each run's eTICI.
//!
//! `cargo run --release -p cathlab-engine --example stroke_figure -- docs/figures/stroke_dsa.png`

use std::path::Path;
use std::sync::Arc;

use cathlab_engine::imaging::expose_snapshot_with;
use cathlab_engine::thrombectomy::StrokeScript;
use cathlab_engine::{AssetCache, Command, SceneFormat, SceneSpec, World};

/// Injects, runs 1 s and returns the subtracted image (line integral with contrast less
/// without; NaN outside the field) with its size.
fn run(world: &mut World, seq: u64) -> Result<(Vec<f32>, u32, u32), Box<dyn std::error::Error>> {
    world.apply(
        seq,
        &Command::Inject {
            volume_ml: 6.0,
            rate_ml_s: 4.0,
        },
    )?;
    for _ in 0..1000 {
        world.step()?;
    }
    let live = world.snapshot();
    let mut mask = live.clone();
    mask.contrast = Arc::new(Vec::new());
    let a = world.assets().clone();
    let (l, m) = (
        expose_snapshot_with(&a, &live, false)?,
        expose_snapshot_with(&a, &mask, false)?,
    );
    let r = world.metrics().reperfusion.expect("a clotted scene");
    println!("eTICI {} ({:.0} %)", r.etici.label(), r.fraction * 100.0);
    // Let the bolus wash out before the next run.
    for _ in 0..2500 {
        world.step()?;
    }
    Ok((
        l.values.iter().zip(&m.values).map(|(a, b)| a - b).collect(),
        l.width,
        l.height,
    ))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .ok_or("usage: stroke_figure OUT.png")?;
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let text = std::fs::read_to_string(scenes.join("stroke_m1_thrombectomy.toml"))?;
    let mut spec = SceneSpec::parse(&text, SceneFormat::Toml)?;
    // Subtraction on the log image before scatter and edge enhancement (whose box kernel
    // rings around the filled vessels), as angiography systems subtract.
    spec.fluoroscopy.scatter_to_primary = 0.0;
    spec.fluoroscopy.edge_enhancement = 0.0;
    let assets = AssetCache::default().load(&spec, &scenes)?;
    let mut world = World::new(assets)?;
    let mut script = StrokeScript::new(&world, "left_middle_cerebral", 1)?;
    let occluded = run(&mut world, 1)?;
    if !script.cross(&mut world)? {
        return Err("the scripted operator did not cross the clot".into());
    }
    let m1 = script.branch_inserted_m;
    script.move_to(&mut world, 1, m1 - 8e-3, 6000)?;
    script.bring_in(&mut world, "stent-retriever-4x20")?;
    script.apply(&mut world, Command::DeployStent)?;
    for _ in 0..5000 {
        world.step()?;
    }
    let bypass = run(&mut world, script.seq + 1)?;
    script.seq += 1;
    script.apply(&mut world, Command::RetrieveStent)?;
    StrokeScript::run_until(&mut world, 10_000, |w| {
        w.metrics().thrombectomy.is_some_and(|t| t.passes > 0)
    })?;
    let after = run(&mut world, script.seq + 1)?;
    let panels = [occluded, bypass, after];
    let (w, h) = (panels[0].1, panels[0].2);
    let mut all: Vec<f32> = panels
        .iter()
        .flat_map(|p| p.0.iter().copied())
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    all.sort_by(f32::total_cmp);
    let top = all
        .get((all.len() as f64 * 0.995) as usize)
        .copied()
        .unwrap_or(1.0)
        .max(1e-6);
    let mut image = image::GrayImage::new(3 * w, h);
    for (k, (values, _, _)) in panels.iter().enumerate() {
        for y in 0..h {
            for x in 0..w {
                let v = values[(x + w * y) as usize];
                let grey = if v.is_finite() {
                    255.0 * (1.0 - (v / top).clamp(0.0, 1.0))
                } else {
                    255.0
                };
                image.put_pixel(k as u32 * w + x, y, image::Luma([grey as u8]));
            }
        }
    }
    image.save(&out)?;
    println!("{out}: {}×{h}", 3 * w);
    Ok(())
}
