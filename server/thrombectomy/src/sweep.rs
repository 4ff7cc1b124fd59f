//! The seeded outcome sweep: scripted thrombectomies of up to three passes over a spread of
//! patients (clot length, wedging, stiffness and friction, pressure drop) and of operator
//! placement (where the stent lands, how squarely the catheter meets the clot), each run
//! from its own seed, so that any table it gives is reproduced exactly.
//!
//! The spreads (assumed, stated): clot length uniform 5–15 mm (NOTES.md); wedge strain
//! uniform 0.02–0.12; modulus, friction and strength each × a log-normal factor of σ = 0.25
//! (biological scatter); pressure drop across the occlusion uniform 6–10 kPa (45–75 mmHg
//! of a 100 mmHg inlet lost across the clot); stent distal end 4 ± 3 mm (normal) beyond the
//! clot's (the taught placement covers the clot with the stent's working length); apposition
//! uniform 0.5–1. A failed pass halves the clot's wedge strain ([`WEDGE_RELIEF`]).

use crate::clot::{Clot, ClotComposition};
use crate::error::Result;
use crate::path::RetrievalPath;
use crate::retrieval::{AspirationPass, AspirationSetup, PassOutcome, StentPass, StentSetup};
use crate::stent::StentRetriever;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

/// The technique of a setting.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Technique {
    /// Stent retriever pulled into a receiving catheter (with suction through it, or not).
    StentRetriever {
        /// The stent.
        stent: StentRetriever,
        /// Bore of the receiving catheter (m).
        receiving_bore_m: f64,
        /// Suction through it (Pa), 0 without.
        suction_pa: f64,
    },
    /// Direct aspiration.
    Aspiration {
        /// Catheter bore (m).
        bore_m: f64,
        /// Suction at the tip (Pa).
        suction_pa: f64,
    },
}

/// One row of the sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setting {
    /// How the clot is attacked.
    pub technique: Technique,
    /// Red-cell fraction of the clots; `None` draws it uniformly in 0.1–0.9 per run.
    pub red_cell_fraction: Option<f64>,
    /// Pull speed (m/s).
    pub pull_speed_m_s: f64,
}

/// The anatomy every run of a sweep shares.
#[derive(Debug, Clone, PartialEq)]
pub struct Site {
    /// Radius of the vessel where the clot lodges (m).
    pub vessel_radius_m: f64,
    /// The way back from the site to the receiving catheter's tip.
    pub path: RetrievalPath,
    /// Inner radius of the delivering microcatheter (m).
    pub channel_radius_m: f64,
}

/// One run's result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunOutcome {
    /// Passes made (1–3).
    pub passes: u32,
    /// Clot out on the first pass with no fragment lost (the first-pass effect).
    pub first_pass: bool,
    /// Clot out within three passes.
    pub retrieved: bool,
    /// Fragments lost downstream.
    pub emboli: u32,
}

/// Most passes a run makes.
pub const MAX_PASSES: u32 = 3;

/// What a failed pass leaves of the clot's wedge strain.
pub const WEDGE_RELIEF: f64 = 0.5;

/// Pull step of the scripted hand (m).
const PULL_STEP_M: f64 = 0.25e-3;

