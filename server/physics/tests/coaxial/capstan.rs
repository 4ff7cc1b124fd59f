//! The capstan law: a wire drawn round a bend against a load on its tip. Sliding, Coulomb
//! friction makes the tension grow along the wire as e^{μθ} in the direction it is drawn
//! (θ the angle its axis turns through on the wall), and fall as e^{−μθ} the other way.

use cathlab_physics::navigation::{Command, Insertion, NavigationSettings, Twist};
use cathlab_physics::wall::RingTube;
use cathlab_physics::{Device, RestShape};
use nalgebra::Vector3;

use crate::support::{merged_stack_in, uniform};

/// A uniform 0.014"-like nitinol wire with wall friction `mu`.
fn wire(mu: f64) -> Device {
    uniform_device("wire", 1.5, 0.356e-3, 0.0, 60e9, mu)
}

/// A ring of tube of core radius `r` (m) and lumen radius 2 mm about the z axis, entered at
/// the origin along x, and settings with the slide's friction on.
pub(crate) fn ring_with_slide_friction(r: f64) -> (RingTube, NavigationSettings) {
    let ring = RingTube {
        center: Vector3::new(0.0, r, 0.0),
        axis: Vector3::z(),
        major_radius_m: r,
        minor_radius_m: 2e-3,
    };
    let settings = NavigationSettings {
        slide_friction: true,
        ..NavigationSettings::default()
    };
    (ring, settings)
}

/// A straight uniform device (nitinol's density) of length (m), outer and inner diameter (m) and
/// Young's modulus (Pa) ([`uniform`]'s), with wall friction `mu`.
fn uniform_device(
    name: &str,
    length_m: f64,
    outer_diameter_m: f64,
    inner_diameter_m: f64,
    young_pa: f64,
    mu: f64,
) -> Device {
    let mut device = uniform(
        name,
        length_m,
        outer_diameter_m,
        inner_diameter_m,
        young_pa,
        RestShape::straight(),
    );
    for section in &mut device.sections {
        section.friction_coefficient = mu;
        section.material.density_kg_m3 = 6500.0;
    }
    device
}

/// A wire pushed 71 mm round a ring of tube (core radius 30 mm, lumen 2 mm: 135° of turn),
/// pulled forward at its tip by 1 N, then drawn back out at 10 mm/s and pushed in again.
/// Between two elements on the inner wall 14 elements apart, the tension's ratio is the
/// capstan factor e^{μθ} while the wire is drawn out and its inverse while it is pushed in
/// (θ the turn between the two elements' axes), within 5 %. Without
/// `NavigationSettings::slide_friction` (the default: the slide through the entry is not
/// slip to the friction law, whose friction then resists only the solve's own corrections)
/// the ratio stays near 0.83 whichever way the wire slides: drawn out, the wrong way.
#[test]
fn a_wire_drawn_round_a_bend_feels_the_capstan_law() {
    let mu = 0.3;
    let r = 0.03;
    let (ring, settings) = ring_with_slide_friction(r);
    let mut stack = merged_stack_in(vec![(wire(mu), 0.01)], ring, settings);
    let go = |v: f64| Command {
        insertion: Insertion::Velocity(v),
        twist: Twist::Rate(0.0),
    };
    stack.set_command(0, go(0.05)).unwrap();
    while stack.inserted_m(0).unwrap() < 0.75 * std::f64::consts::PI * r {
        stack.step().unwrap();
    }
    stack.set_command(0, go(0.0)).unwrap();
    for _ in 0..200 {
        stack.step().unwrap();
    }
    stack.set_tip_load(0, 1.0).unwrap();
    for _ in 0..400 {
        stack.step().unwrap();
    }
    for (phase, speed, sign) in [("drawn out", -0.01, 1.0), ("pushed in", 0.01, -1.0)] {
        stack.set_command(0, go(speed)).unwrap();
        for k in 0..500 {
            stack.step().unwrap();
            // Sliding steadily after the first 100 steps (2 mm).
            if k < 100 || k % 50 != 0 {
                continue;
            }
            let model = stack.model();
            let (a, b) = (16, 30);
            let axis = |e: usize| (model.positions()[e + 1] - model.positions()[e]).normalize();
            let turn = axis(a).dot(&axis(b)).clamp(-1.0, 1.0).acos();
            let ratio = model.element_axial_force_n(a) / model.element_axial_force_n(b);
            let capstan = (sign * mu * turn).exp();
            println!(
                "{phase}, step {k}: tension ratio {ratio:.4}, e^(±μθ) {capstan:.4} (θ {:.1}°)",
                turn.to_degrees()
            );
            assert!(turn > 0.5, "the elements compared lie round the bend");
            assert!(
                (ratio / capstan - 1.0).abs() < 0.05,
                "{phase}: ratio {ratio} against the capstan factor {capstan}"
            );
        }
    }
}

