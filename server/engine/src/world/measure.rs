//! What a step did, measured after the physics: the clock, the wall forces, the tracked tip's
//! path and the target, the reactions each hand feels, and the per-instrument and stack
//! figures.

use nalgebra::{Point3, Vector3};

use super::World;
use super::tips::tracked_tip;
use crate::metrics::EventKind;

impl World {
    /// The step counted: steps, procedure time and fluoroscopy time (s).
    pub(super) fn advance_clock(&mut self, dt: f64) {
        self.step += 1;
        self.metrics.steps = self.step;
        self.metrics.procedure_time_s = self.step as f64 * dt;
        if self.imaging.pedal {
            self.metrics.fluoroscopy_time_s += dt;
        }
    }

    /// The largest and the summed wall force of the step's contacts (N).
    pub(super) fn measure_wall_forces(&mut self) {
        if let Some(contacts) = self.strand.last_contacts() {
            let mut largest: f64 = 0.0;
            let mut total = 0.0;
            for f in &contacts.response.forces {
                let n = f.norm();
                largest = largest.max(n);
                total += n;
            }
            self.metrics.add_wall_forces(largest, total);
        }
    }

    /// The tracked tip's path, its distance left to the target, and whether it reached the
    /// target (reported once).
    pub(super) fn track_target(&mut self) {
        let tip = tracked_tip(&self.assets, &self.strand);
        self.metrics.tip_path_length_m += (tip - self.previous_tip).norm();
        self.previous_tip = tip;
        self.metrics.target_remaining_m = self.assets.remaining_to_target_m(&Point3::from(tip));
        if self.metrics.target_reached_at_s.is_none() {
            let graph = &self.assets.anatomy.graph;
            if let Some(location) = graph.nearest(&Point3::from(tip))
                && location.branch == self.assets.target_branch
                && location.arc_length >= self.assets.spec.target.reach_mm * 1e-3
            {
                self.metrics.target_reached_at_s = Some(self.metrics.procedure_time_s);
                let name = self.assets.spec.target.branch.clone();
                let who = match self.assets.spec.target.instrument {
                    Some(i) if !self.assets.spec.stack.is_empty() => self
                        .strand
                        .device(i)
                        .map_or_else(|| "tip".to_owned(), |d| format!("{}'s tip", d.name)),
                    _ => "tip".to_owned(),
                };
                self.event(
                    EventKind::TargetReached,
                    format!("the {who} reached {name}"),
                );
            }
        }
    }

    /// What the hands feel after the step: the proximal wrench and each hand's reaction.
    pub(super) fn feel_reactions(&mut self) {
        let (wrench, reactions) = self.strand.reactions();
        self.proximal = wrench;
        for (hand, reaction) in self.hands.iter_mut().zip(reactions) {
            hand.reaction = reaction;
        }
    }

    /// Per-instrument and stack metrics after a step.
    pub(super) fn instrument_metrics(&mut self, dt: f64) {
        let n = self.strand.len().min(crate::metrics::MAX_INSTRUMENTS);
        let now: Vec<(Option<Vector3<f64>>, f64)> = (0..n)
            .map(|i| (self.strand.tip_position(i), self.strand.inserted_m(i)))
            .collect();
        // A restart or an exchange of the stack's shape starts the comparison afresh.
        let comparable = self.previous_instruments.len() == n;
        let m = &mut self.metrics;
        m.instrument_count = n as u8;
        for (i, (tip, inserted)) in now.iter().enumerate() {
            let figures = &mut m.instruments[i];
            figures.peak_axial_force_n = figures
                .peak_axial_force_n
                .max(self.hands[i].reaction.axial_force_n.abs());
            figures.peak_torque_nm = figures
                .peak_torque_nm
                .max(self.hands[i].reaction.torque_nm.abs());
            if !comparable {
                continue;
            }
            let (before_tip, before) = self.previous_instruments[i];
            if let (Some(a), Some(b)) = (before_tip, tip) {
                figures.tip_path_length_m += (b - a).norm();
            }
            if (inserted - before).abs() > 1e-9 {
                figures.moving_time_s += dt;
            }
        }
        let leading = self.strand.leading().min(n.saturating_sub(1)) as u8;
        if comparable && leading != m.leading_instrument {
            m.lead_changes += 1;
        }
        m.leading_instrument = leading;
        let mut passed = Vec::new();
        if comparable {
            for k in 1..n {
                let (_, inner_before) = self.previous_instruments[k];
                let (_, outer_before) = self.previous_instruments[k - 1];
                let (inner, outer) = (now[k].1, now[k - 1].1);
                // The inner one led beyond the entry; the outer one advanced past its tip.
                if inner_before > outer_before
                    && inner_before > 0.0
                    && outer >= inner
                    && outer > outer_before
                {
                    m.passed_inner_tip += 1;
                    passed.push(k);
                }
            }
        }
        self.previous_instruments = now;
        for k in passed {
            let name = |i: usize| {
                self.strand
                    .device(i)
                    .map_or_else(|| format!("instrument {i}"), |d| d.name.clone())
            };
            let message = format!(
                "the {} passed the tip of the {}: it no longer follows it",
                name(k - 1),
                name(k)
            );
            self.event(EventKind::Limit, message);
        }
    }
}
