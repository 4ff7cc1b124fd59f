//! A navigation's time step: proximal control (clamped speeds), the device slid through the
//! entry point (base element grown, split or merged), local refinement, detection at the
//! predicted configuration, the beam solve with contacts, and the step halved where it would
//! penetrate the wall.

use nalgebra::{UnitQuaternion, Vector3};

use super::command::{Insertion, Twist};
use super::detection::{Sample, detect, material_of, push_element_samples, warm_start};
use super::settings::{MAX_SUBSTEP_DEPTH, solver_settings, spacing};
use super::sleep::contact_counts;
use super::state::{Navigation, element_spec};
use crate::beam::BeamModel;
use crate::error::Result;
use crate::wall::Wall;

/// What one navigation step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavigationReport {
    /// Contacts detected.
    pub contacts: usize,
    /// Contacts with a positive normal force.
    pub active_contacts: usize,
    /// Gauss–Seidel sweeps.
    pub sweeps: usize,
    /// Whether Gauss–Seidel met its tolerance.
    pub converged: bool,
    /// Inserted length after the step (m).
    pub inserted_m: f64,
    /// Twist angle after the step (rad).
    pub twist_rad: f64,
    /// Elements simulated.
    pub elements: usize,
    /// Whether the step was skipped at rest ([`Navigation::asleep`]).
    pub asleep: bool,
}

/// A push (m) or turn (rad) a step no larger than these leaves the hands still: what is left
/// of a target command once reached (rounding).
pub(crate) const STILL_M: f64 = 1e-12;
/// See [`STILL_M`].
pub(crate) const STILL_RAD: f64 = 1e-12;

impl<W: Wall> Navigation<W> {
    /// Advances one time step.
    pub fn step(&mut self) -> Result<NavigationReport> {
        let dt = self.settings.time_step_s;
        let length = self.device.length_m();
        // 1. Proximal control, clamped.
        let max_push = self.settings.max_insertion_speed_m_s * dt;
        let inserted = self.inserted_m();
        let wanted = match self.command.insertion {
            Insertion::Velocity(v) => v * dt,
            Insertion::Target(x) => x - inserted,
        };
        let min_inserted = self.settings.tip_element_m;
        let push = wanted
            .clamp(-max_push, max_push)
            .clamp(min_inserted - inserted, length - inserted);
        let max_turn = self.settings.max_twist_rate_rad_s * dt;
        let turn = match self.command.twist {
            Twist::Rate(w) => w * dt,
            Twist::Target(a) => a - self.twist_rad,
        }
        .clamp(-max_turn, max_turn);
        // 2. Asleep at rest: nothing to solve.
        let sleep = self.settings.sleep;
        let still = push.abs() <= STILL_M && turn.abs() <= STILL_RAD;
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
        self.refine()?;
        let report = self.advance(push, turn, 0)?;
        self.stillness.after_step(
            sleep.as_ref(),
            self.model.positions(),
            self.model.rotations(),
        );
        self.time_s += dt;
        Ok(report)
    }

    /// Whether the last steps found the device at rest and the next ones, with the hands
    /// still, are skipped ([`NavigationSettings::sleep`](super::NavigationSettings::sleep)).
    pub fn asleep(&self) -> bool {
        self.stillness.asleep(self.settings.sleep.as_ref())
    }

    /// What a step skipped at rest reports: the last step's contacts, no sweep.
    fn sleeping_report(&self) -> NavigationReport {
        let (contacts, active_contacts) = contact_counts(self.last.as_ref());
        NavigationReport {
            contacts,
            active_contacts,
            sweeps: 0,
            converged: true,
            inserted_m: self.inserted_m(),
            twist_rad: self.twist_rad,
            elements: self.model.element_count(),
            asleep: true,
        }
    }

