//! Coaxial runs in the real arch-to-circle-of-Willis anatomy: the two-hand plans to the LCCA
//! and the right vertebral, bit-identical repeats, and merged against nested coupling on a
//! scripted push up the aorta.

use cathlab_physics::presets;
use cathlab_physics::scenarios::{CoaxialPlan, run_coaxial_arch_to_cow};

fn arch_to_cow() -> &'static cathlab_anatomy::real::Anatomy {
    static ANATOMY: std::sync::OnceLock<cathlab_anatomy::real::Anatomy> =
        std::sync::OnceLock::new();
    ANATOMY.get_or_init(|| {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
        cathlab_anatomy::real::load_arch_to_cow(&dir).unwrap()
    })
}

/// Runs the two-hand plan to `target` and checks it: the wire reaches the target, the
/// microcatheter goes 30 mm beyond the catheter, the leading tip ends in the target branch and
/// no node went more than 0.05 mm into the wall.
fn two_hands_reach(target: &str) {
    let anatomy = arch_to_cow();
    let plan = CoaxialPlan::for_target(&anatomy.graph, target).unwrap();
    let run = run_coaxial_arch_to_cow(anatomy, &plan).unwrap();
    println!(
        "{target}: wire exchanged at step {:?}, reached at step {:?}, microcatheter 30 mm beyond the catheter at step {:?}, {} pull-backs, worst penetration {:.4} mm ({:.4} mm with the catheters' rims), inserted {:?} mm, tip in {}",
        run.exchanged_at_step,
        run.reached_at_step,
        run.micro_done_at_step,
        run.retries,
        run.worst_penetration_m * 1e3,
        run.worst_rim_penetration_m * 1e3,
        run.inserted_m
            .iter()
            .map(|l| (l * 1e4).round() / 10.0)
            .collect::<Vec<_>>(),
        run.tip_branch
    );
    assert!(
        run.reached_at_step.is_some(),
        "the wire reached the {target}"
    );
    assert!(
        run.micro_done_at_step.is_some(),
        "the microcatheter went through"
    );
    assert_eq!(run.tip_branch, target);
    assert!(run.inserted_m[1] - run.inserted_m[0] >= 0.03 - 1e-9);
    assert!(run.worst_penetration_m <= 0.05e-3);
    // The catheters' rims are measured but not yet in the contacts (issue 44): 0.39–0.40 mm
    // deep in these runs; held here so that it cannot grow unseen.
    assert!(
        run.worst_rim_penetration_m <= 0.5e-3,
        "{}",
        run.worst_rim_penetration_m
    );
}

#[test]
fn two_hands_take_a_catheter_over_a_wire_to_the_lcca_and_a_microcatheter_beyond() {
    two_hands_reach("LCCA");
}

#[test]
fn two_hands_take_a_catheter_over_exchanged_wires_to_the_right_vertebral_and_a_microcatheter_beyond()
 {
    // No parked guide: the wide-bend wire leads into the brachiocephalic trunk, the catheter
    // tracks over it, the wire is exchanged for a small bend that selects the vertebral.
    two_hands_reach("RVA");
}

#[test]
fn a_coaxial_run_is_bit_identical_when_repeated() {
    let anatomy = arch_to_cow();
    // 14,000 steps of the RVA plan: the wire leads, the catheter tracks, the wire is withdrawn
    // and exchanged, and the new one loaded.
    let plan = CoaxialPlan {
        max_steps: 14_000,
        ..CoaxialPlan::for_target(&anatomy.graph, "RVA").unwrap()
    };
    let a = run_coaxial_arch_to_cow(anatomy, &plan).unwrap();
    let b = run_coaxial_arch_to_cow(anatomy, &plan).unwrap();
    // A phase change takes a loop turn without a step.
    assert!(a.steps > 13_990 && a.steps == b.steps);
    assert!(a.exchanged_at_step.is_some(), "the wire was exchanged");
    assert_eq!(a.tip_position, b.tip_position);
    assert_eq!(a.inserted_m, b.inserted_m);
    assert_eq!(a.worst_penetration_m, b.worst_penetration_m);
}

#[test]
fn merged_and_nested_follow_the_same_scripted_push_up_the_aorta() {
    // The wire leads 10 mm ahead of a 5 F catheter, both pushed at 40 mm/s from the femoral
    // access; the same commands in both modes. (The chart command runs 3000 steps with one to
    // four instruments.)
    use cathlab_physics::scenarios::{ScriptedStack, compare_couplings};
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let anatomy = cathlab_anatomy::real::load_arch_to_cow(&dir).unwrap();
    let script = ScriptedStack::up_the_aorta(
        vec![presets::diagnostic_catheter_5f(), presets::guidewire_035()],
        400,
    );
    let comparison = compare_couplings(&anatomy, &script).unwrap();
    println!("scripted push, 5 F over 0.035\": {comparison}");
    for run in [&comparison.merged, &comparison.nested] {
        assert!(
            run.worst_penetration_m <= 0.05e-3,
            "{}",
            run.worst_penetration_m
        );
    }
}
