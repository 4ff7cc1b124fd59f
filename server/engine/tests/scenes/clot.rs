//! A clot in a scene: the neuro phantom's left M1 occluded, contrast injected from the guide
//! in the ICA. On the rendered image the M1 beyond the clot stays as dark as without contrast
//! while the vessel before it fills as it does without the clot; once the clot is removed,
//! contrast reaches beyond it, and the session's metrics grade the reperfusion from eTICI 0
//! to 3. With pial collaterals the occluded territory keeps the collaterals' share of its
//! flow, and eTICI still grades 0 (antegrade reperfusion only). Bad clots and collaterals
//! name their field.

use std::sync::Arc;

use cathlab_engine::imaging::{carm_of, expose_snapshot_with};
use cathlab_engine::*;
use nalgebra::Point3;

use super::{load, scenes};

fn scene(clot: &str) -> String {
    std::fs::read_to_string(scenes().join("neuro_phantom_m1.toml")).unwrap() + clot
}

const CLOT: &str = "
[[clots]]
branch = \"left_middle_cerebral\"
from_mm = 4.0
length_mm = 8.0
red_cell_fraction = 0.5
";

fn assets(text: &str) -> Arc<SceneAssets> {
    let spec = SceneSpec::parse(text, SceneFormat::Toml).unwrap();
    load(&spec).unwrap()
}

/// Injects 6 mL at 4 mL/s and runs `steps`; returns the world.
fn inject_and_run(world: &mut World, first_seq: u64, steps: usize) {
    world
        .apply(
            first_seq,
            &Command::Inject {
                volume_ml: 6.0,
                rate_ml_s: 4.0,
            },
        )
        .unwrap();
    for _ in 0..steps {
        world.step().unwrap();
    }
}

/// The world's image (no detector noise) and the mean value (line integral) over the M1
/// between each span's ends (mm along it).
fn along_m1(world: &World, spans: &[(f64, f64)]) -> Vec<f64> {
    let a = world.assets();
    let snapshot = world.snapshot();
    let frame = expose_snapshot_with(a, &snapshot, false).unwrap();
    let carm = carm_of(a, &snapshot);
    let graph = &a.anatomy.graph;
    let m1 = &graph.branches[graph.branch_id("left_middle_cerebral").unwrap()];
    spans
        .iter()
        .map(|&(from_mm, to_mm)| {
            let mut sum = 0.0;
            let mut count = 0;
            let mut at = from_mm;
            while at <= to_mm {
                let p = Point3::from(a.to_lps * m1.point_at(at * 1e-3).coords);
                let pixel = carm.project(&p).unwrap();
                let (u, v) = (pixel.x.round() as usize, pixel.y.round() as usize);
                let value = frame.values[u + frame.width as usize * v];
                if value.is_finite() {
                    sum += f64::from(value);
                    count += 1;
                }
                at += 0.5;
            }
            assert!(count > 5, "the M1 is not in the field");
            sum / count as f64
        })
        .collect()
}

#[test]
fn a_clot_in_the_m1_keeps_contrast_beyond_it_off_the_image_until_it_is_removed() {
    let unclotted = assets(&scene(""));
    let clotted = assets(&scene(CLOT));
    assert_eq!(clotted.clots.len(), 1);
    let length_mm = {
        let g = &clotted.anatomy.graph;
        g.branches[g.branch_id("left_middle_cerebral").unwrap()].length() * 1e3
    };
    let steps = 600; // 1.2 s at 500 Hz
    let mut bare = World::new(unclotted.clone()).unwrap();
    for _ in 0..steps {
        bare.step().unwrap();
    }
    let mut filled = World::new(unclotted).unwrap();
    inject_and_run(&mut filled, 1, steps);
    let mut blocked = World::new(clotted).unwrap();
    let at_start = blocked.metrics().reperfusion.unwrap();
    assert_eq!(at_start.etici.label(), "0", "{at_start:?}");
    assert!(
        World::new(assets(&scene("")))
            .unwrap()
            .metrics()
            .reperfusion
            .is_none()
    );
    inject_and_run(&mut blocked, 1, steps);
    let spans = [(0.5, 3.5), (14.0, length_mm - 2.0)];
    let baseline = along_m1(&bare, &spans);
    let contrast = |w: &World| -> Vec<f64> {
        along_m1(w, &spans)
            .iter()
            .zip(&baseline)
            .map(|(a, b)| a - b)
            .collect()
    };
    let (open, blocked_now) = (contrast(&filled), contrast(&blocked));
    let (open_before, open_beyond) = (open[0], open[1]);
    let (blocked_before, blocked_beyond) = (blocked_now[0], blocked_now[1]);
    println!(
        "contrast on the image (line integral over no injection): before the clot {open_before:.4} \
         open / {blocked_before:.4} clotted; beyond it {open_beyond:.4} open / {blocked_beyond:.4} clotted"
    );
    assert!(open_before > 0.0 && open_beyond > 0.0, "the open M1 fills");
    assert!(
        blocked_before > 0.5 * open_before,
        "the M1 before the clot fills"
    );
    assert!(
        blocked_beyond.abs() < 0.02 * open_beyond,
        "contrast got past the clot"
    );
    // Removed (as by a successful retrieval): the next injection fills the M1 beyond.
    blocked.set_clots(&[]).unwrap();
    assert!(blocked.clots().is_empty());
    let after = blocked.metrics().reperfusion.unwrap();
    println!("reperfusion: at the start {at_start:?}, after removal {after:?}");
    assert_eq!(after.etici.label(), "3", "{after:?}");
    inject_and_run(&mut blocked, 10, steps);
    let reopened = contrast(&blocked)[1];
    println!("beyond the clot after its removal: {reopened:.4}");
    assert!(reopened > 0.5 * open_beyond, "no reperfusion after removal");
}

