//! What a procedure step drives: tips crossing a clot (the force its stiffness asks, its
//! resistance on the tips that open it), a stent unsheathed across it engaging it, stent and
//! aspiration passes started and finished, and the fragments they lose lodged downstream.

use std::f64::consts::PI;

use cathlab_hemo::{FlowNetwork, FlowSolution, Occlusion};
use cathlab_physics::DeviceKind;
use cathlab_thrombectomy::sweep::WEDGE_RELIEF;
use cathlab_thrombectomy::{
    AspirationPass, AspirationSetup, DEFAULT_SUCTION_PA, Engagement, PassOutcome, RetrievalPath,
    StentPass, StentRetriever, StentSetup,
};

use super::procedure::{InstrumentView, Pass, Procedure, ProcedureStep, Site};

/// Unsheathed stent length below which the stent counts as sheathed (m).
const SHEATHED_M: f64 = 1e-3;

/// How far short of the clot's face an aspiration catheter's tip still seals on it (m); its
/// apposition falls from 1 at the face to 0.5 there.
const APPOSITION_REACH_M: f64 = 1.5e-3;

/// Tip speed (m/s) over which a clot's resistance to a crossing tip builds up to its full
/// value (a regularised plastic resistance, F·tanh(v/v₀): a tip that stops feels none, so the
/// clot does not push it back).
pub(super) const CROSSING_SPEED_M_S: f64 = 1e-3;

/// Pull of an engaged stent's wire that starts a retrieval pass (m): less is the hand's play.
const START_PULL_M: f64 = 0.2e-3;

/// Fraction of the stent's radius left open as a channel through the clot it holds (the rest
/// is clot bulging through the cells; assumed).
const BYPASS_RADIUS_FRACTION: f64 = 0.5;

impl Procedure {
    /// Tips entering a clot: the force its stiffness asks, and the hand's force meanwhile
    /// (wires and catheters crossing it, before any stent is engaged).
    pub(super) fn crossing(&mut self, instruments: &[InstrumentView]) {
        if self.engaged.is_some() || self.pass.is_some() || self.figures.passes > 0 {
            return;
        }
        for s in self.sites.iter_mut().filter(|s| s.in_place) {
            let Some(from) = s.route_from_m else { continue };
            let to = from + s.clot.length_m;
            for v in instruments.iter().filter(|v| v.stent.is_none()) {
                if v.tip_arc_m > from && v.tip_arc_m <= to + 1e-3 {
                    if !s.crossed {
                        s.crossed = true;
                        self.figures.crossing_force_n =
                            s.clot.mechanics.crossing_force_n(v.outer_diameter_m);
                    }
                    self.figures.peak_crossing_force_n = self
                        .figures
                        .peak_crossing_force_n
                        .max(v.axial_force_n.abs());
                }
            }
        }
    }

    /// The clot's resistance to the tips crossing it: a tip in a clot in place, not inside
    /// an instrument that reaches further, opens the clot from what the instruments ahead of
    /// it inside already opened to its own diameter, against the cavity-expansion force
    /// ([`cathlab_thrombectomy::ClotMechanics::crossing_force_n`] of the two diameters'
    /// difference), regularised by its speed (F·tanh(v/v₀), v₀ = 1 mm/s). Stent retrievers
    /// and an engaged or retrieved clot take none.
    pub(super) fn resist(&mut self, instruments: &[InstrumentView], dt: f64) {
        let n = instruments.len();
        if self.inserted_before.len() != n {
            self.inserted_before = instruments.iter().map(|v| v.inserted_m).collect();
        }
        self.tip_loads.clear();
        self.tip_loads.resize(n, 0.0);
        if self.engaged.is_none() && self.pass.is_none() {
            for s in self.sites.iter().filter(|s| s.in_place && !s.embolus) {
                let Some(from) = s.route_from_m else { continue };
                let to = from + s.clot.length_m;
                for (k, v) in instruments.iter().enumerate() {
                    if v.stent.is_some() || v.tip_arc_m <= from || v.tip_arc_m > to {
                        continue;
                    }
                    // Inside an instrument that reaches further: shielded.
                    if instruments[..k].iter().any(|o| o.tip_arc_m > v.tip_arc_m) {
                        continue;
                    }
                    // The channel the instruments ahead of it inside already opened.
                    let channel = instruments[k + 1..]
                        .iter()
                        .filter(|i| i.tip_arc_m > v.tip_arc_m)
                        .map(|i| i.outer_diameter_m)
                        .fold(0.0, f64::max);
                    let mechanics = &s.clot.mechanics;
                    let force = (mechanics.crossing_force_n(v.outer_diameter_m)
                        - mechanics.crossing_force_n(channel))
                    .max(0.0);
                    let speed = (v.inserted_m - self.inserted_before[k]) / dt.max(1e-12);
                    self.tip_loads[k] = -force * (speed / CROSSING_SPEED_M_S).tanh();
                }
            }
        }
        for (before, v) in self.inserted_before.iter_mut().zip(instruments) {
            *before = v.inserted_m;
        }
    }

