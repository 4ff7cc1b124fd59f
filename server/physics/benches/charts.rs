//! Chart command: `cargo bench -p cathlab-physics --bench charts` measures accuracy and
//! speed and writes SVG charts into `docs/figures/` (plus a CSV of every point).
//! Under `cargo test --benches` it runs a tiny version and writes nothing.

use std::fmt::Write as _;
use std::path::PathBuf;

use cathlab_physics::scenarios::{
    end_moment_rollup, solve_tip_loaded_cantilever, tip_loaded_cantilever,
};
use cathlab_physics::{SolverSettings, StepMode, elastica};
use plotters::prelude::*;

mod common;
use common::{Series, log_chart, time};

fn converged() -> SolverSettings {
    SolverSettings {
        mode: StepMode::CONVERGED,
        ..Default::default()
    }
}

fn paper() -> SolverSettings {
    SolverSettings::default()
}

fn literal_paper() -> SolverSettings {
    SolverSettings {
        geometric_stiffness: false,
        ..SolverSettings::default()
    }
}

fn main() {
    // `cargo bench` passes --bench; `cargo test --benches` does not: then only smoke-test.
    let full = std::env::args().any(|a| a == "--bench");
    let counts: &[usize] = if full {
        &[5, 10, 25, 50, 100, 200, 400]
    } else {
        &[5, 10]
    };
    let alpha = 1.0;
    let mut csv = String::from("chart,series,x,y\n");
    let mut record = |chart: &str, s: &Series| {
        for (x, y) in &s.1 {
            writeln!(csv, "{chart},{},{x:e},{y:e}", s.0).unwrap();
        }
    };
    let reference = elastica::tip_loaded_cantilever(alpha);
    let error_of = |tip: nalgebra::Vector3<f64>| {
        ((tip.x - (1.0 - reference.shortening)).powi(2) + (tip.y + reference.deflection).powi(2))
            .sqrt()
    };

    // 1. Tip error vs N, α = 1 (load ramped over 10 steps).
    let mut conv = Vec::new();
    let mut pap = Vec::new();
    let mut lit = Vec::new();
    for &n in counts {
        let run = |s| {
            tip_loaded_cantilever(alpha, n, s, 10, 0)
                .ok()
                .filter(|r| r.converged)
        };
        if let Some(r) = run(converged()) {
            conv.push((n as f64, r.tip_error));
        }
        // Paper mode with a real-time budget: 10 ramp steps + 10 held steps (20 solves).
        if let Ok(r) = tip_loaded_cantilever(alpha, n, paper(), 10, 10) {
            pap.push((n as f64, r.tip_error));
        }
        if let Ok(r) = tip_loaded_cantilever(alpha, n, literal_paper(), 10, 10) {
            lit.push((n as f64, r.tip_error));
        }
    }
    let error_series: Vec<Series> = vec![
        ("converged mode".into(), conv, BLUE),
        ("paper mode, 20 steps".into(), pap, RED),
        (
            "paper mode, K̄ only (paper's tangent), 20 steps".into(),
            lit,
            GREEN,
        ),
    ];
    // 2. Time per step vs N (paper mode, flexibility included).
    let mut per_step = Vec::new();
    for &n in counts {
        let props = cathlab_physics::scenarios::slender_test_wire();
        let mut model = cathlab_physics::BeamModel::straight(props, 1.0, n, paper()).unwrap();
        model
            .set_load(
                n,
                nalgebra::Vector3::new(0.0, -props.bending_stiffness_nm2, 0.0),
                nalgebra::Vector3::zeros(),
            )
            .unwrap();
        let reps = if full { 2000 / n.max(1) + 20 } else { 2 };
        per_step.push((n as f64, time(reps, || model.step().unwrap())));
    }
    let step_series: Vec<Series> = vec![("one step (paper mode)".into(), per_step, BLUE)];
    // 3. Error vs time: converged mode at each N, and paper mode at N = 50 after k steps
    //    with the load applied at once.
    let mut front_conv = Vec::new();
    for &n in counts {
        let s = SolverSettings {
            mode: StepMode::Converged {
                tolerance: 1e-6,
                max_iterations: 50,
            },
            ..converged()
        };
        let seconds = time(if full { 9 } else { 1 }, || {
            solve_tip_loaded_cantilever(alpha, n, s, 1, 0)
        });
        if let Ok((tip, _, true)) = solve_tip_loaded_cantilever(alpha, n, s, 1, 0) {
            front_conv.push((seconds, error_of(tip)));
        }
    }
    let mut front_paper = Vec::new();
    for steps in if full {
        vec![1, 2, 3, 4, 6, 8, 12, 16, 24]
    } else {
        vec![1, 2]
    } {
        let seconds = time(if full { 9 } else { 1 }, || {
            solve_tip_loaded_cantilever(alpha, 50, paper(), 1, steps - 1)
        });
        if let Ok((tip, _, _)) = solve_tip_loaded_cantilever(alpha, 50, paper(), 1, steps - 1) {
            front_paper.push((seconds, error_of(tip)));
        }
    }
    let front_series: Vec<Series> = vec![
        ("converged mode, N = 5…400".into(), front_conv, BLUE),
        ("paper mode, N = 50, 1…24 steps".into(), front_paper, RED),
    ];
    // 4. Roll-up: tip-to-base distance vs load steps, N = 100.
    let steps_list: &[usize] = if full {
        &[10, 20, 50, 100, 200, 500]
    } else {
        &[10]
    };
    let mut roll = [Vec::new(), Vec::new(), Vec::new()];
    for &steps in steps_list {
        for (i, s) in [
            converged(),
            SolverSettings {
                geometric_stiffness: false,
                ..converged()
            },
            paper(),
        ]
        .into_iter()
        .enumerate()
        {
            if let Ok(r) = end_moment_rollup(100, s, steps)
                && r.converged
            {
                roll[i].push((steps as f64, r.tip_error));
            }
        }
    }
    let [a, b, c] = roll;
    let roll_series: Vec<Series> = vec![
        ("converged, with geometric stiffness".into(), a, BLUE),
        (
            "converged, K̄ only (diverges below 100 steps)".into(),
            b,
            GREEN,
        ),
        ("paper mode (one solve per step)".into(), c, RED),
    ];

    // 5. Coaxial stacks: merged mode against the nested reference, one to four instruments,
    //    pushed from the femoral access up the descending aorta into the arch.
    let (coax_cost, coax_error) = coaxial(full);

    for s in &error_series {
        record("tip_error_vs_n", s);
    }
    for s in &step_series {
        record("time_per_step_vs_n", s);
    }
    for s in &front_series {
        record("error_vs_time", s);
    }
    for s in &roll_series {
        record("rollup_vs_load_steps", s);
    }
    for s in &coax_cost {
        record("coaxial_cost_vs_instruments", s);
    }
    for s in &coax_error {
        record("coaxial_merge_error_vs_instruments", s);
    }
    print!("{csv}");
    if !full {
        return;
    }
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures");
    std::fs::create_dir_all(&dir).unwrap();
    log_chart(
        &dir.join("tip_error_vs_n.svg"),
        "Tip-loaded cantilever, α = 1: tip error vs elements",
        "elements N",
        "tip error / L",
        &error_series,
    );
    log_chart(
        &dir.join("time_per_step_vs_n.svg"),
        "Time per step vs elements (one core)",
        "elements N",
        "seconds per step",
        &step_series,
    );
    log_chart(
        &dir.join("error_vs_time.svg"),
        "Speed–accuracy front, α = 1 cantilever",
        "wall time to answer (s)",
        "tip error / L",
        &front_series,
    );
    log_chart(
        &dir.join("rollup_vs_load_steps.svg"),
        "Roll-up (M = 2πEI/L), N = 100: tip-to-base distance",
        "load steps",
        "distance / L",
        &roll_series,
    );
    log_chart(
        &dir.join("coaxial_cost_vs_instruments.svg"),
        "Coaxial stack in arch-to-cow: median time per step",
        "instruments",
        "ms per step",
        &coax_cost,
    );
    log_chart(
        &dir.join("coaxial_merge_error_vs_instruments.svg"),
        "Merged mode against nested: tip distance over the run",
        "instruments",
        "tip distance (mm)",
        &coax_error,
    );
    std::fs::write(dir.join("charts.csv"), csv).unwrap();
    println!("charts written to {}", dir.display());
}

