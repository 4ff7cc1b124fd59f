//! Clots in the flow network: a clot adds its Darcy resistance (checked on a series chain
//! against the analytic sum), a clot in the left M1 of the real circle-of-Willis network cuts
//! its flow to what seeps through the clot while every junction still conserves flow, and
//! removing it restores every flow; pial collaterals calibrated to a share of the territory's
//! flow bring it past the clot; bad clots and collaterals are named errors.

use cathlab_hemo::{
    ClotComposition, CollateralStatus, FlowNetwork, FlowSolver, HemoError, ML_PER_MIN, MMHG,
    Narrowing, Occlusion, with_pial_collaterals,
};

const ETA: f64 = 4.0e-3;

fn relative(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(f64::MIN_POSITIVE)
}

#[test]
fn a_clot_in_a_series_chain_adds_its_darcy_resistance() {
    let specs = [(0.05, 3e-3), (0.02, 1.5e-3), (0.08, 2.2e-3)];
    let terminal = 3.0e9;
    let (p_in, p_out) = (100.0 * MMHG, 5.0 * MMHG);
    let network = cathlab_hemo::scenarios::series_chain(&specs, terminal, p_in, p_out).unwrap();
    let mut solver = FlowSolver::new(network).unwrap();
    let k = 1e-14;
    solver
        .set_occlusions(&[Occlusion {
            vessel: 1,
            from_arc: 0.005,
            to_arc: 0.015,
            permeability_m2: k,
        }])
        .unwrap();
    let poiseuille = |l: f64, r: f64| 8.0 * ETA * l / (std::f64::consts::PI * r.powi(4));
    let clot = ETA * 0.010 / (k * std::f64::consts::PI * 1.5e-3f64.powi(2));
    let total = poiseuille(0.05, 3e-3)
        + poiseuille(0.01, 1.5e-3)
        + clot
        + poiseuille(0.08, 2.2e-3)
        + terminal;
    let q = (p_in - p_out) / total;
    let solution = solver.solve(None).unwrap();
    for f in &solution.vessels {
        assert!(relative(f.proximal, q) < 1e-9, "{} vs {q}", f.proximal);
    }
    // A catheter narrowing elsewhere still applies on top of the clot.
    solver
        .set_narrowings(&[Narrowing {
            vessel: 0,
            from_arc: 0.0,
            to_arc: 0.05,
            catheter_radius: 1e-3,
        }])
        .unwrap();
    let narrowed = solver.solve(None).unwrap();
    assert!(narrowed.vessels[1].proximal < q);
}

fn circle_of_willis() -> FlowNetwork {
    cathlab_hemo::scenarios::circle_of_willis().expect("the circle-of-Willis network loads")
}

/// The acceptance case: a 10 mm clot in the left M1.
#[test]
fn a_clot_in_the_left_m1_stops_its_flow_and_removing_it_restores_every_flow() {
    let network = circle_of_willis();
    let mut solver = FlowSolver::new(network.clone()).unwrap();
    let open = solver.solve(None).unwrap();
    let m1 = network.vessel_id("23-L-MCA").unwrap();
    let length = network.vessels[m1].length();
    let clot = |composition: f64| Occlusion {
        vessel: m1,
        from_arc: 0.3 * length,
        to_arc: 0.3 * length + 0.010,
        permeability_m2: ClotComposition {
            red_cell_fraction: composition,
        }
        .permeability_m2(),
    };
    let flow = |s: &cathlab_hemo::FlowSolution, name: &str| {
        s.vessels[network.vessel_id(name).unwrap()].proximal / ML_PER_MIN
    };
    solver.set_occlusions(&[clot(0.5)]).unwrap();
    let occluded = solver.solve(None).unwrap();
    let worst = occluded
        .kirchhoff_residuals(&network)
        .iter()
        .fold(0.0f64, |m, r| m.max(r.abs()));
    assert!(
        worst < 1e-12 * occluded.inlet_flow,
        "Kirchhoff residual {worst}"
    );
    println!("| vessel | open (mL/min) | left M1 occluded (mL/min) |");
    for name in [
        "11-L-int-carotidI",
        "23-L-MCA",
        "25-L-ACAA1",
        "29-L-ACA-A2",
        "31-ACoA",
        "19-L-PCoA",
        "24-R-MCA",
    ] {
        println!(
            "| {name} | {:.2} | {:.4} |",
            flow(&open, name),
            flow(&occluded, name)
        );
    }
    // The network has no pial collaterals into the M1 territory: what reaches it is what
    // seeps through the clot, the pressure drop over the clotted vessel and its territory
    // divided by their resistance.
    let seep = flow(&occluded, "23-L-MCA");
    assert!(
        seep >= 0.0 && seep < 1e-3 * flow(&open, "23-L-MCA"),
        "{seep} mL/min"
    );
    let vessel = &network.vessels[m1];
    let outlet = network
        .outlets
        .iter()
        .find(|o| o.node == vessel.to)
        .unwrap();
    let c = clot(0.5);
    let clotted = vessel.resistance_between(network.blood.viscosity, 0.0, c.from_arc)
        + vessel.darcy_resistance_between(
            network.blood.viscosity,
            c.permeability_m2,
            c.from_arc,
            c.to_arc,
        )
        + vessel.resistance_between(network.blood.viscosity, c.to_arc, length);
    let expected =
        (occluded.pressure[vessel.from] - outlet.pressure) / (clotted + outlet.resistance);
    assert!(
        relative(seep * ML_PER_MIN, expected) < 1e-6,
        "{seep} vs {expected}"
    );
    // The other territories get a little more: the pressure upstream rises.
    assert!(flow(&occluded, "24-R-MCA") > flow(&open, "24-R-MCA"));
    assert!(flow(&occluded, "29-L-ACA-A2") > flow(&open, "29-L-ACA-A2"));
    // A fibrin-rich clot lets less through than a red-cell-rich one, by their permeabilities.
    solver.set_occlusions(&[clot(0.0)]).unwrap();
    let white = flow(&solver.solve(None).unwrap(), "23-L-MCA");
    solver.set_occlusions(&[clot(1.0)]).unwrap();
    let red = flow(&solver.solve(None).unwrap(), "23-L-MCA");
    assert!(
        (50.0..150.0).contains(&(red / white)),
        "red/white {}",
        red / white
    );
    // Removed, every flow is back.
    solver.set_occlusions(&[]).unwrap();
    let reopened = solver.solve(None).unwrap();
    for (a, b) in reopened.vessels.iter().zip(&open.vessels) {
        assert!((a.proximal - b.proximal).abs() <= 1e-9 * open.inlet_flow);
    }
}

