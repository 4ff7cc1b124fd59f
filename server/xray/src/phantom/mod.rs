//! The synthesized body around a vessel tree: a skull with orbits, sinuses, petrous ridges
//! and skull base; mandible and teeth; cervical and thoracic vertebrae with their bodies,
//! arches and processes; clavicles, curved ribs and sternum; lungs, heart and aortic-knob
//! shadows. It is placed from landmarks of the vessels (circle of Willis, aortic arch,
//! vertebral arteries, descending aorta), so that every vessel lies in soft tissue where it
//! belongs; vessels crossing bone run in canals (the transverse foramina, the carotid canal,
//! the foramen magnum). Simple shapes with textbook HU.

use std::collections::HashSet;

use cathlab_anatomy::graph::VesselGraph;
use nalgebra::{Matrix3, Point3, Vector3};

use crate::error::{Result, XrayError};
use crate::volume::Volume;

mod chest;
mod head;

/// One centerline sample of a vessel, in patient LPS coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VesselPoint {
    /// Centre (m, LPS).
    pub position: Point3<f64>,
    /// Lumen radius (m).
    pub radius: f64,
}

/// Where the body goes, in patient LPS coordinates (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyLandmarks {
    /// Centre of the circle of Willis (the head is built around it).
    pub circle_of_willis: Point3<f64>,
    /// Height (S, m) of the top of the aortic arch's centreline.
    pub arch_top_s: f64,
    /// Lowest height (S, m) the volume must reach.
    pub bottom_s: f64,
    /// Left–right coordinate of the midline (m).
    pub midline_l: f64,
    /// Posterior coordinate of the centre of the cervical vertebral bodies (m).
    pub cervical_spine_p: f64,
    /// Posterior coordinate of the centre of the thoracic vertebral bodies (m).
    pub thoracic_spine_p: f64,
    /// Left–right coordinate of the aorta's leftmost wall, the aortic knob (m).
    pub aortic_knob_l: f64,
    /// Height of the lungs' apices (S, m): under the subclavian arteries that groove them.
    pub lung_apex_s: f64,
    /// The descending aorta's axis, where the tree has one.
    pub descending_aorta: Option<AortaAxis>,
}

/// A straight fit to the descending aorta: position at the arch top's height, slope and
/// mean radius (LPS, m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AortaAxis {
    /// L and P of the axis at the height of the arch top (m).
    pub at_arch: [f64; 2],
    /// Change of L and P per metre of height.
    pub slope: [f64; 2],
    /// Mean lumen radius (m).
    pub radius: f64,
}

impl AortaAxis {
    /// L and P of the axis at height `s` (m).
    pub fn at(&self, s: f64, arch_top_s: f64) -> [f64; 2] {
        let dz = s - arch_top_s;
        [
            self.at_arch[0] + self.slope[0] * dz,
            self.at_arch[1] + self.slope[1] * dz,
        ]
    }

    /// Least-squares line through `points` (at least two heights).
    fn fit(points: &[&VesselPoint], arch_top_s: f64) -> Option<Self> {
        let n = points.len() as f64;
        let mz = points
            .iter()
            .map(|v| v.position.z - arch_top_s)
            .sum::<f64>()
            / n;
        let szz: f64 = points
            .iter()
            .map(|v| (v.position.z - arch_top_s - mz).powi(2))
            .sum();
        if points.len() < 2 || szz < 1e-8 {
            return None;
        }
        let line = |f: &dyn Fn(&Point3<f64>) -> f64| {
            let m = points.iter().map(|v| f(&v.position)).sum::<f64>() / n;
            let sxz: f64 = points
                .iter()
                .map(|v| (f(&v.position) - m) * (v.position.z - arch_top_s - mz))
                .sum();
            let slope = sxz / szz;
            (m - slope * mz, slope)
        };
        let (l, dl) = line(&|p| p.x);
        let (p, dp) = line(&|p| p.y);
        Some(Self {
            at_arch: [l, p],
            slope: [dl, dp],
            radius: points.iter().map(|v| v.radius).sum::<f64>() / n,
        })
    }
}

