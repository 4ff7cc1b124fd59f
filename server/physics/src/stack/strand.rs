//! Merged mode's strand between solves: nodes that stay on the path as instruments slide
//! through them, tips as nodes, the leader's free shaped part carried rigidly, refinement and
//! coarsening, and the beam model rebuilt on the nodes (unchanged elements reused).

use std::collections::HashMap;

use nalgebra::{UnitQuaternion, Vector3};

use super::composite::{composite_spec, nominal_spacing, same_spec};
use super::instrument::leader;
use super::state::{MIN_GAP_FRACTION, Node, SHARED_TIP_FRACTION, Stack};
use crate::beam::{ElementSpec, hermite_point};
use crate::error::{PhysicsError, Result};
use crate::navigation::solver_settings;
use crate::wall::Wall;

impl<W: Wall> Stack<W> {
    /// Copies the model's node poses into the node list.
    pub(super) fn sync_nodes(&mut self) {
        for ((node, p), q) in self
            .nodes
            .iter_mut()
            .zip(self.model.positions())
            .zip(self.model.rotations())
        {
            node.position = *p;
            node.rotation = *q;
        }
    }

    /// The kinematic predictor: moves the instruments to `targets` and the nodes with them.
    /// The leading instrument's free shaped part is carried rigidly along the tangent where it
    /// starts (the rest of the strand stays on its path: instruments slide through it); a
    /// new leading tip extends the strand along its tip tangent; a retreating one retraces
    /// its path. Tips inside the strand slide along the curve.
    pub(super) fn move_instruments(&mut self, targets: &[(f64, f64)]) -> Result<()> {
        self.carry_beyond_exits(targets);
        let old_end = self.nodes.last().map_or(0.0, |n| n.sigma);
        let old_leader = leader(&self.instruments);
        let old: Vec<f64> = self.instruments.iter().map(|i| i.inserted_m).collect();
        self.place_instruments(targets);
        let new_leader = leader(&self.instruments);
        let new_end = self.instruments[new_leader].inserted_m;
        let others_old = (0..old.len())
            .filter(|&j| j != old_leader)
            .map(|j| old[j])
            .fold(0.0, f64::max);
        let others_new = (0..old.len())
            .filter(|&j| j != new_leader)
            .map(|j| self.instruments[j].inserted_m)
            .fold(0.0, f64::max);
        let delta = new_end - old_end;
        let min_gap = MIN_GAP_FRACTION * self.settings.tip_element_m;
        let snap = SHARED_TIP_FRACTION * self.settings.tip_element_m;
        if delta != 0.0 {
            let lead = &self.instruments[old_leader];
            let shaped_start = lead
                .shaped_from_m
                .map_or(old_end, |s| old[old_leader] - lead.length_m + s);
            let carry_from = shaped_start.max(others_old);
            let carry = new_leader == old_leader
                && (delta > 0.0 || carry_from + delta >= others_new + min_gap);
            if carry {
                // First node strictly beyond every other tip and at or beyond the shaped part.
                let last = self.nodes.len() - 1;
                let c = self
                    .nodes
                    .iter()
                    .position(|n| n.sigma > others_old + snap && n.sigma >= carry_from)
                    .unwrap_or(last)
                    .clamp(1, last);
                let tangent = self.nodes[c].rotation * Vector3::x();
                for node in &mut self.nodes[c..] {
                    node.sigma += delta;
                    node.position += tangent * delta;
                }
                if delta < 0.0 {
                    // Path nodes overrun by the retreating carried part.
                    let start = self.nodes[c].sigma;
                    let mut k = c - 1;
                    while k > 0 && self.nodes[k].sigma > start - min_gap {
                        self.nodes.remove(k);
                        k -= 1;
                    }
                }
            } else if delta > 0.0 {
                // A new leader emerges: extend along the tip tangent (moving the end node while
                // the extension is shorter than the smallest gap).
                let tip = *self.nodes.last().expect("a strand has nodes");
                let tangent = tip.rotation * Vector3::x();
                let node = Node {
                    sigma: new_end,
                    id: tip.id,
                    position: tip.position + tangent * delta,
                    rotation: tip.rotation,
                };
                if delta < min_gap && self.nodes.len() > 2 {
                    *self.nodes.last_mut().expect("a strand has nodes") = node;
                } else {
                    let id = self.fresh_id();
                    self.nodes.push(Node { id, ..node });
                }
            } else {
                // The strand retreats along its own path.
                let (position, rotation) = self.curve_at(new_end);
                while self.nodes.len() > 1
                    && self.nodes[self.nodes.len() - 1].sigma > new_end - min_gap
                {
                    self.nodes.pop();
                }
                let id = self.fresh_id();
                self.nodes.push(Node {
                    sigma: new_end,
                    id,
                    position,
                    rotation,
                });
            }
        }
        if let Some(last) = self.nodes.last_mut() {
            last.sigma = new_end;
        }
        // Tips inside the strand: key nodes sliding along the curve.
        for j in 0..self.instruments.len() {
            let l = self.instruments[j].inserted_m;
            let inside = l > snap && l < new_end - snap;
            let current = self.instruments[j]
                .tip_node
                .and_then(|id| self.nodes.iter().position(|n| n.id == id));
            if !inside {
                self.instruments[j].tip_node = None;
                continue;
            }
            if let Some(k) = current
                && (self.nodes[k].sigma - l).abs() <= snap
                && (self.nodes[k].sigma == l || self.is_tip_node(self.nodes[k].id, j))
            {
                continue;
            }
            // Another tip already near this point: share its node.
            if let Some(shared) = self
                .nodes
                .iter()
                .find(|n| (n.sigma - l).abs() <= snap && self.is_tip_node(n.id, j))
            {
                self.instruments[j].tip_node = Some(shared.id);
                continue;
            }
            let (position, rotation) = self.curve_at(l);
            let id = match current {
                Some(k) if !self.is_tip_node(self.nodes[k].id, j) => self.nodes.remove(k).id,
                _ => self.fresh_id(),
            };
            // Ordinary nodes too close to the tip give way to it.
            let keys = self.key_ids();
            let last = self.nodes.len() - 1;
            let mut k = 1;
            while k < last.min(self.nodes.len() - 1) {
                let n = self.nodes[k];
                if (n.sigma - l).abs() < min_gap && !keys.contains(&n.id) {
                    self.nodes.remove(k);
                } else {
                    k += 1;
                }
            }
            let at = self.nodes.partition_point(|n| n.sigma < l);
            self.nodes.insert(
                at,
                Node {
                    sigma: l,
                    id,
                    position,
                    rotation,
                },
            );
            self.instruments[j].tip_node = Some(id);
        }
        if self.nodes.len() < 2 || self.nodes.windows(2).any(|w| w[1].sigma <= w[0].sigma) {
            return Err(PhysicsError::Stack(format!(
                "node layout lost its order at t = {:.4} s (inserted lengths {:?})",
                self.time_s,
                self.instruments
                    .iter()
                    .map(|i| i.inserted_m)
                    .collect::<Vec<_>>()
            )));
        }
        Ok(())
    }

