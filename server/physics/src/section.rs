//! Cross-section and material properties of one beam: areas, second moments, shear areas.

use crate::error::{PhysicsError, Result, require_finite, require_positive};

/// Linear-elastic isotropic material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Young's modulus E (Pa).
    pub young_modulus_pa: f64,
    /// Poisson ratio ν (dimensionless), in (−1, 0.5).
    pub poisson_ratio: f64,
    /// Mass density ρ (kg/m³).
    pub density_kg_m3: f64,
}

impl Material {
    /// Shear modulus G = E / 2(1 + ν) (Pa).
    pub fn shear_modulus_pa(&self) -> f64 {
        self.young_modulus_pa / (2.0 * (1.0 + self.poisson_ratio))
    }

    /// Checks every field; `owner` names the section in error messages.
    pub fn validate(&self, owner: &str) -> Result<()> {
        require_positive(
            || format!("{owner}: young_modulus_pa"),
            self.young_modulus_pa,
        )?;
        require_positive(|| format!("{owner}: density_kg_m3"), self.density_kg_m3)?;
        let nu = require_finite(|| format!("{owner}: poisson_ratio"), self.poisson_ratio)?;
        if !(nu > -1.0 && nu < 0.5) {
            return Err(PhysicsError::OutOfRange {
                what: format!("{owner}: poisson_ratio"),
                range: "(-1, 0.5)",
                value: nu,
            });
        }
        Ok(())
    }
}

/// Annular (tube) or solid circular cross-section.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CircularSection {
    /// Outer radius (m).
    pub outer_radius_m: f64,
    /// Inner radius (m); 0 for a solid wire.
    pub inner_radius_m: f64,
}

impl CircularSection {
    /// A solid wire of the given radius (m).
    pub fn solid(radius_m: f64) -> Self {
        Self {
            outer_radius_m: radius_m,
            inner_radius_m: 0.0,
        }
    }

    /// Checks radii; `owner` names the section in error messages.
    pub fn validate(&self, owner: &str) -> Result<()> {
        require_positive(|| format!("{owner}: outer_radius_m"), self.outer_radius_m)?;
        let inner = require_finite(|| format!("{owner}: inner_radius_m"), self.inner_radius_m)?;
        if inner < 0.0 {
            return Err(PhysicsError::OutOfRange {
                what: format!("{owner}: inner_radius_m"),
                range: "[0, outer radius)",
                value: inner,
            });
        }
        if inner >= self.outer_radius_m {
            return Err(PhysicsError::InnerRadiusTooLarge {
                section: owner.to_string(),
                inner_m: inner,
                outer_m: self.outer_radius_m,
            });
        }
        Ok(())
    }

    /// Area A (m²).
    pub fn area_m2(&self) -> f64 {
        std::f64::consts::PI * (self.outer_radius_m.powi(2) - self.inner_radius_m.powi(2))
    }

    /// Second moment of area about a diameter, I = Iy = Iz (m⁴).
    pub fn second_moment_m4(&self) -> f64 {
        std::f64::consts::FRAC_PI_4 * (self.outer_radius_m.powi(4) - self.inner_radius_m.powi(4))
    }

    /// Torsion constant J = 2I for a circular section (m⁴).
    pub fn torsion_constant_m4(&self) -> f64 {
        2.0 * self.second_moment_m4()
    }

    /// Timoshenko shear coefficient κ (dimensionless), Cowper (1966) for a hollow circle:
    /// κ = 6(1+ν)(1+m²)² / ((7+6ν)(1+m²)² + (20+12ν)m²), m = r_in/r_out.
    /// Solid circle (m = 0): 6(1+ν)/(7+6ν); thin tube (m → 1): 2(1+ν)/(4+3ν) ≈ ½.
    pub fn shear_coefficient(&self, poisson_ratio: f64) -> f64 {
        let nu = poisson_ratio;
        let m2 = (self.inner_radius_m / self.outer_radius_m).powi(2);
        let a = (1.0 + m2).powi(2);
        6.0 * (1.0 + nu) * a / ((7.0 + 6.0 * nu) * a + (20.0 + 12.0 * nu) * m2)
    }
}

/// Everything a beam element needs of its section, precomputed (SI units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BeamProperties {
    /// Axial stiffness E·A (N).
    pub axial_stiffness_n: f64,
    /// Bending stiffness E·I about the local y and z axes (N·m²).
    pub bending_stiffness_nm2: f64,
    /// Torsional stiffness G·J (N·m²).
    pub torsional_stiffness_nm2: f64,
    /// Shear stiffness κ·G·A (N).
    pub shear_stiffness_n: f64,
    /// Polar radius of gyration squared, J/A (m²), for the geometric stiffness in torsion.
    pub polar_gyration_m2: f64,
    /// Mass per unit length ρ·A (kg/m).
    pub mass_per_length_kg_m: f64,
}

impl BeamProperties {
    /// Properties of a circular section made of `material`.
    pub fn new(section: &CircularSection, material: &Material) -> Self {
        let area = section.area_m2();
        let inertia = section.second_moment_m4();
        let g = material.shear_modulus_pa();
        Self {
            axial_stiffness_n: material.young_modulus_pa * area,
            bending_stiffness_nm2: material.young_modulus_pa * inertia,
            torsional_stiffness_nm2: g * section.torsion_constant_m4(),
            shear_stiffness_n: section.shear_coefficient(material.poisson_ratio) * g * area,
            polar_gyration_m2: section.torsion_constant_m4() / area,
            mass_per_length_kg_m: material.density_kg_m3 * area,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cowper_limits() {
        let nu = 0.3;
        let solid = CircularSection::solid(1.0).shear_coefficient(nu);
        assert!((solid - 6.0 * 1.3 / (7.0 + 1.8)).abs() < 1e-15);
        let thin = CircularSection {
            outer_radius_m: 1.0,
            inner_radius_m: 0.999_999,
        }
        .shear_coefficient(nu);
        assert!((thin - 2.0 * 1.3 / (4.0 + 0.9)).abs() < 1e-5);
    }

    #[test]
    fn tube_properties() {
        let s = CircularSection {
            outer_radius_m: 2.0,
            inner_radius_m: 1.0,
        };
        assert!((s.area_m2() - 3.0 * std::f64::consts::PI).abs() < 1e-12);
        assert!((s.second_moment_m4() - 15.0 * std::f64::consts::FRAC_PI_4).abs() < 1e-12);
    }
}
