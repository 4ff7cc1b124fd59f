//! The scene's `[[stack]]`: a coaxial stack of catalogue or custom instruments, outermost
//! first, each resolved to its device and look; and its checks (each in the catalogue, each
//! fitting inside the one around it, each starting between hubs).

use serde::{Deserialize, Serialize};

use super::devices::{DeviceSpec, appearance_of_entry, catalogue, device_of};
use super::field::scene_error;
use super::limits::LimitsSpec;
use super::start::StartSpec;
use crate::error::Result;

/// One instrument of a scene's coaxial stack.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StackEntry {
    /// Identifier in the device catalogue (`server/physics/devices/catalogue.toml`), e.g.
    /// `catheter-5f-vertebral`; empty when [`StackEntry::custom`] gives the device.
    #[serde(default)]
    pub device: String,
    /// A device of the scene's own instead of a catalogue one (a preset, e.g. a wire shaped
    /// by hand: `custom = { preset = "guidewire_035_shaped", bend_deg = 90.0,
    /// bend_length_mm = 30.0 }`).
    #[serde(default)]
    pub custom: Option<DeviceSpec>,
    /// Where its tip starts (mm beyond the entry point; negative: still inside the instrument
    /// around it, proximal of the entry).
    pub inserted_mm: f64,
}

impl StackEntry {
    /// The device and how it looks on X-ray: the catalogue's entry, or the custom preset.
    /// `index` is the entry's place in the stack, for the error's field path.
    pub fn resolve(
        &self,
        index: usize,
    ) -> Result<(cathlab_physics::Device, cathlab_xray::DeviceAppearance)> {
        match (&self.custom, self.device.is_empty()) {
            (Some(custom), true) => Ok(device_of(custom)),
            (Some(_), false) => Err(scene_error(
                format!("stack[{index}]"),
                "names a catalogue `device` and a `custom` one; give one",
            )),
            (None, true) => Err(scene_error(
                format!("stack[{index}].device"),
                "missing: name a catalogue device or give a `custom` one",
            )),
            (None, false) => {
                let entry = catalogue().get(&self.device).ok_or_else(|| {
                    scene_error(
                        format!("stack[{index}].device"),
                        format!(
                            "'{}' is not in the device catalogue (known: {})",
                            self.device.chars().take(64).collect::<String>(),
                            catalogue()
                                .entries()
                                .iter()
                                .map(|e| e.id.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        ),
                    )
                })?;
                Ok((entry.device.clone(), appearance_of_entry(entry)))
            }
        }
    }

    /// A short name for lists: the catalogue id or the preset's label.
    pub fn label(&self) -> String {
        match &self.custom {
            Some(custom) => custom.label(),
            None => self.device.clone(),
        }
    }
}

/// Most instruments in a stack (guide, intermediate catheter, microcatheter, wire).
pub const MAX_STACK: usize = cathlab_physics::stack::MAX_INSTRUMENTS;

/// Checks the stack (`instrument`: the scene's `target.instrument`): at most [`MAX_STACK`]
/// instruments, each in the catalogue, each fitting inside the one around it, each starting
/// between the hub of the one around it and its own hub. Errors name `stack[i].device` or
/// `stack[i].inserted_mm`.
pub(super) fn validate_stack(
    stack: &[StackEntry],
    instrument: Option<usize>,
    limits: &LimitsSpec,
    start: &StartSpec,
) -> Result<()> {
    if let Some(i) = instrument
        && i >= stack.len().max(1)
    {
        return Err(scene_error(
            "target.instrument",
            format!(
                "{i} is not an instrument of this scene's stack, which has {}",
                stack.len()
            ),
        ));
    }
    if stack.len() > MAX_STACK {
        return Err(scene_error(
            "stack",
            format!(
                "{} instruments; a stack holds at most {MAX_STACK}",
                stack.len()
            ),
        ));
    }
    let mut outer: Option<cathlab_physics::Device> = None;
    for (i, entry) in stack.iter().enumerate() {
        if let Some(custom) = &entry.custom {
            custom.validate(&format!("stack[{i}].custom"))?;
        }
        let device = entry.resolve(i)?.0;
        let inserted = entry.inserted_mm;
        let length_mm = device.length_m() * 1e3;
        // The route up to the entry point is not simulated, but the devices lie along it.
        let mut hub = length_mm - limits.outside_mm - start.along_route_mm;
        let lowest = match &outer {
            None => 2.0,
            Some(o) => {
                cathlab_physics::stack::check_fit(o, &device).map_err(|e| {
                    scene_error(
                        format!("stack[{i}].device"),
                        format!("does not fit inside stack[{}]: {e}", i - 1),
                    )
                })?;
                // The stack's own range: from the outer instrument's hub to where this
                // one's hub meets it.
                let outer_mm = stack[i - 1].inserted_mm;
                let (_, meets) = cathlab_physics::stack::inserted_range(
                    Some((outer_mm, o.length_m() * 1e3)),
                    length_mm,
                    0.0,
                );
                hub = hub.min(meets);
                outer_mm - o.length_m() * 1e3 + limits.outside_mm
            }
        };
        if !(inserted.is_finite() && inserted >= lowest && inserted <= hub) {
            return Err(scene_error(
                format!("stack[{i}].inserted_mm"),
                format!(
                    "{inserted} is outside {lowest:.0}..={hub:.0} (between {} and this \
                     instrument's hub, {} mm staying outside)",
                    if outer.is_some() {
                        "the hub of the instrument around it"
                    } else {
                        "one tip element"
                    },
                    limits.outside_mm
                ),
            ));
        }
        outer = Some(device);
    }
    Ok(())
}
