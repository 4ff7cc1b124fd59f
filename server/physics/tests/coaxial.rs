//! Coaxial stacks in merged mode: composite stiffness against analytic cantilevers, the
//! stiffness-weighted blend of rest shapes, twist of one instrument without the other,
//! invariants of the instruments' positions, and bad input.
//!
//! Figures print with `cargo test -p cathlab-physics --test coaxial -- --nocapture`.

use std::f64::consts::PI;

use cathlab_physics::navigation::{Command, Insertion, NavigationSettings, Twist};
use cathlab_physics::scenarios::{CoaxialPlan, run_coaxial_arch_to_cow};
use cathlab_physics::{
    BeamModel, Catalogue, CircularSection, Coupling, Device, FreeSpace, InstrumentSpec, Material,
    PhysicsError, RestArc, RestShape, Section, SolverSettings, Stack, StepMode, presets,
};
use nalgebra::{UnitQuaternion, Vector3};
use proptest::prelude::*;

/// A uniform device of three identical sections, the distal one with `tip_shape`.
fn uniform(
    name: &str,
    length_m: f64,
    outer_diameter_m: f64,
    inner_diameter_m: f64,
    young_modulus_pa: f64,
    tip_shape: RestShape,
) -> Device {
    let section = |label: &str, length_m: f64, rest_shape: RestShape| Section {
        name: label.into(),
        length_m,
        cross_section: CircularSection {
            outer_radius_m: outer_diameter_m / 2.0,
            inner_radius_m: inner_diameter_m / 2.0,
        },
        material: Material {
            young_modulus_pa,
            poisson_ratio: 0.35,
            density_kg_m3: 2000.0,
        },
        friction_coefficient: 0.05,
        lumen_friction_coefficient: 0.04,
        rest_shape,
    };
    Device::new(
        name,
        vec![
            section("shaft", 0.8 * length_m, RestShape::straight()),
            section("transition", 0.1 * length_m, RestShape::straight()),
            section("tip", 0.1 * length_m, tip_shape),
        ],
    )
    .unwrap()
}

/// A straight 5 F-like tube and a straight 0.035"-like wire.
fn straight_pair() -> (Device, Device) {
    (
        uniform("tube", 1.0, 1.67e-3, 0.97e-3, 2.5e9, RestShape::straight()),
        uniform("wire", 1.5, 0.889e-3, 0.0, 60e9, RestShape::straight()),
    )
}

/// A free-space stack entering along x at the origin, with default settings.
fn coupled_stack(devices: Vec<(Device, f64)>, coupling: Coupling) -> Stack<FreeSpace> {
    let settings = NavigationSettings::default();
    let specs = devices
        .into_iter()
        .map(|(d, l)| InstrumentSpec::new(d, l, &settings))
        .collect();
    Stack::with_coupling(
        specs,
        FreeSpace,
        Vector3::zeros(),
        Vector3::x(),
        settings,
        coupling,
    )
    .unwrap()
}

fn free_stack(devices: Vec<(Device, f64)>) -> Stack<FreeSpace> {
    coupled_stack(devices, Coupling::Merged)
}

/// Switches the strand's model to a converged static solve without drag.
fn static_solve(model: &mut BeamModel) {
    model.set_settings(SolverSettings {
        mode: StepMode::Converged {
            tolerance: 1e-12,
            max_iterations: 200,
        },
        ..SolverSettings::default()
    });
    let report = model.step().unwrap();
    assert!(
        report.converged,
        "static solve did not converge: {report:?}"
    );
}

/// E·I of a circular tube (N·m²).
fn ei(young: f64, outer_d: f64, inner_d: f64) -> f64 {
    young * PI / 64.0 * (outer_d.powi(4) - inner_d.powi(4))
}

/// κ·G·A of a circular tube (N), Cowper's κ.
fn kga(young: f64, nu: f64, outer_d: f64, inner_d: f64) -> f64 {
    let m = inner_d / outer_d;
    let m2 = m * m;
    let kappa = 6.0 * (1.0 + nu) * (1.0 + m2).powi(2)
        / ((7.0 + 6.0 * nu) * (1.0 + m2).powi(2) + (20.0 + 12.0 * nu) * m2);
    kappa * young / (2.0 * (1.0 + nu)) * PI / 4.0 * (outer_d * outer_d - inner_d * inner_d)
}

#[test]
fn composite_cantilever_matches_the_summed_stiffness() {
    let (tube, wire) = straight_pair();
    let ei_tube = ei(2.5e9, 1.67e-3, 0.97e-3);
    let ei_wire = ei(60e9, 0.889e-3, 0.0);
    let kga_tube = kga(2.5e9, 0.35, 1.67e-3, 0.97e-3);
    let kga_wire = kga(60e9, 0.35, 0.889e-3, 0.0);
    let length = 0.1;
    // Full overlap: tips flush.
    let p = 1e-7 * (ei_tube + ei_wire) / (length * length);
    let mut stack = free_stack(vec![(tube.clone(), length), (wire.clone(), length)]);
    let model = stack.model_mut();
    let tip = model.node_count() - 1;
    model
        .set_load(tip, Vector3::new(0.0, p, 0.0), Vector3::zeros())
        .unwrap();
    static_solve(model);
    let deflection = model.tip_position().y;
    let expected =
        p * length.powi(3) / (3.0 * (ei_tube + ei_wire)) + p * length / (kga_tube + kga_wire);
    let error = (deflection - expected).abs() / expected;
    println!(
        "full overlap: deflection {deflection:.6e} m, analytic {expected:.6e} m, relative error {error:.1e}"
    );
    assert!(error < 1e-9, "full overlap relative error {error:e}");

    // Partial overlap: the wire leads 40 mm out of the tube; two-segment cantilever.
    let (a, l) = (0.06, 0.1);
    let ei_a = ei_tube + ei_wire;
    let p = 1e-7 * ei_wire / (l * l);
    let mut stack = free_stack(vec![(tube, a), (wire, l)]);
    let model = stack.model_mut();
    let tip = model.node_count() - 1;
    model
        .set_load(tip, Vector3::new(0.0, p, 0.0), Vector3::zeros())
        .unwrap();
    static_solve(model);
    let v_a = p * a * a * (3.0 * l - a) / (6.0 * ei_a) + p * a / (kga_tube + kga_wire);
    let theta_a = p * a * (2.0 * l - a) / (2.0 * ei_a);
    let expected =
        v_a + theta_a * (l - a) + p * (l - a).powi(3) / (3.0 * ei_wire) + p * (l - a) / kga_wire;
    let deflection = model.tip_position().y;
    let error = (deflection - expected).abs() / expected;
    println!(
        "partial overlap: deflection {deflection:.6e} m, analytic {expected:.6e} m, relative error {error:.1e}"
    );
    assert!(error < 1e-9, "partial overlap relative error {error:e}");
}

