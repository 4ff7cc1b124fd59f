//! Coaxial device stacks: one to four instruments (a guide or sheath, a catheter, a
//! microcatheter, a wire), outermost first, each pushed, pulled and twisted at the entry point
//! on its own, simulated in merged mode as one composite beam.
//!
//! Every instrument `i` is placed by its inserted length ℓᵢ: how far its tip lies beyond the
//! entry point along the path (negative while it is still proximal of the entry inside the
//! instrument around it). The simulated strand runs from the entry (path coordinate σ = 0) to
//! the leading tip (σ = max ℓᵢ); at σ the instruments with ℓᵢ > σ are present, the material
//! point of instrument `i` there being Lᵢ − ℓᵢ + σ from its proximal end.
//!
//! **Merged mode.** Where instruments overlap they bend together, so the strand is one chain
//! of nodes and the beam model, its O(N) solver and the O(M + N) contact solver apply
//! unchanged. Each element is a composite: EA, EI, GJ and κGA summed over the instruments
//! present on it; its rest curvature the stiffness-weighted blend of theirs, each turned by
//! its instrument's twist relative to the strand's (the outermost instrument's). Nodes stay
//! on the path where the strand already lies (a sliding instrument moves *through* them),
//! every instrument tip inside the strand is a node, and the leading instrument's free shaped
//! part is carried rigidly as it advances (follow the leader without straining a curved tip,
//! as in [`crate::navigation`]). Spacing is that of the outermost instrument present (fine
//! near its tip), refined where the strand bends or touches the wall. The outermost instrument
//! present at a point takes the wall contact there with its radius and wall friction.

use std::collections::HashMap;

mod nested;

use nalgebra::{UnitQuaternion, Vector3};

use crate::beam::{
    BeamModel, ContactStep, ElementSpec, SolverSettings, StepMode, ViscousDrag, hermite_point,
};
use crate::device::Device;
use crate::error::{PhysicsError, Result, require_finite, require_positive};
use crate::navigation::{
    ClearanceCache, Command, Effort, Insertion, NavigationSettings, Sample, Twist, detect,
    material_of, push_element_samples, spacing, warm_start,
};
use crate::section::BeamProperties;
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

/// Most instruments in one stack.
pub const MAX_INSTRUMENTS: usize = 4;

/// How many times a step may be halved when it would penetrate the wall.
const MAX_SUBSTEP_DEPTH: usize = 3;

/// Two instrument tips closer than this fraction of the tip element along the path share one
/// node (the geometry at each tip stays exact: [`Stack::tip_position`] evaluates the curve at
/// the inserted length; only which element a sliver of overlap belongs to is rounded).
const SHARED_TIP_FRACTION: f64 = 0.2;

/// Ordinary nodes keep at least this fraction of the tip element from their neighbours.
const MIN_GAP_FRACTION: f64 = 0.3;

/// An instrument to put in a stack: the device, where it starts and how fast the operator's
/// hand may move it.
#[derive(Debug, Clone, PartialEq)]
pub struct InstrumentSpec {
    /// The device.
    pub device: Device,
    /// Initial inserted length (m): how far the tip lies beyond the entry point. The
    /// outermost instrument needs at least one tip element; an inner one may start inside the
    /// one around it (any value down to that one's hub).
    pub inserted_m: f64,
    /// Initial twist at the entry point (rad).
    pub twist_rad: f64,
    /// Largest insertion speed either way (m/s).
    pub max_insertion_speed_m_s: f64,
    /// Largest twist rate either way (rad/s).
    pub max_twist_rate_rad_s: f64,
}

impl InstrumentSpec {
    /// `device` inserted `inserted_m` (m), untwisted, with the speed limits of `settings`.
    pub fn new(device: Device, inserted_m: f64, settings: &NavigationSettings) -> Self {
        Self {
            device,
            inserted_m,
            twist_rad: 0.0,
            max_insertion_speed_m_s: settings.max_insertion_speed_m_s,
            max_twist_rate_rad_s: settings.max_twist_rate_rad_s,
        }
    }
}

/// One instrument's state.
#[derive(Debug, Clone)]
struct Instrument {
    device: Device,
    length_m: f64,
    /// Material coordinate where the distal shaped part starts (m), if any.
    shaped_from_m: Option<f64>,
    inserted_m: f64,
    twist_rad: f64,
    command: Command,
    max_insertion_speed_m_s: f64,
    max_twist_rate_rad_s: f64,
    /// Identifier of the node at this instrument's tip while the tip is inside the strand
    /// (neither withdrawn nor leading).
    tip_node: Option<u64>,
    /// Axial load on the tip (N, along its tangent, positive forward), from the next step
    /// on: what a clot asks of a tip crossing it.
    tip_load_n: f64,
}

/// A node of the strand.
#[derive(Debug, Clone, Copy)]
struct Node {
    /// Path coordinate from the entry point (m).
    sigma: f64,
    /// Stable identifier: an element keeps its rest geometry while its two nodes do.
    id: u64,
    position: Vector3<f64>,
    rotation: UnitQuaternion<f64>,
}

