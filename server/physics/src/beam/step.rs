//! The beam step without contacts: paper or converged mode, one linear solve per iteration
//! through the substructure solver, the divergence guards on the increments, and the split of
//! a step into sub-steps when a guard trips.

use nalgebra::{UnitQuaternion, Vector6};

use super::model::BeamModel;
use super::report::StepReport;
use super::settings::{MAX_TRANSLATION_INCREMENT_LENGTHS, StepMode};
use crate::error::{DivergenceCheck, PhysicsError, Result, require_finite, require_positive};

impl BeamModel {
    /// Advances one step with the configured mode. In converged mode a step that trips an
    /// increment guard or does not converge is split (see
    /// [`SolverSettings::max_substep_halvings`](crate::beam::SolverSettings::max_substep_halvings)); the report then counts every sub-step's
    /// solves. On error the configuration is left as it was.
    pub fn step(&mut self) -> Result<StepReport> {
        self.saved_positions.clone_from(&self.positions);
        self.saved_rotations.clone_from(&self.rotations);
        let mut result = self.step_inner();
        if self.should_split(&result) {
            self.positions.clone_from(&self.saved_positions);
            self.rotations.clone_from(&self.saved_rotations);
            result = self.split_step();
        }
        self.step_count += 1;
        match result {
            Ok(_) => {
                self.last_external.clone_from(&self.external);
                self.last_base = (self.positions[0], self.rotations[0]);
            }
            Err(_) => {
                self.positions.clone_from(&self.saved_positions);
                self.rotations.clone_from(&self.saved_rotations);
            }
        }
        result
    }

    /// Whether a converged-mode step outcome calls for sub-steps.
    fn should_split(&self, result: &Result<StepReport>) -> bool {
        if self.settings.max_substep_halvings == 0
            || !matches!(self.settings.mode, StepMode::Converged { .. })
        {
            return false;
        }
        match result {
            Ok(report) => !report.converged,
            Err(PhysicsError::Diverged { check, .. }) => matches!(
                check,
                DivergenceCheck::RotationIncrement { .. }
                    | DivergenceCheck::TranslationIncrement { .. }
            ),
            Err(_) => false,
        }
    }

    /// The step again as sub-steps: loads and the base pose go from their values at the end
    /// of the last step to the requested ones in fractions, each fraction halved (up to
    /// `max_substep_halvings` times) while its sub-step trips a guard or does not converge.
    fn split_step(&mut self) -> Result<StepReport> {
        let target = self.external.clone();
        let start = self.last_external.clone();
        let (base_to, rotation_to) = (self.positions[0], self.rotations[0]);
        let (base_from, rotation_from) = self.last_base;
        let mut report = StepReport {
            iterations: 0,
            converged: true,
            last_translation_increment_m: 0.0,
            last_rotation_increment_rad: 0.0,
        };
        let (mut done, mut halvings) = (0.0f64, 1usize);
        let mut positions = self.positions.clone();
        let mut rotations = self.rotations.clone();
        let outcome = loop {
            if done >= 1.0 {
                break Ok(());
            }
            let to = (done + 0.5f64.powi(halvings as i32)).min(1.0);
            for ((f, a), b) in self.external.iter_mut().zip(&start).zip(&target) {
                *f = a + (b - a) * to;
            }
            self.positions[0] = base_from + (base_to - base_from) * to;
            self.rotations[0] = rotation_from.slerp(&rotation_to, to);
            let result = self.step_inner();
            if self.should_split(&result) && halvings < self.settings.max_substep_halvings {
                self.positions.clone_from(&positions);
                self.rotations.clone_from(&rotations);
                halvings += 1;
                continue;
            }
            match result {
                Ok(sub) => {
                    report.iterations += sub.iterations;
                    report.converged &= sub.converged;
                    report.last_translation_increment_m = sub.last_translation_increment_m;
                    report.last_rotation_increment_rad = sub.last_rotation_increment_rad;
                    positions.clone_from(&self.positions);
                    rotations.clone_from(&self.rotations);
                    done = to;
                }
                Err(e) => break Err(e),
            }
        };
        self.external = target;
        self.positions[0] = base_to;
        self.rotations[0] = rotation_to;
        outcome.map(|()| report)
    }

    fn step_inner(&mut self) -> Result<StepReport> {
        let (gamma, tolerance, max_iterations) = match self.settings.mode {
            StepMode::Incremental { gamma } => {
                require_finite(|| "gamma".into(), gamma)?;
                if !(gamma > 0.0 && gamma <= 1.0) {
                    return Err(PhysicsError::OutOfRange {
                        what: "gamma".into(),
                        range: "(0, 1]",
                        value: gamma,
                    });
                }
                (gamma, None, 1)
            }
            StepMode::Converged {
                tolerance,
                max_iterations,
            } => (
                1.0,
                Some(require_positive(|| "tolerance".into(), tolerance)?),
                max_iterations.max(1),
            ),
        };
        let mut report = StepReport {
            iterations: 0,
            converged: tolerance.is_none(),
            last_translation_increment_m: 0.0,
            last_rotation_increment_rad: 0.0,
        };
        for iteration in 0..max_iterations {
            let (dx, dtheta) =
                self.iterate(gamma, iteration == 0 && self.settings.compute_flexibility)?;
            report.iterations += 1;
            report.last_translation_increment_m = dx;
            report.last_rotation_increment_rad = dtheta;
            if let Some(tol) = tolerance
                && dx <= tol * self.length_m
                && dtheta <= tol
            {
                report.converged = true;
                break;
            }
        }
        Ok(report)
    }

