//! Seeded, parameterised neurovascular phantom from the aortic root to the circle of Willis:
//! arch types I–III with their great vessels, carotid bifurcations, the ICA siphon,
//! vertebrals joining into the basilar, and the circle of Willis (ACA, MCA, PCA, anterior and
//! posterior communicating arteries). Radii follow NOTES.md; a tortuosity knob bends every
//! vessel smoothly. Coordinates LPS (m), the arch apex near the origin.

use nalgebra::{Point3, Vector3};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

use crate::error::{Result, require_range};
use crate::graph::{BranchSpec, Side, VesselGraph, VesselKind};

/// Aortic arch type: how far the brachiocephalic origin lies below the top of the arch, in
/// common-carotid diameters (I: < 1, II: 1–2, III: > 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum ArchType {
    /// Origin within one CCA diameter of the apex.
    I,
    /// One to two diameters below.
    II,
    /// More than two diameters below (hardest to catheterise).
    III,
}

/// What varies between phantoms.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NeuroPhantomParams {
    /// Random seed: the same seed gives the same phantom.
    pub seed: u64,
    /// Arch type.
    pub arch: ArchType,
    /// 0 (straight vessels) to 1 (markedly tortuous).
    pub tortuosity: f64,
    /// Scale of random variation of positions and radii, 0 to 1 (1: ±10 % radii, ±4 mm).
    pub variability: f64,
}

impl Default for NeuroPhantomParams {
    fn default() -> Self {
        Self {
            seed: 1,
            arch: ArchType::I,
            tortuosity: 0.3,
            variability: 0.5,
        }
    }
}

/// Common carotid diameter used to place the arch branches (m).
const CCA_DIAMETER: f64 = 7e-3;

fn mm(x: f64, y: f64, z: f64) -> Point3<f64> {
    Point3::new(x, y, z) * 1e-3
}

/// Catmull–Rom spline through `controls`, sampled about every `step` metres.
fn spline(controls: &[Point3<f64>], step: f64) -> Vec<Point3<f64>> {
    let n = controls.len();
    let mut out = vec![controls[0]];
    for i in 0..n - 1 {
        let p0 = if i == 0 { controls[0] } else { controls[i - 1] };
        let (p1, p2) = (controls[i], controls[i + 1]);
        let p3 = if i + 2 < n {
            controls[i + 2]
        } else {
            controls[n - 1]
        };
        let count = (((p2 - p1).norm() / step).ceil() as usize).max(1);
        for k in 1..=count {
            let t = k as f64 / count as f64;
            let (t2, t3) = (t * t, t * t * t);
            let v = (p1.coords * 2.0
                + (p2 - p0) * t
                + (p0.coords * 2.0 - p1.coords * 5.0 + p2.coords * 4.0 - p3.coords) * t2
                + (p1.coords * 3.0 - p0.coords - p2.coords * 3.0 + p3.coords) * t3)
                * 0.5;
            out.push(Point3::from(v));
        }
    }
    out
}

struct Builder {
    rng: StdRng,
    params: NeuroPhantomParams,
    graph: VesselGraph,
}

impl Builder {
    fn jitter(&mut self, scale_m: f64) -> Vector3<f64> {
        let v = self.params.variability * scale_m;
        Vector3::new(
            self.rng.random_range(-1.0..=1.0),
            self.rng.random_range(-1.0..=1.0),
            self.rng.random_range(-1.0..=1.0),
        ) * v
    }

    fn radius(&mut self, r_mm: f64) -> f64 {
        r_mm * 1e-3 * (1.0 + 0.1 * self.params.variability * self.rng.random_range(-1.0..=1.0))
    }

