//! A surface with open ends becomes a scene: the arch-to-cow surface with two vessel ends
//! opened by VTK (`data/anatomy/arch-to-cow-open`, zlib-compressed VTP) is capped at load,
//! its centerlines are computed from the surface, the access is its widest open end, the
//! target the vessel whose end lies nearest a point (the other open end), and the scripted
//! two-hand operator takes the catheter there.

use std::path::Path;

use cathlab_engine::*;

const SCENE: &str = r#"
name = "open_surface"
description = "An open-ended surface: catheter over wire from its widest end to a neck vessel"

[anatomy]
kind = "surface"
file = "../../../data/anatomy/arch-to-cow-open/vessels_open.vtp"
unit = "mm"
placement = { rotation_deg = [90.0, 90.0, 0.0] }
access = { end = 0 }
voxel_mm = 0.9
names = {}

[ct]
kind = "phantom"
spacing_mm = 3.0

[[stack]]
device = "catheter-5f-vertebral"
inserted_mm = 10.0

[[stack]]
custom = { preset = "guidewire_035_shaped", bend_deg = 90.0, bend_length_mm = 30.0 }
inserted_mm = 30.0

[target]
end_near_mm = [41.9, 37.2, 551.1]
reach_mm = 3.0
instrument = 0

[autopilot]
lookahead_mm = 20.0
wire_reach_mm = 12.0
catheter_lag_mm = 50.0
catheter_track_mm = 5.0

[fidelity]
step_rate_hz = 500
frame_px = 256
"#;

#[test]
fn an_open_surface_becomes_a_scene_whose_target_the_two_hand_operator_reaches() {
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests");
    let spec = SceneSpec::parse(SCENE, SceneFormat::Toml).unwrap();
    let started = std::time::Instant::now();
    let assets = AssetCache::default().load(&spec, &base).unwrap();
    let graph = &assets.anatomy.graph;
    println!(
        "loaded in {:.1} s: {} branches, target {} ({:.0} mm route), access {:.1?} mm",
        started.elapsed().as_secs_f64(),
        graph.branches.len(),
        assets.spec.target.branch,
        assets.route.length * 1e3,
        (graph.landmarks["access"].coords * 1e3).as_slice()
    );
    assert!(
        assets
            .anatomy
            .lumen
            .mesh()
            .topology()
            .is_closed_oriented_manifold()
    );
    let mut world = World::new(assets.clone()).unwrap();
    let reached = world.follow_two_hands(40_000, 1).unwrap();
    let m = world.metrics();
    println!(
        "reached at step {reached:?}, {} divergence resets, max wall force {:.2} N",
        m.divergence_resets, m.max_wall_force_n
    );
    let snapshot = world.snapshot();
    for (i, instrument) in snapshot.instruments.iter().enumerate() {
        println!(
            "instrument {i}: inserted {:.0} mm",
            instrument.inserted_m * 1e3
        );
    }
    let tip = snapshot
        .nodes
        .last()
        .map(|p| nalgebra::Point3::from(*p))
        .unwrap();
    println!(
        "route legs {:?}; tip {:.1?} mm, {:.0} mm from the target along the route",
        assets
            .route
            .legs
            .iter()
            .map(|l| (
                graph.branches[l.branch].name.clone(),
                ((l.to_arc - l.from_arc).abs() * 1e3).round()
            ))
            .collect::<Vec<_>>(),
        (tip.coords * 1e3).as_slice(),
        assets.remaining_to_target_m(&tip) * 1e3
    );
    assert!(reached.is_some(), "the catheter did not reach the target");
    assert_eq!(m.divergence_resets, 0);
}
