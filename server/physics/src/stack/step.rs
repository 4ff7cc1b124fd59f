//! A stack's time step: every instrument's proximal control (clamped speeds and ranges), the
//! kinematic update, detection at the predicted configuration, the beam solve with contacts,
//! and the step halved where it would penetrate the wall.

use nalgebra::{UnitQuaternion, Vector3};

use super::instrument::{Instrument, inserted_range};
use super::state::{Coupling, NestedStep, Node, Stack};
use crate::beam::{BeamSnapshot, ElementSpec};
use crate::error::Result;
use crate::navigation::{
    Insertion, STILL_M, STILL_RAD, Sample, Twist, contact_counts, detect, material_of,
    push_element_samples, warm_start,
};
use crate::wall::{FreeSpace, Wall};

/// How many times a step may be halved when it would penetrate the wall.
const MAX_SUBSTEP_DEPTH: usize = 3;

/// What one stack step did.
#[derive(Debug, Clone, PartialEq)]
pub struct StackReport {
    /// Contacts detected.
    pub contacts: usize,
    /// Contacts with a positive normal force.
    pub active_contacts: usize,
    /// Gauss–Seidel sweeps.
    pub sweeps: usize,
    /// Whether Gauss–Seidel met its tolerance.
    pub converged: bool,
    /// Inserted length of every instrument at its hand after the step (m), outermost first.
    pub inserted_m: Vec<f64>,
    /// Elements simulated.
    pub elements: usize,
    /// Whether the step was skipped at rest ([`Stack::asleep`]).
    pub asleep: bool,
}

/// Everything [`Stack::advance`] needs to undo a step.
#[derive(Debug, Clone)]
struct Saved {
    model: BeamSnapshot,
    nodes: Vec<Node>,
    specs: Vec<(ElementSpec, u64, u64)>,
    instruments: Vec<Instrument>,
    previous_contacts: Vec<(f64, Vector3<f64>)>,
    next_id: u64,
    chains: Vec<Option<Stack<FreeSpace>>>,
    nested_last: NestedStep,
}

impl<W: Wall> Stack<W> {
    /// Advances one time step: every instrument's proximal control (clamped speeds and
    /// ranges, outermost first), the kinematic update of the strand, detection, the beam solve
    /// with contacts.
    pub fn step(&mut self) -> Result<StackReport> {
        let dt = self.settings.time_step_s;
        let mut targets: Vec<(f64, f64)> = Vec::with_capacity(self.instruments.len());
        for index in 0..self.instruments.len() {
            let instrument = &self.instruments[index];
            let max_push = instrument.max_insertion_speed_m_s * dt;
            let wanted = match instrument.command.insertion {
                Insertion::Velocity(v) => v * dt,
                Insertion::Target(l) => l - instrument.hand_m,
            }
            .clamp(-max_push, max_push);
            // The range follows the instruments around it at their new positions: a hub
            // pushes an inner instrument that has nowhere else to go.
            let outer = index
                .checked_sub(1)
                .map(|k| (targets[k].0, self.instruments[k].length_m));
            let (lo, hi) = inserted_range(outer, instrument.length_m, self.settings.tip_element_m);
            let inserted = (instrument.hand_m + wanted).clamp(lo, hi);
            let max_turn = instrument.max_twist_rate_rad_s * dt;
            let turn = match instrument.command.twist {
                Twist::Rate(w) => w * dt,
                Twist::Target(a) => a - instrument.twist_rad,
            }
            .clamp(-max_turn, max_turn);
            targets.push((inserted, instrument.twist_rad + turn));
        }
        // Asleep at rest (merged coupling only): nothing to solve.
        let sleep = self.sleep();
        let still = self.instruments.iter().zip(&targets).all(|(i, (l, a))| {
            (l - i.hand_m).abs() <= STILL_M && (a - i.twist_rad).abs() <= STILL_RAD
        });
        if still && self.stillness.asleep(sleep.as_ref()) {
            self.time_s += dt;
            return Ok(self.sleeping_report());
        }
        self.stillness.before_step(
            sleep.as_ref(),
            still,
            self.model.positions(),
            self.model.rotations(),
        );
        let report = self.advance(&targets, 0)?;
        self.stillness.after_step(
            sleep.as_ref(),
            self.model.positions(),
            self.model.rotations(),
        );
        self.time_s += dt;
        Ok(report)
    }

    /// Whether the last steps found the stack at rest and the next ones, with every hand
    /// still, are skipped (merged coupling; see [`crate::Sleep`]).
    pub fn asleep(&self) -> bool {
        self.stillness.asleep(self.sleep().as_ref())
    }

    /// When the stack may sleep: the settings' rule in merged coupling, never nested (its
    /// state spans one chain per instrument).
    fn sleep(&self) -> Option<crate::navigation::Sleep> {
        match self.coupling {
            Coupling::Merged => self.settings.sleep,
            Coupling::Nested => None,
        }
    }

    /// Something other than the hands changed the stack (a caller's edit through
    /// [`Self::model_mut`]): the next steps are solved again even if it slept.
    pub fn wake(&mut self) {
        self.stillness.wake();
    }

