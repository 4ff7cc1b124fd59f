//! A navigation's settings: discretization, control limits, contact and refinement; the
//! work caps an overload governor lowers ([`Effort`]); and the node spacing they give along a
//! device.

use crate::beam::{SolverSettings, StepMode, ViscousDrag};
use crate::contact::ContactSettings;
use crate::error::{PhysicsError, Result};

use super::Sleep;

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
    /// Steps skipped while the hands are still and the device has come to rest (`None`, the
    /// default here: every step solved; the engine's scenes sleep).
    pub sleep: Option<Sleep>,
    /// The most axial force any element may carry (N, either way; `None`, the default: no
    /// bound). Before each solve, an element past it is relieved of the excess
    /// ([`crate::beam::BeamModel::relieve_axial_excess`]): the hands' strength is the most
    /// the loads on a device put into it (the engine allows twice that: see its strand).
    pub max_axial_force_n: Option<f64>,
    /// Whether the wall's friction resists the slide through the entry (false by default).
    /// The slide moves the material along the device's own path before the solve, so the
    /// solve's friction otherwise resists only its own corrections: a wire drawn round a bend
    /// then feels its friction with the wrong sign, where Coulomb's law on the whole motion
    /// gives the capstan law, the tension growing as e^{μθ} towards the hand that draws it
    /// (`cargo test -p cathlab-physics --test coaxial capstan`). Each contact's
    /// [`crate::contact::Contact::slip`] then carries the slide. Not yet the default: with
    /// it, the scripted genu prolapse's pull-back hooks its tip in the dead end beyond the
    /// genu and the scenes' two-hand demonstrations change course (docs/physics.md).
    pub slide_friction: bool,
    /// Whether the step cap judges the motion the last contact forces leave
    /// ([`SolverSettings::cap_with_held_contacts`], which says why), and the node split off
    /// at the entry goes on the smooth curve through its neighbours rather than on their
    /// chord (the chord puts it up to 0.1 mm off a bent wire; the uncapped correction of that
    /// stretched the short element at the entry by micrometres, 36 N at the hand for a step).
    /// False by default: with it, the autopilots' shaped wire strays into the left
    /// subclavian instead of the LCCA and the two-hand RVA run changes course
    /// (docs/physics.md, twenty-second session).
    pub cap_with_held_contacts: bool,
    /// Whether a merged stack's inner instruments slide through the ones around them with
    /// their own axial strain (false by default). Without it the strand is one composite
    /// beam axially too, so an inner instrument's compression is the strand's, the hands
    /// share the base force by axial stiffness, and a hand that gives way moves its tip but
    /// not the strain it left in the strand. With it an inner instrument is a cable in the
    /// frictionless lumen around it: its force is its own stiffness over the length it has
    /// inside that lumen times how far its tip lags its hand, its hand feels exactly that,
    /// the strand carries it as the loads a cable puts on its conduit, and the tip slides
    /// until the force beyond the exit is the cable's (`stack/slide.rs`).
    pub axial_slide: bool,
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
                acceleration_depth: 0,
                polish: true,
                ..ContactSettings::default()
            },
            refinement: Some(Refinement::default()),
            sleep: None,
            max_axial_force_n: None,
            slide_friction: false,
            cap_with_held_contacts: false,
            axial_slide: false,
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
    /// Contact iterations: Gauss–Seidel sweeps, and Newton iterations with the sweeps that
    /// finish an unconverged Newton solve (at most the contact settings').
    pub max_sweeps: usize,
    /// Whether the active-set polish may finish an unconverged contact solve (O(A³)).
    pub polish: bool,
    /// Scale of the refinement thresholds (≥ 1): elements bend and touch this much more
    /// before they split, and merge back sooner.
    pub refinement_scale: f64,
    /// Least penetration (m) that halves a step: a step is halved only where it penetrates
    /// past both this and the settings' `substep_penetration_m`. A level that does less per
    /// step (fewer detection rounds and sweeps) leaves more steps a little past the fine
    /// threshold; this keeps its halvings for those that go deep.
    pub min_substep_penetration_m: f64,
    /// Whether a step's penetration left after its last detection round is projected out
    /// ([`ContactSettings::project_penetration`]) instead of halving the step.
    pub project_penetration: bool,
}

