//! This server's place in a fleet sharing one store: its registration and heartbeat (where
//! clients reach it, how many sessions it may run and runs), and the sessions of servers
//! that stopped beating marked lost (their recordings stay replayable).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use cathlab_engine::Engine;

use crate::store::Store;

/// How often a server beats (and at once when its session count changes).
pub const HEARTBEAT: Duration = Duration::from_secs(2);

/// How long a server may stay silent before it is counted lost (s): five heartbeats.
pub const LOST_AFTER_S: f64 = 10.0;

/// The heartbeat thread; stopping it (or dropping it) marks the server stopped.
pub struct Registration {
    address: Arc<parking_lot::Mutex<String>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    store: Arc<Store>,
}

impl std::fmt::Debug for Registration {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Registration")
            .field("server", &self.store.server_id())
            .finish()
    }
}

impl Registration {
    /// Registers this server at `address` with room for `capacity` sessions and beats every
    /// [`HEARTBEAT`] with the engine's session count, marking silent servers' sessions lost.
    pub fn start(
        store: Arc<Store>,
        engine: Arc<Engine>,
        address: String,
        capacity: usize,
    ) -> std::io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let (flag, beating) = (stop.clone(), store.clone());
        let address = Arc::new(parking_lot::Mutex::new(address));
        let advertised = address.clone();
        let capacity = u32::try_from(capacity).unwrap_or(u32::MAX);
        let thread = std::thread::Builder::new()
            .name("fleet-heartbeat".into())
            .spawn(move || {
                while !flag.load(Ordering::Relaxed) {
                    let load = u32::try_from(engine.sessions().len()).unwrap_or(u32::MAX);
                    // A database that cannot be reached is the store's health to report.
                    let address = advertised.lock().clone();
                    if let Err(e) = beating.heartbeat(&address, capacity, load) {
                        tracing::debug!("heartbeat: {e}");
                    }
                    if let Err(e) = beating.mark_lost(LOST_AFTER_S) {
                        tracing::debug!("marking lost servers: {e}");
                    }
                    // Sleep in short slices so that stopping is prompt, and beat at once when
                    // the load changes (the allocation endpoint reads it).
                    let mut slept = Duration::ZERO;
                    while slept < HEARTBEAT && !flag.load(Ordering::Relaxed) {
                        std::thread::sleep(Duration::from_millis(100));
                        slept += Duration::from_millis(100);
                        if engine.sessions().len() != load as usize {
                            break;
                        }
                    }
                }
            })?;
        Ok(Self {
            address,
            stop,
            thread: Some(thread),
            store,
        })
    }

    /// A handle that changes where this server says clients reach it (from the next beat).
    pub fn address(&self) -> AdvertisedAddress {
        AdvertisedAddress(self.address.clone())
    }

    /// Stops beating and marks this server stopped (after its sessions were closed).
    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
            if let Err(e) = self.store.unregister() {
                tracing::warn!("unregistering from the fleet: {e}");
            }
        }
    }
}

/// Where a registered server says clients reach it.
#[derive(Debug, Clone)]
pub struct AdvertisedAddress(Arc<parking_lot::Mutex<String>>);

impl AdvertisedAddress {
    /// Clients reach it at `address` (`scheme://host:port`) from now on.
    pub fn set(&self, address: String) {
        *self.0.lock() = address;
    }

    /// The address now.
    pub fn get(&self) -> String {
        self.0.lock().clone()
    }
}

/// The serving server with the most room (`capacity − load`), if any has room: where a new
/// trainee's session should go. Ties go to the lowest id (deterministic).
pub fn with_most_room(
    servers: &[crate::store::StoredServer],
) -> Option<&crate::store::StoredServer> {
    servers
        .iter()
        .filter(|s| s.status == "serving" && s.load < s.capacity)
        .min_by(|a, b| {
            (b.capacity - b.load)
                .cmp(&(a.capacity - a.load))
                .then_with(|| a.id.cmp(&b.id))
        })
}

impl Drop for Registration {
    fn drop(&mut self) {
        self.stop();
    }
}
