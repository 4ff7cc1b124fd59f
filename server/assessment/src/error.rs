//! Typed errors of the assessment: which samples or setting were wrong, and why.

/// What went wrong.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum AssessmentError {
    /// The samples cannot be assessed (too few, time not increasing, a value not finite).
    #[error("samples: {0}")]
    Samples(String),
    /// The scene's assessment section is wrong (a phase, a benchmark).
    #[error("assessment: {0}")]
    Spec(String),
    /// A setting is out of its range.
    #[error("{what} is {value}, must be {range}")]
    Setting {
        /// The setting.
        what: &'static str,
        /// Its value.
        value: f64,
        /// The allowed range, in words.
        range: &'static str,
    },
}

/// Result of the assessment.
pub type Result<T> = std::result::Result<T, AssessmentError>;
