//! What the world shows: the snapshot for clients and the renderer (patient LPS, every
//! instrument), the wall contacts of the last step, and the digest of the whole simulated
//! state that replays compare.

use nalgebra::{Point3, Vector3};

use super::World;
use super::snapshot::{InstrumentState, Snapshot, WallContact};

impl World {
    /// The wall contacts of the last step in the anatomy's frame: where on the device
    /// centerline (m) and the force's magnitude (N); forceless contacts left out.
    pub fn wall_contacts(&self) -> Vec<(Point3<f64>, f64)> {
        self.contact_forces()
            .into_iter()
            .map(|(p, f)| (Point3::from(p), f.norm()))
            .collect()
    }

    /// The last step's wall contacts with a force, in the anatomy's frame: the point on the
    /// device centerline (m) and the wall's force on the device (N).
    fn contact_forces(&self) -> Vec<(Vector3<f64>, Vector3<f64>)> {
        let Some(step) = self.strand.last_contacts() else {
            return Vec::new();
        };
        let positions = self.strand.model().positions();
        step.contacts
            .iter()
            .zip(&step.response.forces)
            .filter(|(_, f)| f.norm() > 0.0)
            .filter_map(|(c, f)| {
                let a = positions.get(c.element)?;
                let b = positions.get(c.element + 1)?;
                Some((a + (b - a) * c.t, *f))
            })
            .collect()
    }

    /// The world now, for clients and the renderer (LPS).
    pub fn snapshot(&self) -> Snapshot {
        let to_lps = self.assets.to_lps;
        let model = self.strand.model();
        let positions = model.positions();
        let nodes: Vec<Vector3<f64>> = positions.iter().map(|p| to_lps * p).collect();
        let tip_direction = model
            .rotations()
            .last()
            .map(|q| to_lps * (q * Vector3::x()))
            .unwrap_or_else(Vector3::x);
        let contacts = match self.strand.last_contacts() {
            Some(_) => self
                .contact_forces()
                .into_iter()
                .map(|(p, f)| WallContact {
                    position: to_lps * p,
                    force: to_lps * f,
                })
                .collect(),
            None => Vec::new(),
        };
        let p = &self.proximal;
        let force = to_lps * Vector3::new(p[0], p[1], p[2]);
        let moment = to_lps * Vector3::new(p[3], p[4], p[5]);
        let instruments: Vec<InstrumentState> = self
            .hands
            .iter()
            .enumerate()
            .map(|(i, hand)| InstrumentState {
                name: self
                    .strand
                    .device(i)
                    .map_or_else(String::new, |d| d.name.clone()),
                catalogue_id: hand.catalogue_id.clone(),
                nodes: self.strand.polyline(i).iter().map(|p| to_lps * p).collect(),
                inserted_m: self.strand.inserted_m(i),
                twist_rad: self.strand.twist_rad(i),
                tip: self.strand.tip_position(i).map(|p| to_lps * p),
                axial_force_n: hand.reaction.axial_force_n,
                torque_nm: hand.reaction.torque_nm,
                push_limit: hand.push_limit,
                push_force_limit_n: hand.limits.force_n,
                look: hand.look.clone(),
            })
            .collect();
        let innermost = self.hands.len() - 1;
        Snapshot {
            step: self.step,
            time_s: self.metrics.procedure_time_s,
            last_seq: self.last_seq,
            nodes,
            tip_direction,
            inserted_m: self.strand.inserted_m(innermost),
            twist_rad: self.strand.twist_rad(innermost),
            contacts,
            proximal: [force.x, force.y, force.z, moment.x, moment.y, moment.z],
            active_device: self.active_device as u32,
            imaging: self.imaging,
            contrast: self
                .hemo
                .as_ref()
                .map(|h| h.tubes.clone())
                .unwrap_or_default(),
            metrics: self.metrics,
            push_limit: self.hands[innermost].push_limit,
            push_force_limit_n: self.hands[innermost].limits.force_n,
            fidelity_level: self.fidelity,
            instruments,
        }
    }

    /// A 64-bit digest of the whole simulated state (positions, frames, material points,
    /// controls, contrast, imaging, metrics): equal digests mean bit-identical states.
    pub fn digest(&self) -> u64 {
        let mut h = Fnv1a::default();
        h.u64(self.step);
        h.u64(self.last_seq);
        h.u64(self.active_device as u64);
        self.strand.digest_into(|values| h.f64s(values));
        h.f64s(&self.proximal);
        for hand in &self.hands {
            h.f64s(&[hand.reaction.axial_force_n, hand.reaction.torque_nm]);
            h.u64(hand.catalogue_id.len() as u64);
        }
        if let Some(hemo) = &self.hemo {
            h.f64s(&[
                hemo.linked_at_s.unwrap_or(-1.0),
                hemo.program.0,
                hemo.program.1,
            ]);
            for v in 0..hemo.solver.network().vessels.len() {
                h.f64s(hemo.contrast.concentration(v));
            }
        }
        let i = &self.imaging;
        h.u64(i.pedal as u64 | (i.dsa_run as u64) << 8);
        h.f64s(&[i.primary_deg, i.secondary_deg]);
        let m = &self.metrics;
        h.f64s(&[
            m.procedure_time_s,
            m.fluoroscopy_time_s,
            m.contrast_volume_ml,
            m.max_wall_force_n,
            m.wall_force_sum_n,
            m.tip_path_length_m,
            m.target_reached_at_s.unwrap_or(-1.0),
            m.attempt_started_at_s,
        ]);
        h.u64(m.divergence_resets as u64 | (m.operator_resets as u64) << 32);
        h.finish()
    }
}

/// FNV-1a over the bytes of integers and floats (bit patterns, so −0 ≠ +0 and NaNs count).
#[derive(Debug, Clone, Copy)]
struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv1a {
    fn u64(&mut self, v: u64) {
        for b in v.to_le_bytes() {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }
    fn f64s(&mut self, values: &[f64]) {
        for v in values {
            self.u64(v.to_bits());
        }
    }
    fn finish(self) -> u64 {
        self.0
    }
}
