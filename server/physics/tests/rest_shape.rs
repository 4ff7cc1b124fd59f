//! Rest shapes: a J tip straightened and released springs back; base twist turns the tip.

use cathlab_physics::beam::ElementSpec;
use cathlab_physics::presets;
use cathlab_physics::{
    BeamModel, CircularSection, Device, Material, RestShape, Section, SolverSettings, StepMode,
};
use nalgebra::{UnitQuaternion, Vector3};

/// A 9 cm guidewire end with a 3 mm J (π) tip, 1 mm elements.
fn j_tip_wire() -> Device {
    let section = |name: &str, length_m, young, rest_shape| Section {
        name: name.into(),
        length_m,
        cross_section: CircularSection::solid(0.445e-3),
        material: Material {
            young_modulus_pa: young,
            poisson_ratio: 0.33,
            density_kg_m3: 6450.0,
        },
        friction_coefficient: 0.04,
        lumen_friction_coefficient: 0.04,
        rest_shape,
    };
    Device::new(
        "J-tip test wire",
        vec![
            section("shaft", 0.05, 60e9, RestShape::straight()),
            section("transition", 0.02, 15e9, RestShape::straight()),
            section("tip", 0.02, 2e9, RestShape::j(0.003, std::f64::consts::PI)),
        ],
    )
    .unwrap()
}

fn max_distance(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max)
}

fn tip_direction(model: &BeamModel) -> Vector3<f64> {
    model.rotations().last().unwrap() * Vector3::x()
}

#[test]
fn j_tip_pulled_straight_returns_to_rest_when_released() {
    let device = j_tip_wire();
    for (name, settings, release_steps) in [
        (
            "converged",
            SolverSettings {
                mode: StepMode::CONVERGED,
                ..Default::default()
            },
            5,
        ),
        ("paper", SolverSettings::default(), 400),
    ] {
        let mut model = BeamModel::from_device(&device, 90, settings).unwrap();
        let rest = model.positions().to_vec();
        // At rest the J points back along −x.
        assert!(
            tip_direction(&model).x < -0.95,
            "{name}: rest tip {:?}",
            tip_direction(&model)
        );
        let tip = model.node_count() - 1;
        // Pull the tip along +x with a force well above EI·κ² of the J: the bending boundary
        // layer sqrt(EI/T) is then R/7, so only the last fraction of a millimetre stays bent.
        let ei = device.sections[2].beam_properties().bending_stiffness_nm2;
        let pull = 50.0 * ei / 0.003f64.powi(2);
        let ramp = 2000;
        for k in 1..=ramp {
            model
                .set_load(
                    tip,
                    Vector3::x() * pull * k as f64 / ramp as f64,
                    Vector3::zeros(),
                )
                .unwrap();
            model.step().unwrap();
        }
        for _ in 0..release_steps {
            model.step().unwrap();
        }
        let pulled = tip_direction(&model);
        assert!(pulled.x > 0.9, "{name}: pulled tip direction {pulled:?}");
        // The J has opened: the tip is now ahead of where the J turned back.
        assert!(
            model.tip_position().x > rest.last().unwrap().x + 0.005,
            "{name}"
        );
        // Release.
        model.clear_loads();
        for _ in 0..release_steps {
            model.step().unwrap();
        }
        let error = max_distance(model.positions(), &rest);
        println!("{name}: max node distance from rest after release {error:.3e} m");
        assert!(error < 1e-6, "{name}: {error}");
    }
}

#[test]
fn twisting_the_base_rotates_an_angled_tip() {
    let device = cathlab_physics::presets::diagnostic_catheter_5f();
    // The distal 10 cm (shaft, transition and the 45° tip) in 2 mm elements.
    let length = device.length_m();
    let settings = SolverSettings {
        mode: StepMode::CONVERGED,
        ..Default::default()
    };
    let mut model =
        BeamModel::from_device_part(&device, length - 0.1, length, 50, settings).unwrap();
    let rest_tip = model.tip_position();
    assert!(
        rest_tip.y > 1e-3,
        "the angled tip bends towards +y at rest: {rest_tip:?}"
    );
    let turns = 12;
    for _ in 0..turns {
        model
            .drive_base(0.0, std::f64::consts::FRAC_PI_2 / turns as f64)
            .unwrap();
        let report = model.step().unwrap();
        assert!(report.converged);
    }
    // A free device turns rigidly: the tip is the rest tip rotated 90° about the shaft (x).
    let expected =
        UnitQuaternion::from_scaled_axis(Vector3::x() * std::f64::consts::FRAC_PI_2) * rest_tip;
    let error = (model.tip_position() - expected).norm();
    assert!(
        error < 1e-9,
        "tip {:?} expected {expected:?}",
        model.tip_position()
    );
    // Pushing moves it along the shaft.
    model.drive_base(0.01, 0.0).unwrap();
    model.step().unwrap();
    assert!((model.tip_position() - expected - Vector3::x() * 0.01).norm() < 1e-9);
}

#[test]
fn twist_is_transmitted_through_a_held_tip() {
    // Hold the tip's rotation about the shaft with a torsional spring-like opposing moment:
    // the base twist then stores torsion GJ·φ/L along the device, and the reaction torque at
    // the base equals the moment at the tip.
    let device = cathlab_physics::presets::micro_catheter();
    let length = device.length_m();
    let settings = SolverSettings {
        mode: StepMode::CONVERGED,
        ..Default::default()
    };
    let mut model =
        BeamModel::from_device_part(&device, length - 0.05, length, 25, settings).unwrap();
    let tip = model.node_count() - 1;
    let torque = 1e-5;
    model
        .set_load(tip, Vector3::zeros(), Vector3::x() * torque)
        .unwrap();
    model.step().unwrap();
    let gj = device.sections[2].beam_properties().torsional_stiffness_nm2;
    let twist = (model.rotations()[tip].scaled_axis()).x;
    assert!(
        ((twist - torque * 0.05 / gj) / twist).abs() < 1e-6,
        "twist {twist}"
    );
    let reaction = model.base_reaction();
    assert!(
        (reaction[3] + torque).abs() < 1e-9 * torque.max(1.0),
        "base reaction {reaction:?}"
    );
}