/// Lumen radius from which a vessel counts as the aorta (m).
const AORTA_RADIUS: f64 = 7e-3;

impl BodyLandmarks {
    /// Landmarks from a vessel tree's centerline samples (LPS):
    /// - the circle of Willis at the mean of the tree's top 40 mm;
    /// - the aorta is every sample wider than 7 mm; the arch top is its highest sample and
    ///   the knob its leftmost wall;
    /// - the neck lies between 40 mm above the arch and 50 mm below the circle of Willis;
    ///   the midline halfway between its leftmost and rightmost vessel; the cervical
    ///   vertebral bodies at the vertebral arteries' depth (the tenth of neck samples
    ///   furthest back);
    /// - the thoracic vertebral bodies just behind the descending aorta (the back half of
    ///   the aorta more than 40 mm below the arch top), clear of it.
    ///
    /// A tree without an aorta or a neck gets textbook offsets instead.
    pub fn from_vessels(points: &[VesselPoint]) -> Result<Self> {
        if points.len() < 2
            || points.iter().any(|v| {
                !v.position.coords.iter().all(|c| c.is_finite())
                    || !v.radius.is_finite()
                    || v.radius < 0.0
            })
        {
            return Err(XrayError::OutOfRange {
                what: "vessel points for the body phantom".into(),
                range: "at least 2, all finite with radii ≥ 0",
                value: points.len() as f64,
            });
        }
        let z = |v: &&VesselPoint| v.position.z;
        let top = points.iter().map(|v| v.position.z).fold(f64::MIN, f64::max);
        let bottom = points.iter().map(|v| v.position.z).fold(f64::MAX, f64::min);
        let head: Vec<&VesselPoint> = points.iter().filter(|v| z(v) > top - 0.04).collect();
        let mean = |set: &[&VesselPoint], f: &dyn Fn(&Point3<f64>) -> f64| {
            set.iter().map(|v| f(&v.position)).sum::<f64>() / set.len() as f64
        };
        let cow = Point3::new(
            mean(&head, &|p| p.x),
            mean(&head, &|p| p.y),
            mean(&head, &|p| p.z),
        );
        let aorta: Vec<&VesselPoint> = points.iter().filter(|v| v.radius >= AORTA_RADIUS).collect();
        let (arch_top_s, knob) = if aorta.is_empty() {
            (bottom + 0.3 * (top - bottom), None)
        } else {
            (
                aorta.iter().map(z).fold(f64::MIN, f64::max),
                Some(
                    aorta
                        .iter()
                        .map(|v| v.position.x + v.radius)
                        .fold(f64::MIN, f64::max),
                ),
            )
        };
        let neck: Vec<&VesselPoint> = points
            .iter()
            .filter(|v| z(v) > arch_top_s + 0.04 && z(v) < cow.z - 0.05)
            .collect();
        let (midline_l, cervical_spine_p) = if neck.is_empty() {
            (cow.x, cow.y + 0.03)
        } else {
            let min_l = neck.iter().map(|v| v.position.x).fold(f64::MAX, f64::min);
            let max_l = neck.iter().map(|v| v.position.x).fold(f64::MIN, f64::max);
            let mut depth: Vec<f64> = neck.iter().map(|v| v.position.y).collect();
            depth.sort_by(f64::total_cmp);
            let p90 = depth[(depth.len() * 9 / 10).min(depth.len() - 1)];
            (0.5 * (min_l + max_l), p90 - 0.002)
        };
        let low: Vec<&VesselPoint> = aorta
            .iter()
            .copied()
            .filter(|v| z(v) < arch_top_s - 0.04)
            .collect();
        let mut descending_aorta = None;
        let thoracic_spine_p = if low.is_empty() {
            cervical_spine_p + 0.03
        } else {
            let mut depth: Vec<f64> = low.iter().map(|v| v.position.y).collect();
            depth.sort_by(f64::total_cmp);
            let back = &depth[depth.len() / 2..];
            let p = back.iter().sum::<f64>() / back.len() as f64;
            let descending: Vec<&VesselPoint> = low
                .iter()
                .copied()
                .filter(|v| v.position.y >= depth[depth.len() / 2])
                .collect();
            descending_aorta = AortaAxis::fit(&descending, arch_top_s);
            let x = mean(&descending, &|q| q.x) - midline_l;
            let r = descending.iter().map(|v| v.radius).sum::<f64>() / descending.len() as f64;
            // Behind the aorta's centre; further back when the aorta lies in front of the
            // vertebral body rather than beside it.
            let gap = x.abs() - r - THORACIC_BODY[0];
            let behind = if gap >= 0.0 {
                0.008
            } else {
                r + THORACIC_BODY[1] + 0.003
            };
            (p + behind).clamp(cervical_spine_p + 0.01, cervical_spine_p + 0.08)
        };
        // The lung apices: 45 mm above the arch, or under any vessel crossing above them
        // out to the side (the subclavian arteries).
        let apex_default = arch_top_s + 0.045;
        let lung_apex_s = points
            .iter()
            .filter(|v| {
                (v.position.x - midline_l).abs() > 0.035
                    && v.position.z > arch_top_s - 0.01
                    && v.position.z < arch_top_s + 0.08
            })
            .map(|v| v.position.z - v.radius - 0.004)
            .fold(apex_default, f64::min)
            .max(arch_top_s + 0.005);
        Ok(Self {
            descending_aorta,
            lung_apex_s,
            circle_of_willis: cow,
            arch_top_s,
            bottom_s: bottom,
            midline_l,
            cervical_spine_p,
            thoracic_spine_p,
            aortic_knob_l: knob.unwrap_or(midline_l + 0.035),
        })
    }
}

