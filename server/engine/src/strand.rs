//! What the operator's hands hold: one device (a scene's `devices`, one at a time) or a
//! coaxial stack (a scene's `stack`, each instrument in its own hand), behind one interface
//! that the world steps, limits, draws and digests the same way; and the navigation
//! settings of a scene's fidelity.

use cathlab_physics::{
    BeamModel, Command, ContactStep, Device, Effort, InstrumentSpec, Navigation,
    NavigationSettings, Refinement, Sleep, Stack,
};
use nalgebra::Vector3;

use crate::assets::{SceneAssets, SharedWall};
use crate::error::{EngineError, Result};

/// One device or a stack.
#[derive(Debug, Clone)]
pub enum Strand {
    /// One device.
    Single(Navigation<SharedWall>),
    /// A coaxial stack, outermost first.
    Stack(Stack<SharedWall>),
}

/// What one instrument's hand feels: along the entry axis (N, positive when the device
/// resists a push) and about it (N·m).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HandReaction {
    /// Axial force (N).
    pub axial_force_n: f64,
    /// Torque (N·m).
    pub torque_nm: f64,
}

/// The most axial force an element of a device may carry, in hands' strengths
/// (`NavigationSettings::max_axial_force_n` is this times the scene's push limit). A device's
/// own loads put no more than one strength into it; what passes is the slide's strain, which
/// the physics relieves. At one strength (plus the hands' 2 % overshoot) the strain that held
/// a push blocked at its tip is gone, and the wire, free to buckle, loops a metre into the
/// aorta within 20 s of a full-speed push, where a step takes 2 ms even at the governor's
/// lowest level on one core (the attack suite's full-speed push then missed 75 steps); at
/// two it relieves the crushing (the hands within their strength at every level in the 30 s
/// aorta runs) and the push is still held early. Cheaper long loops are the way to one.
const ELEMENT_FORCE_STRENGTHS: f64 = 2.0;

/// The navigation settings of a scene's fidelity.
fn navigation_settings(assets: &SceneAssets) -> NavigationSettings {
    let q = &assets.spec.fidelity;
    let mut settings = NavigationSettings {
        time_step_s: assets.spec.time_step_s(),
        tip_element_m: q.tip_element_mm * 1e-3,
        shaft_element_m: q.shaft_element_mm * 1e-3,
        refinement: q.refine.then(Refinement::default),
        sleep: q.sleep_at_rest.then(Sleep::default),
        max_axial_force_n: Some(ELEMENT_FORCE_STRENGTHS * assets.spec.limits.push_force_n),
        slide_friction: q.slide_friction,
        cap_with_held_contacts: q.cap_with_held_contacts,
        axial_slide: q.axial_slide,
        ..NavigationSettings::default()
    };
    settings.contact.tolerance = q.contact_tolerance;
    settings.contact.method = q.contact_solver.into();
    settings
}

impl Strand {
    /// The scene's start: device `device` of a one-device scene, or the scene's stack.
    pub fn start(assets: &SceneAssets, device: usize) -> Result<Self> {
        let (entry, direction) = assets.entry;
        let settings = navigation_settings(assets);
        if assets.spec.stack.is_empty() {
            return Ok(Strand::Single(Navigation::new(
                assets.devices[device].0.clone(),
                SharedWall(assets.anatomy.clone()),
                entry,
                direction,
                assets.spec.start.inserted_mm * 1e-3,
                settings,
            )?));
        }
        let instruments = assets
            .spec
            .stack
            .iter()
            .zip(&assets.devices)
            .map(|(entry, (device, _))| {
                InstrumentSpec::new(device.clone(), entry.inserted_mm * 1e-3, &settings)
            })
            .collect();
        Ok(Strand::Stack(Stack::new(
            instruments,
            SharedWall(assets.anatomy.clone()),
            entry,
            direction,
            settings,
        )?))
    }

    /// Number of instruments (1 for a single device).
    pub fn len(&self) -> usize {
        match self {
            Strand::Single(_) => 1,
            Strand::Stack(s) => s.len(),
        }
    }

    /// Never empty.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Checks an instrument index from a client.
    pub fn check(&self, index: usize, field: &str) -> Result<()> {
        if index < self.len() {
            Ok(())
        } else {
            Err(EngineError::InvalidArgument {
                field: field.into(),
                reason: format!(
                    "instrument {index} is not in this scene, which has {} (0 is the outermost)",
                    self.len()
                ),
            })
        }
    }

