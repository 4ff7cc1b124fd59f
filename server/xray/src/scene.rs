//! Scene files for eyes-on rendering (YAML): which CT (a file, or the synthesized body around
//! the vessels), which vessel tree and how it sits in the patient, the C-arm pose, contrast
//! filling named branches, devices laid along routes, detector settings and mode.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use cathlab_anatomy::graph::VesselGraph;
use nalgebra::{Matrix3, Point3, Vector3};
use serde::Deserialize;

use crate::detector::DetectorSettings;
use crate::error::{Result, XrayError};
use crate::fluoroscope::{Fluoroscope, FluoroscopeSettings, Frame, ImagingMode, Scene as Shot};
use crate::geometry::{CArm, DetectorGeometry};
use crate::layers::{ContrastTube, DeviceAppearance, Layers};
use crate::phantom::BodyPhantom;
use crate::render::Renderer;
use crate::volume::Volume;

/// Rotation from the bundled arch-to-circle-of-Willis anatomy's frame to patient LPS: its
/// −x runs towards the head (arch → circle of Willis), +y to the patient's left (the LCCA
/// lies at +y of the RCCA) and −z backwards (the vertebral arteries lie at −z of the
/// carotids). Rows: L, P, S.
pub const ARCH_TO_COW_TO_LPS: [[f64; 3]; 3] = [[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]];

/// How a vessel tree's coordinates map to the patient.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Placement {
    /// Already LPS.
    #[default]
    Identity,
    /// The bundled arch-to-cow anatomy ([`ARCH_TO_COW_TO_LPS`]).
    ArchToCow,
}

impl Placement {
    /// The rotation into LPS.
    pub fn rotation(self) -> Matrix3<f64> {
        match self {
            Placement::Identity => Matrix3::identity(),
            Placement::ArchToCow => Matrix3::from_fn(|r, c| ARCH_TO_COW_TO_LPS[r][c]),
        }
    }
}

/// The CT of a scene.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum CtSpec {
    /// The synthesized head-and-neck body around the vessels, voxel spacing in mm.
    Phantom {
        /// Voxel spacing (mm).
        spacing_mm: f64,
    },
    /// A MetaImage or NIfTI file (relative to the scene file).
    File {
        /// The volume.
        path: PathBuf,
        /// HU = `hu_slope` · value + `hu_intercept` (e.g. 1 and −1024 for files stored as
        /// HU + 1024).
        #[serde(default = "one")]
        hu_slope: f64,
        /// See `hu_slope`.
        #[serde(default)]
        hu_intercept: f64,
    },
}

/// Where the isocenter is.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum IsocenterSpec {
    /// A patient point (m, LPS).
    Point([f64; 3]),
    /// A fraction of the way along a named branch.
    Branch {
        /// Branch name.
        name: String,
        /// Fraction of its length, 0–1.
        at: f64,
    },
    /// The centre of the CT volume.
    VolumeCentre,
}

/// The C-arm of a scene.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CArmSpec {
    /// LAO + / RAO − (degrees).
    #[serde(default)]
    pub primary_deg: f64,
    /// CRA + / CAU − (degrees).
    #[serde(default)]
    pub secondary_deg: f64,
    /// Source–image distance (m).
    #[serde(default = "default_sid")]
    pub source_to_image_m: f64,
    /// Source–isocenter distance (m).
    #[serde(default = "default_sod")]
    pub source_to_isocenter_m: f64,
    /// Field of view at the detector (m).
    #[serde(default = "default_fov")]
    pub field_of_view_m: f64,
    /// Image size (pixels).
    #[serde(default = "default_size")]
    pub size_px: [u32; 2],
    /// Open fraction of the field (horizontal, vertical).
    #[serde(default = "default_collimation")]
    pub collimation: [f64; 2],
    /// The isocenter.
    pub isocenter: IsocenterSpec,
}

fn one() -> f64 {
    1.0
}
fn default_sid() -> f64 {
    1.2
}
fn default_sod() -> f64 {
    0.8
}
fn default_fov() -> f64 {
    0.25
}
fn default_size() -> [u32; 2] {
    [512, 512]
}
fn default_collimation() -> [f64; 2] {
    [1.0, 1.0]
}

/// A device laid along the route from the tree's access point to a branch.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceSpec {
    /// `guidewire_035`, `microwire_014` or `catheter_5f`.
    pub preset: String,
    /// Target branch of the route.
    pub to: String,
    /// Where the device starts, as a distance along the route from the access point (m).
    #[serde(default)]
    pub from_m: f64,
    /// Length laid along the route (m).
    pub length_m: f64,
}

/// Contrast filling named branches.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContrastSpec {
    /// Branch names (all branches when empty).
    #[serde(default)]
    pub branches: Vec<String>,
    /// Iodine concentration in the lumen (mg/mL).
    pub concentration_mg_per_ml: f64,
}