    /// With no pass under way: a stent unsheathed across the clot engages it (and a pull on
    /// it starts a pass); suction on a catheter at the clot's face starts an aspiration pass.
    pub(super) fn start_passes(
        &mut self,
        instruments: &[InstrumentView],
        (site, from, length): (usize, f64, f64),
        pressure_drop: f64,
        way_back: &dyn Fn(f64) -> Option<RetrievalPath>,
        out: &mut ProcedureStep,
    ) {
        let to = from + length;
        // The stent retriever and the microcatheter around it.
        let stent = instruments
            .iter()
            .enumerate()
            .skip(1)
            .find_map(|(i, v)| v.stent.map(|s| (i, s)));
        if let Some((k, spec)) = stent {
            let distal = instruments[k].tip_arc_m - spec.from_tip_m;
            let unsheathed = (distal - instruments[k - 1].tip_arc_m).clamp(0.0, spec.length_m);
            if unsheathed < SHEATHED_M {
                self.needs_resheath = false;
                if self.engaged.take().is_some() {
                    self.sites[site].bypass_radius_m = None;
                    out.occlusions = Some(self.occlusions());
                    out.messages.push("the stent was resheathed".into());
                }
            } else if !self.needs_resheath {
                let model = StentRetriever {
                    nominal_diameter_m: spec.nominal_diameter_m,
                    length_m: unsheathed,
                    cof_n_per_m: spec.cof_n_per_m,
                    reference_diameter_m: spec.reference_diameter_m,
                    rrf_ratio: spec.rrf_ratio,
                    transition_m: spec.transition_m,
                    strut_friction: spec.strut_friction,
                    open_area: spec.open_area,
                };
                let clot = self.sites[site].clot;
                let setup = StentSetup {
                    stent: model,
                    clot,
                    distal_offset_m: distal - to,
                    channel_radius_m: instruments[k - 1].bore_m / 2.0,
                    receiving_bore_m: receiving(instruments, k, from)
                        .map_or(instruments[0].bore_m, |(_, v)| v.bore_m),
                    suction_pa: if self.aspiration {
                        DEFAULT_SUCTION_PA
                    } else {
                        0.0
                    },
                    pressure_drop_pa: pressure_drop,
                };
                let overlaps = distal > from && distal - unsheathed < to;
                let changed = self
                    .engaged
                    .as_ref()
                    .is_none_or(|(_, _, u, _)| (u - unsheathed).abs() > 0.5e-3);
                if overlaps
                    && changed
                    && let Ok(engagement) = Engagement::of(&setup)
                    && engagement.grip_n > 0.0
                {
                    let opened = unsheathed >= spec.length_m - 0.5e-3
                        && self.engaged.is_none_or(|e| e.2 < spec.length_m - 0.5e-3);
                    self.figures.grip_n = engagement.grip_n;
                    let channel = BYPASS_RADIUS_FRACTION
                        * clot.vessel_radius_m
                        * engagement.embedding.max(0.3);
                    self.sites[site].bypass_radius_m = Some(channel);
                    out.occlusions = Some(self.occlusions());
                    if opened {
                        out.messages.push(format!(
                            "the stent is open across the clot: {:.1} mm overlap, grip {:.2} N",
                            (engagement.overlap_m.1 - engagement.overlap_m.0) * 1e3,
                            engagement.grip_n
                        ));
                    }
                    let peak = self.engaged.map_or(instruments[k].inserted_m, |e| e.3);
                    self.engaged = Some((site, engagement, unsheathed, peak));
                }
                // A pull of the engaged stent by more than START_PULL_M starts the pass.
                if let Some((s, engagement, u, peak)) = self.engaged
                    && s == site
                {
                    let stent_now = instruments[k].inserted_m;
                    self.engaged = Some((s, engagement, u, peak.max(stent_now)));
                    if stent_now < peak - START_PULL_M {
                        let receiving_tip = receiving(instruments, k, from)
                            .map_or(instruments[0].tip_arc_m, |(_, v)| v.tip_arc_m);
                        if let (Ok(pass), Some(path)) =
                            (StentPass::new(setup), way_back(receiving_tip))
                        {
                            out.messages.push(format!(
                                "pass {}: retrieving the stent with the clot",
                                self.figures.passes + 1
                            ));
                            self.pass = Some(Pass::Stent {
                                site,
                                pass,
                                stent_index: k,
                                last_inserted_m: peak,
                                path,
                                catheter_at_m: (from - receiving_tip).max(0.0),
                            });
                        }
                    }
                }
            }
        }
        if self.pass.is_some() {
            return;
        }
        // Aspiration: the innermost distal-access catheter at the clot's face.
        if !self.aspiration {
            return;
        }
        let Some((c, catheter)) = instruments
            .iter()
            .enumerate()
            .rev()
            .find(|(_, v)| v.kind == Some(DeviceKind::DistalAccess))
        else {
            return;
        };
        let gap = from - catheter.tip_arc_m;
        if !(-0.5e-3..=APPOSITION_REACH_M).contains(&gap) {
            return;
        }
        let apposition = 1.0 - 0.5 * (gap / APPOSITION_REACH_M).clamp(0.0, 1.0);
        let guide_tip = if c > 0 {
            instruments[c - 1].tip_arc_m
        } else {
            0.0
        };
        let Some(path) = way_back(guide_tip) else {
            return;
        };
        if let Ok(pass) = AspirationPass::new(AspirationSetup {
            clot: self.sites[site].clot,
            bore_m: catheter.bore_m,
            suction_pa: DEFAULT_SUCTION_PA,
            apposition,
            pressure_drop_pa: pressure_drop,
        }) {
            out.messages.push(if pass.ingested() {
                "aspiration: the clot is ingested".into()
            } else {
                format!(
                    "aspiration: the clot corks the catheter (held with {:.2} N); withdraw under suction",
                    pass.hold_n()
                )
            });
            self.pass = Some(Pass::Aspiration {
                site,
                pass,
                catheter_index: c,
                last_inserted_m: catheter.inserted_m,
                path,
                guide_at_m: (from - guide_tip).max(0.0),
            });
        }
    }

