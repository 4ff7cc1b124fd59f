//! The scripted operator of the stroke case, phase by phase, for tests and benchmarks: it
//! drives a whole world through recorded commands.

use crate::error::{EngineError, Result};
use crate::scene::catalogue;
use crate::world::{Command, Drive, World};

/// Most steps the scripted crossing may take: 110 s at 500 Hz. From the femoral access the
/// crossing took 65 s on the neuro phantom's triangulated wall and takes 78 s on its implicit
/// wall (80 s was the limit before).
pub const CROSS_STEPS: usize = 55_000;
/// The scripted operator of the stroke case, phase by phase, for tests and benchmarks: every
/// phase applies recorded commands (numbered on from `seq`) and steps the world until it is
/// done or its step budget runs out (false).
#[derive(Debug, Clone)]
pub struct StrokeScript {
    /// The next command's sequence number.
    pub seq: u64,
    /// Inserted length at which a tip reaches the start of the route's branch `branch` (m).
    pub branch_inserted_m: f64,
}

impl StrokeScript {
    /// The script for `world`'s scene, `branch` the occluded branch on its route.
    pub fn new(world: &World, branch: &str, first_seq: u64) -> Result<Self> {
        let assets = world.assets();
        let graph = &assets.anatomy.graph;
        let mut along = 0.0;
        let mut found = false;
        for leg in &assets.route.legs {
            if graph.branches[leg.branch].name == branch {
                found = true;
                break;
            }
            along += (leg.to_arc - leg.from_arc).abs();
        }
        if !found {
            return Err(EngineError::FailedPrecondition(format!(
                "{branch} is not on the scene's route"
            )));
        }
        Ok(Self {
            seq: first_seq,
            branch_inserted_m: along - assets.spec.start.along_route_mm * 1e-3,
        })
    }

    /// Applies `command` as the next recorded one.
    pub fn apply(&mut self, world: &mut World, command: Command) -> Result<()> {
        self.seq += 1;
        world.apply(self.seq, &command)
    }

    /// Steps until `done` or `steps` run out.
    pub fn run_until(
        world: &mut World,
        steps: usize,
        done: impl Fn(&World) -> bool,
    ) -> Result<bool> {
        for _ in 0..steps {
            if done(world) {
                return Ok(true);
            }
            world.step()?;
        }
        Ok(done(world))
    }

    /// The scene's two-hand operator crosses to the target (within `CROSS_STEPS`); then
    /// every hand holds.
    pub fn cross(&mut self, world: &mut World) -> Result<bool> {
        let reached = world.follow_two_hands(CROSS_STEPS, self.seq + 1)?;
        self.seq += 1_000_000;
        for i in 0..world.strand().len() as u32 {
            self.apply(
                world,
                Command::Instrument {
                    index: i,
                    drive: Drive::PushVelocity(0.0),
                },
            )?;
        }
        Ok(reached.is_some())
    }

    /// Instrument `index` moved to `inserted_m` (m).
    pub fn move_to(
        &mut self,
        world: &mut World,
        index: u32,
        inserted_m: f64,
        steps: usize,
    ) -> Result<bool> {
        self.apply(
            world,
            Command::Instrument {
                index,
                drive: Drive::PushTarget(inserted_m),
            },
        )?;
        Self::run_until(world, steps, |w| {
            (w.strand().inserted_m(index as usize) - inserted_m).abs() < 0.3e-3
        })
    }

    /// The innermost instrument exchanged for catalogue entry `id`, then pushed to the tip
    /// of the one around it.
    pub fn bring_in(&mut self, world: &mut World, id: &str) -> Result<bool> {
        let entries = catalogue().entries();
        let Some(k) = entries.iter().position(|e| e.id == id) else {
            return Err(EngineError::FailedPrecondition(format!(
                "{id} is not in the catalogue"
            )));
        };
        let name = entries[k].device.name.clone();
        let inner = world.strand().len() - 1;
        self.apply(
            world,
            Command::Exchange {
                index: inner as u32,
                catalogue: k as u32,
            },
        )?;
        if !Self::run_until(world, 20_000, |w| {
            w.strand().device(inner).is_some_and(|d| d.name == name)
        })? {
            return Ok(false);
        }
        let tip = world.strand().inserted_m(inner - 1);
        self.move_to(world, inner as u32, tip, 20_000)
    }
}
