//! Scene files (TOML or JSON via serde): the anatomy, the CT, the devices a trainee may
//! select, where the device enters, the C-arm, fluoroscopy, optional blood flow for contrast,
//! the target, and the fidelity knobs. Parse errors name the field path and the reason.

use std::path::{Path, PathBuf};

use cathlab_xray::FluoroscopeSettings;
use serde::{Deserialize, Serialize};

use crate::error::{EngineError, Result};

/// A scene: everything a session starts from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    /// Short name (the file stem for catalog scenes).
    #[serde(default)]
    pub name: String,
    /// One line for the scene list.
    #[serde(default)]
    pub description: String,
    /// The vessels.
    pub anatomy: AnatomySpec,
    /// The CT behind the vessels.
    pub ct: CtSpec,
    /// Devices the trainee may select, one at a time; the first is inserted at the start.
    /// A scene has these or a [`SceneSpec::stack`].
    #[serde(default)]
    pub devices: Vec<DeviceSpec>,
    /// A coaxial stack from the device catalogue, outermost first (a guide, a catheter or
    /// microcatheter, a wire), each instrument driven by its own hand.
    #[serde(default)]
    pub stack: Vec<StackEntry>,
    /// Devices on the back table of a stack scene, to exchange an instrument for besides the
    /// catalogue's (for example a wire shaped by hand).
    #[serde(default)]
    pub spares: Vec<SpareSpec>,
    /// Where the device enters.
    #[serde(default)]
    pub start: StartSpec,
    /// The C-arm at the start.
    #[serde(default)]
    pub carm: CArmSpec,
    /// Fluoroscopy.
    #[serde(default)]
    pub fluoroscopy: FluoroscopySpec,
    /// Blood flow and contrast; a scene without it runs no flow solver and refuses injections.
    #[serde(default)]
    pub flow: Option<FlowSpec>,
    /// Clots occluding vessels (they need `flow`).
    #[serde(default)]
    pub clots: Vec<ClotSpec>,
    /// The target the trainee steers to.
    pub target: TargetSpec,
    /// Accuracy against cost.
    #[serde(default)]
    pub fidelity: FidelitySpec,
    /// What the trainee's page shows to guide (all on unless the scene or an instructor's
    /// assessment session turns it off).
    #[serde(default)]
    pub guidance: GuidanceSpec,
    /// What the trainee's hand meets: the device's length and the force it can push with.
    #[serde(default)]
    pub limits: LimitsSpec,
    /// The scene's scripted two-hand operator (a stack scene's demonstration, and the test
    /// that its target can be reached).
    #[serde(default)]
    pub autopilot: Option<AutopilotSpec>,
    /// How sessions on the scene are assessed: phases, error thresholds, expert benchmark.
    #[serde(default)]
    pub assessment: AssessmentSpec,
}

/// How a scene's sessions are assessed (see `docs/assessment.md`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AssessmentSpec {
    /// The procedure's phases in order; none: one phase per vessel of the route, then "at
    /// target".
    pub phases: Vec<cathlab_assessment::PhaseSpec>,
    /// Where errors begin.
    pub errors: cathlab_assessment::ErrorThresholds,
    /// How far from the expert values still passes.
    pub benchmark: cathlab_assessment::BenchmarkSpec,
    /// The expert values by metric key, from the scripted expert run
    /// (`cargo run --release -p cathlab-engine --example expert_benchmark -- SCENE`).
    pub expert: std::collections::BTreeMap<String, f64>,
}

/// A stack scene's scripted operator: the wire (innermost instrument) is steered along the
/// route, the catheter around it follows, anything around that holds; at the target the
/// catheter is tracked over the wire. See [`cathlab_physics::two_hands`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AutopilotSpec {
    /// Push speed (mm/s), 1–100.
    #[serde(default = "default_autopilot_speed")]
    pub push_speed_mm_s: f64,
    /// How far ahead along the route the wire's bend is aimed (mm), 1–100.
    #[serde(default = "default_lookahead_mm")]
    pub lookahead_mm: f64,
    /// The wire is there when its tip is this far into the target branch (mm), 1–500.
    #[serde(default = "default_reach_mm")]
    pub wire_reach_mm: f64,
    /// How far behind the wire's tip the catheter follows (mm), 5–500.
    #[serde(default = "default_lag_mm")]
    pub catheter_lag_mm: f64,
    /// At the target, how far behind the wire's tip the catheter is tracked (mm), 1–500.
    #[serde(default = "default_track_mm")]
    pub catheter_track_mm: f64,
    /// A wire exchange on the way.
    #[serde(default)]
    pub exchange: Option<ExchangeSpec>,
    /// Where the instruments around the catheter park, outermost first: distance along the
    /// route of each one's tip (mm, beyond the start, within the route). While the wire
    /// leads they follow the catheter, each a further `catheter_lag_mm` behind, until there.
    /// Empty: they hold where the stack places them.
    #[serde(default)]
    pub park_along_mm: Vec<f64>,
    /// An access stage first: the stack brought up from the access to a branch on the
    /// route, then its wire taken out and the instruments that lead on loaded.
    #[serde(default)]
    pub access: Option<AccessSpec>,
}

