//! The stent retriever: a self-expanding nitinol stent on a push wire. Its radial force law
//! (rings of struts under hoop tension), its unsheathed shape as a chain of rings between
//! the microcatheter's mouth and its free end, and what it presses against (vessel wall,
//! clot).
//!
//! **Ring law.** A stent is rings of struts. Squeezed from its nominal radius `r₀` to `r`, a
//! ring carries a hoop tension `T = K (r₀ − r)/r₀` (N per metre of stent, `K` the hoop
//! stiffness); Laplace's law turns it into a radial pressure `T/r`, i.e. a radial force per
//! metre of stent `f(r) = 2π T = k (r₀ − r)` with `k = 2πK/r₀`. Unloading (the stent pushing
//! out: the chronic outward force, COF) follows this law; loading (squeezed by a catheter:
//! the radial resistive force, RRF) is stiffer by nitinol's hysteresis, [`StentRetriever::rrf_ratio`].
//!
//! **Chain.** Neighbouring rings are tied by the cell links: a ring's radius is pulled
//! towards its neighbours' with a stiffness `β` (N), so the stent opens over a transition
//! length `ℓ = √(β/k)` beyond the catheter's mouth. Ring `i` balances
//! `β (r₍ᵢ₋₁₎ − 2rᵢ + r₍ᵢ₊₁₎)/h² + f(rᵢ) = g(rᵢ, xᵢ)`, `g` the environment's push-back (an
//! elastic wall, a clot layer); the sheathed end is held at the catheter's inner radius and
//! the free end has no neighbour beyond it.
//!
//! Calibration (chosen, stated): a 4 × 20 mm stent (Solitaire / Trevo class, NOTES.md
//! 3–6 mm × 20–40 mm) with a COF of 0.02 N per mm of stent at 3 mm (0.4 N over its length,
//! of the order of the radial forces stent retrievers are reported to exert at M1 diameters
//! in bench tests, Machi et al., J. NeuroIntervent. Surg. 2017; not re-verified here), an
//! RRF 1.6× the COF (nitinol's loading/unloading plateau ratio, assumed), a 1.5 mm
//! transition (about one cell; assumed), strut–clot friction 0.15 and 80 % open area
//! between struts (assumed; closed-cell laser-cut stents are mostly open).

use crate::error::{Result, ThrombectomyError, require_non_negative, require_positive};
use std::f64::consts::PI;

/// A stent retriever's geometry and radial force law.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StentRetriever {
    /// Nominal (free) diameter (m).
    pub nominal_diameter_m: f64,
    /// Stent length (m).
    pub length_m: f64,
    /// Chronic outward force per metre of stent at `reference_diameter_m` (N/m).
    pub cof_n_per_m: f64,
    /// Diameter at which the COF is given (m), below the nominal.
    pub reference_diameter_m: f64,
    /// Radial resistive force over chronic outward force (loading over unloading).
    pub rrf_ratio: f64,
    /// Length over which the stent opens beyond the catheter's mouth (m).
    pub transition_m: f64,
    /// Coulomb friction of the struts against a clot's surface.
    pub strut_friction: f64,
    /// Fraction of the stent's surface open between struts (0–1): the clot that bulges
    /// into the cells must shear off to escape them.
    pub open_area: f64,
}

impl StentRetriever {
    /// The 4 × 20 mm stent of the module's calibration.
    pub fn solitaire_class_4x20() -> Self {
        Self {
            nominal_diameter_m: 4e-3,
            length_m: 20e-3,
            cof_n_per_m: 20.0,
            reference_diameter_m: 3e-3,
            rrf_ratio: 1.6,
            transition_m: 1.5e-3,
            strut_friction: 0.15,
            open_area: 0.8,
        }
    }

    /// Checks every field.
    pub fn validate(&self) -> Result<()> {
        require_positive("stent nominal diameter (m)", self.nominal_diameter_m)?;
        require_positive("stent length (m)", self.length_m)?;
        require_positive("stent chronic outward force (N/m)", self.cof_n_per_m)?;
        require_positive("stent reference diameter (m)", self.reference_diameter_m)?;
        if self.reference_diameter_m >= self.nominal_diameter_m {
            return Err(ThrombectomyError::InvalidParameter {
                name: "stent reference diameter (m)".into(),
                value: self.reference_diameter_m,
                requirement: "below the nominal diameter",
            });
        }
        if !(self.rrf_ratio.is_finite() && self.rrf_ratio >= 1.0) {
            return Err(ThrombectomyError::InvalidParameter {
                name: "stent RRF/COF ratio".into(),
                value: self.rrf_ratio,
                requirement: "at least 1",
            });
        }
        require_positive("stent transition length (m)", self.transition_m)?;
        require_non_negative("stent strut friction", self.strut_friction)?;
        if !(0.0..=1.0).contains(&self.open_area) {
            return Err(ThrombectomyError::InvalidParameter {
                name: "stent open area".into(),
                value: self.open_area,
                requirement: "between 0 and 1",
            });
        }
        Ok(())
    }

