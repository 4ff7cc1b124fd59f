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

/// A scripted two-hand navigation of a coaxial stack in the real arch-to-cow anatomy, from the
/// femoral access in the descending aorta (no parked catheter): the autopilot steers the wire,
/// the catheter follows over it `catheter_lag_m` behind its tip; where a wire change is
/// planned, the catheter is parked, the wire withdrawn to the hub and exchanged, and the new
/// wire leads on; at the end, optionally, the wire is withdrawn and a microcatheter goes
/// through the catheter over a microwire `micro_beyond_m` past the catheter's tip.
#[derive(Debug, Clone)]
pub struct CoaxialPlan {
    /// Target branch name (`LCCA`, `RVA`).
    pub target: String,
    /// The catheter (outer instrument).
    pub catheter: crate::device::Device,
    /// The first wire.
    pub wire: crate::device::Device,
    /// How far behind the wire's tip the catheter follows (m).
    pub catheter_lag_m: f64,
    /// Once the wire has reached the target, how far behind its tip the catheter is tracked
    /// over it before the wire is withdrawn (m).
    pub catheter_track_m: f64,
    /// A wire change: once the wire tip is this far along the route (m), park the catheter
    /// there, withdraw the wire and lead on with the second device and autopilot settings.
    pub exchange: Option<(
        f64,
        crate::device::Device,
        crate::autopilot::AutopilotSettings,
    )>,
    /// Autopilot settings of the first wire.
    pub autopilot: crate::autopilot::AutopilotSettings,
    /// Microcatheter and microwire sent through the catheter at the end, and how far beyond
    /// the catheter's tip the microcatheter goes (m).
    pub micro: Option<(crate::device::Device, crate::device::Device, f64)>,
    /// Where along the route the instruments enter (m from the femoral access): 0, or the
    /// tip of a guide parked further up.
    pub start_along_m: f64,
    /// Give up after this many steps.
    pub max_steps: usize,
}

impl CoaxialPlan {
    /// The two-hand plans, with a 5 F catheter (45° tip) following 50 mm behind a shaped
    /// 0.035" wire, then a 0.017" microcatheter over a 0.014" microwire 30 mm beyond the
    /// catheter's tip:
    /// - `LCCA`: from the femoral access, the 90°-over-30 mm wire of the single-wire plan all
    ///   the way (eight aims, backing out of a side branch before each);
    /// - `RVA`: from the arch at the left common carotid's origin (as the single-wire plan),
    ///   that wire, aimed 50 mm ahead, into the brachiocephalic trunk; the catheter
    ///   tracked over it to 15 mm behind its tip; the wire withdrawn and exchanged for the
    ///   90°-over-10 mm wire of the single-wire RVA plan, which leaves the parked catheter
    ///   and selects the vertebral while the catheter follows.
    pub fn for_target(graph: &cathlab_anatomy::VesselGraph, target: &str) -> Result<Self> {
        use crate::device::presets::{
            diagnostic_catheter_5f, guidewire_035_shaped, micro_catheter, micro_guidewire_014,
        };
        let single = ArchToCowPlan::for_target(graph, target)?;
        let arch = ArchToCowPlan::for_target(graph, "LCCA")?;
        let right_vertebral = target == "RVA";
        let exchange_at = if right_vertebral {
            let access = nalgebra::Point3::from(cathlab_anatomy::real::ARCH_TO_COW_ACCESS_M);
            let path = graph
                .path_to(&access, target)
                .map_err(|e| crate::error::PhysicsError::Anatomy(e.to_string()))?;
            // 45 mm into the brachiocephalic trunk (5 mm short of its end): the wide 90° bend
            // finds the arch's turn and the trunk; the catheter, tracked over it there, gives
            // the small bend the support to select the vertebral. Exchanged 20–30 mm into the
            // trunk, the stack buckles back into the arch when the new wire is pushed.
            let mut along = 0.0;
            for leg in &path.legs {
                if graph.branches[leg.branch].name == "arch_to_RCCA+RVA" {
                    break;
                }
                along += (leg.to_arc - leg.from_arc).abs();
            }
            along + 0.045
        } else {
            0.0
        };
        Ok(Self {
            target: target.to_owned(),
            catheter: diagnostic_catheter_5f(),
            wire: guidewire_035_shaped(std::f64::consts::FRAC_PI_2, 0.030),
            catheter_lag_m: 0.05,
            catheter_track_m: 0.015,
            exchange: right_vertebral
                .then(|| (exchange_at, single.device.clone(), single.autopilot)),
            autopilot: if right_vertebral {
                // Aimed 50 mm ahead, past the left common carotid's origin (aimed 20 mm ahead,
                // the wide bend takes the carotid or falls back into the left subclavian).
                crate::autopilot::AutopilotSettings {
                    lookahead_m: 0.05,
                    ..arch.autopilot
                }
            } else {
                // Eight aims, backing out of a side branch before the next (with four, each
                // pulled back 15 mm, the wire took the left subclavian at every aim with the
                // catheter behind it once the contacts' normals followed the wall distance's
                // gradient where the surface's interpolated normals stray from it).
                crate::autopilot::AutopilotSettings {
                    aims: 8,
                    retreat_out_of_branch: true,
                    ..single.autopilot
                }
            },
            micro: Some((micro_catheter(), micro_guidewire_014(), 0.03)),
            // As the single-wire plan: to the vertebral from the arch at the left common
            // carotid's origin (a guide parked there). From the femoral access the wide bend
            // took the left subclavian or the left carotid at every aim once the contacts'
            // normals followed the wall distance's gradient where the surface's interpolated
            // normals stray from it (under those alone it found the trunk after five tries).
            start_along_m: single.start_along_m,
            max_steps: 60_000,
        })
    }
}