/// Detector settings of a scene; unset fields take the defaults.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct DetectorSpec {
    /// Mean quanta per pixel (dose).
    pub photons_per_pixel: Option<f64>,
    /// Quantum noise on or off.
    pub noise: Option<bool>,
    /// Blur σ (pixels).
    pub blur_sigma_px: Option<f64>,
    /// Window width (automatic window/level when neither width nor level is given).
    pub window: Option<f64>,
    /// Window level.
    pub level: Option<f64>,
    /// Noise seed.
    pub seed: Option<u64>,
}

/// What the CLI shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ModeSpec {
    /// One fluoroscopy frame.
    #[default]
    Fluoroscopy,
    /// A mask without contrast, then the contrast frame minus the mask.
    Dsa,
    /// DSA, then a live frame on the roadmap.
    Roadmap,
}

/// A scene file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    /// The CT.
    pub ct: CtSpec,
    /// Directory of an arch-to-cow style anatomy (relative to the scene file), if any.
    #[serde(default)]
    pub anatomy: Option<PathBuf>,
    /// How the anatomy sits in the patient.
    #[serde(default)]
    pub placement: Placement,
    /// The C-arm.
    pub carm: CArmSpec,
    /// Contrast, if any.
    #[serde(default)]
    pub contrast: Option<ContrastSpec>,
    /// Devices.
    #[serde(default)]
    pub devices: Vec<DeviceSpec>,
    /// Detector.
    #[serde(default)]
    pub detector: DetectorSpec,
    /// Mode.
    #[serde(default)]
    pub mode: ModeSpec,
}

/// A scene ready to render: volume, pose, layers with and without contrast.
pub struct LoadedScene {
    /// The CT.
    pub volume: Arc<Volume>,
    /// The pose.
    pub carm: CArm,
    /// Devices only.
    pub devices: Layers,
    /// Contrast only.
    pub contrast: Layers,
    /// Devices and contrast.
    pub with_contrast: Layers,
    /// Imaging settings.
    pub settings: FluoroscopeSettings,
    /// Mode.
    pub mode: ModeSpec,
}

fn scene_error(file: &Path, reason: impl Into<String>) -> XrayError {
    XrayError::BadScene {
        file: file.to_owned(),
        reason: reason.into(),
    }
}

impl SceneSpec {
    /// Reads a scene file.
    pub fn read(path: &Path) -> Result<Self> {
        let text = cathlab_anatomy::io::limits::read_regular_text(path).map_err(|source| {
            XrayError::Io {
                file: path.to_owned(),
                source,
            }
        })?;
        serde_yaml_ng::from_str(&text).map_err(|e| scene_error(path, e.to_string()))
    }

