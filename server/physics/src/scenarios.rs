//! Verification scenarios shared by the tests, benchmarks and charts: the tip-loaded
//! cantilever against the elastica, and the end-moment roll-up.

use nalgebra::Vector3;

use crate::beam::{BeamModel, SolverSettings};
use crate::elastica;
use crate::error::Result;
use crate::section::{BeamProperties, CircularSection, Material};

/// Length of the verification beams (m).
pub const TEST_BEAM_LENGTH_M: f64 = 1.0;

/// A very slender steel wire (L/r = 10⁴), so extension and shear change the tip by < 1e-7·L
/// and the inextensible elastica is the right reference.
pub fn slender_test_wire() -> BeamProperties {
    BeamProperties::new(
        &CircularSection::solid(1e-4),
        &Material {
            young_modulus_pa: 200e9,
            poisson_ratio: 0.3,
            density_kg_m3: 7800.0,
        },
    )
}

/// Outcome of a loading scenario.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScenarioResult {
    /// Distance between the computed and the reference tip, divided by L.
    pub tip_error: f64,
    /// Linear solves spent.
    pub solves: usize,
    /// Whether every step reported convergence (always true in paper mode).
    pub converged: bool,
}

/// Clamps the slender wire, ramps a dead tip load P = αEI/L² over `load_steps` steps, holds
/// it for `hold_steps` more, and compares the tip with the elastica.
pub fn tip_loaded_cantilever(
    alpha: f64,
    elements: usize,
    settings: SolverSettings,
    load_steps: usize,
    hold_steps: usize,
) -> Result<ScenarioResult> {
    let (tip, solves, converged) =
        solve_tip_loaded_cantilever(alpha, elements, settings, load_steps, hold_steps)?;
    let length = TEST_BEAM_LENGTH_M;
    let reference = elastica::tip_loaded_cantilever(alpha);
    let expected = Vector3::new(
        length * (1.0 - reference.shortening),
        -length * reference.deflection,
        0.0,
    );
    Ok(ScenarioResult {
        tip_error: (tip - expected).norm() / length,
        solves,
        converged,
    })
}

/// The finite-element part of [`tip_loaded_cantilever`]: returns the tip position (m), the
/// linear solves spent and whether every step converged.
pub fn solve_tip_loaded_cantilever(
    alpha: f64,
    elements: usize,
    settings: SolverSettings,
    load_steps: usize,
    hold_steps: usize,
) -> Result<(Vector3<f64>, usize, bool)> {
    let props = slender_test_wire();
    let length = TEST_BEAM_LENGTH_M;
    let mut model = BeamModel::straight(props, length, elements, settings)?;
    let load = alpha * props.bending_stiffness_nm2 / (length * length);
    let mut solves = 0;
    let mut converged = true;
    for k in 1..=load_steps + hold_steps {
        let fraction = (k.min(load_steps)) as f64 / load_steps as f64;
        model.set_load(
            elements,
            Vector3::new(0.0, -load * fraction, 0.0),
            Vector3::zeros(),
        )?;
        let report = model.step()?;
        solves += report.iterations;
        converged &= report.converged;
    }
    Ok((model.tip_position(), solves, converged))
}

/// Applies an end moment M = 2πEI/L about z to the slender wire in `load_steps` steps;
/// the exact solution is a closed circle, so the tip error is the tip-to-base distance / L.
pub fn end_moment_rollup(
    elements: usize,
    settings: SolverSettings,
    load_steps: usize,
) -> Result<ScenarioResult> {
    end_moment_rollup_turns(elements, settings, load_steps, 1.0)
}

