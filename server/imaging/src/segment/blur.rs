//! How a scanner's blur shrinks a vessel's half-maximum radius, and the correction that
//! undoes it.
//!
//! A cross-section of a straight vessel is a disc of radius `R`; the scanner's point spread
//! (and the partial volume of its voxels, and any smoothing filter) blurs it with, close
//! enough, a Gaussian of σ. The wall found where the image falls half-way from the centre
//! value to the tissue value ("full width at half maximum") then lies inside the true
//! wall: by about `σ²/2R` for wide vessels, and more as `R` nears σ, because a curved edge
//! gathers less of the lumen's brightness than it spreads outside. [`half_maximum_radius`]
//! is that measured radius, [`edge_sigma`] estimates σ from how steeply the image falls at
//! the wall, and [`BlurCorrection`] inverts the one with the other.

/// The fraction of a unit disc of radius `radius` blurred by a 2-D Gaussian of σ `sigma`
/// seen at `s` from the disc's centre (all lengths in the same unit): the integral over
/// circles of radius ρ around the point, weighted by the Gaussian's radial density, of
/// the part of each circle inside the disc.
pub fn blurred_disc(radius: f64, sigma: f64, s: f64) -> f64 {
    if sigma <= 0.0 {
        return if s < radius { 1.0 } else { 0.0 };
    }
    // Midpoint rule over ρ ∈ [0, 8σ] in pieces split where the inside fraction changes
    // form (|R − s| and R + s), so that each piece's integrand is smooth inside.
    let top = 8.0 * sigma;
    let mut cuts = vec![0.0, (radius - s).abs().min(top), (radius + s).min(top), top];
    cuts.dedup();
    let mut sum = 0.0;
    for piece in cuts.windows(2) {
        let steps = 400;
        let d = (piece[1] - piece[0]) / steps as f64;
        for n in 0..steps {
            let rho = piece[0] + (n as f64 + 0.5) * d;
            let density = rho / (sigma * sigma) * (-0.5 * (rho / sigma).powi(2)).exp();
            let inside = if rho + s <= radius {
                1.0
            } else if rho >= s + radius || s >= rho + radius {
                0.0
            } else {
                let c = (rho * rho + s * s - radius * radius) / (2.0 * rho * s);
                c.clamp(-1.0, 1.0).acos() / std::f64::consts::PI
            };
            sum += density * inside * d;
        }
    }
    sum
}

