//! Devices (guidewires, catheters) as sequences of sections, with rest shapes and presets.
//!
//! A device runs from its proximal end (arc length 0, held by the operator) to its distal tip.
//! Each section has its own cross-section, material, wall friction and rest curvature, so a
//! stiff shaft, a transition and a soft shaped tip can be described, as real devices are.

use nalgebra::Vector3;

use crate::error::{PhysicsError, Result, require_finite, require_positive};
use crate::section::{BeamProperties, CircularSection, Material};

/// One arc of a rest shape: constant curvature in a bending plane, with an optional torsion
/// that winds the plane (a helix) for 3D shapes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RestArc {
    /// Arc length (m).
    pub length_m: f64,
    /// Curvature (1/m); 0 for a straight piece between two bends.
    pub curvature_per_m: f64,
    /// Direction the arc bends to, as an angle about the device axis from the material +y axis
    /// (rad): 0 bends towards +y, π/2 towards +z, π back towards −y (a reverse curve).
    pub plane_rad: f64,
    /// Rest torsion (rad/m): how fast the bending plane turns about the axis along the arc.
    pub torsion_per_m: f64,
}

impl RestArc {
    /// A planar arc of `length_m` bending by `angle_rad` in the plane at `plane_rad`.
    pub fn bend(length_m: f64, angle_rad: f64, plane_rad: f64) -> Self {
        Self {
            length_m,
            curvature_per_m: angle_rad / length_m,
            plane_rad,
            torsion_per_m: 0.0,
        }
    }

    /// The material curvature (Darboux) vector of the arc (1/m): torsion along x, bending
    /// about the axis perpendicular to its plane.
    pub fn curvature_vector(&self) -> Vector3<f64> {
        let (sin, cos) = self.plane_rad.sin_cos();
        Vector3::new(
            self.torsion_per_m,
            -self.curvature_per_m * sin,
            self.curvature_per_m * cos,
        )
    }
}

/// Rest (unloaded) shape of a section: a sequence of arcs ending at the section's distal end,
/// straight before them. Bending planes are fixed in the device's material frame, so twisting
/// the device turns them. Straight, angled and J tips are one-arc cases; a Simmons reverse
/// curve, a Cobra or a Headhunter are several.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RestShape {
    /// Arcs, proximal first; the last ends at the section's distal end.
    pub arcs: Vec<RestArc>,
}

impl RestShape {
    /// Straight.
    pub fn straight() -> Self {
        Self::default()
    }

    /// Bent by `angle_rad` over the last `bend_length_m` of the section (angled / hockey-stick
    /// tips), with uniform curvature, towards material +y.
    pub fn angled(angle_rad: f64, bend_length_m: f64) -> Self {
        Self {
            arcs: vec![RestArc::bend(bend_length_m, angle_rad, 0.0)],
        }
    }

    /// A J: an arc of `radius_m` over `angle_rad` (π for a full J) at the distal end of the
    /// section, towards material +y.
    pub fn j(radius_m: f64, angle_rad: f64) -> Self {
        Self {
            arcs: vec![RestArc {
                length_m: radius_m * angle_rad.abs(),
                curvature_per_m: angle_rad.signum() / radius_m,
                plane_rad: 0.0,
                torsion_per_m: 0.0,
            }],
        }
    }

    /// Arcs, proximal first, ending at the section's distal end.
    pub fn from_arcs(arcs: Vec<RestArc>) -> Self {
        Self { arcs }
    }

    /// Whether the shape is straight everywhere.
    pub fn is_straight(&self) -> bool {
        self.arcs
            .iter()
            .all(|a| a.curvature_per_m == 0.0 && a.torsion_per_m == 0.0)
    }

    /// Length of the shaped part at the distal end (m).
    pub fn shaped_length_m(&self) -> f64 {
        self.arcs.iter().map(|a| a.length_m).sum()
    }

    /// Material curvature vector (1/m) at `s` metres from the proximal end of a section of
    /// `length_m`.
    pub fn curvature_at(&self, s: f64, length_m: f64) -> Vector3<f64> {
        let mut start = length_m - self.shaped_length_m();
        if s < start {
            return Vector3::zeros();
        }
        for arc in &self.arcs {
            if s < start + arc.length_m {
                return arc.curvature_vector();
            }
            start += arc.length_m;
        }
        self.arcs
            .last()
            .map_or_else(Vector3::zeros, RestArc::curvature_vector)
    }

