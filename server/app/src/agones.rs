//! This server as an Agones GameServer: Ready once its scenes are warm, a Health ping every
//! [`HEALTH_PERIOD`] while its physics loops keep time, Allocated while it runs sessions
//! (protected from scale-down) and Ready again when the last one ends, the `sessions`
//! counter (count of capacity) whenever it changes, Shutdown once it has closed its sessions
//! at exit.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use cathlab_agones::Sdk;
use cathlab_engine::Engine;

use crate::fleet::AdvertisedAddress;

/// How often a health ping is sent (Agones' default `health.periodSeconds` is 5 s).
pub const HEALTH_PERIOD: Duration = Duration::from_secs(2);

/// How often the session count is looked at (an allocation follows a new session within it).
const WATCH_PERIOD: Duration = Duration::from_millis(250);

/// The counter the Fleet declares for sessions (`spec.template.spec.counters.sessions`).
pub const SESSIONS_COUNTER: &str = "sessions";

/// The least fraction of its steps a running session must have run over a health period for
/// the server to count as keeping time (a wedged or starved physics loop runs none; the
/// overload governor keeps a merely busy one well above this).
pub const MIN_STEP_FRACTION: f64 = 0.5;

/// Connects to the sidecar (`AGONES_SDK_GRPC_PORT`, default 9357), waiting at most
/// `timeout` for it to answer.
pub async fn connect(timeout: Duration) -> anyhow::Result<Sdk> {
    let port = cathlab_agones::port_from_env()?;
    Ok(Sdk::connect(port, timeout).await?)
}

/// Whether the physics loops kept time between two looks: each session seen both times ran
/// at least [`MIN_STEP_FRACTION`] of the steps its rate asks for in the time between.
#[derive(Debug, Default)]
pub struct TimeKeeping {
    last: HashMap<String, (u64, Instant)>,
}

impl TimeKeeping {
    /// Takes a look at `sessions` (id, steps run so far, step rate in Hz) at `now`; false if
    /// any session seen last time ran too few steps since.
    pub fn update(&mut self, sessions: &[(String, u64, f64)], now: Instant) -> bool {
        let mut keeping = true;
        let mut next = HashMap::with_capacity(sessions.len());
        for (id, steps, rate_hz) in sessions {
            if let Some((before, then)) = self.last.get(id) {
                let expected = now.duration_since(*then).as_secs_f64() * rate_hz;
                let ran = steps.saturating_sub(*before) as f64;
                if expected >= 1.0 && ran < MIN_STEP_FRACTION * expected {
                    tracing::warn!(
                        session = %id,
                        ran,
                        expected,
                        "a physics loop is not keeping time: no Agones health ping"
                    );
                    keeping = false;
                }
            }
            next.insert(id.clone(), (*steps, now));
        }
        self.last = next;
        keeping
    }
}

/// Runs the lifecycle until the task is dropped: Ready (after setting the counter), then
/// health pings, counter updates and Allocate/Ready as sessions come and go. With
/// `advertise`, the fleet's registry gets the GameServer's public address and port from
/// Agones (`scheme://address:port`) once Agones has assigned them.
pub async fn run(
    mut sdk: Sdk,
    engine: Arc<Engine>,
    capacity: usize,
    advertise: Option<(AdvertisedAddress, &'static str)>,
) {
    let capacity = i64::try_from(capacity).unwrap_or(i64::MAX);
    let mut count = 0i64;
    if let Err(e) = sdk.set_counter(SESSIONS_COUNTER, 0, capacity).await {
        tracing::warn!("{e}");
    }
    if let Err(e) = sdk.ready().await {
        tracing::error!("{e}");
    }
    tracing::info!("Agones: Ready");
    if let Some((address, scheme)) = &advertise {
        match sdk.public_address().await {
            Ok(Some((host, port))) => {
                let public = format!("{scheme}://{host}:{port}");
                tracing::info!(address = %public, "Agones: the GameServer's address advertised");
                address.set(public);
            }
            Ok(None) => tracing::warn!("Agones gave no address yet: advertising {}", address.get()),
            Err(e) => tracing::warn!("{e}"),
        }
    }
    let mut health = sdk.health();
    let mut keeping = TimeKeeping::default();
    let mut allocated = false;
    let mut last_ping: Option<Instant> = None;
    loop {
        let sessions = engine.sessions();
        let now = Instant::now();
        if last_ping.is_none_or(|t| now.duration_since(t) >= HEALTH_PERIOD) {
            let seen: Vec<(String, u64, f64)> = sessions
                .iter()
                .map(|s| {
                    (
                        s.id().to_owned(),
                        s.timing().summary().steps,
                        s.assets().spec.fidelity.step_rate_hz,
                    )
                })
                .collect();
            if keeping.update(&seen, now) {
                health.ping();
            }
            last_ping = Some(now);
        }
        let n = i64::try_from(sessions.len()).unwrap_or(i64::MAX);
        drop(sessions);
        if n != count {
            match sdk.set_counter(SESSIONS_COUNTER, n, capacity).await {
                Ok(_) => count = n,
                Err(e) => tracing::warn!("{e}"),
            }
        }
        if n > 0 && !allocated {
            match sdk.allocate().await {
                Ok(()) => {
                    allocated = true;
                    tracing::info!("Agones: Allocated");
                }
                Err(e) => tracing::warn!("{e}"),
            }
        } else if n == 0 && allocated {
            // Back in the Fleet's pool: it may be allocated again, or scaled down.
            match sdk.ready().await {
                Ok(()) => {
                    allocated = false;
                    tracing::info!("Agones: Ready again");
                }
                Err(e) => tracing::warn!("{e}"),
            }
        }
        tokio::time::sleep(WATCH_PERIOD).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_keeping_counts_the_steps_each_session_ran_against_its_rate() {
        let mut t = TimeKeeping::default();
        let t0 = Instant::now();
        let t1 = t0 + Duration::from_secs(2);
        // First look: nothing to compare with.
        assert!(t.update(&[("a".into(), 100, 500.0)], t0));
        // 2 s at 500 Hz is 1,000 steps: 900 is keeping time, a new session is not judged.
        assert!(t.update(&[("a".into(), 1000, 500.0), ("b".into(), 0, 500.0)], t1));
        // 400 of 1,000: not keeping time (a); b ran 1,000.
        let t2 = t1 + Duration::from_secs(2);
        assert!(!t.update(&[("a".into(), 1400, 500.0), ("b".into(), 1000, 500.0)], t2));
        // A wedged loop runs none.
        let t3 = t2 + Duration::from_secs(2);
        assert!(!t.update(&[("a".into(), 2400, 500.0), ("b".into(), 1000, 500.0)], t3));
        // Sessions gone: nothing to judge.
        assert!(t.update(&[], t3 + Duration::from_secs(2)));
        // Exactly half is enough.
        let mut t = TimeKeeping::default();
        assert!(t.update(&[("c".into(), 0, 100.0)], t0));
        assert!(t.update(&[("c".into(), 100, 100.0)], t1));
    }
}
