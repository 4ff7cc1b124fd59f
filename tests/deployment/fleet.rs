//! A fleet on this machine: three server processes sharing one PostgreSQL (a throwaway local
//! cluster). Sessions spread over the servers (the allocation endpoint sends each new trainee
//! to the server with the most room, and says so when none has); any server's instructor list shows every
//! running session with the address of the server that runs it; a server killed without
//! warning loses no acknowledged command, its sessions are marked lost by the others, and
//! they replay bit for bit from the shared store.

use std::time::{Duration, Instant};

use cathlab_api::pb;
use cathlab_app::store::cluster::PgCluster;
use cathlab_tests::*;

async fn listed(server: &ServerProcess) -> Vec<pb::SessionInfo> {
    list_all(&mut server.client().await).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_servers_on_one_postgres_share_sessions_and_survive_one_being_killed() {
    let cluster = PgCluster::start().unwrap();
    let url = cluster.database("fleet").unwrap();
    let unused = temp_dir("fleet").join("unused.sqlite");
    let mut servers: Vec<ServerProcess> = (0..3)
        .map(|i| {
            ServerProcess::start(
                &unused,
                &[
                    "--database-url",
                    &url,
                    "--server-id",
                    &format!("s{i}"),
                    "--renderer",
                    "cpu",
                    "--max-sessions",
                    "2",
                    // Every trainee here is one address (127.0.0.1).
                    "--max-sessions-per-client",
                    "2",
                ],
            )
        })
        .collect();

    // Six trainees in turn, each sent by server 0's allocation endpoint to the server with
    // the most room: two sessions on each (capacity 2), a few acknowledged commands each.
    let mut sessions = Vec::new();
    for _ in 0..6 {
        let (status, headers, body) = http_get(&servers[0].address, "/allocate").await;
        assert_eq!(status, 303, "{body}");
        let location = headers["location"].to_str().unwrap().trim_end_matches('/');
        let i = servers
            .iter()
            .position(|s| s.url() == location)
            .unwrap_or_else(|| panic!("{location} is no server of the fleet"));
        let mut client = servers[i].client().await;
        let session = create(&mut client).await;
        // Server 1's sessions (killed, then replayed) keep pushing, so that their replay
        // checks a device on the move; the others' last command stops the push: four devices
        // pushed into the wall for the rest of the test would load the fleet's two cores for
        // nothing.
        for seq in 1..=3 {
            let speed = if seq < 3 || i == 1 {
                10.0 * seq as f64
            } else {
                0.0
            };
            send(&mut client, &session, seq, push(speed)).await.unwrap();
        }
        sessions.push((i, session));
        // The server beats at once when its load changes.
        tokio::time::sleep(Duration::from_millis(400)).await;
    }
    for i in 0..3 {
        assert_eq!(
            sessions.iter().filter(|(j, _)| *j == i).count(),
            2,
            "server {i}'s share: {:?}",
            sessions.iter().map(|(j, _)| j).collect::<Vec<_>>()
        );
    }
    // The fleet is full: the next trainee is told to wait.
    let (status, headers, _) = http_get(&servers[2].address, "/allocate").await;
    assert_eq!(status, 503);
    assert_eq!(headers["retry-after"], "30");

    // Every server lists all six running, each with where it runs.
    for (i, server) in servers.iter().enumerate() {
        let listed = listed(server).await;
        for (j, session) in &sessions {
            let info = listed
                .iter()
                .find(|s| s.session_id == session.session_id)
                .unwrap_or_else(|| panic!("server {i} does not list a session of server {j}"));
            assert_eq!(info.status, pb::SessionStatus::Running as i32);
            let expected = if *j == i {
                String::new()
            } else {
                servers[*j].url()
            };
            assert_eq!(info.server_address, expected, "server {i}, session of {j}");
        }
    }

    // Server 1 dies; its sessions' acknowledged commands are in the store.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    servers[1].kill();
    let lost: Vec<&pb::CreateSessionResponse> = sessions
        .iter()
        .filter(|(i, _)| *i == 1)
        .map(|(_, s)| s)
        .collect();
    let until = Instant::now() + Duration::from_secs(30);
    loop {
        let listed = listed(&servers[0]).await;
        let statuses: Vec<i32> = lost
            .iter()
            .map(|s| {
                listed
                    .iter()
                    .find(|l| l.session_id == s.session_id)
                    .map_or(-1, |l| l.status)
            })
            .collect();
        if statuses
            .iter()
            .all(|s| *s == pb::SessionStatus::Lost as i32)
        {
            for s in &lost {
                let info = listed
                    .iter()
                    .find(|l| l.session_id == s.session_id)
                    .unwrap();
                assert_eq!(info.commands, 3, "acknowledged commands lost");
            }
            break;
        }
        assert!(
            Instant::now() < until,
            "server 1's sessions were never marked lost: {statuses:?}"
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    // The others' sessions run on.
    let listed0 = listed(&servers[0]).await;
    for (i, s) in sessions.iter().filter(|(i, _)| *i != 1) {
        let info = listed0
            .iter()
            .find(|l| l.session_id == s.session_id)
            .unwrap();
        assert_eq!(info.status, pb::SessionStatus::Running as i32, "server {i}");
    }
    // A lost session replays bit for bit on another server.
    let mut client = servers[2].client().await;
    for s in &lost {
        let replay = client
            .replay_session(authed(
                pb::ReplaySessionRequest {
                    session_id: s.session_id.clone(),
                },
                INSTRUCTOR_KEY,
            ))
            .await
            .unwrap()
            .into_inner();
        assert_eq!(replay.commands, 3);
        assert!(replay.checkpoints >= 1, "{replay:?}");
        assert_eq!(replay.matched, replay.checkpoints, "{replay:?}");
    }
}
