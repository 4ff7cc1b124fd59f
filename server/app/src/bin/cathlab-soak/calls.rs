//! The random clients' gRPC calls, valid and invalid: sessions created and closed (sometimes
//! by an observer), commands in and out of range, frame, control, state and metrics streams
//! opened and abandoned or stalled, queries, and replays abandoned.

use std::time::Duration;

use anyhow::Result;
use cathlab_api::authorized as authed;
use cathlab_api::pb;
use cathlab_api::pb::simulator_client::SimulatorClient;
use rand::RngExt;

use crate::client::Chaos;
use crate::common::{KEY, SCENE, command, speed};

impl Chaos {
    pub(crate) async fn create(&mut self) -> Result<()> {
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

    pub(crate) async fn close(&mut self) -> Result<()> {
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

    pub(crate) async fn valid_command(&mut self) -> Result<()> {
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

    pub(crate) async fn invalid_command(&mut self) -> Result<()> {
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
    pub(crate) async fn frames(&mut self) -> Result<()> {
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
    pub(crate) async fn control(&mut self) -> Result<()> {
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
    pub(crate) async fn watch(&mut self) -> Result<()> {
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

    pub(crate) async fn query(&mut self) -> Result<()> {
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

    /// A replay of this client's session, abandoned after a moment.
    pub(crate) async fn replay(&mut self) -> Result<()> {
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
}
