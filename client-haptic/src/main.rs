//! `cathlab-haptic-bridge`: `bridge` connects a haptic device (UDP) to a session's control
//! stream; `virtual-device` plays a scripted device against a bridge. Both print one JSON
//! object per line on standard output.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use cathlab_haptic_bridge::bridge::{self, BridgeConfig, SceneSource, SessionChoice};
use cathlab_haptic_bridge::coupling::CouplingSettings;
use cathlab_haptic_bridge::device::{self, VirtualDevice};
use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(name = "cathlab-haptic-bridge", about = "cathlab haptic-device bridge")]
struct Cli {
    #[command(subcommand)]
    command: Action,
}

#[derive(Debug, Subcommand)]
enum Action {
    /// Bridge a device to a session: attach with --session and --token, or create one with
    /// --scene or --scene-file (made again after a server restart).
    Bridge {
        /// Server URL.
        #[arg(long, default_value = "http://127.0.0.1:50051")]
        server: String,
        /// Session to attach to (with --token, its controller token).
        #[arg(long, requires = "token")]
        session: Option<String>,
        /// Controller token of --session.
        #[arg(long)]
        token: Option<String>,
        /// Create a session on this listed scene.
        #[arg(long, conflicts_with_all = ["session", "scene_file"])]
        scene: Option<String>,
        /// Create a session from this scene file (TOML, sent inline).
        #[arg(long, conflicts_with = "session")]
        scene_file: Option<PathBuf>,
        /// Label for the dashboard.
        #[arg(long, default_value = "haptic")]
        label: String,
        /// UDP address for the device.
        #[arg(long, default_value = "127.0.0.1:7700")]
        udp: SocketAddr,
        /// Loop rate (Hz).
        #[arg(long, default_value_t = 1000.0)]
        rate_hz: f64,
        /// Report period (s).
        #[arg(long, default_value_t = 1.0)]
        report_s: f64,
        /// Stop when standard input closes (for supervisors and tests).
        #[arg(long)]
        exit_on_stdin_eof: bool,
    },
    /// A scripted virtual device.
    VirtualDevice {
        /// The bridge's UDP address.
        #[arg(long, default_value = "127.0.0.1:7700")]
        bridge: SocketAddr,
        /// Motion: push:MM_S:S, twist:DEG_S:S, outer-push:MM_S:S, outer-twist:DEG_S:S,
        /// hold:S, pedal:on|off, comma-separated (the outer segments move the outer hand).
        #[arg(long)]
        script: String,
        /// Speak protocol version 2 with two channels (implied by outer-hand segments).
        #[arg(long)]
        two_hands: bool,
        /// Device rate (Hz).
        #[arg(long, default_value_t = 1000.0)]
        rate_hz: f64,
        /// Fraction of datagrams to drop each way (0..1).
        #[arg(long, default_value_t = 0.0)]
        loss: f64,
        /// Report period (s).
        #[arg(long, default_value_t = 0.1)]
        report_s: f64,
    },
}

fn positive(name: &str, v: f64, max: f64) -> anyhow::Result<f64> {
    if v.is_finite() && v > 0.0 && v <= max {
        Ok(v)
    } else {
        anyhow::bail!("--{name} {v} is outside (0, {max}]")
    }
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Action::Bridge {
            server,
            session,
            token,
            scene,
            scene_file,
            label,
            udp,
            rate_hz,
            report_s,
            exit_on_stdin_eof,
        } => {
            let session = match (session, token, scene, scene_file) {
                (Some(id), Some(token), None, None) => SessionChoice::Attach { id, token },
                (None, _, Some(name), None) => SessionChoice::Create {
                    scene: SceneSource::Name(name),
                    label,
                },
                (None, _, None, Some(file)) => SessionChoice::Create {
                    scene: SceneSource::Toml(
                        std::fs::read_to_string(&file)
                            .with_context(|| format!("reading {}", file.display()))?,
                    ),
                    label,
                },
                _ => anyhow::bail!(
                    "give --session with --token, or --scene, or --scene-file (one of them)"
                ),
            };
            let config = BridgeConfig {
                server,
                session,
                udp,
                rate_hz: positive("rate-hz", rate_hz, 10_000.0)?,
                coupling: CouplingSettings::default(),
                report_every_s: positive("report-s", report_s, 3600.0)?,
                device_timeout_s: 0.1,
            };
            let stop = Arc::new(AtomicBool::new(false));
            if exit_on_stdin_eof {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let _ = std::io::copy(&mut std::io::stdin(), &mut std::io::sink());
                    stop.store(true, Ordering::SeqCst);
                });
            }
            let last = bridge::run(
                config,
                stop,
                |address| {
                    println!(
                        "{}",
                        serde_json::json!({"event": "listening", "udp": address})
                    )
                },
                |report| {
                    println!(
                        "{}",
                        serde_json::json!({"event": "report", "report": report})
                    )
                },
            )?;
            println!(
                "{}",
                serde_json::json!({"event": "stopped", "report": last})
            );
            Ok(())
        }
        Action::VirtualDevice {
            bridge,
            script,
            two_hands,
            rate_hz,
            loss,
            report_s,
        } => {
            if !(0.0..1.0).contains(&loss) {
                anyhow::bail!("--loss {loss} is outside [0, 1)");
            }
            let script = device::parse_script(&script)?;
            let device = VirtualDevice {
                bridge,
                two_hands: two_hands || device::moves_outer_hand(&script),
                script,
                rate_hz: positive("rate-hz", rate_hz, 10_000.0)?,
                loss,
                report_every_s: positive("report-s", report_s, 3600.0)?,
            };
            let last = device::run(&device, |r| {
                println!("{}", serde_json::json!({"event": "sample", "sample": r}))
            })?;
            println!("{}", serde_json::json!({"event": "done", "sample": last}));
            Ok(())
        }
    }
}
