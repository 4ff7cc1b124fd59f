//! One beam element: its rest geometry as specified ([`ElementSpec`]), the rest data and
//! constant stiffness blocks built from it (in the frame-free axisymmetric form), its frame
//! and deformation in the current configuration, and its end wrenches. The local 12×12
//! matrices themselves are in [`crate::element`].

use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3, Vector6};

use super::kinematics::{arc_increment, element_frame};
use crate::element::{BendingCoefficients, local_geometric_stiffness, local_stiffness};
use crate::error::{Result, require_finite, require_positive};
use crate::section::BeamProperties;

/// Rest geometry of one element: properties, length (m) and rest curvature (1/m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ElementSpec {
    /// Section properties.
    pub props: BeamProperties,
    /// Arc length of the element at rest (m).
    pub length_m: f64,
    /// Rest curvature (Darboux) vector in the material frame at the element's start (1/m): x
    /// is the rest torsion rate, y and z the bending curvatures about the material y and z
    /// axes (a positive z component bends towards material +y). The element's rest shape is
    /// the helix the frame traces rotating at this constant rate.
    pub curvature_per_m: Vector3<f64>,
}

impl ElementSpec {
    /// An element bent in the material x–y plane: curvature `kappa_per_m` (1/m) about the
    /// material z axis, positive towards material +y.
    pub fn planar(props: BeamProperties, length_m: f64, kappa_per_m: f64) -> Self {
        Self {
            props,
            length_m,
            curvature_per_m: Vector3::new(0.0, 0.0, kappa_per_m),
        }
    }
}

/// Rest data and constant matrices of one element.
#[derive(Debug, Clone)]
pub(super) struct Element {
    props: BeamProperties,
    pub(super) rest_length_m: f64,
    /// How much longer the rest chord is, axially (m): the slack of a cable in series with
    /// the element (`BeamModel::set_axial_series`); 0 otherwise.
    pub(super) axial_offset_m: f64,
    /// Whether the element is in series with a cable (never kept by a remesh).
    pub(super) series: bool,
    pub(super) offsets: [UnitQuaternion<f64>; 2],
    bending: BendingCoefficients,
    /// K̄e blocks (node-1/node-1, node-1/node-2, node-2/node-2) in frame-free form.
    pub(super) stiffness: [AxisymmetricBlock6; 3],
    /// Geometric stiffness blocks per newton of axial force, frame-free form.
    pub(super) geometric_per_newton: [AxisymmetricBlock6; 3],
}

/// A 3×3 block a·I + b·e eᵀ + c·[e]× of an axisymmetric beam: every sub-block of K̄e and of
/// the geometric stiffness has this form (Iy = Iz), so rotating it into the world frame
/// needs only the element axis e, not the full frame.
#[derive(Debug, Clone, Copy, Default)]
struct AxisymmetricBlock {
    iso: f64,
    axial: f64,
    skew: f64,
}

impl AxisymmetricBlock {
    /// Reads the coefficients off a local block (axis e = x).
    fn from_local(b: &Matrix3<f64>) -> Self {
        debug_assert!((b[(1, 1)] - b[(2, 2)]).abs() <= 1e-12 * b.abs().max());
        debug_assert!((b[(1, 2)] + b[(2, 1)]).abs() <= 1e-12 * b.abs().max());
        Self {
            iso: b[(1, 1)],
            axial: b[(0, 0)] - b[(1, 1)],
            skew: b[(2, 1)],
        }
    }

    fn scaled_add(&self, other: &Self, factor: f64) -> Self {
        Self {
            iso: self.iso + factor * other.iso,
            axial: self.axial + factor * other.axial,
            skew: self.skew + factor * other.skew,
        }
    }

    /// The block in the world frame for element axis `e` (unit).
    fn world(&self, e: &Vector3<f64>) -> Matrix3<f64> {
        let (a, b, c) = (self.iso, self.axial, self.skew);
        Matrix3::new(
            a + b * e.x * e.x,
            b * e.x * e.y - c * e.z,
            b * e.x * e.z + c * e.y,
            b * e.y * e.x + c * e.z,
            a + b * e.y * e.y,
            b * e.y * e.z - c * e.x,
            b * e.z * e.x - c * e.y,
            b * e.z * e.y + c * e.x,
            a + b * e.z * e.z,
        )
    }
}

/// A 6×6 block as four [`AxisymmetricBlock`]s (translation/rotation rows and columns).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct AxisymmetricBlock6([[AxisymmetricBlock; 2]; 2]);

impl AxisymmetricBlock6 {
    fn from_local(k: &Matrix6<f64>) -> Self {
        let sub = |i: usize, j: usize| {
            AxisymmetricBlock::from_local(&k.fixed_view::<3, 3>(3 * i, 3 * j).into_owned())
        };
        Self([[sub(0, 0), sub(0, 1)], [sub(1, 0), sub(1, 1)]])
    }

    pub(super) fn scaled_add(&self, other: &Self, factor: f64) -> Self {
        let f = |i: usize, j: usize| self.0[i][j].scaled_add(&other.0[i][j], factor);
        Self([[f(0, 0), f(0, 1)], [f(1, 0), f(1, 1)]])
    }

    /// Adds the world-frame block for element axis `e` into `out`.
    pub(super) fn add_world_to(&self, e: &Vector3<f64>, out: &mut Matrix6<f64>) {
        for i in 0..2 {
            for j in 0..2 {
                let mut view = out.fixed_view_mut::<3, 3>(3 * i, 3 * j);
                view += self.0[i][j].world(e);
            }
        }
    }
}