/// Curvature (1/m) of the strand between path coordinates `a` < `b`: the rotation angle
/// between the frames there over the arc length.
fn curvature_between(stack: &Stack<FreeSpace>, a: f64, b: f64) -> f64 {
    let (_, qa) = stack.point_at(a);
    let (_, qb) = stack.point_at(b);
    (qa * Vector3::x()).angle(&(qb * Vector3::x())) / (b - a)
}

/// Node path coordinates strictly inside (a, b), first and last.
fn nodes_within(stack: &Stack<FreeSpace>, a: f64, b: f64) -> (f64, f64) {
    let inside: Vec<f64> = stack
        .node_sigma_m()
        .into_iter()
        .filter(|&s| s > a + 1e-9 && s < b - 1e-9)
        .collect();
    (inside[0], *inside.last().unwrap())
}

fn run_to_targets(stack: &mut Stack<FreeSpace>, targets: &[(usize, Option<f64>, Option<f64>)]) {
    for &(i, inserted, twist) in targets {
        let current = stack.command(i).unwrap();
        stack
            .set_command(
                i,
                Command {
                    insertion: inserted.map_or(current.insertion, Insertion::Target),
                    twist: twist.map_or(current.twist, Twist::Target),
                },
            )
            .unwrap();
    }
    for _ in 0..20_000 {
        stack.step().unwrap();
        let done = targets.iter().all(|&(i, inserted, twist)| {
            inserted.is_none_or(|l| stack.inserted_m(i).unwrap() == l)
                && twist.is_none_or(|t| stack.twist_rad(i).unwrap() == t)
        });
        if done {
            return;
        }
    }
    panic!("targets not reached");
}

#[test]
fn j_wire_straightens_inside_a_catheter_and_recovers_outside() {
    let mut catheter = presets::diagnostic_catheter_5f();
    catheter.sections[2].rest_shape = RestShape::straight();
    let wire = presets::guidewire_035();
    let radius = 0.003;
    let j_length = radius * PI;
    let (l_cath, l_wire) = (0.15, 0.14);
    let mut stack = free_stack(vec![(catheter, l_cath), (wire, l_wire)]);
    static_solve(stack.model_mut());
    // Inside: the catheter's soft tip (0.15 GPa) around the wire's coil tip (2 GPa).
    let ei_cath = ei(0.15e9, 5e-3 / 3.0, 0.038 * 0.0254);
    let ei_wire = ei(2e9, 0.035 * 0.0254, 0.0);
    let blend = ei_wire / (ei_wire + ei_cath) / radius;
    let (a, b) = nodes_within(&stack, l_wire - j_length, l_wire);
    let inside = curvature_between(&stack, a, b);
    let error = (inside - blend).abs() / blend;
    println!(
        "J inside the catheter: curvature {inside:.4} 1/m, blend formula {blend:.4} 1/m (rest {:.4}), relative error {error:.1e}",
        1.0 / radius
    );
    assert!(error < 1e-6, "blend error {error:e}");
    // Pushed 30 mm out of the catheter tip: the J comes back.
    run_to_targets(&mut stack, &[(1, Some(l_cath + 0.03), None)]);
    static_solve(stack.model_mut());
    let end = l_cath + 0.03;
    let (a, b) = nodes_within(&stack, end - j_length, end);
    let outside = curvature_between(&stack, a, b);
    let error = (outside * radius - 1.0).abs();
    println!("J pushed 30 mm out: curvature {outside:.6} 1/m, relative error {error:.1e}");
    assert!(error < 1e-6, "recovered J error {error:e}");
}

/// Unit bend direction of the strand between path coordinates `a` < `b`: where the tangent
/// turns to, across the tangent at `a`.
fn bend_direction(stack: &Stack<FreeSpace>, a: f64, b: f64) -> (Vector3<f64>, Vector3<f64>) {
    let ta = stack.point_at(a).1 * Vector3::x();
    let tb = stack.point_at(b).1 * Vector3::x();
    ((tb - ta * ta.dot(&tb)).normalize(), ta)
}

/// Angle (rad) of `direction` about `tangent` from the entry's +y axis carried to `tangent`
/// by the minimal rotation (parallel transport along a planar path).
fn roll_angle(direction: &Vector3<f64>, tangent: &Vector3<f64>) -> f64 {
    let carry = UnitQuaternion::rotation_between(&Vector3::x(), tangent)
        .unwrap_or_else(UnitQuaternion::identity);
    let reference = carry * Vector3::y();
    let across = tangent.cross(&reference);
    direction.dot(&across).atan2(direction.dot(&reference))
}

fn wrap(angle: f64) -> f64 {
    (angle + PI).rem_euclid(2.0 * PI) - PI
}

#[test]
fn twisting_one_instrument_turns_its_curve_and_not_the_others() {
    let catheter = presets::diagnostic_catheter_5f(); // 45° over the distal 8 mm
    let wire = presets::guidewire_035_shaped(45f64.to_radians(), 0.010);
    let (l_cath, l_wire) = (0.15, 0.17);
    let measure = |stack: &Stack<FreeSpace>| {
        let (c, ct) = bend_direction(stack, l_cath - 0.012, l_cath - 0.001);
        let (w, wt) = bend_direction(stack, l_wire - 0.011, l_wire);
        (roll_angle(&c, &ct), roll_angle(&w, &wt))
    };
    turn_each_alone(
        ("", "catheter", 6),
        || free_stack(vec![(catheter.clone(), l_cath), (wire.clone(), l_wire)]),
        |stack| static_solve(stack.model_mut()),
        measure,
        1e-6,
    );
}

/// Turns each of a two-instrument stack's instruments 90° on its own (a fresh stack each
/// time, brought to rest by `solve` before and after) and checks that its curve turns 90° and
/// the other's not, within `tolerance` (rad). `measure` gives the roll angles (rad) of the
/// outer's curve and the wire's tip; `(label, outer, digits)` name them in the printout.
fn turn_each_alone(
    (label, outer, digits): (&str, &str, usize),
    new_stack: impl Fn() -> Stack<FreeSpace>,
    solve: impl Fn(&mut Stack<FreeSpace>),
    measure: impl Fn(&Stack<FreeSpace>) -> (f64, f64),
    tolerance: f64,
) {
    for (turned, name) in [(0, outer), (1, "wire")] {
        let mut stack = new_stack();
        solve(&mut stack);
        let (outer0, wire0) = measure(&stack);
        run_to_targets(&mut stack, &[(turned, None, Some(PI / 2.0))]);
        solve(&mut stack);
        let (outer1, wire1) = measure(&stack);
        let (d_outer, d_wire) = (wrap(outer1 - outer0), wrap(wire1 - wire0));
        println!(
            "{label}{name} turned 90°: {outer} curve turned {:.digits$}°, wire tip turned {:.digits$}°",
            d_outer.to_degrees(),
            d_wire.to_degrees()
        );
        let (expect_outer, expect_wire) = if turned == 0 {
            (PI / 2.0, 0.0)
        } else {
            (0.0, PI / 2.0)
        };
        assert!(
            (d_outer - expect_outer).abs() < tolerance,
            "{outer} curve turned {d_outer}"
        );
        assert!(
            (d_wire - expect_wire).abs() < tolerance,
            "wire tip turned {d_wire}"
        );
    }
}

