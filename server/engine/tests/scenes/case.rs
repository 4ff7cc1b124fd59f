//! The stroke case end to end in the engine. The whole case from the femoral access
//! (`scenes/stroke_m1_from_access.toml`): the scripted operator brings the guide up to the
//! cervical ICA with the distal-access catheter over a shaped 0.035" wire, takes the wire out,
//! loads the microcatheter and the microwire and crosses the left M1 clot; then the stent
//! retriever (exchanged for the microwire, pushed to the microcatheter's tip, unsheathed over
//! the clot, retrieved into the distal-access catheter). From the trainee's scene
//! (`scenes/stroke_m1_thrombectomy.toml`, the guide already in the ICA): aspiration (the
//! distal-access catheter at the clot's face, suction on). The session's
//! metrics carry the crossing forces, passes, first-pass effect, reperfusion time and the
//! eTICI grade from the flow; the final run's contrast reaches beyond the clot.

use std::sync::{Arc, OnceLock};

use cathlab_engine::metrics::Etici;
use cathlab_engine::thrombectomy::StrokeScript;
use cathlab_engine::*;
use nalgebra::{Point3, Vector3};

use super::scenes;

/// Loads a scene of the scene directory by name (through the binary's one cache).
fn load(name: &str) -> Arc<SceneAssets> {
    let text = std::fs::read_to_string(scenes().join(format!("{name}.toml"))).unwrap();
    let spec = SceneSpec::parse(&text, SceneFormat::Toml).unwrap();
    super::load(&spec).unwrap()
}

/// The trainee's scene: the guide already in the ICA.
fn assets() -> Arc<SceneAssets> {
    static ASSETS: OnceLock<Arc<SceneAssets>> = OnceLock::new();
    ASSETS
        .get_or_init(|| load("stroke_m1_thrombectomy"))
        .clone()
}

struct Case {
    world: World,
    script: StrokeScript,
    m1: f64,
}

impl Case {
    /// The scene with the clot crossed: the microcatheter 6 mm beyond it, every hand still.
    fn crossed() -> Self {
        Self::crossed_in(assets())
    }

    /// As [`Case::crossed`] in the scene `assets`.
    fn crossed_in(assets: Arc<SceneAssets>) -> Self {
        let mut world = World::new(assets).unwrap();
        let mut script = StrokeScript::new(&world, "left_middle_cerebral", 1).unwrap();
        assert!(
            script.cross(&mut world).unwrap(),
            "the microcatheter crossed the clot"
        );
        let m1 = script.branch_inserted_m;
        Self { world, script, m1 }
    }

    fn apply(&mut self, command: Command) -> Result<()> {
        self.script.apply(&mut self.world, command)
    }

    fn drive(&mut self, index: u32, drive: Drive) {
        self.apply(Command::Instrument { index, drive }).unwrap();
    }

    fn run(&mut self, steps: usize) {
        for _ in 0..steps {
            self.world.step().unwrap();
        }
    }

    /// Runs up to `steps` until `done`.
    fn run_until(&mut self, steps: usize, done: impl Fn(&World) -> bool) -> bool {
        StrokeScript::run_until(&mut self.world, steps, done).unwrap()
    }

    fn figures(&self) -> cathlab_engine::metrics::ThrombectomyMetric {
        self.world.metrics().thrombectomy.unwrap()
    }

    fn reperfusion(&self) -> (f64, Etici) {
        let r = self.world.metrics().reperfusion.unwrap();
        (r.fraction, r.etici)
    }

    /// Runs a DSA with an injection (through the innermost catheter) for `steps` and returns
    /// the most iodine drawn, at any frame, within 1.5 mm of the M1 between 14 and 20 mm
    /// along it (beyond the clot's 4–12 mm) (mg/mL).
    fn contrast_beyond_clot(&mut self, steps: usize) -> f64 {
        self.apply(Command::Dsa(true)).unwrap();
        self.apply(Command::Inject {
            volume_ml: 6.0,
            rate_ml_s: 4.0,
        })
        .unwrap();
        let a = self.world.assets().clone();
        let m1 = a.anatomy.graph.branch("left_middle_cerebral").unwrap();
        let beyond: Vec<Point3<f64>> = (14..=20)
            .map(|mm| Point3::from(a.to_lps * m1.point_at(f64::from(mm) * 1e-3).coords))
            .collect();
        let mut most: f64 = 0.0;
        for _ in 0..steps / 50 {
            self.run(50);
            let snapshot = self.world.snapshot();
            for t in snapshot.contrast.iter() {
                let ab = t.end - t.start;
                let near = beyond.iter().any(|p| {
                    let s = ((p - t.start).dot(&ab) / ab.norm_squared().max(1e-30)).clamp(0.0, 1.0);
                    (t.start + ab * s - p).norm() < 1.5e-3
                });
                if near {
                    most = most.max(t.concentration_mg_per_ml);
                }
            }
        }
        most
    }
}

