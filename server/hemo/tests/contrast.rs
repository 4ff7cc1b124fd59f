//! Contrast advection: bolus transport against the exact solution (timing, peak, order of
//! convergence), first-order upwind for contrast, iodine mass balance on the real network,
//! the maximum principle, junction mixing against steady mass balance, and backflow.

use cathlab_hemo::scenarios::{BolusShape, advect_bolus};
use cathlab_hemo::{
    Blood, Contrast, ContrastSettings, FlowNetwork, FlowSolver, Injection, Inlet, InletCondition,
    Limiter, MMHG, Outlet, Vessel,
};
use proptest::prelude::*;

#[test]
fn bolus_arrives_on_time_and_keeps_its_peak_not_with_upwind() {
    println!("| bolus (5 mm) | cells | limiter | peak kept | arrival error (cells) |");
    for shape in [BolusShape::Plug, BolusShape::Gaussian] {
        for dx in [1e-3, 0.5e-3, 0.25e-3] {
            for limiter in [
                Limiter::Upwind,
                Limiter::VanLeer,
                Limiter::MonotonizedCentral,
                Limiter::Superbee,
            ] {
                let run = advect_bolus(limiter, shape, dx, 0.5, 5e-3, 0.15).unwrap();
                let kept = run.peak_kept();
                let shift = run.arrival_error_cells();
                println!(
                    "| {shape:?} | {:.2} mm | {limiter:?} | {:.1} % | {shift:+.2} |",
                    dx * 1e3,
                    100.0 * kept
                );
                assert!(run.profile.iter().all(|&c| (0.0..=300.0).contains(&c)));
                // The acceptance case: the default 0.25 mm cells.
                if dx == ContrastSettings::default().cell_length {
                    assert!(
                        shift.abs() <= 1.0,
                        "{shape:?} {limiter:?} off by {shift} cells"
                    );
                    match limiter {
                        Limiter::Upwind => assert!(kept < 0.6, "upwind kept {kept}"),
                        _ => assert!(kept >= 0.85, "{limiter:?} kept only {kept}"),
                    }
                }
            }
        }
    }
}

#[test]
fn van_leer_converges_at_second_order_and_upwind_at_first() {
    let l1_error = |limiter, dx| {
        let run = advect_bolus(limiter, BolusShape::Gaussian, dx, 0.5, 20e-3, 0.05).unwrap();
        run.relative_l1_error()
    };
    for (limiter, lo, hi) in [(Limiter::VanLeer, 1.6, 2.3), (Limiter::Upwind, 0.8, 1.2)] {
        let errors: Vec<f64> = [2e-3, 1e-3, 0.5e-3, 0.25e-3]
            .iter()
            .map(|&dx| l1_error(limiter, dx))
            .collect();
        let order = (errors[2] / errors[3]).log2();
        println!("{limiter:?}: relative L1 errors {errors:?}, observed order {order:.2}");
        assert!((lo..=hi).contains(&order), "{limiter:?} order {order}");
    }
}

fn circle_of_willis() -> FlowNetwork {
    cathlab_hemo::scenarios::circle_of_willis().expect("the circle-of-Willis network loads")
}