#[test]
fn a_stack_that_does_not_fit_is_a_typed_error_naming_both_devices() {
    let settings = NavigationSettings::default();
    let microcatheter = presets::micro_catheter();
    let wire = presets::guidewire_035();
    let err = Stack::new(
        vec![
            InstrumentSpec::new(microcatheter, 0.1, &settings),
            InstrumentSpec::new(wire, 0.05, &settings),
        ],
        FreeSpace,
        Vector3::zeros(),
        Vector3::x(),
        settings,
    )
    .unwrap_err();
    assert!(matches!(err, PhysicsError::StackFit { .. }), "{err:?}");
    let text = err.to_string();
    assert!(
        text.contains("0.035in J guidewire") && text.contains("micro-catheter 0.017in ID"),
        "{text}"
    );
}

#[test]
fn stack_bad_input_is_named() {
    let settings = NavigationSettings::default();
    let (tube, wire) = straight_pair();
    let spec = |d: &Device, l| InstrumentSpec::new(d.clone(), l, &settings);
    let make = |specs: Vec<InstrumentSpec>| {
        Stack::new(specs, FreeSpace, Vector3::zeros(), Vector3::x(), settings)
    };
    let too_many = make(vec![spec(&tube, 0.1); 5]).unwrap_err().to_string();
    assert!(too_many.contains("number of instruments"), "{too_many}");
    let none = make(vec![]).unwrap_err().to_string();
    assert!(none.contains("number of instruments"), "{none}");
    let deep = make(vec![spec(&tube, 0.1), spec(&wire, 0.7)])
        .unwrap_err()
        .to_string();
    assert!(deep.contains("instrument 1 \"wire\""), "{deep}");
    let mut stack = make(vec![spec(&tube, 0.1), spec(&wire, 0.05)]).unwrap();
    let nan = stack
        .set_command(
            1,
            Command {
                insertion: Insertion::Velocity(f64::NAN),
                twist: Twist::Rate(0.0),
            },
        )
        .unwrap_err()
        .to_string();
    assert!(nan.contains("instrument 1: insertion command"), "{nan}");
    let missing = stack.set_command(2, Command::default()).unwrap_err();
    assert!(missing.to_string().contains("no instrument 2"), "{missing}");
    let inserted = stack.exchange(1, wire.clone()).unwrap_err().to_string();
    assert!(inserted.contains("still inserted"), "{inserted}");
}

