//! Navigation scenarios: a device pushed, pulled and twisted through walls, with the
//! penetration, stability and determinism checks of the contact model.

use cathlab_physics::navigation::{Command, Insertion, Navigation, NavigationSettings, Twist};
use cathlab_physics::wall::{CappedTube, Wall};
use cathlab_physics::{BeamModel, SolverSettings, presets};
use nalgebra::Vector3;

/// Penetration tolerance of every scenario (m): 0.05 mm, a tenth of a guidewire's diameter.
const PENETRATION: f64 = 0.05e-3;

fn tube(length: f64, radius: f64) -> CappedTube {
    CappedTube {
        start: Vector3::zeros(),
        axis: Vector3::x(),
        length_m: length,
        radius_m: radius,
    }
}

fn navigation<W: Wall>(wall: W, inserted: f64) -> Navigation<W> {
    Navigation::new(
        presets::micro_guidewire_014(),
        wall,
        Vector3::zeros(),
        Vector3::x(),
        inserted,
        NavigationSettings::default(),
    )
    .unwrap()
}

fn push(speed: f64) -> Command {
    Command {
        insertion: Insertion::Velocity(speed),
        twist: Twist::Rate(0.0),
    }
}

#[test]
fn elastic_energy_matches_clapeyron() {
    // A cantilever under a small tip load stores ½ F·δ (linear regime).
    let props = presets::micro_guidewire_014().sections[0].beam_properties();
    let mut model = BeamModel::straight(props, 0.05, 40, SolverSettings::default()).unwrap();
    let force = 1e-4;
    model
        .set_load(40, Vector3::new(0.0, force, 0.0), Vector3::zeros())
        .unwrap();
    for _ in 0..20 {
        model.step().unwrap();
    }
    let work = 0.5 * force * model.tip_position().y;
    let energy = model.elastic_energy();
    assert!((energy - work).abs() < 1e-3 * work, "{energy} vs {work}");
}

#[test]
fn free_push_translates_an_angled_tip_exactly() {
    // In free space a push moves the whole inserted device along the entry axis, its angled
    // tip unchanged: the predictor slides the shaft along itself and carries the tip rigidly.
    let mut nav = navigation(tube(1.0, 0.5), 0.01);
    let tip0 = nav.tip_position();
    nav.set_command(push(0.05)).unwrap();
    for _ in 0..100 {
        let report = nav.step().unwrap();
        assert_eq!(report.contacts, 0);
    }
    let moved = nav.tip_position() - tip0;
    let expected = Vector3::x() * (0.05 * 100.0 / 500.0);
    assert!((moved - expected).norm() < 1e-12, "{moved:?}");
    assert!(nav.model().elastic_energy() < 1e-15);
    assert!((nav.inserted_m() - 0.02).abs() < 1e-12);
    // Pulling back the same way returns the same shape.
    nav.set_command(push(-0.05)).unwrap();
    for _ in 0..100 {
        nav.step().unwrap();
    }
    assert!((nav.tip_position() - tip0).norm() < 1e-9);
}

/// Runs `steps` steps of `command`, checking every step: finite state, penetration below the
/// tolerance, and the device inside the tube's radius and before its cap. Returns the largest
/// penetration, elastic energy and hand work seen.
fn run_checked(
    nav: &mut Navigation<CappedTube>,
    command: Command,
    steps: usize,
) -> (f64, f64, f64) {
    nav.set_command(command).unwrap();
    let wall = *nav.wall();
    let (mut worst, mut energy, mut work) = (0.0f64, 0.0f64, 0.0f64);
    for step in 0..steps {
        let before = nav.inserted_m();
        let report = nav.step().unwrap_or_else(|e| panic!("step {step}: {e}"));
        let reaction = nav.proximal_reaction();
        // The hand applies the base reaction; its axial part does work on the insertion.
        work += reaction[0] * (nav.inserted_m() - before);
        let penetration = nav.max_penetration_m();
        worst = worst.max(penetration);
        energy = energy.max(nav.model().elastic_energy());
        assert!(
            penetration < PENETRATION,
            "step {step}: penetration {:.4} mm ({report:?})",
            penetration * 1e3
        );
        for p in nav.model().positions() {
            assert!(p.iter().all(|v| v.is_finite()));
            let radial = (p.y * p.y + p.z * p.z).sqrt();
            assert!(
                radial < wall.radius_m && p.x < wall.length_m,
                "escaped at {p:?}"
            );
        }
    }
    (worst, energy, work)
}

