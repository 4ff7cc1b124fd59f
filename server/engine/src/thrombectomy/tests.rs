//! The procedure's mechanics on a small flow network: a clot's resistance to the tips that
//! open it, and where fragments lodge.

use std::f64::consts::PI;

use cathlab_hemo::{
    Blood, FlowNetwork, FlowSolver, Inlet, InletCondition, Occlusion, Outlet, Vessel,
};
use cathlab_thrombectomy::{Clot, ClotComposition};

use super::passes::{CROSSING_SPEED_M_S, lodge};
use super::procedure::{InstrumentView, Procedure, SCENE_WEDGE_STRAIN, Site};

/// A parent artery (r 1.5 mm) forking into a wide (1.0 mm) and a narrow (0.6 mm) branch,
/// each forking again into two 0.5 mm branches; every end drains through the same
/// terminal resistance.
fn tree() -> FlowNetwork {
    let v = |name: &str, from, to, r| Vessel::uniform(name, from, to, 20e-3, r);
    let vessels = vec![
        v("parent", 0, 1, 1.5e-3),
        v("wide", 1, 2, 1.0e-3),
        v("narrow", 1, 3, 0.6e-3),
        v("wide-a", 2, 4, 0.5e-3),
        v("wide-b", 2, 5, 0.5e-3),
        v("narrow-a", 3, 6, 0.5e-3),
        v("narrow-b", 3, 7, 0.5e-3),
    ];
    let outlets = (4..8)
        .map(|node| Outlet {
            node,
            resistance: 5e9,
            pressure: 0.0,
        })
        .collect();
    FlowNetwork::new(
        8,
        vessels,
        Inlet {
            node: 0,
            condition: InletCondition::Pressure(13_000.0),
        },
        outlets,
        Blood::default(),
    )
    .unwrap()
}

fn site() -> Site {
    let occlusion = Occlusion {
        vessel: 0,
        from_arc: 4e-3,
        to_arc: 12e-3,
        permeability_m2: 1e-15,
    };
    Site {
        occlusion,
        clot: Clot::new(
            ClotComposition {
                red_cell_fraction: 0.5,
            },
            8e-3,
            1.5e-3,
            SCENE_WEDGE_STRAIN,
        ),
        route_from_m: Some(0.0),
        in_place: true,
        bypass_radius_m: None,
        crossed: false,
        embolus: false,
    }
}

fn view(tip_arc_m: f64, inserted_m: f64, outer_diameter_m: f64) -> InstrumentView {
    InstrumentView {
        kind: None,
        stent: None,
        tip_arc_m,
        inserted_m,
        outer_diameter_m,
        bore_m: 0.0,
        axial_force_n: 0.0,
    }
}

/// A tip advancing in the clot is resisted by the cavity-expansion force of its diameter
/// (less the channel the instruments ahead of it opened), scaled by tanh(v/v₀); a tip
/// inside an instrument that reaches further, a still tip, a tip outside the clot and a
/// stent take none.
#[test]
fn the_clot_resists_the_tips_that_open_it() {
    let network = tree();
    let s = site();
    let mut p = Procedure::new(&[s.occlusion], &[0.5], &network, &[(0, 0.0, 20e-3)]);
    let m = s.clot.mechanics;
    let (wire, micro, guide) = (0.36e-3, 0.8e-3, 2.0e-3);
    let dt = 0.002;
    let at = |p: &mut Procedure, views: &[InstrumentView]| {
        p.resist(views, dt);
        p.tip_loads().to_vec()
    };
    // Guide outside the clot, microcatheter in it behind the wire, the wire in it ahead.
    let before = [
        view(2e-3, 0.10, guide),
        view(6e-3, 0.20, micro),
        view(8e-3, 0.30, wire),
    ];
    assert_eq!(at(&mut p, &before), [0.0, 0.0, 0.0], "nothing moved yet");
    let v = 10e-3;
    let moved = [
        view(2e-3, 0.10, guide),
        view(6e-3, 0.20 + v * dt, micro),
        view(8e-3, 0.30 + v * dt, wire),
    ];
    let loads = at(&mut p, &moved);
    let scale = (v / CROSSING_SPEED_M_S).tanh();
    assert_eq!(loads[0], 0.0);
    let micro_expected = -(m.crossing_force_n(micro) - m.crossing_force_n(wire)) * scale;
    assert!(
        (loads[1] - micro_expected).abs() < 1e-12 * micro_expected.abs(),
        "{loads:?}"
    );
    let wire_expected = -m.crossing_force_n(wire) * scale;
    assert!(
        (loads[2] - wire_expected).abs() < 1e-12 * wire_expected.abs(),
        "{loads:?}"
    );
    // Drawn back through it: resisted the other way.
    let back = [
        view(2e-3, 0.10, guide),
        view(6e-3, 0.20, micro),
        view(8e-3, 0.30, wire),
    ];
    let loads = at(&mut p, &back);
    assert!(loads[1] > 0.0 && loads[2] > 0.0, "{loads:?}");
    // The wire inside the microcatheter, which reaches further: shielded; a stent too.
    let mut inside = [
        view(2e-3, 0.10, guide),
        view(9e-3, 0.21, micro),
        view(8e-3, 0.31, wire),
    ];
    let loads = at(&mut p, &inside);
    assert_eq!(loads[2], 0.0, "{loads:?}");
    assert!(loads[1] < 0.0);
    inside[1].stent = crate::scene::catalogue()
        .get("stent-retriever-4x20")
        .and_then(|e| e.stent);
    assert!(inside[1].stent.is_some());
    inside[1].inserted_m += 0.01;
    let loads = at(&mut p, &inside);
    assert_eq!(loads[1], 0.0, "a stent takes none: {loads:?}");
    // Beyond the clot: none.
    let beyond = [
        view(2e-3, 0.10, guide),
        view(15e-3, 0.30, micro),
        view(16e-3, 0.40, wire),
    ];
    assert_eq!(at(&mut p, &beyond), [0.0, 0.0, 0.0]);
}

/// A fragment follows the most flow until a vessel is narrower than the sphere of its
/// volume, and lodges there with its volume.
#[test]
fn fragments_ride_the_main_flow_and_lodge_where_they_no_longer_fit() {
    let network = tree();
    let open = FlowSolver::new(network.clone())
        .unwrap()
        .solve(None)
        .unwrap();
    assert!(open.vessels[1].proximal > open.vessels[2].proximal);
    let site = site();
    // 2 mm of the 1.5 mm clot: a sphere of 1.28 mm radius, wider than the wide branch.
    let big = lodge(&site, 2e-3, &network, &open).unwrap();
    assert_eq!(network.vessels[big.vessel].name, "wide");
    let volume = site.clot.area_m2() * 2e-3;
    let lodged = PI * 1e-3 * 1e-3 * (big.to_arc - big.from_arc);
    assert!((lodged - volume).abs() < 1e-9 * volume);
    // 0.1 mm: a 0.38 mm sphere fits every branch and rides the main flow to its end.
    let small = lodge(&site, 0.1e-3, &network, &open).unwrap();
    assert!(network.vessels[small.vessel].name.starts_with("wide-"));
    // The occlusion it makes cuts that branch's flow.
    let mut solver = FlowSolver::new(network.clone()).unwrap();
    solver.set_occlusions(&[big]).unwrap();
    let now = solver.solve(None).unwrap();
    assert!(now.vessels[1].proximal < 0.01 * open.vessels[1].proximal);
}
