//! A clot's mechanics by composition: compressive stiffness, friction against the wall,
//! strength, how it wedges in the vessel and what it takes to cross or to squeeze it.
//!
//! Every property interpolates log-linearly between a fibrin/platelet-rich ("white") and a
//! red-cell-rich ("red") end by the red-cell fraction, as [`ClotComposition::permeability_m2`]
//! does for the flow. The ends are chosen inside published ranges:
//!
//! | property | fibrin-rich | red-cell-rich | source |
//! |---|---|---|---|
//! | compressive modulus | 200 kPa | 20 kPa | clot analogues stiffen several- to tenfold with fibrin content (Johnson et al., Ann. Biomed. Eng. 2019–2020; Boodt et al., Stroke 2021); ends chosen, not re-verified here |
//! | wall friction (Coulomb) | 0.35 | 0.12 | friction of clot analogues rises with fibrin content (Gunning et al., J. NeuroIntervent. Surg. 2018); ends chosen |
//! | tensile strength | 60 kPa | 10 kPa | assumed: tens of kPa, fibrin-rich the stronger (fracture tests of clot analogues, Fereidoonnezhad et al., Acta Biomater. 2021) |
//! | rate sensitivity of friction | 0.12 per e-fold of speed over 1 mm/s | same | assumed: clots are viscoelastic, their friction rises with sliding speed |

pub use cathlab_hemo::ClotComposition;

use crate::error::{Result, require_positive};
use std::f64::consts::PI;

/// Compressive (tangent) modulus of a fibrin-rich clot (Pa).
pub const FIBRIN_RICH_MODULUS_PA: f64 = 200e3;
/// Compressive (tangent) modulus of a red-cell-rich clot (Pa).
pub const RED_CELL_RICH_MODULUS_PA: f64 = 20e3;
/// Clot–wall Coulomb friction of a fibrin-rich clot.
pub const FIBRIN_RICH_WALL_FRICTION: f64 = 0.35;
/// Clot–wall Coulomb friction of a red-cell-rich clot.
pub const RED_CELL_RICH_WALL_FRICTION: f64 = 0.12;
/// Tensile strength of a fibrin-rich clot (Pa).
pub const FIBRIN_RICH_STRENGTH_PA: f64 = 60e3;
/// Tensile strength of a red-cell-rich clot (Pa).
pub const RED_CELL_RICH_STRENGTH_PA: f64 = 10e3;
/// Rise of the clot's friction per e-fold of sliding speed over [`REFERENCE_SPEED_M_S`].
pub const FRICTION_RATE_SENSITIVITY: f64 = 0.12;
/// Sliding speed at which the friction coefficients hold (m/s).
pub const REFERENCE_SPEED_M_S: f64 = 1e-3;

/// A clot's mechanical properties.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClotMechanics {
    /// Compressive tangent modulus (Pa).
    pub modulus_pa: f64,
    /// Coulomb friction against the vessel wall at [`REFERENCE_SPEED_M_S`].
    pub wall_friction: f64,
    /// Tensile strength (Pa): a tail dragged by more stress than this breaks off.
    pub strength_pa: f64,
}

fn blend(fibrin: f64, red: f64, composition: ClotComposition) -> f64 {
    let f = composition.red_cell_fraction.clamp(0.0, 1.0);
    fibrin.powf(1.0 - f) * red.powf(f)
}

impl ClotMechanics {
    /// The properties of a clot of `composition`.
    pub fn of(composition: ClotComposition) -> Self {
        Self {
            modulus_pa: blend(
                FIBRIN_RICH_MODULUS_PA,
                RED_CELL_RICH_MODULUS_PA,
                composition,
            ),
            wall_friction: blend(
                FIBRIN_RICH_WALL_FRICTION,
                RED_CELL_RICH_WALL_FRICTION,
                composition,
            ),
            strength_pa: blend(
                FIBRIN_RICH_STRENGTH_PA,
                RED_CELL_RICH_STRENGTH_PA,
                composition,
            ),
        }
    }

    /// Wall friction when sliding at `speed_m_s` (m/s): rate-strengthening, logarithmic in
    /// speed above [`REFERENCE_SPEED_M_S`].
    pub fn wall_friction_at(&self, speed_m_s: f64) -> f64 {
        self.wall_friction
            * (1.0 + FRICTION_RATE_SENSITIVITY * (1.0 + speed_m_s.abs() / REFERENCE_SPEED_M_S).ln())
    }