/// Applies an end moment M = 2π·turns·EI/L about z to the slender wire in `load_steps`
/// steps; the exact solution is an arc of curvature M/EI through `turns` full turns, so the
/// tip error is the distance from the arc's end point, divided by L.
pub fn end_moment_rollup_turns(
    elements: usize,
    settings: SolverSettings,
    load_steps: usize,
    turns: f64,
) -> Result<ScenarioResult> {
    let props = slender_test_wire();
    let length = TEST_BEAM_LENGTH_M;
    let mut model = BeamModel::straight(props, length, elements, settings)?;
    let angle = 2.0 * std::f64::consts::PI * turns;
    let moment = angle * props.bending_stiffness_nm2 / length;
    let mut solves = 0;
    let mut converged = true;
    for k in 1..=load_steps {
        let fraction = k as f64 / load_steps as f64;
        model.set_load(
            elements,
            Vector3::zeros(),
            Vector3::new(0.0, 0.0, moment * fraction),
        )?;
        let report = model.step()?;
        solves += report.iterations;
        converged &= report.converged;
    }
    let radius = length / angle;
    let exact = Vector3::new(radius * angle.sin(), radius * (1.0 - angle.cos()), 0.0);
    Ok(ScenarioResult {
        tip_error: (model.tip_position() - exact).norm() / length,
        solves,
        converged,
    })
}

/// A 0.014" micro-guidewire pushed around a tight ring of tube (core radius 12 mm, lumen
/// 2 mm) until about 100 elements are inserted (2 mm shaft elements), then 50 steps at
/// 20 mm/s: it hugs the outer wall with some 60 active contacts. The benchmark and chart state
/// for contact-heavy steps; `settings` may change the contact solver (its element sizes are
/// overridden).
pub fn wire_in_a_ring(
    settings: crate::navigation::NavigationSettings,
) -> Result<crate::navigation::Navigation<crate::wall::RingTube>> {
    use crate::navigation::{Command, Insertion, Navigation, NavigationSettings, Twist};
    let wall = crate::wall::RingTube {
        center: Vector3::new(0.0, 0.012, 0.0),
        axis: Vector3::z(),
        major_radius_m: 0.012,
        minor_radius_m: 2e-3,
    };
    let settings = NavigationSettings {
        shaft_element_m: 2e-3,
        ..settings
    };
    let mut nav = Navigation::new(
        crate::device::presets::micro_guidewire_014(),
        wall,
        Vector3::zeros(),
        Vector3::x(),
        0.01,
        settings,
    )?;
    let push = |speed| Command {
        insertion: Insertion::Velocity(speed),
        twist: Twist::Rate(0.0),
    };
    nav.set_command(push(0.1))?;
    while nav.step()?.elements < 100 {}
    nav.set_command(push(0.02))?;
    for _ in 0..50 {
        nav.step()?;
    }
    Ok(nav)
}

/// A scripted navigation in the real arch-to-circle-of-Willis anatomy: which device, where it
/// starts and how the autopilot drives.
#[derive(Debug, Clone)]
pub struct ArchToCowPlan {
    /// Target branch name (`LCCA`, `RVA`, `RCCA`, `LVA`).
    pub target: String,
    /// The guidewire, its tip shaped for the route.
    pub device: crate::device::Device,
    /// Where along the route from the access point the wire starts (m): 0 at the femoral
    /// access in the descending aorta, more for a guide catheter parked further up.
    pub start_along_m: f64,
    /// Autopilot settings.
    pub autopilot: crate::autopilot::AutopilotSettings,
    /// Give up after this many steps.
    pub max_steps: usize,
}

