//! The flow and contrast stage of a step: the injector linked to a DSA run fired when due,
//! the injected volume counted, the contrast advected every few steps while any moves and
//! drawn as tubes (LPS); the flow re-solved for an injection at the tip or new clots, and the
//! reperfusion graded.

use std::sync::Arc;

use cathlab_hemo::Injection;
use cathlab_hemo::reperfusion::occluded_territory;
use cathlab_xray::ContrastTube;
use nalgebra::Point3;

use super::World;
use super::hemo::{CONTRAST_DRAW_THRESHOLD, reperfusion_metric};
use super::tips::injection_tip;
use crate::error::{EngineError, Result};
use crate::metrics::EventKind;

impl World {
    /// Advances the contrast by `dt` (s): fires a linked injection that is due, counts the
    /// injected volume, moves the contrast every `contrast_every_steps` while any moves.
    pub(super) fn step_contrast(&mut self, dt: f64) -> Result<()> {
        self.fire_linked_injection()?;
        let every = self.assets.spec.fidelity.contrast_every_steps;
        let to_lps = self.assets.to_lps;
        let Some(hemo) = &mut self.hemo else {
            return Ok(());
        };
        // Injected volume counts every step; the flow changes when the bolus is done.
        let mut finished = false;
        if let Some((left, rate)) = &mut hemo.injection {
            let dv = (*rate * dt).min(*left);
            *left -= dv;
            self.metrics.contrast_volume_ml += dv * 1e6;
            finished = *left <= 0.0;
        }
        // Steps count only while contrast moves: the first sub-step after an idle spell
        // spans one period, not the whole spell (which broke the CFL limit after minutes).
        if hemo.active {
            hemo.steps_since_contrast += 1;
        } else {
            hemo.steps_since_contrast = 0;
        }
        if hemo.active && hemo.steps_since_contrast >= every {
            let span = hemo.steps_since_contrast as f64 * dt;
            hemo.steps_since_contrast = 0;
            hemo.contrast.step(span)?;
            let network = hemo.solver.network();
            let tubes: Vec<ContrastTube> = hemo
                .contrast
                .segments(network, CONTRAST_DRAW_THRESHOLD)
                .into_iter()
                .map(|s| ContrastTube {
                    start: Point3::from(to_lps * s.start.coords),
                    end: Point3::from(to_lps * s.end.coords),
                    start_radius_m: s.start_radius,
                    end_radius_m: s.end_radius,
                    concentration_mg_per_ml: s.concentration,
                })
                .collect();
            hemo.active = hemo.injection.is_some() || !tubes.is_empty();
            hemo.tubes = Arc::new(tubes);
        }
        if finished {
            hemo.injection = None;
            self.update_injection()?;
        }
        Ok(())
    }

    /// Fires the injector linked to the DSA run when its time has come.
    fn fire_linked_injection(&mut self) -> Result<()> {
        let now = self.metrics.procedure_time_s;
        let Some(hemo) = &mut self.hemo else {
            return Ok(());
        };
        if hemo.linked_at_s.is_none_or(|at| now < at) {
            return Ok(());
        }
        hemo.linked_at_s = None;
        let (volume_ml, rate_ml_s) = hemo.program;
        hemo.injection = Some((volume_ml * 1e-6, rate_ml_s * 1e-6));
        match self.update_injection() {
            Ok(()) => self.event(
                EventKind::Contrast,
                format!("injector linked to the DSA run: {volume_ml:.1} mL at {rate_ml_s:.1} mL/s"),
            ),
            Err(e) => {
                if let Some(hemo) = &mut self.hemo {
                    hemo.injection = None;
                }
                self.event(
                    EventKind::Contrast,
                    format!("linked injection not given: {e}"),
                );
            }
        }
        Ok(())
    }

    /// Replaces the clots in the flow (vessel i = graph branch i; an empty slice reopens
    /// every vessel) and re-solves the flow that carries the contrast.
    pub fn set_clots(&mut self, clots: &[cathlab_hemo::Occlusion]) -> Result<()> {
        self.replace_clots(clots, true)
    }

    /// As [`World::set_clots`]; with `new_territory` false the territory whose reperfusion
    /// is graded stays the scene's (emboli and bypass channels do not redefine it).
    pub(super) fn replace_clots(
        &mut self,
        clots: &[cathlab_hemo::Occlusion],
        new_territory: bool,
    ) -> Result<()> {
        let Some(hemo) = &mut self.hemo else {
            return Err(EngineError::FailedPrecondition(
                "the scene has no flow for clots to act on".into(),
            ));
        };
        hemo.solver.set_occlusions(clots)?;
        let now = hemo.solver.solve(None)?;
        hemo.flow_now = now.clone();
        // Graded on the network without collaterals, when the scene has them.
        let (open, now) = match &mut hemo.grading {
            None => (hemo.open_flow.clone(), now),
            Some((g, open)) => {
                g.set_occlusions(clots)?;
                (open.clone(), g.solve(None)?)
            }
        };
        if new_territory && !clots.is_empty() {
            // New clots cut off their own territory; removing them keeps the old one, whose
            // reperfusion is then measured.
            let cut = occluded_territory(&open, &now)?;
            if !cut.is_empty() {
                hemo.territory = cut;
            }
        }
        self.metrics.reperfusion = reperfusion_metric(&open, &now, &hemo.territory)?;
        self.update_injection()
    }

    /// Re-solves the flow for the current injection (at the device tip) or none.
    pub(super) fn update_injection(&mut self) -> Result<()> {
        let tip = Point3::from(injection_tip(&self.strand));
        let graph = &self.assets.anatomy.graph;
        let Some(hemo) = &mut self.hemo else {
            return Ok(());
        };
        let injection = match hemo.injection {
            Some((_, rate)) => {
                let location = graph.nearest(&tip).ok_or_else(|| {
                    EngineError::FailedPrecondition("the tip is not near any vessel".into())
                })?;
                Some(Injection {
                    vessel: location.branch,
                    arc: location.arc_length,
                    rate,
                    concentration: hemo.agent_mg_per_ml,
                })
            }
            None => None,
        };
        let solution = hemo.solver.solve(injection.as_ref())?;
        hemo.contrast.set_flow(hemo.solver.network(), &solution)?;
        hemo.active |= injection.is_some();
        Ok(())
    }
}