#[test]
fn a_withdrawn_wire_is_exchanged_for_another() {
    let (tube, wire) = straight_pair();
    let mut stack = free_stack(vec![(tube, 0.1), (wire, 0.12)]);
    let (hub, _) = stack.inserted_range_m(1).unwrap();
    run_to_targets(&mut stack, &[(1, Some(hub), None)]);
    let micro = uniform(
        "straight 0.014in wire",
        2.0,
        0.36e-3,
        0.0,
        55e9,
        RestShape::straight(),
    );
    stack.exchange(1, micro.clone()).unwrap();
    assert_eq!(stack.device(1).unwrap(), &micro);
    run_to_targets(&mut stack, &[(1, Some(0.13), None)]);
    let gap = (stack.tip_position(1).unwrap() - stack.tip_position(0).unwrap()).norm();
    assert!((gap - 0.03).abs() < 1e-9, "new wire leads by {gap}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Random pushes and pulls of a straight triaxial stack in free space: every instrument
    /// stays within its range (an inner tip leaves the one around it only through its distal
    /// tip), the strand is as long as the leading instrument is inserted, and the tips lie
    /// on the entry axis at exactly their inserted lengths.
    #[test]
    fn instruments_keep_their_lengths_and_order(
        moves in prop::collection::vec((0usize..3, -0.08f64..0.08), 1..6)
    ) {
        let guide = uniform("guide", 0.9, 2.3e-3, 1.8e-3, 3e9, RestShape::straight());
        let micro = uniform("micro", 1.5, 0.9e-3, 0.45e-3, 1.5e9, RestShape::straight());
        let wire = uniform("wire", 2.0, 0.36e-3, 0.0, 55e9, RestShape::straight());
        let mut stack = free_stack(vec![(guide, 0.10), (micro, 0.08), (wire, 0.12)]);
        for (index, change) in moves {
            let (lo, hi) = stack.inserted_range_m(index).unwrap();
            let target = (stack.inserted_m(index).unwrap() + change).clamp(lo, hi);
            stack.set_command(index, Command {
                insertion: Insertion::Target(target),
                twist: Twist::Rate(0.0),
            }).unwrap();
            for _ in 0..300 {
                stack.step().unwrap();
                for k in 0..3 {
                    let l = stack.inserted_m(k).unwrap();
                    let (lo, hi) = stack.inserted_range_m(k).unwrap();
                    prop_assert!(l >= lo - 1e-12 && l <= hi + 1e-12, "instrument {} at {} outside [{}, {}]", k, l, lo, hi);
                }
                let lead = (0..3).map(|k| stack.inserted_m(k).unwrap()).fold(f64::MIN, f64::max);
                prop_assert!((stack.model().length_m() - lead).abs() < 1e-9);
                if stack.inserted_m(index).unwrap() == target {
                    break;
                }
            }
            for k in 0..3 {
                let l = stack.inserted_m(k).unwrap();
                if let Some(tip) = stack.tip_position(k) {
                    prop_assert!((tip - Vector3::x() * l).norm() < 1e-9, "tip {} at {:?}, inserted {}", k, tip, l);
                }
            }
        }
    }
}

/// A one-device catalogue whose tip section has `field = value`.
fn catalogue_with(field: &str, value: &str) -> String {
    let section = |name: &str, tip: bool| {
        let mut fields = vec![
            ("length_mm", "100.0"),
            ("outer_diameter_mm", "1.67"),
            ("inner_diameter_mm", "0.97"),
            ("young_modulus_gpa", "2.5"),
            ("poisson_ratio", "0.4"),
            ("density_kg_m3", "1150.0"),
            ("wall_friction", "0.05"),
            ("lumen_friction", "0.04"),
        ];
        if tip {
            for f in &mut fields {
                if f.0 == field {
                    f.1 = value;
                }
            }
        }
        let body: String = fields.iter().map(|(k, v)| format!("{k} = {v}\n")).collect();
        format!("[[device.section]]\nname = \"{name}\"\n{body}")
    };
    format!(
        "[[device]]\nid = \"test-catheter\"\nname = \"Test catheter\"\nkind = \"catheter\"\nsource = \"test\"\n{}{}{}",
        section("shaft", false),
        section("transition", false),
        section("tip", true)
    )
}

fn definition_error(text: &str) -> (String, String, String) {
    match Catalogue::from_toml_str(text) {
        Err(PhysicsError::DeviceDefinition {
            device,
            section,
            field,
            ..
        }) => (device, section, field),
        other => panic!("expected a device definition error, got {other:?}"),
    }
}

#[test]
fn catalogue_inner_diameter_not_below_outer_is_named() {
    let (device, section, field) = definition_error(&catalogue_with("inner_diameter_mm", "1.67"));
    assert_eq!(
        (device.as_str(), section.as_str(), field.as_str()),
        ("test-catheter", "section \"tip\"", "inner_diameter_mm")
    );
}

#[test]
fn catalogue_negative_length_is_named() {
    let (device, section, field) = definition_error(&catalogue_with("length_mm", "-5.0"));
    assert_eq!(
        (device.as_str(), section.as_str(), field.as_str()),
        ("test-catheter", "section \"tip\"", "length_mm")
    );
}

#[test]
fn catalogue_nan_is_named() {
    let text = catalogue_with("young_modulus_gpa", "nan");
    let err = Catalogue::from_toml_str(&text).unwrap_err();
    assert!(
        err.to_string()
            .contains("young_modulus_gpa: must be finite"),
        "{err}"
    );
    assert_eq!(
        definition_error(&text).2,
        "young_modulus_gpa",
        "the field is named"
    );
}

#[test]
fn catalogue_arcs_longer_than_their_section_are_named() {
    let text = catalogue_with("lumen_friction", "0.04")
        + "[[device.section.arc]]\nlength_mm = 150.0\nangle_deg = 90.0\n";
    let (_, section, field) = definition_error(&text);
    assert_eq!(
        (section.as_str(), field.as_str()),
        ("section \"tip\"", "arc")
    );
}

#[test]
fn catalogue_syntax_and_unknown_fields_are_errors() {
    let err = Catalogue::from_toml_str(&catalogue_with("length_mm", "\"long\"")).unwrap_err();
    assert!(matches!(err, PhysicsError::CatalogueSyntax(_)), "{err:?}");
    let err =
        Catalogue::from_toml_str(&(catalogue_with("length_mm", "100.0") + "colour = \"blue\"\n"))
            .unwrap_err();
    assert!(err.to_string().contains("colour"), "{err}");
    let unknown = Catalogue::builtin().device("no-such-device").unwrap_err();
    assert!(unknown.to_string().contains("no-such-device"), "{unknown}");
}

#[test]
fn a_user_device_in_toml_runs_in_a_stack() {
    let catalogue = Catalogue::from_toml_str(&catalogue_with("length_mm", "100.0")).unwrap();
    let entry = catalogue.get("test-catheter").unwrap();
    assert!((entry.device.length_m() - 0.3).abs() < 1e-12);
    let mut stack = free_stack(vec![
        (entry.device.clone(), 0.05),
        (presets::guidewire_035(), 0.07),
    ]);
    stack.step().unwrap();
    assert!((stack.tip_position(0).unwrap() - Vector3::x() * 0.05).norm() < 1e-9);
}

/// A 5 F Simmons-like reverse-curve catheter (100 cm): a 180° primary hook over 30 mm, a
/// 30 mm limb, a 30° reverse tip curve over 8 mm.
fn simmons() -> Device {
    let mut catheter = presets::diagnostic_catheter_5f();
    let tip = &mut catheter.sections[2];
    tip.length_m = 0.08;
    tip.rest_shape = RestShape::from_arcs(vec![
        RestArc::bend(0.030, PI, 0.0),
        RestArc::bend(0.030, 0.0, 0.0),
        RestArc::bend(0.008, PI / 6.0, PI),
    ]);
    catheter.sections[1].length_m = 0.02;
    catheter
}

/// Signed turning (rad) of a curve in the world x–y plane from path coordinate `a` to `b`,
/// summed over 0.5 mm pieces (so that turns beyond 180° unwrap).
fn turning(stack: &Stack<FreeSpace>, a: f64, b: f64) -> f64 {
    turning_along(|s| stack.point_at(s).1, a, b)
}

/// [`turning`] along any curve given by its frame at path coordinate `s`.
fn turning_along(frame: impl Fn(f64) -> UnitQuaternion<f64>, a: f64, b: f64) -> f64 {
    let pieces = ((b - a) / 0.5e-3).ceil() as usize;
    (0..pieces)
        .map(|k| {
            let s = |j: usize| a + (b - a) * j as f64 / pieces as f64;
            let ta = frame(s(k)) * Vector3::x();
            let tb = frame(s(k + 1)) * Vector3::x();
            ta.cross(&tb).z.atan2(ta.dot(&tb))
        })
        .sum()
}

#[test]
fn a_stiff_wire_straightens_a_simmons_curve_which_returns_as_it_is_withdrawn() {
    let catheter = simmons();
    let wire = presets::guidewire_035(); // 60 GPa shaft, 150 mm soft distal part
    let l_cath = 0.2;
    // From 10 mm before the shaped part (straight at rest) to the tip.
    let shaped_from = l_cath - 0.078;
    // The wire's stiff shaft covers the whole curve: its tip 160 mm beyond the catheter's.
    let mut stack = free_stack(vec![(catheter, l_cath), (wire, l_cath + 0.16)]);
    static_solve(stack.model_mut());
    let ei_cath = ei(0.15e9, 5e-3 / 3.0, 0.038 * 0.0254);
    let ei_wire = ei(60e9, 0.035 * 0.0254, 0.0);
    let share = ei_cath / (ei_cath + ei_wire);
    // Net planar turning: 180° one way, 30° back.
    let rest = PI - PI / 6.0;
    let straightened = turning(&stack, shaped_from, l_cath);
    let error = (straightened - share * rest).abs();
    println!(
        "Simmons with a stiff wire: tip turned {:.4}° (blend formula {:.4}°, rest {:.1}°)",
        straightened.to_degrees(),
        (share * rest).to_degrees(),
        rest.to_degrees()
    );
    assert!(error < 1e-6, "straightened angle error {error:e} rad");
    // Withdraw the wire in 20 mm steps: the curve comes back (through more than its rest
    // turning while the wire's soft tip still holds the reverse tip curve straight).
    let mut previous = straightened;
    for back in [0.17, 0.19, 0.21, 0.23, 0.25] {
        run_to_targets(&mut stack, &[(1, Some(l_cath + 0.16 - back), None)]);
        static_solve(stack.model_mut());
        let angle = turning(&stack, shaped_from, l_cath);
        println!(
            "  wire tip {:.0} mm behind the catheter tip: curve {:.2}°",
            (back - 0.16) * 1e3,
            angle.to_degrees()
        );
        assert!(angle > straightened, "the curve comes back");
        previous = angle;
    }
    // Withdrawn behind the whole shaped part: the rest shape, exactly.
    let error = (previous - rest).abs();
    assert!(error < 1e-6, "recovered angle error {error:e} rad");
}

fn arch_to_cow() -> &'static cathlab_anatomy::real::Anatomy {
    static ANATOMY: std::sync::OnceLock<cathlab_anatomy::real::Anatomy> =
        std::sync::OnceLock::new();
    ANATOMY.get_or_init(|| {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
        cathlab_anatomy::real::load_arch_to_cow(&dir).unwrap()
    })
}

