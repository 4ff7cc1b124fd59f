//! Synthetic X-ray (fluoroscopy) for cathlab: C-arm geometry in DICOM XA conventions, CT
//! volumes loaded from MetaImage and NIfTI, polyenergetic Beer–Lambert projection of the CT
//! and of analytic contrast and device layers, detector effects, and the fluoroscopy modes
//! (pulsed fluoroscopy, last-image hold, DSA, roadmap), on the CPU (rayon) or on wgpu.
//! Plain library: no threads of its own beyond rayon, no networking. Lengths are metres,
//! attenuation coefficients 1/m, unless a name says otherwise.

pub mod detector;
pub mod dose;
pub mod error;
pub mod fluoroscope;
pub mod geometry;
pub mod golden;
pub mod gpu;
pub mod layers;
pub mod phantom;
pub mod processing;
pub mod render;
pub mod scene;
pub mod spectrum;
pub mod volume;

pub use detector::DetectorSettings;
pub use dose::{DoseSettings, DoseTally, ExposureDose};
pub use error::{Result, XrayError};
pub use fluoroscope::{
    EdgeEnhancement, Fluoroscope, FluoroscopeSettings, Frame, ImagingMode, PulseRate, Scene,
};
pub use geometry::{CArm, DetectorGeometry};
pub use gpu::GpuRenderer;
pub use layers::{ContrastTube, DeviceAppearance, LayerMaterial, Layers};
pub use processing::ScatterSettings;
pub use render::{CpuRenderer, MarchSettings, PathImage, Renderer};
pub use spectrum::{HuModel, MaterialPaths, Spectrum};
pub use volume::Volume;
