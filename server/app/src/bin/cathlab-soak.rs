//! `cathlab-soak`: the server under a long, seeded, random mix of what clients do, valid and
//! invalid — sessions created and closed, commands in and out of range, frame, state and
//! control streams opened and abandoned or stalled, wrong secrets, hostile scenes, garbage on
//! the port — beside one well-behaved control session, until the server has run a given
//! number of physics steps. It runs in rounds; after each, the random clients stop, their
//! sessions close and the server's resident memory is read at rest. It fails (exit status 1)
//! on a panic in the server's log, an INTERNAL or UNKNOWN answer, a missed step in the
//! control session, resting resident memory (VmRSS) or resting live heap (the bytes the
//! server's counting allocator has out: what a leak grows, whatever the allocator keeps) more
//! than 10 % above the first round's, or a server that stops answering. Resting anonymous
//! memory is shown beside them.

mod harness;

use std::collections::BTreeMap;
use std::process::Stdio;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
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

/// What a random client may do, and how often (weights out of 100).
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
}

impl Action {
    const ALL: [Action; 11] = [
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
        }
    }
}

const KEY: &str = "soak-instructor-key";
const SCENE: &str = "arch_to_cow_lcca";

/// The server's limits for the soak: tight timeouts so that stalls and silences are met often;
/// a throttle high enough that the random wrong secrets do not lock the control session out
/// (the throttle has its own attack test).
const CONFIG: &str = "max_sessions = 8\nmax_replays = 1\ncontrol_timeout_ms = 250\n\
stream_stall_timeout_ms = 2000\nstream_buffer_mib = 64\nauth_failures_per_minute = 100000\n\
control_inputs_per_second = 2000\n";

/// What the random clients saw: answers by kind of action and status code.
#[derive(Default)]
struct Tally {
    answers: Mutex<BTreeMap<(&'static str, String), u64>>,
    /// The first message seen for each (action, code).
    examples: Mutex<BTreeMap<(&'static str, String), String>>,
    /// INTERNAL or UNKNOWN answers, with what was asked.
    faults: Mutex<Vec<String>>,
    actions: AtomicU64,
}

impl Tally {
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
        })
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

    /// Closes this client's session and waits for its stalled streams to be dropped.
    async fn finish(mut self) {
        let _ = self.close().await;
        for s in self.stalls.drain(..) {
            let _ = s.await;
        }
    }
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
    std::fs::write(dir.join("server.toml"), CONFIG)?;
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
        let stop = Arc::new(AtomicBool::new(false));
        let mut clients = Vec::new();
        for i in 0..cli.clients as u64 {
            let mut chaos = Chaos::new(
                server.url(),
                server.address.clone(),
                cli.seed.wrapping_mul(1_000_003) ^ (round << 16) ^ i,
                tally.clone(),
                actions.clone(),
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
    for f in tally.faults.lock().iter().take(10) {
        failures.push(f.clone());
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
