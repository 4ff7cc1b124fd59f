//! The errors a scene's load gives: the field path and the reason, never the server's paths
//! or a file's contents.

use std::path::Path;

use crate::error::EngineError;

/// A scene error at `path` for `reason`.
pub(super) fn scene_error(path: &str, reason: impl std::fmt::Display) -> EngineError {
    EngineError::Scene {
        path: path.into(),
        reason: reason.to_string(),
    }
}

/// A file a scene named could not be read: the detail goes to the log, the client hears only
/// which field (never the server's paths or the file's contents).
pub(super) fn unreadable(field: &str, path: &Path, e: impl std::fmt::Display) -> EngineError {
    tracing::warn!(field, path = %path.display(), "scene file unreadable: {e}");
    // A reader's limit says which limit and by how much (no path, no contents): the caller
    // learns why; anything else stays in the log (no echo of a file's contents).
    let text = e.to_string();
    match text.find(cathlab_anatomy::io::limits::REFUSED) {
        Some(at) => scene_error(field, &text[at..]),
        None => scene_error(
            field,
            "cannot be read as what the field names (the server's log has the detail)",
        ),
    }
}
