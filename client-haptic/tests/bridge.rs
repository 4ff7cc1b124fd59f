//! The bridge end to end: a real cathlab server (in this process, on loopback), the bridge
//! and a scripted virtual device as separate processes. The device pushes a straight wire
//! into the capped end of the real LCCA: the rendered force rises. With 10 % of datagrams
//! dropped each way; and the server is stopped and started again under the bridge, which
//! reconnects, makes a new session and renders again.

use std::io::{BufRead, BufReader};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use cathlab_app::config::{RendererChoice, ServerConfig};
use serde_json::Value;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The default scene with a 0.014" microwire started 46 mm before the end of the LCCA route
/// (416 mm long), where the lumen is capped.
fn wall_scene() -> String {
    let text = std::fs::read_to_string(repo().join("scenes/arch_to_cow_lcca.toml")).unwrap();
    let start = text.find("[[devices]]").unwrap();
    let end = text.find("[start]").unwrap();
    let text = format!(
        "{}[[devices]]\npreset = \"microwire_014\"\n\n{}",
        &text[..start],
        &text[end..]
    );
    text.replace("along_route_mm = 0.0", "along_route_mm = 360.0")
}

struct Server {
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Server {
    fn start(port: u16, database: &Path) -> Self {
        let config = ServerConfig {
            listen: format!("127.0.0.1:{port}"),
            database: database.to_path_buf(),
            scenes: repo().join("scenes"),
            renderer: RendererChoice::Cpu,
            web_root: repo().join("no-web-client"),
            ..ServerConfig::default()
        };
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::spawn(move || {
            tokio::runtime::Runtime::new()
                .unwrap()
                .block_on(cathlab_app::server::serve(config, async {
                    let _ = stopped.await;
                }))
                .unwrap();
        });
        // Wait until it accepts connections.
        let deadline = Instant::now() + Duration::from_secs(60);
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "server did not start");
            std::thread::sleep(Duration::from_millis(50));
        }
        Self {
            stop: Some(stop),
            thread: Some(thread),
        }
    }

    fn stop(mut self) {
        let _ = self.stop.take().unwrap().send(());
        self.thread.take().unwrap().join().unwrap();
    }
}

/// A child printing JSON lines, read on a thread.
struct Lines {
    child: Child,
    lines: mpsc::Receiver<Value>,
}

impl Lines {
    fn spawn(args: &[&str]) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_cathlab-haptic-bridge"))
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let stdout = child.stdout.take().unwrap();
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if let Ok(v) = serde_json::from_str::<Value>(&line) {
                    let _ = tx.send(v);
                }
            }
        });
        Self { child, lines }
    }

    fn next(&self, what: &str) -> Value {
        self.lines
            .recv_timeout(Duration::from_secs(60))
            .unwrap_or_else(|_| panic!("no {what} within 60 s"))
    }

    /// The newest report (the bridge reports every 0.2 s; older lines are skipped).
    fn latest(&self) -> Value {
        std::thread::sleep(Duration::from_millis(300));
        let mut last = None;
        while let Ok(v) = self.lines.try_recv() {
            if v["event"] == "report" {
                last = Some(v["report"].clone());
            }
        }
        last.expect("a report in the last 0.3 s")
    }

    /// Reports until one satisfies `done` (or panics after `seconds`).
    fn until(&self, seconds: f64, what: &str, done: impl Fn(&Value) -> bool) -> Value {
        let deadline = Instant::now() + Duration::from_secs_f64(seconds);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(v) if done(&v) => return v,
                Ok(v) if std::env::var("HAPTIC_DEBUG").is_ok() => println!("{v}"),
                Ok(_) => {}
                Err(_) => panic!("no {what} within {seconds} s"),
            }
        }
    }
}

/// Runs a virtual device to the end of its script; returns its samples.
fn device(bridge: &str, script: &str, loss: f64) -> Vec<Value> {
    let run = Lines::spawn(&[
        "virtual-device",
        "--bridge",
        bridge,
        "--script",
        script,
        "--loss",
        &loss.to_string(),
        "--report-s",
        "0.05",
    ]);
    let mut samples = Vec::new();
    loop {
        let v = run.next("device sample");
        let done = v["event"] == "done";
        samples.push(v["sample"].clone());
        if done {
            break;
        }
    }
    samples
}

