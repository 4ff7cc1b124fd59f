//! The imaging chain over time: a renderer, the background cached per pose and volume,
//! pulsed fluoroscopy (7.5/15/30 pulses per second), last-image hold, digital subtraction
//! angiography (mask subtraction, peak opacification) and roadmap.

use std::sync::Arc;

use crate::detector::{self, DetectorSettings};
use crate::error::{Result, XrayError};
use crate::geometry::CArm;
use crate::layers::Layers;
use crate::render::{MarchSettings, PathImage, Renderer};

use crate::spectrum::Spectrum;
use crate::volume::Volume;

/// Fluoroscopy pulse rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum PulseRate {
    /// 7.5 pulses per second (low dose).
    #[serde(rename = "7.5")]
    Hz7_5,
    /// 15 pulses per second.
    #[serde(rename = "15")]
    Hz15,
    /// 30 pulses per second.
    #[serde(rename = "30")]
    Hz30,
}

impl PulseRate {
    /// Pulses per second.
    pub fn hz(self) -> f64 {
        match self {
            PulseRate::Hz7_5 => 7.5,
            PulseRate::Hz15 => 15.0,
            PulseRate::Hz30 => 30.0,
        }
    }
}

/// What the monitor shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImagingMode {
    /// Live fluoroscopy.
    Fluoroscopy,
    /// Digital subtraction angiography: the first exposure of the run is the mask, later
    /// ones show live − mask (contrast dark on grey, bone and soft tissue gone).
    Subtraction,
    /// Roadmap: live fluoroscopy minus the DSA mask, minus the peak-opacity vessel map of the
    /// last DSA run (capped at a set depth): white vessels, dark devices, on grey.
    Roadmap,
}

/// One displayed image.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Exposure count since the imaging chain started (a held frame keeps its index).
    pub index: u64,
    /// Time of the exposure (s).
    pub time_s: f64,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// The mode it was made in.
    pub mode: ImagingMode,
    /// Whether this is a held last image (no exposure behind it now).
    pub held: bool,
    /// Displayed value per pixel: line integral −ln(N/N0), subtracted in DSA and roadmap;
    /// NaN outside the collimated field.
    pub values: Vec<f32>,
    /// Window width and centre used for the grey encodings.
    pub window: (f64, f64),
}

impl Frame {
    /// Window/level to 8-bit grey, row-major.
    pub fn to_8bit(&self) -> Vec<u8> {
        detector::encode_8bit(&self.values, self.window.0, self.window.1)
    }

    /// Window/level to 16-bit grey, row-major.
    pub fn to_16bit(&self) -> Vec<u16> {
        detector::encode_16bit(&self.values, self.window.0, self.window.1)
    }
}

/// What one exposure looks at.
#[derive(Debug, Clone, Copy)]
pub struct Scene<'a> {
    /// The CT (real or synthesized).
    pub volume: &'a Arc<Volume>,
    /// The pose.
    pub carm: &'a CArm,
    /// Contrast and devices now.
    pub layers: &'a Layers,
}

/// Settings of the imaging chain.
#[derive(Debug, Clone, PartialEq)]
pub struct FluoroscopeSettings {
    /// Beam spectrum.
    pub spectrum: Spectrum,
    /// Background ray-march.
    pub march: MarchSettings,
    /// Detector and display.
    pub detector: DetectorSettings,
    /// Fluoroscopy pulse rate.
    pub pulse_rate: PulseRate,
    /// Window width for subtracted images (line-integral units).
    pub subtraction_window: f64,
    /// Roadmap vessel-map depth (line-integral units): the DSA peak opacity is capped here,
    /// so that vessels show as an even light plateau and devices stay dark on top of it.
    pub roadmap_vessel_depth: f64,
}

impl Default for FluoroscopeSettings {
    fn default() -> Self {
        Self {
            spectrum: Spectrum::default(),
            march: MarchSettings::default(),
            detector: DetectorSettings::default(),
            pulse_rate: PulseRate::Hz15,
            subtraction_window: 1.5,
            roadmap_vessel_depth: 0.35,
        }
    }
}