    /// Instrument `index`'s command in force.
    pub fn command(&self, index: usize) -> Command {
        match self {
            Strand::Single(n) => n.current_command(),
            Strand::Stack(s) => s.command(index).unwrap_or_default(),
        }
    }

    /// Replaces instrument `index`'s command.
    pub fn set_command(&mut self, index: usize, command: Command) -> Result<()> {
        match self {
            Strand::Single(n) => n.set_command(command)?,
            Strand::Stack(s) => s.set_command(index, command)?,
        }
        Ok(())
    }

    /// Instrument `index`'s device.
    pub fn device(&self, index: usize) -> Option<&Device> {
        match self {
            Strand::Single(n) => (index == 0).then(|| n.device()),
            Strand::Stack(s) => s.device(index),
        }
    }

    /// Inserted length of instrument `index` (m).
    pub fn inserted_m(&self, index: usize) -> f64 {
        match self {
            Strand::Single(n) => n.inserted_m(),
            Strand::Stack(s) => s.inserted_m(index).unwrap_or(0.0),
        }
    }

    /// Twist of instrument `index` at the entry (rad).
    pub fn twist_rad(&self, index: usize) -> f64 {
        match self {
            Strand::Single(n) => n.twist_rad(),
            Strand::Stack(s) => s.twist_rad(index).unwrap_or(0.0),
        }
    }

    /// The most instrument `index` may be inserted now by the stack's own geometry (where its
    /// hub meets the hub around it; the outermost's length; infinite for a single device).
    pub fn hub_limit_m(&self, index: usize) -> f64 {
        match self {
            Strand::Single(_) => f64::INFINITY,
            Strand::Stack(s) => s.inserted_range_m(index).map_or(f64::INFINITY, |r| r.1),
        }
    }

    /// The index of the instrument whose tip leads (the farthest in).
    pub fn leading(&self) -> usize {
        (0..self.len())
            .max_by(|&a, &b| self.inserted_m(a).total_cmp(&self.inserted_m(b)))
            .unwrap_or(0)
    }

    /// Tip of instrument `index` (anatomy frame, m); `None` while it is withdrawn inside the
    /// one around it, proximal of the entry.
    pub fn tip_position(&self, index: usize) -> Option<Vector3<f64>> {
        match self {
            Strand::Single(n) => Some(n.tip_position()),
            Strand::Stack(s) => s.tip_position(index),
        }
    }

    /// The leading tip (anatomy frame, m).
    pub fn leading_tip(&self) -> Vector3<f64> {
        self.tip_position(self.leading())
            .unwrap_or_else(|| self.model().positions()[0])
    }

    /// Caps the work of the following steps.
    pub fn set_effort(&mut self, effort: Effort) -> Result<()> {
        match self {
            Strand::Single(n) => n.set_effort(effort)?,
            Strand::Stack(s) => s.set_effort(effort)?,
        }
        Ok(())
    }

    /// Sleep at rest on or off ([`Sleep`]'s defaults; a scene's `fidelity.sleep_at_rest`).
    pub fn set_sleep(&mut self, on: bool) {
        let sleep = on.then(Sleep::default);
        match self {
            Strand::Single(n) => n.set_sleep(sleep),
            Strand::Stack(s) => s.set_sleep(sleep),
        }
    }

    /// Whether the last steps found every instrument at rest with the hands still, so that
    /// the next such steps are skipped.
    pub fn asleep(&self) -> bool {
        match self {
            Strand::Single(n) => n.asleep(),
            Strand::Stack(s) => s.asleep(),
        }
    }

    /// One physics step.
    pub fn step(&mut self) -> cathlab_physics::Result<()> {
        match self {
            Strand::Single(n) => n.step().map(|_| ()),
            Strand::Stack(s) => s.step().map(|_| ()),
        }
    }

    /// The beam model of the whole strand.
    pub fn model(&self) -> &BeamModel {
        match self {
            Strand::Single(n) => n.model(),
            Strand::Stack(s) => s.model(),
        }
    }

    /// How far the deepest point of any instrument's surface lies past the wall (m, 0 when
    /// none does): every detection sample of every instrument, each with its own outer
    /// radius.
    pub fn max_penetration_m(&self) -> f64 {
        match self {
            Strand::Single(n) => n.max_penetration_m(),
            Strand::Stack(s) => s.max_penetration_m(),
        }
    }