/// What one stack step did.
#[derive(Debug, Clone, PartialEq)]
pub struct StackReport {
    /// Contacts detected.
    pub contacts: usize,
    /// Contacts with a positive normal force.
    pub active_contacts: usize,
    /// Gauss–Seidel sweeps.
    pub sweeps: usize,
    /// Whether Gauss–Seidel met its tolerance.
    pub converged: bool,
    /// Inserted length of every instrument after the step (m), outermost first.
    pub inserted_m: Vec<f64>,
    /// Elements simulated.
    pub elements: usize,
}

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

/// A coaxial stack of instruments navigated through a vessel in merged mode.
#[derive(Debug, Clone)]
pub struct Stack<W: Wall> {
    instruments: Vec<Instrument>,
    wall: W,
    settings: NavigationSettings,
    model: BeamModel,
    nodes: Vec<Node>,
    /// Rest geometry of every element and the node ids it was built between.
    specs: Vec<(ElementSpec, u64, u64)>,
    next_id: u64,
    entry_position: Vector3<f64>,
    entry_rotation: UnitQuaternion<f64>,
    time_s: f64,
    last: Option<ContactStep>,
    /// Path coordinates and local forces of the last contacts (for warm starts).
    previous_contacts: Vec<(f64, Vector3<f64>)>,
    coupling: Coupling,
    /// Nested mode: each instrument's own chain (a one-instrument stack), `None` while it
    /// lies within one tip element of the entry.
    chains: Vec<Option<Stack<FreeSpace>>>,
    /// Nested mode: the last step's contacts (for warm starts and the penetration check).
    nested_last: nested::NestedStep,
    /// The work cap of the following steps (an overload governor lowers it).
    effort: Effort,
    /// Wall-distance bounds that spare collision points their probes.
    clearance: ClearanceCache,
    /// Whether the model carries tip loads (cleared when none is left).
    tip_loaded: bool,
}

/// Everything [`Stack::advance`] needs to undo a step.
#[derive(Debug, Clone)]
struct Saved {
    model: crate::beam::BeamSnapshot,
    nodes: Vec<Node>,
    specs: Vec<(ElementSpec, u64, u64)>,
    instruments: Vec<Instrument>,
    previous_contacts: Vec<(f64, Vector3<f64>)>,
    next_id: u64,
    chains: Vec<Option<Stack<FreeSpace>>>,
    nested_last: nested::NestedStep,
}

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
        self.stack.instruments[self.index].inserted_m
    }
}

