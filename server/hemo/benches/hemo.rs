//! Flow and contrast benchmarks, one core: factorizing and re-solving a 1,000-vessel network,
//! a catheter-narrowing update, and one contrast sub-step over 10,000 cells
//! (`cargo bench -p cathlab-hemo --bench hemo`).

use std::hint::black_box;

use cathlab_hemo::network::random_network;
use cathlab_hemo::scenarios::circle_of_willis;
use cathlab_hemo::{Contrast, ContrastSettings, FlowNetwork, FlowSolver, Injection, Narrowing};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

/// 1,000 vessels: a random tree of 901 nodes plus 100 loop-closing vessels.
fn network_1000() -> FlowNetwork {
    let network = random_network(11, 901, 100).unwrap();
    assert_eq!(network.vessels.len(), 1000);
    network
}

fn flow(c: &mut Criterion) {
    let network = network_1000();
    let mut group = c.benchmark_group("flow_1000_vessels");
    group.bench_function("factorize", |b| {
        b.iter(|| FlowSolver::new(black_box(network.clone())).unwrap())
    });
    let mut solver = FlowSolver::new(network.clone()).unwrap();
    group.bench_function("resolve", |b| b.iter(|| solver.solve(None).unwrap()));
    let injection = Injection {
        vessel: 500,
        arc: 0.5 * network.vessels[500].length(),
        rate: 5e-6,
        concentration: 300.0,
    };
    group.bench_function("resolve_with_injection", |b| {
        b.iter(|| solver.solve(Some(black_box(&injection))).unwrap())
    });
    // A catheter along 8 vessels: the rank-8 update, then a solve.
    let narrowings: Vec<Narrowing> = (0..8)
        .map(|i| Narrowing {
            vessel: 100 * i + 7,
            from_arc: 0.0,
            to_arc: network.vessels[100 * i + 7].length(),
            catheter_radius: 0.3e-3,
        })
        .collect();
    group.bench_function("narrow_8_vessels_and_solve", |b| {
        b.iter(|| {
            solver.set_narrowings(black_box(&narrowings)).unwrap();
            solver.solve(None).unwrap()
        })
    });
    group.finish();
}

fn contrast(c: &mut Criterion) {
    // 100 vessels of 25 mm at 0.25 mm cells: 10,000 cells.
    let network = random_network(5, 101, 0).unwrap();
    let settings = ContrastSettings::default();
    let mut cells_network = network.clone();
    for v in &mut cells_network.vessels {
        let last = v.stations.len() - 1;
        v.stations[last].arc = 100.0 * settings.cell_length;
    }
    let network = FlowNetwork::new(
        cells_network.node_count,
        cells_network.vessels,
        cells_network.inlet,
        cells_network.outlets,
        cells_network.blood,
    )
    .unwrap();
    let solution = FlowSolver::new(network.clone())
        .unwrap()
        .solve(None)
        .unwrap();
    let mut field = Contrast::new(&network, settings).unwrap();
    assert_eq!(field.cell_count(), 10_000);
    field.set_flow(&network, &solution).unwrap();
    for v in 0..network.vessels.len() {
        field
            .fill(v, |x| 100.0 + 100.0 * (x * 300.0).sin())
            .unwrap();
    }
    let dt = field.max_time_step();
    let mut group = c.benchmark_group("contrast");
    group.throughput(Throughput::Elements(10_000));
    group.bench_function("substep_10000_cells", |b| {
        b.iter(|| assert_eq!(field.step(black_box(dt)).unwrap(), 1))
    });
    // The real network at the default resolution: one 60 Hz frame with an ICA injection.
    let cow = circle_of_willis().unwrap();
    let ica = cow.vessel_id("11-L-int-carotidI").unwrap();
    let solution = FlowSolver::new(cow.clone())
        .unwrap()
        .solve(Some(&Injection {
            vessel: ica,
            arc: 0.05,
            rate: 6e-6,
            concentration: 300.0,
        }))
        .unwrap();
    let mut field = Contrast::new(&cow, settings).unwrap();
    field.set_flow(&cow, &solution).unwrap();
    let substeps = field.step(1.0 / 60.0).unwrap();
    println!(
        "circle of Willis: {} cells, {substeps} sub-steps per 60 Hz frame",
        field.cell_count()
    );
    group.throughput(Throughput::Elements(field.cell_count() as u64));
    group.bench_function("circle_of_willis_60hz_frame", |b| {
        b.iter(|| field.step(black_box(1.0 / 60.0)).unwrap())
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = flow, contrast
}
criterion_main!(benches);
