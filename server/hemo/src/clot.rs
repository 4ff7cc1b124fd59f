//! Occlusions of vessels by clots. A clot's composition, from fibrin/platelet-rich to
//! red-cell-rich, sets its hydraulic permeability. A clot filling the lumen is a porous plug
//! with Darcy's law `ΔP = η L Q / (k A)`: at the permeabilities measured for clots it
//! resists a million times more than the open lumen it fills, so distal flow comes only
//! through collaterals the network has. [`crate::FlowSolver::set_occlusions`] puts clots in
//! the flow solution.

use crate::error::{HemoError, Result, require_finite};

/// What a clot is made of.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClotComposition {
    /// Fraction of the clot's volume that is red cells (0 = fibrin/platelet-rich, "white";
    /// 1 = red-cell-rich, "red"). Retrieved stroke clots span about 0.1–0.9.
    pub red_cell_fraction: f64,
}

/// Permeability of a fibrin/platelet-rich clot (m²). Wufsus, Macera & Neeves (Biophys. J.
/// 2013) measured 10⁻¹³–10⁻¹⁷ m² for clots of rising fibrin and platelet density; the dense
/// end is chosen for white clots.
pub const FIBRIN_RICH_PERMEABILITY_M2: f64 = 1e-16;

/// Permeability of a red-cell-rich clot (m²): the porous end of the same range, with red
/// cells loosely held in a sparse fibrin mesh.
pub const RED_CELL_RICH_PERMEABILITY_M2: f64 = 1e-14;

impl ClotComposition {
    /// Checks the fraction.
    pub fn validate(&self) -> Result<()> {
        if !(0.0..=1.0).contains(&self.red_cell_fraction) {
            return Err(HemoError::InvalidParameter {
                name: "clot red-cell fraction".into(),
                value: self.red_cell_fraction,
                requirement: "between 0 and 1",
            });
        }
        Ok(())
    }

    /// Hydraulic permeability (m²): log-linear between the fibrin-rich and red-cell-rich
    /// values by the red-cell fraction.
    pub fn permeability_m2(&self) -> f64 {
        let f = self.red_cell_fraction.clamp(0.0, 1.0);
        FIBRIN_RICH_PERMEABILITY_M2.powf(1.0 - f) * RED_CELL_RICH_PERMEABILITY_M2.powf(f)
    }
}

/// A clot filling part of a vessel's lumen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Occlusion {
    /// The vessel.
    pub vessel: usize,
    /// Arc length where the clot starts (m from the vessel's start).
    pub from_arc: f64,
    /// Arc length where it ends (m), greater than `from_arc`.
    pub to_arc: f64,
    /// Its hydraulic permeability (m²), for example [`ClotComposition::permeability_m2`].
    pub permeability_m2: f64,
}

impl Occlusion {
    /// Checks the clot against a vessel of `length` (m) named `vessel_name`.
    pub(crate) fn validate(&self, vessel_name: &str, length: f64) -> Result<()> {
        require_finite(
            || format!("clot start arc (m) in vessel {vessel_name:?}"),
            self.from_arc,
        )?;
        require_finite(
            || format!("clot end arc (m) in vessel {vessel_name:?}"),
            self.to_arc,
        )?;
        if !(0.0..length).contains(&self.from_arc) {
            return Err(HemoError::InvalidParameter {
                name: format!("clot start arc (m) in vessel {vessel_name:?}"),
                value: self.from_arc,
                requirement: "within the vessel's length",
            });
        }
        if !(self.to_arc > self.from_arc && self.to_arc <= length) {
            return Err(HemoError::InvalidParameter {
                name: format!("clot end arc (m) in vessel {vessel_name:?}"),
                value: self.to_arc,
                requirement: "past its start arc and within the vessel's length",
            });
        }
        if !(self.permeability_m2.is_finite() && self.permeability_m2 > 0.0) {
            return Err(HemoError::InvalidParameter {
                name: format!("clot permeability (m²) in vessel {vessel_name:?}"),
                value: self.permeability_m2,
                requirement: "finite and > 0",
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permeability_runs_from_fibrin_rich_to_red_cell_rich() {
        let white = ClotComposition {
            red_cell_fraction: 0.0,
        };
        let red = ClotComposition {
            red_cell_fraction: 1.0,
        };
        let mixed = ClotComposition {
            red_cell_fraction: 0.5,
        };
        assert_eq!(white.permeability_m2(), FIBRIN_RICH_PERMEABILITY_M2);
        assert!((red.permeability_m2() / RED_CELL_RICH_PERMEABILITY_M2 - 1.0).abs() < 1e-12);
        assert!((mixed.permeability_m2() / 1e-15 - 1.0).abs() < 1e-9);
        assert!(
            ClotComposition {
                red_cell_fraction: 1.2
            }
            .validate()
            .is_err()
        );
    }
}
