//! The segmented real CT as a scene: `scenes/segmented_aorta_suprarenal.toml` segments
//! `data/ct/aorta.mha` at load, and a shaped wire driven by the autopilot navigates the
//! segmented lumen from the distal aorta past the renal arteries' branch points to the upper
//! abdominal aorta, with flow from the aorta and fluoroscopy of the same CT.

use std::path::Path;

use cathlab_engine::*;
use cathlab_physics::autopilot::{Autopilot, AutopilotSettings};

#[test]
fn a_wire_navigates_the_segmented_aorta_past_the_renal_arteries() {
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let text = std::fs::read_to_string(scenes.join("segmented_aorta_suprarenal.toml")).unwrap();
    let spec = SceneSpec::parse(&text, SceneFormat::Toml).unwrap();
    let assets = AssetCache::default().load(&spec, &scenes).unwrap();
    let graph = &assets.anatomy.graph;
    assert!(
        graph.branches.len() >= 7,
        "{} branches",
        graph.branches.len()
    );
    assert!(
        assets
            .anatomy
            .lumen
            .mesh()
            .topology()
            .is_closed_oriented_manifold()
    );
    // The target is the aorta above the renal arteries: the route passes branch points.
    let target = graph.branch(&assets.spec.target.branch).unwrap();
    let mean_radius = target.radii.iter().sum::<f64>() / target.radii.len() as f64;
    println!(
        "segmented scene: {} branches, route {:.0} mm, target {} {:.0} mm long, mean radius {:.1} mm",
        graph.branches.len(),
        assets.route.length * 1e3,
        target.name,
        target.length() * 1e3,
        mean_radius * 1e3
    );
    assert!(mean_radius > 6e-3 && mean_radius < 15e-3);
    let legs = assets.route.legs.len();
    assert!(legs >= 4, "the route has {legs} legs");

    let mut world = World::new(assets.clone()).unwrap();
    let mut pilot = Autopilot::new(
        graph,
        assets.route.clone(),
        spec.start.along_route_mm * 1e-3,
        AutopilotSettings {
            reach_m: spec.target.reach_mm * 1e-3,
            // Side branches start on the aorta's centerline, 10 mm inside its wall: the
            // region a branch shares with the aorta is a radius deep, not the default 10 mm.
            stray_depth_m: 0.02,
            ..AutopilotSettings::default()
        },
    )
    .unwrap();
    let reached = world.follow_autopilot(&mut pilot, 40 * 500, 1).unwrap();
    let m = world.metrics();
    println!(
        "autopilot: reached at step {reached:?} ({:.2} s), {} retries; tip path {:.0} mm, wall force max {:.3} N",
        reached.unwrap_or(0) as f64 * spec.time_step_s(),
        pilot.retries(),
        m.tip_path_length_m * 1e3,
        m.max_wall_force_n
    );
    assert!(reached.is_some(), "the wire did not reach the upper aorta");
    assert!(m.target_reached_at_s.is_some());
    // Every node of the wire is inside the segmented lumen (within the contact tolerance).
    let snapshot = world.snapshot();
    let outside = snapshot
        .nodes
        .iter()
        .filter(|p| {
            let p = nalgebra::Point3::from(**p);
            assets.anatomy.lumen.query(&p).signed_distance > 0.5e-3
        })
        .count();
    assert_eq!(outside, 0, "wire nodes outside the lumen");
    // Fluoroscopy of the real CT with the wire in it renders, and the wire darkens it.
    let frame = cathlab_engine::imaging::expose_snapshot(&assets, &snapshot).unwrap();
    let (raw, w, h) = encode_frame(&frame, Encoding::Raw8, 0, 0).unwrap();
    assert_eq!((w, h, raw.len()), (512, 512, 512 * 512));
}

#[test]
fn a_bad_segmentation_scene_names_the_field_and_the_fault() {
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let text = std::fs::read_to_string(scenes.join("segmented_aorta_suprarenal.toml")).unwrap();
    let cases = [
        (
            text.replace("seed_voxel = [72, 300, 17]", "seed_voxel = [500, 0, 0]"),
            "anatomy.seed_voxel",
            "outside the volume",
        ),
        (
            text.replace("seed_voxel = [72, 300, 17]", "seed_voxel = [2, 2, 2]"),
            "anatomy.seed_voxel",
            "contrast-filled vessel",
        ),
        (
            text.replace(
                "volume = \"../data/ct/aorta.mha\"",
                "volume = \"../data/ct/missing.mha\"",
            ),
            "anatomy.volume",
            // The server's paths are never echoed (hardening: files outside the data roots
            // and missing ones answer alike).
            "names no file",
        ),
    ];
    for (scene, field, fault) in cases {
        let spec = SceneSpec::parse(&scene, SceneFormat::Toml).unwrap();
        let message = AssetCache::default()
            .load(&spec, &scenes)
            .unwrap_err()
            .to_string();
        assert!(
            message.contains(field) && message.contains(fault),
            "{message}"
        );
    }
}