#[test]
fn iodine_is_conserved_on_the_circle_of_willis() {
    let network = circle_of_willis();
    let solver = FlowSolver::new(network.clone()).unwrap();
    let ica = network.vessel_id("11-L-int-carotidI").unwrap();
    // A 6 mL/s, 300 mgI/mL injection for 1.5 s into the left ICA, then 4.5 s of washout.
    let injection = Injection {
        vessel: ica,
        arc: 0.5 * network.vessels[ica].length(),
        rate: 6e-6,
        concentration: 300.0,
    };
    let with = solver.solve(Some(&injection)).unwrap();
    let without = solver.solve(None).unwrap();
    let mut contrast = Contrast::new(&network, ContrastSettings::default()).unwrap();
    let dt = 1.0 / 60.0;
    let mut substeps = 0;
    for frame in 0..360 {
        let flow = if frame < 90 { &with } else { &without };
        contrast.set_flow(&network, flow).unwrap();
        substeps += contrast.step(dt).unwrap();
        let (lo, hi) = contrast.range();
        assert!(
            lo >= 0.0 && hi <= 300.0 * (1.0 + 1e-12),
            "range {lo}..{hi} at frame {frame}"
        );
    }
    let injected = contrast.iodine_injected();
    let present = contrast.iodine_present();
    let washed = contrast.iodine_washed_out();
    let imbalance = (injected - present - washed).abs() / injected;
    println!(
        "injected {:.4} g iodine, present {:.4} g, washed out {:.4} g after 6 s \
         ({substeps} sub-steps): relative imbalance {imbalance:.1e}",
        injected * 1e3,
        present * 1e3,
        washed * 1e3
    );
    assert!((injected - 6e-6 * 1.5 * 300.0).abs() < 1e-9 * injected);
    assert!(imbalance < 1e-9, "imbalance {imbalance}");
    assert!(
        washed > 0.5 * injected,
        "most contrast washes out within 4.5 s"
    );
}

#[test]
fn junctions_mix_by_flow_and_reach_the_steady_mass_balance() {
    // Inlet -> A; A splits into two unequal vessels that rejoin at B; B -> outlet. Injection in
    // the first branch. At steady state the branch carries J·C/(Q_branch + J) downstream of the
    // tip and the outlet vessel carries J·C/(Q_total + J).
    let network = FlowNetwork::new(
        4,
        vec![
            Vessel::uniform("in", 0, 1, 0.02, 2e-3),
            Vessel::uniform("upper", 1, 2, 0.03, 1.5e-3),
            Vessel::uniform("lower", 1, 2, 0.05, 1.2e-3),
            Vessel::uniform("out", 2, 3, 0.02, 2e-3),
        ],
        Inlet {
            node: 0,
            condition: InletCondition::Pressure(90.0 * MMHG),
        },
        vec![Outlet {
            node: 3,
            resistance: 6e9,
            pressure: 0.0,
        }],
        Blood::default(),
    )
    .unwrap();
    let injection = Injection {
        vessel: 1,
        arc: 0.01,
        rate: 0.5e-6,
        concentration: 300.0,
    };
    let solution = FlowSolver::new(network.clone())
        .unwrap()
        .solve(Some(&injection))
        .unwrap();
    let mut contrast = Contrast::new(&network, ContrastSettings::default()).unwrap();
    contrast.set_flow(&network, &solution).unwrap();
    for _ in 0..600 {
        contrast.step(0.01).unwrap();
    }
    let upper = solution.vessels[1];
    let branch_expected = injection.rate * 300.0 / upper.distal;
    let out_expected = injection.rate * 300.0 / solution.vessels[3].proximal;
    let branch_end = *contrast.concentration(1).last().unwrap();
    let out_end = *contrast.concentration(3).last().unwrap();
    println!(
        "steady mixing: branch {branch_end:.6} (expected {branch_expected:.6}), outlet \
         {out_end:.6} (expected {out_expected:.6}) mg/mL"
    );
    assert!((branch_end - branch_expected).abs() < 1e-9 * branch_expected);
    assert!((out_end - out_expected).abs() < 1e-9 * out_expected);
    assert!(
        contrast.concentration(2).iter().all(|&c| c == 0.0),
        "the other branch stays clear"
    );
}

#[test]
fn a_strong_injection_pushes_contrast_upstream_and_out_of_the_inlet() {
    let network = FlowNetwork::new(
        2,
        vec![Vessel::uniform("tube", 0, 1, 0.1, 2e-3)],
        Inlet {
            node: 0,
            condition: InletCondition::Pressure(100.0 * MMHG),
        },
        vec![Outlet {
            node: 1,
            resistance: 6e9,
            pressure: 0.0,
        }],
        Blood::default(),
    )
    .unwrap();
    let injection = Injection {
        vessel: 0,
        arc: 0.06,
        rate: 6e-6,
        concentration: 300.0,
    };
    let solution = FlowSolver::new(network.clone())
        .unwrap()
        .solve(Some(&injection))
        .unwrap();
    assert!(
        solution.vessels[0].proximal < 0.0,
        "backflow upstream of the tip"
    );
    let mut contrast = Contrast::new(&network, ContrastSettings::default()).unwrap();
    contrast.set_flow(&network, &solution).unwrap();
    for _ in 0..100 {
        contrast.step(0.01).unwrap();
    }
    let c = contrast.concentration(0);
    assert!(
        c[5] > 100.0,
        "contrast reached 5 mm from the inlet against the resting flow"
    );
    let balance =
        contrast.iodine_injected() - contrast.iodine_present() - contrast.iodine_washed_out();
    assert!(balance.abs() < 1e-9 * contrast.iodine_injected());
}

