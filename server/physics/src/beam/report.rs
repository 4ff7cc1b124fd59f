//! What a beam step reports: the solves and last increments ([`StepReport`]), and for a step
//! with contacts the contacts and their forces ([`ContactStep`]).

use crate::contact::{Contact, ContactResponse};

/// What a step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    /// Linear solves performed.
    pub iterations: usize,
    /// Whether the converged mode met its tolerance (always true in paper mode).
    pub converged: bool,
    /// Largest node translation increment of the last iteration (m).
    pub last_translation_increment_m: f64,
    /// Largest node rotation increment of the last iteration (rad).
    pub last_rotation_increment_rad: f64,
}

/// What a step with contacts did.
#[derive(Debug, Clone, PartialEq)]
pub struct ContactStep {
    /// The beam step (one linear solve plus the contact correction).
    pub report: StepReport,
    /// The contacts detected for this step.
    pub contacts: Vec<Contact>,
    /// Their forces.
    pub response: ContactResponse,
    /// The deepest penetration the last detection saw in the solved configuration (m; 0 when
    /// the step had no contacts).
    pub penetration_m: f64,
}