/// How a step's motion is capped in [`pushed_round_a_ring`].
#[derive(Debug, Clone, Copy)]
enum Cap {
    /// The physics' default: the free motion scaled to 0.2 mm and 0.2 rad.
    Free,
    /// `cap_with_held_contacts`: the motion the last contact forces leave scaled to the cap.
    Held,
    /// No cap to speak of (1 m, 3 rad).
    Lifted,
}

/// A wire pushed round a ring of tube (core radius 12 mm, lumen 2 mm) against nothing but
/// the wall's friction, with the slide's friction on: the hand's push, `(hand N, friction N)`
/// after 300 steps at 10 mm/s, the friction being the sum of the contacts' tangential
/// forces.
fn pushed_round_a_ring(cap: Cap) -> (f64, f64) {
    use cathlab_physics::Navigation;
    let defaults = NavigationSettings::default();
    let lifted = matches!(cap, Cap::Lifted);
    let settings = NavigationSettings {
        slide_friction: true,
        cap_with_held_contacts: matches!(cap, Cap::Held),
        max_step_m: if lifted { 1.0 } else { defaults.max_step_m },
        max_step_rad: if lifted { 3.0 } else { defaults.max_step_rad },
        ..defaults
    };
    let ring = RingTube {
        center: Vector3::new(0.0, 0.012, 0.0),
        axis: Vector3::z(),
        major_radius_m: 0.012,
        minor_radius_m: 2e-3,
    };
    let mut nav = Navigation::new(
        wire(0.3),
        ring,
        Vector3::zeros(),
        Vector3::x(),
        0.01,
        settings,
    )
    .unwrap();
    let go = |v: f64| Command {
        insertion: Insertion::Velocity(v),
        twist: Twist::Rate(0.0),
    };
    nav.set_command(go(0.02)).unwrap();
    while nav.inserted_m() < 0.08 {
        nav.step().unwrap();
    }
    nav.set_command(go(0.01)).unwrap();
    for _ in 0..300 {
        nav.step().unwrap();
    }
    let axis = nav.model().rotations()[0] * Vector3::x();
    let hand = nav.proximal_reaction().fixed_rows::<3>(0).dot(&axis);
    let friction: f64 = nav
        .last_contacts()
        .unwrap()
        .response
        .local
        .iter()
        .map(|l| (l.y * l.y + l.z * l.z).sqrt())
        .sum();
    (hand, friction)
}

/// Pushed round a ring against its friction alone, the hand feels that friction, within
/// 25 % of the contacts' tangential forces summed: with the cap on a step's motion lifted
/// (1.34 against 1.19 N), and with the cap judging the motion the last contact forces leave
/// (`cap_with_held_contacts`: 1.30 against 1.17 N). With the default cap on the free motion
/// the figures print only: the hand then felt 21.6 N against 0.035 N of friction
/// (twenty-second session). The free motion, solved without the wall, is the wire springing
/// straight through it; scaled to the cap, it leaves the wall the cap's share of its force,
/// and the entry's elements strain that nothing outside the wire balances.
#[test]
fn a_wire_pushed_round_a_ring_feels_its_friction_at_the_hand() {
    for cap in [Cap::Lifted, Cap::Held, Cap::Free] {
        let (hand, friction) = pushed_round_a_ring(cap);
        println!("{cap:?}: hand {hand:.3} N, wall friction {friction:.3} N");
        if matches!(cap, Cap::Free) {
            continue;
        }
        assert!(
            friction > 0.3,
            "{cap:?}: the wall holds the wire back: {friction} N"
        );
        assert!(
            (hand / friction - 1.0).abs() < 0.25,
            "{cap:?}: hand {hand} N against the wall's friction {friction} N"
        );
    }
}