#[test]
fn pushing_into_a_dead_end_for_ten_seconds_buckles_and_loops_without_escape() {
    // 0.014" wire in a 4 mm tube closed 40 mm in, pushed at 10 mm/s for 10 s: 100 mm of wire
    // into 30 mm of tube. It hits the cap, buckles, folds and loops back.
    let mut nav = navigation(tube(0.04, 2e-3), 0.01);
    let (worst, energy, work) = run_checked(&mut nav, push(0.01), 5000);
    println!(
        "dead end: worst penetration {:.4} mm, peak elastic energy {energy:.3e} J, hand work \
         {work:.3e} J, tip at {:?} mm",
        worst * 1e3,
        (nav.tip_position() * 1e3).as_slice()
    );
    assert!(nav.inserted_m() > 0.105);
    // Bounded energy: no more than bending the whole inserted wire to the tightest fold the
    // tube allows, κ = 2/(D − d), twice over (torsion and stretch included).
    let props = nav.device().sections[0].beam_properties();
    let kappa = 2.0 / (4e-3 - 2.0 * nav.device().sections[0].cross_section.outer_radius_m);
    let bound = props.bending_stiffness_nm2 * kappa * kappa * nav.inserted_m();
    assert!(
        energy < bound,
        "energy {energy} J above the fold bound {bound} J"
    );
    assert!(work > 0.0, "the hand pushed");
    assert!(nav.tip_position().x < 0.038, "the wire folded back");
}

#[test]
fn twenty_turns_of_twist_stay_stable() {
    // A wire 60 mm into a tube, twisted 20 turns at 2 turns/s with a slow push.
    let mut nav = navigation(tube(0.2, 1.5e-3), 0.06);
    let command = Command {
        insertion: Insertion::Velocity(0.002),
        twist: Twist::Rate(4.0 * std::f64::consts::PI),
    };
    let (worst, energy, _) = run_checked(&mut nav, command, 5000);
    println!(
        "20 turns: worst penetration {:.4} mm, peak energy {energy:.3e} J",
        worst * 1e3
    );
    assert!((nav.twist_rad() - 40.0 * std::f64::consts::PI).abs() < 1e-9);
    assert!(energy < 1e-3, "energy {energy}");
}

#[test]
fn a_fast_push_does_not_tunnel_through_the_cap() {
    // 100 mm/s straight into the cap: the tip never passes it.
    let mut nav = navigation(tube(0.05, 2e-3), 0.01);
    let (worst, _, _) = run_checked(&mut nav, push(0.1), 800);
    println!(
        "100 mm/s into the cap: worst penetration {:.4} mm",
        worst * 1e3
    );
}

#[test]
fn the_tip_node_takes_contacts_from_two_walls_in_a_corner() {
    let mut nav = navigation(tube(0.03, 2e-3), 0.01);
    nav.set_command(push(0.05)).unwrap();
    let mut most = 0;
    for _ in 0..600 {
        nav.step().unwrap();
        let step = nav.last_contacts().unwrap();
        let tip_element = nav.model().element_count() - 1;
        let at_tip: Vec<_> = step
            .contacts
            .iter()
            .zip(&step.response.local)
            .filter(|(c, l)| c.element == tip_element && c.t > 0.5 && l.x > 0.0)
            .collect();
        most = most.max(at_tip.len());
        assert!(nav.max_penetration_m() < PENETRATION);
    }
    assert!(most >= 2, "corner contacts on the tip: {most}");
}

#[test]
fn scripted_runs_are_bit_identical() {
    let script = |nav: &mut Navigation<CappedTube>| {
        for (speed, twist, steps) in [(0.05, 0.0, 300), (0.02, 3.0, 300), (-0.03, -2.0, 200)] {
            nav.set_command(Command {
                insertion: Insertion::Velocity(speed),
                twist: Twist::Rate(twist),
            })
            .unwrap();
            for _ in 0..steps {
                nav.step().unwrap();
            }
        }
        nav.model().positions().to_vec()
    };
    let a = script(&mut navigation(tube(0.06, 2e-3), 0.01));
    let b = script(&mut navigation(tube(0.06, 2e-3), 0.01));
    assert_eq!(a.len(), b.len());
    for (p, q) in a.iter().zip(&b) {
        assert_eq!(p.map(f64::to_bits), q.map(f64::to_bits));
    }
}

