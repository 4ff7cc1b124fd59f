//! The bridge: a UDP receiver for the device, a gRPC task holding the session's control
//! stream (reconnecting, and recreating its session after a server restart), and the 1 kHz
//! loop between them that runs the coupling law and reports timing statistics.

use std::collections::VecDeque;
use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use cathlab_api::pb::simulator_client::SimulatorClient;
use cathlab_api::{authorized, pb};
use hdrhistogram::Histogram;
use parking_lot::Mutex;
use serde::Serialize;
use tokio::sync::mpsc;
use tonic::transport::{Channel, Endpoint};

use crate::coupling::{Coupling, CouplingSettings, ServerSample};
use crate::protocol::{DeviceSample, Feedback, HandFeedback, lost_between};

/// Which session to drive.
#[derive(Debug, Clone)]
pub enum SessionChoice {
    /// An existing session, with its controller token.
    Attach {
        /// Session id.
        id: String,
        /// Controller token.
        token: String,
    },
    /// A session of its own, created (again after a server restart) from a listed scene
    /// name or an inline scene text (TOML).
    Create {
        /// Scene name or TOML text.
        scene: SceneSource,
        /// Dashboard label.
        label: String,
    },
}

/// A scene to create a session from.
#[derive(Debug, Clone)]
pub enum SceneSource {
    /// A scene the server lists.
    Name(String),
    /// A scene text (TOML).
    Toml(String),
}

/// The bridge's settings.
#[derive(Debug, Clone)]
pub struct BridgeConfig {
    /// Server URL (`http://127.0.0.1:50051`).
    pub server: String,
    /// The session.
    pub session: SessionChoice,
    /// UDP address to listen on for the device.
    pub udp: SocketAddr,
    /// Loop rate (Hz).
    pub rate_hz: f64,
    /// The coupling law.
    pub coupling: CouplingSettings,
    /// Report period (s).
    pub report_every_s: f64,
    /// A device silent for longer than this is treated as gone (s).
    pub device_timeout_s: f64,
}

/// Statistics, reported periodically (cumulative since the start).
#[derive(Debug, Clone, Serialize, Default)]
pub struct Report {
    /// Time since the start (s).
    pub t_s: f64,
    /// Loop ticks run.
    pub ticks: u64,
    /// Loop period percentiles (µs) and ticks that started more than a period late.
    pub period_p50_us: u64,
    /// 99th percentile (µs).
    pub period_p99_us: u64,
    /// Largest (µs).
    pub period_max_us: u64,
    /// Ticks late by a whole period or more.
    pub overruns: u64,
    /// Setpoint → state carrying it, round trip (ms).
    pub round_trip_p50_ms: f64,
    /// 99th percentile (ms).
    pub round_trip_p99_ms: f64,
    /// Round trips measured.
    pub round_trips: u64,
    /// Server states received.
    pub server_updates: u64,
    /// Server state age when used, 99th percentile (ms).
    pub state_age_p99_ms: f64,
    /// Connected to a session now.
    pub connected: bool,
    /// Session driven now (empty when none).
    pub session: String,
    /// Control streams opened after the first.
    pub reconnects: u64,
    /// Sessions created.
    pub sessions_created: u64,
    /// Device datagrams accepted, lost (sequence gaps) and rejected (malformed).
    pub device_packets: u64,
    /// Lost in transit.
    pub device_lost: u64,
    /// Malformed.
    pub device_rejected: u64,
    /// Last rendered force (N) and torque (N·mm).
    pub force_n: f64,
    /// Torque (N·mm).
    pub torque_nmm: f64,
    /// Last server inserted length (mm) and axial reaction (N).
    pub inserted_mm: f64,
    /// Axial reaction (N).
    pub server_force_n: f64,
    /// A two-channel device's outer hand: last rendered force (N) and torque (N·mm).
    pub outer_force_n: f64,
    /// Torque (N·mm).
    pub outer_torque_nmm: f64,
    /// The outer instrument's last server inserted length (mm) and axial reaction (N).
    pub outer_inserted_mm: f64,
    /// Axial reaction (N).
    pub outer_server_force_n: f64,
    /// The stack index the outer hand drives (absent without an outer instrument).
    pub outer_instrument: Option<u32>,
    /// Last error from the server side, if any.
    pub last_error: String,
}

