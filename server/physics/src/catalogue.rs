//! The device catalogue: guidewires, microwires, diagnostic catheters, guides, long sheaths,
//! distal-access catheters and microcatheters as data (TOML), each with the source of its
//! figures. A user defines a new device in the same format without touching code; a bad
//! definition is a typed error naming the device, the section and the field.
//!
//! The built-in catalogue is `server/physics/devices/catalogue.toml`, compiled in. Units are in
//! the key names (`length_mm`, `young_modulus_gpa`, `angle_deg`); see that file's header.

use std::f64::consts::PI;

use serde::Deserialize;

use crate::device::{Device, MIN_SECTIONS, RestArc, RestShape, Section};
use crate::error::{PhysicsError, Result};
use crate::section::{CircularSection, Material};

/// The built-in catalogue's text.
pub const BUILTIN_TOML: &str = include_str!("../devices/catalogue.toml");

/// What a device is for, as operators sort them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DeviceKind {
    /// Guide catheter (6–8 F, parked in the neck).
    Guide,
    /// Long sheath (0.088" lumen).
    Sheath,
    /// Distal-access / aspiration catheter.
    DistalAccess,
    /// Diagnostic catheter (4–6 F, shaped).
    Catheter,
    /// Microcatheter (0.017"–0.027" lumen).
    Microcatheter,
    /// 0.035" / 0.038" guidewire.
    Guidewire,
    /// 0.010" / 0.014" microwire.
    Microwire,
    /// Stent retriever: a self-expanding stent on a push wire (its `[device.stent]` table
    /// gives the stent).
    StentRetriever,
}

/// The stent of a stent retriever, as the catalogue gives it (SI units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StentSpec {
    /// Nominal (free) diameter (m).
    pub nominal_diameter_m: f64,
    /// Stent length (m).
    pub length_m: f64,
    /// Where the stent's distal end lies from the device's tip (m): the distal wire beyond.
    pub from_tip_m: f64,
    /// Chronic outward force per metre of stent (N/m) at `reference_diameter_m`.
    pub cof_n_per_m: f64,
    /// Diameter the COF is given at (m).
    pub reference_diameter_m: f64,
    /// Radial resistive force over chronic outward force.
    pub rrf_ratio: f64,
    /// Length over which it opens beyond the catheter's mouth (m).
    pub transition_m: f64,
    /// Strut–clot Coulomb friction.
    pub strut_friction: f64,
    /// Open fraction of its surface between struts.
    pub open_area: f64,
}

/// One catalogue entry.
#[derive(Debug, Clone, PartialEq)]
pub struct CatalogueEntry {
    /// Stable identifier (`catheter-5f-simmons-2`).
    pub id: String,
    /// Kind of device.
    pub kind: DeviceKind,
    /// Where the figures come from.
    pub source: String,
    /// The device, validated.
    pub device: Device,
    /// Radiopaque marker bands and tip coils, as the X-ray shows them.
    pub markers: Vec<Marker>,
    /// The stent, for a stent retriever.
    pub stent: Option<StentSpec>,
}

/// A radiopaque marker band or tip coil (platinum–iridium), placed from the distal tip.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Marker {
    /// Distance of its distal edge from the tip (m).
    pub from_tip_m: f64,
    /// Length (m).
    pub length_m: f64,
    /// Metal fill fraction of the cross-section (a band 1, a coil about 0.6).
    pub fill: f64,
}