    /// Advances by `push` (m) and `turn` (rad); where the solved step still penetrates the wall
    /// by more than the sub-step threshold (a violent event: buckling, a slide along a curved
    /// wall) or diverged, the step is undone and taken as two halves, up to
    /// [`MAX_SUBSTEP_DEPTH`] times.
    fn advance(&mut self, push: f64, turn: f64, depth: usize) -> Result<NavigationReport> {
        let max_depth = self.effort.substep_depth(MAX_SUBSTEP_DEPTH);
        let saved = (depth < max_depth).then(|| {
            (
                self.model.snapshot(),
                self.material.clone(),
                self.twist_rad,
                self.previous_contacts.clone(),
            )
        });
        self.model
            .set_settings(solver_settings(&self.settings, 0.5f64.powi(depth as i32)));
        let result = self.single_step(push, turn, saved.is_none());
        // Halved where the solve diverged (a rotation increment past π, a node thrown) or
        // still penetrates the wall; a divergence at the deepest halving is reported.
        let halve = match &result {
            Ok(_) => {
                self.last.as_ref().map_or(0.0, |s| s.penetration_m)
                    > self
                        .effort
                        .substep_penetration(self.settings.substep_penetration_m)
            }
            Err(e) => e.is_divergence(),
        };
        if halve && let Some((model, material, twist, previous)) = saved {
            self.model.restore(model);
            self.material = material;
            self.twist_rad = twist;
            self.previous_contacts = previous;
            self.advance(0.5 * push, 0.5 * turn, depth + 1)?;
            return self.advance(0.5 * push, 0.5 * turn, depth + 1);
        }
        result
    }

