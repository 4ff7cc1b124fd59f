//! The implicit lumen as the wall: signed distance, closest wall point and outward normal
//! from the field of a vessel graph and its analytic gradient, for anatomies whose graph is
//! the lumen (the generated phantoms). Built in milliseconds and a few megabytes where a
//! triangulated surface and its query grid take seconds and gigabytes.

use nalgebra::{Point3, Vector3};

use crate::error::Result;
use crate::graph::VesselGraph;
use crate::implicit::LumenField;
use crate::lumen::{Proximity, WallQuery};

/// [`WallQuery::triangle`] of a query answered by an implicit wall (there are no triangles).
pub const NO_TRIANGLE: u32 = u32::MAX;

/// Smallest gradient norm the distance is divided by: on the ridge inside a junction where two
/// vessels' gradients cancel, the distance is at most four times the field's value rather
/// than the value divided by nearly zero.
const MIN_GRADIENT_NORM: f64 = 0.25;

/// Past this distance from the wall (m), a query takes a second Newton step from where the
/// first landed.
const PROJECTED_BEYOND_M: f64 = 0.05e-3;

/// How an implicit wall is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldWallSettings {
    /// Width of the smooth union where branches meet, as a fraction of the smaller radius
    /// (that of [`crate::surface::SurfaceSettings::blend_fraction`], so that the wall is the
    /// surface the phantom's meshes are made from).
    pub blend_fraction: f64,
    /// How far outside the walls the field's values are exact (m); beyond, queries fall back
    /// to the nearest vessel over all segments.
    pub margin_m: f64,
    /// Edge of the query index's cells (m).
    pub cell_m: f64,
}

impl Default for FieldWallSettings {
    fn default() -> Self {
        Self {
            blend_fraction: 0.5,
            margin_m: 3e-3,
            cell_m: 1.5e-3,
        }
    }
}

/// A vessel graph's implicit lumen prepared for wall queries.
#[derive(Debug, Clone)]
pub struct FieldWall {
    field: LumenField,
}

impl FieldWall {
    /// The wall of `graph`'s lumen.
    pub fn new(graph: &VesselGraph, settings: &FieldWallSettings) -> Result<Self> {
        let field = LumenField::new(graph, settings.blend_fraction, settings.margin_m)?
            .with_fine_index(settings.cell_m)?;
        Ok(Self { field })
    }

    /// The field the wall is the zero level of.
    pub fn field(&self) -> &LumenField {
        &self.field
    }

    /// Heap bytes held.
    pub fn memory_bytes(&self) -> usize {
        self.field.memory_bytes()
    }

    /// The wall query at `point`: the distance is the field's value over its gradient's norm
    /// (a Newton step to the zero level: exact on a straight tube, to second order in the
    /// distance elsewhere), the normal the gradient's direction, the closest point one such
    /// step away. Beyond the field's far value, the nearest vessel over all segments.
    pub fn query(&self, point: &Point3<f64>) -> WallQuery {
        let (value, gradient) = self.field.value_gradient(point);
        self.answer(point, value, gradient)
    }

    /// The wall query if the wall is within `max_distance` (m) of `point`, else which side
    /// of the wall the point is on.
    pub fn proximity(&self, point: &Point3<f64>, max_distance: f64) -> Proximity {
        let (value, gradient) = self.field.value_gradient(point);
        if value >= self.field.far_value() && max_distance < self.field.far_value() {
            return Proximity::Far { inside: false };
        }
        let q = self.answer(point, value, gradient);
        if q.signed_distance.abs() <= max_distance {
            Proximity::Near(q)
        } else {
            Proximity::Far { inside: q.inside() }
        }
    }

    fn answer(&self, point: &Point3<f64>, value: f64, gradient: Vector3<f64>) -> WallQuery {
        if value >= self.field.far_value() {
            let (value, gradient) = self.field.nearest_wall(point);
            return Self::newton(point, value, gradient);
        }
        let first = Self::newton(point, value, gradient);
        if value.abs() <= PROJECTED_BEYOND_M {
            return first;
        }
        // Farther from a curved wall, one Newton step lands beside the wall: a second from
        // there finds it, and the normal is the one there.
        let (v, g) = self.field.value_gradient(&first.closest_wall_point);
        if v >= self.field.far_value() {
            return first;
        }
        let foot = Self::newton(&first.closest_wall_point, v, g);
        let offset = point - foot.closest_wall_point;
        let distance = offset.norm();
        WallQuery {
            signed_distance: if value < 0.0 { -distance } else { distance },
            closest_wall_point: foot.closest_wall_point,
            outward_normal: foot.outward_normal,
            triangle: NO_TRIANGLE,
        }
    }