/// Counters of work done, for tests and reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FluoroscopeStats {
    /// Exposures made.
    pub exposures: u64,
    /// Background projections rendered (cache misses).
    pub background_renders: u64,
}

struct CachedBackground {
    volume: Arc<Volume>,
    carm: CArm,
    march: MarchSettings,
    image: PathImage,
}

struct SubtractionMasks {
    carm: CArm,
    mask: Vec<f32>,
    peak_opacity: Vec<f32>,
}

/// The imaging chain: call [`Fluoroscope::update`] every simulation tick.
pub struct Fluoroscope {
    renderer: Box<dyn Renderer>,
    settings: FluoroscopeSettings,
    cache: Option<CachedBackground>,
    mode: ImagingMode,
    last: Option<Frame>,
    next_pulse_s: Option<f64>,
    masks: Option<SubtractionMasks>,
    stats: FluoroscopeStats,
}

impl Fluoroscope {
    /// A chain on `renderer`; checks the settings.
    pub fn new(renderer: Box<dyn Renderer>, settings: FluoroscopeSettings) -> Result<Self> {
        settings.march.validate()?;
        settings.detector.validate()?;
        for (what, value) in [
            ("subtraction window width", settings.subtraction_window),
            ("roadmap vessel depth", settings.roadmap_vessel_depth),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(XrayError::OutOfRange {
                    what: what.into(),
                    range: "finite and > 0",
                    value,
                });
            }
        }
        Ok(Self {
            renderer,
            settings,
            cache: None,
            mode: ImagingMode::Fluoroscopy,
            last: None,
            next_pulse_s: None,
            masks: None,
            stats: FluoroscopeStats::default(),
        })
    }

    /// The settings.
    pub fn settings(&self) -> &FluoroscopeSettings {
        &self.settings
    }

    /// The renderer's name.
    pub fn renderer_name(&self) -> String {
        self.renderer.name()
    }

    /// Work counters.
    pub fn stats(&self) -> FluoroscopeStats {
        self.stats
    }

    /// The current mode.
    pub fn mode(&self) -> ImagingMode {
        self.mode
    }

    /// Changes the pulse rate; the next pulse comes one new period after the last.
    pub fn set_pulse_rate(&mut self, rate: PulseRate) {
        if let (Some(next), Some(last)) = (self.next_pulse_s, &self.last) {
            self.next_pulse_s = Some(next.min(last.time_s + 1.0 / rate.hz()));
        }
        self.settings.pulse_rate = rate;
    }

    /// Switches mode. Starting [`ImagingMode::Subtraction`] begins a new run whose first
    /// exposure is the mask; [`ImagingMode::Roadmap`] needs a finished DSA run at the same
    /// pose, else an error names what is missing.
    pub fn set_mode(&mut self, mode: ImagingMode, carm: &CArm) -> Result<()> {
        match mode {
            ImagingMode::Subtraction => self.masks = None,
            ImagingMode::Roadmap => match &self.masks {
                Some(m) if m.carm == *carm => {}
                Some(_) => {
                    return Err(XrayError::Unavailable(
                        "roadmap: the C-arm moved since the DSA run; run DSA again".into(),
                    ));
                }
                None => {
                    return Err(XrayError::Unavailable(
                        "roadmap: no DSA run to take the vessel map from".into(),
                    ));
                }
            },
            ImagingMode::Fluoroscopy => {}
        }
        self.mode = mode;
        // A new mode exposes at once.
        self.next_pulse_s = None;
        Ok(())
    }

    /// Whether an exposure is due at `time_s` with the pedal down: callers can skip building
    /// layers for ticks between pulses.
    pub fn pulse_due(&self, time_s: f64) -> bool {
        self.next_pulse_s.is_none_or(|next| time_s >= next)
    }

    /// Advances to `time_s`. With the pedal down an exposure is made when a pulse is due
    /// (at the fluoroscopy pulse rate), and the new frame is returned; otherwise the last
    /// image is returned again (marked `held` while the pedal is up), or `None` before any
    /// exposure. The frame is borrowed: ticks between pulses copy nothing.
    pub fn update(&mut self, time_s: f64, pedal: bool, scene: Scene<'_>) -> Result<Option<&Frame>> {
        if !time_s.is_finite() {
            return Err(XrayError::NotFinite {
                what: "fluoroscope time (s)".into(),
                value: time_s,
            });
        }
        let due = self.pulse_due(time_s);
        if !pedal || !due {
            if !pedal {
                self.next_pulse_s = None;
            }
            if let Some(last) = &mut self.last {
                last.held = !pedal;
            }
            return Ok(self.last.as_ref());
        }
        let period = 1.0 / self.settings.pulse_rate.hz();
        // Keep the pulse train's phase, but never queue missed pulses.
        self.next_pulse_s = Some(match self.next_pulse_s {
            Some(next) if time_s - next < period => next + period,
            _ => time_s + period,
        });
        let frame = self.expose(time_s, scene)?;
        Ok(Some(self.last.insert(frame)))
    }

    /// Makes one exposure now, whatever the pulse clock says (cine and tests).
    pub fn expose(&mut self, time_s: f64, scene: Scene<'_>) -> Result<Frame> {
        self.refresh_background(scene.volume, scene.carm)?;
        let layers = if scene.layers.pieces().is_empty() {
            None
        } else {
            Some(self.renderer.project_layers(scene.layers, scene.carm)?)
        };
        let geometry = &scene.carm.detector;
        let transmitted = detector::transmission(
            &self.settings.spectrum,
            self.cache.as_ref().map(|c| &c.image),
            layers.as_ref(),
            geometry.width_px,
            geometry.height_px,
        );
        let index = self.stats.exposures;
        self.stats.exposures += 1;
        let mut values = detector::expose(&transmitted, geometry, &self.settings.detector, index);
        let d = &self.settings.detector;
        let mut window = (d.window, d.level);
        match self.mode {
            ImagingMode::Fluoroscopy => {
                if d.auto_window {
                    window = detector::auto_window(&values, geometry.width_px, geometry.height_px)
                        .unwrap_or(window);
                }
            }
            ImagingMode::Subtraction => {
                window = (self.settings.subtraction_window, 0.0);
                match &mut self.masks {
                    Some(m) if m.carm == *scene.carm => {
                        for ((v, mask), peak) in
                            values.iter_mut().zip(&m.mask).zip(&mut m.peak_opacity)
                        {
                            *v -= mask;
                            *peak = peak.max(*v);
                        }
                    }
                    _ => {
                        // The first exposure of a run (or after a pose change) is the mask.
                        self.masks = Some(SubtractionMasks {
                            carm: *scene.carm,
                            mask: values.clone(),
                            peak_opacity: vec![0.0; values.len()],
                        });
                        values.iter_mut().for_each(|v| *v -= *v);
                    }
                }
            }
            ImagingMode::Roadmap => {
                window = (self.settings.subtraction_window, 0.0);
                let m = self
                    .masks
                    .as_ref()
                    .filter(|m| m.carm == *scene.carm)
                    .ok_or_else(|| {
                        XrayError::Unavailable("roadmap: the C-arm moved since the DSA run".into())
                    })?;
                let depth = self.settings.roadmap_vessel_depth as f32;
                for ((v, mask), peak) in values.iter_mut().zip(&m.mask).zip(&m.peak_opacity) {
                    *v = *v - mask - peak.min(depth);
                }
            }
        }
        Ok(Frame {
            index,
            time_s,
            width: geometry.width_px,
            height: geometry.height_px,
            mode: self.mode,
            held: false,
            values,
            window,
        })
    }

    /// The background for this volume and pose: cached, re-rendered only when either (or
    /// the march settings) changed.
    fn refresh_background(&mut self, volume: &Arc<Volume>, carm: &CArm) -> Result<()> {
        let hit = self.cache.as_ref().is_some_and(|c| {
            Arc::ptr_eq(&c.volume, volume) && c.carm == *carm && c.march == self.settings.march
        });
        if !hit {
            let image = self
                .renderer
                .project_volume(volume, carm, &self.settings.march)?;
            self.stats.background_renders += 1;
            self.cache = Some(CachedBackground {
                volume: Arc::clone(volume),
                carm: *carm,
                march: self.settings.march,
                image,
            });
        }
        Ok(())
    }
}