    /// Whether node `id` is the tip node of an instrument other than `except`.
    fn is_tip_node(&self, id: u64, except: usize) -> bool {
        self.instruments
            .iter()
            .enumerate()
            .any(|(k, i)| k != except && i.tip_node == Some(id))
    }

    /// Identifiers of every tip node.
    fn key_ids(&self) -> Vec<u64> {
        self.instruments.iter().filter_map(|i| i.tip_node).collect()
    }

    fn fresh_id(&mut self) -> u64 {
        self.next_id += 1;
        self.next_id - 1
    }

    /// The smooth curve through the current nodes at path coordinate `sigma` (clamped).
    fn curve_at(&self, sigma: f64) -> (Vector3<f64>, UnitQuaternion<f64>) {
        curve_through(&self.nodes, sigma)
    }

    /// Splits elements longer than 1.5 nominal spacings, or bending more than the refinement
    /// angle, or touching the wall while longer than the contact element (not below the tip
    /// element length); removes ordinary nodes whose two elements together are shorter than
    /// 1.25 nominal spacings, bend little and touch nothing.
    pub(super) fn refine(&mut self) {
        let shortest = self.settings.tip_element_m;
        let refinement = self.settings.refinement.map(|r| self.effort.refinement(r));
        let active: Vec<f64> = self
            .previous_contacts
            .iter()
            .filter(|(_, force)| force.x > 0.0)
            .map(|(sigma, _)| *sigma)
            .collect();
        let touching = |a: f64, b: f64| active.iter().any(|&s| s >= a && s <= b);
        let bend =
            |a: &Node, b: &Node| (a.rotation * Vector3::x()).angle(&(b.rotation * Vector3::x()));
        let mut k = self.nodes.len() - 1;
        while k > 0 {
            let (a, b) = (self.nodes[k - 1], self.nodes[k]);
            let long = b.sigma - a.sigma;
            let h = nominal_spacing(&self.settings, &self.instruments, 0.5 * (a.sigma + b.sigma));
            let refine = refinement.is_some_and(|r| {
                long >= 2.0 * shortest
                    && (bend(&a, &b) > r.max_bend_rad
                        || (long > r.contact_element_m && touching(a.sigma, b.sigma)))
            });
            if long > 1.5 * h || refine {
                let (position, rotation) =
                    hermite_point((&a.position, &a.rotation), (&b.position, &b.rotation), 0.5);
                let id = self.fresh_id();
                self.nodes.insert(
                    k,
                    Node {
                        sigma: 0.5 * (a.sigma + b.sigma),
                        id,
                        position,
                        rotation,
                    },
                );
            }
            k -= 1;
        }
        let keys = self.key_ids();
        let max_bend = refinement.map_or(f64::INFINITY, |r| r.max_bend_rad);
        let min_gap = MIN_GAP_FRACTION * shortest;
        let mut k = 1;
        while k + 1 < self.nodes.len() {
            let (a, n, b) = (self.nodes[k - 1], self.nodes[k], self.nodes[k + 1]);
            let h = nominal_spacing(&self.settings, &self.instruments, n.sigma);
            let crowded = n.sigma - a.sigma < min_gap || b.sigma - n.sigma < min_gap;
            if !keys.contains(&n.id)
                && (crowded
                    || (b.sigma - a.sigma < 1.25 * h
                        && bend(&a, &n) + bend(&n, &b) < max_bend / 3.0
                        && !touching(a.sigma, b.sigma)))
            {
                self.nodes.remove(k);
            } else {
                k += 1;
            }
        }
    }