    /// One Newton step from `point` towards the field's zero level.
    fn newton(point: &Point3<f64>, value: f64, gradient: Vector3<f64>) -> WallQuery {
        let norm = gradient.norm();
        // On a vessel's axis the gradient vanishes: any direction across it is as near.
        let normal = if norm > 1e-12 {
            gradient / norm
        } else {
            Vector3::x()
        };
        let distance = value / norm.max(MIN_GRADIENT_NORM);
        WallQuery {
            signed_distance: distance,
            closest_wall_point: point - normal * distance,
            outward_normal: normal,
            triangle: NO_TRIANGLE,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Lumen;
    use crate::lumen::GridSettings;
    use crate::phantom::{straight_tube, y_bifurcation};
    use crate::surface::{SurfaceSettings, lumen_surface};
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    /// Inside a straight tube, away from its capped ends, the query is the tube's own: the
    /// distance to the axis less the radius, the normal straight out from the axis.
    #[test]
    fn a_straight_tube_answers_the_analytic_distance_and_normal() {
        let (radius, length) = (2e-3, 40e-3);
        let graph = straight_tube(radius, length).unwrap();
        let wall = FieldWall::new(&graph, &FieldWallSettings::default()).unwrap();
        let b = &graph.branches[0];
        let (a, axis) = (
            b.points[0],
            (b.points[b.points.len() - 1] - b.points[0]).normalize(),
        );
        let mut rng = StdRng::seed_from_u64(3);
        for _ in 0..2000 {
            let along = rng.random_range(8e-3..length - 8e-3);
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            let across = axis.cross(&Vector3::x()).normalize();
            let other = axis.cross(&across);
            let out = across * angle.cos() + other * angle.sin();
            let rho = rng.random_range(0.2e-3..3.5e-3);
            let p = a + axis * along + out * rho;
            let q = wall.query(&p);
            assert!(
                (q.signed_distance - (rho - radius)).abs() < 1e-12,
                "{q:?} at rho {rho}"
            );
            assert!((q.outward_normal - out).norm() < 1e-9);
            assert!(((q.closest_wall_point - a) - axis * along - out * radius).norm() < 1e-12);
            match wall.proximity(&p, 0.5e-3) {
                Proximity::Near(n) => assert!((rho - radius).abs() <= 0.5e-3 && n == q),
                Proximity::Far { inside } => {
                    assert!((rho - radius).abs() > 0.5e-3 && inside == (rho < radius))
                }
            }
        }
    }

    /// Near the walls of a bifurcation (away from its capped ends) the implicit wall answers
    /// what the exact queries of its finely triangulated zero level answer: within 1 mm of
    /// the wall, distances within 0.02 mm and normals within 4° at the 99th percentile (the
    /// largest errors lie across the crotch, where the nearest wall switches branch); within
    /// 0.3 mm, within 0.02 mm and 5° everywhere. A point far outside (a device through the wall) is
    /// still measured, from the nearest vessel.
    #[test]
    fn a_bifurcations_wall_is_its_triangulated_surfaces() {
        let graph = y_bifurcation(4e-3, 3e-3, 30e-3, 25e-3, 0.5).unwrap();
        let wall = FieldWall::new(&graph, &FieldWallSettings::default()).unwrap();
        let surface = SurfaceSettings {
            cells_per_radius: 6.0,
            ..SurfaceSettings::default()
        };
        let mesh = Lumen::with_grid_settings(
            lumen_surface(&graph, &surface).unwrap(),
            "y",
            GridSettings::default(),
        )
        .unwrap();
        let mut rng = StdRng::seed_from_u64(4);
        let (mut distance, mut normal) = (Vec::new(), Vec::new());
        // Worst distance error (m) and normal error (°) within 0.3 mm of the wall.
        let mut near = (0.0f64, 0.0f64);
        while distance.len() < 5000 {
            let b = &graph.branches[rng.random_range(0..graph.branches.len())];
            // Not at the capped ends: there the field is the larger of the tube's and the
            // cap's values, not a distance, outside the rim.
            let s = rng.random_range(0.0..b.length());
            let direction = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let p = b.point_at(s) + direction * (b.radius_at(s) * rng.random_range(0.5..1.4));
            let ends = graph.branches.iter().map(|b| {
                let (first, last) = (b.points[0], b.points[b.points.len() - 1]);
                if b.name == "parent" { first } else { last }
            });
            if ends.into_iter().any(|e| (p - e).norm() < 6e-3) {
                continue;
            }
            let exact = mesh.query(&p);
            if exact.signed_distance.abs() > 1e-3 {
                continue;
            }
            let q = wall.query(&p);
            distance.push((q.signed_distance - exact.signed_distance).abs());
            normal.push(q.outward_normal.angle(&exact.outward_normal).to_degrees());
            if exact.signed_distance.abs() < 0.3e-3 {
                near.0 = near
                    .0
                    .max((q.signed_distance - exact.signed_distance).abs());
                near.1 = near
                    .1
                    .max(q.outward_normal.angle(&exact.outward_normal).to_degrees());
            }
        }
        distance.sort_by(f64::total_cmp);
        normal.sort_by(f64::total_cmp);
        let at = |v: &[f64], f: f64| v[((v.len() - 1) as f64 * f) as usize];
        println!(
            "within 1 mm: distance error p50 {:.4} p99 {:.4} max {:.4} mm, normal p50 {:.2} \
             p99 {:.2} max {:.1}°; within 0.3 mm: {:.4} mm, {:.1}° at most",
            at(&distance, 0.5) * 1e3,
            at(&distance, 0.99) * 1e3,
            at(&distance, 1.0) * 1e3,
            at(&normal, 0.5),
            at(&normal, 0.99),
            at(&normal, 1.0),
            near.0 * 1e3,
            near.1
        );
        assert!(at(&distance, 0.99) < 0.02e-3);
        assert!(at(&normal, 0.99) < 4.0);
        assert!(near.0 < 0.02e-3 && near.1 < 5.0, "{near:?}");
        let far = graph.branches[0].points[0] + Vector3::new(0.0, 0.0, 0.0) + Vector3::x() * 0.02;
        let q = wall.query(&far);
        let exact = mesh.query(&far);
        assert!(q.signed_distance > 0.01, "{q:?}");
        assert!(
            (q.signed_distance - exact.signed_distance).abs() < 1e-3,
            "{q:?} {exact:?}"
        );
    }
}
