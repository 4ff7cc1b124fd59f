//! Contact benchmarks, one core (`cargo bench -p cathlab-physics --bench contact`):
//! - the cost of one Gauss–Seidel sweep as contacts grow from 10 to 200 on N = 200 elements
//!   (the O(M + N) claim: at most 3× from 10 to 200 contacts);
//! - a full navigation step (control, collision detection, beam solve, contacts with friction)
//!   of a wire buckled in a dead-end tube, with its element and contact counts printed.

use std::hint::black_box;

use cathlab_physics::contact::{Contact, ContactSettings, gauss_seidel};
use cathlab_physics::navigation::{Command, Insertion, Navigation, NavigationSettings, Twist};
use cathlab_physics::scenarios::wire_in_a_ring;
use cathlab_physics::wall::CappedTube;
use cathlab_physics::{BeamModel, SolverSettings, Substructure, presets};
use criterion::{BatchSize, BenchmarkId, Criterion, criterion_group, criterion_main};
use nalgebra::{Vector3, Vector6};

fn sweep_cost(c: &mut Criterion) {
    let elements = 200;
    let props = presets::micro_guidewire_014().sections[0].beam_properties();
    let mut model = BeamModel::straight(props, 0.4, elements, SolverSettings::default()).unwrap();
    let k = model.tangent_stiffness().clone();
    let mut substructure = Substructure::new(&k).unwrap();
    let flexibility = substructure.flexibility();
    let mut load = vec![Vector6::zeros(); elements];
    load[elements - 1] = Vector6::new(0.0, -1e-3, 2e-4, 0.0, 0.0, 0.0);
    let free = substructure.solve(&load);
    // Each budget runs that many frictional sweeps, then as many with the friction frozen
    // (tolerance 0 never converges). The cost of one iteration is the difference between the
    // two budgets over the 40 extra sweeps: the one-off set-up (compliance blocks, ordering)
    // cancels out.
    let mut group = c.benchmark_group("gauss_seidel_n200");
    for contacts in [10usize, 25, 50, 100, 200] {
        let list: Vec<Contact> = (0..contacts)
            .map(|i| {
                let position = (i as f64 + 0.5) / contacts as f64 * elements as f64;
                let angle = 0.3 * (i as f64).sin();
                Contact {
                    element: (position as usize).min(elements - 1),
                    t: position.fract(),
                    normal: Vector3::new(0.0, angle.cos(), angle.sin()),
                    gap: 1e-5 * ((i % 7) as f64 - 3.0),
                    friction: 0.05,
                    slip: Vector3::zeros(),
                }
            })
            .collect();
        for budget in [10usize, 30] {
            let settings = ContactSettings {
                tolerance: 0.0,
                absolute_tolerance_n: 0.0,
                max_iterations: budget,
                ..Default::default()
            };
            group.bench_with_input(
                BenchmarkId::new(
                    format!("{contacts}_contacts"),
                    format!("{budget}+{budget}_sweeps"),
                ),
                &list,
                |b, list| {
                    b.iter(|| {
                        gauss_seidel(&flexibility, &free, black_box(list), &settings, None).unwrap()
                    })
                },
            );
        }
    }
    group.finish();
}

fn navigation_step(c: &mut Criterion) {
    // A 0.014" wire pushed 60 mm into a 4 mm tube closed 40 mm in: buckled, many contacts.
    let wall = CappedTube {
        start: Vector3::zeros(),
        axis: Vector3::x(),
        length_m: 0.04,
        radius_m: 2e-3,
    };
    let mut nav = Navigation::new(
        presets::micro_guidewire_014(),
        wall,
        Vector3::zeros(),
        Vector3::x(),
        0.01,
        NavigationSettings::default(),
    )
    .unwrap();
    nav.set_command(Command {
        insertion: Insertion::Velocity(0.01),
        twist: Twist::Rate(0.0),
    })
    .unwrap();
    for _ in 0..3000 {
        nav.step().unwrap();
    }
    let report = nav.step().unwrap();
    println!(
        "navigation state: {} elements, {} contacts ({} active)",
        report.elements, report.contacts, report.active_contacts
    );
    c.bench_function("navigation_step_buckled_in_tube", |b| {
        b.iter_batched(
            || nav.clone(),
            |mut n| n.step().unwrap(),
            BatchSize::SmallInput,
        )
    });
}

fn navigation_step_n100(c: &mut Criterion) {
    // A 0.014" wire pushed around a ring of tube (core radius 12 mm, lumen 2 mm): it hugs the
    // outer wall along its whole length. GS_TOL=… overrides the Gauss–Seidel force tolerance.
    let mut settings = NavigationSettings::default();
    if let Some(t) = std::env::var("GS_TOL").ok().and_then(|t| t.parse().ok()) {
        settings.contact.tolerance = t;
    }
    let mut nav = wire_in_a_ring(settings).unwrap();
    let report = nav.step().unwrap();
    let mut worst: f64 = 0.0;
    let mut probe = nav.clone();
    for _ in 0..100 {
        probe.step().unwrap();
        worst = worst.max(probe.max_penetration_m());
    }
    println!(
        "worst penetration over 100 more steps: {:.4} mm",
        worst * 1e3
    );
    println!(
        "ring state: {} elements, {} contacts ({} active), {} sweeps, inserted {:.0} mm",
        report.elements,
        report.contacts,
        report.active_contacts,
        report.sweeps,
        report.inserted_m * 1e3
    );
    c.bench_function("navigation_step_n100_ring", |b| {
        b.iter_batched(
            || nav.clone(),
            |mut n| n.step().unwrap(),
            BatchSize::SmallInput,
        )
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = sweep_cost, navigation_step, navigation_step_n100
}
criterion_main!(benches);
