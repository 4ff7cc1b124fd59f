//! Navigation: a device pushed, pulled and twisted at an entry point (the sheath) into a
//! vessel, of which only the inserted length is simulated. Nodes are material points of the
//! device, spaced finely near the tip and coarsely along the shaft; as the device slides in,
//! the element next to the entry point grows and is split when it is 1.5 element lengths
//! long, and as it slides out it shrinks and is merged when it is half an element long — the
//! new node is placed on the current chord, so the shape never jumps. Each step: proximal
//! control (clamped speeds), collision detection at the predicted configuration, the beam solve
//! with Gauss–Seidel contact and Coulomb friction, and the proximal reaction on request.

use nalgebra::{UnitQuaternion, Vector3, Vector6};

use crate::beam::{BeamModel, ContactStep, ElementSpec, SolverSettings, StepMode, ViscousDrag};
use crate::contact::{Contact, ContactSettings, point_displacement};
use crate::device::Device;
use crate::error::{PhysicsError, Result, require_finite, require_positive};
use crate::wall::Wall;

/// Discretization, control limits and contact settings of a navigation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavigationSettings {
    /// Physics time step (s); 1/500 s by default.
    pub time_step_s: f64,
    /// Largest insertion speed either way (m/s).
    pub max_insertion_speed_m_s: f64,
    /// Largest twist rate either way (rad/s).
    pub max_twist_rate_rad_s: f64,
    /// Element length near the tip (m).
    pub tip_element_m: f64,
    /// Element length along the shaft (m).
    pub shaft_element_m: f64,
    /// Length from the tip discretized with `tip_element_m`; the spacing then grows linearly to
    /// `shaft_element_m` over the same length again (m).
    pub tip_zone_m: f64,
    /// Points closer to the wall than this (device surface to wall, m) become contacts, whose
    /// force may still come out zero.
    pub contact_margin_m: f64,
    /// Collision points along each element are at most this far apart (m).
    pub sample_spacing_m: f64,
    /// Viscous drag per unit length (N·s/m²) regularizing each step (see
    /// [`crate::beam::ViscousDrag`]): it slows motion in directions the device offers no
    /// stiffness (buckling) without changing any equilibrium.
    pub drag_n_s_per_m2: f64,
    /// Largest translation (m) of any node in one step, beyond the commanded sliding.
    pub max_step_m: f64,
    /// Largest rotation (rad) of any node in one step.
    pub max_step_rad: f64,
    /// A step whose solved configuration still penetrates the wall by more than this (m) is
    /// redone as two half steps.
    pub substep_penetration_m: f64,
    /// Gauss–Seidel settings.
    pub contact: ContactSettings,
    /// Local refinement where the device bends or touches the wall (`None`: the nominal
    /// spacing only).
    pub refinement: Option<Refinement>,
}

/// Where the device gets nodes beyond its nominal spacing. Before each step, elements that
/// bend by more than `max_bend_rad` between their two nodes, or that carry an active contact
/// and are longer than `contact_element_m`, are halved (down to `tip_element_m`), the new node
/// placed on the smooth curve through the old ones so that the shape does not jump. Two
/// halves merge back when together they bend less than a third of `max_bend_rad`, carry no
/// active contact and are shorter than 1.25 nominal spacings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Refinement {
    /// Largest angle between the tangents at an element's two nodes (rad).
    pub max_bend_rad: f64,
    /// Longest element allowed to carry an active contact (m).
    pub contact_element_m: f64,
}

impl Default for Refinement {
    fn default() -> Self {
        Self {
            max_bend_rad: 0.1,
            contact_element_m: 2.5e-3,
        }
    }
}

impl Default for NavigationSettings {
    fn default() -> Self {
        Self {
            time_step_s: 1.0 / 500.0,
            max_insertion_speed_m_s: 0.15,
            max_twist_rate_rad_s: 4.0 * std::f64::consts::PI,
            tip_element_m: 1.5e-3,
            shaft_element_m: 5e-3,
            tip_zone_m: 30e-3,
            contact_margin_m: 0.3e-3,
            sample_spacing_m: 1e-3,
            drag_n_s_per_m2: 10.0,
            max_step_m: 0.2e-3,
            max_step_rad: 0.2,
            substep_penetration_m: 0.02e-3,
            contact: ContactSettings {
                tolerance: 1e-3,
                absolute_tolerance_n: 1e-7,
                violation_tolerance_m: 1e-6,
                max_iterations: 300,
                relaxation: 1.0,
                detection_rounds: 4,
                penetration_tolerance_m: 0.01e-3,
                acceleration_depth: 5,
                polish: true,
            },
            refinement: Some(Refinement::default()),
        }
    }
}

