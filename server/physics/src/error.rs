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
    /// The simulation produced NaN or infinity; the state was left as it was before the step.
    #[error("non-finite {quantity} at node {node} in step {step}: the simulation diverged")]
    Diverged {
        /// What became non-finite (position, rotation, force...).
        quantity: &'static str,
        /// Node index.
        node: usize,
        /// Step counter at which it happened.
        step: u64,
    },
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
