//! Coaxial device stacks: one to four instruments (a guide or sheath, a catheter, a
//! microcatheter, a wire), outermost first, each pushed, pulled and twisted at the entry point
//! on its own, simulated in merged mode as one composite beam.
//!
//! Every instrument `i` is placed by its inserted length ℓᵢ: how far its tip lies beyond the
//! entry point along the path (negative while it is still proximal of the entry inside the
//! instrument around it). The simulated strand runs from the entry (path coordinate σ = 0) to
//! the leading tip (σ = max ℓᵢ); at σ the instruments with ℓᵢ > σ are present, the material
//! point of instrument `i` there being Lᵢ − ℓᵢ + σ from its proximal end.
//!
//! **Merged mode.** Where instruments overlap they bend together, so the strand is one chain
//! of nodes and the beam model, its O(N) solver and the O(M + N) contact solver apply
//! unchanged. Each element is a composite: EA, EI, GJ and κGA summed over the instruments
//! present on it; its rest curvature the stiffness-weighted blend of theirs, each turned by
//! its instrument's twist relative to the strand's (the outermost instrument's). Nodes stay
//! on the path where the strand already lies (a sliding instrument moves *through* them),
//! every instrument tip inside the strand is a node, and the leading instrument's free shaped
//! part is carried rigidly as it advances (follow the leader without straining a curved tip,
//! as in [`crate::navigation`]). Spacing is that of the outermost instrument present (fine
//! near its tip), refined where the strand bends or touches the wall. The outermost instrument
//! present at a point takes the wall contact there with its radius and wall friction.
//!
//! The module is cut by concept: the instruments and their ranges (`instrument.rs`), merged
//! mode's composite elements (`composite.rs`), the [`Stack`]'s data, construction and
//! accessors (`state.rs`), where the instruments are (`pose.rs`), the loads at their ends
//! (`loads.rs`), inner instruments sliding with their own axial strain (`slide.rs`), loading
//! and exchanging instruments (`exchange.rs`), the step (`step.rs`), the merged strand's nodes
//! as the instruments move (`strand.rs`) and nested mode (`nested.rs`).

mod composite;
mod exchange;
mod instrument;
mod loads;
mod nested;
mod pose;
mod slide;
mod state;
mod step;
mod strand;
#[cfg(test)]
mod tests;

pub use instrument::{InstrumentSpec, MAX_INSTRUMENTS, check_fit, inserted_range};
pub use loads::ProximalReaction;
pub use pose::InstrumentView;
pub use state::{Coupling, Stack};
pub use step::StackReport;