fn lognormal(rng: &mut StdRng, sigma: f64) -> f64 {
    // Box–Muller.
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random::<f64>();
    (sigma * (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()).exp()
}

fn normal(rng: &mut StdRng, mean: f64, sigma: f64) -> f64 {
    mean + sigma * lognormal(rng, 1.0).ln()
}

/// One scripted thrombectomy, from `seed`.
pub fn run(setting: &Setting, site: &Site, seed: u64) -> Result<RunOutcome> {
    let mut rng = StdRng::seed_from_u64(seed);
    let fraction = setting
        .red_cell_fraction
        .unwrap_or_else(|| rng.random_range(0.1..0.9));
    let composition = ClotComposition {
        red_cell_fraction: fraction,
    };
    let mut clot = Clot::new(
        composition,
        rng.random_range(5e-3..15e-3),
        site.vessel_radius_m,
        rng.random_range(0.02..0.12),
    );
    clot.mechanics.modulus_pa *= lognormal(&mut rng, 0.25);
    clot.mechanics.wall_friction *= lognormal(&mut rng, 0.25);
    clot.mechanics.strength_pa *= lognormal(&mut rng, 0.25);
    let pressure_drop_pa = rng.random_range(6e3..10e3);
    let speed = setting.pull_speed_m_s;
    let back = site.path.length_m();
    let mut emboli = 0;
    for pass in 1..=MAX_PASSES {
        let outcome = match setting.technique {
            Technique::StentRetriever {
                stent,
                receiving_bore_m,
                suction_pa,
            } => {
                let mut p = StentPass::new(StentSetup {
                    stent,
                    clot,
                    distal_offset_m: normal(&mut rng, 4e-3, 3e-3),
                    channel_radius_m: site.channel_radius_m,
                    receiving_bore_m,
                    suction_pa,
                    pressure_drop_pa,
                })?;
                loop {
                    if let Some(o) = p.advance(PULL_STEP_M, speed, &site.path, back) {
                        break o;
                    }
                }
            }
            Technique::Aspiration { bore_m, suction_pa } => {
                let mut p = AspirationPass::new(AspirationSetup {
                    clot,
                    bore_m,
                    suction_pa,
                    apposition: rng.random_range(0.5..1.0),
                    pressure_drop_pa,
                })?;
                loop {
                    if let Some(o) = p.advance(PULL_STEP_M, speed, &site.path, back) {
                        break o;
                    }
                }
            }
        };
        let lost = outcome.emboli_m().len() as u32;
        emboli += lost;
        match outcome {
            PassOutcome::Retrieved { .. } => {
                return Ok(RunOutcome {
                    passes: pass,
                    first_pass: pass == 1 && lost == 0,
                    retrieved: true,
                    emboli,
                });
            }
            PassOutcome::Failed { emboli_m, .. } => {
                // What broke off is gone downstream; the rest stays for the next pass,
                // loosened: a pass that dragged on it halves its wedging (assumed; why
                // clots that resist the first pass often come with the next).
                clot.length_m = (clot.length_m - emboli_m.iter().sum::<f64>()).max(1e-3);
                clot.wedge_strain *= WEDGE_RELIEF;
            }
        }
    }
    Ok(RunOutcome {
        passes: MAX_PASSES,
        first_pass: false,
        retrieved: false,
        emboli,
    })
}

/// A setting's rates over its runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// Runs made.
    pub runs: u32,
    /// Fraction retrieved on the first pass with no fragment lost.
    pub first_pass_rate: f64,
    /// Fraction retrieved within three passes.
    pub success_rate: f64,
    /// Mean passes.
    pub mean_passes: f64,
    /// Fraction of runs that lost at least one fragment downstream.
    pub emboli_rate: f64,
}

/// Runs `runs` thrombectomies of `setting`, seeds `base_seed..base_seed + runs`.
pub fn sweep(setting: &Setting, site: &Site, runs: u32, base_seed: u64) -> Result<Summary> {
    let (mut first, mut ok, mut passes, mut emb) = (0u32, 0u32, 0u32, 0u32);
    for k in 0..runs {
        let o = run(setting, site, base_seed + u64::from(k))?;
        first += u32::from(o.first_pass);
        ok += u32::from(o.retrieved);
        passes += o.passes;
        emb += u32::from(o.emboli > 0);
    }
    let n = f64::from(runs.max(1));
    Ok(Summary {
        runs,
        first_pass_rate: f64::from(first) / n,
        success_rate: f64::from(ok) / n,
        mean_passes: f64::from(passes) / n,
        emboli_rate: f64::from(emb) / n,
    })
}