impl Element {
    /// An element from its rest geometry alone (the offsets are relative, so the pose of the
    /// rest shape does not matter).
    pub(super) fn from_spec(spec: &ElementSpec) -> Result<Self> {
        require_positive(|| "element length_m".into(), spec.length_m)?;
        for v in spec.curvature_per_m.iter() {
            require_finite(|| "element curvature_per_m".into(), *v)?;
        }
        let (dp, dq) = arc_increment(&spec.curvature_per_m, spec.length_m);
        let frame = element_frame(&UnitQuaternion::identity(), &dq, &dp);
        Ok(Self::new(
            spec.props,
            dp.norm(),
            [frame, dq.inverse() * frame],
        ))
    }

    /// The axial force (N, tension positive) at chord length `chord_m` (m): E·A/ℓ₀ times the
    /// chord's change from the rest chord.
    pub(super) fn axial_force_n(&self, chord_m: f64) -> f64 {
        self.props.axial_stiffness_n / self.rest_length_m
            * (chord_m - self.rest_length_m - self.axial_offset_m)
    }

    /// This element in series with a cable of axial stiffness `cable_n_m` (N/m) whose slack
    /// is `slack_m` (m, positive: the cable compressed by that much): its axial stiffness the
    /// two in series, its rest chord longer by the slack, as the cable's length lets the
    /// element's material out or in (the rest unchanged).
    pub(super) fn in_series(&self, cable_n_m: f64, slack_m: f64) -> Self {
        let own = self.props.axial_stiffness_n / self.rest_length_m;
        let series = own * cable_n_m / (own + cable_n_m);
        let props = BeamProperties {
            axial_stiffness_n: series * self.rest_length_m,
            ..self.props
        };
        let mut element = Self::new(props, self.rest_length_m, self.offsets);
        element.axial_offset_m = slack_m;
        element.series = true;
        element
    }

    pub(super) fn new(
        props: BeamProperties,
        rest_length_m: f64,
        offsets: [UnitQuaternion<f64>; 2],
    ) -> Self {
        let split = |k: &crate::element::Matrix12| {
            [(0, 0), (0, 6), (6, 6)].map(|(i, j)| {
                AxisymmetricBlock6::from_local(&k.fixed_view::<6, 6>(i, j).into_owned())
            })
        };
        let phi = 12.0 * props.bending_stiffness_nm2
            / (props.shear_stiffness_n * rest_length_m * rest_length_m);
        Self {
            props,
            rest_length_m,
            axial_offset_m: 0.0,
            series: false,
            offsets,
            bending: BendingCoefficients::new(props.bending_stiffness_nm2, rest_length_m, phi),
            stiffness: split(&local_stiffness(&props, rest_length_m)),
            geometric_per_newton: split(&local_geometric_stiffness(&props, rest_length_m, 1.0)),
        }
    }
}

/// The element frame and local deformation in the current configuration.
#[derive(Debug, Clone, Copy)]
pub(super) struct ElementState {
    pub(super) frame: Matrix3<f64>,
    pub(super) chord_m: f64,
    pub(super) theta: [Vector3<f64>; 2],
}

/// Local end wrenches of an element (node 1, node 2) and its axial force (N), from the
/// condensed stiffness: exact element equilibrium in the current chord length.
pub(super) fn element_forces(
    element: &Element,
    state: &ElementState,
) -> (Vector6<f64>, Vector6<f64>, f64) {
    let p = &element.props;
    let l0 = element.rest_length_m;
    let b = &element.bending;
    let [t1, t2] = state.theta;
    let axial = element.axial_force_n(state.chord_m);
    let torsion = p.torsional_stiffness_nm2 / l0 * (t1.x - t2.x);
    let m1y = b.k_tt_near * t1.y + b.k_tt_far * t2.y;
    let m2y = b.k_tt_far * t1.y + b.k_tt_near * t2.y;
    let m1z = b.k_tt_near * t1.z + b.k_tt_far * t2.z;
    let m2z = b.k_tt_far * t1.z + b.k_tt_near * t2.z;
    let shear_y = -(m1z + m2z) / state.chord_m;
    let shear_z = (m1y + m2y) / state.chord_m;
    let f2 = Vector6::new(axial, shear_y, shear_z, -torsion, m2y, m2z);
    let f1 = Vector6::new(-axial, -shear_y, -shear_z, torsion, m1y, m1z);
    (f1, f2, axial)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_free_blocks_equal_the_full_rotation() {
        // Fast path vs naive R₆ K R₆ᵀ for a random frame and every element block.
        let props = BeamProperties::new(
            &crate::section::CircularSection {
                outer_radius_m: 1e-3,
                inner_radius_m: 4e-4,
            },
            &crate::section::Material {
                young_modulus_pa: 3e9,
                poisson_ratio: 0.4,
                density_kg_m3: 1e3,
            },
        );
        let k = crate::element::local_stiffness(&props, 0.01)
            + crate::element::local_geometric_stiffness(&props, 0.01, -0.7);
        let frame =
            UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -1.1, 0.7)).to_rotation_matrix();
        let r = frame.matrix();
        let mut r6 = Matrix6::zeros();
        r6.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
        r6.fixed_view_mut::<3, 3>(3, 3).copy_from(r);
        for (i, j) in [(0, 0), (0, 6), (6, 6), (6, 0)] {
            let local = k.fixed_view::<6, 6>(i, j).into_owned();
            let naive = r6 * local * r6.transpose();
            let mut fast = Matrix6::zeros();
            AxisymmetricBlock6::from_local(&local)
                .add_world_to(&r.column(0).into_owned(), &mut fast);
            assert!(
                (fast - naive).abs().max() <= 1e-12 * naive.abs().max(),
                "block ({i},{j})"
            );
        }
    }
}