    /// Integral of the curvature vector over [a, b] (m from the section's proximal end, within
    /// a section of `length_m`), in 1/m · m.
    pub fn integrated_curvature(&self, a: f64, b: f64, length_m: f64) -> Vector3<f64> {
        let mut start = length_m - self.shaped_length_m();
        let mut total = Vector3::zeros();
        for arc in &self.arcs {
            let end = start + arc.length_m;
            let overlap = b.min(end) - a.max(start);
            if overlap > 0.0 {
                total += arc.curvature_vector() * overlap;
            }
            start = end;
        }
        total
    }

    fn validate(&self, owner: &str, length_m: f64) -> Result<()> {
        for (k, arc) in self.arcs.iter().enumerate() {
            let what = |field: &str| format!("{owner}: rest arc {k} {field}");
            require_positive(|| what("length_m"), arc.length_m)?;
            require_finite(|| what("curvature_per_m"), arc.curvature_per_m)?;
            require_finite(|| what("plane_rad"), arc.plane_rad)?;
            require_finite(|| what("torsion_per_m"), arc.torsion_per_m)?;
        }
        let shaped = self.shaped_length_m();
        if shaped > length_m * (1.0 + 1e-12) {
            return Err(PhysicsError::OutOfRange {
                what: format!("{owner}: curved length of the rest shape (m)"),
                range: "(0, section length]",
                value: shaped,
            });
        }
        Ok(())
    }
}

/// One section of a device.
#[derive(Debug, Clone, PartialEq)]
pub struct Section {
    /// Name, used in error messages and displays ("shaft", "tip").
    pub name: String,
    /// Length along the device (m).
    pub length_m: f64,
    /// Cross-section (outer/inner radius, m).
    pub cross_section: CircularSection,
    /// Material (Young's modulus, Poisson ratio, density).
    pub material: Material,
    /// Coulomb friction coefficient against the vessel wall (dimensionless).
    pub friction_coefficient: f64,
    /// Coulomb friction coefficient of an instrument sliding inside this section's lumen
    /// (dimensionless; unused for a solid wire).
    pub lumen_friction_coefficient: f64,
    /// Rest curvature.
    pub rest_shape: RestShape,
}

impl Section {
    /// Checks every parameter of the section.
    pub fn validate(&self) -> Result<()> {
        let owner = format!("section \"{}\"", self.name);
        require_positive(|| format!("{owner}: length_m"), self.length_m)?;
        self.cross_section.validate(&owner)?;
        self.material.validate(&owner)?;
        let mu = require_finite(
            || format!("{owner}: friction_coefficient"),
            self.friction_coefficient,
        )?;
        let lumen_mu = require_finite(
            || format!("{owner}: lumen_friction_coefficient"),
            self.lumen_friction_coefficient,
        )?;
        for (field, value) in [
            ("friction_coefficient", mu),
            ("lumen_friction_coefficient", lumen_mu),
        ] {
            if value < 0.0 {
                return Err(PhysicsError::OutOfRange {
                    what: format!("{owner}: {field}"),
                    range: "[0, ∞)",
                    value,
                });
            }
        }
        self.rest_shape.validate(&owner, self.length_m)
    }

    /// Precomputed beam properties of this section.
    pub fn beam_properties(&self) -> BeamProperties {
        BeamProperties::new(&self.cross_section, &self.material)
    }
}

/// A guidewire or catheter: sections from proximal (index 0) to distal.
#[derive(Debug, Clone, PartialEq)]
pub struct Device {
    /// Display name.
    pub name: String,
    /// Sections, proximal first.
    pub sections: Vec<Section>,
}

/// Minimum number of sections of a device (shaft, transition, tip).
pub const MIN_SECTIONS: usize = 3;

impl Device {
    /// Builds and validates a device.
    pub fn new(name: impl Into<String>, sections: Vec<Section>) -> Result<Self> {
        let device = Self {
            name: name.into(),
            sections,
        };
        device.validate()?;
        Ok(device)
    }

    /// Checks the section count and every section.
    pub fn validate(&self) -> Result<()> {
        if self.sections.len() < MIN_SECTIONS {
            return Err(PhysicsError::TooFewSections {
                device: self.name.clone(),
                count: self.sections.len(),
                min: MIN_SECTIONS,
            });
        }
        self.sections.iter().try_for_each(Section::validate)
    }

    /// Total length (m).
    pub fn length_m(&self) -> f64 {
        self.sections.iter().map(|s| s.length_m).sum()
    }