/// A 0.035" wire at rest as a circular arc of radius 20 mm: eight 5 mm elements.
fn arc_model() -> (BeamModel, ElementSpec, f64) {
    let props = presets::guidewire_035().sections[0].beam_properties();
    let radius = 0.02;
    let spec = ElementSpec::planar(props, 5e-3, 1.0 / radius);
    let model = BeamModel::new(
        &[spec; 8],
        Vector3::zeros(),
        UnitQuaternion::identity(),
        SolverSettings::default(),
    )
    .unwrap();
    (model, spec, radius)
}

#[test]
fn splitting_an_arc_places_the_new_node_on_the_arc_and_keeps_it_at_rest() {
    let (mut model, spec, radius) = arc_model();
    let before = model.positions().to_vec();
    let half = ElementSpec {
        length_m: 2.5e-3,
        ..spec
    };
    model.split_element(3, half, half).unwrap();
    let after = model.positions().to_vec();
    assert_eq!(after.len(), before.len() + 1);
    // No existing node moved.
    assert_eq!(&after[..4], &before[..4]);
    assert_eq!(&after[5..], &before[4..]);
    // The arc bends about material z towards +y: its centre is at (0, R, 0).
    let centre = Vector3::new(0.0, radius, 0.0);
    let off_arc = ((after[4] - centre).norm() - radius).abs();
    let sagitta = radius * (1.0 - (2.5e-3 / radius).cos());
    println!("new node {off_arc:.3e} m off the arc; the chord midpoint would be {sagitta:.3e} m");
    assert!(off_arc < 1e-3 * sagitta, "{off_arc}");
    let tangent = model.rotations()[4] * Vector3::x();
    let exact = Vector3::z().cross(&(after[4] - centre)).normalize();
    assert!(tangent.angle(&exact) < 1e-9, "{}", tangent.angle(&exact));
    // Two curved halves of a curved element at rest are still at rest: a step moves nothing.
    let report = model.step().unwrap();
    assert!(report.converged);
    let moved = max_distance(model.positions(), &after);
    assert!(moved < 1e-12, "{moved}");
    // Merging back gives the original model.
    model.merge_elements(3, spec).unwrap();
    assert!(max_distance(model.positions(), &before) < 1e-12);
    assert!(model.split_element(9, half, half).is_err());
    assert!(model.merge_elements(7, spec).is_err());
}

#[test]
fn pulling_out_joins_the_base_elements_without_compressing_them() {
    // A straight 0.035" wire laid on an arc of 20 mm radius (bent, so each chord is shorter
    // than its element): elements of 2.5, 5, 5 and 5 mm from the entry.
    let props = presets::guidewire_035().sections[0].beam_properties();
    let lengths = [2.5e-3, 5e-3, 5e-3, 5e-3];
    let specs: Vec<ElementSpec> = lengths
        .iter()
        .map(|&l| ElementSpec::planar(props, l, 0.0))
        .collect();
    let mut model = BeamModel::new(
        &specs,
        Vector3::zeros(),
        UnitQuaternion::identity(),
        SolverSettings::default(),
    )
    .unwrap();
    let radius = 0.02;
    let mut s = 0.0;
    let mut positions = vec![Vector3::zeros()];
    let mut rotations = vec![UnitQuaternion::identity()];
    for &l in &lengths {
        s += l;
        let angle = s / radius;
        positions.push(Vector3::new(
            radius * angle.sin(),
            radius * (1.0 - angle.cos()),
            0.0,
        ));
        rotations.push(UnitQuaternion::from_axis_angle(&Vector3::z_axis(), angle));
    }
    model.set_nodes(&positions, &rotations).unwrap();
    let chord = |p: &[Vector3<f64>], e: usize| (p[e + 1] - p[e]).norm();
    let before = model.positions().to_vec();
    let stretch_before = (chord(&before, 0) + chord(&before, 1)) / (lengths[0] + lengths[1]) - 1.0;
    let as_they_lay = (before[2] - before[0]).norm() / (lengths[0] + lengths[1]) - 1.0;
    model
        .remove_node_after_base(ElementSpec::planar(props, lengths[0] + lengths[1], 0.0))
        .unwrap();
    let after = model.positions().to_vec();
    let stretch_after = chord(&after, 0) / (lengths[0] + lengths[1]) - 1.0;
    println!(
        "the two base elements' stretch {stretch_before:.3e}; joined {stretch_after:.3e} \
         (joined as they lay: {as_they_lay:.3e}, {:.1} N more compression)",
        (stretch_before - as_they_lay) * props.axial_stiffness_n
    );
    // The joined element is stretched as the two were together, not squeezed by its chord
    // cutting the bend; the nodes beyond keep their elements' chords.
    assert!((stretch_after - stretch_before).abs() < 1e-12);
    assert!(
        stretch_before - as_they_lay > 1e-5,
        "the test bends the wire"
    );
    for e in 1..after.len() - 1 {
        assert!((chord(&after, e) - chord(&before, e + 1)).abs() < 1e-15);
    }
}
