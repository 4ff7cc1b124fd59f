//! Reports from scripted runs on the real arch: a clean run commits no error; runs that idle
//! under fluoroscopy, overrun the contrast budget or push past the route's turn-off commit
//! exactly those errors; dose follows the exposures; the replay frames show the device.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, OnceLock};

use cathlab_assessment::ErrorKind;
use cathlab_engine::*;

fn scenes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

fn cache() -> &'static AssetCache {
    static CACHE: OnceLock<AssetCache> = OnceLock::new();
    CACHE.get_or_init(AssetCache::default)
}

fn load(text: &str) -> Arc<SceneAssets> {
    let spec = SceneSpec::parse(text, SceneFormat::Toml).unwrap();
    cache().load(&spec, &scenes()).unwrap()
}

fn scene(file: &str) -> String {
    std::fs::read_to_string(scenes().join(file)).unwrap()
}

fn assets(extra: &str) -> Arc<SceneAssets> {
    load(&(scene("arch_to_cow_lcca.toml") + extra))
}

/// Commands at simulated times (s), as a recording would hold them.
fn script(assets: &SceneAssets, timed: &[(f64, Command)]) -> Vec<CommandRecord> {
    let dt = assets.spec.time_step_s();
    timed
        .iter()
        .enumerate()
        .map(|(i, (t, command))| CommandRecord {
            ordinal: i as u64,
            step: (t / dt).round() as u64,
            seq: i as u64 + 1,
            command: *command,
        })
        .collect()
}

fn report(assets: &Arc<SceneAssets>, timed: &[(f64, Command)], end_s: f64) -> SessionReport {
    let commands = script(assets, timed);
    let end = (end_s / assets.spec.time_step_s()).round() as u64;
    let options = ReportOptions {
        frame_every_s: 2.0,
        frame_px: 64,
        ..ReportOptions::default()
    };
    assess(
        assets.clone(),
        &commands,
        end,
        &options,
        &AtomicBool::new(false),
    )
    .unwrap()
}

fn kinds(r: &SessionReport) -> Vec<ErrorKind> {
    r.errors.iter().map(|e| e.kind).collect()
}

fn value(r: &SessionReport, key: &str) -> f64 {
    r.metrics.iter().find(|m| m.key == key).unwrap().value
}

#[test]
fn a_clean_run_commits_no_error_and_its_dose_follows_its_exposures() {
    let assets = assets("");
    let r = report(
        &assets,
        &[
            (0.0, Command::Fluoroscopy(true)),
            (0.0, Command::PushVelocity(0.02)),
            (2.0, Command::PushVelocity(0.0)),
            (2.0, Command::Fluoroscopy(false)),
        ],
        3.0,
    );
    assert_eq!(kinds(&r), vec![], "{:?}", r.errors);
    assert!((value(&r, "procedure_time_s") - 3.0).abs() < 1e-9);
    assert!((value(&r, "fluoroscopy_time_s") - 2.0).abs() < 0.11);
    // 2 s at 15 pulses a second: 30 exposures of the same dose each (the pose does not
    // change and the exposure control aims for the same detector dose).
    let kerma = value(&r, "air_kerma_mgy");
    assert!(kerma > 0.0, "{kerma}");
    let tip = value(&r, "tip_path_m");
    assert!(
        (0.03..0.05).contains(&tip),
        "tip path {tip} m for 40 mm pushed"
    );
    assert_eq!(r.samples.len(), 31);
    assert!(r.frames.len() >= 2 && r.frames.iter().all(|f| !f.png.is_empty()));
    assert_ne!(
        r.frames[0].instruments, r.frames[1].instruments,
        "the device moved between frames"
    );
    assert_eq!(r.phases[0].start_s, Some(0.0));

    // With the exposure control off every pulse has the scene's quanta: 2 s at 15 pulses a
    // second is 30 exposures (31 if the last falls on the pedal's release), each of the dose
    // the xray crate's formula gives for those quanta through this C-arm's field.
    let fixed = load(&scene("arch_to_cow_lcca.toml").replace(
        "[fluoroscopy]\n",
        "[fluoroscopy]\nautomatic_exposure = false\n",
    ));
    let r = report(
        &fixed,
        &[
            (0.0, Command::Fluoroscopy(true)),
            (2.0, Command::Fluoroscopy(false)),
        ],
        2.5,
    );
    let settings = cathlab_engine::session::fluoroscope_settings(&fixed);
    let one = cathlab_xray::ExposureDose::of(
        fixed.spec.fluoroscopy.photons_per_pixel,
        &fixed.carm,
        cathlab_xray::dose::quanta_per_mm2_per_ugy(&settings.spectrum),
    );
    let pulses = value(&r, "air_kerma_mgy") / one.reference_air_kerma_mgy;
    assert!(
        (pulses - 30.0).abs() < 1e-6 || (pulses - 31.0).abs() < 1e-6,
        "{pulses} exposures' worth"
    );
    let kap_pulses = value(&r, "kap_gy_cm2") / one.kerma_area_product_gy_cm2;
    assert!((kap_pulses - pulses).abs() < 1e-6);
}