/// Semi-axes of a cervical vertebral body (left–right, front–back; m).
const CERVICAL_BODY: [f64; 2] = [0.012, 0.008];
/// Semi-axes of a thoracic vertebral body (m).
const THORACIC_BODY: [f64; 2] = [0.016, 0.013];

/// What a point of the body is made of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tissue {
    /// Outside the body, or an airway or sinus.
    Air,
    /// Aerated lung.
    Lung,
    /// Subcutaneous or orbital fat.
    Fat,
    /// Muscle, organs, blood and vessel walls.
    Soft,
    /// Brain.
    Brain,
    /// Intervertebral disc or costal cartilage.
    Cartilage,
    /// Cancellous bone (vertebral bodies, sternum).
    CancellousBone,
    /// Cortical bone (skull, cortices, ribs, clavicles, mandible).
    CorticalBone,
    /// The dense petrous bone.
    PetrousBone,
    /// Tooth enamel and dentine.
    Tooth,
}

impl Tissue {
    /// Textbook CT number (HU).
    pub fn hu(self) -> f64 {
        match self {
            Tissue::Air => -1000.0,
            Tissue::Lung => -820.0,
            Tissue::Fat => -90.0,
            Tissue::Soft => 40.0,
            Tissue::Brain => 35.0,
            Tissue::Cartilage => 110.0,
            Tissue::CancellousBone => 300.0,
            Tissue::CorticalBone => 1200.0,
            Tissue::PetrousBone => 1700.0,
            Tissue::Tooth => 2200.0,
        }
    }

    /// Soft tissue a vessel may run in (not air, lung or bone).
    pub fn is_soft(self) -> bool {
        matches!(
            self,
            Tissue::Soft | Tissue::Brain | Tissue::Fat | Tissue::Cartilage
        )
    }

    fn is_bone(self) -> bool {
        matches!(
            self,
            Tissue::CancellousBone | Tissue::CorticalBone | Tissue::PetrousBone | Tissue::Tooth
        )
    }
}