    pub(super) fn finish_pass(
        &mut self,
        site: usize,
        outcome: PassOutcome,
        network: &FlowNetwork,
        open: &FlowSolution,
        out: &mut ProcedureStep,
    ) {
        self.pass = None;
        self.engaged = None;
        self.figures.grip_n = 0.0;
        self.figures.passes += 1;
        out.pass_ended = true;
        let pass = self.figures.passes;
        let emboli = outcome.emboli_m().to_vec();
        let retrieved = outcome.retrieved();
        if retrieved {
            self.sites[site].in_place = false;
            if pass == 1 && emboli.is_empty() {
                self.figures.first_pass_effect = true;
            }
            out.messages.push(format!("pass {pass}: the clot is out"));
        } else {
            let reason = match &outcome {
                PassOutcome::Failed { reason, .. } => *reason,
                PassOutcome::Retrieved { .. } => "",
            };
            let s = &mut self.sites[site];
            s.bypass_radius_m = None;
            s.clot.wedge_strain *= WEDGE_RELIEF;
            self.needs_resheath = true;
            out.messages.push(format!(
                "pass {pass}: the clot was lost ({reason} let go); it is still in place"
            ));
        }
        for length in emboli {
            if let Some(o) = lodge(&self.sites[site], length, network, open) {
                self.figures.emboli += 1;
                let name = &network.vessels[o.vessel].name;
                out.messages.push(format!(
                    "a {:.1} mm fragment embolized to {name}",
                    length * 1e3
                ));
                let mut clot = self.sites[site].clot;
                clot.length_m = o.to_arc - o.from_arc;
                clot.vessel_radius_m = network.vessels[o.vessel].radius_at(o.from_arc);
                self.sites.push(Site {
                    occlusion: o,
                    clot,
                    route_from_m: None,
                    in_place: true,
                    bypass_radius_m: None,
                    crossed: false,
                    embolus: true,
                });
            }
        }
        out.occlusions = Some(self.occlusions());
    }
}

/// The catheter a stent at instrument `k` is pulled into: the innermost one outside its
/// microcatheter whose tip is short of the clot.
fn receiving(
    instruments: &[InstrumentView],
    k: usize,
    from: f64,
) -> Option<(usize, &InstrumentView)> {
    instruments[..k.saturating_sub(1)]
        .iter()
        .enumerate()
        .rev()
        .find(|(_, v)| v.bore_m > 0.0 && v.tip_arc_m <= from)
}

/// Where a fragment of `length_m` of the clot at `site` lodges: carried down the branch with
/// the most flow at each junction (with every vessel open) until a vessel is narrower than
/// the fragment (a sphere of its volume), or at the end of the last.
pub(super) fn lodge(
    site: &Site,
    length_m: f64,
    network: &FlowNetwork,
    open: &FlowSolution,
) -> Option<Occlusion> {
    let volume = site.clot.area_m2() * length_m;
    let sphere = (3.0 * volume / (4.0 * PI)).cbrt();
    let mut vessel = site.occlusion.vessel;
    for _ in 0..network.vessels.len() {
        let node = network.vessels[vessel].to;
        let next = network
            .vessels
            .iter()
            .enumerate()
            .filter(|(_, v)| v.from == node)
            .max_by(|a, b| {
                open.vessels[a.0]
                    .proximal
                    .total_cmp(&open.vessels[b.0].proximal)
            });
        match next {
            Some((i, v)) => {
                vessel = i;
                if v.radius_at(0.0) < sphere {
                    break;
                }
            }
            None => break,
        }
    }
    if vessel == site.occlusion.vessel {
        return None;
    }
    let v = &network.vessels[vessel];
    let r = v.radius_at(0.0);
    let len = (volume / (PI * r * r)).clamp(0.5e-3, 0.9 * v.length());
    Some(Occlusion {
        vessel,
        from_arc: 0.0,
        to_arc: len,
        permeability_m2: site.occlusion.permeability_m2,
    })
}
