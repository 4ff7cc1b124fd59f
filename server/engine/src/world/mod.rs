//! A session's deterministic world: the navigated device, optional flow and contrast, the
//! imaging state the trainee controls, and the metrics. No threads and no wall clock: the same
//! scene and the same commands at the same steps give the same state, bit for bit, which is
//! what replay relies on.
//!
//! This module holds the world's data, its start and [`World::step`], which runs the stages
//! of a step in order, each in its own module:
//!
//! 1. `demonstration`: the scene's scripted operator, while it demonstrates, decides;
//! 2. `exchange`: an exchange under way draws its instrument back, or replaces it;
//! 3. `physics`: the strand stepped within each hand's limits, a diverged step reset;
//! 4. `measure`: the clock, wall forces, the tracked tip and the target, the hands'
//!    reactions, per-instrument figures;
//! 5. `thrombectomy`: the clots' procedure, in a clotted scene;
//! 6. `contrast`: the injector, and the contrast carried by the flow.
//!
//! Commands apply between steps (`apply`, `exchange`); `observe` makes the snapshot and the
//! digest. The data the stages share live below the world: `command`, `snapshot`, `hand`,
//! `fidelity`, `hemo`, `operator` and `tips`.

use std::sync::Arc;

use cathlab_hemo::FlowSolution;
use cathlab_physics::Navigation;
use cathlab_xray::PulseRate;
use nalgebra::{Point3, Vector3};

use crate::assets::{SceneAssets, SharedWall};
use crate::error::Result;
use crate::metrics::{Event, EventKind, Metrics};
use crate::strand::Strand;
use crate::thrombectomy::Procedure;

mod apply;
mod command;
mod contrast;
mod demonstration;
mod exchange;
mod fidelity;
mod hand;
mod hemo;
mod measure;
mod observe;
mod operator;
mod physics;
mod snapshot;
mod thrombectomy;
mod tips;

pub use command::{Command, Drive, RETRIEVE_SPEED_M_S};
pub use fidelity::{MAX_FIDELITY_LEVEL, fidelity_effort};
pub use hand::{DeviceLimits, PushLimit};
pub use hemo::LINKED_INJECTION_DELAY_S;
pub use snapshot::{Imaging, InstrumentState, Mode, Snapshot, WallContact};
pub use tips::MAX_ESCAPE_M;

use hand::{Hand, PendingExchange, start_hands};
use hemo::Hemo;
use operator::SceneOperator;
use tips::tracked_tip;

/// One session's simulation.
pub struct World {
    assets: Arc<SceneAssets>,
    strand: Strand,
    /// One per instrument, outermost first.
    hands: Vec<Hand>,
    active_device: usize,
    imaging: Imaging,
    hemo: Option<Hemo>,
    metrics: Metrics,
    step: u64,
    last_seq: u64,
    previous_tip: Vector3<f64>,
    events: Vec<Event>,
    proximal: [f64; 6],
    fidelity: u8,
    /// Each instrument's tip (None: withdrawn) and inserted length after the last step.
    previous_instruments: Vec<(Option<Vector3<f64>>, f64)>,
    /// An exchange under way: the instrument (and those inside it) being withdrawn to the
    /// hub of the one around it, then replaced.
    exchanging: Option<PendingExchange>,
    /// The thrombectomy of a clotted scene with flow.
    procedure: Option<Procedure>,
    /// The scene's scripted operator, while it demonstrates.
    demonstration: Option<SceneOperator>,
    /// The world applies its own operator's commands (they do not end a demonstration).
    operating: bool,
}

impl std::fmt::Debug for World {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("World")
            .field("scene", &self.assets.spec.name)
            .field("step", &self.step)
            .finish_non_exhaustive()
    }
}

impl World {
    /// Advances one physics step (and contrast every few steps). Divergence puts the device
    /// back at its start, reports it and counts it; the world stays usable.
    pub fn step(&mut self) -> Result<()> {
        let dt = self.assets.spec.time_step_s();
        self.demonstrate()?;
        self.advance_exchange()?;
        self.step_physics(dt)?;
        self.advance_clock(dt);
        self.measure_wall_forces();
        self.track_target();
        self.feel_reactions();
        self.instrument_metrics(dt);
        self.step_procedure(dt)?;
        self.step_contrast(dt)?;
        Ok(())
    }

