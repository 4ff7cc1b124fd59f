//! The `cathlab.v1.Simulator` service: thin handlers that authenticate the bearer token,
//! validate the message (through `cathlab-api`), call the engine and convert the answer.
//! Streams forward the newest value of the engine's latest-value channels.

use std::collections::HashMap;
use std::net::IpAddr;
use std::path::Path;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use cathlab_api::pb::simulator_server::Simulator;
use cathlab_api::{
    command_from_wire, control_from_wire, event_to_wire, metrics_to_wire, pb, state_to_wire,
    status_of, timing_to_wire,
};
use cathlab_engine::engine::SceneSource;
use cathlab_engine::scene::GuidanceSpec;

use crate::auth::{Throttle, same_secret};
use crate::config::{
    AUTH_FAILURES_PER_MINUTE, CONTROL_INPUTS_PER_SECOND, CONTROL_TIMEOUT, InlineScenes,
    STREAM_BUFFER_BYTES, STREAM_STALL, UNATTENDED_SESSION_TIMEOUT,
};
use crate::connections;
use crate::streams::{FrameRequest, FrameStream, StreamBudget};
use cathlab_engine::session::Session;
use cathlab_engine::world::Command;
use cathlab_engine::{CommandRecord, Encoding, Engine, EngineError, SceneFormat, SceneSpec};
use parking_lot::{Mutex, RwLock};
use tokio::sync::{mpsc, oneshot};
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::{Stream, StreamExt};
use tonic::{Request, Response, Status, Streaming};

use crate::reports::{AccountRole, Caller, Reports, store_status, token_hash};
use crate::store::{Store, StoredAccount, StoredSession};

/// A boxed response stream.
pub type ResponseStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send + 'static>>;

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
struct Tokens {
    controller: String,
    observer: String,
}

/// The service state.
pub struct SimulatorService {
    engine: Arc<Engine>,
    store: Arc<Store>,
    reports: Arc<Reports>,
    instructor_key: Option<String>,
    tokens: RwLock<HashMap<String, Tokens>>,
    inline_scenes: InlineScenes,
    throttle: Throttle,
    control_timeout: Duration,
    holds: Arc<Mutex<HashMap<(String, HeldAxis), u64>>>,
    stream_budget: Arc<StreamBudget>,
    stream_stall: Duration,
    control_inputs_per_second: u32,
    default_scene: String,
    attendance: Arc<Mutex<HashMap<String, Attendance>>>,
    unattended_timeout: Option<Duration>,
    clients: Arc<Mutex<ClientSessions>>,
    max_sessions_per_client: usize,
    creations_per_minute: u32,
}

/// Who created which running session (an account, else an address), and the creations
/// under way: no one client may hold every place.
#[derive(Debug, Default)]
struct ClientSessions {
    creator: HashMap<String, String>,
    pending: HashMap<String, usize>,
    /// Creations per client in the current minute: when the minute began, how many.
    recent: HashMap<String, (Instant, u32)>,
}

/// A creation under way, counted against its client until it ends.
struct Creating {
    clients: Arc<Mutex<ClientSessions>>,
    client: String,
}

impl Drop for Creating {
    fn drop(&mut self) {
        let mut clients = self.clients.lock();
        if let Some(n) = clients.pending.get_mut(&self.client) {
            *n -= 1;
            if *n == 0 {
                clients.pending.remove(&self.client);
            }
        }
    }
}

/// Whether anyone attends a running session: its controller's open streams, and when its
/// controller was last heard from (a call with its token, or the end of one of its streams).
#[derive(Debug, Clone, Copy)]
struct Attendance {
    streams: usize,
    last: Instant,
}

/// Counts one controller stream of a session while it lives; when dropped (the stream
/// ended, or its client went away) the session was attended until now.
struct Attending {
    attendance: Arc<Mutex<HashMap<String, Attendance>>>,
    id: String,
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
type HeldAxis = (Option<u32>, Axis);

/// A speed a unary command sets (and a held one lapses).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
enum Axis {
    Push,
    Twist,
}

/// The axis a unary command drives, and whether it asks for hold mode with a non-zero speed
/// (targets and other commands: `None`, or the axis with `false`).
fn speed_axis(command: Option<&pb::Command>) -> Option<(Axis, bool)> {
    use pb::command::Kind;
    Some(match command?.kind.as_ref()? {
        Kind::Insertion(i) => match i.mode {
            Some(pb::insertion::Mode::VelocityMmS(v)) => (Axis::Push, i.hold && v != 0.0),
            _ => (Axis::Push, false),
        },
        Kind::Twist(t) => match t.mode {
            Some(pb::twist::Mode::RateDegS(w)) => (Axis::Twist, t.hold && w != 0.0),
            _ => (Axis::Twist, false),
        },
        _ => return None,
    })
}

impl std::fmt::Debug for SimulatorService {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimulatorService").finish_non_exhaustive()
    }
}

/// How many instruments `session` has now (its last state; a stack's loads and unloads
/// change it, and the engine checks the index again where the command applies).
fn instrument_count(session: &Session) -> u32 {
    let now = session.state().borrow().instruments.len();
    let scene = session.assets().spec.stack.len();
    now.max(scene).max(1) as u32
}

fn random_hex(bytes: usize) -> String {
    use rand::RngExt;
    let mut rng = rand::rng();
    (0..bytes)
        .map(|_| format!("{:02x}", rng.random::<u8>()))
        .collect()
}

fn unix_us() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// The caller's address (unspecified for in-process callers).
fn peer_of<T>(request: &Request<T>) -> IpAddr {
    connections::address(request)
}

/// `id` if it can be a session id (at most 64 letters, digits, `-` or `_`); else
/// INVALID_ARGUMENT that says what it is without echoing it.
fn checked_id(id: &str) -> Result<&str, Status> {
    if id.is_empty() {
        return Err(Status::invalid_argument("session_id: missing"));
    }
    if id.len() > 64
        || !id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
    {
        return Err(Status::invalid_argument(format!(
            "session_id: {} bytes that are not a session id",
            id.len()
        )));
    }
    Ok(id)
}

/// Recorded sessions on a `ListSessions` page unless the caller asks for fewer.
pub const DEFAULT_PAGE_SIZE: usize = 100;

/// The most recorded sessions one `ListSessions` page holds.
pub const MAX_PAGE_SIZE: usize = 500;

/// The last session of the previous page, as `next_page_token` named it (its creation
/// time's bits in hex, a dot, its id).
fn parse_page_token(token: &str) -> Result<(f64, String), Status> {
    let bad = || Status::invalid_argument("page_token: not a next_page_token of this server");
    let (bits, id) = token.split_once('.').ok_or_else(bad)?;
    let created = f64::from_bits(u64::from_str_radix(bits, 16).map_err(|_| bad())?);
    checked_id(id).map_err(|_| bad())?;
    if !created.is_finite() {
        return Err(bad());
    }
    Ok((created, id.to_owned()))
}

