//! Replays and frame streams: replays queued for the trainee first and below live physics,
//! stalled frame streams cut within their budget, a token holder replaying to keep a trainee
//! from her report.

use super::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn replays_are_for_the_trainee_one_at_a_time_and_below_live_physics() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("replays", "max_replays = 1\n");
    let mut client = server.client().await;
    let recorded = create(&mut client).await;
    let bystander = create(&mut client).await;
    send(&mut client, &recorded, 1, push(40.0)).await.unwrap();
    send(&mut client, &bystander, 1, push(20.0)).await.unwrap();
    tokio::time::sleep(std::time::Duration::from_secs(8)).await;
    let replayer = client.clone();
    let replay = |token: String| {
        let mut client = replayer.clone();
        let id = recorded.session_id.clone();
        async move {
            client
                .replay_session(authed(pb::ReplaySessionRequest { session_id: id }, &token))
                .await
                .map(|r| r.into_inner())
        }
    };

    let watching = replay(recorded.observer_token.clone()).await.unwrap_err();
    assert_eq!(
        watching.code(),
        tonic::Code::PermissionDenied,
        "{watching:?}"
    );

    // Four at once with a limit of one (the default): one runs (niced), three are told to
    // wait, and the live session beside it keeps its rate. (With a limit of four, niced
    // replays cost it 0-26 missed steps here, replays at normal priority 274.)
    let missed_before = missed_steps(&mut client, &bystander).await;
    let started = std::time::Instant::now();
    let calls: Vec<_> = (0..4)
        .map(|_| tokio::spawn(replay(recorded.controller_token.clone())))
        .collect();
    let mut answers = Vec::new();
    for call in calls {
        answers.push(call.await.unwrap());
    }
    let took = started.elapsed();
    let missed = missed_steps(&mut client, &bystander).await - missed_before;
    let ran: Vec<_> = answers.iter().filter_map(|a| a.as_ref().ok()).collect();
    let refused = answers
        .iter()
        .filter(|a| matches!(a, Err(s) if s.code() == tonic::Code::ResourceExhausted))
        .count();
    println!(
        "4 concurrent replays, limit 1: {} ran ({} steps, {}/{} checkpoints match) in {:.1} s, {refused} refused; the other session missed {missed} steps meanwhile",
        ran.len(),
        ran[0].steps,
        ran[0].matched,
        ran[0].checkpoints,
        took.as_secs_f64()
    );
    assert_eq!((ran.len(), refused), (1, 3), "{answers:?}");
    assert!(ran[0].checkpoints >= 5 && ran[0].matched == ran[0].checkpoints);
    assert_eq!(missed, 0);

    // A caller that goes away abandons its replay and gives its place back.
    let abandoned = tokio::time::timeout(
        std::time::Duration::from_millis(100),
        replay(recorded.controller_token.clone()),
    )
    .await;
    assert!(
        abandoned.is_err(),
        "the replay outlived 100 ms: {abandoned:?}"
    );
    tokio::time::sleep(std::time::Duration::from_millis(300)).await;
    replay(INSTRUCTOR_KEY.to_owned())
        .await
        .expect("the abandoned replay gave its place back");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn stalled_frame_streams_stay_within_their_budget_and_are_cut() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with(
        "stalled",
        "stream_buffer_mib = 128\nstream_stall_timeout_ms = 4000\n",
    );
    let pid = server.child.id();
    let mut client = server.client().await;
    let bystander = create(&mut client).await;
    let watched = create(&mut client).await;
    send(&mut client, &bystander, 1, push(20.0)).await.unwrap();
    let pedal = command(pb::command::Kind::Fluoroscopy(true));
    send(&mut client, &watched, 1, pedal).await.unwrap();
    let request = pb::StreamFramesRequest {
        session_id: watched.session_id.clone(),
        encoding: pb::FrameEncoding::Raw16 as i32,
        width: 2048,
        height: 2048,
        ..Default::default()
    };
    // One frame read, so the renderer and encoders have warmed up.
    first_frame(&mut client, request.clone(), &watched.observer_token).await;
    tokio::time::sleep(std::time::Duration::from_secs(1)).await;
    let base = rss_bytes(pid);
    let heap_base = server_metric(&server, "cathlab_heap_bytes").await;
    let missed_before = missed_steps(&mut client, &bystander).await;

    // 24 readers that never read, six to a connection.
    let mut connections = Vec::new();
    let mut stalled = Vec::new();
    for _ in 0..4 {
        let mut own = pb::simulator_client::SimulatorClient::connect(server.url())
            .await
            .unwrap()
            .max_decoding_message_size(64 << 20);
        for _ in 0..6 {
            stalled.push(
                own.stream_frames(authed(request.clone(), &watched.observer_token))
                    .await
                    .unwrap()
                    .into_inner(),
            );
        }
        connections.push(own);
    }
    let mut peak = 0;
    let mut held_peak = 0.0f64;
    for _ in 0..6 {
        tokio::time::sleep(std::time::Duration::from_millis(500)).await;
        peak = peak.max(rss_bytes(pid));
        held_peak = held_peak.max(server_metric(&server, "cathlab_stream_buffer_bytes").await);
    }
    // Past the stall timeout the connections of the streams holding frames are cut (the
    // others held nothing: their frames were withheld).
    tokio::time::sleep(std::time::Duration::from_secs(4)).await;
    let cut = server_metric(&server, "cathlab_stalled_streams_cut").await;
    let mut ended = 0;
    for s in &mut stalled {
        let end = tokio::time::timeout(std::time::Duration::from_millis(100), s.message()).await;
        ended += usize::from(matches!(end, Ok(Err(_)) | Ok(Ok(None))));
    }
    drop((stalled, connections));
    // The server learns that a connection went when its connection task next runs, and h2
    // frees the frames queued on it then: on a loaded machine that takes a few seconds, so
    // the live heap is watched for up to 10 s to come back.
    let gone = std::time::Instant::now();
    let mut heap_after;
    loop {
        tokio::time::sleep(std::time::Duration::from_millis(250)).await;
        heap_after = server_metric(&server, "cathlab_heap_bytes").await;
        if heap_after < heap_base + 8.0 * 1048576.0 || gone.elapsed().as_secs() >= 10 {
            break;
        }
    }
    let settled_s = gone.elapsed().as_secs_f64();
    let held_after = server_metric(&server, "cathlab_stream_buffer_bytes").await;
    let after = rss_bytes(pid);
    let missed = missed_steps(&mut client, &bystander).await - missed_before;
    // A fresh reader is served again.
    let frame = first_frame(&mut client, request, &watched.observer_token).await;
    println!(
        "24 stalled raw16 2048x2048 frame streams, budget 128 MiB (32 MiB per address): RSS +{:.0} MiB at peak, budget held at peak {:.0} MiB; after the 4 s stall timeout {cut} connections cut ({ended} streams ended); with the clients gone {:.0} MiB held, live heap {:+.1} MiB after {settled_s:.2} s, RSS {:+.0} MiB; the other session missed {missed} steps",
        (peak as f64 - base as f64) / 1048576.0,
        held_peak / 1048576.0,
        held_after / 1048576.0,
        (heap_after - heap_base) / 1048576.0,
        (after as f64 - base as f64) / 1048576.0,
    );
    assert!(held_peak <= 32.0 * 1048576.0, "{held_peak}");
    // What the streams hold is their address's share (a quarter of the budget); RSS adds
    // the encoders' and the transport's working buffers (+34-48 MiB in warm runs, +85 MiB
    // once from a fresh clone), and stays under the configured 128 MiB.
    assert!(peak < base + (128 << 20), "{peak} vs {base}");
    assert!(cut >= 1.0 && ended >= 6, "{cut} {ended}");
    assert_eq!(held_after, 0.0);
    // Nothing the streams held is still live: the live heap (the server's counting
    // allocator) is back within one 8 MiB frame of where it was (once in CI +13.9 MiB at a
    // fixed 2 s after the clients went: the frames h2 still queued on connections it had not
    // yet seen close).
    assert!(
        heap_after < heap_base + 8.0 * 1048576.0,
        "{heap_after} vs {heap_base}"
    );
    // What the allocator keeps resident of the freed buffers is its own business: +10-16 MiB
    // alone, +26 MiB in a fresh-clone run, +44 MiB once in CI with the compute lane beside
    // it (mimalloc purges a thread's freed pages only when that thread allocates again).
    // Bounded here by half the configured 128 MiB budget.
    assert!(after < base + (64 << 20), "{after} vs {base}");
    // 0 when run alone; once in a full run of this binary a single catch-up drop (25-50
    // steps of the ~7,000 in the window) was seen: at most one is allowed.
    assert!(missed <= 50, "{missed}");
    assert_eq!(frame.width, 2048);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replaying_token_holder_cannot_keep_a_trainee_from_her_report() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("replay-queue", "max_replays = 1\n");
    let mut client = server.client().await;
    let trainee = account(&mut client, "Rita").await;
    let scene = || {
        Some(pb::create_session_request::Scene::SceneName(
            "arch_to_cow_lcca".into(),
        ))
    };
    let hers = client
        .create_session(authed(
            pb::CreateSessionRequest {
                scene: scene(),
                ..Default::default()
            },
            &trainee.token,
        ))
        .await
        .unwrap()
        .into_inner();
    let mallorys = create(&mut client).await;
    send(&mut client, &hers, 1, push(20.0)).await.unwrap();
    send(&mut client, &mallorys, 1, push(20.0)).await.unwrap();
    tokio::time::sleep(std::time::Duration::from_secs(6)).await;
    // Mallory replays her own session back to back, and tries to queue more at once.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let replays = std::sync::Arc::new(std::sync::atomic::AtomicU32::new(0));
    let hog = {
        let (c, stop, replays) = (client.clone(), stop.clone(), replays.clone());
        let (id, token) = (
            mallorys.session_id.clone(),
            mallorys.controller_token.clone(),
        );
        tokio::spawn(async move {
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                let calls: Vec<_> = (0..3)
                    .map(|_| {
                        let mut c = c.clone();
                        let (id, token) = (id.clone(), token.clone());
                        tokio::spawn(async move {
                            c.replay_session(authed(
                                pb::ReplaySessionRequest { session_id: id },
                                &token,
                            ))
                            .await
                        })
                    })
                    .collect();
                let mut ran = 0;
                for call in calls {
                    if call.await.is_ok_and(|a| a.is_ok()) {
                        ran += 1;
                    }
                }
                replays.fetch_add(ran, std::sync::atomic::Ordering::Relaxed);
                assert!(ran <= 1, "one replay per caller at a time");
                if ran == 0 {
                    tokio::time::sleep(std::time::Duration::from_millis(50)).await;
                }
            }
        })
    };
    tokio::time::sleep(std::time::Duration::from_millis(300)).await;
    // Rita finishes: her report is made at close and she reads it, waiting her turn.
    close(&mut client, &hers).await;
    let started = std::time::Instant::now();
    let report = client
        .get_report(authed(
            pb::GetReportRequest {
                session_id: hers.session_id.clone(),
            },
            &trainee.token,
        ))
        .await;
    let took = started.elapsed();
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = hog.await;
    println!(
        "the trainee's report beside a replaying token holder: {} in {:.1} s (Mallory's replays meanwhile: {})",
        if report.is_ok() { "made" } else { "refused" },
        took.as_secs_f64(),
        replays.load(std::sync::atomic::Ordering::Relaxed)
    );
    let report = report.expect("the trainee's report is made, not refused");
    assert_eq!(report.into_inner().session_id, hers.session_id);
}
