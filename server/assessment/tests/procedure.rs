//! Phases and errors on hand-made sessions: each error committed on purpose is found once,
//! with its time and vessel; a clean session has none; scores and verdicts by hand.

use std::collections::BTreeMap;

use cathlab_assessment::{
    BenchmarkSpec, Counts, ErrorKind, ErrorThresholds, EventRecord, PhaseSpec, Sample, Trace,
    detect_errors, detect_phases, judge, summarize,
};

/// A clean 10 s session at 10 Hz: the tip advances 10 mm/s along x on the route, through the
/// aorta (0–4 s), the carotid (4–8 s) and the MCA (8–10 s), with fluoroscopy on and light
/// forces.
fn clean() -> Vec<Sample> {
    (0..=100)
        .map(|i| {
            let t = i as f64 * 0.1;
            let x = 0.01 * t;
            let vessel = if t < 4.0 {
                "aorta"
            } else if t < 8.0 {
                "left common carotid"
            } else {
                "left middle cerebral M1"
            };
            Sample {
                time_s: t,
                tip_m: [x, 0.0, 0.0],
                along_route_m: x,
                inserted_m: vec![x],
                twist_rad: vec![0.0],
                wall_force_n: [0.1, 0.05, 0.01],
                fluoroscopy: true,
                contrast_ml: 2.0 * t,
                air_kerma_mgy: 0.5 * t,
                kap_gy_cm2: 0.05 * t,
                vessel: vessel.into(),
                ..Sample::default()
            }
        })
        .collect()
}

fn kinds(samples: Vec<Sample>) -> Vec<ErrorKind> {
    detect_errors(&Trace::new(samples).unwrap(), &ErrorThresholds::default())
        .unwrap()
        .iter()
        .map(|e| e.kind)
        .collect()
}

#[test]
fn a_clean_session_commits_no_error() {
    assert_eq!(kinds(clean()), vec![]);
}

#[test]
fn each_error_committed_on_purpose_is_found_once_where_and_when_it_happened() {
    // 20 mm into a side branch from 2 to 3 s.
    let mut s = clean();
    for x in &mut s[20..=30] {
        x.off_route_m = 0.02;
        x.vessel = "left subclavian".into();
    }
    let errors = detect_errors(&Trace::new(s).unwrap(), &ErrorThresholds::default()).unwrap();
    assert_eq!(errors.len(), 1);
    assert_eq!(errors[0].kind, ErrorKind::OffRoute);
    assert_eq!((errors[0].start_s, errors[0].end_s), (2.0, 3.0));
    assert_eq!(errors[0].vessel, "left subclavian");
    assert!(errors[0].detail.contains("20 mm"), "{}", errors[0].detail);
    // 10 mm is within the 15 mm limit.
    let mut s = clean();
    s[20].off_route_m = 0.01;
    assert_eq!(kinds(s), vec![]);

    // 0.3 N intracranial at 9 s.
    let mut s = clean();
    s[90].wall_force_n[2] = 0.3;
    assert_eq!(kinds(s), vec![ErrorKind::IntracranialForce]);

    // Hands still for 6 s under fluoroscopy (1–7 s), then a still spell of 3 s that is not.
    let mut s = clean();
    for x in &mut s[10..=70] {
        x.inserted_m = vec![0.01];
        x.tip_m = [0.01, 0.0, 0.0];
    }
    let errors = detect_errors(&Trace::new(s).unwrap(), &ErrorThresholds::default()).unwrap();
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert_eq!(errors[0].kind, ErrorKind::IdleFluoroscopy);
    assert!((errors[0].start_s - 1.0).abs() < 1e-9 && (errors[0].end_s - 7.0).abs() < 1e-9);
    // The same stillness with the pedal up is no error.
    let mut s = clean();
    for (i, x) in s.iter_mut().enumerate() {
        x.fluoroscopy = false;
        if (10..=70).contains(&i) {
            x.inserted_m = vec![0.01];
        }
    }
    assert_eq!(kinds(s), vec![]);

    // 70 mL against a 60 mL budget: once, when crossed (30 s at 2 mL/s... here 7 mL/s).
    let mut s = clean();
    for x in &mut s {
        x.contrast_ml = 7.0 * x.time_s;
    }
    let errors = detect_errors(&Trace::new(s).unwrap(), &ErrorThresholds::default()).unwrap();
    assert_eq!(errors.len(), 1);
    assert_eq!(errors[0].kind, ErrorKind::ContrastOverBudget);
    assert!(
        (errors[0].start_s - 8.6).abs() < 1e-9,
        "{}",
        errors[0].start_s
    );

    // The catheter passed the wire's tip twice (at 5 s and 6 s).
    let mut s = clean();
    for x in &mut s[50..] {
        x.passed_inner_tip = 1;
    }
    for x in &mut s[60..] {
        x.passed_inner_tip = 2;
    }
    let errors = detect_errors(&Trace::new(s).unwrap(), &ErrorThresholds::default()).unwrap();
    let times: Vec<f64> = errors.iter().map(|e| e.start_s).collect();
    assert_eq!(times, vec![5.0, 6.0]);
    assert!(
        errors
            .iter()
            .all(|e| e.kind == ErrorKind::UnsupportedAdvance && e.vessel == "left common carotid")
    );
}