/// The access stage of the scripted operator: the stack's wire leads (the catheter around it
/// following, the instruments around that following to their parks) until its tip is
/// `into_mm` along `branch`; the catheter is tracked over it to `catheter_track_mm` behind
/// its tip; the wire is withdrawn and taken out and the catalogue devices `load` are loaded,
/// outermost first; then the operator drives them to the target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccessSpec {
    /// A branch on the route, before the target's.
    pub branch: String,
    /// How far into it the wire's tip goes (mm), 1–500.
    pub into_mm: f64,
    /// How many of the stack's innermost instruments come out before the loading (the
    /// access wire, and the diagnostic catheter it went up in), 1 to all but the outermost.
    #[serde(default = "default_unload")]
    pub unload: usize,
    /// Catalogue identifiers loaded once those are out, outermost first.
    pub load: Vec<String>,
    /// How far ahead along the route the access wire's bend is aimed (mm), 1–100.
    #[serde(default = "default_lookahead_mm")]
    pub lookahead_mm: f64,
    /// How far behind the access wire's tip the catheter follows (mm), 5–500.
    #[serde(default = "default_lag_mm")]
    pub catheter_lag_mm: f64,
}

/// A wire exchange of the scripted operator: once the wire's tip is `into_mm` along
/// `branch`, the catheter is tracked over it and parked, the wire withdrawn to the hub and
/// exchanged for `device`, which leads on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExchangeSpec {
    /// A branch on the route.
    pub branch: String,
    /// How far into it (mm), 0–500.
    pub into_mm: f64,
    /// The new wire: a catalogue identifier, or empty with `spare`.
    #[serde(default)]
    pub device: String,
    /// The new wire: one of the scene's `spares` (index).
    #[serde(default)]
    pub spare: Option<usize>,
    /// How far ahead the new wire's bend is aimed (mm), 1–100.
    #[serde(default = "default_lookahead_mm")]
    pub lookahead_mm: f64,
    /// The new wire is there when its tip is this far into the target branch (mm), 1–500.
    #[serde(default = "default_reach_mm")]
    pub wire_reach_mm: f64,
}

fn default_autopilot_speed() -> f64 {
    20.0
}
fn default_lookahead_mm() -> f64 {
    20.0
}
fn default_unload() -> usize {
    1
}
fn default_lag_mm() -> f64 {
    50.0
}
fn default_track_mm() -> f64 {
    15.0
}

/// The physical limits of a push. The force limit of a device is the smaller of the
/// operator's and the Euler buckling load of its proximal shaft over the unsupported length
/// between the hand and the sheath's valve (clamped at both ends): about 1.9 N for a 0.014"
/// micro-guidewire over 30 mm, so that wire buckles outside before the hand's 10 N.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LimitsSpec {
    /// The most a hand pushes with (N).
    pub push_force_n: f64,
    /// Length of device unsupported between the hand and the sheath's valve (mm).
    pub unsupported_mm: f64,
    /// Length of device that stays outside the access: sheath, valve, hub and grip (mm).
    pub outside_mm: f64,
}

impl Default for LimitsSpec {
    fn default() -> Self {
        Self {
            push_force_n: 10.0,
            unsupported_mm: 30.0,
            outside_mm: 150.0,
        }
    }
}

/// What the trainee's page may show to guide; an instructor turns it off for assessment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GuidanceSpec {
    /// The target vessel outlined on the subtraction and roadmap images (the server sends
    /// the outline only when this is on).
    pub target_marker: bool,
    /// The remaining distance to the target in the HUD.
    pub target_distance: bool,
    /// Prompts: "hold F for fluoroscopy" and the target-reached banner.
    pub prompts: bool,
}

impl Default for GuidanceSpec {
    fn default() -> Self {
        Self {
            target_marker: true,
            target_distance: true,
            prompts: true,
        }
    }
}

impl GuidanceSpec {
    /// No guidance: an assessment.
    pub fn off() -> Self {
        Self {
            target_marker: false,
            target_distance: false,
            prompts: false,
        }
    }
}