/// Merged and nested runs of the same scripted push with 1 to 4 instruments (sheath, distal
/// access catheter, 0.021" microcatheter, 0.014" microwire, each tip 10 mm ahead of the one
/// around it): the median cost of a step in each mode, and the distance between the two
/// modes' tips (the outermost's and the leading one's, largest over the run).
fn coaxial(full: bool) -> (Vec<Series>, Vec<Series>) {
    use cathlab_physics::scenarios::{ScriptedStack, compare_couplings};
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let anatomy = cathlab_anatomy::real::load_arch_to_cow(&dir).unwrap();
    let catalogue = cathlab_physics::Catalogue::builtin();
    let devices: Vec<_> = [
        "sheath-088-90",
        "distal-access-071-132",
        "microcatheter-021-160",
        "microwire-014-angled",
    ]
    .iter()
    .map(|id| catalogue.device(id).unwrap())
    .collect();
    let (counts, steps) = if full { (1..=4, 1200) } else { (2..=2, 40) };
    let (mut merged_cost, mut nested_cost) = (Vec::new(), Vec::new());
    let (mut outer_error, mut lead_error) = (Vec::new(), Vec::new());
    for n in counts {
        let script = ScriptedStack::up_the_aorta(devices[..n].to_vec(), steps);
        let comparison = compare_couplings(&anatomy, &script).unwrap();
        let x = n as f64;
        merged_cost.push((x, comparison.merged.median_step_s() * 1e3));
        nested_cost.push((x, comparison.nested.median_step_s() * 1e3));
        outer_error.push((x, comparison.tip_distance_m[0].0 * 1e3));
        lead_error.push((x, comparison.tip_distance_m[n - 1].0 * 1e3));
        println!("coaxial, {n} instrument(s), {steps} steps at 40 mm/s: {comparison}");
    }
    (
        vec![
            ("merged".into(), merged_cost, BLUE),
            ("nested".into(), nested_cost, RED),
        ],
        vec![
            ("outermost tip".into(), outer_error, BLUE),
            ("leading tip".into(), lead_error, RED),
        ],
    )
}
