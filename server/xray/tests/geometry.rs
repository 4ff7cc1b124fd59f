//! C-arm projection against hand-computed cases, and ray/projection consistency.

use cathlab_xray::geometry::{CArm, DetectorGeometry};
use nalgebra::{Point3, Vector3};
use proptest::prelude::*;

const CENTER: f64 = 255.5;

/// Pixels per metre at the isocenter for the default C-arm (512 px over 0.25 m, SID/SOD 1.5).
fn px_per_m_at_iso() -> f64 {
    1.5 / (0.25 / 512.0)
}

fn close(a: f64, b: f64) {
    assert!((a - b).abs() < 1e-9, "{a} vs {b}");
}

#[test]
fn ap_view_hand_computed() {
    let c = CArm::default();
    close(c.source().y, 0.8);
    close(c.detector_center().y, -0.4);
    let iso = c.project(&Point3::origin()).unwrap();
    close(iso.x, CENTER);
    close(iso.y, CENTER);
    // 10 mm to the patient's left: right of centre, magnified 1.5×.
    let left = c.project(&Point3::new(0.01, 0.0, 0.0)).unwrap();
    close(left.x, CENTER + 0.01 * px_per_m_at_iso());
    close(left.y, CENTER);
    // 10 mm superior: above centre.
    let head = c.project(&Point3::new(0.0, 0.0, 0.01)).unwrap();
    close(head.y, CENTER - 0.01 * px_per_m_at_iso());
    // 0.2 m nearer the detector (anterior): magnification 1.2 / 1.0.
    let near = c.project(&Point3::new(0.01, -0.2, 0.0)).unwrap();
    close(near.x, CENTER + 0.01 * 1.2 / (0.25 / 512.0));
}

#[test]
fn lao_90_puts_the_detector_on_the_patients_left() {
    let c = CArm {
        primary_deg: 90.0,
        ..CArm::default()
    };
    let d = c.beam_direction();
    assert!((d - Vector3::x()).norm() < 1e-12, "{d}");
    assert!(c.detector_center().x > 0.0);
    // Posterior shows to the right, head still at the top.
    let back = c.project(&Point3::new(0.0, 0.01, 0.0)).unwrap();
    close(back.x, CENTER + 0.01 * px_per_m_at_iso());
    let head = c.project(&Point3::new(0.0, 0.0, 0.01)).unwrap();
    close(head.y, CENTER - 0.01 * px_per_m_at_iso());
    let rao = CArm {
        primary_deg: -90.0,
        ..CArm::default()
    };
    assert!(rao.detector_center().x < 0.0);
}

#[test]
fn cranial_tilt_moves_the_detector_towards_the_head() {
    let c = CArm {
        secondary_deg: 30.0,
        ..CArm::default()
    };
    let d = c.beam_direction();
    let s = 30f64.to_radians();
    assert!(
        (d - Vector3::new(0.0, -s.cos(), s.sin())).norm() < 1e-12,
        "{d}"
    );
    let caudal = CArm {
        secondary_deg: -30.0,
        ..CArm::default()
    };
    assert!(caudal.detector_center().z < 0.0);
}

#[test]
fn table_moves_the_isocenter_and_zoom_the_pitch() {
    let c = CArm {
        isocenter_m: Vector3::new(0.05, 0.0, -0.1),
        detector: DetectorGeometry {
            field_of_view_m: 0.125,
            ..DetectorGeometry::default()
        },
        ..CArm::default()
    };
    let p = c.project(&Point3::new(0.05, 0.0, -0.1)).unwrap();
    close(p.x, CENTER);
    let q = c.project(&Point3::new(0.06, 0.0, -0.1)).unwrap();
    close(q.x - CENTER, 2.0 * 0.01 * px_per_m_at_iso());
}

#[test]
fn bad_geometry_is_named() {
    let nan = CArm {
        primary_deg: f64::NAN,
        ..CArm::default()
    };
    assert!(
        nan.validate()
            .unwrap_err()
            .to_string()
            .contains("primary angle")
    );
    let empty = CArm {
        detector: DetectorGeometry {
            width_px: 0,
            ..DetectorGeometry::default()
        },
        ..CArm::default()
    };
    assert!(
        empty
            .validate()
            .unwrap_err()
            .to_string()
            .contains("detector width")
    );
    let inverted = CArm {
        source_to_isocenter_m: 1.5,
        ..CArm::default()
    };
    assert!(
        inverted
            .validate()
            .unwrap_err()
            .to_string()
            .contains("source-to-isocenter")
    );
    let collimated = CArm {
        detector: DetectorGeometry {
            collimation: (0.0, 1.0),
            ..DetectorGeometry::default()
        },
        ..CArm::default()
    };
    assert!(collimated.validate().is_err());
    // Half-open collimation: the centre is exposed, the edges are not.
    let half = DetectorGeometry {
        collimation: (0.5, 0.5),
        ..DetectorGeometry::default()
    };
    assert!(half.is_exposed(CENTER, CENTER));
    assert!(half.is_exposed(CENTER + 127.0, CENTER));
    assert!(!half.is_exposed(CENTER + 129.0, CENTER));
    assert!(!half.is_exposed(CENTER, 0.0));
    assert!(CArm::default().validate().is_ok());
}

proptest! {
    #[test]
    fn every_point_on_a_pixel_ray_projects_to_that_pixel(
        primary in -120.0f64..120.0,
        secondary in -45.0f64..45.0,
        u in 0.0f64..511.0,
        v in 0.0f64..511.0,
        depth in 0.3f64..1.1,
    ) {
        let c = CArm { primary_deg: primary, secondary_deg: secondary, ..CArm::default() };
        let ray = c.ray(u, v);
        let p = ray.origin + ray.direction * depth;
        let back = c.project(&p).unwrap();
        prop_assert!((back.x - u).abs() < 1e-7 && (back.y - v).abs() < 1e-7);
        // The ray ends on the detector plane.
        let end = ray.origin + ray.direction * ray.length_m;
        prop_assert!(((end - c.detector_center()).dot(&c.beam_direction())).abs() < 1e-12);
    }
}