/// The vessels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum AnatomySpec {
    /// Imported files in the layout of the bundled arch-to-circle-of-Willis anatomy:
    /// `vessels.obj` (mm) and `centerlines/*.mrk.json`; placed into LPS by
    /// [`cathlab_xray::scene::ARCH_TO_COW_TO_LPS`].
    ArchToCow {
        /// The directory (relative to the scene file).
        dir: PathBuf,
        /// Adds the circle of Willis computed from the surface
        /// (`cathlab_imaging::circle_of_willis`, about 2 s): the given curves end 20 mm
        /// earlier and the named head arteries (`left_internal_carotid`,
        /// `left_middle_cerebral`, `basilar`, …) continue them.
        #[serde(default)]
        circle_of_willis: bool,
    },
    /// Vessels segmented from a CT angiography volume at load (`cathlab segment`'s
    /// pipeline with its default settings): the vessel tree that holds the seed, its
    /// centerlines and lumen surface; the access point is the tree's end farthest from the
    /// seed, branches are named `vessel_00`, `vessel_01`, … breadth-first from there.
    CtSegmentation {
        /// The volume (MetaImage or NIfTI, relative to the scene file).
        volume: PathBuf,
        /// A voxel (i, j, k) inside a contrast-filled vessel.
        seed_voxel: [usize; 3],
    },
    /// Any vessel surface (OBJ, STL, PLY, VTP; open ends are capped at load) with optional
    /// centerlines (else computed from the surface), its unit, its placement into patient
    /// LPS, the access end, and branch names. `cathlab case` writes such scenes.
    Surface {
        /// The surface file (relative to the scene file).
        file: PathBuf,
        /// Its length unit: "mm" (default), "cm", "m" or "um".
        #[serde(default = "default_unit")]
        unit: cathlab_anatomy::io::LengthUnit,
        /// Rotation then translation into LPS; absent: the file is in LPS already.
        #[serde(default)]
        placement: cathlab_imaging::case::Placement,
        /// Centerlines: a graph `.json` (as `cathlab case` writes), `.vtp` lines with a
        /// radius array, Slicer `.mrk.json` curves, or `.swc`; absent: computed at load.
        #[serde(default)]
        centerlines: Option<PathBuf>,
        /// Where the devices enter: `{ end = 0 }` (open ends by radius, largest first) or
        /// `{ near_mm = [x, y, z] }` (the open end nearest an LPS point).
        #[serde(default)]
        access: cathlab_imaging::case::AccessChoice,
        /// New branch names: `{ vessel_03 = "left_ica" }`.
        #[serde(default)]
        names: std::collections::BTreeMap<String, String>,
        /// Voxel size for centerlines computed at load (mm), 0.1–5; chosen from the size
        /// of the surface when absent.
        #[serde(default)]
        voxel_mm: Option<f64>,
    },
    /// The seeded neuro phantom (aortic arch to circle of Willis), meshed into a lumen
    /// surface at load.
    NeuroPhantom {
        /// Seed of its variations.
        #[serde(default)]
        seed: u64,
        /// Tortuosity 0–1.
        #[serde(default = "default_tortuosity")]
        tortuosity: f64,
    },
}

fn default_unit() -> cathlab_anatomy::io::LengthUnit {
    cathlab_anatomy::io::LengthUnit::Mm
}

fn default_tortuosity() -> f64 {
    0.3
}

/// The CT.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum CtSpec {
    /// The synthesized head-and-neck body placed around the vessels.
    Phantom {
        /// Voxel spacing (mm), 0.5–5.
        spacing_mm: f64,
    },
    /// A MetaImage or NIfTI file (relative to the scene file).
    File {
        /// The volume.
        path: PathBuf,
        /// HU = slope · value + intercept.
        #[serde(default = "one")]
        hu_slope: f64,
        /// See `hu_slope`.
        #[serde(default)]
        hu_intercept: f64,
    },
}

fn one() -> f64 {
    1.0
}

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
}

/// A device on a stack scene's back table: a catalogue identifier or a preset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpareSpec {
    /// Catalogue identifier; empty when `custom` gives the device.
    #[serde(default)]
    pub device: String,
    /// A preset.
    #[serde(default)]
    pub custom: Option<DeviceSpec>,
}

impl SpareSpec {
    /// A short name for lists: the catalogue id or the preset's label.
    pub fn label(&self) -> String {
        match &self.custom {
            Some(custom) => custom.label(),
            None => self.device.clone(),
        }
    }

    /// The device and its look; `index` is its place among the spares, for the error's path.
    pub fn resolve(
        &self,
        index: usize,
    ) -> Result<(cathlab_physics::Device, cathlab_xray::DeviceAppearance)> {
        StackEntry {
            device: self.device.clone(),
            custom: self.custom.clone(),
            inserted_mm: 0.0,
        }
        .resolve(index)
        .map_err(|e| match e {
            EngineError::Scene { path, reason } => {
                scene_error(path.replacen("stack", "spares", 1), reason)
            }
            other => other,
        })
    }
}

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
            (Some(custom), true) => Ok(crate::assets::device_of(custom)),
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
                Ok((
                    entry.device.clone(),
                    crate::assets::appearance_of_entry(entry),
                ))
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

/// Most spares on a scene's back table.
pub const MAX_SPARES: usize = 16;

/// Most instruments in a stack (guide, intermediate catheter, microcatheter, wire).
pub const MAX_STACK: usize = cathlab_physics::stack::MAX_INSTRUMENTS;

/// The built-in device catalogue, parsed once.
pub fn catalogue() -> &'static cathlab_physics::Catalogue {
    static CATALOGUE: std::sync::OnceLock<cathlab_physics::Catalogue> = std::sync::OnceLock::new();
    CATALOGUE.get_or_init(cathlab_physics::Catalogue::builtin)
}

/// Where the device enters the vessels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartSpec {
    /// Distance along the route from the access point to the target where the device enters
    /// (mm): 0 at the femoral access, more for a guide catheter parked further up.
    #[serde(default)]
    pub along_route_mm: f64,
    /// Length inserted at the start (mm).
    #[serde(default = "default_inserted_mm")]
    pub inserted_mm: f64,
}

fn default_inserted_mm() -> f64 {
    10.0
}

impl Default for StartSpec {
    fn default() -> Self {
        Self {
            along_route_mm: 0.0,
            inserted_mm: default_inserted_mm(),
        }
    }
}

