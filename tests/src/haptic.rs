//! Shared by the bridge's end-to-end test and its latency benchmark: a real cathlab server in
//! this process, the bridge and virtual-device processes, their JSON lines, the wall scene.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use cathlab_app::config::{InlineScenes, RendererChoice, ServerConfig};
use serde_json::Value;

/// Held by each end-to-end test for its whole run: each starts a server, a bridge and devices
/// at 1 kHz, and two at once on two cores starve each other's loops.
pub fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The default scene with a 0.014" microwire started 46 mm before the end of the LCCA route
/// (416 mm long), where the lumen is capped.
pub fn wall_scene() -> String {
    let text =
        std::fs::read_to_string(crate::repo_root().join("scenes/arch_to_cow_lcca.toml")).unwrap();
    let start = text.find("[[devices]]").unwrap();
    let end = text.find("[start]").unwrap();
    let text = format!(
        "{}[[devices]]\npreset = \"microwire_014\"\n\n{}",
        &text[..start],
        &text[end..]
    );
    text.replace("along_route_mm = 0.0", "along_route_mm = 360.0")
}

/// The wall scene with a coaxial stack instead: a 5 F catheter with its tip 20 mm in and a
/// straight 0.014" microwire (the wall scene's) 10 mm out of it (the cap is 56 mm beyond the entry).
pub fn coaxial_wall_scene() -> String {
    let text = wall_scene();
    let start = text.find("[[devices]]").unwrap();
    let end = text.find("[start]").unwrap();
    format!(
        "{}[[stack]]\ndevice = \"catheter-5f-vertebral\"\ninserted_mm = 20.0\n\n\
         [[stack]]\ncustom = {{ preset = \"microwire_014\" }}\ninserted_mm = 30.0\n\n{}",
        &text[..start],
        &text[end..]
    )
}

/// A loopback server on a free port (recording to `database`) and the bridge connected to
/// it with the wall scene written into `dir`, once the bridge reports its UDP address and a
/// connection.
pub struct Rig {
    /// The server.
    pub server: Server,
    /// Its port, to start it again on.
    pub port: u16,
    /// The bridge process (reports every 0.2 s; exits when its stdin closes).
    pub bridge: Lines,
    /// The bridge's device address.
    pub udp: String,
}

impl Rig {
    /// [`Rig::start_with`] the wall scene.
    pub fn start(dir: &Path, database: &Path) -> Self {
        Self::start_with(dir, database, &wall_scene())
    }

    /// The same with another scene text.
    pub fn start_with(dir: &Path, database: &Path, scene_text: &str) -> Self {
        std::fs::create_dir_all(dir).unwrap();
        let scene = dir.join("wall.toml");
        std::fs::write(&scene, scene_text).unwrap();
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let server = Server::start(port, database);
        let url = format!("http://127.0.0.1:{port}");
        let bridge = Lines::spawn(&[
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
        let udp = bridge.next("listening line")["udp"]
            .as_str()
            .unwrap()
            .to_owned();
        bridge.until(60.0, "a connected report", |v| {
            v["report"]["connected"] == true
        });
        Self {
            server,
            port,
            bridge,
            udp,
        }
    }
}

/// The cathlab server running in this process (on its own runtime thread).
pub struct Server {
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Server {
    /// Starts a server on 127.0.0.1:`port` recording to `database`, once it answers.
    pub fn start(port: u16, database: &Path) -> Self {
        let config = ServerConfig {
            listen: format!("127.0.0.1:{port}"),
            database: database.to_path_buf(),
            scenes: crate::repo_root().join("scenes"),
            renderer: RendererChoice::Cpu,
            web_root: crate::repo_root().join("no-web-client"),
            // The bridge sends its wall scene as a scene text.
            inline_scenes: InlineScenes::Anyone,
            // The anatomy built once for every suite (as the spawned servers read it).
            asset_disk_cache: Some(crate::asset_disk_cache()),
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

    /// Shuts the server down gracefully and joins its thread.
    pub fn stop(mut self) {
        let _ = self.stop.take().unwrap().send(());
        self.thread.take().unwrap().join().unwrap();
    }
}

/// A child printing JSON lines, read on a thread.
pub struct Lines {
    /// The process.
    pub child: Child,
    /// Its stdout lines that parse as JSON.
    pub lines: mpsc::Receiver<Value>,
}

impl Lines {
    /// Starts `cathlab-haptic-bridge` with `args`.
    pub fn spawn(args: &[&str]) -> Self {
        let mut child = Command::new(crate::binary("cathlab-haptic-bridge"))
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

    /// The next JSON line (60 s at most; `what` names it in the panic).
    pub fn next(&self, what: &str) -> Value {
        self.lines
            .recv_timeout(Duration::from_secs(60))
            .unwrap_or_else(|_| panic!("no {what} within 60 s"))
    }

    /// The newest report (the bridge reports every 0.2 s; older lines are skipped).
    pub fn latest(&self) -> Value {
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
    pub fn until(&self, seconds: f64, what: &str, done: impl Fn(&Value) -> bool) -> Value {
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
pub fn device(bridge: &str, script: &str, loss: f64) -> Vec<Value> {
    run_device(&[bridge, script, &loss.to_string()], false)
}

/// The same with a two-channel device (protocol version 2), no loss.
pub fn two_hand_device(bridge: &str, script: &str) -> Vec<Value> {
    run_device(&[bridge, script, "0"], true)
}

fn run_device([bridge, script, loss]: &[&str; 3], two_hands: bool) -> Vec<Value> {
    let mut args = vec![
        "virtual-device",
        "--bridge",
        bridge,
        "--script",
        script,
        "--loss",
        loss,
        "--report-s",
        "0.05",
    ];
    if two_hands {
        args.push("--two-hands");
    }
    let run = Lines::spawn(&args);
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

/// The mean rendered force (N) of `samples` between `from_s` and `to_s` (s).
pub fn mean_force(samples: &[Value], from_s: f64, to_s: f64) -> f64 {
    mean_of(samples, "force_n", from_s, to_s)
}

/// A sample field's mean over `from_s..to_s`.
pub fn mean_of(samples: &[Value], field: &str, from_s: f64, to_s: f64) -> f64 {
    let picked: Vec<f64> = samples
        .iter()
        .filter(|s| (from_s..to_s).contains(&s["t_s"].as_f64().unwrap()))
        .map(|s| s[field].as_f64().unwrap())
        .collect();
    assert!(!picked.is_empty(), "no samples in {from_s}..{to_s} s");
    picked.iter().sum::<f64>() / picked.len() as f64
}
