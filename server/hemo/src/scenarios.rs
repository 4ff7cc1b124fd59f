//! Reference scenarios shared by tests, benchmarks and charts: the bundled circle-of-Willis
//! network, a series chain of uniform vessels, and a bolus advected down a straight tube,
//! compared with the exact (shifted) profile.

use crate::contrast::{Contrast, ContrastSettings, Limiter};
use crate::error::Result;
use crate::flow::FlowSolver;
use crate::network::{Blood, FlowNetwork, Inlet, InletCondition, Outlet, Vessel};

/// A chain of uniform vessels `(length m, radius m)` from node 0 (inlet at `inlet_pa`) to
/// the last node, which drains through `terminal` (Pa·s/m³) into `outlet_pa`; default blood.
pub fn series_chain(
    specs: &[(f64, f64)],
    terminal: f64,
    inlet_pa: f64,
    outlet_pa: f64,
) -> Result<FlowNetwork> {
    let vessels: Vec<Vessel> = specs
        .iter()
        .enumerate()
        .map(|(i, &(l, r))| Vessel::uniform(format!("v{i}"), i, i + 1, l, r))
        .collect();
    FlowNetwork::new(
        specs.len() + 1,
        vessels,
        Inlet {
            node: 0,
            condition: InletCondition::Pressure(inlet_pa),
        },
        vec![Outlet {
            node: specs.len(),
            resistance: terminal,
            pressure: outlet_pa,
        }],
        Blood::default(),
    )
}

/// The bundled real circle-of-Willis network (`data/flow/circle_of_willis.yaml`, openBF) at
/// 100 mmHg inlet pressure and 0 mmHg venous pressure.
pub fn circle_of_willis() -> Result<FlowNetwork> {
    crate::openbf::read_openbf(
        std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../data/flow/circle_of_willis.yaml"
        )),
        crate::openbf::OpenBfBoundary {
            inlet: InletCondition::Pressure(100.0 * crate::network::MMHG),
            outlet_pressure: 0.0,
        },
    )
}

/// A straight tube of `length` and `radius` (m) fed with a prescribed flow that gives mean
/// speed `speed` (m/s), draining to 0 Pa.
pub fn straight_tube(length: f64, radius: f64, speed: f64) -> Result<FlowNetwork> {
    FlowNetwork::new(
        2,
        vec![Vessel::uniform("tube", 0, 1, length, radius)],
        Inlet {
            node: 0,
            condition: InletCondition::Flow(speed * std::f64::consts::PI * radius * radius),
        },
        vec![Outlet {
            node: 1,
            resistance: 0.0,
            pressure: 0.0,
        }],
        Blood::default(),
    )
}

/// Bolus shapes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BolusShape {
    /// A plug (top hat) as long as the bolus width: what a short injection leaves.
    Plug,
    /// A Gaussian whose full width at half maximum is the bolus width.
    Gaussian,
}

/// A bolus run: the computed and exact cell averages after transport.
#[derive(Debug, Clone, PartialEq)]
pub struct BolusRun {
    /// Computed concentration per cell (mg/mL).
    pub profile: Vec<f64>,
    /// Exact cell averages of the shifted initial profile (mg/mL).
    pub exact: Vec<f64>,
    /// Cell length (m).
    pub cell_length: f64,
}

impl BolusRun {
    /// Computed peak over exact peak.
    pub fn peak_kept(&self) -> f64 {
        max(&self.profile) / max(&self.exact)
    }

    /// Position error of the bolus (cells): the centre of the span above half maximum,
    /// computed minus exact.
    pub fn arrival_error_cells(&self) -> f64 {
        half_maximum_centre(&self.profile) - half_maximum_centre(&self.exact)
    }

    /// L1 error relative to the exact bolus's total.
    pub fn relative_l1_error(&self) -> f64 {
        let error: f64 = self
            .profile
            .iter()
            .zip(&self.exact)
            .map(|(a, b)| (a - b).abs())
            .sum();
        error / self.exact.iter().sum::<f64>()
    }
}

fn max(values: &[f64]) -> f64 {
    values.iter().copied().fold(f64::MIN, f64::max)
}

/// Cell position (fractional index) of the middle of the span above half the maximum.
fn half_maximum_centre(values: &[f64]) -> f64 {
    let half = 0.5 * max(values);
    let first = values.iter().position(|&v| v >= half).unwrap_or(0);
    let last = values.iter().rposition(|&v| v >= half).unwrap_or(0);
    let crossing = |i: usize, j: usize| {
        let (a, b) = (values[i], values[j]);
        i as f64 + (half - a) / (b - a) * (j as f64 - i as f64)
    };
    let front = if first > 0 {
        crossing(first - 1, first)
    } else {
        0.0
    };
    let back = if last + 1 < values.len() {
        crossing(last, last + 1)
    } else {
        last as f64
    };
    0.5 * (front + back)
}

/// Average of `f` over `[a, b]` (composite Simpson, 16 intervals).
fn cell_average(f: impl Fn(f64) -> f64, a: f64, b: f64) -> f64 {
    let n = 16;
    let h = (b - a) / n as f64;
    let mut sum = f(a) + f(b);
    for i in 1..n {
        sum += f(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    sum * h / 3.0 / (b - a)
}

/// Advects a 300 mg/mL bolus of `shape` and `width` (m) `distance` metres down a 250 mm tube
/// (r = 2 mm, 0.2 m/s) on cells of `cell_length`, in steps of exactly Courant number `cfl`.
/// The bolus starts centred at 20 mm (or 6σ for wide Gaussians, so none of it is cut off).
pub fn advect_bolus(
    limiter: Limiter,
    shape: BolusShape,
    cell_length: f64,
    cfl: f64,
    width: f64,
    distance: f64,
) -> Result<BolusRun> {
    let speed = 0.2;
    let network = straight_tube(0.25, 2e-3, speed)?;
    let solution = FlowSolver::new(network.clone())?.solve(None)?;
    let mut contrast = Contrast::new(
        &network,
        ContrastSettings {
            cell_length,
            cfl: 1.0,
            limiter,
        },
    )?;
    contrast.set_flow(&network, &solution)?;
    let dx = contrast.cell_length(0);
    let sigma = width / (8.0 * 2f64.ln()).sqrt();
    let x0 = (6.0 * sigma).max(0.02);
    let bolus = |centre: f64| {
        move |x: f64| match shape {
            BolusShape::Gaussian => 300.0 * (-0.5 * ((x - centre) / sigma).powi(2)).exp(),
            BolusShape::Plug if (x - centre).abs() <= 0.5 * width => 300.0,
            BolusShape::Plug => 0.0,
        }
    };
    let initial = bolus(x0);
    contrast.fill(0, |x| cell_average(initial, x - 0.5 * dx, x + 0.5 * dx))?;
    let dt = cfl * dx / speed;
    let steps = (distance / (speed * dt)).round() as usize;
    for _ in 0..steps {
        contrast.step(dt)?;
    }
    let target = bolus(x0 + steps as f64 * speed * dt);
    let exact = contrast
        .cell_centers(0)
        .iter()
        .map(|&x| cell_average(target, x - 0.5 * dx, x + 0.5 * dx))
        .collect();
    Ok(BolusRun {
        profile: contrast.concentration(0).to_vec(),
        exact,
        cell_length: dx,
    })
}
