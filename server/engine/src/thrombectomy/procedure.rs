//! The procedure state of a clotted session: the scene's clots placed on the route (and the
//! emboli lodged since), suction, the engaged stent, the pass under way and the figures; and
//! one step of it, which hands the crossings and passes to `passes`.

use std::f64::consts::PI;

use cathlab_hemo::{FlowNetwork, FlowSolution, Occlusion};
use cathlab_physics::{DeviceKind, StentSpec};
use cathlab_thrombectomy::{
    AspirationPass, Clot, ClotComposition, Engagement, PassOutcome, RetrievalPath, StentPass,
};
use nalgebra::Point3;

use super::route::way_back;

/// Wedge strain of a scene's clot (the middle of the sweep's 0.02–0.12).
pub const SCENE_WEDGE_STRAIN: f64 = 0.07;

/// What the procedure needs of one instrument each step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstrumentView {
    /// Kind, from the catalogue (`None` for a custom device).
    pub kind: Option<DeviceKind>,
    /// The stent, for a stent retriever.
    pub stent: Option<StentSpec>,
    /// Tip's distance along the route (m).
    pub tip_arc_m: f64,
    /// Inserted length (m).
    pub inserted_m: f64,
    /// Distal outer diameter (m).
    pub outer_diameter_m: f64,
    /// Distal lumen (m), 0 for a wire.
    pub bore_m: f64,
    /// Axial force on the hand (N).
    pub axial_force_n: f64,
}

/// A clot of the scene.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Site {
    pub(super) occlusion: Occlusion,
    pub(super) clot: Clot,
    /// Proximal end along the route (m), if the route passes it.
    pub(super) route_from_m: Option<f64>,
    pub(super) in_place: bool,
    /// Channel held open by a stent across it (m).
    pub(super) bypass_radius_m: Option<f64>,
    pub(super) crossed: bool,
    /// An embolus (not the scene's clot).
    pub(super) embolus: bool,
}

/// The pass under way.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Pass {
    Stent {
        site: usize,
        pass: StentPass,
        stent_index: usize,
        last_inserted_m: f64,
        /// The way back to the receiving catheter's tip, and how far that is (m).
        path: RetrievalPath,
        catheter_at_m: f64,
    },
    Aspiration {
        site: usize,
        pass: AspirationPass,
        catheter_index: usize,
        last_inserted_m: f64,
        /// The way back to the guide's tip, and how far that is (m).
        path: RetrievalPath,
        guide_at_m: f64,
    },
}

/// What a step of the procedure asks of the world.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct ProcedureStep {
    /// The clots changed: the flow's occlusions now.
    pub occlusions: Option<Vec<Occlusion>>,
    /// Things to tell the trainee.
    pub messages: Vec<String>,
    /// A pass ended: the hands that pulled should stop.
    pub pass_ended: bool,
}

/// Figures of the procedure, for the metrics.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ProcedureFigures {
    /// Passes made (stent retriever or aspiration).
    pub passes: u32,
    /// The first pass retrieved the clot with no fragment lost.
    pub first_pass_effect: bool,
    /// Fragments lodged downstream.
    pub emboli: u32,
    /// The largest axial force on a hand while its tip was in a clot (N).
    pub peak_crossing_force_n: f64,
    /// Force the clot's stiffness asks of the first tip that crossed it (N).
    pub crossing_force_n: f64,
    /// The deployed stent's grip on the clot (N), 0 when none.
    pub grip_n: f64,
}

/// The procedure state of a session.
#[derive(Debug, Clone, PartialEq)]
pub struct Procedure {
    pub(super) sites: Vec<Site>,
    pub(super) aspiration: bool,
    /// The engaged stent: site, engagement, unsheathed length (m), the stent's largest
    /// inserted length since (m).
    pub(super) engaged: Option<(usize, Engagement, f64, f64)>,
    pub(super) needs_resheath: bool,
    pub(super) pass: Option<Pass>,
    pub(super) figures: ProcedureFigures,
    /// Each instrument's inserted length at the last step (m), for its speed.
    pub(super) inserted_before: Vec<f64>,
    /// Each instrument's axial tip load from the clot it is crossing (N, negative resisting
    /// an advance), for the beam's next step.
    pub(super) tip_loads: Vec<f64>,
}

