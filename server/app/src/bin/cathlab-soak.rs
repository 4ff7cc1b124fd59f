//! `cathlab-soak`: the server under a long, seeded, random mix of what clients do, valid and
//! invalid — sessions created and closed, commands in and out of range, frame, state and
//! control streams opened and abandoned or stalled, wrong secrets, hostile scenes, garbage on
//! the port, floods of HTTP/2 streams that never finish their messages, HTTP/1.1 bodies that
//! stall or never start, sockets that say nothing, scenes naming decompression bombs — beside
//! one well-behaved control session, until the server has run a given number of physics
//! steps. It runs in rounds; after each, the random clients stop, their sessions close and the
//! server's resident memory is read at rest. It fails (exit status 1) on a panic in the
//! server's log, an INTERNAL or UNKNOWN answer, another answer the server must not give (a
//! bomb accepted or refused without naming its field, a stalled connection the server keeps
//! past its timeouts), a missed step in the control session, resting resident memory (VmRSS)
//! or resting live heap (the bytes the server's counting allocator has out: what a leak
//! grows, whatever the allocator keeps) more than 10 % above the first round's, or a server
//! that stops answering. Resting anonymous memory is shown beside them. Every connection goes
//! to the server it started on 127.0.0.1.

mod harness;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use bytes::Bytes;
use cathlab_api::authorized as authed;
use cathlab_api::pb;
use cathlab_api::pb::simulator_client::SimulatorClient;
use clap::Parser;
use harness::{Server, ServerArgs};
use parking_lot::Mutex;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use tonic::transport::Channel;

#[derive(Debug, Parser)]
#[command(name = "cathlab-soak", about = "cathlab server soak test")]
struct Cli {
    /// Physics steps (all sessions together, from the server's metrics) to run.
    #[arg(long, default_value_t = 1_000_000)]
    steps: u64,
    /// Seconds of random clients per round.
    #[arg(long, default_value_t = 30.0)]
    round_seconds: f64,
    /// Give up (and fail) after this many seconds.
    #[arg(long, default_value_t = 7200.0)]
    max_seconds: f64,
    /// Random clients at once (each holds at most one session of its own).
    #[arg(long, default_value_t = 3)]
    clients: usize,
    /// Seed of the random clients.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Resting resident memory and live heap may each grow this fraction over the first
    /// round's.
    #[arg(long, default_value_t = 0.10)]
    rss_tolerance: f64,
    /// The watched session may miss this fraction of its steps (default none: the release
    /// soak holds real time throughout). The short smoke under `cargo test` runs a debug
    /// server on two shared cores, where one scheduling stall of tens of milliseconds is the
    /// machine, not the server; a client that hurts a bystander misses far more.
    #[arg(long, default_value_t = 0.0)]
    missed_tolerance: f64,
    /// Only these actions (comma-separated; default all, at their usual weights): to find
    /// which one grows memory.
    #[arg(long, value_enum, value_delimiter = ',')]
    actions: Vec<Action>,
    #[command(flatten)]
    target: ServerArgs,
}

/// What a random client may do, and how often (relative weights).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Action {
    Create,
    Close,
    ValidCommand,
    InvalidCommand,
    Frames,
    Control,
    Watch,
    Query,
    HostileScene,
    Garbage,
    Replay,
    /// An HTTP/2 connection opening up to 100 streams, each a message begun and stalled.
    H2Flood,
    /// HTTP/1.1 gRPC-Web requests whose bodies stop part-way.
    StalledBody,
    /// Requests (HTTP/1.1 and HTTP/2) whose bodies never start.
    BodyNeverStarts,
    /// Sockets that never send a byte.
    IdleSockets,
    /// Inline scenes whose CT is a decompression bomb or a header declaring too many voxels.
    BombFile,
}

impl Action {
    const ALL: [Action; 16] = [
        Action::Create,
        Action::Close,
        Action::ValidCommand,
        Action::InvalidCommand,
        Action::Frames,
        Action::Control,
        Action::Watch,
        Action::Query,
        Action::HostileScene,
        Action::Garbage,
        Action::Replay,
        Action::H2Flood,
        Action::StalledBody,
        Action::BodyNeverStarts,
        Action::IdleSockets,
        Action::BombFile,
    ];

    fn weight(self) -> u32 {
        match self {
            Action::Create => 8,
            Action::Close => 3,
            Action::ValidCommand => 30,
            Action::InvalidCommand => 15,
            Action::Frames => 10,
            Action::Control => 8,
            Action::Watch => 8,
            Action::Query => 8,
            Action::HostileScene => 5,
            Action::Garbage => 3,
            Action::Replay => 2,
            Action::H2Flood => 3,
            Action::StalledBody => 3,
            Action::BodyNeverStarts => 2,
            Action::IdleSockets => 3,
            Action::BombFile => 4,
        }
    }

    /// How many times one client may start it in a round (the connection attacks run in
    /// tasks of their own, each bounded in time; these bound how many sockets they hold).
    fn per_round(self) -> u32 {
        match self {
            Action::H2Flood | Action::BodyNeverStarts => 2,
            Action::StalledBody | Action::IdleSockets => 3,
            Action::BombFile => 6,
            _ => u32::MAX,
        }
    }
}

const KEY: &str = "soak-instructor-key";
const SCENE: &str = "arch_to_cow_lcca";

/// How long a connection may be idle, and a request message take to arrive (the soak's
/// `connection_idle_timeout_s` and `message_read_timeout_s`: short, so that the connection
/// attacks resolve within a round).
const IDLE_TIMEOUT_S: u64 = 5;
const MESSAGE_TIMEOUT_S: u64 = 3;

/// The server's limits for the soak: tight timeouts so that stalls and silences are met often;
/// a throttle high enough that the random wrong secrets do not lock the control session out
/// (the throttle has its own attack test); per-client session limits and a per-address
/// connection limit high enough that the random clients, all on 127.0.0.1, and the soak's own
/// reads of `/metrics` are never refused for them (those limits have their own attack tests);
/// a small request buffer, so that HTTP/2 floods meet it; and `data_roots` with the directory
/// of the bomb files.
fn config(data_roots: &[PathBuf]) -> String {
    let roots: Vec<String> = data_roots
        .iter()
        .map(|r| format!("{:?}", r.display().to_string()))
        .collect();
    format!(
        "max_sessions = 8\nmax_replays = 1\ncontrol_timeout_ms = 250\n\
         stream_stall_timeout_ms = 2000\nstream_buffer_mib = 64\n\
         auth_failures_per_minute = 100000\ncontrol_inputs_per_second = 2000\n\
         max_sessions_per_client = 8\nsession_creations_per_minute = 100000\n\
         max_connections_per_address = 192\nconnection_idle_timeout_s = {IDLE_TIMEOUT_S}\n\
         message_read_timeout_s = {MESSAGE_TIMEOUT_S}\nrequest_buffer_mib = 16\n\
         data_roots = [{}]\n",
        roots.join(", ")
    )
}

