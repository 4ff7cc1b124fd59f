//! From a world snapshot to an X-ray frame: the renderer shared by all sessions (one copy of
//! each CT on the device), a scene's fluoroscope settings, the layers of a snapshot (contrast
//! and the device), the frames a session renders, and frame encodings for clients (raw
//! 8/16-bit, PNG, JPEG, resized).

use std::sync::Arc;

use cathlab_xray::{
    CArm, DoseTally, EdgeEnhancement, FluoroscopeSettings, Frame, Layers, MarchSettings, PathImage,
    Renderer, ScatterSettings, Volume,
};
use image::codecs::jpeg::JpegEncoder;
use image::codecs::png::PngEncoder;
use image::{ImageBuffer, ImageEncoder, Luma};
use nalgebra::Point3;
use parking_lot::Mutex;

use crate::assets::SceneAssets;
use crate::error::{EngineError, Result};
use crate::world::Snapshot;

/// One renderer for every session: calls are serialized, and a GPU renderer keeps one copy of
/// each volume for all of them.
#[derive(Clone)]
pub struct SharedRenderer(Arc<Mutex<Box<dyn Renderer>>>);

impl std::fmt::Debug for SharedRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_tuple("SharedRenderer")
            .field(&self.0.lock().name())
            .finish()
    }
}

impl SharedRenderer {
    /// Shares `renderer`.
    pub fn new(renderer: Box<dyn Renderer>) -> Self {
        Self(Arc::new(Mutex::new(renderer)))
    }
}

impl Renderer for SharedRenderer {
    fn name(&self) -> String {
        self.0.lock().name()
    }

    fn project_volume(
        &mut self,
        volume: &Arc<Volume>,
        carm: &CArm,
        settings: &MarchSettings,
    ) -> cathlab_xray::Result<PathImage> {
        self.0.lock().project_volume(volume, carm, settings)
    }

    fn project_layers(&mut self, layers: &Layers, carm: &CArm) -> cathlab_xray::Result<PathImage> {
        self.0.lock().project_layers(layers, carm)
    }

    fn device_memory_bytes(&self) -> usize {
        self.0.lock().device_memory_bytes()
    }
}

/// The imaging settings of a scene.
pub fn fluoroscope_settings(assets: &SceneAssets) -> FluoroscopeSettings {
    let f = &assets.spec.fluoroscopy;
    let mut settings = FluoroscopeSettings::angio_suite();
    settings.detector.photons_per_pixel = f.photons_per_pixel;
    settings.detector.noise = f.noise;
    settings.detector.seed = f.seed;
    settings.detector.auto_window = true;
    settings.dose.automatic = f.automatic_exposure;
    settings.recursive_weight = f.recursive_weight;
    settings.mask_frames = f.dsa_mask_frames;
    settings.scatter = (f.scatter_to_primary > 0.0).then(|| ScatterSettings {
        scatter_to_primary: f.scatter_to_primary,
        ..ScatterSettings::default()
    });
    settings.edge_enhancement = (f.edge_enhancement > 0.0).then(|| EdgeEnhancement {
        amount: f.edge_enhancement,
        ..EdgeEnhancement::default()
    });
    settings
}

/// A displayed frame with the state it shows.
#[derive(Debug, Clone)]
pub struct RenderedFrame {
    /// The image.
    pub frame: Frame,
    /// Last command sequence number applied in the snapshot it shows.
    pub last_seq: u64,
    /// Step of that snapshot.
    pub step: u64,
    /// Dose accumulated by the session's exposures up to this frame.
    pub dose: DoseTally,
    /// The target vessel projected into the image as (x, y) fractions of its width and height
    /// from the top-left, when the scene's guidance shows the marker; empty otherwise.
    pub target_outline: Vec<[f32; 2]>,
}

/// One fluoroscopy exposure of `snapshot` outside any session (tests and tools): a fresh
/// fluoroscope with the scene's settings on the CPU renderer, at time 0.
pub fn expose_snapshot(assets: &SceneAssets, snapshot: &Snapshot) -> Result<cathlab_xray::Frame> {
    expose_snapshot_with(assets, snapshot, true)
}

/// The same, with the detector's quantum noise on or off (off: golden images).
pub fn expose_snapshot_with(
    assets: &SceneAssets,
    snapshot: &Snapshot,
    noise: bool,
) -> Result<cathlab_xray::Frame> {
    let mut settings = fluoroscope_settings(assets);
    settings.detector.noise &= noise;
    let mut chain =
        cathlab_xray::Fluoroscope::new(Box::new(cathlab_xray::CpuRenderer::default()), settings)?;
    let layers = layers_of(assets, snapshot)?;
    let carm = carm_of(assets, snapshot);
    Ok(chain.expose(
        0.0,
        cathlab_xray::Scene {
            volume: &assets.volume,
            carm: &carm,
            layers: &layers,
        },
    )?)
}

