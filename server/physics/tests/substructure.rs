//! The substructure solver and flexibility blocks against dense references.

mod common;

use cathlab_physics::{
    BeamModel, BlockTridiagonal, SolverSettings, StepMode, Substructure, presets,
};
use nalgebra::{DMatrix, DVector, Matrix6, SMatrix, Vector3, Vector6};
use proptest::prelude::*;

/// A random SPD block-tridiagonal matrix: a sum of random PSD "element" matrices coupling
/// neighbours, plus a positive shift on the first block (the clamp).
fn random_system(nodes: usize, seed_values: &[f64]) -> BlockTridiagonal {
    let mut k = BlockTridiagonal::zeros(nodes);
    let mut it = seed_values.iter().cycle().copied();
    let mut next = move || it.next().unwrap();
    let mut clamp = SMatrix::<f64, 6, 6>::from_fn(|_, _| next());
    clamp = clamp * clamp.transpose() + Matrix6::identity();
    k.diagonal[0] += clamp;
    for e in 0..nodes.saturating_sub(1) {
        let b = SMatrix::<f64, 12, 12>::from_fn(|_, _| next());
        let m = b * b.transpose() + SMatrix::<f64, 12, 12>::identity() * 0.1;
        k.diagonal[e] += m.fixed_view::<6, 6>(0, 0);
        k.diagonal[e + 1] += m.fixed_view::<6, 6>(6, 6);
        k.upper[e] += m.fixed_view::<6, 6>(0, 6);
    }
    k
}

fn flatten(v: &[Vector6<f64>]) -> DVector<f64> {
    DVector::from_iterator(6 * v.len(), v.iter().flat_map(|b| b.iter().copied()))
}

/// Checks solve, diagonal flexibility blocks and a sample of off-diagonal blocks against a
/// dense LU solve and a dense inverse; returns the worst relative error.
/// The dense reference is LU with one refinement step, the substructure solve likewise.
fn compare_with_dense(k: &BlockTridiagonal, f: &[Vector6<f64>]) -> f64 {
    let dense = k.to_dense();
    let lu = dense.clone().lu();
    let mut sub = Substructure::new(k).unwrap();
    let u = flatten(&sub.solve_refined(k, f));
    let fd = flatten(f);
    let mut reference = lu.solve(&fd).unwrap();
    reference += lu.solve(&(&fd - &dense * &reference)).unwrap();
    let mut worst = (&u - &reference).norm() / reference.norm();

    // Dense inverse with one Newton–Schulz refinement step, X ← X + X(I − K X).
    let mut inverse = lu.try_inverse().unwrap();
    let correction =
        &inverse * (DMatrix::identity(6 * k.nodes(), 6 * k.nodes()) - &dense * &inverse);
    inverse += correction;
    let flex = sub.flexibility();
    let n = k.nodes();
    let block_err = |i: usize, j: usize| {
        let exact = inverse.view((6 * i, 6 * j), (6, 6)).into_owned();
        let got = DMatrix::from_column_slice(6, 6, flex.block(i, j).as_slice());
        // Relative to the diagonal blocks' scale, since far couplings decay.
        let scale = inverse
            .view((6 * i, 6 * i), (6, 6))
            .norm()
            .max(inverse.view((6 * j, 6 * j), (6, 6)).norm());
        (got - exact).norm() / scale
    };
    for i in 0..n {
        worst = worst.max(block_err(i, i));
    }
    for (i, j) in [(0, n - 1), (n / 2, n - 1), (n - 1, 0), (0, n / 3)] {
        worst = worst.max(block_err(i, j));
    }
    worst
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(100))]
    #[test]
    fn random_spd_systems_match_dense(
        nodes in 1usize..40,
        values in proptest::collection::vec(-1.0f64..1.0, 200..400),
        loads in proptest::collection::vec(-1.0f64..1.0, 6..60),
    ) {
        let k = random_system(nodes, &values);
        let f: Vec<Vector6<f64>> = (0..nodes)
            .map(|i| Vector6::from_fn(|r, _| loads[(6 * i + r) % loads.len()]))
            .collect();
        let err = compare_with_dense(&k, &f);
        prop_assert!(err < 1e-10, "relative error {err}");
    }
}

