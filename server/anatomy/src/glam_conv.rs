//! The one place where nalgebra types (used throughout cathlab) meet parry's glam types.

use nalgebra::{Point3, Vector3};
use parry3d_f64::math::Vector as GlamVector;

/// nalgebra point → glam vector.
#[inline]
pub fn to_glam(p: &Point3<f64>) -> GlamVector {
    GlamVector::new(p.x, p.y, p.z)
}

/// glam vector → nalgebra point.
#[inline]
pub fn to_point(v: GlamVector) -> Point3<f64> {
    Point3::new(v.x, v.y, v.z)
}

/// glam vector → nalgebra vector.
#[inline]
pub fn to_vector(v: GlamVector) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}