#[test]
fn bad_clots_name_their_field() {
    let cases = [
        (
            CLOT.replace("left_middle_cerebral", "nowhere"),
            "clots[0].branch",
        ),
        (
            CLOT.replace("from_mm = 4.0", "from_mm = -1.0"),
            "clots[0].from_mm",
        ),
        (
            CLOT.replace("length_mm = 8.0", "length_mm = 900.0"),
            "clots[0].length_mm",
        ),
        (
            CLOT.replace("length_mm = 8.0", "length_mm = 0.0"),
            "clots[0].length_mm",
        ),
        (
            CLOT.replace("red_cell_fraction = 0.5", "red_cell_fraction = 2.0"),
            "clots[0].red_cell_fraction",
        ),
    ];
    for (clot, field) in cases {
        let spec = SceneSpec::parse(&scene(&clot), SceneFormat::Toml).unwrap();
        let e = load(&spec).unwrap_err().to_string();
        assert!(e.contains(field), "{field}: {e}");
    }
    // A clot without flow.
    let text = scene(CLOT);
    let start = text.find("[flow]").unwrap();
    let end = start + text[start..].find("\n\n").unwrap();
    let no_flow = format!("{}{}", &text[..start], &text[end..]);
    let spec = SceneSpec::parse(&no_flow, SceneFormat::Toml).unwrap();
    let e = load(&spec).unwrap_err().to_string();
    assert!(e.contains("clots[0].branch") && e.contains("[flow]"), "{e}");
}

const COLLATERALS: &str = "
[flow.collaterals]
recipient = \"left_middle_cerebral\"
donors = [\"left_anterior_cerebral_a2\", \"left_posterior_cerebral_p2\"]
supply_fraction = 0.4
";

/// Good collaterals (0.4): with the M1 clotted, the MCA territory still gets about 40 % of
/// its resting flow, through the collateral vessels; the network conserves flow; eTICI grades
/// the antegrade reperfusion on the network without them: 0 with the clot, 3 without.
#[test]
fn collaterals_feed_the_occluded_territory_and_etici_grades_without_them() {
    let open = World::new(assets(&scene(COLLATERALS))).unwrap();
    let clotted = World::new(assets(&scene(&format!("{COLLATERALS}{CLOT}")))).unwrap();
    let branches = open.assets().anatomy.graph.branches.len();
    let network = open.assets().network.as_ref().unwrap();
    assert_eq!(
        network.vessels.len(),
        branches + 2,
        "two collateral vessels"
    );
    let m1 = network.vessel_id("left_middle_cerebral").unwrap();
    let (before, after) = (
        open.flow_now().unwrap().vessels[m1].distal,
        clotted.flow_now().unwrap().vessels[m1].distal,
    );
    let collateral: f64 = clotted.flow_now().unwrap().vessels[branches..]
        .iter()
        .map(|v| v.proximal)
        .sum();
    println!(
        "M1 flow open {before:.3e} m³/s; clotted: M1 {after:.3e}, collaterals {collateral:.3e} ({:.1} % of open)",
        100.0 * collateral / before
    );
    assert!(after.abs() < 0.01 * before, "the clot stops the M1");
    assert!(
        (collateral / before - 0.4).abs() < 0.05,
        "the collaterals bring their share: {}",
        collateral / before
    );
    let graded = clotted.metrics().reperfusion.unwrap();
    assert_eq!(graded.etici.label(), "0", "{graded:?}");
    assert!(graded.fraction < 0.05, "{graded:?}");
    let mut clotted = clotted;
    clotted.set_clots(&[]).unwrap();
    let reopened = clotted.metrics().reperfusion.unwrap();
    assert_eq!(reopened.etici.label(), "3", "{reopened:?}");
    // Bad collaterals name their field.
    for (bad, field) in [
        (
            COLLATERALS.replace("0.4", "1.5"),
            "flow.collaterals.supply_fraction",
        ),
        (
            COLLATERALS.replace("left_anterior_cerebral_a2", "nowhere"),
            "flow.collaterals",
        ),
        (
            COLLATERALS.replace(
                "[\"left_anterior_cerebral_a2\", \"left_posterior_cerebral_p2\"]",
                "[]",
            ),
            "flow.collaterals.donors",
        ),
    ] {
        assert_ne!(bad, COLLATERALS);
        let e = SceneSpec::parse(&scene(&bad), SceneFormat::Toml)
            .and_then(|spec| load(&spec).map(|_| ()))
            .unwrap_err()
            .to_string();
        assert!(e.contains(field), "{field}: {e}");
    }
}
