//! The imaging chain over time: a renderer, the background cached per pose and volume,
//! pulsed fluoroscopy (7.5/15/30 pulses per second) with automatic exposure control, dose
//! accounting and recursive (temporal) filtering, last-image hold, digital subtraction
//! angiography (a mask averaged over the run's first frames, peak opacification) and roadmap.

use std::sync::Arc;

use crate::detector::{self, DetectorSettings};
use crate::dose::{self, DoseSettings, DoseTally, ExposureDose};
use crate::error::{Result, XrayError};
use crate::geometry::CArm;
use crate::layers::Layers;
use crate::processing::{self, ScatterSettings};
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
    /// Dose per mode and automatic exposure control.
    pub dose: DoseSettings,
    /// Recursive filter weight α ∈ (0, 1] of live fluoroscopy and roadmap: each shown image
    /// is α·new + (1 − α)·previous, which divides the variance of still parts by
    /// (2 − α)/α (3 at α = 0.5) and lags moving ones by (1 − α)/α frames. 1 is off.
    pub recursive_weight: f64,
    /// Motion-adaptive recursion: where a pixel changed by more than its quantum noise can
    /// explain (a moving wire), the filter lets the new value through. The weight rises from
    /// `recursive_weight` at 2σ of the expected frame-to-memory difference to 1 at 4σ, σ from
    /// the pixel's own quanta. Still parts keep (almost all of) the filter's noise cut; a
    /// moving device leaves no lagging ghost.
    pub motion_adaptive: bool,
    /// How many exposures open a DSA run and are averaged into its mask (their noise
    /// variance in the subtraction falls as 1/k); they show as an empty subtraction.
    pub mask_frames: u32,
    /// Pixel-shift correction of DSA: when the patient moved after the mask (another volume),
    /// the mask is moved by the sub-pixel translation that best lays the anatomy at the mask
    /// on the anatomy now (noise- and contrast-free, as a registration on a landmark region
    /// without contrast would; searched within ±4 pixels, applied from a quarter pixel).
    pub pixel_shift: bool,
    /// Patient scatter and the anti-scatter grid; `None` leaves only primary radiation.
    pub scatter: Option<ScatterSettings>,
    /// Unsharp-mask edge enhancement of live fluoroscopy and roadmap images; `None` is off.
    pub edge_enhancement: Option<EdgeEnhancement>,
}

impl FluoroscopeSettings {
    /// The chain as an angio suite runs it (and the server's scenes by default): exposure
    /// control, scatter through a 10:1 grid, recursive filtering at α = 0.5, edge enhancement,
    /// a DSA mask of 3 frames and the automatic window. [`Default`] keeps every stage off.
    pub fn angio_suite() -> Self {
        let mut s = Self::default();
        s.dose.automatic = true;
        s.detector.auto_window = true;
        s.recursive_weight = 0.5;
        s.motion_adaptive = true;
        s.pixel_shift = true;
        s.mask_frames = 3;
        s.scatter = Some(ScatterSettings::default());
        s.edge_enhancement = Some(EdgeEnhancement::default());
        s
    }
}

/// Unsharp-mask edge enhancement: `x + amount·(x − G_σ ⊛ x)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeEnhancement {
    /// σ of the blur subtracted (pixels).
    pub sigma_px: f64,
    /// How much of the difference is added back.
    pub amount: f64,
}

impl Default for EdgeEnhancement {
    fn default() -> Self {
        Self {
            sigma_px: 2.0,
            amount: 0.6,
        }
    }
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
            dose: DoseSettings::default(),
            recursive_weight: 1.0,
            motion_adaptive: false,
            pixel_shift: false,
            mask_frames: 1,
            scatter: None,
            edge_enhancement: None,
        }
    }
}