/// With pial collaterals from the left ACA and PCA territories, the occluded M1's territory
/// still gets the collaterals' share: the network's only route past the clot.
#[test]
fn collaterals_feed_the_occluded_territory_at_their_calibrated_share() {
    let network = circle_of_willis();
    let (with, resistance) = with_pial_collaterals(
        &network,
        "23-L-MCA",
        &["29-L-ACA-A2", "32-L-PCA-P2"],
        CollateralStatus {
            supply_fraction: 0.2,
        },
    )
    .unwrap();
    println!("collateral resistance {resistance:.3e} Pa·s/m³");
    let bare = FlowSolver::new(network.clone())
        .unwrap()
        .solve(None)
        .unwrap();
    let mut solver = FlowSolver::new(with.clone()).unwrap();
    let open = solver.solve(None).unwrap();
    let m1 = with.vessel_id("23-L-MCA").unwrap();
    let territory = with
        .outlets
        .iter()
        .position(|o| o.node == with.vessels[m1].to)
        .unwrap();
    // At rest the territories' pressures are alike: the collaterals barely change the flows.
    for (a, b) in open.vessels.iter().zip(&bare.vessels) {
        assert!((a.proximal - b.proximal).abs() < 0.02 * bare.vessels[m1].proximal);
    }
    let length = with.vessels[m1].length();
    solver
        .set_occlusions(&[Occlusion {
            vessel: m1,
            from_arc: 0.3 * length,
            to_arc: 0.3 * length + 0.010,
            permeability_m2: ClotComposition {
                red_cell_fraction: 0.5,
            }
            .permeability_m2(),
        }])
        .unwrap();
    let occluded = solver.solve(None).unwrap();
    let worst = occluded
        .kirchhoff_residuals(&with)
        .iter()
        .fold(0.0f64, |m, r| m.max(r.abs()));
    assert!(
        worst < 1e-12 * occluded.inlet_flow,
        "Kirchhoff residual {worst}"
    );
    let collateral: f64 = occluded.vessels[network.vessels.len()..]
        .iter()
        .map(|v| v.proximal)
        .sum();
    let seep = occluded.vessels[m1].proximal;
    let reached = occluded.outlet_flows[territory];
    println!(
        "left MCA territory: {:.1} mL/min open, {:.2} mL/min occluded ({:.2} through the \
         collaterals, {:.5} through the clot)",
        open.outlet_flows[territory] / ML_PER_MIN,
        reached / ML_PER_MIN,
        collateral / ML_PER_MIN,
        seep / ML_PER_MIN
    );
    // Both collaterals run towards the occluded territory, and bring all it gets but the seep.
    assert!(
        occluded.vessels[network.vessels.len()..]
            .iter()
            .all(|v| v.proximal > 0.0)
    );
    assert!(relative(reached, collateral + seep) < 1e-9);
    assert!(relative(reached, 0.2 * bare.vessels[m1].proximal) < 0.01);
    let bad = with_pial_collaterals(
        &network,
        "23-L-MCA",
        &["29-L-ACA-A2"],
        CollateralStatus {
            supply_fraction: 1.5,
        },
    )
    .unwrap_err();
    assert!(
        bad.to_string().contains("collateral supply fraction"),
        "{bad}"
    );
    let unknown = with_pial_collaterals(
        &network,
        "23-L-MCA",
        &["no such vessel"],
        CollateralStatus {
            supply_fraction: 0.2,
        },
    )
    .unwrap_err();
    assert!(unknown.to_string().contains("no such vessel"), "{unknown}");
}

