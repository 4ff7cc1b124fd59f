//! Leptomeningeal (pial) collaterals: the small arteries over the brain's surface that join
//! the distal territories of the anterior, middle and posterior cerebral arteries. With an
//! M1 occluded they are what still feeds the MCA territory (retrogradely, late on DSA), and
//! how well they do it ("collateral status") is one of the strongest predictors of stroke
//! outcome. Each collateral is a vessel between a donor's and a recipient's territory nodes;
//! its resistance is calibrated so that, with the recipient's artery occluded, the
//! collaterals deliver a chosen fraction of the recipient's resting flow.

use crate::clot::Occlusion;
use crate::error::{HemoError, Result};
use crate::flow::FlowSolver;
use crate::network::{FlowNetwork, Vessel};

/// Length given to a collateral vessel (m): its volume (π r² L) delays contrast through it.
pub const COLLATERAL_LENGTH_M: f64 = 0.05;

/// Collateral status as the share of the recipient's resting flow that reaches its
/// territory with its artery occluded. The scene chooses it; typical choices, from the
/// ischaemic thresholds of cerebral blood flow (normal about 50 mL/100 g/min, penumbra
/// 10–20, core below 10; Astrup et al., Stroke 1981): good 0.4, moderate 0.2, poor 0.05.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CollateralStatus {
    /// Fraction of the recipient's resting flow (0 < f < 1).
    pub supply_fraction: f64,
}

/// Adds collaterals from the end of each donor vessel to the end of `recipient`, all of one
/// resistance, calibrated (bisection on its logarithm) so that with `recipient` occluded
/// along its whole length they deliver `status.supply_fraction` of its open-network flow.
/// Returns the new network and the collateral resistance (Pa·s/m³).
pub fn with_pial_collaterals(
    network: &FlowNetwork,
    recipient: &str,
    donors: &[&str],
    status: CollateralStatus,
) -> Result<(FlowNetwork, f64)> {
    let f = status.supply_fraction;
    if !(f > 0.0 && f < 1.0) {
        return Err(HemoError::InvalidParameter {
            name: "collateral supply fraction".into(),
            value: f,
            requirement: "between 0 and 1, exclusive",
        });
    }
    let to = network.vessel(recipient)?.to;
    let from: Vec<usize> = donors
        .iter()
        .map(|d| network.vessel(d).map(|v| v.to))
        .collect::<Result<_>>()?;
    let resting = {
        let id = network.vessel_id(recipient)?;
        FlowSolver::new(network.clone())?.solve(None)?.vessels[id].proximal
    };
    let eta = network.blood.viscosity;
    let build = |resistance: f64| -> Result<FlowNetwork> {
        // A uniform tube of the collateral length with this Poiseuille resistance.
        let radius =
            (8.0 * eta * COLLATERAL_LENGTH_M / (std::f64::consts::PI * resistance)).powf(0.25);
        let mut vessels = network.vessels.clone();
        for (d, &node) in donors.iter().zip(&from) {
            vessels.push(Vessel::uniform(
                format!("pial collateral {d} → {recipient}"),
                node,
                to,
                COLLATERAL_LENGTH_M,
                radius,
            ));
        }
        FlowNetwork::new(
            network.node_count,
            vessels,
            network.inlet,
            network.outlets.clone(),
            network.blood,
        )
    };
    // The territory's inflow with the recipient closed: what the collaterals bring.
    let supplied = |resistance: f64| -> Result<f64> {
        let candidate = build(resistance)?;
        let id = candidate.vessel_id(recipient)?;
        let length = candidate.vessels[id].length();
        let mut solver = FlowSolver::new(candidate)?;
        solver.set_occlusions(&[Occlusion {
            vessel: id,
            from_arc: 0.0,
            to_arc: length,
            permeability_m2: 1e-18,
        }])?;
        let s = solver.solve(None)?;
        Ok(s.vessels[network.vessels.len()..]
            .iter()
            .map(|v| v.proximal)
            .sum())
    };
    let target = f * resting;
    let (mut lo, mut hi) = (1e6f64.ln(), 1e16f64.ln());
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if supplied(mid.exp())? > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let resistance = (0.5 * (lo + hi)).exp();
    Ok((build(resistance)?, resistance))
}