/// The C-arm at the start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CArmSpec {
    /// LAO + / RAO − (deg).
    #[serde(default)]
    pub primary_deg: f64,
    /// CRA + / CAU − (deg).
    #[serde(default)]
    pub secondary_deg: f64,
    /// Source–image distance (mm).
    #[serde(default = "default_sid_mm")]
    pub source_to_image_mm: f64,
    /// Source–isocenter distance (mm).
    #[serde(default = "default_sod_mm")]
    pub source_to_isocenter_mm: f64,
    /// Field of view at the detector (mm).
    #[serde(default = "default_fov_mm")]
    pub field_of_view_mm: f64,
    /// Branch the isocenter sits on (the target branch when empty).
    #[serde(default)]
    pub isocenter_branch: String,
    /// Fraction along that branch, 0–1.
    #[serde(default = "default_isocenter_at")]
    pub isocenter_at: f64,
}

fn default_sid_mm() -> f64 {
    1200.0
}
fn default_sod_mm() -> f64 {
    800.0
}
fn default_fov_mm() -> f64 {
    300.0
}
fn default_isocenter_at() -> f64 {
    0.0
}

impl Default for CArmSpec {
    fn default() -> Self {
        Self {
            primary_deg: 0.0,
            secondary_deg: 0.0,
            source_to_image_mm: default_sid_mm(),
            source_to_isocenter_mm: default_sod_mm(),
            field_of_view_mm: default_fov_mm(),
            isocenter_branch: String::new(),
            isocenter_at: default_isocenter_at(),
        }
    }
}

/// Fluoroscopy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FluoroscopySpec {
    /// Pulses per second: 7.5, 15 or 30.
    #[serde(default = "default_pulse_rate")]
    pub pulse_rate: f64,
    /// Mean quanta per pixel with nothing in the beam, when exposure control is off.
    #[serde(default = "default_photons")]
    pub photons_per_pixel: f64,
    /// Automatic exposure control: each mode's detector dose behind the patient (0.03 µGy a
    /// fluoroscopy pulse, 2.5 µGy a DSA frame) sets the quanta; off, `photons_per_pixel`.
    #[serde(default = "yes")]
    pub automatic_exposure: bool,
    /// Recursive filter weight of live images, 0 < α ≤ 1 (1 is off).
    #[serde(default = "default_recursive_weight")]
    pub recursive_weight: f64,
    /// Exposures averaged into a DSA run's mask (1–16).
    #[serde(default = "default_mask_frames")]
    pub dsa_mask_frames: u32,
    /// Scatter-to-primary ratio of the patient before the anti-scatter grid (a 10:1 grid:
    /// primary 0.7, scatter 0.1 transmitted); 0 is primary radiation only.
    #[serde(default = "default_scatter_to_primary")]
    pub scatter_to_primary: f64,
    /// Edge enhancement of live images (unsharp mask, σ 2 px): how much of the difference is
    /// added back; 0 is off.
    #[serde(default = "default_edge_enhancement")]
    pub edge_enhancement: f64,
    /// Quantum noise.
    #[serde(default = "yes")]
    pub noise: bool,
    /// Noise seed.
    #[serde(default = "default_seed")]
    pub seed: u64,
}

fn default_pulse_rate() -> f64 {
    15.0
}
fn default_photons() -> f64 {
    2000.0
}
fn default_recursive_weight() -> f64 {
    FluoroscopeSettings::angio_suite().recursive_weight
}
fn default_mask_frames() -> u32 {
    FluoroscopeSettings::angio_suite().mask_frames
}
fn default_scatter_to_primary() -> f64 {
    FluoroscopeSettings::angio_suite()
        .scatter
        .map_or(0.0, |s| s.scatter_to_primary)
}
fn default_edge_enhancement() -> f64 {
    FluoroscopeSettings::angio_suite()
        .edge_enhancement
        .map_or(0.0, |e| e.amount)
}
fn yes() -> bool {
    true
}
fn default_seed() -> u64 {
    1
}

impl Default for FluoroscopySpec {
    fn default() -> Self {
        Self {
            pulse_rate: default_pulse_rate(),
            photons_per_pixel: default_photons(),
            automatic_exposure: true,
            recursive_weight: default_recursive_weight(),
            dsa_mask_frames: default_mask_frames(),
            scatter_to_primary: default_scatter_to_primary(),
            edge_enhancement: default_edge_enhancement(),
            noise: true,
            seed: default_seed(),
        }
    }
}

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

/// The target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetSpec {
    /// Target branch name; or empty, with `end_near_mm`.
    #[serde(default)]
    pub branch: String,
    /// The target is the branch whose free end is nearest this LPS point (mm), when
    /// `branch` is empty.
    #[serde(default)]
    pub end_near_mm: Option<[f64; 3]>,
    /// Reached when the tip is this far along the branch (mm).
    #[serde(default = "default_reach_mm")]
    pub reach_mm: f64,
    /// In a stack, the instrument whose tip must get there (index, outermost first: the
    /// catheter, not just the wire ahead of it); by default whichever tip leads.
    #[serde(default)]
    pub instrument: Option<usize>,
}

fn default_reach_mm() -> f64 {
    50.0
}