#[test]
fn phases_start_in_order_when_their_condition_first_holds() {
    let trace = Trace::new(clean()).unwrap();
    let events = vec![EventRecord {
        time_s: 9.5,
        kind: "target_reached".into(),
        message: "the tip reached left middle cerebral M1".into(),
    }];
    let phase = |name: &str| PhaseSpec {
        name: name.into(),
        ..PhaseSpec::default()
    };
    let specs = vec![
        phase("access"),
        PhaseSpec {
            vessel: Some("carotid".into()),
            ..phase("target-vessel selection")
        },
        PhaseSpec {
            along_route_mm: Some(85.0),
            ..phase("microcatheter navigation")
        },
        PhaseSpec {
            event: Some("stent deployed".into()),
            ..phase("device deployment")
        },
        PhaseSpec {
            event: Some("REACHED".into()),
            ..phase("at target")
        },
    ];
    let phases = detect_phases(&trace, &events, &specs).unwrap();
    let times: Vec<(Option<f64>, Option<f64>)> =
        phases.iter().map(|p| (p.start_s, p.end_s)).collect();
    assert_eq!(times[0], (Some(0.0), Some(4.0)));
    assert_eq!(times[1], (Some(4.0), Some(8.5)));
    assert_eq!(times[2].0, Some(8.5));
    assert_eq!(times[3], (None, None), "never deployed");
    assert_eq!(times[2].1, Some(9.5), "ends at the next reached phase");
    assert_eq!(times[4], (Some(9.5), Some(10.0)));
    let bad = PhaseSpec {
        vessel: Some("x".into()),
        event: Some("y".into()),
        ..phase("two conditions")
    };
    let e = detect_phases(&trace, &events, &[bad])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("`two conditions` names 2 start conditions"),
        "{e}"
    );
}

#[test]
fn scores_come_from_the_samples_and_verdicts_from_the_expert_range() {
    let trace = Trace::new(clean()).unwrap();
    let counts = Counts {
        injections: 2,
        dsa_runs: 1,
        roadmaps: 1,
        target_reached_at_s: Some(9.5),
    };
    let metrics = summarize(&trace, &counts, &[], &ErrorThresholds::default()).unwrap();
    let value = |k: &str| metrics.iter().find(|m| m.key == k).unwrap().value;
    assert!((value("procedure_time_s") - 10.0).abs() < 1e-12);
    assert!((value("fluoroscopy_time_s") - 10.0).abs() < 1e-9);
    assert!((value("air_kerma_mgy") - 5.0).abs() < 1e-12);
    assert!((value("contrast_ml") - 20.0).abs() < 1e-12);
    assert!((value("tip_path_m") - 0.1).abs() < 1e-12);
    assert!((value("path_ratio") - 1.0).abs() < 1e-9);
    assert_eq!(value("time_to_target_s"), 9.5);
    assert_eq!(value("injections"), 2.0);
    assert_eq!(value("errors"), 0.0);
    // Expert 8 s to target, 1.5×: 9.5 s passes; expert fluoroscopy 5 s: 10 s does not.
    let expert = BTreeMap::from([
        ("time_to_target_s".to_owned(), 8.0),
        ("fluoroscopy_time_s".to_owned(), 5.0),
    ]);
    let verdicts = judge(&metrics, &expert, &BenchmarkSpec::default()).unwrap();
    assert_eq!(verdicts.len(), 2);
    let of = |k: &str| verdicts.iter().find(|v| v.key == k).unwrap();
    assert!(of("time_to_target_s").within && of("time_to_target_s").limit == 12.0);
    assert!(!of("fluoroscopy_time_s").within);
    // A hand-set limit wins over the factor.
    let spec = BenchmarkSpec {
        limits: BTreeMap::from([("fluoroscopy_time_s".to_owned(), 12.0)]),
        ..BenchmarkSpec::default()
    };
    let verdicts = judge(&metrics, &expert, &spec).unwrap();
    assert!(verdicts.iter().all(|v| v.within));
    let bad = BenchmarkSpec {
        pass_factor: 0.5,
        ..BenchmarkSpec::default()
    };
    assert!(judge(&metrics, &expert, &bad).is_err());
}