/// How many times a step may be halved when it would penetrate the wall.
pub const MAX_SUBSTEP_DEPTH: usize = 3;

/// How much work a step may do, below what the settings allow: the knobs an overload
/// governor turns to keep the step rate when a scene gets expensive (a long device looped
/// against the wall). [`Effort::FULL`] leaves the settings as they are.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Effort {
    /// Halvings of a step that would penetrate the wall (at most [`MAX_SUBSTEP_DEPTH`]).
    pub max_substep_depth: usize,
    /// Detection-and-solve rounds per step (at most the contact settings').
    pub max_detection_rounds: usize,
    /// Gauss–Seidel sweeps (at most the contact settings').
    pub max_sweeps: usize,
    /// Whether the active-set polish may finish an unconverged contact solve (O(A³)).
    pub polish: bool,
    /// Scale of the refinement thresholds (≥ 1): elements bend and touch this much more
    /// before they split, and merge back sooner.
    pub refinement_scale: f64,
}

impl Effort {
    /// No cap.
    pub const FULL: Effort = Effort {
        max_substep_depth: MAX_SUBSTEP_DEPTH,
        max_detection_rounds: usize::MAX,
        max_sweeps: usize::MAX,
        polish: true,
        refinement_scale: 1.0,
    };

    /// Checks the effort's values.
    pub fn validate(&self) -> Result<()> {
        if !(self.refinement_scale.is_finite() && self.refinement_scale >= 1.0) {
            return Err(PhysicsError::OutOfRange {
                what: "effort.refinement_scale".into(),
                range: "[1, ∞)",
                value: self.refinement_scale,
            });
        }
        Ok(())
    }

    /// `base` with its sweeps, detection rounds (at least one) and polish capped by this
    /// effort.
    pub fn contact(&self, base: &ContactSettings) -> ContactSettings {
        ContactSettings {
            max_iterations: base.max_iterations.min(self.max_sweeps),
            detection_rounds: base.detection_rounds.min(self.max_detection_rounds).max(1),
            polish: base.polish && self.polish,
            ..*base
        }
    }

    /// `base` with its thresholds scaled by [`Effort::refinement_scale`].
    pub fn refinement(&self, base: Refinement) -> Refinement {
        Refinement {
            max_bend_rad: base.max_bend_rad * self.refinement_scale,
            contact_element_m: base.contact_element_m * self.refinement_scale,
        }
    }

    /// The deepest step halving allowed, at most `ceiling`.
    pub fn substep_depth(&self, ceiling: usize) -> usize {
        self.max_substep_depth.min(ceiling)
    }
}

/// Push/pull command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Insertion {
    /// Insertion speed (m/s; negative pulls).
    Velocity(f64),
    /// Inserted length to move to (m).
    Target(f64),
}

/// Twist command (about the device axis at the entry point).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Twist {
    /// Twist rate (rad/s).
    Rate(f64),
    /// Twist angle to move to (rad).
    Target(f64),
}

/// The operator's command at the device's proximal end.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    /// Push/pull.
    pub insertion: Insertion,
    /// Twist.
    pub twist: Twist,
}

impl Default for Command {
    fn default() -> Self {
        Self {
            insertion: Insertion::Velocity(0.0),
            twist: Twist::Rate(0.0),
        }
    }
}

/// What one navigation step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavigationReport {
    /// Contacts detected.
    pub contacts: usize,
    /// Contacts with a positive normal force.
    pub active_contacts: usize,
    /// Gauss–Seidel sweeps.
    pub sweeps: usize,
    /// Whether Gauss–Seidel met its tolerance.
    pub converged: bool,
    /// Inserted length after the step (m).
    pub inserted_m: f64,
    /// Twist angle after the step (rad).
    pub twist_rad: f64,
    /// Elements simulated.
    pub elements: usize,
}

/// A device being navigated through a vessel.
#[derive(Debug, Clone)]
pub struct Navigation<W: Wall> {
    device: Device,
    wall: W,
    settings: NavigationSettings,
    model: BeamModel,
    entry_position: Vector3<f64>,
    entry_rotation: UnitQuaternion<f64>,
    /// Material coordinate (m from the proximal end) of every simulated node, base to tip.
    material: Vec<f64>,
    twist_rad: f64,
    command: Command,
    time_s: f64,
    last: Option<ContactStep>,
    /// Material coordinates and local forces of the last contacts (for warm starts).
    previous_contacts: Vec<(f64, Vector3<f64>)>,
    effort: Effort,
    /// Wall-distance bounds that spare collision points their probes.
    clearance: ClearanceCache,
}

