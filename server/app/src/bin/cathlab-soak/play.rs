//! A random client's play: each turn an action drawn by weight (within its budget for the
//! round) and run, a client error counted; and its end.

use std::sync::atomic::Ordering;

use rand::RngExt;

use crate::actions::Action;
use crate::client::Chaos;

impl Chaos {
    pub(crate) async fn act(&mut self) {
        self.tally.actions.fetch_add(1, Ordering::Relaxed);
        let total: u32 = self.actions.iter().map(|a| a.weight()).sum();
        let mut roll = self.rng.random_range(0..total);
        let mut action = self.actions[0];
        for &a in &self.actions {
            if roll < a.weight() {
                action = a;
                break;
            }
            roll -= a.weight();
        }
        let acted = match action {
            Action::Create => self.create().await,
            Action::Close => self.close().await,
            Action::ValidCommand => self.valid_command().await,
            Action::InvalidCommand => self.invalid_command().await,
            Action::Frames => self.frames().await,
            Action::Control => self.control().await,
            Action::Watch => self.watch().await,
            Action::Query => self.query().await,
            Action::HostileScene => self.hostile_scene().await,
            Action::Garbage => self.garbage().await,
            Action::Replay => self.replay().await,
            _ if !self.budget(action) => Ok(()),
            Action::H2Flood => self.h2_flood(),
            Action::StalledBody => self.stalled_body(),
            Action::BodyNeverStarts => self.body_never_starts(),
            Action::IdleSockets => self.idle_sockets(),
            Action::BombFile => self.bomb_file().await,
        };
        if let Err(e) = acted {
            // Transport failures of abandoned streams are part of the game; record them.
            self.tally
                .answers
                .lock()
                .entry(("client error", format!("{e:#}").chars().take(60).collect()))
                .and_modify(|n| *n += 1)
                .or_insert(1);
        }
    }

    /// Closes this client's session and waits for its stalled streams to be dropped.
    pub(crate) async fn finish(mut self) {
        let _ = self.close().await;
        for s in self.stalls.drain(..) {
            let _ = s.await;
        }
    }
}
