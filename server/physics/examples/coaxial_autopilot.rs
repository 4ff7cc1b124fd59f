//! Two-hand coaxial navigation in the real arch-to-circle-of-Willis anatomy: a 5 F catheter
//! follows a shaped 0.035" wire from the femoral access; optionally a microcatheter and a
//! microwire go on through the catheter. Prints step-time percentiles and worst penetration.
//!
//! `cargo run --release -p cathlab-physics --example coaxial_autopilot -- LCCA RVA`

use std::path::Path;

use cathlab_anatomy::real::load_arch_to_cow;
use cathlab_physics::scenarios::{CoaxialPlan, run_coaxial_arch_to_cow};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let anatomy = load_arch_to_cow(&dir)?;
    let mut targets: Vec<String> = std::env::args().skip(1).collect();
    if targets.is_empty() {
        targets = vec!["LCCA".into(), "RVA".into()];
    }
    for target in targets {
        let plan = CoaxialPlan::for_target(&anatomy.graph, &target)?;
        let run = run_coaxial_arch_to_cow(&anatomy, &plan)?;
        let mut times = run.step_times_s.clone();
        times.sort_by(f64::total_cmp);
        let percentile = |p: f64| times[((times.len() - 1) as f64 * p).round() as usize] * 1e3;
        println!(
            "{target}: wire {} at step {:?}, microcatheter {} at step {:?}; {} steps, {} pull-backs, tip in {}, inserted {:?} mm",
            if run.reached_at_step.is_some() {
                "reached"
            } else {
                "NOT reached"
            },
            run.reached_at_step,
            if run.micro_done_at_step.is_some() {
                "through"
            } else {
                "NOT through"
            },
            run.micro_done_at_step,
            run.steps,
            run.retries,
            run.tip_branch,
            run.inserted_m
                .iter()
                .map(|l| (l * 1e4).round() / 10.0)
                .collect::<Vec<_>>()
        );
        println!(
            "  step time p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms; worst penetration {:.4} mm; largest hand force {:.3} N",
            percentile(0.5),
            percentile(0.99),
            times.last().copied().unwrap_or(0.0) * 1e3,
            run.worst_penetration_m * 1e3,
            run.max_hand_force_n
        );
        for (label, range) in [
            ("first 5,000 steps (wire leads)", 0..5_000.min(times.len())),
            (
                "last 2,000 steps (microcatheter)",
                run.step_times_s.len().saturating_sub(2_000)..run.step_times_s.len(),
            ),
        ] {
            let mut part = run.step_times_s[range.clone()].to_vec();
            part.sort_by(f64::total_cmp);
            if part.is_empty() {
                continue;
            }
            let pc = |p: f64| part[((part.len() - 1) as f64 * p).round() as usize] * 1e3;
            let stats = &run.step_stats[range.clone()];
            let mean = |f: fn(&(usize, usize, usize)) -> usize| {
                stats.iter().map(f).sum::<usize>() as f64 / stats.len().max(1) as f64
            };
            println!(
                "  {label}: p50 {:.3} ms, p99 {:.3} ms; mean {:.1} sweeps, {:.1} active contacts, {:.0} elements",
                pc(0.5),
                pc(0.99),
                mean(|s| s.0),
                mean(|s| s.1),
                mean(|s| s.2)
            );
        }
    }
    Ok(())
}
