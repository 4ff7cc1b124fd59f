//! Operating a stack: devices that do not fit, bad input named, a withdrawn wire exchanged,
//! the instruments' ranges and order under random pushes and pulls, and the overload
//! governor's effort cap.

use cathlab_physics::navigation::{Command, Insertion, NavigationSettings, Twist};
use cathlab_physics::{Device, FreeSpace, InstrumentSpec, PhysicsError, RestShape, Stack, presets};
use nalgebra::Vector3;
use proptest::prelude::*;

use crate::support::{free_stack, merged_stack_in, run_to_targets, straight_pair, uniform};

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

/// A stack pushed round a ring of tube (contacts along its outer wall), under `effort`:
/// per step, the contact sweeps and the element count; the final node positions; and the
/// deepest any point went past the wall after a step (m).
fn ring_run(
    effort: Option<cathlab_physics::Effort>,
) -> (Vec<(usize, usize)>, Vec<Vector3<f64>>, f64) {
    use cathlab_physics::wall::RingTube;
    let settings = NavigationSettings::default();
    let (tube, wire) = straight_pair();
    let ring = RingTube {
        center: Vector3::new(0.0, 0.03, 0.0),
        axis: Vector3::z(),
        major_radius_m: 0.03,
        minor_radius_m: 2e-3,
    };
    let mut stack = merged_stack_in(vec![(tube, 0.02), (wire, 0.03)], ring, settings);
    if let Some(effort) = effort {
        stack.set_effort(effort).unwrap();
    }
    let push = Command {
        insertion: Insertion::Velocity(0.05),
        twist: Twist::Rate(0.0),
    };
    stack.set_command(0, push).unwrap();
    stack.set_command(1, push).unwrap();
    let mut deepest: f64 = 0.0;
    let work = (0..400)
        .map(|_| {
            let report = stack.step().unwrap();
            deepest = deepest.max(stack.max_penetration_m());
            (report.sweeps, report.elements)
        })
        .collect();
    (work, stack.model().positions().to_vec(), deepest)
}

/// The overload governor's effort caps a stack's work as it does a single device's: full
/// effort changes nothing (bit for bit), a capped one never sweeps past its cap and refines
/// less, and a refinement scale below 1 is refused by name. Neither leaves a point past the
/// wall by more than the contact tolerance: a step that will not be halved (here every
/// step of the capped effort, which halves none and asks no projection) projects out what
/// its one detection round leaves (before, the capped stack went 1.85 mm past the wall).
#[test]
fn a_stack_under_a_capped_effort_does_less_work() {
    use cathlab_physics::Effort;
    let (default_work, default_nodes, _) = ring_run(None);
    let (full_work, full_nodes, full_deepest) = ring_run(Some(Effort::FULL));
    assert_eq!(default_work, full_work);
    assert_eq!(default_nodes, full_nodes);
    let capped = Effort {
        max_substep_depth: 0,
        max_detection_rounds: 1,
        max_sweeps: 5,
        polish: false,
        refinement_scale: 4.0,
        min_substep_penetration_m: 0.0,
        project_penetration: false,
    };
    let (capped_work, _, capped_deepest) = ring_run(Some(capped));
    let most_sweeps = |w: &[(usize, usize)]| w.iter().map(|x| x.0).max().unwrap();
    let elements = |w: &[(usize, usize)]| w.iter().map(|x| x.1).sum::<usize>();
    println!(
        "ring, 400 steps: most sweeps a step {} (full) / {} (capped at 5 + 5 normal-only); element-steps {} / {}",
        most_sweeps(&full_work),
        most_sweeps(&capped_work),
        elements(&full_work),
        elements(&capped_work)
    );
    println!(
        "deepest past the wall after a step: {:.4} mm (full) / {:.4} mm (capped)",
        full_deepest * 1e3,
        capped_deepest * 1e3
    );
    assert!(full_deepest <= 0.0105e-3, "{full_deepest}");
    assert!(capped_deepest <= 0.0105e-3, "{capped_deepest}");
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
    match stack.set_effort(Effort {
        min_substep_penetration_m: f64::NAN,
        ..Effort::FULL
    }) {
        Err(PhysicsError::OutOfRange { what, .. }) => {
            assert_eq!(what, "effort.min_substep_penetration_m")
        }
        other => panic!("{other:?}"),
    }
}
