//! The synthesized body's chest below the thoracic inlet: wall, clavicles, ribs, sternum,
//! lungs, mediastinum and heart, and the rib cage's and diaphragm's outlines.

use nalgebra::{Point3, Vector3};

use super::{BodyPhantom, CLAVICLE_RADIUS, Region, Sample, Tissue, ell, segment_distance};

impl BodyPhantom {
    /// The rib cage's section at height `z`: semi-axes (m).
    pub(super) fn cage_at(&self, z: f64) -> [f64; 2] {
        let top = self.landmarks.lung_apex_s + 0.012;
        let bottom = self.landmarks.arch_top_s - 0.05;
        let t = ((top - z) / (top - bottom)).clamp(0.0, 1.0);
        [0.145 * t.powf(0.45).max(0.0), 0.1 * t.powf(0.2).max(0.0)]
    }

    /// Height of the diaphragm's dome at `x` from the midline (m); the right is higher.
    pub(super) fn diaphragm(&self, x: f64) -> f64 {
        self.landmarks.arch_top_s - 0.15 * self.scale - 0.035 * (x / 0.13).powi(2)
            + if x < 0.0 { 0.015 } else { 0.0 }
    }

    /// The clavicles' bone at `p`, if any: cortex outside 4 mm from their axis, marrow within.
    pub(super) fn clavicle(&self, p: &Point3<f64>) -> Option<Sample> {
        let outside = |(lo, hi): &(Vector3<f64>, Vector3<f64>)| {
            (0..3).any(|i| p.coords[i] < lo[i] || p.coords[i] > hi[i])
        };
        for (line, (whole, pieces)) in self.clavicles.iter().zip(&self.clavicle_boxes) {
            if outside(whole) {
                continue;
            }
            // Only the pieces whose box, grown by the bone's radius, holds the point can be
            // nearer than the radius: the others are skipped (the same answer, a fraction of
            // the distances).
            let d = line
                .windows(2)
                .zip(pieces)
                .filter(|(_, b)| !outside(b))
                .map(|(w, _)| segment_distance(p, &w[0], &w[1]))
                .fold(f64::MAX, f64::min);
            if d < CLAVICLE_RADIUS {
                return Some(Sample {
                    tissue: if d > 0.004 {
                        Tissue::CorticalBone
                    } else {
                        Tissue::CancellousBone
                    },
                    region: Region::ChestWall,
                });
            }
        }
        None
    }

    /// The thorax below the inlet: wall, ribs, sternum, lungs, mediastinum, heart.
    pub(super) fn thorax(&self, x: f64, p: &Point3<f64>) -> Sample {
        let m = &self.landmarks;
        let sample = |tissue, region| Sample { tissue, region };
        let y = p.y - self.chest_p;
        // The body wall: an ellipse, narrowing above the inlet where the trapezius slopes
        // from the shoulders up to the neck.
        let half = 0.165 - 1.8 * (p.z - self.inlet_s).max(0.0);
        let depth = 0.112 - 0.3 * (p.z - self.inlet_s).max(0.0);
        if half < 0.05 || depth < 0.05 {
            return sample(Tissue::Air, Region::Outside);
        }
        let wall = ((x / half).powi(2) + ((y - 0.005) / depth).powi(2)).sqrt();
        if wall > 1.0 {
            return sample(Tissue::Air, Region::Outside);
        }
        if let Some(s) = self.clavicle(p) {
            return s;
        }
        let diaphragm = self.diaphragm(x);
        let cage = self.cage_at(p.z);
        let r = if cage[0] > 0.0 {
            ((x / cage[0]).powi(2) + (y / cage[1]).powi(2)).sqrt()
        } else {
            f64::INFINITY
        };
        // Sternum: the manubrium, then the body.
        let front = -cage[1].max(0.09);
        let sternum_half = if p.z > m.arch_top_s - 0.02 {
            0.024
        } else {
            0.014
        };
        if x.abs() < sternum_half
            && y > front - 0.004
            && y < front + 0.01
            && p.z < self.inlet_s - 0.005
            && p.z > m.arch_top_s - 0.17 * self.scale
        {
            return sample(Tissue::CancellousBone, Region::ChestWall);
        }
        // Ribs: each from its vertebra round to the front, falling as it goes.
        if (0.86..1.0).contains(&r) && p.z > diaphragm - 0.06 {
            let theta = x.abs().atan2(y * cage[0] / cage[1]) / std::f64::consts::PI;
            let bend = -0.065 * theta * theta + 0.012 * (std::f64::consts::PI * theta).sin();
            let period = 0.025 * self.scale;
            let k = ((self.t1_s - 0.01 + bend - p.z) / period).round();
            let centre = self.t1_s - 0.01 - k * period + bend;
            if (0.0..12.0).contains(&k) && (p.z - centre).abs() < 0.0055 && theta > 0.08 {
                let band = (r - 0.93).abs() * cage[0].min(cage[1]);
                if band < 0.0045 {
                    return sample(
                        if theta > 0.86 {
                            Tissue::Cartilage
                        } else {
                            Tissue::CorticalBone
                        },
                        Region::ChestWall,
                    );
                }
            }
        }
        if p.z < diaphragm {
            return sample(
                if wall > 0.95 {
                    Tissue::Fat
                } else {
                    Tissue::Soft
                },
                Region::Abdomen,
            );
        }
        // The heart, low and to the left, behind the sternum.
        let heart = ell(
            Vector3::new(
                x - 0.022,
                y - (front + 0.06),
                p.z - (m.arch_top_s - 0.105 * self.scale),
            ),
            [0.068, 0.055, 0.065],
        );
        if heart < 1.0 {
            return sample(Tissue::Soft, Region::Mediastinum);
        }
        if r >= 0.9 {
            return sample(
                if wall > 0.95 {
                    Tissue::Fat
                } else {
                    Tissue::Soft
                },
                Region::ChestWall,
            );
        }
        // Mediastinum: narrow above the arch, bulging out to the aortic knob at the arch,
        // and round the descending aorta beside the spine.
        let knob = m.aortic_knob_l - m.midline_l + 0.004;
        let (spine_p, a) = self.spine_at(p.z);
        let bulge = 1.0 - ((p.z - (m.arch_top_s - 0.012)) / 0.034).powi(2);
        let left = 0.04 + (knob - 0.04).max(0.0) * bulge.max(0.0).sqrt();
        if x > -0.036 && x < left {
            return sample(Tissue::Soft, Region::Mediastinum);
        }
        if let Some(axis) = &m.descending_aorta
            && p.z < m.arch_top_s
        {
            let [l, q] = axis.at(p.z, m.arch_top_s);
            if (p.x - l).hypot(p.y - q) < axis.radius + 0.01 {
                return sample(Tissue::Soft, Region::Mediastinum);
            }
        }
        if p.y > spine_p + a[1] + 0.02 && x.abs() < 0.05 {
            return sample(Tissue::Soft, Region::ChestWall);
        }
        // Above the apices: the root of the neck (muscles, the subclavian vessels).
        if p.z > m.lung_apex_s - 0.025 * ((x.abs() - 0.06) / 0.05).powi(2) {
            return sample(Tissue::Soft, Region::Mediastinum);
        }
        sample(Tissue::Lung, Region::Lung)
    }
}

