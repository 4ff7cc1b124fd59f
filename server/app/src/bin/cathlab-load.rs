//! `cathlab-load`: the server's load benchmark. Starts `cathlab-server` as a child process on
//! 127.0.0.1 with a fresh database and, for each session count, runs that many sessions at
//! once on the default scene (500 Hz physics, fluoroscopy at 15 pulses/s, 512×512 frames
//! streamed raw to a client each, state streamed too, the wire being pushed), then reports
//! missed physics steps and step/frame time percentiles from the server, frame rates as
//! received, the server's resident memory per session, the command-to-state latency of unary
//! commands and the round trip of the bidirectional control stream at 1 kHz.
//!
//! With `--servers N` (N > 1) it loads a fleet instead: a throwaway PostgreSQL cluster (Debian's
//! binaries) and N server processes sharing it, `--sessions-per-server` sessions on each, and
//! reports each server's steps, late and missed steps, the command-to-state latency measured
//! on every server at once, and the rows the fleet wrote to the shared store per second.

mod harness;

use std::process::Stdio;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use cathlab_api::authorized as authed;
use cathlab_api::pb;
use cathlab_api::pb::simulator_client::SimulatorClient;
use clap::Parser;
use harness::{Server, ServerArgs, rss_mib};
use tonic::transport::Channel;

#[derive(Debug, Parser)]
#[command(name = "cathlab-load", about = "cathlab server load benchmark")]
struct Cli {
    /// Session counts to run, in order.
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,5,6")]
    sessions: Vec<usize>,
    /// Measured seconds per session count (after a 3 s warm-up).
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Latency samples (unary) and control inputs (1 kHz stream).
    #[arg(long, default_value_t = 2000)]
    samples: usize,
    /// The scene every session runs (a name in the scene directory), e.g. the triaxial
    /// `neuro_phantom_m1`.
    #[arg(long, default_value = "arch_to_cow_lcca")]
    scene: String,
    /// Servers in a fleet sharing one PostgreSQL (1: the single-server benchmark).
    #[arg(long, default_value_t = 1)]
    servers: usize,
    /// Sessions on each server of the fleet.
    #[arg(long, default_value_t = 1)]
    sessions_per_server: usize,
    /// Sessions the memory measurement opens one after another (at least 2: the growth per
    /// extra session), 3 s apart.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(2..=16))]
    memory_sessions: u64,
    #[command(flatten)]
    target: ServerArgs,
}

fn start_server(cli: &Cli, database: &std::path::Path) -> Result<Server> {
    // Every session of the benchmark comes from one client: the per-client limits (which
    // keep one client from taking every place) are lifted for it.
    let config = database.with_extension("toml");
    std::fs::write(
        &config,
        "max_sessions_per_client = 4096\nsession_creations_per_minute = 100000\n",
    )?;
    // The 1 kHz probe runs an inline scene.
    Server::start(
        &Server::binary(cli.target.server.as_deref())?,
        database,
        &cli.target.scenes,
        "load",
        &[
            "--renderer",
            &cli.target.renderer,
            "--inline-scenes",
            "anyone",
            "--config",
            config.to_str().context("a UTF-8 temporary path")?,
        ],
        Stdio::inherit(),
    )
}

fn command(kind: pb::command::Kind) -> Option<pb::Command> {
    Some(pb::Command {
        kind: Some(kind),
        instrument: None,
    })
}

fn push(mm_s: f64) -> Option<pb::Command> {
    command(pb::command::Kind::Insertion(pb::Insertion {
        mode: Some(pb::insertion::Mode::VelocityMmS(mm_s)),
        hold: false,
    }))
}