/// The tally's rows of the connection and file attacks, printed after each round.
const ATTACK_ROWS: [&str; 7] = [
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
struct Tally {
    answers: Mutex<BTreeMap<(&'static str, String), u64>>,
    /// The first message seen for each (action, code).
    examples: Mutex<BTreeMap<(&'static str, String), String>>,
    /// INTERNAL or UNKNOWN answers, and other answers the server must not give, with what
    /// was asked.
    faults: Mutex<Vec<String>>,
    actions: AtomicU64,
}

impl Tally {
    /// Counts one outcome that is not a tonic status (a socket closed, a stream reset).
    fn row(&self, action: &'static str, outcome: impl Into<String>, n: u64) {
        if n > 0 {
            *self
                .answers
                .lock()
                .entry((action, outcome.into()))
                .or_default() += n;
        }
    }

    /// An answer the server must not give.
    fn wrong(&self, what: String) {
        self.faults.lock().push(what);
    }

    fn answer<T>(&self, action: &'static str, result: &Result<T, tonic::Status>) {
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

/// One random client: its connection, its session, its sequence numbers.
struct Chaos {
    rng: StdRng,
    url: String,
    address: String,
    client: SimulatorClient<Channel>,
    session: Option<pb::CreateSessionResponse>,
    seq: u64,
    tally: Arc<Tally>,
    /// Streams left stalled, dropped by their own tasks.
    stalls: Vec<tokio::task::JoinHandle<()>>,
    /// What it may do (never empty).
    actions: Vec<Action>,
    /// The bomb scenes.
    bombs: Arc<Bombs>,
    /// How many times each action was started this round.
    started: BTreeMap<&'static str, u32>,
}

fn command(kind: pb::command::Kind) -> Option<pb::Command> {
    Some(pb::Command {
        kind: Some(kind),
        instrument: None,
    })
}

fn speed(mm_s: f64, hold: bool) -> pb::command::Kind {
    pb::command::Kind::Insertion(pb::Insertion {
        mode: Some(pb::insertion::Mode::VelocityMmS(mm_s)),
        hold,
    })
}

impl Chaos {
    async fn new(
        url: String,
        address: String,
        seed: u64,
        tally: Arc<Tally>,
        actions: Vec<Action>,
        bombs: Arc<Bombs>,
    ) -> Result<Self> {
        let client = SimulatorClient::connect(url.clone())
            .await?
            .max_decoding_message_size(64 << 20);
        Ok(Self {
            rng: StdRng::seed_from_u64(seed),
            url,
            address,
            client,
            session: None,
            seq: 0,
            tally,
            stalls: Vec::new(),
            actions,
            bombs,
            started: BTreeMap::new(),
        })
    }

    /// Whether `action` may start again this round (and counts it).
    fn budget(&mut self, action: Action) -> bool {
        let name: &'static str = match action {
            Action::H2Flood => "h2 flood",
            Action::StalledBody => "stalled body",
            Action::BodyNeverStarts => "body never starts",
            Action::IdleSockets => "idle socket",
            Action::BombFile => "bomb file",
            _ => return true,
        };
        let n = self.started.entry(name).or_default();
        *n += 1;
        *n <= action.per_round()
    }

    fn pick<T: Clone>(&mut self, items: &[T]) -> T {
        items[self.rng.random_range(0..items.len())].clone()
    }

    /// A session id and token: this client's, or (rarely) a wrong one.
    fn target(&mut self) -> (String, String) {
        let own = self
            .session
            .as_ref()
            .map(|s| (s.session_id.clone(), s.controller_token.clone()));
        match (own, self.rng.random_range(0..20)) {
            (Some((id, _)), 0) => (id, "not-a-token".into()),
            (_, 1) => ("no-such-session".into(), "not-a-token".into()),
            (Some(own), _) => own,
            (None, _) => ("no-such-session".into(), KEY.into()),
        }
    }

    async fn act(&mut self) {
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

    async fn create(&mut self) -> Result<()> {
        if self.session.is_some() {
            return self.close().await;
        }
        let created = self
            .client
            .create_session(pb::CreateSessionRequest {
                scene: Some(pb::create_session_request::Scene::SceneName(SCENE.into())),
                label: format!("soak {}", self.rng.random_range(0..1000)),
                ..Default::default()
            })
            .await
            .map(|r| r.into_inner());
        self.tally.answer("create", &created);
        if let Ok(s) = created {
            self.session = Some(s);
            self.seq = 0;
        }
        Ok(())
    }

    async fn close(&mut self) -> Result<()> {
        let Some(s) = self.session.take() else {
            return Ok(());
        };
        if self.rng.random_bool(0.3) {
            let wrong = self
                .client
                .close_session(authed(
                    pb::CloseSessionRequest {
                        session_id: s.session_id.clone(),
                    },
                    &s.observer_token,
                ))
                .await;
            self.tally.answer("close as observer", &wrong);
        }
        let closed = self
            .client
            .close_session(authed(
                pb::CloseSessionRequest {
                    session_id: s.session_id.clone(),
                },
                &s.controller_token,
            ))
            .await;
        self.tally.answer("close", &closed);
        Ok(())
    }

    async fn send(&mut self, action: &'static str, command: Option<pb::Command>, seq: u64) {
        let (session_id, token) = self.target();
        let sent = self
            .client
            .send_command(authed(
                pb::SendCommandRequest {
                    session_id,
                    seq,
                    command,
                },
                &token,
            ))
            .await;
        self.tally.answer(action, &sent);
    }

    async fn valid_command(&mut self) -> Result<()> {
        use pb::command::Kind;
        let r = &mut self.rng;
        let kind = match r.random_range(0..12) {
            0..4 => speed(r.random_range(-40.0..40.0), r.random_bool(0.5)),
            4 => Kind::Twist(pb::Twist {
                mode: Some(pb::twist::Mode::RateDegS(r.random_range(-180.0..180.0))),
                hold: r.random_bool(0.5),
            }),
            5 => Kind::Fluoroscopy(r.random_bool(0.6)),
            6 => Kind::PulseRate(r.random_range(1..4)),
            7 => Kind::Carm(pb::CArmPose {
                primary_deg: r.random_range(-120.0..120.0),
                secondary_deg: r.random_range(-60.0..60.0),
            }),
            8 => Kind::Inject(pb::Injection {
                volume_ml: r.random_range(1.0..20.0),
                rate_ml_s: r.random_range(1.0..10.0),
            }),
            9 => Kind::SelectDevice(r.random_range(0..3)),
            10 => Kind::Dsa(r.random_bool(0.5)),
            _ => Kind::Reset(true),
        };
        // A speed sometimes names the instrument (the only one of this one-device scene).
        let mut valid = command(kind);
        if let Some(c) = valid.as_mut()
            && matches!(c.kind, Some(Kind::Insertion(_)) | Some(Kind::Twist(_)))
            && r.random_bool(0.3)
        {
            c.instrument = Some(0);
        }
        self.seq += 1;
        let seq = self.seq;
        self.send("valid command", valid, seq).await;
        Ok(())
    }

    async fn invalid_command(&mut self) -> Result<()> {
        use pb::command::Kind;
        let r = &mut self.rng;
        // An instrument the scene does not have, or an exchange it cannot make (a one-device
        // scene; an unknown catalogue entry or spare).
        let instrument = r
            .random_bool(0.15)
            .then(|| [1, 2, 7, u32::MAX][r.random_range(0..4)]);
        let kind = match r.random_range(0..11) {
            9 => Some(Kind::Exchange(pb::Exchange {
                instrument: r.random_range(0..3),
                device: Some(pb::exchange::Device::CatalogueId(
                    [
                        "no-such-wire",
                        "",
                        "guidewire-035-j-3mm",
                        "../../etc/passwd",
                    ][r.random_range(0..4)]
                    .into(),
                )),
            })),
            10 => Some(Kind::Exchange(pb::Exchange {
                instrument: r.random_range(0..3),
                device: r
                    .random_bool(0.5)
                    .then_some(pb::exchange::Device::Spare(u32::MAX)),
            })),
            0 => Some(speed(f64::NAN, false)),
            1 => Some(speed(f64::INFINITY, true)),
            2 => Some(speed(1e9, false)),
            3 => Some(Kind::Carm(pb::CArmPose {
                primary_deg: 500.0,
                secondary_deg: f64::NAN,
            })),
            4 => Some(Kind::Inject(pb::Injection {
                volume_ml: -1.0,
                rate_ml_s: 1e6,
            })),
            5 => Some(Kind::SelectDevice(u32::MAX)),
            6 => Some(Kind::PulseRate(99)),
            7 => Some(Kind::Insertion(pb::Insertion {
                mode: None,
                hold: false,
            })),
            _ => None,
        };
        // Sometimes an old sequence number instead.
        let seq = if r.random_bool(0.2) { 0 } else { self.seq + 1 };
        self.seq = self.seq.max(seq);
        self.send(
            "invalid command",
            kind.map(|k| pb::Command {
                kind: Some(k),
                instrument,
            }),
            seq,
        )
        .await;
        Ok(())
    }

    /// A frame stream read for a few frames, then dropped, or left stalled for a while.
    async fn frames(&mut self) -> Result<()> {
        let Some(s) = self.session.clone() else {
            return self.create().await;
        };
        let r = &mut self.rng;
        let encoding = r.random_range(0..5);
        let size = [0u32, 16, 128, 512, 1024, 2048, 5, 4096][r.random_range(0..8)];
        let request = pb::StreamFramesRequest {
            session_id: s.session_id.clone(),
            encoding,
            width: size,
            height: if r.random_bool(0.8) { size } else { 700 },
            jpeg_quality: r.random_range(0..120),
        };
        let read = r.random_range(0..4);
        let stall = r.random_bool(0.3).then(|| r.random_range(0..4000));
        // Its own connection, as a browser tab's would be.
        let mut own = SimulatorClient::connect(self.url.clone())
            .await?
            .max_decoding_message_size(64 << 20);
        let opened = own
            .stream_frames(authed(request, &s.observer_token))
            .await
            .map(|r| r.into_inner());
        self.tally.answer("frame stream", &opened);
        let Ok(mut frames) = opened else {
            return Ok(());
        };
        for _ in 0..read {
            match tokio::time::timeout(Duration::from_secs(2), frames.message()).await {
                Ok(Ok(Some(_))) => {}
                Ok(Err(status)) => {
                    self.tally.answer::<()>("frame stream read", &Err(status));
                    break;
                }
                _ => break,
            }
        }
        if let Some(ms) = stall {
            self.stalls.push(tokio::spawn(async move {
                tokio::time::sleep(Duration::from_millis(ms)).await;
                drop((frames, own));
            }));
        }
        Ok(())
    }

    /// A control stream: inputs at about 100 Hz, some bad, ended by a half-close, a hang-up or
    /// silence.
    async fn control(&mut self) -> Result<()> {
        let Some(s) = self.session.clone() else {
            return self.create().await;
        };
        let mut own = SimulatorClient::connect(self.url.clone()).await?;
        let (tx, rx) = tokio::sync::mpsc::channel(256);
        let first_seq = self.seq + 1;
        tx.send(pb::ControlInput {
            session_id: s.session_id.clone(),
            seq: first_seq,
            push_mm_s: 5.0,
            twist_deg_s: 0.0,
            hands: Vec::new(),
        })
        .await?;
        let opened = own
            .control(authed(
                tokio_stream::wrappers::ReceiverStream::new(rx),
                &s.controller_token,
            ))
            .await
            .map(|r| r.into_inner());
        self.tally.answer("control stream", &opened);
        let Ok(mut outputs) = opened else {
            return Ok(());
        };
        let drain = tokio::spawn(async move {
            loop {
                match outputs.message().await {
                    Ok(Some(_)) => continue,
                    Ok(None) => return None,
                    Err(status) => return Some(status),
                }
            }
        });
        let n = self.rng.random_range(1..100);
        let mut seq = first_seq;
        let mut tick = tokio::time::interval(Duration::from_millis(10));
        for _ in 0..n {
            tick.tick().await;
            seq += 1;
            let r = &mut self.rng;
            let (push, twist, seq_sent) = match r.random_range(0..50) {
                0 => (f64::NAN, 0.0, seq),
                1 => (1e12, 0.0, seq),
                2 => (5.0, 0.0, seq.saturating_sub(5)),
                _ => (
                    r.random_range(-30.0..30.0),
                    r.random_range(-90.0..90.0),
                    seq,
                ),
            };
            if tx
                .send(pb::ControlInput {
                    session_id: String::new(),
                    seq: seq_sent,
                    push_mm_s: push,
                    twist_deg_s: twist,
                    hands: Vec::new(),
                })
                .await
                .is_err()
            {
                break;
            }
        }
        self.seq = seq;
        match self.rng.random_range(0..3) {
            0 => {
                drop(tx);
                let end = tokio::time::timeout(Duration::from_secs(3), drain).await;
                if let Ok(Ok(Some(status))) = end {
                    self.tally.answer::<()>("control stream end", &Err(status));
                }
            }
            1 => {
                drain.abort();
                drop((tx, own));
            }
            _ => {
                tokio::time::sleep(Duration::from_millis(400)).await;
                drain.abort();
                drop((tx, own));
            }
        }
        Ok(())
    }

    /// A state or metrics stream read briefly, then dropped.
    async fn watch(&mut self) -> Result<()> {
        let (session_id, token) = self.target();
        if self.rng.random_bool(0.5) {
            let opened = self
                .client
                .stream_state(authed(
                    pb::StreamStateRequest {
                        session_id,
                        tip_only: self.rng.random_bool(0.5),
                    },
                    &token,
                ))
                .await
                .map(|r| r.into_inner());
            self.tally.answer("state stream", &opened);
            if let Ok(mut states) = opened {
                for _ in 0..self.rng.random_range(0..50) {
                    if !matches!(states.message().await, Ok(Some(_))) {
                        break;
                    }
                }
            }
        } else {
            let opened = self
                .client
                .stream_metrics(authed(pb::StreamMetricsRequest { session_id }, &token))
                .await
                .map(|r| r.into_inner());
            self.tally.answer("metrics stream", &opened);
            if let Ok(mut updates) = opened {
                let _ = tokio::time::timeout(Duration::from_millis(300), updates.message()).await;
            }
        }
        Ok(())
    }

    async fn query(&mut self) -> Result<()> {
        let (session_id, token) = self.target();
        match self.rng.random_range(0..4) {
            0 => {
                let r = self.client.list_scenes(pb::ListScenesRequest {}).await;
                self.tally.answer("list scenes", &r);
            }
            1 => {
                let key = if self.rng.random_bool(0.8) {
                    KEY
                } else {
                    "wrong-key"
                };
                let r = self
                    .client
                    .list_sessions(authed(
                        pb::ListSessionsRequest {
                            include_recorded: self.rng.random_bool(0.5),
                            ..Default::default()
                        },
                        key,
                    ))
                    .await;
                self.tally.answer("list sessions", &r);
            }
            2 => {
                let r = self
                    .client
                    .get_session(authed(pb::GetSessionRequest { session_id }, &token))
                    .await;
                self.tally.answer("get session", &r);
            }
            _ => {
                let r = self
                    .client
                    .get_anatomy(authed(pb::GetAnatomyRequest { session_id }, &token))
                    .await;
                self.tally.answer("get anatomy", &r);
            }
        }
        Ok(())
    }

    /// Inline scenes that must be refused: unparsable, naming files outside the data roots,
    /// out of range, or sent without the instructor key.
    async fn hostile_scene(&mut self) -> Result<()> {
        let scenes = [
            "this is not toml [[[".to_owned(),
            "name = \"x\"\n[anatomy]\nkind = \"volume\"\nvolume = \"/etc/hostname\"\n".to_owned(),
            "name = \"x\"\n[ct]\npath = \"../../../etc/passwd\"\n".to_owned(),
            format!("name = \"x{}\"\n[fidelity]\nstep_rate_hz = 1e9\n", self.seq),
            "x".repeat(self.rng.random_range(1..200_000)),
        ];
        let text = self.pick(&scenes);
        let key = if self.rng.random_bool(0.7) { KEY } else { "" };
        let r = self
            .client
            .create_session(authed(
                pb::CreateSessionRequest {
                    scene: Some(pb::create_session_request::Scene::SceneToml(text)),
                    label: "hostile".into(),
                    ..Default::default()
                },
                key,
            ))
            .await;
        if let Ok(created) = &r {
            // Nothing above is a valid scene: say so, and give the place back.
            self.tally
                .faults
                .lock()
                .push("a hostile inline scene was accepted".into());
            let _ = self
                .client
                .close_session(authed(
                    pb::CloseSessionRequest {
                        session_id: created.get_ref().session_id.clone(),
                    },
                    &created.get_ref().controller_token,
                ))
                .await;
        }
        self.tally.answer("hostile scene", &r);
        Ok(())
    }

    /// Bytes that are not what the port expects: random bytes, or a gRPC-Web call whose body
    /// is not a protobuf message.
    async fn garbage(&mut self) -> Result<()> {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut stream = tokio::net::TcpStream::connect(&self.address).await?;
        let bytes: Vec<u8> = if self.rng.random_bool(0.5) {
            (0..self.rng.random_range(1..4096))
                .map(|_| self.rng.random())
                .collect()
        } else {
            let body: Vec<u8> = (0..64).map(|_| self.rng.random()).collect();
            let mut framed = vec![0u8];
            framed.extend_from_slice(&(body.len() as u32).to_be_bytes());
            framed.extend_from_slice(&body);
            let mut request = format!(
                "POST /cathlab.v1.Simulator/SendCommand HTTP/1.1\r\nHost: {}\r\n\
                 content-type: application/grpc-web+proto\r\nx-grpc-web: 1\r\n\
                 content-length: {}\r\nConnection: close\r\n\r\n",
                self.address,
                framed.len()
            )
            .into_bytes();
            request.extend_from_slice(&framed);
            request
        };
        stream.write_all(&bytes).await?;
        let mut answer = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(2), stream.read_to_end(&mut answer)).await;
        let text = String::from_utf8_lossy(&answer);
        let code = if text.contains("grpc-status: 13") || text.contains("grpc-status:13") {
            self.tally
                .faults
                .lock()
                .push("garbage answered INTERNAL".into());
            "INTERNAL"
        } else if text.starts_with("HTTP/1.1") {
            "answered"
        } else {
            "closed"
        };
        *self
            .tally
            .answers
            .lock()
            .entry(("garbage", code.into()))
            .or_default() += 1;
        Ok(())
    }

    /// A replay of this client's session, abandoned after a moment.
    async fn replay(&mut self) -> Result<()> {
        let (session_id, token) = self.target();
        let mut client = self.client.clone();
        let wait = Duration::from_millis(self.rng.random_range(0..1500));
        let r = tokio::time::timeout(
            wait,
            client.replay_session(authed(pb::ReplaySessionRequest { session_id }, &token)),
        )
        .await;
        if let Ok(r) = r {
            self.tally.answer("replay", &r);
        }
        Ok(())
    }

    /// An HTTP/2 connection (prior knowledge) opening 16–100 streams to GetSession, each a
    /// gRPC message header declaring 900 KiB and part of it, then nothing more: the server
    /// must cut each (DEADLINE_EXCEEDED after `message_read_timeout_s`, RESOURCE_EXHAUSTED
    /// when the request buffer is full, or a reset). Runs in a task of its own; streams not
    /// opened within the first wave's timeout and a half are counted and given up.
    fn h2_flood(&mut self) -> Result<()> {
        let streams = self.rng.random_range(16..=100);
        let sent = [1 << 10, 64 << 10, 256 << 10, 880 << 10][self.rng.random_range(0..4)];
        let body = partial_message(900 << 10, sent);
        let (tally, address) = (self.tally.clone(), self.address.clone());
        self.stalls.push(tokio::spawn(async move {
            h2_streams(&tally, "h2 flood", &address, streams, Some(body)).await;
        }));
        Ok(())
    }

    /// 1–3 HTTP/1.1 gRPC-Web POSTs whose content-length says 900 KiB more than the body's
    /// first 3 bytes to 512 KiB, then silence: answered DEADLINE_EXCEEDED (or
    /// RESOURCE_EXHAUSTED) and closed. Runs in a task of its own.
    fn stalled_body(&mut self) -> Result<()> {
        for _ in 0..self.rng.random_range(1..=3) {
            let sent = [3, 1 << 10, 64 << 10, 512 << 10][self.rng.random_range(0..4)];
            let mut request = web_post_head(&self.address, 5 + (900 << 10));
            request.extend_from_slice(&partial_message(900 << 10, sent)[..sent.max(3)]);
            let (tally, address) = (self.tally.clone(), self.address.clone());
            self.stalls.push(tokio::spawn(async move {
                http1_stall(&tally, "stalled body", &address, request).await;
            }));
        }
        Ok(())
    }

    /// Requests whose bodies never start: 1–3 HTTP/1.1 gRPC-Web POSTs declaring a body and
    /// sending only their headers, or an HTTP/2 connection with 1–8 streams of headers only.
    /// Neither timeout may be dodged: each must be answered or closed. Runs in a task of
    /// its own.
    fn body_never_starts(&mut self) -> Result<()> {
        let (tally, address) = (self.tally.clone(), self.address.clone());
        if self.rng.random_bool(0.5) {
            let streams = self.rng.random_range(1..=8);
            self.stalls.push(tokio::spawn(async move {
                h2_streams(&tally, "body never starts h2", &address, streams, None).await;
            }));
        } else {
            for _ in 0..self.rng.random_range(1..=3) {
                let request = web_post_head(&self.address, 5 + (900 << 10));
                let (tally, address) = (tally.clone(), address.clone());
                self.stalls.push(tokio::spawn(async move {
                    http1_stall(&tally, "body never starts", &address, request).await;
                }));
            }
        }
        Ok(())
    }

    /// 1–4 sockets that connect and send nothing: the server closes each after
    /// `connection_idle_timeout_s`. Runs in a task of its own.
    fn idle_sockets(&mut self) -> Result<()> {
        for _ in 0..self.rng.random_range(1..=4) {
            let (tally, address) = (self.tally.clone(), self.address.clone());
            self.stalls.push(tokio::spawn(async move {
                let end = raw_exchange(&address, Vec::new(), stall_limit()).await;
                match end.closed_after {
                    None => tally.wrong(format!(
                        "an idle socket was still open after {} s \
                         (connection_idle_timeout_s {IDLE_TIMEOUT_S})",
                        stall_limit().as_secs()
                    )),
                    Some(after) if after.as_secs_f64() < IDLE_TIMEOUT_S as f64 - 0.5 => {
                        tally.row("idle socket", "closed at once", 1);
                    }
                    Some(_) => tally.row("idle socket", "closed by the idle timeout", 1),
                }
                if !end.received.is_empty() {
                    tally.row("idle socket", "sent bytes it was not asked for", 1);
                }
            }));
        }
        Ok(())
    }

    /// An instructor's inline scene whose CT is one of the bomb files: INVALID_ARGUMENT
    /// naming `ct.path` and saying "refused:", no path.
    async fn bomb_file(&mut self) -> Result<()> {
        let bombs = self.bombs.clone();
        let (name, text) = self.pick(&bombs.scenes);
        let r = self
            .client
            .create_session(authed(
                pb::CreateSessionRequest {
                    scene: Some(pb::create_session_request::Scene::SceneToml(text)),
                    label: "bomb".into(),
                    ..Default::default()
                },
                KEY,
            ))
            .await;
        match &r {
            Ok(created) => {
                self.tally.wrong(format!("the bomb {name} was accepted"));
                let _ = self
                    .client
                    .close_session(authed(
                        pb::CloseSessionRequest {
                            session_id: created.get_ref().session_id.clone(),
                        },
                        &created.get_ref().controller_token,
                    ))
                    .await;
            }
            Err(s) if s.code() == tonic::Code::InvalidArgument => {
                let m = s.message();
                if !m.contains("ct.path") || !m.contains("refused:") {
                    self.tally.wrong(format!(
                        "the bomb {name} was refused without naming ct.path and saying \
                         \"refused:\": {m}"
                    ));
                }
                if m.contains(&self.bombs.dir) {
                    self.tally.wrong(format!(
                        "the refusal of the bomb {name} shows its path: {m}"
                    ));
                }
            }
            // A full server or a throttle may answer first: counted, not judged.
            Err(s)
                if matches!(
                    s.code(),
                    tonic::Code::ResourceExhausted | tonic::Code::Unavailable
                ) => {}
            Err(s) => {
                if !matches!(s.code(), tonic::Code::Internal | tonic::Code::Unknown) {
                    self.tally.wrong(format!(
                        "the bomb {name} was answered {:?}: {}",
                        s.code(),
                        s.message()
                    ));
                }
            }
        }
        self.tally.answer("bomb file", &r);
        Ok(())
    }

    /// Closes this client's session and waits for its stalled streams to be dropped.
    async fn finish(mut self) {
        let _ = self.close().await;
        for s in self.stalls.drain(..) {
            let _ = s.await;
        }
    }
}

/// A gRPC message header declaring `declared` bytes, then `sent` zero bytes of it.
fn partial_message(declared: usize, sent: usize) -> Bytes {
    let mut body = Vec::with_capacity(5 + sent);
    body.push(0);
    body.extend_from_slice(&(declared as u32).to_be_bytes());
    body.resize(5 + sent, 0);
    Bytes::from(body)
}

/// How long a stalled request or a silent socket is given before it counts as kept open:
/// both timeouts and a margin for a loaded machine.
fn stall_limit() -> Duration {
    Duration::from_secs(MESSAGE_TIMEOUT_S + IDLE_TIMEOUT_S + 4)
}

/// The head of an HTTP/1.1 gRPC-Web POST to GetSession declaring a body of `length` bytes.
fn web_post_head(address: &str, length: usize) -> Vec<u8> {
    format!(
        "POST /cathlab.v1.Simulator/GetSession HTTP/1.1\r\nHost: {address}\r\n\
         content-type: application/grpc-web+proto\r\nx-grpc-web: 1\r\n\
         content-length: {length}\r\n\r\n"
    )
    .into_bytes()
}

/// The number after the first `grpc-status:` in `bytes` (HTTP/1.1 headers or a gRPC-Web
/// trailers frame).
fn grpc_status_in(bytes: &[u8]) -> Option<u32> {
    let text = String::from_utf8_lossy(bytes).to_ascii_lowercase();
    let at = text.find("grpc-status:")? + "grpc-status:".len();
    text[at..]
        .trim_start()
        .chars()
        .take_while(char::is_ascii_digit)
        .collect::<String>()
        .parse()
        .ok()
}

/// The name of a gRPC status code.
fn code_name(code: u32) -> String {
    format!("{:?}", tonic::Code::from_i32(code as i32))
}

/// What became of one raw connection: what the server sent, and when it closed (None:
/// still open at the limit).
struct RawEnd {
    received: Vec<u8>,
    closed_after: Option<Duration>,
}

/// Connects to `address`, writes `request` (keeping the connection open) and reads until the
/// server closes it or `limit` passes; the socket is closed then.
async fn raw_exchange(address: &str, request: Vec<u8>, limit: Duration) -> RawEnd {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let started = Instant::now();
    let deadline = tokio::time::Instant::now() + limit;
    let mut received = Vec::new();
    let closed = |received| RawEnd {
        received,
        closed_after: Some(started.elapsed()),
    };
    let Ok(Ok(mut stream)) =
        tokio::time::timeout_at(deadline, tokio::net::TcpStream::connect(address)).await
    else {
        return closed(received);
    };
    match tokio::time::timeout_at(deadline, stream.write_all(&request)).await {
        Ok(Ok(())) => {}
        Ok(Err(_)) => return closed(received),
        Err(_) => {
            return RawEnd {
                received,
                closed_after: None,
            };
        }
    }
    let mut buffer = vec![0u8; 16 << 10];
    loop {
        match tokio::time::timeout_at(deadline, stream.read(&mut buffer)).await {
            Ok(Ok(0)) | Ok(Err(_)) => return closed(received),
            Ok(Ok(n)) => received.extend_from_slice(&buffer[..n]),
            Err(_) => {
                return RawEnd {
                    received,
                    closed_after: None,
                };
            }
        }
    }
}

/// One HTTP/1.1 request that stalls (`request` is all of it the server gets): counted under
/// `action` by the grpc-status it was answered with, or as closed unanswered; a status of
/// INTERNAL or UNKNOWN, or a connection kept past both timeouts, is a fault.
async fn http1_stall(tally: &Tally, action: &'static str, address: &str, request: Vec<u8>) {
    let end = raw_exchange(address, request, stall_limit()).await;
    let status = grpc_status_in(&end.received);
    if let Some(code @ (2 | 13)) = status {
        tally.wrong(format!(
            "{action}: answered {}: {}",
            code_name(code),
            String::from_utf8_lossy(&end.received)
                .chars()
                .take(300)
                .collect::<String>()
        ));
    }
    let answer = match (status, end.received.is_empty()) {
        (Some(code), _) => code_name(code),
        (None, true) => "unanswered".to_owned(),
        (None, false) => String::from_utf8_lossy(&end.received)
            .lines()
            .next()
            .unwrap_or("")
            .chars()
            .take(40)
            .collect(),
    };
    match end.closed_after {
        Some(_) => tally.row(action, format!("{answer}, closed"), 1),
        None => {
            tally.row(action, format!("{answer}, kept open"), 1);
            tally.wrong(format!(
                "{action}: the server kept the connection open {} s \
                 (message_read_timeout_s {MESSAGE_TIMEOUT_S}, connection_idle_timeout_s \
                 {IDLE_TIMEOUT_S}), answered: {answer}",
                stall_limit().as_secs()
            ));
        }
    }
}

/// How an HTTP/2 gRPC stream ended: its grpc-status and message, or None when the response
/// carried none.
async fn h2_status(
    response: h2::client::ResponseFuture,
) -> Result<Option<(u32, String)>, h2::Error> {
    let status = |headers: &http::HeaderMap| {
        let code = headers
            .get("grpc-status")?
            .to_str()
            .ok()?
            .trim()
            .parse()
            .ok()?;
        let message = headers
            .get("grpc-message")
            .and_then(|m| m.to_str().ok())
            .unwrap_or("")
            .to_owned();
        Some((code, message))
    };
    let (parts, mut body) = response.await?.into_parts();
    if let Some(s) = status(&parts.headers) {
        return Ok(Some(s));
    }
    while let Some(chunk) = body.data().await {
        let chunk = chunk?;
        let _ = body.flow_control().release_capacity(chunk.len());
    }
    Ok(body.trailers().await?.as_ref().and_then(status))
}

/// An HTTP/2 connection (prior knowledge) to `address` opening `streams` streams to
/// GetSession, each sending `body` (a message it never finishes) or, with None, only its
/// headers. Streams are opened as the server's SETTINGS_MAX_CONCURRENT_STREAMS lets them,
/// until one message timeout and a half has passed; those left are counted "not opened".
/// Each opened stream must end within [`stall_limit`]: with DEADLINE_EXCEEDED or
/// RESOURCE_EXHAUSTED, a reset, or the connection closed; another status, INTERNAL or
/// UNKNOWN (or a reset with INTERNAL_ERROR, which a gRPC client reads as INTERNAL) or no end
/// at all is a fault. Counted under `action` and "h2 flood stream" or `action` alone.
async fn h2_streams(
    tally: &Arc<Tally>,
    action: &'static str,
    address: &str,
    streams: usize,
    body: Option<Bytes>,
) {
    let row: &'static str = if body.is_some() {
        "h2 flood stream"
    } else {
        action
    };
    let connected = async {
        let tcp = tokio::net::TcpStream::connect(address).await?;
        tcp.set_nodelay(true)?;
        let (sender, connection) = h2::client::Builder::new()
            .max_send_buffer_size(4 << 20)
            .handshake::<_, Bytes>(tcp)
            .await?;
        anyhow::Ok((sender, connection))
    };
    let (mut sender, connection) =
        match tokio::time::timeout(Duration::from_secs(3), connected).await {
            Ok(Ok(c)) => c,
            Ok(Err(e)) => {
                tally.row(action, format!("connection failed: {e:#}"), 1);
                return;
            }
            Err(_) => {
                tally.row(action, "connection not made within 3 s", 1);
                return;
            }
        };
    let driver = tokio::spawn(async move {
        let _ = connection.await;
    });
    let opening_ends =
        tokio::time::Instant::now() + Duration::from_millis(MESSAGE_TIMEOUT_S * 1000 + 1500);
    let mut ends = Vec::new();
    for _ in 0..streams {
        sender = match tokio::time::timeout_at(opening_ends, sender.ready()).await {
            Ok(Ok(s)) => s,
            Ok(Err(e)) => {
                tally.row(action, format!("connection ended: {e}"), 1);
                break;
            }
            Err(_) => break,
        };
        let request = http::Request::builder()
            .method("POST")
            .uri(format!("http://{address}/cathlab.v1.Simulator/GetSession"))
            .header("content-type", "application/grpc")
            .header("te", "trailers")
            .body(())
            .expect("a valid request");
        let (response, mut send) = match sender.send_request(request, false) {
            Ok(r) => r,
            Err(e) => {
                tally.row(action, format!("not sent: {e}"), 1);
                break;
            }
        };
        if let Some(body) = &body {
            let _ = send.send_data(body.clone(), false);
        }
        ends.push(tokio::spawn(async move {
            let end = tokio::time::timeout(stall_limit(), h2_status(response)).await;
            drop(send);
            end
        }));
    }
    tally.row(
        row,
        "not opened (waiting for the stream limit)",
        (streams - ends.len()) as u64,
    );
    tally.row(action, "connections", 1);
    for end in ends {
        let Ok(end) = end.await else { continue };
        let outcome = match end {
            Err(_) => {
                tally.wrong(format!(
                    "{action}: a stream had no end within {} s (message_read_timeout_s \
                     {MESSAGE_TIMEOUT_S}, connection_idle_timeout_s {IDLE_TIMEOUT_S})",
                    stall_limit().as_secs()
                ));
                "no end".to_owned()
            }
            Ok(Ok(Some((code, message)))) => {
                if !matches!(code, 4 | 8) {
                    tally.wrong(format!("{action}: answered {}: {message}", code_name(code)));
                }
                code_name(code)
            }
            Ok(Ok(None)) => {
                tally.wrong(format!("{action}: a response without a grpc-status"));
                "no grpc-status".to_owned()
            }
            Ok(Err(e)) => match e.reason() {
                Some(reason) if e.is_reset() => {
                    if reason == h2::Reason::INTERNAL_ERROR {
                        tally.wrong(format!("{action}: a stream reset with INTERNAL_ERROR"));
                    }
                    format!("reset {reason:?}")
                }
                Some(reason) if e.is_go_away() => format!("GOAWAY {reason:?}"),
                _ => "connection closed".to_owned(),
            },
        };
        tally.row(row, outcome, 1);
    }
    driver.abort();
}

/// The bomb files and the inline scenes naming them.
struct Bombs {
    /// The directory they are in (a data root), as a refusal must not show it.
    dir: String,
    /// (file name, scene text).
    scenes: Vec<(&'static str, String)>,
}

/// `bytes` of zeros through `encoder`, a mebibyte at a time.
fn zeros_into<W: std::io::Write>(mut encoder: W, bytes: usize) -> std::io::Result<W> {
    let chunk = vec![0u8; 1 << 20];
    for _ in 0..bytes >> 20 {
        encoder.write_all(&chunk)?;
    }
    Ok(encoder)
}

/// A MetaImage (MET_UCHAR) with its data inline.
fn metaimage(dims: &str, compressed: bool, data: &[u8]) -> Vec<u8> {
    let mut out = format!(
        "ObjectType = Image\nNDims = 3\nDimSize = {dims}\nElementType = MET_UCHAR\n\
         CompressedData = {}\nElementDataFile = LOCAL\n",
        if compressed { "True" } else { "False" }
    )
    .into_bytes();
    out.extend_from_slice(data);
    out
}

/// A gzip NIfTI-1 declaring 1024³ bytes, whose data inflates to `bytes` of zeros.
fn nifti_gzip_bomb(bytes: usize) -> std::io::Result<Vec<u8>> {
    use std::io::Write as _;
    let mut header = vec![0u8; 352];
    header[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (o, v) in [
        (40, 3i16),
        (42, 1024),
        (44, 1024),
        (46, 1024),
        (70, 2),
        (72, 8),
    ] {
        header[o..o + 2].copy_from_slice(&v.to_le_bytes());
    }
    for o in [80, 84, 88] {
        header[o..o + 4].copy_from_slice(&1.0f32.to_le_bytes());
    }
    header[108..112].copy_from_slice(&352.0f32.to_le_bytes());
    header[344..348].copy_from_slice(b"n+1\0");
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    gz.write_all(&header)?;
    zeros_into(gz, bytes)?.finish()
}

/// Writes the bomb files into `dir` and makes the scenes naming them: the default scene
/// (read from `scenes`) with its `[ct]` a file.
fn write_bombs(dir: &Path, scenes: &Path) -> Result<Bombs> {
    std::fs::create_dir_all(dir)?;
    let zlib_zeros = zeros_into(
        flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best()),
        64 << 20,
    )?
    .finish()?;
    let files: [(&'static str, Vec<u8>); 3] = [
        // 150 bytes declaring 10¹⁵ voxels.
        (
            "tiny.mha",
            metaimage(
                "100000 100000 100000",
                true,
                &[0x78, 0x9c, 0x03, 0, 0, 0, 0, 1],
            ),
        ),
        // 64³ declared, 64 MiB inflated.
        ("lying.mha", metaimage("64 64 64", true, &zlib_zeros)),
        // 1024³ declared, 64 MiB inflated.
        ("bomb.nii.gz", nifti_gzip_bomb(64 << 20)?),
    ];
    let template = std::fs::read_to_string(scenes.join(format!("{SCENE}.toml")))
        .with_context(|| format!("the scene {SCENE} in {}", scenes.display()))?;
    let phantom = "[ct]\nkind = \"phantom\"\nspacing_mm = 2.0";
    if !template.contains(phantom) {
        bail!("the scene {SCENE} has no phantom [ct] for the bombs to replace");
    }
    let mut bombs = Bombs {
        dir: dir.display().to_string(),
        scenes: Vec::new(),
    };
    for (name, bytes) in files {
        let path = dir.join(name);
        std::fs::write(&path, bytes)?;
        let ct = format!(
            "[ct]\nkind = \"file\"\npath = {:?}",
            path.display().to_string()
        );
        bombs.scenes.push((name, template.replace(phantom, &ct)));
    }
    Ok(bombs)
}

/// The well-behaved session: fluoroscopy on, its frames read by a reader that keeps up, the
/// wire pushed in and out; its missed steps are what the soak watches.
struct Watched {
    session: pb::CreateSessionResponse,
    frames: Arc<AtomicU64>,
}

async fn watched_session(client: &mut SimulatorClient<Channel>) -> Result<Watched> {
    let session = client
        .create_session(pb::CreateSessionRequest {
            scene: Some(pb::create_session_request::Scene::SceneName(SCENE.into())),
            label: "soak control".into(),
            ..Default::default()
        })
        .await?
        .into_inner();
    let mut frames = client
        .stream_frames(authed(
            pb::StreamFramesRequest {
                session_id: session.session_id.clone(),
                encoding: pb::FrameEncoding::Raw8 as i32,
                ..Default::default()
            },
            &session.observer_token,
        ))
        .await?
        .into_inner();
    let count = Arc::new(AtomicU64::new(0));
    let counter = count.clone();
    tokio::spawn(async move {
        while let Ok(Some(_)) = frames.message().await {
            counter.fetch_add(1, Ordering::Relaxed);
        }
    });
    Ok(Watched {
        session,
        frames: count,
    })
}

async fn timing(client: &mut SimulatorClient<Channel>, w: &Watched) -> Result<pb::Timing> {
    client
        .get_session(authed(
            pb::GetSessionRequest {
                session_id: w.session.session_id.clone(),
            },
            &w.session.observer_token,
        ))
        .await?
        .into_inner()
        .timing
        .context("a live session has timing")
}

/// Drives the watched session: fluoroscopy on, then 10 mm/s in and out every 4 s, until `stop`.
async fn drive(
    mut client: SimulatorClient<Channel>,
    w: pb::CreateSessionResponse,
    stop: Arc<AtomicBool>,
) {
    let send = |client: &mut SimulatorClient<Channel>, seq: u64, kind| {
        let request = authed(
            pb::SendCommandRequest {
                session_id: w.session_id.clone(),
                seq,
                command: command(kind),
            },
            &w.controller_token,
        );
        let mut c = client.clone();
        async move { c.send_command(request).await }
    };
    let _ = send(&mut client, 1, pb::command::Kind::Fluoroscopy(true)).await;
    let mut seq = 1;
    while !stop.load(Ordering::Relaxed) {
        seq += 1;
        let mm_s = if seq % 2 == 0 { 10.0 } else { -10.0 };
        let _ = send(&mut client, seq, speed(mm_s, false)).await;
        tokio::time::sleep(Duration::from_secs(4)).await;
    }
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<()> {
    let cli = Cli::parse();
    let dir = std::env::temp_dir().join(format!("cathlab-soak-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    // The data roots: the scenes and the data beside them, as by default, and the bombs'.
    let scenes = cli
        .target
        .scenes
        .canonicalize()
        .with_context(|| format!("the scenes directory {}", cli.target.scenes.display()))?;
    let bomb_dir = dir.join("bombs");
    let bombs = Arc::new(write_bombs(&bomb_dir, &scenes)?);
    let mut roots = vec![scenes.clone()];
    roots.extend(scenes.join("../data").canonicalize().ok());
    roots.push(bomb_dir.canonicalize()?);
    std::fs::write(dir.join("server.toml"), config(&roots))?;
    let config = dir.join("server.toml");
    let mut server = Server::start(
        &Server::binary(cli.target.server.as_deref())?,
        &dir.join("soak.sqlite"),
        &cli.target.scenes,
        KEY,
        &[
            "--renderer",
            &cli.target.renderer,
            "--config",
            config.to_str().context("a UTF-8 temporary path")?,
        ],
        Stdio::piped(),
    )?;
    // The log: panics and errors are counted and shown, the rest (warnings about the random
    // clients' mistakes) counted.
    let panics = Arc::new(AtomicU64::new(0));
    let warnings = Arc::new(AtomicU64::new(0));
    let log = server.child.stderr.take().context("no stderr")?;
    let reader = {
        let (panics, warnings) = (panics.clone(), warnings.clone());
        std::thread::spawn(move || {
            use std::io::BufRead;
            for line in std::io::BufReader::new(log).lines().map_while(Result::ok) {
                if line.contains("panicked") {
                    panics.fetch_add(1, Ordering::Relaxed);
                    eprintln!("server: {line}");
                } else if line.contains("ERROR") {
                    eprintln!("server: {line}");
                } else {
                    warnings.fetch_add(1, Ordering::Relaxed);
                }
            }
        })
    };
    let mut client = SimulatorClient::connect(server.url())
        .await?
        .max_decoding_message_size(64 << 20);
    let watched = watched_session(&mut client).await?;
    let stop_driving = Arc::new(AtomicBool::new(false));
    let driver = tokio::spawn(drive(
        client.clone(),
        watched.session.clone(),
        stop_driving.clone(),
    ));
    tokio::time::sleep(Duration::from_secs(3)).await;
    println!(
        "cathlab-soak: server pid {} at {}, seed {}, {} random clients, rounds of {} s, until {} physics steps",
        server.child.id(),
        server.address,
        cli.seed,
        cli.clients,
        cli.round_seconds,
        cli.steps
    );
    let started = Instant::now();
    let first = timing(&mut client, &watched).await?;
    let steps_at_start = server.metric("cathlab_physics_step_seconds_count").await?;
    let tally = Arc::new(Tally::default());
    let mut resting = Vec::new();
    let mut live = Vec::new();
    let mut anonymous = Vec::new();
    let mut failures = Vec::new();
    let actions = if cli.actions.is_empty() {
        Action::ALL.to_vec()
    } else {
        cli.actions.clone()
    };
    for round in 0u64.. {
        let before: BTreeMap<_, _> = tally.answers.lock().clone();
        let stop = Arc::new(AtomicBool::new(false));
        let mut clients = Vec::new();
        for i in 0..cli.clients as u64 {
            let mut chaos = Chaos::new(
                server.url(),
                server.address.clone(),
                cli.seed.wrapping_mul(1_000_003) ^ (round << 16) ^ i,
                tally.clone(),
                actions.clone(),
                bombs.clone(),
            )
            .await?;
            let stop = stop.clone();
            clients.push(tokio::spawn(async move {
                while !stop.load(Ordering::Relaxed) {
                    // Every action is bounded in time, so a round always ends.
                    let _ = tokio::time::timeout(Duration::from_secs(10), chaos.act()).await;
                    let pause = chaos.rng.random_range(20..200);
                    tokio::time::sleep(Duration::from_millis(pause)).await;
                }
                chaos.finish().await;
            }));
        }
        tokio::time::sleep(Duration::from_secs_f64(cli.round_seconds)).await;
        stop.store(true, Ordering::Relaxed);
        for c in clients {
            c.await?;
        }
        // At rest: only the watched session is left; give the streams' ends a moment.
        tokio::time::sleep(Duration::from_secs(3)).await;
        let (rss, anon) = (server.rss_mib(), server.anon_mib());
        resting.push(rss);
        anonymous.push(anon);
        // Live heap bytes (the server's counting allocator): a leak grows these; memory the
        // allocator keeps after frees grows only the resident figures. The least of three
        // samples, so that a frame of the watched session in flight does not count.
        let mut heap = f64::INFINITY;
        for _ in 0..3 {
            let bytes = server
                .metric("cathlab_heap_bytes")
                .await
                .unwrap_or(f64::NAN);
            heap = heap.min(bytes / 1048576.0);
            tokio::time::sleep(Duration::from_millis(300)).await;
        }
        live.push(heap);
        let steps = server.metric("cathlab_physics_step_seconds_count").await? - steps_at_start;
        let t = timing(&mut client, &watched).await?;
        println!(
            "round {round}: {:.0} s, {steps:.0} physics steps, {} actions, resting RSS {rss:.1} MiB ({anon:.1} anonymous, {heap:.1} live heap), watched session missed {} steps ({} frames read)",
            started.elapsed().as_secs_f64(),
            tally.actions.load(Ordering::Relaxed),
            t.missed_steps - first.missed_steps,
            watched.frames.load(Ordering::Relaxed)
        );
        // This round's connection and file attacks, by outcome.
        let mut attacks: BTreeMap<&str, Vec<String>> = BTreeMap::new();
        for ((action, answer), n) in tally.answers.lock().iter() {
            let n = n - before.get(&(*action, answer.clone())).copied().unwrap_or(0);
            if n > 0 && ATTACK_ROWS.contains(action) {
                attacks
                    .entry(action)
                    .or_default()
                    .push(format!("{answer} {n}"));
            }
        }
        for (action, outcomes) in &attacks {
            println!("  {action}: {}", outcomes.join(", "));
        }
        if let Ok(Some(status)) = server.child.try_wait() {
            failures.push(format!("the server exited: {status}"));
            break;
        }
        if steps >= cli.steps as f64 {
            break;
        }
        if started.elapsed().as_secs_f64() > cli.max_seconds {
            failures.push(format!(
                "{steps:.0} of {} steps in {} s",
                cli.steps, cli.max_seconds
            ));
            break;
        }
    }
    stop_driving.store(true, Ordering::Relaxed);
    driver.abort();

    let last = timing(&mut client, &watched).await?;
    let missed = last.missed_steps - first.missed_steps;
    let steps = server.metric("cathlab_physics_step_seconds_count").await? - steps_at_start;
    // Still serving: a fresh session is created and closed.
    let fresh = client
        .create_session(pb::CreateSessionRequest {
            scene: Some(pb::create_session_request::Scene::SceneName(SCENE.into())),
            label: "after the soak".into(),
            ..Default::default()
        })
        .await;
    match fresh {
        Ok(s) => {
            let s = s.into_inner();
            client
                .close_session(authed(
                    pb::CloseSessionRequest {
                        session_id: s.session_id,
                    },
                    &s.controller_token,
                ))
                .await?;
        }
        Err(status) => failures.push(format!("a session after the soak: {status}")),
    }

    println!();
    println!("| action | answer | count | first message |");
    println!("|---|---|---|---|");
    let examples = tally.examples.lock();
    for (key, n) in tally.answers.lock().iter() {
        let example = examples.get(key).map_or("", String::as_str);
        println!("| {} | {} | {n} | {example} |", key.0, key.1);
    }
    drop(examples);
    let rounded = |v: &[f64]| {
        v.iter()
            .map(|v| (v * 10.0).round() / 10.0)
            .collect::<Vec<_>>()
    };
    // A leak keeps what it took: judged is the least of the last two rounds (the last alone
    // with fewer than three), so a round that happened to rest with a closing session's or an
    // inline scene's memory still held does not count, while a leak grows both. A NaN (not
    // read) propagates and fails.
    let growth = |v: &[f64]| {
        let tail = &v[v.len().saturating_sub(2).max(1).min(v.len() - 1)..];
        let judged = tail.iter().copied().fold(f64::INFINITY, |a, b| {
            if a.is_nan() || b.is_nan() {
                f64::NAN
            } else {
                a.min(b)
            }
        });
        (v[0], judged, (judged / v[0] - 1.0) * 100.0)
    };
    let (baseline, judged, rss_growth) = growth(&resting);
    let (heap_first, heap_judged, heap_growth) = growth(&live);
    println!();
    println!(
        "{steps:.0} physics steps in {:.0} s, {} actions; panics {}, faults {}, log warnings {}; watched session missed {missed} of {} steps",
        started.elapsed().as_secs_f64(),
        tally.actions.load(Ordering::Relaxed),
        panics.load(Ordering::Relaxed),
        tally.faults.lock().len(),
        warnings.load(Ordering::Relaxed),
        last.steps - first.steps,
    );
    println!(
        "resting RSS {:?} MiB (first {baseline:.1}, judged {judged:.1}, {rss_growth:+.1} %)",
        rounded(&resting)
    );
    println!(
        "resting live heap {:?} MiB (first {heap_first:.1}, judged {heap_judged:.1}, {heap_growth:+.1} %)",
        rounded(&live)
    );
    println!("resting anonymous RSS {:?} MiB", rounded(&anonymous));
    drop(server);
    let _ = reader.join();
    let _ = std::fs::remove_dir_all(&dir);

    if panics.load(Ordering::Relaxed) > 0 {
        failures.push(format!(
            "{} panics in the server's log",
            panics.load(Ordering::Relaxed)
        ));
    }
    // Each kind of fault once, with how often it was met.
    let mut faults: Vec<(String, usize)> = Vec::new();
    for f in tally.faults.lock().iter() {
        match faults.iter_mut().find(|(seen, _)| seen == f) {
            Some((_, n)) => *n += 1,
            None => faults.push((f.clone(), 1)),
        }
    }
    for (f, n) in faults.into_iter().take(10) {
        failures.push(if n > 1 { format!("{n} times: {f}") } else { f });
    }
    let watched_steps = last.steps.saturating_sub(first.steps).max(1);
    if missed as f64 > cli.missed_tolerance * watched_steps as f64 {
        failures.push(format!(
            "the watched session missed {missed} of {watched_steps} steps (tolerance {:.2} %)",
            100.0 * cli.missed_tolerance
        ));
    }
    if judged.is_nan() || judged > baseline * (1.0 + cli.rss_tolerance) {
        failures.push(format!(
            "resting RSS grew from {baseline:.1} to {judged:.1} MiB"
        ));
    }
    // A live heap that could not be read (NaN) fails too.
    if heap_judged.is_nan() || heap_judged > heap_first * (1.0 + cli.rss_tolerance) {
        failures.push(format!(
            "resting live heap grew from {heap_first:.1} to {heap_judged:.1} MiB"
        ));
    }
    if !failures.is_empty() {
        bail!("the soak failed: {failures:#?}");
    }
    println!("soak passed");
    Ok(())
}