#[cfg(test)]
mod clavicle_tests {
    use super::*;
    use nalgebra::Matrix3;
    use proptest::prelude::*;

    /// The body around the default neuro phantom (built once).
    fn body() -> &'static BodyPhantom {
        static BODY: std::sync::OnceLock<BodyPhantom> = std::sync::OnceLock::new();
        BODY.get_or_init(|| {
            let graph = cathlab_anatomy::phantom::neuro_phantom(&Default::default()).unwrap();
            BodyPhantom::around_graph(&graph, &Matrix3::identity()).unwrap()
        })
    }

    /// The clavicle test of every piece, without the boxes.
    fn naive(body: &BodyPhantom, p: &Point3<f64>) -> Option<Tissue> {
        let d = body
            .clavicles
            .iter()
            .flat_map(|line| line.windows(2))
            .map(|w| segment_distance(p, &w[0], &w[1]))
            .fold(f64::MAX, f64::min);
        (d < CLAVICLE_RADIUS).then_some(if d > 0.004 {
            Tissue::CorticalBone
        } else {
            Tissue::CancellousBone
        })
    }

    proptest! {
        /// The boxes skip only pieces that cannot hold the point: the same bone everywhere
        /// around the clavicles (the fast path against the naive one).
        #[test]
        fn the_boxed_clavicle_test_is_the_naive_one(
            u in 0.0f64..1.0, v in 0.0f64..1.0, w in 0.0f64..1.0, side in prop::bool::ANY,
        ) {
            let body = body();
            let line = &body.clavicles[usize::from(side)];
            let lo = line.iter().fold(line[0].coords, |a, p| a.inf(&p.coords)).add_scalar(-0.02);
            let hi = line.iter().fold(line[0].coords, |a, p| a.sup(&p.coords)).add_scalar(0.02);
            let p = Point3::from(lo + (hi - lo).component_mul(&Vector3::new(u, v, w)));
            prop_assert_eq!(body.clavicle(&p).map(|s| s.tissue), naive(body, &p));
        }

        /// The same near the bone itself (cortex, marrow and just outside): a point on a piece
        /// moved up to 1.5 radii in any direction.
        #[test]
        fn the_boxed_clavicle_test_is_the_naive_one_at_the_bone(
            side in prop::bool::ANY,
            piece in 0usize..24,
            along in 0.0f64..1.0,
            offset in prop::array::uniform3(-1.5f64..1.5),
        ) {
            let body = body();
            let line = &body.clavicles[usize::from(side)];
            let (a, b) = (line[piece], line[piece + 1]);
            let p = a + (b - a) * along + Vector3::from(offset) * CLAVICLE_RADIUS;
            prop_assert_eq!(body.clavicle(&p).map(|s| s.tissue), naive(body, &p));
        }
    }
}
