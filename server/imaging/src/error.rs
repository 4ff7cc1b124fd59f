//! Typed errors of the imaging crate: every error names the file (or parameter) and what is
//! wrong.

use std::path::PathBuf;

use cathlab_anatomy::AnatomyError;

/// Everything that can go wrong while reading volumes or segmenting them.
#[derive(Debug, thiserror::Error)]
pub enum ImagingError {
    /// The file could not be read (or written) at all.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The file.
        file: PathBuf,
        /// The operating-system error.
        #[source]
        source: std::io::Error,
    },
    /// A volume file is malformed: a missing or bad header field, or too little data.
    #[error("{file}: {reason}")]
    BadVolume {
        /// The file.
        file: PathBuf,
        /// What is wrong, e.g. `ElementSpacing: axis 1 is 0 (must be > 0)`.
        reason: String,
    },
    /// A volume file uses a feature the readers do not support.
    #[error("{file}: unsupported {what}")]
    UnsupportedVolume {
        /// The file.
        file: PathBuf,
        /// What, e.g. `ElementType MET_LONG`.
        what: String,
    },
    /// A volume built in memory is inconsistent (zero size or spacing, wrong value count).
    #[error("invalid volume: {0}")]
    InvalidVolume(String),
    /// A DICOM series is unusable: no slices, mixed series, a missing slice, inconsistent
    /// geometry, a transfer syntax that cannot be decoded.
    #[error("{dir}: DICOM: {reason}")]
    Dicom {
        /// The folder or file.
        dir: PathBuf,
        /// What is wrong, naming the file and the attribute.
        reason: String,
    },
    /// Segmentation could not proceed: the seed is outside the volume or the lumen, nothing
    /// was segmented, the skeleton is empty.
    #[error("segmentation: {0}")]
    Segmentation(String),
    /// A case (a surface or volume made into a scene) is inconsistent: the field and why.
    #[error("{field}: {reason}")]
    Case {
        /// The field, e.g. `access.end`.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// The vessel geometry built from the image is invalid.
    #[error(transparent)]
    Anatomy(#[from] AnatomyError),
}

/// Shorthand for results of this crate.
pub type Result<T> = std::result::Result<T, ImagingError>;
