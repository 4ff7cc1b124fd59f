//! Typed errors of the X-ray library: bad geometry, unreadable or unsupported volumes.

use std::path::PathBuf;

use thiserror::Error;

/// Everything that can go wrong in `cathlab-xray`; every variant names what was wrong.
#[derive(Debug, Error)]
pub enum XrayError {
    /// A geometry parameter that must be finite is NaN or infinite.
    #[error("{what} must be finite, got {value}")]
    NotFinite {
        /// Which parameter.
        what: String,
        /// The offending value.
        value: f64,
    },
    /// A parameter outside its admissible range.
    #[error("{what} must be {range}, got {value}")]
    OutOfRange {
        /// Which parameter.
        what: String,
        /// The admissible range, in words.
        range: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A volume file could not be read.
    #[error("{file}: {source}")]
    Io {
        /// The file.
        file: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A volume file is malformed: a missing or bad header field, or too little data.
    #[error("{file}: {reason}")]
    BadVolume {
        /// The file.
        file: PathBuf,
        /// What is wrong, e.g. `DimSize: expected 3 positive integers`.
        reason: String,
    },
    /// A volume file uses a feature this reader does not support.
    #[error("{file}: unsupported {what}")]
    Unsupported {
        /// The file.
        file: PathBuf,
        /// What, e.g. `ElementType MET_LONG_ARRAY`.
        what: String,
    },
    /// A volume built in memory is inconsistent (zero size or spacing, non-orthonormal
    /// direction, wrong voxel count).
    #[error("invalid volume: {0}")]
    InvalidVolume(String),
    /// An operation that needs something not there yet, e.g. a roadmap without a DSA run.
    #[error("{0}")]
    Unavailable(String),
    /// The GPU path failed: no adapter, a device error, a buffer that would not map.
    #[error("gpu: {0}")]
    Gpu(String),
    /// A scene file is malformed.
    #[error("{file}: {reason}")]
    BadScene {
        /// The file.
        file: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

/// Result alias of the X-ray library.
pub type Result<T> = std::result::Result<T, XrayError>;

pub(crate) fn require_finite(what: impl Fn() -> String, value: f64) -> Result<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(XrayError::NotFinite {
            what: what(),
            value,
        })
    }
}

pub(crate) fn require_positive(what: impl Fn() -> String, value: f64) -> Result<f64> {
    require_finite(&what, value)?;
    if value > 0.0 {
        Ok(value)
    } else {
        Err(XrayError::OutOfRange {
            what: what(),
            range: "> 0",
            value,
        })
    }
}
