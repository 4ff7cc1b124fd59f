//! Vascular anatomy for cathlab: the vessel graph, procedural and analytic phantoms, import
//! and export of real anatomy, watertight lumen surfaces and fast lumen (wall) queries.
//!
//! Units: metres throughout; coordinates in the patient LPS frame (x to the patient's left,
//! y posterior, z superior), as 3D Slicer and DICOM use. Files in millimetres are converted on
//! import.

pub mod capping;
pub mod centerline;
pub mod components;
pub mod decimate;
pub mod error;
pub mod field_wall;
pub mod glam_conv;
pub mod graph;
pub mod implicit;
pub mod io;
pub mod lumen;
pub mod mesh;
pub mod phantom;
pub mod real;
pub mod stored;
pub mod surface;
pub mod tubes;
pub mod wall_query;

pub use error::{AnatomyError, Result};
pub use graph::{Branch, BranchSpec, GraphLocation, Side, VesselGraph, VesselKind, VesselPath};
pub use lumen::{Lumen, WallQuery};
pub use mesh::{MeshTopology, TriangleMesh};