/// Checks that `inner` fits the lumen of `outer`: its largest outer diameter is smaller than
/// the smallest inner diameter of `outer`.
pub fn check_fit(outer: &Device, inner: &Device) -> Result<()> {
    let lumen = outer
        .sections
        .iter()
        .map(|s| 2.0 * s.cross_section.inner_radius_m)
        .fold(f64::INFINITY, f64::min);
    let diameter = inner
        .sections
        .iter()
        .map(|s| 2.0 * s.cross_section.outer_radius_m)
        .fold(0.0, f64::max);
    if diameter < lumen {
        Ok(())
    } else {
        Err(PhysicsError::StackFit {
            inner: inner.name.clone(),
            outer: outer.name.clone(),
            inner_diameter_mm: diameter * 1e3,
            lumen_mm: lumen * 1e3,
        })
    }
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
            let state = Instrument {
                shaped_from_m: spec.device.shaped_from_m(),
                length_m,
                inserted_m: spec.inserted_m,
                twist_rad: spec.twist_rad,
                command: Command::default(),
                max_insertion_speed_m_s: spec.max_insertion_speed_m_s,
                max_twist_rate_rad_s: spec.max_twist_rate_rad_s,
                tip_node: None,
                tip_load_n: 0.0,
                device: spec.device,
            };
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
            .map(|w| composite_spec(&states, w[0], w[1]))
            .collect();
        let base_rotation =
            entry_rotation * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), twist0);
        let model = BeamModel::new(
            &specs,
            entry_position,
            base_rotation,
            solver_settings(&settings),
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
            nested_last: nested::NestedStep::default(),
            tip_loaded: false,
            effort: Effort::FULL,
            clearance: ClearanceCache::default(),
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
        self.effort = effort;
        Ok(())
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

    /// Inserted length of instrument `index` (m): how far its tip lies beyond the entry point.
    pub fn inserted_m(&self, index: usize) -> Option<f64> {
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
    fn chain(&self, index: usize) -> &Stack<FreeSpace> {
        self.chains[index]
            .as_ref()
            .expect("the chain asked for is present")
    }

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

    /// Simulated time (s).
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// The contacts and forces of the last step (merged mode; `None` in nested mode, whose
    /// contacts join chains: see [`Self::nested_contacts`]).
    pub fn last_contacts(&self) -> Option<&ContactStep> {
        self.last.as_ref()
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
    /// 0 when nothing penetrates), over the collision points.
    pub fn max_penetration_m(&self) -> f64 {
        if self.coupling == Coupling::Nested {
            return self.nested_max_penetration();
        }
        let positions = self.model.positions();
        self.sample_layout()
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

    /// What each instrument's hand feels (outermost first): the strand's base reaction along
    /// and about the entry axis, shared among the instruments at the entry in proportion to
    /// their axial (force) and torsional (torque) stiffness; in nested mode each instrument's
    /// own chain's base reaction. Instruments withdrawn proximal of the entry feel nothing.
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
        present
            .iter()
            .map(|p| match p {
                Some(p) => ProximalReaction {
                    axial_force_n: force * p.axial_stiffness_n / ea,
                    torque_nm: torque * p.torsional_stiffness_nm2 / gj,
                },
                None => ProximalReaction {
                    axial_force_n: 0.0,
                    torque_nm: 0.0,
                },
            })
            .collect()
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

    /// Adds `device` as the new innermost instrument, its tip at the hub of the one around it
    /// (to be pushed in), as an operator loads a microwire into a microcatheter.
    pub fn push_instrument(&mut self, device: Device) -> Result<()> {
        if self.instruments.len() >= MAX_INSTRUMENTS {
            return Err(PhysicsError::OutOfRange {
                what: "number of instruments in a stack".into(),
                range: "1 to 4",
                value: (self.instruments.len() + 1) as f64,
            });
        }
        device.validate()?;
        let outer = self.instruments.last().expect("a stack has an instrument");
        check_fit(&outer.device, &device)?;
        let (lo, _) = inserted_range(
            Some((outer.inserted_m, outer.length_m)),
            device.length_m(),
            self.settings.tip_element_m,
        );
        let (speed, rate) = (outer.max_insertion_speed_m_s, outer.max_twist_rate_rad_s);
        self.instruments.push(Instrument {
            length_m: device.length_m(),
            shaped_from_m: device.shaped_from_m(),
            inserted_m: lo,
            twist_rad: 0.0,
            command: Command::default(),
            max_insertion_speed_m_s: speed,
            max_twist_rate_rad_s: rate,
            tip_node: None,
            tip_load_n: 0.0,
            device,
        });
        Ok(())
    }

    /// Removes the innermost instrument (not the only one), which must be withdrawn to the hub
    /// of the one around it; returns its device.
    pub fn pop_instrument(&mut self) -> Result<Device> {
        let index = self.instruments.len() - 1;
        if index == 0 {
            return Err(PhysicsError::Stack(
                "the outermost instrument cannot be removed".into(),
            ));
        }
        let instrument = &self.instruments[index];
        let (lo, _) = inserted_range(
            around(&self.instruments, index),
            instrument.length_m,
            self.settings.tip_element_m,
        );
        if instrument.inserted_m > lo + 1e-12 {
            return Err(PhysicsError::Stack(format!(
                "instrument {index} \"{}\" is still inserted {:.1} mm beyond the hub of the one around it; withdraw it before removing it",
                instrument.device.name,
                (instrument.inserted_m - lo) * 1e3
            )));
        }
        Ok(self.instruments.pop().expect("checked above").device)
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

    /// Puts the instruments' tip loads on the merged model (after it is rebuilt).
    fn apply_tip_loads(&mut self) -> Result<()> {
        if self.instruments.iter().all(|i| i.tip_load_n == 0.0) && !self.tip_loaded {
            return Ok(());
        }
        self.model.clear_loads();
        self.tip_loaded = false;
        for k in 0..self.instruments.len() {
            let load = self.instruments[k].tip_load_n;
            if load == 0.0 {
                continue;
            }
            if let Some(i) = self.tip_node_index(k) {
                let axis = self.nodes[i].rotation * Vector3::x();
                self.model.set_load(i, axis * load, Vector3::zeros())?;
                self.tip_loaded = true;
            }
        }
        Ok(())
    }

    /// Whether instrument `index` may be exchanged for `device` once withdrawn: not the
    /// outermost, a valid device that fits the one around it and the one inside it.
    pub fn check_exchange(&self, index: usize, device: &Device) -> Result<()> {
        self.check_index(index)?;
        if index == 0 {
            return Err(PhysicsError::Stack(
                "the outermost instrument cannot be exchanged".into(),
            ));
        }
        device.validate()?;
        check_fit(&self.instruments[index - 1].device, device)?;
        if let Some(inner) = self.instruments.get(index + 1) {
            check_fit(device, &inner.device)?;
        }
        Ok(())
    }

    /// The first instrument from `index` inward still inserted beyond the hub of the one
    /// around it, and by how much (m); `None` when all are withdrawn (an exchange may go on).
    pub fn still_inserted(&self, index: usize) -> Option<(usize, f64)> {
        self.instruments
            .iter()
            .enumerate()
            .skip(index)
            .find_map(|(k, instrument)| {
                let (lo, _) = inserted_range(
                    around(&self.instruments, k),
                    instrument.length_m,
                    self.settings.tip_element_m,
                );
                (instrument.inserted_m > lo + 1e-12).then_some((k, instrument.inserted_m - lo))
            })
    }

    /// Replaces instrument `index` (not the outermost) by `device`, as an operator exchanges a
    /// wire: allowed only while it, and everything inside it, is withdrawn to the hub of the
    /// instrument around it. The new device starts there, untwisted.
    pub fn exchange(&mut self, index: usize, device: Device) -> Result<()> {
        self.check_exchange(index, &device)?;
        if let Some((k, beyond_m)) = self.still_inserted(index) {
            return Err(PhysicsError::Stack(format!(
                "instrument {k} \"{}\" is still inserted {:.1} mm beyond the hub of the one around it; withdraw it before exchanging",
                self.instruments[k].device.name,
                beyond_m * 1e3
            )));
        }
        let (lo, _) = inserted_range(
            around(&self.instruments, index),
            device.length_m(),
            self.settings.tip_element_m,
        );
        let old = &self.instruments[index];
        self.instruments[index] = Instrument {
            length_m: device.length_m(),
            shaped_from_m: device.shaped_from_m(),
            inserted_m: lo,
            twist_rad: 0.0,
            command: Command::default(),
            max_insertion_speed_m_s: old.max_insertion_speed_m_s,
            max_twist_rate_rad_s: old.max_twist_rate_rad_s,
            tip_node: None,
            tip_load_n: 0.0,
            device,
        };
        Ok(())
    }

    /// Advances one time step: every instrument's proximal control (clamped speeds and
    /// ranges, outermost first), the kinematic update of the strand, detection, the beam solve
    /// with contacts.
    pub fn step(&mut self) -> Result<StackReport> {
        let dt = self.settings.time_step_s;
        let mut targets: Vec<(f64, f64)> = Vec::with_capacity(self.instruments.len());
        for index in 0..self.instruments.len() {
            let instrument = &self.instruments[index];
            let max_push = instrument.max_insertion_speed_m_s * dt;
            let wanted = match instrument.command.insertion {
                Insertion::Velocity(v) => v * dt,
                Insertion::Target(l) => l - instrument.inserted_m,
            }
            .clamp(-max_push, max_push);
            // The range follows the instruments around it at their new positions: a hub
            // pushes an inner instrument that has nowhere else to go.
            let outer = index
                .checked_sub(1)
                .map(|k| (targets[k].0, self.instruments[k].length_m));
            let (lo, hi) = inserted_range(outer, instrument.length_m, self.settings.tip_element_m);
            let inserted = (instrument.inserted_m + wanted).clamp(lo, hi);
            let max_turn = instrument.max_twist_rate_rad_s * dt;
            let turn = match instrument.command.twist {
                Twist::Rate(w) => w * dt,
                Twist::Target(a) => a - instrument.twist_rad,
            }
            .clamp(-max_turn, max_turn);
            targets.push((inserted, instrument.twist_rad + turn));
        }
        let report = self.advance(&targets, 0)?;
        self.time_s += dt;
        Ok(report)
    }

    /// Moves every instrument to `targets` (inserted length m, twist rad) in one solve, or,
    /// where that solve still penetrates the wall beyond the sub-step threshold, in two halves
    /// (up to [`MAX_SUBSTEP_DEPTH`] times).
    fn advance(&mut self, targets: &[(f64, f64)], depth: usize) -> Result<StackReport> {
        let saved: Option<Saved> =
            (depth < self.effort.substep_depth(MAX_SUBSTEP_DEPTH)).then(|| Saved {
                model: self.model.snapshot(),
                nodes: self.nodes.clone(),
                specs: self.specs.clone(),
                instruments: self.instruments.clone(),
                previous_contacts: self.previous_contacts.clone(),
                next_id: self.next_id,
                chains: self.chains.clone(),
                nested_last: self.nested_last.clone(),
            });
        let report = match self.coupling {
            Coupling::Merged => self.single_step(targets)?,
            Coupling::Nested => self.nested_step(targets)?,
        };
        let penetration = match self.coupling {
            Coupling::Merged => self.last.as_ref().map_or(0.0, |s| s.penetration_m),
            Coupling::Nested => self.nested_last.penetration_m,
        };
        if penetration > self.settings.substep_penetration_m
            && let Some(saved) = saved
        {
            self.model.restore(saved.model);
            self.nodes = saved.nodes;
            self.specs = saved.specs;
            self.previous_contacts = saved.previous_contacts;
            self.next_id = saved.next_id;
            self.chains = saved.chains;
            self.nested_last = saved.nested_last;
            let half: Vec<(f64, f64)> = saved
                .instruments
                .iter()
                .zip(targets)
                .map(|(i, t)| (0.5 * (i.inserted_m + t.0), 0.5 * (i.twist_rad + t.1)))
                .collect();
            self.instruments = saved.instruments;
            self.advance(&half, depth + 1)?;
            return self.advance(targets, depth + 1);
        }
        Ok(report)
    }

    /// The kinematic part of a step: moves the instruments to `targets` and the nodes with
    /// them, refines, rebuilds the model and places its base.
    fn prepare(&mut self, targets: &[(f64, f64)]) -> Result<()> {
        self.sync_nodes();
        self.move_instruments(targets)?;
        self.refine();
        self.rebuild_model()?;
        self.apply_tip_loads()?;
        let twist =
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), self.instruments[0].twist_rad);
        self.model
            .place_base(self.entry_position, self.entry_rotation * twist)
    }

    /// One solve: kinematic update, detection, beam solve with contacts.
    fn single_step(&mut self, targets: &[(f64, f64)]) -> Result<StackReport> {
        self.prepare(targets)?;
        let samples = self.sample_layout();
        let wall = &self.wall;
        let margin = self.settings.contact_margin_m;
        let sigma: Vec<f64> = self.nodes.iter().map(|n| n.sigma).collect();
        let previous = &self.previous_contacts;
        let tolerance = self.settings.sample_spacing_m;
        let clearance = &mut self.clearance;
        let step = self.model.step_with_contacts(
            |positions, _rotations, free| {
                Ok(detect(wall, &samples, positions, free, margin, clearance))
            },
            &self.effort.contact(&self.settings.contact),
            |contacts| warm_start(contacts, &sigma, previous, tolerance),
        )?;
        self.previous_contacts = step
            .contacts
            .iter()
            .zip(&step.response.local)
            .map(|(c, l)| (material_of(&sigma, c), *l))
            .collect();
        let report = StackReport {
            contacts: step.contacts.len(),
            active_contacts: step.response.local.iter().filter(|l| l.x > 0.0).count(),
            sweeps: step.response.iterations,
            converged: step.response.converged,
            inserted_m: self.instruments.iter().map(|i| i.inserted_m).collect(),
            elements: self.model.element_count(),
        };
        self.last = Some(step);
        self.sync_nodes();
        Ok(report)
    }

    /// Copies the model's node poses into the node list.
    fn sync_nodes(&mut self) {
        for ((node, p), q) in self
            .nodes
            .iter_mut()
            .zip(self.model.positions())
            .zip(self.model.rotations())
        {
            node.position = *p;
            node.rotation = *q;
        }
    }

    /// The kinematic predictor: moves the instruments to `targets` and the nodes with them.
    /// The leading instrument's free shaped part is carried rigidly along the tangent where it
    /// starts (the rest of the strand stays on its path: instruments slide through it); a
    /// new leading tip extends the strand along its tip tangent; a retreating one retraces
    /// its path. Tips inside the strand slide along the curve.
    fn move_instruments(&mut self, targets: &[(f64, f64)]) -> Result<()> {
        let old_end = self.nodes.last().map_or(0.0, |n| n.sigma);
        let old_leader = leader(&self.instruments);
        let old: Vec<f64> = self.instruments.iter().map(|i| i.inserted_m).collect();
        for (instrument, &(l, phi)) in self.instruments.iter_mut().zip(targets) {
            instrument.inserted_m = l;
            instrument.twist_rad = phi;
        }
        let new_leader = leader(&self.instruments);
        let new_end = self.instruments[new_leader].inserted_m;
        let others_old = (0..old.len())
            .filter(|&j| j != old_leader)
            .map(|j| old[j])
            .fold(0.0, f64::max);
        let others_new = (0..old.len())
            .filter(|&j| j != new_leader)
            .map(|j| self.instruments[j].inserted_m)
            .fold(0.0, f64::max);
        let delta = new_end - old_end;
        let min_gap = MIN_GAP_FRACTION * self.settings.tip_element_m;
        let snap = SHARED_TIP_FRACTION * self.settings.tip_element_m;
        if delta != 0.0 {
            let lead = &self.instruments[old_leader];
            let shaped_start = lead
                .shaped_from_m
                .map_or(old_end, |s| old[old_leader] - lead.length_m + s);
            let carry_from = shaped_start.max(others_old);
            let carry = new_leader == old_leader
                && (delta > 0.0 || carry_from + delta >= others_new + min_gap);
            if carry {
                // First node strictly beyond every other tip and at or beyond the shaped part.
                let last = self.nodes.len() - 1;
                let c = self
                    .nodes
                    .iter()
                    .position(|n| n.sigma > others_old + snap && n.sigma >= carry_from)
                    .unwrap_or(last)
                    .clamp(1, last);
                let tangent = self.nodes[c].rotation * Vector3::x();
                for node in &mut self.nodes[c..] {
                    node.sigma += delta;
                    node.position += tangent * delta;
                }
                if delta < 0.0 {
                    // Path nodes overrun by the retreating carried part.
                    let start = self.nodes[c].sigma;
                    let mut k = c - 1;
                    while k > 0 && self.nodes[k].sigma > start - min_gap {
                        self.nodes.remove(k);
                        k -= 1;
                    }
                }
            } else if delta > 0.0 {
                // A new leader emerges: extend along the tip tangent (moving the end node while
                // the extension is shorter than the smallest gap).
                let tip = *self.nodes.last().expect("a strand has nodes");
                let tangent = tip.rotation * Vector3::x();
                let node = Node {
                    sigma: new_end,
                    id: tip.id,
                    position: tip.position + tangent * delta,
                    rotation: tip.rotation,
                };
                if delta < min_gap && self.nodes.len() > 2 {
                    *self.nodes.last_mut().expect("a strand has nodes") = node;
                } else {
                    let id = self.fresh_id();
                    self.nodes.push(Node { id, ..node });
                }
            } else {
                // The strand retreats along its own path.
                let (position, rotation) = self.curve_at(new_end);
                while self.nodes.len() > 1
                    && self.nodes[self.nodes.len() - 1].sigma > new_end - min_gap
                {
                    self.nodes.pop();
                }
                let id = self.fresh_id();
                self.nodes.push(Node {
                    sigma: new_end,
                    id,
                    position,
                    rotation,
                });
            }
        }
        if let Some(last) = self.nodes.last_mut() {
            last.sigma = new_end;
        }
        // Tips inside the strand: key nodes sliding along the curve.
        for j in 0..self.instruments.len() {
            let l = self.instruments[j].inserted_m;
            let inside = l > snap && l < new_end - snap;
            let current = self.instruments[j]
                .tip_node
                .and_then(|id| self.nodes.iter().position(|n| n.id == id));
            if !inside {
                self.instruments[j].tip_node = None;
                continue;
            }
            if let Some(k) = current
                && (self.nodes[k].sigma - l).abs() <= snap
                && (self.nodes[k].sigma == l || self.is_tip_node(self.nodes[k].id, j))
            {
                continue;
            }
            // Another tip already near this point: share its node.
            if let Some(shared) = self
                .nodes
                .iter()
                .find(|n| (n.sigma - l).abs() <= snap && self.is_tip_node(n.id, j))
            {
                self.instruments[j].tip_node = Some(shared.id);
                continue;
            }
            let (position, rotation) = self.curve_at(l);
            let id = match current {
                Some(k) if !self.is_tip_node(self.nodes[k].id, j) => self.nodes.remove(k).id,
                _ => self.fresh_id(),
            };
            // Ordinary nodes too close to the tip give way to it.
            let keys = self.key_ids();
            let last = self.nodes.len() - 1;
            let mut k = 1;
            while k < last.min(self.nodes.len() - 1) {
                let n = self.nodes[k];
                if (n.sigma - l).abs() < min_gap && !keys.contains(&n.id) {
                    self.nodes.remove(k);
                } else {
                    k += 1;
                }
            }
            let at = self.nodes.partition_point(|n| n.sigma < l);
            self.nodes.insert(
                at,
                Node {
                    sigma: l,
                    id,
                    position,
                    rotation,
                },
            );
            self.instruments[j].tip_node = Some(id);
        }
        if self.nodes.len() < 2 || self.nodes.windows(2).any(|w| w[1].sigma <= w[0].sigma) {
            return Err(PhysicsError::Stack(format!(
                "node layout lost its order at t = {:.4} s (inserted lengths {:?})",
                self.time_s,
                self.instruments
                    .iter()
                    .map(|i| i.inserted_m)
                    .collect::<Vec<_>>()
            )));
        }
        Ok(())
    }

    /// Whether node `id` is the tip node of an instrument other than `except`.
    fn is_tip_node(&self, id: u64, except: usize) -> bool {
        self.instruments
            .iter()
            .enumerate()
            .any(|(k, i)| k != except && i.tip_node == Some(id))
    }

    /// Identifiers of every tip node.
    fn key_ids(&self) -> Vec<u64> {
        self.instruments.iter().filter_map(|i| i.tip_node).collect()
    }

    fn fresh_id(&mut self) -> u64 {
        self.next_id += 1;
        self.next_id - 1
    }

    /// The smooth curve through the current nodes at path coordinate `sigma` (clamped).
    fn curve_at(&self, sigma: f64) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let k = self
            .nodes
            .partition_point(|n| n.sigma <= sigma)
            .clamp(1, self.nodes.len() - 1)
            - 1;
        let (a, b) = (&self.nodes[k], &self.nodes[k + 1]);
        let f = ((sigma - a.sigma) / (b.sigma - a.sigma)).clamp(0.0, 1.0);
        hermite_point((&a.position, &a.rotation), (&b.position, &b.rotation), f)
    }

    /// Splits elements longer than 1.5 nominal spacings, or bending more than the refinement
    /// angle, or touching the wall while longer than the contact element (not below the tip
    /// element length); removes ordinary nodes whose two elements together are shorter than
    /// 1.25 nominal spacings, bend little and touch nothing.
    fn refine(&mut self) {
        let shortest = self.settings.tip_element_m;
        let refinement = self.settings.refinement.map(|r| self.effort.refinement(r));
        let active: Vec<f64> = self
            .previous_contacts
            .iter()
            .filter(|(_, force)| force.x > 0.0)
            .map(|(sigma, _)| *sigma)
            .collect();
        let touching = |a: f64, b: f64| active.iter().any(|&s| s >= a && s <= b);
        let bend =
            |a: &Node, b: &Node| (a.rotation * Vector3::x()).angle(&(b.rotation * Vector3::x()));
        let mut k = self.nodes.len() - 1;
        while k > 0 {
            let (a, b) = (self.nodes[k - 1], self.nodes[k]);
            let long = b.sigma - a.sigma;
            let h = nominal_spacing(&self.settings, &self.instruments, 0.5 * (a.sigma + b.sigma));
            let refine = refinement.is_some_and(|r| {
                long >= 2.0 * shortest
                    && (bend(&a, &b) > r.max_bend_rad
                        || (long > r.contact_element_m && touching(a.sigma, b.sigma)))
            });
            if long > 1.5 * h || refine {
                let (position, rotation) =
                    hermite_point((&a.position, &a.rotation), (&b.position, &b.rotation), 0.5);
                let id = self.fresh_id();
                self.nodes.insert(
                    k,
                    Node {
                        sigma: 0.5 * (a.sigma + b.sigma),
                        id,
                        position,
                        rotation,
                    },
                );
            }
            k -= 1;
        }
        let keys = self.key_ids();
        let max_bend = refinement.map_or(f64::INFINITY, |r| r.max_bend_rad);
        let min_gap = MIN_GAP_FRACTION * shortest;
        let mut k = 1;
        while k + 1 < self.nodes.len() {
            let (a, n, b) = (self.nodes[k - 1], self.nodes[k], self.nodes[k + 1]);
            let h = nominal_spacing(&self.settings, &self.instruments, n.sigma);
            let crowded = n.sigma - a.sigma < min_gap || b.sigma - n.sigma < min_gap;
            if !keys.contains(&n.id)
                && (crowded
                    || (b.sigma - a.sigma < 1.25 * h
                        && bend(&a, &n) + bend(&n, &b) < max_bend / 3.0
                        && !touching(a.sigma, b.sigma)))
            {
                self.nodes.remove(k);
            } else {
                k += 1;
            }
        }
    }

    /// Rebuilds the beam model on the current nodes, reusing every element whose two nodes
    /// and rest geometry are unchanged.
    fn rebuild_model(&mut self) -> Result<()> {
        let old: HashMap<(u64, u64), usize> = self
            .specs
            .iter()
            .enumerate()
            .map(|(e, (_, a, b))| ((*a, *b), e))
            .collect();
        let mut specs = Vec::with_capacity(self.nodes.len() - 1);
        let mut keep = Vec::with_capacity(self.nodes.len() - 1);
        for w in self.nodes.windows(2) {
            let spec = composite_spec(&self.instruments, w[0].sigma, w[1].sigma);
            let kept = old
                .get(&(w[0].id, w[1].id))
                .copied()
                .filter(|&e| same_spec(&self.specs[e].0, &spec));
            keep.push(kept);
            specs.push((spec, w[0].id, w[1].id));
        }
        let positions: Vec<Vector3<f64>> = self.nodes.iter().map(|n| n.position).collect();
        let rotations: Vec<UnitQuaternion<f64>> = self.nodes.iter().map(|n| n.rotation).collect();
        let plain: Vec<ElementSpec> = specs.iter().map(|s| s.0).collect();
        self.model.remesh(&plain, &keep, &positions, &rotations)?;
        self.model.set_settings(solver_settings(&self.settings));
        self.specs = specs;
        Ok(())
    }

    /// Collision points per element, with the radius and wall friction of the outermost
    /// instrument present.
    fn sample_layout(&self) -> Vec<Sample> {
        let mut samples = Vec::new();
        let elements = self.model.element_count();
        for e in 0..elements {
            let (a, b) = (self.nodes[e].sigma, self.nodes[e + 1].sigma);
            let mid = 0.5 * (a + b);
            let Some(outer) = self.instruments.iter().find(|i| i.inserted_m > mid) else {
                continue;
            };
            let (section, _) = outer
                .device
                .section_at(outer.length_m - outer.inserted_m + mid);
            push_element_samples(
                &mut samples,
                (e, elements),
                b - a,
                self.settings.sample_spacing_m,
                section,
            );
        }
        samples
    }

    fn check_index(&self, index: usize) -> Result<()> {
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

/// The beam solver settings of a navigated strand.
fn solver_settings(settings: &NavigationSettings) -> SolverSettings {
    SolverSettings {
        mode: StepMode::PAPER,
        geometric_stiffness: true,
        compute_flexibility: true,
        drag: (settings.drag_n_s_per_m2 > 0.0).then_some(ViscousDrag {
            per_length_n_s_per_m2: settings.drag_n_s_per_m2,
            time_step_s: settings.time_step_s,
        }),
        max_step_increment: Some((settings.max_step_m, settings.max_step_rad)),
        geometric_stiffness_in_compression: false,
        max_substep_halvings: 0,
    }
}

/// The instrument whose tip leads (largest inserted length; the innermost of equals).
fn leader(instruments: &[Instrument]) -> usize {
    let mut best = 0;
    for (k, i) in instruments.iter().enumerate() {
        if i.inserted_m >= instruments[best].inserted_m {
            best = k;
        }
    }
    best
}

/// Range of the inserted length (m) of an instrument of `length_m` inside `outer` (inserted
/// length and length of the instrument directly around it, m): from the hub of the one directly around it to
/// where its own hub meets that hub; for the outermost, one tip element to its length.
pub fn inserted_range(outer: Option<(f64, f64)>, length_m: f64, tip_element_m: f64) -> (f64, f64) {
    match outer {
        None => (tip_element_m, length_m),
        Some((inserted_m, outer_length_m)) => {
            let hub = inserted_m - outer_length_m;
            (hub, hub + length_m)
        }
    }
}

/// Inserted length and length (m) of the instrument around instrument `index`.
fn around(instruments: &[Instrument], index: usize) -> Option<(f64, f64)> {
    index
        .checked_sub(1)
        .map(|k| (instruments[k].inserted_m, instruments[k].length_m))
}

/// Nominal node spacing at path coordinate `sigma`: that of the outermost instrument present
/// there, fine near its own tip (an inner instrument's tip inside another changes the
/// composite's stiffness, which the tip node captures, not its shape).
fn nominal_spacing(settings: &NavigationSettings, instruments: &[Instrument], sigma: f64) -> f64 {
    instruments
        .iter()
        .find(|i| i.inserted_m > sigma)
        .map_or(settings.tip_element_m, |i| {
            spacing(settings, i.inserted_m, sigma)
        })
}

/// Section properties of `instrument` at path coordinate `sigma`.
fn properties_at(instrument: &Instrument, sigma: f64) -> BeamProperties {
    let m = instrument.length_m - instrument.inserted_m + sigma;
    instrument.device.section_at(m).0.beam_properties()
}

/// Rest geometry of the composite element between path coordinates `a` < `b`: stiffnesses
/// summed over the instruments present, rest curvature blended by stiffness (bending by EI,
/// torsion by GJ), each instrument's turned by its twist relative to the outermost's.
fn composite_spec(instruments: &[Instrument], a: f64, b: f64) -> ElementSpec {
    let mid = 0.5 * (a + b);
    let reference = instruments[0].twist_rad;
    let mut props = BeamProperties {
        axial_stiffness_n: 0.0,
        bending_stiffness_nm2: 0.0,
        torsional_stiffness_nm2: 0.0,
        shear_stiffness_n: 0.0,
        polar_gyration_m2: 0.0,
        mass_per_length_kg_m: 0.0,
    };
    let (mut area, mut polar) = (0.0, 0.0);
    let mut bending = Vector3::zeros();
    let mut torsion = 0.0;
    for instrument in instruments.iter().filter(|i| i.inserted_m > mid) {
        let offset = instrument.length_m - instrument.inserted_m;
        let (section, _) = instrument.device.section_at(offset + mid);
        let p = section.beam_properties();
        let kappa = instrument
            .device
            .mean_rest_curvature(offset + a, offset + b);
        let turned =
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), instrument.twist_rad - reference)
                * kappa;
        bending += Vector3::new(0.0, turned.y, turned.z) * p.bending_stiffness_nm2;
        torsion += turned.x * p.torsional_stiffness_nm2;
        props.axial_stiffness_n += p.axial_stiffness_n;
        props.bending_stiffness_nm2 += p.bending_stiffness_nm2;
        props.torsional_stiffness_nm2 += p.torsional_stiffness_nm2;
        props.shear_stiffness_n += p.shear_stiffness_n;
        props.mass_per_length_kg_m += p.mass_per_length_kg_m;
        let section_area = section.cross_section.area_m2();
        area += section_area;
        polar += p.polar_gyration_m2 * section_area;
    }
    props.polar_gyration_m2 = if area > 0.0 { polar / area } else { 0.0 };
    let mut curvature = bending / props.bending_stiffness_nm2;
    curvature.x = torsion / props.torsional_stiffness_nm2;
    ElementSpec {
        props,
        length_m: b - a,
        curvature_per_m: curvature,
    }
}

/// Whether two rest geometries agree to round-off (an element carried with its material has
/// the same geometry up to the last bits of its path coordinates).
fn same_spec(a: &ElementSpec, b: &ElementSpec) -> bool {
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * x.abs().max(y.abs()).max(1e-300);
    a.props == b.props
        && close(a.length_m, b.length_m)
        && (a.curvature_per_m - b.curvature_per_m).norm()
            <= 1e-9 * a.curvature_per_m.norm().max(1.0)
}