/// Accuracy against cost.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FidelitySpec {
    /// Physics steps per second (100–2000).
    #[serde(default = "default_step_rate")]
    pub step_rate_hz: f64,
    /// Element length near the tip (mm).
    #[serde(default = "default_tip_element_mm")]
    pub tip_element_mm: f64,
    /// Element length along the shaft (mm).
    #[serde(default = "default_shaft_element_mm")]
    pub shaft_element_mm: f64,
    /// Gauss–Seidel relative force tolerance.
    #[serde(default = "default_contact_tolerance")]
    pub contact_tolerance: f64,
    /// Refine elements where the device bends or touches.
    #[serde(default = "yes")]
    pub refine: bool,
    /// Detector size (pixels, square).
    #[serde(default = "default_frame_px")]
    pub frame_px: u32,
    /// Contrast cell length (mm).
    #[serde(default = "default_cell_mm")]
    pub contrast_cell_mm: f64,
    /// Contrast advances every this many physics steps.
    #[serde(default = "default_contrast_every")]
    pub contrast_every_steps: u32,
}

fn default_step_rate() -> f64 {
    500.0
}
fn default_tip_element_mm() -> f64 {
    1.5
}
fn default_shaft_element_mm() -> f64 {
    5.0
}
fn default_contact_tolerance() -> f64 {
    1e-3
}
fn default_frame_px() -> u32 {
    512
}
fn default_cell_mm() -> f64 {
    0.5
}
fn default_contrast_every() -> u32 {
    10
}

impl Default for FidelitySpec {
    fn default() -> Self {
        Self {
            step_rate_hz: default_step_rate(),
            tip_element_mm: default_tip_element_mm(),
            shaft_element_mm: default_shaft_element_mm(),
            contact_tolerance: default_contact_tolerance(),
            refine: true,
            frame_px: default_frame_px(),
            contrast_cell_mm: default_cell_mm(),
            contrast_every_steps: default_contrast_every(),
        }
    }
}

/// Scene text formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneFormat {
    /// TOML.
    Toml,
    /// JSON.
    Json,
}

fn scene_error(path: impl Into<String>, reason: impl Into<String>) -> EngineError {
    EngineError::Scene {
        path: path.into(),
        reason: reason.into(),
    }
}

impl SceneSpec {
    /// A conservative estimate of the memory this scene's assets take (bytes), made before
    /// anything loads: a phantom CT is sampled over at most 0.34 × 0.30 × 0.60 m at its
    /// spacing (16-bit voxels), plus 64 MiB for the anatomy, flow network and devices. A CT
    /// file counts as it is loaded (checked by the loader's own limits), so it adds nothing
    /// here.
    pub fn estimated_bytes(&self) -> usize {
        let ct = match &self.ct {
            CtSpec::Phantom { spacing_mm } if *spacing_mm > 0.0 => {
                let voxels = (340.0 / spacing_mm) * (300.0 / spacing_mm) * (600.0 / spacing_mm);
                (voxels * 2.0) as usize
            }
            _ => 0,
        };
        ct + (64 << 20)
    }

    /// Parses a scene text; errors name the field path (`fidelity.step_rate_hz`) and the
    /// reason, and the values are checked ([`SceneSpec::validate`]).
    pub fn parse(text: &str, format: SceneFormat) -> Result<Self> {
        let spec: SceneSpec = match format {
            SceneFormat::Toml => {
                let de = toml::Deserializer::parse(text)
                    .map_err(|e| scene_error("(document)", e.message().to_owned()))?;
                serde_path_to_error::deserialize(de).map_err(|e| {
                    let path = e.path().to_string();
                    scene_error(path, e.into_inner().message().to_owned())
                })?
            }
            SceneFormat::Json => {
                let mut de = serde_json::Deserializer::from_str(text);
                serde_path_to_error::deserialize(&mut de).map_err(|e| {
                    let path = e.path().to_string();
                    scene_error(path, e.into_inner().to_string())
                })?
            }
        };
        spec.validate()?;
        Ok(spec)
    }

    /// Reads a scene file (`.toml` or `.json`); its name defaults to the file stem.
    pub fn read(file: &Path) -> Result<Self> {
        let text = cathlab_anatomy::io::limits::read_regular_text(file).map_err(|source| {
            EngineError::Io {
                file: file.to_owned(),
                source,
            }
        })?;
        let format = if file.extension().is_some_and(|e| e == "json") {
            SceneFormat::Json
        } else {
            SceneFormat::Toml
        };
        let mut spec = Self::parse(&text, format).map_err(|e| match e {
            EngineError::Scene { path, reason } => EngineError::Scene {
                path: format!("{}: {path}", file.display()),
                reason,
            },
            other => other,
        })?;
        if spec.name.is_empty() {
            spec.name = file
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
        }
        Ok(spec)
    }