    /// One solve: slide, twist, detect, solve; `last_try` where it will not be halved again.
    fn single_step(&mut self, push: f64, turn: f64, last_try: bool) -> Result<NavigationReport> {
        let slid = self.slide(push)?;
        self.twist_rad += turn;
        let twist = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), self.twist_rad);
        self.model
            .place_base(self.entry_position, self.entry_rotation * twist)?;
        if let Some(limit) = self.settings.max_axial_force_n {
            self.model.relieve_axial_excess(limit)?;
        }
        // 2–4. Detection at the predicted configuration, beam solve with contacts.
        let mut samples = self.sample_layout();
        if self.settings.slide_friction {
            for s in &mut samples {
                s.slip = slid[s.element] * (1.0 - s.t) + slid[s.element + 1] * s.t;
            }
        }
        let wall = &self.wall;
        let margin = self.settings.contact_margin_m;
        let material = &self.material;
        let previous = &self.previous_contacts;
        let tolerance = self.settings.sample_spacing_m;
        let contact = if last_try {
            self.effort.last_try_contact(&self.settings.contact)
        } else {
            self.effort.contact(&self.settings.contact)
        };
        let clearance = &mut self.clearance;
        let step = self.model.step_with_contacts(
            |positions, _rotations, free| {
                Ok(detect(wall, &samples, positions, free, margin, clearance))
            },
            &contact,
            |contacts| warm_start(contacts, material, previous, tolerance),
        )?;
        self.previous_contacts = step
            .contacts
            .iter()
            .zip(&step.response.local)
            .map(|(c, l)| (material_of(&self.material, c), *l))
            .collect();
        let report = NavigationReport {
            contacts: step.contacts.len(),
            active_contacts: step.response.local.iter().filter(|l| l.x > 0.0).count(),
            sweeps: step.response.iterations,
            converged: step.response.converged,
            inserted_m: self.inserted_m(),
            twist_rad: self.twist_rad,
            elements: self.model.element_count(),
            asleep: false,
        };
        self.last = Some(step);
        Ok(report)
    }

    /// Slides the device in (`push` > 0) or out through the entry point, growing or shrinking
    /// the element next to it and splitting or merging it as needed. Returns how far the
    /// material at each node moved (m, one per node as the model now has them; at the entry,
    /// `push` along the entry axis): the slip the wall's friction resists in this step's
    /// solve.
    fn slide(&mut self, push: f64) -> Result<Vec<Vector3<f64>>> {
        if push == 0.0 {
            return Ok(vec![Vector3::zeros(); self.model.positions().len()]);
        }
        let length = self.device.length_m();
        // Predictor. Follow the leader along the straight part: every node moves along the
        // device's current shape by `push` (behind the entry along the entry axis), so the
        // material slides along its own path and nothing is compressed. A curved rest shape at
        // the tip (angled or J) is carried rigidly by the last straight node, which moves along
        // its own axis (pushed) or back along the curve (pulled): sliding material through a
        // bend would strain it.
        let positions = self.model.positions().to_vec();
        let rotations = self.model.rotations().to_vec();
        // What the hand felt (N, tension positive), kept across a merge at the entry.
        let held = self.model.element_axial_force_n(0);
        let last = self.material.len() - 1;
        let curved_from = self.first_curved_element().map_or(last, |e| e.max(1));
        let along = |s: f64| -> (Vector3<f64>, UnitQuaternion<f64>) {
            let m = &self.material;
            if s <= m[0] {
                let q = rotations[0];
                (positions[0] - q * Vector3::x() * (m[0] - s), q)
            } else {
                let k = m.partition_point(|&x| x <= s).clamp(1, last) - 1;
                let f = ((s - m[k]) / (m[k + 1] - m[k])).min(1.0);
                (
                    positions[k] + (positions[k + 1] - positions[k]) * f,
                    rotations[k].slerp(&rotations[k + 1], f),
                )
            }
        };
        let mut new_positions = positions.clone();
        let mut new_rotations = rotations.clone();
        for i in 1..curved_from {
            (new_positions[i], new_rotations[i]) = along(self.material[i] + push);
        }
        if push > 0.0 {
            let carried = rotations[curved_from] * Vector3::x() * push;
            for p in &mut new_positions[curved_from..] {
                *p += carried;
            }
        } else {
            // Pulled back, the curved part moves as a rigid body fixed to its first node's
            // frame, which retraces the curve. (Carried back along that node's axis, a tip
            // folded by a loop moved sideways while the wire behind it withdrew, the element
            // between them stretched tenfold; translated back along the curve without
            // turning with it, an angled tip swept into the wall of a tortuous carotid and
            // hooked there, and a microwire held against a 40 N pull.)
            let (at, frame) = along(self.material[curved_from] + push);
            let turn = frame * rotations[curved_from].inverse();
            for i in curved_from..=last {
                new_positions[i] = at + turn * (positions[i] - positions[curved_from]);
                new_rotations[i] = turn * rotations[i];
            }
        }
        self.model.set_nodes(&new_positions, &new_rotations)?;
        self.material[0] -= push;
        // The material's motion: at the entry along its axis, elsewhere each node's.
        let entry_slip = rotations[0] * Vector3::x() * push;
        let mut slid: Vec<Vector3<f64>> = new_positions
            .iter()
            .zip(&positions)
            .map(|(new, old)| new - old)
            .collect();
        slid[0] = entry_slip;
        loop {
            let base = self.material[0];
            let first = self.material[1];
            let h = spacing(&self.settings, length, first);
            let element = first - base;
            // Only split while pushing and only merge while pulling: with a spacing that varies
            // along the device, doing both could alternate forever.
            if push > 0.0 && element > 1.5 * h {
                let on_curve = if self.settings.cap_with_held_contacts {
                    self.split_entry_on_curve(h)?
                } else {
                    None
                };
                let split = match on_curve {
                    Some(split) => split,
                    None => {
                        let split = first - h;
                        self.model.insert_node_after_base(
                            element_spec(&self.device, base, split),
                            element_spec(&self.device, split, first),
                        )?;
                        split
                    }
                };
                self.material.insert(1, split);
                slid.insert(1, entry_slip);
            } else if push < 0.0 && element < 0.5 * h && self.material.len() > 2 {
                // The hand feels element 0's axial force. Element 1 may carry more (what the
                // wall's friction holds beyond node 1, or strain a capped step has not yet
                // corrected there, up to the relief's bound): joined as they are, a pulled wire
                // went from 2 to 14 N of compression at the hand in one step. So the joined
                // element keeps element 0's force from before the slide: the entry's material
                // coordinate moves by the difference in strain (micrometres: the wire slips
                // that far at the hand).
                let second = self.material[2];
                let merged = element_spec(&self.device, base, second);
                let stiffness = merged.props.axial_stiffness_n;
                self.model.remove_node_after_base(merged)?;
                self.material.remove(1);
                slid.remove(1);
                let chord = (self.model.positions()[1] - self.model.positions()[0]).norm();
                let rest = rest_carrying(chord, stiffness, held);
                // (A force near E·A would mean a wrecked element: then joined as it lies.)
                if (rest - (second - base)).abs() < 0.1 * (second - base) {
                    self.material[0] = second - rest;
                }
            } else {
                self.model
                    .set_base_element(element_spec(&self.device, base, first))?;
                return Ok(slid);
            }
        }
    }

    /// Splits the element at the entry by a new node on the smooth curve through its nodes,
    /// about `h` (m, rest) from node 1, and returns the new node's material coordinate (m);
    /// the entry's moves by micrometres. None, splitting nothing, where the element's force
    /// is near −E·A (a wrecked element: the caller splits it on the chord). On the chord the new node would kink the device
    /// (with the held-contacts cap, whose correction is not scaled, that put 36 N on the hand
    /// for one step); on the curve the two halves' chords add up to more than the element's
    /// (ℓθ²/32 on an arc turning θ: 1–2 µm, 15–30 N on a 0.035" wire's 2 mm elements). So
    /// each half's rest length is the one at which its chord carries the element's axial
    /// force, as the entry's merge keeps it.
    fn split_entry_on_curve(&mut self, h: f64) -> Result<Option<f64>> {
        let (base, first) = (self.material[0], self.material[1]);
        let rest = first - base;
        let [p0, p1] = [self.model.positions()[0], self.model.positions()[1]];
        let stiffness = |a: f64, b: f64| element_spec(&self.device, a, b).props.axial_stiffness_n;
        let force = stiffness(base, first) / rest * ((p1 - p0).norm() - rest);
        let (position, rotation) = self.model.base_curve_point(1.0 - h / rest);
        let split =
            first - rest_carrying((p1 - position).norm(), stiffness(first - h, first), force);
        let new_base = split - rest_carrying((position - p0).norm(), stiffness(base, split), force);
        if !((new_base - base).abs() < 0.1 * h && split > new_base && split < first) {
            return Ok(None);
        }
        self.model.insert_node_after_base_at(
            element_spec(&self.device, new_base, split),
            element_spec(&self.device, split, first),
            position,
            rotation,
        )?;
        self.material[0] = new_base;
        Ok(Some(split))
    }

    /// Halves elements that bend too much or touch the wall and merges halves that no longer
    /// need to be apart (see [`Refinement`](super::Refinement)). The element at the entry point is left to
    /// [`Self::slide`]. Runs between steps, so the last contacts decide.
    fn refine(&mut self) -> Result<()> {
        let Some(refinement) = self.settings.refinement else {
            return Ok(());
        };
        let refinement = self.effort.refinement(refinement);
        let length = self.device.length_m();
        let shortest = self.settings.tip_element_m;
        // Material coordinates of the active contacts, ordered along the device.
        let active: Vec<f64> = self.last.as_ref().map_or_else(Vec::new, |step| {
            step.contacts
                .iter()
                .zip(&step.response.local)
                .filter(|(_, l)| l.x > 0.0)
                .map(|(c, _)| material_of(&self.material, c))
                .collect()
        });
        let touching = |a: f64, b: f64| active.iter().any(|&s| s >= a && s <= b);
        let bend = |model: &BeamModel, e: usize| {
            let r = model.rotations();
            (r[e] * Vector3::x()).angle(&(r[e + 1] * Vector3::x()))
        };
        // Split, tip first so that the indices still to visit stay valid.
        for e in (1..self.model.element_count()).rev() {
            let (a, b) = (self.material[e], self.material[e + 1]);
            let long = b - a;
            if long >= 2.0 * shortest
                && (bend(&self.model, e) > refinement.max_bend_rad
                    || (long > refinement.contact_element_m && touching(a, b)))
            {
                let mid = 0.5 * (a + b);
                self.model.split_element(
                    e,
                    element_spec(&self.device, a, mid),
                    element_spec(&self.device, mid, b),
                )?;
                self.material.insert(e + 1, mid);
            }
        }
        // Merge.
        let mut e = 1;
        while e + 1 < self.model.element_count() {
            let (a, b) = (self.material[e], self.material[e + 2]);
            let nominal = spacing(&self.settings, length, 0.5 * (a + b));
            if b - a < 1.25 * nominal
                && bend(&self.model, e) + bend(&self.model, e + 1) < refinement.max_bend_rad / 3.0
                && !touching(a, b)
            {
                self.model
                    .merge_elements(e, element_spec(&self.device, a, b))?;
                self.material.remove(e + 1);
            } else {
                e += 1;
            }
        }
        Ok(())
    }

    /// Collision points per element: (element, t, device radius, friction).
    fn sample_layout(&self) -> Vec<Sample> {
        let mut samples = Vec::new();
        let elements = self.model.element_count();
        for e in 0..elements {
            let (a, b) = (self.material[e], self.material[e + 1]);
            let (section, _) = self.device.section_at(0.5 * (a + b));
            push_element_samples(
                &mut samples,
                (e, elements),
                b - a,
                self.settings.sample_spacing_m,
                section,
            );
        }
        samples
    }

    /// The largest penetration of the device into the wall in the current configuration (m;
    /// 0 when nothing penetrates), over the collision points.
    pub fn max_penetration_m(&self) -> f64 {
        let positions = self.model.positions();
        self.sample_layout()
            .iter()
            .enumerate()
            .filter_map(|(i, s)| {
                let p = positions[s.element] * (1.0 - s.t) + positions[s.element + 1] * s.t;
                // A point the detection's bounds show clear of the wall cannot penetrate it.
                if self.clearance.clear_of_wall(i, &p, s.radius) {
                    return None;
                }
                self.wall
                    .probe(&p, s.radius)
                    .map(|probe| s.radius - probe.clearance_m)
            })
            .fold(0.0, f64::max)
    }
}