/// A microcatheter round a ring of tube (core radius 30 mm, lumen 2 mm) with a wire in it,
/// the wall's friction 0.3 and the slide's friction on; the wire is pushed 3 mm further at
/// 10 mm/s against a 0.5 N load on its tip. What the wall takes along the catheter is the
/// strand's axial force a tenth of the catheter in less that just beyond its tip. Held still,
/// the catheter takes little of the wire's push there (0.021 N against 0.64 N; bound 5 %):
/// the lumen between them is frictionless in merged mode, so the wall cannot hold the wire
/// back through the still catheter (with the wall's friction on those points, the
/// catheter's rim's included, it took −0.167 N). Pushed along with the wire at 10 mm/s, the
/// catheter's own slide meets the wall's whole sliding friction there: the contacts along
/// it resist with μ times their normal force (0.0083 N on 0.028 N), within 5 %.
#[test]
fn a_still_catheter_passes_a_wire_pushed_through_it_nothing_of_the_wall() {
    let r = 0.03;
    let (ring, settings) = ring_with_slide_friction(r);
    let catheter = uniform_device("catheter", 1.3, 0.9e-3, 0.5e-3, 2.5e9, 0.3);
    let go = |v: f64| Command {
        insertion: Insertion::Velocity(v),
        twist: Twist::Rate(0.0),
    };
    for catheter_speed in [0.0, 0.01] {
        let mut stack = merged_stack_in(
            vec![(catheter.clone(), 0.01), (wire(0.3), 0.02)],
            ring,
            settings,
        );
        stack.set_command(0, go(0.05)).unwrap();
        stack.set_command(1, go(0.05)).unwrap();
        while stack.inserted_m(0).unwrap() < 0.6 * std::f64::consts::PI * r {
            stack.step().unwrap();
        }
        stack.set_command(0, go(0.0)).unwrap();
        stack.set_command(1, go(0.0)).unwrap();
        for _ in 0..200 {
            stack.step().unwrap();
        }
        stack.set_tip_load(1, -0.5).unwrap();
        stack.set_command(0, go(catheter_speed)).unwrap();
        stack.set_command(1, go(0.01)).unwrap();
        for _ in 0..150 {
            stack.step().unwrap();
        }
        // Compression (N) in the first element beyond a path coordinate (m).
        let sigma = stack.node_sigma_m();
        let compression = |at: f64| {
            let e = (0..sigma.len() - 1)
                .find(|&e| 0.5 * (sigma[e] + sigma[e + 1]) > at)
                .unwrap();
            -stack.model().element_axial_force_n(e)
        };
        // From a tenth of the catheter in (past the entry's own elements) to past its tip.
        let tip = stack.inserted_m(0).unwrap();
        let entry = compression(0.1 * tip);
        let wire_push = compression(tip);
        let along_catheter = entry - wire_push;
        println!(
            "catheter at {:.0} mm/s, wire at 10 mm/s: {entry:.4} N near the entry, {wire_push:.4} N \
             beyond the catheter's tip, {along_catheter:.4} N on the wall between",
            catheter_speed * 1e3
        );
        assert!(wire_push > 0.45, "the wire pushes its load: {wire_push} N");
        if catheter_speed == 0.0 {
            assert!(
                along_catheter.abs() < 0.05 * wire_push,
                "the wall along the still catheter: {along_catheter} N"
            );
        } else {
            // Sliding, the catheter meets the wall's friction along its stretch.
            let step = stack.last_contacts().unwrap();
            let along: Vec<_> = step
                .contacts
                .iter()
                .zip(&step.response.local)
                .filter(|(c, _)| 0.5 * (sigma[c.element] + sigma[c.element + 1]) < tip)
                .map(|(_, l)| l)
                .collect();
            let friction: f64 = along.iter().map(|l| (l.y * l.y + l.z * l.z).sqrt()).sum();
            let normal: f64 = along.iter().map(|l| l.x).sum();
            println!(
                "  along the sliding catheter: wall friction {friction:.4} N on {normal:.4} N of \
                 normal force"
            );
            assert!(normal > 0.01, "the catheter lies on the wall: {normal} N");
            assert!(
                (friction / (0.3 * normal) - 1.0).abs() < 0.05,
                "sliding friction along the catheter: {friction} N on {normal} N"
            );
        }
    }
}
