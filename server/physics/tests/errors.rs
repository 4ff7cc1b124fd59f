//! Bad input gets typed errors naming the problem; divergence is reported and rolled back.

use cathlab_physics::{
    BeamModel, Device, PhysicsError, RestShape, Section, SolverSettings, StepMode, presets,
};
use nalgebra::{UnitQuaternion, Vector3};

fn sections() -> Vec<Section> {
    presets::micro_catheter().sections
}

fn with(edit: impl FnOnce(&mut Section)) -> Result<Device, PhysicsError> {
    let mut s = sections();
    edit(&mut s[1]);
    Device::new("bad", s)
}

#[test]
fn invalid_parameters_are_named() {
    let cases: Vec<(Result<Device, PhysicsError>, &str)> = vec![
        (with(|s| s.length_m = 0.0), "length_m must be > 0"),
        (with(|s| s.length_m = -1.0), "length_m must be > 0"),
        (
            with(|s| s.cross_section.outer_radius_m = 0.0),
            "outer_radius_m must be > 0",
        ),
        (
            with(|s| s.cross_section.inner_radius_m = 1.0),
            "inner radius",
        ),
        (
            with(|s| s.cross_section.inner_radius_m = -1e-4),
            "inner_radius_m must be in",
        ),
        (
            with(|s| s.material.young_modulus_pa = -5.0),
            "young_modulus_pa must be > 0",
        ),
        (
            with(|s| s.material.young_modulus_pa = f64::NAN),
            "young_modulus_pa must be finite",
        ),
        (
            with(|s| s.material.poisson_ratio = 0.5),
            "poisson_ratio must be in (-1, 0.5)",
        ),
        (
            with(|s| s.material.poisson_ratio = -1.0),
            "poisson_ratio must be in (-1, 0.5)",
        ),
        (
            with(|s| s.material.density_kg_m3 = 0.0),
            "density_kg_m3 must be > 0",
        ),
        (
            with(|s| s.friction_coefficient = -0.1),
            "friction_coefficient",
        ),
        (
            with(|s| s.friction_coefficient = f64::INFINITY),
            "friction_coefficient must be finite",
        ),
        (
            with(|s| s.rest_shape = RestShape::j(0.0, 1.0)),
            "rest arc 0 length_m must be > 0",
        ),
        (
            with(|s| s.rest_shape = RestShape::j(1.0, 3.0)),
            "curved length",
        ),
        (
            with(|s| s.rest_shape = RestShape::angled(f64::NAN, 0.01)),
            "rest arc 0 curvature_per_m must be finite",
        ),
        (
            Device::new("short", sections()[..2].to_vec()),
            "at least 3 are required",
        ),
    ];
    for (result, needle) in cases {
        let err = result.expect_err(needle).to_string();
        assert!(err.contains(needle), "{err:?} should mention {needle:?}");
        assert!(
            err.contains("transition") || err.contains("short"),
            "{err:?} should name the section"
        );
    }
}

#[test]
fn invalid_model_inputs_are_errors_not_panics() {
    let device = presets::micro_catheter();
    let s = SolverSettings::default();
    assert!(matches!(
        BeamModel::from_device(&device, 0, s),
        Err(PhysicsError::TooFewElements { .. })
    ));
    assert!(BeamModel::from_device_part(&device, 0.5, 0.2, 10, s).is_err());
    assert!(BeamModel::from_device_part(&device, 0.0, 99.0, 10, s).is_err());
    assert!(BeamModel::from_device_part(&device, f64::NAN, 1.0, 10, s).is_err());
    let mut model = BeamModel::from_device(&device, 10, s).unwrap();
    assert!(
        model
            .set_load(99, Vector3::zeros(), Vector3::zeros())
            .is_err()
    );
    assert!(
        model
            .set_load(3, Vector3::new(f64::NAN, 0.0, 0.0), Vector3::zeros())
            .is_err()
    );
    assert!(model.drive_base(f64::INFINITY, 0.0).is_err());
    assert!(
        model
            .set_base_pose(Vector3::new(0.0, f64::NAN, 0.0), UnitQuaternion::identity())
            .is_err()
    );
    model.set_settings(SolverSettings {
        mode: StepMode::Incremental { gamma: 0.0 },
        ..s
    });
    assert!(matches!(model.step(), Err(PhysicsError::OutOfRange { .. })));
    model.set_settings(SolverSettings {
        mode: StepMode::Converged {
            tolerance: -1.0,
            max_iterations: 5,
        },
        ..s
    });
    assert!(matches!(
        model.step(),
        Err(PhysicsError::NotPositive { .. })
    ));
}

#[test]
fn divergence_is_detected_and_the_state_kept() {
    let device = presets::micro_guidewire_014();
    let mut model = BeamModel::from_device(&device, 20, SolverSettings::default()).unwrap();
    model.step().unwrap();
    let before = model.positions().to_vec();
    // An absurd load makes the linear solve move nodes by light-years.
    model
        .set_load(20, Vector3::new(0.0, 1e300, 0.0), Vector3::zeros())
        .unwrap();
    let err = model.step().unwrap_err();
    assert!(
        matches!(err, PhysicsError::Diverged { node: _, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("diverged"), "{err}");
    // The second step, numbered from 1, and the check that tripped (a finite but huge
    // increment, not a NaN).
    assert!(err.to_string().starts_with("step 2, node "), "{err}");
    assert!(
        err.to_string().contains("translation increment of"),
        "{err}"
    );
    assert_eq!(model.positions(), &before[..], "state must be rolled back");
    assert!(
        model
            .positions()
            .iter()
            .all(|p| p.iter().all(|v| v.is_finite()))
    );
}
