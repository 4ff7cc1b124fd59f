//! A merged stack's inner instruments sliding inside the ones around them
//! ([`NavigationSettings::axial_slide`](crate::navigation::NavigationSettings)): how far each
//! one's material lags its hand, the force that carries, the loads it puts on the strand, and
//! the slide that moves each tip until the part beyond its exit carries that force.
//!
//! An inner instrument `k` leaves the instruments around it at its **exit**, the farthest of
//! their tips (path coordinate σₓ). From its hand, held at the hub of the instrument directly
//! around it, to the exit it lies in a lumen without friction (merged mode has none), so it
//! carries one axial force there, F = K·λ: K its axial stiffness over that length
//! (1/K = ∫ dm / EA), λ how far its tip lags its hand (the hand's inserted length less the
//! tip's). The strand's composite elements then carry only the outermost instrument's axial
//! stiffness, and the force is the load a cable puts on its conduit: F·(tᵢ₋₁ − tᵢ) at each node
//! on the way (tᵢ the chord direction of element i), sideways where the path bends, and
//! F·tₓ₋₁ at the exit node, where the instrument goes on as the strand; together F·t₀, which
//! its hand holds, not the strand's base.
//!
//! While the tip lies beyond its exit, the hand's move carries the material beyond the exit
//! along the strand's curve (its nodes slid along it and relabelled, as a single device's are
//! by a push), and in the solve the first element beyond the exit is **in series with the
//! cable**: its axial stiffness the two in series, its rest chord longer by the cable's
//! slack λ, so that the solve lets material through the exit as far as the part beyond gives
//! (`BeamModel::set_axial_series`). After the solve the material let through moves from the
//! cable to that element (the nodes and tips beyond relabelled where they lie), and λ is
//! what the solved force leaves the cable, F/K. Before the twenty-eighth session the tip's
//! placement was relaxed after each solve at up to 10 mm/s, sliding the tip along the strand:
//! that left the compression of the part behind the tip where it was, so a hand that gave way
//! could not unload it. A tip that shares the exit's node (within 0.3 mm of it) keeps its
//! compression, which moves only with its hand; a tip inside the instruments around it
//! carries nothing, and its lag is let go at 10 mm/s.

use nalgebra::Vector3;

use super::instrument::{inserted_range, properties_at};
use super::state::{Coupling, MIN_GAP_FRACTION, SHARED_TIP_FRACTION, Stack};
use super::strand::curve_through;
use crate::wall::Wall;

/// How fast a tip inside the instruments around it lets its lag go (m/s): 10 mm/s, 0.02 mm
/// a step.
const MAX_SLIDE_M_S: f64 = 0.01;

/// Where an inner instrument's tip lies against its exit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Exit {
    /// Inside the instruments around it, by more than two tips that share a node: it carries
    /// nothing.
    Inside,
    /// Within two tips that share a node of the exit, which is this node: it carries its
    /// force there.
    Shared(usize),
    /// Beyond the exit, whose node is this one, with an element of its own past it.
    Beyond(usize),
}

impl<W: Wall> Stack<W> {
    /// Whether the inner instruments slide with their own axial strain.
    pub(super) fn slides(&self) -> bool {
        self.settings.axial_slide && self.coupling == Coupling::Merged
    }

    /// Path coordinate (m) where instrument `k` leaves the instruments around it: the farthest
    /// of their tips (0 for the outermost).
    fn exit_m(&self, k: usize) -> f64 {
        self.instruments[..k]
            .iter()
            .map(|i| i.inserted_m)
            .fold(0.0, f64::max)
    }