/// The rest length (m) at which an element whose chord is `chord` m long carries `force` N
/// (tension positive) with axial stiffness `ea` (N): what a split or a merge at the entry
/// gives an element so that the force the hand feels does not jump.
fn rest_carrying(chord: f64, ea: f64, force: f64) -> f64 {
    chord * ea / (ea + force)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::presets;
    use crate::navigation::NavigationSettings;
    use crate::wall::CappedTube;

    /// A 0.035" wire 100 mm into a straight 300 mm tube of 2 mm radius.
    fn wire_in_a_tube(settings: NavigationSettings) -> Navigation<CappedTube> {
        let tube = CappedTube {
            start: Vector3::zeros(),
            axis: Vector3::x(),
            length_m: 0.3,
            radius_m: 2e-3,
        };
        Navigation::new(
            presets::guidewire_035(),
            tube,
            Vector3::zeros(),
            Vector3::x(),
            0.1,
            settings,
        )
        .unwrap()
    }

    /// Regression (the random operator on `arch_to_cow_lcca`, seed 1, at 33.478 s): a wire
    /// pulled out through the entry, element 0 at 2 N of compression and element 1 at 20 N
    /// (strain the capped steps had not yet corrected), felt 14 N at the hand the step the two
    /// were joined. Joined, they keep element 0's force; the entry moves by micrometres.
    #[test]
    fn a_merge_at_the_entry_keeps_the_force_the_hand_feels() {
        let mut nav = wire_in_a_tube(NavigationSettings::default());
        let pull = -0.05e-3;
        let length = nav.device.length_m();
        // Pulled (slid alone: nothing loads the straight wire) until the next pull joins
        // elements 0 and 1.
        loop {
            let (base, first) = (nav.material[0] - pull, nav.material[1]);
            if first - base < 0.5 * spacing(&nav.settings, length, first) {
                break;
            }
            nav.slide(pull).unwrap();
        }
        // Element 1 crushed by 10 µm: node 2 and all beyond moved towards node 1.
        let crush = 10e-6;
        let mut positions = nav.model.positions().to_vec();
        for p in &mut positions[2..] {
            p.x -= crush;
        }
        let rotations = nav.model.rotations().to_vec();
        nav.model.set_nodes(&positions, &rotations).unwrap();
        let felt = nav.model.element_axial_force_n(0);
        let crushed = nav.model.element_axial_force_n(1);
        let (elements, entry) = (nav.model.element_count(), nav.material[0]);
        assert!(felt.abs() < 1e-6 && crushed < -5.0, "{felt} N, {crushed} N");
        nav.slide(pull).unwrap();
        assert_eq!(nav.model.element_count(), elements - 1, "joined");
        let joined = nav.model.element_axial_force_n(0);
        assert!(
            (joined - felt).abs() < 1e-6,
            "the hand felt {felt} N before the join and {joined} N after ({crushed} N crushed)"
        );
        // The entry moved by the pull and by the crushed micrometre at most.
        let moved = nav.material[0] - entry;
        assert!(
            (moved + pull).abs() <= crush,
            "entry moved {moved} m for a {pull} m pull"
        );
    }

    /// The held-contacts cap does not scale the correction a split makes, so the entry's split
    /// puts its new node on the curve (on the chord it kinked the wire: 36 N at the hand for
    /// one step); there the halves' chords add up to more than the element's, and with the
    /// element's rest length cut in two they were stretched by 1–2 µm (19 N at the hand for
    /// one step, the random operator on `arch_to_cow_lcca` at 60.8 s). Each half now carries
    /// the element's force; the entry moves by micrometres.
    #[test]
    fn a_split_at_the_entry_on_the_curve_keeps_the_force_the_hand_feels() {
        let mut nav = wire_in_a_tube(NavigationSettings {
            cap_with_held_contacts: true,
            ..NavigationSettings::default()
        });
        let push = 0.05e-3;
        let length = nav.device.length_m();
        // Pushed (slid alone) until the next push splits element 0.
        loop {
            let (base, first) = (nav.material[0] - push, nav.material[1]);
            if first - base > 1.5 * spacing(&nav.settings, length, first) {
                break;
            }
            nav.slide(push).unwrap();
        }
        // Element 0 bent by 0.3 rad as an arc (node 1's frame turned by θ, the rest of the
        // wire by θ/2 about the entry) and every element stretched by 5e-4.
        let theta: f64 = 0.3;
        let (half, whole) = (
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.5 * theta),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), theta),
        );
        let positions: Vec<Vector3<f64>> = nav
            .model
            .positions()
            .iter()
            .map(|p| half * p * (1.0 + 5e-4))
            .collect();
        let mut rotations = nav.model.rotations().to_vec();
        for q in &mut rotations[1..] {
            *q = whole * *q;
        }
        nav.model.set_nodes(&positions, &rotations).unwrap();
        let felt = nav.model.element_axial_force_n(0);
        let (elements, entry) = (nav.model.element_count(), nav.material[0]);
        assert!(felt > 1.0, "stretched: {felt} N");
        nav.slide(push).unwrap();
        assert_eq!(nav.model.element_count(), elements + 1, "split");
        let halves = [0, 1].map(|e| nav.model.element_axial_force_n(e));
        for force in halves {
            assert!(
                (force - felt).abs() < 0.02 * felt,
                "the hand felt {felt} N before the split; the halves carry {halves:?} N"
            );
        }
        assert!((halves[0] - halves[1]).abs() < 1e-6 * felt, "{halves:?} N");
        // On the curve, off the chord.
        let p = nav.model.positions();
        let chord = (p[2] - p[0]).normalize();
        let off = (p[1] - p[0]).cross(&chord).norm();
        assert!(off > 5e-6, "the new node is {off} m off the chord");
        // The entry moved by the push and by what the curve adds to the chord (the halves'
        // chords' excess over the element's; 19 µm on this 0.3 rad bend, ℓθ²/24-ish).
        let moved = nav.material[0] - entry;
        let excess = (p[1] - p[0]).norm() + (p[2] - p[1]).norm() - (p[2] - p[0]).norm();
        assert!(
            (moved + push).abs() <= 1.01 * excess && excess < 0.05 * push.max(1e-3),
            "entry moved {moved} m for a {push} m push ({excess} m of curve)"
        );
    }
}