#[test]
fn bad_commands_and_settings_give_clear_errors() {
    let mut nav = navigation(tube(0.05, 2e-3), 0.01);
    let err = nav.set_command(push(f64::NAN)).unwrap_err();
    assert!(err.to_string().contains("insertion"), "{err}");
    let err = Navigation::new(
        presets::micro_guidewire_014(),
        tube(0.05, 2e-3),
        Vector3::zeros(),
        Vector3::zeros(),
        0.01,
        NavigationSettings::default(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("entry direction"), "{err}");
    let err = Navigation::new(
        presets::micro_guidewire_014(),
        tube(0.05, 2e-3),
        Vector3::zeros(),
        Vector3::x(),
        5.0,
        NavigationSettings::default(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("inserted length"), "{err}");
    let err = Navigation::new(
        presets::micro_guidewire_014(),
        tube(0.05, 2e-3),
        Vector3::zeros(),
        Vector3::x(),
        0.01,
        NavigationSettings {
            refinement: Some(cathlab_physics::navigation::Refinement {
                max_bend_rad: f64::NAN,
                ..Default::default()
            }),
            ..NavigationSettings::default()
        },
    )
    .unwrap_err();
    assert!(err.to_string().contains("refinement.max_bend_rad"), "{err}");
}

/// The Y bifurcation of the anatomy crate (parent r = 2 mm along +z, children r = 1.6 mm at
/// ±30° towards +x (left) and −x (right)), meshed and wrapped as a lumen.
fn y_lumen() -> (cathlab_anatomy::VesselGraph, cathlab_anatomy::Lumen) {
    use cathlab_anatomy::phantom::analytic::y_bifurcation;
    use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};
    let graph = y_bifurcation(2e-3, 1.6e-3, 0.04, 0.04, 0.52).unwrap();
    let mesh = lumen_surface(
        &graph,
        &SurfaceSettings {
            cells_per_radius: 1.5,
            smoothing_iterations: 1,
            ..SurfaceSettings::default()
        },
    )
    .unwrap();
    // Contact queries look at most a millimetre from the wall: a narrow band builds fast.
    let lumen = cathlab_anatomy::Lumen::with_grid_settings(
        mesh,
        "Y bifurcation",
        cathlab_anatomy::lumen::GridSettings {
            cell_size: Some(0.25e-3),
            band: 1.5e-3,
        },
    )
    .unwrap();
    (graph, lumen)
}

#[test]
fn twisting_an_angled_tip_selects_the_branch_of_a_y_bifurcation() {
    let (graph, lumen) = y_lumen();
    for (branch, sign) in [("left", 1.0), ("right", -1.0)] {
        let mut nav = Navigation::new(
            presets::micro_guidewire_014(),
            &lumen,
            Vector3::new(0.0, 0.0, -0.036),
            Vector3::z(),
            0.01,
            NavigationSettings::default(),
        )
        .unwrap();
        // The tip's bend points this way at zero twist; turn it towards the wanted branch.
        let bend = nav.tip_position() - Vector3::new(0.0, 0.0, nav.tip_position().z);
        let twist = (0.0f64).atan2(sign) - bend.y.atan2(bend.x);
        nav.set_command(Command {
            insertion: Insertion::Velocity(0.0),
            twist: Twist::Target(twist),
        })
        .unwrap();
        for _ in 0..250 {
            nav.step().unwrap();
        }
        nav.set_command(Command {
            insertion: Insertion::Velocity(0.03),
            twist: Twist::Target(twist),
        })
        .unwrap();
        let mut worst: f64 = 0.0;
        // 27 mm of push: the tip passes the carina (z = 0) and runs 20 mm up a branch.
        for step in 0..900 {
            nav.step()
                .unwrap_or_else(|e| panic!("{branch} step {step}: {e}"));
            worst = worst.max(nav.max_penetration_m());
        }
        let tip = nav.tip_position();
        let location = graph
            .nearest(&nalgebra::Point3::from(tip))
            .expect("the tip is near the graph");
        println!(
            "{branch}: tip at {:?} mm in {:?}, worst penetration {:.4} mm",
            (tip * 1e3).as_slice(),
            graph.branches[location.branch].name,
            worst * 1e3
        );
        assert_eq!(graph.branches[location.branch].name, branch);
        assert!(tip.z > 0.015, "the tip went well into the branch");
        assert!(tip.x * sign > 0.008, "on the {branch} side");
        assert!(worst < PENETRATION, "penetration {worst}");
    }
}

#[test]
fn tip_bend_direction_follows_the_twist_in_free_space() {
    let mut nav = navigation(tube(1.0, 0.5), 0.02);
    let before = nav.tip_bend_direction().expect("angled tip");
    // The tip's sideways offset is along the bend direction.
    let offset = nav.tip_position() - Vector3::x() * nav.tip_position().x;
    assert!(before.dot(&offset.normalize()) > 0.999);
    nav.set_command(Command {
        insertion: Insertion::Velocity(0.0),
        twist: Twist::Target(std::f64::consts::FRAC_PI_2),
    })
    .unwrap();
    for _ in 0..200 {
        nav.step().unwrap();
    }
    let after = nav.tip_bend_direction().unwrap();
    // A free device carries the twist to its tip: the bend turned a quarter turn about x
    // (to the drag-regularized steps' residual lag).
    let turned = Vector3::x().cross(&before);
    assert!((after - turned).norm() < 1e-3, "{after:?} vs {turned:?}");
    assert!((nav.tip_axis() - Vector3::x()).norm() < 1e-3);
}

/// The real arch-to-circle-of-Willis anatomy, loaded once for the tests that share it.
fn arch_to_cow() -> &'static cathlab_anatomy::real::Anatomy {
    static ANATOMY: std::sync::OnceLock<cathlab_anatomy::real::Anatomy> =
        std::sync::OnceLock::new();
    ANATOMY.get_or_init(|| {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
        cathlab_anatomy::real::load_arch_to_cow(&dir).unwrap()
    })
}

