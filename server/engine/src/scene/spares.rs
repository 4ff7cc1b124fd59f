//! The scene's `[[spares]]`: the back table of a stack scene (devices an instrument may be
//! exchanged for besides the catalogue's), and their checks.

use serde::{Deserialize, Serialize};

use super::devices::DeviceSpec;
use super::field::scene_error;
use super::stack::StackEntry;
use crate::error::{EngineError, Result};

/// A device on a stack scene's back table: a catalogue identifier or a preset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpareSpec {
    /// Catalogue identifier; empty when `custom` gives the device.
    #[serde(default)]
    pub device: String,
    /// A preset.
    #[serde(default)]
    pub custom: Option<DeviceSpec>,
}

impl SpareSpec {
    /// A short name for lists: the catalogue id or the preset's label.
    pub fn label(&self) -> String {
        match &self.custom {
            Some(custom) => custom.label(),
            None => self.device.clone(),
        }
    }

    /// The device and its look; `index` is its place among the spares, for the error's path.
    pub fn resolve(
        &self,
        index: usize,
    ) -> Result<(cathlab_physics::Device, cathlab_xray::DeviceAppearance)> {
        StackEntry {
            device: self.device.clone(),
            custom: self.custom.clone(),
            inserted_mm: 0.0,
        }
        .resolve(index)
        .map_err(|e| match e {
            EngineError::Scene { path, reason } => {
                scene_error(path.replacen("stack", "spares", 1), reason)
            }
            other => other,
        })
    }
}

/// Most spares on a scene's back table.
pub const MAX_SPARES: usize = 16;

/// Checks the back table: only for a stack scene, each spare's preset and device, at most
/// [`MAX_SPARES`].
pub(super) fn validate_spares(spares: &[SpareSpec], stack: &[StackEntry]) -> Result<()> {
    if !spares.is_empty() && stack.is_empty() {
        return Err(scene_error(
            "spares",
            "spares are for a stack scene's exchanges",
        ));
    }
    for (i, spare) in spares.iter().enumerate() {
        if let Some(custom) = &spare.custom {
            custom.validate(&format!("spares[{i}].custom"))?;
        }
        spare.resolve(i)?;
    }
    if spares.len() > MAX_SPARES {
        return Err(scene_error(
            "spares",
            format!("{} spares; at most {MAX_SPARES}", spares.len()),
        ));
    }
    Ok(())
}