impl<W: Wall> Navigation<W> {
    /// Starts with `inserted_m` of `device` through the entry point at `entry_position`, heading
    /// along `entry_direction`, in its rest shape.
    pub fn new(
        device: Device,
        wall: W,
        entry_position: Vector3<f64>,
        entry_direction: Vector3<f64>,
        inserted_m: f64,
        settings: NavigationSettings,
    ) -> Result<Self> {
        device.validate()?;
        require_positive(|| "time_step_s".into(), settings.time_step_s)?;
        require_positive(|| "tip_element_m".into(), settings.tip_element_m)?;
        require_positive(|| "shaft_element_m".into(), settings.shaft_element_m)?;
        require_positive(|| "sample_spacing_m".into(), settings.sample_spacing_m)?;
        require_positive(
            || "max_insertion_speed_m_s".into(),
            settings.max_insertion_speed_m_s,
        )?;
        require_positive(
            || "max_twist_rate_rad_s".into(),
            settings.max_twist_rate_rad_s,
        )?;
        require_finite(|| "contact_margin_m".into(), settings.contact_margin_m)?;
        if let Some(refinement) = settings.refinement {
            require_positive(|| "refinement.max_bend_rad".into(), refinement.max_bend_rad)?;
            require_positive(
                || "refinement.contact_element_m".into(),
                refinement.contact_element_m,
            )?;
        }
        for (i, v) in entry_position
            .iter()
            .chain(entry_direction.iter())
            .enumerate()
        {
            require_finite(|| format!("entry pose component {i}"), *v)?;
        }
        let length = device.length_m();
        if !(inserted_m >= settings.tip_element_m && inserted_m <= length) {
            return Err(PhysicsError::OutOfRange {
                what: "initial inserted length (m)".into(),
                range: "between the tip element length and the device length",
                value: inserted_m,
            });
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
        // Nodes from the tip back to the entry point.
        let base = length - inserted_m;
        let mut material = vec![length];
        loop {
            let last = *material.last().unwrap();
            let next = last - spacing(&settings, length, last);
            if next <= base + 0.5 * spacing(&settings, length, last) {
                material.push(base);
                break;
            }
            material.push(next);
        }
        material.reverse();
        let specs: Vec<ElementSpec> = material
            .windows(2)
            .map(|w| element_spec(&device, w[0], w[1]))
            .collect();
        let model = BeamModel::new(
            &specs,
            entry_position,
            entry_rotation,
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
            },
        )?;
        Ok(Self {
            device,
            wall,
            settings,
            model,
            entry_position,
            entry_rotation,
            material,
            twist_rad: 0.0,
            command: Command::default(),
            time_s: 0.0,
            last: None,
            previous_contacts: Vec::new(),
            effort: Effort::FULL,
            clearance: ClearanceCache::default(),
        })
    }

    /// Caps the work of the following steps (see [`Effort`]).
    pub fn set_effort(&mut self, effort: Effort) -> Result<()> {
        effort.validate()?;
        self.effort = effort;
        Ok(())
    }

    /// The work cap in force.
    pub fn effort(&self) -> Effort {
        self.effort
    }

    /// Replaces the operator's command (applied from the next step on).
    pub fn set_command(&mut self, command: Command) -> Result<()> {
        let value = match command.insertion {
            Insertion::Velocity(v) | Insertion::Target(v) => v,
        };
        require_finite(|| "insertion command".into(), value)?;
        let value = match command.twist {
            Twist::Rate(v) | Twist::Target(v) => v,
        };
        require_finite(|| "twist command".into(), value)?;
        self.command = command;
        Ok(())
    }

    /// The operator's command in force.
    pub fn current_command(&self) -> Command {
        self.command
    }

    /// Replaces the Gauss–Seidel settings (from the next step on).
    pub fn set_contact_settings(&mut self, contact: ContactSettings) {
        self.settings.contact = contact;
    }

    /// The beam model of the inserted part.
    pub fn model(&self) -> &BeamModel {
        &self.model
    }

    /// The device.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// The wall.
    pub fn wall(&self) -> &W {
        &self.wall
    }

    /// Inserted length (m).
    pub fn inserted_m(&self) -> f64 {
        self.device.length_m() - self.material[0]
    }

    /// Twist applied at the entry point (rad).
    pub fn twist_rad(&self) -> f64 {
        self.twist_rad
    }

    /// Simulated time (s).
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// Material coordinate of every node (m from the device's proximal end), base to tip.
    pub fn node_material_m(&self) -> &[f64] {
        &self.material
    }