fn navigate_arch_to_cow(target: &str) {
    use cathlab_physics::scenarios::{ArchToCowPlan, run_arch_to_cow};
    let anatomy = arch_to_cow();
    let plan = ArchToCowPlan::for_target(&anatomy.graph, target).unwrap();
    let run = run_arch_to_cow(anatomy, &plan).unwrap();
    println!(
        "{target}: reached at step {:?}, {} pull-backs, worst penetration {:.4} mm, tip in {}",
        run.reached_at_step,
        run.retries,
        run.worst_penetration_m * 1e3,
        run.tip_branch
    );
    assert!(
        run.reached_at_step.is_some(),
        "{target} not reached in {} steps; the tip ended in {}",
        run.steps,
        run.tip_branch
    );
    assert_eq!(run.tip_branch, target);
    assert!(
        run.worst_penetration_m < PENETRATION,
        "{target}: penetration {} m",
        run.worst_penetration_m
    );
}

#[test]
fn a_shaped_guidewire_reaches_the_left_common_carotid_from_the_femoral_access() {
    navigate_arch_to_cow("LCCA");
}

#[test]
fn a_shaped_guidewire_reaches_the_right_vertebral_from_the_aortic_arch() {
    navigate_arch_to_cow("RVA");
}

#[test]
fn the_stock_angled_catheter_runs_on_into_the_left_subclavian_instead_of_the_arch() {
    // Negative control for the tip shape: the 5 F catheter's 45° over 8 mm spans a third of
    // the 20 mm aorta and cannot find the arch's 77° turn; the autopilot keeps backing off.
    use cathlab_physics::scenarios::{ArchToCowPlan, run_arch_to_cow};
    let anatomy = arch_to_cow();
    let mut plan = ArchToCowPlan::for_target(&anatomy.graph, "LCCA").unwrap();
    plan.device = presets::diagnostic_catheter_5f();
    plan.max_steps = 4_000;
    let run = run_arch_to_cow(anatomy, &plan).unwrap();
    assert!(run.reached_at_step.is_none());
    assert!(run.retries >= 1, "it never strayed");
    assert!(run.worst_penetration_m < PENETRATION);
}

