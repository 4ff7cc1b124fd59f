//! Typed errors of the physics library: invalid parameters, singular systems, non-finite results.

use thiserror::Error;

/// Everything that can go wrong in `cathlab-physics`. Every variant names what was wrong.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PhysicsError {
    /// A parameter that must be a finite number is NaN or infinite.
    #[error("{what} must be finite, got {value}")]
    NotFinite {
        /// Which parameter, e.g. `section "tip": young_modulus_pa`.
        what: String,
        /// The offending value.
        value: f64,
    },
    /// A parameter that must be strictly positive is zero or negative.
    #[error("{what} must be > 0, got {value}")]
    NotPositive {
        /// Which parameter.
        what: String,
        /// The offending value.
        value: f64,
    },
    /// A parameter outside its admissible range.
    #[error("{what} must be in {range}, got {value}")]
    OutOfRange {
        /// Which parameter.
        what: String,
        /// The admissible range, in words, e.g. `(-1, 0.5)`.
        range: &'static str,
        /// The offending value.
        value: f64,
    },
    /// An anatomy query a scenario depends on failed (unknown target branch, no path).
    #[error("anatomy: {0}")]
    Anatomy(String),
    /// A tube whose inner radius is not smaller than its outer radius.
    #[error(
        "section \"{section}\": inner radius {inner_m} m must be smaller than outer radius {outer_m} m"
    )]
    InnerRadiusTooLarge {
        /// Section name.
        section: String,
        /// Inner radius (m).
        inner_m: f64,
        /// Outer radius (m).
        outer_m: f64,
    },
    /// A device needs at least three sections (shaft, transition, tip).
    #[error("device \"{device}\" has {count} sections; at least {min} are required")]
    TooFewSections {
        /// Device name.
        device: String,
        /// Sections given.
        count: usize,
        /// Sections required.
        min: usize,
    },
    /// An inner instrument of a coaxial stack does not fit the lumen of the one around it.
    #[error(
        "\"{inner}\" (largest outer diameter {inner_diameter_mm:.3} mm) does not fit the lumen of \"{outer}\" (smallest inner diameter {lumen_mm:.3} mm)"
    )]
    StackFit {
        /// The inner device's name.
        inner: String,
        /// The outer device's name.
        outer: String,
        /// Largest outer diameter of the inner device (mm).
        inner_diameter_mm: f64,
        /// Smallest lumen diameter of the outer device (mm).
        lumen_mm: f64,
    },
    /// A device definition (catalogue entry) with a bad field.
    #[error("device \"{device}\", {section}: {field}: {problem}")]
    DeviceDefinition {
        /// Device identifier or name.
        device: String,
        /// `section "name"`, or `device` for a device-level field.
        section: String,
        /// The field, as written in the definition (`inner_diameter_mm`).
        field: String,
        /// What is wrong with it.
        problem: String,
    },
    /// A device catalogue that is not valid TOML or lacks a field (the message names the line
    /// and the key).
    #[error("device catalogue: {0}")]
    CatalogueSyntax(String),
    /// A stack operation that the stack's state does not allow (exchanging an instrument that
    /// is still inserted, an instrument index out of range).
    #[error("stack: {0}")]
    Stack(String),
    /// A discretisation needs at least one element.
    #[error("a beam needs at least {min} element(s), got {count}")]
    TooFewElements {
        /// Elements requested.
        count: usize,
        /// Minimum.
        min: usize,
    },
    /// A vector passed in does not have the length the model expects.
    #[error("{what}: expected length {expected}, got {actual}")]
    LengthMismatch {
        /// Which input.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Actual length.
        actual: usize,
    },
    /// A pivot block of the stiffness matrix could not be inverted.
    #[error("stiffness block at node {node} is singular (is the structure constrained?)")]
    SingularBlock {
        /// Node index (0-based, among the unknown nodes).
        node: usize,
    },
    /// A step failed a divergence check; the state was left as it was before the step.
    #[error("step {step}, node {node}: {check}: the simulation diverged")]
    Diverged {
        /// Which check tripped.
        check: DivergenceCheck,
        /// Node index (in the model whose step diverged; 0 where no node is concerned).
        node: usize,
        /// The step that diverged, numbered from 1.
        step: u64,
    },
}

impl PhysicsError {
    /// Whether this is a step that failed a divergence check (and left the state as it was):
    /// one a smaller step may pass.
    pub fn is_divergence(&self) -> bool {
        matches!(self, PhysicsError::Diverged { .. })
    }
}

/// The divergence check that tripped (see [`PhysicsError::Diverged`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DivergenceCheck {
    /// A quantity (named) became NaN or infinite.
    NonFinite(&'static str),
    /// One linear solve moved a node farther than the limit: no quasi-static load a device can
    /// bear does that.
    TranslationIncrement {
        /// The node's translation increment (m).
        increment_m: f64,
        /// The limit (m): [`crate::beam::MAX_TRANSLATION_INCREMENT_LENGTHS`] device lengths.
        limit_m: f64,
    },
    /// One linear solve rotated a node by more than π: the rotation vector is no longer a
    /// unique description of the increment.
    RotationIncrement {
        /// The node's rotation increment (rad).
        increment_rad: f64,
    },
}

impl std::fmt::Display for DivergenceCheck {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            DivergenceCheck::NonFinite(quantity) => write!(f, "non-finite {quantity}"),
            DivergenceCheck::TranslationIncrement {
                increment_m,
                limit_m,
            } => write!(
                f,
                "translation increment of {increment_m:.3e} m exceeds the limit of {limit_m:.3e} m"
            ),
            DivergenceCheck::RotationIncrement { increment_rad } => {
                write!(f, "rotation increment of {increment_rad:.3} rad exceeds π")
            }
        }
    }
}

/// Result alias of the physics library.
pub type Result<T> = std::result::Result<T, PhysicsError>;

/// Fails with [`PhysicsError::NotFinite`] unless `value` is finite.
pub(crate) fn require_finite(what: impl FnOnce() -> String, value: f64) -> Result<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(PhysicsError::NotFinite {
            what: what(),
            value,
        })
    }
}

/// Fails unless `value` is finite and strictly positive.
pub(crate) fn require_positive(what: impl Fn() -> String, value: f64) -> Result<f64> {
    require_finite(&what, value)?;
    if value > 0.0 {
        Ok(value)
    } else {
        Err(PhysicsError::NotPositive {
            what: what(),
            value,
        })
    }
}