    /// Checks every value's range; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let a = &self.assessment;
        a.phases
            .iter()
            .try_for_each(|p| p.validate())
            .and_then(|()| a.errors.validate())
            .and_then(|()| a.benchmark.validate())
            .map_err(|e| scene_error("assessment", e.to_string()))?;
        if let Some((key, value)) = a.expert.iter().find(|(_, v)| !v.is_finite()) {
            return Err(scene_error(
                "assessment.expert",
                format!("`{key}` is {value}, must be finite"),
            ));
        }
        let range = |path: &str, value: f64, lo: f64, hi: f64| -> Result<()> {
            if value.is_finite() && value >= lo && value <= hi {
                Ok(())
            } else {
                Err(scene_error(path, format!("{value} is outside {lo}..={hi}")))
            }
        };
        match (self.devices.is_empty(), self.stack.is_empty()) {
            (true, true) => {
                return Err(scene_error(
                    "devices",
                    "a scene needs `devices` (one at a time) or a `stack` (coaxial)",
                ));
            }
            (false, false) => {
                return Err(scene_error(
                    "stack",
                    "a scene has `devices` (one at a time) or a `stack` (coaxial), not both",
                ));
            }
            _ => {}
        }
        for (i, d) in self.devices.iter().enumerate() {
            if let DeviceSpec::Guidewire035Shaped {
                bend_deg,
                bend_length_mm,
            } = d
            {
                range(&format!("devices[{i}].bend_deg"), *bend_deg, 0.0, 180.0)?;
                range(
                    &format!("devices[{i}].bend_length_mm"),
                    *bend_length_mm,
                    2.0,
                    100.0,
                )?;
            }
        }
        if let AnatomySpec::NeuroPhantom { tortuosity, .. } = &self.anatomy {
            range("anatomy.tortuosity", *tortuosity, 0.0, 1.0)?;
        }
        if let AnatomySpec::Surface {
            placement,
            voxel_mm,
            names,
            ..
        } = &self.anatomy
        {
            if let Some(v) = voxel_mm {
                range("anatomy.voxel_mm", *v, 0.1, 5.0)?;
            }
            for (a, r) in placement.rotation_deg.iter().enumerate() {
                range(
                    &format!("anatomy.placement.rotation_deg[{a}]"),
                    *r,
                    -360.0,
                    360.0,
                )?;
            }
            for (a, t) in placement.translation_mm.iter().enumerate() {
                range(
                    &format!("anatomy.placement.translation_mm[{a}]"),
                    *t,
                    -5000.0,
                    5000.0,
                )?;
            }
            if names.len() > 1000 {
                return Err(scene_error("anatomy.names", "more than 1000 names"));
            }
        }
        match (self.target.branch.is_empty(), &self.target.end_near_mm) {
            (true, None) => {
                return Err(scene_error(
                    "target",
                    "name a `branch`, or give `end_near_mm` (an LPS point near a vessel's end)",
                ));
            }
            (false, Some(_)) => {
                return Err(scene_error(
                    "target",
                    "names a `branch` and gives `end_near_mm`; give one",
                ));
            }
            (true, Some(p)) => {
                for (a, c) in p.iter().enumerate() {
                    range(&format!("target.end_near_mm[{a}]"), *c, -5000.0, 5000.0)?;
                }
            }
            (false, None) => {}
        }
        match &self.ct {
            CtSpec::Phantom { spacing_mm } => range("ct.spacing_mm", *spacing_mm, 0.5, 5.0)?,
            CtSpec::File {
                hu_slope,
                hu_intercept,
                ..
            } => {
                range("ct.hu_slope", *hu_slope, -1e6, 1e6)?;
                range("ct.hu_intercept", *hu_intercept, -1e6, 1e6)?;
            }
        }
        range(
            "start.along_route_mm",
            self.start.along_route_mm,
            0.0,
            2000.0,
        )?;
        range("start.inserted_mm", self.start.inserted_mm, 2.0, 500.0)?;
        let c = &self.carm;
        range("carm.primary_deg", c.primary_deg, -120.0, 120.0)?;
        range("carm.secondary_deg", c.secondary_deg, -60.0, 60.0)?;
        range(
            "carm.source_to_image_mm",
            c.source_to_image_mm,
            500.0,
            2000.0,
        )?;
        range(
            "carm.source_to_isocenter_mm",
            c.source_to_isocenter_mm,
            200.0,
            c.source_to_image_mm - 50.0,
        )?;
        range("carm.field_of_view_mm", c.field_of_view_mm, 50.0, 500.0)?;
        range("carm.isocenter_at", c.isocenter_at, 0.0, 1.0)?;
        let f = &self.fluoroscopy;
        if ![7.5, 15.0, 30.0].contains(&f.pulse_rate) {
            return Err(scene_error(
                "fluoroscopy.pulse_rate",
                format!("{} is not one of 7.5, 15, 30", f.pulse_rate),
            ));
        }
        range(
            "fluoroscopy.photons_per_pixel",
            f.photons_per_pixel,
            1.0,
            1e7,
        )?;
        range(
            "fluoroscopy.recursive_weight",
            f.recursive_weight,
            0.05,
            1.0,
        )?;
        range(
            "fluoroscopy.dsa_mask_frames",
            f64::from(f.dsa_mask_frames),
            1.0,
            16.0,
        )?;
        range(
            "fluoroscopy.scatter_to_primary",
            f.scatter_to_primary,
            0.0,
            10.0,
        )?;
        range("fluoroscopy.edge_enhancement", f.edge_enhancement, 0.0, 3.0)?;
        if let Some(flow) = &self.flow {
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
        }
        range("target.reach_mm", self.target.reach_mm, 0.0, 500.0)?;
        let l = &self.limits;
        range("limits.push_force_n", l.push_force_n, 0.1, 10_000.0)?;
        range("limits.unsupported_mm", l.unsupported_mm, 5.0, 500.0)?;
        range("limits.outside_mm", l.outside_mm, 0.0, 2000.0)?;
        let q = &self.fidelity;
        range("fidelity.step_rate_hz", q.step_rate_hz, 100.0, 2000.0)?;
        range("fidelity.tip_element_mm", q.tip_element_mm, 0.25, 10.0)?;
        range(
            "fidelity.shaft_element_mm",
            q.shaft_element_mm,
            q.tip_element_mm,
            50.0,
        )?;
        range("fidelity.contact_tolerance", q.contact_tolerance, 1e-8, 0.5)?;
        range("fidelity.frame_px", q.frame_px as f64, 64.0, 2048.0)?;
        range("fidelity.contrast_cell_mm", q.contrast_cell_mm, 0.1, 5.0)?;
        range(
            "fidelity.contrast_every_steps",
            q.contrast_every_steps as f64,
            1.0,
            100.0,
        )?;
        // Last: it needs `limits` checked.
        if let Some(a) = &self.autopilot {
            if self.stack.len() < 2 {
                return Err(scene_error(
                    "autopilot",
                    "the two-hand autopilot needs a stack of at least a catheter and a wire",
                ));
            }
            range("autopilot.push_speed_mm_s", a.push_speed_mm_s, 1.0, 100.0)?;
            range("autopilot.lookahead_mm", a.lookahead_mm, 1.0, 100.0)?;
            range("autopilot.wire_reach_mm", a.wire_reach_mm, 1.0, 500.0)?;
            range("autopilot.catheter_lag_mm", a.catheter_lag_mm, 5.0, 500.0)?;
            range(
                "autopilot.catheter_track_mm",
                a.catheter_track_mm,
                1.0,
                500.0,
            )?;
            if let Some(x) = &a.access {
                range("autopilot.access.into_mm", x.into_mm, 1.0, 500.0)?;
                range("autopilot.access.lookahead_mm", x.lookahead_mm, 1.0, 100.0)?;
                range(
                    "autopilot.access.catheter_lag_mm",
                    x.catheter_lag_mm,
                    5.0,
                    500.0,
                )?;
                if x.unload == 0 || x.unload >= self.stack.len() {
                    return Err(scene_error(
                        "autopilot.access.unload",
                        format!(
                            "{} of a stack of {}: 1 to all but the outermost",
                            x.unload,
                            self.stack.len()
                        ),
                    ));
                }
                let kept = self.stack.len() - x.unload;
                let count = kept + x.load.len();
                if x.load.is_empty() || !(2..=MAX_STACK).contains(&count) {
                    return Err(scene_error(
                        "autopilot.access.load",
                        format!(
                            "{} devices to load after the access wire: the stack would hold \
                             {count} (2 to {MAX_STACK})",
                            x.load.len()
                        ),
                    ));
                }
                let mut outer = self.stack[kept - 1].resolve(kept - 1)?.0;
                for (k, id) in x.load.iter().enumerate() {
                    let field = format!("autopilot.access.load[{k}]");
                    let device = catalogue()
                        .device(id)
                        .map_err(|e| scene_error(&field, e.to_string()))?;
                    cathlab_physics::stack::check_fit(&outer, &device)
                        .map_err(|e| scene_error(&field, format!("does not fit: {e}")))?;
                    outer = device;
                }
                if a.exchange.is_some() {
                    return Err(scene_error(
                        "autopilot.access",
                        "an access stage and a wire exchange do not go together",
                    ));
                }
            }
            // With an access stage, the stack the operator drives to the target is the one
            // after the loading.
            let driven = match &a.access {
                Some(x) => {
                    (self.stack.len().saturating_sub(x.unload) + x.load.len()).max(self.stack.len())
                }
                None => self.stack.len(),
            };
            if a.park_along_mm.len() > driven - 2 {
                return Err(scene_error(
                    "autopilot.park_along_mm",
                    format!(
                        "{} parks for {} instruments around the catheter",
                        a.park_along_mm.len(),
                        driven - 2
                    ),
                ));
            }
            for (k, &mm) in a.park_along_mm.iter().enumerate() {
                range(
                    &format!("autopilot.park_along_mm[{k}]"),
                    mm,
                    self.start.along_route_mm,
                    self.start.along_route_mm + 2000.0,
                )?;
            }
            if let Some(x) = &a.exchange {
                range("autopilot.exchange.into_mm", x.into_mm, 0.0, 500.0)?;
                range(
                    "autopilot.exchange.lookahead_mm",
                    x.lookahead_mm,
                    1.0,
                    100.0,
                )?;
                range(
                    "autopilot.exchange.wire_reach_mm",
                    x.wire_reach_mm,
                    1.0,
                    500.0,
                )?;
                match (x.spare, x.device.is_empty()) {
                    (Some(k), true) if k < self.spares.len() => {}
                    (Some(k), true) => {
                        return Err(scene_error(
                            "autopilot.exchange.spare",
                            format!("{k} is not a spare (the scene has {})", self.spares.len()),
                        ));
                    }
                    (None, false) => {
                        catalogue().get(&x.device).ok_or_else(|| {
                            scene_error(
                                "autopilot.exchange.device",
                                format!(
                                    "'{}' is not in the device catalogue",
                                    x.device.chars().take(64).collect::<String>()
                                ),
                            )
                        })?;
                    }
                    _ => {
                        return Err(scene_error(
                            "autopilot.exchange",
                            "name the new wire by `device` (catalogue) or `spare`, one of them",
                        ));
                    }
                }
            }
        }
        if !self.spares.is_empty() && self.stack.is_empty() {
            return Err(scene_error(
                "spares",
                "spares are for a stack scene's exchanges",
            ));
        }
        for (i, spare) in self.spares.iter().enumerate() {
            if let Some(DeviceSpec::Guidewire035Shaped {
                bend_deg,
                bend_length_mm,
            }) = &spare.custom
            {
                range(
                    &format!("spares[{i}].custom.bend_deg"),
                    *bend_deg,
                    0.0,
                    180.0,
                )?;
                range(
                    &format!("spares[{i}].custom.bend_length_mm"),
                    *bend_length_mm,
                    2.0,
                    100.0,
                )?;
            }
            spare.resolve(i)?;
        }
        if self.spares.len() > MAX_SPARES {
            return Err(scene_error(
                "spares",
                format!("{} spares; at most {MAX_SPARES}", self.spares.len()),
            ));
        }
        self.validate_stack()
    }

    /// Checks the stack: at most [`MAX_STACK`] instruments, each in the catalogue, each
    /// fitting inside the one around it, each starting between the hub of the one around it
    /// and its own hub. Errors name `stack[i].device` or `stack[i].inserted_mm`.
    fn validate_stack(&self) -> Result<()> {
        if let Some(i) = self.target.instrument
            && i >= self.stack.len().max(1)
        {
            return Err(scene_error(
                "target.instrument",
                format!(
                    "{i} is not an instrument of this scene's stack, which has {}",
                    self.stack.len()
                ),
            ));
        }
        if self.stack.len() > MAX_STACK {
            return Err(scene_error(
                "stack",
                format!(
                    "{} instruments; a stack holds at most {MAX_STACK}",
                    self.stack.len()
                ),
            ));
        }
        let mut outer: Option<cathlab_physics::Device> = None;
        let range = |path: &str, value: f64, lo: f64, hi: f64| -> Result<()> {
            if value.is_finite() && value >= lo && value <= hi {
                Ok(())
            } else {
                Err(scene_error(path, format!("{value} is outside {lo}..={hi}")))
            }
        };
        for (i, entry) in self.stack.iter().enumerate() {
            if let Some(DeviceSpec::Guidewire035Shaped {
                bend_deg,
                bend_length_mm,
            }) = &entry.custom
            {
                range(
                    &format!("stack[{i}].custom.bend_deg"),
                    *bend_deg,
                    0.0,
                    180.0,
                )?;
                range(
                    &format!("stack[{i}].custom.bend_length_mm"),
                    *bend_length_mm,
                    2.0,
                    100.0,
                )?;
            }
            let device = entry.resolve(i)?.0;
            let inserted = entry.inserted_mm;
            let length_mm = device.length_m() * 1e3;
            // The route up to the entry point is not simulated, but the devices lie along it.
            let mut hub = length_mm - self.limits.outside_mm - self.start.along_route_mm;
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
                    let outer_mm = self.stack[i - 1].inserted_mm;
                    let (_, meets) = cathlab_physics::stack::inserted_range(
                        Some((outer_mm, o.length_m() * 1e3)),
                        length_mm,
                        0.0,
                    );
                    hub = hub.min(meets);
                    outer_mm - o.length_m() * 1e3 + self.limits.outside_mm
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
                        self.limits.outside_mm
                    ),
                ));
            }
            outer = Some(device);
        }
        Ok(())
    }

    /// Physics time step (s).
    pub fn time_step_s(&self) -> f64 {
        1.0 / self.fidelity.step_rate_hz
    }
}

