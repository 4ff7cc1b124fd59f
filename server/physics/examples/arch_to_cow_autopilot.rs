//! Scripted navigation in the real arch-to-circle-of-Willis anatomy: the route-following
//! autopilot pushes a shaped 0.035" guidewire to the left common carotid (from the femoral
//! access in the descending aorta) or to the right vertebral (from a guide catheter in the
//! aortic arch) and reports the step-time percentiles and the worst penetration.
//!
//! `cargo run --release -p cathlab-physics --example arch_to_cow_autopilot -- LCCA RVA`

use std::path::Path;

use cathlab_anatomy::real::load_arch_to_cow;
use cathlab_physics::scenarios::{ArchToCowPlan, run_arch_to_cow};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let started = std::time::Instant::now();
    let anatomy = load_arch_to_cow(&dir)?;
    println!("anatomy loaded in {:.1} s", started.elapsed().as_secs_f64());
    let mut targets: Vec<String> = std::env::args().skip(1).collect();
    if targets.is_empty() {
        targets = vec!["LCCA".into(), "RVA".into()];
    }
    for target in targets {
        let plan = ArchToCowPlan::for_target(&anatomy.graph, &target)?;
        let run = run_arch_to_cow(&anatomy, &plan)?;
        let mut times = run.step_times_s.clone();
        times.sort_by(f64::total_cmp);
        let percentile = |p: f64| times[((times.len() - 1) as f64 * p).round() as usize] * 1e3;
        println!(
            "{target}: {} with {} from {:.0} mm along the route; {} after {} steps ({:.1} s \
             simulated), {} pull-backs, tip in {}",
            if run.reached_at_step.is_some() {
                "reached"
            } else {
                "NOT reached"
            },
            plan.device.name,
            plan.start_along_m * 1e3,
            if run.reached_at_step.is_some() {
                "target"
            } else {
                "gave up"
            },
            run.steps,
            run.steps as f64 / 500.0,
            run.retries,
            run.tip_branch
        );
        println!(
            "  step time p50 {:.3} ms, p90 {:.3} ms, p99 {:.3} ms, max {:.3} ms; worst \
             penetration {:.4} mm; up to {} active contacts",
            percentile(0.5),
            percentile(0.9),
            percentile(0.99),
            times.last().copied().unwrap_or(0.0) * 1e3,
            run.worst_penetration_m * 1e3,
            run.max_active_contacts
        );
    }
    Ok(())
}