#[test]
fn elements_are_halved_where_the_wire_bends_and_merged_when_it_straightens() {
    use cathlab_physics::navigation::Refinement;
    // A 0.014" wire pushed 30 mm past a dead end 40 mm into a 4 mm tube buckles; pulled back,
    // it straightens again.
    let wall = tube(0.04, 2e-3);
    let mut nav = navigation(wall, 0.01);
    let nominal_at = |inserted: f64| {
        let mut fresh = navigation(tube(0.04, 2e-3), inserted);
        fresh.step().unwrap();
        fresh.model().element_count()
    };
    let refinement = Refinement::default();
    let mut most_elements = 0;
    let mut worst_bend: f64 = 0.0;
    let mut worst: f64 = 0.0;
    for step in 0..3500 {
        let speed = if step < 3500 / 2 { 0.04 } else { -0.04 };
        nav.set_command(push(speed)).unwrap();
        let report = nav.step().unwrap();
        most_elements = most_elements.max(report.elements);
        worst = worst.max(nav.max_penetration_m());
        // Right after a step the elements reflect the bends of the previous one; check the
        // criterion on those long enough to be split.
        let model = nav.model();
        let material = nav.node_material_m();
        for e in 1..model.element_count() {
            if material[e + 1] - material[e] >= 3e-3 {
                let r = model.rotations();
                worst_bend =
                    worst_bend.max((r[e] * Vector3::x()).angle(&(r[e + 1] * Vector3::x())));
            }
        }
    }
    let inserted = nav.inserted_m();
    let nominal = nominal_at(inserted);
    println!(
        "most elements {most_elements}; back at {:.1} mm: {} elements (nominal {nominal}); \
         worst bend of a splittable element after a step {worst_bend:.3} rad; penetration {:.4} mm",
        inserted * 1e3,
        nav.model().element_count(),
        worst * 1e3
    );
    // Buckled, it needed more nodes than a straight wire of the same length.
    assert!(most_elements as f64 > 1.3 * nominal_at(0.04) as f64);
    // Straight again, the extra nodes merged away.
    assert!(nav.model().element_count() <= nominal + 1);
    // Splitting kept up with the bending: at most one step's worth above the threshold.
    assert!(worst_bend < 2.0 * refinement.max_bend_rad, "{worst_bend}");
    assert!(worst < PENETRATION);
}

#[test]
fn bad_arch_to_cow_plans_give_clear_errors() {
    use cathlab_physics::scenarios::{ArchToCowPlan, run_arch_to_cow};
    let anatomy = arch_to_cow();
    let err = run_arch_to_cow(
        anatomy,
        &ArchToCowPlan {
            target: "basilar".into(),
            ..ArchToCowPlan::for_target(&anatomy.graph, "LCCA").unwrap()
        },
    )
    .unwrap_err();
    assert!(err.to_string().contains("basilar"), "{err}");
    let mut plan = ArchToCowPlan::for_target(&anatomy.graph, "LCCA").unwrap();
    plan.start_along_m = 10.0;
    let err = run_arch_to_cow(anatomy, &plan).unwrap_err();
    assert!(err.to_string().contains("autopilot start"), "{err}");
    let mut plan = ArchToCowPlan::for_target(&anatomy.graph, "LCCA").unwrap();
    plan.autopilot.lookahead_m = f64::NAN;
    let err = run_arch_to_cow(anatomy, &plan).unwrap_err();
    assert!(err.to_string().contains("lookahead_m"), "{err}");
}

/// The overload governor's cheapest step (no halving, one detection round, 20 sweeps, no
/// polish, coarse refinement) keeps the wire inside the wall only by projecting out what
/// still penetrates: pushed into a dead end at 100 mm/s, the wire stays within the contact
/// tolerance (0.01 mm) at every step. A step that will not be halved projects whether or
/// not its effort asks (`Effort::last_try_contact`): before that, the wire without the
/// projection went past the wall by more than the 0.05 mm every fidelity level must hold.
#[test]
fn the_cheapest_step_projects_what_still_penetrates_out_of_the_wall() {
    use cathlab_physics::Effort;
    let cheapest = |project_penetration| Effort {
        max_substep_depth: 0,
        max_detection_rounds: 1,
        max_sweeps: 20,
        polish: false,
        refinement_scale: 4.0,
        min_substep_penetration_m: 0.0,
        project_penetration,
    };
    let worst = |project| {
        let mut nav = navigation(tube(0.04, 2e-3), 0.01);
        nav.set_effort(cheapest(project)).unwrap();
        nav.set_command(push(0.1)).unwrap();
        let mut worst: f64 = 0.0;
        for step in 0..1000 {
            nav.step().unwrap_or_else(|e| panic!("step {step}: {e}"));
            worst = worst.max(nav.max_penetration_m());
        }
        worst
    };
    let (without, with) = (worst(false), worst(true));
    println!(
        "dead end at 100 mm/s, the cheapest step: worst penetration {:.4} mm with its effort's projection off, {:.4} mm with it on",
        without * 1e3,
        with * 1e3
    );
    assert!(without <= 0.0105e-3, "{without}");
    assert!(with <= 0.0105e-3, "{with}");
}