    /// One linearisation and solve; returns the largest increments (m, rad).
    fn iterate(&mut self, gamma: f64, flexibility: bool) -> Result<(f64, f64)> {
        self.solve_free(gamma, flexibility)?;
        let increments = std::mem::take(&mut self.rhs);
        let result = self.apply_increments(&increments);
        self.rhs = increments;
        result
    }

    /// Assembles, factors and solves K Δu = f_ext − γ f_int: leaves the free increment of every
    /// unknown node in `self.rhs` (and the flexibility blocks, if asked).
    pub(super) fn solve_free(&mut self, gamma: f64, flexibility: bool) -> Result<()> {
        self.assemble();
        for (i, rhs) in self.rhs.iter_mut().enumerate() {
            *rhs = self.external[i + 1] - gamma * self.internal[i + 1];
        }
        self.substructure.factor(&self.stiffness)?;
        self.substructure.solve_in_place(&mut self.rhs);
        if flexibility {
            self.substructure.flexibility_into(&mut self.flexibility);
        }
        Ok(())
    }

    /// Relieves every element whose axial force (N, either way) exceeds `limit_n` of the
    /// excess: the loads that undo the excess alone (pulling a stretched element's nodes
    /// together, pushing a crushed one's apart) solved through the tangent, drag included,
    /// and applied. Returns the largest excess (N; 0 when none, and nothing moves). Nothing
    /// moves on error.
    ///
    /// What it is for: a navigated device's slide places nodes on the polyline of its last
    /// shape, which cuts the corners of a bent wire (up to 8 % of an element's length in one
    /// pulled step through a coil); the step's correction of that strain is scaled down with
    /// the rest of the free motion where the step cap holds a springback the wall will cancel,
    /// so the strain can outgrow the correction and crush elements to a tenth of their length
    /// (kilonewtons in a wire a hand pushes with 10 N, felt at the hand). No load within the
    /// hands' strength puts more than that strength into a single device's elements (along a
    /// device the axial force changes only by friction and drag), so what exceeds it is the
    /// predictor's error, relieved before the next step is solved.
    pub fn relieve_axial_excess(&mut self, limit_n: f64) -> Result<f64> {
        self.relieve_axial_excess_by(|_| limit_n)
    }

    /// [`Self::relieve_axial_excess`] with each element's own bound (N), `limit_n(e)` for
    /// element `e`: a coaxial stack's merged element carries each instrument's force, so its
    /// bound is the strength of the hands on the instruments it holds.
    pub fn relieve_axial_excess_by(&mut self, limit_n: impl Fn(usize) -> f64) -> Result<f64> {
        let mut loads = vec![Vector6::zeros(); self.node_count() - 1];
        let mut worst: f64 = 0.0;
        for (e, element) in self.elements.iter().enumerate() {
            let limit_n = limit_n(e);
            let chord = self.positions[e + 1] - self.positions[e];
            let length = chord.norm();
            let force = element.axial_force_n(length);
            let excess = force - force.clamp(-limit_n, limit_n);
            if excess == 0.0 || length == 0.0 {
                continue;
            }
            worst = worst.max(excess.abs());
            let pull = chord * (excess / length);
            if e > 0 {
                let mut near = loads[e - 1].fixed_rows_mut::<3>(0);
                near += pull;
            }
            let mut far = loads[e].fixed_rows_mut::<3>(0);
            far -= pull;
        }
        if worst == 0.0 {
            return Ok(0.0);
        }
        self.assemble();
        self.substructure.factor(&self.stiffness)?;
        self.substructure.solve_in_place(&mut loads);
        self.apply_increments(&loads)?;
        Ok(worst)
    }

    /// Applies increments (one per unknown node) after the divergence checks; returns the
    /// largest translation (m) and rotation (rad) increment.
    pub(super) fn apply_increments(&mut self, increments: &[Vector6<f64>]) -> Result<(f64, f64)> {
        let mut max_dx: f64 = 0.0;
        let mut max_dtheta: f64 = 0.0;
        for (i, du) in increments.iter().enumerate() {
            let dx = du.fixed_rows::<3>(0).into_owned();
            let dtheta = du.fixed_rows::<3>(3).into_owned();
            let diverged = |check| PhysicsError::Diverged {
                check,
                node: i + 1,
                step: self.step_count + 1,
            };
            if !du.iter().all(|v| v.is_finite()) {
                return Err(diverged(DivergenceCheck::NonFinite("increment")));
            }
            let limit_m = MAX_TRANSLATION_INCREMENT_LENGTHS * self.length_m;
            if dx.norm() > limit_m {
                return Err(diverged(DivergenceCheck::TranslationIncrement {
                    increment_m: dx.norm(),
                    limit_m,
                }));
            }
            if dtheta.norm() > std::f64::consts::PI {
                return Err(diverged(DivergenceCheck::RotationIncrement {
                    increment_rad: dtheta.norm(),
                }));
            }
            max_dx = max_dx.max(dx.norm());
            max_dtheta = max_dtheta.max(dtheta.norm());
        }
        for (i, du) in increments.iter().enumerate() {
            self.positions[i + 1] += du.fixed_rows::<3>(0).into_owned();
            let q = UnitQuaternion::from_scaled_axis(du.fixed_rows::<3>(3).into_owned())
                * self.rotations[i + 1];
            self.rotations[i + 1] = UnitQuaternion::new_normalize(q.into_inner());
        }
        Ok((max_dx, max_dtheta))
    }
}
