//! The overload governor's fidelity levels: what each allows a physics step (the solver's
//! effort and a cap on the push speed).

use cathlab_physics::{Effort, MAX_SUBSTEP_DEPTH};

/// The lowest fidelity the overload governor may set.
pub const MAX_FIDELITY_LEVEL: u8 = 3;

/// The penetration (m) past which the lower levels halve a step: with fewer detection rounds
/// and sweeps, the full-fidelity threshold (0.02 mm) would halve most steps of a push held
/// against the wall, and without halvings nodes went 0.08-0.31 mm past it. Under the 0.05 mm
/// every level must hold (`cargo bench -p cathlab-engine --bench stress`).
const DEEP_STEP_M: f64 = 0.035e-3;

/// What a fidelity level allows a step: the physics' effort, a cap on the push speed (m/s),
/// and a description for the event.
pub fn fidelity_effort(level: u8) -> (Effort, Option<f64>, &'static str) {
    match level {
        0 => (Effort::FULL, None, "the scene's fidelity"),
        1 => (
            Effort {
                max_detection_rounds: 3,
                min_substep_penetration_m: DEEP_STEP_M,
                ..Effort::FULL
            },
            None,
            "sub-steps only past 0.035 mm, three detection rounds",
        ),
        2 => (
            Effort {
                max_substep_depth: MAX_SUBSTEP_DEPTH,
                max_detection_rounds: 3,
                max_sweeps: 60,
                polish: true,
                refinement_scale: 2.0,
                min_substep_penetration_m: DEEP_STEP_M,
            },
            None,
            "sub-steps only past 0.035 mm, three detection rounds, 60 contact sweeps, \
             refinement halved",
        ),
        _ => (
            Effort {
                max_substep_depth: MAX_SUBSTEP_DEPTH,
                max_detection_rounds: 1,
                max_sweeps: 20,
                polish: false,
                refinement_scale: 4.0,
                min_substep_penetration_m: DEEP_STEP_M,
            },
            Some(0.03),
            "sub-steps only past 0.035 mm, one detection round, 20 contact sweeps, \
             refinement quartered, pushes slowed to 30 mm/s",
        ),
    }
}
