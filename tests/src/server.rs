//! Starting the real `cathlab-server` binary on 127.0.0.1 and talking to it with the
//! generated gRPC client.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use crate::repo_root;

use cathlab_api::pb;
use cathlab_api::pb::simulator_client::SimulatorClient;
use tonic::transport::Channel;

/// The instructor key the test servers run with.
pub const INSTRUCTOR_KEY: &str = "test-instructor-key";

/// A server process; killed (SIGKILL) when dropped unless shut down first.
pub struct ServerProcess {
    /// The process.
    pub child: Child,
    /// The address it printed (host:port).
    pub address: String,
    /// Its database file.
    pub database: PathBuf,
}

impl ServerProcess {
    /// Starts a server on a free port with `database`, with extra flags.
    pub fn start(database: &Path, extra: &[&str]) -> Self {
        Self::start_with_env(database, extra, &[])
    }

    /// [`ServerProcess::start`] with extra environment variables.
    pub fn start_with_env(database: &Path, extra: &[&str], env: &[(&str, &str)]) -> Self {
        let mut child = Command::new(crate::binary("cathlab-server"))
            .args(["--listen", "127.0.0.1:0", "--database"])
            .arg(database)
            .arg("--scenes")
            .arg(repo_root().join("scenes"))
            .arg("--exit-on-stdin-eof")
            .args(extra)
            .env("CATHLAB_INSTRUCTOR_KEY", INSTRUCTOR_KEY)
            .env("RUST_LOG", "warn")
            .env("CATHLAB_ASSET_DISK_CACHE", crate::asset_disk_cache())
            .envs(env.iter().copied())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("cathlab-server starts");
        let stdout = child.stdout.take().unwrap();
        let mut lines = BufReader::new(stdout).lines();
        let address = loop {
            let line = lines
                .next()
                .expect("the server prints its address")
                .unwrap();
            if let Some(a) = line.strip_prefix("cathlab-server listening on ") {
                break a.trim().to_owned();
            }
        };
        // Keep draining stdout so the server never blocks on it.
        std::thread::spawn(move || for _ in lines {});
        Self {
            child,
            address,
            database: database.to_owned(),
        }
    }

    /// `http://ADDR`.
    pub fn url(&self) -> String {
        format!("http://{}", self.address)
    }

