//! The queue for the server's replay places (a report's assessment, an on-demand replay):
//! reports go first, each caller has at most one replay queued or running, and a waiting
//! caller is served in turn rather than refused, so that no one holding a session token can
//! keep the places from a trainee's report.

use std::collections::VecDeque;
use std::sync::Arc;

use parking_lot::Mutex;
use tonic::Status;

/// Which kind of replay waits: a report (the trainee's own, or the one made at close) comes
/// before an on-demand replay.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Priority {
    /// A report to compute.
    Report,
    /// `ReplaySession`.
    Replay,
}

#[derive(Debug)]
struct Waiting {
    ticket: u64,
    priority: Priority,
    caller: String,
}

#[derive(Debug, Default)]
struct State {
    running: Vec<(u64, String)>,
    waiting: VecDeque<Waiting>,
    next: u64,
}

/// Places for replays, handed out by priority, then in order of arrival.
#[derive(Debug)]
pub struct ReplayQueue {
    places: usize,
    max_waiting: usize,
    state: Mutex<State>,
    changed: tokio::sync::Notify,
}

/// A place among the running replays, given back when dropped.
#[derive(Debug)]
pub struct Place {
    queue: Arc<ReplayQueue>,
    ticket: u64,
}

impl Drop for Place {
    fn drop(&mut self) {
        self.queue
            .state
            .lock()
            .running
            .retain(|(t, _)| *t != self.ticket);
        self.queue.changed.notify_waiters();
    }
}

/// A caller's turn in the queue, withdrawn if it goes away while waiting.
struct Turn<'a> {
    queue: &'a Arc<ReplayQueue>,
    ticket: u64,
    placed: bool,
}

impl Drop for Turn<'_> {
    fn drop(&mut self) {
        if !self.placed {
            self.queue
                .state
                .lock()
                .waiting
                .retain(|w| w.ticket != self.ticket);
            self.queue.changed.notify_waiters();
        }
    }
}

impl ReplayQueue {
    /// `places` replays at once; at most `max_waiting` on-demand replays wait (reports always
    /// wait their turn).
    pub fn new(places: usize, max_waiting: usize) -> Arc<Self> {
        Arc::new(Self {
            places: places.max(1),
            max_waiting,
            state: Mutex::new(State::default()),
            changed: tokio::sync::Notify::new(),
        })
    }

    /// Replays running and waiting now.
    pub fn counts(&self) -> (usize, usize) {
        let state = self.state.lock();
        (state.running.len(), state.waiting.len())
    }

    /// Waits for a place for `caller` (a token's hash, an account, an address). An on-demand
    /// replay is refused when its caller already has one queued or running, or when too many
    /// wait; a report is never refused.
    pub async fn enter(
        self: &Arc<Self>,
        priority: Priority,
        caller: &str,
    ) -> Result<Place, Status> {
        let ticket = {
            let mut state = self.state.lock();
            if priority == Priority::Replay {
                let mine = state.running.iter().any(|(_, c)| c == caller)
                    || state.waiting.iter().any(|w| w.caller == caller);
                if mine {
                    return Err(Status::resource_exhausted(
                        "this caller has a replay queued or running already; one at a time",
                    ));
                }
                let waiting = state
                    .waiting
                    .iter()
                    .filter(|w| w.priority == Priority::Replay)
                    .count();
                if waiting >= self.max_waiting {
                    return Err(Status::resource_exhausted(format!(
                        "{waiting} replays wait already; try again when one ends"
                    )));
                }
            }
            state.next += 1;
            let ticket = state.next;
            state.waiting.push_back(Waiting {
                ticket,
                priority,
                caller: caller.to_owned(),
            });
            ticket
        };
        let mut turn = Turn {
            queue: self,
            ticket,
            placed: false,
        };
        loop {
            let notified = self.changed.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            {
                let mut state = self.state.lock();
                // The first waiting of the best priority goes next.
                let next = state
                    .waiting
                    .iter()
                    .enumerate()
                    .min_by_key(|(i, w)| (w.priority, *i))
                    .map(|(_, w)| w.ticket);
                if state.running.len() < self.places && next == Some(ticket) {
                    state.waiting.retain(|w| w.ticket != ticket);
                    state.running.push((ticket, caller.to_owned()));
                    turn.placed = true;
                    return Ok(Place {
                        queue: self.clone(),
                        ticket,
                    });
                }
            }
            notified.await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[tokio::test]
    async fn reports_go_first_callers_get_one_each_and_leavers_free_their_turn() {
        let queue = ReplayQueue::new(1, 8);
        let running = queue.enter(Priority::Replay, "mallory").await.unwrap();
        // Mallory cannot queue a second.
        let again = queue.enter(Priority::Replay, "mallory").await.unwrap_err();
        assert_eq!(again.code(), tonic::Code::ResourceExhausted);
        // Bob waits for a replay, then a trainee's report arrives: the report goes first.
        let (q1, q2) = (queue.clone(), queue.clone());
        let bob = tokio::spawn(async move {
            let _p = q1.enter(Priority::Replay, "bob").await.unwrap();
            tokio::time::Instant::now()
        });
        tokio::time::sleep(Duration::from_millis(20)).await;
        let report = tokio::spawn(async move {
            let p = q2.enter(Priority::Report, "alice").await.unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
            drop(p);
            tokio::time::Instant::now()
        });
        tokio::time::sleep(Duration::from_millis(20)).await;
        assert_eq!(queue.counts(), (1, 2));
        drop(running);
        let (report_done, bob_placed) = (report.await.unwrap(), bob.await.unwrap());
        assert!(
            bob_placed >= report_done,
            "the report ran before Bob's replay"
        );
        // A caller that goes away while waiting leaves no turn behind.
        let blocker = queue.enter(Priority::Replay, "carol").await.unwrap();
        let q3 = queue.clone();
        let gone = tokio::spawn(async move { q3.enter(Priority::Replay, "dave").await });
        tokio::time::sleep(Duration::from_millis(20)).await;
        gone.abort();
        let _ = gone.await;
        assert_eq!(queue.counts(), (1, 0));
        drop(blocker);
        assert_eq!(queue.counts(), (0, 0));
    }
}
