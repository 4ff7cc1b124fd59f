//! Attenuation physics: the materials a frame is made of, a polyenergetic beam as energy bins,
//! the HU → μ model of CT voxels, and Beer–Lambert transmission of per-pixel material paths.
//!
//! Every pixel carries five material path lengths (m), whatever renderer made them:
//! - `water`: ∫ water-equivalent fraction ds through the CT (1 in soft tissue, 0 in air);
//! - `bone`: ∫ bone fraction ds through the CT (HU above water, scaled to cortical bone);
//! - `iodine`: ∫ (c / 300 mg/mL) ds through contrast-filled lumen;
//! - `nitinol`, `platinum`: ∫ metal fill fraction ds through devices.
//!
//! In energy bin E the line integral is
//! `μw·water + (μb − μw)·bone + μI·iodine + (μNi − μw)·nitinol + (μPt − μw)·platinum`: iodine
//! is added to the blood already in the CT, and a device displaces the blood (water) it sits
//! in. The transmitted fraction is `Σ_E w_E exp(−L_E)`, which hardens the beam as it should.

use crate::error::{Result, XrayError, require_finite};

/// Linear attenuation coefficients (1/m) of each material at one energy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MaterialAttenuation {
    /// Water (and blood, soft tissue at HU 0).
    pub water: f64,
    /// Cortical bone.
    pub cortical_bone: f64,
    /// Iodine at 300 mgI/mL, over and above the water it is dissolved in.
    pub iodine_300: f64,
    /// Nitinol (guidewire cores, stents, catheter braids).
    pub nitinol: f64,
    /// Platinum (tip coils, marker bands).
    pub platinum: f64,
}

impl MaterialAttenuation {
    /// The tabulated figures at 60 keV (NOTES.md; 1/mm there, 1/m here).
    pub const KEV_60: Self = Self {
        water: 20.6,
        cortical_bone: 60.0,
        iodine_300: 227.0,
        nitinol: 760.0,
        platinum: 9300.0,
    };
    /// The tabulated figures at 80 keV (NOTES.md; 1/mm there, 1/m here).
    pub const KEV_80: Self = Self {
        water: 18.4,
        cortical_bone: 43.0,
        iodine_300: 105.0,
        nitinol: 380.0,
        platinum: 18700.0,
    };

    fn as_array(&self) -> [f64; 5] {
        [
            self.water,
            self.cortical_bone,
            self.iodine_300,
            self.nitinol,
            self.platinum,
        ]
    }

    /// The coefficients applied to the five path channels, in [`MaterialPaths`] order (1/m).
    #[inline]
    pub fn channel_coefficients(&self) -> [f64; 5] {
        [
            self.water,
            self.cortical_bone - self.water,
            self.iodine_300,
            self.nitinol - self.water,
            self.platinum - self.water,
        ]
    }
}

/// One energy bin of the beam as the detector sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyBin {
    /// Bin energy (keV), for reports.
    pub kev: f64,
    /// Share of the unattenuated detector signal in this bin (the bins' weights sum to 1).
    pub weight: f64,
    /// Attenuation of each material at this energy.
    pub attenuation: MaterialAttenuation,
}

/// A polyenergetic beam: detector-signal weights over energy bins.
#[derive(Debug, Clone, PartialEq)]
pub struct Spectrum {
    bins: Vec<EnergyBin>,
}

impl Default for Spectrum {
    /// Two bins, 60 and 80 keV, sharing the signal equally: a filtered ~80 kVp
    /// neuro-fluoroscopy beam at the resolution of the tabulated figures.
    fn default() -> Self {
        Self {
            bins: vec![
                EnergyBin {
                    kev: 60.0,
                    weight: 0.5,
                    attenuation: MaterialAttenuation::KEV_60,
                },
                EnergyBin {
                    kev: 80.0,
                    weight: 0.5,
                    attenuation: MaterialAttenuation::KEV_80,
                },
            ],
        }
    }
}