/// Which part of the body a point belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Region {
    /// Outside the body.
    Outside,
    /// Inside the skull.
    Cranium,
    /// Face and jaw below the cranium.
    Face,
    /// The neck, above the thoracic inlet.
    Neck,
    /// The mediastinum: between the lungs, from the inlet to the diaphragm (heart, aorta).
    Mediastinum,
    /// A lung.
    Lung,
    /// The chest wall with ribs, sternum, clavicles and spine, and the shoulders.
    ChestWall,
    /// Below the diaphragm.
    Abdomen,
}

/// One point's tissue and region.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sample {
    /// What it is made of.
    pub tissue: Tissue,
    /// Where it is.
    pub region: Region,
}

/// Side of the cubic cells the vessel canals are rasterised on (m).
const CANAL_CELL: f64 = 1e-3;

/// Radius of a clavicle's bone (m).
const CLAVICLE_RADIUS: f64 = 0.0065;

/// A clavicle's bounding box and its pieces' boxes, grown by [`CLAVICLE_RADIUS`] (m).
type ClavicleBoxes = (
    (Vector3<f64>, Vector3<f64>),
    Vec<(Vector3<f64>, Vector3<f64>)>,
);
/// Clearance of bone around a vessel's lumen (m).
const CANAL_CLEARANCE: f64 = 1.5e-3;

/// The body around a vessel tree: landmarks, derived heights and the vessels' bony canals.
#[derive(Debug, Clone)]
pub struct BodyPhantom {
    landmarks: BodyLandmarks,
    /// Vertical scale of the neck and spine (1: textbook adult).
    scale: f64,
    /// Top of the dens (S, m).
    dens_s: f64,
    /// Thoracic inlet (S, m): above it is the neck.
    inlet_s: f64,
    /// Top of the first thoracic vertebra (S, m).
    t1_s: f64,
    /// Centre of the rib cage's elliptic section (P, m).
    chest_p: f64,
    /// Clavicles: polylines (LPS, m).
    clavicles: [Vec<Point3<f64>>; 2],
    /// Per clavicle: the box of all its pieces and the box of each piece, grown by the bone's
    /// radius (LPS, m).
    clavicle_boxes: [ClavicleBoxes; 2],
    canals: HashSet<[i32; 3]>,
}

