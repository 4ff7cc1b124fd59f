//! Flow networks from the anatomy's vessel graphs: one vessel per branch, with the branch's
//! centerline and radii, the inlet at a named branch's free end and an outlet at every other
//! free end, each with a terminal resistance that scales with its radius.

use cathlab_anatomy::VesselGraph;

use crate::error::{HemoError, Result, require_positive};
use crate::network::{Blood, FlowNetwork, Inlet, InletCondition, Outlet, Station, Vessel};

/// Terminal (peripheral) resistance of an outlet of radius r:
/// `R = reference_resistance · (reference_radius / r)^exponent`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerminalResistance {
    /// Radius of the reference outlet (m).
    pub reference_radius: f64,
    /// Its terminal resistance (Pa·s/m³).
    pub reference_resistance: f64,
    /// How fast resistance falls with radius (3 is Murray's law; the cerebral outlets of the
    /// circle-of-Willis data follow about 2).
    pub exponent: f64,
}

impl Default for TerminalResistance {
    /// Calibrated to the middle cerebral outlet of the circle-of-Willis data (r = 1.43 mm,
    /// 5.97·10⁹ Pa·s/m³), exponent 2 (its MCA, ACA and PCA outlets fit 2.0).
    fn default() -> Self {
        Self {
            reference_radius: 1.43e-3,
            reference_resistance: 5.97e9,
            exponent: 2.0,
        }
    }
}

/// How to turn a vessel graph into a flow network.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphFlowSettings {
    /// The branch whose free end is the inlet (for the neuro phantom, `ascending_aorta`).
    pub inlet_branch: String,
    /// The inlet condition.
    pub inlet: InletCondition,
    /// Terminal resistance of every other free end.
    pub terminal: TerminalResistance,
    /// Venous pressure beyond the terminal resistances (Pa).
    pub outlet_pressure: f64,
    /// Blood.
    pub blood: Blood,
}

impl Default for GraphFlowSettings {
    /// Inlet at the ascending aorta's root at 100 mmHg, default terminals, venous 0 Pa.
    fn default() -> Self {
        Self {
            inlet_branch: "ascending_aorta".into(),
            inlet: InletCondition::Pressure(100.0 * crate::network::MMHG),
            terminal: TerminalResistance::default(),
            outlet_pressure: 0.0,
            blood: Blood::default(),
        }
    }
}

/// Builds the flow network of `graph`: vessel i is branch i, node ids are the graph's.
pub fn network_from_graph(
    graph: &VesselGraph,
    settings: &GraphFlowSettings,
) -> Result<FlowNetwork> {
    let t = settings.terminal;
    require_positive(
        || "terminal reference radius (m)".into(),
        t.reference_radius,
    )?;
    require_positive(
        || "terminal reference resistance (Pa·s/m³)".into(),
        t.reference_resistance,
    )?;
    let node_count = graph.nodes.len();
    let degree = graph.node_degrees();
    let mut vessels = Vec::with_capacity(graph.branches.len());
    for branch in &graph.branches {
        let mut stations = Vec::with_capacity(branch.points.len());
        let mut points = Vec::with_capacity(branch.points.len());
        for ((p, &r), &arc) in branch
            .points
            .iter()
            .zip(&branch.radii)
            .zip(branch.arc_lengths())
        {
            // Coincident centerline points would give a zero-length piece: keep the first.
            if stations.last().is_some_and(|s: &Station| arc <= s.arc) {
                continue;
            }
            stations.push(Station { arc, radius: r });
            points.push(*p);
        }
        vessels.push(Vessel {
            name: branch.name.clone(),
            from: branch.start,
            to: branch.end,
            stations,
            centerline: Some(points),
        });
    }
    let inlet_branch = graph
        .branch(&settings.inlet_branch)
        .map_err(|_| HemoError::UnknownVessel(settings.inlet_branch.clone()))?;
    let inlet_node = [inlet_branch.start, inlet_branch.end]
        .into_iter()
        .find(|&n| degree[n] == 1)
        .ok_or_else(|| HemoError::InvalidBoundary {
            node: inlet_branch.start,
            message: format!(
                "branch {:?} has no free end for the inlet",
                settings.inlet_branch
            ),
        })?;
    let mut outlets = Vec::new();
    for (node, &d) in degree.iter().enumerate() {
        if d != 1 || node == inlet_node {
            continue;
        }
        let radius = graph
            .branches
            .iter()
            .find_map(|b| {
                if b.start == node {
                    b.radii.first().copied()
                } else if b.end == node {
                    b.radii.last().copied()
                } else {
                    None
                }
            })
            .unwrap_or(t.reference_radius);
        outlets.push(Outlet {
            node,
            resistance: t.reference_resistance * (t.reference_radius / radius).powf(t.exponent),
            pressure: settings.outlet_pressure,
        });
    }
    FlowNetwork::new(
        node_count,
        vessels,
        Inlet {
            node: inlet_node,
            condition: settings.inlet,
        },
        outlets,
        settings.blood,
    )
}