    /// Nominal radius (m).
    pub fn nominal_radius_m(&self) -> f64 {
        self.nominal_diameter_m / 2.0
    }

    /// Radial stiffness `k` (N/m per m of stent, i.e. N/m²): `f(r) = k (r₀ − r)`.
    pub fn radial_stiffness(&self) -> f64 {
        self.cof_n_per_m / (self.nominal_radius_m() - self.reference_diameter_m / 2.0)
    }

    /// Hoop stiffness `K` (N/m) of the ring law `T = K (r₀ − r)/r₀`.
    pub fn hoop_stiffness_n_per_m(&self) -> f64 {
        self.radial_stiffness() * self.nominal_radius_m() / (2.0 * PI)
    }

    /// Chronic outward force per metre of stent at radius `r` (N/m): `k (r₀ − r)`, zero at
    /// and beyond the nominal radius.
    pub fn outward_force_n_per_m(&self, radius_m: f64) -> f64 {
        self.radial_stiffness() * (self.nominal_radius_m() - radius_m).max(0.0)
    }

    /// Radial resistive force per metre (N/m) while being squeezed to radius `r`.
    pub fn resistive_force_n_per_m(&self, radius_m: f64) -> f64 {
        self.rrf_ratio * self.outward_force_n_per_m(radius_m)
    }

    /// Link stiffness `β = k ℓ²` (N).
    pub fn link_stiffness_n(&self) -> f64 {
        self.radial_stiffness() * self.transition_m * self.transition_m
    }
}

/// What surrounds the stent at one place along it: the vessel wall, and maybe a clot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surroundings {
    /// Vessel lumen radius (m).
    pub vessel_radius_m: f64,
    /// Vessel wall stiffness (N/m per m of vessel): pushed out by `d` the wall pushes back
    /// `k_v d` per metre; for a thin-walled tube `k_v = 2π E_w t / R`.
    pub wall_stiffness: f64,
    /// A clot filling the lumen here: its compressive modulus (Pa) and the radius of the
    /// channel the microcatheter left through it (m).
    pub clot: Option<(f64, f64)>,
}

/// Wall stiffness of a cerebral artery of radius `radius_m` (N/m²): thin-walled tube with a
/// 1.5 MPa wall and a wall a sixth of the radius thick (assumed; cerebral arteries have
/// wall-to-lumen ratios of about 0.1–0.2 and moduli of about 1–2 MPa).
pub fn cerebral_wall_stiffness(radius_m: f64) -> f64 {
    let thickness = radius_m / 6.0;
    2.0 * PI * 1.5e6 * thickness / radius_m
}

impl Surroundings {
    /// Push-back on the stent at radius `r` (N/m) and its derivative in `r` (N/m²).
    pub fn push_back(&self, r: f64) -> (f64, f64) {
        let mut g = 0.0;
        let mut dg = 0.0;
        if r > self.vessel_radius_m {
            g += self.wall_stiffness * (r - self.vessel_radius_m);
            dg += self.wall_stiffness;
        }
        if let Some((modulus, channel)) = self.clot
            && r > channel
        {
            // The clot layer between the stent and the wall, squeezed by the strain
            // (r − r_c)/(R − r_c), pressing on the stent's circumference.
            let depth = (self.vessel_radius_m - channel).max(1e-9);
            let strain = (r - channel) / depth;
            g += 2.0 * PI * r * modulus * strain;
            dg += 2.0 * PI * modulus * (strain + r / depth);
        }
        (g, dg)
    }

    /// Radius (m) where the stent `stent` balances these surroundings with no neighbours
    /// (a long stent far from the catheter): `f(r) = g(r)`, by bisection to 1e-13 m.
    pub fn balance_radius_m(&self, stent: &StentRetriever) -> f64 {
        let (mut lo, mut hi) = (0.0, stent.nominal_radius_m());
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if stent.outward_force_n_per_m(mid) > self.push_back(mid).0 {
                lo = mid;
            } else {
                hi = mid;
            }
            if hi - lo < 1e-13 {
                break;
            }
        }
        0.5 * (lo + hi)
    }
}

/// The unsheathed stent's shape: ring radii every `spacing_m` from the catheter's mouth.
#[derive(Debug, Clone, PartialEq)]
pub struct Deployment {
    /// Ring spacing (m).
    pub spacing_m: f64,
    /// Ring radii (m), ring 0 at the mouth (held at the catheter's inner radius).
    pub radii_m: Vec<f64>,
    /// Radial force on each ring's surroundings (N per metre of stent).
    pub force_n_per_m: Vec<f64>,
}