impl Procedure {
    /// The scene's clots (`occlusions`, with their compositions) placed on the route whose
    /// legs are given as (branch, from arc, to arc) (m).
    pub fn new(
        occlusions: &[Occlusion],
        compositions: &[f64],
        network: &FlowNetwork,
        legs: &[(usize, f64, f64)],
    ) -> Self {
        let sites = occlusions
            .iter()
            .zip(compositions)
            .map(|(o, &red)| {
                let vessel = &network.vessels[o.vessel];
                let radius = vessel.radius_at(0.5 * (o.from_arc + o.to_arc));
                let mut before = 0.0;
                let mut route_from_m = None;
                for &(branch, from, to) in legs {
                    if branch == o.vessel {
                        route_from_m = Some(if to >= from {
                            before + (o.from_arc - from)
                        } else {
                            before + (from - o.to_arc)
                        });
                        break;
                    }
                    before += (to - from).abs();
                }
                Site {
                    occlusion: *o,
                    clot: Clot::new(
                        ClotComposition {
                            red_cell_fraction: red,
                        },
                        o.to_arc - o.from_arc,
                        radius,
                        SCENE_WEDGE_STRAIN,
                    ),
                    route_from_m,
                    in_place: true,
                    bypass_radius_m: None,
                    crossed: false,
                    embolus: false,
                }
            })
            .collect();
        Self {
            sites,
            aspiration: false,
            engaged: None,
            needs_resheath: false,
            pass: None,
            figures: ProcedureFigures::default(),
            inserted_before: Vec::new(),
            tip_loads: Vec::new(),
        }
    }

    /// Each instrument's axial tip load from the clot it crosses (N, along its tangent,
    /// negative resisting an advance; outermost first), as of the last step.
    pub fn tip_loads(&self) -> &[f64] {
        &self.tip_loads
    }

    /// Suction on or off.
    pub fn set_aspiration(&mut self, on: bool) {
        self.aspiration = on;
    }

    /// Whether suction is on.
    pub fn aspiration(&self) -> bool {
        self.aspiration
    }

    /// The figures so far.
    pub fn figures(&self) -> ProcedureFigures {
        self.figures
    }

    /// The clots still in the patient, as the flow takes them (bypass channels included).
    pub fn occlusions(&self) -> Vec<Occlusion> {
        self.sites
            .iter()
            .filter(|s| s.in_place)
            .map(|s| {
                let mut o = s.occlusion;
                if let Some(r) = s.bypass_radius_m {
                    // Darcy plug in parallel with a Poiseuille channel of radius r:
                    // k_eff = k + π r⁴ / (8 A).
                    o.permeability_m2 += PI * r.powi(4) / (8.0 * s.clot.area_m2());
                }
                o
            })
            .collect()
    }

    /// The scene's clot that is in place on the route, nearest the access.
    fn site_on_route(&self) -> Option<(usize, f64)> {
        self.sites
            .iter()
            .enumerate()
            .filter(|(_, s)| s.in_place && !s.embolus)
            .filter_map(|(i, s)| s.route_from_m.map(|a| (i, a)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// One step: `instruments` outermost first, `dt` (s); `route` samples and radii
    /// (spacing `spacing_m`); the flow `now` and with every vessel open, `open`.
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        instruments: &[InstrumentView],
        dt: f64,
        route: &[Point3<f64>],
        radii: &[f64],
        spacing_m: f64,
        network: &FlowNetwork,
        now: &FlowSolution,
        open: &FlowSolution,
    ) -> ProcedureStep {
        let mut out = ProcedureStep::default();
        self.crossing(instruments);
        self.resist(instruments, dt);
        let Some((site, from)) = self.site_on_route() else {
            return out;
        };
        let length = self.sites[site].clot.length_m;
        let vessel = &network.vessels[self.sites[site].occlusion.vessel];
        let pressure_drop = (now.pressure[vessel.from] - now.pressure[vessel.to]).max(0.0);
        // The way back from the clot's proximal end to a tip at `to` along the route, built
        // once when a pass starts.
        let path_to = |to: f64| way_back(route, radii, spacing_m, from, to);
        let mut outcome = None;
        match &mut self.pass {
            Some(Pass::Stent {
                site: s,
                pass,
                stent_index,
                last_inserted_m,
                path,
                catheter_at_m,
            }) => {
                let now_in = instruments[*stent_index].inserted_m;
                let pull = *last_inserted_m - now_in;
                *last_inserted_m = now_in;
                if pull > 0.0 {
                    outcome = pass
                        .advance(pull, pull / dt, path, *catheter_at_m)
                        .map(|o| (*s, o));
                }
            }
            Some(Pass::Aspiration {
                site: s,
                pass,
                catheter_index,
                last_inserted_m,
                path,
                guide_at_m,
            }) => {
                if !self.aspiration {
                    outcome = Some((
                        *s,
                        PassOutcome::Failed {
                            emboli_m: Vec::new(),
                            reason: "suction released",
                        },
                    ));
                } else {
                    let now_in = instruments[*catheter_index].inserted_m;
                    let pull = *last_inserted_m - now_in;
                    *last_inserted_m = now_in;
                    if pass.ingested() || pull > 0.0 {
                        outcome = pass
                            .advance(pull.max(0.0), pull.max(0.0) / dt, path, *guide_at_m)
                            .map(|o| (*s, o));
                    }
                }
            }
            None => {
                self.start_passes(
                    instruments,
                    (site, from, length),
                    pressure_drop,
                    &path_to,
                    &mut out,
                );
            }
        }
        if let Some((s, o)) = outcome {
            self.finish_pass(s, o, network, open, &mut out);
        }
        out
    }
}
