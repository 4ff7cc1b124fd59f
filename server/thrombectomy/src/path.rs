//! The way back: from the clot's site to the receiving catheter's tip, as the clot travels
//! it (distance travelled, vessel radius, turning accumulated).

use crate::error::{Result, ThrombectomyError};
use nalgebra::Point3;

/// One sample of the way back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathSample {
    /// Distance travelled from the clot's site (m).
    pub travel_m: f64,
    /// Vessel radius there (m).
    pub radius_m: f64,
    /// Total turning of the centreline from the site to here (rad).
    pub turning_rad: f64,
}

/// The way from the clot's site back to the receiving catheter.
#[derive(Debug, Clone, PartialEq)]
pub struct RetrievalPath {
    samples: Vec<PathSample>,
}

impl RetrievalPath {
    /// A straight vessel of `length_m` and constant `radius_m` (m).
    pub fn straight(length_m: f64, radius_m: f64) -> Self {
        Self {
            samples: vec![
                PathSample {
                    travel_m: 0.0,
                    radius_m,
                    turning_rad: 0.0,
                },
                PathSample {
                    travel_m: length_m,
                    radius_m,
                    turning_rad: 0.0,
                },
            ],
        }
    }

    /// The way along a centreline, `points` from the clot's site back to the catheter tip
    /// (m) with the vessel's radius at each (m); turning is the sum of the angles between
    /// successive segments.
    pub fn from_centerline(points: &[Point3<f64>], radii: &[f64]) -> Result<Self> {
        if points.len() < 2 || points.len() != radii.len() {
            return Err(ThrombectomyError::InvalidParameter {
                name: "retrieval path points".into(),
                value: points.len() as f64,
                requirement: "at least 2, one radius each",
            });
        }
        let mut samples = Vec::with_capacity(points.len());
        let (mut travel, mut turning) = (0.0, 0.0);
        for i in 0..points.len() {
            if i > 0 {
                travel += (points[i] - points[i - 1]).norm();
            }
            if i > 0 && i + 1 < points.len() {
                let a = points[i] - points[i - 1];
                let b = points[i + 1] - points[i];
                if a.norm() > 0.0 && b.norm() > 0.0 {
                    turning += a.angle(&b);
                }
            }
            samples.push(PathSample {
                travel_m: travel,
                radius_m: radii[i],
                turning_rad: turning,
            });
        }
        Ok(Self { samples })
    }

    /// Its length (m).
    pub fn length_m(&self) -> f64 {
        self.samples.last().map_or(0.0, |s| s.travel_m)
    }

    /// Total turning (rad).
    pub fn turning_rad(&self) -> f64 {
        self.samples.last().map_or(0.0, |s| s.turning_rad)
    }

    /// Radius and turning after `travel_m` (m), linear between samples, held at the ends.
    pub fn at(&self, travel_m: f64) -> (f64, f64) {
        let s = &self.samples;
        let i = s.partition_point(|p| p.travel_m <= travel_m);
        if i == 0 {
            return (s[0].radius_m, s[0].turning_rad);
        }
        if i >= s.len() {
            let last = s[s.len() - 1];
            return (last.radius_m, last.turning_rad);
        }
        let (a, b) = (s[i - 1], s[i]);
        let t = (travel_m - a.travel_m) / (b.travel_m - a.travel_m).max(1e-15);
        (
            a.radius_m + t * (b.radius_m - a.radius_m),
            a.turning_rad + t * (b.turning_rad - a.turning_rad),
        )
    }

    /// The samples.
    pub fn samples(&self) -> &[PathSample] {
        &self.samples
    }
}
