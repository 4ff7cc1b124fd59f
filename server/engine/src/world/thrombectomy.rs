//! The thrombectomy stage of a step, in a clotted scene with flow: the instruments seen on
//! the route (kind, stent, tip, bore, hand force), the procedure stepped (crossings, stent
//! and aspiration passes, emboli), the clots' resistance loaded on the tips crossing them,
//! the figures into the metrics, and the flow re-solved when the clots change.

use cathlab_physics::Insertion;
use nalgebra::Point3;

use super::World;
use super::command::Drive;
use crate::assets::ROUTE_SPACING_M;
use crate::error::Result;
use crate::metrics::{EventKind, ThrombectomyMetric};
use crate::thrombectomy::{InstrumentView, route_arc};

impl World {
    /// Steps the thrombectomy: instruments on the route, passes, clots into the flow.
    pub(super) fn step_procedure(&mut self, dt: f64) -> Result<()> {
        let (Some(procedure), Some(hemo)) = (&mut self.procedure, &self.hemo) else {
            return Ok(());
        };
        let catalogue = crate::scene::catalogue();
        let assets = &self.assets;
        let views: Vec<InstrumentView> = (0..self.strand.len())
            .map(|i| {
                let entry = catalogue.get(&self.hands[i].catalogue_id);
                let tip = self.strand.tip_position(i).map_or(0.0, |t| {
                    route_arc(&assets.route_samples, ROUTE_SPACING_M, &Point3::from(t))
                });
                let section = self
                    .strand
                    .device(i)
                    .and_then(|d| d.sections.last())
                    .map(|s| s.cross_section);
                InstrumentView {
                    kind: entry.map(|e| e.kind),
                    stent: entry.and_then(|e| e.stent),
                    tip_arc_m: tip,
                    inserted_m: self.strand.inserted_m(i),
                    outer_diameter_m: section.map_or(0.0, |c| 2.0 * c.outer_radius_m),
                    bore_m: section.map_or(0.0, |c| 2.0 * c.inner_radius_m),
                    axial_force_n: self.hands[i].reaction.axial_force_n,
                }
            })
            .collect();
        let outcome = procedure.step(
            &views,
            dt,
            &assets.route_samples,
            &assets.route_radii,
            ROUTE_SPACING_M,
            hemo.solver.network(),
            &hemo.flow_now,
            &hemo.open_flow,
        );
        // The clot's resistance on the tips crossing it, for the next step (a one-device
        // scene records the crossing but does not load its beam).
        if self.strand.stack().is_some() {
            for (k, &load) in procedure.tip_loads().iter().enumerate() {
                self.strand.set_tip_load(k, load)?;
            }
        }
        let figures = procedure.figures();
        self.metrics.thrombectomy = Some(ThrombectomyMetric {
            passes: figures.passes,
            first_pass_effect: figures.first_pass_effect,
            emboli: figures.emboli,
            crossing_force_n: figures.crossing_force_n,
            peak_crossing_force_n: figures.peak_crossing_force_n,
            grip_n: figures.grip_n,
            aspiration: procedure.aspiration(),
            reperfused_at_s: self.metrics.thrombectomy.and_then(|t| t.reperfused_at_s),
        });
        for message in outcome.messages {
            self.event(EventKind::Thrombectomy, message);
        }
        if outcome.pass_ended {
            for i in 0..self.strand.len() {
                if matches!(self.strand.command(i).insertion, Insertion::Velocity(v) if v < 0.0) {
                    self.drive(i, Drive::PushVelocity(0.0))?;
                }
            }
        }
        if let Some(occlusions) = outcome.occlusions {
            self.replace_clots(&occlusions, false)?;
        }
        if let (Some(t), Some(r)) = (&mut self.metrics.thrombectomy, &self.metrics.reperfusion)
            && t.reperfused_at_s.is_none()
            && r.etici.successful()
        {
            t.reperfused_at_s = Some(self.metrics.procedure_time_s);
        }
        Ok(())
    }
}
