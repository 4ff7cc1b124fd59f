//! Criterion benchmarks: one step (frames, element matrices, substructure solve,
//! flexibility) against N, and the time to static equilibrium of the α = 1 cantilever.

use std::hint::black_box;

use cathlab_physics::scenarios::{solve_tip_loaded_cantilever, tip_loaded_cantilever};
use cathlab_physics::{BeamModel, SolverSettings, StepMode, presets};
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use nalgebra::Vector3;

/// The distal 20 cm of the 0.014" micro-guidewire under a lateral tip load, after it has
/// deflected: a realistic deformed state for every N.
fn deformed_guidewire(elements: usize) -> BeamModel {
    let device = presets::micro_guidewire_014();
    let l = device.length_m();
    let mut model =
        BeamModel::from_device_part(&device, l - 0.2, l, elements, SolverSettings::default())
            .unwrap();
    model
        .set_load(elements, Vector3::new(0.0, 0.0, -5e-5), Vector3::zeros())
        .unwrap();
    for _ in 0..5 {
        model.step().unwrap();
    }
    model
}

fn step(c: &mut Criterion) {
    let mut group = c.benchmark_group("step");
    for n in [25, 50, 100, 200, 400, 1000] {
        let mut model = deformed_guidewire(n);
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| black_box(model.step().unwrap()));
        });
    }
    group.finish();
}

fn equilibrium(c: &mut Criterion) {
    // α = 1 cantilever, N = 100, from straight to 1e-4·L: converged mode with the load
    // applied in one step (the tolerance below gives a tip error far under 1e-4·L).
    let settings = SolverSettings {
        mode: StepMode::Converged {
            tolerance: 1e-6,
            max_iterations: 50,
        },
        geometric_stiffness: true,
        compute_flexibility: false,
        drag: None,
        max_step_increment: None,
        cap_with_held_contacts: false,
        geometric_stiffness_in_compression: true,
        max_substep_halvings: 0,
    };
    let result = tip_loaded_cantilever(1.0, 100, settings, 1, 0).unwrap();
    assert!(result.converged && result.tip_error < 1e-4, "{result:?}");
    println!(
        "α = 1, N = 100: tip error {:.2e}·L in {} solves",
        result.tip_error, result.solves
    );
    c.bench_function("equilibrium_alpha1_n100", |b| {
        b.iter(|| black_box(solve_tip_loaded_cantilever(1.0, 100, settings, 1, 0).unwrap()));
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).measurement_time(std::time::Duration::from_secs(3));
    targets = step, equilibrium
}
criterion_main!(benches);
