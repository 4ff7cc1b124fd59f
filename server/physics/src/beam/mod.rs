//! A discretised device: node positions and quaternion frames, the incremental
//! (co-rotational) Timoshenko formulation, assembly, and the paper and converged step modes.
//!
//! **Kinematics.** Node `i` has a position `x_i` (m) and a unit quaternion `q_i` mapping its
//! material frame (x along the device) to the world. For each element the rest configuration
//! stores the chord length `l0` and, per end node, the constant offset `O_i = R_i0ᵀ R_e0`
//! between the node frame and the element frame at rest, so a curved rest shape carries no
//! stress. In the current configuration the element frame `R_e` has its x axis along the
//! chord and its y/z axes from the mid-rotation of `R_1 O_1` and `R_2 O_2`; the local
//! deformation ū − ū0 is then (chord − l0, θ̄1, θ̄2) with θ̄_i = log(R_eᵀ R_i O_i).
//! This is the paper's Eq. (1) measured in a chord-aligned frame rather than the first node's
//! frame: it keeps every element in exact moment equilibrium in its current shape, which the
//! first-node frame does not (its error would make the scheme first-order accurate).
//!
//! **Step.** The local stiffness K̄e is rotated by Λ = diag(R_e, R_e, R_e, R_e) into
//! `K_e = Λᵀ K̄e Λ` (Eq. 3) and assembled; the elastic force `−γ Λᵀ K̄e (ū − ū0)` (Eq. 5,
//! with the sign that restores the rest shape) is added to the external forces, and one linear
//! solve (the substructure solver) gives the increments, applied as x += Δx and
//! q ← exp(Δθ) q. The *paper mode* does this once per step; the *converged mode* repeats it
//! (γ = 1) until the increments fall below a tolerance, which is a quasi-Newton solve of
//! static equilibrium. Optionally the tangent includes the geometric stiffness of the current
//! axial force, which keeps the iteration contractive under large tension.
//!
//! Note that with γ < 1 the paper's step leaves the static equilibrium at f_int = f_ext/γ, so
//! γ = 1 (the default) is the only value that reproduces applied loads exactly.
//!
//! The module is cut by concept: [`ElementSpec`] and the per-element rest data and forces
//! (`element.rs`), the frame and rest-arc geometry (`kinematics.rs`), the solver options
//! (`settings.rs`) and step reports (`report.rs`), the [`BeamModel`] with its construction,
//! loads and base drive (`model.rs`), changes of its discretization (`remesh.rs`), the
//! assembly of forces and tangent (`assembly.rs`), the step (`step.rs`) and the step with
//! contacts (`contact_step.rs`).

mod assembly;
mod contact_step;
mod element;
mod kinematics;
mod model;
mod remesh;
mod report;
mod settings;
mod step;

pub use element::ElementSpec;
pub(crate) use kinematics::hermite_point;
pub use kinematics::{minimal_rotation, rotation_vector};
pub use model::{BeamModel, BeamSnapshot};
pub use report::{ContactStep, StepReport};
pub use settings::{MAX_TRANSLATION_INCREMENT_LENGTHS, SolverSettings, StepMode, ViscousDrag};