/// Which branch of the scene's graph `tip` (m, anatomy frame) lies in.
fn branch_of(world: &World, tip: Vector3<f64>) -> String {
    let graph = &world.assets().anatomy.graph;
    let at = graph.nearest(&Point3::from(tip)).unwrap();
    graph.branches[at.branch].name.clone()
}

#[test]
fn thrombectomy_from_femoral_access_by_stent_retriever_to_etici_3() {
    let mut case = Case::crossed_in(load("stroke_m1_from_access"));
    // The access stage: the guide went up over the diagnostic catheter and the 0.035" wire,
    // which came out; the distal-access catheter, the microcatheter and the microwire were
    // loaded through it.
    let events: Vec<(u64, String)> = case
        .world
        .take_events()
        .into_iter()
        .map(|e| (e.step, e.message))
        .collect();
    let at = |needle: &str| {
        events
            .iter()
            .find(|(_, m)| m.contains(needle))
            .map(|(s, _)| *s)
            .unwrap_or_else(|| panic!("{needle} in {events:?}"))
    };
    let wire_out = at("0.035in guidewire, 90 deg over 30 mm taken out");
    let out = at("catheter-5f-vertebral taken out");
    assert!(wire_out <= out);
    let loaded = at("microwire-014-angled loaded into");
    let reached = at("reached left_middle_cerebral");
    assert!(out <= loaded && loaded < reached, "{events:?}");
    let w = &case.world;
    assert_eq!(w.strand().len(), 4);
    assert_eq!(
        branch_of(w, w.strand().tip_position(0).unwrap()),
        "left_internal_carotid"
    );
    assert_eq!(
        branch_of(w, w.strand().tip_position(1).unwrap()),
        "left_internal_carotid"
    );
    assert_eq!(
        branch_of(w, w.strand().tip_position(2).unwrap()),
        "left_middle_cerebral"
    );
    // The guide parked where the scene says: 305 mm along the route, from a sheath 10 mm in.
    let guide = w.strand().inserted_m(0);
    assert!((guide - 0.295).abs() < 2e-3, "{guide}");
    let f = case.figures();
    assert!(f.crossing_force_n > 0.0, "crossing asked a force: {f:?}");
    assert!(
        f.peak_crossing_force_n > 0.0,
        "the hand's force was measured: {f:?}"
    );
    assert_eq!(case.reperfusion().1, Etici::Grade0);
    // Stent commands need a stent retriever in the stack.
    let e = case.apply(Command::DeployStent).unwrap_err().to_string();
    assert!(e.contains("no stent retriever"), "{e}");
    assert!(case.apply(Command::RetrieveStent).is_err());
    // The distal-access catheter up to 8 mm short of the M1; the microwire out, the stent
    // retriever in, pushed to the microcatheter's tip.
    let m1 = case.m1;
    assert!(
        case.script
            .move_to(&mut case.world, 1, m1 - 8e-3, 6000)
            .unwrap()
    );
    assert!(
        case.script
            .bring_in(&mut case.world, "stent-retriever-4x20")
            .unwrap()
    );
    // Deployed: the stent grips the clot and its channel lets some flow through.
    case.apply(Command::DeployStent).unwrap();
    case.run(5000);
    let f = case.figures();
    assert!(f.grip_n > 0.05, "{f:?}");
    let (bypass, grade) = case.reperfusion();
    assert!(
        bypass > 0.05 && bypass < 0.9,
        "partial flow through the deployed stent: {bypass} ({grade:?})"
    );
    assert_eq!(case.world.clots().len(), 1);
    let before = case.world.metrics().procedure_time_s;
    // Retrieved into the distal-access catheter at 3 mm/s: out on the first pass.
    case.apply(Command::RetrieveStent).unwrap();
    assert!(case.run_until(10_000, |w| {
        w.metrics().thrombectomy.is_some_and(|t| t.passes > 0)
    }));
    let f = case.figures();
    let said: Vec<String> = case
        .world
        .take_events()
        .into_iter()
        .filter(|e| e.kind == EventKind::Thrombectomy)
        .map(|e| e.message)
        .collect();
    assert_eq!(f.passes, 1);
    assert!(f.first_pass_effect, "{f:?} {said:?}");
    assert_eq!(f.emboli, 0);
    assert!(case.world.clots().is_empty());
    let (fraction, grade) = case.reperfusion();
    assert!(fraction > 0.99, "{fraction}");
    assert_eq!(grade, Etici::Grade3);
    let at = f.reperfused_at_s.unwrap();
    assert!(at > before && at <= case.world.metrics().procedure_time_s);
    // The hands stopped when the pass ended.
    let stopped = case.world.strand().inserted_m(3);
    case.run(200);
    assert!((case.world.strand().inserted_m(3) - stopped).abs() < 1e-4);
    // The final run: contrast reaches beyond where the clot was.
    let beyond = case.contrast_beyond_clot(1500);
    assert!(
        beyond > 20.0,
        "iodine beyond the clot's site: {beyond} mg/mL"
    );
    let events: Vec<String> = said
        .into_iter()
        .chain(
            case.world
                .take_events()
                .into_iter()
                .filter(|e| e.kind == EventKind::Thrombectomy)
                .map(|e| e.message),
        )
        .collect();
    assert!(
        events.iter().any(|m| m.contains("open across the clot")),
        "{events:?}"
    );
    assert!(
        events.iter().any(|m| m.contains("pass 1: the clot is out")),
        "{events:?}"
    );
}