/// The contrast and device layers of `snapshot`.
pub fn layers_of(_assets: &SceneAssets, snapshot: &Snapshot) -> Result<Layers> {
    let mut layers = Layers::new();
    if !snapshot.contrast.is_empty() {
        layers.add_contrast(&snapshot.contrast, 0.0)?;
    }
    // Outermost first; a hollow catheter adds only its wall, so what runs inside it shows
    // through.
    for instrument in &snapshot.instruments {
        let points: Vec<Point3<f64>> = instrument.nodes.iter().map(|p| Point3::from(*p)).collect();
        if points.len() >= 2 {
            layers.add_device(&points, &instrument.look)?;
        }
    }
    Ok(layers)
}

/// The C-arm of `assets` turned to the snapshot's angles.
pub fn carm_of(assets: &SceneAssets, snapshot: &Snapshot) -> CArm {
    CArm {
        primary_deg: snapshot.imaging.primary_deg,
        secondary_deg: snapshot.imaging.secondary_deg,
        ..assets.carm
    }
}

/// How a client wants frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// 8-bit grey, row-major.
    Raw8,
    /// 16-bit grey, little-endian, row-major.
    Raw16,
    /// PNG (8-bit grey).
    Png,
    /// JPEG (8-bit grey) at a quality 1–100.
    Jpeg(u8),
}

/// Encodes a displayed frame at `width` × `height` (the frame's own size when either is 0).
/// Returns the bytes and the size used.
pub fn encode_frame(
    frame: &cathlab_xray::Frame,
    encoding: Encoding,
    width: u32,
    height: u32,
) -> Result<(Vec<u8>, u32, u32)> {
    let (w, h) = if width == 0 || height == 0 {
        (frame.width, frame.height)
    } else {
        (width, height)
    };
    let resize = (w, h) != (frame.width, frame.height);
    let encode_error = |e: image::ImageError| EngineError::InvalidArgument {
        field: "encoding".into(),
        reason: e.to_string(),
    };
    if encoding == Encoding::Raw16 {
        let grey = frame.to_16bit();
        let mut image: ImageBuffer<Luma<u16>, Vec<u16>> =
            ImageBuffer::from_raw(frame.width, frame.height, grey).ok_or_else(size_mismatch)?;
        if resize {
            image = image::imageops::resize(&image, w, h, image::imageops::FilterType::Triangle);
        }
        let bytes = image
            .into_raw()
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        return Ok((bytes, w, h));
    }
    let grey = frame.to_8bit();
    let mut image: ImageBuffer<Luma<u8>, Vec<u8>> =
        ImageBuffer::from_raw(frame.width, frame.height, grey).ok_or_else(size_mismatch)?;
    if resize {
        image = image::imageops::resize(&image, w, h, image::imageops::FilterType::Triangle);
    }
    let bytes = match encoding {
        Encoding::Raw8 | Encoding::Raw16 => image.into_raw(),
        Encoding::Png => {
            let mut out = Vec::new();
            PngEncoder::new(&mut out)
                .write_image(image.as_raw(), w, h, image::ExtendedColorType::L8)
                .map_err(encode_error)?;
            out
        }
        Encoding::Jpeg(quality) => {
            let mut out = Vec::new();
            JpegEncoder::new_with_quality(&mut out, quality.clamp(1, 100))
                .write_image(image.as_raw(), w, h, image::ExtendedColorType::L8)
                .map_err(encode_error)?;
            out
        }
    };
    Ok((bytes, w, h))
}

fn size_mismatch() -> EngineError {
    EngineError::InvalidArgument {
        field: "frame".into(),
        reason: "pixel count does not match the frame size".into(),
    }
}

/// An encoded frame: the bytes and the size used.
pub type Encoded = Result<(Vec<u8>, u32, u32)>;

/// [`encode_frame`] on the rayon pool (niced below physics, see `priority`); the answer comes
/// through the returned channel.
pub fn encode_in_pool(
    frame: Arc<RenderedFrame>,
    encoding: Encoding,
    width: u32,
    height: u32,
) -> tokio::sync::oneshot::Receiver<Encoded> {
    let (tx, rx) = tokio::sync::oneshot::channel();
    rayon::spawn(move || {
        let _ = tx.send(encode_frame(&frame.frame, encoding, width, height));
    });
    rx
}
