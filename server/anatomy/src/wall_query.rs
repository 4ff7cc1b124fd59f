//! What a wall query answers, whichever wall answers it (a triangulated surface or a graph's
//! implicit lumen): the signed distance, the closest wall point and the outward normal, or
//! only which side a point is on when the wall is far.

use nalgebra::{Point3, Vector3};

/// The answer to a wall query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallQuery {
    /// Signed distance to the wall (m): negative inside the lumen, positive outside.
    pub signed_distance: f64,
    /// Closest point on the wall (m).
    pub closest_wall_point: Point3<f64>,
    /// Unit normal at the closest point, pointing out of the lumen (on a surface interpolated
    /// from vertex normals, so it varies smoothly over the facets; on an implicit wall the
    /// field's gradient).
    pub outward_normal: Vector3<f64>,
    /// Index of the triangle holding the closest point
    /// ([`crate::field_wall::NO_TRIANGLE`] on an implicit wall).
    pub triangle: u32,
}

impl WallQuery {
    /// True when the query point is inside the lumen.
    pub fn inside(&self) -> bool {
        self.signed_distance < 0.0
    }
}

/// Whether the wall is near a point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Proximity {
    /// The wall is within the asked distance: the full answer.
    Near(WallQuery),
    /// The wall is farther than the asked distance; `inside` says on which side the point is.
    Far {
        /// True inside the lumen.
        inside: bool,
    },
}
