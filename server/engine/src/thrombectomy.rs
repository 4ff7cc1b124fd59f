//! The thrombectomy of a clotted scene, step by step: where each clot sits on the route,
//! what crossing it took, the stent retriever unsheathed across it (engagement, bypass flow),
//! retrieval and aspiration passes driven by the hands, emboli lodged downstream, and the
//! clots the flow must carry. The mechanics are `cathlab-thrombectomy`'s; this module maps
//! instruments on the route to its passes.

use cathlab_hemo::{FlowNetwork, FlowSolution, Occlusion};
use cathlab_physics::{DeviceKind, StentSpec};
use cathlab_thrombectomy::sweep::WEDGE_RELIEF;
use cathlab_thrombectomy::{
    AspirationPass, AspirationSetup, Clot, ClotComposition, DEFAULT_SUCTION_PA, Engagement,
    PassOutcome, RetrievalPath, StentPass, StentRetriever, StentSetup,
};
use nalgebra::Point3;
use std::f64::consts::PI;

/// Wedge strain of a scene's clot (the middle of the sweep's 0.02–0.12).
pub const SCENE_WEDGE_STRAIN: f64 = 0.07;

/// Unsheathed stent length below which the stent counts as sheathed (m).
const SHEATHED_M: f64 = 1e-3;

/// How far short of the clot's face an aspiration catheter's tip still seals on it (m); its
/// apposition falls from 1 at the face to 0.5 there.
const APPOSITION_REACH_M: f64 = 1.5e-3;

/// Tip speed (m/s) over which a clot's resistance to a crossing tip builds up to its full
/// value (a regularised plastic resistance, F·tanh(v/v₀): a tip that stops feels none, so the
/// clot does not push it back).
const CROSSING_SPEED_M_S: f64 = 1e-3;

/// Pull of an engaged stent's wire that starts a retrieval pass (m): less is the hand's play.
const START_PULL_M: f64 = 0.2e-3;

/// Fraction of the stent's radius left open as a channel through the clot it holds (the rest
/// is clot bulging through the cells; assumed).
const BYPASS_RADIUS_FRACTION: f64 = 0.5;

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
struct Site {
    occlusion: Occlusion,
    clot: Clot,
    /// Proximal end along the route (m), if the route passes it.
    route_from_m: Option<f64>,
    in_place: bool,
    /// Channel held open by a stent across it (m).
    bypass_radius_m: Option<f64>,
    crossed: bool,
    /// An embolus (not the scene's clot).
    embolus: bool,
}

/// The pass under way.
#[derive(Debug, Clone, PartialEq)]
enum Pass {
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
    sites: Vec<Site>,
    aspiration: bool,
    /// The engaged stent: site, engagement, unsheathed length (m), the stent's largest
    /// inserted length since (m).
    engaged: Option<(usize, Engagement, f64, f64)>,
    needs_resheath: bool,
    pass: Option<Pass>,
    figures: ProcedureFigures,
    /// Each instrument's inserted length at the last step (m), for its speed.
    inserted_before: Vec<f64>,
    /// Each instrument's axial tip load from the clot it is crossing (N, negative resisting
    /// an advance), for the beam's next step.
    tip_loads: Vec<f64>,
}

