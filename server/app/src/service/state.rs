//! The service's state: [`SimulatorService`] with its builders (each limit's default from
//! `config`), the sessions' tokens and roles, who created which running session, who attends
//! each, and the held speeds.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use cathlab_engine::Engine;
use parking_lot::{Mutex, RwLock};

use crate::auth::Throttle;
use crate::config::{
    AUTH_FAILURES_PER_MINUTE, CONTROL_INPUTS_PER_SECOND, CONTROL_TIMEOUT, InlineScenes,
    STREAM_BUFFER_BYTES, STREAM_STALL, UNATTENDED_SESSION_TIMEOUT,
};
use crate::reports::Reports;
use crate::store::Store;
use crate::streams::StreamBudget;

/// Who a token belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// May command the session.
    Controller,
    /// May read the session.
    Observer,
    /// May read and list every session.
    Instructor,
}

#[derive(Debug, Clone)]
pub(super) struct Tokens {
    pub(super) controller: String,
    pub(super) observer: String,
}

/// The service state.
pub struct SimulatorService {
    pub(super) engine: Arc<Engine>,
    pub(super) store: Arc<Store>,
    pub(super) reports: Arc<Reports>,
    pub(super) instructor_key: Option<String>,
    pub(super) tokens: RwLock<HashMap<String, Tokens>>,
    pub(super) inline_scenes: InlineScenes,
    pub(super) throttle: Throttle,
    pub(super) control_timeout: Duration,
    pub(super) holds: Arc<Mutex<HashMap<(String, HeldAxis), u64>>>,
    pub(super) stream_budget: Arc<StreamBudget>,
    pub(super) stream_stall: Duration,
    pub(super) control_inputs_per_second: u32,
    pub(super) default_scene: String,
    pub(super) attendance: Arc<Mutex<HashMap<String, Attendance>>>,
    pub(super) unattended_timeout: Option<Duration>,
    pub(super) clients: Arc<Mutex<ClientSessions>>,
    pub(super) max_sessions_per_client: usize,
    pub(super) creations_per_minute: u32,
}

/// Who created which running session (an account, else an address), and the creations
/// under way: no one client may hold every place.
#[derive(Debug, Default)]
pub(super) struct ClientSessions {
    pub(super) creator: HashMap<String, String>,
    pub(super) pending: HashMap<String, usize>,
    /// Creations per client in the current minute: when the minute began, how many.
    pub(super) recent: HashMap<String, (Instant, u32)>,
}

/// Whether anyone attends a running session: its controller's open streams, and when its
/// controller was last heard from (a call with its token, or the end of one of its streams).
#[derive(Debug, Clone, Copy)]
pub(super) struct Attendance {
    pub(super) streams: usize,
    pub(super) last: Instant,
}

/// Counts one controller stream of a session while it lives; when dropped (the stream
/// ended, or its client went away) the session was attended until now.
pub(super) struct Attending {
    pub(super) attendance: Arc<Mutex<HashMap<String, Attendance>>>,
    pub(super) id: String,
}

impl Drop for Attending {
    fn drop(&mut self) {
        if let Some(a) = self.attendance.lock().get_mut(&self.id) {
            a.streams = a.streams.saturating_sub(1);
            a.last = Instant::now();
        }
    }
}

/// A held speed: the instrument it drives (`None`: the innermost) and its axis.
pub(super) type HeldAxis = (Option<u32>, Axis);

/// A speed a unary command sets (and a held one lapses).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(super) enum Axis {
    Push,
    Twist,
}

impl std::fmt::Debug for SimulatorService {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimulatorService").finish_non_exhaustive()
    }
}

