//! Solver options of a beam model: the step mode (paper or converged), geometric stiffness,
//! viscous drag, step-size limits and sub-step splitting, and the divergence limit on a
//! translation increment.

/// How a step is computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepMode {
    /// The paper's incremental method: one linear solve per step with restoring-force factor
    /// γ ∈ (0, 1].
    Incremental {
        /// γ of Eq. (5).
        gamma: f64,
    },
    /// Repeat the linearisation within the step until the largest translation increment is
    /// below `tolerance`·(device length) and the largest rotation increment below
    /// `tolerance` rad, or `max_iterations` is reached.
    Converged {
        /// Relative tolerance (dimensionless).
        tolerance: f64,
        /// Iteration cap per step.
        max_iterations: usize,
    },
}

impl StepMode {
    /// The paper mode with γ = 1.
    pub const PAPER: StepMode = StepMode::Incremental { gamma: 1.0 };
    /// Converged mode to 1e-8 relative increments, at most 100 iterations. (Slender wires,
    /// L/r ~ 10⁴, have a round-off floor near 1e-9·L in their increments.)
    pub const CONVERGED: StepMode = StepMode::Converged {
        tolerance: 1e-8,
        max_iterations: 100,
    };
}

/// Solver options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverSettings {
    /// Paper or converged step.
    pub mode: StepMode,
    /// Add the geometric (axial-force) stiffness to the tangent.
    pub geometric_stiffness: bool,
    /// Compute the flexibility blocks (diagonal of K⁻¹ and couplings) each step.
    pub compute_flexibility: bool,
    /// Viscous drag of the surrounding fluid, which turns each quasi-static step into a step
    /// of overdamped motion: `(K + C/Δt) Δu = f_ext − f_int`. It leaves every equilibrium
    /// unchanged (Δu = 0 there) and keeps steps bounded where K is near-singular (buckling).
    pub drag: Option<ViscousDrag>,
    /// Largest node translation (m) and rotation (rad) of the free motion in a step with
    /// contacts; a larger free increment is scaled down as a whole before the contacts are
    /// solved, so a violent event such as buckling proceeds over several steps.
    pub max_step_increment: Option<(f64, f64)>,
    /// With a step cap, judge the motion the last step's contact forces leave, not the whole
    /// free motion (false by default). The free motion is solved without the wall, so where a
    /// device is pressed on it the free motion is mostly the springback the wall holds; scaled
    /// to the cap with it, the contact forces the solve finds are the cap's share of the
    /// wall's (a wire pushed round a ring: 0.035 N of friction against 1.19 N, and 21.6 N at
    /// the hand, the rest strain nothing balances). With it, the free motion is taken with the
    /// last forces held (`K⁻¹(r + Jᵀλ_last)`), only that is scaled to the cap, and the contact
    /// solve finds the whole forces from there; where the motion it leaves is still past the
    /// cap (a contact released, a loop let go), the step is solved again the old way.
    pub cap_with_held_contacts: bool,
    /// Include the geometric stiffness of compressed elements too. Off, only tension stiffens
    /// the tangent: the tangent stays positive definite however hard the device is pushed, and
    /// the step relaxes into a buckled shape instead of following an unstable straight branch
    /// (see the buckling test).
    pub geometric_stiffness_in_compression: bool,
    /// Converged mode only: when a step trips an increment guard (a rotation larger than π, a
    /// translation larger than [`MAX_TRANSLATION_INCREMENT_LENGTHS`] device lengths) or does
    /// not converge, it is redone as sub-steps that apply the change of loads and base pose
    /// since the last step in fractions, halving the fraction up to this many times before
    /// the step is reported as diverged (0: never split).
    pub max_substep_halvings: usize,
}

/// Viscous drag per unit length on the device (Levenberg–Marquardt regularization with a
/// physical meaning).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViscousDrag {
    /// Drag force per unit length per unit velocity (N·s/m²); rotations get the drag of a rod
    /// segment turning about its centre, c·ℓ³/12 per node.
    pub per_length_n_s_per_m2: f64,
    /// The time step it acts over (s).
    pub time_step_s: f64,
}

impl Default for SolverSettings {
    fn default() -> Self {
        Self {
            mode: StepMode::PAPER,
            geometric_stiffness: true,
            compute_flexibility: true,
            drag: None,
            max_step_increment: None,
            cap_with_held_contacts: false,
            geometric_stiffness_in_compression: true,
            max_substep_halvings: 10,
        }
    }
}

/// A single linear solve that moves a node by more than this many device lengths is taken
/// as divergence: no quasi-static load a device can bear does that.
pub const MAX_TRANSLATION_INCREMENT_LENGTHS: f64 = 10.0;
