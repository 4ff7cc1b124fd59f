//! A navigation's data and its handling between steps: the [`Navigation`] itself, its
//! construction in the device's rest shape, its accessors and command, the tip's pose, and the
//! rest geometry of the device between two material points.

use nalgebra::{UnitQuaternion, Vector3, Vector6};

use super::command::{Command, Insertion, Twist};
use super::detection::ClearanceCache;
use super::settings::{Effort, NavigationSettings, solver_settings, spacing};
use super::sleep::Stillness;
use crate::beam::{BeamModel, ContactStep, ElementSpec};
use crate::contact::ContactSettings;
use crate::device::Device;
use crate::error::{PhysicsError, Result, require_finite, require_positive};
use crate::wall::Wall;

/// A device being navigated through a vessel.
#[derive(Debug, Clone)]
pub struct Navigation<W: Wall> {
    pub(super) device: Device,
    pub(super) wall: W,
    pub(super) settings: NavigationSettings,
    pub(super) model: BeamModel,
    pub(super) entry_position: Vector3<f64>,
    pub(super) entry_rotation: UnitQuaternion<f64>,
    /// Material coordinate (m from the proximal end) of every simulated node, base to tip.
    pub(super) material: Vec<f64>,
    pub(super) twist_rad: f64,
    pub(super) command: Command,
    pub(super) time_s: f64,
    pub(super) last: Option<ContactStep>,
    /// Material coordinates and local forces of the last contacts (for warm starts).
    pub(super) previous_contacts: Vec<(f64, Vector3<f64>)>,
    pub(super) effort: Effort,
    /// Wall-distance bounds that spare collision points their probes.
    pub(super) clearance: ClearanceCache,
    /// How long the device has been at rest ([`NavigationSettings::sleep`]).
    pub(super) stillness: Stillness,
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
            solver_settings(&settings, 1.0),
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
            stillness: Stillness::default(),
        })
    }

    /// Caps the work of the following steps (see [`Effort`]).
    pub fn set_effort(&mut self, effort: Effort) -> Result<()> {
        effort.validate()?;
        if effort != self.effort {
            self.stillness.wake();
        }
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

    /// Sleep at rest on (`Some`) or off (see [`NavigationSettings::sleep`]); counts the quiet
    /// steps afresh.
    pub fn set_sleep(&mut self, sleep: Option<crate::navigation::Sleep>) {
        self.stillness.wake();
        self.settings.sleep = sleep;
    }

    /// Replaces the Gauss–Seidel settings (from the next step on).
    pub fn set_contact_settings(&mut self, contact: ContactSettings) {
        self.stillness.wake();
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
    pub(super) fn first_curved_element(&self) -> Option<usize> {
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
}

/// Rest geometry of the device between material coordinates `a` < `b`.
pub(super) fn element_spec(device: &Device, a: f64, b: f64) -> ElementSpec {
    let mid = 0.5 * (a + b);
    ElementSpec {
        props: device.section_at(mid).0.beam_properties(),
        length_m: b - a,
        curvature_per_m: device.mean_rest_curvature(a, b),
    }
}