    /// The scene's start: its first device inserted, pedal up, the scene's C-arm pose.
    pub fn new(assets: Arc<SceneAssets>) -> Result<Self> {
        let strand = Strand::start(&assets, 0)?;
        let (hemo, reperfusion) = Hemo::start(&assets)?;
        let rate = assets.spec.fluoroscopy.pulse_rate;
        let pulse_rate = if rate < 10.0 {
            PulseRate::Hz7_5
        } else if rate > 20.0 {
            PulseRate::Hz30
        } else {
            PulseRate::Hz15
        };
        let tip = tracked_tip(&assets, &strand);
        let target_remaining_m = assets.remaining_to_target_m(&Point3::from(tip));
        let hands = start_hands(&assets, 0);
        let procedure = match (&assets.network, assets.clots.is_empty()) {
            (Some(network), false) => {
                let legs: Vec<(usize, f64, f64)> = assets
                    .route
                    .legs
                    .iter()
                    .map(|l| (l.branch, l.from_arc, l.to_arc))
                    .collect();
                let reds: Vec<f64> = assets
                    .spec
                    .clots
                    .iter()
                    .map(|c| c.red_cell_fraction)
                    .collect();
                Some(Procedure::new(&assets.clots, &reds, network, &legs))
            }
            _ => None,
        };
        Ok(Self {
            imaging: Imaging {
                pedal: false,
                pulse_rate,
                mode: Mode::Fluoroscopy,
                primary_deg: assets.spec.carm.primary_deg,
                secondary_deg: assets.spec.carm.secondary_deg,
                dsa_run: 0,
                dsa_pose: None,
            },
            assets,
            strand,
            hands,
            active_device: 0,
            hemo,
            metrics: Metrics {
                target_remaining_m,
                reperfusion,
                ..Metrics::default()
            },
            step: 0,
            last_seq: 0,
            previous_tip: tip,
            events: Vec::new(),
            proximal: [0.0; 6],
            fidelity: 0,
            previous_instruments: Vec::new(),
            exchanging: None,
            procedure,
            demonstration: None,
            operating: false,
        })
    }

    /// The scene.
    pub fn assets(&self) -> &Arc<SceneAssets> {
        &self.assets
    }

    /// The sequence number of the last command applied.
    pub fn last_seq(&self) -> u64 {
        self.last_seq
    }

    /// The overload governor's level in force.
    pub fn fidelity_level(&self) -> u8 {
        self.fidelity
    }

    /// Steps taken.
    pub fn step_index(&self) -> u64 {
        self.step
    }

    /// The navigated device of a one-device scene (read-only: scripted drivers look at it to
    /// choose commands); `None` for a stack.
    pub fn navigation(&self) -> Option<&Navigation<SharedWall>> {
        self.strand.navigation()
    }

    /// What the hands hold: one device or the stack.
    pub fn strand(&self) -> &Strand {
        &self.strand
    }

    /// Sleep at rest on or off for the devices in hand (until one is put back at its start,
    /// which takes the scene's `fidelity.sleep_at_rest`): for benchmarks that compare.
    pub fn set_sleep(&mut self, on: bool) {
        self.strand.set_sleep(on);
    }

    /// Metrics so far.
    pub fn metrics(&self) -> &Metrics {
        &self.metrics
    }

    /// Events since the last call.
    pub fn take_events(&mut self) -> Vec<Event> {
        std::mem::take(&mut self.events)
    }

    fn event(&mut self, kind: EventKind, message: impl Into<String>) {
        self.events.push(Event {
            step: self.step,
            time_s: self.metrics.procedure_time_s,
            kind,
            message: message.into(),
        });
    }

    /// The thrombectomy's figures, when the scene has a clot.
    pub fn procedure(&self) -> Option<&Procedure> {
        self.procedure.as_ref()
    }

    /// The flow with the clots now and no injection (vessel i = graph branch i, then any
    /// collaterals), when the scene has flow.
    pub fn flow_now(&self) -> Option<&FlowSolution> {
        self.hemo.as_ref().map(|h| &h.flow_now)
    }

    /// The clots in the flow now.
    pub fn clots(&self) -> Vec<cathlab_hemo::Occlusion> {
        self.hemo
            .as_ref()
            .map_or_else(Vec::new, |h| h.solver.occlusions().copied().collect())
    }

    /// Whether the scene's scripted operator is driving (a demonstration under way).
    pub fn demonstrating(&self) -> bool {
        self.demonstration.is_some()
    }

    /// The imaging state the trainee set.
    pub fn imaging(&self) -> Imaging {
        self.imaging
    }

    /// The leading tip (anatomy frame, m).
    pub fn leading_tip(&self) -> Vector3<f64> {
        self.strand.leading_tip()
    }
}