impl Deployment {
    /// Solves the unsheathed chain: `unsheathed_m` of stent beyond a catheter of inner radius
    /// `mouth_radius_m`, ring `i` at distance `i·h` from the mouth surrounded by
    /// `around(x)`. Newton on the tridiagonal system (the Jacobian is diagonally dominant:
    /// the ring law and the push-back both stiffen), to 1e-12 m.
    pub fn solve(
        stent: &StentRetriever,
        unsheathed_m: f64,
        mouth_radius_m: f64,
        spacing_m: f64,
        around: impl Fn(f64) -> Surroundings,
    ) -> Result<Self> {
        stent.validate()?;
        require_positive("ring spacing (m)", spacing_m)?;
        require_non_negative("unsheathed length (m)", unsheathed_m)?;
        require_positive("catheter inner radius (m)", mouth_radius_m)?;
        let unsheathed = unsheathed_m.min(stent.length_m);
        let n = (unsheathed / spacing_m).round() as usize;
        let mut r = vec![mouth_radius_m; n + 1];
        let env: Vec<Surroundings> = (0..=n).map(|i| around(i as f64 * spacing_m)).collect();
        if n == 0 {
            return Ok(Self {
                spacing_m,
                radii_m: r,
                force_n_per_m: vec![0.0],
            });
        }
        // Start from the local balances (exact far from the mouth).
        for i in 1..=n {
            r[i] = env[i]
                .balance_radius_m(stent)
                .max(mouth_radius_m.min(stent.nominal_radius_m()));
        }
        let beta = stent.link_stiffness_n() / (spacing_m * spacing_m);
        let k = stent.radial_stiffness();
        let r0 = stent.nominal_radius_m();
        let mut residual = vec![0.0; n];
        let (mut lower, mut diag, mut upper) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for _ in 0..100 {
            for i in 1..=n {
                let left = r[i - 1];
                let right = if i < n { r[i + 1] } else { r[i] };
                let (g, dg) = env[i].push_back(r[i]);
                let (f, df) = if r[i] < r0 {
                    (k * (r0 - r[i]), -k)
                } else {
                    (0.0, 0.0)
                };
                residual[i - 1] = beta * (left - 2.0 * r[i] + right) + f - g;
                diag[i - 1] = if i < n { -2.0 * beta } else { -beta } + df - dg;
                lower[i - 1] = if i > 1 { beta } else { 0.0 };
                upper[i - 1] = if i < n { beta } else { 0.0 };
            }
            let delta = thomas(&lower, &diag, &upper, &residual);
            let mut largest: f64 = 0.0;
            for i in 1..=n {
                // Newton on J Δ = −R.
                let step = -delta[i - 1];
                r[i] = (r[i] + step).max(0.0);
                largest = largest.max(step.abs());
            }
            if largest < 1e-12 {
                break;
            }
        }
        let force_n_per_m = r
            .iter()
            .map(|&ri| stent.outward_force_n_per_m(ri))
            .collect();
        Ok(Self {
            spacing_m,
            radii_m: r,
            force_n_per_m,
        })
    }

    /// Radial force (N) the stent exerts on `[from_m, to_m]` of its length from the mouth.
    pub fn radial_force_over_n(&self, from_m: f64, to_m: f64) -> f64 {
        let h = self.spacing_m;
        self.force_n_per_m
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let (a, b) = ((i as f64 - 0.5) * h, (i as f64 + 0.5) * h);
                let overlap = (b.min(to_m) - a.max(from_m).max(0.0)).max(0.0);
                f * overlap
            })
            .sum()
    }
}

/// Solves a tridiagonal system (Thomas algorithm); `lower[0]` and `upper[n−1]` unused.
pub(crate) fn thomas(lower: &[f64], diag: &[f64], upper: &[f64], rhs: &[f64]) -> Vec<f64> {
    let n = diag.len();
    let mut c = vec![0.0; n];
    let mut d = vec![0.0; n];
    let mut x = vec![0.0; n];
    if n == 0 {
        return x;
    }
    c[0] = upper[0] / diag[0];
    d[0] = rhs[0] / diag[0];
    for i in 1..n {
        let m = diag[i] - lower[i] * c[i - 1];
        c[i] = upper[i] / m;
        d[i] = (rhs[i] - lower[i] * d[i - 1]) / m;
    }
    x[n - 1] = d[n - 1];
    for i in (0..n - 1).rev() {
        x[i] = d[i] - c[i] * x[i + 1];
    }
    x
}
