//! The vessel wall as the device sees it: a probe that tells, for a point on the device's
//! centerline, how far it is from the wall and which way the wall pushes. Implemented for the
//! anatomy's lumen surfaces and for analytic walls (a capped tube) that tests use as exact
//! references.

use std::sync::Arc;

use cathlab_anatomy::Lumen;
use cathlab_anatomy::lumen::Proximity;
use nalgebra::{Point3, Vector3};

use crate::contact::perpendicular;

/// What a probe sees at a point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallProbe {
    /// Distance from the point to the wall (m): positive inside the lumen, negative outside.
    pub clearance_m: f64,
    /// Unit normal of the wall at the closest point, pointing into the lumen (the direction the
    /// wall pushes the device).
    pub normal: Vector3<f64>,
}

/// A vessel wall.
pub trait Wall {
    /// The probe at `point` (m) if the wall is within `search_m` of it or the point is outside
    /// the lumen; `None` when the point is inside and farther than `search_m` from the wall.
    fn probe(&self, point: &Vector3<f64>, search_m: f64) -> Option<WallProbe>;
}

impl<T: Wall + ?Sized> Wall for &T {
    fn probe(&self, point: &Vector3<f64>, search_m: f64) -> Option<WallProbe> {
        (**self).probe(point, search_m)
    }
}

impl<T: Wall + ?Sized> Wall for Arc<T> {
    fn probe(&self, point: &Vector3<f64>, search_m: f64) -> Option<WallProbe> {
        (**self).probe(point, search_m)
    }
}

/// No wall at all: free space, for tests and free-standing devices.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FreeSpace;

impl Wall for FreeSpace {
    fn probe(&self, _point: &Vector3<f64>, _search_m: f64) -> Option<WallProbe> {
        None
    }
}

impl Wall for Lumen {
    fn probe(&self, point: &Vector3<f64>, search_m: f64) -> Option<WallProbe> {
        let p = Point3::from(*point);
        let query = match self.proximity(&p, search_m) {
            Proximity::Near(q) => q,
            Proximity::Far { inside: true } => return None,
            Proximity::Far { inside: false } => self.query(&p),
        };
        Some(WallProbe {
            clearance_m: -query.signed_distance,
            normal: contact_normal(point, &query),
        })
    }
}

/// Below this distance (m) from the wall the direction to the closest wall point is round-off,
/// and the surface's own normal stands in for it.
const GRADIENT_MIN_DISTANCE_M: f64 = 1e-9;

/// The surface's interpolated normal is the contact's normal while it is within this cosine
/// (about 26°) of the wall distance's gradient.
const SMOOTH_NORMAL_MIN_COS: f64 = 0.9;

/// The contact's normal at `point` (unit, into the lumen). The surface's normal interpolated
/// from its vertices varies smoothly over the facets, as the vessel it stands for does, and
/// is taken where it is within about 26° of the direction in which the clearance grows
/// fastest (from the closest wall point to an inside point, from an outside point to the
/// closest wall point); elsewhere that direction is, so that the contact's plane is the
/// distance's own linearization. Where a coarse surface bends sharply (the carotid siphon's
/// genu) the interpolated normal was up to 120° from it: a point pushed out along it went
/// deeper, and a wire folded there ended 0.2 mm past the wall after every detection round.
fn contact_normal(point: &Vector3<f64>, query: &cathlab_anatomy::WallQuery) -> Vector3<f64> {
    let smooth = -query.outward_normal;
    let away = point - query.closest_wall_point.coords;
    let distance = away.norm();
    if distance <= GRADIENT_MIN_DISTANCE_M {
        return smooth;
    }
    let gradient = away * (-query.signed_distance.signum() / distance);
    if smooth.dot(&gradient) >= SMOOTH_NORMAL_MIN_COS {
        smooth
    } else {
        gradient
    }
}

/// A straight tube of `radius` from `start` along unit `axis` for `length`, closed by a flat
/// cap at the far end (a dead end) and open at the start. Exact distances and normals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CappedTube {
    /// Centre of the open end (m).
    pub start: Vector3<f64>,
    /// Unit axis direction.
    pub axis: Vector3<f64>,
    /// Length to the cap (m).
    pub length_m: f64,
    /// Lumen radius (m).
    pub radius_m: f64,
}

impl Wall for CappedTube {
    fn probe(&self, point: &Vector3<f64>, search_m: f64) -> Option<WallProbe> {
        let d = point - self.start;
        let along = d.dot(&self.axis);
        let radial = d - self.axis * along;
        let rho = radial.norm();
        let radial_unit = if rho > 1e-300 {
            radial / rho
        } else {
            // On the axis: any radial direction, picked deterministically.
            perpendicular(&self.axis)
        };
        let to_side = self.radius_m - rho;
        let to_cap = self.length_m - along;
        let probe = if to_cap < to_side {
            WallProbe {
                clearance_m: to_cap,
                normal: -self.axis,
            }
        } else {
            WallProbe {
                clearance_m: to_side,
                normal: -radial_unit,
            }
        };
        (probe.clearance_m < 0.0 || probe.clearance_m <= search_m).then_some(probe)
    }
}

/// A closed ring of tube: the torus with core circle of `major_radius_m` about `axis` through
/// `center`, and lumen radius `minor_radius_m`. A device pushed along it hugs the outer wall
/// with contacts along its whole length. Exact distances and normals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RingTube {
    /// Centre of the core circle (m).
    pub center: Vector3<f64>,
    /// Unit axis of the ring.
    pub axis: Vector3<f64>,
    /// Radius of the core circle (m).
    pub major_radius_m: f64,
    /// Lumen radius (m).
    pub minor_radius_m: f64,
}

impl Wall for RingTube {
    fn probe(&self, point: &Vector3<f64>, search_m: f64) -> Option<WallProbe> {
        let d = point - self.center;
        let height = d.dot(&self.axis);
        let in_plane = d - self.axis * height;
        let radial = in_plane
            .try_normalize(1e-300)
            .unwrap_or_else(|| perpendicular(&self.axis));
        let core = self.center + radial * self.major_radius_m;
        let offset = point - core;
        let distance = offset.norm();
        let outward = offset.try_normalize(1e-300).unwrap_or(radial);
        let clearance = self.minor_radius_m - distance;
        (clearance < 0.0 || clearance <= search_m).then_some(WallProbe {
            clearance_m: clearance,
            normal: -outward,
        })
    }
}