/// Runs the two-hand plan to `target` and checks it: the wire reaches the target, the
/// microcatheter goes 30 mm beyond the catheter, the leading tip ends in the target branch and
/// no node went more than 0.05 mm into the wall.
fn two_hands_reach(target: &str) {
    let anatomy = arch_to_cow();
    let plan = CoaxialPlan::for_target(&anatomy.graph, target).unwrap();
    let run = run_coaxial_arch_to_cow(anatomy, &plan).unwrap();
    println!(
        "{target}: wire exchanged at step {:?}, reached at step {:?}, microcatheter 30 mm beyond the catheter at step {:?}, {} pull-backs, worst penetration {:.4} mm, inserted {:?} mm, tip in {}",
        run.exchanged_at_step,
        run.reached_at_step,
        run.micro_done_at_step,
        run.retries,
        run.worst_penetration_m * 1e3,
        run.inserted_m
            .iter()
            .map(|l| (l * 1e4).round() / 10.0)
            .collect::<Vec<_>>(),
        run.tip_branch
    );
    assert!(
        run.reached_at_step.is_some(),
        "the wire reached the {target}"
    );
    assert!(
        run.micro_done_at_step.is_some(),
        "the microcatheter went through"
    );
    assert_eq!(run.tip_branch, target);
    assert!(run.inserted_m[1] - run.inserted_m[0] >= 0.03 - 1e-9);
    assert!(run.worst_penetration_m <= 0.05e-3);
}

#[test]
fn two_hands_take_a_catheter_over_a_wire_to_the_lcca_and_a_microcatheter_beyond() {
    two_hands_reach("LCCA");
}

#[test]
fn two_hands_take_a_catheter_over_exchanged_wires_to_the_right_vertebral_and_a_microcatheter_beyond()
 {
    // No parked guide: the wide-bend wire leads into the brachiocephalic trunk, the catheter
    // tracks over it, the wire is exchanged for a small bend that selects the vertebral.
    two_hands_reach("RVA");
}

#[test]
fn a_coaxial_run_is_bit_identical_when_repeated() {
    let anatomy = arch_to_cow();
    // 14,000 steps of the RVA plan: the wire leads, the catheter tracks, the wire is withdrawn
    // and exchanged, and the new one loaded.
    let plan = CoaxialPlan {
        max_steps: 14_000,
        ..CoaxialPlan::for_target(&anatomy.graph, "RVA").unwrap()
    };
    let a = run_coaxial_arch_to_cow(anatomy, &plan).unwrap();
    let b = run_coaxial_arch_to_cow(anatomy, &plan).unwrap();
    // A phase change takes a loop turn without a step.
    assert!(a.steps > 13_990 && a.steps == b.steps);
    assert!(a.exchanged_at_step.is_some(), "the wire was exchanged");
    assert_eq!(a.tip_position, b.tip_position);
    assert_eq!(a.inserted_m, b.inserted_m);
    assert_eq!(a.worst_penetration_m, b.worst_penetration_m);
}

#[test]
fn the_builtin_catalogue_is_valid_sourced_and_nests() {
    use cathlab_physics::DeviceKind::*;
    let catalogue = Catalogue::builtin();
    assert!(catalogue.entries().len() >= 18);
    for entry in catalogue.entries() {
        assert!(
            !entry.source.trim().is_empty(),
            "{} has no source",
            entry.id
        );
        entry.device.validate().unwrap();
    }
    let of = |kind| {
        catalogue
            .entries()
            .iter()
            .filter(move |e| e.kind == kind)
            .map(|e| &e.device)
    };
    // The clinical stacks: every microwire in every microcatheter, every microcatheter in
    // every distal-access catheter, those in the long sheath, 0.035" wires in 5 F catheters.
    for (outer, inner) in [
        (Microcatheter, Microwire),
        (DistalAccess, Microcatheter),
        (Sheath, DistalAccess),
        (Guide, Catheter),
        (Catheter, Guidewire),
    ] {
        for o in of(outer) {
            for i in of(inner) {
                cathlab_physics::stack::check_fit(o, i).unwrap_or_else(|e| panic!("{e}"));
            }
        }
    }
    // Stent retrievers go through 0.021" and 0.027" microcatheters, not 0.017" ones.
    for stent in catalogue
        .entries()
        .iter()
        .filter(|e| e.kind == StentRetriever)
    {
        let spec = stent.stent.expect("a stent retriever has its stent");
        assert!(spec.from_tip_m + spec.length_m <= stent.device.length_m());
        for id in ["microcatheter-021-160", "microcatheter-027-150"] {
            let outer = catalogue.device(id).unwrap();
            cathlab_physics::stack::check_fit(&outer, &stent.device)
                .unwrap_or_else(|e| panic!("{e}"));
        }
        let small = catalogue.device("microcatheter-017-150").unwrap();
        assert!(cathlab_physics::stack::check_fit(&small, &stent.device).is_err());
    }
    // Shapes from the catalogue behave: the Simmons reverse curve turns back on itself.
    let simmons = catalogue.device("catheter-5f-simmons-2").unwrap();
    assert!(!simmons.sections.last().unwrap().rest_shape.is_straight());
}

/// A free-space stack in nested mode.
fn nested_stack(devices: Vec<(Device, f64)>) -> Stack<FreeSpace> {
    coupled_stack(devices, Coupling::Nested)
}

