//! The scene's `[ct]`: the CT behind the vessels (the synthesized phantom or a file), and its
//! checks.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::field::range;
use crate::error::Result;

/// The CT.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum CtSpec {
    /// The synthesized head-and-neck body placed around the vessels.
    Phantom {
        /// Voxel spacing (mm), 0.5–5.
        spacing_mm: f64,
    },
    /// A MetaImage or NIfTI file (relative to the scene file).
    File {
        /// The volume.
        path: PathBuf,
        /// HU = slope · value + intercept.
        #[serde(default = "one")]
        hu_slope: f64,
        /// See `hu_slope`.
        #[serde(default)]
        hu_intercept: f64,
    },
}

fn one() -> f64 {
    1.0
}

impl CtSpec {
    /// Checks the phantom's spacing or the file's HU rescale.
    pub(super) fn validate(&self) -> Result<()> {
        match self {
            CtSpec::Phantom { spacing_mm } => range("ct.spacing_mm", *spacing_mm, 0.5, 5.0)?,
            CtSpec::File {
                hu_slope,
                hu_intercept,
                ..
            } => {
                range("ct.hu_slope", *hu_slope, -1e6, 1e6)?;
                range("ct.hu_intercept", *hu_intercept, -1e6, 1e6)?;
            }
        }
        Ok(())
    }
}
