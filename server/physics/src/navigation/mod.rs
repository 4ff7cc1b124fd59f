//! Navigation: a device pushed, pulled and twisted at an entry point (the sheath) into a
//! vessel, of which only the inserted length is simulated. Nodes are material points of the
//! device, spaced finely near the tip and coarsely along the shaft; as the device slides in,
//! the element next to the entry point grows and is split when it is 1.5 element lengths
//! long, and as it slides out it shrinks and is merged when it is half an element long — the
//! new node is placed on the current chord, so the shape never jumps. Each step: proximal
//! control (clamped speeds), collision detection at the predicted configuration, the beam solve
//! with Gauss–Seidel contact and Coulomb friction, and the proximal reaction on request.
//!
//! The module is cut by concept: the settings and work caps (`settings.rs`), the operator's
//! commands (`command.rs`), the [`Navigation`]'s data, construction and accessors
//! (`state.rs`), the step (`step.rs`), sleep at rest (`sleep.rs`), and collision points with
//! contact detection (`detection.rs`, shared with coaxial stacks).

mod command;
mod detection;
mod settings;
mod sleep;
mod state;
mod step;

pub use command::{Command, Insertion, Twist};
pub(crate) use detection::{
    ClearanceCache, Sample, detect, material_of, push_element_samples, warm_start,
};
pub(crate) use settings::solver_settings;
pub(crate) use settings::spacing;
pub use settings::{Effort, MAX_SUBSTEP_DEPTH, NavigationSettings, Refinement};
pub use sleep::Sleep;
pub(crate) use sleep::{Stillness, contact_counts};
pub use state::Navigation;
pub use step::NavigationReport;
pub(crate) use step::{STILL_M, STILL_RAD};