    /// The contacts and forces of the last step.
    pub fn last_contacts(&self) -> Option<&ContactStep> {
        self.last.as_ref()
    }

    /// Tip position (m).
    pub fn tip_position(&self) -> Vector3<f64> {
        self.model.tip_position()
    }

    /// Where a curved tip (angled or J) points, across the device: the material +y axis (the
    /// side the rest shape bends to) of the node where the curved part starts, as a unit world
    /// vector perpendicular to the device there. `None` for a straight device.
    pub fn tip_bend_direction(&self) -> Option<Vector3<f64>> {
        let e = self.first_curved_element()?;
        let q = self.model.rotations()[e];
        let tangent = q * Vector3::x();
        let side = q * Vector3::y();
        (side - tangent * tangent.dot(&side)).try_normalize(1e-12)
    }

    /// Unit tangent of the device at the start of its curved tip (or at the tip if straight).
    pub fn tip_axis(&self) -> Vector3<f64> {
        let e = self
            .first_curved_element()
            .unwrap_or(self.model.element_count());
        self.model.rotations()[e] * Vector3::x()
    }

    /// The most proximal element with a rest curvature: where a curved tip (angled or J)
    /// starts. `None` for a straight device.
    fn first_curved_element(&self) -> Option<usize> {
        (0..self.model.element_count()).find(|&e| {
            self.device
                .mean_rest_curvature(self.material[e], self.material[e + 1])
                != Vector3::zeros()
        })
    }

    /// The wrench the operator's hand feels at the entry point (force N, moment N·m, world
    /// frame): the base reaction of the device in its current configuration.
    pub fn proximal_reaction(&mut self) -> Vector6<f64> {
        self.model.base_reaction()
    }

    /// Advances one time step.
    pub fn step(&mut self) -> Result<NavigationReport> {
        let dt = self.settings.time_step_s;
        let length = self.device.length_m();
        // 1. Proximal control, clamped.
        let max_push = self.settings.max_insertion_speed_m_s * dt;
        let inserted = self.inserted_m();
        let wanted = match self.command.insertion {
            Insertion::Velocity(v) => v * dt,
            Insertion::Target(x) => x - inserted,
        };
        let min_inserted = self.settings.tip_element_m;
        let push = wanted
            .clamp(-max_push, max_push)
            .clamp(min_inserted - inserted, length - inserted);
        let max_turn = self.settings.max_twist_rate_rad_s * dt;
        let turn = match self.command.twist {
            Twist::Rate(w) => w * dt,
            Twist::Target(a) => a - self.twist_rad,
        }
        .clamp(-max_turn, max_turn);
        self.refine()?;
        let report = self.advance(push, turn, 0)?;
        self.time_s += dt;
        Ok(report)
    }

    /// Advances by `push` (m) and `turn` (rad); where the solved step still penetrates the wall
    /// by more than the sub-step threshold (a violent event: buckling, a slide along a curved
    /// wall), the step is undone and taken as two halves, up to [`MAX_SUBSTEP_DEPTH`] times.
    fn advance(&mut self, push: f64, turn: f64, depth: usize) -> Result<NavigationReport> {
        let max_depth = self.effort.substep_depth(MAX_SUBSTEP_DEPTH);
        let saved = (depth < max_depth).then(|| {
            (
                self.model.snapshot(),
                self.material.clone(),
                self.twist_rad,
                self.previous_contacts.clone(),
            )
        });
        let report = self.single_step(push, turn)?;
        let penetration = self.last.as_ref().map_or(0.0, |s| s.penetration_m);
        if penetration > self.settings.substep_penetration_m
            && let Some((model, material, twist, previous)) = saved
        {
            self.model.restore(model);
            self.material = material;
            self.twist_rad = twist;
            self.previous_contacts = previous;
            self.advance(0.5 * push, 0.5 * turn, depth + 1)?;
            return self.advance(0.5 * push, 0.5 * turn, depth + 1);
        }
        Ok(report)
    }