    /// Loads what the scene names; paths are relative to `base` (the scene file's folder).
    pub fn load(&self, file: &Path) -> Result<LoadedScene> {
        let base = file.parent().unwrap_or(Path::new("."));
        let rotation = self.placement.rotation();
        let graph: Option<VesselGraph> = match &self.anatomy {
            Some(dir) => {
                let anatomy = cathlab_anatomy::real::load_arch_to_cow(&base.join(dir))
                    .map_err(|e| scene_error(file, format!("anatomy: {e}")))?;
                Some(anatomy.graph)
            }
            None => None,
        };
        let to_lps = |p: &Point3<f64>| Point3::from(rotation * p.coords);
        // The vessel tree, or an error saying which part of the scene needed one.
        let need_graph = |why: &str| {
            graph
                .as_ref()
                .ok_or_else(|| scene_error(file, format!("{why} needs an anatomy")))
        };
        let volume = match &self.ct {
            CtSpec::Phantom { spacing_mm } => {
                let graph = need_graph("ct: phantom")?;
                BodyPhantom::around_graph(graph, &rotation)?.volume(spacing_mm * 1e-3)?
            }
            CtSpec::File {
                path,
                hu_slope,
                hu_intercept,
            } => {
                let mut v = Volume::load(&base.join(path))?;
                v.rescale(*hu_slope, *hu_intercept)?;
                v
            }
        };
        let c = &self.carm;
        let isocenter = match &c.isocenter {
            IsocenterSpec::Point(p) => Vector3::from(*p),
            IsocenterSpec::VolumeCentre => {
                let far = Vector3::from(volume.dims.map(|n| (n - 1) as f64));
                volume.position_of(&(far * 0.5)).coords
            }
            IsocenterSpec::Branch { name, at } => {
                let graph = need_graph("isocenter on a branch")?;
                let b = graph
                    .branch(name)
                    .map_err(|e| scene_error(file, format!("isocenter: {e}")))?;
                to_lps(&b.point_at(at.clamp(0.0, 1.0) * b.length())).coords
            }
        };
        let carm = CArm {
            primary_deg: c.primary_deg,
            secondary_deg: c.secondary_deg,
            source_to_image_m: c.source_to_image_m,
            source_to_isocenter_m: c.source_to_isocenter_m,
            isocenter_m: isocenter,
            detector: DetectorGeometry {
                width_px: c.size_px[0],
                height_px: c.size_px[1],
                field_of_view_m: c.field_of_view_m,
                collimation: (c.collimation[0], c.collimation[1]),
            },
        };
        carm.validate()?;
        let mut devices = Layers::new();
        for (i, d) in self.devices.iter().enumerate() {
            let graph = need_graph("a device")?;
            let look = match d.preset.as_str() {
                "guidewire_035" => DeviceAppearance::guidewire_035(),
                "microwire_014" => DeviceAppearance::microwire_014(),
                "catheter_5f" => DeviceAppearance::catheter_5f(),
                other => {
                    return Err(scene_error(
                        file,
                        format!(
                            "device {i}: unknown preset {other:?} (guidewire_035, \
                             microwire_014, catheter_5f)"
                        ),
                    ));
                }
            };
            let access = graph
                .branches
                .first()
                .map(|b| b.points[0])
                .ok_or_else(|| scene_error(file, "anatomy has no branches"))?;
            let path = graph
                .path_to(&access, &d.to)
                .map_err(|e| scene_error(file, format!("device {i}: {e}")))?;
            let points: Vec<Point3<f64>> = graph
                .sample_path(&path, 0.002)
                .into_iter()
                .filter(|(_, s)| *s >= d.from_m && *s <= d.from_m + d.length_m)
                .map(|(p, _)| to_lps(&p))
                .collect();
            if points.len() < 2 {
                return Err(scene_error(
                    file,
                    format!("device {i}: nothing of the route lies in the given stretch"),
                ));
            }
            devices.add_device(&points, &look)?;
        }
        let mut contrast = Layers::new();
        if let Some(spec) = &self.contrast {
            let graph = need_graph("contrast")?;
            let mut tubes = Vec::new();
            for b in &graph.branches {
                if !spec.branches.is_empty() && !spec.branches.contains(&b.name) {
                    continue;
                }
                for i in 0..b.points.len() - 1 {
                    tubes.push(ContrastTube {
                        start: to_lps(&b.points[i]),
                        end: to_lps(&b.points[i + 1]),
                        start_radius_m: b.radii[i],
                        end_radius_m: b.radii[i + 1],
                        concentration_mg_per_ml: spec.concentration_mg_per_ml,
                    });
                }
            }
            for name in &spec.branches {
                graph
                    .branch(name)
                    .map_err(|e| scene_error(file, format!("contrast: {e}")))?;
            }
            contrast.add_contrast(&tubes, 0.0)?;
        }
        let mut with_contrast = devices.clone();
        for piece in contrast.pieces() {
            with_contrast.push_piece(*piece)?;
        }
        let d = DetectorSettings::default();
        let s = &self.detector;
        let detector = DetectorSettings {
            photons_per_pixel: s.photons_per_pixel.unwrap_or(d.photons_per_pixel),
            noise: s.noise.unwrap_or(d.noise),
            blur_sigma_px: s.blur_sigma_px.unwrap_or(d.blur_sigma_px),
            window: s.window.unwrap_or(d.window),
            level: s.level.unwrap_or(d.level),
            seed: s.seed.unwrap_or(d.seed),
            auto_window: s.window.is_none() && s.level.is_none(),
        };
        detector.validate()?;
        Ok(LoadedScene {
            volume: Arc::new(volume),
            carm,
            devices,
            contrast,
            with_contrast,
            settings: FluoroscopeSettings {
                detector,
                ..FluoroscopeSettings::default()
            },
            mode: self.mode,
        })
    }
}

impl LoadedScene {
    /// Renders the scene's image in its mode on `renderer`: a fluoroscopy frame (with
    /// contrast when the scene has some), a DSA frame (mask without contrast, then with), or
    /// a roadmap frame (a DSA run of the contrast alone, then the devices live over the
    /// vessel map).
    pub fn render(&self, renderer: Box<dyn Renderer>) -> Result<Frame> {
        let mut chain = Fluoroscope::new(renderer, self.settings.clone())?;
        let shot = |layers| Shot {
            volume: &self.volume,
            carm: &self.carm,
            layers,
        };
        match self.mode {
            ModeSpec::Fluoroscopy => chain.expose(0.0, shot(&self.with_contrast)),
            ModeSpec::Dsa => {
                chain.set_mode(ImagingMode::Subtraction, &self.carm)?;
                chain.expose(0.0, shot(&self.devices))?;
                chain.expose(0.5, shot(&self.with_contrast))
            }
            ModeSpec::Roadmap => {
                let empty = Layers::new();
                chain.set_mode(ImagingMode::Subtraction, &self.carm)?;
                chain.expose(0.0, shot(&empty))?;
                chain.expose(0.5, shot(&self.contrast))?;
                chain.set_mode(ImagingMode::Roadmap, &self.carm)?;
                chain.expose(1.0, shot(&self.devices))
            }
        }
    }
}