    /// Adds smooth lateral waves (zero at both ends) scaled by the tortuosity.
    fn tortuous(&mut self, points: Vec<Point3<f64>>) -> Vec<Point3<f64>> {
        let n = points.len();
        if n < 3 || self.params.tortuosity <= 0.0 {
            return points;
        }
        let length: f64 = points.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        let amplitude = 0.05 * self.params.tortuosity * length;
        let waves: Vec<(f64, f64, Vector3<f64>)> = (0..2)
            .map(|k| {
                let dir = Vector3::new(
                    self.rng.random_range(-1.0..=1.0),
                    self.rng.random_range(-1.0..=1.0),
                    self.rng.random_range(-1.0..=1.0),
                );
                (
                    f64::from(k + 1) * std::f64::consts::PI,
                    self.rng.random_range(0.0..std::f64::consts::TAU),
                    dir,
                )
            })
            .collect();
        let mut s = 0.0;
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            if i > 0 {
                s += (points[i] - points[i - 1]).norm();
            }
            let u = s / length;
            let tangent = (points[(i + 1).min(n - 1)] - points[i.saturating_sub(1)]).normalize();
            let mut offset = Vector3::zeros();
            for (freq, phase, dir) in &waves {
                let lateral = dir - tangent * dir.dot(&tangent);
                offset += lateral * ((freq * u + phase).sin() * (std::f64::consts::PI * u).sin());
            }
            out.push(points[i] + offset * amplitude);
        }
        out
    }

    fn add(
        &mut self,
        name: &str,
        kind: VesselKind,
        side: Side,
        controls: &[Point3<f64>],
        radii_mm: (f64, f64),
        bend: bool,
    ) -> Result<Vec<Point3<f64>>> {
        let (r0, r1) = (self.radius(radii_mm.0), self.radius(radii_mm.1));
        let step = 0.5 * r0.min(r1);
        let mut points = spline(controls, step.max(2e-4));
        if bend {
            points = self.tortuous(points);
        }
        let length: f64 = points.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        let mut s = 0.0;
        let mut radii = Vec::with_capacity(points.len());
        for i in 0..points.len() {
            if i > 0 {
                s += (points[i] - points[i - 1]).norm();
            }
            radii.push(r0 + (r1 - r0) * s / length);
        }
        self.graph.add_branch(BranchSpec {
            name: name.to_owned(),
            kind,
            side,
            points: points.clone(),
            radii,
        })?;
        Ok(points)
    }
}

