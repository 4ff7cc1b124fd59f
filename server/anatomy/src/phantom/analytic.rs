//! Analytic phantoms: a straight tube, a torus segment and a symmetric Y bifurcation, each a
//! vessel graph whose lumen has a closed-form distance away from its ends and junction.

use nalgebra::{Point3, Vector3};

use crate::error::{Result, require_positive, require_range};
use crate::graph::{BranchSpec, Side, VesselGraph, VesselKind};

fn spec(name: &str, points: Vec<Point3<f64>>, radius: f64) -> BranchSpec {
    let radii = vec![radius; points.len()];
    BranchSpec {
        name: name.to_owned(),
        kind: VesselKind::Other,
        side: Side::Midline,
        points,
        radii,
    }
}

/// A straight tube of `radius` (m) along +z from the origin, `length` (m) long, sampled every
/// `radius`; landmark `access` at the origin end.
pub fn straight_tube(radius: f64, length: f64) -> Result<VesselGraph> {
    require_positive("radius", radius)?;
    require_positive("length", length)?;
    let n = ((length / radius).ceil() as usize).max(1);
    let points = (0..=n)
        .map(|i| Point3::new(0.0, 0.0, length * i as f64 / n as f64))
        .collect();
    let mut g = VesselGraph::new();
    g.add_branch(spec("tube", points, radius))?;
    g.landmarks.insert("access".into(), Point3::origin());
    Ok(g)
}

/// A tube of `radius` (m) bent along a circle of `major_radius` (m) in the xy-plane, centred
/// at the origin, from angle 0 through `angle` (rad), sampled every 0.5° at most.
pub fn torus_segment(major_radius: f64, radius: f64, angle: f64) -> Result<VesselGraph> {
    require_positive("major_radius", major_radius)?;
    require_positive("radius", radius)?;
    require_range(
        "angle",
        angle,
        1e-3,
        1.9 * std::f64::consts::PI,
        "between 0.001 and 1.9π rad",
    )?;
    if radius >= major_radius {
        return Err(crate::error::AnatomyError::InvalidParameter {
            name: "radius",
            value: radius,
            requirement: "smaller than major_radius",
        });
    }
    let n = ((angle / 0.5f64.to_radians()).ceil() as usize).max(2);
    let points = (0..=n)
        .map(|i| {
            let t = angle * i as f64 / n as f64;
            Point3::new(major_radius * t.cos(), major_radius * t.sin(), 0.0)
        })
        .collect();
    let mut g = VesselGraph::new();
    g.add_branch(spec("torus", points, radius))?;
    g.landmarks
        .insert("access".into(), Point3::new(major_radius, 0.0, 0.0));
    Ok(g)
}

/// A parent tube along +z ending at the origin, splitting into `left` (towards −x... +x is the
/// patient's left) and `right` children at ±`half_angle` (rad) from the z axis in the xz-plane.
/// Lengths and radii in metres; landmark `access` at the parent's open end.
pub fn y_bifurcation(
    parent_radius: f64,
    child_radius: f64,
    parent_length: f64,
    child_length: f64,
    half_angle: f64,
) -> Result<VesselGraph> {
    require_positive("parent_radius", parent_radius)?;
    require_positive("child_radius", child_radius)?;
    require_positive("parent_length", parent_length)?;
    require_positive("child_length", child_length)?;
    require_range(
        "half_angle",
        half_angle,
        0.1,
        1.4,
        "between 0.1 and 1.4 rad",
    )?;
    let line = |from: Point3<f64>, dir: Vector3<f64>, length: f64, step: f64| -> Vec<Point3<f64>> {
        let n = ((length / step).ceil() as usize).max(1);
        (0..=n)
            .map(|i| from + dir * (length * i as f64 / n as f64))
            .collect()
    };
    let mut g = VesselGraph::new();
    let start = Point3::new(0.0, 0.0, -parent_length);
    g.add_branch(spec(
        "parent",
        line(start, Vector3::z(), parent_length, parent_radius),
        parent_radius,
    ))?;
    for (name, side, sign) in [("left", Side::Left, 1.0), ("right", Side::Right, -1.0)] {
        let dir = Vector3::new(sign * half_angle.sin(), 0.0, half_angle.cos());
        let mut s = spec(
            name,
            line(Point3::origin(), dir, child_length, child_radius),
            child_radius,
        );
        s.side = side;
        g.add_branch(s)?;
    }
    g.landmarks.insert("access".into(), start);
    Ok(g)
}
