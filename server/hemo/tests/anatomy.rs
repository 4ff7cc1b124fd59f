//! Flow and contrast on the anatomy's own vessel graphs: the seeded neuro phantom (inlet at the
//! aortic root, an outlet at every free end) with an injection at a catheter tip located in 3D.

use cathlab_anatomy::phantom::neuro::{NeuroPhantomParams, neuro_phantom};
use cathlab_hemo::{
    Contrast, ContrastSettings, FlowSolver, GraphFlowSettings, Injection, ML_PER_MIN,
    network_from_graph,
};

#[test]
fn neuro_phantom_flows_and_a_carotid_injection_opacify_the_right_territory() {
    let graph = neuro_phantom(&NeuroPhantomParams::default()).unwrap();
    let network = network_from_graph(&graph, &GraphFlowSettings::default()).unwrap();
    assert_eq!(network.vessels.len(), graph.branches.len());
    let solver = FlowSolver::new(network.clone()).unwrap();
    let solution = solver.solve(None).unwrap();
    let residual = solution.kirchhoff_residuals(&network);
    assert!(
        residual
            .iter()
            .all(|r| r.abs() <= 1e-12 * solution.inlet_flow)
    );
    let flow = |name: &str| {
        solution.vessels[network.vessel_id(name).unwrap()]
            .proximal
            .abs()
            / ML_PER_MIN
    };
    println!("| phantom vessel | flow (mL/min) |");
    for name in [
        "left_internal_carotid",
        "right_internal_carotid",
        "left_middle_cerebral",
        "right_middle_cerebral",
        "basilar",
        "left_vertebral",
    ] {
        println!("| {name} | {:.0} |", flow(name));
    }
    for side in ["left", "right"] {
        let ica = flow(&format!("{side}_internal_carotid"));
        let mca = flow(&format!("{side}_middle_cerebral"));
        assert!((120.0..=400.0).contains(&ica), "{side} ICA {ica:.0} mL/min");
        assert!((60.0..=250.0).contains(&mca), "{side} MCA {mca:.0} mL/min");
        assert!(mca < ica);
    }

    // A catheter tip in the left ICA, found from its 3D position as the physics would give it.
    let lica = graph.branch("left_internal_carotid").unwrap();
    let tip = lica.point_at(0.02);
    let location = graph.nearest(&tip).unwrap();
    assert_eq!(
        graph.branches[location.branch].name,
        "left_internal_carotid"
    );
    let injection = Injection {
        vessel: location.branch,
        arc: location.arc_length,
        rate: 4e-6,
        concentration: 300.0,
    };
    let with = solver.solve(Some(&injection)).unwrap();
    let mut contrast = Contrast::new(&network, ContrastSettings::default()).unwrap();
    contrast.set_flow(&network, &with).unwrap();
    for _ in 0..60 {
        contrast.step(1.0 / 60.0).unwrap();
    }
    let mean = |name: &str| {
        let c = contrast.concentration(network.vessel_id(name).unwrap());
        c.iter().sum::<f64>() / c.len() as f64
    };
    let left = mean("left_middle_cerebral");
    let right = mean("right_middle_cerebral");
    println!(
        "after 1 s of a 4 mL/s left-ICA injection: left MCA {left:.1} mg/mL, right MCA {right:.2} mg/mL"
    );
    assert!(left > 50.0, "the injected territory fills");
    assert!(
        right < 0.1 * left,
        "the other hemisphere stays mostly clear"
    );
    // Rendering segments lie on the centerlines with the vessel's radius.
    let segments = contrast.segments(&network, 1.0);
    assert!(!segments.is_empty());
    for s in &segments {
        let mid = nalgebra::center(&s.start, &s.end);
        let near = graph.nearest(&mid).unwrap();
        // A cell chord can cut a centerline corner by a little.
        assert!(
            near.distance < 0.02 * near.radius,
            "segment off the centerline by {}",
            near.distance
        );
        assert!((s.start_radius - near.radius).abs() < 0.05 * near.radius + 1e-5);
    }
    let balance =
        contrast.iodine_injected() - contrast.iodine_present() - contrast.iodine_washed_out();
    assert!(balance.abs() < 1e-9 * contrast.iodine_injected());
}

#[test]
fn bad_graph_settings_give_clear_errors() {
    let graph = neuro_phantom(&NeuroPhantomParams::default()).unwrap();
    let err = network_from_graph(
        &graph,
        &GraphFlowSettings {
            inlet_branch: "no_such_branch".into(),
            ..GraphFlowSettings::default()
        },
    )
    .unwrap_err();
    assert!(err.to_string().contains("no_such_branch"), "{err}");
    let mut settings = GraphFlowSettings::default();
    settings.terminal.reference_radius = -1e-3;
    let err = network_from_graph(&graph, &settings).unwrap_err();
    assert!(
        err.to_string().contains("terminal reference radius"),
        "{err}"
    );
    // A branch with a free end on neither side cannot be the inlet.
    let err = network_from_graph(
        &graph,
        &GraphFlowSettings {
            inlet_branch: "basilar".into(),
            ..GraphFlowSettings::default()
        },
    )
    .unwrap_err();
    assert!(err.to_string().contains("no free end"), "{err}");
}