async fn send(
    client: &mut SimulatorClient<Channel>,
    s: &pb::CreateSessionResponse,
    seq: u64,
    c: Option<pb::Command>,
) -> Result<pb::CommandAck> {
    Ok(client
        .send_command(authed(
            pb::SendCommandRequest {
                session_id: s.session_id.clone(),
                seq,
                command: c,
            },
            &s.controller_token,
        ))
        .await?
        .into_inner())
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

/// A loaded session: frames and state drained by client tasks.
struct Loaded {
    session: pb::CreateSessionResponse,
    frames: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

async fn load_session(client: &mut SimulatorClient<Channel>, scene: &str) -> Result<Loaded> {
    load_scene(
        client,
        pb::create_session_request::Scene::SceneName(scene.into()),
    )
    .await
}

async fn load_scene(
    client: &mut SimulatorClient<Channel>,
    scene: pb::create_session_request::Scene,
) -> Result<Loaded> {
    let session = client
        .create_session(pb::CreateSessionRequest {
            scene: Some(scene),
            label: "load".into(),
            ..Default::default()
        })
        .await?
        .into_inner();
    send(
        client,
        &session,
        1,
        command(pb::command::Kind::Fluoroscopy(true)),
    )
    .await?;
    // Push slowly in and out so the wire keeps moving through contacts.
    send(client, &session, 2, push(15.0)).await?;
    let frames = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let mut stream = client
        .stream_frames(authed(
            pb::StreamFramesRequest {
                session_id: session.session_id.clone(),
                encoding: pb::FrameEncoding::Raw8 as i32,
                width: 0,
                height: 0,
                jpeg_quality: 0,
            },
            &session.observer_token,
        ))
        .await?
        .into_inner();
    let counter = frames.clone();
    tokio::spawn(async move {
        while let Ok(Some(_)) = stream.message().await {
            counter.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
    });
    let mut states = client
        .stream_state(authed(
            pb::StreamStateRequest {
                session_id: session.session_id.clone(),
                tip_only: false,
            },
            &session.observer_token,
        ))
        .await?
        .into_inner();
    tokio::spawn(async move { while let Ok(Some(_)) = states.message().await {} });
    Ok(Loaded { session, frames })
}

async fn close_all(client: &mut SimulatorClient<Channel>, loaded: &mut Vec<Loaded>) -> Result<()> {
    for l in loaded.drain(..) {
        client
            .close_session(authed(
                pb::CloseSessionRequest {
                    session_id: l.session.session_id.clone(),
                },
                &l.session.controller_token,
            ))
            .await?;
    }
    Ok(())
}

/// Unary command → first state that reports it applied.
async fn unary_latency(
    client: &mut SimulatorClient<Channel>,
    s: &pb::CreateSessionResponse,
    samples: usize,
) -> Result<Vec<f64>> {
    let mut states = client
        .stream_state(authed(
            pb::StreamStateRequest {
                session_id: s.session_id.clone(),
                tip_only: true,
            },
            &s.observer_token,
        ))
        .await?
        .into_inner();
    let mut latencies = Vec::with_capacity(samples);
    for i in 0..samples as u64 {
        let seq = 1000 + i;
        let started = Instant::now();
        let mut c = client.clone();
        let session = s.clone();
        let sender = tokio::spawn(async move {
            send(
                &mut c,
                &session,
                seq,
                push(if i % 2 == 0 { 5.0 } else { -5.0 }),
            )
            .await
        });
        loop {
            let state = states.message().await?.context("state stream ended")?;
            if state.last_seq >= seq {
                latencies.push(started.elapsed().as_secs_f64() * 1e3);
                break;
            }
        }
        sender.await??;
        // A pause of random length (OS sleep, not tokio's millisecond timer wheel, whose ticks
        // would lock the sends to a fixed phase of the physics period).
        let pause = Duration::from_micros(300 + rand::random_range(0..2000));
        tokio::task::spawn_blocking(move || std::thread::sleep(pause)).await?;
    }
    latencies.sort_by(f64::total_cmp);
    Ok(latencies)
}

/// Control stream at 1 kHz: input sent → first output reporting it.
async fn control_round_trip(
    client: &mut SimulatorClient<Channel>,
    s: &pb::CreateSessionResponse,
    samples: usize,
) -> Result<Vec<f64>> {
    let (tx, rx) = tokio::sync::mpsc::channel(64);
    let request = authed(
        tokio_stream::wrappers::ReceiverStream::new(rx),
        &s.controller_token,
    );
    let sent_at = std::sync::Arc::new(parking_lot::Mutex::new(Vec::<Instant>::with_capacity(
        samples,
    )));
    let id = s.session_id.clone();
    let times = sent_at.clone();
    let base_seq = 1_000_000u64;
    // Inputs at 1 kHz from an OS thread with precise sleeps, each at a random point of its
    // millisecond, so that they fall at every phase of the physics period.
    let sender = std::thread::spawn(move || {
        let start = Instant::now();
        for i in 0..samples as u64 {
            let due = start
                + Duration::from_millis(i)
                + Duration::from_micros(rand::random_range(0..1000));
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
            times.lock().push(Instant::now());
            let input = pb::ControlInput {
                session_id: if i == 0 { id.clone() } else { String::new() },
                seq: base_seq + i,
                push_mm_s: if (i / 250) % 2 == 0 { 10.0 } else { -10.0 },
                twist_deg_s: 0.0,
                hands: Vec::new(),
            };
            if tx.blocking_send(input).is_err() {
                break;
            }
        }
        tx
    });
    let mut outputs = client.control(request).await?.into_inner();
    let mut acknowledged = 0usize;
    let mut rtts = Vec::with_capacity(samples);
    while acknowledged < samples {
        let out = outputs.message().await?.context("control stream ended")?;
        let now = Instant::now();
        let last = out.state.map_or(0, |s| s.last_seq);
        if last < base_seq {
            continue;
        }
        let upto = ((last - base_seq) as usize + 1).min(samples);
        let times = sent_at.lock();
        while acknowledged < upto && acknowledged < times.len() {
            rtts.push((now - times[acknowledged]).as_secs_f64() * 1e3);
            acknowledged += 1;
        }
    }
    drop(
        sender
            .join()
            .map_err(|_| anyhow::anyhow!("the input thread panicked"))?,
    );
    rtts.sort_by(f64::total_cmp);
    Ok(rtts)
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<()> {
    let cli = Cli::parse();
    if cli.servers > 1 {
        return fleet(&cli).await;
    }
    let dir = std::env::temp_dir().join(format!("cathlab-load-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let server = start_server(&cli, &dir.join("load.sqlite"))?;
    let pid = server.child.id();
    let mut client = SimulatorClient::connect(format!("http://{}", server.address))
        .await?
        .max_decoding_message_size(64 << 20);
    let idle = rss_mib(pid);
    println!(
        "cathlab-load: server pid {pid} at {}, idle RSS {idle:.1} MiB",
        server.address
    );

    // Memory: one session, then more on the same scene.
    let mut loaded = Vec::new();
    let mut rss = Vec::new();
    let mut created = Vec::new();
    for _ in 0..cli.memory_sessions {
        let started = std::time::Instant::now();
        loaded.push(load_session(&mut client, &cli.scene).await?);
        created.push(started.elapsed().as_secs_f64());
        tokio::time::sleep(Duration::from_secs(3)).await;
        rss.push(rss_mib(pid));
    }
    // The first creation loads the scene's assets (built, or read from a disk cache where the
    // server has one); the others share them.
    println!(
        "load: {} session created in {:.2} s (its assets loaded), then {:?} s",
        cli.scene,
        created[0],
        created[1..]
            .iter()
            .map(|v| (v * 100.0).round() / 100.0)
            .collect::<Vec<_>>()
    );
    let growth: Vec<f64> = rss.windows(2).map(|w| w[1] - w[0]).collect();
    println!(
        "memory: RSS with 1..{} sessions {:?} MiB; growth per extra session {:?} MiB",
        cli.memory_sessions,
        rss.iter()
            .map(|v| (v * 10.0).round() / 10.0)
            .collect::<Vec<_>>(),
        growth
            .iter()
            .map(|v| (v * 10.0).round() / 10.0)
            .collect::<Vec<_>>()
    );
    close_all(&mut client, &mut loaded).await?;

    // Latency on an otherwise idle server (one session, fluoroscopy on), at the default 500 Hz
    // physics and on the same scene at 1 kHz (the haptic bridge's rate).
    let default_scene =
        std::fs::read_to_string(cli.target.scenes.join(format!("{}.toml", cli.scene)))?;
    for rate in [500, 1000] {
        let text = default_scene.replace("step_rate_hz = 500", &format!("step_rate_hz = {rate}"));
        let probe = load_scene(
            &mut client,
            pb::create_session_request::Scene::SceneToml(text),
        )
        .await?;
        tokio::time::sleep(Duration::from_secs(2)).await;
        let unary = unary_latency(&mut client, &probe.session, cli.samples.min(1000)).await?;
        let control = control_round_trip(&mut client, &probe.session, cli.samples).await?;
        println!(
            "{rate} Hz physics: command → state (unary, {} samples): p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
            unary.len(),
            percentile(&unary, 0.5),
            percentile(&unary, 0.99),
            unary.last().copied().unwrap_or(f64::NAN)
        );
        println!(
            "{rate} Hz physics: control stream at 1 kHz ({} inputs): round trip p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
            control.len(),
            percentile(&control, 0.5),
            percentile(&control, 0.99),
            control.last().copied().unwrap_or(f64::NAN)
        );
        let mut probe_list = vec![probe];
        close_all(&mut client, &mut probe_list).await?;
    }

    println!();
    println!(
        "| sessions | steps | late | missed | step p50 | step p99 | step max | frames/s per session | frame p50 | frame p99 | frame max |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for &n in &cli.sessions {
        for _ in 0..n {
            loaded.push(load_session(&mut client, &cli.scene).await?);
        }
        tokio::time::sleep(Duration::from_secs(3)).await;
        let start_frames: Vec<u64> = loaded
            .iter()
            .map(|l| l.frames.load(std::sync::atomic::Ordering::Relaxed))
            .collect();
        let mut infos0 = Vec::new();
        for l in &loaded {
            infos0.push(session_info(&mut client, &l.session).await?);
        }
        let started = Instant::now();
        tokio::time::sleep(Duration::from_secs_f64(cli.seconds)).await;
        let elapsed = started.elapsed().as_secs_f64();
        let mut infos = Vec::new();
        for l in &loaded {
            infos.push(session_info(&mut client, &l.session).await?);
        }
        let fps: Vec<f64> = loaded
            .iter()
            .zip(&start_frames)
            .map(|(l, s)| {
                (l.frames.load(std::sync::atomic::Ordering::Relaxed) - s) as f64 / elapsed
            })
            .collect();
        let t = |i: &pb::SessionInfo| i.timing.unwrap_or_default();
        let steps: u64 = infos
            .iter()
            .zip(&infos0)
            .map(|(a, b)| t(a).steps - t(b).steps)
            .sum();
        let late: u64 = infos
            .iter()
            .zip(&infos0)
            .map(|(a, b)| t(a).late_steps - t(b).late_steps)
            .sum();
        let missed: u64 = infos
            .iter()
            .zip(&infos0)
            .map(|(a, b)| t(a).missed_steps - t(b).missed_steps)
            .sum();
        let worst = |f: fn(&pb::Timing) -> f64| infos.iter().map(|i| f(&t(i))).fold(0.0, f64::max);
        println!(
            "| {n} | {steps} ({:.0}/s each) | {late} | {missed} | {:.3} ms | {:.3} ms | {:.2} ms | {:.1}–{:.1} | {:.1} ms | {:.1} ms | {:.0} ms |",
            steps as f64 / elapsed / n as f64,
            worst(|t| t.step_time_p50_ms),
            worst(|t| t.step_time_p99_ms),
            worst(|t| t.step_time_max_ms),
            fps.iter().copied().fold(f64::INFINITY, f64::min),
            fps.iter().copied().fold(0.0, f64::max),
            worst(|t| t.frame_time_p50_ms),
            worst(|t| t.frame_time_p99_ms),
            worst(|t| t.frame_time_max_ms),
        );
        close_all(&mut client, &mut loaded).await?;
    }
    println!(
        "(late: steps started a whole period behind schedule; missed: periods dropped after falling 25 periods behind; percentiles are the worst session's, over each session's whole life)"
    );
    drop(server);
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

async fn session_info(
    client: &mut SimulatorClient<Channel>,
    s: &pb::CreateSessionResponse,
) -> Result<pb::SessionInfo> {
    Ok(client
        .get_session(authed(
            pb::GetSessionRequest {
                session_id: s.session_id.clone(),
            },
            &s.observer_token,
        ))
        .await?
        .into_inner())
}

/// Rows in the store's recording tables (commands, checkpoints, events).
fn store_rows(url: &str) -> Result<[i64; 3]> {
    let url = url.to_owned();
    // The sync client runs a runtime of its own: off the async threads.
    std::thread::spawn(move || -> Result<[i64; 3]> {
        let mut db = postgres::Client::connect(&url, postgres::NoTls)?;
        let row = db.query_one(
            "SELECT (SELECT count(*) FROM commands), (SELECT count(*) FROM checkpoints), \
             (SELECT count(*) FROM events)",
            &[],
        )?;
        Ok([row.get(0), row.get(1), row.get(2)])
    })
    .join()
    .map_err(|_| anyhow::anyhow!("the store query panicked"))?
}

/// The fleet benchmark: `--servers` processes on one PostgreSQL.
async fn fleet(cli: &Cli) -> Result<()> {
    let cluster = cathlab_app::store::cluster::PgCluster::start()
        .map_err(|e| anyhow::anyhow!("starting PostgreSQL: {e}"))?;
    let url = cluster
        .database("fleet")
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let dir = std::env::temp_dir().join(format!("cathlab-fleet-load-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let binary = Server::binary(cli.target.server.as_deref())?;
    let mut servers = Vec::new();
    for i in 0..cli.servers {
        let id = format!("fleet-{i}");
        servers.push(Server::start(
            &binary,
            &dir.join(format!("{id}.sqlite")),
            &cli.target.scenes,
            &id,
            &[
                "--renderer",
                &cli.target.renderer,
                "--database-url",
                &url,
                "--server-id",
                &id,
            ],
            Stdio::inherit(),
        )?);
    }
    let mut clients = Vec::new();
    let mut loaded = Vec::new();
    for server in &servers {
        let mut client = SimulatorClient::connect(format!("http://{}", server.address))
            .await?
            .max_decoding_message_size(64 << 20);
        let mut here = Vec::new();
        for _ in 0..cli.sessions_per_server {
            here.push(load_session(&mut client, &cli.scene).await?);
        }
        clients.push(client);
        loaded.push(here);
    }
    println!(
        "cathlab-load: a fleet of {} servers on one PostgreSQL, {} session(s) each on {}",
        cli.servers, cli.sessions_per_server, cli.scene
    );
    tokio::time::sleep(Duration::from_secs(3)).await;
    let mut before = Vec::new();
    for (client, here) in clients.iter_mut().zip(&loaded) {
        for l in here {
            before.push(session_info(client, &l.session).await?);
        }
    }
    let rows0 = store_rows(&url)?;
    let started = Instant::now();
    // Command → state on every server at once (each command stored before its ack).
    let probes: Vec<_> = clients
        .iter()
        .zip(&loaded)
        .map(|(client, here)| {
            let (mut client, session) = (client.clone(), here[0].session.clone());
            let samples = cli.samples.min(1000);
            tokio::spawn(async move { unary_latency(&mut client, &session, samples).await })
        })
        .collect();
    let mut latencies = Vec::new();
    for p in probes {
        latencies.extend(p.await??);
    }
    let rest = Duration::from_secs_f64(cli.seconds).saturating_sub(started.elapsed());
    tokio::time::sleep(rest).await;
    let elapsed = started.elapsed().as_secs_f64();
    let rows1 = store_rows(&url)?;
    let mut after = Vec::new();
    for (client, here) in clients.iter_mut().zip(&loaded) {
        for l in here {
            after.push(session_info(client, &l.session).await?);
        }
    }
    latencies.sort_by(f64::total_cmp);
    let t = |i: &pb::SessionInfo| i.timing.unwrap_or_default();
    println!();
    println!("| server | sessions | steps/s each | late | missed | step p99 |");
    println!("|---|---|---|---|---|---|");
    let per = cli.sessions_per_server;
    for s in 0..cli.servers {
        let range = s * per..(s + 1) * per;
        let steps: u64 = range
            .clone()
            .map(|i| t(&after[i]).steps - t(&before[i]).steps)
            .sum();
        let late: u64 = range
            .clone()
            .map(|i| t(&after[i]).late_steps - t(&before[i]).late_steps)
            .sum();
        let missed: u64 = range
            .clone()
            .map(|i| t(&after[i]).missed_steps - t(&before[i]).missed_steps)
            .sum();
        let p99 = range
            .map(|i| t(&after[i]).step_time_p99_ms)
            .fold(0.0, f64::max);
        println!(
            "| fleet-{s} | {per} | {:.0} | {late} | {missed} | {p99:.3} ms |",
            steps as f64 / elapsed / per as f64
        );
    }
    println!(
        "command → state over the fleet (unary, {} samples, {} servers at once): p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
        latencies.len(),
        cli.servers,
        percentile(&latencies, 0.5),
        percentile(&latencies, 0.99),
        latencies.last().copied().unwrap_or(f64::NAN)
    );
    let rate = |k: usize| (rows1[k] - rows0[k]) as f64 / elapsed;
    println!(
        "shared store: {:.0} commands/s, {:.0} checkpoints/s, {:.1} events/s written ({:.0} rows/s) over {elapsed:.1} s",
        rate(0),
        rate(1),
        rate(2),
        rate(0) + rate(1) + rate(2)
    );
    // Durable commands as fast as they are acknowledged: every session's client sends back to
    // back for 5 s (each ack follows its commit to the shared store).
    let burst = Duration::from_secs(5);
    let senders: Vec<_> = clients
        .iter()
        .zip(&loaded)
        .flat_map(|(client, here)| {
            here.iter().map(move |l| {
                let (mut client, session) = (client.clone(), l.session.clone());
                tokio::spawn(async move {
                    let started = Instant::now();
                    let mut acked = 0u64;
                    while started.elapsed() < burst {
                        let seq = 10_000 + acked;
                        send(
                            &mut client,
                            &session,
                            seq,
                            push(if seq.is_multiple_of(2) { 1.0 } else { -1.0 }),
                        )
                        .await?;
                        acked += 1;
                    }
                    anyhow::Ok(acked)
                })
            })
        })
        .collect();
    let mut acked = 0;
    for s in senders {
        acked += s.await??;
    }
    println!(
        "durable commands, every session's client sending back to back for {} s: {:.0} acknowledged/s over the fleet",
        burst.as_secs(),
        acked as f64 / burst.as_secs_f64()
    );
    for (client, mut here) in clients.iter_mut().zip(loaded) {
        close_all(client, &mut here).await?;
    }
    drop(servers);
    drop(cluster);
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
