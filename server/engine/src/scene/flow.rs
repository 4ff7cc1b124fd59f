//! The scene's `[flow]` (blood flow and contrast, with optional pial collaterals) and its
//! `[[clots]]`, and the flow's checks (the clots are checked against the vessels when the
//! scene loads).

use serde::{Deserialize, Serialize};

use super::field::{range, scene_error};
use crate::error::Result;

/// Blood flow and contrast.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlowSpec {
    /// The branch whose free end is the inlet.
    pub inlet_branch: String,
    /// Inlet pressure (mmHg).
    #[serde(default = "default_pressure")]
    pub pressure_mmhg: f64,
    /// Iodine concentration of the contrast agent (mg/mL).
    #[serde(default = "default_agent")]
    pub agent_mg_per_ml: f64,
    /// Pial collaterals feeding a territory whose artery may be occluded.
    #[serde(default)]
    pub collaterals: Option<CollateralSpec>,
}

/// Leptomeningeal collaterals: vessels from the ends of the donor branches to the end of the
/// recipient branch, calibrated so that with the recipient occluded they bring
/// `supply_fraction` of its resting flow (the collateral status: good 0.4, moderate 0.2,
/// poor 0.05; see `cathlab_hemo::CollateralStatus`). eTICI grades the antegrade reperfusion,
/// so it is measured on the network without them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollateralSpec {
    /// The branch whose territory the collaterals feed.
    pub recipient: String,
    /// The branches whose territories they come from.
    pub donors: Vec<String>,
    /// Share of the recipient's resting flow they bring with it occluded, 0.01–0.9.
    pub supply_fraction: f64,
}

/// A clot in a vessel: where, how long, and what it is made of.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClotSpec {
    /// The branch it sits in.
    pub branch: String,
    /// Where it starts, along the branch from its start (mm).
    pub from_mm: f64,
    /// Its length (mm); stroke clots are 5–15 mm.
    pub length_mm: f64,
    /// Fraction of red cells, 0 (fibrin/platelet-rich) to 1 (red-cell-rich).
    #[serde(default = "default_red_cells")]
    pub red_cell_fraction: f64,
}

fn default_red_cells() -> f64 {
    0.5
}

fn default_pressure() -> f64 {
    100.0
}
fn default_agent() -> f64 {
    300.0
}

impl FlowSpec {
    /// Checks the pressure, the contrast agent and the collaterals.
    pub(super) fn validate(&self) -> Result<()> {
        let flow = self;
        range("flow.pressure_mmhg", flow.pressure_mmhg, 10.0, 300.0)?;
        range("flow.agent_mg_per_ml", flow.agent_mg_per_ml, 50.0, 400.0)?;
        if let Some(c) = &flow.collaterals {
            range(
                "flow.collaterals.supply_fraction",
                c.supply_fraction,
                0.01,
                0.9,
            )?;
            if c.donors.is_empty() || c.donors.len() > 8 {
                return Err(scene_error(
                    "flow.collaterals.donors",
                    format!("{} donor branches (1 to 8)", c.donors.len()),
                ));
            }
        }
        Ok(())
    }
}