#[derive(Default)]
struct DeviceLink {
    latest: Option<(DeviceSample, Instant)>,
    from: Option<SocketAddr>,
    last_seq: Option<u32>,
    packets: u64,
    lost: u64,
    rejected: u64,
}

#[derive(Default)]
struct ServerLink {
    latest: Option<(pb::DeviceState, Instant)>,
    inputs: Option<mpsc::Sender<pb::ControlInput>>,
    commands: Option<mpsc::UnboundedSender<pb::Command>>,
    session: String,
    generation: u64,
    updates: u64,
    reconnects: u64,
    created: u64,
    pending: VecDeque<(u64, Instant)>,
    round_trip_us: Option<Histogram<u64>>,
    last_error: String,
}

struct Shared {
    device: Mutex<DeviceLink>,
    server: Mutex<ServerLink>,
    stop: Arc<AtomicBool>,
}

/// Runs the bridge until `stop` is set; `listening` is called with the bound UDP address,
/// `report` every report period. Returns the final report.
pub fn run(
    config: BridgeConfig,
    stop: Arc<AtomicBool>,
    listening: impl FnOnce(SocketAddr),
    mut report: impl FnMut(&Report),
) -> anyhow::Result<Report> {
    let socket = UdpSocket::bind(config.udp).with_context(|| format!("binding {}", config.udp))?;
    socket.set_read_timeout(Some(Duration::from_millis(50)))?;
    listening(socket.local_addr()?);
    let shared = Arc::new(Shared {
        device: Mutex::new(DeviceLink::default()),
        server: Mutex::new(ServerLink {
            round_trip_us: Some(Histogram::new_with_bounds(1, 60_000_000, 3)?),
            ..ServerLink::default()
        }),
        stop: stop.clone(),
    });
    let receiver = {
        let shared = shared.clone();
        let socket = socket.try_clone()?;
        std::thread::Builder::new()
            .name("haptic-udp".into())
            .spawn(move || receive(&socket, &shared))?
    };
    let grpc = {
        let shared = shared.clone();
        let config = config.clone();
        std::thread::Builder::new()
            .name("haptic-grpc".into())
            .spawn(move || -> anyhow::Result<()> {
                tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()?
                    .block_on(hold_session(&config, &shared));
                Ok(())
            })?
    };
    let last = control_loop(&config, &shared, &socket, &mut report);
    stop.store(true, Ordering::SeqCst);
    let _ = receiver.join();
    let _ = grpc.join();
    last
}

fn receive(socket: &UdpSocket, shared: &Shared) {
    let mut buffer = [0u8; 256];
    while !shared.stop.load(Ordering::Relaxed) {
        let Ok((n, from)) = socket.recv_from(&mut buffer) else {
            continue;
        };
        let mut link = shared.device.lock();
        match DeviceSample::decode(&buffer[..n.min(buffer.len())]) {
            Ok(sample) => {
                // A device that restarted (new address, or silent past the timeout) starts
                // its sequence afresh.
                let restarted = link.from != Some(from)
                    || link
                        .latest
                        .is_none_or(|(_, at)| at.elapsed() > Duration::from_millis(500));
                if restarted {
                    link.last_seq = None;
                }
                if let Some(previous) = link.last_seq {
                    link.lost += u64::from(lost_between(previous, sample.seq));
                    if sample.seq.wrapping_sub(previous) > u32::MAX / 2 || sample.seq == previous {
                        continue; // late or repeated: keep the newer one
                    }
                }
                link.last_seq = Some(sample.seq);
                link.packets += 1;
                link.from = Some(from);
                link.latest = Some((sample, Instant::now()));
            }
            Err(_) => link.rejected += 1,
        }
    }
}