/// Steps a nested stack with its commands held until no node of any chain moves more than
/// `tolerance_m` in a step; returns the steps taken.
fn settle(stack: &mut Stack<FreeSpace>, tolerance_m: f64, max_steps: usize) -> usize {
    // Every instrument's points every millimetre along the path (nodes come and go).
    let snapshot = |stack: &Stack<FreeSpace>| -> Vec<Vector3<f64>> {
        (0..stack.len())
            .flat_map(|i| {
                let l = stack.inserted_m(i).unwrap();
                (0..(l * 1e3) as usize).map(move |k| (i, k as f64 * 1e-3))
            })
            .map(|(i, s)| stack.instrument_point(i, s).unwrap().0)
            .collect()
    };
    for step in 1..=max_steps {
        let before = snapshot(stack);
        stack.step().unwrap();
        let after = snapshot(stack);
        if before.len() == after.len()
            && before
                .iter()
                .zip(&after)
                .all(|(a, b)| (a - b).norm() <= tolerance_m)
        {
            return step;
        }
    }
    panic!("the nested stack did not settle in {max_steps} steps");
}

/// Curvature (1/m) of instrument `index` between path coordinates `a` < `b` from its frames.
fn curvature_of_frames(stack: &Stack<FreeSpace>, index: usize, a: f64, b: f64) -> f64 {
    let ta = stack.instrument_point(index, a).unwrap().1 * Vector3::x();
    let tb = stack.instrument_point(index, b).unwrap().1 * Vector3::x();
    ta.angle(&tb) / (b - a)
}

/// Largest distance (m) of instrument `inner`'s centre line from instrument `outer`'s, across
/// the outer's tangent, sampled every 0.5 mm over path coordinates `a` to `b`.
fn lateral_offset(stack: &Stack<FreeSpace>, inner: usize, outer: usize, a: f64, b: f64) -> f64 {
    let count = ((b - a) / 0.5e-3) as usize;
    (0..=count)
        .map(|k| {
            let s = a + (b - a) * k as f64 / count as f64;
            let (p, _) = stack.instrument_point(inner, s).unwrap();
            let (q, r) = stack.instrument_point(outer, s).unwrap();
            let t = r * Vector3::x();
            let d = p - q;
            (d - t * t.dot(&d)).norm()
        })
        .fold(0.0, f64::max)
}

/// Curvature (1/m) of instrument `index` between path coordinates `a` < `b`: the turn of its
/// centre line's chord tangents (0.25 mm chords) over the arc length.
fn instrument_curvature(stack: &Stack<FreeSpace>, index: usize, a: f64, b: f64) -> f64 {
    let at = |s: f64| stack.instrument_point(index, s).unwrap().0;
    let h = 0.125e-3;
    let ta = at(a + h) - at(a - h);
    let tb = at(b + h) - at(b - h);
    ta.angle(&tb) / (b - a)
}

#[test]
fn nested_j_wire_inside_a_tube_keeps_within_the_clearance_and_recovers_outside() {
    // A soft tube with 0.31 mm of radial clearance around a 0.035" J wire (3 mm radius).
    let tube = uniform("tube", 1.0, 2.0e-3, 1.5e-3, 0.3e9, RestShape::straight());
    let wire = presets::guidewire_035();
    let clearance = (1.5e-3 - 0.035 * 0.0254) / 2.0;
    let radius = 0.003;
    let j_length = radius * PI;
    let (l_tube, l_wire) = (0.15, 0.14);
    let mut stack = nested_stack(vec![(tube, l_tube), (wire, l_wire)]);
    let steps = settle(&mut stack, 1e-6, 6000);
    let ei_tube = ei(0.3e9, 2.0e-3, 1.5e-3);
    let ei_wire = ei(2e9, 0.035 * 0.0254, 0.0);
    let blend = ei_wire / (ei_wire + ei_tube) / radius;
    let (a, b) = (l_wire - j_length + 0.5e-3, l_wire - 0.5e-3);
    let wire_inside = instrument_curvature(&stack, 1, a, b);
    let tube_there = instrument_curvature(&stack, 0, a, b);
    let offset = lateral_offset(&stack, 1, 0, 0.0, l_wire);
    let penetration = stack.max_penetration_m();
    println!(
        "nested J inside the tube (settled in {steps} steps): wire curvature {wire_inside:.2} 1/m, tube {tube_there:.2} 1/m, merged blend {blend:.2} 1/m (rest {:.2}); largest lateral offset {:.4} mm of {:.4} mm clearance; penetration {:.5} mm",
        1.0 / radius,
        offset * 1e3,
        clearance * 1e3,
        penetration * 1e3
    );
    // The clearance is visible (the J leans on the lumen) and bounds the offset.
    let tolerance = NavigationSettings::default()
        .contact
        .penetration_tolerance_m;
    assert!(offset <= clearance + tolerance, "offset {offset} m");
    assert!(
        offset >= 0.5 * clearance,
        "offset {offset} m: the J does not lean on the lumen"
    );
    assert!(penetration <= tolerance, "penetration {penetration} m");
    // The lumen holds the J much straighter than its rest shape.
    assert!(wire_inside < 0.5 / radius, "J inside at {wire_inside} 1/m");
    // Pushed 30 mm out of the tube: the free J is its rest shape.
    run_to_targets(&mut stack, &[(1, Some(l_tube + 0.03), None)]);
    settle(&mut stack, 1e-6, 6000);
    let end = l_tube + 0.03;
    let outside = curvature_of_frames(&stack, 1, end - j_length + 0.5e-3, end - 0.5e-3);
    let error = (outside * radius - 1.0).abs();
    println!("  pushed 30 mm out: curvature {outside:.6} 1/m, relative error {error:.1e}");
    assert!(error < 1e-6, "recovered J error {error:e}");
}

#[test]
fn nested_twist_turns_one_instrument_and_not_the_other() {
    // A soft tube with a 45° tip over 8 mm and 0.31 mm of radial clearance; a 0.035" wire with
    // a 45°/10 mm tip leading 20 mm beyond it.
    let tube = uniform(
        "tube",
        1.0,
        2.0e-3,
        1.5e-3,
        0.3e9,
        RestShape::angled(PI / 4.0, 0.008),
    );
    let wire = presets::guidewire_035_shaped(PI / 4.0, 0.010);
    let (l_tube, l_wire) = (0.15, 0.17);
    let direction = |stack: &Stack<FreeSpace>, index: usize, a: f64, b: f64| {
        let ta = stack.instrument_point(index, a).unwrap().1 * Vector3::x();
        let tb = stack.instrument_point(index, b).unwrap().1 * Vector3::x();
        roll_angle(&(tb - ta * ta.dot(&tb)).normalize(), &ta)
    };
    let measure = |stack: &Stack<FreeSpace>| {
        (
            direction(stack, 0, l_tube - 0.012, l_tube - 0.001),
            direction(stack, 1, l_wire - 0.011, l_wire),
        )
    };
    // Lumen friction couples the two a little; within a degree.
    turn_each_alone(
        ("nested, ", "tube", 3),
        || nested_stack(vec![(tube.clone(), l_tube), (wire.clone(), l_wire)]),
        |stack| {
            settle(stack, 1e-6, 6000);
        },
        measure,
        1f64.to_radians(),
    );
}