/// The tangent of a preset's part [start, end] (m) in `elements` elements, deformed by a
/// tip load through a few converged steps, so it has rotated frames, rest curvature and
/// axial force.
fn device_tangent(
    device: &cathlab_physics::Device,
    start: f64,
    end: f64,
    elements: usize,
) -> BlockTridiagonal {
    let settings = SolverSettings {
        mode: StepMode::CONVERGED,
        ..Default::default()
    };
    let mut model = BeamModel::from_device_part(device, start, end, elements, settings).unwrap();
    let tip = model.node_count() - 1;
    let ei = device.sections[2].beam_properties().bending_stiffness_nm2;
    let length = model.length_m();
    let load = Vector3::new(0.0, 0.5, 0.3) * ei / length.powi(2);
    model.set_load(tip, load, Vector3::zeros()).unwrap();
    for _ in 0..3 {
        model.step().unwrap();
    }
    model.tangent_stiffness().clone()
}

fn device_loads(nodes: usize) -> Vec<Vector6<f64>> {
    (0..nodes)
        .map(|i| Vector6::new(1e-3, -2e-3, 1e-3, 1e-5, 2e-5, -1e-5) * (1.0 + i as f64 * 0.01))
        .collect()
}

#[test]
fn inserted_device_matrices_match_dense() {
    // The inserted distal part of each preset at 5 mm and 1 cm elements. Finer or longer
    // chains reach condition numbers (1e10 and up) at which f64 cannot resolve 1e-10 by any
    // method: there the flexibility blocks differ from the dense inverse by ~1e-10 (e.g.
    // 1.2e-10 for the 0.035" wire at 10 cm / 20 elements) and the next test applies.
    for (id, device) in presets::all() {
        let l = device.length_m();
        for (inserted, elements) in [(0.05, 10), (0.10, 10)] {
            let k = device_tangent(&device, l - inserted, l, elements);
            let err = compare_with_dense(&k, &device_loads(k.nodes()));
            assert!(
                err < 1e-10,
                "{id}, {inserted} m in {elements}: relative error {err}"
            );
        }
    }
}

#[test]
fn full_length_device_matrices_agree_within_conditioning() {
    // A whole 1–2 m device in 60–200 elements has a condition number of 1e11–1e13, so any two
    // f64 solvers (dense LU and dense Cholesky included) differ by up to κ·ε. The substructure
    // solve must stay within that bound and be backward stable.
    for (id, device) in presets::all() {
        let l = device.length_m();
        for (start, elements) in [(l - 0.2, 100), (0.0, 60), (0.0, 200)] {
            let k = device_tangent(&device, start, l, elements);
            let f = device_loads(k.nodes());
            let dense = k.to_dense();
            let sv = dense.clone().singular_values();
            let condition = sv.max() / sv.min();
            let fd = flatten(&f);
            let reference = dense.clone().lu().solve(&fd).unwrap();
            let u = flatten(&Substructure::new(&k).unwrap().solve(&f));
            let forward = (&u - &reference).norm() / reference.norm();
            let backward = (&dense * &u - &fd).norm() / (dense.norm() * u.norm());
            assert!(
                forward < 10.0 * condition * f64::EPSILON,
                "{id}/{elements}: {forward} vs κ={condition:e}"
            );
            assert!(
                backward < 1e-16,
                "{id}/{elements}: backward error {backward}"
            );
        }
    }
}

#[test]
fn singular_matrix_is_reported_not_panicked() {
    let k = BlockTridiagonal::zeros(3);
    let err = Substructure::new(&k).unwrap_err();
    assert!(
        matches!(
            err,
            cathlab_physics::PhysicsError::SingularBlock { node: 0 }
        ),
        "{err}"
    );
}
