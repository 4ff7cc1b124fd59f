//! A synthesized head-and-neck CT (skull with skull base, brain, neck, cervical and thoracic
//! spine, trachea, thorax with lungs, ribs and sternum, air around) placed around a vessel
//! phantom, so that every scene has a realistic background. Simple shapes with textbook HU.

use nalgebra::{Point3, Vector3};

use crate::error::{Result, XrayError};
use crate::volume::Volume;

/// Where the body goes, in patient LPS coordinates (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyLandmarks {
    /// Centre of the circle of Willis (the head is built around it).
    pub circle_of_willis: Point3<f64>,
    /// Height (S, m) of the top of the aortic arch: the thorax starts above it.
    pub arch_top_s: f64,
    /// Lowest height (S, m) the volume must reach.
    pub bottom_s: f64,
    /// Left–right coordinate of the midline (m).
    pub midline_l: f64,
    /// Posterior coordinate of the front of the vertebral bodies (m).
    pub spine_front_p: f64,
}

impl BodyLandmarks {
    /// Landmarks from a vessel tree's centerline points (LPS): the circle of Willis at the
    /// top of the tree, the midline at the mean left–right position of its top 40 mm, the
    /// spine just behind the most posterior neck vessel (the vertebral arteries), the arch
    /// at the top of the lowest fifth of the tree.
    pub fn from_vessels(points: &[Point3<f64>]) -> Result<Self> {
        if points.len() < 2
            || points
                .iter()
                .any(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(XrayError::OutOfRange {
                what: "vessel points for the body phantom".into(),
                range: "at least 2, all finite",
                value: points.len() as f64,
            });
        }
        let top = points.iter().map(|p| p.z).fold(f64::MIN, f64::max);
        let bottom = points.iter().map(|p| p.z).fold(f64::MAX, f64::min);
        let head: Vec<&Point3<f64>> = points.iter().filter(|p| p.z > top - 0.04).collect();
        let mean = |f: &dyn Fn(&Point3<f64>) -> f64| {
            head.iter().map(|p| f(p)).sum::<f64>() / head.len() as f64
        };
        let (l, p) = (mean(&|q| q.x), mean(&|q| q.y));
        let span = top - bottom;
        let neck: Vec<&Point3<f64>> = points
            .iter()
            .filter(|q| q.z < top - 0.06 && q.z > bottom + 0.35 * span)
            .collect();
        let spine_front_p = neck.iter().map(|q| q.y).fold(p, f64::max) + 0.006;
        Ok(Self {
            circle_of_willis: Point3::new(l, p, top),
            arch_top_s: bottom + 0.3 * span,
            bottom_s: bottom,
            midline_l: l,
            spine_front_p,
        })
    }
}

/// HU of the tissues used.
mod hu {
    pub const AIR: f64 = -1000.0;
    pub const LUNG: f64 = -820.0;
    pub const FAT: f64 = -90.0;
    pub const SOFT: f64 = 40.0;
    pub const BRAIN: f64 = 35.0;
    pub const SKULL: f64 = 1300.0;
    pub const PETROUS: f64 = 1700.0;
    pub const VERTEBRA: f64 = 450.0;
    pub const CORTEX: f64 = 1100.0;
    pub const DISC: f64 = 90.0;
    pub const RIB: f64 = 800.0;
}

