//! The overload governor's fidelity levels: what each allows a physics step (the solver's
//! effort and a cap on the push speed).

use cathlab_physics::Effort;

/// The lowest fidelity the overload governor may set.
pub const MAX_FIDELITY_LEVEL: u8 = 3;

/// What a fidelity level allows a step: the physics' effort, a cap on the push speed (m/s),
/// and a description for the event.
pub fn fidelity_effort(level: u8) -> (Effort, Option<f64>, &'static str) {
    match level {
        0 => (Effort::FULL, None, "the scene's fidelity"),
        1 => (
            Effort {
                max_substep_depth: 1,
                max_detection_rounds: 2,
                ..Effort::FULL
            },
            None,
            "one sub-step halving, two detection rounds",
        ),
        2 => (
            Effort {
                max_substep_depth: 0,
                max_detection_rounds: 2,
                max_sweeps: 60,
                polish: true,
                refinement_scale: 2.0,
            },
            None,
            "no sub-steps, two detection rounds, 60 contact sweeps, refinement halved",
        ),
        _ => (
            Effort {
                max_substep_depth: 0,
                max_detection_rounds: 1,
                max_sweeps: 20,
                polish: false,
                refinement_scale: 4.0,
            },
            Some(0.03),
            "no sub-steps, one detection round, 20 contact sweeps, refinement quartered, \
             pushes slowed to 30 mm/s",
        ),
    }
}