/// Keeps a control stream open: connect, create or attach the session, stream; on any
/// failure wait (capped exponential back-off) and start again.
async fn hold_session(config: &BridgeConfig, shared: &Shared) {
    let mut backoff = Duration::from_millis(100);
    let mut own: Option<(String, String)> = None;
    let mut opened = 0u64;
    while !shared.stop.load(Ordering::Relaxed) {
        let result = stream_once(config, shared, &mut own, &mut opened).await;
        {
            let mut link = shared.server.lock();
            link.inputs = None;
            link.commands = None;
            link.latest = None;
            link.pending.clear();
            if let Err(e) = &result {
                link.last_error = format!("{e:#}");
            }
        }
        if shared.stop.load(Ordering::Relaxed) {
            break;
        }
        if result.is_ok() {
            backoff = Duration::from_millis(100);
        }
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(Duration::from_secs(2));
    }
}

async fn stream_once(
    config: &BridgeConfig,
    shared: &Shared,
    own: &mut Option<(String, String)>,
    opened: &mut u64,
) -> anyhow::Result<()> {
    let channel: Channel = Endpoint::from_shared(config.server.clone())?
        .connect_timeout(Duration::from_secs(1))
        .tcp_nodelay(true)
        .connect()
        .await
        .with_context(|| format!("connecting to {}", config.server))?;
    let mut client = SimulatorClient::new(channel);
    let (id, token) = match &config.session {
        SessionChoice::Attach { id, token } => (id.clone(), token.clone()),
        SessionChoice::Create { scene, label } => {
            if let Some(existing) = own.clone() {
                existing
            } else {
                let scene = match scene {
                    SceneSource::Name(n) => pb::create_session_request::Scene::SceneName(n.clone()),
                    SceneSource::Toml(t) => pb::create_session_request::Scene::SceneToml(t.clone()),
                };
                let created = client
                    .create_session(pb::CreateSessionRequest {
                        scene: Some(scene),
                        label: label.clone(),
                        ..Default::default()
                    })
                    .await
                    .context("creating a session")?
                    .into_inner();
                shared.server.lock().created += 1;
                let pair = (created.session_id, created.controller_token);
                *own = Some(pair.clone());
                pair
            }
        }
    };
    let (input_tx, input_rx) = mpsc::channel::<pb::ControlInput>(256);
    input_tx
        .send(pb::ControlInput {
            session_id: id.clone(),
            seq: 0,
            push_mm_s: 0.0,
            twist_deg_s: 0.0,
            hands: Vec::new(),
        })
        .await?;
    let response = client
        .control(authorized(
            tokio_stream::wrappers::ReceiverStream::new(input_rx),
            &token,
        ))
        .await;
    let mut outputs = match response {
        Ok(r) => r.into_inner(),
        Err(status) => {
            if status.code() == tonic::Code::NotFound {
                *own = None; // the server restarted: make a new session next time
            }
            return Err(anyhow::anyhow!("{}: {}", status.code(), status.message()));
        }
    };
    let (command_tx, mut command_rx) = mpsc::unbounded_channel::<pb::Command>();
    {
        let mut link = shared.server.lock();
        link.inputs = Some(input_tx);
        link.commands = Some(command_tx);
        link.session = id.clone();
        link.generation += 1;
        if *opened > 0 {
            link.reconnects += 1;
        }
        link.last_error.clear();
    }
    *opened += 1;
    let mut command_seq = 1u64 << 48;
    // An interval, not a sleep re-armed on every pass: states arrive every 2 ms, and a fresh
    // 100 ms sleep each time would never fire, so the stop flag would never be seen.
    let mut stop_check = tokio::time::interval(Duration::from_millis(100));
    loop {
        tokio::select! {
            message = outputs.message() => {
                let state = match message {
                    Ok(Some(out)) => out.state.unwrap_or_default(),
                    Ok(None) => return Err(anyhow::anyhow!("the server ended the control stream")),
                    Err(status) => {
                        if status.code() == tonic::Code::NotFound {
                            *own = None;
                        }
                        return Err(anyhow::anyhow!("{}: {}", status.code(), status.message()));
                    }
                };
                let now = Instant::now();
                let mut link = shared.server.lock();
                link.updates += 1;
                let mut newest = None;
                while link.pending.front().is_some_and(|(seq, _)| *seq <= state.last_seq) {
                    newest = link.pending.pop_front();
                }
                if let Some((_, sent)) = newest {
                    let us = now.duration_since(sent).as_micros() as u64;
                    if let Some(h) = link.round_trip_us.as_mut() {
                        let _ = h.record(us.max(1));
                    }
                }
                link.latest = Some((state, now));
            }
            Some(command) = command_rx.recv() => {
                command_seq += 1;
                // Buttons: a failure is reported, the stream goes on.
                if let Err(status) = client
                    .send_command(authorized(pb::SendCommandRequest {
                        session_id: id.clone(),
                        seq: command_seq,
                        command: Some(command),
                    }, &token))
                    .await
                {
                    shared.server.lock().last_error = format!("{}: {}", status.code(), status.message());
                }
            }
            _ = stop_check.tick() => {
                if shared.stop.load(Ordering::Relaxed) {
                    return Ok(());
                }
            }
        }
    }
}