#[test]
fn thrombectomy_by_aspiration_at_the_clot_face() {
    let mut case = Case::crossed();
    // The same crossing as a session's demonstration (the operator inside the world):
    // step for step the same world.
    let mut shown = World::new(assets()).unwrap();
    shown.apply(1, &Command::Demonstrate(true)).unwrap();
    let reached = case.world.metrics().target_reached_at_s.unwrap();
    while shown.metrics().target_reached_at_s.is_none() {
        assert!(
            shown.metrics().procedure_time_s <= reached,
            "the demonstration reaches it too"
        );
        shown.step().unwrap();
    }
    assert_eq!(shown.metrics().target_reached_at_s, Some(reached));
    shown.step().unwrap();
    assert!(
        shown
            .take_events()
            .iter()
            .any(|e| e.message.contains("demonstration done"))
    );
    let face = case.m1 + 4e-3;
    // Suction with the catheter far from the clot starts nothing.
    case.apply(Command::Aspiration(true)).unwrap();
    case.run(200);
    assert_eq!(case.figures().passes, 0);
    assert!(case.world.metrics().thrombectomy.unwrap().aspiration);
    case.apply(Command::Aspiration(false)).unwrap();
    // The distal-access catheter over the microcatheter to the clot's face (its tip's
    // distance along the route); the microcatheter and microwire drawn back into it.
    let a = case.world.assets().clone();
    let face_arc = face + a.spec.start.along_route_mm * 1e-3;
    let tip_arc = |w: &World| {
        let tip = w.strand().tip_position(1).unwrap();
        cathlab_engine::thrombectomy::route_arc(
            &a.route_samples,
            cathlab_engine::assets::ROUTE_SPACING_M,
            &Point3::from(tip),
        )
    };
    case.drive(1, Drive::PushVelocity(5e-3));
    assert!(case.run_until(20_000, |w| tip_arc(w) >= face_arc - 0.7e-3));
    case.drive(1, Drive::PushVelocity(0.0));
    let dac = case.world.strand().inserted_m(1);
    assert!(
        tip_arc(&case.world) <= face_arc + 0.5e-3,
        "the tip stopped at the face"
    );
    case.drive(2, Drive::PushTarget(dac - 10e-3));
    case.drive(3, Drive::PushTarget(dac - 8e-3));
    case.run(6000);
    assert_eq!(case.world.clots().len(), 1);
    case.apply(Command::Aspiration(true)).unwrap();
    assert!(
        case.run_until(500, |w| w.clots().is_empty()),
        "the clot was ingested"
    );
    let f = case.figures();
    assert_eq!(f.passes, 1);
    assert!(f.first_pass_effect);
    assert_eq!(case.reperfusion().1, Etici::Grade3);
}