impl SimulatorService {
    /// A service over `engine`, recording to `store`; `instructor_key` unlocks listing and
    /// watching every session.
    pub fn new(engine: Arc<Engine>, store: Arc<Store>, instructor_key: Option<String>) -> Self {
        Self {
            reports: Arc::new(Reports::new(engine.clone(), store.clone())),
            store,
            instructor_key: instructor_key.filter(|k| !k.is_empty()),
            tokens: RwLock::new(HashMap::new()),
            inline_scenes: InlineScenes::default(),
            throttle: Throttle::new(AUTH_FAILURES_PER_MINUTE, Duration::from_secs(60)),
            control_timeout: CONTROL_TIMEOUT,
            holds: Arc::default(),
            stream_budget: StreamBudget::new(STREAM_BUFFER_BYTES, engine.metrics().clone()),
            stream_stall: STREAM_STALL,
            control_inputs_per_second: CONTROL_INPUTS_PER_SECOND,
            attendance: Arc::default(),
            unattended_timeout: Some(UNATTENDED_SESSION_TIMEOUT),
            clients: Arc::default(),
            max_sessions_per_client: usize::MAX,
            creations_per_minute: u32::MAX,
            default_scene: crate::config::ServerConfig::default()
                .resolve_default_scene(&engine.catalog().names())
                .unwrap_or_default(),
            engine,
        }
    }

    /// The scene `ListScenes` names as the default (`ServerConfig::resolve_default_scene`).
    pub fn with_default_scene(mut self, name: String) -> Self {
        self.default_scene = name;
        self
    }

    /// The bytes all frame streams' encoded frames may hold together, and how long one may
    /// wait for its reader before the reader's connection is cut.
    pub fn with_stream_limits(mut self, budget_bytes: usize, stall: Duration) -> Self {
        self.stream_budget = StreamBudget::new(budget_bytes, self.engine.metrics().clone());
        self.stream_stall = stall;
        self
    }

    /// Control inputs one stream may send a second; past it the stream ends with
    /// RESOURCE_EXHAUSTED (the device stops).
    pub fn with_control_inputs_per_second(mut self, per_second: u32) -> Self {
        self.control_inputs_per_second = per_second.max(1);
        self
    }

    /// How long a running session may go without its controller before it is closed
    /// (`None`: never); [`SimulatorService::close_unattended`] applies it.
    pub fn with_unattended_timeout(mut self, timeout: Option<Duration>) -> Self {
        self.unattended_timeout = timeout;
        self
    }

    /// At most `n` running sessions created by one client (an account, else an address);
    /// instructors create for others and are not limited.
    pub fn with_max_sessions_per_client(mut self, n: usize) -> Self {
        self.max_sessions_per_client = n.max(1);
        self
    }

    /// At most `n` sessions created a minute by one client (instructors are not limited):
    /// a create-and-close loop cannot fill the store.
    pub fn with_session_creations_per_minute(mut self, n: u32) -> Self {
        self.creations_per_minute = n.max(1);
        self
    }

    /// How long a control stream may go quiet before its setpoints are zeroed.
    pub fn with_control_timeout(mut self, timeout: Duration) -> Self {
        self.control_timeout = timeout;
        self
    }

    /// At most `per_minute` wrong keys or tokens a minute from one address.
    pub fn with_auth_failures_per_minute(mut self, per_minute: u32) -> Self {
        self.throttle = Throttle::new(per_minute, Duration::from_secs(60));
        self
    }

    /// Who may create sessions from scene texts.
    pub fn with_inline_scenes(mut self, inline_scenes: InlineScenes) -> Self {
        self.inline_scenes = inline_scenes;
        self
    }

    /// Marks `id`'s controller as heard from now, with `opened` more streams open.
    pub(super) fn attended(&self, id: &str, opened: usize) {
        let now = Instant::now();
        let mut attendance = self.attendance.lock();
        match attendance.get_mut(id) {
            Some(a) => {
                a.streams += opened;
                a.last = now;
            }
            None => {
                attendance.insert(
                    id.to_owned(),
                    Attendance {
                        streams: opened,
                        last: now,
                    },
                );
            }
        }
    }

    /// Counts a stream of `id`'s controller until the returned guard drops (an observer's
    /// or instructor's stream does not count: `None`).
    pub(super) fn attending(&self, id: &str, role: Role) -> Option<Attending> {
        if role != Role::Controller {
            return None;
        }
        self.attended(id, 1);
        Some(Attending {
            attendance: self.attendance.clone(),
            id: id.to_owned(),
        })
    }
}