fn bearer<T>(request: &Request<T>) -> Option<String> {
    let value = request.metadata().get("authorization")?.to_str().ok()?;
    value
        .strip_prefix("Bearer ")
        .or_else(|| value.strip_prefix("bearer "))
        .map(|t| t.trim().to_owned())
}

fn engine_status(e: EngineError) -> Status {
    status_of(&e)
}

/// A database that cannot answer is UNAVAILABLE (retry later); a corrupt value INTERNAL.
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

    /// Closes the running sessions whose controller has been away longer than the unattended
    /// timeout (no stream open with the controller token, no call with it), as their
    /// controller's CloseSession would; returns their ids. A session this service did not
    /// create counts as attended until now.
    pub async fn close_unattended(&self) -> Vec<String> {
        let Some(timeout) = self.unattended_timeout else {
            return Vec::new();
        };
        let running: Vec<String> = self
            .engine
            .sessions()
            .iter()
            .map(|s| s.id().to_owned())
            .collect();
        let now = Instant::now();
        let away: Vec<(String, Duration)> = {
            let mut attendance = self.attendance.lock();
            attendance.retain(|id, _| running.contains(id));
            running
                .iter()
                .filter_map(|id| {
                    let a = attendance.entry(id.clone()).or_insert(Attendance {
                        streams: 0,
                        last: now,
                    });
                    let away = now.saturating_duration_since(a.last);
                    (a.streams == 0 && away > timeout).then(|| (id.clone(), away))
                })
                .collect()
        };
        let mut closed = Vec::new();
        for (id, away) in away {
            match self.close(&id).await {
                Ok(_) => {
                    tracing::info!(
                        session = %id,
                        away_s = away.as_secs(),
                        "closed: its controller was away longer than the unattended timeout"
                    );
                    closed.push(id);
                }
                Err(e) => {
                    tracing::warn!(session = %id, "closing an unattended session: {}", e.message())
                }
            }
        }
        closed
    }

    /// Marks `id`'s controller as heard from now, with `opened` more streams open.
    fn attended(&self, id: &str, opened: usize) {
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
    fn attending(&self, id: &str, role: Role) -> Option<Attending> {
        if role != Role::Controller {
            return None;
        }
        self.attended(id, 1);
        Some(Attending {
            attendance: self.attendance.clone(),
            id: id.to_owned(),
        })
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

    /// Counts a creation by `client` against its limits, or refuses it.
    fn creating(&self, client: &str) -> Result<Creating, Status> {
        let running: std::collections::HashSet<String> = self
            .engine
            .sessions()
            .iter()
            .map(|s| s.id().to_owned())
            .collect();
        let mut clients = self.clients.lock();
        clients.creator.retain(|id, _| running.contains(id));
        let holds = clients.creator.values().filter(|c| *c == client).count()
            + clients.pending.get(client).copied().unwrap_or(0);
        if holds >= self.max_sessions_per_client {
            return Err(Status::resource_exhausted(format!(
                "this client runs {holds} sessions, the most one client may \
                 (max_sessions_per_client); close one first"
            )));
        }
        let now = Instant::now();
        if clients.recent.len() > 10_000 {
            clients
                .recent
                .retain(|_, (since, _)| now.duration_since(*since) < Duration::from_secs(60));
        }
        let recent = clients.recent.entry(client.to_owned()).or_insert((now, 0));
        if now.duration_since(recent.0) >= Duration::from_secs(60) {
            *recent = (now, 0);
        }
        if recent.1 >= self.creations_per_minute {
            let wait = 60 - now.duration_since(recent.0).as_secs();
            return Err(Status::resource_exhausted(format!(
                "this client created {} sessions this minute, the most it may \
                 (session_creations_per_minute); retry in {wait} s",
                recent.1
            )));
        }
        recent.1 += 1;
        *clients.pending.entry(client.to_owned()).or_insert(0) += 1;
        Ok(Creating {
            clients: self.clients.clone(),
            client: client.to_owned(),
        })
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

    fn is_instructor_key(&self, token: Option<&str>) -> bool {
        matches!((token, &self.instructor_key), (Some(t), Some(k)) if same_secret(t, k))
    }

    /// The instructor key or an instructor account's token.
    fn is_instructor(&self, token: Option<&str>) -> bool {
        self.is_instructor_key(token)
            || token.is_some_and(|t| {
                matches!(self.account_of(t), Some(a) if a.role == AccountRole::Instructor.as_str())
            })
    }

    /// The account `token` belongs to (a store error reads as none).
    fn account_of(&self, token: &str) -> Option<StoredAccount> {
        self.store
            .account_by_token_hash(&token_hash(token))
            .ok()
            .flatten()
    }

    /// Who the request comes from. An address that guessed wrong too often is refused.
    fn caller<T>(&self, request: &Request<T>) -> Result<Caller, Status> {
        let token = bearer(request);
        // An account's token is random (nothing to guess): never throttled.
        if let Some(account) = token.as_deref().and_then(|t| self.account_of(t)) {
            return Ok(Caller::Account(account));
        }
        self.throttle.check(peer_of(request))?;
        Ok(if self.is_instructor_key(token.as_deref()) {
            Caller::InstructorKey
        } else {
            Caller::Other(token)
        })
    }

    /// Whether the caller is an instructor (the key or an instructor account). An address
    /// that guessed wrong too often is refused; a token of nobody counts as a guess.
    fn instructor<T>(&self, request: &Request<T>) -> Result<bool, Status> {
        let caller = self.caller(request)?;
        if let Caller::Other(Some(_)) = caller {
            self.throttle
                .failed(peer_of(request), "a wrong instructor key");
        }
        Ok(caller.is_instructor())
    }

    /// A caller that may read `id`'s report, and the stored session. A wrong token counts as
    /// a guess.
    fn report_reader<T>(&self, request: &Request<T>, id: &str) -> Result<StoredSession, Status> {
        checked_id(id)?;
        let caller = self.caller(request)?;
        let session = self.reports.session(id)?;
        caller.may_read(&session).inspect_err(|e| {
            if e.code() != tonic::Code::Unauthenticated && matches!(caller, Caller::Other(_)) {
                self.throttle
                    .failed(peer_of(request), "a token of no session or account");
            }
        })?;
        Ok(session)
    }

    /// Checks the caller's bearer token for `session_id`: NOT_FOUND for an unknown session,
    /// UNAUTHENTICATED without a valid token, PERMISSION_DENIED when reading is not enough.
    fn authorize(
        &self,
        peer: IpAddr,
        token: Option<&str>,
        session_id: &str,
        control: bool,
    ) -> Result<Role, Status> {
        checked_id(session_id)?;
        let known = self.tokens.read().get(session_id).cloned();
        // The session's own tokens first: a controller's every command and stream is checked
        // here, and only a token that is neither reads the account store.
        let own = match (token, known.as_ref()) {
            (Some(t), Some(k)) if same_secret(t, &k.controller) => Some(Role::Controller),
            (Some(t), Some(k)) if same_secret(t, &k.observer) => Some(Role::Observer),
            _ => None,
        };
        // A session's own token (random, 192 bits: nothing to guess) is never throttled, so
        // that a trainee's stop or close goes through while someone at the same address
        // (behind the same proxy) guesses; everything else is refused once the address has
        // used up its guesses.
        if own.is_none() {
            self.throttle.check(peer)?;
        }
        let role = if let Some(role) = own {
            role
        } else if self.is_instructor(token) {
            Role::Instructor
        } else {
            if known.is_none() {
                return Err(Status::not_found(format!("session {session_id:?}")));
            }
            match token {
                Some(_) => {
                    self.throttle.failed(peer, "a token of no session");
                    return Err(Status::unauthenticated(format!(
                        "the token is not one of session {session_id:?}"
                    )));
                }
                None => {
                    return Err(Status::unauthenticated(
                        "missing `authorization: Bearer <token>` metadata",
                    ));
                }
            }
        };
        // A command keeps a session attended; a read does not (a client holding sessions
        // with one cheap GetSession each would keep them from everyone).
        if control && role == Role::Controller {
            self.attended(session_id, 0);
        }
        if control && role != Role::Controller {
            return Err(Status::permission_denied(format!(
                "{} may watch session {session_id:?} but not command it",
                match role {
                    Role::Observer => "an observer",
                    _ => "an instructor",
                }
            )));
        }
        Ok(role)
    }

    fn session(&self, id: &str) -> Result<Arc<Session>, Status> {
        self.engine.get(id).map_err(engine_status)
    }

    /// The running session `id` if the request's token may read it.
    fn readable<T>(&self, request: &Request<T>, id: &str) -> Result<Arc<Session>, Status> {
        self.authorize(peer_of(request), bearer(request).as_deref(), id, false)?;
        self.session(id)
    }

    /// The running session `id` if the request's token may read it, and the guard that
    /// counts the stream as its controller's while it lives (see [`Self::attending`]).
    fn watched<T>(
        &self,
        request: &Request<T>,
        id: &str,
    ) -> Result<(Arc<Session>, Option<Attending>), Status> {
        let role = self.authorize(peer_of(request), bearer(request).as_deref(), id, false)?;
        let session = self.session(id)?;
        Ok((session, self.attending(id, role)))
    }

    fn info_of(&self, session: &Session) -> pb::SessionInfo {
        let state = session.state().borrow().clone();
        pb::SessionInfo {
            session_id: session.id().to_owned(),
            scene_name: session.assets().spec.name.clone(),
            label: session.label().to_owned(),
            status: if session.is_running() {
                pb::SessionStatus::Running
            } else {
                pb::SessionStatus::Closed
            } as i32,
            created_unix_s: session.created_unix_s(),
            step_rate_hz: session.assets().spec.fidelity.step_rate_hz,
            metrics: Some(metrics_to_wire(&state.metrics)),
            timing: Some(timing_to_wire(&session.timing().summary())),
            commands: session.commands_recorded(),
            active_device: state.active_device,
            observer_token: String::new(),
            guidance: Some(guidance_to_wire(&session.assets().spec.guidance)),
            server_address: String::new(),
        }
    }

    fn stored_info(&self, s: &StoredSession) -> Result<pb::SessionInfo, Status> {
        let metrics = self
            .store
            .last_checkpoint(&s.id)
            .map_err(store_status)?
            .map(|c| metrics_to_wire(&c.metrics));
        Ok(pb::SessionInfo {
            session_id: s.id.clone(),
            scene_name: s.scene_name.clone(),
            label: s.label.clone(),
            status: match s.status.as_str() {
                "running" => pb::SessionStatus::Running,
                "closed" => pb::SessionStatus::Closed,
                "lost" => pb::SessionStatus::Lost,
                _ => pb::SessionStatus::Interrupted,
            } as i32,
            created_unix_s: s.created_unix_s,
            step_rate_hz: s.step_rate_hz,
            metrics,
            timing: None,
            commands: self.store.command_count(&s.id).map_err(store_status)?,
            active_device: 0,
            observer_token: String::new(),
            guidance: serde_json::from_str::<SceneSpec>(&s.scene_json)
                .ok()
                .map(|spec| guidance_to_wire(&spec.guidance)),
            server_address: String::new(),
        })
    }

    /// Hold mode for unary speed commands: a held speed lapses to zero unless a newer
    /// command on its axis comes within the control timeout (any newer command on the axis
    /// cancels the lapse).
    fn hold(
        &self,
        session: &Arc<Session>,
        (instrument, axis): (Option<u32>, Axis),
        hold: bool,
        seq: u64,
    ) {
        let key = (session.id().to_owned(), (instrument, axis));
        let generation = {
            let mut holds = self.holds.lock();
            let g = holds.entry(key.clone()).or_insert(0);
            *g += 1;
            *g
        };
        if !hold {
            return;
        }
        let (holds, session, timeout) = (self.holds.clone(), session.clone(), self.control_timeout);
        tokio::spawn(async move {
            tokio::time::sleep(timeout).await;
            if holds.lock().get(&key) != Some(&generation) {
                return;
            }
            tracing::info!(session = %session.id(), ?axis, "held speed not renewed: zeroed");
            let zero = match (instrument, axis) {
                (None, Axis::Push) => Command::PushVelocity(0.0),
                (None, Axis::Twist) => Command::TwistRate(0.0),
                (Some(index), Axis::Push) => Command::Instrument {
                    index,
                    drive: cathlab_engine::Drive::PushVelocity(0.0),
                },
                (Some(index), Axis::Twist) => Command::Instrument {
                    index,
                    drive: cathlab_engine::Drive::TwistRate(0.0),
                },
            };
            let _ = session.send(seq, zero, None);
        });
    }

    /// Closes the running session `id`: the engine stops it, the store marks it closed, its
    /// tokens end, and a trainee's report is made in the background.
    async fn close(&self, id: &str) -> Result<Arc<Session>, Status> {
        let engine = self.engine.clone();
        let closing = id.to_owned();
        let session = tokio::task::spawn_blocking(move || engine.close(&closing))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(engine_status)?;
        self.store.set_status(id, "closed");
        self.store.flush();
        self.tokens.write().remove(id);
        self.attendance.lock().remove(id);
        self.holds.lock().retain(|(s, _), _| s != id);
        // A trainee's session: its report, made now in the background, so that the history
        // and the learning curve have its scores (an anonymous session's report is made when
        // someone asks for it).
        if let Ok(Some(stored)) = self.store.session(id)
            && stored.account_id.is_some()
        {
            let reports = self.reports.clone();
            tokio::spawn(async move {
                if let Err(e) = reports.get(&stored).await {
                    tracing::info!(session = %stored.id, "report not made at close: {}", e.message());
                }
            });
        }
        Ok(session)
    }

    /// Closes every session and waits for the store (graceful shutdown).
    pub fn shutdown(&self) {
        for s in self.engine.sessions() {
            self.store.set_status(s.id(), "closed");
        }
        self.engine.shutdown();
        self.store.flush();
    }
}

fn encoding_of(request: &pb::StreamFramesRequest) -> Result<Encoding, Status> {
    Ok(match pb::FrameEncoding::try_from(request.encoding) {
        Ok(pb::FrameEncoding::Raw8) | Ok(pb::FrameEncoding::Unspecified) => Encoding::Raw8,
        Ok(pb::FrameEncoding::Raw16) => Encoding::Raw16,
        Ok(pb::FrameEncoding::Png) => Encoding::Png,
        Ok(pb::FrameEncoding::Jpeg) => {
            let q = if request.jpeg_quality == 0 {
                85
            } else {
                request.jpeg_quality
            };
            if q > 100 {
                return Err(Status::invalid_argument(format!(
                    "jpeg_quality: {q} is outside 1..=100"
                )));
            }
            Encoding::Jpeg(q as u8)
        }
        Err(_) => {
            return Err(Status::invalid_argument(format!(
                "encoding: {} is not a FrameEncoding",
                request.encoding
            )));
        }
    })
}

#[tonic::async_trait]
impl Simulator for SimulatorService {
    async fn list_scenes(
        &self,
        _: Request<pb::ListScenesRequest>,
    ) -> Result<Response<pb::ListScenesResponse>, Status> {
        let scenes = self
            .engine
            .catalog()
            .scenes()
            .iter()
            .map(|(s, _)| pb::SceneSummary {
                name: s.name.clone(),
                description: s.description.clone(),
                devices: s.devices.iter().map(|d| d.label()).collect(),
                has_flow: s.flow.is_some(),
                target: s.target.branch.clone(),
                stack: s
                    .stack
                    .iter()
                    .map(|e| pb::StackInstrument {
                        device: e.label(),
                        inserted_mm: e.inserted_mm,
                    })
                    .collect(),
                spares: s.spares.iter().map(|e| e.label()).collect(),
            })
            .collect();
        let catalogue = cathlab_engine::scene::catalogue()
            .entries()
            .iter()
            .map(|e| {
                let tip = e.device.sections.last().map(|s| s.cross_section);
                pb::CatalogueDevice {
                    id: e.id.clone(),
                    name: e.device.name.clone(),
                    kind: format!("{:?}", e.kind),
                    length_mm: e.device.length_m() * 1e3,
                    outer_diameter_mm: tip.map_or(0.0, |c| 2e3 * c.outer_radius_m),
                    inner_diameter_mm: tip.map_or(0.0, |c| 2e3 * c.inner_radius_m),
                }
            })
            .collect();
        Ok(Response::new(pb::ListScenesResponse {
            scenes,
            catalogue,
            default_scene: self.default_scene.clone(),
        }))
    }

    async fn create_session(
        &self,
        request: Request<pb::CreateSessionRequest>,
    ) -> Result<Response<pb::CreateSessionResponse>, Status> {
        let caller = self.caller(&request)?;
        let instructor = caller.is_instructor();
        let account_id = match &caller {
            Caller::Account(a) => Some(a.id.clone()),
            _ => None,
        };
        let client = match &account_id {
            Some(a) => format!("account {a}"),
            None => format!("address {}", peer_of(&request)),
        };
        let creating = if instructor {
            None
        } else {
            Some(self.creating(&client)?)
        };
        let r = request.into_inner();
        let inline = matches!(
            r.scene,
            Some(
                pb::create_session_request::Scene::SceneToml(_)
                    | pb::create_session_request::Scene::SceneJson(_)
            )
        );
        match (inline, self.inline_scenes) {
            (true, InlineScenes::Off) => {
                return Err(Status::permission_denied(
                    "scene: this server takes only its listed scenes (inline scenes are off)",
                ));
            }
            (true, InlineScenes::Instructors) if !instructor => {
                return Err(Status::permission_denied(
                    "scene: an inline scene needs the instructor key (or a listed scene)",
                ));
            }
            _ => {}
        }
        let source = match r.scene {
            Some(pb::create_session_request::Scene::SceneName(name)) => SceneSource::Named(name),
            Some(pb::create_session_request::Scene::SceneToml(text)) => {
                SceneSource::Inline(text, SceneFormat::Toml)
            }
            Some(pb::create_session_request::Scene::SceneJson(text)) => {
                SceneSource::Inline(text, SceneFormat::Json)
            }
            None => return Err(Status::invalid_argument("scene: missing")),
        };
        if r.label.len() > 200 {
            return Err(Status::invalid_argument("label: longer than 200 bytes"));
        }
        let (mut spec, base) = self.engine.scene(&source).map_err(engine_status)?;
        if r.assessment {
            spec.guidance = GuidanceSpec::off();
        }
        let id = random_hex(16);
        let tokens = Tokens {
            controller: random_hex(24),
            observer: random_hex(24),
        };
        let engine = self.engine.clone();
        let (label, session_id) = (r.label.clone(), id.clone());
        let spec_for_load = spec.clone();
        let base_for_load = base.clone();
        let session = tokio::task::spawn_blocking(move || {
            engine.create(session_id, label, &spec_for_load, &base_for_load)
        })
        .await
        .map_err(|e| Status::internal(e.to_string()))?
        .map_err(engine_status)?;
        self.store
            .insert_session(StoredSession {
                id: id.clone(),
                label: r.label,
                scene_name: spec.name.clone(),
                scene_json: serde_json::to_string(&spec)
                    .map_err(|e| Status::internal(format!("scene: {e}")))?,
                base_dir: base,
                created_unix_s: session.created_unix_s(),
                status: "running".into(),
                step_rate_hz: spec.fidelity.step_rate_hz,
                account_id,
                controller_hash: Some(token_hash(&tokens.controller)),
                server_id: Some(self.store.server_id().to_owned()),
            })
            .map_err(|e| {
                tracing::warn!("recording a new session: {e}");
                Status::unavailable("the session store cannot be written; try again shortly")
            })?;
        self.tokens.write().insert(id.clone(), tokens.clone());
        if let Some(creating) = creating {
            self.clients.lock().creator.insert(id.clone(), client);
            drop(creating);
        }
        self.attended(&id, 0);
        tracing::info!(session = %id, scene = %spec.name, "session created");
        Ok(Response::new(pb::CreateSessionResponse {
            session_id: id,
            controller_token: tokens.controller,
            observer_token: tokens.observer,
            info: Some(self.info_of(&session)),
        }))
    }

    async fn list_sessions(
        &self,
        request: Request<pb::ListSessionsRequest>,
    ) -> Result<Response<pb::ListSessionsResponse>, Status> {
        if !self.instructor(&request)? {
            return Err(Status::permission_denied(
                "listing sessions needs the instructor key",
            ));
        }
        let page_size = match request.get_ref().page_size {
            0 => DEFAULT_PAGE_SIZE,
            n => (n as usize).min(MAX_PAGE_SIZE),
        };
        let after = match request.get_ref().page_token.as_str() {
            "" => None,
            token => Some(parse_page_token(token)?),
        };
        let first_page = after.is_none();
        let tokens = self.tokens.read().clone();
        let mut sessions: Vec<pb::SessionInfo> = self
            .engine
            .sessions()
            .iter()
            .map(|s| pb::SessionInfo {
                observer_token: tokens
                    .get(s.id())
                    .map(|t| t.observer.clone())
                    .unwrap_or_default(),
                ..self.info_of(s)
            })
            .collect();
        // The fleet's other servers' running sessions always (with where they run), the
        // recorded ones when asked for.
        let elsewhere = self.store.running_elsewhere().map_err(store_status)?;
        if !elsewhere.is_empty() {
            let servers: std::collections::HashMap<String, String> = self
                .store
                .servers()
                .map_err(store_status)?
                .into_iter()
                .filter(|s| s.status == "serving")
                .map(|s| (s.id, s.address))
                .collect();
            for stored in &elsewhere {
                // A server that stopped beating is about to be marked lost: its sessions are
                // not listed live meanwhile (nothing could be streamed from it).
                let Some(server_address) = stored
                    .server_id
                    .as_ref()
                    .and_then(|id| servers.get(id).cloned())
                else {
                    continue;
                };
                sessions.push(pb::SessionInfo {
                    server_address,
                    ..self.stored_info(stored)?
                });
            }
        }
        if !first_page {
            sessions.clear();
        }
        let mut next_page_token = String::new();
        if request.get_ref().include_recorded {
            let listed: std::collections::HashSet<String> =
                sessions.iter().map(|s| s.session_id.clone()).collect();
            let (page, more) = self
                .store
                .sessions_page(after, page_size)
                .map_err(store_status)?;
            if more && let Some(last) = page.last() {
                next_page_token = format!("{:x}.{}", last.created_unix_s.to_bits(), last.id);
            }
            for stored in &page {
                if !listed.contains(&stored.id) {
                    sessions.push(self.stored_info(stored)?);
                }
            }
        }
        Ok(Response::new(pb::ListSessionsResponse {
            sessions,
            next_page_token,
        }))
    }

    async fn get_session(
        &self,
        request: Request<pb::GetSessionRequest>,
    ) -> Result<Response<pb::SessionInfo>, Status> {
        let id = checked_id(&request.get_ref().session_id)?.to_owned();
        if let Ok(session) = self.engine.get(&id) {
            self.authorize(peer_of(&request), bearer(&request).as_deref(), &id, false)?;
            return Ok(Response::new(self.info_of(&session)));
        }
        // A recorded session (closed, or from before a restart): instructors only.
        let stored = self
            .store
            .session(&id)
            .map_err(store_status)?
            .ok_or_else(|| Status::not_found(format!("session {id:?}")))?;
        if !self.instructor(&request)? {
            return Err(Status::permission_denied(
                "recorded sessions are for the instructor key",
            ));
        }
        Ok(Response::new(self.stored_info(&stored)?))
    }

    async fn close_session(
        &self,
        request: Request<pb::CloseSessionRequest>,
    ) -> Result<Response<pb::CloseSessionResponse>, Status> {
        let id = request.get_ref().session_id.clone();
        let role = self.authorize(peer_of(&request), bearer(&request).as_deref(), &id, false)?;
        if role == Role::Observer {
            return Err(Status::permission_denied(
                "an observer cannot close a session",
            ));
        }
        let session = self.close(&id).await?;
        Ok(Response::new(pb::CloseSessionResponse {
            info: Some(self.info_of(&session)),
        }))
    }

    async fn send_command(
        &self,
        request: Request<pb::SendCommandRequest>,
    ) -> Result<Response<pb::CommandAck>, Status> {
        let id = request.get_ref().session_id.clone();
        self.authorize(peer_of(&request), bearer(&request).as_deref(), &id, true)?;
        let r = request.into_inner();
        let command = command_from_wire(r.command.as_ref())?;
        let session = self.session(&id)?;
        let instruments = instrument_count(&session);
        let instrument = r.command.as_ref().and_then(|c| c.instrument);
        if let Some(index) = instrument
            && index >= instruments
        {
            return Err(Status::invalid_argument(format!(
                "command.instrument: {index} is not an instrument of this scene, which has \
                 {instruments} (0 is the outermost)"
            )));
        }
        let record = session
            .command(r.seq, command)
            .await
            .map_err(engine_status)?;
        if let Some((axis, hold)) = speed_axis(r.command.as_ref()) {
            self.hold(&session, (instrument, axis), hold, r.seq);
        }
        Ok(Response::new(pb::CommandAck {
            seq: record.seq,
            step: record.step,
        }))
    }

    type ControlStream = ResponseStream<pb::ControlOutput>;

    async fn control(
        &self,
        request: Request<Streaming<pb::ControlInput>>,
    ) -> Result<Response<Self::ControlStream>, Status> {
        let (token, peer) = (bearer(&request), peer_of(&request));
        let mut inputs = request.into_inner();
        let first = inputs
            .message()
            .await?
            .ok_or_else(|| Status::invalid_argument("session_id: the stream sent nothing"))?;
        let id = first.session_id.clone();
        // Authorized with the token from the stream's metadata.
        let role = self.authorize(peer, token.as_deref(), &id, true)?;
        let session = self.session(&id)?;
        let attending = self.attending(&id, role);
        let (out_tx, out_rx) = mpsc::channel::<Result<pb::ControlOutput, Status>>(64);
        let (pending_tx, mut pending_rx) = mpsc::channel::<(
            u64,
            oneshot::Receiver<cathlab_engine::Result<CommandRecord>>,
        )>(4096);
        // Dropped when the inputs end: the outputs then end too (a half-closed stream ends).
        let (inputs_done, mut inputs_ended) = oneshot::channel::<()>();
        // Inputs: validate and queue; a bad input ends the stream with its error.
        {
            let session = session.clone();
            let out_tx = out_tx.clone();
            let quiet_after = self.control_timeout;
            let per_second = self.control_inputs_per_second;
            tokio::spawn(async move {
                let _inputs_done = inputs_done;
                let mut next = Some(first);
                let (mut last_seq, mut driving) = (0, true);
                let mut previous: Option<u64> = None;
                // A token bucket: `per_second` inputs a second, a second's worth at once.
                let (mut tokens, mut refilled) = (per_second as f64, tokio::time::Instant::now());
                // The dead-man rule: a stream that goes quiet or away leaves the device still.
                // It zeroes the innermost's setpoints and those of every instrument a hand of
                // this stream drove (bit i: instrument i).
                let instruments = instrument_count(&session);
                let mut driven = 0u64;
                let stop = |seq: u64, why: &str, driven: u64| {
                    tracing::info!(session = %session.id(), "control stream {why}: setpoints zeroed");
                    let _ = session.send(
                        seq,
                        Command::Setpoints {
                            push_m_s: 0.0,
                            twist_rad_s: 0.0,
                        },
                        None,
                    );
                    for index in (0..instruments.min(64)).filter(|i| driven & (1 << i) != 0) {
                        let _ = session.send(
                            seq,
                            Command::Instrument {
                                index,
                                drive: cathlab_engine::world::Drive::Setpoints {
                                    push_m_s: 0.0,
                                    twist_rad_s: 0.0,
                                },
                            },
                            None,
                        );
                    }
                };
                loop {
                    let input = match next.take() {
                        Some(i) => i,
                        None => match tokio::time::timeout(quiet_after, inputs.message()).await {
                            Ok(Ok(Some(i))) => i,
                            Ok(Ok(None)) => {
                                stop(last_seq, "ended", driven);
                                break;
                            }
                            Ok(Err(e)) => {
                                stop(last_seq, "broke", driven);
                                let _ = out_tx.send(Err(e)).await;
                                break;
                            }
                            Err(_) => {
                                if driving {
                                    stop(last_seq, "went quiet", driven);
                                    driving = false;
                                }
                                continue;
                            }
                        },
                    };
                    if let Some(p) = previous
                        && input.seq <= p
                    {
                        stop(
                            last_seq,
                            "sent a sequence number that does not increase",
                            driven,
                        );
                        let _ = out_tx
                            .send(Err(Status::invalid_argument(format!(
                                "seq: {} does not increase (the last was {p})",
                                input.seq
                            ))))
                            .await;
                        break;
                    }
                    let now = tokio::time::Instant::now();
                    tokens = (tokens + (now - refilled).as_secs_f64() * per_second as f64)
                        .min(per_second as f64);
                    refilled = now;
                    if tokens < 1.0 {
                        stop(last_seq, "sent too fast", driven);
                        let _ = out_tx
                            .send(Err(Status::resource_exhausted(format!(
                                "control inputs: more than {per_second} a second"
                            ))))
                            .await;
                        break;
                    }
                    tokens -= 1.0;
                    previous = Some(input.seq);
                    (last_seq, driving) = (input.seq, true);
                    let commands = match control_from_wire(&input, instruments) {
                        Ok(c) => c,
                        Err(e) => {
                            stop(last_seq, "sent a bad input", driven);
                            let _ = out_tx.send(Err(e)).await;
                            break;
                        }
                    };
                    let mut sent = true;
                    for command in commands {
                        if let Command::Instrument { index, .. } = command {
                            driven |= 1 << index.min(63);
                        }
                        let (ack_tx, ack_rx) = oneshot::channel();
                        if let Err(e) = session.send(input.seq, command, Some(ack_tx)) {
                            let _ = out_tx.send(Err(engine_status(e))).await;
                            sent = false;
                            break;
                        }
                        if pending_tx.send((input.seq, ack_rx)).await.is_err() {
                            sent = false;
                            break;
                        }
                    }
                    if !sent {
                        break;
                    }
                }
            });
        }
        // Durability: the acknowledgements (committed to the store) in order; the highest
        // committed sequence number goes out with every state. A failed command ends the
        // stream with its error.
        let durable = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let (failed_tx, mut failed) = oneshot::channel::<Status>();
        let acks = {
            let durable = durable.clone();
            tokio::spawn(async move {
                while let Some((seq, ack)) = pending_rx.recv().await {
                    match ack.await {
                        Ok(Ok(_)) => durable.store(seq, std::sync::atomic::Ordering::Release),
                        Ok(Err(e)) => {
                            let _ = failed_tx.send(engine_status(e));
                            return;
                        }
                        // The session closed: its end reaches the state stream.
                        Err(_) => return,
                    }
                }
            })
        };
        // Outputs: every new state as soon as the step that made it is done (the hand feels
        // the wall within a step), with the durable sequence number beside it.
        {
            let mut state = session.state();
            tokio::spawn(async move {
                let durable_seq = || durable.load(std::sync::atomic::Ordering::Acquire);
                let message =
                    |snapshot: &cathlab_engine::Snapshot, durable_seq: u64| pb::ControlOutput {
                        state: Some(state_to_wire(snapshot, true, unix_us())),
                        durable_seq,
                    };
                // Set once the acknowledgements are all in without a failure.
                let mut acks_done = false;
                loop {
                    tokio::select! {
                        changed = state.changed() => if changed.is_err() { break },
                        status = &mut failed, if !acks_done => {
                            match status {
                                Ok(status) => {
                                    let _ = out_tx.send(Err(status)).await;
                                    return;
                                }
                                Err(_) => {
                                    acks_done = true;
                                    continue;
                                }
                            }
                        }
                        _ = &mut inputs_ended => {
                            // The inputs ended: once what was sent is durable (or failed),
                            // a last state says so, and the stream ends.
                            let _ = acks.await;
                            if !acks_done && let Ok(status) = failed.try_recv() {
                                let _ = out_tx.send(Err(status)).await;
                                return;
                            }
                            let snapshot = state.borrow_and_update().clone();
                            let _ = out_tx.send(Ok(message(&snapshot, durable_seq()))).await;
                            return;
                        }
                    }
                    let snapshot = state.borrow_and_update().clone();
                    if out_tx
                        .send(Ok(message(&snapshot, durable_seq())))
                        .await
                        .is_err()
                    {
                        break;
                    }
                }
            });
        }
        Ok(Response::new(Box::pin(ReceiverStream::new(out_rx).map(
            move |output| {
                let _attending = &attending;
                output
            },
        ))))
    }

    type StreamStateStream = ResponseStream<pb::DeviceState>;

    async fn stream_state(
        &self,
        request: Request<pb::StreamStateRequest>,
    ) -> Result<Response<Self::StreamStateStream>, Status> {
        let (session, attending) = self.watched(&request, &request.get_ref().session_id)?;
        let tip_only = request.get_ref().tip_only;
        let stream = tokio_stream::wrappers::WatchStream::new(session.state()).map(move |s| {
            let _attending = &attending;
            Ok(state_to_wire(&s, tip_only, unix_us()))
        });
        Ok(Response::new(Box::pin(stream)))
    }

    type StreamFramesStream = ResponseStream<pb::XrayFrame>;

    async fn stream_frames(
        &self,
        request: Request<pb::StreamFramesRequest>,
    ) -> Result<Response<Self::StreamFramesStream>, Status> {
        let (session, attending) = self.watched(&request, &request.get_ref().session_id)?;
        let cutter = connections::peer(&request).map(|p| p.cutter.clone());
        let address = peer_of(&request);
        let r = request.into_inner();
        let encoding = encoding_of(&r)?;
        for (field, v) in [("width", r.width), ("height", r.height)] {
            if v != 0 && !(16..=2048).contains(&v) {
                return Err(Status::invalid_argument(format!(
                    "{field}: {v} is outside 16..=2048 (0 keeps the detector size)"
                )));
            }
        }
        if (r.width == 0) != (r.height == 0) {
            return Err(Status::invalid_argument(
                "width, height: give both or neither",
            ));
        }
        let stream = FrameStream::new(
            session.frames(),
            FrameRequest {
                encoding,
                width: r.width,
                height: r.height,
            },
            self.stream_budget.clone(),
            (address, self.stream_stall, cutter),
        );
        Ok(Response::new(Box::pin(stream.map(move |frame| {
            let _attending = &attending;
            frame
        }))))
    }

    type StreamMetricsStream = ResponseStream<pb::SessionUpdate>;

    async fn stream_metrics(
        &self,
        request: Request<pb::StreamMetricsRequest>,
    ) -> Result<Response<Self::StreamMetricsStream>, Status> {
        let (session, attending) = self.watched(&request, &request.get_ref().session_id)?;
        let mut events = session.events();
        let state = session.state();
        // The timeline so far (subscribed first, so nothing falls between the two); live
        // events the store already held are not sent twice.
        let session_id = request.get_ref().session_id.clone();
        let store = self.store.clone();
        let history = tokio::task::spawn_blocking(move || store.events(&session_id))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(|e| Status::internal(e.to_string()))?;
        let (tx, rx) = mpsc::channel::<Result<pb::SessionUpdate, Status>>(16 + history.len());
        let mut sent = std::collections::HashSet::new();
        for (step, time_s, kind, message) in history {
            let event = pb::Event {
                step,
                time_s,
                kind,
                message,
            };
            sent.insert((event.step, event.kind.clone(), event.message.clone()));
            let update = pb::session_update::Kind::Event(event);
            // The channel holds the whole history: this cannot wait.
            let _ = tx.try_send(Ok(pb::SessionUpdate { kind: Some(update) }));
        }
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_secs(1));
            loop {
                let update = tokio::select! {
                    _ = tick.tick() => pb::session_update::Kind::Metrics(
                        metrics_to_wire(&state.borrow().metrics)),
                    event = events.recv() => match event {
                        Ok(e) => {
                            let event = event_to_wire(&e);
                            if sent.remove(&(event.step, event.kind.clone(), event.message.clone())) {
                                continue;
                            }
                            pb::session_update::Kind::Event(event)
                        }
                        Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                            pb::session_update::Kind::Event(pb::Event {
                                kind: "lagged".into(),
                                message: format!("{n} events skipped (slow reader)"),
                                ..pb::Event::default()
                            })
                        }
                        Err(_) => break,
                    },
                };
                if tx
                    .send(Ok(pb::SessionUpdate { kind: Some(update) }))
                    .await
                    .is_err()
                {
                    break;
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx).map(
            move |update| {
                let _attending = &attending;
                update
            },
        ))))
    }

    async fn get_anatomy(
        &self,
        request: Request<pb::GetAnatomyRequest>,
    ) -> Result<Response<pb::Anatomy>, Status> {
        let session = self.readable(&request, &request.get_ref().session_id)?;
        let assets = session.assets();
        let to_lps = |p: &nalgebra::Point3<f64>| {
            let v = assets.to_lps * p.coords;
            [v.x as f32 * 1e3, v.y as f32 * 1e3, v.z as f32 * 1e3]
        };
        let graph = &assets.anatomy.graph;
        let branches = graph
            .branches
            .iter()
            .map(|b| pb::Branch {
                name: b.name.clone(),
                points_mm: b.points.iter().flat_map(to_lps).collect(),
                radii_mm: b.radii.iter().map(|r| *r as f32 * 1e3).collect(),
            })
            .collect();
        let mesh = assets.anatomy.lumen.mesh();
        let access = assets.point_to_lps(&assets.entry.0) * 1e3;
        Ok(Response::new(pb::Anatomy {
            branches,
            vertices_mm: mesh.vertices.iter().flat_map(to_lps).collect(),
            triangles: mesh
                .triangles
                .iter()
                .flat_map(|t| t.iter().copied())
                .collect(),
            access_mm: Some(pb::Vec3 {
                x: access.x,
                y: access.y,
                z: access.z,
            }),
            target: assets.spec.target.branch.clone(),
        }))
    }

    async fn replay_session(
        &self,
        request: Request<pb::ReplaySessionRequest>,
    ) -> Result<Response<pb::ReplayResult>, Status> {
        let id = checked_id(&request.get_ref().session_id)?.to_owned();
        if self.engine.get(&id).is_ok() {
            // A live session: its trainee or an instructor (an observer only watches).
            let role =
                self.authorize(peer_of(&request), bearer(&request).as_deref(), &id, false)?;
            if role == Role::Observer {
                return Err(Status::permission_denied(
                    "replay is for the session's trainee and instructors, not its observers",
                ));
            }
        } else if !self.instructor(&request)? {
            return Err(
                if self.store.session(&id).map_err(store_status)?.is_some() {
                    Status::permission_denied(
                        "replaying a recorded session needs the instructor key",
                    )
                } else {
                    Status::not_found(format!("session {id:?}"))
                },
            );
        }
        // A place among the replays, then a niced thread of its own; a caller that goes away
        // abandons the replay (the guard below is dropped with this handler).
        // Queued behind reports, one per caller (a token's hash, else an address).
        let caller =
            bearer(&request).map_or_else(|| peer_of(&request).to_string(), |t| token_hash(&t));
        let place = self
            .reports
            .queue()
            .enter(crate::replays::Priority::Replay, &caller)
            .await?;
        let permit = self.engine.replay_permit().map_err(engine_status)?;
        let cancel = CancelOnDrop(Arc::new(AtomicBool::new(false)));
        let (engine, store, flag) = (self.engine.clone(), self.store.clone(), cancel.0.clone());
        let (done_tx, done_rx) = oneshot::channel();
        std::thread::Builder::new()
            .name("replay".into())
            .spawn(move || {
                cathlab_engine::priority::lower_current_thread(
                    cathlab_engine::priority::REPLAY_NICE,
                );
                let outcome = replay_stored(&engine, &store, &id, &flag);
                // The place is given back before the answer goes out: a caller that starts
                // another replay on hearing it must find the place free (a niced thread
                // could otherwise hold it for a while after answering).
                drop(permit);
                drop(place);
                let _ = done_tx.send(outcome);
            })
            .map_err(|e| Status::internal(format!("cannot start a replay thread: {e}")))?;
        let outcome = done_rx
            .await
            .map_err(|_| Status::internal("the replay thread ended without an answer"))??;
        drop(cancel);
        Ok(Response::new(outcome))
    }

    async fn create_account(
        &self,
        request: Request<pb::CreateAccountRequest>,
    ) -> Result<Response<pb::Account>, Status> {
        if !self.instructor(&request)? {
            return Err(Status::permission_denied(
                "creating accounts needs the instructor key or an instructor's account",
            ));
        }
        let r = request.into_inner();
        let name = r.name.trim();
        if name.is_empty() || name.len() > 100 {
            return Err(Status::invalid_argument("name: 1 to 100 bytes"));
        }
        let role = AccountRole::parse(&r.role)?;
        let token = random_hex(24);
        let account = StoredAccount {
            id: random_hex(8),
            name: name.to_owned(),
            role: role.as_str().to_owned(),
            token_hash: token_hash(&token),
            created_unix_s: unix_us() as f64 * 1e-6,
        };
        self.store.insert_account(&account).map_err(store_status)?;
        tracing::info!(account = %account.id, role = role.as_str(), "account created");
        Ok(Response::new(pb::Account {
            token,
            ..account_to_wire(&account)
        }))
    }

    async fn list_accounts(
        &self,
        request: Request<pb::ListAccountsRequest>,
    ) -> Result<Response<pb::ListAccountsResponse>, Status> {
        if !self.instructor(&request)? {
            return Err(Status::permission_denied(
                "listing accounts needs the instructor role",
            ));
        }
        let accounts = self.store.accounts().map_err(store_status)?;
        Ok(Response::new(pb::ListAccountsResponse {
            accounts: accounts.iter().map(account_to_wire).collect(),
        }))
    }

    async fn who_am_i(
        &self,
        request: Request<pb::WhoAmIRequest>,
    ) -> Result<Response<pb::Account>, Status> {
        match self.caller(&request)? {
            Caller::Account(a) => Ok(Response::new(account_to_wire(&a))),
            Caller::InstructorKey => Ok(Response::new(pb::Account {
                name: "instructor (server key)".into(),
                role: AccountRole::Instructor.as_str().into(),
                ..pb::Account::default()
            })),
            Caller::Other(token) => {
                if token.is_some() {
                    self.throttle
                        .failed(peer_of(&request), "a token of no account");
                }
                Err(Status::unauthenticated("the token is not an account's"))
            }
        }
    }

    async fn get_report(
        &self,
        request: Request<pb::GetReportRequest>,
    ) -> Result<Response<pb::Report>, Status> {
        let id = request.get_ref().session_id.clone();
        let session = self.report_reader(&request, &id)?;
        let report = self.reports.get(&session).await?;
        let trainee_name = match &session.account_id {
            Some(a) => self
                .store
                .account(a)
                .map_err(store_status)?
                .map(|a| a.name)
                .unwrap_or_default(),
            None => session.label.clone(),
        };
        Ok(Response::new(pb::Report {
            session_id: id,
            account_id: session.account_id.unwrap_or_default(),
            trainee_name,
            scene_name: session.scene_name,
            created_unix_s: session.created_unix_s,
            json: report.json,
        }))
    }

    async fn get_report_frame(
        &self,
        request: Request<pb::GetReportFrameRequest>,
    ) -> Result<Response<pb::ReportFrame>, Status> {
        let (id, index) = (
            request.get_ref().session_id.clone(),
            request.get_ref().index,
        );
        self.report_reader(&request, &id)?;
        let (time_s, png) = self
            .store
            .report_frame(&id, index)
            .map_err(store_status)?
            .ok_or_else(|| {
                Status::not_found(format!(
                    "frame {index} of session {id:?}'s report (is the report made?)"
                ))
            })?;
        Ok(Response::new(pb::ReportFrame { time_s, png }))
    }

    async fn get_history(
        &self,
        request: Request<pb::GetHistoryRequest>,
    ) -> Result<Response<pb::History>, Status> {
        let caller = self.caller(&request)?;
        let wanted = request.get_ref().account_id.clone();
        let account = match (&caller, wanted.is_empty()) {
            (Caller::Account(a), true) => a.clone(),
            (Caller::Account(a), false) if a.id == wanted => a.clone(),
            (Caller::InstructorKey | Caller::Account(_), false) if caller.is_instructor() => {
                checked_id(&wanted).map_err(|e| {
                    Status::invalid_argument(e.message().replacen("session_id", "account_id", 1))
                })?;
                self.store
                    .account(&wanted)
                    .map_err(store_status)?
                    .ok_or_else(|| Status::not_found(format!("account {wanted:?}")))?
            }
            (Caller::Account(_) | Caller::InstructorKey, false) => {
                return Err(Status::permission_denied(
                    "another trainee's history needs the instructor role",
                ));
            }
            (Caller::InstructorKey, true) => {
                return Err(Status::invalid_argument(
                    "account_id: the instructor key has no history of its own; name a trainee",
                ));
            }
            (Caller::Other(token), _) => {
                // A token that is nobody's is a guess, counted as every other.
                if token.is_some() {
                    self.throttle
                        .failed(peer_of(&request), "a token of no account");
                }
                return Err(Status::unauthenticated(
                    "a history needs an account's token or the instructor role",
                ));
            }
        };
        let mut entries = Vec::new();
        for s in self.store.sessions_of(&account.id).map_err(store_status)? {
            let report = self.store.report(&s.id).ok().flatten();
            let expert = serde_json::from_str::<SceneSpec>(&s.scene_json)
                .map(|spec| spec.assessment.expert.into_iter().collect())
                .unwrap_or_default();
            entries.push(pb::HistoryEntry {
                session_id: s.id,
                scene_name: s.scene_name,
                created_unix_s: s.created_unix_s,
                assessed: report.is_some(),
                within: report.as_ref().map_or(0, |r| r.within),
                judged: report.as_ref().map_or(0, |r| r.judged),
                metrics: report
                    .map(|r| r.metrics.into_iter().collect())
                    .unwrap_or_default(),
                expert,
            });
        }
        Ok(Response::new(pb::History {
            account: Some(account_to_wire(&account)),
            entries,
        }))
    }
}

