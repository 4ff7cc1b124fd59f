//! Scene files: a bad field is refused by name and reason (the stack against the catalogue,
//! spares, the autopilot and its access stage, guidance and limits, a circle of Willis
//! without its inflows), and the asset cache keeps nothing of a failed scene.

use std::path::Path;
use std::sync::Arc;

use cathlab_engine::*;

use super::{assert_scene_errors, cache, default_text, scenes, stack_text};

#[test]
fn a_stack_is_checked_against_the_catalogue_and_the_fit_of_each_instrument() {
    let catheter = ("catheter-5f-vertebral", 40.0);
    let wire = ("guidewire-035-angled-hydrophilic", 60.0);
    let good = stack_text(&[("guide-6f-071-90", 20.0), catheter, wire]);
    let spec = SceneSpec::parse(&good, SceneFormat::Toml).unwrap();
    assert_eq!(spec.stack.len(), 3);
    assert!(spec.devices.is_empty());
    let cases = [
        (
            stack_text(&[catheter, ("guidewire-099", 60.0)]),
            "stack[1].device",
            "not in the device catalogue",
        ),
        (
            // A 0.035" wire in a 0.017" microcatheter.
            stack_text(&[("microcatheter-017-150", 40.0), wire]),
            "stack[1].device",
            "does not fit",
        ),
        (
            // The wire's tip behind the catheter's hub.
            stack_text(&[catheter, ("guidewire-035-angled-hydrophilic", -2000.0)]),
            "stack[1].inserted_mm",
            "outside",
        ),
        (
            // Past its own hub.
            stack_text(&[catheter, ("guidewire-035-angled-hydrophilic", 1600.0)]),
            "stack[1].inserted_mm",
            "outside",
        ),
        (
            // Within its own length less what stays outside (1,350 mm), but its hub would
            // pass the catheter's: the 1,500 mm wire reaches at most 540 mm beyond the entry
            // in a 1,000 mm catheter inserted 40 mm.
            stack_text(&[catheter, ("guidewire-035-angled-hydrophilic", 600.0)]),
            "stack[1].inserted_mm",
            "outside",
        ),
        (
            stack_text(&[("catheter-5f-vertebral", f64::INFINITY)]),
            "stack[0].inserted_mm",
            "outside",
        ),
        (
            stack_text(&[("sheath-088-90", 20.0); 5]),
            "stack",
            "at most 4",
        ),
        (
            good.replace(
                "[start]",
                "[[devices]]\npreset = \"catheter_5f\"\n\n[start]",
            ),
            "stack",
            "not both",
        ),
        (stack_text(&[]), "devices", "or a `stack`"),
    ];
    for (text, path, reason) in cases {
        match SceneSpec::parse(&text, SceneFormat::Toml) {
            Err(EngineError::Scene { path: p, reason: r }) => {
                assert_eq!(p, path, "{r}");
                assert!(r.contains(reason), "{reason}: got {r}");
            }
            other => panic!("{path}: {other:?}"),
        }
    }
    // The good one loads and runs: three instruments, outermost first, each where the scene
    // put it, the inner two inside the guide.
    let assets = cache().load(&spec, &scenes()).unwrap();
    let mut world = World::new(assets).unwrap();
    world.step().unwrap();
    let s = world.snapshot();
    let inserted: Vec<f64> = s.instruments.iter().map(|i| i.inserted_m).collect();
    assert_eq!(s.instruments.len(), 3);
    for (got, want) in inserted.iter().zip([0.020, 0.040, 0.060]) {
        assert!((got - want).abs() < 1e-9, "{inserted:?}");
    }
    assert_eq!(s.instruments[1].catalogue_id, "catheter-5f-vertebral");
    // Each instrument's centerline ends at its tip; the tips 20 mm apart along the strand
    // (the straight distance within a few mm of that: the strand starts in the instruments'
    // composite rest shape, the catheter's and the wire's shaped tips).
    for i in s.instruments.windows(2) {
        let gap = i[1].tip.unwrap() - i[0].tip.unwrap();
        assert!((gap.norm() - 0.020).abs() < 3e-3, "{}", gap.norm());
        assert_eq!(i[0].nodes.last().copied(), i[0].tip);
    }
    // A command for a fourth instrument is refused, naming it.
    let missing = Command::Instrument {
        index: 3,
        drive: Drive::PushVelocity(0.01),
    };
    match world.apply(1, &missing) {
        Err(EngineError::InvalidArgument { field, reason }) => {
            assert_eq!(field, "instrument");
            assert!(reason.contains("instrument 3"), "{reason}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn scene_errors_name_the_field_and_the_reason() {
    let cases = [
        (
            default_text().replace("step_rate_hz = 500", "step_rate_hz = \"fast\""),
            "fidelity.step_rate_hz",
            "invalid type",
        ),
        (
            default_text().replace("step_rate_hz = 500", "step_rate_hz = 5"),
            "fidelity.step_rate_hz",
            "outside",
        ),
        (
            default_text().replace("bend_deg = 90.0", "bend_deg = 90.0\nstiffness = 1"),
            "devices[0]",
            "unknown field",
        ),
        (
            default_text().replace("preset = \"catheter_5f\"", "preset = \"catheter_9f\""),
            "devices[2]",
            "unknown variant",
        ),
        (
            default_text().replace("pulse_rate = 15", "pulse_rate = 12"),
            "fluoroscopy.pulse_rate",
            "not one of",
        ),
        (
            default_text().replace(
                "step_rate_hz = 500",
                "step_rate_hz = 500\ncontact_solver = \"magic\"",
            ),
            "fidelity.contact_solver",
            "unknown variant",
        ),
        ("not = [toml".to_owned(), "(document)", ""),
    ];
    // The imaging chain's knobs, each out of its range.
    let chain = [
        ("recursive_weight = 0.0", "fluoroscopy.recursive_weight"),
        ("dsa_mask_frames = 40", "fluoroscopy.dsa_mask_frames"),
        (
            "scatter_to_primary = -1.0",
            "fluoroscopy.scatter_to_primary",
        ),
        ("edge_enhancement = nan", "fluoroscopy.edge_enhancement"),
    ]
    .map(|(line, path)| {
        (
            default_text().replace("pulse_rate = 15", &format!("pulse_rate = 15\n{line}")),
            path,
            "",
        )
    });
    let cases: Vec<(String, &str, &str)> = cases.into_iter().chain(chain).collect();
    for (text, path, reason) in cases {
        match SceneSpec::parse(&text, SceneFormat::Toml) {
            Err(EngineError::Scene { path: p, reason: r }) => {
                assert!(p.contains(path), "{path}: got {p} ({r})");
                assert!(r.contains(reason), "{reason}: got {r}");
            }
            other => panic!("{path}: {other:?}"),
        }
    }
    // JSON works the same way.
    let spec = SceneSpec::parse(&default_text(), SceneFormat::Toml).unwrap();
    let mut json: serde_json::Value = serde_json::to_value(&spec).unwrap();
    json["carm"]["primary_deg"] = serde_json::json!(500.0);
    match SceneSpec::parse(&json.to_string(), SceneFormat::Json) {
        Err(EngineError::Scene { path, .. }) => assert_eq!(path, "carm.primary_deg"),
        other => panic!("{other:?}"),
    }
    // A branch the anatomy lacks is named when the scene loads.
    let missing = default_text().replace("branch = \"LCCA\"", "branch = \"LMCA\"");
    let spec = SceneSpec::parse(&missing, SceneFormat::Toml).unwrap();
    match cache().load(&spec, &scenes()) {
        Err(EngineError::Scene { path, reason }) => {
            assert_eq!(path, "target.branch");
            assert!(reason.contains("LMCA"), "{reason}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn the_asset_cache_keeps_nothing_of_a_failed_scene_and_stays_within_its_budget() {
    // A scene that fails after its anatomy and CT are built (an unknown isocenter branch).
    let cache = AssetCache::default();
    let bad = default_text().replace("isocenter_branch = \"LCCA\"", "isocenter_branch = \"nope\"");
    assert_ne!(bad, default_text());
    let spec = SceneSpec::parse(&bad, SceneFormat::Toml).unwrap();
    let error = cache.load(&spec, &scenes()).unwrap_err().to_string();
    assert!(error.contains("carm.isocenter_branch"), "{error}");
    assert_eq!(
        cache.counts(),
        (0, 0, 0),
        "the failed scene left assets behind"
    );
    assert_eq!(cache.bytes(), 0);
    // A budget smaller than one scene: a scene in use stays, one no session holds goes when
    // the next is loaded.
    let small = AssetCache::with_budget(1);
    let first = small
        .load(
            &SceneSpec::parse(&default_text(), SceneFormat::Toml).unwrap(),
            &scenes(),
        )
        .unwrap();
    let one_scene = small.bytes();
    assert!(one_scene > 1 << 20, "{one_scene} bytes");
    assert_eq!(small.counts(), (1, 1, 1), "in use, so kept");
    drop(first);
    let coarser = default_text().replace("spacing_mm = 2.0", "spacing_mm = 3.0");
    let second = small
        .load(
            &SceneSpec::parse(&coarser, SceneFormat::Toml).unwrap(),
            &scenes(),
        )
        .unwrap();
    println!(
        "one scene: {:.1} MiB; after a second with the first unused: {:?}, {:.1} MiB",
        one_scene as f64 / (1 << 20) as f64,
        small.counts(),
        small.bytes() as f64 / (1 << 20) as f64
    );
    assert_eq!(
        small.counts(),
        (1, 1, 1),
        "the unused scene and its CT went"
    );
    assert!(Arc::strong_count(&second) >= 1);
}

#[test]
fn a_bad_guidance_or_limits_table_is_named() {
    for (extra, field) in [
        ("\n[guidance]\ntarget_marker = \"yes\"\n", "guidance"),
        ("\n[guidance]\nhints = true\n", "guidance"),
        ("\n[limits]\npush_force_n = -1.0\n", "limits.push_force_n"),
        (
            "\n[limits]\ntwist_torque_nm = 0.0\n",
            "limits.twist_torque_nm",
        ),
        ("\n[limits]\noutside_mm = 1e9\n", "limits.outside_mm"),
    ] {
        let error = SceneSpec::parse(&(default_text() + extra), SceneFormat::Toml)
            .expect_err(extra)
            .to_string();
        assert!(error.contains(field), "{extra:?}: {error}");
    }
}

#[test]
fn a_stack_scene_names_bad_spares_autopilot_and_target_instrument() {
    let rva = std::fs::read_to_string(scenes().join("arch_to_cow_rva_coaxial.toml")).unwrap();
    let cases = [
        (
            rva.replace("bend_length_mm = 10.0 }", "bend_length_mm = -3.0 }"),
            "spares[0].custom.bend_length_mm",
        ),
        (
            rva.replace("[[spares]]\ncustom = { preset = \"guidewire_035_shaped\", bend_deg = 90.0, bend_length_mm = 10.0 }", "[[spares]]\ndevice = \"guidewire-9000\""),
            "spares[0]",
        ),
        (rva.replace("lookahead_mm = 50.0", "lookahead_mm = 0.0"), "autopilot.lookahead_mm"),
        (
            rva.replace("catheter_lag_mm = 50.0", "catheter_lag_mm = nan"),
            "autopilot.catheter_lag_mm",
        ),
        (rva.replace("spare = 0", "spare = 3"), "autopilot.exchange.spare"),
        (rva.replace("into_mm = 45.0", "into_mm = 45.0\nspeed = 2"), "autopilot.exchange"),
        (rva.replace("instrument = 0", "instrument = 2"), "target.instrument"),
        (
            rva.replace("branch = \"arch_to_RCCA+RVA\"", "branch = \"nowhere\""),
            "autopilot.exchange.branch",
        ),
    ];
    assert_scene_errors(&rva, &cases);
}

#[test]
fn an_access_stage_names_its_bad_fields() {
    let access = std::fs::read_to_string(scenes().join("stroke_m1_from_access.toml")).unwrap();
    let loads =
        "load = [\"distal-access-058-115\", \"microcatheter-021-160\", \"microwire-014-angled\"]";
    let cases = [
        (access.replace("into_mm = 40.0", "into_mm = 0.0"), "autopilot.access.into_mm"),
        (access.replace("unload = 2", "unload = 3"), "autopilot.access.unload"),
        (
            access.replace(loads, "load = [\"guide-6f-071-90\"]"),
            "autopilot.access.load[0]",
        ),
        (
            access.replace(loads, "load = [\"nowhere-1\"]"),
            "autopilot.access.load[0]",
        ),
        (
            access.replace(
                loads,
                "load = [\"distal-access-058-115\", \"microcatheter-021-160\", \"microwire-014-angled\", \"microwire-014-j\"]",
            ),
            "autopilot.access.load",
        ),
        (
            access.replace("park_along_mm = [305.0, 317.0]", "park_along_mm = [305.0, 317.0, 330.0]"),
            "autopilot.park_along_mm",
        ),
        (
            access.replace("park_along_mm = [305.0, 317.0]", "park_along_mm = [5.0, 317.0]"),
            "autopilot.park_along_mm[0]",
        ),
        (
            access.replace(
                "branch = \"left_internal_carotid\"\ninto_mm",
                "branch = \"left_middle_cerebral\"\ninto_mm",
            ),
            "autopilot.access.branch",
        ),
        (
            access.replace(
                "branch = \"left_internal_carotid\"\ninto_mm",
                "branch = \"nowhere\"\ninto_mm",
            ),
            "autopilot.access.branch",
        ),
    ];
    assert_scene_errors(&access, &cases);
}

/// An anatomy folder whose vertebral curve is missing cannot give the circle of Willis its
/// four inflows: the scene is refused naming `anatomy.circle_of_willis`, and the same folder
/// without the circle still loads.
#[test]
fn a_circle_of_willis_without_its_four_inflows_is_refused_by_name() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let dir = std::env::temp_dir().join(format!("cathlab-cow-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("centerlines")).unwrap();
    std::fs::copy(data.join("vessels.obj"), dir.join("vessels.obj")).unwrap();
    for curve in ["LCCA", "RCCA", "RVA"] {
        let name = format!("centerlines/{curve}.mrk.json");
        std::fs::copy(data.join(&name), dir.join(&name)).unwrap();
    }
    let base = std::fs::read_to_string(scenes().join("arch_to_cow_basilar.toml")).unwrap();
    let text = base
        .replace(
            "dir = \"../data/anatomy/arch-to-cow\"",
            &format!("dir = {:?}", dir.display().to_string()),
        )
        .replace("branch = \"LVA\"", "branch = \"RVA\"");
    assert_scene_errors(&base, &[(text.clone(), "anatomy.circle_of_willis")]);
    let without = text
        .replace("circle_of_willis = true", "circle_of_willis = false")
        .replace(
            "isocenter_branch = \"basilar\"",
            "isocenter_branch = \"RVA\"",
        )
        .replace("branch = \"basilar\"", "branch = \"RVA\"")
        .replace(
            "branch = \"RVA\"\ninto_mm",
            "branch = \"arch_to_RCCA+RVA\"\ninto_mm",
        )
        .replace("into_mm = 120.0", "into_mm = 10.0");
    let spec = SceneSpec::parse(&without, SceneFormat::Toml).unwrap();
    if let Err(e) = cache().load(&spec, &scenes()) {
        panic!("without the circle: {e}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The physics options a scene may turn on (`fidelity.slide_friction`,
/// `fidelity.cap_with_held_contacts`, `fidelity.axial_slide`) are off unless the scene says
/// so, read when it does, and a value of the wrong type is named, each option by its own path.
#[test]
fn a_scene_turns_the_physics_options_on_by_name() {
    let plain = SceneSpec::parse(&default_text(), SceneFormat::Toml).unwrap();
    assert!(!plain.fidelity.slide_friction);
    assert!(!plain.fidelity.cap_with_held_contacts);
    assert!(!plain.fidelity.axial_slide);
    let text = default_text().replace(
        "step_rate_hz = 500",
        "step_rate_hz = 500\nslide_friction = true\ncap_with_held_contacts = true\naxial_slide = true",
    );
    let on = SceneSpec::parse(&text, SceneFormat::Toml).unwrap();
    assert!(on.fidelity.slide_friction);
    assert!(on.fidelity.cap_with_held_contacts);
    assert!(on.fidelity.axial_slide);
    for (option, value) in [
        ("slide_friction", "1"),
        ("cap_with_held_contacts", "\"yes\""),
        ("axial_slide", "0.5"),
    ] {
        let bad = default_text().replace(
            "step_rate_hz = 500",
            &format!("step_rate_hz = 500\n{option} = {value}"),
        );
        match SceneSpec::parse(&bad, SceneFormat::Toml) {
            Err(EngineError::Scene { path, reason }) => {
                assert!(
                    path.contains(&format!("fidelity.{option}")),
                    "{path}: {reason}"
                );
                assert!(reason.contains("invalid type"), "{reason}");
            }
            other => panic!("expected a scene error naming {option}, got {other:?}"),
        }
    }
}
