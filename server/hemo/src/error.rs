//! Typed errors of the hemodynamics crate: each names the vessel, node, parameter or file at fault.

use std::path::PathBuf;

/// Everything that can go wrong while building, reading or solving a flow network, or while
/// advecting contrast on it.
#[derive(Debug, thiserror::Error)]
pub enum HemoError {
    /// A file could not be read.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The file.
        file: PathBuf,
        /// The operating-system error.
        #[source]
        source: std::io::Error,
    },
    /// A file's contents are malformed.
    #[error("{file}: {message}")]
    Parse {
        /// The file (or a description of an in-memory source).
        file: String,
        /// What is wrong, with the entry that holds it.
        message: String,
    },
    /// A numeric parameter is NaN, infinite or outside its valid range.
    #[error("invalid {name} = {value}: must be {requirement}")]
    InvalidParameter {
        /// What the parameter is (for example `vessel "L-MCA" radius (m)`).
        name: String,
        /// The offending value.
        value: f64,
        /// The valid range, in words.
        requirement: &'static str,
    },
    /// A vessel's two ends are the same node, or it refers to a node that does not exist.
    #[error("vessel {vessel:?}: {message}")]
    InvalidVessel {
        /// The vessel's name.
        vessel: String,
        /// What is wrong.
        message: String,
    },
    /// The network's vessels form more than one connected piece.
    #[error(
        "the network is disconnected: {components} separate pieces (node {example_node} is not connected to the inlet)"
    )]
    Disconnected {
        /// The number of connected components.
        components: usize,
        /// A node that the inlet cannot reach.
        example_node: usize,
    },
    /// The network has no outlet, so blood has nowhere to go.
    #[error(
        "the network has no outlet: add at least one outlet node with a terminal resistance or pressure"
    )]
    NoOutlet,
    /// A boundary condition is attached to a node that is not a free end, or twice.
    #[error("node {node}: {message}")]
    InvalidBoundary {
        /// The node.
        node: usize,
        /// What is wrong.
        message: String,
    },
    /// A named vessel (or branch) does not exist.
    #[error("no vessel named {0:?}")]
    UnknownVessel(String),
    /// A vessel index is out of range.
    #[error("vessel index {index} out of range (the network has {count} vessels)")]
    VesselIndex {
        /// The index asked for.
        index: usize,
        /// The number of vessels.
        count: usize,
    },
    /// The linear solver failed (the conductance matrix is not positive definite).
    #[error("flow solve failed: {0}")]
    Solver(String),
    /// Anatomy could not be used to build a network.
    #[error(transparent)]
    Anatomy(#[from] cathlab_anatomy::AnatomyError),
}

/// Result with [`HemoError`].
pub type Result<T> = std::result::Result<T, HemoError>;

/// Checks that `value` is finite and strictly positive.
pub(crate) fn require_positive(name: impl FnOnce() -> String, value: f64) -> Result<f64> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(HemoError::InvalidParameter {
            name: name(),
            value,
            requirement: "finite and > 0",
        })
    }
}

/// Checks that `value` is finite and not negative.
pub(crate) fn require_non_negative(name: impl FnOnce() -> String, value: f64) -> Result<f64> {
    if value.is_finite() && value >= 0.0 {
        Ok(value)
    } else {
        Err(HemoError::InvalidParameter {
            name: name(),
            value,
            requirement: "finite and >= 0",
        })
    }
}

/// Checks that `value` is finite.
pub(crate) fn require_finite(name: impl FnOnce() -> String, value: f64) -> Result<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(HemoError::InvalidParameter {
            name: name(),
            value,
            requirement: "finite",
        })
    }
}
