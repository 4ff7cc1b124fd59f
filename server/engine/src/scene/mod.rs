//! Scene files (TOML or JSON via serde): the anatomy, the CT, the devices a trainee may
//! select, where the device enters, the C-arm, fluoroscopy, optional blood flow for contrast,
//! the target, and the fidelity knobs. Parse errors name the field path and the reason.
//!
//! One module per section of the scene file, each with its checks ([`SceneSpec::validate`]
//! runs them in order): `anatomy`, `ct`, `devices` (the presets and the device catalogue),
//! `stack`, `spares`, `start`, `carm`, `fluoroscopy`, `flow` (and the clots), `target`,
//! `fidelity`, `guidance`, `limits`, `autopilot` and `assessment`; `spec` holds the scene
//! itself and reads it, `catalog` a directory of scenes, `field` what the checks share.

mod anatomy;
mod assessment;
mod autopilot;
mod carm;
mod catalog;
mod ct;
mod devices;
mod fidelity;
pub(crate) mod field;
mod flow;
mod fluoroscopy;
mod guidance;
mod limits;
mod spares;
mod spec;
mod stack;
mod start;
mod target;

pub use anatomy::AnatomySpec;
pub use assessment::AssessmentSpec;
pub use autopilot::{AccessSpec, AutopilotSpec, ExchangeSpec};
pub use carm::CArmSpec;
pub use catalog::{SceneCatalog, scene_files};
pub use ct::CtSpec;
pub use devices::{DeviceSpec, appearance_of_entry, catalogue, device_of};
pub use fidelity::{ContactSolver, FidelitySpec};
pub use flow::{ClotSpec, CollateralSpec, FlowSpec};
pub use fluoroscopy::FluoroscopySpec;
pub use guidance::GuidanceSpec;
pub use limits::{FORCE_OVERSHOOT, LimitsSpec};
pub use spares::{MAX_SPARES, SpareSpec};
pub use spec::{SceneFormat, SceneSpec};
pub use stack::{MAX_STACK, StackEntry};
pub use start::StartSpec;
pub use target::TargetSpec;
