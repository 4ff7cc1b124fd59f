//! Where a stack's instruments are: points on the strand or an instrument's own chain, the
//! tips, their axes and bend directions, the penetration into the wall, and one instrument
//! as the autopilot steers it ([`InstrumentView`]).

use nalgebra::{UnitQuaternion, Vector3};

use super::state::{Coupling, Stack};
use crate::beam::hermite_point;
use crate::wall::Wall;

/// One instrument of a stack, as the autopilot steers it.
#[derive(Debug, Clone, Copy)]
pub struct InstrumentView<'a, W: Wall> {
    stack: &'a Stack<W>,
    index: usize,
}

impl<W: Wall> crate::autopilot::Steered for InstrumentView<'_, W> {
    fn tip_position(&self) -> Vector3<f64> {
        self.stack
            .tip_position(self.index)
            .unwrap_or(self.stack.entry_position)
    }
    fn tip_axis(&self) -> Vector3<f64> {
        self.stack
            .tip_axis(self.index)
            .unwrap_or_else(|| self.stack.entry_rotation * Vector3::x())
    }
    fn tip_bend_direction(&self) -> Option<Vector3<f64>> {
        self.stack.tip_bend_direction(self.index)
    }
    fn twist_rad(&self) -> f64 {
        self.stack.instruments[self.index].twist_rad
    }
    fn inserted_m(&self) -> f64 {
        self.stack
            .inserted_m(self.index)
            .expect("a view's instrument is in its stack")
    }
}

impl<W: Wall> Stack<W> {
    /// Position (m) and frame of instrument `index` at path coordinate `sigma` (m from the
    /// entry point, clamped to its chain), with the twist (rad) its frames are measured from:
    /// the strand's in merged mode; in nested mode the instrument's own chain, or that of the
    /// innermost instrument around it while it has none.
    fn frame_of(&self, index: usize, sigma: f64) -> ((Vector3<f64>, UnitQuaternion<f64>), f64) {
        match self.coupling {
            Coupling::Merged => (self.point_at(sigma), self.instruments[0].twist_rad),
            Coupling::Nested => {
                let k = (0..=index)
                    .rev()
                    .find(|&k| self.chains.get(k).is_some_and(Option::is_some))
                    .unwrap_or(0);
                (self.chain(k).point_at(sigma), self.instruments[k].twist_rad)
            }
        }
    }

    /// Position (m) and frame of instrument `index` at path coordinate `sigma` (m from the
    /// entry point): on the strand in merged mode, on the instrument's own chain in nested
    /// mode.
    pub fn instrument_point(
        &self,
        index: usize,
        sigma: f64,
    ) -> Option<(Vector3<f64>, UnitQuaternion<f64>)> {
        (index < self.instruments.len()).then(|| self.frame_of(index, sigma).0)
    }

    /// Position of instrument `index`'s tip (m), or `None` while it is withdrawn proximal of
    /// the entry point.
    pub fn tip_position(&self, index: usize) -> Option<Vector3<f64>> {
        let l = self.instruments.get(index)?.inserted_m;
        (l > 0.0).then(|| self.frame_of(index, l).0.0)
    }

    /// Position (m) and frame of the strand at path coordinate `sigma` (m from the entry
    /// point, clamped to the strand), on the smooth curve through the nodes (nested mode: of
    /// the outermost instrument's chain).
    pub fn point_at(&self, sigma: f64) -> (Vector3<f64>, UnitQuaternion<f64>) {
        if self.coupling == Coupling::Nested {
            return self.chain(0).point_at(sigma);
        }
        let positions = self.model.positions();
        let rotations = self.model.rotations();
        let k = self
            .nodes
            .partition_point(|n| n.sigma <= sigma)
            .clamp(1, self.nodes.len() - 1)
            - 1;
        let (a, b) = (self.nodes[k].sigma, self.nodes[k + 1].sigma);
        let f = ((sigma - a) / (b - a)).clamp(0.0, 1.0);
        hermite_point(
            (&positions[k], &rotations[k]),
            (&positions[k + 1], &rotations[k + 1]),
            f,
        )
    }

    /// The largest penetration of the strand into the wall in the current configuration (m;
    /// 0 when nothing penetrates), over the collision points, each catheter's rim with its
    /// own radius where the instrument inside it goes on.
    pub fn max_penetration_m(&self) -> f64 {
        self.penetration(true)
    }

    /// As [`Stack::max_penetration_m`] over each instrument's shaft alone: a catheter's rim
    /// with the radius of the instrument going on.
    pub fn max_shaft_penetration_m(&self) -> f64 {
        self.penetration(false)
    }

    fn penetration(&self, rims: bool) -> f64 {
        if self.coupling == Coupling::Nested {
            return self.nested_max_penetration();
        }
        let positions = self.model.positions();
        self.sample_layout(rims)
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

    /// Unit tangent of instrument `index` where its shaped tip starts (at its tip if it is
    /// straight); `None` while it is withdrawn proximal of the entry.
    pub fn tip_axis(&self, index: usize) -> Option<Vector3<f64>> {
        let instrument = self.instruments.get(index)?;
        let l = instrument.inserted_m;
        if l <= 0.0 {
            return None;
        }
        let start = instrument
            .shaped_from_m
            .map_or(l, |s| l - instrument.length_m + s)
            .clamp(0.0, l);
        Some(self.frame_of(index, start).0.1 * Vector3::x())
    }

    /// Unit world direction instrument `index`'s shaped tip bends to where it starts, across
    /// the strand: its material bending direction turned by its own twist. `None` for a
    /// straight or withdrawn instrument.
    pub fn tip_bend_direction(&self, index: usize) -> Option<Vector3<f64>> {
        let instrument = self.instruments.get(index)?;
        let l = instrument.inserted_m;
        let shaped = instrument.shaped_from_m?;
        if l <= 0.0 {
            return None;
        }
        let kappa = instrument.device.rest_curvature_at(shaped + 1e-9);
        let bend = kappa.cross(&Vector3::x()).try_normalize(1e-12)?;
        let start = (l - instrument.length_m + shaped).clamp(0.0, l);
        let ((_, q), reference) = self.frame_of(index, start);
        let relative =
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), instrument.twist_rad - reference);
        let tangent = q * Vector3::x();
        let side = q * (relative * bend);
        (side - tangent * tangent.dot(&side)).try_normalize(1e-12)
    }

    /// One instrument as the autopilot sees it.
    pub fn instrument(&self, index: usize) -> Option<InstrumentView<'_, W>> {
        (index < self.instruments.len()).then_some(InstrumentView { stack: self, index })
    }
}