/// The radius at which a disc of `radius` blurred by σ `sigma` falls to half its centre
/// value (same units): what a half-maximum wall criterion measures.
pub fn half_maximum_radius(radius: f64, sigma: f64) -> f64 {
    if sigma <= 0.0 {
        return radius;
    }
    let half = 0.5 * blurred_disc(radius, sigma, 0.0);
    let (mut lo, mut hi) = (0.0, radius + 8.0 * sigma);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if blurred_disc(radius, sigma, mid) > half {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// σ (m) of a Gaussian edge whose value falls by `drop_fraction` of the full contrast
/// between `half_width` (m) inside and `half_width` outside the wall: the fall is
/// `erf(w/σ√2)`. `None` when the fall is no fall (≤ 0) or the whole contrast (≥ 1, a
/// sharp wall: σ is below what the samples resolve).
pub fn edge_sigma(drop_fraction: f64, half_width: f64) -> Option<f64> {
    if !(drop_fraction > 0.0 && drop_fraction < 0.999) {
        return None;
    }
    // Invert erf by bisection on x = w/(σ√2) ∈ (0, 3].
    let (mut lo, mut hi) = (0.0_f64, 3.0_f64);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if libm::erf(mid) < drop_fraction {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(half_width / (0.5 * (lo + hi) * std::f64::consts::SQRT_2))
}

/// The inverse of [`half_maximum_radius`] for any σ, from a table of the dimensionless
/// measured radius `r/σ` against the true `R/σ` (monotonic in `R`).
#[derive(Debug, Clone)]
pub struct BlurCorrection {
    /// (`R/σ`, `r/σ`) pairs, increasing in both.
    table: Vec<(f64, f64)>,
}

/// Past this `R/σ` the first-order law `r = R − σ²/2R` is used (its error is far below a
/// percent there).
const TABLE_END: f64 = 12.0;

impl Default for BlurCorrection {
    fn default() -> Self {
        Self::new()
    }
}

impl BlurCorrection {
    /// Tabulates [`half_maximum_radius`] for `R/σ` from 0.8 to 12 (a few milliseconds).
    pub fn new() -> Self {
        let steps = ((TABLE_END - 0.8) / 0.1).round() as usize;
        let table = (0..=steps)
            .map(|n| {
                let ratio = 0.8 + 0.1 * n as f64;
                (ratio, half_maximum_radius(ratio, 1.0))
            })
            .collect();
        Self { table }
    }

    /// The true radius (m) of a vessel whose half-maximum radius measured `measured` (m) in
    /// an image blurred by σ `sigma` (m). Radii smaller than any blurred disc can show are
    /// returned as the smallest resolvable one; σ ≤ 0 changes nothing.
    pub fn true_radius(&self, measured: f64, sigma: f64) -> f64 {
        if sigma <= 0.0 || measured <= 0.0 {
            return measured;
        }
        let m = measured / sigma;
        let last = self.table[self.table.len() - 1];
        if m >= last.1 {
            // r = R − 1/(2R) in units of σ: R = (r + √(r² + 2)) / 2.
            return 0.5 * (m + (m * m + 2.0).sqrt()) * sigma;
        }
        let first = self.table[0];
        if m <= first.1 {
            return first.0 * sigma;
        }
        let k = self.table.partition_point(|&(_, r)| r < m);
        let (a, b) = (self.table[k - 1], self.table[k]);
        let t = (m - a.1) / (b.1 - a.1);
        (a.0 + t * (b.0 - a.0)) * sigma
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force: the blurred disc as a sum of the Gaussian over a fine Cartesian grid.
    fn brute(radius: f64, sigma: f64, s: f64) -> f64 {
        let n = 600;
        let half = radius + 6.0 * sigma;
        let d = 2.0 * half / n as f64;
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n {
                let x = -half + (i as f64 + 0.5) * d;
                let y = -half + (j as f64 + 0.5) * d;
                if x * x + y * y <= radius * radius {
                    let r2 = (x - s).powi(2) + y * y;
                    sum += (-0.5 * r2 / (sigma * sigma)).exp() * d * d;
                }
            }
        }
        sum / (std::f64::consts::TAU * sigma * sigma)
    }

    #[test]
    fn the_blurred_disc_matches_a_brute_force_sum_and_the_centre_law() {
        for (r, sigma, s) in [
            (1.0, 0.5, 0.0),
            (1.0, 0.5, 0.9),
            (2.0, 0.4, 2.3),
            (0.6, 0.5, 0.3),
        ] {
            let fast = blurred_disc(r, sigma, s);
            let slow = brute(r, sigma, s);
            assert!(
                (fast - slow).abs() < 2e-3,
                "{r} {sigma} {s}: {fast} vs {slow}"
            );
        }
        // At the centre: 1 − exp(−R²/2σ²).
        let centre = blurred_disc(1.3, 0.7, 0.0);
        assert!((centre - (1.0 - (-0.5 * (1.3f64 / 0.7).powi(2)).exp())).abs() < 1e-4);
    }

    #[test]
    fn the_half_maximum_radius_follows_the_curvature_law_for_wide_vessels() {
        for ratio in [6.0, 10.0, 20.0] {
            let r = half_maximum_radius(ratio, 1.0);
            let law = ratio - 1.0 / (2.0 * ratio);
            assert!((r - law).abs() < 0.02 / ratio, "{ratio}: {r} vs {law}");
            assert!(r < ratio);
        }
    }

    #[test]
    fn the_correction_inverts_the_blur() {
        let c = BlurCorrection::new();
        for sigma in [0.2e-3, 0.4e-3, 0.8e-3] {
            for radius in [1.0e-3, 1.5e-3, 2.5e-3, 4.0e-3, 12.0e-3] {
                let measured = half_maximum_radius(radius, sigma);
                let back = c.true_radius(measured, sigma);
                assert!(
                    (back - radius).abs() < 2e-3 * radius,
                    "R {radius} σ {sigma}: measured {measured} → {back}"
                );
            }
        }
        assert_eq!(c.true_radius(1e-3, 0.0), 1e-3);
    }

    #[test]
    fn the_edge_width_comes_back_from_the_fall_across_the_wall() {
        for sigma in [0.2, 0.3, 0.5, 1.0, 2.0] {
            let w = 0.5;
            let fall = libm::erf(w / (sigma * std::f64::consts::SQRT_2));
            let back = edge_sigma(fall, w).unwrap();
            assert!((back - sigma).abs() < 1e-6 * sigma, "{sigma}: {back}");
        }
        assert_eq!(edge_sigma(1.0, 0.5), None);
        assert_eq!(edge_sigma(0.0, 0.5), None);
    }
}