/// Robust σ of mostly-background values: 1.4826 × the median absolute deviation.
fn robust_sigma(values: &[f32]) -> Option<f32> {
    let mut v: Vec<f32> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let n = v.len();
    let median = *v.select_nth_unstable_by(n / 2, f32::total_cmp).1;
    let mut deviations: Vec<f32> = v.iter().map(|x| (x - median).abs()).collect();
    let mad = *deviations.select_nth_unstable_by(n / 2, f32::total_cmp).1;
    Some(1.4826 * mad)
}

/// The roadmap's vessel map from a run's peak opacity: where the peak clears
/// [`VESSEL_THRESHOLD_SIGMA`] noise σ, the peak capped at `depth`; elsewhere nothing, so the
/// background stays clean.
fn vessel_map(peak: &[f32], noise_sigma: Option<f32>, depth: f32) -> Vec<f32> {
    let threshold = noise_sigma.map_or(0.0, |s| VESSEL_THRESHOLD_SIGMA * s);
    peak.iter()
        .map(|p| if *p > threshold { p.min(depth) } else { 0.0 })
        .collect()
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
    /// The mean of the first `frames` exposures of the run, devices left out.
    mask: Vec<f32>,
    frames: u32,
    /// Per pixel, the largest smoothed subtraction of the contrast (devices left out).
    peak_opacity: Vec<f32>,
    /// Noise σ of one smoothed subtraction, from the run's first subtracted frame.
    noise_sigma: Option<f32>,
    /// The roadmap's vessel map, made from the peak on first use.
    vessel_map: Option<Vec<f32>>,
    /// The pixel shift found for the last live frame (pixels; zero without pixel shift).
    shift: (f64, f64),
    /// With pixel shift: the patient at the mask and the anatomy's noise-free attenuation
    /// `−ln T` then, to register a moved patient against.
    anatomy: Option<(Arc<Volume>, Vec<f32>)>,
}

/// `−ln T` of detected fractions.
fn attenuation_of(transmitted: &[f32]) -> Vec<f32> {
    transmitted.iter().map(|t| -t.max(1e-30).ln()).collect()
}

/// How far pixel shift searches (pixels either way).
const PIXEL_SHIFT_SEARCH_PX: i32 = 4;
/// The smallest shift pixel shift applies (pixels): below it the interpolation's blur would
/// cost more than the misregistration.
const PIXEL_SHIFT_MIN_PX: f64 = 0.25;

/// σ (pixels) of the smoothing before a DSA frame's contrast enters the peak opacity.
const PEAK_SMOOTHING_PX: f64 = 1.0;

/// Vessel-map threshold in noise σ of a smoothed subtraction: the peak of a run's noise stays
/// below it (about 4σ over 10⁶ pixel-frames), contrast above it.
const VESSEL_THRESHOLD_SIGMA: f32 = 5.0;

/// The recursive filter's memory: the last shown image of a mode at a pose.
struct Recursion {
    carm: CArm,
    mode: ImagingMode,
    shown: Vec<f32>,
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
    recursion: Option<Recursion>,
    dose: DoseTally,
    quanta_per_mm2_per_ugy: f64,
    stats: FluoroscopeStats,
}

