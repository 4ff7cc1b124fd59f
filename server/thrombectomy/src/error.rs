//! Errors of the thrombectomy models: the parameter and what it must be.

use thiserror::Error;

/// What went wrong.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ThrombectomyError {
    /// A parameter out of its range.
    #[error("{name} = {value} is invalid: it must be {requirement}")]
    InvalidParameter {
        /// The parameter, with its unit.
        name: String,
        /// Its value.
        value: f64,
        /// What it must be.
        requirement: &'static str,
    },
}

/// Result of the thrombectomy models.
pub type Result<T> = std::result::Result<T, ThrombectomyError>;

/// Checks that `value` is finite and above zero.
pub(crate) fn require_positive(name: &str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(ThrombectomyError::InvalidParameter {
            name: name.into(),
            value,
            requirement: "finite and above zero",
        })
    }
}

/// Checks that `value` is finite and not negative.
pub(crate) fn require_non_negative(name: &str, value: f64) -> Result<()> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(ThrombectomyError::InvalidParameter {
            name: name.into(),
            value,
            requirement: "finite and not negative",
        })
    }
}
