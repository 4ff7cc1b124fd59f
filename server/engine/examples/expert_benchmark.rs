//! The expert benchmark of stack scenes: each scene's two-hand autopilot demonstrates from the
//! start with fluoroscopy on until the target is reached; the run is assessed like a
//! trainee's and its scores printed as the `[assessment.expert]` table to paste into the
//! scene file (the scores the report judges trainees against).
//!
//!   cargo run --release -p cathlab-engine --example expert_benchmark -- scenes/NAME.toml...

use std::path::Path;
use std::sync::atomic::AtomicBool;

use cathlab_engine::*;

fn main() -> std::result::Result<(), Box<dyn std::error::Error>> {
    let cache = AssetCache::default();
    for file in std::env::args().skip(1) {
        let path = Path::new(&file);
        let text = std::fs::read_to_string(path)?;
        let spec = SceneSpec::parse(&text, SceneFormat::Toml)?;
        let base = path.parent().unwrap_or(Path::new("."));
        let assets = cache.load(&spec, base)?;
        let started = std::time::Instant::now();
        let (commands, end) = expert_run(assets.clone(), 60_000)?;
        let report = assess(
            assets,
            &commands,
            end,
            &ReportOptions::default(),
            &AtomicBool::new(false),
        )?;
        println!(
            "# {file}: expert run of {:.2} s simulated ({:.0} s wall), {} error(s)",
            report.duration_s,
            started.elapsed().as_secs_f64(),
            report.errors.len()
        );
        for p in &report.phases {
            match (p.start_s, p.end_s) {
                (Some(a), Some(b)) => println!("#   phase {}: {a:.1}–{b:.1} s", p.name),
                _ => println!("#   phase {}: not reached", p.name),
            }
        }
        for e in &report.errors {
            println!("#   {:.1} s {}: {}", e.start_s, e.kind.as_str(), e.detail);
        }
        println!("[assessment.expert]");
        for m in &report.metrics {
            if report::is_expert_metric(&m.key, m.value) {
                println!("{} = {}", m.key, significant(m.value, 4));
            }
        }
        println!();
    }
    Ok(())
}

/// `v` to `digits` significant digits.
fn significant(v: f64, digits: i32) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let scale = 10f64.powi(digits - 1 - v.abs().log10().floor() as i32);
    (v * scale).round() / scale
}
