//! The tally of what the random clients saw: answers by action and status code, the first
//! message of each, and the faults (answers the server must not give).

use std::collections::BTreeMap;
use std::sync::atomic::AtomicU64;

use parking_lot::Mutex;

/// The tally's rows of the connection and file attacks, printed after each round.
pub(crate) const ATTACK_ROWS: [&str; 7] = [
    "h2 flood",
    "h2 flood stream",
    "stalled body",
    "body never starts",
    "body never starts h2",
    "idle socket",
    "bomb file",
];

/// What the random clients saw: answers by kind of action and status code.
#[derive(Default)]
pub(crate) struct Tally {
    pub(crate) answers: Mutex<BTreeMap<(&'static str, String), u64>>,
    /// The first message seen for each (action, code).
    pub(crate) examples: Mutex<BTreeMap<(&'static str, String), String>>,
    /// INTERNAL or UNKNOWN answers, and other answers the server must not give, with what
    /// was asked.
    pub(crate) faults: Mutex<Vec<String>>,
    pub(crate) actions: AtomicU64,
}

impl Tally {
    /// Counts one outcome that is not a tonic status (a socket closed, a stream reset).
    pub(crate) fn row(&self, action: &'static str, outcome: impl Into<String>, n: u64) {
        if n > 0 {
            *self
                .answers
                .lock()
                .entry((action, outcome.into()))
                .or_default() += n;
        }
    }

    /// An answer the server must not give.
    pub(crate) fn wrong(&self, what: String) {
        self.faults.lock().push(what);
    }

    pub(crate) fn answer<T>(&self, action: &'static str, result: &Result<T, tonic::Status>) {
        let code = match result {
            Ok(_) => "OK".to_owned(),
            Err(s) => format!("{:?}", s.code()),
        };
        if let Err(s) = result
            && matches!(s.code(), tonic::Code::Internal | tonic::Code::Unknown)
        {
            self.faults
                .lock()
                .push(format!("{action}: {:?} {}", s.code(), s.message()));
        }
        if let Err(s) = result {
            self.examples
                .lock()
                .entry((action, code.clone()))
                .or_insert_with(|| s.message().chars().take(80).collect());
        }
        *self.answers.lock().entry((action, code)).or_default() += 1;
    }
}
