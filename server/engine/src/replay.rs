//! Deterministic replay: a fresh world on the recorded scene, the recorded commands applied at
//! their recorded steps, and the state digest compared at every recorded checkpoint.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::assets::SceneAssets;
use crate::error::{EngineError, Result};
use crate::metrics::Metrics;
use crate::session::{Checkpoint, CommandRecord};
use crate::world::{Command, World};

/// What a replay found.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayOutcome {
    /// Steps re-run.
    pub steps: u64,
    /// The operator's commands applied (the overload governor's fidelity changes apply too,
    /// uncounted).
    pub commands: usize,
    /// Checkpoints compared.
    pub checkpoints: usize,
    /// Checkpoints whose digest matched.
    pub matched: usize,
    /// The last checkpoint's recorded digest.
    pub recorded_digest: u64,
    /// The replayed digest at that step.
    pub replayed_digest: u64,
    /// Metrics at the end of the replay.
    pub metrics: Metrics,
}

/// Replays `commands` (in ordinal order) on `assets` up to the last checkpoint (or the last
/// command's step when there is none), comparing digests at each checkpoint.
pub fn replay(
    assets: Arc<SceneAssets>,
    commands: &[CommandRecord],
    checkpoints: &[Checkpoint],
) -> Result<ReplayOutcome> {
    replay_until(assets, commands, checkpoints, &AtomicBool::new(false))
}

/// [`replay`], abandoned with [`EngineError::Cancelled`] once `cancel` is set (the caller went
/// away): checked every step.
pub fn replay_until(
    assets: Arc<SceneAssets>,
    commands: &[CommandRecord],
    checkpoints: &[Checkpoint],
    cancel: &AtomicBool,
) -> Result<ReplayOutcome> {
    let mut world = World::new(assets)?;
    let end = checkpoints
        .iter()
        .map(|c| c.step)
        .max()
        .unwrap_or_else(|| commands.iter().map(|c| c.step).max().unwrap_or(0));
    let mut next_command = 0;
    let mut next_checkpoint = 0;
    let mut outcome = ReplayOutcome {
        steps: 0,
        commands: 0,
        checkpoints: 0,
        matched: 0,
        recorded_digest: 0,
        replayed_digest: world.digest(),
        metrics: Metrics::default(),
    };
    let mut checkpoints: Vec<&Checkpoint> = checkpoints.iter().collect();
    checkpoints.sort_by_key(|c| c.step);
    while world.step_index() <= end {
        while next_checkpoint < checkpoints.len()
            && checkpoints[next_checkpoint].step == world.step_index()
        {
            let c = checkpoints[next_checkpoint];
            let digest = world.digest();
            outcome.checkpoints += 1;
            outcome.matched += usize::from(digest == c.digest);
            outcome.recorded_digest = c.digest;
            outcome.replayed_digest = digest;
            next_checkpoint += 1;
        }
        if world.step_index() == end {
            break;
        }
        while next_command < commands.len() && commands[next_command].step == world.step_index() {
            let c = &commands[next_command];
            // A command that applied live applies again; report it if not.
            world.apply(c.seq, &c.command)?;
            outcome.commands += usize::from(!matches!(c.command, Command::Fidelity(_)));
            next_command += 1;
        }
        if cancel.load(Ordering::Relaxed) {
            return Err(EngineError::Cancelled(format!(
                "replay abandoned at step {} of {end}",
                world.step_index()
            )));
        }
        world.step()?;
        world.take_events();
    }
    outcome.steps = world.step_index();
    outcome.metrics = *world.metrics();
    Ok(outcome)
}
