//! Reader for openBF-style network files (YAML): vessel segments with start and end nodes,
//! length and proximal/distal radii, and Windkessel outlets whose total peripheral resistance
//! becomes the terminal resistance of the steady network.
//!
//! The elastic parameters (E, gamma profile) and compliances (Cc) are read past: steady
//! Poiseuille flow does not use them.

use std::path::Path;

use serde::Deserialize;

use crate::error::{HemoError, Result};
use crate::network::{Blood, FlowNetwork, Inlet, InletCondition, Outlet, Vessel};

#[derive(Debug, Deserialize)]
struct FileYaml {
    blood: Option<BloodYaml>,
    network: Vec<VesselYaml>,
}

#[derive(Debug, Deserialize)]
struct BloodYaml {
    rho: f64,
    mu: f64,
}

#[derive(Debug, Deserialize)]
struct VesselYaml {
    label: String,
    sn: usize,
    tn: usize,
    #[serde(rename = "L")]
    length: f64,
    #[serde(rename = "R0")]
    radius: Option<f64>,
    #[serde(rename = "Rp")]
    proximal_radius: Option<f64>,
    #[serde(rename = "Rd")]
    distal_radius: Option<f64>,
    outlet: Option<String>,
    #[serde(rename = "R1")]
    r1: Option<f64>,
    #[serde(rename = "R2")]
    r2: Option<f64>,
}

/// Boundary conditions for a network read from a file that describes only its geometry and
/// peripheral resistances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpenBfBoundary {
    /// The condition at the inlet (the one free end without an outlet).
    pub inlet: InletCondition,
    /// Venous pressure beyond every terminal resistance (Pa).
    pub outlet_pressure: f64,
}

/// Reads an openBF network file.
pub fn read_openbf(path: &Path, boundary: OpenBfBoundary) -> Result<FlowNetwork> {
    let text =
        cathlab_anatomy::io::limits::read_regular_text(path).map_err(|source| HemoError::Io {
            file: path.to_path_buf(),
            source,
        })?;
    parse_openbf(&text, &path.display().to_string(), boundary)
}

/// Parses an openBF network from `text`; `file` names it in errors. Nodes are renumbered from
/// the file's 1-based numbers to 0-based; the inlet is the only free end without an outlet.
pub fn parse_openbf(text: &str, file: &str, boundary: OpenBfBoundary) -> Result<FlowNetwork> {
    let parse_error = |message: String| HemoError::Parse {
        file: file.to_string(),
        message,
    };
    let yaml: FileYaml = serde_yaml_ng::from_str(text)
        .map_err(|e| parse_error(format!("not an openBF network: {e}")))?;
    if yaml.network.is_empty() {
        return Err(parse_error("the network has no vessels".into()));
    }
    let blood = match yaml.blood {
        Some(b) => Blood {
            viscosity: b.mu,
            density: b.rho,
        },
        None => Blood::default(),
    };
    let node_count = yaml
        .network
        .iter()
        .map(|v| v.sn.max(v.tn))
        .max()
        .unwrap_or(0);
    let mut vessels = Vec::with_capacity(yaml.network.len());
    let mut outlets = Vec::new();
    let mut degree = vec![0usize; node_count + 1];
    for v in &yaml.network {
        if v.sn == 0 || v.tn == 0 {
            return Err(parse_error(format!(
                "vessel {:?}: node numbers start at 1",
                v.label
            )));
        }
        let (proximal, distal) = match (v.proximal_radius, v.distal_radius, v.radius) {
            (Some(p), Some(d), _) => (p, d),
            (None, None, Some(r)) => (r, r),
            _ => {
                return Err(parse_error(format!(
                    "vessel {:?}: give either Rp and Rd or R0",
                    v.label
                )));
            }
        };
        degree[v.sn] += 1;
        degree[v.tn] += 1;
        vessels.push(Vessel::tapered(
            v.label.clone(),
            v.sn - 1,
            v.tn - 1,
            v.length,
            proximal,
            distal,
        ));
        if let Some(kind) = &v.outlet {
            let resistance = match (kind.as_str(), v.r1, v.r2) {
                ("wk3" | "wk2", Some(r1), r2) => r1 + r2.unwrap_or(0.0),
                ("reflection", ..) => 0.0,
                _ => {
                    return Err(parse_error(format!(
                        "vessel {:?}: outlet {kind:?} needs R1 (and optionally R2)",
                        v.label
                    )));
                }
            };
            outlets.push(Outlet {
                node: v.tn - 1,
                resistance,
                pressure: boundary.outlet_pressure,
            });
        }
    }
    let outlet_nodes: Vec<usize> = outlets.iter().map(|o| o.node + 1).collect();
    let free_ends: Vec<usize> = (1..=node_count)
        .filter(|&n| degree[n] == 1 && !outlet_nodes.contains(&n))
        .collect();
    let inlet_node = match free_ends.as_slice() {
        [n] => n - 1,
        [] => return Err(parse_error("no inlet: every free end is an outlet".into())),
        many => {
            return Err(parse_error(format!(
                "several free ends without an outlet ({many:?}): which is the inlet?"
            )));
        }
    };
    FlowNetwork::new(
        node_count,
        vessels,
        Inlet {
            node: inlet_node,
            condition: boundary.inlet,
        },
        outlets,
        blood,
    )
}
