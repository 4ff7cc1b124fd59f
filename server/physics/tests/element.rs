//! The Timoshenko element: symmetry, rigid modes, positivity, and exact linear solutions.

mod common;

use cathlab_physics::element::{local_geometric_stiffness, local_stiffness};
use cathlab_physics::{
    BeamModel, BeamProperties, CircularSection, Material, SolverSettings, Substructure,
};
use common::{rel, wire};
use nalgebra::{SVector, SymmetricEigen, Vector3, Vector6};
use proptest::prelude::*;

fn props(outer: f64, inner_fraction: f64, young: f64, nu: f64) -> BeamProperties {
    BeamProperties::new(
        &CircularSection {
            outer_radius_m: outer,
            inner_radius_m: outer * inner_fraction,
        },
        &Material {
            young_modulus_pa: young,
            poisson_ratio: nu,
            density_kg_m3: 1000.0,
        },
    )
}

/// The six rigid-body motions of an element of length `l` along x: three translations and
/// three infinitesimal rotations about node 1.
fn rigid_modes(l: f64) -> Vec<SVector<f64, 12>> {
    let mut modes = Vec::new();
    for axis in 0..3 {
        let mut t = SVector::<f64, 12>::zeros();
        t[axis] = 1.0;
        t[6 + axis] = 1.0;
        modes.push(t);
    }
    for axis in 0..3 {
        let mut omega = Vector3::zeros();
        omega[axis] = 1.0;
        let tip = omega.cross(&Vector3::new(l, 0.0, 0.0));
        let mut r = SVector::<f64, 12>::zeros();
        for k in 0..3 {
            r[3 + k] = omega[k];
            r[6 + k] = tip[k];
            r[9 + k] = omega[k];
        }
        modes.push(r);
    }
    modes
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn element_is_symmetric_psd_with_six_rigid_modes(
        outer in 1e-4f64..1e-2,
        inner_fraction in 0.0f64..0.9,
        slenderness in 1.0f64..200.0,
        young in 1e8f64..2e11,
        nu in -0.9f64..0.49,
    ) {
        let p = props(outer, inner_fraction, young, nu);
        let l = outer * slenderness;
        let k = local_stiffness(&p, l);
        prop_assert_eq!(k, k.transpose());
        // Rigid-body motions produce no force.
        let scale = k.abs().max();
        for r in rigid_modes(l) {
            prop_assert!((k * r).abs().max() <= 1e-12 * scale * r.abs().max());
        }
        // Exactly six zero eigenvalues, the other six strictly positive. Scale rotations by
        // l so the eigenvalues share units (N/m) and the spectrum is not artificially spread.
        let mut d = SVector::<f64, 12>::from_element(1.0);
        for i in [3, 4, 5, 9, 10, 11] { d[i] = 1.0 / l; }
        let scaled = nalgebra::SMatrix::<f64, 12, 12>::from_diagonal(&d) * k
            * nalgebra::SMatrix::<f64, 12, 12>::from_diagonal(&d);
        let eig = SymmetricEigen::new(scaled).eigenvalues;
        let max = eig.max();
        let zero = eig.iter().filter(|v| v.abs() <= 1e-10 * max).count();
        let positive = eig.iter().filter(|v| **v > 1e-10 * max).count();
        prop_assert_eq!(zero, 6, "eigenvalues {:?}", eig);
        prop_assert_eq!(positive, 6);
    }

    #[test]
    fn geometric_stiffness_is_symmetric_and_vanishes_on_translations(
        outer in 1e-4f64..1e-2, l in 1e-3f64..1.0, force in -10.0f64..10.0,
    ) {
        let kg = local_geometric_stiffness(&props(outer, 0.0, 1e9, 0.3), l, force);
        prop_assert_eq!(kg, kg.transpose());
        for r in rigid_modes(l).into_iter().take(3) {
            prop_assert!((kg * r).abs().max() <= 1e-12 * kg.abs().max().max(1e-300));
        }
    }
}

/// Linear solve of a cantilever of `n` elements with a tip wrench.
fn cantilever_tip(p: BeamProperties, length: f64, n: usize, tip: Vector6<f64>) -> Vector6<f64> {
    let mut model = BeamModel::straight(p, length, n, SolverSettings::default()).unwrap();
    let k = model.tangent_stiffness().clone();
    let mut f = vec![Vector6::zeros(); n];
    f[n - 1] = tip;
    Substructure::new(&k).unwrap().solve(&f)[n - 1]
}

#[test]
fn cantilever_tip_deflection_is_exact_for_any_element_count() {
    // A stubby beam (L/r = 3) so the shear term PL/κGA is ~20 % of the total.
    let (r, length, load) = (0.01, 0.03, 3.0);
    let p = wire(r);
    let expected = cathlab_physics::elastica::timoshenko_tip_deflection(
        load,
        length,
        p.bending_stiffness_nm2,
        p.shear_stiffness_n,
    );
    let shear_part = load * length / p.shear_stiffness_n;
    assert!(shear_part / expected > 0.05, "the test must exercise shear");
    for n in 1..=30 {
        let u = cantilever_tip(p, length, n, Vector6::new(0.0, load, 0.0, 0.0, 0.0, 0.0));
        assert!(
            rel(u[1], expected) < 1e-9,
            "n={n}: v={} expected {expected}",
            u[1]
        );
        // Section rotation at the tip: PL²/2EI (shear does not rotate the section).
        let slope = load * length * length / (2.0 * p.bending_stiffness_nm2);
        assert!(
            rel(u[5], slope) < 1e-9,
            "n={n}: θz={} expected {slope}",
            u[5]
        );
        // Same in the x–z plane, where θy = −dw/dx.
        let w = cantilever_tip(p, length, n, Vector6::new(0.0, 0.0, load, 0.0, 0.0, 0.0));
        assert!(
            rel(w[2], expected) < 1e-9 && rel(-w[4], slope) < 1e-9,
            "n={n}: {w:?}"
        );
        // Axial: PL/EA.
        let a = cantilever_tip(p, length, n, Vector6::new(load, 0.0, 0.0, 0.0, 0.0, 0.0));
        assert!(rel(a[0], load * length / p.axial_stiffness_n) < 1e-9);
    }
}

#[test]
fn torsion_is_exact() {
    let (length, torque) = (0.5, 0.02);
    let p = wire(0.5e-3);
    for n in [1, 2, 7, 40] {
        let u = cantilever_tip(p, length, n, Vector6::new(0.0, 0.0, 0.0, torque, 0.0, 0.0));
        assert!(
            rel(u[3], torque * length / p.torsional_stiffness_nm2) < 1e-9,
            "n={n}"
        );
    }
}
