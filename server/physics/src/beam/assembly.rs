//! Assembly of a beam model: every element's frame and deformation from the node frames,
//! internal forces f_int = Λᵀ K̄e(ū − ū0), the block-tridiagonal tangent (with the geometric
//! stiffness and drag), and what is read off them: residual, elastic energy, base reaction.

use nalgebra::{Matrix3, Vector6};

use super::element::{ElementState, element_forces};
use super::kinematics::{element_frame, rotation_vector};
use super::model::BeamModel;
use crate::substructure::BlockTridiagonal;

impl BeamModel {
    /// Internal forces f_int = Λᵀ K̄e(ū − ū0) and the tangent stiffness of the unknown nodes.
    pub(super) fn assemble(&mut self) {
        self.stiffness.clear();
        self.internal.iter_mut().for_each(|f| f.fill(0.0));
        let geometric = self.settings.geometric_stiffness;
        for (e, element) in self.elements.iter().enumerate() {
            let state = self.element_state(e);
            let (f1, f2, axial_force) = element_forces(element, &state);
            let r = &state.frame;
            self.internal[e] += rotate_wrench(r, &f1);
            self.internal[e + 1] += rotate_wrench(r, &f2);

            let mut k = element.stiffness;
            if geometric {
                let force = if self.settings.geometric_stiffness_in_compression {
                    axial_force
                } else {
                    axial_force.max(0.0)
                };
                for (block, g) in k.iter_mut().zip(&element.geometric_per_newton) {
                    *block = block.scaled_add(g, force);
                }
            }
            let axis = r.column(0).into_owned();
            k[2].add_world_to(&axis, &mut self.stiffness.diagonal[e]);
            if e > 0 {
                k[0].add_world_to(&axis, &mut self.stiffness.diagonal[e - 1]);
                k[1].add_world_to(&axis, &mut self.stiffness.upper[e - 1]);
            }
        }
        if let Some(drag) = self.settings.drag {
            let rate = drag.per_length_n_s_per_m2 / drag.time_step_s;
            let elements = self.elements.len();
            for (i, block) in self.stiffness.diagonal.iter_mut().enumerate() {
                // Unknown i is node i + 1: half of each adjacent element.
                let node = i + 1;
                let mut share = 0.5 * self.elements[node - 1].rest_length_m;
                if node < elements {
                    share += 0.5 * self.elements[node].rest_length_m;
                }
                let translational = rate * share;
                let rotational = rate * share.powi(3) / 12.0;
                for d in 0..3 {
                    block[(d, d)] += translational;
                    block[(d + 3, d + 3)] += rotational;
                }
            }
        }
    }

    fn element_state(&self, e: usize) -> ElementState {
        let element = &self.elements[e];
        let s1 = self.rotations[e] * element.offsets[0];
        let s2 = self.rotations[e + 1] * element.offsets[1];
        let chord = self.positions[e + 1] - self.positions[e];
        let frame_q = element_frame(&s1, &s2, &chord);
        let inv = frame_q.inverse();
        ElementState {
            frame: frame_q.to_rotation_matrix().into_inner(),
            chord_m: chord.norm(),
            theta: [rotation_vector(&(inv * s1)), rotation_vector(&(inv * s2))],
        }
    }

    /// Residual f_ext − f_int on the unknown nodes (N and N·m), for convergence checks.
    pub fn residual(&mut self) -> Vec<Vector6<f64>> {
        self.assemble();
        (1..self.node_count())
            .map(|i| self.external[i] - self.internal[i])
            .collect()
    }

    /// The tangent stiffness of the unknown nodes in the current configuration.
    pub fn tangent_stiffness(&mut self) -> &BlockTridiagonal {
        self.assemble();
        &self.stiffness
    }

    /// Elastic energy stored in the device (J): ½ Σ ū·K̄e ū over the elements, with the local
    /// deformation ū measured from the rest shape.
    pub fn elastic_energy(&self) -> f64 {
        (0..self.elements.len())
            .map(|e| {
                let element = &self.elements[e];
                let state = self.element_state(e);
                let (f1, f2, axial) = element_forces(element, &state);
                let [t1, t2] = state.theta;
                let torsion = f1[3];
                0.5 * (axial * (state.chord_m - element.rest_length_m)
                    + torsion * (t1.x - t2.x)
                    + f1[4] * t1.y
                    + f2[4] * t2.y
                    + f1[5] * t1.z
                    + f2[5] * t2.z)
            })
            .sum()
    }

    /// The largest axial force any element carries (N, either way), as the element computes
    /// it from its chord. A wire's own axial force stays
    /// near what the hands and the wall put into it; far more is a numerical fault, such as
    /// elements crushed by motions the step did not correct.
    pub fn max_axial_force_n(&self) -> f64 {
        (0..self.elements.len())
            .map(|e| self.element_axial_force_n(e).abs())
            .fold(0.0, f64::max)
    }

    /// Puts element `index` in series with a cable of axial stiffness `cable_n_m` (N/m) and
    /// slack `slack_m` (m, positive compressed) until the next remesh: the exit of an
    /// instrument sliding inside another, whose length inside lets material through the exit
    /// within the solve (`stack/slide.rs`).
    pub fn set_axial_series(&mut self, index: usize, cable_n_m: f64, slack_m: f64) {
        if let Some(element) = self.elements.get(index) {
            self.elements[index] = element.in_series(cable_n_m, slack_m);
        }
    }

