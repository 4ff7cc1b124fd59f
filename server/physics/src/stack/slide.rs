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
//! The tip's placement is where the part beyond the exit carries F. Each move shares the
//! hand's motion between the tip and λ as two springs in series (the cable's K and the part
//! beyond's stiffness against the tip's placement, a secant learnt from the solves); after
//! each solve the tip slides by the difference between the force in the first element beyond
//! the exit and F over the two stiffnesses (at most 10 mm/s). A tip that shares the exit's
//! node (within 0.3 mm of it) keeps its compression, which moves only with its hand; a tip
//! inside the instruments around it carries nothing, and its lag is let go.

use nalgebra::Vector3;

use super::instrument::{inserted_range, properties_at};
use super::state::{Coupling, SHARED_TIP_FRACTION, Stack};
use crate::wall::Wall;

/// The part beyond an exit is never taken stiffer than its axial stiffness over this many tip
/// elements (a contact can hold it no closer to the exit than the first node past it).
const SHORTEST_HOLD_TIP_ELEMENTS: f64 = 1.0;

/// The fastest a tip slides to its cable's force after a solve (m/s): 10 mm/s, 0.02 mm a
/// step. A tip just beyond its exit has a part beyond of one short element, whose force jumps
/// with the placement; sliding up to a push's length a step (0.3 mm) there, the relaxation
/// overshot, the tip crossed in and out of the node it shares within 0.3 mm of the exit, and
/// the imbalance loaded the guide's hand (`stroke_m1_thrombectomy`'s seed 1 with the options
/// on: the guide past its strength at 4.808 s; with 10 mm/s at 12.534 s, on a twist).
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

/// Slides smaller than this (m) teach nothing of the part beyond the exit: the force there
/// changes with everything else in the step too.
const LEARNING_SLIDE_M: f64 = 1e-7;

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
    /// instruments: each tip with its hand, or, sliding, by the share of the hand's move the
    /// part beyond its exit lets through (the rest compresses or stretches it), within the
    /// range the instrument around it leaves.
    pub(super) fn place_instruments(&mut self, targets: &[(f64, f64)]) {
        let slides = self.slides();
        for (k, &(l, phi)) in targets.iter().enumerate() {
            self.instruments[k].twist_rad = phi;
            if !slides || k == 0 {
                let instrument = &mut self.instruments[k];
                instrument.hand_m = l;
                instrument.inserted_m = l;
                instrument.lag_m = 0.0;
                continue;
            }
            let cable = self.covered_stiffness_n_m(k);
            let outer = (
                self.instruments[k - 1].inserted_m,
                self.instruments[k - 1].length_m,
            );
            let tip_element = self.settings.tip_element_m;
            let instrument = &mut self.instruments[k];
            let beyond = instrument.slide.beyond_n_m;
            instrument.lag_m += (l - instrument.hand_m) * beyond / (cable + beyond);
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

    /// After a solve: each sliding tip slides by what the first element beyond its exit
    /// carries past its cable's force, over the cable's stiffness and that of the part beyond
    /// (a secant of that force against the tip's placement, from this solve and the last),
    /// at most [`MAX_SLIDE_M_S`]; a tip inside the instruments around it lets its lag
    /// go at that rate. The slide is taken at the next move.
    pub(super) fn relax_slides(&mut self) {
        if !self.slides() {
            return;
        }
        let most = MAX_SLIDE_M_S * self.settings.time_step_s * self.step_fraction;
        let shortest = SHORTEST_HOLD_TIP_ELEMENTS * self.settings.tip_element_m;
        for k in 1..self.instruments.len() {
            let exit = match self.exit_state(k) {
                Exit::Beyond(exit) => exit,
                Exit::Shared(_) => {
                    // No element of its own beyond the exit to measure: the tip holds its
                    // compression, and moves only with its hand.
                    self.instruments[k].slide.last = None;
                    continue;
                }
                Exit::Inside => {
                    let instrument = &mut self.instruments[k];
                    instrument.slide = Default::default();
                    instrument.lag_m -= instrument.lag_m.clamp(-most, most);
                    continue;
                }
            };
            let cable = self.covered_stiffness_n_m(k);
            let held = self.cable_force_n(k);
            let beyond_ea =
                properties_at(&self.instruments[k], self.nodes[exit].sigma).axial_stiffness_n;
            let carried = -self.model.element_axial_force_n(exit);
            let instrument = &mut self.instruments[k];
            let placed = instrument.inserted_m;
            if let Some((before, at)) = instrument.slide.last
                && (placed - at).abs() > LEARNING_SLIDE_M
            {
                instrument.slide.beyond_n_m =
                    ((carried - before) / (placed - at)).clamp(0.0, beyond_ea / shortest);
            }
            instrument.slide.last = Some((carried, placed));
            let excess = carried - held;
            instrument.lag_m += (excess / (cable + instrument.slide.beyond_n_m)).clamp(-most, most);
        }
    }
}
