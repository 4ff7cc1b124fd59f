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

mod actions;
mod attacks;
mod bombs;
mod calls;
mod client;
mod common;
#[path = "../harness/mod.rs"]
mod harness;
mod play;
mod raw;
mod tally;
mod watched;

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
use rand::RngExt;

use actions::Action;
use bombs::write_bombs;
use client::Chaos;
use common::{KEY, SCENE, config};
use tally::{ATTACK_ROWS, Tally};
use watched::{drive, timing, watched_session};

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