impl CoaxialPlan {
    /// The plan as the two-hand autopilot takes it.
    pub fn two_hand_plan(&self) -> crate::two_hands::TwoHandPlan {
        use crate::two_hands::Finish;
        crate::two_hands::TwoHandPlan {
            catheter_lag_m: self.catheter_lag_m,
            catheter_track_m: self.catheter_track_m,
            exchange: self.exchange.clone(),
            autopilot: self.autopilot,
            finish: match &self.micro {
                Some((micro, wire, beyond)) => {
                    Finish::Microcatheter(micro.clone(), wire.clone(), *beyond)
                }
                None => Finish::AtWire,
            },
            outer_parks_m: Vec::new(),
        }
    }
}

/// The outcome of [`run_coaxial_arch_to_cow`].
#[derive(Debug, Clone, Default)]
pub struct CoaxialRun {
    /// Step at which the wire tip reached the target, if it did.
    pub reached_at_step: Option<usize>,
    /// Step at which the first wire, withdrawn to the hub, was exchanged for the second.
    pub exchanged_at_step: Option<usize>,
    /// Step at which the microcatheter was `micro_beyond_m` past the catheter's tip.
    pub micro_done_at_step: Option<usize>,
    /// Steps taken.
    pub steps: usize,
    /// Worst penetration into the wall over all steps, of each instrument's shaft alone (a
    /// catheter's rim with the radius of the instrument going on; m).
    pub worst_penetration_m: f64,
    /// Worst penetration with each catheter's rim at its own radius, as the contacts see it
    /// (m).
    pub worst_rim_penetration_m: f64,
    /// Wall-clock time of every step (s).
    pub step_times_s: Vec<f64>,
    /// Pull-backs of the autopilot.
    pub retries: usize,
    /// Branch nearest to the leading tip at the end.
    pub tip_branch: String,
    /// Inserted lengths at the end (m), outermost first.
    pub inserted_m: Vec<f64>,
    /// Leading tip position at the end (m).
    pub tip_position: Vector3<f64>,
    /// Largest axial force any hand felt (N).
    pub max_hand_force_n: f64,
    /// Gauss–Seidel sweeps, active contacts and elements of every step.
    pub step_stats: Vec<(usize, usize, usize)>,
}