    /// Axial stiffness (N/m) of inner instrument `k` between its hand, at the hub of the
    /// instrument around it, and its exit: 1 / ∫ dm / EA over that material (at least one tip
    /// element of it).
    fn covered_stiffness_n_m(&self, k: usize) -> f64 {
        let instrument = &self.instruments[k];
        let outer = &self.instruments[k - 1];
        let offset = instrument.length_m - instrument.inserted_m;
        let from = (offset + outer.inserted_m - outer.length_m).max(0.0);
        let to = (offset + self.exit_m(k)).min(instrument.length_m);
        let shortest = self.settings.tip_element_m;
        let mut compliance = 0.0;
        let mut start = 0.0;
        for section in &instrument.device.sections {
            let end = start + section.length_m;
            let overlap = to.min(end) - from.max(start);
            if overlap > 0.0 {
                compliance += overlap / section.beam_properties().axial_stiffness_n;
            }
            start = end;
        }
        if to - from < shortest {
            let ea = properties_at(instrument, self.exit_m(k)).axial_stiffness_n;
            compliance += (shortest - (to - from).max(0.0)) / ea;
        }
        1.0 / compliance
    }

    /// Where inner instrument `k`'s tip lies against its exit, with the exit's node where it
    /// does not lie inside.
    fn exit_state(&self, k: usize) -> Exit {
        let exit = self.exit_m(k);
        let snap = SHARED_TIP_FRACTION * self.settings.tip_element_m;
        let placed = self.instruments[k].inserted_m;
        if placed < exit - snap {
            return Exit::Inside;
        }
        let node = self
            .nodes
            .iter()
            .enumerate()
            .filter(|(_, n)| (n.sigma - exit).abs() <= snap)
            .min_by(|a, b| {
                (a.1.sigma - exit)
                    .abs()
                    .total_cmp(&(b.1.sigma - exit).abs())
            })
            .map(|(i, _)| i)
            .filter(|&i| i > 0);
        match node {
            Some(i) if placed > exit + snap && i + 1 < self.nodes.len() => Exit::Beyond(i),
            Some(i) => Exit::Shared(i),
            None => Exit::Inside,
        }
    }

    /// Index of the node at inner instrument `k`'s exit while its tip lies beyond it or
    /// shares its node, `None` while inside.
    fn exit_node(&self, k: usize) -> Option<usize> {
        match self.exit_state(k) {
            Exit::Beyond(i) | Exit::Shared(i) => Some(i),
            Exit::Inside => None,
        }
    }

    /// The axial force (N, compression positive) inner instrument `k` carries from its hand to
    /// its exit, which its hand feels: zero without the slide, for the outermost, and while
    /// its tip lies inside the instruments around it (beyond sharing the exit's node).
    pub(super) fn slide_force_n(&self, k: usize) -> f64 {
        if !self.slides() || k == 0 || self.exit_node(k).is_none() {
            return 0.0;
        }
        self.cable_force_n(k)
    }

    /// The force (N, compression positive) inner instrument `k`'s lag puts in its length
    /// inside the ones around it: its stiffness there times the lag as placed.
    fn cable_force_n(&self, k: usize) -> f64 {
        let instrument = &self.instruments[k];
        self.covered_stiffness_n_m(k) * (instrument.hand_m - instrument.inserted_m)
    }

    /// Moves every hand to `targets` (inserted length m, twist rad) and places the
    /// instruments: each tip with its hand, or, sliding with its tip beyond its exit, its
    /// hand's move less what `carry_beyond_exits` carried beyond the exit (a pull's part that
    /// would take the tip into the exit) to the cable's slack, within the range the
    /// instrument around it leaves.
    pub(super) fn place_instruments(&mut self, targets: &[(f64, f64)]) {
        let slides = self.slides();
        let beyond: Vec<bool> = (0..targets.len())
            .map(|k| slides && k > 0 && matches!(self.exit_state(k), Exit::Beyond(_)))
            .collect();
        for (k, &(l, phi)) in targets.iter().enumerate() {
            self.instruments[k].twist_rad = phi;
            if !slides || k == 0 {
                let instrument = &mut self.instruments[k];
                instrument.hand_m = l;
                instrument.inserted_m = l;
                instrument.lag_m = 0.0;
                continue;
            }
            let outer = (
                self.instruments[k - 1].inserted_m,
                self.instruments[k - 1].length_m,
            );
            let tip_element = self.settings.tip_element_m;
            let instrument = &mut self.instruments[k];
            if beyond[k] {
                instrument.lag_m += l - instrument.hand_m;
            }
            let (lo, hi) = inserted_range(Some(outer), instrument.length_m, tip_element);
            instrument.hand_m = l;
            instrument.inserted_m = (l - instrument.lag_m).clamp(lo, hi);
            instrument.lag_m = l - instrument.inserted_m;
        }
    }

