//! Shared helpers of the physics integration tests.
#![allow(dead_code)]

use cathlab_physics::{BeamProperties, CircularSection, Material};

/// A steel-like material.
pub fn steel() -> Material {
    Material {
        young_modulus_pa: 200e9,
        poisson_ratio: 0.3,
        density_kg_m3: 7800.0,
    }
}

/// Properties of a solid steel wire of radius `r` (m).
pub fn wire(r: f64) -> BeamProperties {
    BeamProperties::new(&CircularSection::solid(r), &steel())
}

/// Relative difference |a − b| / max(|b|, tiny).
pub fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-300)
}
