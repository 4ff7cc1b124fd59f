//! Renders a stack scene after its scripted two-hand operator has reached the target: one
//! fluoroscopy frame (CPU renderer, the scene's settings) as PNG, for the README.
//!
//! `cargo run --release -p cathlab-engine --example stack_figure -- scenes/neuro_phantom_m1.toml docs/figures/neuro_phantom_m1.png`

use std::path::Path;

use cathlab_engine::imaging::{Encoding, encode_frame, expose_snapshot};
use cathlab_engine::{AssetCache, SceneFormat, SceneSpec, World};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(scene), Some(out)) = (args.get(1), args.get(2)) else {
        return Err("usage: stack_figure SCENE.toml OUT.png".into());
    };
    let path = Path::new(scene);
    let mut spec = SceneSpec::parse(&std::fs::read_to_string(path)?, SceneFormat::Toml)?;
    spec.name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let base = path.parent().unwrap_or(Path::new("."));
    let started = std::time::Instant::now();
    let assets = AssetCache::default().load(&spec, base)?;
    println!("loaded in {:.1} s", started.elapsed().as_secs_f64());
    let mut world = World::new(assets.clone())?;
    let started = std::time::Instant::now();
    let reached = world.follow_two_hands(40_000, 1)?;
    println!(
        "two-hand run: {:.2} s wall, {:.3} ms a step",
        started.elapsed().as_secs_f64(),
        started.elapsed().as_secs_f64() * 1e3 / world.step_index().max(1) as f64
    );
    let snapshot = world.snapshot();
    for i in &snapshot.instruments {
        println!(
            "{}: {:.1} mm inserted, {} nodes",
            i.name,
            i.inserted_m * 1e3,
            i.nodes.len()
        );
    }
    println!("target reached at step {reached:?}");
    let frame = expose_snapshot(&assets, &snapshot)?;
    let (png, w, h) = encode_frame(&frame, Encoding::Png, 0, 0)?;
    std::fs::write(out, png)?;
    println!("{out}: {w}×{h}");
    Ok(())
}
