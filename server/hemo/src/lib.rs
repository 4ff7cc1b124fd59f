//! Blood flow and contrast agent for cathlab: steady Poiseuille flow on the vessel network
//! (one sparse Cholesky factorization per anatomy, cheap re-solves, catheter narrowing and tip
//! injection), and iodine contrast advected along the vessels by a conservative flux-limited
//! scheme with junction mixing and washout.
//!
//! Units: SI (m, Pa, s, m³/s, Pa·s/m³); iodine concentration in mg/mL (= kg/m³), iodine mass
//! in kg. [`network::MMHG`] and [`network::ML_PER_S`] convert clinical units.

pub mod clot;
pub mod collaterals;
pub mod contrast;
pub mod error;
pub mod flow;
pub mod graph;
pub mod network;
pub mod openbf;
pub mod reperfusion;
pub mod scenarios;

pub use clot::{ClotComposition, Occlusion};
pub use collaterals::{CollateralStatus, with_pial_collaterals};
pub use contrast::{Contrast, ContrastSegment, ContrastSettings, Limiter};
pub use error::{HemoError, Result};
pub use flow::{FlowSolution, FlowSolver, Injection, Narrowing, VesselFlow};
pub use graph::{GraphFlowSettings, TerminalResistance, network_from_graph};
pub use network::{
    Blood, FlowNetwork, Inlet, InletCondition, ML_PER_MIN, ML_PER_S, MMHG, Outlet, Station, Vessel,
};
pub use openbf::{OpenBfBoundary, parse_openbf, read_openbf};