    /// The section containing arc length `s` (m from the proximal end) and the distance into
    /// it; past the ends it clamps to the first/last section.
    pub fn section_at(&self, s: f64) -> (&Section, f64) {
        let mut start = 0.0;
        for section in &self.sections {
            if s < start + section.length_m {
                return (section, (s - start).max(0.0));
            }
            start += section.length_m;
        }
        let last = self
            .sections
            .last()
            .expect("validated devices have sections");
        (last, last.length_m)
    }

    /// Rest curvature vector (1/m, material frame, see [`RestArc::curvature_vector`]) at arc
    /// length `s`.
    pub fn rest_curvature_at(&self, s: f64) -> Vector3<f64> {
        let (section, local) = self.section_at(s);
        section.rest_shape.curvature_at(local, section.length_m)
    }

    /// Mean rest curvature vector (1/m) over arc lengths [a, b] (m from the proximal end,
    /// a < b): the exact average of the piecewise-constant profile, so that an element that
    /// straddles the start of a bend carries its share of it.
    pub fn mean_rest_curvature(&self, a: f64, b: f64) -> Vector3<f64> {
        let mut start = 0.0;
        let mut total = Vector3::zeros();
        for section in &self.sections {
            let end = start + section.length_m;
            let (lo, hi) = (a.max(start), b.min(end));
            if hi > lo {
                total += section.rest_shape.integrated_curvature(
                    lo - start,
                    hi - start,
                    section.length_m,
                );
            }
            start = end;
        }
        total / (b - a)
    }

    /// Arc length (m from the proximal end) where the distal shaped part begins: the start of
    /// the most proximal arc of the last run of shaped sections; `None` for a straight device.
    pub fn shaped_from_m(&self) -> Option<f64> {
        let mut start = 0.0;
        let mut first = None;
        for section in &self.sections {
            if section.rest_shape.is_straight() {
                first = None;
            } else if first.is_none() {
                first = Some(start + section.length_m - section.rest_shape.shaped_length_m());
            }
            start += section.length_m;
        }
        first
    }
}

/// Named device presets with literature-based values (see `presets` docs and NOTES.md).
pub mod presets {
    use super::*;

    const INCH_M: f64 = 0.0254;
    const FRENCH_M: f64 = 1.0e-3 / 3.0;

    fn nitinol(young_modulus_pa: f64) -> Material {
        Material {
            young_modulus_pa,
            poisson_ratio: 0.33,
            density_kg_m3: 6450.0,
        }
    }

    fn polymer(young_modulus_pa: f64) -> Material {
        Material {
            young_modulus_pa,
            poisson_ratio: 0.4,
            density_kg_m3: 1150.0,
        }
    }

    fn section(
        name: &str,
        length_m: f64,
        cross_section: CircularSection,
        material: Material,
        friction_coefficient: f64,
        rest_shape: RestShape,
    ) -> Section {
        Section {
            name: name.into(),
            length_m,
            cross_section,
            material,
            friction_coefficient,
            // Inter-device friction of coated devices (NOTES.md: μ ≈ 0.04).
            lumen_friction_coefficient: 0.04,
            rest_shape,
        }
    }

    /// 0.014" (0.36 mm) neurovascular micro-guidewire, 200 cm, 45° angled tip.
    ///
    /// Moduli are *effective flexural* moduli of a solid wire of the full outer diameter:
    /// a nitinol core (E ≈ 55 GPa) fills the shaft; the transition grinds the core down (an
    /// effective 12 GPa); the distal 3 cm is a platinum coil over a thin core, very soft
    /// (≈ 1.5 GPa effective), hydrophilic-coated (μ ≈ 0.03).
    pub fn micro_guidewire_014() -> Device {
        let r = 0.014 * INCH_M / 2.0;
        let wire = CircularSection::solid(r);
        Device {
            name: "0.014in micro-guidewire".into(),
            sections: vec![
                section(
                    "shaft",
                    1.62,
                    wire,
                    nitinol(55e9),
                    0.08,
                    RestShape::straight(),
                ),
                section(
                    "transition",
                    0.35,
                    wire,
                    nitinol(12e9),
                    0.03,
                    RestShape::straight(),
                ),
                section(
                    "tip",
                    0.03,
                    wire,
                    Material {
                        density_kg_m3: 12000.0,
                        ..nitinol(1.5e9)
                    },
                    0.03,
                    RestShape::angled(45f64.to_radians(), 0.002),
                ),
            ],
        }
    }

