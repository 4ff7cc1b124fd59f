//! The overload governor's fidelity levels: what each allows a physics step (the solver's
//! effort and a cap on the push speed).

use cathlab_physics::Effort;

/// The lowest fidelity the overload governor may set.
pub const MAX_FIDELITY_LEVEL: u8 = 3;

/// The penetration (m) past which level 1 halves a step, once (full fidelity: 0.02 mm, up to
/// three times): with fewer detection rounds the full threshold would halve most steps of a
/// push held against the wall, and each level must cost less than the one above it. Levels 2
/// and 3 do not halve at all (a halved step costs two or more solves, which is what an
/// overloaded server cannot give: with halvings past this threshold there, the
/// stroke scene under `cathlab-load` missed 658 steps of 5,000 with one session); they move
/// what still penetrates out along the wall's normal instead. Below the 0.05 mm every level
/// must hold (`cargo bench -p cathlab-engine --bench stress`).
const DEEP_STEP_M: f64 = 0.035e-3;

/// What a fidelity level allows a step: the physics' effort, a cap on the push speed (m/s),
/// and a description for the event.
pub fn fidelity_effort(level: u8) -> (Effort, Option<f64>, &'static str) {
    match level {
        0 => (Effort::FULL, None, "the scene's fidelity"),
        1 => (
            Effort {
                max_substep_depth: 1,
                max_detection_rounds: 2,
                min_substep_penetration_m: DEEP_STEP_M,
                project_penetration: true,
                ..Effort::FULL
            },
            None,
            "one sub-step halving, only past 0.035 mm, two detection rounds, penetration \
             projected out",
        ),
        2 => (
            Effort {
                max_substep_depth: 0,
                max_detection_rounds: 2,
                max_sweeps: 60,
                polish: true,
                refinement_scale: 2.0,
                min_substep_penetration_m: 0.0,
                project_penetration: true,
            },
            None,
            "no sub-steps, two detection rounds, 60 contact sweeps, refinement halved, \
             penetration projected out",
        ),
        _ => (
            Effort {
                max_substep_depth: 0,
                max_detection_rounds: 1,
                max_sweeps: 20,
                polish: false,
                refinement_scale: 4.0,
                min_substep_penetration_m: 0.0,
                project_penetration: true,
            },
            Some(0.03),
            "no sub-steps, one detection round, 20 contact sweeps, refinement quartered, \
             penetration projected out, pushes slowed to 30 mm/s",
        ),
    }
}