fn mean_force(samples: &[Value], from_s: f64, to_s: f64) -> f64 {
    let picked: Vec<f64> = samples
        .iter()
        .filter(|s| (from_s..to_s).contains(&s["t_s"].as_f64().unwrap()))
        .map(|s| s["force_n"].as_f64().unwrap())
        .collect();
    assert!(!picked.is_empty(), "no samples in {from_s}..{to_s} s");
    picked.iter().sum::<f64>() / picked.len() as f64
}

#[test]
fn a_virtual_device_feels_the_wall_through_loss_and_a_server_restart() {
    let dir = std::env::temp_dir().join(format!("cathlab-haptic-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("wall.toml");
    std::fs::write(&scene, wall_scene()).unwrap();
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let database = dir.join("haptic.sqlite");
    let server = Server::start(port, &database);
    let url = format!("http://127.0.0.1:{port}");
    let mut bridge = Lines::spawn(&[
        "bridge",
        "--server",
        &url,
        "--scene-file",
        scene.to_str().unwrap(),
        "--udp",
        "127.0.0.1:0",
        "--report-s",
        "0.2",
        "--exit-on-stdin-eof",
    ]);
    let listening = bridge.next("listening line");
    let udp = listening["udp"].as_str().unwrap().to_owned();
    bridge.until(60.0, "a connected report", |v| {
        v["report"]["connected"] == true
    });

    // Hold, then push 60 mm at 15 mm/s: free for ~40 mm, then into the cap.
    let samples = device(&udp, "hold:1,push:15:4,hold:0.5", 0.1);
    if std::env::var("HAPTIC_DEBUG").is_ok() {
        for s in &samples {
            println!("{s}");
        }
        while let Ok(v) = bridge.lines.try_recv() {
            println!("{v}");
        }
    }
    let free = mean_force(&samples, 1.3, 2.3);
    let wall = mean_force(&samples, 4.5, 5.5);
    let connected = samples.iter().filter(|s| s["live"] == true).count();
    println!(
        "force: free {free:.4} N, against the wall {wall:.4} N; {connected} of {} samples live",
        samples.len()
    );
    assert!(
        connected * 10 >= samples.len() * 8,
        "feedback live most of the time"
    );
    assert!(wall > 0.05, "the wall pushes back: {wall} N");
    assert!(
        wall > 3.0 * free.abs().max(0.005),
        "force rises at the wall: {free} → {wall} N"
    );
    let report = bridge.latest();
    println!("bridge: {report}");
    let packets = report["device_packets"].as_f64().unwrap();
    let lost = report["device_lost"].as_f64().unwrap();
    let loss = lost / (packets + lost);
    assert!(
        (0.05..0.15).contains(&loss),
        "10 % dropped, {:.1} % counted lost",
        100.0 * loss
    );
    assert!(report["round_trips"].as_u64().unwrap() > 100, "{report}");

    // The server goes away: the bridge stays, reports the loss, the device is told.
    server.stop();
    bridge.until(10.0, "a disconnected report", |v| {
        v["report"]["connected"] == false
    });
    let quiet = device(&udp, "push:10:0.5", 0.0);
    assert!(
        quiet.iter().all(|s| s["live"] == false),
        "no live feedback without a server"
    );

    // Back on the same port: the bridge reconnects and makes a new session.
    let server = Server::start(port, &database);
    let report = bridge.until(30.0, "a reconnected report", |v| {
        v["report"]["connected"] == true && v["report"]["sessions_created"] == 2
    })["report"]
        .clone();
    assert!(report["reconnects"].as_u64().unwrap() >= 1);
    let again = device(&udp, "hold:0.5,push:15:4", 0.0);
    assert!(
        mean_force(&again, 4.0, 4.5) > 0.05,
        "the wall is felt again after the restart"
    );

    drop(bridge.child.stdin.take());
    let stopped = bridge.until(10.0, "the stopped line", |v| v["event"] == "stopped");
    println!("final bridge report: {}", stopped["report"]);
    assert!(bridge.child.wait().unwrap().success());
    server.stop();
    let _ = std::fs::remove_dir_all(&dir);
}