    /// 0.035" (0.89 mm) standard guidewire, 150 cm, 3 mm J tip.
    ///
    /// Whole-wire flexural moduli of 0.035" wires measure 9.5–158 GPa; this stiff-shaft wire
    /// uses 60 GPa in the shaft, 15 GPa in the taper and a 2 GPa coil tip, PTFE/hydrophilic
    /// friction 0.08 / 0.04.
    pub fn guidewire_035() -> Device {
        let wire = CircularSection::solid(0.035 * INCH_M / 2.0);
        Device {
            name: "0.035in J guidewire".into(),
            sections: vec![
                section(
                    "shaft",
                    1.35,
                    wire,
                    nitinol(60e9),
                    0.08,
                    RestShape::straight(),
                ),
                section(
                    "transition",
                    0.10,
                    wire,
                    nitinol(15e9),
                    0.04,
                    RestShape::straight(),
                ),
                section(
                    "tip",
                    0.05,
                    wire,
                    Material {
                        density_kg_m3: 12000.0,
                        ..nitinol(2e9)
                    },
                    0.04,
                    RestShape::j(0.003, std::f64::consts::PI),
                ),
            ],
        }
    }

    /// The 0.035" nitinol guidewire of [`guidewire_035`] with its tip shaped by the user, as
    /// clinicians shape a tip for the anatomy ahead: bent by `angle_rad` over the distal
    /// `bend_length_m` (a 90° bend over 30 mm turns from the descending aorta into the arch;
    /// 90° over 10 mm selects the vertebral from the subclavian). The soft tip section is
    /// 50 mm long, or the bend plus 5 mm if longer.
    pub fn guidewire_035_shaped(angle_rad: f64, bend_length_m: f64) -> Device {
        let mut wire = guidewire_035();
        wire.name = format!(
            "0.035in guidewire, {:.0} deg over {:.0} mm",
            angle_rad.to_degrees(),
            bend_length_m * 1e3
        );
        if let Some(tip) = wire.sections.last_mut() {
            tip.length_m = tip.length_m.max(bend_length_m + 0.005);
            tip.rest_shape = RestShape::angled(angle_rad, bend_length_m);
        }
        wire
    }

    /// 5 F (1.67 mm OD, 0.038" = 0.97 mm ID) diagnostic catheter, 100 cm, 45° angled tip.
    ///
    /// Braided polymer shaft (effective E ≈ 2.5 GPa), softer transition (0.8 GPa) and an
    /// atraumatic soft tip (0.15 GPa); hydrophilic coating μ ≈ 0.05.
    pub fn diagnostic_catheter_5f() -> Device {
        let tube = CircularSection {
            outer_radius_m: 5.0 * FRENCH_M / 2.0,
            inner_radius_m: 0.038 * INCH_M / 2.0,
        };
        Device {
            name: "5F diagnostic catheter".into(),
            sections: vec![
                section(
                    "shaft",
                    0.90,
                    tube,
                    polymer(2.5e9),
                    0.05,
                    RestShape::straight(),
                ),
                section(
                    "transition",
                    0.08,
                    tube,
                    polymer(0.8e9),
                    0.05,
                    RestShape::straight(),
                ),
                section(
                    "tip",
                    0.02,
                    tube,
                    polymer(0.15e9),
                    0.05,
                    RestShape::angled(45f64.to_radians(), 0.008),
                ),
            ],
        }
    }

    /// Micro-catheter, 0.67 mm OD / 0.43 mm (0.017") ID, 150 cm, straight tip.
    ///
    /// Braid-reinforced polymer: shaft 1.5 GPa, transition 0.4 GPa, distal 0.08 GPa; μ ≈ 0.04.
    pub fn micro_catheter() -> Device {
        let tube = CircularSection {
            outer_radius_m: 0.67e-3 / 2.0,
            inner_radius_m: 0.017 * INCH_M / 2.0,
        };
        Device {
            name: "micro-catheter 0.017in ID".into(),
            sections: vec![
                section(
                    "shaft",
                    1.20,
                    tube,
                    polymer(1.5e9),
                    0.04,
                    RestShape::straight(),
                ),
                section(
                    "transition",
                    0.25,
                    tube,
                    polymer(0.4e9),
                    0.04,
                    RestShape::straight(),
                ),
                section(
                    "tip",
                    0.05,
                    tube,
                    polymer(0.08e9),
                    0.04,
                    RestShape::straight(),
                ),
            ],
        }
    }

    /// Every preset with a stable identifier.
    pub fn all() -> Vec<(&'static str, Device)> {
        vec![
            ("micro-guidewire-014", micro_guidewire_014()),
            ("guidewire-035", guidewire_035()),
            ("catheter-5f", diagnostic_catheter_5f()),
            ("micro-catheter", micro_catheter()),
        ]
    }
}
