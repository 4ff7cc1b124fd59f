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

/// The real surface's anterior genu (the carotid siphon's hairpin, about 4 mm radius) stops a
/// microwire pushed up the left carotid at 50 mm/s: pushed on 150 mm with its tip held there,
/// the wire buckles, folds back and prolapses down the wide cervical carotid (its tip ends
/// 140 mm below the genu), and comes back out to where it started when pulled, with no
/// divergence (issue 44's scripted prolapse).
#[test]
fn a_microwire_blocked_at_the_anterior_genu_loops_and_pulls_back_out() {
    use cathlab_physics::{Command, Insertion, Navigation, NavigationSettings, Twist};
    let anatomy = arch_to_cow();
    let access = nalgebra::Point3::from(cathlab_anatomy::real::ARCH_TO_COW_ACCESS_M);
    let path = anatomy.graph.path_to(&access, "LCCA").unwrap();
    let route = anatomy.graph.sample_path(&path, 0.001);
    // The genu: the sharpest turn of the route's carotid part (its last 150 mm), the turn
    // measured over ±3 mm.
    let turn = |k: usize| {
        let a = (route[k].0 - route[k - 3].0).normalize();
        let b = (route[k + 3].0 - route[k].0).normalize();
        a.dot(&b).clamp(-1.0, 1.0).acos()
    };
    let genu = (route.len() - 150..route.len() - 4)
        .max_by(|&a, &b| turn(a).total_cmp(&turn(b)))
        .unwrap();
    // The wire starts 40 mm before it, 10 mm in.
    let start = genu - 50;
    let entry = route[start].0.coords;
    let direction = (route[start + 10].0 - route[start].0).normalize();
    let mut nav = Navigation::new(
        presets::micro_guidewire_014(),
        &anatomy.lumen,
        entry,
        direction,
        0.01,
        NavigationSettings::default(),
    )
    .unwrap();
    let along = |p: &nalgebra::Vector3<f64>| {
        (0..route.len())
            .min_by(|&a, &b| {
                (route[a].0.coords - p)
                    .norm()
                    .total_cmp(&(route[b].0.coords - p).norm())
            })
            .unwrap()
    };
    let speed = 0.05;
    // Drives at `velocity` (m/s) for `metres`; returns the deepest penetration (m) and the
    // tip's furthest sample along the route.
    let drive = |nav: &mut Navigation<&cathlab_anatomy::Lumen>, velocity: f64, metres: f64| {
        let mut worst_penetration: f64 = 0.0;
        let mut furthest = 0;
        nav.set_command(Command {
            insertion: Insertion::Velocity(velocity),
            twist: Twist::Rate(0.0),
        })
        .unwrap();
        let steps =
            (metres / velocity.abs() / NavigationSettings::default().time_step_s).round() as usize;
        for step in 0..steps {
            nav.step()
                .unwrap_or_else(|e| panic!("step {step} at {velocity} m/s: {e}"));
            worst_penetration = worst_penetration.max(nav.max_penetration_m());
            furthest = furthest.max(along(&nav.tip_position()));
        }
        (worst_penetration, furthest)
    };
    let start_tip = nav.tip_position();
    let (pushing_penetration, furthest) = drive(&mut nav, speed, 0.15);
    let pushed_tip = along(&nav.tip_position());
    // Slack: wire inserted beyond the straight distance its tip went along the route.
    let slack = nav.inserted_m() - 0.001 * (pushed_tip as f64 - start as f64);
    let positions = nav.model().positions().to_vec();
    // The loop: somewhere the wire runs back towards the entry (a tangent against the route).
    let reversed = positions
        .windows(2)
        .any(|w| (w[1] - w[0]).normalize().dot(&direction) < -0.5);
    println!(
        "genu {} mm along the route ({:.0}° over 6 mm); after 150 mm: tip {} mm along (furthest {}), {:.0} mm of slack, wire folded back: {reversed}, deepest {:.4} mm",
        genu,
        turn(genu).to_degrees(),
        pushed_tip,
        furthest,
        slack * 1e3,
        pushing_penetration * 1e3
    );
    assert!(
        furthest <= genu + 10,
        "the tip passed the genu ({furthest} mm along)"
    );
    // The prolapse: the tip itself went back down the carotid, below where the wire started.
    assert!(
        pushed_tip + 50 < genu,
        "the tip stayed at {pushed_tip} mm along (the genu at {genu}): no prolapse"
    );
    assert!(reversed, "the wire did not fold back");
    let (pulling_penetration, _) = drive(&mut nav, -2.0 * speed, 0.15);
    let worst_penetration = pushing_penetration.max(pulling_penetration);
    let back = (nav.tip_position() - start_tip).norm();
    println!(
        "pulled back: inserted {:.1} mm, tip {:.1} mm from where it started, deepest {:.4} mm",
        nav.inserted_m() * 1e3,
        back * 1e3,
        worst_penetration * 1e3
    );
    assert!((nav.inserted_m() - 0.01).abs() < 1e-3);
    assert!(back < 0.005, "the tip came back to {:.1} mm", back * 1e3);
    // Where the wire folds, nodes go 0.20–0.24 mm past the wall (0.45 mm pushed at 20 mm/s)
    // with four detection rounds and three halvings spent: issue 44 asks 0.05 mm. Held here
    // so that it cannot grow unseen. The fold's path is sensitive: a contact solve that
    // differs only in round-off (an updated instead of a fresh factorization) took it along
    // another path whose pull left a loop, the tip 38 mm from its start and 0.46 mm deep.
    assert!(worst_penetration <= 0.3e-3, "{}", worst_penetration);
}
