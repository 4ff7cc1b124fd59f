//! Session places and the store: concurrent creates against the limit, one client trying to
//! take (and keep) every place, recorded sessions paged and pruned, a store removed under the
//! server, the smaller holes.

use super::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn concurrent_creates_never_pass_the_session_limit() {
    let _exclusive = EXCLUSIVE.lock().await;
    // One client here: its own limits (tested below) lifted.
    let (server, _dir) = server_with(
        "admission",
        "max_sessions = 16\nmax_sessions_per_client = 16\nsession_creations_per_minute = 100\n",
    );
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_client_cannot_take_every_place_nor_keep_them_with_reads() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with(
        "hoarder",
        "max_sessions = 4\nunattended_session_timeout_s = 2\nsession_creations_per_minute = 3\n",
    );
    let mut client = server.client().await;
    // An anonymous client gets half the places.
    let held = [create(&mut client).await, create(&mut client).await];
    let third = client
        .create_session(pb::CreateSessionRequest {
            scene: Some(pb::create_session_request::Scene::SceneName(
                "arch_to_cow_lcca".into(),
            )),
            ..Default::default()
        })
        .await
        .unwrap_err();
    println!(
        "the hoarder's third: {:?} {}",
        third.code(),
        third.message()
    );
    assert_eq!(third.code(), tonic::Code::ResourceExhausted);
    assert!(third.message().contains("max_sessions_per_client"));
    // A trainee (another client) still gets a place.
    let trainee = account(&mut client, "Rita").await;
    let hers = client
        .create_session(authed(
            pb::CreateSessionRequest {
                scene: Some(pb::create_session_request::Scene::SceneName(
                    "arch_to_cow_lcca".into(),
                )),
                ..Default::default()
            },
            &trainee.token,
        ))
        .await
        .expect("the trainee gets a place")
        .into_inner();
    // Cheap reads do not keep the hoarder's sessions: they close one timeout later, while
    // the trainee's, with a stream open, stays.
    let mut stream = client
        .stream_state(authed(
            pb::StreamStateRequest {
                session_id: hers.session_id.clone(),
                tip_only: true,
            },
            &hers.controller_token,
        ))
        .await
        .unwrap()
        .into_inner();
    let keep_reading = async { while stream.message().await.ok().flatten().is_some() {} };
    let poll = async {
        let started = std::time::Instant::now();
        let mut closed_at = None;
        while started.elapsed() < std::time::Duration::from_secs(12) {
            let mut open = 0;
            for s in &held {
                let info = client
                    .get_session(authed(
                        pb::GetSessionRequest {
                            session_id: s.session_id.clone(),
                        },
                        &s.controller_token,
                    ))
                    .await;
                if info.is_ok_and(|i| i.into_inner().status == pb::SessionStatus::Running as i32) {
                    open += 1;
                }
            }
            if open == 0 {
                closed_at = Some(started.elapsed());
                break;
            }
            tokio::time::sleep(std::time::Duration::from_millis(400)).await;
        }
        closed_at
    };
    let closed_at = tokio::select! {
        c = poll => c,
        _ = keep_reading => None,
    };
    println!("the hoarder's sessions, read every 400 ms, closed after {closed_at:?}");
    assert!(closed_at.is_some_and(|t| t < std::time::Duration::from_secs(8)));
    let info = client
        .get_session(authed(
            pb::GetSessionRequest {
                session_id: hers.session_id.clone(),
            },
            &hers.controller_token,
        ))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(info.status, pb::SessionStatus::Running as i32, "{info:?}");
    // Its places back, the hoarder may create again, but no faster than its rate.
    let again = create(&mut client).await;
    let fast = client
        .create_session(pb::CreateSessionRequest {
            scene: Some(pb::create_session_request::Scene::SceneName(
                "arch_to_cow_lcca".into(),
            )),
            ..Default::default()
        })
        .await
        .unwrap_err();
    println!(
        "a fourth creation in a minute: {:?} {}",
        fast.code(),
        fast.message()
    );
    assert_eq!(fast.code(), tonic::Code::ResourceExhausted);
    assert!(fast.message().contains("session_creations_per_minute"));
    close(&mut client, &again).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recorded_sessions_are_paged_and_pruned_by_the_retention_settings() {
    let _exclusive = EXCLUSIVE.lock().await;
    let dir = temp_dir("retention");
    let config = dir.join("server.toml");
    std::fs::write(
        &config,
        "session_creations_per_minute = 100\nmax_recorded_anonymous_sessions = 3\n",
    )
    .unwrap();
    let database = dir.join("db.sqlite");
    let start = || ServerProcess::start(&database, &["--config", config.to_str().unwrap()]);
    let mut server = start();
    let mut client = server.client().await;
    let trainee = account(&mut client, "Ada").await;
    let mut anonymous = Vec::new();
    for _ in 0..7 {
        let s = create(&mut client).await;
        close(&mut client, &s).await;
        anonymous.push(s.session_id);
    }
    let hers = client
        .create_session(authed(
            pb::CreateSessionRequest {
                scene: Some(pb::create_session_request::Scene::SceneName(
                    "arch_to_cow_lcca".into(),
                )),
                ..Default::default()
            },
            &trainee.token,
        ))
        .await
        .unwrap()
        .into_inner();
    close(&mut client, &hers).await;
    // Pages of two: every recorded session once, newest first.
    let mut paged = Vec::new();
    let mut page_token = String::new();
    let mut pages = 0;
    loop {
        let page = client
            .list_sessions(authed(
                pb::ListSessionsRequest {
                    include_recorded: true,
                    page_size: 2,
                    page_token,
                },
                INSTRUCTOR_KEY,
            ))
            .await
            .unwrap()
            .into_inner();
        pages += 1;
        assert!(page.sessions.len() <= 2);
        paged.extend(page.sessions.into_iter().map(|s| s.session_id));
        if page.next_page_token.is_empty() {
            break;
        }
        page_token = page.next_page_token;
    }
    println!("{} recorded sessions in {pages} pages of two", paged.len());
    assert_eq!(paged.len(), 8);
    assert_eq!(pages, 4);
    let unique: std::collections::HashSet<_> = paged.iter().collect();
    assert_eq!(unique.len(), 8);
    let bad = client
        .list_sessions(authed(
            pb::ListSessionsRequest {
                include_recorded: true,
                page_size: 2,
                page_token: "forged".into(),
            },
            INSTRUCTOR_KEY,
        ))
        .await
        .unwrap_err();
    assert_eq!(bad.code(), tonic::Code::InvalidArgument);
    assert!(bad.message().contains("page_token"));
    // Pruned at start (and each minute): the newest three anonymous sessions stay, and the
    // trainee's (her history) stays whatever its age.
    assert!(server.stop());
    let server = start();
    let mut client = server.client().await;
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    let kept: Vec<String> = list_all(&mut client)
        .await
        .into_iter()
        .map(|s| s.session_id)
        .collect();
    println!("kept after pruning: {} of 8", kept.len());
    assert_eq!(kept.len(), 4, "{kept:?}");
    assert!(kept.contains(&hers.session_id));
    for id in &anonymous[4..] {
        assert!(kept.contains(id), "a newest anonymous session went");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_store_removed_under_the_server_acknowledges_nothing_and_shows_no_path() {
    use tonic_health::pb::health_client::HealthClient;
    let _exclusive = EXCLUSIVE.lock().await;
    let dir = temp_dir("removed");
    let store_dir = dir.join("store");
    std::fs::create_dir_all(&store_dir).unwrap();
    let server = ServerProcess::start(&store_dir.join("db.sqlite"), &[]);
    let mut client = server.client().await;
    let session = create(&mut client).await;
    send(&mut client, &session, 1, push(1.0)).await.unwrap();
    std::fs::remove_dir_all(&store_dir).unwrap();
    let channel = tonic::transport::Channel::from_shared(server.url())
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut health = HealthClient::new(channel);
    let started = std::time::Instant::now();
    let mut seq = 2;
    let mut refused = None;
    while started.elapsed() < std::time::Duration::from_secs(10) {
        seq += 1;
        if let Err(e) = send(&mut client, &session, seq, push(1.0)).await {
            refused = Some(e);
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    }
    let refused = refused.expect("a command was refused once the store was gone");
    println!(
        "after {:.1} s a command got {:?}: {}",
        started.elapsed().as_secs_f64(),
        refused.code(),
        refused.message()
    );
    assert_eq!(refused.code(), tonic::Code::Unavailable);
    assert!(!refused.message().contains("/tmp"), "{}", refused.message());
    let mut status = 0;
    for _ in 0..20 {
        status = health
            .check(tonic_health::pb::HealthCheckRequest {
                service: String::new(),
            })
            .await
            .unwrap()
            .into_inner()
            .status;
        if status == tonic_health::pb::health_check_response::ServingStatus::NotServing as i32 {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(250)).await;
    }
    assert_eq!(
        status,
        tonic_health::pb::health_check_response::ServingStatus::NotServing as i32
    );
    let (code, _, body) = http_get(&server.address, "/allocate").await;
    println!("/allocate: {code} {}", body.trim());
    assert_eq!(code, 503);
    assert!(!body.contains("/tmp") && !body.contains("sqlite"), "{body}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_smaller_holes_are_closed() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("smaller", "control_inputs_per_second = 500\n");
    let mut client = server.client().await;
    let session = create(&mut client).await;
    let input = |seq: u64| pb::ControlInput {
        session_id: if seq == 1 {
            session.session_id.clone()
        } else {
            String::new()
        },
        seq,
        push_mm_s: 1.0,
        twist_deg_s: 0.0,
        hands: Vec::new(),
    };

    // A 900 KB session id is refused by its size, not echoed.
    let huge = "a".repeat(900_000);
    let refused = client
        .get_session(authed(
            pb::GetSessionRequest { session_id: huge },
            &session.controller_token,
        ))
        .await
        .unwrap_err();
    assert_eq!(refused.code(), tonic::Code::InvalidArgument);
    assert!(refused.message().len() < 100, "{}", refused.message().len());

    // Sequence numbers must increase.
    let (tx, mut outputs) = control_stream(&server, &session.controller_token, input(1)).await;
    tx.send(input(5)).await.unwrap();
    tx.send(input(3)).await.unwrap();
    let backwards = end_of(&mut outputs).await.expect("an error");
    assert_eq!(
        backwards.code(),
        tonic::Code::InvalidArgument,
        "{backwards:?}"
    );
    assert!(backwards.message().starts_with("seq: 3"), "{backwards:?}");

    // A stream whose client closed its side ends (it went on for ever).
    let (tx, mut outputs) = control_stream(&server, &session.controller_token, input(1)).await;
    tx.send(input(2)).await.unwrap();
    drop(tx);
    assert!(end_of(&mut outputs).await.is_none());

    // Inputs faster than the configured rate end the stream.
    let (tx, mut outputs) = control_stream(&server, &session.controller_token, input(1)).await;
    for seq in 2..=2000 {
        if tx.send(input(seq)).await.is_err() {
            break;
        }
    }
    let flood = end_of(&mut outputs).await.expect("an error");
    assert_eq!(flood.code(), tonic::Code::ResourceExhausted, "{flood:?}");
    println!(
        "900 KB id: {:?}; backwards seq: {:?}; flood: {:?}",
        refused.message(),
        backwards.message(),
        flood.message()
    );
    close(&mut client, &session).await;

    // A session's recording is bounded: past it, commands are refused and the session says why.
    let (bounded, _dir) = server_with("recording", "max_recorded_commands = 50\n");
    let mut client = bounded.client().await;
    let session = create(&mut client).await;
    let mut refused = None;
    for seq in 1..=60u64 {
        if let Err(status) = send(&mut client, &session, seq, push(1.0)).await {
            refused = Some((seq, status));
            break;
        }
    }
    let (seq, status) = refused.expect("the 51st command is refused");
    println!("recording bound of 50 commands: command {seq} refused: {status:?}");
    assert_eq!(seq, 51);
    assert_eq!(status.code(), tonic::Code::ResourceExhausted);
    assert!(status.message().contains("recording is full"), "{status:?}");
    close(&mut client, &session).await;
}
