//! Chart command: `cargo bench -p cathlab-engine --bench contact_chart` records the contact
//! problems the bundled scenes pose under the random operator (every `every`-th step with at
//! least four contacts, warm starts as the steps had them), solves each again by projected
//! Gauss–Seidel, Gauss–Seidel with Anderson acceleration and the active-set polish (the
//! scenes' setting before Newton), and semismooth Newton, and writes
//! `docs/figures/contact_residual_vs_time.svg` (and a CSV): the median over problems of the
//! Alart–Curnier residual, relative to the largest force, against solve time. It prints each
//! method's iterations (p50, p95, max) and how many problems Newton solved in at most five.
//! Without `--bench` (as in `cargo test`) it records a few problems of one scene and writes
//! nothing. To study a solver on the same problems again and again: `CONTACT_SCENES` (scenes
//! to record), `CONTACT_SECONDS`, `CONTACT_EVERY`, `CONTACT_LIMIT` (what is recorded),
//! `CONTACT_PROBLEMS=file.json` (read the problems from there, or record and write them),
//! `CONTACT_PICK=k` (one problem), `CONTACT_METHODS` (methods whose label contains it),
//! `CONTACT_SCENE_TOLERANCE` (the scenes' stopping rule instead of the tight one, with
//! `CONTACT_TOL` and `CONTACT_VIOLATION` to change it), `CONTACT_ACCURACY` (instead of the
//! chart, a table of stopping rules: sweeps, solve time, and how far the contact points'
//! displacement lies from a tightly solved reference); any of them leaves the committed
//! chart alone.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use cathlab_engine::stress::{StressSettings, run};
use cathlab_engine::*;
use cathlab_physics::contact::{
    ContactMethod, ContactSettings, RecordedProblem, RecordingPlan, delassus_problem,
    gauss_seidel_observed, newton, newton_solve_observed, record,
};
use nalgebra::Vector3;
use plotters::prelude::*;

#[path = "../../physics/benches/common/mod.rs"]
#[allow(dead_code)]
mod common;
use common::{Series, log_chart};

/// One method's run on one problem: the time per iteration (s) and the relative residual
/// before the first and after every iteration.
struct Trace {
    seconds_per_iteration: f64,
    residuals: Vec<f64>,
}

type Solver = fn(&RecordedProblem, &ContactSettings, &mut dyn FnMut(&[Vector3<f64>]));

fn gauss_seidel(
    p: &RecordedProblem,
    s: &ContactSettings,
    observe: &mut dyn FnMut(&[Vector3<f64>]),
) {
    gauss_seidel_observed(
        &p.flexibility,
        &p.free,
        &p.contacts,
        s,
        p.warm_start.as_deref(),
        observe,
    )
    .unwrap();
}

fn newton(p: &RecordedProblem, s: &ContactSettings, observe: &mut dyn FnMut(&[Vector3<f64>])) {
    newton_solve_observed(
        &p.flexibility,
        &p.free,
        &p.contacts,
        s,
        p.warm_start.as_deref(),
        observe,
    )
    .unwrap();
}

fn trace(problem: &RecordedProblem, settings: &ContactSettings, solver: Solver) -> Trace {
    let delassus =
        delassus_problem(&problem.flexibility, &problem.free, &problem.contacts).unwrap();
    let start: Vec<Vector3<f64>> = problem
        .warm_start
        .clone()
        .unwrap_or_else(|| vec![Vector3::zeros(); problem.contacts.len()]);
    let mut iterates = vec![start];
    solver(problem, settings, &mut |l| iterates.push(l.to_vec()));
    // Timed without the observer's copies: the median of five solves.
    let mut times: Vec<f64> = (0..5)
        .map(|_| {
            let t = Instant::now();
            solver(problem, settings, &mut |_| {});
            t.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    let iterations = (iterates.len() - 1).max(1);
    let residuals = iterates
        .iter()
        .map(|l| {
            let force = l.iter().map(|v| v.norm()).fold(1e-12, f64::max);
            newton::residual(&delassus, l) / force
        })
        .collect();
    Trace {
        seconds_per_iteration: times[2] / iterations as f64,
        residuals,
    }
}

/// The value of the experiment option `name` (an environment variable), or `default` where it
/// is unset; a value that does not read stops the run, naming the option.
fn option<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name).map_or(default, |v| {
        v.parse()
            .unwrap_or_else(|_| panic!("{name}: cannot read {v:?}"))
    })
}