/// A server state's instrument as the coupling law needs it.
fn sample_of(i: &pb::InstrumentState, age_s: f64) -> ServerSample {
    ServerSample {
        inserted_mm: i.inserted_mm,
        twist_deg: i.twist_deg,
        axial_force_n: i.axial_force_n,
        axial_torque_nmm: i.axial_torque_nmm,
        age_s,
    }
}

/// What the loop reads from the server link in one tick: the inner (or only) instrument's
/// sample, the outer hand's (its sample and stack index, and the innermost's index) when the
/// scene has two instruments or more, and the state's age.
struct ServerView {
    inner: ServerSample,
    outer: Option<(ServerSample, u32, u32)>,
    age_s: f64,
}

fn view(state: &pb::DeviceState, age_s: f64) -> ServerView {
    let n = state.instruments.len();
    let inner = match state.instruments.last() {
        Some(i) => sample_of(i, age_s),
        None => ServerSample {
            inserted_mm: state.inserted_mm,
            twist_deg: state.twist_deg,
            axial_force_n: state.axial_force_n,
            axial_torque_nmm: state.axial_torque_nmm,
            age_s,
        },
    };
    ServerView {
        inner,
        outer: (n >= 2).then(|| {
            (
                sample_of(&state.instruments[n - 2], age_s),
                (n - 2) as u32,
                (n - 1) as u32,
            )
        }),
        age_s,
    }
}

/// The last tick's outputs and server view, for the reports.
#[derive(Default)]
struct Last {
    inner: crate::coupling::Output,
    outer: crate::coupling::Output,
    server: Option<ServerSample>,
    outer_server: Option<(ServerSample, u32)>,
}