    /// The wall.
    pub fn wall(&self) -> &SharedWall {
        match self {
            Strand::Single(n) => n.wall(),
            Strand::Stack(s) => s.wall(),
        }
    }

    /// The last step's contacts.
    pub fn last_contacts(&self) -> Option<&ContactStep> {
        match self {
            Strand::Single(n) => n.last_contacts(),
            Strand::Stack(s) => s.last_contacts(),
        }
    }

    /// The whole strand's base wrench (force N, moment N·m, anatomy frame) and what each
    /// instrument's hand feels (outermost first).
    pub fn reactions(&mut self) -> ([f64; 6], Vec<HandReaction>) {
        match self {
            Strand::Single(n) => {
                let r = n.proximal_reaction();
                let wrench = [r[0], r[1], r[2], r[3], r[4], r[5]];
                let positions = n.model().positions();
                let axis = match positions {
                    [a, b, ..] => (b - a).try_normalize(1e-12),
                    _ => None,
                };
                let hand = axis.map_or(HandReaction::default(), |axis| HandReaction {
                    axial_force_n: Vector3::new(r[0], r[1], r[2]).dot(&axis),
                    torque_nm: Vector3::new(r[3], r[4], r[5]).dot(&axis),
                });
                (wrench, vec![hand])
            }
            Strand::Stack(s) => {
                let hands = s
                    .proximal_reactions()
                    .into_iter()
                    .map(|r| HandReaction {
                        axial_force_n: r.axial_force_n,
                        torque_nm: r.torque_nm,
                    })
                    .collect();
                let r = s.model_mut().base_reaction();
                ([r[0], r[1], r[2], r[3], r[4], r[5]], hands)
            }
        }
    }

    /// Instrument `index`'s centerline, proximal first (anatomy frame, m): the strand's nodes
    /// up to its tip and the tip itself; empty while it is withdrawn proximal of the entry.
    pub fn polyline(&self, index: usize) -> Vec<Vector3<f64>> {
        match self {
            Strand::Single(n) => n.model().positions().to_vec(),
            Strand::Stack(s) => {
                let Some(tip) = s.tip_position(index) else {
                    return Vec::new();
                };
                let l = s.inserted_m(index).unwrap_or(0.0);
                let sigma = s.node_sigma_m();
                let positions = s.model().positions();
                let mut points: Vec<Vector3<f64>> = sigma
                    .iter()
                    .zip(positions)
                    .take_while(|(x, _)| **x < l - 1e-6)
                    .map(|(_, p)| *p)
                    .collect();
                points.push(tip);
                points
            }
        }
    }

    /// Everything that makes the state, for the world's digest: positions, frames, material
    /// or path coordinates, and every instrument's inserted length and twist.
    pub fn digest_into(&self, mut add: impl FnMut(&[f64])) {
        let model = self.model();
        for p in model.positions() {
            add(p.as_slice());
        }
        for q in model.rotations() {
            add(q.coords.as_slice());
        }
        match self {
            Strand::Single(n) => add(n.node_material_m()),
            Strand::Stack(s) => add(&s.node_sigma_m()),
        }
        for i in 0..self.len() {
            add(&[self.inserted_m(i), self.twist_rad(i)]);
        }
    }

    /// The stack, if this is one.
    pub fn stack(&self) -> Option<&Stack<SharedWall>> {
        match self {
            Strand::Single(_) => None,
            Strand::Stack(s) => Some(s),
        }
    }

    /// Sets the axial load on instrument `index`'s tip (N, along its tangent, negative
    /// resisting an advance): a clot resisting a crossing tip. A stack's only.
    pub fn set_tip_load(&mut self, index: usize, axial_n: f64) -> Result<()> {
        match self {
            Strand::Single(_) => Err(EngineError::FailedPrecondition(
                "tip loads are for a coaxial stack".into(),
            )),
            Strand::Stack(s) => s
                .set_tip_load(index, axial_n)
                .map_err(|e| EngineError::FailedPrecondition(e.to_string())),
        }
    }

    /// The stack, if this is one (mutable: exchanges).
    pub fn stack_mut(&mut self) -> Option<&mut Stack<SharedWall>> {
        match self {
            Strand::Single(_) => None,
            Strand::Stack(s) => Some(s),
        }
    }

    /// The single device's navigation, if this is one.
    pub fn navigation(&self) -> Option<&Navigation<SharedWall>> {
        match self {
            Strand::Single(n) => Some(n),
            Strand::Stack(_) => None,
        }
    }
}
