//! C-arm geometry in DICOM XA conventions: positioner angles, distances, detector, zoom,
//! collimation and table, and the projection from patient coordinates to detector pixels.
//!
//! Patient coordinates are DICOM LPS (x towards the patient's left, y posterior, z superior),
//! in metres. At 0°/0° (an AP view) the tube is under the table (posterior), the beam runs
//! anteriorly (−y) and the image shows the patient's left on the right (+u = +x) and the head
//! at the top (+v, rows downwards, = −z). The primary angle turns the detector towards the
//! patient's left (LAO, +) or right (RAO, −) about the patient's long axis; the secondary
//! angle then tilts it towards the head (CRA, +) or the feet (CAU, −).

use nalgebra::{Matrix3, Matrix3x4, Point3, Rotation3, Vector2, Vector3};

use crate::error::{Result, XrayError, require_finite, require_positive};

/// The detector: pixel grid, zoom (field of view) and collimation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorGeometry {
    /// Image width (pixels, columns).
    pub width_px: u32,
    /// Image height (pixels, rows).
    pub height_px: u32,
    /// Side of the square field of view on the detector at the current zoom (m); the pixel
    /// pitch is this over the larger of width and height. Typical: 0.15–0.40 m.
    pub field_of_view_m: f64,
    /// Fraction of the field left open by the collimator, horizontally and vertically (1 is
    /// fully open); pixels outside receive no exposure.
    pub collimation: (f64, f64),
}

impl Default for DetectorGeometry {
    fn default() -> Self {
        Self {
            width_px: 512,
            height_px: 512,
            field_of_view_m: 0.25,
            collimation: (1.0, 1.0),
        }
    }
}

impl DetectorGeometry {
    /// Pixel pitch on the detector (m).
    pub fn pixel_pitch_m(&self) -> f64 {
        self.field_of_view_m / f64::from(self.width_px.max(self.height_px))
    }

    /// Pixel coordinates of the detector centre (pixel centres at integers).
    pub fn center_px(&self) -> (f64, f64) {
        (
            0.5 * f64::from(self.width_px - 1),
            0.5 * f64::from(self.height_px - 1),
        )
    }

    /// Whether pixel (u, v) lies inside the collimated field.
    pub fn is_exposed(&self, u: f64, v: f64) -> bool {
        let (cu, cv) = self.center_px();
        (u - cu).abs() <= 0.5 * self.collimation.0 * f64::from(self.width_px)
            && (v - cv).abs() <= 0.5 * self.collimation.1 * f64::from(self.height_px)
    }
}

/// A C-arm pose and its fixed distances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CArm {
    /// Primary angle (degrees): LAO positive, RAO negative.
    pub primary_deg: f64,
    /// Secondary angle (degrees): CRA positive, CAU negative.
    pub secondary_deg: f64,
    /// Source to image (detector) distance (m); 0.9–1.2 m.
    pub source_to_image_m: f64,
    /// Source to isocenter distance (m).
    pub source_to_isocenter_m: f64,
    /// Where the isocenter is in patient coordinates (m): moving the table moves this.
    pub isocenter_m: Vector3<f64>,
    /// The detector.
    pub detector: DetectorGeometry,
}

impl Default for CArm {
    fn default() -> Self {
        Self {
            primary_deg: 0.0,
            secondary_deg: 0.0,
            source_to_image_m: 1.2,
            source_to_isocenter_m: 0.8,
            isocenter_m: Vector3::zeros(),
            detector: DetectorGeometry::default(),
        }
    }
}

/// A projection ray: from the source through a pixel centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// The focal spot (m).
    pub origin: Point3<f64>,
    /// Unit direction.
    pub direction: Vector3<f64>,
    /// Distance from the source to the detector along this ray (m).
    pub length_m: f64,
}

impl CArm {
    /// Checks every parameter; the error names the first bad one.
    pub fn validate(&self) -> Result<()> {
        require_finite(|| "primary angle (deg)".into(), self.primary_deg)?;
        require_finite(|| "secondary angle (deg)".into(), self.secondary_deg)?;
        if self.primary_deg.abs() > 180.0 {
            return Err(XrayError::OutOfRange {
                what: "primary angle (deg)".into(),
                range: "within ±180",
                value: self.primary_deg,
            });
        }
        if self.secondary_deg.abs() > 90.0 {
            return Err(XrayError::OutOfRange {
                what: "secondary angle (deg)".into(),
                range: "within ±90",
                value: self.secondary_deg,
            });
        }
        require_positive(
            || "source-to-image distance (m)".into(),
            self.source_to_image_m,
        )?;
        require_positive(
            || "source-to-isocenter distance (m)".into(),
            self.source_to_isocenter_m,
        )?;
        if self.source_to_isocenter_m >= self.source_to_image_m {
            return Err(XrayError::OutOfRange {
                what: "source-to-isocenter distance (m)".into(),
                range: "smaller than the source-to-image distance",
                value: self.source_to_isocenter_m,
            });
        }
        for (i, v) in self.isocenter_m.iter().enumerate() {
            require_finite(|| format!("isocenter component {i} (m)"), *v)?;
        }
        let d = &self.detector;
        for (what, px) in [
            ("detector width (px)", d.width_px),
            ("detector height (px)", d.height_px),
        ] {
            if px == 0 {
                return Err(XrayError::OutOfRange {
                    what: what.into(),
                    range: "at least 1",
                    value: 0.0,
                });
            }
        }
        require_positive(|| "field of view (m)".into(), d.field_of_view_m)?;
        for (what, c) in [
            ("horizontal collimation", d.collimation.0),
            ("vertical collimation", d.collimation.1),
        ] {
            require_finite(|| what.into(), c)?;
            if !(c > 0.0 && c <= 1.0) {
                return Err(XrayError::OutOfRange {
                    what: what.into(),
                    range: "in (0, 1]",
                    value: c,
                });
            }
        }
        Ok(())
    }

