//! A stack's data and its handling between steps: the coupling, the strand's nodes, the
//! [`Stack`] itself, its construction and validation, and its accessors and commands.

use nalgebra::{UnitQuaternion, Vector3};

use super::composite::{composite_spec, nominal_spacing};
use super::instrument::{
    Instrument, InstrumentSpec, MAX_INSTRUMENTS, around, check_fit, inserted_range,
};
use crate::beam::{BeamModel, ContactStep, ElementSpec};
use crate::coupled::CoupledContact;
use crate::device::Device;
use crate::error::{PhysicsError, Result, require_finite, require_positive};
use crate::navigation::{
    ClearanceCache, Command, Effort, Insertion, NavigationSettings, Stillness, Twist,
    solver_settings,
};
use crate::wall::{FreeSpace, Wall};

/// How a stack couples its instruments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Coupling {
    /// One composite beam where instruments overlap (the fast default).
    #[default]
    Merged,
    /// Each instrument its own chain, an inner one in contact with the lumen of the one
    /// around it (radial clearance, lumen friction): the reference, and a fidelity option.
    Nested,
}

/// Two instrument tips closer than this fraction of the tip element along the path share one
/// node (the geometry at each tip stays exact: [`Stack::tip_position`] evaluates the curve at
/// the inserted length; only which element a sliver of overlap belongs to is rounded).
pub(super) const SHARED_TIP_FRACTION: f64 = 0.2;

/// Ordinary nodes keep at least this fraction of the tip element from their neighbours.
pub(super) const MIN_GAP_FRACTION: f64 = 0.3;

/// A node of the strand.
#[derive(Debug, Clone, Copy)]
pub(super) struct Node {
    /// Path coordinate from the entry point (m).
    pub(super) sigma: f64,
    /// Stable identifier: an element keeps its rest geometry while its two nodes do.
    pub(super) id: u64,
    pub(super) position: Vector3<f64>,
    pub(super) rotation: UnitQuaternion<f64>,
}

/// A coaxial stack of instruments navigated through a vessel in merged mode.
#[derive(Debug, Clone)]
pub struct Stack<W: Wall> {
    pub(super) instruments: Vec<Instrument>,
    pub(super) wall: W,
    pub(super) settings: NavigationSettings,
    pub(super) model: BeamModel,
    pub(super) nodes: Vec<Node>,
    /// Rest geometry of every element and the node ids it was built between.
    pub(super) specs: Vec<(ElementSpec, u64, u64)>,
    pub(super) next_id: u64,
    pub(super) entry_position: Vector3<f64>,
    pub(super) entry_rotation: UnitQuaternion<f64>,
    pub(super) time_s: f64,
    pub(super) last: Option<ContactStep>,
    /// Path coordinates and local forces of the last contacts (for warm starts).
    pub(super) previous_contacts: Vec<(f64, Vector3<f64>)>,
    pub(super) coupling: Coupling,
    /// Nested mode: each instrument's own chain (a one-instrument stack), `None` while it
    /// lies within one tip element of the entry.
    pub(super) chains: Vec<Option<Stack<FreeSpace>>>,
    /// Nested mode: the last step's contacts (for warm starts and the penetration check).
    pub(super) nested_last: NestedStep,
    /// The work cap of the following steps (an overload governor lowers it).
    pub(super) effort: Effort,
    /// Wall-distance bounds that spare collision points their probes.
    pub(super) clearance: ClearanceCache,
    /// The share of a time step the next solve covers (½ⁿ in a step halved n times).
    pub(super) step_fraction: f64,
    /// The exits in series with their cables in the solve under way: (instrument, exit
    /// node) (`stack/slide.rs`).
    pub(super) series: Vec<(usize, usize)>,
    /// Whether the model carries tip loads (cleared when none is left).
    pub(super) tip_loaded: bool,
    /// How long the stack has been at rest ([`NavigationSettings::sleep`]).
    pub(super) stillness: Stillness,
}

/// Nested mode's record of the last step.
#[derive(Debug, Clone, Default)]
pub(super) struct NestedStep {
    /// The contacts, in the order they were solved.
    pub(super) contacts: Vec<CoupledContact>,
    /// Path coordinate of each contact's first side (m).
    pub(super) sigma: Vec<f64>,
    /// Local forces of each contact (N).
    pub(super) local: Vec<Vector3<f64>>,
    /// Largest penetration found after the solve (m).
    pub(super) penetration_m: f64,
}