#[test]
fn a_device_at_rest_sleeps_where_the_solved_steps_would_keep_it_and_wakes_when_pushed() {
    use cathlab_physics::Sleep;
    // 0.014" wire pushed into a dead end for 4 s (40 mm in, buckled against the cap 30 mm
    // beyond where it started), then the hand holds.
    let mut nav = navigation(tube(0.04, 2e-3), 0.01);
    nav.set_command(push(0.01)).unwrap();
    for step in 0..2000 {
        nav.step().unwrap_or_else(|e| panic!("step {step}: {e}"));
    }
    nav.set_command(push(0.0)).unwrap();
    let mut solved = nav.clone();
    nav.set_sleep(Some(Sleep::default()));
    // The reference solves every step; the sleeper stops solving once no node's mean
    // position drifted 5 µm from the first half to the second of 100 steps in a row.
    let mut fell_asleep = None;
    let mut frozen = None;
    let mut settled = Vec::new();
    for step in 0..4000 {
        solved.step().unwrap();
        let report = nav.step().unwrap();
        if report.asleep {
            fell_asleep.get_or_insert(step);
            let now = nav.model().positions().to_vec();
            // Asleep, nothing moves at all.
            assert_eq!(*frozen.get_or_insert_with(|| now.clone()), now, "{step}");
        }
        if step == 2999 {
            settled = solved.model().positions().to_vec();
        }
    }
    let fell_asleep = fell_asleep.expect("the wire came to rest");
    let apart = nav
        .model()
        .positions()
        .iter()
        .zip(solved.model().positions())
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    // The solved run has come to its equilibrium (not creeping): the sleeper stopped short of
    // it by what was left of the relaxation, within the drift a window allows (5 µm; a
    // detector pixel is 200-400 µm).
    let creep = settled
        .iter()
        .zip(solved.model().positions())
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    let (felt, felt_solved) = (nav.proximal_reaction(), solved.proximal_reaction());
    println!(
        "a wire buckled in a dead end, hands still: asleep after {fell_asleep} steps; after 8 s the sleeper's nodes {:.3} µm from the solved run's (which moved {:.1e} µm in its last 2 s), hand force {:.4} N against {:.4} N, deepest {:.4} mm",
        apart * 1e6,
        creep * 1e6,
        felt.fixed_rows::<3>(0).norm(),
        felt_solved.fixed_rows::<3>(0).norm(),
        nav.max_penetration_m() * 1e3,
    );
    assert!(fell_asleep < 1000, "{fell_asleep}");
    assert!(creep < 1e-9, "{creep}");
    assert!(apart < Sleep::default().max_drift_m, "{apart}");
    assert!(
        (felt - felt_solved).fixed_rows::<3>(0).norm()
            < 1e-3 * felt_solved.fixed_rows::<3>(0).norm().max(1e-3),
        "{felt} {felt_solved}"
    );
    assert!(nav.max_penetration_m() <= PENETRATION);
    // A push wakes it: the wire goes in, the step is solved.
    let tip = nav.tip_position();
    nav.set_command(push(0.01)).unwrap();
    let report = nav.step().unwrap();
    assert!(!report.asleep && report.sweeps > 0, "{report:?}");
    assert!((nav.inserted_m() - solved.inserted_m() - 0.01 / 500.0).abs() < 1e-12);
    assert!(nav.tip_position() != tip);
    // Sleep off: every step is solved.
    nav.set_command(push(0.0)).unwrap();
    nav.set_sleep(None);
    for _ in 0..200 {
        assert!(!nav.step().unwrap().asleep);
    }
}