    /// What a step skipped at rest reports: the last step's contacts, no sweep.
    fn sleeping_report(&self) -> StackReport {
        let (contacts, active_contacts) = contact_counts(self.last.as_ref());
        StackReport {
            contacts,
            active_contacts,
            sweeps: 0,
            converged: true,
            inserted_m: self.instruments.iter().map(|i| i.hand_m).collect(),
            elements: self.model.element_count(),
            asleep: true,
        }
    }

    /// Moves every instrument to `targets` (inserted length m, twist rad) in one solve, or,
    /// where that solve still penetrates the wall beyond the sub-step threshold or diverged, in
    /// two halves (up to [`MAX_SUBSTEP_DEPTH`] times).
    fn advance(&mut self, targets: &[(f64, f64)], depth: usize) -> Result<StackReport> {
        let saved: Option<Saved> =
            (depth < self.effort.substep_depth(MAX_SUBSTEP_DEPTH)).then(|| Saved {
                model: self.model.snapshot(),
                nodes: self.nodes.clone(),
                specs: self.specs.clone(),
                instruments: self.instruments.clone(),
                previous_contacts: self.previous_contacts.clone(),
                next_id: self.next_id,
                chains: self.chains.clone(),
                nested_last: self.nested_last.clone(),
            });
        self.step_fraction = 0.5f64.powi(depth as i32);
        let result = match self.coupling {
            Coupling::Merged => self.single_step(targets, saved.is_none()),
            Coupling::Nested => self.nested_step(targets),
        };
        // Halved where the solve diverged (a rotation increment past π, a node thrown) or
        // still penetrates the wall; a divergence at the deepest halving is reported.
        let halve = match &result {
            Ok(_) => {
                let penetration = match self.coupling {
                    Coupling::Merged => self.last.as_ref().map_or(0.0, |s| s.penetration_m),
                    Coupling::Nested => self.nested_last.penetration_m,
                };
                penetration
                    > self
                        .effort
                        .substep_penetration(self.settings.substep_penetration_m)
            }
            Err(e) => e.is_divergence(),
        };
        if halve && let Some(saved) = saved {
            self.model.restore(saved.model);
            self.nodes = saved.nodes;
            self.specs = saved.specs;
            self.previous_contacts = saved.previous_contacts;
            self.next_id = saved.next_id;
            self.chains = saved.chains;
            self.nested_last = saved.nested_last;
            let half: Vec<(f64, f64)> = saved
                .instruments
                .iter()
                .zip(targets)
                .map(|(i, t)| (0.5 * (i.hand_m + t.0), 0.5 * (i.twist_rad + t.1)))
                .collect();
            self.instruments = saved.instruments;
            self.advance(&half, depth + 1)?;
            return self.advance(targets, depth + 1);
        }
        result
    }