    /// One solve: slide, twist, detect, solve.
    fn single_step(&mut self, push: f64, turn: f64) -> Result<NavigationReport> {
        self.slide(push)?;
        self.twist_rad += turn;
        let twist = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), self.twist_rad);
        self.model
            .place_base(self.entry_position, self.entry_rotation * twist)?;
        // 2–4. Detection at the predicted configuration, beam solve with contacts.
        let samples = self.sample_layout();
        let wall = &self.wall;
        let margin = self.settings.contact_margin_m;
        let material = &self.material;
        let previous = &self.previous_contacts;
        let tolerance = self.settings.sample_spacing_m;
        let contact = self.effort.contact(&self.settings.contact);
        let clearance = &mut self.clearance;
        let step = self.model.step_with_contacts(
            |positions, _rotations, free| {
                Ok(detect(wall, &samples, positions, free, margin, clearance))
            },
            &contact,
            |contacts| warm_start(contacts, material, previous, tolerance),
        )?;
        self.previous_contacts = step
            .contacts
            .iter()
            .zip(&step.response.local)
            .map(|(c, l)| (material_of(&self.material, c), *l))
            .collect();
        let report = NavigationReport {
            contacts: step.contacts.len(),
            active_contacts: step.response.local.iter().filter(|l| l.x > 0.0).count(),
            sweeps: step.response.iterations,
            converged: step.response.converged,
            inserted_m: self.inserted_m(),
            twist_rad: self.twist_rad,
            elements: self.model.element_count(),
        };
        self.last = Some(step);
        Ok(report)
    }

    /// Slides the device in (`push` > 0) or out through the entry point, growing or shrinking
    /// the element next to it and splitting or merging it as needed.
    fn slide(&mut self, push: f64) -> Result<()> {
        if push == 0.0 {
            return Ok(());
        }
        let length = self.device.length_m();
        // Predictor. Follow the leader along the straight part: every node moves along the
        // device's current shape by `push` (behind the entry along the entry axis), so the
        // material slides along its own path and nothing is compressed. A curved rest shape at
        // the tip (angled or J) is carried rigidly by the last straight node, which moves along
        // its own axis: sliding material through a bend would strain it.
        let positions = self.model.positions().to_vec();
        let rotations = self.model.rotations().to_vec();
        let last = self.material.len() - 1;
        let curved_from = self.first_curved_element().map_or(last, |e| e.max(1));
        let along = |s: f64| -> (Vector3<f64>, UnitQuaternion<f64>) {
            let m = &self.material;
            if s <= m[0] {
                let q = rotations[0];
                (positions[0] - q * Vector3::x() * (m[0] - s), q)
            } else {
                let k = m.partition_point(|&x| x <= s).clamp(1, last) - 1;
                let f = ((s - m[k]) / (m[k + 1] - m[k])).min(1.0);
                (
                    positions[k] + (positions[k + 1] - positions[k]) * f,
                    rotations[k].slerp(&rotations[k + 1], f),
                )
            }
        };
        let mut new_positions = positions.clone();
        let mut new_rotations = rotations.clone();
        for i in 1..curved_from {
            (new_positions[i], new_rotations[i]) = along(self.material[i] + push);
        }
        let carried = rotations[curved_from] * Vector3::x() * push;
        for p in &mut new_positions[curved_from..] {
            *p += carried;
        }
        self.model.set_nodes(&new_positions, &new_rotations)?;
        self.material[0] -= push;
        loop {
            let base = self.material[0];
            let first = self.material[1];
            let h = spacing(&self.settings, length, first);
            let element = first - base;
            // Only split while pushing and only merge while pulling: with a spacing that varies
            // along the device, doing both could alternate forever.
            if push > 0.0 && element > 1.5 * h {
                let split = first - h;
                self.model.insert_node_after_base(
                    element_spec(&self.device, base, split),
                    element_spec(&self.device, split, first),
                )?;
                self.material.insert(1, split);
            } else if push < 0.0 && element < 0.5 * h && self.material.len() > 2 {
                let second = self.material[2];
                self.model
                    .remove_node_after_base(element_spec(&self.device, base, second))?;
                self.material.remove(1);
            } else {
                return self
                    .model
                    .set_base_element(element_spec(&self.device, base, first));
            }
        }
    }

    /// Halves elements that bend too much or touch the wall and merges halves that no longer
    /// need to be apart (see [`Refinement`]). The element at the entry point is left to
    /// [`Self::slide`]. Runs between steps, so the last contacts decide.
    fn refine(&mut self) -> Result<()> {
        let Some(refinement) = self.settings.refinement else {
            return Ok(());
        };
        let refinement = self.effort.refinement(refinement);
        let length = self.device.length_m();
        let shortest = self.settings.tip_element_m;
        // Material coordinates of the active contacts, ordered along the device.
        let active: Vec<f64> = self.last.as_ref().map_or_else(Vec::new, |step| {
            step.contacts
                .iter()
                .zip(&step.response.local)
                .filter(|(_, l)| l.x > 0.0)
                .map(|(c, _)| material_of(&self.material, c))
                .collect()
        });
        let touching = |a: f64, b: f64| active.iter().any(|&s| s >= a && s <= b);
        let bend = |model: &BeamModel, e: usize| {
            let r = model.rotations();
            (r[e] * Vector3::x()).angle(&(r[e + 1] * Vector3::x()))
        };
        // Split, tip first so that the indices still to visit stay valid.
        for e in (1..self.model.element_count()).rev() {
            let (a, b) = (self.material[e], self.material[e + 1]);
            let long = b - a;
            if long >= 2.0 * shortest
                && (bend(&self.model, e) > refinement.max_bend_rad
                    || (long > refinement.contact_element_m && touching(a, b)))
            {
                let mid = 0.5 * (a + b);
                self.model.split_element(
                    e,
                    element_spec(&self.device, a, mid),
                    element_spec(&self.device, mid, b),
                )?;
                self.material.insert(e + 1, mid);
            }
        }
        // Merge.
        let mut e = 1;
        while e + 1 < self.model.element_count() {
            let (a, b) = (self.material[e], self.material[e + 2]);
            let nominal = spacing(&self.settings, length, 0.5 * (a + b));
            if b - a < 1.25 * nominal
                && bend(&self.model, e) + bend(&self.model, e + 1) < refinement.max_bend_rad / 3.0
                && !touching(a, b)
            {
                self.model
                    .merge_elements(e, element_spec(&self.device, a, b))?;
                self.material.remove(e + 1);
            } else {
                e += 1;
            }
        }
        Ok(())
    }

    /// Collision points per element: (element, t, device radius, friction).
    fn sample_layout(&self) -> Vec<Sample> {
        let mut samples = Vec::new();
        let elements = self.model.element_count();
        for e in 0..elements {
            let (a, b) = (self.material[e], self.material[e + 1]);
            let (section, _) = self.device.section_at(0.5 * (a + b));
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

    /// The largest penetration of the device into the wall in the current configuration (m;
    /// 0 when nothing penetrates), over the collision points.
    pub fn max_penetration_m(&self) -> f64 {
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
}

/// Material coordinate of a contact point (m from the proximal end).
pub(crate) fn material_of(material: &[f64], contact: &Contact) -> f64 {
    let (a, b) = (material[contact.element], material[contact.element + 1]);
    a + contact.t * (b - a)
}

/// The previous step's forces for contacts within `tolerance` (m, along the device) of the
/// same material point, as a Gauss–Seidel warm start; both lists are ordered along the device.
pub(crate) fn warm_start(
    contacts: &[Contact],
    material: &[f64],
    previous: &[(f64, Vector3<f64>)],
    tolerance: f64,
) -> Option<Vec<Vector3<f64>>> {
    if previous.is_empty() {
        return None;
    }
    let mut j = 0;
    let warm = contacts
        .iter()
        .map(|c| {
            let s = material_of(material, c);
            while j + 1 < previous.len()
                && (previous[j + 1].0 - s).abs() <= (previous[j].0 - s).abs()
            {
                j += 1;
            }
            if (previous[j].0 - s).abs() <= tolerance {
                previous[j].1
            } else {
                Vector3::zeros()
            }
        })
        .collect();
    Some(warm)
}

/// One collision point.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Sample {
    pub(crate) element: usize,
    pub(crate) t: f64,
    pub(crate) radius: f64,
    pub(crate) friction: f64,
}

/// Appends the collision points of element `e` of `elements` (its length `length_m`, points
/// about `spacing_m` apart) with the radius and wall friction of `section`. t = 0 belongs to
/// the element (node e); the tip (t = 1) only to the last element.
pub(crate) fn push_element_samples(
    samples: &mut Vec<Sample>,
    (e, elements): (usize, usize),
    length_m: f64,
    spacing_m: f64,
    section: &crate::device::Section,
) {
    let count = (length_m / spacing_m).ceil().max(1.0) as usize;
    let last = if e + 1 == elements { count } else { count - 1 };
    // The base node is driven (held by the sheath or the hand): no contact force can move
    // it, so a contact there has no compliance and Gauss–Seidel cannot resolve it (it stalled
    // every sweep where the entry touched a segmented lumen's end).
    let first = usize::from(e == 0);
    for j in first..=last {
        samples.push(Sample {
            element: e,
            t: j as f64 / count as f64,
            radius: section.cross_section.outer_radius_m,
            friction: section.friction_coefficient,
        });
    }
}

/// Node spacing at material coordinate `s` (m from the proximal end) of a device of `length`.
pub(crate) fn spacing(settings: &NavigationSettings, length: f64, s: f64) -> f64 {
    let from_tip = length - s;
    let ramp = ((from_tip - settings.tip_zone_m) / settings.tip_zone_m).clamp(0.0, 1.0);
    settings.tip_element_m + ramp * (settings.shaft_element_m - settings.tip_element_m)
}

/// Rest geometry of the device between material coordinates `a` < `b`.
fn element_spec(device: &Device, a: f64, b: f64) -> ElementSpec {
    let mid = 0.5 * (a + b);
    ElementSpec {
        props: device.section_at(mid).0.beam_properties(),
        length_m: b - a,
        curvature_per_m: device.mean_rest_curvature(a, b),
    }
}

/// How far beyond its search radius a collision point's probe looks (m), so that the
/// distance it finds lets the point skip the probes of the following steps.
pub(crate) const CLEARANCE_REACH_M: f64 = 1e-3;

/// Slack on the clearance bound (m): far above rounding, far below any contact margin.
const CLEARANCE_SLACK_M: f64 = 1e-9;

/// Per collision point: where it was last probed and a lower bound on its distance to the
/// wall there (0: none known). The distance to the wall changes no faster than the point
/// moves, so a point that has moved less than its bound minus its search radius is still
/// clear of the wall and needs no probe: the contacts are exactly those of probing every
/// point (a skipped probe would have found no wall within the search radius). Most of a
/// device lies clear of the wall and moves a fraction of a millimetre a step, so most probes
/// are skipped.
#[derive(Debug, Clone, Default)]
pub(crate) struct ClearanceCache {
    points: Vec<(Vector3<f64>, f64)>,
}

impl ClearanceCache {
    /// Room for `n` collision points (a changed layout keeps the bounds: each is tied to the
    /// position it was found at, not to the sample).
    fn fit(&mut self, n: usize) {
        self.points.resize(n, (Vector3::zeros(), 0.0));
    }

    /// Whether point `i`, now at `at`, is certainly farther than `search` from the wall.
    pub(crate) fn clear_of_wall(&self, i: usize, at: &Vector3<f64>, search: f64) -> bool {
        let Some(&(at0, bound)) = self.points.get(i) else {
            return false;
        };
        bound > 0.0 && (at - at0).norm() < bound - search - CLEARANCE_SLACK_M
    }

    /// Records what a probe with search radius `reach` found at `at`: no wall within it
    /// while inside (`None`), the distance to the wall when inside, nothing when outside.
    fn remember(
        &mut self,
        i: usize,
        at: &Vector3<f64>,
        probe: Option<&crate::WallProbe>,
        reach: f64,
    ) {
        let bound = match probe {
            None => reach,
            Some(p) => p.clearance_m.max(0.0),
        };
        self.points[i] = (*at, bound);
    }
}

/// Contacts at the predicted configuration x + Δu_free: for each element the deepest collision
/// point within the margin, with its gap shifted back so that `gap + n·δ_free` is the
/// predicted gap (the contact solver linearizes about the free motion, so a fast push cannot
/// tunnel through the wall).
pub(crate) fn detect<W: Wall>(
    wall: &W,
    samples: &[Sample],
    positions: &[Vector3<f64>],
    free: &[Vector6<f64>],
    margin: f64,
    cache: &mut ClearanceCache,
) -> Vec<Contact> {
    let mut contacts: Vec<Contact> = Vec::new();
    // Predicted gaps of the contacts of the current element (parallel to its tail of
    // `contacts`): one contact per element and wall direction, the deepest.
    let mut deepest: Vec<f64> = Vec::new();
    let mut element_start = 0;
    cache.fit(samples.len());
    for (i, s) in samples.iter().enumerate() {
        let delta = point_displacement(free, s.element, s.t);
        let at = positions[s.element] * (1.0 - s.t) + positions[s.element + 1] * s.t + delta;
        let search = s.radius + margin;
        if cache.clear_of_wall(i, &at, search) {
            continue;
        }
        let probe = wall.probe(&at, search + CLEARANCE_REACH_M);
        cache.remember(i, &at, probe.as_ref(), search + CLEARANCE_REACH_M);
        let Some(probe) = probe else {
            continue;
        };
        let predicted_gap = probe.clearance_m - s.radius;
        if predicted_gap > margin {
            continue;
        }
        let contact = Contact {
            element: s.element,
            t: s.t,
            normal: probe.normal,
            gap: predicted_gap - probe.normal.dot(&delta),
            friction: s.friction,
        };
        if contacts.last().is_none_or(|c| c.element != s.element) {
            element_start = contacts.len();
            deepest.clear();
        }
        // One contact per element half and wall direction: an element lying along the wall
        // keeps a contact near each end.
        let same_wall = contacts[element_start..]
            .iter()
            .position(|c| c.normal.dot(&contact.normal) > 0.9 && (c.t < 0.5) == (contact.t < 0.5));
        match same_wall {
            Some(k) if predicted_gap < deepest[k] => {
                contacts[element_start + k] = contact;
                deepest[k] = predicted_gap;
            }
            Some(_) => {}
            None => {
                contacts.push(contact);
                deepest.push(predicted_gap);
            }
        }
    }
    contacts
}

#[cfg(test)]
mod clearance_tests {
    use super::*;
    use crate::WallProbe;
    use crate::wall::{CappedTube, RingTube};
    use proptest::prelude::*;

    /// A chain of `n` nodes along x through the tube, each moved by `wiggle` (m) per step.
    fn chain(n: usize, y: f64, z: f64) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|i| Vector3::new(0.004 * i as f64, y, z))
            .collect()
    }

    fn samples(elements: usize, radius: f64) -> Vec<Sample> {
        (0..elements)
            .flat_map(|e| {
                (0..4).map(move |j| Sample {
                    element: e,
                    t: j as f64 / 4.0,
                    radius,
                    friction: 0.1,
                })
            })
            .collect()
    }

    proptest! {
        /// The contacts found with the bounds kept from step to step are exactly those of
        /// probing every point every step, whatever the walk (the fast path against the naive
        /// one), in a capped tube and in a ring.
        #[test]
        fn kept_bounds_find_exactly_the_contacts_of_probing_every_point(
            y in -0.0015f64..0.0015,
            z in -0.0015f64..0.0015,
            steps in prop::collection::vec((-2e-4f64..2e-4, -2e-4f64..2e-4, -1e-3f64..1e-3), 1..60),
            radius in 1e-4f64..5e-4,
            margin in 0.0f64..3e-4,
            ring in any::<bool>(),
        ) {
            let tube = CappedTube {
                start: Vector3::new(-0.01, 0.0, 0.0),
                axis: Vector3::x(),
                length_m: 0.05,
                radius_m: 0.002,
            };
            let torus = RingTube {
                center: Vector3::new(0.02, -0.03, 0.0),
                axis: Vector3::z(),
                major_radius_m: 0.03,
                minor_radius_m: 0.002,
            };
            let mut positions = chain(9, y, z);
            let layout = samples(8, radius);
            let free = vec![Vector6::zeros(); positions.len()];
            let mut kept = ClearanceCache::default();
            for (k, (dy, dz, dx)) in steps.iter().enumerate() {
                for (i, p) in positions.iter_mut().enumerate() {
                    // Each node its own drift: bends as well as translations.
                    let f = 1.0 + 0.1 * i as f64;
                    *p += Vector3::new(*dx, dy * f, dz * (2.0 - f * 0.5));
                }
                let (fast, naive) = if ring {
                    (
                        detect(&torus, &layout, &positions, &free, margin, &mut kept),
                        detect(&torus, &layout, &positions, &free, margin, &mut ClearanceCache::default()),
                    )
                } else {
                    (
                        detect(&tube, &layout, &positions, &free, margin, &mut kept),
                        detect(&tube, &layout, &positions, &free, margin, &mut ClearanceCache::default()),
                    )
                };
                prop_assert_eq!(fast, naive, "step {}", k);
            }
        }
    }

    #[test]
    fn points_clear_of_the_wall_skip_their_probes() {
        /// Counts its probes.
        struct Counting<'a>(&'a CappedTube, std::cell::Cell<usize>);
        impl Wall for Counting<'_> {
            fn probe(&self, point: &Vector3<f64>, search_m: f64) -> Option<WallProbe> {
                self.1.set(self.1.get() + 1);
                self.0.probe(point, search_m)
            }
        }
        let tube = CappedTube {
            start: Vector3::new(-0.01, 0.0, 0.0),
            axis: Vector3::x(),
            length_m: 0.05,
            radius_m: 0.002,
        };
        let wall = Counting(&tube, std::cell::Cell::new(0));
        let mut positions = chain(9, 0.0, 0.0);
        let layout = samples(8, 2e-4);
        let free = vec![Vector6::zeros(); positions.len()];
        let mut kept = ClearanceCache::default();
        for _ in 0..100 {
            for p in &mut positions {
                p.x += 4e-5; // 20 mm/s at 500 Hz
            }
            assert!(detect(&wall, &layout, &positions, &free, 1e-4, &mut kept).is_empty());
        }
        // On the axis 1.7 mm clear of the wall: a probe about every 40 steps, not 100.
        let probes = wall.1.get();
        println!("{probes} probes for {} point-steps", 100 * layout.len());
        assert!(probes < 10 * layout.len(), "{probes}");
    }
}
