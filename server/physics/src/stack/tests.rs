//! Unit tests of the merged step's stages that the public API does not reach: the relief of
//! a crushed composite element.

use nalgebra::Vector3;

use super::{InstrumentSpec, Stack};
use crate::FreeSpace;
use crate::device::presets;
use crate::navigation::NavigationSettings;

/// A 5 F catheter 100 mm in with a 0.035" wire 160 mm in, in free space, each hand's
/// strength `limit_n` bounding its elements.
fn catheter_over_wire(limit_n: f64) -> Stack<FreeSpace> {
    let settings = NavigationSettings {
        max_axial_force_n: Some(limit_n),
        ..NavigationSettings::default()
    };
    let specs = vec![
        InstrumentSpec::new(presets::diagnostic_catheter_5f(), 0.10, &settings),
        InstrumentSpec::new(presets::guidewire_035(), 0.16, &settings),
    ];
    Stack::new(specs, FreeSpace, Vector3::zeros(), Vector3::x(), settings).unwrap()
}

/// Shortens element `e` of the stack's model by `by_m`, moving every node beyond it back
/// along its chord (the other elements keep their shape).
fn crush(stack: &mut Stack<FreeSpace>, e: usize, by_m: f64) {
    let model = stack.model_mut();
    let mut positions = model.positions().to_vec();
    let axis = (positions[e + 1] - positions[e]).normalize();
    for p in &mut positions[e + 1..] {
        *p -= axis * by_m;
    }
    let rotations = model.rotations().to_vec();
    model.set_nodes(&positions, &rotations).unwrap();
}

#[test]
fn a_merged_element_is_relieved_to_the_strength_of_the_hands_it_holds() {
    let limit = 10.0;
    // The element in the middle of the overlap holds both instruments (bound 20 N); one
    // 20 mm beyond the catheter's tip holds the wire alone (10 N).
    for (at_m, hands) in [(0.05, 2.0), (0.12, 1.0)] {
        let mut stack = catheter_over_wire(limit);
        let targets: Vec<(f64, f64)> = stack
            .instruments
            .iter()
            .map(|i| (i.inserted_m, i.twist_rad))
            .collect();
        stack.prepare(&targets).unwrap();
        assert!(stack.model().max_axial_force_n() < 1e-6, "a stack at rest");
        let e = stack
            .nodes
            .windows(2)
            .position(|w| w[0].sigma <= at_m && at_m < w[1].sigma)
            .unwrap();
        crush(&mut stack, e, 200e-6);
        let before = stack.model().max_axial_force_n();
        assert!(before > 5.0 * hands * limit, "{before} N");
        stack.prepare(&targets).unwrap();
        let after = stack.model().max_axial_force_n();
        let bound = hands * limit;
        // One solve through the tangent, with the navigation's drag on the nodes: within
        // 1 % of the bound (the drag holds the nodes back by a fraction of the relief).
        assert!(
            (after - bound).abs() < 1e-2 * bound,
            "at {at_m} m: {before} N relieved to {after} N, the bound is {bound} N"
        );
        // Again: the rest of the excess, nothing where there is none.
        stack.prepare(&targets).unwrap();
        let again = stack.model().max_axial_force_n();
        assert!(
            (again - bound).abs() <= (after - bound).abs() * 0.1,
            "{after} N, then {again} N"
        );
    }
}