    /// The gantry rotation: maps the AP frame (beam −y, u +x, v −z) to the current pose.
    pub fn rotation(&self) -> Rotation3<f64> {
        let primary = Rotation3::from_axis_angle(&Vector3::z_axis(), self.primary_deg.to_radians());
        let secondary =
            Rotation3::from_axis_angle(&Vector3::x_axis(), -self.secondary_deg.to_radians());
        primary * secondary
    }

    /// Unit beam direction (source → detector).
    pub fn beam_direction(&self) -> Vector3<f64> {
        self.rotation() * -Vector3::y()
    }

    /// Detector axes: image +u (columns, rightwards) and +v (rows, downwards), unit vectors.
    pub fn detector_axes(&self) -> (Vector3<f64>, Vector3<f64>) {
        let r = self.rotation();
        (r * Vector3::x(), r * -Vector3::z())
    }

    /// The focal spot in patient coordinates (m).
    pub fn source(&self) -> Point3<f64> {
        Point3::from(self.isocenter_m - self.beam_direction() * self.source_to_isocenter_m)
    }

    /// Centre of the detector in patient coordinates (m).
    pub fn detector_center(&self) -> Point3<f64> {
        Point3::from(
            self.isocenter_m
                + self.beam_direction() * (self.source_to_image_m - self.source_to_isocenter_m),
        )
    }

    /// Magnification at the isocenter (SID / SOD).
    pub fn magnification(&self) -> f64 {
        self.source_to_image_m / self.source_to_isocenter_m
    }

    /// The 3×4 projection matrix P: a patient point (x, y, z, 1) maps to (w·u, w·v, w), with
    /// w the depth along the beam (m) and (u, v) pixel coordinates (pixel centres at integers,
    /// (0, 0) the top-left pixel).
    pub fn projection_matrix(&self) -> Matrix3x4<f64> {
        let (eu, ev) = self.detector_axes();
        let d = self.beam_direction();
        let pitch = self.detector.pixel_pitch_m();
        let sid = self.source_to_image_m;
        let (cu, cv) = self.detector.center_px();
        // Intrinsics: u = sid/pitch · (x·eu)/(x·d) + cu, in source-centred coordinates.
        let k = Matrix3::new(sid / pitch, 0.0, cu, 0.0, sid / pitch, cv, 0.0, 0.0, 1.0);
        let r = Matrix3::from_rows(&[eu.transpose(), ev.transpose(), d.transpose()]);
        let t = -(r * self.source().coords);
        let mut extrinsic = Matrix3x4::zeros();
        extrinsic.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        extrinsic.set_column(3, &t);
        k * extrinsic
    }

    /// Pixel coordinates of a patient point; `None` behind the source.
    pub fn project(&self, point: &Point3<f64>) -> Option<Vector2<f64>> {
        let h = self.projection_matrix() * point.to_homogeneous();
        (h.z > 0.0).then(|| Vector2::new(h.x / h.z, h.y / h.z))
    }

    /// The ray from the source through pixel (u, v) (pixel centres at integers).
    pub fn ray(&self, u: f64, v: f64) -> Ray {
        self.ray_grid().ray(u, v)
    }

    /// The pose's rays, set up once for a whole image.
    pub fn ray_grid(&self) -> RayGrid {
        let (eu, ev) = self.detector_axes();
        let pitch = self.detector.pixel_pitch_m();
        let (cu, cv) = self.detector.center_px();
        RayGrid {
            source: self.source(),
            // The detector point of pixel (0, 0).
            corner: self.detector_center() - eu * (cu * pitch) - ev * (cv * pitch),
            step_u: eu * pitch,
            step_v: ev * pitch,
        }
    }
}

/// Every pixel's ray of one pose: the source and the detector plane as a corner and two
/// per-pixel steps (m, patient coordinates).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayGrid {
    /// The focal spot.
    pub source: Point3<f64>,
    /// Detector position of pixel (0, 0)'s centre.
    pub corner: Point3<f64>,
    /// Detector displacement from one column to the next.
    pub step_u: Vector3<f64>,
    /// Detector displacement from one row to the next.
    pub step_v: Vector3<f64>,
}

impl RayGrid {
    /// The ray through pixel (u, v) (pixel centres at integers).
    #[inline]
    pub fn ray(&self, u: f64, v: f64) -> Ray {
        let to = self.corner + self.step_u * u + self.step_v * v - self.source;
        let length_m = to.norm();
        Ray {
            origin: self.source,
            direction: to / length_m,
            length_m,
        }
    }
}
