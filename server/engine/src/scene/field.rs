//! What every section's checks share: the error naming a field's path and the reason, the
//! range check, and serde's `true` default.

use crate::error::{EngineError, Result};

/// A scene error at `path` (`fidelity.step_rate_hz`, `stack[1].device`) for `reason`.
pub(crate) fn scene_error(path: impl Into<String>, reason: impl Into<String>) -> EngineError {
    EngineError::Scene {
        path: path.into(),
        reason: reason.into(),
    }
}

/// Checks that `value` is finite and within `lo..=hi`; the error names `path`.
pub(super) fn range(path: &str, value: f64, lo: f64, hi: f64) -> Result<()> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(scene_error(path, format!("{value} is outside {lo}..={hi}")))
    }
}

/// serde's default for switches that are on unless a scene turns them off.
pub(super) fn yes() -> bool {
    true
}