/// Builds a phantom. All branch names are listed in the crate's README; targets of interest:
/// `left_common_carotid`, `right_vertebral`, `left_middle_cerebral`, `basilar` and so on.
pub fn neuro_phantom(params: &NeuroPhantomParams) -> Result<VesselGraph> {
    require_range("tortuosity", params.tortuosity, 0.0, 1.0, "between 0 and 1")?;
    require_range(
        "variability",
        params.variability,
        0.0,
        1.0,
        "between 0 and 1",
    )?;
    let mut b = Builder {
        rng: StdRng::seed_from_u64(params.seed),
        params: *params,
        graph: VesselGraph::new(),
    };
    let drop = match params.arch {
        ArchType::I => 0.5,
        ArchType::II => 1.5,
        ArchType::III => 2.5,
    } * CCA_DIAMETER
        + b.params.variability * 0.25 * CCA_DIAMETER * b.rng.random_range(-1.0..=1.0);
    // Aorta: ascending on the patient's right and anterior, arch apex at z = 0, descending on
    // the left and posterior. Origins of the great vessels lie on the arch at given heights.
    let apex = mm(0.0, 5.0, 0.0);
    let aorta_controls = [
        mm(-20.0, -25.0, -80.0),
        mm(-22.0, -18.0, -45.0),
        mm(-18.0, -8.0, -14.0) + Vector3::new(0.0, 0.0, -drop * 0.6),
        apex,
        mm(18.0, 18.0, -12.0),
        mm(22.0, 32.0, -45.0),
        mm(20.0, 35.0, -90.0),
        mm(18.0, 35.0, -150.0),
    ];
    let aorta = spline(&aorta_controls, 1e-3);
    // Origins: the point on each limb at the wanted depth below the apex.
    let apex_index = aorta
        .iter()
        .enumerate()
        .max_by(|a, c| a.1.z.total_cmp(&c.1.z))
        .map_or(0, |(i, _)| i);
    let top = aorta[apex_index].z;
    let below = |depth: f64, right_limb: bool| -> usize {
        let range: Vec<usize> = if right_limb {
            (0..apex_index).rev().collect()
        } else {
            (apex_index..aorta.len()).collect()
        };
        range
            .into_iter()
            .find(|&i| top - aorta[i].z >= depth)
            .unwrap_or(apex_index)
    };
    let bct_at = below(drop, true);
    let lcca_at = below(0.3 * drop + 1e-3, false).max(apex_index + 1);
    let lsa_at = below(drop + 8e-3, false).max(lcca_at + 8);
    let aorta_radius = |i: usize| 14e-3 - 3e-3 * i as f64 / aorta.len() as f64;
    let cuts = [0, bct_at, lcca_at, lsa_at, aorta.len() - 1];
    let names = [
        "ascending_aorta",
        "aortic_arch_1",
        "aortic_arch_2",
        "descending_aorta",
    ];
    for (k, name) in names.iter().enumerate() {
        let points: Vec<_> = aorta[cuts[k]..=cuts[k + 1]].to_vec();
        let radii = (cuts[k]..=cuts[k + 1]).map(aorta_radius).collect();
        b.graph.add_branch(BranchSpec {
            name: (*name).to_owned(),
            kind: VesselKind::Aorta,
            side: Side::Midline,
            points,
            radii,
        })?;
    }
    let (bct_origin, lcca_origin, lsa_origin) = (aorta[bct_at], aorta[lcca_at], aorta[lsa_at]);
    // Brachiocephalic trunk and the right side.
    let bct_end = mm(-30.0, -5.0, 40.0) + b.jitter(4e-3);
    b.add(
        "brachiocephalic",
        VesselKind::Brachiocephalic,
        Side::Right,
        &[
            bct_origin,
            bct_origin + Vector3::new(-0.004, 0.0, 0.015),
            bct_end,
        ],
        (6.0, 5.5),
        true,
    )?;
    let mut sides = Vec::new();
    for side in [Side::Right, Side::Left] {
        let sign = if side == Side::Left { 1.0 } else { -1.0 };
        let prefix = if side == Side::Left { "left" } else { "right" };
        let (cca_origin, sca_origin) = if side == Side::Left {
            (lcca_origin, lsa_origin)
        } else {
            (bct_end, bct_end)
        };
        // Subclavian to the vertebral origin, then on towards the arm.
        let va_origin = mm(sign * 45.0, 15.0, 35.0) + b.jitter(4e-3);
        b.add(
            &format!("{prefix}_subclavian"),
            VesselKind::Subclavian,
            side,
            &[
                sca_origin,
                sca_origin + Vector3::new(sign * 0.01, 0.0, 0.02),
                va_origin,
            ],
            (4.5, 4.0),
            true,
        )?;
        b.add(
            &format!("{prefix}_subclavian_distal"),
            VesselKind::Subclavian,
            side,
            &[
                va_origin,
                mm(sign * 70.0, 15.0, 30.0),
                mm(sign * 100.0, 20.0, 10.0),
            ],
            (4.0, 3.5),
            true,
        )?;
        let carotid_bifurcation = mm(sign * 28.0, 0.0, 120.0) + b.jitter(4e-3);
        b.add(
            &format!("{prefix}_common_carotid"),
            VesselKind::CommonCarotid,
            side,
            &[
                cca_origin,
                cca_origin + Vector3::new(0.0, 0.0, 0.02),
                carotid_bifurcation,
            ],
            (3.5, 3.4),
            true,
        )?;
        b.add(
            &format!("{prefix}_external_carotid"),
            VesselKind::ExternalCarotid,
            side,
            &[
                carotid_bifurcation,
                mm(sign * 30.0, -12.0, 150.0),
                mm(sign * 40.0, -20.0, 185.0),
            ],
            (2.2, 1.6),
            true,
        )?;
        // ICA: cervical segment, then the siphon (an S in the sagittal plane) to the terminus.
        let terminus = mm(sign * 15.0, 2.0, 215.0) + b.jitter(2e-3);
        let ica = [
            carotid_bifurcation,
            mm(sign * 30.0, 8.0, 150.0),
            mm(sign * 25.0, 10.0, 180.0),
            mm(sign * 20.0, -8.0, 192.0),
            mm(sign * 18.0, -14.0, 203.0),
            mm(sign * 17.0, -4.0, 211.0),
            terminus,
        ];
        b.add(
            &format!("{prefix}_internal_carotid"),
            VesselKind::InternalCarotid,
            side,
            &ica,
            (2.6, 1.8),
            false,
        )?;
        b.add(
            &format!("{prefix}_middle_cerebral"),
            VesselKind::MiddleCerebral,
            side,
            &[
                terminus,
                mm(sign * 35.0, 4.0, 218.0),
                mm(sign * 55.0, 8.0, 228.0),
            ],
            (1.55, 1.3),
            true,
        )?;
        let acom_end = mm(sign * 2.0, -14.0, 222.0);
        b.add(
            &format!("{prefix}_anterior_cerebral_a1"),
            VesselKind::AnteriorCerebral,
            side,
            &[terminus, mm(sign * 8.0, -8.0, 220.0), acom_end],
            (1.2, 1.1),
            false,
        )?;
        b.add(
            &format!("{prefix}_anterior_cerebral_a2"),
            VesselKind::AnteriorCerebral,
            side,
            &[
                acom_end,
                mm(sign * 3.0, -25.0, 240.0),
                mm(sign * 4.0, -30.0, 265.0),
            ],
            (1.1, 0.9),
            true,
        )?;
        // Vertebral: from the subclavian up the spine to the vertebrobasilar junction.
        let vb_junction = mm(0.0, 28.0, 190.0);
        b.add(
            &format!("{prefix}_vertebral"),
            VesselKind::Vertebral,
            side,
            &[
                va_origin,
                mm(sign * 30.0, 25.0, 80.0),
                mm(sign * 25.0, 30.0, 150.0),
                mm(sign * 18.0, 40.0, 175.0),
                mm(sign * 5.0, 32.0, 186.0),
                vb_junction,
            ],
            (1.9, 1.7),
            true,
        )?;
        sides.push((side, sign, terminus));
    }
    let tip = mm(0.0, 24.0, 218.0);
    b.add(
        "basilar",
        VesselKind::Basilar,
        Side::Midline,
        &[mm(0.0, 28.0, 190.0), mm(0.0, 26.0, 205.0), tip],
        (1.8, 1.55),
        false,
    )?;
    b.add(
        "anterior_communicating",
        VesselKind::AnteriorCommunicating,
        Side::Midline,
        &[mm(-2.0, -14.0, 222.0), mm(2.0, -14.0, 222.0)],
        (0.75, 0.75),
        false,
    )?;
    for (side, sign, terminus) in sides {
        let prefix = if side == Side::Left { "left" } else { "right" };
        let p1_end = mm(sign * 12.0, 22.0, 219.0);
        b.add(
            &format!("{prefix}_posterior_cerebral_p1"),
            VesselKind::PosteriorCerebral,
            side,
            &[tip, mm(sign * 6.0, 24.0, 219.0), p1_end],
            (1.1, 1.05),
            false,
        )?;
        b.add(
            &format!("{prefix}_posterior_cerebral_p2"),
            VesselKind::PosteriorCerebral,
            side,
            &[
                p1_end,
                mm(sign * 25.0, 35.0, 222.0),
                mm(sign * 35.0, 55.0, 228.0),
            ],
            (1.05, 0.9),
            true,
        )?;
        b.add(
            &format!("{prefix}_posterior_communicating"),
            VesselKind::PosteriorCommunicating,
            side,
            &[terminus, mm(sign * 14.0, 12.0, 217.0), p1_end],
            (0.7, 0.7),
            false,
        )?;
    }
    let access = *aorta.last().unwrap_or(&Point3::origin());
    b.graph.landmarks.insert("access".into(), access);
    Ok(b.graph)
}
