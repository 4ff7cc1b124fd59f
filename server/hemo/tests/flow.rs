//! Network flow against analytic series/parallel/Murray solutions, a dense brute-force nodal
//! solve, the annular Poiseuille profile integrated numerically, and the real circle-of-Willis
//! network.

use cathlab_hemo::{
    Blood, FlowNetwork, FlowSolver, HemoError, Injection, Inlet, InletCondition, ML_PER_MIN, MMHG,
    Narrowing, OpenBfBoundary, Outlet, Vessel, network::annulus_factor,
};
use nalgebra::{DMatrix, DVector};
use proptest::prelude::*;
use rand::{RngExt, SeedableRng, rngs::StdRng};

const ETA: f64 = 4.0e-3;

fn poiseuille(length: f64, radius: f64) -> f64 {
    8.0 * ETA * length / (std::f64::consts::PI * radius.powi(4))
}

fn blood() -> Blood {
    Blood::default()
}

/// Composite Simpson's rule for `f` over `[a, b]` on 20 000 intervals.
fn simpson(f: impl Fn(f64) -> f64, a: f64, b: f64) -> f64 {
    let n = 20_000;
    let h = (b - a) / n as f64;
    let mut sum = f(a) + f(b);
    for i in 1..n {
        sum += f(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    sum * h / 3.0
}

fn relative(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(f64::MIN_POSITIVE)
}

fn circle_of_willis() -> FlowNetwork {
    cathlab_hemo::scenarios::circle_of_willis().expect("the circle-of-Willis network loads")
}

#[test]
fn series_chain_matches_the_sum_of_resistances() {
    let specs = [(0.05, 3e-3), (0.02, 1.5e-3), (0.08, 2.2e-3)];
    let terminal = 3.0e9;
    let (p_in, p_out) = (100.0 * MMHG, 5.0 * MMHG);
    let network = cathlab_hemo::scenarios::series_chain(&specs, terminal, p_in, p_out).unwrap();
    let solution = FlowSolver::new(network).unwrap().solve(None).unwrap();
    let resistances: Vec<f64> = specs.iter().map(|&(l, r)| poiseuille(l, r)).collect();
    let q = (p_in - p_out) / (resistances.iter().sum::<f64>() + terminal);
    let mut p = p_in;
    for (i, f) in solution.vessels.iter().enumerate() {
        assert!(
            relative(f.proximal, q) < 1e-12,
            "vessel {i}: {} vs {q}",
            f.proximal
        );
        assert!(relative(solution.pressure[i], p) < 1e-12);
        p -= q * resistances[i];
    }
    assert!(relative(solution.pressure[3], p) < 1e-12);
    assert!(relative(solution.inlet_flow, q) < 1e-12);
    assert!(relative(solution.outlet_flows[0], q) < 1e-12);
}

#[test]
fn parallel_vessels_split_the_flow_by_conductance() {
    // Node 0 (inlet) -> node 1 through three parallel vessels, then node 1 -> node 2 (outlet).
    let parallel = [(0.04, 1e-3), (0.06, 2e-3), (0.03, 1.5e-3)];
    let mut vessels: Vec<Vessel> = parallel
        .iter()
        .enumerate()
        .map(|(i, &(l, r))| Vessel::uniform(format!("p{i}"), 0, 1, l, r))
        .collect();
    vessels.push(Vessel::uniform("trunk", 1, 2, 0.05, 2.5e-3));
    let q_in = 4.0 * 1e-6; // 4 mL/s prescribed
    let network = FlowNetwork::new(
        3,
        vessels,
        Inlet {
            node: 0,
            condition: InletCondition::Flow(q_in),
        },
        vec![Outlet {
            node: 2,
            resistance: 0.0,
            pressure: 0.0,
        }],
        blood(),
    )
    .unwrap();
    let solution = FlowSolver::new(network).unwrap().solve(None).unwrap();
    let g: Vec<f64> = parallel
        .iter()
        .map(|&(l, r)| 1.0 / poiseuille(l, r))
        .collect();
    let g_total: f64 = g.iter().sum();
    for (i, gi) in g.iter().enumerate() {
        let expected = q_in * gi / g_total;
        assert!(relative(solution.vessels[i].proximal, expected) < 1e-12);
    }
    let expected_p0 = q_in / g_total + q_in * poiseuille(0.05, 2.5e-3);
    assert!(relative(solution.pressure[0], expected_p0) < 1e-12);
    assert!(relative(solution.outlet_flows[0], q_in) < 1e-12);
}

#[test]
fn tapered_resistance_matches_numerical_integration() {
    let v = Vessel::tapered("taper", 0, 1, 0.1, 3e-3, 1.2e-3);
    let exact = v.resistance_between(ETA, 0.0, 0.1);
    // Composite Simpson on 8·r(s)⁻⁴ η / π with 20,000 intervals.
    let numeric = simpson(
        |s| 8.0 * ETA / (std::f64::consts::PI * v.radius_at(s).powi(4)),
        0.0,
        0.1,
    );
    assert!(relative(exact, numeric) < 1e-10, "{exact} vs {numeric}");
    let volume = v.volume_between(0.0, 0.1);
    let cone =
        std::f64::consts::PI * 0.1 / 3.0 * (3e-3f64.powi(2) + 3e-3 * 1.2e-3 + 1.2e-3f64.powi(2));
    assert!(relative(volume, cone) < 1e-13);
}

#[test]
fn annular_factor_matches_the_integrated_velocity_profile() {
    // u(ρ) = G/(4η) [(R² − ρ²) − (R² − a²) ln(R/ρ)/ln(R/a)], Q = ∫ 2πρ u dρ over a..R.
    let r_outer: f64 = 1.0;
    for kappa in [0.05, 0.2, 0.5, 0.8] {
        let a = kappa * r_outer;
        let u = |rho: f64| {
            (r_outer * r_outer - rho * rho)
                - (r_outer * r_outer - a * a) * (r_outer / rho).ln() / (r_outer / a).ln()
        };
        let q_annulus = simpson(
            |rho| 2.0 * std::f64::consts::PI * rho * u(rho) / 4.0,
            a,
            r_outer,
        );
        let q_open = std::f64::consts::PI * r_outer.powi(4) / 8.0;
        let numeric = q_annulus / q_open;
        assert!(
            (annulus_factor(kappa) - numeric).abs() < 1e-9,
            "κ = {kappa}: {} vs {numeric}",
            annulus_factor(kappa)
        );
    }
    assert!((annulus_factor(1e-300) - 1.0).abs() < 1e-2);
}

#[test]
fn a_catheter_never_lowers_a_steeply_tapered_vessels_resistance() {
    // Regression (CI seed 346315): the annular resistance was one 5-point quadrature of
    // 1 / (r⁴ f(κ)), which under-counts ∫ r⁻⁴ on a steep taper; a thin catheter there came out
    // below the open vessel and a narrowing raised the network's inlet flow. Reference: composite
    // Simpson's rule on 20 000 intervals.
    let eta = 3.5e-3;
    for (r0, r1) in [(4e-3, 0.6e-3), (0.6e-3, 4e-3), (2e-3, 1.9e-3)] {
        let vessel = Vessel::tapered("cone", 0, 1, 0.05, r0, r1);
        for catheter in [1e-6, 0.1e-3, 0.4e-3, 0.55e-3] {
            let open = vessel.resistance_between(eta, 0.0, 0.05);
            let annular = vessel.annular_resistance_between(eta, 0.0, 0.05, catheter);
            assert!(
                annular >= open,
                "{r0} → {r1}, catheter {catheter}: {annular} < {open}"
            );
            let integrand = |s: f64| {
                let r = r0 + (r1 - r0) * s / 0.05;
                let kappa = (catheter / r).min(0.99);
                8.0 * eta / std::f64::consts::PI / (r.powi(4) * annulus_factor(kappa))
            };
            let reference = simpson(integrand, 0.0, 0.05);
            assert!(
                relative(annular, reference) < 1e-4,
                "{r0} → {r1}, catheter {catheter}: {annular} vs {reference}"
            );
        }
    }
}

/// An independent dense nodal solve: K p = f with Dirichlet rows, via nalgebra's LU.
fn dense_solve(network: &FlowNetwork, conductance: &[f64]) -> Vec<f64> {
    let n = network.node_count;
    let mut k = DMatrix::<f64>::zeros(n, n);
    let mut f = DVector::<f64>::zeros(n);
    for (v, &g) in network.vessels.iter().zip(conductance) {
        k[(v.from, v.from)] += g;
        k[(v.to, v.to)] += g;
        k[(v.from, v.to)] -= g;
        k[(v.to, v.from)] -= g;
    }
    let mut dirichlet = vec![None; n];
    match network.inlet.condition {
        InletCondition::Pressure(p) => dirichlet[network.inlet.node] = Some(p),
        InletCondition::Flow(q) => f[network.inlet.node] += q,
    }
    for o in &network.outlets {
        if o.resistance == 0.0 {
            dirichlet[o.node] = Some(o.pressure);
        } else {
            k[(o.node, o.node)] += 1.0 / o.resistance;
            f[o.node] += o.pressure / o.resistance;
        }
    }
    for (node, d) in dirichlet.iter().enumerate() {
        if let Some(p) = d {
            k.row_mut(node).fill(0.0);
            k[(node, node)] = 1.0;
            f[node] = *p;
        }
    }
    let p = k.lu().solve(&f).expect("dense solve");
    p.iter().copied().collect()
}

fn random_network(seed: u64, nodes: usize, extra: usize) -> FlowNetwork {
    cathlab_hemo::network::random_network(seed, nodes, extra).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn sparse_solve_matches_a_dense_solve(seed in 0u64..1_000_000, nodes in 4usize..60, extra in 0usize..12) {
        let network = random_network(seed, nodes, extra);
        let solver = FlowSolver::new(network.clone()).unwrap();
        let sparse = solver.solve(None).unwrap();
        let dense = dense_solve(&network, solver.conductances());
        let scale = 100.0 * MMHG;
        for (a, b) in sparse.pressure.iter().zip(&dense) {
            prop_assert!((a - b).abs() < 1e-10 * scale, "{a} vs {b}");
        }
        let residual = sparse.kirchhoff_residuals(&network);
        let q_scale = sparse.vessels.iter().map(|f| f.proximal.abs()).fold(0.0, f64::max);
        for r in residual {
            prop_assert!(r.abs() <= 1e-12 * q_scale, "Kirchhoff residual {r} vs flow {q_scale}");
        }
    }

    #[test]
    fn narrowing_update_matches_a_dense_solve(seed in 0u64..1_000_000, nodes in 4usize..40, k in 1usize..6) {
        let network = random_network(seed, nodes, 3);
        let mut solver = FlowSolver::new(network.clone()).unwrap();
        let mut rng = StdRng::seed_from_u64(seed ^ 0x5eed);
        let narrowings: Vec<Narrowing> = (0..k)
            .map(|_| {
                let vessel = rng.random_range(0..network.vessels.len());
                let length = network.vessels[vessel].length();
                let a = rng.random_range(0.0..0.5 * length);
                Narrowing {
                    vessel,
                    from_arc: a,
                    to_arc: rng.random_range(a..length),
                    catheter_radius: 0.4e-3,
                }
            })
            .collect();
        solver.set_narrowings(&narrowings).unwrap();
        let updated = solver.solve(None).unwrap();
        let dense = dense_solve(&network, solver.conductances());
        for (a, b) in updated.pressure.iter().zip(&dense) {
            prop_assert!((a - b).abs() < 1e-9 * 100.0 * MMHG, "{a} vs {b}");
        }
        // Narrowing only ever raises resistance, so with one pressure at every outlet (a
        // two-terminal network, Rayleigh's monotonicity law) the inlet flow cannot grow. With
        // outlets at different pressures it can: outlet-to-outlet backflow through a narrowed
        // vessel is cut and more of the outlets' demand falls on the inlet (CI seed 346315).
        let mut level = network.clone();
        for outlet in &mut level.outlets {
            outlet.pressure = 0.0;
        }
        let mut solver = FlowSolver::new(level).unwrap();
        let open = solver.solve(None).unwrap();
        solver.set_narrowings(&narrowings).unwrap();
        let narrowed = solver.solve(None).unwrap();
        prop_assert!(
            narrowed.inlet_flow <= open.inlet_flow * (1.0 + 1e-12),
            "{} > {}",
            narrowed.inlet_flow,
            open.inlet_flow
        );
    }
}

#[test]
fn murray_tree_gives_flow_proportional_to_radius_cubed() {
    // A full binary tree, depth 6, random asymmetric splits conserving r³, length = 20 r:
    // every subtree's resistance ∝ r⁻³, so the flow in every vessel ∝ r³.
    let mut rng = StdRng::seed_from_u64(7);
    let mut vessels = Vec::new();
    let mut radius_of_node_vessel = Vec::new();
    // Node 0: inlet; vessel 0 from node 0 to node 1 with radius r0.
    let r0 = 3e-3;
    vessels.push(Vessel::uniform("root", 0, 1, 20.0 * r0, r0));
    radius_of_node_vessel.push(r0);
    let mut frontier = vec![(1usize, r0)];
    let mut next_node = 2;
    for _level in 0..6 {
        let mut next = Vec::new();
        for (node, r) in frontier {
            let share: f64 = rng.random_range(0.15..0.85);
            for s in [share, 1.0 - share] {
                let rc = r * s.cbrt();
                vessels.push(Vessel::uniform(
                    format!("n{next_node}"),
                    node,
                    next_node,
                    20.0 * rc,
                    rc,
                ));
                radius_of_node_vessel.push(rc);
                next.push((next_node, rc));
                next_node += 1;
            }
        }
        frontier = next;
    }
    let outlets = frontier
        .iter()
        .map(|&(node, _)| Outlet {
            node,
            resistance: 0.0,
            pressure: 0.0,
        })
        .collect();
    let network = FlowNetwork::new(
        next_node,
        vessels,
        Inlet {
            node: 0,
            condition: InletCondition::Pressure(80.0 * MMHG),
        },
        outlets,
        blood(),
    )
    .unwrap();
    let solution = FlowSolver::new(network).unwrap().solve(None).unwrap();
    let q0 = solution.vessels[0].proximal;
    let mut worst: f64 = 0.0;
    for (f, r) in solution.vessels.iter().zip(&radius_of_node_vessel) {
        let expected = q0 * (r / r0).powi(3);
        worst = worst.max(relative(f.proximal, expected));
    }
    println!("Murray tree (127 vessels): worst relative deviation from Q ∝ r³ = {worst:.1e}");
    assert!(worst < 1e-12, "worst deviation {worst}");
}

#[test]
fn injection_is_a_point_source_that_can_reverse_upstream_flow() {
    // Tube 0 -> 1 -> 2 (two halves), inlet at 0 (pressure), outlet at 2 through R_t.
    let (l, r) = (0.1, 2e-3);
    let network = FlowNetwork::new(
        2,
        vec![Vessel::uniform("tube", 0, 1, l, r)],
        Inlet {
            node: 0,
            condition: InletCondition::Pressure(100.0 * MMHG),
        },
        vec![Outlet {
            node: 1,
            resistance: 6e9,
            pressure: 0.0,
        }],
        blood(),
    )
    .unwrap();
    let solver = FlowSolver::new(network.clone()).unwrap();
    let resting = solver.solve(None).unwrap().vessels[0].proximal;
    let (r1, r2, rt) = (poiseuille(0.04, r), poiseuille(0.06, r), 6e9);
    for rate_ml_s in [1.0, 3.0, 6.0] {
        let rate = rate_ml_s * 1e-6;
        let injection = Injection {
            vessel: 0,
            arc: 0.04,
            rate,
            concentration: 300.0,
        };
        let s = solver.solve(Some(&injection)).unwrap();
        // Superposition: resting flow minus the share of J that goes upstream.
        let upstream = (100.0 * MMHG - rate * (r2 + rt)) / (r1 + r2 + rt);
        assert!(relative(s.vessels[0].proximal, upstream) < 1e-12);
        assert!(relative(s.vessels[0].distal, upstream + rate) < 1e-12);
        assert!(relative(s.outlet_flows[0], upstream + rate) < 1e-12);
        println!(
            "injection {rate_ml_s} mL/s into a vessel carrying {:.2} mL/s: upstream flow {:.3} mL/s",
            resting * 1e6,
            upstream * 1e6
        );
        if rate > resting * (r1 + r2 + rt) / (r2 + rt) {
            assert!(
                s.vessels[0].proximal < 0.0,
                "a strong injection reverses upstream flow"
            );
            assert!(s.inlet_flow < 0.0);
        }
    }
}

#[test]
fn circle_of_willis_flows_are_physiological() {
    let network = circle_of_willis();
    assert_eq!(network.vessels.len(), 33);
    assert_eq!(network.outlets.len(), 11);
    let solver = FlowSolver::new(network.clone()).unwrap();
    let solution = solver.solve(None).unwrap();
    let flow =
        |name: &str| solution.vessels[network.vessel_id(name).unwrap()].proximal / ML_PER_MIN;
    let residual = solution.kirchhoff_residuals(&network);
    let worst = residual.iter().fold(0.0f64, |m, r| m.max(r.abs()));
    assert!(
        worst < 1e-12 * solution.inlet_flow,
        "Kirchhoff residual {worst}"
    );
    // Ranges (mL/min) from transcranial Doppler and phase-contrast MRI in healthy adults.
    let checks = [
        ("L-ICA", flow("11-L-int-carotidI"), 180.0, 350.0),
        ("R-ICA", flow("12-R-int-carotidI"), 180.0, 350.0),
        ("L-MCA", flow("23-L-MCA"), 90.0, 200.0),
        ("R-MCA", flow("24-R-MCA"), 90.0, 200.0),
        ("L-ACA A2", flow("29-L-ACA-A2"), 40.0, 130.0),
        ("R-ACA A2", flow("30-R-ACA-A2"), 40.0, 130.0),
        ("L-PCA P2", flow("32-L-PCA-P2"), 30.0, 110.0),
        ("R-PCA P2", flow("33-R-PCA-P2"), 30.0, 110.0),
        ("basilar", flow("22-Basilar"), 80.0, 250.0),
        ("R-vertebral", flow("14-R-vertebral"), 40.0, 150.0),
        ("L-vertebral", flow("17-L-vertebral"), 40.0, 150.0),
    ];
    println!("| vessel | flow (mL/min) | range |");
    for (name, q, lo, hi) in checks {
        println!("| {name} | {q:.0} | {lo:.0}–{hi:.0} |");
        assert!(
            (lo..=hi).contains(&q),
            "{name}: {q:.1} mL/min outside {lo}–{hi}"
        );
    }
    let cerebral = flow("11-L-int-carotidI") + flow("12-R-int-carotidI") + flow("22-Basilar");
    println!(
        "total cerebral {cerebral:.0} mL/min; cardiac output {:.2} L/min",
        solution.inlet_flow / ML_PER_MIN / 1000.0
    );
    assert!((450.0..=900.0).contains(&cerebral));
}

#[test]
fn a_catheter_in_the_carotid_reduces_its_flow() {
    let network = circle_of_willis();
    let mut solver = FlowSolver::new(network.clone()).unwrap();
    let lcca = network.vessel_id("5-L-commoncarotid").unwrap();
    let open = solver.solve(None).unwrap().vessels[lcca].proximal;
    // A 6 F guide catheter (1 mm outer radius) along the whole 2.5 mm-radius LCCA.
    solver
        .set_narrowings(&[Narrowing {
            vessel: lcca,
            from_arc: 0.0,
            to_arc: network.vessels[lcca].length(),
            catheter_radius: 1.0e-3,
        }])
        .unwrap();
    let narrowed = solver.solve(None).unwrap();
    let q = narrowed.vessels[lcca].proximal;
    println!(
        "LCCA flow {:.0} mL/min open, {:.0} mL/min with a 6 F catheter",
        open / ML_PER_MIN,
        q / ML_PER_MIN
    );
    assert!(q < open && q > 0.5 * open);
    let residual = narrowed.kirchhoff_residuals(&network);
    assert!(
        residual
            .iter()
            .all(|r| r.abs() < 1e-12 * narrowed.inlet_flow)
    );
}

#[test]
fn bad_input_gives_clear_errors() {
    let inlet = Inlet {
        node: 0,
        condition: InletCondition::Pressure(100.0 * MMHG),
    };
    let outlet = vec![Outlet {
        node: 1,
        resistance: 1e9,
        pressure: 0.0,
    }];
    let err = FlowNetwork::new(
        2,
        vec![Vessel::uniform("neg", 0, 1, 0.1, -1e-3)],
        inlet,
        outlet.clone(),
        blood(),
    )
    .unwrap_err();
    assert!(matches!(err, HemoError::InvalidParameter { .. }));
    assert!(err.to_string().contains("\"neg\" radius"), "{err}");

    let err = FlowNetwork::new(
        2,
        vec![Vessel::uniform("zero", 0, 1, 0.0, 1e-3)],
        inlet,
        outlet.clone(),
        blood(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("zero"), "{err}");

    let err = FlowNetwork::new(
        4,
        vec![
            Vessel::uniform("a", 0, 1, 0.1, 1e-3),
            Vessel::uniform("b", 2, 3, 0.1, 1e-3),
        ],
        inlet,
        outlet.clone(),
        blood(),
    )
    .unwrap_err();
    assert!(
        matches!(err, HemoError::Disconnected { components: 2, .. }),
        "{err}"
    );

    let err = FlowNetwork::new(
        2,
        vec![Vessel::uniform("a", 0, 1, 0.1, 1e-3)],
        inlet,
        vec![],
        blood(),
    )
    .unwrap_err();
    assert!(matches!(err, HemoError::NoOutlet), "{err}");

    let err = FlowNetwork::new(
        2,
        vec![Vessel::uniform("loop", 1, 1, 0.1, 1e-3)],
        inlet,
        outlet.clone(),
        blood(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("both ends"), "{err}");

    let network = FlowNetwork::new(
        2,
        vec![Vessel::uniform("a", 0, 1, 0.1, 1e-3)],
        inlet,
        outlet,
        blood(),
    )
    .unwrap();
    let solver = FlowSolver::new(network).unwrap();
    let err = solver
        .solve(Some(&Injection {
            vessel: 0,
            arc: 0.05,
            rate: f64::NAN,
            concentration: 300.0,
        }))
        .unwrap_err();
    assert!(err.to_string().contains("injection rate"), "{err}");
    let err = solver
        .solve(Some(&Injection {
            vessel: 3,
            arc: 0.05,
            rate: 1e-6,
            concentration: 300.0,
        }))
        .unwrap_err();
    assert!(
        matches!(err, HemoError::VesselIndex { index: 3, count: 1 }),
        "{err}"
    );

    let err = cathlab_hemo::parse_openbf(
        "network:\n  - label: a\n    sn: 1\n    tn: 2\n    L: 0.1\n",
        "inline.yaml",
        OpenBfBoundary {
            inlet: InletCondition::Pressure(1.0),
            outlet_pressure: 0.0,
        },
    )
    .unwrap_err();
    assert!(
        err.to_string().contains("inline.yaml") && err.to_string().contains("Rp"),
        "{err}"
    );
    let err = cathlab_hemo::parse_openbf(
        "network: [",
        "broken.yaml",
        OpenBfBoundary {
            inlet: InletCondition::Pressure(1.0),
            outlet_pressure: 0.0,
        },
    )
    .unwrap_err();
    assert!(matches!(err, HemoError::Parse { .. }), "{err}");
}
