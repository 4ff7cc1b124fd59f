//! Flow and contrast of a scene that has them: the flow solver (with the clots now, with
//! every vessel open, and on the grading network without collaterals), the contrast in the
//! vessels, the injection under way and the power injector's program, and the reperfusion
//! metric of the territory the clots cut off.

use std::sync::Arc;

use cathlab_hemo::reperfusion::{occluded_territory, reperfusion};
use cathlab_hemo::{Contrast, ContrastSettings, FlowSolution, FlowSolver};
use cathlab_xray::ContrastTube;

use crate::assets::SceneAssets;
use crate::error::Result;
use crate::metrics::ReperfusionMetric;

/// Flow and contrast of a scene that has them.
pub(super) struct Hemo {
    pub(super) solver: FlowSolver,
    pub(super) contrast: Contrast,
    pub(super) agent_mg_per_ml: f64,
    /// Volume left to inject (m³) and rate (m³/s), while injecting.
    pub(super) injection: Option<(f64, f64)>,
    pub(super) steps_since_contrast: u32,
    pub(super) tubes: Arc<Vec<ContrastTube>>,
    /// Whether any iodine is in the vessels (contrast steps only then).
    pub(super) active: bool,
    /// The power injector's program (mL, mL/s): the last injection's, run again when a DSA
    /// run fires it.
    pub(super) program: (f64, f64),
    /// When the injector linked to the current DSA run fires (procedure time, s).
    pub(super) linked_at_s: Option<f64>,
    /// The flow with every vessel open and no injection: what reperfusion is measured
    /// against.
    pub(super) open_flow: FlowSolution,
    /// The outlets the clots cut off (empty without clots), on the grading network.
    pub(super) territory: Vec<usize>,
    /// A scene with collaterals: the network without them and its open flow, on which
    /// eTICI grades the antegrade reperfusion (the collaterals' retrograde filling does not
    /// count).
    pub(super) grading: Option<(FlowSolver, FlowSolution)>,
    /// The flow with the clots now and no injection (pressures across a clot).
    pub(super) flow_now: FlowSolution,
}

/// The power injector's program before any injection: 6 mL at 4 mL/s, a selective
/// common-carotid run through a 5 F catheter.
const DEFAULT_INJECTOR_PROGRAM: (f64, f64) = (6.0, 4.0);

/// Delay from the start of a DSA run to the linked injection (s): the mask frames come first.
pub const LINKED_INJECTION_DELAY_S: f64 = 0.5;

/// Threshold below which contrast cells are not drawn (mg/mL).
pub(super) const CONTRAST_DRAW_THRESHOLD: f64 = 1.0;

impl Hemo {
    /// The flow and contrast of `assets`' scene at its start (none without flow), and the
    /// reperfusion metric of the territory its clots cut off.
    pub(super) fn start(assets: &SceneAssets) -> Result<(Option<Self>, Option<ReperfusionMetric>)> {
        let mut reperfusion = None;
        let hemo = match &assets.network {
            None => None,
            Some(network) => {
                let mut solver = FlowSolver::new(network.clone())?;
                let open_flow = solver.solve(None)?;
                let flow = if assets.clots.is_empty() {
                    open_flow.clone()
                } else {
                    solver.set_occlusions(&assets.clots)?;
                    solver.solve(None)?
                };
                let mut grading = match &assets.grading_network {
                    None => None,
                    Some(n) => {
                        let mut g = FlowSolver::new(n.clone())?;
                        let open = g.solve(None)?;
                        g.set_occlusions(&assets.clots)?;
                        Some((g, open))
                    }
                };
                let (graded_open, graded_now) = match &mut grading {
                    None => (open_flow.clone(), flow.clone()),
                    Some((g, open)) => (open.clone(), g.solve(None)?),
                };
                let territory = if assets.clots.is_empty() {
                    Vec::new()
                } else {
                    occluded_territory(&graded_open, &graded_now)?
                };
                let mut contrast = Contrast::new(
                    network,
                    ContrastSettings {
                        cell_length: assets.spec.fidelity.contrast_cell_mm * 1e-3,
                        ..ContrastSettings::default()
                    },
                )?;
                contrast.set_flow(network, &flow)?;
                reperfusion = reperfusion_metric(&graded_open, &graded_now, &territory)?;
                Some(Hemo {
                    solver,
                    contrast,
                    agent_mg_per_ml: assets
                        .spec
                        .flow
                        .as_ref()
                        .map_or(300.0, |f| f.agent_mg_per_ml),
                    injection: None,
                    steps_since_contrast: 0,
                    tubes: Arc::new(Vec::new()),
                    active: false,
                    program: DEFAULT_INJECTOR_PROGRAM,
                    linked_at_s: None,
                    open_flow,
                    territory,
                    grading,
                    flow_now: flow,
                })
            }
        };
        Ok((hemo, reperfusion))
    }
}

/// The reperfusion of `territory` in the flow `now` (no injection) against `open`, for the
/// metrics; none while no clot has cut anything off.
pub(super) fn reperfusion_metric(
    open: &FlowSolution,
    now: &FlowSolution,
    territory: &[usize],
) -> Result<Option<ReperfusionMetric>> {
    if territory.is_empty() {
        return Ok(None);
    }
    let r = reperfusion(open, now, territory)?;
    Ok(Some(ReperfusionMetric {
        fraction: r.fraction,
        etici: r.grade,
    }))
}
