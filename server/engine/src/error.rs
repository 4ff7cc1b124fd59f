//! The engine's error type: what went wrong, in terms the API layer maps to status codes.

use std::path::PathBuf;

/// Everything the engine can report.
#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    /// A scene text or file that does not parse or holds a bad value: `path` names the field
    /// (`fidelity.step_rate_hz`), `reason` what is wrong with it.
    #[error("scene: {path}: {reason}")]
    Scene {
        /// Field path (and file, for scene files).
        path: String,
        /// What is wrong.
        reason: String,
    },
    /// A command argument out of range.
    #[error("{field}: {reason}")]
    InvalidArgument {
        /// The field.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// A command that cannot apply in the session's state (roadmap without a DSA run,
    /// injection in a scene without flow).
    #[error("{0}")]
    FailedPrecondition(String),
    /// A limit of the server is reached (sessions, replays): try later.
    #[error("{0}")]
    Exhausted(String),
    /// Work abandoned because its caller went away.
    #[error("cancelled: {0}")]
    Cancelled(String),
    /// No such scene or session.
    #[error("not found: {0}")]
    NotFound(String),
    /// The session has stopped.
    #[error("session closed: {0}")]
    Closed(String),
    /// Too many queued commands.
    #[error("command queue full ({0} pending)")]
    QueueFull(usize),
    /// A file could not be read.
    #[error("{file}: {source}")]
    Io {
        /// The file.
        file: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// Loading the scene's anatomy failed.
    #[error("anatomy: {0}")]
    Anatomy(#[from] cathlab_anatomy::AnatomyError),
    /// Reading or segmenting an image failed.
    #[error("imaging: {0}")]
    Imaging(#[from] cathlab_imaging::ImagingError),
    /// The physics refused something.
    #[error("physics: {0}")]
    Physics(#[from] cathlab_physics::PhysicsError),
    /// Flow or contrast refused something.
    #[error("flow: {0}")]
    Hemo(#[from] cathlab_hemo::HemoError),
    /// Imaging refused something.
    #[error("x-ray: {0}")]
    Xray(#[from] cathlab_xray::XrayError),
    /// A session thread could not start.
    #[error("cannot start a thread: {0}")]
    Spawn(String),
    /// The recording store failed.
    #[error("store: {0}")]
    Store(String),
}

/// Engine results.
pub type Result<T> = std::result::Result<T, EngineError>;