impl ArchToCowPlan {
    /// The plans that reach their targets:
    /// - `LCCA`: from the access point in the descending aorta, a 0.035" wire with a 90° bend
    ///   over 30 mm (wide enough to find the arch's 77° turn in a 20 mm aorta instead of
    ///   running on into the left subclavian), aimed 20 mm ahead;
    /// - `RVA`: from a guide catheter parked in the aortic arch at the brachiocephalic origin,
    ///   a 0.035" wire with a 90° bend over 10 mm (small enough for the 10 mm brachiocephalic
    ///   and the vertebral origin), aimed 5 mm ahead.
    ///
    /// Any other target gets the LCCA plan's device and settings from the access point.
    pub fn for_target(graph: &cathlab_anatomy::VesselGraph, target: &str) -> Result<Self> {
        use crate::autopilot::AutopilotSettings;
        use crate::device::presets::guidewire_035_shaped;
        let right_vertebral = target == "RVA";
        let start_along_m = if right_vertebral {
            // The route's leg into the brachiocephalic trunk starts at the arch.
            let access = nalgebra::Point3::from(cathlab_anatomy::real::ARCH_TO_COW_ACCESS_M);
            let path = graph
                .path_to(&access, target)
                .map_err(|e| crate::error::PhysicsError::Anatomy(e.to_string()))?;
            let mut along = 0.0;
            for leg in &path.legs {
                if graph.branches[leg.branch].name == "arch_to_RCCA+RVA" {
                    break;
                }
                along += (leg.to_arc - leg.from_arc).abs();
            }
            along
        } else {
            0.0
        };
        let (bend_length_m, lookahead_m) = if right_vertebral {
            (0.010, 0.005)
        } else {
            (0.030, 0.020)
        };
        Ok(Self {
            target: target.to_owned(),
            device: guidewire_035_shaped(std::f64::consts::FRAC_PI_2, bend_length_m),
            start_along_m,
            autopilot: AutopilotSettings {
                lookahead_m,
                // The RVA branch starts with 24 mm of subclavian artery: go 76 mm beyond.
                reach_m: if right_vertebral { 0.1 } else { 0.05 },
                ..AutopilotSettings::default()
            },
            max_steps: 15_000,
        })
    }
}

/// The outcome of [`run_arch_to_cow`].
#[derive(Debug, Clone)]
pub struct ArchToCowRun {
    /// Step at which the tip was `reach_m` into the target branch, if it got there.
    pub reached_at_step: Option<usize>,
    /// Steps taken.
    pub steps: usize,
    /// Worst penetration into the wall over all steps (m).
    pub worst_penetration_m: f64,
    /// Wall-clock time of every step (s), in order.
    pub step_times_s: Vec<f64>,
    /// Pull-backs after straying into a side branch.
    pub retries: usize,
    /// Branch nearest to the tip at the end.
    pub tip_branch: String,
    /// Most active contacts in one step.
    pub max_active_contacts: usize,
}

/// Drives `plan` through the real arch-to-cow anatomy until the tip reaches the target or
/// `plan.max_steps` run out.
pub fn run_arch_to_cow(
    anatomy: &cathlab_anatomy::real::Anatomy,
    plan: &ArchToCowPlan,
) -> Result<ArchToCowRun> {
    use crate::autopilot::{Autopilot, AutopilotPhase};
    use crate::navigation::{Navigation, NavigationSettings};
    let access = nalgebra::Point3::from(cathlab_anatomy::real::ARCH_TO_COW_ACCESS_M);
    let path = anatomy
        .graph
        .path_to(&access, &plan.target)
        .map_err(|e| crate::error::PhysicsError::Anatomy(e.to_string()))?;
    let mut pilot = Autopilot::new(&anatomy.graph, path, plan.start_along_m, plan.autopilot)?;
    let (entry, direction) = pilot.entry();
    let mut nav = Navigation::new(
        plan.device.clone(),
        &anatomy.lumen,
        entry,
        direction,
        0.01,
        NavigationSettings::default(),
    )?;
    let mut run = ArchToCowRun {
        reached_at_step: None,
        steps: 0,
        worst_penetration_m: 0.0,
        step_times_s: Vec::with_capacity(plan.max_steps),
        retries: 0,
        tip_branch: String::new(),
        max_active_contacts: 0,
    };
    for step in 0..plan.max_steps {
        let command = pilot.command(&nav);
        if pilot.phase() == AutopilotPhase::Reached {
            run.reached_at_step = Some(step);
            break;
        }
        nav.set_command(command)?;
        let started = std::time::Instant::now();
        let report = nav.step()?;
        run.step_times_s.push(started.elapsed().as_secs_f64());
        run.steps += 1;
        run.worst_penetration_m = run.worst_penetration_m.max(nav.max_penetration_m());
        run.max_active_contacts = run.max_active_contacts.max(report.active_contacts);
    }
    run.retries = pilot.retries();
    let tip = nalgebra::Point3::from(nav.tip_position());
    run.tip_branch = anatomy
        .graph
        .nearest(&tip)
        .map(|l| anatomy.graph.branches[l.branch].name.clone())
        .unwrap_or_default();
    Ok(run)
}
