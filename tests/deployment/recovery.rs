//! Kill the server (SIGKILL) during a session and start it again on the same database: every
//! acknowledged command and the metrics are there, the session shows as interrupted, and
//! replaying its commands reproduces every recorded state digest bit for bit.

use std::time::Duration;

use cathlab_api::pb;
use cathlab_tests::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_server_keeps_every_acknowledged_command_and_replays_exactly() {
    let dir = temp_dir("recovery");
    let database = dir.join("cathlab.sqlite");
    kill_and_recover(&database, &[]).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_server_on_postgres_keeps_every_acknowledged_command_and_replays_exactly() {
    let cluster = cathlab_app::store::cluster::PgCluster::start().unwrap();
    let url = cluster.database("recovery").unwrap();
    // The SQLite file is named but not used: the URL wins.
    let unused = temp_dir("recovery-postgres").join("unused.sqlite");
    kill_and_recover(&unused, &["--database-url", &url]).await;
    assert!(
        !unused.exists(),
        "the SQLite file was made beside PostgreSQL"
    );
}

/// Runs a little procedure, kills the server, starts it again on the same store (`database`,
/// or what `store` flags name) and checks the recording.
async fn kill_and_recover(database: &std::path::Path, store: &[&str]) {
    let mut server = ServerProcess::start(database, store);
    let mut client = server.client().await;
    let session = create(&mut client).await;
    let id = session.session_id.clone();

    // A little procedure: push, twist, fluoroscopy, inject, push on, C-arm.
    let script: Vec<Option<pb::Command>> = vec![
        push(25.0),
        command(pb::command::Kind::Twist(pb::Twist {
            mode: Some(pb::twist::Mode::RateDegS(90.0)),
            hold: false,
        })),
        command(pb::command::Kind::Fluoroscopy(true)),
        command(pb::command::Kind::Inject(pb::Injection {
            volume_ml: 3.0,
            rate_ml_s: 3.0,
        })),
        push(40.0),
        command(pb::command::Kind::Twist(pb::Twist {
            mode: Some(pb::twist::Mode::TargetDeg(-45.0)),
            hold: false,
        })),
        command(pb::command::Kind::Carm(pb::CArmPose {
            primary_deg: 30.0,
            secondary_deg: 10.0,
        })),
        push(-10.0),
    ];
    let mut acknowledged = Vec::new();
    for (i, c) in script.into_iter().enumerate() {
        let ack = send(&mut client, &session, i as u64 + 1, c).await.unwrap();
        acknowledged.push(ack);
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    // Let a few checkpoints (one per simulated second) pass, then kill without warning.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let live = state(&mut client, &id, &session.controller_token).await;
    assert!(live.step > 1000, "only {} steps", live.step);
    drop(client);
    server.kill();

    let server = ServerProcess::start(database, store);
    let mut client = server.client().await;
    let recorded = listed_session(&mut client, &id).await;
    assert_eq!(recorded.status, pb::SessionStatus::Interrupted as i32);
    assert_eq!(recorded.commands, acknowledged.len() as u64);
    let metrics = recorded.metrics.expect("metrics were recorded");
    assert!(metrics.procedure_time_s >= 2.0, "{metrics:?}");
    assert!(
        (metrics.contrast_volume_ml - 3.0).abs() < 1e-6,
        "{metrics:?}"
    );
    assert!(metrics.fluoroscopy_time_s > 1.0, "{metrics:?}");

    // Controllers' tokens died with the process; recorded sessions are the instructor's.
    let refused = client
        .get_session(authed(
            pb::GetSessionRequest {
                session_id: id.clone(),
            },
            &session.controller_token,
        ))
        .await
        .unwrap_err();
    assert_eq!(refused.code(), tonic::Code::PermissionDenied);

    let replay = client
        .replay_session(authed(
            pb::ReplaySessionRequest {
                session_id: id.clone(),
            },
            INSTRUCTOR_KEY,
        ))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(replay.commands as usize, acknowledged.len());
    assert!(replay.checkpoints >= 2, "{replay:?}");
    assert_eq!(replay.matched, replay.checkpoints, "{replay:?}");
    assert_eq!(replay.recorded_digest, replay.replayed_digest);
    let replayed = replay.metrics.unwrap();
    assert_eq!(replayed.steps, metrics.steps);
    assert_eq!(replayed.tip_path_length_mm, metrics.tip_path_length_mm);

    // The command-line replay agrees.
    drop(server);
    let output = std::process::Command::new(cathlab_tests::binary("cathlab-server"))
        .arg("--database")
        .arg(database)
        .args(store)
        .arg("--scenes")
        .arg(repo_root().join("scenes"))
        .args(["--renderer", "cpu", "replay", "--session", &id])
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{text} {}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(
        text.contains(&format!("{0}/{0} checkpoints match", replay.checkpoints)),
        "{text}"
    );
}

#[cfg(unix)]
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_shuts_down_gracefully_closing_sessions() {
    let dir = temp_dir("sigterm");
    let database = dir.join("cathlab.sqlite");
    let mut server = ServerProcess::start(&database, &["--renderer", "cpu"]);
    let mut client = server.client().await;
    let session = create(&mut client).await;
    for seq in 1..=3 {
        send(&mut client, &session, seq, push(10.0 * seq as f64))
            .await
            .unwrap();
    }
    drop(client);
    let pid = rustix::process::Pid::from_raw(server.child.id() as i32).unwrap();
    rustix::process::kill_process(pid, rustix::process::Signal::TERM).unwrap();
    let started = std::time::Instant::now();
    let status = loop {
        if let Some(status) = server.child.try_wait().unwrap() {
            break status;
        }
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "no exit after SIGTERM"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert!(status.success(), "{status:?}");

    let server = ServerProcess::start(&database, &["--renderer", "cpu"]);
    let mut client = server.client().await;
    let recorded = listed_session(&mut client, &session.session_id).await;
    assert_eq!(recorded.status, pb::SessionStatus::Closed as i32);
    assert_eq!(recorded.commands, 3);
}