    /// The axial force element `index` carries (N, tension positive), as the element
    /// computes it from its chord: E·A/ℓ₀ times the chord's change from the rest length.
    pub fn element_axial_force_n(&self, index: usize) -> f64 {
        self.elements[index]
            .axial_force_n((self.positions[index + 1] - self.positions[index]).norm())
    }

    /// Reaction wrench at the base (force N, moment N·m, world frame): what the operator's
    /// hand must apply to hold the device where it is.
    pub fn base_reaction(&mut self) -> Vector6<f64> {
        self.assemble();
        self.internal[0] - self.external[0]
    }
}

fn rotate_wrench(r: &Matrix3<f64>, w: &Vector6<f64>) -> Vector6<f64> {
    let f = r * w.fixed_rows::<3>(0);
    let m = r * w.fixed_rows::<3>(3);
    Vector6::new(f.x, f.y, f.z, m.x, m.y, m.z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::beam::{ElementSpec, SolverSettings};
    use crate::section::BeamProperties;
    use nalgebra::{UnitQuaternion, Vector3};

    /// A solid round section of `radius_m` in a material of Young's modulus `e_pa`.
    fn solid(radius_m: f64, e_pa: f64) -> BeamProperties {
        BeamProperties::new(
            &crate::section::CircularSection::solid(radius_m),
            &crate::section::Material {
                young_modulus_pa: e_pa,
                poisson_ratio: 0.33,
                density_kg_m3: 6450.0,
            },
        )
    }

    /// A J tip: twenty straight 1 mm elements, then twenty curved at 3 mm radius.
    fn j_tip(props: BeamProperties) -> BeamModel {
        let specs: Vec<ElementSpec> = (0..40)
            .map(|i| ElementSpec::planar(props, 1e-3, if i >= 20 { 1.0 / 3e-3 } else { 0.0 }))
            .collect();
        BeamModel::new(
            &specs,
            Vector3::zeros(),
            UnitQuaternion::identity(),
            SolverSettings::default(),
        )
        .unwrap()
    }

    #[test]
    fn curved_rest_shape_is_stress_free() {
        // Regression: the acos errors above left forces of ~1e-4·EI/l² in a J tip at rest.
        let props = solid(0.4e-3, 2e9);
        let mut model = j_tip(props);
        let scale = props.bending_stiffness_nm2 / 1e-6;
        let worst = model
            .residual()
            .iter()
            .map(|r| r.abs().max())
            .fold(0.0, f64::max);
        assert!(worst < 1e-12 * scale, "{worst} vs {scale}");
    }

    #[test]
    fn relieving_an_element_crushed_in_a_curved_wire_leaves_it_at_the_bound() {
        // A J tip whose part beyond element 25 is moved back along that element's chord by
        // 0.2 mm: it crushes the element to 80 % of its length and strains nothing else, so
        // the exact relief is that part moved forward again until the element carries the
        // bound, the rest untouched.
        let props = solid(0.2e-3, 60e9);
        let mut model = j_tip(props);
        let (crushed, limit) = (25, 10.0);
        let mut positions = model.positions().to_vec();
        let axis = (positions[crushed + 1] - positions[crushed]).normalize();
        for p in &mut positions[crushed + 1..] {
            *p -= axis * 0.2e-3;
        }
        let rotations = model.rotations().to_vec();
        model.set_nodes(&positions, &rotations).unwrap();
        let force = |model: &BeamModel, e: usize| {
            let chord = (model.positions()[e + 1] - model.positions()[e]).norm();
            model.elements[e].axial_force_n(chord)
        };
        let before = force(&model, crushed);
        assert!(before < -1000.0, "{before}");
        let excess = model.relieve_axial_excess(limit).unwrap();
        assert!((excess - (-before - limit)).abs() < 1e-9 * excess);
        let after = force(&model, crushed);
        assert!((after + limit).abs() < 1e-6 * excess, "{after}");
        for e in (0..40).filter(|&e| e != crushed) {
            assert!(force(&model, e).abs() < 1e-6 * excess, "element {e}");
        }
        assert!(model.residual().iter().all(|r| r.norm() < limit * 1.0001));
        // Nothing past the bound: nothing moves.
        let settled = model.positions().to_vec();
        assert_eq!(model.relieve_axial_excess(limit).unwrap(), 0.0);
        assert_eq!(model.positions(), &settled[..]);
    }

    #[test]
    fn the_largest_element_force_is_hookes_law_on_the_most_strained_element() {
        // Ten 1 mm elements along x; node 4 moved 2 µm towards the base: element 3 is
        // shortened by 2 µm and element 4 lengthened by as much, E·A·2·10⁻³ either way, and
        // the base reaction (node 0's internal force) sees none of it.
        let props = solid(0.2e-3, 60e9);
        let mut model = BeamModel::straight(props, 0.01, 10, SolverSettings::default()).unwrap();
        assert_eq!(model.max_axial_force_n(), 0.0);
        let mut positions = model.positions().to_vec();
        positions[4].x -= 2e-6;
        let rotations = model.rotations().to_vec();
        model.set_nodes(&positions, &rotations).unwrap();
        let expected = props.axial_stiffness_n * 2e-3;
        let found = model.max_axial_force_n();
        assert!(
            (found - expected).abs() < 1e-9 * expected,
            "{found} vs {expected}"
        );
        assert!(model.base_reaction().fixed_rows::<3>(0).norm() < 1e-9 * expected);
    }
}