/// Smoothstep from 0 at `a` to 1 at `b`.
fn smooth(a: f64, b: f64, x: f64) -> f64 {
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Normalised elliptic radius of `(dx, dy, dz)` with semi-axes `a`.
fn ell(d: Vector3<f64>, a: [f64; 3]) -> f64 {
    ((d.x / a[0]).powi(2) + (d.y / a[1]).powi(2) + (d.z / a[2]).powi(2)).sqrt()
}

/// Distance from `p` to a capsule `a`–`b`.
fn segment_distance(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    let ab = b - a;
    if ab.norm_squared() == 0.0 {
        return (p - a).norm();
    }
    let t = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
    (p - (a + ab * t)).norm()
}

impl BodyPhantom {
    /// The body around the vessels: landmarks from them and canals along them.
    pub fn around(vessels: &[Vec<VesselPoint>]) -> Result<Self> {
        let all: Vec<VesselPoint> = vessels.iter().flatten().copied().collect();
        let landmarks = BodyLandmarks::from_vessels(&all)?;
        let mut body = Self::new(landmarks);
        for branch in vessels {
            body.carve(branch);
        }
        Ok(body)
    }

    /// The body around a vessel graph whose coordinates `to_lps` turns into LPS.
    pub fn around_graph(graph: &VesselGraph, to_lps: &Matrix3<f64>) -> Result<Self> {
        let vessels: Vec<Vec<VesselPoint>> = graph
            .branches
            .iter()
            .map(|b| {
                b.points
                    .iter()
                    .zip(&b.radii)
                    .map(|(p, &radius)| VesselPoint {
                        position: Point3::from(to_lps * p.coords),
                        radius,
                    })
                    .collect()
            })
            .collect();
        Self::around(&vessels)
    }

    /// The body around `landmarks` alone (no canals).
    pub fn new(landmarks: BodyLandmarks) -> Self {
        let m = landmarks;
        let dens_s = m.circle_of_willis.z - 0.03;
        // Dens to the arch top: C2 with its dens, C3–C7 and T1–T3 (textbook 0.202 m).
        let scale = ((dens_s - m.arch_top_s) / 0.202).clamp(0.7, 1.3);
        let t1_s = m.arch_top_s + 3.0 * 0.025 * scale;
        let inlet_s = m.arch_top_s + 0.035 * scale;
        let chest_p = m.thoracic_spine_p - 0.075;
        let notch = Point3::new(m.midline_l, chest_p - 0.088, inlet_s - 0.005);
        let clavicles = [-1.0, 1.0].map(|side: f64| {
            (0..=24)
                .map(|i| {
                    let t = i as f64 / 24.0;
                    Point3::new(
                        m.midline_l + side * (0.022 + 0.128 * t),
                        notch.y + 0.01 + 0.075 * t - 0.018 * (std::f64::consts::PI * t).sin(),
                        notch.z + 0.035 * t.powf(1.5),
                    )
                })
                .collect()
        });
        let clavicle_boxes = clavicles.each_ref().map(|line: &Vec<Point3<f64>>| {
            let grown = |a: &Point3<f64>, b: &Point3<f64>| {
                (
                    a.coords.inf(&b.coords).add_scalar(-CLAVICLE_RADIUS),
                    a.coords.sup(&b.coords).add_scalar(CLAVICLE_RADIUS),
                )
            };
            let pieces: Vec<_> = line.windows(2).map(|w| grown(&w[0], &w[1])).collect();
            let whole = pieces
                .iter()
                .fold(pieces[0], |(lo, hi), (a, b)| (lo.inf(a), hi.sup(b)));
            (whole, pieces)
        });
        Self {
            landmarks,
            scale,
            dens_s,
            inlet_s,
            t1_s,
            chest_p,
            clavicles,
            clavicle_boxes,
            canals: HashSet::new(),
        }
    }

    /// The landmarks the body was placed from.
    pub fn landmarks(&self) -> &BodyLandmarks {
        &self.landmarks
    }

    /// Marks the cells within a vessel's radius plus clearance as a canal through bone.
    fn carve(&mut self, branch: &[VesselPoint]) {
        let cell = |p: Vector3<f64>| p.map(|c| (c / CANAL_CELL).floor() as i32);
        let pairs: Vec<(VesselPoint, VesselPoint)> = match branch {
            [only] => vec![(*only, *only)],
            _ => branch.windows(2).map(|w| (w[0], w[1])).collect(),
        };
        for (a, b) in pairs {
            let reach = a.radius.max(b.radius) + CANAL_CLEARANCE + 0.5 * CANAL_CELL * 3f64.sqrt();
            let lo = cell(a.position.coords.inf(&b.position.coords).add_scalar(-reach));
            let hi = cell(a.position.coords.sup(&b.position.coords).add_scalar(reach));
            for i in lo.x..=hi.x {
                for j in lo.y..=hi.y {
                    for k in lo.z..=hi.z {
                        let c =
                            Point3::new(f64::from(i) + 0.5, f64::from(j) + 0.5, f64::from(k) + 0.5)
                                * CANAL_CELL;
                        if segment_distance(&c, &a.position, &b.position) <= reach {
                            self.canals.insert([i, j, k]);
                        }
                    }
                }
            }
        }
    }

    fn in_canal(&self, p: &Point3<f64>) -> bool {
        let c = p.coords.map(|c| (c / CANAL_CELL).floor() as i32);
        self.canals.contains(&[c.x, c.y, c.z])
    }

    /// Tissue and region at a patient point (LPS, m).
    pub fn sample(&self, p: &Point3<f64>) -> Sample {
        let mut s = self.sample_shapes(p);
        let displaced = s.tissue.is_bone()
            || (s.tissue == Tissue::Air && s.region != Region::Outside && s.region != Region::Lung);
        if displaced && self.in_canal(p) {
            s.tissue = Tissue::Soft;
        }
        s
    }

    /// CT number at a patient point (HU).
    pub fn hu(&self, p: &Point3<f64>) -> f64 {
        self.sample(p).tissue.hu()
    }

    /// Centre of the vertebral bodies (P, m), their semi-axes (m) at height `z`, and whether
    /// `z` is in the thoracic spine.
    fn spine_at(&self, z: f64) -> (f64, [f64; 2]) {
        let m = &self.landmarks;
        // Lordosis to kyphosis: from the C6 body to the T3 body.
        let t = smooth(self.t1_s + 0.045 * self.scale, m.arch_top_s + 0.01, z);
        let p = m.cervical_spine_p + (m.thoracic_spine_p - m.cervical_spine_p) * t;
        let a = [
            CERVICAL_BODY[0] + (THORACIC_BODY[0] - CERVICAL_BODY[0]) * t,
            CERVICAL_BODY[1] + (THORACIC_BODY[1] - CERVICAL_BODY[1]) * t,
        ];
        (p, a)
    }

    /// Where `z` is within its vertebral level: `Some(true)` in a body, `Some(false)` in a
    /// disc, `None` above the dens.
    fn vertebral_level(&self, z: f64) -> Option<bool> {
        let s = self.scale;
        let depth = self.dens_s - z;
        if depth < 0.0 {
            return None;
        }
        let c2 = 0.032 * s;
        if depth < c2 {
            return Some(true);
        }
        let cervical = 5.0 * 0.019 * s;
        let (period, disc, into) = if depth < c2 + cervical {
            (0.019 * s, 0.0045 * s, depth - c2)
        } else {
            (0.025 * s, 0.0045 * s, depth - c2 - cervical)
        };
        Some(into.rem_euclid(period) >= disc)
    }

    /// The spine: bodies, discs, arches, spinous and transverse processes.
    fn spine(&self, x: f64, p: &Point3<f64>) -> Option<Tissue> {
        let level = self.vertebral_level(p.z)?;
        let (centre, a) = self.spine_at(p.z);
        let y = p.y - centre;
        let body = ((x / a[0]).powi(2) + (y / a[1]).powi(2)).sqrt();
        let dens = p.z > self.dens_s - 0.014 * self.scale;
        if dens {
            // The dens: a peg on top of C2, ringed by the atlas.
            let r = (x * x + (y + 0.002).powi(2)).sqrt();
            if r < 0.005 {
                return Some(Tissue::CancellousBone);
            }
            let atlas = ((x / 0.024).powi(2) + ((y - 0.008) / 0.02).powi(2)).sqrt();
            if p.z < self.dens_s - 0.004 && atlas < 1.0 && atlas > 0.8 {
                return Some(Tissue::CorticalBone);
            }
            return None;
        }
        if body <= 1.0 {
            return Some(if !level {
                Tissue::Cartilage
            } else if body > 0.82 {
                Tissue::CorticalBone
            } else {
                Tissue::CancellousBone
            });
        }
        if !level {
            return None;
        }
        // The canal behind the body, ringed by pedicles and laminae.
        let canal_c = a[1] + 0.009;
        let r = (x * x + (y - canal_c).powi(2)).sqrt();
        if r < 0.0075 {
            return None;
        }
        if r < 0.012 && y > a[1] * 0.5 {
            return Some(Tissue::CorticalBone);
        }
        // Spinous process, backwards and downwards.
        if x.abs() < 0.003 && y > canal_c && y < canal_c + 0.032 {
            return Some(Tissue::CorticalBone);
        }
        // Transverse processes.
        let reach =
            0.016 + 0.006 * (a[0] - CERVICAL_BODY[0]) / (THORACIC_BODY[0] - CERVICAL_BODY[0]);
        if x.abs() > a[0] * 0.8
            && x.abs() < a[0] + reach
            && y > canal_c - 0.008
            && y < canal_c + 0.004
        {
            return Some(Tissue::CorticalBone);
        }
        None
    }

    fn sample_shapes(&self, p: &Point3<f64>) -> Sample {
        let m = &self.landmarks;
        let cow = m.circle_of_willis;
        let x = p.x - m.midline_l;
        let sample = |tissue, region| Sample { tissue, region };
        if let Some(s) = self.head(x, p) {
            return s;
        }
        if let Some(t) = self.spine(x, p) {
            let region = if p.z > self.inlet_s {
                Region::Neck
            } else {
                Region::ChestWall
            };
            return sample(t, region);
        }
        // The airway: pharynx, larynx and trachea in front of the spine, to the carina.
        let (spine_p, a) = self.spine_at(p.z);
        let airway_p = spine_p - a[1] - 0.017;
        if p.z < cow.z - 0.045 && p.z > m.arch_top_s - 0.03 {
            let w = if p.z > cow.z - 0.09 { 0.014 } else { 0.008 };
            if ((x / w).powi(2) + ((p.y - airway_p) / 0.008).powi(2)).sqrt() < 1.0 {
                let region = if p.z > self.inlet_s {
                    Region::Neck
                } else {
                    Region::Mediastinum
                };
                return sample(Tissue::Air, region);
            }
        }
        if p.z > self.inlet_s {
            return self.neck(x, p);
        }
        self.thorax(x, p)
    }

    /// The neck and the shoulders above the thoracic inlet.
    fn neck(&self, x: f64, p: &Point3<f64>) -> Sample {
        let (spine_p, _) = self.spine_at(p.z);
        let centre = spine_p - 0.02;
        let r = ((x / 0.058).powi(2) + ((p.y - centre) / 0.06).powi(2)).sqrt();
        if let Some(s) = self.clavicle(p) {
            return s;
        }
        if r <= 1.0 {
            return Sample {
                tissue: if r > 0.92 { Tissue::Fat } else { Tissue::Soft },
                region: Region::Neck,
            };
        }
        // Beside the neck: the shoulders, the lung apices and the root of the neck.
        self.thorax(x, p)
    }

    /// Samples the body on a grid of `spacing_m`, covering the vessels (±0.17 m left–right,
    /// from the face to the back, from the skull top down to 30 mm below the lowest vessel),
    /// with 2³ sub-samples per voxel for partial-volume edges.
    pub fn volume(&self, spacing_m: f64) -> Result<Volume> {
        crate::error::require_positive(|| "phantom voxel spacing (m)".into(), spacing_m)?;
        let m = &self.landmarks;
        let cow = m.circle_of_willis;
        let top = cow.z + 0.012 + 0.088 + 0.012 + 0.004;
        let bottom = m.bottom_s - 0.03;
        let front = (cow.y - 0.038 - 0.068).min(self.chest_p - 0.112 + 0.005) - 0.004;
        let back = (cow.y + 0.012 + 0.1).max(self.chest_p + 0.117) + 0.004;
        let extent = Vector3::new(0.34, back - front, top - bottom);
        let dims = extent.map(|e| (e / spacing_m).ceil() as usize + 1);
        if dims.iter().product::<usize>() > 512 * 512 * 512 {
            return Err(XrayError::OutOfRange {
                what: "phantom voxel count".into(),
                range: "at most 512³ (use a coarser spacing)",
                value: dims.iter().product::<usize>() as f64,
            });
        }
        let centre = Vector3::new(m.midline_l, 0.5 * (front + back), 0.5 * (top + bottom));
        Volume::from_fn(
            [dims.x, dims.y, dims.z],
            Vector3::repeat(spacing_m),
            centre,
            2,
            |p| self.hu(p),
        )
    }
}