/// Drives `plan` through the real arch-to-cow anatomy with a merged coaxial stack.
pub fn run_coaxial_arch_to_cow(
    anatomy: &cathlab_anatomy::real::Anatomy,
    plan: &CoaxialPlan,
) -> Result<CoaxialRun> {
    coaxial_arch_to_cow_stack(anatomy, plan).map(|(run, _)| run)
}

/// [`run_coaxial_arch_to_cow`], returning the stack in its final state too (the benchmarks'
/// triaxial state).
pub fn coaxial_arch_to_cow_stack<'a>(
    anatomy: &'a cathlab_anatomy::real::Anatomy,
    plan: &CoaxialPlan,
) -> Result<(CoaxialRun, crate::stack::Stack<&'a cathlab_anatomy::Lumen>)> {
    use crate::navigation::NavigationSettings;
    use crate::stack::{InstrumentSpec, Stack};
    use crate::two_hands::{TwoHandAction, TwoHands};
    let access = nalgebra::Point3::from(cathlab_anatomy::real::ARCH_TO_COW_ACCESS_M);
    let path = anatomy
        .graph
        .path_to(&access, &plan.target)
        .map_err(|e| crate::error::PhysicsError::Anatomy(e.to_string()))?;
    let mut hands = TwoHands::new(
        &anatomy.graph,
        path.clone(),
        plan.start_along_m,
        plan.two_hand_plan(),
    )?;
    let (entry, direction) =
        crate::autopilot::Autopilot::new(&anatomy.graph, path, plan.start_along_m, plan.autopilot)?
            .entry();
    let settings = NavigationSettings::default();
    let mut stack = Stack::new(
        vec![
            InstrumentSpec::new(plan.catheter.clone(), 0.01, &settings),
            InstrumentSpec::new(plan.wire.clone(), 0.03, &settings),
        ],
        &anatomy.lumen,
        entry,
        direction,
        settings,
    )?;
    let mut run = CoaxialRun {
        step_times_s: Vec::with_capacity(plan.max_steps),
        ..Default::default()
    };
    for step in 0..plan.max_steps {
        match hands.next(&stack)? {
            TwoHandAction::Done => {
                if hands.wire_reached() {
                    run.reached_at_step.get_or_insert(step);
                }
                if plan.micro.is_some() {
                    run.micro_done_at_step = Some(step);
                }
                break;
            }
            TwoHandAction::Exchange(index, device) => {
                stack.exchange(index, device)?;
                run.exchanged_at_step = Some(step);
                continue;
            }
            TwoHandAction::Replace(devices) => {
                stack.pop_instrument()?;
                for device in devices {
                    stack.push_instrument(device)?;
                }
                continue;
            }
            TwoHandAction::Drive(commands) => {
                for (index, command) in commands {
                    stack.set_command(index, command)?;
                }
            }
        }
        if hands.wire_reached() {
            run.reached_at_step.get_or_insert(step);
        }
        let started = std::time::Instant::now();
        let report = stack.step()?;
        run.step_times_s.push(started.elapsed().as_secs_f64());
        run.step_stats
            .push((report.sweeps, report.active_contacts, report.elements));
        run.steps += 1;
        run.worst_penetration_m = run.worst_penetration_m.max(stack.max_shaft_penetration_m());
        run.worst_rim_penetration_m = run.worst_rim_penetration_m.max(stack.max_penetration_m());
        for reaction in stack.proximal_reactions() {
            run.max_hand_force_n = run.max_hand_force_n.max(reaction.axial_force_n.abs());
        }
    }
    run.retries = hands.retries();
    let lead = (0..stack.len())
        .max_by(|&a, &b| {
            stack
                .inserted_m(a)
                .unwrap_or(0.0)
                .total_cmp(&stack.inserted_m(b).unwrap_or(0.0))
        })
        .unwrap_or(0);
    run.tip_position = stack.tip_position(lead).unwrap_or(entry);
    run.inserted_m = (0..stack.len())
        .map(|k| stack.inserted_m(k).unwrap_or(0.0))
        .collect();
    run.tip_branch = anatomy
        .graph
        .nearest(&nalgebra::Point3::from(run.tip_position))
        .map(|l| anatomy.graph.branches[l.branch].name.clone())
        .unwrap_or_default();
    Ok((run, stack))
}