#[test]
fn errors_committed_on_purpose_on_the_arch_are_found_and_nothing_else() {
    // The target is the right common carotid; the straight wire pushed fast goes up the left
    // one instead.
    let rcca =
        load(&scene("arch_to_cow_lcca.toml").replace("branch = \"LCCA\"", "branch = \"RCCA\""));
    let r = report(
        &rcca,
        &[
            (0.0, Command::SelectDevice(1)),
            (0.0, Command::PushVelocity(0.06)),
        ],
        2.8,
    );
    assert_eq!(kinds(&r), vec![ErrorKind::OffRoute], "{:?}", r.errors);
    assert_eq!(r.errors[0].vessel, "LCCA");

    // Fluoroscopy on with no hand moving for 3 s (the scene allows 2), and 5 mL of contrast
    // against a budget of 3 mL.
    let assets =
        assets("\n[assessment.errors]\nidle_fluoroscopy_s = 2.0\ncontrast_budget_ml = 3.0\n");
    let r = report(
        &assets,
        &[
            (0.0, Command::Fluoroscopy(true)),
            (
                0.5,
                Command::Inject {
                    volume_ml: 5.0,
                    rate_ml_s: 5.0,
                },
            ),
        ],
        3.0,
    );
    assert_eq!(
        kinds(&r),
        vec![ErrorKind::IdleFluoroscopy, ErrorKind::ContrastOverBudget],
        "{:?}",
        r.errors
    );
    assert!((value(&r, "contrast_ml") - 5.0).abs() < 1e-6);
    assert_eq!(value(&r, "injections"), 1.0);
    let over = &r.errors[1];
    assert!(
        (over.start_s - 1.1).abs() < 0.11,
        "3 mL at 5 mL/s from 0.5 s: {}",
        over.start_s
    );
    // The dose grows with the exposures: 3 s of fluoroscopy against the clean run's 2 s.
    let per_second = value(&r, "air_kerma_mgy") / value(&r, "fluoroscopy_time_s");
    assert!(per_second > 0.0);
}

#[test]
fn a_catheter_pushed_past_its_wire_commits_an_unsupported_advance() {
    let assets = load(&scene("arch_to_cow_lcca_coaxial.toml"));
    let r = report(
        &assets,
        &[(
            0.0,
            Command::Instrument {
                index: 0,
                drive: Drive::PushVelocity(0.04),
            },
        )],
        1.5,
    );
    assert_eq!(
        kinds(&r),
        vec![ErrorKind::UnsupportedAdvance],
        "{:?}",
        r.errors
    );
    assert_eq!(value(&r, "passed_inner_tip"), 1.0);
}

#[test]
fn a_wire_pushed_hard_into_the_basilar_commits_the_intracranial_force_error() {
    // The basilar scene with one straight wire, started 45 mm short of the target.
    let text = scene("arch_to_cow_basilar.toml");
    let (from, to) = (
        text.find("[[stack]]").unwrap(),
        text.find("[carm]").unwrap(),
    );
    let text = format!(
        "{}[[devices]]\npreset = \"guidewire_035\"\n\n[start]\nalong_route_mm = 340.0\n\n{}",
        &text[..from],
        &text[to..text.find("[autopilot]").unwrap()]
    )
    .replace("instrument = 2\n", "");
    let r = report(&load(&text), &[(0.0, Command::PushVelocity(0.05))], 1.0);
    let found = kinds(&r);
    assert!(!found.is_empty(), "no error");
    assert!(
        found.iter().all(|k| *k == ErrorKind::IntracranialForce),
        "{:?}",
        r.errors
    );
    assert!(
        r.errors.iter().all(|e| e.vessel == "basilar"),
        "{:?}",
        r.errors
    );
    assert!(value(&r, "peak_force_intracranial_n") > 0.2);
}

#[test]
fn the_committed_expert_benchmark_is_what_the_expert_run_scores() {
    // The scene file's [assessment.expert] table, against a fresh run of the command that
    // wrote it (`--example expert_benchmark`, 4 significant digits).
    let assets = load(&scene("arch_to_cow_lcca_coaxial.toml"));
    let expert = assets.spec.assessment.expert.clone();
    assert!(expert.len() >= 8, "{expert:?}");
    let (commands, end) = expert_run(assets.clone(), 60_000).unwrap();
    let r = assess(
        assets,
        &commands,
        end,
        &ReportOptions::default(),
        &AtomicBool::new(false),
    )
    .unwrap();
    let fresh: Vec<(&str, f64)> = r
        .metrics
        .iter()
        .filter(|m| report::is_expert_metric(&m.key, m.value))
        .map(|m| (m.key.as_str(), m.value))
        .collect();
    assert_eq!(fresh.len(), expert.len(), "{fresh:?} vs {expert:?}");
    for (key, value) in fresh {
        let committed = expert[key];
        assert!(
            (value - committed).abs() <= 1e-3 * value.abs(),
            "{key}: the run scores {value}, the scene says {committed}"
        );
    }
    // The run is within its own expert range (1.5×), and commits no error.
    assert!(r.verdicts.iter().all(|v| v.within), "{:?}", r.verdicts);
    assert_eq!(r.errors, vec![]);
}