fn control_loop(
    config: &BridgeConfig,
    shared: &Shared,
    socket: &UdpSocket,
    report: &mut impl FnMut(&Report),
) -> anyhow::Result<Report> {
    let period = Duration::from_secs_f64(1.0 / config.rate_hz);
    let dt = period.as_secs_f64();
    // One law per hand: the inner (or only) instrument's, and a two-channel device's outer.
    let mut coupling = Coupling::new(config.coupling);
    let mut outer_coupling = Coupling::new(config.coupling);
    let mut periods = Histogram::<u64>::new_with_bounds(1, 10_000_000, 3)?;
    let mut ages = Histogram::<u64>::new_with_bounds(1, 60_000_000, 3)?;
    let start = Instant::now();
    let (mut next, mut previous_tick) = (start, start);
    let mut last = Last::default();
    let (mut ticks, mut overruns) = (0u64, 0u64);
    let mut next_report = config.report_every_s;
    let mut generation = 0;
    let mut input_seq = 0u64;
    // The setpoints last sent (inner push, twist, outer push, twist) and when.
    let mut sent: Option<([f64; 4], Instant)> = None;
    let mut buttons = (false, false);
    while !shared.stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if ticks > 0 {
            let _ = periods.record((now.duration_since(previous_tick).as_micros() as u64).max(1));
        }
        previous_tick = now;
        ticks += 1;
        let (device, from) = {
            let link = shared.device.lock();
            let fresh = link
                .latest
                .filter(|(_, at)| now.duration_since(*at).as_secs_f64() <= config.device_timeout_s);
            (fresh.map(|(s, _)| s), link.from)
        };
        let (server, inputs, commands, connected) = {
            let link = shared.server.lock();
            if link.generation != generation {
                generation = link.generation;
                coupling.disengage();
                outer_coupling.disengage();
                sent = None;
            }
            let server = link
                .latest
                .as_ref()
                .map(|(s, at)| view(s, now.saturating_duration_since(*at).as_secs_f64()));
            (
                server,
                link.inputs.clone(),
                link.commands.clone(),
                link.inputs.is_some(),
            )
        };
        if let Some(v) = &server {
            let _ = ages.record(((v.age_s * 1e6) as u64).max(1));
        }
        let output = match device {
            Some(d) => coupling.update(
                dt,
                d.insertion_mm,
                d.rotation_deg,
                server.as_ref().map(|v| v.inner),
            ),
            // No device: stop the simulated one, render nothing, re-engage on return.
            None => {
                coupling.disengage();
                Default::default()
            }
        };
        // The outer hand: a two-channel device on a scene with an outer instrument.
        let outer_server = server.as_ref().and_then(|v| v.outer);
        let outer = match (device.and_then(|d| d.outer), outer_server) {
            (Some(p), Some((sample, _, _))) => {
                outer_coupling.update(dt, p.insertion_mm, p.rotation_deg, Some(sample))
            }
            _ => {
                outer_coupling.disengage();
                Default::default()
            }
        };
        let hands = device.is_some_and(|d| d.outer.is_some());
        // Setpoints: on change but no faster than the server's physics (every 2 ms: each one
        // is a recorded command), and at least every 20 ms as a keep-alive.
        if let Some(inputs) = &inputs {
            let setpoints = [
                output.push_mm_s,
                output.twist_deg_s,
                outer.push_mm_s,
                outer.twist_deg_s,
            ];
            let due = sent.is_none_or(|(p, at)| {
                let since = now.duration_since(at);
                let changed = p.iter().zip(&setpoints).any(|(a, b)| (a - b).abs() > 0.01);
                (changed && since >= Duration::from_millis(2)) || since >= Duration::from_millis(20)
            });
            if due {
                input_seq += 1;
                // Two hands: each names its instrument; one: the plain setpoints drive the
                // innermost.
                let input = match outer_server.filter(|_| hands) {
                    Some((_, outer_index, inner_index)) => pb::ControlInput {
                        session_id: String::new(),
                        seq: input_seq,
                        push_mm_s: 0.0,
                        twist_deg_s: 0.0,
                        hands: vec![
                            pb::HandSetpoint {
                                instrument: outer_index,
                                push_mm_s: outer.push_mm_s,
                                twist_deg_s: outer.twist_deg_s,
                            },
                            pb::HandSetpoint {
                                instrument: inner_index,
                                push_mm_s: output.push_mm_s,
                                twist_deg_s: output.twist_deg_s,
                            },
                        ],
                    },
                    None => pb::ControlInput {
                        session_id: String::new(),
                        seq: input_seq,
                        push_mm_s: output.push_mm_s,
                        twist_deg_s: output.twist_deg_s,
                        hands: Vec::new(),
                    },
                };
                if inputs.try_send(input).is_ok() {
                    shared.server.lock().pending.push_back((input_seq, now));
                    sent = Some((setpoints, now));
                }
            }
        }
        if let (Some(d), Some(commands)) = (device, &commands) {
            if d.pedal != buttons.0 {
                let _ = commands.send(pb::Command {
                    kind: Some(pb::command::Kind::Fluoroscopy(d.pedal)),
                    instrument: None,
                });
            }
            if d.reset && !buttons.1 {
                let _ = commands.send(pb::Command {
                    kind: Some(pb::command::Kind::Reset(true)),
                    instrument: None,
                });
            }
            buttons = (d.pedal, d.reset);
        }
        if let (Some(d), Some(to)) = (device, from) {
            // Answered in the device's own version: the outer channel only to a device that
            // sent one (live only when the scene has an outer instrument).
            let feedback = Feedback {
                seq: d.seq,
                device_time_us: d.device_time_us,
                state_age_us: server
                    .as_ref()
                    .map(|v| (v.age_s * 1e6).min(u32::MAX as f64) as u32)
                    .unwrap_or(u32::MAX),
                connected,
                live: output.live,
                force_n: output.force_n,
                torque_nmm: output.torque_nmm,
                outer: d.outer.map(|_| HandFeedback {
                    force_n: outer.force_n,
                    torque_nmm: outer.torque_nmm,
                    live: outer.live,
                }),
            };
            let _ = socket.send_to(&feedback.encode(), to);
        }
        last = Last {
            inner: output,
            outer,
            server: server.as_ref().map(|v| v.inner),
            outer_server: outer_server.map(|(s, i, _)| (s, i)),
        };
        // Reports (locks, quantiles, string copies) only when due, not every tick.
        let t = start.elapsed().as_secs_f64();
        if t >= next_report {
            report(&snapshot(
                t, ticks, overruns, &periods, &ages, shared, &last,
            ));
            next_report += config.report_every_s;
        }
        next += period;
        let after = Instant::now();
        if next > after {
            std::thread::sleep(next - after);
        } else if after.duration_since(next) >= period {
            overruns += 1;
            next = after;
        }
    }
    let t = start.elapsed().as_secs_f64();
    Ok(snapshot(t, ticks, overruns, &periods, &ages, shared, &last))
}

