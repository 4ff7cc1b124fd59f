//! Criterion benchmarks of coaxial stacks in merged mode: one step of a triaxial stack
//! (5 F catheter, 0.017" microcatheter, 0.014" microwire) in the real arch-to-cow anatomy with
//! its wall contacts, and the cost of a step against the node count in free space.
//!
//! `cargo bench -p cathlab-physics --bench coaxial`; the triaxial state comes from the two-hand
//! LCCA run (about 22,500 steps of set-up).

use std::hint::black_box;
use std::path::Path;

use cathlab_anatomy::real::load_arch_to_cow;
use cathlab_physics::navigation::{Command, Insertion, NavigationSettings, Twist};
use cathlab_physics::scenarios::{CoaxialPlan, coaxial_arch_to_cow_stack};
use cathlab_physics::{FreeSpace, InstrumentSpec, Stack, presets};
use criterion::{BatchSize, BenchmarkId, Criterion, criterion_group, criterion_main};
use nalgebra::Vector3;

fn push(speed: f64) -> Command {
    Command {
        insertion: Insertion::Velocity(speed),
        twist: Twist::Rate(0.0),
    }
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn triaxial(c: &mut Criterion) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let anatomy = load_arch_to_cow(&dir).unwrap();
    let plan = CoaxialPlan::for_target(&anatomy.graph, "LCCA").unwrap();
    let (run, mut stack) = coaxial_arch_to_cow_stack(&anatomy, &plan).unwrap();
    assert!(run.micro_done_at_step.is_some(), "set-up run failed");
    // The operator advances the microcatheter and microwire together at 10 mm/s.
    stack.set_command(1, push(0.01)).unwrap();
    stack.set_command(2, push(0.01)).unwrap();
    let start = stack.clone();
    let mut times = Vec::new();
    let mut elements = 0;
    let mut contacts = 0;
    for _ in 0..1000 {
        let started = std::time::Instant::now();
        let report = stack.step().unwrap();
        times.push(started.elapsed().as_secs_f64() * 1e3);
        elements = elements.max(report.elements);
        contacts = contacts.max(report.active_contacts);
    }
    times.sort_by(f64::total_cmp);
    println!(
        "triaxial merged step, 1000 steps at 10 mm/s: p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms; up to {elements} elements, {contacts} active contacts",
        percentile(&times, 0.5),
        percentile(&times, 0.99),
        times.last().unwrap()
    );
    c.bench_function("triaxial_merged_step_arch_to_cow", |b| {
        b.iter_batched(
            || start.clone(),
            |mut s| black_box(s.step().unwrap()),
            BatchSize::SmallInput,
        );
    });
}

/// A straight triaxial stack in free space with `elements` elements along 300 mm, pushed.
fn free_triaxial(elements: usize) -> Stack<FreeSpace> {
    let h = 0.3 / elements as f64;
    let settings = NavigationSettings {
        tip_element_m: h,
        shaft_element_m: h,
        refinement: None,
        ..NavigationSettings::default()
    };
    let spec = |device, l| InstrumentSpec::new(device, l, &settings);
    let mut stack = Stack::new(
        vec![
            spec(presets::diagnostic_catheter_5f(), 0.26),
            spec(presets::micro_catheter(), 0.28),
            spec(presets::micro_guidewire_014(), 0.30),
        ],
        FreeSpace,
        Vector3::zeros(),
        Vector3::x(),
        settings,
    )
    .unwrap();
    stack.set_command(1, push(0.01)).unwrap();
    stack.step().unwrap();
    stack
}

fn linearity(c: &mut Criterion) {
    let mut group = c.benchmark_group("triaxial_free_step_vs_elements");
    for n in [100, 200, 400, 1000] {
        let start = free_triaxial(n);
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter_batched(
                || start.clone(),
                |mut s| black_box(s.step().unwrap()),
                BatchSize::SmallInput,
            );
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = triaxial, linearity
}
criterion_main!(benches);
