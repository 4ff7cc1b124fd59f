//! Phantoms: analytic shapes with known answers for tests, and seeded, parameterised
//! neurovascular anatomy from the aortic arch to the circle of Willis.

pub mod analytic;
pub mod neuro;

pub use analytic::{straight_tube, torus_segment, y_bifurcation};
pub use neuro::{ArchType, NeuroPhantomParams, neuro_phantom};