/// HU at a patient point of the body around `m`.
pub fn body_hu(m: &BodyLandmarks, p: &Point3<f64>) -> f64 {
    let cow = m.circle_of_willis;
    let x = p.x - m.midline_l;
    // Head: ellipsoid around the circle of Willis with a 7 mm skull and 4 mm scalp.
    let head_centre = cow + Vector3::new(0.0, 0.005, 0.02);
    let e = |q: &Point3<f64>, c: &Point3<f64>, a: [f64; 3]| {
        let d = q - c;
        ((d.x / a[0]).powi(2) + (d.y / a[1]).powi(2) + (d.z / a[2]).powi(2)).sqrt()
    };
    let head_axes = [0.072, 0.092, 0.105];
    let r_head = e(p, &head_centre, head_axes);
    if r_head <= 1.0 + 0.004 / 0.09 {
        // Skull base: petrous ridges either side of the circle of Willis.
        for side in [-1.0, 1.0] {
            let c = Point3::new(m.midline_l + side * 0.035, cow.y + 0.012, cow.z - 0.012);
            if e(p, &c, [0.022, 0.010, 0.009]) <= 1.0 {
                return hu::PETROUS;
            }
        }
        return if r_head > 1.0 {
            hu::SOFT
        } else if r_head > 1.0 - 0.007 / 0.09 {
            hu::SKULL
        } else {
            hu::BRAIN
        };
    }
    let neck_top = head_centre.z - 0.08;
    if p.z > neck_top + 0.02 {
        return hu::AIR;
    }
    // Spine: vertebral bodies (cortex, cancellous bone, discs) with posterior elements.
    let spine_p = m.spine_front_p + 0.009;
    let body_r = ((x / 0.011).powi(2) + ((p.y - spine_p) / 0.009).powi(2)).sqrt();
    let level = (p.z - cow.z).rem_euclid(0.018);
    if body_r <= 1.0 && p.z < cow.z - 0.03 {
        return if level < 0.004 {
            hu::DISC
        } else if body_r > 0.8 {
            hu::CORTEX
        } else {
            hu::VERTEBRA
        };
    }
    let arch = ((x / 0.014).powi(2) + ((p.y - spine_p - 0.022) / 0.012).powi(2)).sqrt();
    if arch <= 1.0
        && (arch > 0.55 || (x.abs() < 0.003 && p.y > spine_p + 0.028))
        && p.z < cow.z - 0.03
    {
        return hu::CORTEX;
    }
    let in_thorax = p.z < m.arch_top_s + 0.03;
    // Trachea: an air tube in front of the spine, through the neck into the chest.
    let trachea_p = m.spine_front_p - 0.022;
    if (x * x + (p.y - trachea_p).powi(2)).sqrt() < 0.008 && p.z > m.arch_top_s - 0.05 {
        return hu::AIR;
    }
    if !in_thorax {
        // Neck: an elliptic cylinder of soft tissue under a layer of fat.
        let r = ((x / 0.055).powi(2) + ((p.y - spine_p + 0.01) / 0.058).powi(2)).sqrt();
        return if r > 1.0 {
            hu::AIR
        } else if r > 0.92 {
            hu::FAT
        } else {
            hu::SOFT
        };
    }
    // Thorax: soft-tissue wall, ribs, sternum, two lungs beside the mediastinum.
    let thorax_c = spine_p - 0.06;
    let r = ((x / 0.16).powi(2) + ((p.y - thorax_c) / 0.11).powi(2)).sqrt();
    if r > 1.0 {
        return hu::AIR;
    }
    let rib_level = (p.z - m.arch_top_s).rem_euclid(0.028);
    if r > 0.86 && r < 0.92 && rib_level < 0.009 {
        return hu::RIB;
    }
    if r > 0.86 {
        return if r > 0.95 { hu::FAT } else { hu::SOFT };
    }
    if x.abs() < 0.015 && p.y < thorax_c - 0.09 {
        return hu::CORTEX;
    }
    let mediastinum = x.abs() < 0.045 + 0.02 * (1.0 - r);
    if !mediastinum && r < 0.84 {
        return hu::LUNG;
    }
    hu::SOFT
}

/// Samples the body around `landmarks` on a grid of `spacing_m`, covering the vessels
/// (±0.17 m left–right, ±0.13 m front–back of the spine, from the skull top down to the
/// lowest vessel point), with 2³ sub-samples per voxel for partial-volume edges.
pub fn head_and_neck(landmarks: &BodyLandmarks, spacing_m: f64) -> Result<Volume> {
    crate::error::require_positive(|| "phantom voxel spacing (m)".into(), spacing_m)?;
    let top = landmarks.circle_of_willis.z + 0.14;
    let bottom = landmarks.bottom_s - 0.02;
    let extent = Vector3::new(0.34, 0.26, top - bottom);
    let dims = extent.map(|e| (e / spacing_m).ceil() as usize + 1);
    if dims.iter().product::<usize>() > 512 * 512 * 512 {
        return Err(XrayError::OutOfRange {
            what: "phantom voxel count".into(),
            range: "at most 512³ (use a coarser spacing)",
            value: dims.iter().product::<usize>() as f64,
        });
    }
    let centre = Vector3::new(
        landmarks.midline_l,
        landmarks.spine_front_p - 0.03,
        0.5 * (top + bottom),
    );
    Volume::from_fn(
        [dims.x, dims.y, dims.z],
        Vector3::repeat(spacing_m),
        centre,
        2,
        |p| body_hu(landmarks, p),
    )
}