/// Distance along the route polyline of the point nearest `p` (m), the samples `spacing_m`
/// apart.
pub fn route_arc(samples: &[Point3<f64>], spacing_m: f64, p: &Point3<f64>) -> f64 {
    let mut best = (f64::MAX, 0.0);
    for i in 0..samples.len().saturating_sub(1) {
        let (a, b) = (samples[i], samples[i + 1]);
        let ab = b - a;
        let t = ((p - a).dot(&ab) / ab.norm_squared().max(1e-30)).clamp(0.0, 1.0);
        let d = (a + ab * t - p).norm_squared();
        if d < best.0 {
            best = (d, (i as f64 + t) * spacing_m);
        }
    }
    best.1
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

    /// Tips entering a clot: the force its stiffness asks, and the hand's force meanwhile
    /// (wires and catheters crossing it, before any stent is engaged).
    fn crossing(&mut self, instruments: &[InstrumentView]) {
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
    fn resist(&mut self, instruments: &[InstrumentView], dt: f64) {
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
    fn start_passes(
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

    fn finish_pass(
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

/// The way back along the route (samples `spacing_m` apart, with their radii) from a clot's
/// proximal end at `from` to a tip at `to` (m).
fn way_back(
    route: &[Point3<f64>],
    radii: &[f64],
    spacing_m: f64,
    from: f64,
    to: f64,
) -> Option<RetrievalPath> {
    let (a, b) = (
        (to / spacing_m).floor().max(0.0) as usize,
        ((from / spacing_m).ceil() as usize).min(route.len() - 1),
    );
    if b <= a + 1 {
        return Some(RetrievalPath::straight(spacing_m, radii[b]));
    }
    let points: Vec<_> = route[a..=b].iter().rev().copied().collect();
    let r: Vec<_> = radii[a..=b].iter().rev().copied().collect();
    RetrievalPath::from_centerline(&points, &r).ok()
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
fn lodge(
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

/// The scripted operator of the stroke case, phase by phase, for tests and benchmarks: every
/// phase applies recorded commands (numbered on from `seq`) and steps the world until it is
/// done or its step budget runs out (false).
#[derive(Debug, Clone)]
pub struct StrokeScript {
    /// The next command's sequence number.
    pub seq: u64,
    /// Inserted length at which a tip reaches the start of the route's branch `branch` (m).
    pub branch_inserted_m: f64,
}

impl StrokeScript {
    /// The script for `world`'s scene, `branch` the occluded branch on its route.
    pub fn new(world: &crate::World, branch: &str, first_seq: u64) -> crate::Result<Self> {
        let assets = world.assets();
        let graph = &assets.anatomy.graph;
        let mut along = 0.0;
        let mut found = false;
        for leg in &assets.route.legs {
            if graph.branches[leg.branch].name == branch {
                found = true;
                break;
            }
            along += (leg.to_arc - leg.from_arc).abs();
        }
        if !found {
            return Err(crate::EngineError::FailedPrecondition(format!(
                "{branch} is not on the scene's route"
            )));
        }
        Ok(Self {
            seq: first_seq,
            branch_inserted_m: along - assets.spec.start.along_route_mm * 1e-3,
        })
    }

    /// Applies `command` as the next recorded one.
    pub fn apply(
        &mut self,
        world: &mut crate::World,
        command: crate::Command,
    ) -> crate::Result<()> {
        self.seq += 1;
        world.apply(self.seq, &command)
    }

    /// Steps until `done` or `steps` run out.
    pub fn run_until(
        world: &mut crate::World,
        steps: usize,
        done: impl Fn(&crate::World) -> bool,
    ) -> crate::Result<bool> {
        for _ in 0..steps {
            if done(world) {
                return Ok(true);
            }
            world.step()?;
        }
        Ok(done(world))
    }

    /// The scene's two-hand operator crosses to the target; then every hand holds.
    pub fn cross(&mut self, world: &mut crate::World) -> crate::Result<bool> {
        let reached = world.follow_two_hands(40_000, self.seq + 1)?;
        self.seq += 1_000_000;
        for i in 0..world.strand().len() as u32 {
            self.apply(
                world,
                crate::Command::Instrument {
                    index: i,
                    drive: crate::Drive::PushVelocity(0.0),
                },
            )?;
        }
        Ok(reached.is_some())
    }

    /// Instrument `index` moved to `inserted_m` (m).
    pub fn move_to(
        &mut self,
        world: &mut crate::World,
        index: u32,
        inserted_m: f64,
        steps: usize,
    ) -> crate::Result<bool> {
        self.apply(
            world,
            crate::Command::Instrument {
                index,
                drive: crate::Drive::PushTarget(inserted_m),
            },
        )?;
        Self::run_until(world, steps, |w| {
            (w.strand().inserted_m(index as usize) - inserted_m).abs() < 0.3e-3
        })
    }

    /// The innermost instrument exchanged for catalogue entry `id`, then pushed to the tip
    /// of the one around it.
    pub fn bring_in(&mut self, world: &mut crate::World, id: &str) -> crate::Result<bool> {
        let entries = crate::scene::catalogue().entries();
        let Some(k) = entries.iter().position(|e| e.id == id) else {
            return Err(crate::EngineError::FailedPrecondition(format!(
                "{id} is not in the catalogue"
            )));
        };
        let name = entries[k].device.name.clone();
        let inner = world.strand().len() - 1;
        self.apply(
            world,
            crate::Command::Exchange {
                index: inner as u32,
                catalogue: k as u32,
            },
        )?;
        if !Self::run_until(world, 20_000, |w| {
            w.strand().device(inner).is_some_and(|d| d.name == name)
        })? {
            return Ok(false);
        }
        let tip = world.strand().inserted_m(inner - 1);
        self.move_to(world, inner as u32, tip, 20_000)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cathlab_hemo::{Blood, FlowSolver, Inlet, InletCondition, Outlet, Vessel};

    /// A parent artery (r 1.5 mm) forking into a wide (1.0 mm) and a narrow (0.6 mm) branch,
    /// each forking again into two 0.5 mm branches; every end drains through the same
    /// terminal resistance.
    fn tree() -> FlowNetwork {
        let v = |name: &str, from, to, r| Vessel::uniform(name, from, to, 20e-3, r);
        let vessels = vec![
            v("parent", 0, 1, 1.5e-3),
            v("wide", 1, 2, 1.0e-3),
            v("narrow", 1, 3, 0.6e-3),
            v("wide-a", 2, 4, 0.5e-3),
            v("wide-b", 2, 5, 0.5e-3),
            v("narrow-a", 3, 6, 0.5e-3),
            v("narrow-b", 3, 7, 0.5e-3),
        ];
        let outlets = (4..8)
            .map(|node| Outlet {
                node,
                resistance: 5e9,
                pressure: 0.0,
            })
            .collect();
        FlowNetwork::new(
            8,
            vessels,
            Inlet {
                node: 0,
                condition: InletCondition::Pressure(13_000.0),
            },
            outlets,
            Blood::default(),
        )
        .unwrap()
    }

    fn site() -> Site {
        let occlusion = Occlusion {
            vessel: 0,
            from_arc: 4e-3,
            to_arc: 12e-3,
            permeability_m2: 1e-15,
        };
        Site {
            occlusion,
            clot: Clot::new(
                ClotComposition {
                    red_cell_fraction: 0.5,
                },
                8e-3,
                1.5e-3,
                SCENE_WEDGE_STRAIN,
            ),
            route_from_m: Some(0.0),
            in_place: true,
            bypass_radius_m: None,
            crossed: false,
            embolus: false,
        }
    }

    fn view(tip_arc_m: f64, inserted_m: f64, outer_diameter_m: f64) -> InstrumentView {
        InstrumentView {
            kind: None,
            stent: None,
            tip_arc_m,
            inserted_m,
            outer_diameter_m,
            bore_m: 0.0,
            axial_force_n: 0.0,
        }
    }

    /// A tip advancing in the clot is resisted by the cavity-expansion force of its diameter
    /// (less the channel the instruments ahead of it opened), scaled by tanh(v/v₀); a tip
    /// inside an instrument that reaches further, a still tip, a tip outside the clot and a
    /// stent take none.
    #[test]
    fn the_clot_resists_the_tips_that_open_it() {
        let network = tree();
        let s = site();
        let mut p = Procedure::new(&[s.occlusion], &[0.5], &network, &[(0, 0.0, 20e-3)]);
        let m = s.clot.mechanics;
        let (wire, micro, guide) = (0.36e-3, 0.8e-3, 2.0e-3);
        let dt = 0.002;
        let at = |p: &mut Procedure, views: &[InstrumentView]| {
            p.resist(views, dt);
            p.tip_loads().to_vec()
        };
        // Guide outside the clot, microcatheter in it behind the wire, the wire in it ahead.
        let before = [
            view(2e-3, 0.10, guide),
            view(6e-3, 0.20, micro),
            view(8e-3, 0.30, wire),
        ];
        assert_eq!(at(&mut p, &before), [0.0, 0.0, 0.0], "nothing moved yet");
        let v = 10e-3;
        let moved = [
            view(2e-3, 0.10, guide),
            view(6e-3, 0.20 + v * dt, micro),
            view(8e-3, 0.30 + v * dt, wire),
        ];
        let loads = at(&mut p, &moved);
        let scale = (v / CROSSING_SPEED_M_S).tanh();
        assert_eq!(loads[0], 0.0);
        let micro_expected = -(m.crossing_force_n(micro) - m.crossing_force_n(wire)) * scale;
        assert!(
            (loads[1] - micro_expected).abs() < 1e-12 * micro_expected.abs(),
            "{loads:?}"
        );
        let wire_expected = -m.crossing_force_n(wire) * scale;
        assert!(
            (loads[2] - wire_expected).abs() < 1e-12 * wire_expected.abs(),
            "{loads:?}"
        );
        // Drawn back through it: resisted the other way.
        let back = [
            view(2e-3, 0.10, guide),
            view(6e-3, 0.20, micro),
            view(8e-3, 0.30, wire),
        ];
        let loads = at(&mut p, &back);
        assert!(loads[1] > 0.0 && loads[2] > 0.0, "{loads:?}");
        // The wire inside the microcatheter, which reaches further: shielded; a stent too.
        let mut inside = [
            view(2e-3, 0.10, guide),
            view(9e-3, 0.21, micro),
            view(8e-3, 0.31, wire),
        ];
        let loads = at(&mut p, &inside);
        assert_eq!(loads[2], 0.0, "{loads:?}");
        assert!(loads[1] < 0.0);
        inside[1].stent = crate::scene::catalogue()
            .get("stent-retriever-4x20")
            .and_then(|e| e.stent);
        assert!(inside[1].stent.is_some());
        inside[1].inserted_m += 0.01;
        let loads = at(&mut p, &inside);
        assert_eq!(loads[1], 0.0, "a stent takes none: {loads:?}");
        // Beyond the clot: none.
        let beyond = [
            view(2e-3, 0.10, guide),
            view(15e-3, 0.30, micro),
            view(16e-3, 0.40, wire),
        ];
        assert_eq!(at(&mut p, &beyond), [0.0, 0.0, 0.0]);
    }

    /// A fragment follows the most flow until a vessel is narrower than the sphere of its
    /// volume, and lodges there with its volume.
    #[test]
    fn fragments_ride_the_main_flow_and_lodge_where_they_no_longer_fit() {
        let network = tree();
        let open = FlowSolver::new(network.clone())
            .unwrap()
            .solve(None)
            .unwrap();
        assert!(open.vessels[1].proximal > open.vessels[2].proximal);
        let site = site();
        // 2 mm of the 1.5 mm clot: a sphere of 1.28 mm radius, wider than the wide branch.
        let big = lodge(&site, 2e-3, &network, &open).unwrap();
        assert_eq!(network.vessels[big.vessel].name, "wide");
        let volume = site.clot.area_m2() * 2e-3;
        let lodged = PI * 1e-3 * 1e-3 * (big.to_arc - big.from_arc);
        assert!((lodged - volume).abs() < 1e-9 * volume);
        // 0.1 mm: a 0.38 mm sphere fits every branch and rides the main flow to its end.
        let small = lodge(&site, 0.1e-3, &network, &open).unwrap();
        assert!(network.vessels[small.vessel].name.starts_with("wide-"));
        // The occlusion it makes cuts that branch's flow.
        let mut solver = FlowSolver::new(network.clone()).unwrap();
        solver.set_occlusions(&[big]).unwrap();
        let now = solver.solve(None).unwrap();
        assert!(now.vessels[1].proximal < 0.01 * open.vessels[1].proximal);
    }
}