/// Turn (degrees, in the world x–y plane) between the centre-line chords of instrument `index`
/// over path coordinates `a..a + 2 mm` and `b − 2 mm..b`: where the curve points, read off the
/// positions (a frame at a free end turns with its rest shape between contacts).
fn chord_turn(point: impl Fn(f64) -> Vector3<f64>, a: f64, b: f64) -> f64 {
    let ta = (point(a + 2e-3) - point(a)).normalize();
    let tb = (point(b) - point(b - 2e-3)).normalize();
    ta.cross(&tb).z.atan2(ta.dot(&tb)).to_degrees()
}

#[test]
fn a_stiff_wire_straightens_an_angled_catheter_in_both_modes() {
    // A 5 F catheter with its 45°/8 mm tip over a 0.035" wire whose stiff shaft crosses the
    // curve (tip 160 mm beyond): 38 µm of radial clearance in nested mode.
    let catheter = presets::diagnostic_catheter_5f();
    let wire = presets::guidewire_035();
    let l_cath = 0.2;
    let (a, b) = (l_cath - 0.012, l_cath - 0.001);
    let clearance = (0.038 - 0.035) * 0.0254 / 2.0;
    let devices = vec![(catheter, l_cath), (wire, l_cath + 0.16)];
    let mut merged = free_stack(devices.clone());
    static_solve(merged.model_mut());
    let ei_cath = ei(0.15e9, 5e-3 / 3.0, 0.038 * 0.0254); // the 20 mm tip section
    let ei_wire = ei(60e9, 0.035 * 0.0254, 0.0);
    let rest = PI / 4.0;
    let blend = ei_cath / (ei_cath + ei_wire) * rest;
    let merged_frames = turning(&merged, l_cath - 0.012, l_cath);
    assert!(
        (merged_frames - blend).abs() < 1e-6,
        "merged {merged_frames} vs blend {blend}"
    );
    let merged_chords = chord_turn(|s| merged.point_at(s).0, a, b);
    // Nested: stepped (it does not settle to 1 µm a step at this clearance; see docs).
    let mut nested = nested_stack(devices);
    let steps = 400;
    let t = std::time::Instant::now();
    for _ in 0..steps {
        nested.step().unwrap();
    }
    let per_step = t.elapsed().as_secs_f64() / steps as f64;
    let catheter_chords = chord_turn(|s| nested.instrument_point(0, s).unwrap().0, a, b);
    let wire_chords = chord_turn(|s| nested.instrument_point(1, s).unwrap().0, a, b);
    let penetration = nested.max_penetration_m();
    println!(
        "angled 5 F over a stiff 0.035\" wire: merged tip turns {:.4}° (blend formula {:.4}°, rest {:.0}°); chords {:.3}° merged, nested catheter {:.3}° / wire {:.3}° after {steps} steps ({:.1} ms/step); nested penetration {:.4} mm of {:.4} mm clearance",
        merged_frames.to_degrees(),
        blend.to_degrees(),
        rest.to_degrees(),
        merged_chords,
        catheter_chords,
        wire_chords,
        per_step * 1e3,
        penetration * 1e3,
        clearance * 1e3
    );
    // Nested: the catheter's chords may tilt against the wire's by the clearance over a chord
    // at each end (2c / 2 mm each); the wire straightens the curve to near the blend.
    let play = (4.0 * clearance / 2e-3_f64).to_degrees();
    assert!(
        (catheter_chords - wire_chords).abs() <= play,
        "catheter {catheter_chords}° vs wire {wire_chords}° beyond the play {play}°"
    );
    assert!(
        (catheter_chords - merged_chords).abs() <= play + 1.0,
        "nested {catheter_chords}° vs merged {merged_chords}°"
    );
    assert!(
        penetration <= 0.1 * clearance,
        "penetration {penetration} m"
    );
}

#[test]
fn merged_and_nested_follow_the_same_scripted_push_up_the_aorta() {
    // The wire leads 10 mm ahead of a 5 F catheter, both pushed at 40 mm/s from the femoral
    // access; the same commands in both modes. (The chart command runs 3000 steps with one to
    // four instruments.)
    use cathlab_physics::scenarios::{ScriptedStack, compare_couplings};
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let anatomy = cathlab_anatomy::real::load_arch_to_cow(&dir).unwrap();
    let script = ScriptedStack::up_the_aorta(
        vec![presets::diagnostic_catheter_5f(), presets::guidewire_035()],
        400,
    );
    let comparison = compare_couplings(&anatomy, &script).unwrap();
    println!("scripted push, 5 F over 0.035\": {comparison}");
    for run in [&comparison.merged, &comparison.nested] {
        assert!(
            run.worst_penetration_m <= 0.05e-3,
            "{}",
            run.worst_penetration_m
        );
    }
}

/// A stack pushed round a ring of tube (contacts along its outer wall), under `effort`:
/// per step, the contact sweeps and the element count; and the final node positions.
fn ring_run(effort: Option<cathlab_physics::Effort>) -> (Vec<(usize, usize)>, Vec<Vector3<f64>>) {
    use cathlab_physics::wall::RingTube;
    let settings = NavigationSettings::default();
    let (tube, wire) = straight_pair();
    let ring = RingTube {
        center: Vector3::new(0.0, 0.03, 0.0),
        axis: Vector3::z(),
        major_radius_m: 0.03,
        minor_radius_m: 2e-3,
    };
    let mut stack = Stack::with_coupling(
        vec![
            InstrumentSpec::new(tube, 0.02, &settings),
            InstrumentSpec::new(wire, 0.03, &settings),
        ],
        ring,
        Vector3::zeros(),
        Vector3::x(),
        settings,
        Coupling::Merged,
    )
    .unwrap();
    if let Some(effort) = effort {
        stack.set_effort(effort).unwrap();
    }
    let push = Command {
        insertion: Insertion::Velocity(0.05),
        twist: Twist::Rate(0.0),
    };
    stack.set_command(0, push).unwrap();
    stack.set_command(1, push).unwrap();
    let work = (0..400)
        .map(|_| {
            let report = stack.step().unwrap();
            (report.sweeps, report.elements)
        })
        .collect();
    (work, stack.model().positions().to_vec())
}