impl Spectrum {
    /// Checks the bins and normalizes their weights to sum to 1. At most
    /// [`Spectrum::MAX_BINS`] bins (the GPU path carries them in a fixed-size uniform).
    pub fn new(mut bins: Vec<EnergyBin>) -> Result<Self> {
        if bins.is_empty() || bins.len() > Self::MAX_BINS {
            return Err(XrayError::OutOfRange {
                what: "number of spectrum bins".into(),
                range: "1 to 8",
                value: bins.len() as f64,
            });
        }
        let mut total = 0.0;
        for (i, bin) in bins.iter().enumerate() {
            require_finite(|| format!("spectrum bin {i} energy (keV)"), bin.kev)?;
            if !(bin.weight.is_finite() && bin.weight >= 0.0) {
                return Err(XrayError::OutOfRange {
                    what: format!("spectrum bin {i} weight"),
                    range: "finite and ≥ 0",
                    value: bin.weight,
                });
            }
            for (m, mu) in bin.attenuation.as_array().into_iter().enumerate() {
                if !(mu.is_finite() && mu >= 0.0) {
                    return Err(XrayError::OutOfRange {
                        what: format!("spectrum bin {i} attenuation of material {m} (1/m)"),
                        range: "finite and ≥ 0",
                        value: mu,
                    });
                }
            }
            total += bin.weight;
        }
        if total <= 0.0 {
            return Err(XrayError::OutOfRange {
                what: "sum of spectrum weights".into(),
                range: "> 0",
                value: total,
            });
        }
        for bin in &mut bins {
            bin.weight /= total;
        }
        Ok(Self { bins })
    }

    /// The most bins a spectrum may have.
    pub const MAX_BINS: usize = 8;

    /// A single energy: the tabulated 60 or 80 keV figures (other energies are not
    /// tabulated, so they are refused).
    pub fn monoenergetic(kev: f64) -> Result<Self> {
        let attenuation = if kev == 60.0 {
            MaterialAttenuation::KEV_60
        } else if kev == 80.0 {
            MaterialAttenuation::KEV_80
        } else {
            return Err(XrayError::OutOfRange {
                what: "monoenergetic beam energy (keV)".into(),
                range: "60 or 80 (the tabulated energies)",
                value: kev,
            });
        };
        Self::new(vec![EnergyBin {
            kev,
            weight: 1.0,
            attenuation,
        }])
    }

    /// The bins, weights summing to 1.
    pub fn bins(&self) -> &[EnergyBin] {
        &self.bins
    }

    /// Transmitted fraction of the detector signal through the given material paths.
    #[inline]
    pub fn transmission(&self, paths: &MaterialPaths) -> f64 {
        self.bins
            .iter()
            .map(|bin| bin.weight * (-paths.line_integral(&bin.attenuation)).exp())
            .sum()
    }
}

/// Material path lengths along one ray (m); see the module docs for their meaning.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MaterialPaths {
    /// Water-equivalent path through the CT (m).
    pub water: f64,
    /// Bone-fraction path through the CT (m).
    pub bone: f64,
    /// Iodine path at 300 mg/mL (m).
    pub iodine: f64,
    /// Nitinol path (m).
    pub nitinol: f64,
    /// Platinum path (m).
    pub platinum: f64,
}

impl MaterialPaths {
    /// The five channels in order: water, bone, iodine, nitinol, platinum.
    #[inline]
    pub fn as_array(&self) -> [f64; 5] {
        [
            self.water,
            self.bone,
            self.iodine,
            self.nitinol,
            self.platinum,
        ]
    }

    /// ∫ μ ds at one energy (dimensionless).
    #[inline]
    pub fn line_integral(&self, attenuation: &MaterialAttenuation) -> f64 {
        self.as_array()
            .iter()
            .zip(attenuation.channel_coefficients())
            .map(|(path, mu)| path * mu)
            .sum()
    }
}

/// How CT numbers become material fractions: below water, a water/air mix
/// (`water = 1 + HU/1000`); above water, full water plus a bone fraction `HU / bone_hu`, so
/// that μ(HU) is the classic bilinear model, exact for air, water and cortical bone.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HuModel {
    /// HU of cortical bone (where the bone fraction reaches 1).
    pub bone_hu: f64,
}

impl Default for HuModel {
    /// `bone_hu = 1000 (μb/μw − 1)` at 60 keV, the usual effective energy of a 120 kVp CT:
    /// 1913 HU.
    fn default() -> Self {
        let mu = MaterialAttenuation::KEV_60;
        Self {
            bone_hu: 1000.0 * (mu.cortical_bone / mu.water - 1.0),
        }
    }
}

impl HuModel {
    /// Checks the model.
    pub fn validate(&self) -> Result<()> {
        crate::error::require_positive(|| "HU of cortical bone".into(), self.bone_hu).map(|_| ())
    }

    /// (water fraction, bone fraction) of a voxel at `hu`.
    #[inline]
    pub fn fractions(&self, hu: f64) -> (f64, f64) {
        if hu <= 0.0 {
            ((1.0 + hu * 1e-3).max(0.0), 0.0)
        } else {
            (1.0, hu / self.bone_hu)
        }
    }
}