impl Effort {
    /// No cap.
    pub const FULL: Effort = Effort {
        max_substep_depth: MAX_SUBSTEP_DEPTH,
        max_detection_rounds: usize::MAX,
        max_sweeps: usize::MAX,
        polish: true,
        refinement_scale: 1.0,
        min_substep_penetration_m: 0.0,
        project_penetration: false,
    };

    /// Checks the effort's values.
    pub fn validate(&self) -> Result<()> {
        if !(self.min_substep_penetration_m.is_finite() && self.min_substep_penetration_m >= 0.0) {
            return Err(PhysicsError::OutOfRange {
                what: "effort.min_substep_penetration_m".into(),
                range: "[0, ∞)",
                value: self.min_substep_penetration_m,
            });
        }
        if !(self.refinement_scale.is_finite() && self.refinement_scale >= 1.0) {
            return Err(PhysicsError::OutOfRange {
                what: "effort.refinement_scale".into(),
                range: "[1, ∞)",
                value: self.refinement_scale,
            });
        }
        Ok(())
    }

    /// `base` with its sweeps and Newton iterations, detection rounds (at least one) and polish capped by this
    /// effort.
    pub fn contact(&self, base: &ContactSettings) -> ContactSettings {
        ContactSettings {
            max_iterations: base.max_iterations.min(self.max_sweeps),
            newton_iterations: base.newton_iterations.min(self.max_sweeps),
            detection_rounds: base.detection_rounds.min(self.max_detection_rounds).max(1),
            polish: base.polish && self.polish,
            project_penetration: base.project_penetration || self.project_penetration,
            ..*base
        }
    }

    /// As [`Effort::contact`], for a try that will not be halved again (the deepest halving,
    /// [`Effort::substep_depth`]): the penetration its last detection round leaves is
    /// projected out ([`ContactSettings::project_penetration`]), since no smaller step will
    /// take it out. Halving cannot where the rounds, not the step's size, leave it: a
    /// microcatheter sliding round the curved wall of `stroke_m1_from_access` kept 0.056,
    /// 0.069 and 0.068 mm at a half, a quarter and an eighth of its step, each point's planes
    /// of four rounds satisfied and the wall curving past them.
    pub fn last_try_contact(&self, base: &ContactSettings) -> ContactSettings {
        ContactSettings {
            project_penetration: true,
            ..self.contact(base)
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

    /// The penetration (m) past which a step is halved, given the settings' own threshold.
    pub fn substep_penetration(&self, base_m: f64) -> f64 {
        base_m.max(self.min_substep_penetration_m)
    }
}

/// The beam solver settings of a navigated device or strand, for a solve that covers
/// `fraction` of a time step (1 for a whole step, ½ⁿ for a step halved n times): the drag's
/// time step and the caps on a solve's free motion scale with it, so that a halved step moves
/// the device half as far where it springs back (a loop releasing, a buckled wire snapping
/// straight), not only where it is pushed. Before, the halves each kept the whole step's drag
/// and caps, and a step halved three times to stay out of the wall took its elastic recoil
/// eight times over.
pub(crate) fn solver_settings(settings: &NavigationSettings, fraction: f64) -> SolverSettings {
    SolverSettings {
        mode: StepMode::PAPER,
        geometric_stiffness: true,
        compute_flexibility: true,
        drag: (settings.drag_n_s_per_m2 > 0.0).then_some(ViscousDrag {
            per_length_n_s_per_m2: settings.drag_n_s_per_m2,
            time_step_s: settings.time_step_s * fraction,
        }),
        max_step_increment: Some((
            settings.max_step_m * fraction,
            settings.max_step_rad * fraction,
        )),
        cap_with_held_contacts: settings.cap_with_held_contacts,
        geometric_stiffness_in_compression: false,
        max_substep_halvings: 0,
    }
}

/// Node spacing at material coordinate `s` (m from the proximal end) of a device of `length`.
pub(crate) fn spacing(settings: &NavigationSettings, length: f64, s: f64) -> f64 {
    let from_tip = length - s;
    let ramp = ((from_tip - settings.tip_zone_m) / settings.tip_zone_m).clamp(0.0, 1.0);
    settings.tip_element_m + ramp * (settings.shaft_element_m - settings.tip_element_m)
}
