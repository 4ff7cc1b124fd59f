//! Typed errors of the anatomy crate: every error names the file (or parameter) and what is wrong.

use std::path::PathBuf;

/// Everything that can go wrong while reading, building or querying anatomy.
#[derive(Debug, thiserror::Error)]
pub enum AnatomyError {
    /// The file could not be read at all.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The file.
        file: PathBuf,
        /// The operating-system error.
        #[source]
        source: std::io::Error,
    },
    /// The file's contents are malformed (truncated, not a number, bad index, NaN, ...).
    #[error("{file}{}: {message}", line.map(|l| format!(" line {l}")).unwrap_or_default())]
    Parse {
        /// The file (or a description of an in-memory source).
        file: String,
        /// The 1-based line, where the format is line-based.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// The file parsed but holds no geometry.
    #[error("{file}: empty: {message}")]
    Empty {
        /// The file.
        file: String,
        /// What was expected.
        message: String,
    },
    /// The declared (or assumed) length unit is unknown or gives an implausible anatomy.
    #[error("{file}: units: {message}")]
    Units {
        /// The file.
        file: String,
        /// What is wrong.
        message: String,
    },
    /// A surface is not a closed, consistently oriented 2-manifold where one is required.
    #[error("{file}: not a closed manifold surface: {message}")]
    NotManifold {
        /// The file or the generator that produced the surface.
        file: String,
        /// The first defects found.
        message: String,
    },
    /// A numeric parameter is out of its valid range.
    #[error("invalid parameter {name} = {value}: must be {requirement}")]
    InvalidParameter {
        /// The parameter's name.
        name: &'static str,
        /// The offending value.
        value: f64,
        /// The valid range, in words.
        requirement: &'static str,
    },
    /// A vessel graph is malformed (too few points, dangling junction, mismatched radii, ...).
    #[error("invalid vessel graph: {0}")]
    InvalidGraph(String),
    /// No branch has this name.
    #[error("no branch named {0:?}")]
    UnknownBranch(String),
    /// The vessel graph does not connect the two places.
    #[error("no path from {from} to {to}")]
    NoPath {
        /// The start, in words.
        from: String,
        /// The target, in words.
        to: String,
    },
}

/// Shorthand for results of this crate.
pub type Result<T> = std::result::Result<T, AnatomyError>;

/// Checks that `value` is finite and strictly positive.
pub(crate) fn require_positive(name: &'static str, value: f64) -> Result<f64> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(AnatomyError::InvalidParameter {
            name,
            value,
            requirement: "finite and > 0",
        })
    }
}

/// Checks that `value` lies in `[low, high]` (and is finite).
pub(crate) fn require_range(
    name: &'static str,
    value: f64,
    low: f64,
    high: f64,
    requirement: &'static str,
) -> Result<f64> {
    if value.is_finite() && value >= low && value <= high {
        Ok(value)
    } else {
        Err(AnatomyError::InvalidParameter {
            name,
            value,
            requirement,
        })
    }
}
