//! The beam step with contacts: free solve, detection, the contact solve (Newton or
//! Gauss–Seidel) through the flexibility blocks, correction solve, with repeated detection
//! rounds; and the halves of a step whose contacts couple several chains (nested coaxial
//! instruments).

use nalgebra::{UnitQuaternion, Vector3, Vector6};

use super::model::BeamModel;
use super::report::{ContactStep, StepReport};
use super::settings::StepMode;
use crate::contact::{
    Contact, ContactResponse, ContactSettings, contact_loads, point_displacement, solve,
};
use crate::error::{PhysicsError, Result};

impl BeamModel {
    /// One paper-mode step with contact: the free increment is solved, `detect` turns the
    /// configuration and the free increment into contacts (positions, rotations, free increment
    /// per unknown node), the contact solve finds the contact forces through the flexibility blocks,
    /// and one more O(N) solve adds their effect. The contact forces are totals, not increments:
    /// the next step's residual no longer contains them, and its contact solve finds them again
    /// (warm-started from what `warm_start` returns for the detected contacts: local forces per
    /// contact). With `settings.detection_rounds` > 1, detection runs again at the solved
    /// configuration, and if it finds a wall penetrated by more than
    /// `settings.penetration_tolerance_m` that the contact set lacks, the contacts are solved
    /// again with it (the report's `iterations` counts the rounds). Nothing changes on error.
    pub fn step_with_contacts(
        &mut self,
        detect: impl FnMut(
            &[Vector3<f64>],
            &[UnitQuaternion<f64>],
            &[Vector6<f64>],
        ) -> Result<Vec<Contact>>,
        settings: &ContactSettings,
        warm_start: impl FnOnce(&[Contact]) -> Option<Vec<Vector3<f64>>>,
    ) -> Result<ContactStep> {
        self.saved_positions.clone_from(&self.positions);
        self.saved_rotations.clone_from(&self.rotations);
        let mut result = self.step_with_contacts_inner(detect, settings, warm_start);
        if let Err(PhysicsError::Diverged { step, .. }) = &mut result
            && *step == 0
        {
            *step = self.step_count + 1;
        }
        self.step_count += 1;
        if result.is_err() {
            self.positions.clone_from(&self.saved_positions);
            self.rotations.clone_from(&self.saved_rotations);
        }
        result
    }

    fn step_with_contacts_inner(
        &mut self,
        mut detect: impl FnMut(
            &[Vector3<f64>],
            &[UnitQuaternion<f64>],
            &[Vector6<f64>],
        ) -> Result<Vec<Contact>>,
        settings: &ContactSettings,
        warm_start: impl FnOnce(&[Contact]) -> Option<Vec<Vector3<f64>>>,
    ) -> Result<ContactStep> {
        // Step-size control on the free motion: detection predicts with the capped free
        // motion, and the contact solve makes the end state feasible whatever the scale. With
        // `cap_with_held_contacts` the cap judges the motion the last contact forces leave
        // first, and only where the motion the contacts then leave passes the cap (a contact
        // released, a loop let go) is the free motion itself scaled.
        let capped = self.begin_coupled_step()?;
        let whole = (self.settings.cap_with_held_contacts
            && self.settings.max_step_increment.is_some()
            && self.rhs != capped)
            .then(|| self.rhs.clone());
        let contacts = detect(&self.positions, &self.rotations, &capped)?;
        let warm = if contacts.is_empty() {
            None
        } else {
            warm_start(&contacts)
        };
        if let (Some(whole), Some(held)) = (whole, warm.as_ref()) {
            // The motion the last contact forces leave: the cap judges that, and the contact
            // solve starts from it, so that a wall's force is not scaled with the springback
            // it holds.
            let mut held_motion = contact_loads(&contacts, held, whole.len());
            self.substructure.solve_in_place(&mut held_motion);
            let mut free: Vec<Vector6<f64>> =
                whole.iter().zip(&held_motion).map(|(w, h)| w + h).collect();
            let scale = 1.0 / self.step_cap_excess(&free).max(1.0);
            for (f, h) in free.iter_mut().zip(&held_motion) {
                *f = *f * scale - h;
            }
            let rounds = self.contact_rounds(&mut detect, settings, &free, &contacts, &warm)?;
            if self.step_cap_excess(&rounds.increments) <= 1.0 + 1e-9 {
                return self.finish_contact_rounds(rounds, settings);
            }
        }
        let rounds = self.contact_rounds(&mut detect, settings, &capped, &contacts, &warm)?;
        self.finish_contact_rounds(rounds, settings)
    }

    /// How far `increments` go past the step cap
    /// ([`SolverSettings::max_step_increment`](super::SolverSettings)): the largest node
    /// translation over its cap, or rotation over its (1 or less: within; 0 without a cap).
    fn step_cap_excess(&self, increments: &[Vector6<f64>]) -> f64 {
        self.settings
            .max_step_increment
            .map_or(0.0, |(max_dx, max_dtheta)| {
                let (dx, dtheta) = largest_increments(increments);
                (dx / max_dx).max(dtheta / max_dtheta)
            })
    }