    /// The loads the sliding instruments' forces put on the strand's nodes (N, world frame):
    /// a cable's on its conduit, from node 1 to each one's exit node.
    pub(super) fn slide_loads(&self) -> Vec<Vector3<f64>> {
        let mut loads = vec![Vector3::zeros(); self.nodes.len()];
        if !self.slides() {
            return loads;
        }
        let positions = self.model.positions();
        let chord = |e: usize| {
            (positions[e + 1] - positions[e])
                .try_normalize(1e-15)
                .unwrap_or_else(Vector3::zeros)
        };
        for k in 1..self.instruments.len() {
            let Some(exit) = self.exit_node(k) else {
                continue;
            };
            let force = self.cable_force_n(k);
            if force == 0.0 {
                continue;
            }
            for (i, load) in loads.iter_mut().enumerate().take(exit).skip(1) {
                *load += (chord(i - 1) - chord(i)) * force;
            }
            loads[exit] += chord(exit - 1) * force;
        }
        loads
    }

    /// After a solve: a tip inside the instruments around it lets its lag go at up to
    /// [`MAX_SLIDE_M_S`] (beyond the exit the solve lets the material through:
    /// `let_through_exits`; a tip sharing the exit's node keeps its compression).
    pub(super) fn relax_slides(&mut self) {
        if !self.slides() {
            return;
        }
        let most = MAX_SLIDE_M_S * self.settings.time_step_s * self.step_fraction;
        for k in 1..self.instruments.len() {
            if self.exit_state(k) == Exit::Inside {
                let instrument = &mut self.instruments[k];
                instrument.lag_m -= instrument.lag_m.clamp(-most, most);
            }
        }
    }

    /// Before a solve: the first element beyond each sliding instrument's exit is put in
    /// series with that instrument's cable, slack and all (`BeamModel::set_axial_series`), so
    /// that the solve lets the material through the exit as far as the part beyond gives,
    /// instead of a relaxation after it (which left the compression of the part beyond
    /// where it was, or crushed the element at the exit).
    pub(super) fn put_exits_in_series(&mut self) {
        self.series.clear();
        if !self.slides() {
            return;
        }
        for k in 1..self.instruments.len() {
            if let Exit::Beyond(exit) = self.exit_state(k) {
                let cable = self.covered_stiffness_n_m(k);
                let slack = self.instruments[k].lag_m;
                self.model.set_axial_series(exit, cable, slack);
                self.series.push((k, exit));
            }
        }
    }

    /// After a solve: the material each cable let through its exit (its slack less the
    /// compression the solved force leaves it) moves from the cable to the element beyond
    /// the exit, the nodes and tips beyond relabelled where they lie (`flow_through_exit`);
    /// what that element cannot give moves the tip at the next move.
    pub(super) fn let_through_exits(&mut self) {
        for (k, exit) in std::mem::take(&mut self.series) {
            let cable = self.covered_stiffness_n_m(k);
            let force = -self.model.element_axial_force_n(exit);
            let through = self.instruments[k].lag_m - force / cable;
            let taken = self.flow_through_exit(exit, -through);
            self.instruments[k].lag_m += -through - taken;
        }
    }