/// A scripted open-loop stack run through the real arch-to-cow anatomy: the instruments
/// (outermost first) start from the femoral access with each inner tip `lead_m` ahead of the
/// one around it and are all pushed at `speed_m_s`, so the innermost leads and the others
/// follow at a fixed lag. The same commands drive either coupling, so the runs compare the
/// two modes.
#[derive(Debug, Clone)]
pub struct ScriptedStack {
    /// The instruments, outermost first.
    pub devices: Vec<crate::device::Device>,
    /// Inserted length of the outermost instrument at the start (m).
    pub start_m: f64,
    /// How far each inner tip leads the one around it (m).
    pub lead_m: f64,
    /// Push speed of every hand (m/s).
    pub speed_m_s: f64,
    /// Steps with the hands held before the push, for the straight start to relax (not
    /// recorded).
    pub settle_steps: usize,
    /// Steps to take pushing.
    pub steps: usize,
    /// Record the tips and hand forces every this many steps.
    pub sample_every: usize,
}

impl ScriptedStack {
    /// The comparison push: `devices` (outermost first) from 20 mm in, each inner tip 10 mm
    /// ahead of the one around it, 20 steps to relax, then `steps` steps at 40 mm/s, sampled
    /// every 20 steps.
    pub fn up_the_aorta(devices: Vec<crate::device::Device>, steps: usize) -> Self {
        Self {
            devices,
            start_m: 0.02,
            lead_m: 0.01,
            speed_m_s: 0.04,
            settle_steps: 20,
            steps,
            sample_every: 20,
        }
    }
}

/// The record of a [`ScriptedStack`] run.
#[derive(Debug, Clone, Default)]
pub struct ScriptedStackRun {
    /// Per sample: every instrument's tip position (m), outermost first.
    pub tips: Vec<Vec<Vector3<f64>>>,
    /// Per sample: every hand's axial force (N), outermost first.
    pub hand_forces_n: Vec<Vec<f64>>,
    /// Wall-clock time of every step (s).
    pub step_times_s: Vec<f64>,
    /// Worst penetration into the wall (or a lumen) over all steps (m).
    pub worst_penetration_m: f64,
    /// Steps whose Gauss–Seidel did not meet its tolerance.
    pub unconverged_steps: usize,
}

impl ScriptedStackRun {
    /// Median wall time of a step (s).
    pub fn median_step_s(&self) -> f64 {
        let mut t = self.step_times_s.clone();
        t.sort_by(f64::total_cmp);
        t.get(t.len() / 2).copied().unwrap_or(0.0)
    }

    /// Per instrument, the largest and the root-mean-square distance (m) between its tip here
    /// and in `reference` over the common samples.
    pub fn tip_deviation_m(&self, reference: &Self) -> Vec<(f64, f64)> {
        let count = self.tips.first().map_or(0, Vec::len);
        (0..count)
            .map(|k| {
                let d: Vec<f64> = self
                    .tips
                    .iter()
                    .zip(&reference.tips)
                    .map(|(a, b)| (a[k] - b[k]).norm())
                    .collect();
                let largest = d.iter().copied().fold(0.0, f64::max);
                let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len().max(1) as f64).sqrt();
                (largest, rms)
            })
            .collect()
    }

    /// The largest axial force any hand felt over the samples (N).
    pub fn largest_hand_force_n(&self) -> f64 {
        self.hand_forces_n
            .iter()
            .flat_map(|f| f.iter().map(|v| v.abs()))
            .fold(0.0, f64::max)
    }
}

/// One [`ScriptedStack`] run in both couplings, nested mode the reference.
#[derive(Debug, Clone)]
pub struct CouplingComparison {
    /// The merged run.
    pub merged: ScriptedStackRun,
    /// The nested run.
    pub nested: ScriptedStackRun,
    /// Per instrument, outermost first: the largest and the RMS distance (m) between its tips
    /// in the two runs.
    pub tip_distance_m: Vec<(f64, f64)>,
}