/// A set of devices read from TOML.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Catalogue {
    entries: Vec<CatalogueEntry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    #[serde(default)]
    device: Vec<RawDevice>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDevice {
    id: String,
    name: String,
    kind: DeviceKind,
    source: String,
    #[serde(default)]
    section: Vec<RawSection>,
    #[serde(default)]
    marker: Vec<RawMarker>,
    stent: Option<RawStent>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStent {
    nominal_diameter_mm: f64,
    length_mm: f64,
    from_tip_mm: f64,
    cof_n_per_mm: f64,
    reference_diameter_mm: f64,
    rrf_ratio: f64,
    transition_mm: f64,
    strut_friction: f64,
    open_area: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMarker {
    from_tip_mm: f64,
    length_mm: f64,
    #[serde(default = "full")]
    fill: f64,
}

fn full() -> f64 {
    1.0
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSection {
    name: String,
    length_mm: f64,
    outer_diameter_mm: f64,
    inner_diameter_mm: f64,
    young_modulus_gpa: f64,
    poisson_ratio: f64,
    density_kg_m3: f64,
    wall_friction: f64,
    lumen_friction: f64,
    #[serde(default)]
    arc: Vec<RawArc>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawArc {
    length_mm: f64,
    angle_deg: f64,
    #[serde(default)]
    plane_deg: f64,
    #[serde(default)]
    twist_deg: f64,
}

impl Catalogue {
    /// The built-in catalogue.
    pub fn builtin() -> Self {
        Self::from_toml_str(BUILTIN_TOML).expect("the built-in catalogue is valid (tested)")
    }

    /// Reads a catalogue from TOML text: `[[device]]` tables with `[[device.section]]` and
    /// optional `[[device.section.arc]]` sub-tables.
    pub fn from_toml_str(text: &str) -> Result<Self> {
        let raw: RawFile =
            toml::from_str(text).map_err(|e| PhysicsError::CatalogueSyntax(e.to_string()))?;
        let mut entries: Vec<CatalogueEntry> = Vec::with_capacity(raw.device.len());
        for device in raw.device {
            let entry = convert(device)?;
            if entries.iter().any(|e| e.id == entry.id) {
                return Err(PhysicsError::DeviceDefinition {
                    device: entry.id,
                    section: "device".into(),
                    field: "id".into(),
                    problem: "defined twice".into(),
                });
            }
            entries.push(entry);
        }
        Ok(Self { entries })
    }

    /// Every entry, in file order.
    pub fn entries(&self) -> &[CatalogueEntry] {
        &self.entries
    }

    /// The entry with identifier `id`.
    pub fn get(&self, id: &str) -> Option<&CatalogueEntry> {
        self.entries.iter().find(|e| e.id == id)
    }

    /// The device with identifier `id`, or an error naming it and the identifiers known.
    pub fn device(&self, id: &str) -> Result<Device> {
        self.get(id)
            .map(|e| e.device.clone())
            .ok_or_else(|| PhysicsError::DeviceDefinition {
                device: id.into(),
                section: "device".into(),
                field: "id".into(),
                problem: format!(
                    "not in the catalogue (known: {})",
                    self.entries
                        .iter()
                        .map(|e| e.id.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            })
    }
}

/// `value` if it is finite and `ok`, else the fault naming `owner`'s `field` and `rule`.
fn checked(
    fault: &impl Fn(&str, &str, String) -> PhysicsError,
    owner: &str,
    field: &str,
    value: f64,
    ok: bool,
    rule: &str,
) -> Result<f64> {
    if !value.is_finite() {
        Err(fault(owner, field, format!("must be finite, got {value}")))
    } else if !ok {
        Err(fault(owner, field, format!("must be {rule}, got {value}")))
    } else {
        Ok(value)
    }
}

/// Checks one raw device field by field and builds it.
fn convert(raw: RawDevice) -> Result<CatalogueEntry> {
    let id = raw.id;
    let fault = |section: &str, field: &str, problem: String| PhysicsError::DeviceDefinition {
        device: id.clone(),
        section: section.into(),
        field: field.into(),
        problem,
    };
    if raw.section.len() < MIN_SECTIONS {
        return Err(fault(
            "device",
            "section",
            format!(
                "{} sections given; at least {MIN_SECTIONS} are required (shaft, transition, tip)",
                raw.section.len()
            ),
        ));
    }
    let mut sections = Vec::with_capacity(raw.section.len());
    for s in raw.section {
        let owner = format!("section \"{}\"", s.name);
        let check = |field: &str, value: f64, ok: bool, rule: &str| {
            checked(&fault, &owner, field, value, ok, rule)
        };
        let length_mm = check("length_mm", s.length_mm, s.length_mm > 0.0, "> 0")?;
        let outer = check(
            "outer_diameter_mm",
            s.outer_diameter_mm,
            s.outer_diameter_mm > 0.0,
            "> 0",
        )?;
        let inner = check(
            "inner_diameter_mm",
            s.inner_diameter_mm,
            s.inner_diameter_mm >= 0.0 && s.inner_diameter_mm < s.outer_diameter_mm,
            "≥ 0 and smaller than outer_diameter_mm",
        )?;
        let young = check(
            "young_modulus_gpa",
            s.young_modulus_gpa,
            s.young_modulus_gpa > 0.0,
            "> 0",
        )?;
        let nu = check(
            "poisson_ratio",
            s.poisson_ratio,
            s.poisson_ratio > -1.0 && s.poisson_ratio < 0.5,
            "in (−1, 0.5)",
        )?;
        let density = check(
            "density_kg_m3",
            s.density_kg_m3,
            s.density_kg_m3 > 0.0,
            "> 0",
        )?;
        let wall = check(
            "wall_friction",
            s.wall_friction,
            s.wall_friction >= 0.0,
            "≥ 0",
        )?;
        let lumen = check(
            "lumen_friction",
            s.lumen_friction,
            s.lumen_friction >= 0.0,
            "≥ 0",
        )?;
        let mut arcs = Vec::with_capacity(s.arc.len());
        for (k, arc) in s.arc.iter().enumerate() {
            let length = check(
                &format!("arc {k} length_mm"),
                arc.length_mm,
                arc.length_mm > 0.0,
                "> 0",
            )?;
            let angle = check(&format!("arc {k} angle_deg"), arc.angle_deg, true, "")?;
            let plane = check(&format!("arc {k} plane_deg"), arc.plane_deg, true, "")?;
            let twist = check(&format!("arc {k} twist_deg"), arc.twist_deg, true, "")?;
            let length_m = length * 1e-3;
            arcs.push(RestArc {
                length_m,
                curvature_per_m: angle.to_radians() / length_m,
                plane_rad: plane * PI / 180.0,
                torsion_per_m: twist.to_radians() / length_m,
            });
        }
        let shaped_mm: f64 = s.arc.iter().map(|a| a.length_mm).sum();
        if shaped_mm > length_mm * (1.0 + 1e-12) {
            return Err(fault(
                &owner,
                "arc",
                format!(
                    "the arcs are {shaped_mm} mm long, longer than the section's {length_mm} mm"
                ),
            ));
        }
        sections.push(Section {
            name: s.name,
            length_m: length_mm * 1e-3,
            cross_section: CircularSection {
                outer_radius_m: outer * 0.5e-3,
                inner_radius_m: inner * 0.5e-3,
            },
            material: Material {
                young_modulus_pa: young * 1e9,
                poisson_ratio: nu,
                density_kg_m3: density,
            },
            friction_coefficient: wall,
            lumen_friction_coefficient: lumen,
            rest_shape: RestShape::from_arcs(arcs),
        });
    }
    let device = Device::new(raw.name, sections)?;
    let length_mm = device.length_m() * 1e3;
    let mut markers = Vec::with_capacity(raw.marker.len());
    for (k, m) in raw.marker.iter().enumerate() {
        let owner = format!("marker {k}");
        let check = |field: &str, value: f64, ok: bool, rule: &str| {
            checked(&fault, &owner, field, value, ok, rule)
        };
        let from_tip = check("from_tip_mm", m.from_tip_mm, m.from_tip_mm >= 0.0, "≥ 0")?;
        let length = check(
            "length_mm",
            m.length_mm,
            m.length_mm > 0.0 && from_tip + m.length_mm <= length_mm,
            "> 0 and end within the device",
        )?;
        let fill = check("fill", m.fill, m.fill > 0.0 && m.fill <= 1.0, "in (0, 1]")?;
        markers.push(Marker {
            from_tip_m: from_tip * 1e-3,
            length_m: length * 1e-3,
            fill,
        });
    }
    let stent = match (raw.kind, raw.stent) {
        (DeviceKind::StentRetriever, None) => {
            return Err(fault(
                "stent",
                "stent",
                "a stent retriever needs its [device.stent] table".into(),
            ));
        }
        (DeviceKind::StentRetriever, Some(t)) => {
            let check = |field: &str, value: f64, ok: bool, rule: &str| {
                checked(&fault, "stent", field, value, ok, rule)
            };
            let nominal = check(
                "nominal_diameter_mm",
                t.nominal_diameter_mm,
                t.nominal_diameter_mm > 0.0,
                "> 0",
            )?;
            let length = check("length_mm", t.length_mm, t.length_mm > 0.0, "> 0")?;
            let from_tip = check(
                "from_tip_mm",
                t.from_tip_mm,
                t.from_tip_mm >= 0.0 && t.from_tip_mm + t.length_mm <= length_mm,
                "≥ 0 and the stent within the device",
            )?;
            let cof = check("cof_n_per_mm", t.cof_n_per_mm, t.cof_n_per_mm > 0.0, "> 0")?;
            let reference = check(
                "reference_diameter_mm",
                t.reference_diameter_mm,
                t.reference_diameter_mm > 0.0 && t.reference_diameter_mm < nominal,
                "> 0 and below nominal_diameter_mm",
            )?;
            let rrf = check("rrf_ratio", t.rrf_ratio, t.rrf_ratio >= 1.0, "≥ 1")?;
            let transition = check(
                "transition_mm",
                t.transition_mm,
                t.transition_mm > 0.0,
                "> 0",
            )?;
            let strut = check(
                "strut_friction",
                t.strut_friction,
                t.strut_friction >= 0.0,
                "≥ 0",
            )?;
            let open = check(
                "open_area",
                t.open_area,
                (0.0..=1.0).contains(&t.open_area),
                "in [0, 1]",
            )?;
            Some(StentSpec {
                nominal_diameter_m: nominal * 1e-3,
                length_m: length * 1e-3,
                from_tip_m: from_tip * 1e-3,
                cof_n_per_m: cof * 1e3,
                reference_diameter_m: reference * 1e-3,
                rrf_ratio: rrf,
                transition_m: transition * 1e-3,
                strut_friction: strut,
                open_area: open,
            })
        }
        (_, Some(_)) => {
            return Err(fault(
                "stent",
                "stent",
                "only a stent retriever has a [device.stent] table".into(),
            ));
        }
        (_, None) => None,
    };
    Ok(CatalogueEntry {
        id,
        kind: raw.kind,
        source: raw.source,
        device,
        markers,
        stent,
    })
}
