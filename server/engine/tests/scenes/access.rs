//! A stack at the femoral access (`stroke_m1_from_access`): the innermost instrument taken
//! out step by step, and devices loaded that fit the stack.

use std::sync::Arc;

use cathlab_engine::*;

use super::{load, scenes};

fn assets(text: &str) -> Arc<SceneAssets> {
    let spec = SceneSpec::parse(text, SceneFormat::Toml).unwrap();
    load(&spec).unwrap()
}

#[test]
fn a_stack_takes_its_innermost_out_step_by_step_and_loads_devices_that_fit() {
    let text = std::fs::read_to_string(scenes().join("stroke_m1_from_access.toml")).unwrap();
    let mut world = World::new(assets(&text)).unwrap();
    let index = |id: &str| {
        cathlab_engine::scene::catalogue()
            .entries()
            .iter()
            .position(|e| e.id == id)
            .unwrap() as u32
    };
    let ids = |w: &World| -> Vec<String> {
        w.snapshot()
            .instruments
            .iter()
            .map(|i| i.catalogue_id.clone())
            .collect()
    };
    // A full lumen: nothing fits inside the 0.035" wire.
    let refused = world
        .apply(
            1,
            &Command::Load {
                catalogue: index("microwire-014-angled"),
            },
        )
        .unwrap_err();
    assert!(refused.to_string().contains("fit"), "{refused}");
    // The wire (30 mm in) out: drawn back step by step; a push on it cancels.
    world.apply(2, &Command::Unload).unwrap();
    world.step().unwrap();
    world
        .apply(
            3,
            &Command::Instrument {
                index: 2,
                drive: Drive::PushVelocity(0.01),
            },
        )
        .unwrap();
    assert!(
        world
            .take_events()
            .iter()
            .any(|e| e.message.contains("cancelled")),
        "a push cancels the unloading"
    );
    // Loading waits for an unloading under way.
    world.apply(4, &Command::Unload).unwrap();
    let busy = world
        .apply(
            5,
            &Command::Load {
                catalogue: index("microcatheter-021-160"),
            },
        )
        .unwrap_err();
    assert!(busy.to_string().contains("under way"), "{busy}");
    let mut steps = 0;
    while world.strand().len() == 3 {
        world.step().unwrap();
        steps += 1;
        assert!(steps < 20_000, "the unloading never finished");
    }
    assert_eq!(ids(&world), ["guide-6f-071-90", "catheter-5f-vertebral"]);
    let (lo, _) = world.strand().stack().unwrap().inserted_range_m(1).unwrap();
    println!(
        "unloaded in {steps} steps; the catheter's hub range starts at {:.0} mm",
        lo * 1e3
    );
    // A microcatheter, then a microwire into it: each the new innermost, at the hub.
    world
        .apply(
            6,
            &Command::Load {
                catalogue: index("microcatheter-021-160"),
            },
        )
        .unwrap();
    world
        .apply(
            7,
            &Command::Load {
                catalogue: index("microwire-014-angled"),
            },
        )
        .unwrap();
    assert_eq!(
        ids(&world),
        [
            "guide-6f-071-90",
            "catheter-5f-vertebral",
            "microcatheter-021-160",
            "microwire-014-angled"
        ]
    );
    let stack = world.strand().stack().unwrap();
    for k in 2..4 {
        let (lo, _) = stack.inserted_range_m(k).unwrap();
        assert_eq!(
            stack.inserted_m(k),
            Some(lo),
            "instrument {k} starts at the hub"
        );
    }
    world.step().unwrap();
    // Four is the most a stack holds; a spare the scene does not have is named.
    let full = world
        .apply(
            8,
            &Command::Load {
                catalogue: index("microwire-014-j"),
            },
        )
        .unwrap_err();
    assert!(full.to_string().contains("number of instruments"), "{full}");
    let missing = world
        .apply(9, &Command::LoadSpare { spare: 0 })
        .unwrap_err();
    assert!(
        missing.to_string().contains("spare 0 does not exist"),
        "{missing}"
    );
    // Everything but the guide out (the two new ones at their hubs: at once; the catheter
    // drawn back first); the guide stays.
    world.apply(10, &Command::Unload).unwrap();
    world.apply(11, &Command::Unload).unwrap();
    assert_eq!(world.strand().len(), 2);
    world.apply(12, &Command::Unload).unwrap();
    let again = world.apply(13, &Command::Unload).unwrap_err();
    assert!(again.to_string().contains("under way"), "{again}");
    let mut steps = 0;
    while world.strand().len() == 2 {
        world.step().unwrap();
        steps += 1;
        assert!(steps < 20_000, "the catheter's unloading never finished");
    }
    assert_eq!(ids(&world), ["guide-6f-071-90"]);
    let outermost = world.apply(14, &Command::Unload).unwrap_err();
    assert!(outermost.to_string().contains("outermost"), "{outermost}");
}