fn account_to_wire(a: &StoredAccount) -> pb::Account {
    pb::Account {
        account_id: a.id.clone(),
        name: a.name.clone(),
        role: a.role.clone(),
        token: String::new(),
        created_unix_s: a.created_unix_s,
    }
}

/// Sets its flag when dropped: work on another thread sees that its caller went away.
struct CancelOnDrop(Arc<AtomicBool>);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// Replays a stored session from the store (also used by `cathlab-server replay`).
/// `cancel` abandons it.
pub fn replay_stored(
    engine: &Engine,
    store: &Store,
    id: &str,
    cancel: &AtomicBool,
) -> Result<pb::ReplayResult, Status> {
    let stored = store
        .session(id)
        .map_err(store_status)?
        .ok_or_else(|| Status::not_found(format!("session {id:?}")))?;
    let spec: SceneSpec = serde_json::from_str(&stored.scene_json)
        .map_err(|e| Status::internal(format!("stored scene of {id}: {e}")))?;
    let assets = engine
        .load(&spec, Path::new(&stored.base_dir))
        .map_err(engine_status)?;
    let commands = store.commands(id).map_err(store_status)?;
    let checkpoints = store.checkpoints(id).map_err(store_status)?;
    let outcome = cathlab_engine::replay_until(assets, &commands, &checkpoints, cancel)
        .map_err(engine_status)?;
    Ok(pb::ReplayResult {
        steps: outcome.steps,
        commands: outcome.commands as u32,
        checkpoints: outcome.checkpoints as u32,
        matched: outcome.matched as u32,
        recorded_digest: format!("{:016x}", outcome.recorded_digest),
        replayed_digest: format!("{:016x}", outcome.replayed_digest),
        metrics: Some(metrics_to_wire(&outcome.metrics)),
    })
}

fn guidance_to_wire(g: &GuidanceSpec) -> pb::Guidance {
    pb::Guidance {
        target_marker: g.target_marker,
        target_distance: g.target_distance,
        prompts: g.prompts,
    }
}
