//! Merged mode's composite strand: summed stiffness against analytic cantilevers, the
//! stiffness-weighted blend of rest shapes (a J wire, a Simmons curve), twist of one
//! instrument without the other, and tip loads carried to the hands.

use std::f64::consts::PI;

use cathlab_physics::{Coupling, Device, FreeSpace, RestArc, RestShape, Stack, presets};
use nalgebra::Vector3;

use crate::support::{
    coupled_stack, ei, free_stack, kga, roll_angle, run_to_targets, static_solve, straight_pair,
    turn_each_alone, turning,
};

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

/// A tip load (a clot resisting a crossing tip) reaches the hands: held still in free space,
/// the hands push with the load (the sum of their axial forces, static balance of the strand), whether the
/// loaded tip leads or lies inside the strand; none without it; bad loads are named. The stack
/// sleeps at rest, and a load put on or taken off wakes it.
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
        stack.set_sleep(Some(cathlab_physics::Sleep::default()));
        for _ in 0..300 {
            stack.step().unwrap();
        }
        assert!(stack.asleep(), "{name}: at rest in free space");
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
        assert!(!stack.asleep());
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