fn y_network() -> FlowNetwork {
    FlowNetwork::new(
        4,
        vec![
            Vessel::tapered("parent", 0, 1, 0.04, 2.5e-3, 2.2e-3),
            Vessel::uniform("left", 1, 2, 0.03, 1.6e-3),
            Vessel::tapered("right", 1, 3, 0.05, 1.8e-3, 1.1e-3),
        ],
        Inlet {
            node: 0,
            condition: InletCondition::Pressure(100.0 * MMHG),
        },
        vec![
            Outlet {
                node: 2,
                resistance: 5e9,
                pressure: 0.0,
            },
            Outlet {
                node: 3,
                resistance: 8e9,
                pressure: 0.0,
            },
        ],
        Blood::default(),
    )
    .unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    /// The maximum principle: no concentration below 0 or above the initial maximum (or the
    /// injected concentration), for every limiter and random data.
    #[test]
    fn concentrations_stay_within_their_initial_bounds(
        values in proptest::collection::vec(0.0f64..1.0, 150),
        limiter_index in 0usize..3,
        cfl in 0.2f64..1.0,
        inject in proptest::bool::ANY,
    ) {
        let limiter = [Limiter::Upwind, Limiter::VanLeer, Limiter::Superbee][limiter_index];
        let network = y_network();
        let injection = Injection { vessel: 2, arc: 0.02, rate: 0.4e-6, concentration: 0.8 };
        let solution = FlowSolver::new(network.clone())
            .unwrap()
            .solve(inject.then_some(&injection))
            .unwrap();
        let mut contrast =
            Contrast::new(&network, ContrastSettings { cell_length: 1e-3, cfl, limiter }).unwrap();
        let mut k = 0;
        for v in 0..3 {
            let n = contrast.concentration(v).len();
            let slice = values[k..k + n].to_vec();
            contrast.fill(v, |x| slice[((x / contrast_dx(&network, v, n)) as usize).min(n - 1)]).unwrap();
            k += n;
        }
        let (_, initial_max) = contrast.range();
        let bound = if inject { initial_max.max(0.8) } else { initial_max };
        contrast.set_flow(&network, &solution).unwrap();
        for _ in 0..40 {
            contrast.step(0.003).unwrap();
            let (lo, hi) = contrast.range();
            prop_assert!(lo >= 0.0, "negative concentration {lo}");
            prop_assert!(hi <= bound * (1.0 + 1e-12), "new maximum {hi} > {bound}");
        }
    }
}

fn contrast_dx(network: &FlowNetwork, vessel: usize, cells: usize) -> f64 {
    network.vessels[vessel].length() / cells as f64
}

#[test]
fn bad_contrast_input_gives_clear_errors() {
    let network = y_network();
    let err = Contrast::new(
        &network,
        ContrastSettings {
            cfl: 1.5,
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(err.to_string().contains("CFL"), "{err}");
    let mut contrast = Contrast::new(&network, ContrastSettings::default()).unwrap();
    let err = contrast.step(f64::NAN).unwrap_err();
    assert!(err.to_string().contains("time step"), "{err}");
    let err = contrast.fill(0, |_| -1.0).unwrap_err();
    assert!(err.to_string().contains("initial concentration"), "{err}");
    let err = contrast.fill(9, |_| 1.0).unwrap_err();
    assert!(err.to_string().contains("vessel index 9"), "{err}");
}
