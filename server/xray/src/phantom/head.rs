//! The synthesized body's head: scalp, skull, brain, skull base, orbits, sinuses, face,
//! mandible and teeth, around the circle of Willis.

use nalgebra::{Point3, Vector3};

use super::{BodyPhantom, Region, Sample, Tissue, ell, segment_distance, smooth};

impl BodyPhantom {
    /// The head: scalp, skull, brain, skull base, orbits, sinuses, face, mandible and teeth.
    pub(super) fn head(&self, x: f64, p: &Point3<f64>) -> Option<Sample> {
        let cow = self.landmarks.circle_of_willis;
        let d = Vector3::new(x, p.y - cow.y - 0.012, p.z - cow.z - 0.012);
        let inner = [0.068, 0.088, 0.088];
        let r = ell(d, inner);
        let sample = |tissue, region| Some(Sample { tissue, region });
        let rel = Vector3::new(x, p.y - cow.y, p.z - cow.z);
        // Orbits: fat cones under a bony rim, in front of the circle of Willis.
        for side in [-1.0, 1.0] {
            let o = ell(
                rel - Vector3::new(side * 0.031, -0.06, 0.006),
                [0.017, 0.022, 0.016],
            );
            if o < 1.0 {
                return sample(
                    if o > 0.86 {
                        Tissue::CorticalBone
                    } else {
                        Tissue::Fat
                    },
                    Region::Face,
                );
            }
        }
        // The cranial floor: anterior fossa over the orbits, middle fossa around the sella,
        // posterior fossa behind.
        let floor = 0.024
            + (-0.022 - 0.024) * smooth(-0.045, -0.025, rel.y)
            + (-0.045 + 0.022) * smooth(0.008, 0.028, rel.y)
            - 0.008 * (x / 0.05).powi(2).min(1.0) * smooth(-0.03, -0.015, rel.y);
        let thickness = 0.007;
        let outer = r <= 1.0 + thickness / 0.088;
        let scalp = r <= 1.0 + (thickness + 0.005) / 0.088;
        if scalp && rel.z >= floor - 0.008 {
            // Sinuses first: frontal in the frontal bone, sphenoid under the sella.
            for side in [-1.0, 1.0] {
                if ell(
                    rel - Vector3::new(side * 0.011, -0.07, 0.038),
                    [0.011, 0.007, 0.012],
                ) < 1.0
                {
                    return sample(Tissue::Air, Region::Face);
                }
            }
            if ell(
                rel - Vector3::new(0.0, -0.022, -0.02),
                [0.011, 0.011, 0.009],
            ) < 1.0
            {
                return sample(Tissue::Air, Region::Cranium);
            }
            // Petrous ridges: from the apex beside the clivus out and back.
            for side in [-1.0, 1.0] {
                let a = Point3::new(side * 0.012, 0.006, -0.02);
                let b = Point3::new(side * 0.056, 0.036, -0.014);
                if segment_distance(&Point3::from(rel), &a, &b) < 0.008 {
                    return sample(Tissue::PetrousBone, Region::Cranium);
                }
            }
            // Clivus: from the dorsum sellae down to the foramen magnum.
            let a = Point3::new(0.0, 0.01, -0.012);
            let b = Point3::new(0.0, 0.022, -0.045);
            if segment_distance(&Point3::from(rel), &a, &b) < 0.006 && rel.x.abs() < 0.012 {
                return sample(Tissue::CorticalBone, Region::Cranium);
            }
            if r > 1.0 {
                return sample(
                    if outer {
                        Tissue::CorticalBone
                    } else {
                        Tissue::Soft
                    },
                    if outer { Region::Cranium } else { Region::Face },
                );
            }
            if rel.z >= floor {
                return sample(Tissue::Brain, Region::Cranium);
            }
            // The floor itself, open at the foramen magnum.
            let foramen = (x * x + (rel.y - 0.032).powi(2)).sqrt() < 0.017;
            return sample(
                if foramen {
                    Tissue::Soft
                } else {
                    Tissue::CorticalBone
                },
                Region::Cranium,
            );
        }
        // Under the skull base, inside the head's outline: the deep face and the muscles
        // and glands of the upper neck.
        let under_skull = scalp && rel.z < floor - 0.008;
        // Face and jaw under the cranium.
        let face = ell(
            rel - Vector3::new(0.0, -0.038, -0.045),
            [0.062, 0.068, 0.068],
        );
        if face < 1.3 {
            // The mandibular rami up to the condyles.
            if (x.abs() - 0.047).abs() < 0.004
                && rel.y > -0.01
                && rel.y < 0.01
                && rel.z > -0.095
                && rel.z < -0.035
            {
                return sample(Tissue::CorticalBone, Region::Face);
            }
        }
        if face >= 1.0 || rel.y > 0.0 {
            return under_skull.then_some(Sample {
                tissue: Tissue::Soft,
                region: if rel.y < 0.0 {
                    Region::Face
                } else {
                    Region::Neck
                },
            });
        }
        for side in [-1.0, 1.0] {
            if ell(
                rel - Vector3::new(side * 0.025, -0.058, -0.028),
                [0.016, 0.018, 0.017],
            ) < 1.0
            {
                return sample(Tissue::Air, Region::Face);
            }
        }
        if ell(rel - Vector3::new(0.0, -0.062, -0.01), [0.01, 0.026, 0.028]) < 1.0 {
            return sample(Tissue::Air, Region::Face);
        }
        // The dental arches (a parabola in the axial plane) and the mandible under them.
        let arch_p = |reach: f64| -0.085 + (0.085 - 0.002) * (x / reach).powi(2).min(1.0);
        let on_arch = |reach: f64, z0: f64, z1: f64, half: f64| {
            x.abs() <= reach && rel.z > z0 && rel.z < z1 && (rel.y - arch_p(reach)).abs() < half
        };
        if on_arch(0.04, -0.06, -0.049, 0.005) || on_arch(0.038, -0.072, -0.061, 0.005) {
            return sample(Tissue::Tooth, Region::Face);
        }
        if on_arch(0.046, -0.102, -0.072, 0.005) {
            return sample(Tissue::CorticalBone, Region::Face);
        }
        let skin = if face > 0.94 {
            Tissue::Fat
        } else {
            Tissue::Soft
        };
        sample(skin, Region::Face)
    }
}
