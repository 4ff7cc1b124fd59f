//! Reference solutions for verification: the Euler elastica of a tip-loaded cantilever,
//! solved by shooting to ~1e-12, and closed-form results used by the tests.

/// Equilibrium of an inextensible, unshearable cantilever of length L clamped horizontally
/// and loaded at its tip by a dead vertical force P, for α = PL²/EI.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ElasticaTip {
    /// Vertical tip deflection v/L (dimensionless, positive along the load).
    pub deflection: f64,
    /// Horizontal shortening u/L = 1 − x_tip/L.
    pub shortening: f64,
    /// Tip rotation (rad).
    pub tip_angle_rad: f64,
}

/// Integrates θ'' = −α cos θ on s ∈ [0, 1] from θ(0)=0, θ'(0)=m with `steps` RK4 steps;
/// returns (θ(1), θ'(1), x(1), y(1)) where y is measured along the load.
fn shoot(alpha: f64, m: f64, steps: usize) -> (f64, f64, f64, f64) {
    // State: θ, θ', x, y.
    let f = |s: [f64; 4]| [s[1], -alpha * s[0].cos(), s[0].cos(), s[0].sin()];
    let h = 1.0 / steps as f64;
    let mut y = [0.0, m, 0.0, 0.0];
    let add = |a: [f64; 4], b: [f64; 4], k: f64| {
        [
            a[0] + k * b[0],
            a[1] + k * b[1],
            a[2] + k * b[2],
            a[3] + k * b[3],
        ]
    };
    for _ in 0..steps {
        let k1 = f(y);
        let k2 = f(add(y, k1, h / 2.0));
        let k3 = f(add(y, k2, h / 2.0));
        let k4 = f(add(y, k3, h));
        for i in 0..4 {
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
    }
    (y[0], y[1], y[2], y[3])
}

/// Solves the tip-loaded elastica for α = PL²/EI ≥ 0 (the fundamental branch) with
/// `steps` RK4 steps; bisection on the root curvature θ'(0) ∈ (0, α).
pub fn tip_loaded_cantilever_with(alpha: f64, steps: usize) -> ElasticaTip {
    if alpha <= 0.0 {
        return ElasticaTip {
            deflection: 0.0,
            shortening: 0.0,
            tip_angle_rad: 0.0,
        };
    }
    let (mut lo, mut hi) = (0.0, alpha);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid == lo || mid == hi {
            break;
        }
        if shoot(alpha, mid, steps).1 > 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let (theta, _, x, y) = shoot(alpha, 0.5 * (lo + hi), steps);
    ElasticaTip {
        deflection: y,
        shortening: 1.0 - x,
        tip_angle_rad: theta,
    }
}

/// [`tip_loaded_cantilever_with`] at 20,000 RK4 steps (error below 1e-12).
pub fn tip_loaded_cantilever(alpha: f64) -> ElasticaTip {
    tip_loaded_cantilever_with(alpha, 20_000)
}

/// Euler buckling load of a clamped–free column, π²EI/(4L²) (N).
pub fn clamped_free_buckling_load(bending_stiffness_nm2: f64, length_m: f64) -> f64 {
    std::f64::consts::PI.powi(2) * bending_stiffness_nm2 / (4.0 * length_m * length_m)
}

/// Linear cantilever tip deflection under a tip load with shear, PL³/3EI + PL/κGA (m).
pub fn timoshenko_tip_deflection(
    load_n: f64,
    length_m: f64,
    bending_stiffness_nm2: f64,
    shear_stiffness_n: f64,
) -> f64 {
    load_n * length_m.powi(3) / (3.0 * bending_stiffness_nm2)
        + load_n * length_m / shear_stiffness_n
}