    /// The contact solve of a step from the free increment `free`, with detection rounds:
    /// `contacts` were detected at the predicted configuration (`warm`: their warm start).
    /// Moves nothing.
    fn contact_rounds(
        &mut self,
        detect: &mut impl FnMut(
            &[Vector3<f64>],
            &[UnitQuaternion<f64>],
            &[Vector6<f64>],
        ) -> Result<Vec<Contact>>,
        settings: &ContactSettings,
        free: &[Vector6<f64>],
        contacts: &[Contact],
        warm: &Option<Vec<Vector3<f64>>>,
    ) -> Result<ContactRounds> {
        let mut contacts = contacts.to_vec();
        let mut warm = warm.clone();
        let rounds = settings.detection_rounds.max(1);
        let mut increments;
        let mut response;
        let mut round = 0;
        let mut penetration: f64 = 0.0;
        // The contacts still penetrated after the last round, and how deep, to project out.
        let mut projection: Option<(Vec<Contact>, Vec<f64>)> = None;
        loop {
            response = if contacts.is_empty() {
                ContactResponse {
                    nodal_loads: vec![Vector6::zeros(); free.len()],
                    converged: true,
                    ..Default::default()
                }
            } else {
                solve(
                    &self.flexibility,
                    free,
                    &contacts,
                    settings,
                    warm.as_deref(),
                )?
            };
            increments = response.nodal_loads.clone();
            if !contacts.is_empty() {
                self.substructure.solve_in_place(&mut increments);
            }
            for (du, f) in increments.iter_mut().zip(free) {
                *du += f;
            }
            round += 1;
            if contacts.is_empty() {
                break;
            }
            // Look again where the contact forces moved the device: a wall it now penetrates
            // (one the contact set lacks, such as a corner's other wall, or one whose
            // linearization went stale as the device slid along a curved wall) means another
            // round with fresh contacts there. With one round allowed the look is still
            // taken: the penetration it measures is what decides a halving of the step (before,
            // a single round reported none, and a node at the governor's lowest level ended
            // 0.08 mm past the wall unhalved).
            let mut next = detect(&self.positions, &self.rotations, &increments)?;
            let depth = |c: &Contact| {
                -(c.gap
                    + c.normal
                        .dot(&point_displacement(&increments, c.element, c.t)))
            };
            let depths: Vec<f64> = next.iter().map(depth).collect();
            penetration = depths.iter().copied().fold(0.0, f64::max);
            if penetration <= settings.penetration_tolerance_m || round >= rounds {
                if penetration > settings.penetration_tolerance_m && settings.project_penetration {
                    projection = Some((next, depths));
                }
                break;
            }
            // Keep the earlier rounds' contacts too (a wall the contact forces pushed the device
            // away from still bounds it), ordered along the device. A point found again still
            // penetrating, on a wall whose normal turned (a tip wedged into a narrowing,
            // sliding along the curve round after round), keeps its earlier plane beside the
            // new one, so that the wedge holds it.
            let kept: Vec<Contact> = contacts
                .iter()
                .filter(|old| {
                    next.iter().find(|c| same_contact(c, old)).is_none_or(|c| {
                        !same_plane(c, old) && depth(c) > settings.penetration_tolerance_m
                    })
                })
                .copied()
                .collect();
            next.extend(kept);
            next.sort_by(|a, b| {
                (a.element, a.t)
                    .partial_cmp(&(b.element, b.t))
                    .unwrap_or(std::cmp::Ordering::Equal)
            });
            warm = Some(carry_forces(&next, &contacts, &response.local));
            contacts = next;
        }
        Ok(ContactRounds {
            increments,
            response,
            contacts,
            round,
            penetration,
            projection,
        })
    }

    /// Applies what [`Self::contact_rounds`] found: the penetration left projected out (where
    /// `settings` ask), then the increments.
    fn finish_contact_rounds(
        &mut self,
        rounds: ContactRounds,
        settings: &ContactSettings,
    ) -> Result<ContactStep> {
        let ContactRounds {
            mut increments,
            response,
            contacts,
            round,
            penetration,
            projection,
        } = rounds;
        if let Some((left, depths)) = projection {
            project_out(
                &left,
                &depths,
                settings.penetration_tolerance_m,
                &mut increments,
            );
        }
        let (dx, dtheta) = self.apply_increments(&increments)?;
        Ok(ContactStep {
            report: StepReport {
                iterations: round,
                converged: response.converged,
                last_translation_increment_m: dx,
                last_rotation_increment_rad: dtheta,
            },
            contacts,
            response,
            penetration_m: penetration,
        })
    }