    /// Moves `flow` (m, positive inwards) of an inner instrument's material through its exit
    /// node `exit`: the element beyond the exit, which is that instrument's, loses that rest
    /// length, and every node and tip beyond it is relabelled where it lies (path coordinates
    /// lowered by `flow`, positions kept). The element keeps at least half the smallest gap
    /// between nodes (the refinement then joins it with the next); what does not fit is not
    /// taken. Returns the flow taken (m).
    fn flow_through_exit(&mut self, exit: usize, flow: f64) -> f64 {
        let min_gap = MIN_GAP_FRACTION * self.settings.tip_element_m;
        let Some(next) = self.nodes.get(exit + 1) else {
            return 0.0;
        };
        let room = next.sigma - self.nodes[exit].sigma - 0.5 * min_gap;
        let flow = flow.min(room.max(0.0));
        if flow == 0.0 {
            return 0.0;
        }
        let from = self.nodes[exit].sigma;
        for node in &mut self.nodes[exit + 1..] {
            node.sigma -= flow;
        }
        self.relabel_beyond(from, -flow);
        flow
    }

    /// Moves by `by` (m) the path coordinates of everything beyond `from` (m) but the nodes:
    /// the last contacts' and the tips', each hand staying where it is (so its instrument's
    /// lag changes by −`by`).
    fn relabel_beyond(&mut self, from: f64, by: f64) {
        for (sigma, _) in &mut self.previous_contacts {
            if *sigma > from {
                *sigma += by;
            }
        }
        for instrument in &mut self.instruments {
            if instrument.inserted_m > from {
                instrument.inserted_m += by;
                instrument.lag_m -= by;
            }
        }
    }

    /// The predictor of a sliding instrument whose tip lies beyond its exit: its hand's move
    /// carries the material beyond the exit along the strand's curve (nodes and tips beyond
    /// the exit slid along it and relabelled by the move), as a single device's nodes are
    /// slid by its push, so that the solve does not drag them there; the cable's slack is
    /// unchanged, and the solve lets through the exit what the part beyond does not take
    /// (`put_exits_in_series`). A pull carries no tip back into its exit (the rest of it
    /// goes to the slack).
    pub(super) fn carry_beyond_exits(&mut self, targets: &[(f64, f64)]) {
        if !self.slides() {
            return;
        }
        let snap = SHARED_TIP_FRACTION * self.settings.tip_element_m;
        let min_gap = MIN_GAP_FRACTION * self.settings.tip_element_m;
        let count = self.instruments.len();
        for (k, target) in targets.iter().enumerate().take(count).skip(1) {
            let Exit::Beyond(exit) = self.exit_state(k) else {
                continue;
            };
            let wanted = target.0 - self.instruments[k].hand_m;
            let exit_sigma = self.nodes[exit].sigma;
            let room = self.instruments[k].inserted_m - exit_sigma - 2.0 * snap;
            let shift = wanted.max(-room.max(0.0));
            self.instruments[k].hand_m += shift;
            if shift == 0.0 {
                continue;
            }
            let old = self.nodes.clone();
            let end = *old.last().expect("a strand has nodes");
            for node in &mut self.nodes[exit + 1..] {
                let at = node.sigma + shift;
                let (position, rotation) = if at >= end.sigma {
                    let tangent = end.rotation * Vector3::x();
                    (end.position + tangent * (at - end.sigma), end.rotation)
                } else {
                    curve_through(&old, at)
                };
                node.sigma = at;
                node.position = position;
                node.rotation = rotation;
            }
            // Nodes a pull brought back onto the exit's.
            let keys: Vec<u64> = self.instruments.iter().filter_map(|i| i.tip_node).collect();
            let i = exit + 1;
            while i + 1 < self.nodes.len()
                && self.nodes[i].sigma < exit_sigma + min_gap
                && !keys.contains(&self.nodes[i].id)
            {
                self.nodes.remove(i);
            }
            // Every tip beyond the exit goes with the part: an inner one's (inside the part)
            // against its own hand, which it lags the more; this instrument's with its hand,
            // moved by the shift above, so its lag stays.
            self.relabel_beyond(exit_sigma, shift);
            self.instruments[k].lag_m += shift;
        }
    }
}