    /// A gRPC client connected to it (retried while it starts).
    pub async fn client(&self) -> SimulatorClient<Channel> {
        for _ in 0..50 {
            if let Ok(c) = SimulatorClient::connect(self.url()).await {
                return c.max_decoding_message_size(64 << 20);
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        panic!("cannot connect to {}", self.url());
    }

    /// A clean stop (stdin closed: the server closes its sessions and exits); false if it
    /// had not exited within 30 s (then it is killed).
    pub fn stop(&mut self) -> bool {
        drop(self.child.stdin.take());
        let deadline = std::time::Instant::now() + Duration::from_secs(30);
        while std::time::Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return true;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        self.kill();
        false
    }

    /// SIGKILL, no chance to clean up.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for ServerProcess {
    fn drop(&mut self) {
        self.kill();
    }
}

pub use cathlab_api::authorized as authed;

/// Creates a session on the default scene.
pub async fn create(client: &mut SimulatorClient<Channel>) -> pb::CreateSessionResponse {
    client
        .create_session(pb::CreateSessionRequest {
            scene: Some(pb::create_session_request::Scene::SceneName(
                "arch_to_cow_lcca".into(),
            )),
            label: "test".into(),
            ..Default::default()
        })
        .await
        .expect("session created")
        .into_inner()
}

/// A command of `kind` for the first instrument.
pub fn command(kind: pb::command::Kind) -> Option<pb::Command> {
    Some(pb::Command {
        kind: Some(kind),
        instrument: None,
    })
}

/// A velocity insertion command (mm/s; negative pulls).
pub fn push(mm_s: f64) -> Option<pb::Command> {
    command(pb::command::Kind::Insertion(pb::Insertion {
        mode: Some(pb::insertion::Mode::VelocityMmS(mm_s)),
        hold: false,
    }))
}

/// Sends `command` with sequence number `seq` to `session`.
pub async fn send(
    client: &mut SimulatorClient<Channel>,
    session: &pb::CreateSessionResponse,
    seq: u64,
    command: Option<pb::Command>,
) -> Result<pb::CommandAck, tonic::Status> {
    client
        .send_command(authed(
            pb::SendCommandRequest {
                session_id: session.session_id.clone(),
                seq,
                command,
            },
            &session.controller_token,
        ))
        .await
        .map(|r| r.into_inner())
}

/// The newest state of a session as `token` sees it.
pub async fn state(
    client: &mut SimulatorClient<Channel>,
    session_id: &str,
    token: &str,
) -> pb::DeviceState {
    let mut stream = client
        .stream_state(authed(
            pb::StreamStateRequest {
                session_id: session_id.into(),
                tip_only: false,
            },
            token,
        ))
        .await
        .unwrap()
        .into_inner();
    stream.message().await.unwrap().expect("a state")
}

/// The instructor's list: every session, live and recorded (and, in a fleet, the other
/// servers' running ones).
pub async fn list_all(client: &mut SimulatorClient<Channel>) -> Vec<pb::SessionInfo> {
    let mut all = Vec::new();
    let mut page_token = String::new();
    loop {
        let page = client
            .list_sessions(authed(
                pb::ListSessionsRequest {
                    include_recorded: true,
                    page_token,
                    ..Default::default()
                },
                INSTRUCTOR_KEY,
            ))
            .await
            .unwrap()
            .into_inner();
        all.extend(page.sessions);
        if page.next_page_token.is_empty() {
            return all;
        }
        page_token = page.next_page_token;
    }
}

/// A session as the instructor's list (live and recorded) shows it.
pub async fn listed_session(
    client: &mut SimulatorClient<Channel>,
    session_id: &str,
) -> pb::SessionInfo {
    list_all(client)
        .await
        .into_iter()
        .find(|s| s.session_id == session_id)
        .expect("the session is listed")
}

/// The first frame of a session's stream as `token` asks for it (within a minute).
pub async fn first_frame(
    client: &mut SimulatorClient<Channel>,
    request: pb::StreamFramesRequest,
    token: &str,
) -> pb::XrayFrame {
    let mut frames = client
        .stream_frames(authed(request, token))
        .await
        .unwrap()
        .into_inner();
    tokio::time::timeout(std::time::Duration::from_secs(60), frames.message())
        .await
        .expect("a frame within a minute")
        .unwrap()
        .expect("a frame")
}

/// Closes a session with its controller token.
pub async fn close(client: &mut SimulatorClient<Channel>, session: &pb::CreateSessionResponse) {
    client
        .close_session(authed(
            pb::CloseSessionRequest {
                session_id: session.session_id.clone(),
            },
            &session.controller_token,
        ))
        .await
        .expect("the session closes");
}

/// `GET path` over plain HTTP/1.1 from the server at `address` (`host:port`): the status, the
/// headers and the body.
pub async fn http_get(address: &str, path: &str) -> (u16, hyper::HeaderMap, String) {
    use http_body_util::{BodyExt, Empty};
    use hyper::body::Bytes;
    let stream = tokio::net::TcpStream::connect(address).await.unwrap();
    let (mut sender, connection) =
        hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(stream))
            .await
            .unwrap();
    tokio::spawn(connection);
    let request = hyper::Request::get(path)
        .header("host", address)
        .body(Empty::<Bytes>::new())
        .unwrap();
    let response = sender.send_request(request).await.unwrap();
    let status = response.status().as_u16();
    let headers = response.headers().clone();
    let bytes = response.into_body().collect().await.unwrap().to_bytes();
    (
        status,
        headers,
        String::from_utf8_lossy(&bytes).into_owned(),
    )
}
