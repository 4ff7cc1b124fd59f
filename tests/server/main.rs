//! The real server on 127.0.0.1 driven by a real gRPC client (and a raw HTTP/1.1 gRPC-Web
//! request): sessions, pushing, frames, roles, gRPC-Web, reflection and health, bad input,
//! the haptic control stream, metrics and events.

mod input;
mod sessions;
mod transport;

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use cathlab_api::pb;
use cathlab_tests::*;
use prost::Message;

fn shared() -> &'static ServerProcess {
    static SERVER: OnceLock<ServerProcess> = OnceLock::new();
    SERVER.get_or_init(|| {
        let dir = temp_dir("shared");
        ServerProcess::start(
            &dir.join("cathlab.sqlite"),
            &["--cors-origin", "http://localhost:8080"],
        )
    })
}

/// GET over HTTP/1.1 with hyper.
async fn reqwest_free_get(address: &str, path: &str) -> String {
    let (status, _, body) = http_get(address, path).await;
    assert_eq!(status, 200);
    body
}

/// Waits until the session's state is past `step` and returns it.
async fn state_after(
    client: &mut cathlab_api::pb::simulator_client::SimulatorClient<tonic::transport::Channel>,
    session: &pb::CreateSessionResponse,
    step: u64,
) -> pb::DeviceState {
    let mut stream = client
        .stream_state(authed(
            pb::StreamStateRequest {
                session_id: session.session_id.clone(),
                tip_only: false,
            },
            &session.observer_token,
        ))
        .await
        .unwrap()
        .into_inner();
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let s = stream.message().await.unwrap().unwrap();
        if s.step >= step {
            return s;
        }
        assert!(Instant::now() < deadline, "the session does not step");
    }
}
