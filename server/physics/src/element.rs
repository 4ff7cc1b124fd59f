//! The 3D Timoshenko beam element in its local frame: 12×12 elastic and geometric stiffness.
//!
//! Local axis x runs from node 1 to node 2; y and z are principal axes of the section.
//! Degrees of freedom per node: displacements (u, v, w) and rotations (θx, θy, θz), in that
//! order, node 1 then node 2. Sign convention: θz = +dv/dx, θy = −dw/dx.
//!
//! The stiffness follows Przemieniecki, *Theory of Matrix Structural Analysis* (1968), §5.6,
//! with the shear parameters Φy = 12EIz/(κGA l²), Φz = 12EIy/(κGA l²). It is *not* the
//! matrix printed in Cotin et al. (2005), which has three misprints (see NOTES.md): here the
//! torsion entries are ±GJ/l, entry (11,11) is (4+Φ)EI/(l(1+Φ)) and entry (11,3) is
//! −6EIy/(l²(1+Φz)) for the w/θy coupling at node 2 (0-based indices (10, 2) below).

use nalgebra::SMatrix;

use crate::section::BeamProperties;

/// A 12×12 matrix in element DOF order.
pub type Matrix12 = SMatrix<f64, 12, 12>;

/// Local elastic stiffness K̄e of a Timoshenko beam of length `length_m` (SI units).
pub fn local_stiffness(props: &BeamProperties, length_m: f64) -> Matrix12 {
    let l = length_m;
    let ei = props.bending_stiffness_nm2;
    let phi = 12.0 * ei / (props.shear_stiffness_n * l * l);
    let ea_l = props.axial_stiffness_n / l;
    let gj_l = props.torsional_stiffness_nm2 / l;
    let b = BendingCoefficients::new(ei, l, phi);

    let mut k = Matrix12::zeros();
    // Axial.
    k[(0, 0)] = ea_l;
    k[(6, 6)] = ea_l;
    k[(0, 6)] = -ea_l;
    // Torsion.
    k[(3, 3)] = gj_l;
    k[(9, 9)] = gj_l;
    k[(3, 9)] = -gj_l;
    // Bending in the x–y plane: v (1, 7) with θz (5, 11).
    k[(1, 1)] = b.k_vv;
    k[(7, 7)] = b.k_vv;
    k[(1, 7)] = -b.k_vv;
    k[(1, 5)] = b.k_vt;
    k[(1, 11)] = b.k_vt;
    k[(5, 7)] = -b.k_vt;
    k[(7, 11)] = -b.k_vt;
    k[(5, 5)] = b.k_tt_near;
    k[(11, 11)] = b.k_tt_near;
    k[(5, 11)] = b.k_tt_far;
    // Bending in the x–z plane: w (2, 8) with θy (4, 10); θy = −dw/dx flips the coupling sign.
    k[(2, 2)] = b.k_vv;
    k[(8, 8)] = b.k_vv;
    k[(2, 8)] = -b.k_vv;
    k[(2, 4)] = -b.k_vt;
    k[(2, 10)] = -b.k_vt;
    k[(4, 8)] = b.k_vt;
    k[(8, 10)] = b.k_vt;
    k[(4, 4)] = b.k_tt_near;
    k[(10, 10)] = b.k_tt_near;
    k[(4, 10)] = b.k_tt_far;
    symmetrize_upper(&mut k);
    k
}

/// Local geometric (initial-stress) stiffness of a beam under axial force `axial_force_n`
/// (N, tension positive), consistent cubic interpolation (Przemieniecki §15).
pub fn local_geometric_stiffness(
    props: &BeamProperties,
    length_m: f64,
    axial_force_n: f64,
) -> Matrix12 {
    let l = length_m;
    let c = axial_force_n / l;
    let a = 6.0 / 5.0 * c;
    let b = l / 10.0 * c;
    let d = 2.0 * l * l / 15.0 * c;
    let e = -l * l / 30.0 * c;
    let t = props.polar_gyration_m2 * c;

    let mut k = Matrix12::zeros();
    // v / θz.
    k[(1, 1)] = a;
    k[(7, 7)] = a;
    k[(1, 7)] = -a;
    k[(1, 5)] = b;
    k[(1, 11)] = b;
    k[(5, 7)] = -b;
    k[(7, 11)] = -b;
    k[(5, 5)] = d;
    k[(11, 11)] = d;
    k[(5, 11)] = e;
    // w / θy (coupling signs flipped).
    k[(2, 2)] = a;
    k[(8, 8)] = a;
    k[(2, 8)] = -a;
    k[(2, 4)] = -b;
    k[(2, 10)] = -b;
    k[(4, 8)] = b;
    k[(8, 10)] = b;
    k[(4, 4)] = d;
    k[(10, 10)] = d;
    k[(4, 10)] = e;
    // Torsion (Wagner term of a circular section).
    k[(3, 3)] = t;
    k[(9, 9)] = t;
    k[(3, 9)] = -t;
    symmetrize_upper(&mut k);
    k
}

/// Bending coefficients shared by both planes (equal principal moments).
#[derive(Debug, Clone, Copy)]
pub(crate) struct BendingCoefficients {
    /// 12EI / (l³(1+Φ)).
    pub k_vv: f64,
    /// 6EI / (l²(1+Φ)).
    pub k_vt: f64,
    /// (4+Φ)EI / (l(1+Φ)).
    pub k_tt_near: f64,
    /// (2−Φ)EI / (l(1+Φ)).
    pub k_tt_far: f64,
}

impl BendingCoefficients {
    pub(crate) fn new(ei: f64, l: f64, phi: f64) -> Self {
        let s = ei / (1.0 + phi);
        Self {
            k_vv: 12.0 * s / (l * l * l),
            k_vt: 6.0 * s / (l * l),
            k_tt_near: (4.0 + phi) * s / l,
            k_tt_far: (2.0 - phi) * s / l,
        }
    }
}

/// Copies the upper triangle into the lower one.
fn symmetrize_upper(k: &mut Matrix12) {
    for i in 0..12 {
        for j in 0..i {
            k[(i, j)] = k[(j, i)];
        }
    }
}