impl Fluoroscope {
    /// A chain on `renderer`; checks the settings.
    pub fn new(renderer: Box<dyn Renderer>, settings: FluoroscopeSettings) -> Result<Self> {
        settings.march.validate()?;
        settings.detector.validate()?;
        settings.dose.validate()?;
        if let Some(scatter) = &settings.scatter {
            scatter.validate()?;
        }
        if let Some(edge) = &settings.edge_enhancement
            && !(edge.sigma_px.is_finite()
                && (0.3..=20.0).contains(&edge.sigma_px)
                && edge.amount.is_finite()
                && (0.0..=5.0).contains(&edge.amount))
        {
            return Err(XrayError::OutOfRange {
                what: "edge enhancement σ (px) or amount".into(),
                range: "0.3 ≤ σ ≤ 20 px, 0 ≤ amount ≤ 5",
                value: if (0.3..=20.0).contains(&edge.sigma_px) {
                    edge.amount
                } else {
                    edge.sigma_px
                },
            });
        }
        if !(settings.recursive_weight > 0.0 && settings.recursive_weight <= 1.0) {
            return Err(XrayError::OutOfRange {
                what: "recursive filter weight".into(),
                range: "0 < α ≤ 1",
                value: settings.recursive_weight,
            });
        }
        if !(1..=64).contains(&settings.mask_frames) {
            return Err(XrayError::OutOfRange {
                what: "DSA mask frames".into(),
                range: "1 to 64",
                value: f64::from(settings.mask_frames),
            });
        }
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
        let quanta_per_mm2_per_ugy = dose::quanta_per_mm2_per_ugy(&settings.spectrum);
        Ok(Self {
            renderer,
            settings,
            cache: None,
            mode: ImagingMode::Fluoroscopy,
            last: None,
            next_pulse_s: None,
            masks: None,
            recursion: None,
            dose: DoseTally::default(),
            quanta_per_mm2_per_ugy,
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

    /// The DSA pixel shift found for the last subtraction frame (pixels, `(dx, dy)`: the mask
    /// was moved by it), when a run is under way.
    pub fn pixel_shift(&self) -> Option<(f64, f64)> {
        self.masks.as_ref().map(|m| m.shift)
    }

    /// Dose accumulated since the chain started.
    pub fn dose(&self) -> DoseTally {
        self.dose
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
        let transmitted = self.detected_fraction(layers.as_ref(), geometry);
        let index = self.stats.exposures;
        self.stats.exposures += 1;
        let subtraction = self.mode == ImagingMode::Subtraction;
        let mut detector_settings = self.settings.detector;
        let dose_settings = &self.settings.dose;
        if dose_settings.automatic {
            let aim = if subtraction {
                dose_settings.subtraction_detector_ugy
            } else {
                dose_settings.fluoroscopy_detector_ugy
            };
            if let Some(t) = dose::measuring_field_transmission(
                &transmitted,
                geometry.width_px,
                geometry.height_px,
            ) {
                detector_settings.photons_per_pixel = dose::controlled_photons_per_pixel(
                    aim,
                    t,
                    geometry.pixel_pitch_m(),
                    self.quanta_per_mm2_per_ugy,
                    dose_settings.max_photons_per_pixel,
                );
            }
        }
        self.dose.add(
            &ExposureDose::of(
                detector_settings.photons_per_pixel,
                scene.carm,
                self.quanta_per_mm2_per_ugy,
            ),
            subtraction,
        );
        let mut values = detector::expose(&transmitted, geometry, &detector_settings, index);
        // A DSA run's mask and vessel map leave the devices out (the same exposure without
        // their attenuation, the same noise draw): a device that moves leaves no ghost.
        let contrast_only = match (&layers, subtraction) {
            (Some(l), true) if l.channels[1..].iter().any(|c| c.iter().any(|p| *p != 0.0)) => {
                let mut iodine_only = l.clone();
                for plane in &mut iodine_only.channels[1..] {
                    plane.iter_mut().for_each(|p| *p = 0.0);
                }
                let t = self.detected_fraction(Some(&iodine_only), geometry);
                Some(detector::expose(&t, geometry, &detector_settings, index))
            }
            _ => None,
        };
        let d = self.settings.detector;
        let mut window = (d.window, d.level);
        match self.mode {
            ImagingMode::Fluoroscopy => {
                self.recursive_filter(&mut values, scene.carm, &detector_settings, None);
                self.enhance_edges(&mut values, geometry);
                if d.auto_window {
                    window = detector::auto_window(&values, geometry.width_px, geometry.height_px)
                        .unwrap_or(window);
                }
            }
            ImagingMode::Subtraction => {
                window = (self.settings.subtraction_window, 0.0);
                let wanted = self.settings.mask_frames;
                let clean = contrast_only.as_ref().unwrap_or(&values);
                // The noise-free anatomy, when pixel shift needs it: at a run's start, and
                // when the patient moved since the mask.
                let same_run = self.masks.as_ref().is_some_and(|m| m.carm == *scene.carm);
                let moved = self
                    .masks
                    .as_ref()
                    .and_then(|m| m.anatomy.as_ref())
                    .is_some_and(|(v, _)| !Arc::ptr_eq(v, scene.volume));
                let anatomy_now = (self.settings.pixel_shift && (!same_run || moved))
                    .then(|| attenuation_of(&self.detected_fraction(None, geometry)));
                match &mut self.masks {
                    Some(m) if m.carm == *scene.carm && m.frames < wanted => {
                        // Still building the mask: a running mean.
                        m.frames += 1;
                        let k = m.frames as f32;
                        for (mask, c) in m.mask.iter_mut().zip(clean) {
                            *mask += (*c - *mask) / k;
                        }
                        values.iter_mut().for_each(|v| *v -= *v);
                    }
                    Some(m) if m.carm == *scene.carm => {
                        let (w, h) = (geometry.width_px as usize, geometry.height_px as usize);
                        // Pixel shift: only a patient who moved since the mask (another
                        // volume) is registered, on the noise-free anatomy, so that neither
                        // noise nor the contrast itself can pull the mask off a still patient.
                        let shifted = match (&m.anatomy, &anatomy_now) {
                            (Some((_, at_mask)), Some(now)) => {
                                let (dx, dy) = processing::register_shift(
                                    at_mask,
                                    now,
                                    w,
                                    h,
                                    PIXEL_SHIFT_SEARCH_PX,
                                );
                                m.shift = (dx, dy);
                                (dx.hypot(dy) >= PIXEL_SHIFT_MIN_PX)
                                    .then(|| processing::shift_image(&m.mask, w, h, dx, dy))
                            }
                            _ => {
                                m.shift = (0.0, 0.0);
                                None
                            }
                        };
                        let mask = shifted.as_ref().unwrap_or(&m.mask);
                        // Collimated (NaN) pixels count as no opacity.
                        let mut opacity: Vec<f32> = clean
                            .iter()
                            .zip(mask)
                            .map(|(c, mask)| c - mask)
                            .map(|o| if o.is_finite() { o } else { 0.0 })
                            .collect();
                        detector::gaussian_blur(
                            &mut opacity,
                            geometry.width_px as usize,
                            geometry.height_px as usize,
                            PEAK_SMOOTHING_PX,
                        );
                        if m.noise_sigma.is_none() {
                            m.noise_sigma = robust_sigma(&opacity);
                        }
                        for (peak, o) in m.peak_opacity.iter_mut().zip(&opacity) {
                            *peak = peak.max(*o);
                        }
                        m.vessel_map = None;
                        for (v, mask) in values.iter_mut().zip(mask) {
                            *v -= mask;
                        }
                    }
                    _ => {
                        // The first exposure of a run (or after a pose change) starts the mask.
                        self.masks = Some(SubtractionMasks {
                            carm: *scene.carm,
                            mask: clean.clone(),
                            frames: 1,
                            peak_opacity: vec![0.0; values.len()],
                            noise_sigma: None,
                            vessel_map: None,
                            shift: (0.0, 0.0),
                            anatomy: anatomy_now.map(|a| (Arc::clone(scene.volume), a)),
                        });
                        values.iter_mut().for_each(|v| *v -= *v);
                    }
                }
            }
            ImagingMode::Roadmap => {
                window = (self.settings.subtraction_window, 0.0);
                let depth = self.settings.roadmap_vessel_depth as f32;
                let m = self
                    .masks
                    .as_mut()
                    .filter(|m| m.carm == *scene.carm)
                    .ok_or_else(|| {
                        XrayError::Unavailable("roadmap: the C-arm moved since the DSA run".into())
                    })?;
                let map = m
                    .vessel_map
                    .get_or_insert_with(|| vessel_map(&m.peak_opacity, m.noise_sigma, depth));
                let live = self.settings.motion_adaptive.then(|| values.clone());
                for ((v, mask), vessel) in values.iter_mut().zip(&m.mask).zip(map.iter()) {
                    *v = *v - mask - vessel;
                }
                self.recursive_filter(&mut values, scene.carm, &detector_settings, live.as_deref());
                self.enhance_edges(&mut values, geometry);
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

    /// The fraction of the unattenuated beam each pixel detects: the cached background and
    /// `layers` through the spectrum, plus scatter behind the grid when it is on.
    fn detected_fraction(
        &self,
        layers: Option<&PathImage>,
        geometry: &crate::geometry::DetectorGeometry,
    ) -> Vec<f32> {
        let mut transmitted = detector::transmission(
            &self.settings.spectrum,
            self.cache.as_ref().map(|c| &c.image),
            layers,
            geometry.width_px,
            geometry.height_px,
        );
        if let Some(scatter) = &self.settings.scatter {
            processing::add_scatter(
                &mut transmitted,
                geometry.width_px,
                geometry.height_px,
                geometry.pixel_pitch_m(),
                scatter,
            );
        }
        transmitted
    }

    /// Edge enhancement of a shown image, if on.
    fn enhance_edges(&self, values: &mut [f32], geometry: &crate::geometry::DetectorGeometry) {
        if let Some(edge) = &self.settings.edge_enhancement {
            processing::unsharp_mask(
                values,
                geometry.width_px,
                geometry.height_px,
                edge.sigma_px,
                edge.amount,
            );
        }
    }

    /// Recursive filtering of `values` in place against the last image shown in this mode at
    /// this pose (none after a mode or pose change: the new image shows as it is).
    /// `attenuation` is the exposure's own `−ln(N/N0)` per pixel where `values` are something
    /// else (a roadmap's subtraction); `None` when `values` are the exposure.
    fn recursive_filter(
        &mut self,
        values: &mut [f32],
        carm: &CArm,
        exposure: &DetectorSettings,
        attenuation: Option<&[f32]>,
    ) {
        let alpha = self.settings.recursive_weight as f32;
        if alpha >= 1.0 {
            return;
        }
        // σ of (new − memory) per unit of √(e^v): the new value's quantum noise √(e^v / N0),
        // less after the detector blur (white noise through a Gaussian of σ_b keeps
        // 1/(2√π σ_b) of its σ), and the memory's own σ²·α/(2 − α) added.
        let blur = exposure.blur_sigma_px;
        let blurred = if blur > 0.5 {
            (1.0 / (2.0 * std::f64::consts::PI.sqrt() * blur)).min(1.0)
        } else {
            1.0
        };
        let spread = (blurred / exposure.photons_per_pixel.sqrt()
            * (2.0 / (2.0 - f64::from(alpha))).sqrt()) as f32;
        let adaptive = self.settings.motion_adaptive;
        match &mut self.recursion {
            Some(r) if r.carm == *carm && r.mode == self.mode && r.shown.len() == values.len() => {
                use rayon::prelude::*;
                values
                    .par_iter_mut()
                    .zip(r.shown.par_iter_mut())
                    .enumerate()
                    .for_each(|(i, (v, shown))| {
                        let mut a = alpha;
                        if adaptive {
                            let log = attenuation.map_or(*shown, |l| l[i]);
                            let z = (*v - *shown).abs() / (spread * (0.5 * log).exp());
                            if z.is_finite() {
                                a += (1.0 - alpha) * (0.5 * (z - 2.0)).clamp(0.0, 1.0);
                            }
                        }
                        *v = a * *v + (1.0 - a) * *shown;
                        *shown = *v;
                    });
            }
            _ => {
                self.recursion = Some(Recursion {
                    carm: *carm,
                    mode: self.mode,
                    shown: values.to_vec(),
                });
            }
        }
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
