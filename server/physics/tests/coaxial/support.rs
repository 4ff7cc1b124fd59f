//! Shared builders and measures of the coaxial tests: test devices, free-space stacks,
//! static solves, tube stiffnesses, commands run to their targets, and curve angles.

use std::f64::consts::PI;

use cathlab_physics::navigation::{Command, Insertion, NavigationSettings, Twist};
use cathlab_physics::{
    BeamModel, CircularSection, Coupling, Device, FreeSpace, InstrumentSpec, Material, RestShape,
    Section, SolverSettings, Stack, StepMode,
};
use nalgebra::{UnitQuaternion, Vector3};

/// A uniform device of three identical sections, the distal one with `tip_shape`.
pub fn uniform(
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
pub fn straight_pair() -> (Device, Device) {
    (
        uniform("tube", 1.0, 1.67e-3, 0.97e-3, 2.5e9, RestShape::straight()),
        uniform("wire", 1.5, 0.889e-3, 0.0, 60e9, RestShape::straight()),
    )
}

/// A free-space stack entering along x at the origin, with default settings.
pub fn coupled_stack(devices: Vec<(Device, f64)>, coupling: Coupling) -> Stack<FreeSpace> {
    stack_in(devices, FreeSpace, NavigationSettings::default(), coupling)
}

/// A merged stack in `wall`, entering along x at the origin: each device with its inserted
/// length (m), outermost first.
pub fn merged_stack_in<W: cathlab_physics::Wall>(
    devices: Vec<(Device, f64)>,
    wall: W,
    settings: NavigationSettings,
) -> Stack<W> {
    stack_in(devices, wall, settings, Coupling::Merged)
}

/// A stack in `wall`, entering along x at the origin, coupled as `coupling` says.
fn stack_in<W: cathlab_physics::Wall>(
    devices: Vec<(Device, f64)>,
    wall: W,
    settings: NavigationSettings,
    coupling: Coupling,
) -> Stack<W> {
    let specs = devices
        .into_iter()
        .map(|(d, l)| InstrumentSpec::new(d, l, &settings))
        .collect();
    Stack::with_coupling(
        specs,
        wall,
        Vector3::zeros(),
        Vector3::x(),
        settings,
        coupling,
    )
    .unwrap()
}

pub fn free_stack(devices: Vec<(Device, f64)>) -> Stack<FreeSpace> {
    coupled_stack(devices, Coupling::Merged)
}

/// Switches the strand's model to a converged static solve without drag.
pub fn static_solve(model: &mut BeamModel) {
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
pub fn ei(young: f64, outer_d: f64, inner_d: f64) -> f64 {
    young * PI / 64.0 * (outer_d.powi(4) - inner_d.powi(4))
}

/// κ·G·A of a circular tube (N), Cowper's κ.
pub fn kga(young: f64, nu: f64, outer_d: f64, inner_d: f64) -> f64 {
    let m = inner_d / outer_d;
    let m2 = m * m;
    let kappa = 6.0 * (1.0 + nu) * (1.0 + m2).powi(2)
        / ((7.0 + 6.0 * nu) * (1.0 + m2).powi(2) + (20.0 + 12.0 * nu) * m2);
    kappa * young / (2.0 * (1.0 + nu)) * PI / 4.0 * (outer_d * outer_d - inner_d * inner_d)
}

pub fn run_to_targets(stack: &mut Stack<FreeSpace>, targets: &[(usize, Option<f64>, Option<f64>)]) {
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

/// Angle (rad) of `direction` about `tangent` from the entry's +y axis carried to `tangent`
/// by the minimal rotation (parallel transport along a planar path).
pub fn roll_angle(direction: &Vector3<f64>, tangent: &Vector3<f64>) -> f64 {
    let carry = UnitQuaternion::rotation_between(&Vector3::x(), tangent)
        .unwrap_or_else(UnitQuaternion::identity);
    let reference = carry * Vector3::y();
    let across = tangent.cross(&reference);
    direction.dot(&across).atan2(direction.dot(&reference))
}

pub fn wrap(angle: f64) -> f64 {
    (angle + PI).rem_euclid(2.0 * PI) - PI
}

/// Turns each of a two-instrument stack's instruments 90° on its own (a fresh stack each
/// time, brought to rest by `solve` before and after) and checks that its curve turns 90° and
/// the other's not, within `tolerance` (rad). `measure` gives the roll angles (rad) of the
/// outer's curve and the wire's tip; `(label, outer, digits)` name them in the printout.
pub fn turn_each_alone(
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

/// Signed turning (rad) of a curve in the world x–y plane from path coordinate `a` to `b`,
/// summed over 0.5 mm pieces (so that turns beyond 180° unwrap).
pub fn turning(stack: &Stack<FreeSpace>, a: f64, b: f64) -> f64 {
    turning_along(|s| stack.point_at(s).1, a, b)
}

/// [`turning`] along any curve given by its frame at path coordinate `s`.
pub fn turning_along(frame: impl Fn(f64) -> UnitQuaternion<f64>, a: f64, b: f64) -> f64 {
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