    /// The first half of a step whose contacts couple this chain to others (nested coaxial
    /// instruments): assembles, factors, and returns the free increment of every unknown node
    /// (step-size controlled as in [`Self::step_with_contacts`]), leaving the flexibility
    /// blocks for the coupled contact solve. Nothing moves until [`Self::finish_coupled_step`].
    pub(crate) fn begin_coupled_step(&mut self) -> Result<Vec<Vector6<f64>>> {
        let gamma = match self.settings.mode {
            StepMode::Incremental { gamma } => gamma,
            StepMode::Converged { .. } => 1.0,
        };
        self.solve_free(gamma, true)?;
        let mut free = self.rhs.clone();
        if let Some((max_dx, max_dtheta)) = self.settings.max_step_increment {
            let (dx, dtheta) = largest_increments(&free);
            let scale = (max_dx / dx).min(max_dtheta / dtheta).min(1.0);
            if scale < 1.0 {
                free.iter_mut().for_each(|du| *du *= scale);
            }
        }
        Ok(free)
    }

    /// The increments of a coupled step: `free` plus K⁻¹ `loads` (contact loads per unknown
    /// node, N and N·m), by one O(N) solve with the factorization of
    /// [`Self::begin_coupled_step`].
    pub(crate) fn coupled_increments(
        &mut self,
        free: &[Vector6<f64>],
        loads: &[Vector6<f64>],
    ) -> Vec<Vector6<f64>> {
        let mut increments = loads.to_vec();
        self.substructure.solve_in_place(&mut increments);
        for (du, f) in increments.iter_mut().zip(free) {
            *du += f;
        }
        increments
    }

    /// The second half of a coupled step: applies `increments` after the divergence checks
    /// (nothing moves if one trips) and counts the step.
    pub(crate) fn finish_coupled_step(
        &mut self,
        increments: &[Vector6<f64>],
    ) -> Result<StepReport> {
        let result = self.apply_increments(increments);
        self.step_count += 1;
        let (dx, dtheta) = result?;
        Ok(StepReport {
            iterations: 1,
            converged: true,
            last_translation_increment_m: dx,
            last_rotation_increment_rad: dtheta,
        })
    }
}

/// The largest node translation (m) and rotation (rad) among `increments`.
fn largest_increments(increments: &[Vector6<f64>]) -> (f64, f64) {
    increments.iter().fold((0.0f64, 0.0f64), |(a, b), du| {
        (
            a.max(du.fixed_rows::<3>(0).norm()),
            b.max(du.fixed_rows::<3>(3).norm()),
        )
    })
}

/// What a step's contact solve found, before anything moves: the increments, the last
/// round's response and contacts, the rounds taken, the penetration the last look saw, and the
/// contacts still penetrated past the tolerance with their depths (to project out).
struct ContactRounds {
    increments: Vec<Vector6<f64>>,
    response: ContactResponse,
    contacts: Vec<Contact>,
    round: usize,
    penetration: f64,
    projection: Option<(Vec<Contact>, Vec<f64>)>,
}

/// Whether two contacts are the same wall touching the same point: same element and
/// parameter, normals within about 25°.
fn same_contact(a: &Contact, b: &Contact) -> bool {
    a.element == b.element && (a.t - b.t).abs() <= 1e-9 && a.normal.dot(&b.normal) > 0.9
}

/// Whether two contacts are one plane: the same point with normals within about 0.25°.
fn same_plane(a: &Contact, b: &Contact) -> bool {
    a.element == b.element && (a.t - b.t).abs() <= 1e-9 && a.normal.dot(&b.normal) > 0.99999
}

/// Moves each element with a contact deeper than `tolerance` (its `depths`, m) out along that
/// contact's normal by its depth: both of its nodes' translations in `increments` (unknown
/// nodes; node 0, the driven base, stays), each node by the largest push any of its
/// elements' contacts asks along that normal beyond what it already got.
fn project_out(
    contacts: &[Contact],
    depths: &[f64],
    tolerance: f64,
    increments: &mut [Vector6<f64>],
) {
    let mut pushes = vec![Vector3::<f64>::zeros(); increments.len()];
    for (c, &d) in contacts.iter().zip(depths) {
        if d <= tolerance {
            continue;
        }
        for node in [c.element, c.element + 1] {
            let Some(push) = node.checked_sub(1).and_then(|i| pushes.get_mut(i)) else {
                continue;
            };
            let missing = d - push.dot(&c.normal);
            if missing > 0.0 {
                *push += c.normal * missing;
            }
        }
    }
    for (increment, push) in increments.iter_mut().zip(&pushes) {
        let mut translation = increment.fixed_rows_mut::<3>(0);
        translation += push;
    }
}

/// Forces of `old` contacts carried over to the same `new` ones (zero for the rest): the
/// warm start of a repeated detection round. Each old force goes to at most one new contact,
/// the one whose normal is nearest its own (where two old ones choose the same new one, the
/// later one's force is kept: a warm start only).
fn carry_forces(new: &[Contact], old: &[Contact], forces: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let mut carried = vec![Vector3::zeros(); new.len()];
    for (o, f) in old.iter().zip(forces) {
        let best = new
            .iter()
            .enumerate()
            .filter(|(_, c)| same_contact(o, c))
            .max_by(|(_, a), (_, b)| a.normal.dot(&o.normal).total_cmp(&b.normal.dot(&o.normal)));
        if let Some((k, _)) = best {
            carried[k] = *f;
        }
    }
    carried
}
