//! `cathlab case` output is a scene folder the server serves unchanged: a surface with open
//! ends and a CT angiography volume each become a scene that `check_scenes` (what
//! `cathlab-server --check-scenes` runs) loads; careless cases are refused naming the field.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use cathlab_anatomy::io::LengthUnit;
use cathlab_engine::check::check_scenes;
use cathlab_engine::*;
use cathlab_imaging::ImagingError;
use cathlab_imaging::case::{
    AccessChoice, CaseOptions, Placement, SurfaceCase, load_surface_case, write_case,
};
use cathlab_imaging::segment::Seed;

fn data(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../data")
        .join(path)
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("cathlab-case-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn an_open_surface_becomes_a_served_scene_and_its_autopilot_reaches_the_named_target() {
    let out = scratch("surface");
    let report = write_case(
        &data("anatomy/arch-to-cow-open/vessels_open.vtp"),
        &CaseOptions {
            placement: Placement {
                rotation_deg: [90.0, 90.0, 0.0],
                translation_mm: [0.0; 3],
            },
            target_near_mm: Some([41.9, 37.2, 551.1]),
            voxel_m: Some(0.9e-3),
            name: Some("open_arch".into()),
            ..CaseOptions::default()
        },
        &out,
    )
    .unwrap();
    println!(
        "case: {} open ends (radii {:?} mm), {} branches, target {} {:.0} mm away",
        report.open_ends.len(),
        report
            .open_ends
            .iter()
            .map(|e| (e.radius_mm * 10.0).round() / 10.0)
            .collect::<Vec<_>>(),
        report.branches.len(),
        report.target,
        report.route_mm
    );
    assert_eq!(report.open_ends.len(), 3);
    for file in [
        "open_arch.toml",
        "open_arch/surface.vtp",
        "open_arch/graph.json",
        "open_arch/centerlines.vtp",
        "open_arch/preview.png",
        "open_arch/report.json",
    ] {
        assert!(out.join(file).is_file(), "{file} written");
    }
    // The user names the target branch in the scene, as the preview invites.
    let scene_file = out.join("open_arch.toml");
    let text = std::fs::read_to_string(&scene_file).unwrap();
    let text = text
        .replace(
            "[anatomy.names]\n",
            &format!("[anatomy.names]\n{} = \"neck_vessel\"\n", report.target),
        )
        .replace(
            &format!("branch = \"{}\"", report.target),
            "branch = \"neck_vessel\"",
        );
    std::fs::write(&scene_file, text).unwrap();
    let checks = check_scenes(&out, &[], None).unwrap();
    assert_eq!(checks.len(), 1);
    println!("{}", checks[0].line());
    assert!(checks[0].outcome.is_ok(), "{}", checks[0].line());
    // The scripted operator takes the catheter to the named target.
    let spec = SceneSpec::read(&scene_file).unwrap();
    let assets = AssetCache::default().load(&spec, &out).unwrap();
    assert_eq!(assets.spec.target.branch, "neck_vessel");
    let mut world = World::new(assets).unwrap();
    let reached = world.follow_two_hands(40_000, 1).unwrap();
    println!("reached at step {reached:?}");
    assert!(reached.is_some());
    assert_eq!(world.metrics().divergence_resets, 0);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_cta_volume_becomes_a_served_scene_with_its_ct() {
    let out = scratch("volume");
    let report = write_case(
        &data("ct/aorta.mha"),
        &CaseOptions {
            seed: Some(Seed::Voxel([72, 300, 17])),
            ..CaseOptions::default()
        },
        &out,
    )
    .unwrap();
    assert_eq!(report.name, "aorta");
    assert!(out.join("aorta/ct.mha").is_file());
    let checks = check_scenes(&out, &[], None).unwrap();
    println!("{}", checks[0].line());
    assert!(checks[0].outcome.is_ok(), "{}", checks[0].line());
    let _ = std::fs::remove_dir_all(&out);
}

fn case_error(result: std::result::Result<impl std::fmt::Debug, ImagingError>) -> (String, String) {
    match result {
        Err(ImagingError::Case { field, reason }) => (field, reason),
        other => panic!("expected a case error, got {other:?}"),
    }
}

#[test]
fn careless_cases_are_refused_naming_the_field() {
    let open = SurfaceCase {
        surface: data("anatomy/arch-to-cow-open/vessels_open.vtp"),
        unit: LengthUnit::Mm,
        placement: Placement::default(),
        centerlines: None,
        access: AccessChoice::End(7),
        names: BTreeMap::new(),
        voxel_m: Some(0.9e-3),
        max_voxels: 32_000_000,
    };
    let (field, reason) = case_error(load_surface_case(&open));
    assert_eq!(field, "access.end");
    assert!(reason.contains("3 open ends"), "{reason}");
    let closed = SurfaceCase {
        surface: data("anatomy/arch-to-cow/vessels.obj"),
        access: AccessChoice::End(0),
        ..open.clone()
    };
    let (field, reason) = case_error(load_surface_case(&closed));
    assert_eq!(field, "access.end");
    assert!(reason.contains("closed"), "{reason}");
    let unknown = SurfaceCase {
        centerlines: Some(data("anatomy/arch-to-cow/LICENSE")),
        access: AccessChoice::End(0),
        ..open.clone()
    };
    let (field, _) = case_error(load_surface_case(&unknown));
    assert_eq!(field, "anatomy.centerlines");
    let renamed = SurfaceCase {
        access: AccessChoice::End(0),
        names: BTreeMap::from([("vessel_999".to_owned(), "x".to_owned())]),
        ..open.clone()
    };
    let (field, _) = case_error(load_surface_case(&renamed));
    assert_eq!(field, "anatomy.names.vessel_999");
    // A volume without a seed.
    let (field, _) = case_error(write_case(
        &data("ct/aorta.mha"),
        &CaseOptions::default(),
        &scratch("noseed"),
    ));
    assert_eq!(field, "seed");
}

#[test]
fn check_scenes_names_the_failing_scene_and_field() {
    let dir = scratch("check");
    std::fs::create_dir_all(&dir).unwrap();
    let anatomy = data("anatomy/arch-to-cow");
    std::fs::write(
        dir.join("bad.toml"),
        format!(
            "[anatomy]\nkind = \"arch_to_cow\"\ndir = {:?}\n[ct]\nkind = \"phantom\"\nspacing_mm = 3.0\n[[devices]]\npreset = \"guidewire_035\"\n[target]\nbranch = \"no_such_vessel\"\n",
            anatomy.display().to_string()
        ),
    )
    .unwrap();
    std::fs::write(dir.join("broken.toml"), "this is not toml = = =").unwrap();
    let checks = check_scenes(&dir, &[data(""), dir.clone()], None).unwrap();
    let lines: Vec<String> = checks.iter().map(|c| c.line()).collect();
    println!("{lines:#?}");
    assert_eq!(checks.len(), 2);
    assert!(
        lines[0].starts_with("FAIL")
            && lines[0].contains("target.branch")
            && lines[0].contains("no_such_vessel")
    );
    assert!(lines[1].starts_with("FAIL") && lines[1].contains("broken.toml"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A small vessel, as in an aneurysm model: a 2 mm tube (radius 1 mm) whose first 14 mm run
/// straight from the access, turn through 90° on a 10 mm radius and run 30 mm on, with a
/// side branch of radius 0.8 mm leaving the bend's end at 45°; the surface (binary STL, mm)
/// is cut open 2 mm short of its three ends. Returns the far ends of the main vessel and of
/// the side branch (mm).
fn small_vessel_surface(file: &Path) -> ([f64; 3], [f64; 3]) {
    use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};
    use cathlab_anatomy::{BranchSpec, Side, TriangleMesh, VesselGraph, VesselKind};
    use nalgebra::{Point3, Vector3};
    let mm = |x: f64, y: f64, z: f64| Point3::new(x, y, z) * 1e-3;
    let branch = |name: &str, points: Vec<Point3<f64>>, radius: f64| BranchSpec {
        name: name.into(),
        kind: VesselKind::Other,
        side: Side::Midline,
        radii: vec![radius; points.len()],
        points,
    };
    // 14 mm along +x, a quarter circle about (14, 10) to (24, 10) heading +y, then 30 mm on.
    let mut first: Vec<Point3<f64>> = (0..=14).map(|i| mm(i as f64, 0.0, 0.0)).collect();
    first.extend((1..=16).map(|i| {
        let a = std::f64::consts::FRAC_PI_2 * i as f64 / 16.0;
        mm(14.0 + 10.0 * a.sin(), 10.0 - 10.0 * a.cos(), 0.0)
    }));
    let junction = *first.last().unwrap();
    let on: Vec<Point3<f64>> = (0..=30).map(|i| mm(24.0, 10.0 + i as f64, 0.0)).collect();
    let side_dir = Vector3::new(1.0, 1.0, 0.0).normalize();
    let side: Vec<Point3<f64>> = (0..=25)
        .map(|i| junction + side_dir * (i as f64 * 1e-3))
        .collect();
    let (main_end, side_end) = (*on.last().unwrap(), *side.last().unwrap());
    let mut graph = VesselGraph::new();
    graph.add_branch(branch("proximal", first, 1e-3)).unwrap();
    graph.add_branch(branch("distal", on, 1e-3)).unwrap();
    graph.add_branch(branch("side", side, 0.8e-3)).unwrap();
    let graph = graph.finish().unwrap();
    let closed = lumen_surface(&graph, &SurfaceSettings::default()).unwrap();
    // Open: drop the triangles within 2 mm of each end's cap.
    let cuts = [
        (mm(0.0, 0.0, 0.0), -Vector3::x()),
        (main_end, Vector3::y()),
        (side_end, side_dir),
    ];
    let triangles: Vec<[u32; 3]> = closed
        .triangles
        .iter()
        .filter(|t| {
            let c = t
                .iter()
                .map(|&i| closed.vertices[i as usize].coords)
                .sum::<Vector3<f64>>()
                / 3.0;
            cuts.iter()
                .all(|(end, out)| (c - end.coords).dot(out) < -2e-3)
        })
        .copied()
        .collect();
    let open = TriangleMesh::new(closed.vertices.clone(), triangles, "small vessel").unwrap();
    std::fs::write(
        file,
        cathlab_anatomy::io::stl::to_binary(&open, LengthUnit::Mm),
    )
    .unwrap();
    let mm_of = |p: Point3<f64>| [p.x * 1e3, p.y * 1e3, p.z * 1e3];
    (mm_of(main_end), mm_of(side_end))
}

#[test]
fn a_small_vessel_case_gets_micro_instruments_that_start_inside_and_a_device_outside_fails() {
    let out = scratch("small");
    std::fs::create_dir_all(&out).unwrap();
    let surface = out.join("small_vessel.stl");
    let (_, side_end) = small_vessel_surface(&surface);
    let scenes = out.join("scenes");
    let report = write_case(
        &surface,
        &CaseOptions {
            access: AccessChoice::NearMm([0.0, 0.0, 0.0]),
            target_near_mm: Some(side_end),
            voxel_m: Some(0.15e-3),
            name: Some("small".into()),
            ..CaseOptions::default()
        },
        &scenes,
    )
    .unwrap();
    println!(
        "small vessel: {} open ends, narrow lumen {:.2} mm, instruments {:?} inserted {:?} mm, \
         target {} {:.0} mm away",
        report.open_ends.len(),
        report.narrow_lumen_mm,
        report.instruments,
        report.inserted_mm,
        report.target,
        report.route_mm
    );
    assert_eq!(report.open_ends.len(), 3);
    // The 5 F catheter (1.67 mm) cannot go where the lumen is 1.6–2 mm across; the angled
    // microwire's 45° bend (1.9 mm sideways) cannot stand out beside the microcatheter in a
    // 2 mm vessel, so the wire is the straight one.
    assert_eq!(
        report.instruments,
        [
            "microcatheter-017-150".to_owned(),
            "microwire-014-straight".to_owned()
        ]
    );
    // Both start in the straight stretch (the centerline begins ~4 mm in, past the cut end,
    // and the bend at 14 mm), the wire ahead of the catheter.
    let [catheter, wire] = report.inserted_mm;
    assert!(
        catheter < wire && wire > 4.0 && wire < 12.0,
        "{:?}",
        report.inserted_mm
    );
    let checks = check_scenes(&scenes, &[], None).unwrap();
    println!("{}", checks[0].line());
    assert!(checks[0].outcome.is_ok(), "{}", checks[0].line());
    // The same scene with the wire pushed 30 mm in at the start (as the 0.035" wire was):
    // it leaves the vessel at the bend, and the check says so.
    let file = scenes.join("small.toml");
    let text = std::fs::read_to_string(&file).unwrap();
    let wire_line = format!("inserted_mm = {:.1}", report.inserted_mm[1]);
    assert!(text.contains(&wire_line), "{text}");
    std::fs::write(&file, text.replace(&wire_line, "inserted_mm = 30.0")).unwrap();
    let checks = check_scenes(&scenes, &[], None).unwrap();
    let line = checks[0].line();
    println!("{line}");
    assert!(
        line.starts_with("FAIL") && line.contains("stack") && line.contains("outside the lumen"),
        "{line}"
    );
    let _ = std::fs::remove_dir_all(&out);
}