fn snapshot(
    t_s: f64,
    ticks: u64,
    overruns: u64,
    periods: &Histogram<u64>,
    ages: &Histogram<u64>,
    shared: &Shared,
    last: &Last,
) -> Report {
    let (output, server) = (&last.inner, last.server);
    let device = shared.device.lock();
    let link = shared.server.lock();
    let trips = link.round_trip_us.as_ref();
    Report {
        t_s,
        ticks,
        period_p50_us: periods.value_at_quantile(0.5),
        period_p99_us: periods.value_at_quantile(0.99),
        period_max_us: periods.max(),
        overruns,
        round_trip_p50_ms: trips.map_or(0.0, |h| h.value_at_quantile(0.5) as f64 / 1e3),
        round_trip_p99_ms: trips.map_or(0.0, |h| h.value_at_quantile(0.99) as f64 / 1e3),
        round_trips: trips.map_or(0, |h| h.len()),
        server_updates: link.updates,
        state_age_p99_ms: ages.value_at_quantile(0.99) as f64 / 1e3,
        connected: link.inputs.is_some(),
        session: if link.inputs.is_some() {
            link.session.clone()
        } else {
            String::new()
        },
        reconnects: link.reconnects,
        sessions_created: link.created,
        device_packets: device.packets,
        device_lost: device.lost,
        device_rejected: device.rejected,
        force_n: output.force_n,
        torque_nmm: output.torque_nmm,
        inserted_mm: server.map_or(0.0, |s| s.inserted_mm),
        server_force_n: server.map_or(0.0, |s| s.axial_force_n),
        outer_force_n: last.outer.force_n,
        outer_torque_nmm: last.outer.torque_nmm,
        outer_inserted_mm: last.outer_server.map_or(0.0, |(s, _)| s.inserted_mm),
        outer_server_force_n: last.outer_server.map_or(0.0, |(s, _)| s.axial_force_n),
        outer_instrument: last.outer_server.map(|(_, i)| i),
        last_error: link.last_error.clone(),
    }
}
