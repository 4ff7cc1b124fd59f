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
    let props = slender_test_wire();
    let length = TEST_BEAM_LENGTH_M;
    let mut model = BeamModel::straight(props, length, elements, settings)?;
    let moment = 2.0 * std::f64::consts::PI * props.bending_stiffness_nm2 / length;
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
    Ok(ScenarioResult {
        tip_error: model.tip_position().norm() / length,
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