/// The reperfusion grade of the left M1's territory as the clot lets more through (a sweep
/// of its permeability, as a stent's channel or a partial retrieval would): the territory is
/// the left MCA's outlet alone, the fraction is its flow over the open flow, and the grade
/// climbs through the eTICI bands from 0 to 3.
#[test]
fn reperfusion_climbs_through_the_etici_grades_as_the_clot_opens() {
    use cathlab_hemo::reperfusion::{occluded_territory, reperfusion};
    let network = circle_of_willis();
    let mut solver = FlowSolver::new(network.clone()).unwrap();
    let open = solver.solve(None).unwrap();
    let m1 = network.vessel_id("23-L-MCA").unwrap();
    let outlet = network
        .outlets
        .iter()
        .position(|o| o.node == network.vessels[m1].to)
        .unwrap();
    let length = network.vessels[m1].length();
    let clot = |k: f64| Occlusion {
        vessel: m1,
        from_arc: 0.3 * length,
        to_arc: 0.3 * length + 0.010,
        permeability_m2: k,
    };
    solver.set_occlusions(&[clot(1e-15)]).unwrap();
    let territory = occluded_territory(&open, &solver.solve(None).unwrap()).unwrap();
    assert_eq!(territory, vec![outlet]);
    let mut grades = Vec::new();
    for step in 0..=40 {
        let k = 1e-15 * 10f64.powf(step as f64 * 0.25);
        solver.set_occlusions(&[clot(k)]).unwrap();
        let now = solver.solve(None).unwrap();
        let r = reperfusion(&open, &now, &territory).unwrap();
        let ratio = now.outlet_flows[outlet] / open.outlet_flows[outlet];
        assert!(
            (r.fraction - ratio.min(1.0)).abs() < 1e-12,
            "{} vs {ratio}",
            r.fraction
        );
        grades.push(r.grade);
    }
    assert!(grades.windows(2).all(|w| w[0] <= w[1]), "{grades:?}");
    let mut distinct = grades.clone();
    distinct.dedup();
    println!(
        "grades over the sweep: {:?}",
        distinct.iter().map(|g| g.label()).collect::<Vec<_>>()
    );
    assert!(distinct.len() >= 5, "{distinct:?}");
    assert_eq!(grades[0].label(), "0");
    solver.set_occlusions(&[]).unwrap();
    let back = reperfusion(&open, &solver.solve(None).unwrap(), &territory).unwrap();
    assert_eq!(back.grade.label(), "3");
}

#[test]
fn bad_clots_are_named_errors() {
    let network = circle_of_willis();
    let mut solver = FlowSolver::new(network.clone()).unwrap();
    let m1 = network.vessel_id("23-L-MCA").unwrap();
    let length = network.vessels[m1].length();
    let good = Occlusion {
        vessel: m1,
        from_arc: 0.001,
        to_arc: 0.005,
        permeability_m2: 1e-15,
    };
    let cases = [
        (
            Occlusion {
                vessel: 999,
                ..good
            },
            "999",
        ),
        (
            Occlusion {
                from_arc: -0.001,
                ..good
            },
            "clot start arc",
        ),
        (
            Occlusion {
                to_arc: 0.0005,
                ..good
            },
            "clot end arc",
        ),
        (
            Occlusion {
                to_arc: length + 0.01,
                ..good
            },
            "clot end arc",
        ),
        (
            Occlusion {
                permeability_m2: 0.0,
                ..good
            },
            "clot permeability",
        ),
        (
            Occlusion {
                permeability_m2: f64::NAN,
                ..good
            },
            "clot permeability",
        ),
    ];
    for (clot, expected) in cases {
        let e = solver.set_occlusions(&[clot]).unwrap_err();
        assert!(e.to_string().contains(expected), "{e}");
        assert!(!matches!(e, HemoError::Solver(_)), "{e}");
    }
    // A refused clot leaves the solver as it was.
    assert_eq!(solver.occlusions().count(), 0);
    assert!(
        ClotComposition {
            red_cell_fraction: -0.1
        }
        .validate()
        .unwrap_err()
        .to_string()
        .contains("red-cell fraction")
    );
}
