//! The scene's `[start]`: where the device enters the vessels, and its checks.

use serde::{Deserialize, Serialize};

use super::field::range;
use crate::error::Result;

/// Where the device enters the vessels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartSpec {
    /// Distance along the route from the access point to the target where the device enters
    /// (mm): 0 at the femoral access, more for a guide catheter parked further up.
    #[serde(default)]
    pub along_route_mm: f64,
    /// Length inserted at the start (mm).
    #[serde(default = "default_inserted_mm")]
    pub inserted_mm: f64,
}

fn default_inserted_mm() -> f64 {
    10.0
}

impl Default for StartSpec {
    fn default() -> Self {
        Self {
            along_route_mm: 0.0,
            inserted_mm: default_inserted_mm(),
        }
    }
}

impl StartSpec {
    /// Checks the entry point along the route and the length inserted at the start.
    pub(super) fn validate(&self) -> Result<()> {
        range("start.along_route_mm", self.along_route_mm, 0.0, 2000.0)?;
        range("start.inserted_mm", self.inserted_mm, 2.0, 500.0)?;
        Ok(())
    }
}
