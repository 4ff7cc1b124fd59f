//! Frame and rest-arc geometry of a beam: rotation vectors and minimal rotations accurate
//! near the identity, the chord-aligned element frame, the exact helix of a constant rest
//! curvature, and the Hermite curve through two nodes.

use nalgebra::{UnitQuaternion, Vector3};

/// Unit vector of the material x axis (along the device).
pub(super) fn axis_x() -> Vector3<f64> {
    Vector3::x()
}

/// Rotation vector (axis × angle, rad) of a unit quaternion, accurate near the identity.
///
/// nalgebra's `scaled_axis` computes the angle as 2·acos(w), which loses half the digits
/// near w = 1 (an error of ~1e-8 rad on an exact rest state); 2·atan2(|v|, w) does not.
pub fn rotation_vector(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (w, v) = (q.scalar(), q.vector());
    let (w, v) = if w < 0.0 {
        (-w, -v)
    } else {
        (w, v.into_owned())
    };
    let sin_half = v.norm();
    if sin_half < 1e-300 {
        return Vector3::zeros();
    }
    let angle = 2.0 * sin_half.atan2(w);
    v * (angle / sin_half)
}

/// Element frame: mid-rotation of the two corrected node frames, turned so x lies on the chord.
pub(super) fn element_frame(
    s1: &UnitQuaternion<f64>,
    s2: &UnitQuaternion<f64>,
    chord: &Vector3<f64>,
) -> UnitQuaternion<f64> {
    let half = UnitQuaternion::from_scaled_axis(rotation_vector(&(s1.inverse() * s2)) * 0.5);
    let mid = s1 * half;
    let tangent = mid * axis_x();
    minimal_rotation(&tangent, &chord.normalize()) * mid
}

/// The smallest rotation taking unit vector `a` to unit vector `b`: the normalised
/// quaternion (1 + a·b, a×b). Accurate for nearly parallel vectors, unlike nalgebra's
/// `rotation_between`, whose acos of the dot product is only good to ~1e-8 rad there.
/// Anti-parallel inputs (never met by an element frame) give the identity.
pub fn minimal_rotation(a: &Vector3<f64>, b: &Vector3<f64>) -> UnitQuaternion<f64> {
    let w = 1.0 + a.dot(b);
    if w <= 1e-12 {
        return UnitQuaternion::identity();
    }
    let v = a.cross(b);
    UnitQuaternion::new_normalize(nalgebra::Quaternion::new(w, v.x, v.y, v.z))
}

/// The point at fraction `f` ∈ [0, 1] of the smooth curve between two nodes (position m,
/// frame): the cubic Hermite interpolant of their positions and tangents, with the tangent
/// length chord / cos²(θ/4) (θ the angle between the end tangents) that puts it exactly on a
/// circular arc; the frame is the slerp of the two node frames.
pub(crate) fn hermite_point(
    (p0, q0): (&Vector3<f64>, &UnitQuaternion<f64>),
    (p1, q1): (&Vector3<f64>, &UnitQuaternion<f64>),
    f: f64,
) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let (d0, d1) = (q0 * Vector3::x(), q1 * Vector3::x());
    let scale = (p1 - p0).norm() / (0.25 * d0.angle(&d1).min(3.0)).cos().powi(2);
    let (t0, t1) = (d0 * scale, d1 * scale);
    let (f2, f3) = (f * f, f * f * f);
    let position = p0 * (2.0 * f3 - 3.0 * f2 + 1.0)
        + t0 * (f3 - 2.0 * f2 + f)
        + p1 * (-2.0 * f3 + 3.0 * f2)
        + t1 * (f3 - f2);
    (position, q0.slerp(q1, f))
}

/// Position and rotation increment along a helix of constant material curvature vector
/// `kappa` (1/m, see [`ElementSpec::curvature_per_m`](crate::beam::ElementSpec::curvature_per_m)) and arc length `length` (m), in the
/// frame at its start: the frame turns by exp(s·κ̂), and the position is
/// ∫₀ᴸ exp(s·κ̂)·x ds = (L·I + (1 − cos θ)/|κ|²·κ̂ + (L − sin θ/|κ|)/|κ|²·κ̂²)·x, θ = |κ|L.
pub(super) fn arc_increment(
    kappa: &Vector3<f64>,
    length: f64,
) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let k = kappa.norm();
    let theta = k * length;
    // Coefficients of κ̂ and κ̂², with their series near θ = 0.
    let (c1, c2) = if theta < 1e-4 {
        let t2 = theta * theta;
        (
            length * length / 2.0 * (1.0 - t2 / 12.0),
            length * length * length / 6.0 * (1.0 - t2 / 20.0),
        )
    } else {
        (
            (1.0 - theta.cos()) / (k * k),
            (length - theta.sin() / k) / (k * k),
        )
    };
    let x = Vector3::x();
    let kx = kappa.cross(&x);
    let kkx = kappa.cross(&kx);
    (
        x * length + kx * c1 + kkx * c2,
        UnitQuaternion::from_scaled_axis(kappa * length),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed-form helix increment against a fine midpoint integration of the frame ODE
    /// (planar, torsion only, and a general 3D curvature, small and large angles).
    #[test]
    fn helix_increment_matches_integrated_frame() {
        for kappa in [
            Vector3::new(0.0, 0.0, 300.0),
            Vector3::new(50.0, 0.0, 0.0),
            Vector3::new(40.0, -120.0, 250.0),
            Vector3::new(1e-5, 2e-5, -3e-5),
        ] {
            let length = 0.02;
            let n = 20_000;
            let ds = length / n as f64;
            let mut p = Vector3::zeros();
            for i in 0..n {
                let q = UnitQuaternion::from_scaled_axis(kappa * ((i as f64 + 0.5) * ds));
                p += q * Vector3::x() * ds;
            }
            let (dp, dq) = arc_increment(&kappa, length);
            assert!(
                (dp - p).norm() < 1e-9 * length,
                "{kappa:?}: {dp:?} vs {p:?}"
            );
            let exact = UnitQuaternion::from_scaled_axis(kappa * length);
            assert!(dq.angle_to(&exact) < 1e-12);
        }
    }

    #[test]
    fn rotation_vector_is_accurate_near_identity() {
        // Regression: nalgebra's acos-based angle gave ~1e-8 rad for rotations of 1e-12 rad.
        for angle in [1e-15, 1e-12, 1e-9, 1e-4, 1.0, 3.0] {
            let axis = Vector3::new(1.0, -2.0, 0.5).normalize();
            let q = UnitQuaternion::from_scaled_axis(axis * angle);
            let back = rotation_vector(&q);
            assert!(
                (back - axis * angle).norm() <= 1e-15 * angle.max(1e-15) * 4.0,
                "{angle}: {back:?}"
            );
        }
    }

    #[test]
    fn minimal_rotation_is_accurate_for_nearly_parallel_vectors() {
        // Regression: nalgebra's rotation_between returned 1.5e-8 rad for vectors 1e-16 apart.
        let a = Vector3::new(0.6, 0.8, 0.0);
        for tilt in [0.0, 1e-16, 1e-12, 1e-6, 0.5] {
            let b = (a + Vector3::z() * tilt).normalize();
            let q = minimal_rotation(&a, &b);
            assert!((q * a - b).norm() < 1e-15, "{tilt}");
            assert!(
                (rotation_vector(&q).norm() - tilt.atan()).abs() < 1e-15,
                "{tilt}"
            );
        }
    }
}
