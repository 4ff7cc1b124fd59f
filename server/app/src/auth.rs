//! Checking bearer secrets: constant-time comparison, and throttling of addresses that guess
//! wrong (a wrong instructor key, or a token that belongs to no session).

use std::collections::HashMap;
use std::net::IpAddr;
use std::time::{Duration, Instant};

use parking_lot::Mutex;
use subtle::ConstantTimeEq;
use tonic::Status;

/// Whether two secrets are equal, in time that does not depend on where they differ.
pub fn same_secret(a: &str, b: &str) -> bool {
    a.len() == b.len() && bool::from(a.as_bytes().ct_eq(b.as_bytes()))
}

/// Failed guesses from one address in the current window.
#[derive(Debug, Clone, Copy)]
struct Failures {
    count: u32,
    since: Instant,
}

/// Counts failed secrets per address; past the limit in a window, the address is refused
/// (RESOURCE_EXHAUSTED) until the window ends, whatever it sends.
#[derive(Debug)]
pub struct Throttle {
    per_window: u32,
    window: Duration,
    failures: Mutex<HashMap<IpAddr, Failures>>,
}

impl Throttle {
    /// At most `per_window` failed guesses per `window` from one address.
    pub fn new(per_window: u32, window: Duration) -> Self {
        Self {
            per_window,
            window,
            failures: Mutex::new(HashMap::new()),
        }
    }

    /// Refuses an address that used up its guesses, saying when it may try again.
    pub fn check(&self, peer: IpAddr) -> Result<(), Status> {
        let mut failures = self.failures.lock();
        let Some(f) = failures.get(&peer).copied() else {
            return Ok(());
        };
        let elapsed = f.since.elapsed();
        if elapsed >= self.window {
            failures.remove(&peer);
            return Ok(());
        }
        if f.count >= self.per_window {
            return Err(Status::resource_exhausted(format!(
                "too many wrong keys or tokens from this address; retry in {} s",
                (self.window - elapsed).as_secs() + 1
            )));
        }
        Ok(())
    }

    /// Counts (and logs) a wrong key or token from `peer`.
    pub fn failed(&self, peer: IpAddr, what: &str) {
        let mut failures = self.failures.lock();
        // Forget addresses whose window ended, so that the map stays small.
        if failures.len() > 10_000 {
            let window = self.window;
            failures.retain(|_, f| f.since.elapsed() < window);
        }
        let f = failures.entry(peer).or_insert(Failures {
            count: 0,
            since: Instant::now(),
        });
        if f.since.elapsed() >= self.window {
            *f = Failures {
                count: 0,
                since: Instant::now(),
            };
        }
        f.count += 1;
        if f.count < self.per_window {
            tracing::warn!(%peer, failures = f.count, "{what}");
        } else if f.count == self.per_window {
            tracing::warn!(
                %peer,
                failures = f.count,
                "{what}; this address is refused for the rest of the {} s window",
                self.window.as_secs()
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn secrets_compare_whole_and_addresses_are_refused_past_their_guesses() {
        assert!(same_secret("abc", "abc"));
        assert!(!same_secret("abc", "abd") && !same_secret("abc", "abcd") && !same_secret("", "a"));
        let throttle = Throttle::new(3, Duration::from_millis(200));
        let (a, b): (IpAddr, IpAddr) = ("10.0.0.1".parse().unwrap(), "10.0.0.2".parse().unwrap());
        for _ in 0..3 {
            assert!(throttle.check(a).is_ok());
            throttle.failed(a, "wrong key");
        }
        let refused = throttle.check(a).unwrap_err();
        assert_eq!(refused.code(), tonic::Code::ResourceExhausted);
        assert!(throttle.check(b).is_ok(), "another address is not affected");
        std::thread::sleep(Duration::from_millis(250));
        assert!(throttle.check(a).is_ok(), "the window ended");
    }
}