impl<W: Wall> Stack<W> {
    /// A stack of `instruments` (outermost first) in merged mode through the entry point at
    /// `entry_position`, heading along `entry_direction`, in the composite rest shape.
    pub fn new(
        instruments: Vec<InstrumentSpec>,
        wall: W,
        entry_position: Vector3<f64>,
        entry_direction: Vector3<f64>,
        settings: NavigationSettings,
    ) -> Result<Self> {
        Self::with_coupling(
            instruments,
            wall,
            entry_position,
            entry_direction,
            settings,
            Coupling::Merged,
        )
    }

    /// A stack as [`Self::new`] makes it, with the instruments coupled as `coupling` says. In
    /// nested mode every instrument starts on the centre line of the one around it.
    pub fn with_coupling(
        instruments: Vec<InstrumentSpec>,
        wall: W,
        entry_position: Vector3<f64>,
        entry_direction: Vector3<f64>,
        settings: NavigationSettings,
        coupling: Coupling,
    ) -> Result<Self> {
        if instruments.is_empty() || instruments.len() > MAX_INSTRUMENTS {
            return Err(PhysicsError::OutOfRange {
                what: "number of instruments in a stack".into(),
                range: "1 to 4",
                value: instruments.len() as f64,
            });
        }
        validate_settings(&settings)?;
        for (i, v) in entry_position
            .iter()
            .chain(entry_direction.iter())
            .enumerate()
        {
            require_finite(|| format!("entry pose component {i}"), *v)?;
        }
        let direction =
            entry_direction
                .try_normalize(1e-12)
                .ok_or_else(|| PhysicsError::OutOfRange {
                    what: "entry direction length".into(),
                    range: "non-zero",
                    value: entry_direction.norm(),
                })?;
        let entry_rotation = UnitQuaternion::rotation_between(&Vector3::x(), &direction)
            .unwrap_or_else(|| {
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI)
            });
        for spec in &instruments {
            spec.device.validate()?;
        }
        for pair in instruments.windows(2) {
            check_fit(&pair[0].device, &pair[1].device)?;
        }
        let mut states = Vec::with_capacity(instruments.len());
        for (i, spec) in instruments.into_iter().enumerate() {
            let name = spec.device.name.clone();
            require_finite(|| format!("\"{name}\": twist_rad"), spec.twist_rad)?;
            require_positive(
                || format!("\"{name}\": max_insertion_speed_m_s"),
                spec.max_insertion_speed_m_s,
            )?;
            require_positive(
                || format!("\"{name}\": max_twist_rate_rad_s"),
                spec.max_twist_rate_rad_s,
            )?;
            let length_m = spec.device.length_m();
            let state = Instrument::new(
                spec.device,
                spec.inserted_m,
                spec.twist_rad,
                spec.max_insertion_speed_m_s,
                spec.max_twist_rate_rad_s,
            );
            let outer = states
                .last()
                .map(|o: &Instrument| (o.inserted_m, o.length_m));
            let (lo, hi) = inserted_range(outer, length_m, settings.tip_element_m);
            if !(spec.inserted_m >= lo && spec.inserted_m <= hi) {
                return Err(PhysicsError::OutOfRange {
                    what: format!("initial inserted length of instrument {i} \"{name}\" (m)"),
                    range: if i == 0 {
                        "between the tip element length and the device length"
                    } else {
                        "between the hub of the instrument around it and that hub plus the device length"
                    },
                    value: spec.inserted_m,
                });
            }
            states.push(state);
        }
        // Initial nodes: key points (entry, tips) with the nominal spacing between them, the
        // strand in its composite rest shape.
        let end = states.iter().map(|s| s.inserted_m).fold(f64::MIN, f64::max);
        let mut keys: Vec<f64> = vec![0.0, end];
        keys.extend(
            states
                .iter()
                .map(|s| s.inserted_m)
                .filter(|&l| l > 0.0 && l < end),
        );
        let snap = SHARED_TIP_FRACTION * settings.tip_element_m;
        keys.retain(|&k| k == 0.0 || k == end || (k > snap && k < end - snap));
        keys.sort_by(f64::total_cmp);
        keys.dedup_by(|a, b| (*a - *b).abs() <= snap);
        let mut sigma = vec![0.0];
        for pair in keys.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            let mut interior = Vec::new();
            let mut at = b;
            loop {
                let h = nominal_spacing(&settings, &states, at);
                let next = at - h;
                if next <= a + 0.5 * h {
                    break;
                }
                interior.push(next);
                at = next;
            }
            sigma.extend(interior.into_iter().rev());
            sigma.push(b);
        }
        let twist0 = states[0].twist_rad;
        let specs: Vec<ElementSpec> = sigma
            .windows(2)
            .map(|w| composite_spec(&states, w[0], w[1], settings.axial_slide))
            .collect();
        let base_rotation =
            entry_rotation * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), twist0);
        let model = BeamModel::new(
            &specs,
            entry_position,
            base_rotation,
            solver_settings(&settings, 1.0),
        )?;
        let nodes: Vec<Node> = sigma
            .iter()
            .enumerate()
            .map(|(k, &s)| Node {
                sigma: s,
                id: k as u64,
                position: model.positions()[k],
                rotation: model.rotations()[k],
            })
            .collect();
        let specs = specs
            .into_iter()
            .enumerate()
            .map(|(e, spec)| (spec, e as u64, e as u64 + 1))
            .collect();
        for state in &mut states {
            let l = state.inserted_m;
            state.tip_node = (l > snap && l < end - snap)
                .then(|| nodes.iter().find(|n| (n.sigma - l).abs() <= snap))
                .flatten()
                .map(|n| n.id);
        }
        let mut stack = Self {
            next_id: nodes.len() as u64,
            instruments: states,
            wall,
            settings,
            model,
            nodes,
            specs,
            entry_position,
            entry_rotation,
            time_s: 0.0,
            last: None,
            previous_contacts: Vec::new(),
            coupling,
            chains: Vec::new(),
            nested_last: NestedStep::default(),
            tip_loaded: false,
            effort: Effort::FULL,
            clearance: ClearanceCache::default(),
            stillness: Stillness::default(),
            step_fraction: 1.0,
            series: Vec::new(),
        };
        if coupling == Coupling::Nested {
            stack.update_chains()?;
        }
        Ok(stack)
    }

    /// Caps the work of the following steps: step halvings, detection rounds, contact sweeps,
    /// polish and refinement, as for a single device ([`Effort`]).
    pub fn set_effort(&mut self, effort: Effort) -> Result<()> {
        effort.validate()?;
        if effort != self.effort {
            self.stillness.wake();
        }
        self.effort = effort;
        Ok(())
    }

    /// Sleep at rest on (`Some`) or off (see [`NavigationSettings::sleep`]); counts the quiet
    /// steps afresh.
    pub fn set_sleep(&mut self, sleep: Option<crate::navigation::Sleep>) {
        self.stillness.wake();
        self.settings.sleep = sleep;
    }

    /// The work cap in force.
    pub fn effort(&self) -> Effort {
        self.effort
    }

    /// How the instruments are coupled.
    pub fn coupling(&self) -> Coupling {
        self.coupling
    }

    /// Number of instruments.
    pub fn len(&self) -> usize {
        self.instruments.len()
    }

    /// Whether the stack is empty (never: a stack has at least one instrument).
    pub fn is_empty(&self) -> bool {
        self.instruments.is_empty()
    }

    /// Replaces instrument `index`'s command (applied from the next step on).
    pub fn set_command(&mut self, index: usize, command: Command) -> Result<()> {
        self.check_index(index)?;
        let value = match command.insertion {
            Insertion::Velocity(v) | Insertion::Target(v) => v,
        };
        require_finite(|| format!("instrument {index}: insertion command"), value)?;
        let value = match command.twist {
            Twist::Rate(v) | Twist::Target(v) => v,
        };
        require_finite(|| format!("instrument {index}: twist command"), value)?;
        self.instruments[index].command = command;
        Ok(())
    }

    /// Instrument `index`'s command in force.
    pub fn command(&self, index: usize) -> Option<Command> {
        self.instruments.get(index).map(|i| i.command)
    }

    /// Instrument `index`'s device.
    pub fn device(&self, index: usize) -> Option<&Device> {
        self.instruments.get(index).map(|i| &i.device)
    }

    /// Inserted length of instrument `index` at its hand (m): how far its tip would lie beyond
    /// the entry point unstrained, and does unless it slides inside the one around it
    /// ([`NavigationSettings::axial_slide`]; see [`Self::tip_inserted_m`]).
    pub fn inserted_m(&self, index: usize) -> Option<f64> {
        self.instruments.get(index).map(|i| i.hand_m)
    }

    /// How far instrument `index`'s tip lies beyond the entry point (m): its inserted length
    /// at the hand less the compression of its length inside the one around it.
    pub fn tip_inserted_m(&self, index: usize) -> Option<f64> {
        self.instruments.get(index).map(|i| i.inserted_m)
    }

    /// Twist of instrument `index` at the entry point (rad).
    pub fn twist_rad(&self, index: usize) -> Option<f64> {
        self.instruments.get(index).map(|i| i.twist_rad)
    }

    /// The range instrument `index`'s inserted length may take now (m): from the hub of the
    /// instrument around it (withdrawn completely) to where its own hub meets that hub; for
    /// the outermost, from one tip element to its length.
    pub fn inserted_range_m(&self, index: usize) -> Option<(f64, f64)> {
        let instrument = self.instruments.get(index)?;
        Some(inserted_range(
            around(&self.instruments, index),
            instrument.length_m,
            self.settings.tip_element_m,
        ))
    }

    /// The wall.
    pub fn wall(&self) -> &W {
        &self.wall
    }

    /// The strand's beam model (merged mode: all instruments on one chain; nested mode: the
    /// outermost instrument's chain).
    pub fn model(&self) -> &BeamModel {
        match self.coupling {
            Coupling::Merged => &self.model,
            Coupling::Nested => self.chain(0).model(),
        }
    }

    /// Mutable access to the strand's beam model, for loads and static solves in tests and
    /// benchmarks; the next [`Self::step`] rebuilds the discretization from the instruments
    /// and restores the navigation's solver settings and loads.
    pub fn model_mut(&mut self) -> &mut BeamModel {
        match self.coupling {
            Coupling::Merged => &mut self.model,
            Coupling::Nested => self.chains[0]
                .as_mut()
                .expect("the outermost chain is always present")
                .model_mut(),
        }
    }

    /// The beam model that carries instrument `index`: the strand in merged mode, its own
    /// chain in nested mode (`None` there while it lies within one tip element of the entry).
    pub fn instrument_model(&self, index: usize) -> Option<&BeamModel> {
        match self.coupling {
            Coupling::Merged => (index < self.instruments.len()).then_some(&self.model),
            Coupling::Nested => self.chains.get(index)?.as_ref().map(|c| c.model()),
        }
    }

    /// Path coordinate of every node (m from the entry point), base to tip (nested mode: of
    /// the outermost instrument's chain).
    pub fn node_sigma_m(&self) -> Vec<f64> {
        match self.coupling {
            Coupling::Merged => self.nodes.iter().map(|n| n.sigma).collect(),
            Coupling::Nested => self.chain(0).node_sigma_m(),
        }
    }

    /// Nested mode: chain `index`, which must be present.
    pub(super) fn chain(&self, index: usize) -> &Stack<FreeSpace> {
        self.chains[index]
            .as_ref()
            .expect("the chain asked for is present")
    }

    /// Simulated time (s).
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// The contacts and forces of the last step (merged mode; `None` in nested mode, whose
    /// contacts join chains: see [`Self::nested_contacts`]).
    pub fn last_contacts(&self) -> Option<&ContactStep> {
        self.last.as_ref()
    }

    pub(super) fn check_index(&self, index: usize) -> Result<()> {
        if index < self.instruments.len() {
            Ok(())
        } else {
            Err(PhysicsError::Stack(format!(
                "no instrument {index}: the stack has {}",
                self.instruments.len()
            )))
        }
    }
}

/// Checks the discretization and control settings.
fn validate_settings(settings: &NavigationSettings) -> Result<()> {
    require_positive(|| "time_step_s".into(), settings.time_step_s)?;
    require_positive(|| "tip_element_m".into(), settings.tip_element_m)?;
    require_positive(|| "shaft_element_m".into(), settings.shaft_element_m)?;
    require_positive(|| "tip_zone_m".into(), settings.tip_zone_m)?;
    require_positive(|| "sample_spacing_m".into(), settings.sample_spacing_m)?;
    require_finite(|| "contact_margin_m".into(), settings.contact_margin_m)?;
    if let Some(refinement) = settings.refinement {
        require_positive(|| "refinement.max_bend_rad".into(), refinement.max_bend_rad)?;
        require_positive(
            || "refinement.contact_element_m".into(),
            refinement.contact_element_m,
        )?;
    }
    Ok(())
}
