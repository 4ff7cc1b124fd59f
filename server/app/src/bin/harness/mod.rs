//! What the load and soak benchmarks share: the server as a child process, its resident
//! memory and its Prometheus text.

// Each binary uses a part of it.
#![allow(dead_code)]

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use anyhow::{Context, Result};

/// The flags both benchmarks take to start their server.
#[derive(Debug, clap::Args)]
pub struct ServerArgs {
    /// The server binary (default: next to this one).
    #[arg(long)]
    pub server: Option<PathBuf>,
    /// Scene directory.
    #[arg(long, default_value = "scenes")]
    pub scenes: PathBuf,
    /// Renderer (auto, cpu, gpu).
    #[arg(long, default_value = "auto")]
    pub renderer: String,
}

/// A `cathlab-server` child process; killed when dropped.
pub struct Server {
    /// The process.
    pub child: Child,
    /// `HOST:PORT` it listens on.
    pub address: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Server {
    /// The server binary: `explicit`, or `cathlab-server` next to the running binary.
    pub fn binary(explicit: Option<&Path>) -> Result<PathBuf> {
        Ok(match explicit {
            Some(p) => p.to_owned(),
            None => std::env::current_exe()?
                .parent()
                .context("no parent directory")?
                .join("cathlab-server"),
        })
    }

    /// Starts `binary` on 127.0.0.1 (a free port) with `database`, `scenes`, the instructor
    /// key `key` and `extra` flags; `stderr` is where its log goes.
    pub fn start(
        binary: &Path,
        database: &Path,
        scenes: &Path,
        key: &str,
        extra: &[&str],
        stderr: Stdio,
    ) -> Result<Self> {
        let mut child = Command::new(binary)
            .args(["--listen", "127.0.0.1:0", "--database"])
            .arg(database)
            .arg("--scenes")
            .arg(scenes)
            .arg("--exit-on-stdin-eof")
            .args(extra)
            .env("CATHLAB_INSTRUCTOR_KEY", key)
            .env("RUST_LOG", "warn")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .with_context(|| format!("starting {}", binary.display()))?;
        let stdout = child.stdout.take().context("no stdout")?;
        let mut lines = std::io::BufReader::new(stdout).lines();
        let address = loop {
            let line = lines.next().context("the server exited")??;
            if let Some(a) = line.strip_prefix("cathlab-server listening on ") {
                break a.trim().to_owned();
            }
        };
        // Keep draining stdout so the server never blocks on it.
        std::thread::spawn(move || for _ in lines {});
        Ok(Self { child, address })
    }

    /// `http://HOST:PORT`.
    pub fn url(&self) -> String {
        format!("http://{}", self.address)
    }

    /// Resident memory (MiB), NaN when it cannot be read.
    pub fn rss_mib(&self) -> f64 {
        rss_mib(self.child.id())
    }

    /// Resident anonymous memory (MiB: the heap and stacks, without the pages of mapped
    /// files such as the binary's own code), NaN when it cannot be read.
    pub fn anon_mib(&self) -> f64 {
        status_mib(self.child.id(), "RssAnon:")
    }

    /// One sample of a Prometheus family (`name` or `name_total`) from `/metrics`.
    pub async fn metric(&self, name: &str) -> Result<f64> {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut stream = tokio::net::TcpStream::connect(&self.address).await?;
        stream
            .write_all(
                format!(
                    "GET /metrics HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
                    self.address
                )
                .as_bytes(),
            )
            .await?;
        let mut text = String::new();
        stream.read_to_string(&mut text).await?;
        text.lines()
            .find_map(|l| {
                l.strip_prefix(&format!("{name} "))
                    .or_else(|| l.strip_prefix(&format!("{name}_total ")))
            })
            .and_then(|v| v.trim().parse().ok())
            .with_context(|| format!("{name} in /metrics"))
    }
}

/// Resident memory of process `pid` (MiB), NaN when it cannot be read.
pub fn rss_mib(pid: u32) -> f64 {
    status_mib(pid, "VmRSS:")
}

/// A memory line of `/proc/PID/status` (`VmRSS:`, `RssAnon:`, `RssFile:`) in MiB, NaN when
/// it cannot be read.
pub fn status_mib(pid: u32, field: &str) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(field))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}
