//! Chart command: `cargo bench -p cathlab-physics --bench contact_chart` measures contact
//! accuracy against time per navigation step as the Gauss–Seidel force tolerance varies, on a
//! wire pushed around a tight ring of tube (≈100 elements, ≈60 active contacts), and writes
//! `docs/figures/contact_accuracy_vs_time.svg` (and a CSV). Accuracy is the penetration after
//! the step and the error of the proximal reaction force against a solve converged to 1e-9.
//! Under `cargo test --benches` it runs two tolerances and writes nothing.

use std::fmt::Write as _;
use std::path::PathBuf;

use cathlab_physics::navigation::NavigationSettings;
use cathlab_physics::scenarios::wire_in_a_ring;
use plotters::prelude::*;

mod common;
use common::{Series, log_chart, time};

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let settings = NavigationSettings::default();
    let nav = wire_in_a_ring(settings).unwrap();
    let with_tolerance = |tolerance: f64, violation: f64, sweeps: usize| {
        let mut n = nav.clone();
        let mut contact = settings.contact;
        contact.tolerance = tolerance;
        contact.violation_tolerance_m = violation;
        contact.max_iterations = sweeps;
        n.set_contact_settings(contact);
        n
    };
    let mut reference = with_tolerance(1e-9, f64::INFINITY, 100_000);
    reference.step().unwrap();
    let reference_force = reference.proximal_reaction().fixed_rows::<3>(0).norm();
    let tolerances: &[f64] = if full {
        &[3e-1, 1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5, 1e-5]
    } else {
        &[1e-1, 1e-3]
    };
    let mut penetration = Vec::new();
    let mut force_error = Vec::new();
    let mut csv = String::from("tolerance,seconds_per_step,penetration_m,force_error\n");
    for &tolerance in tolerances {
        // Median over runs of one step from the same state (the clone is not timed).
        let runs = if full { 15 } else { 1 };
        let mut samples: Vec<f64> = (0..runs)
            .map(|_| {
                let mut n = with_tolerance(tolerance, f64::INFINITY, 100_000);
                time(1, || n.step().unwrap())
            })
            .collect();
        samples.sort_by(f64::total_cmp);
        let seconds = samples[runs / 2];
        let mut n = with_tolerance(tolerance, f64::INFINITY, 100_000);
        n.step().unwrap();
        let pen = n.max_penetration_m().max(1e-9);
        let force = n.proximal_reaction().fixed_rows::<3>(0).norm();
        let error = ((force - reference_force).abs() / reference_force).max(1e-12);
        println!(
            "tolerance {tolerance:.0e}: {:.0} µs per step, penetration {:.2e} m, reaction error {error:.2e}",
            seconds * 1e6,
            pen
        );
        writeln!(csv, "{tolerance:e},{seconds:e},{pen:e},{error:e}").unwrap();
        penetration.push((seconds, pen * 1e3));
        force_error.push((seconds, error));
    }
    if !full {
        return;
    }
    let series: Vec<Series> = vec![
        ("penetration after the step (mm)".into(), penetration, RED),
        (
            "proximal force error vs converged (relative)".into(),
            force_error,
            BLUE,
        ),
    ];
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures");
    log_chart(
        &dir.join("contact_accuracy_vs_time.svg"),
        "Contact accuracy vs time per step, GS tolerance 3e-1…1e-5 (ring, N≈100, ~60 contacts)",
        "seconds per navigation step (one core)",
        "error",
        &series,
    );
    std::fs::write(dir.join("contact_accuracy_vs_time.csv"), csv).unwrap();
    println!("wrote docs/figures/contact_accuracy_vs_time.svg");
}
