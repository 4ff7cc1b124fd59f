//! The server attacked from outside, as a hostile or careless client would: each test starts
//! the real `cathlab-server` with a configuration file and goes at one of its limits.

mod connections;
mod control;
mod files;
mod keys;
mod places;
mod replays;
mod scenes;

use std::path::PathBuf;

use cathlab_api::pb;
use cathlab_tests::*;

/// A server started with `config` (TOML) written into a fresh directory.
fn server_with(name: &str, config: &str) -> (ServerProcess, PathBuf) {
    let dir = temp_dir(name);
    let file = dir.join("server.toml");
    std::fs::write(&file, config).unwrap();
    let server = ServerProcess::start(
        &dir.join("db.sqlite"),
        &["--config", file.to_str().unwrap()],
    );
    (server, dir)
}

/// Resident memory of a process (bytes), from /proc.
fn rss_bytes(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let kb: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("VmRSS");
    kb * 1024
}

fn default_scene_text() -> String {
    std::fs::read_to_string(repo_root().join("scenes/arch_to_cow_lcca.toml")).unwrap()
}

fn inline(text: String) -> pb::CreateSessionRequest {
    pb::CreateSessionRequest {
        scene: Some(pb::create_session_request::Scene::SceneToml(text)),
        label: "attack".into(),
        ..Default::default()
    }
}

/// Tests that measure timing (missed steps, coasting) take this, so that the binary's other
/// tests do not load the two cores under them.
static EXCLUSIVE: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Steps a session has missed so far.
async fn missed_steps(
    client: &mut pb::simulator_client::SimulatorClient<tonic::transport::Channel>,
    session: &pb::CreateSessionResponse,
) -> u64 {
    client
        .get_session(authed(
            pb::GetSessionRequest {
                session_id: session.session_id.clone(),
            },
            &session.controller_token,
        ))
        .await
        .unwrap()
        .into_inner()
        .timing
        .expect("a live session has timing")
        .missed_steps
}

/// The server's Prometheus text, one value.
async fn server_metric(server: &ServerProcess, name: &str) -> f64 {
    let url = format!("{}/metrics", server.url());
    let text = tokio::task::spawn_blocking(move || {
        let out = std::process::Command::new("curl")
            .args(["-s", &url])
            .output()
            .expect("curl");
        String::from_utf8_lossy(&out.stdout).into_owned()
    })
    .await
    .unwrap();
    text.lines()
        .find_map(|l| l.strip_prefix(&format!("{name} ")))
        .or_else(|| {
            text.lines()
                .find_map(|l| l.strip_prefix(&format!("{name}_total ")))
        })
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("{name} in /metrics"))
}

/// Opens a control stream on its own connection with `first` sent; returns the input sender
/// and the outputs.
async fn control_stream(
    server: &ServerProcess,
    token: &str,
    first: pb::ControlInput,
) -> (
    tokio::sync::mpsc::Sender<pb::ControlInput>,
    tonic::Streaming<pb::ControlOutput>,
) {
    let mut own = pb::simulator_client::SimulatorClient::connect(server.url())
        .await
        .unwrap();
    let (tx, rx) = tokio::sync::mpsc::channel(4096);
    tx.send(first).await.unwrap();
    let outputs = own
        .control(authed(
            tokio_stream::wrappers::ReceiverStream::new(rx),
            token,
        ))
        .await
        .unwrap()
        .into_inner();
    (tx, outputs)
}

/// The status that ends `outputs` (within 10 s), or None when they end cleanly.
async fn end_of(outputs: &mut tonic::Streaming<pb::ControlOutput>) -> Option<tonic::Status> {
    tokio::time::timeout(std::time::Duration::from_secs(10), async {
        loop {
            match outputs.message().await {
                Ok(Some(_)) => continue,
                Ok(None) => return None,
                Err(status) => return Some(status),
            }
        }
    })
    .await
    .expect("the stream ended within 10 s")
}

/// Whether the instructor's list shows `id` running.
async fn running(
    client: &mut pb::simulator_client::SimulatorClient<tonic::transport::Channel>,
    id: &str,
) -> bool {
    listed_session(client, id).await.status == pb::SessionStatus::Running as i32
}

type SimulatorClient = pb::simulator_client::SimulatorClient<tonic::transport::Channel>;

async fn account(client: &mut SimulatorClient, name: &str) -> pb::Account {
    client
        .create_account(authed(
            pb::CreateAccountRequest {
                name: name.into(),
                role: "trainee".into(),
            },
            INSTRUCTOR_KEY,
        ))
        .await
        .expect("account created")
        .into_inner()
}