/// Prints, per stopping rule, the sweeps, the solve time and the largest difference of the
/// contact points' displacement from the tightly solved reference (see `CONTACT_ACCURACY`).
fn accuracy(problems: &[RecordedProblem]) {
    let base = cathlab_physics::NavigationSettings::default().contact;
    let solve = |p: &RecordedProblem, s: &ContactSettings| {
        gauss_seidel_observed(
            &p.flexibility,
            &p.free,
            &p.contacts,
            s,
            p.warm_start.as_deref(),
            &mut |_| {},
        )
        .unwrap()
    };
    let displacement = |p: &RecordedProblem, local: &[Vector3<f64>]| {
        let d = delassus_problem(&p.flexibility, &p.free, &p.contacts).unwrap();
        let lambda = nalgebra::DVector::from_iterator(
            3 * local.len(),
            local.iter().flat_map(|l| [l.x, l.y, l.z]),
        );
        &d.w * lambda + &d.q
    };
    let reference: Vec<nalgebra::DVector<f64>> = problems
        .iter()
        .map(|p| {
            let tight = ContactSettings {
                tolerance: 1e-10,
                absolute_tolerance_n: 0.0,
                violation_tolerance_m: f64::INFINITY,
                max_iterations: 5000,
                acceleration_depth: 0,
                polish: false,
                ..base
            };
            displacement(p, &solve(p, &tight).local)
        })
        .collect();
    println!(
        "| rule (relative, violation µm, sweep cap) | solver | sweeps p50 / p95 | solve p50 / p95 (µs) | Δ contact displacement p50 / p95 / max (µm) | deepest normal (µm) |"
    );
    println!("|---|---|---|---|---|---|");
    // The stopping rules with the scenes' sweep cap, then the scenes' rule under lower caps
    // (an unconverged solve ends in the polish: exact normal forces, friction as it stood).
    let rules = [
        (1e-3, 1e-6),
        (3e-3, 1e-6),
        (1e-2, 1e-6),
        (1e-2, 3e-6),
        (1e-2, 5e-6),
        (1e-2, 1e-5),
        (3e-2, 1e-5),
    ]
    .map(|(t, v)| (t, v, base.max_iterations));
    let caps = [150, 100, 60, 40, 25].map(|cap| (base.tolerance, base.violation_tolerance_m, cap));
    for (tolerance, violation, cap) in rules.into_iter().chain(caps) {
        for (label, depth, polish) in [
            ("Gauss–Seidel", 0, false),
            ("+ polish", 0, true),
            ("+ Anderson + polish", 5, true),
        ] {
            if cap < base.max_iterations && !polish {
                continue;
            }
            let settings = ContactSettings {
                tolerance,
                violation_tolerance_m: violation,
                acceleration_depth: depth,
                polish,
                max_iterations: cap,
                ..base
            };
            let mut sweeps = Vec::new();
            let mut times = Vec::new();
            let mut errors = Vec::new();
            let mut deepest: f64 = 0.0;
            for (p, r) in problems.iter().zip(&reference) {
                let t = Instant::now();
                let response = solve(p, &settings);
                times.push(t.elapsed().as_secs_f64() * 1e6);
                sweeps.push(response.iterations as f64);
                let u = displacement(p, &response.local);
                errors.push((&u - r).amax() * 1e6);
                for k in 0..p.contacts.len() {
                    deepest = deepest.max(-u[3 * k] * 1e6);
                }
            }
            for v in [&mut sweeps, &mut times, &mut errors] {
                v.sort_by(f64::total_cmp);
            }
            println!(
                "| {tolerance:e}, {}, cap {cap} | {label} | {} / {} | {:.0} / {:.0} | {:.2} / {:.2} / {:.2} | {deepest:.2} |",
                violation * 1e6,
                quantile(&sweeps, 0.5),
                quantile(&sweeps, 0.95),
                quantile(&times, 0.5),
                quantile(&times, 0.95),
                quantile(&errors, 0.5),
                quantile(&errors, 0.95),
                quantile(&errors, 1.0),
            );
        }
    }
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let disk = Path::new(env!("CARGO_TARGET_TMPDIR")).join("asset-cache");
    let cache = AssetCache::default().with_disk_cache(&disk);
    let default_names: &[&str] = if full {
        &[
            "arch_to_cow_lcca",
            "arch_to_cow_basilar",
            "arch_to_cow_lcca_coaxial",
            "segmented_aorta_suprarenal",
            "neuro_phantom_m1",
        ]
    } else {
        &["arch_to_cow_lcca"]
    };
    // CONTACT_SCENES (comma-separated) records other scenes; CONTACT_PROBLEMS=file reads the
    // problems from that JSON file if it exists, else records them and writes it (to try a
    // solver again and again on the same problems); neither changes the committed chart's run.
    let names: Vec<String> = std::env::var("CONTACT_SCENES")
        .map(|s| s.split(',').map(str::to_owned).collect())
        .unwrap_or_else(|_| default_names.iter().map(|s| s.to_string()).collect());
    let stored = std::env::var("CONTACT_PROBLEMS").ok().map(PathBuf::from);
    // CONTACT_EVERY, CONTACT_LIMIT and CONTACT_SECONDS change what is recorded.
    let plan = RecordingPlan {
        min_contacts: 4,
        every: option("CONTACT_EVERY", if full { 97 } else { 5 }),
        limit: option("CONTACT_LIMIT", if full { 60 } else { 4 }),
    };
    let seconds: f64 = option("CONTACT_SECONDS", if full { 30.0 } else { 2.0 });
    let problems: Vec<RecordedProblem> = match &stored {
        Some(path) if path.exists() => {
            let problems: Vec<RecordedProblem> =
                serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
            println!("{} problems read from {}", problems.len(), path.display());
            problems
        }
        _ => {
            let mut problems = Vec::new();
            for name in &names {
                let text = std::fs::read_to_string(scenes.join(format!("{name}.toml"))).unwrap();
                let spec = SceneSpec::parse(&text, SceneFormat::Toml).unwrap();
                let mut world = World::new(cache.load(&spec, &scenes).unwrap()).unwrap();
                let (_, recorded) =
                    record(plan, || run(&mut world, &StressSettings::new(7, seconds)));
                println!("{name}: {} problems recorded", recorded.len());
                problems.extend(recorded);
            }
            if let Some(path) = &stored {
                std::fs::write(path, serde_json::to_vec(&problems).unwrap()).unwrap();
            }
            problems
        }
    };
    // CONTACT_PICK=k: only the k-th problem (to trace one solve).
    let problems: Vec<RecordedProblem> = match std::env::var("CONTACT_PICK") {
        Ok(_) => vec![problems[option("CONTACT_PICK", 0usize)].clone()],
        Err(_) => problems,
    };
    // CONTACT_SCENE_TOLERANCE: the scenes' own stopping rule instead of the chart's tight one,
    // CONTACT_TOL and CONTACT_VIOLATION changing it.
    let scene_rule = std::env::var("CONTACT_SCENE_TOLERANCE").is_ok().then(|| {
        let base = cathlab_physics::NavigationSettings::default().contact;
        ContactSettings {
            tolerance: option("CONTACT_TOL", base.tolerance),
            violation_tolerance_m: option("CONTACT_VIOLATION", base.violation_tolerance_m),
            ..base
        }
    });
    // CONTACT_ACCURACY: what a looser stopping rule costs in accuracy, against what it saves:
    // each problem solved to 1e-10 as the reference, then under the scenes' rule with the
    // relative tolerance and violation bound loosened; the contact points' displacement
    // (W λ + q, the motion the forces give the device there) compared with the reference's.
    if std::env::var("CONTACT_ACCURACY").is_ok() {
        accuracy(&problems);
        return;
    }
    let tight = |method, depth, polish| {
        if let Some(rule) = scene_rule {
            return ContactSettings {
                method,
                acceleration_depth: depth,
                polish,
                ..rule
            };
        }
        ContactSettings {
            method,
            tolerance: 1e-9,
            absolute_tolerance_n: 0.0,
            violation_tolerance_m: f64::INFINITY,
            max_iterations: 300,
            acceleration_depth: depth,
            polish,
            ..ContactSettings::default()
        }
    };
    let methods: [(&str, ContactSettings, Solver, RGBColor); 3] = [
        (
            "Gauss–Seidel",
            tight(ContactMethod::GaussSeidel, 0, false),
            gauss_seidel,
            RED,
        ),
        (
            "Gauss–Seidel, Anderson + active-set polish",
            tight(ContactMethod::GaussSeidel, 5, true),
            gauss_seidel,
            BLUE,
        ),
        (
            "semismooth Newton",
            tight(ContactMethod::Newton, 0, false),
            newton,
            GREEN,
        ),
    ];
    let mut csv = String::from("method,problem,contacts,iteration,seconds,relative_residual\n");
    let mut series: Vec<Series> = Vec::new();
    // CONTACT_METHODS: only the methods whose label contains it.
    let only = std::env::var("CONTACT_METHODS").ok();
    for (label, settings, solver, color) in methods {
        if only.as_ref().is_some_and(|o| !label.contains(o.as_str())) {
            continue;
        }
        let traces: Vec<Trace> = problems
            .iter()
            .map(|p| trace(p, &settings, solver))
            .collect();
        let mut iterations: Vec<f64> = traces
            .iter()
            .map(|t| (t.residuals.len() - 1) as f64)
            .collect();
        iterations.sort_by(f64::total_cmp);
        let mut per_solve: Vec<f64> = traces
            .iter()
            .map(|t| t.seconds_per_iteration * (t.residuals.len() - 1) as f64 * 1e6)
            .collect();
        per_solve.sort_by(f64::total_cmp);
        let within = |n: f64| iterations.iter().filter(|&&i| i <= n).count();
        println!(
            "{label}: {} problems, iterations p50 {} p95 {} max {}, {} in at most 5; solve p50 {:.1} µs, p95 {:.1} µs",
            traces.len(),
            quantile(&iterations, 0.5),
            quantile(&iterations, 0.95),
            quantile(&iterations, 1.0),
            within(5.0),
            quantile(&per_solve, 0.5),
            quantile(&per_solve, 0.95),
        );
        for (k, (t, p)) in traces.iter().zip(&problems).enumerate() {
            for (i, r) in t.residuals.iter().enumerate() {
                writeln!(
                    csv,
                    "{label},{k},{},{i},{:e},{r:e}",
                    p.contacts.len(),
                    t.seconds_per_iteration * i as f64
                )
                .unwrap();
            }
        }
        // The median residual over problems on a common time grid (µs): each problem's last
        // iterate finished by then.
        let grid: Vec<f64> = (0..40).map(|i| 10f64.powf(0.0 + i as f64 * 0.1)).collect();
        let curve: Vec<(f64, f64)> = grid
            .iter()
            .map(|&us| {
                let mut at: Vec<f64> = traces
                    .iter()
                    .map(|t| {
                        let done = ((us * 1e-6) / t.seconds_per_iteration).floor() as usize;
                        t.residuals[done.min(t.residuals.len() - 1)].max(1e-16)
                    })
                    .collect();
                at.sort_by(f64::total_cmp);
                (us, quantile(&at, 0.5))
            })
            .collect();
        series.push((label.to_owned(), curve, color));
    }
    // Any CONTACT_* option makes the run an experiment: the committed chart stays.
    let custom = std::env::vars().any(|(name, _)| name.starts_with("CONTACT_"));
    if !full || custom {
        return;
    }
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures");
    std::fs::write(dir.join("contact_residual_vs_time.csv"), csv).unwrap();
    log_chart(
        &dir.join("contact_residual_vs_time.svg"),
        "Contact problems recorded in the bundled scenes (median)",
        "solve time (µs)",
        "residual / largest force",
        &series,
    );
}