impl std::fmt::Display for CouplingComparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (m, n) = (&self.merged, &self.nested);
        write!(
            f,
            "merged {:.3} ms/step, nested {:.3} ms/step; tip distance merged–nested, outermost first:",
            m.median_step_s() * 1e3,
            n.median_step_s() * 1e3
        )?;
        for (largest, rms) in &self.tip_distance_m {
            write!(f, " {:.2} mm (rms {:.2})", largest * 1e3, rms * 1e3)?;
        }
        write!(
            f,
            "; largest hand force merged {:.3} N, nested {:.3} N; worst penetration merged {:.4} mm, nested {:.4} mm; unconverged steps {} / {}",
            m.largest_hand_force_n(),
            n.largest_hand_force_n(),
            m.worst_penetration_m * 1e3,
            n.worst_penetration_m * 1e3,
            m.unconverged_steps,
            n.unconverged_steps
        )
    }
}

/// Runs `script` in the arch-to-cow anatomy in merged and in nested mode.
pub fn compare_couplings(
    anatomy: &cathlab_anatomy::real::Anatomy,
    script: &ScriptedStack,
) -> Result<CouplingComparison> {
    use crate::stack::Coupling;
    let merged = run_scripted_stack(anatomy, script, Coupling::Merged)?;
    let nested = run_scripted_stack(anatomy, script, Coupling::Nested)?;
    let tip_distance_m = merged.tip_deviation_m(&nested);
    Ok(CouplingComparison {
        merged,
        nested,
        tip_distance_m,
    })
}

/// Runs `script` in the arch-to-cow anatomy with the instruments coupled as `coupling` says.
pub fn run_scripted_stack(
    anatomy: &cathlab_anatomy::real::Anatomy,
    script: &ScriptedStack,
    coupling: crate::stack::Coupling,
) -> Result<ScriptedStackRun> {
    use crate::navigation::{Command, Insertion, NavigationSettings, Twist};
    use crate::stack::{InstrumentSpec, Stack};
    let access = nalgebra::Point3::from(cathlab_anatomy::real::ARCH_TO_COW_ACCESS_M);
    let path = anatomy
        .graph
        .path_to(&access, "LCCA")
        .map_err(|e| crate::error::PhysicsError::Anatomy(e.to_string()))?;
    let route = anatomy.graph.sample_path(&path, 1e-3);
    let (entry, direction) = crate::autopilot::route_entry(&route);
    let settings = NavigationSettings::default();
    let specs = script
        .devices
        .iter()
        .enumerate()
        .map(|(k, d)| {
            InstrumentSpec::new(
                d.clone(),
                script.start_m + k as f64 * script.lead_m,
                &settings,
            )
        })
        .collect();
    let mut stack =
        Stack::with_coupling(specs, &anatomy.lumen, entry, direction, settings, coupling)?;
    let push = |stack: &mut Stack<_>, speed| -> Result<()> {
        for k in 0..stack.len() {
            let command = Command {
                insertion: Insertion::Velocity(speed),
                twist: Twist::Rate(0.0),
            };
            stack.set_command(k, command)?;
        }
        Ok(())
    };
    push(&mut stack, 0.0)?;
    for _ in 0..script.settle_steps {
        stack.step()?;
    }
    push(&mut stack, script.speed_m_s)?;
    let mut run = ScriptedStackRun::default();
    let every = script.sample_every.max(1);
    for step in 1..=script.steps {
        let started = std::time::Instant::now();
        let report = stack.step()?;
        run.step_times_s.push(started.elapsed().as_secs_f64());
        run.unconverged_steps += usize::from(!report.converged);
        run.worst_penetration_m = run.worst_penetration_m.max(stack.max_penetration_m());
        if step % every == 0 {
            run.tips.push(
                (0..stack.len())
                    .map(|k| stack.tip_position(k).unwrap_or(entry))
                    .collect(),
            );
            run.hand_forces_n.push(
                stack
                    .proximal_reactions()
                    .iter()
                    .map(|r| r.axial_force_n)
                    .collect(),
            );
        }
    }
    Ok(run)
}
