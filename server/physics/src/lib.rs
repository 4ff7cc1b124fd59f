//! cathlab-physics: guidewire and catheter mechanics for interventional-radiology simulation.
//!
//! Devices are chains of 3D Timoshenko beams (after Cotin et al., MICCAI 2005) whose frames
//! are updated every step from the previous solution; each step is one block-tridiagonal
//! linear solve done in O(N) by substructure analysis, which also yields the flexibility
//! blocks that contact response needs. Contacts with the vessel wall (Signorini with Coulomb
//! friction) are solved by projected Gauss–Seidel through those blocks with an active-set
//! polish (or semismooth Newton on the Delassus matrix they give), and a navigation simulates
//! only the inserted length under push, pull and twist, skipping its steps once at rest.
//! Plain synchronous, deterministic library: SI units, f64.

pub mod autopilot;
pub mod beam;
pub mod catalogue;
pub mod contact;
pub mod coupled;
pub mod device;
pub mod elastica;
pub mod element;
pub mod error;
pub mod navigation;
pub mod scenarios;
pub mod section;
pub mod stack;
pub mod substructure;
pub mod two_hands;
pub mod wall;

pub use beam::{
    BeamModel, ContactStep, ElementSpec, SolverSettings, StepMode, StepReport, ViscousDrag,
};
pub use catalogue::{Catalogue, CatalogueEntry, DeviceKind, Marker, StentSpec};
pub use contact::{Contact, ContactMethod, ContactResponse, ContactSettings};
pub use device::{Device, RestArc, RestShape, Section, presets};
pub use error::{DivergenceCheck, PhysicsError, Result};
pub use navigation::{
    Command, Effort, Insertion, Navigation, NavigationReport, NavigationSettings, Refinement,
    Sleep, Twist,
};
pub use section::{BeamProperties, CircularSection, Material};
pub use stack::{Coupling, InstrumentSpec, InstrumentView, ProximalReaction, Stack, StackReport};
pub use substructure::{BlockTridiagonal, Flexibility, Substructure};
pub use wall::{CappedTube, FreeSpace, RingTube, Wall, WallProbe};
