//! The overload governor's fidelity levels: what each allows a physics step (the solver's
//! effort and a cap on the push speed).

use cathlab_physics::Effort;
use cathlab_physics::navigation::MAX_SUBSTEP_DEPTH;

/// The lowest fidelity the overload governor may set.
pub const MAX_FIDELITY_LEVEL: u8 = 3;

/// What a fidelity level allows a step: the physics' effort, a cap on the push speed (m/s),
/// and a description for the event.
pub fn fidelity_effort(level: u8) -> (Effort, Option<f64>, &'static str) {
    match level {
        0 => (Effort::FULL, None, "the scene's fidelity"),
        // Every level keeps the step's halvings and two detection rounds: a step that still
        // penetrates the wall is taken again in halves, which costs only the steps that need
        // it. (With one halving or none, random-operator runs held at levels 2 and 3 left
        // nodes 0.08–0.18 mm past the wall; a coaxial run at level 2 needed all three
        // halvings to stay within 0.05 mm.)
        1 => (
            Effort {
                max_detection_rounds: 2,
                ..Effort::FULL
            },
            None,
            "two detection rounds",
        ),
        2 => (
            Effort {
                max_substep_depth: MAX_SUBSTEP_DEPTH,
                max_detection_rounds: 2,
                max_sweeps: 60,
                polish: true,
                refinement_scale: 2.0,
            },
            None,
            "two detection rounds, 60 contact sweeps, refinement halved",
        ),
        _ => (
            Effort {
                max_substep_depth: MAX_SUBSTEP_DEPTH,
                max_detection_rounds: 2,
                max_sweeps: 20,
                polish: false,
                refinement_scale: 4.0,
            },
            Some(0.03),
            "two detection rounds, 20 contact sweeps, refinement quartered, pushes slowed to \
             30 mm/s",
        ),
    }
}