    /// Pressure (Pa) that squeezes the clot, of free diameter `clot_diameter_m`, into a bore
    /// of `bore_m` (m): drained compression (a clot is a porous network that gives up its
    /// serum when squeezed, so its section shrinks without lengthening it) with the Hencky
    /// law, `E ln(D/d)`, the derivative of the energy `E ε²/2` in the logarithmic strain
    /// `ε = ln(D/d)`; zero when it fits. Chosen over an incompressible law, which would
    /// lengthen the clot and ask several times the pressure clots are seen to enter
    /// catheters at.
    pub fn ingestion_pressure_pa(&self, clot_diameter_m: f64, bore_m: f64) -> f64 {
        if bore_m >= clot_diameter_m {
            0.0
        } else {
            self.modulus_pa * (clot_diameter_m / bore_m).ln()
        }
    }

    /// Force (N) to push a blunt tip of `tip_diameter_m` (m) into the clot: the cavity-
    /// expansion limit pressure of an incompressible neo-Hookean solid, 5μ/2 = 5E/6, over the
    /// tip's area.
    pub fn crossing_force_n(&self, tip_diameter_m: f64) -> f64 {
        5.0 / 6.0 * self.modulus_pa * PI * tip_diameter_m * tip_diameter_m / 4.0
    }
}

/// A clot lodged in a vessel: where, how big, what it is made of.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clot {
    /// Composition.
    pub composition: ClotComposition,
    /// Mechanics: [`ClotMechanics::of`] the composition, or a patient's variation of it.
    pub mechanics: ClotMechanics,
    /// Length (m).
    pub length_m: f64,
    /// Radius of the vessel where it lodged (m); the clot fills it.
    pub vessel_radius_m: f64,
    /// How much wider the free clot is than the vessel it wedged in (strain, 0.05–0.2
    /// assumed): sets the pressure with which it holds the wall.
    pub wedge_strain: f64,
}

impl Clot {
    /// A clot of `composition`, `length_m` long (m), lodged in a vessel of `vessel_radius_m`
    /// (m) with `wedge_strain`; mechanics from the composition.
    pub fn new(
        composition: ClotComposition,
        length_m: f64,
        vessel_radius_m: f64,
        wedge_strain: f64,
    ) -> Self {
        Self {
            composition,
            mechanics: ClotMechanics::of(composition),
            length_m,
            vessel_radius_m,
            wedge_strain,
        }
    }

    /// Checks every field.
    pub fn validate(&self) -> Result<()> {
        crate::error::require_non_negative(
            "clot red-cell fraction",
            self.composition.red_cell_fraction,
        )?;
        if self.composition.red_cell_fraction > 1.0 {
            return Err(crate::ThrombectomyError::InvalidParameter {
                name: "clot red-cell fraction".into(),
                value: self.composition.red_cell_fraction,
                requirement: "between 0 and 1",
            });
        }
        require_positive("clot modulus (Pa)", self.mechanics.modulus_pa)?;
        crate::error::require_non_negative("clot wall friction", self.mechanics.wall_friction)?;
        require_positive("clot strength (Pa)", self.mechanics.strength_pa)?;
        require_positive("clot length (m)", self.length_m)?;
        require_positive("clot vessel radius (m)", self.vessel_radius_m)?;
        crate::error::require_non_negative("clot wedge strain", self.wedge_strain)
    }

    /// Free diameter (m): the vessel's, widened by the wedge strain.
    pub fn free_diameter_m(&self) -> f64 {
        2.0 * self.vessel_radius_m * (1.0 + self.wedge_strain)
    }

    /// Pressure (Pa) with which the clot holds a vessel of radius `radius_m` (m): its modulus
    /// times the strain by which it is squeezed there, zero where it is free.
    pub fn wall_pressure_pa(&self, radius_m: f64) -> f64 {
        let strain = (self.free_diameter_m() / (2.0 * radius_m) - 1.0).max(0.0);
        self.mechanics.modulus_pa * strain
    }

    /// Cross-section (m²) where it lodged.
    pub fn area_m2(&self) -> f64 {
        PI * self.vessel_radius_m * self.vessel_radius_m
    }

    /// Volume (m³).
    pub fn volume_m3(&self) -> f64 {
        self.area_m2() * self.length_m
    }
}