    /// The kinematic part of a step: moves the instruments to `targets` and the nodes with
    /// them, refines, rebuilds the model and places its base.
    pub(super) fn prepare(&mut self, targets: &[(f64, f64)]) -> Result<()> {
        self.sync_nodes();
        self.move_instruments(targets)?;
        self.refine();
        self.rebuild_model()?;
        self.apply_tip_loads()?;
        self.put_exits_in_series();
        let twist =
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), self.instruments[0].twist_rad);
        self.model
            .place_base(self.entry_position, self.entry_rotation * twist)?;
        // A merged element carries the force of every instrument it holds, each within its
        // hand's strength: the bound is the single device's times their number.
        if let Some(limit) = self.settings.max_axial_force_n {
            let nodes = &self.nodes;
            let instruments = &self.instruments;
            self.model.relieve_axial_excess_by(|e| {
                let mid = 0.5 * (nodes[e].sigma + nodes[e + 1].sigma);
                let held = instruments.iter().filter(|i| i.inserted_m > mid).count();
                limit * held.max(1) as f64
            })?;
        }
        Ok(())
    }

    /// One solve: kinematic update, detection, beam solve with contacts; `last_try` where it
    /// will not be halved again.
    fn single_step(&mut self, targets: &[(f64, f64)], last_try: bool) -> Result<StackReport> {
        let before: Vec<(f64, f64)> = self
            .instruments
            .iter()
            .map(|i| (i.inserted_m, i.twist_rad))
            .collect();
        self.prepare(targets)?;
        let mut samples = self.sample_layout(true);
        self.set_slips(&mut samples, &before);
        let wall = &self.wall;
        let margin = self.settings.contact_margin_m;
        let sigma: Vec<f64> = self.nodes.iter().map(|n| n.sigma).collect();
        let previous = &self.previous_contacts;
        let tolerance = self.settings.sample_spacing_m;
        let clearance = &mut self.clearance;
        let step = self.model.step_with_contacts(
            |positions, _rotations, free| {
                Ok(detect(wall, &samples, positions, free, margin, clearance))
            },
            &if last_try {
                self.effort.last_try_contact(&self.settings.contact)
            } else {
                self.effort.contact(&self.settings.contact)
            },
            |contacts| warm_start(contacts, &sigma, previous, tolerance),
        )?;
        self.previous_contacts = step
            .contacts
            .iter()
            .zip(&step.response.local)
            .map(|(c, l)| (material_of(&sigma, c), *l))
            .collect();
        let report = StackReport {
            contacts: step.contacts.len(),
            active_contacts: step.response.local.iter().filter(|l| l.x > 0.0).count(),
            sweeps: step.response.iterations,
            converged: step.response.converged,
            inserted_m: self.instruments.iter().map(|i| i.hand_m).collect(),
            elements: self.model.element_count(),
            asleep: false,
        };
        self.last = Some(step);
        self.sync_nodes();
        self.let_through_exits();
        self.relax_slides();
        Ok(report)
    }

    /// With [`NavigationSettings::slide_friction`](crate::navigation::NavigationSettings), sets
    /// each collision point's slip: the outermost instrument there slid along the strand
    /// by its own move this step (the inserted lengths and twists `before` it, m and rad),
    /// and the wall's friction resists that in the solve. The strand's nodes stay where the
    /// instruments slide through them, so the slip is not in the free motion. Where the
    /// outermost instrument is still and one inside it slides or turns, the point has no
    /// friction: the wall holds the still one, and the lumen between them (frictionless in
    /// merged mode) passes it none of the moving one's load. (With the wall's friction
    /// there, a wire pushed through a still microcatheter round a ring put −0.167 N of its
    /// 0.64 N into the wall along the catheter; without, 0.021 N: the coaxial `capstan`
    /// tests.)
    fn set_slips(&self, samples: &mut [Sample], before: &[(f64, f64)]) {
        if !self.settings.slide_friction {
            return;
        }
        let positions = self.model.positions();
        let moved = |k: usize| {
            let i = &self.instruments[k];
            (i.inserted_m - before[k].0, i.twist_rad != before[k].1)
        };
        // Per element: the outermost instrument there.
        let outer: Vec<Option<usize>> = (0..self.model.element_count())
            .map(|e| {
                let mid = 0.5 * (self.nodes[e].sigma + self.nodes[e + 1].sigma);
                self.instruments.iter().position(|i| i.inserted_m > mid)
            })
            .collect();
        // A point of instrument `k` at path coordinate `sigma` on element `e`: its slip, or
        // none where `k` is still and an instrument inside it there moves.
        let slip = |k: usize, e: usize, sigma: f64| -> Option<Vector3<f64>> {
            let (advance, turned) = moved(k);
            let inner_moves = (k + 1..self.instruments.len()).any(|j| {
                let (a, t) = moved(j);
                self.instruments[j].inserted_m > sigma && (a != 0.0 || t)
            });
            if advance == 0.0 && !turned && inner_moves {
                return None;
            }
            let axis = (positions[e + 1] - positions[e])
                .try_normalize(1e-12)
                .unwrap_or_else(Vector3::zeros);
            Some(axis * advance)
        };
        for s in samples {
            let e = s.element;
            // An outer instrument's rim (the first point past its tip) is its own.
            let rim = (s.t == 0.0 && e > 0 && outer[e - 1] != outer[e])
                .then(|| outer[e - 1])
                .flatten();
            let Some(k) = rim.or(outer[e]) else {
                continue;
            };
            let sigma = self.nodes[e].sigma + s.t * (self.nodes[e + 1].sigma - self.nodes[e].sigma);
            match slip(k, e, sigma) {
                Some(v) => s.slip = v,
                None => s.friction = 0.0,
            }
        }
    }

    /// Collision points per element, with the radius and wall friction of the outermost
    /// instrument present. The node where an outer instrument ends (a catheter's tip, with
    /// the wire going on) is the next element's first point, with the inner instrument's
    /// radius: `rims` gives it the outer one's, so that the catheter's rim meets the wall
    /// there. The contacts use it (since the eleventh session: before, the rims went 0.2–0.4
    /// mm past the wall unseen); `rims` false gives the layout without, each instrument's
    /// shaft alone.
    pub(super) fn sample_layout(&self, rims: bool) -> Vec<Sample> {
        let mut samples: Vec<Sample> = Vec::new();
        let elements = self.model.element_count();
        // The last element's index and section, when it was sampled.
        let mut previous: Option<(usize, f64, f64)> = None;
        for e in 0..elements {
            let (a, b) = (self.nodes[e].sigma, self.nodes[e + 1].sigma);
            let mid = 0.5 * (a + b);
            let Some(outer) = self.instruments.iter().find(|i| i.inserted_m > mid) else {
                continue;
            };
            let (section, _) = outer
                .device
                .section_at(outer.length_m - outer.inserted_m + mid);
            let first = samples.len();
            push_element_samples(
                &mut samples,
                (e, elements),
                b - a,
                self.settings.sample_spacing_m,
                section,
            );
            if let Some((before, radius, friction)) = previous
                && rims
                && before + 1 == e
                && let Some(start) = samples.get_mut(first)
                && start.element == e
                && start.t == 0.0
                && radius > start.radius
            {
                start.radius = radius;
                start.friction = friction;
            }
            previous = Some((
                e,
                section.cross_section.outer_radius_m,
                section.friction_coefficient,
            ));
        }
        samples
    }
}