/// Scenes found in a directory, by name.
#[derive(Debug, Clone, Default)]
pub struct SceneCatalog {
    scenes: Vec<(SceneSpec, PathBuf)>,
}

/// The scene files of `dir`: its `.toml` and `.json` files, sorted by name.
pub fn scene_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|source| EngineError::Io {
        file: dir.to_owned(),
        source,
    })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml" || e == "json"))
        .collect();
    files.sort();
    Ok(files)
}

impl SceneCatalog {
    /// Reads every `.toml` and `.json` scene in `dir` (sorted by name); a scene that does not
    /// parse is an error naming its file.
    pub fn read_dir(dir: &Path) -> Result<Self> {
        let scenes = scene_files(dir)?
            .into_iter()
            .map(|f| SceneSpec::read(&f).map(|s| (s, f)))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self { scenes })
    }

    /// The scenes with the files they came from.
    pub fn scenes(&self) -> &[(SceneSpec, PathBuf)] {
        &self.scenes
    }

    /// The scenes' names, in the catalogue's order.
    pub fn names(&self) -> Vec<&str> {
        self.scenes.iter().map(|(s, _)| s.name.as_str()).collect()
    }

    /// A scene by name, with the directory its relative paths start from.
    pub fn get(&self, name: &str) -> Result<(&SceneSpec, PathBuf)> {
        self.scenes
            .iter()
            .find(|(s, _)| s.name == name)
            .map(|(s, f)| (s, f.parent().unwrap_or(Path::new(".")).to_owned()))
            .ok_or_else(|| EngineError::NotFound(format!("scene {name:?}")))
    }
}
