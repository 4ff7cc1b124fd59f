//! A scene: everything a session starts from, one field per section, read from TOML or JSON
//! (errors name the field path and the reason) and checked section by section, in order.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::anatomy::AnatomySpec;
use super::assessment::AssessmentSpec;
use super::autopilot::AutopilotSpec;
use super::carm::CArmSpec;
use super::ct::CtSpec;
use super::devices::DeviceSpec;
use super::fidelity::FidelitySpec;
use super::field::scene_error;
use super::flow::{ClotSpec, FlowSpec};
use super::fluoroscopy::FluoroscopySpec;
use super::guidance::GuidanceSpec;
use super::limits::LimitsSpec;
use super::spares::{SpareSpec, validate_spares};
use super::stack::{StackEntry, validate_stack};
use super::start::StartSpec;
use super::target::TargetSpec;
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

/// Scene text formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneFormat {
    /// TOML.
    Toml,
    /// JSON.
    Json,
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
        self.assessment.validate()?;
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
            d.validate(&format!("devices[{i}]"))?;
        }
        self.anatomy.validate()?;
        self.target.validate()?;
        self.ct.validate()?;
        self.start.validate()?;
        self.carm.validate()?;
        self.fluoroscopy.validate()?;
        if let Some(flow) = &self.flow {
            flow.validate()?;
        }
        self.target.validate_reach()?;
        self.limits.validate()?;
        self.fidelity.validate()?;
        // Last: it needs `limits` checked.
        if let Some(a) = &self.autopilot {
            a.validate(&self.stack, &self.spares, &self.start)?;
        }
        validate_spares(&self.spares, &self.stack)?;
        validate_stack(
            &self.stack,
            self.target.instrument,
            &self.limits,
            &self.start,
        )
    }

    /// Physics time step (s).
    pub fn time_step_s(&self) -> f64 {
        1.0 / self.fidelity.step_rate_hz
    }
}
