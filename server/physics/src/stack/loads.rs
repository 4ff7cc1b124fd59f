//! Loads at the ends of a stack's instruments: the push and twist each hand feels (its share
//! of the strand's base reaction), and axial loads on the tips (a clot resisting a crossing
//! tip).

use nalgebra::Vector3;

use super::instrument::properties_at;
use super::state::{Coupling, Stack};
use crate::error::{PhysicsError, Result, require_finite};
use crate::section::BeamProperties;
use crate::wall::Wall;

/// The push and twist an instrument's hand feels: the share of the strand's base reaction
/// carried by that instrument.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProximalReaction {
    /// Force the hand applies along the entry axis (N): positive pushing in.
    pub axial_force_n: f64,
    /// Torque the hand applies about the entry axis (N·m), right-handed about the direction
    /// of insertion.
    pub torque_nm: f64,
}

impl<W: Wall> Stack<W> {
    /// What each instrument's hand feels (outermost first): the strand's base reaction along
    /// and about the entry axis, shared among the instruments at the entry in proportion to
    /// their axial (force) and torsional (torque) stiffness; in nested mode each instrument's
    /// own chain's base reaction. Instruments withdrawn proximal of the entry feel nothing.
    /// With [`NavigationSettings::axial_slide`](crate::navigation::NavigationSettings) an
    /// inner instrument's hand feels the force it carries inside the ones around it
    /// (`stack/slide.rs`) and the outermost's the strand's base force.
    pub fn proximal_reactions(&mut self) -> Vec<ProximalReaction> {
        if self.coupling == Coupling::Nested {
            return self.nested_proximal_reactions();
        }
        let wrench = self.model.base_reaction();
        let axis = self.model.rotations()[0] * Vector3::x();
        let force = wrench.fixed_rows::<3>(0).dot(&axis);
        let torque = wrench.fixed_rows::<3>(3).dot(&axis);
        let sigma = 0.5 * self.nodes[1].sigma;
        let present: Vec<Option<BeamProperties>> = self
            .instruments
            .iter()
            .map(|i| (i.inserted_m > sigma).then(|| properties_at(i, sigma)))
            .collect();
        let ea: f64 = present.iter().flatten().map(|p| p.axial_stiffness_n).sum();
        let gj: f64 = present
            .iter()
            .flatten()
            .map(|p| p.torsional_stiffness_nm2)
            .sum();
        let sliding = self.slides();
        present
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let torque_nm = p.map_or(0.0, |p| torque * p.torsional_stiffness_nm2 / gj);
                let axial_force_n = if sliding {
                    // The strand's base carries the outermost instrument's own force; each
                    // inner one's is its cable's, held by its hand alone.
                    if k == 0 { force } else { self.slide_force_n(k) }
                } else {
                    p.map_or(0.0, |p| force * p.axial_stiffness_n / ea)
                };
                ProximalReaction {
                    axial_force_n,
                    torque_nm,
                }
            })
            .collect()
    }

    /// Sets an axial load (N) on instrument `index`'s tip, along its tangent (positive
    /// forward, negative resisting its advance), applied every step until set again: the
    /// resistance of a clot the tip is crossing. Merged coupling only (a nested stack is a
    /// typed error); on a withdrawn tip it waits.
    pub fn set_tip_load(&mut self, index: usize, axial_n: f64) -> Result<()> {
        self.check_index(index)?;
        require_finite(|| format!("tip load of instrument {index}"), axial_n)?;
        if self.coupling == Coupling::Nested && axial_n != 0.0 {
            return Err(PhysicsError::Stack(
                "tip loads are applied in merged coupling only".into(),
            ));
        }
        if self.instruments[index].tip_load_n != axial_n {
            self.stillness.wake();
        }
        self.instruments[index].tip_load_n = axial_n;
        Ok(())
    }

    /// The axial tip load of instrument `index` (N), as set.
    pub fn tip_load_n(&self, index: usize) -> Option<f64> {
        self.instruments.get(index).map(|i| i.tip_load_n)
    }

    /// Index of the node at instrument `k`'s tip in the merged strand: its key node inside
    /// the strand, the last node when it leads; `None` while withdrawn.
    fn tip_node_index(&self, k: usize) -> Option<usize> {
        let instrument = &self.instruments[k];
        match instrument.tip_node {
            Some(id) => self.nodes.iter().position(|n| n.id == id),
            None => {
                let last = self.nodes.len() - 1;
                let snap = 0.5 * self.settings.sample_spacing_m;
                (instrument.inserted_m > snap
                    && instrument.inserted_m >= self.nodes[last].sigma - snap)
                    .then_some(last)
            }
        }
    }

    /// Puts the instruments' tip loads and the sliding instruments' loads
    /// (`stack/slide.rs`) on the merged model (after it is rebuilt).
    pub(super) fn apply_tip_loads(&mut self) -> Result<()> {
        if self.instruments.iter().all(|i| i.tip_load_n == 0.0)
            && !self.tip_loaded
            && !self.slides()
        {
            return Ok(());
        }
        let mut loads = self.slide_loads();
        for k in 0..self.instruments.len() {
            let load = self.instruments[k].tip_load_n;
            if load == 0.0 {
                continue;
            }
            if let Some(i) = self.tip_node_index(k) {
                loads[i] += self.nodes[i].rotation * Vector3::x() * load;
            }
        }
        self.model.clear_loads();
        self.tip_loaded = false;
        for (i, load) in loads.iter().enumerate() {
            if *load != Vector3::zeros() {
                self.model.set_load(i, *load, Vector3::zeros())?;
                self.tip_loaded = true;
            }
        }
        Ok(())
    }
}
