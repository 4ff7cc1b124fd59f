//! The server attacked from outside, as a hostile or careless client would: each test starts
//! the real `cathlab-server` with a configuration file and goes at one of its limits.

mod common;

use std::path::PathBuf;

use cathlab_api::pb;
use common::*;

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

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn concurrent_creates_never_pass_the_session_limit() {
    let (server, _dir) = server_with("admission", "max_sessions = 16\n");
    // Load the scene once, so that the 30 creates race on admission, not on loading.
    let mut client = server.client().await;
    let first = create(&mut client).await;
    close(&mut client, &first).await;
    let attempts: Vec<_> = (0..30)
        .map(|_| {
            let url = server.url();
            tokio::spawn(async move {
                let mut c = pb::simulator_client::SimulatorClient::connect(url)
                    .await
                    .unwrap();
                c.create_session(pb::CreateSessionRequest {
                    scene: Some(pb::create_session_request::Scene::SceneName(
                        "arch_to_cow_lcca".into(),
                    )),
                    label: "race".into(),
                    ..Default::default()
                })
                .await
            })
        })
        .collect();
    let mut created = Vec::new();
    let mut refused = Vec::new();
    for a in attempts {
        match a.await.unwrap() {
            Ok(r) => created.push(r.into_inner()),
            Err(status) => refused.push(status),
        }
    }
    println!(
        "30 concurrent creates with a limit of 16: {} created, {} refused ({:?})",
        created.len(),
        refused.len(),
        refused.first().map(|s| (s.code(), s.message().to_owned()))
    );
    assert_eq!(created.len(), 16);
    assert!(
        refused
            .iter()
            .all(|s| s.code() == tonic::Code::ResourceExhausted && s.message().contains("16"))
    );
    // A place frees when a session closes.
    close(&mut client, &created[0]).await;
    let again = create(&mut client).await;
    assert!(!again.session_id.is_empty());
}