    /// Rebuilds the beam model on the current nodes, reusing every element whose two nodes
    /// and rest geometry are unchanged.
    pub(super) fn rebuild_model(&mut self) -> Result<()> {
        let old: HashMap<(u64, u64), usize> = self
            .specs
            .iter()
            .enumerate()
            .map(|(e, (_, a, b))| ((*a, *b), e))
            .collect();
        let mut specs = Vec::with_capacity(self.nodes.len() - 1);
        let mut keep = Vec::with_capacity(self.nodes.len() - 1);
        for w in self.nodes.windows(2) {
            let spec = composite_spec(
                &self.instruments,
                w[0].sigma,
                w[1].sigma,
                self.settings.axial_slide,
            );
            let kept = old
                .get(&(w[0].id, w[1].id))
                .copied()
                .filter(|&e| same_spec(&self.specs[e].0, &spec));
            keep.push(kept);
            specs.push((spec, w[0].id, w[1].id));
        }
        let positions: Vec<Vector3<f64>> = self.nodes.iter().map(|n| n.position).collect();
        let rotations: Vec<UnitQuaternion<f64>> = self.nodes.iter().map(|n| n.rotation).collect();
        let plain: Vec<ElementSpec> = specs.iter().map(|s| s.0).collect();
        self.model.remesh(&plain, &keep, &positions, &rotations)?;
        self.model
            .set_settings(solver_settings(&self.settings, self.step_fraction));
        self.specs = specs;
        Ok(())
    }
}

/// The smooth curve through `nodes` (ordered by path coordinate) at path coordinate `sigma`
/// (m, clamped to the strand): Hermite between the two nodes around it.
pub(super) fn curve_through(nodes: &[Node], sigma: f64) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let k = nodes
        .partition_point(|n| n.sigma <= sigma)
        .clamp(1, nodes.len() - 1)
        - 1;
    let (a, b) = (&nodes[k], &nodes[k + 1]);
    let f = ((sigma - a.sigma) / (b.sigma - a.sigma)).clamp(0.0, 1.0);
    hermite_point((&a.position, &a.rotation), (&b.position, &b.rotation), f)
}
