//! The devices a scene names: the presets of its `devices` (one at a time) and of any
//! `custom` instrument or spare, the built-in device catalogue, and what each resolves to:
//! the physics device and how it looks on X-ray.

use cathlab_physics::{Device, presets};
use cathlab_xray::DeviceAppearance;
use serde::{Deserialize, Serialize};

use super::field::range;
use crate::error::Result;

/// A device preset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "preset", rename_all = "snake_case", deny_unknown_fields)]
pub enum DeviceSpec {
    /// 0.035" guidewire with a J tip.
    #[serde(rename = "guidewire_035")]
    Guidewire035,
    /// 0.035" guidewire with a shaped tip.
    #[serde(rename = "guidewire_035_shaped")]
    Guidewire035Shaped {
        /// Bend angle (deg), 0–180.
        bend_deg: f64,
        /// Length over which the tip bends (mm), 2–100.
        bend_length_mm: f64,
    },
    /// 0.014" micro-guidewire, angled 45°.
    #[serde(rename = "microwire_014")]
    Microwire014,
    /// 5 F diagnostic catheter, angled 45°.
    #[serde(rename = "catheter_5f")]
    Catheter5f,
}

impl DeviceSpec {
    /// A short name for lists.
    pub fn label(&self) -> String {
        match self {
            DeviceSpec::Guidewire035 => "guidewire_035".into(),
            DeviceSpec::Guidewire035Shaped {
                bend_deg,
                bend_length_mm,
            } => format!("guidewire_035_shaped ({bend_deg}° over {bend_length_mm} mm)"),
            DeviceSpec::Microwire014 => "microwire_014".into(),
            DeviceSpec::Catheter5f => "catheter_5f".into(),
        }
    }

    /// Checks a shaped wire's bend; `path` names the preset (`devices[0]`,
    /// `stack[2].custom`).
    pub(super) fn validate(&self, path: &str) -> Result<()> {
        if let DeviceSpec::Guidewire035Shaped {
            bend_deg,
            bend_length_mm,
        } = self
        {
            range(&format!("{path}.bend_deg"), *bend_deg, 0.0, 180.0)?;
            range(
                &format!("{path}.bend_length_mm"),
                *bend_length_mm,
                2.0,
                100.0,
            )?;
        }
        Ok(())
    }
}

/// The built-in device catalogue, parsed once.
pub fn catalogue() -> &'static cathlab_physics::Catalogue {
    static CATALOGUE: std::sync::OnceLock<cathlab_physics::Catalogue> = std::sync::OnceLock::new();
    CATALOGUE.get_or_init(cathlab_physics::Catalogue::builtin)
}

/// The physics device and X-ray appearance of a preset.
pub fn device_of(spec: &DeviceSpec) -> (Device, DeviceAppearance) {
    match spec {
        DeviceSpec::Guidewire035 => (presets::guidewire_035(), DeviceAppearance::guidewire_035()),
        DeviceSpec::Guidewire035Shaped {
            bend_deg,
            bend_length_mm,
        } => (
            presets::guidewire_035_shaped(bend_deg.to_radians(), bend_length_mm * 1e-3),
            DeviceAppearance::guidewire_035(),
        ),
        DeviceSpec::Microwire014 => (
            presets::micro_guidewire_014(),
            DeviceAppearance::microwire_014(),
        ),
        DeviceSpec::Catheter5f => (
            presets::diagnostic_catheter_5f(),
            DeviceAppearance::catheter_5f(),
        ),
    }
}

/// How a catalogue device looks on X-ray: its distal section's outer and lumen radii, a shaft
/// of its kind (a wire's solid nitinol or steel core; a catheter's braid or coil, or its
/// barium-loaded jacket, as a fraction of metal in its wall) and its catalogue markers in
/// platinum.
pub fn appearance_of_entry(entry: &cathlab_physics::CatalogueEntry) -> DeviceAppearance {
    use cathlab_physics::DeviceKind;
    use cathlab_xray::LayerMaterial;
    use cathlab_xray::layers::DeviceBand;
    let (outer_radius_m, inner_radius_m) = entry.device.sections.last().map_or((0.0, 0.0), |s| {
        (
            s.cross_section.outer_radius_m,
            s.cross_section.inner_radius_m,
        )
    });
    let fill = match entry.kind {
        DeviceKind::Guidewire | DeviceKind::Microwire | DeviceKind::StentRetriever => 1.0,
        DeviceKind::Catheter => 0.15,
        DeviceKind::Guide | DeviceKind::Sheath | DeviceKind::DistalAccess => 0.2,
        DeviceKind::Microcatheter => 0.1,
    };
    DeviceAppearance {
        outer_radius_m,
        inner_radius_m,
        material: LayerMaterial::Nitinol,
        fill,
        bands: entry
            .markers
            .iter()
            .map(|m| DeviceBand {
                from_tip_m: m.from_tip_m,
                length_m: m.length_m,
                material: LayerMaterial::Platinum,
                fill: m.fill,
            })
            .collect(),
    }
}