/// The overload governor's effort caps a stack's work as it does a single device's: full
/// effort changes nothing (bit for bit), a capped one never sweeps past its cap and refines
/// less, and a refinement scale below 1 is refused by name.
#[test]
fn a_stack_under_a_capped_effort_does_less_work() {
    use cathlab_physics::Effort;
    let (default_work, default_nodes) = ring_run(None);
    let (full_work, full_nodes) = ring_run(Some(Effort::FULL));
    assert_eq!(default_work, full_work);
    assert_eq!(default_nodes, full_nodes);
    let capped = Effort {
        max_substep_depth: 0,
        max_detection_rounds: 1,
        max_sweeps: 5,
        polish: false,
        refinement_scale: 4.0,
    };
    let (capped_work, _) = ring_run(Some(capped));
    let most_sweeps = |w: &[(usize, usize)]| w.iter().map(|x| x.0).max().unwrap();
    let elements = |w: &[(usize, usize)]| w.iter().map(|x| x.1).sum::<usize>();
    println!(
        "ring, 400 steps: most sweeps a step {} (full) / {} (capped at 5 + 5 normal-only); element-steps {} / {}",
        most_sweeps(&full_work),
        most_sweeps(&capped_work),
        elements(&full_work),
        elements(&capped_work)
    );
    assert!(
        most_sweeps(&full_work) > 5,
        "the ring must need more than the cap"
    );
    // With friction the solver may add as many normal-only sweeps (the tangential forces held)
    // as its budget allows Coulomb sweeps.
    assert!(most_sweeps(&capped_work) <= 2 * 5);
    assert!(elements(&capped_work) <= elements(&full_work));
    let (tube, wire) = straight_pair();
    let mut stack = free_stack(vec![(tube, 0.02), (wire, 0.03)]);
    match stack.set_effort(Effort {
        refinement_scale: 0.5,
        ..Effort::FULL
    }) {
        Err(PhysicsError::OutOfRange { what, .. }) => assert_eq!(what, "effort.refinement_scale"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn catalogue_markers_are_checked_and_named() {
    let base = catalogue_with("lumen_friction", "0.04");
    let marker = |from_tip: &str, length: &str| {
        format!("{base}\n[[device.marker]]\nfrom_tip_mm = {from_tip}\nlength_mm = {length}\n")
    };
    let (device, section, field) = definition_error(&marker("-1.0", "1.0"));
    assert_eq!(
        (device.as_str(), section.as_str(), field.as_str()),
        ("test-catheter", "marker 0", "from_tip_mm")
    );
    let (_, _, field) = definition_error(&marker("0.0", "5000.0"));
    assert_eq!(field, "length_mm");
    let ok = Catalogue::from_toml_str(&marker("0.5", "1.0")).unwrap();
    let m = ok.get("test-catheter").unwrap().markers[0];
    assert_eq!((m.from_tip_m, m.length_m, m.fill), (0.5e-3, 1e-3, 1.0));
    // Every built-in microcatheter carries its two marker bands 30 mm apart.
    for entry in Catalogue::builtin().entries() {
        if entry.kind == cathlab_physics::DeviceKind::Microcatheter {
            assert_eq!(entry.markers.len(), 2, "{}", entry.id);
        }
    }
}

/// The stent retriever's `[device.stent]` table: required for that kind, refused on any other,
/// and its fields checked by name.
#[test]
fn catalogue_stent_tables_are_checked_by_name() {
    let text = cathlab_physics::catalogue::BUILTIN_TOML;
    let stent = &text[text.find("# ---- stent-retriever-4x20").unwrap()..];
    assert!(
        Catalogue::from_toml_str(stent).unwrap().entries()[0]
            .stent
            .is_some()
    );
    let start = stent.find("[device.stent]").unwrap();
    let end = start + stent[start..].find("\n\n").unwrap();
    let without = format!("{}{}", &stent[..start], &stent[end..]);
    let (device, section, field) = definition_error(&without);
    assert_eq!(
        (device.as_str(), section.as_str(), field.as_str()),
        ("stent-retriever-4x20", "stent", "stent")
    );
    for (from, to, field) in [
        ("open_area = 0.8", "open_area = 1.5", "open_area"),
        (
            "reference_diameter_mm = 3.0",
            "reference_diameter_mm = 4.5",
            "reference_diameter_mm",
        ),
        ("rrf_ratio = 1.6", "rrf_ratio = 0.5", "rrf_ratio"),
        (
            "from_tip_mm = 5.0\ncof",
            "from_tip_mm = 1790.0\ncof",
            "from_tip_mm",
        ),
        ("cof_n_per_mm = 0.02", "cof_n_per_mm = nan", "cof_n_per_mm"),
    ] {
        assert!(stent.contains(from), "{from}");
        let (_, section, got) = definition_error(&stent.replace(from, to));
        assert_eq!((section.as_str(), got.as_str()), ("stent", field));
    }
    let table = &stent[start..end];
    let (device, _, field) =
        definition_error(&(catalogue_with("lumen_friction", "0.04") + "\n" + table + "\n"));
    assert_eq!(
        (device.as_str(), field.as_str()),
        ("test-catheter", "stent")
    );
}

/// A tip load (a clot resisting a crossing tip) reaches the hands: held still in free space,
/// the hands push with the load (the sum of their axial forces, static balance of the strand), whether the
/// loaded tip leads or lies inside the strand; none without it; bad loads are named.
#[test]
fn a_tip_load_reaches_the_hands_in_static_balance() {
    let (tube, wire) = straight_pair();
    let load = 0.05;
    let hands = |stack: &mut Stack<FreeSpace>| -> f64 {
        stack
            .proximal_reactions()
            .iter()
            .map(|r| r.axial_force_n)
            .sum()
    };
    for (loaded, name) in [(1, "the leading wire's tip"), (0, "the tube's tip, inside")] {
        let mut stack = free_stack(vec![(tube.clone(), 0.06), (wire.clone(), 0.1)]);
        for _ in 0..50 {
            stack.step().unwrap();
        }
        let free = hands(&mut stack);
        stack.set_tip_load(loaded, -load).unwrap();
        assert_eq!(stack.tip_load_n(loaded), Some(-load));
        for _ in 0..400 {
            stack.step().unwrap();
        }
        let held = hands(&mut stack);
        println!("{name}: hands {free:.2e} N free, {held:.6} N against a {load} N tip load");
        assert!(free.abs() < 1e-6 * load, "{name}: {free}");
        assert!(
            (held - load).abs() < 0.01 * load,
            "{name}: the hands carry {held} N of a {load} N load"
        );
        // Taken off: the hands are free again.
        stack.set_tip_load(loaded, 0.0).unwrap();
        for _ in 0..400 {
            stack.step().unwrap();
        }
        let after = hands(&mut stack);
        assert!(after.abs() < 0.01 * load, "{name}: {after}");
    }
    let mut stack = free_stack(vec![(tube.clone(), 0.06), (wire.clone(), 0.1)]);
    assert!(stack.set_tip_load(2, -load).is_err());
    assert!(stack.set_tip_load(1, f64::NAN).is_err());
    let mut nested = coupled_stack(vec![(tube, 0.06), (wire, 0.1)], Coupling::Nested);
    let e = nested.set_tip_load(1, -load).unwrap_err().to_string();
    assert!(e.contains("merged"), "{e}");
}
