//! The server attacked from outside, as a hostile or careless client would: each test starts
//! the real `cathlab-server` with a configuration file and goes at one of its limits.

mod connections;
mod files;

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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failing_inline_scenes_need_the_key_and_leave_no_memory_behind() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("memory", "asset_cache_mib = 512\n");
    let mut client = server.client().await;
    // Without the instructor key an inline scene is refused before anything is read.
    let anonymous = client
        .create_session(inline(default_scene_text()))
        .await
        .unwrap_err();
    assert_eq!(
        anonymous.code(),
        tonic::Code::PermissionDenied,
        "{anonymous:?}"
    );
    assert!(anonymous.message().contains("instructor key"));
    // A listed scene warms the cache; then 6 inline scenes that fail only after their CT is
    // built (each with another spacing, so each builds a new one of about 16 MiB; the
    // isocenter branch is unknown): kept, they would pass the 50 MiB allowance.
    let warm = create(&mut client).await;
    close(&mut client, &warm).await;
    let pid = server.child.id();
    let start = rss_bytes(pid);
    for i in 0..6 {
        let text = default_scene_text()
            .replace(
                "spacing_mm = 2.0",
                &format!("spacing_mm = {}", 2.0 + 0.01 * f64::from(i + 1)),
            )
            .replace("isocenter_branch = \"LCCA\"", "isocenter_branch = \"nope\"");
        let error = client
            .create_session(authed(inline(text), INSTRUCTOR_KEY))
            .await
            .unwrap_err();
        assert_eq!(error.code(), tonic::Code::InvalidArgument, "{error:?}");
        assert!(
            error.message().contains("carm.isocenter_branch"),
            "{error:?}"
        );
    }
    let end = rss_bytes(pid);
    println!(
        "6 failing inline scenes: RSS {:.1} → {:.1} MiB",
        start as f64 / 1048576.0,
        end as f64 / 1048576.0
    );
    assert!(
        end < start + (50 << 20),
        "RSS grew {} MiB",
        (end - start) >> 20
    );
    // A phantom too fine for the asset budget (about 1 GiB at 0.5 mm, against 512 MiB) is
    // refused before loading.
    let fine = default_scene_text().replace("spacing_mm = 2.0", "spacing_mm = 0.5");
    let error = client
        .create_session(authed(inline(fine), INSTRUCTOR_KEY))
        .await
        .unwrap_err();
    println!("0.5 mm phantom: {:?} {}", error.code(), error.message());
    assert_eq!(error.code(), tonic::Code::ResourceExhausted);
    assert!(error.message().contains("budget"), "{error:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scenes_cannot_name_files_outside_the_data_roots_nor_echo_them() {
    let _exclusive = EXCLUSIVE.lock().await;
    // A data root of our own beside the bundled data, with a MetaImage header whose data file
    // points out of it.
    let outside = temp_dir("outside");
    std::fs::write(outside.join("secret.raw"), "top secret contents\n").unwrap();
    let root = temp_dir("root");
    std::fs::write(
        root.join("evil.mhd"),
        format!(
            "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\nElementDataFile = {}\n",
            outside.join("secret.raw").display()
        ),
    )
    .unwrap();
    std::fs::write(root.join("notes.mha"), "the first line of a text file\n").unwrap();
    std::os::unix::fs::symlink(outside.join("secret.raw"), root.join("link.mha")).unwrap();
    let config = format!(
        "data_roots = [{:?}, {:?}, {:?}]\n",
        repo_root().join("scenes").display().to_string(),
        repo_root().join("data").display().to_string(),
        root.display().to_string()
    );
    let (server, _dir) = server_with("paths", &config);
    let mut client = server.client().await;
    let ct_file = |path: &str| {
        default_scene_text().replace(
            "[ct]\nkind = \"phantom\"\nspacing_mm = 2.0",
            &format!("[ct]\nkind = \"file\"\npath = {path:?}"),
        )
    };
    assert_ne!(ct_file("x"), default_scene_text());
    let hostile = [
        ct_file("/etc/hostname"),
        ct_file("../../../../../../etc/passwd"),
        ct_file("../../x.mha"),
        ct_file(&root.join("evil.mhd").display().to_string()),
        ct_file(&root.join("notes.mha").display().to_string()),
        ct_file(&outside.join("secret.raw").display().to_string()),
        default_scene_text().replace("dir = \"../data/anatomy/arch-to-cow\"", "dir = \"/etc\""),
        ct_file(&root.join("link.mha").display().to_string()),
    ];
    for (i, text) in hostile.into_iter().enumerate() {
        let error = client
            .create_session(authed(inline(text), INSTRUCTOR_KEY))
            .await
            .unwrap_err();
        let message = error.message();
        println!("hostile scene {i}: {:?} {message}", error.code());
        assert_eq!(error.code(), tonic::Code::InvalidArgument, "{i}: {error:?}");
        assert!(
            message.contains("ct.path") || message.contains("anatomy.dir"),
            "{i}: names the field: {message}"
        );
        if [0, 1, 2, 5, 6, 7].contains(&i) {
            // Missing and outside read alike: no oracle for files outside the roots.
            assert!(message.contains("names no file in the server's data directories"));
        }
        for leak in [
            "/etc",
            "/tmp",
            "secret",
            "first line",
            "hostname",
            "passwd",
            repo_root().canonicalize().unwrap().to_str().unwrap(),
        ] {
            assert!(!message.contains(leak), "{i}: {message:?} shows {leak:?}");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn guessing_the_instructor_key_is_throttled() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("guessing", "auth_failures_per_minute = 10\n");
    let mut client = server.client().await;
    let started = std::time::Instant::now();
    let (mut evaluated, mut refused) = (0, 0);
    for i in 0..200 {
        let error = client
            .list_sessions(authed(
                pb::ListSessionsRequest {
                    include_recorded: false,
                    ..Default::default()
                },
                &format!("guess-{i:04}"),
            ))
            .await
            .unwrap_err();
        match error.code() {
            tonic::Code::PermissionDenied => evaluated += 1,
            tonic::Code::ResourceExhausted => refused += 1,
            other => panic!("{other:?}: {error:?}"),
        }
    }
    let seconds = started.elapsed().as_secs_f64();
    println!(
        "200 wrong keys in {seconds:.2} s: {evaluated} evaluated, {refused} refused before the check"
    );
    assert_eq!(evaluated, 10);
    assert_eq!(refused, 190);
    // Once refused, the address is refused whatever it sends, the right key included (or the
    // guessing would go on between right and wrong).
    let right = client
        .list_sessions(authed(
            pb::ListSessionsRequest {
                include_recorded: false,
                ..Default::default()
            },
            INSTRUCTOR_KEY,
        ))
        .await
        .unwrap_err();
    assert_eq!(right.code(), tonic::Code::ResourceExhausted);
    assert!(right.message().contains("retry in"), "{right:?}");
}

#[test]
fn a_weak_instructor_key_is_refused_beyond_loopback() {
    let dir = temp_dir("exposed");
    for (listen, key, starts) in [
        ("0.0.0.0:0", "instructor", false),
        ("0.0.0.0:0", "short", false),
        ("127.0.0.1:0", "instructor", true),
    ] {
        let mut child = std::process::Command::new(cathlab_tests::binary("cathlab-server"))
            .args(["--listen", listen, "--database"])
            .arg(dir.join(format!("{key}.sqlite")))
            .arg("--scenes")
            .arg(repo_root().join("scenes"))
            .arg("--exit-on-stdin-eof")
            .env("CATHLAB_INSTRUCTOR_KEY", key)
            .env("RUST_LOG", "warn")
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        if starts {
            use std::io::BufRead;
            let mut line = String::new();
            std::io::BufReader::new(child.stdout.take().unwrap())
                .read_line(&mut line)
                .unwrap();
            assert!(line.contains("listening"), "{line}");
            drop(child.stdin.take());
            child.wait().unwrap();
        } else {
            let out = child.wait_with_output().unwrap();
            let stderr = String::from_utf8_lossy(&out.stderr);
            println!("{listen} with {key:?}: {}", stderr.trim());
            assert!(!out.status.success());
            assert!(
                stderr.contains("weak instructor key") && stderr.contains("CATHLAB_INSTRUCTOR_KEY")
            );
        }
    }
}

#[test]
fn a_catalog_scene_naming_a_missing_file_stops_the_server_at_start() {
    let dir = temp_dir("catalog");
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let scene = default_scene_text().replace(
        "dir = \"../data/anatomy/arch-to-cow\"",
        "dir = \"anatomy/moved-away\"",
    );
    assert!(scene.contains("moved-away"));
    std::fs::write(scenes.join("moved.toml"), scene).unwrap();
    let out = std::process::Command::new(cathlab_tests::binary("cathlab-server"))
        .args(["--listen", "127.0.0.1:0", "--database"])
        .arg(dir.join("db.sqlite"))
        .arg("--scenes")
        .arg(&scenes)
        .arg("--exit-on-stdin-eof")
        .env("CATHLAB_INSTRUCTOR_KEY", INSTRUCTOR_KEY)
        .env("RUST_LOG", "warn")
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{}", stderr.trim());
    assert!(!out.status.success());
    assert!(
        stderr.contains("moved.toml") && stderr.contains("anatomy.dir"),
        "{stderr}"
    );
}

/// Drives a session through a control stream at 50 mm/s for 1 s from its own connection, then
/// goes quiet (`hang_up` false: the stream stays open) or drops the connection (true). Returns
/// how long (simulated s) the device kept advancing after the last input.
async fn coast_after_the_last_input(server: &ServerProcess, hang_up: bool) -> f64 {
    let mut client = server.client().await;
    let session = create(&mut client).await;
    let url = server.url();
    let (id, token) = (session.session_id.clone(), session.controller_token.clone());
    let (quiet_tx, quiet_rx) = tokio::sync::oneshot::channel::<()>();
    let driver = tokio::spawn(async move {
        let mut own = pb::simulator_client::SimulatorClient::connect(url)
            .await
            .unwrap();
        let (tx, rx) = tokio::sync::mpsc::channel(16);
        // The server answers the call once the first input is in: send it before waiting.
        tx.send(pb::ControlInput {
            session_id: id.clone(),
            seq: 1,
            push_mm_s: 50.0,
            twist_deg_s: 0.0,
            hands: Vec::new(),
        })
        .await
        .unwrap();
        let mut outputs = own
            .control(authed(
                tokio_stream::wrappers::ReceiverStream::new(rx),
                &token,
            ))
            .await
            .unwrap()
            .into_inner();
        tokio::spawn(async move { while let Ok(Some(_)) = outputs.message().await {} });
        let mut tick = tokio::time::interval(std::time::Duration::from_millis(10));
        for seq in 2..=100u64 {
            tick.tick().await;
            tx.send(pb::ControlInput {
                session_id: String::new(),
                seq,
                push_mm_s: 50.0,
                twist_deg_s: 0.0,
                hands: Vec::new(),
            })
            .await
            .unwrap();
        }
        let _ = quiet_tx.send(());
        // Quiet with the stream open, or gone with the connection.
        if !hang_up {
            tokio::time::sleep(std::time::Duration::from_secs(3)).await;
        }
        drop((tx, own));
    });
    quiet_rx.await.unwrap();
    let coast = moving_after_now(&mut client, &session).await;
    driver.abort();
    close(&mut client, &session).await;
    coast
}

/// How long (simulated s) the session's device goes on advancing from now, watched for 1.5 s.
async fn moving_after_now(
    client: &mut pb::simulator_client::SimulatorClient<tonic::transport::Channel>,
    session: &pb::CreateSessionResponse,
) -> f64 {
    // Subscribed now: the first state is the one at the last input.
    let mut states = client
        .stream_state(authed(
            pb::StreamStateRequest {
                session_id: session.session_id.clone(),
                tip_only: true,
            },
            &session.observer_token,
        ))
        .await
        .unwrap()
        .into_inner();
    let last_input = states.message().await.unwrap().unwrap();
    let (mut moving_until, mut previous) = (last_input.time_s, last_input.inserted_mm);
    loop {
        let s = states.message().await.unwrap().unwrap();
        if s.inserted_mm > previous + 1e-3 {
            moving_until = s.time_s;
        }
        previous = s.inserted_mm;
        if s.time_s > last_input.time_s + 1.5 {
            break;
        }
    }
    moving_until - last_input.time_s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_control_stream_that_goes_quiet_or_away_leaves_the_device_still() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("deadman", "control_timeout_ms = 250\n");
    let quiet = coast_after_the_last_input(&server, false).await;
    let gone = coast_after_the_last_input(&server, true).await;
    println!(
        "after the last input at 50 mm/s the device went on {:.0} ms (stream quiet, 250 ms timeout), {:.0} ms (connection dropped)",
        quiet * 1e3,
        gone * 1e3
    );
    assert!(quiet > 0.15 && quiet < 0.25 + 0.1, "{quiet}");
    assert!(gone < 0.25 + 0.1, "{gone}");
}

/// Drives a session with unary push commands at 50 mm/s every 50 ms for 1 s (`hold`: in hold
/// mode), then stops sending; returns how long (simulated s) the device went on.
async fn coast_after_unary_pushes(server: &ServerProcess, hold: bool) -> f64 {
    let mut client = server.client().await;
    let session = create(&mut client).await;
    let held_push = |hold| {
        command(pb::command::Kind::Insertion(pb::Insertion {
            mode: Some(pb::insertion::Mode::VelocityMmS(50.0)),
            hold,
        }))
    };
    let mut tick = tokio::time::interval(std::time::Duration::from_millis(50));
    for seq in 1..=20u64 {
        tick.tick().await;
        send(&mut client, &session, seq, held_push(hold))
            .await
            .unwrap();
    }
    let coast = moving_after_now(&mut client, &session).await;
    close(&mut client, &session).await;
    coast
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn held_unary_speeds_lapse_when_no_longer_repeated() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("hold", "control_timeout_ms = 250\n");
    let held = coast_after_unary_pushes(&server, true).await;
    let unheld = coast_after_unary_pushes(&server, false).await;
    println!(
        "after the last unary push at 50 mm/s the device went on {:.0} ms (hold mode, 250 ms timeout), {:.0} ms of a 1.5 s watch (no hold)",
        held * 1e3,
        unheld * 1e3
    );
    // The held speed lapsed one timeout after the last repeat; without hold it went on.
    assert!(held > 0.15 && held < 0.25 + 0.1, "{held}");
    assert!(unheld > 1.4, "{unheld}");
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
    tokio::time::sleep(std::time::Duration::from_secs(2)).await;
    let held_after = server_metric(&server, "cathlab_stream_buffer_bytes").await;
    let after = rss_bytes(pid);
    let missed = missed_steps(&mut client, &bystander).await - missed_before;
    // A fresh reader is served again.
    let frame = first_frame(&mut client, request, &watched.observer_token).await;
    println!(
        "24 stalled raw16 2048x2048 frame streams, budget 128 MiB (32 MiB per address): RSS +{:.0} MiB at peak, budget held at peak {:.0} MiB; after the 4 s stall timeout {cut} connections cut ({ended} streams ended); with the clients gone {:.0} MiB held, RSS +{:.0} MiB; the other session missed {missed} steps",
        (peak as f64 - base as f64) / 1048576.0,
        held_peak / 1048576.0,
        held_after / 1048576.0,
        (after as f64 - base as f64) / 1048576.0,
    );
    assert!(held_peak <= 32.0 * 1048576.0, "{held_peak}");
    // What the streams hold is their address's share (a quarter of the budget); RSS adds
    // the encoders' and the transport's working buffers (+34-48 MiB in warm runs, +85 MiB
    // once from a fresh clone), and stays under the configured 128 MiB.
    assert!(peak < base + (128 << 20), "{peak} vs {base}");
    assert!(cut >= 1.0 && ended >= 6, "{cut} {ended}");
    assert_eq!(held_after, 0.0);
    assert!(after < base + (16 << 20), "{after} vs {base}");
    // 0 when run alone; once in a full run of this binary a single catch-up drop (25-50
    // steps of the ~7,000 in the window) was seen: at most one is allowed.
    assert!(missed <= 50, "{missed}");
    assert_eq!(frame.width, 2048);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_speed_push_meets_the_device_limits_in_real_time() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("overload", "");
    let mut client = server.client().await;
    let session = create(&mut client).await;
    let mut events = client
        .stream_metrics(authed(
            pb::StreamMetricsRequest {
                session_id: session.session_id.clone(),
            },
            &session.observer_token,
        ))
        .await
        .unwrap()
        .into_inner();
    let mut states = client
        .stream_state(authed(
            pb::StreamStateRequest {
                session_id: session.session_id.clone(),
                tip_only: true,
            },
            &session.observer_token,
        ))
        .await
        .unwrap()
        .into_inner();
    let missed_before = missed_steps(&mut client, &session).await;
    send(&mut client, &session, 1, push(500.0)).await.unwrap();
    let start = states.message().await.unwrap().unwrap();
    let (mut max_force, mut last) = (0.0f64, start.clone());
    let (mut held, mut lowest_fidelity) = (0, 0);
    while last.time_s < start.time_s + 20.0 {
        last = states.message().await.unwrap().unwrap();
        max_force = max_force.max(last.axial_force_n);
        held += usize::from(last.push_limit != pb::PushLimit::None as i32);
        lowest_fidelity = lowest_fidelity.max(last.fidelity_level);
    }
    let info = client
        .get_session(authed(
            pb::GetSessionRequest {
                session_id: session.session_id.clone(),
            },
            &session.controller_token,
        ))
        .await
        .unwrap()
        .into_inner();
    let timing = info.timing.unwrap();
    let missed = timing.missed_steps - missed_before;
    let mut said = Vec::new();
    while let Ok(Ok(Some(u))) =
        tokio::time::timeout(std::time::Duration::from_millis(200), events.message()).await
    {
        if let Some(pb::session_update::Kind::Event(e)) = u.kind {
            said.push(format!("{} {}", e.kind, e.message));
        }
    }
    println!(
        "500 mm/s push for 20 s: inserted {:.0} -> {:.0} mm, largest axial force {max_force:.1} N (limit {:.0} N, held in {held} states), fidelity down to level {lowest_fidelity}, missed {missed} steps, step p50 {:.2} p99 {:.2} max {:.1} ms; events: {said:?}",
        start.inserted_mm,
        last.inserted_mm,
        last.push_force_limit_n,
        timing.step_time_p50_ms,
        timing.step_time_p99_ms,
        timing.step_time_max_ms
    );
    // The rate held: no step was missed.
    assert_eq!(missed, 0);
    // The push met the hand's 10 N and was held there (within a step's rise), and said so.
    assert_eq!(last.push_force_limit_n, 10.0);
    assert!(
        held > 0 && max_force < 2.0 * last.push_force_limit_n,
        "{max_force}"
    );
    assert!(
        said.iter().any(|e| e.starts_with("limit push held")),
        "{said:?}"
    );
    // What kept the rate was reported, not hidden.
    if lowest_fidelity > 0 {
        assert!(said.iter().any(|e| e.starts_with("overload")), "{said:?}");
    }
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_whose_controller_went_away_are_closed() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("unattended", "unattended_session_timeout_s = 2\n");
    let mut client = server.client().await;
    // Nobody ever comes; the controller holds a state stream open; only an observer watches;
    // the controller sends a command every 400 ms (and nothing else).
    let nobody = create(&mut client).await;
    let streaming = create(&mut client).await;
    let observed = create(&mut client).await;
    let commanding = create(&mut client).await;
    let open = |session: &pb::CreateSessionResponse, token: &str| {
        let (mut client, id, token) =
            (client.clone(), session.session_id.clone(), token.to_owned());
        async move {
            client
                .stream_state(authed(
                    pb::StreamStateRequest {
                        session_id: id,
                        tip_only: true,
                    },
                    &token,
                ))
                .await
                .unwrap()
                .into_inner()
        }
    };
    let held = open(&streaming, &streaming.controller_token).await;
    let watching = open(&observed, &observed.observer_token).await;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let sender = {
        let (mut client, session, stop) = (client.clone(), commanding.clone(), stop.clone());
        tokio::spawn(async move {
            let mut seq = 0;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                seq += 1;
                send(&mut client, &session, seq, push(0.0)).await.unwrap();
                tokio::time::sleep(std::time::Duration::from_millis(400)).await;
            }
        })
    };
    let seconds = std::time::Duration::from_secs;
    tokio::time::sleep(seconds(1)).await;
    for s in [&nobody, &streaming, &observed, &commanding] {
        assert!(
            running(&mut client, &s.session_id).await,
            "closed before the timeout"
        );
    }
    tokio::time::sleep(seconds(3)).await;
    let after = [
        running(&mut client, &nobody.session_id).await,
        running(&mut client, &streaming.session_id).await,
        running(&mut client, &observed.session_id).await,
        running(&mut client, &commanding.session_id).await,
    ];
    println!(
        "after 4 s, running: nobody {}, controller's stream {}, observer only {}, commands {}",
        after[0], after[1], after[2], after[3]
    );
    assert_eq!(after, [false, true, false, true]);
    // The closed session's controller is told so; a new session can take its place.
    let gone = send(&mut client, &nobody, 1, push(1.0)).await.unwrap_err();
    assert_eq!(gone.code(), tonic::Code::NotFound, "{gone:?}");
    // The stream ends and the commands stop: both close one timeout later.
    drop((held, watching));
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    sender.await.unwrap();
    tokio::time::sleep(seconds(1)).await;
    assert!(
        running(&mut client, &streaming.session_id).await,
        "closed at once when its stream ended"
    );
    tokio::time::sleep(seconds(3)).await;
    assert!(
        !running(&mut client, &streaming.session_id).await,
        "the controller's stream ended 4 s ago"
    );
    assert!(
        !running(&mut client, &commanding.session_id).await,
        "the last command came 4 s ago"
    );
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

#[test]
fn check_scenes_prints_a_line_per_scene_and_fails_if_one_fails() {
    let dir = temp_dir("check-scenes");
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let data = repo_root().join("data").canonicalize().unwrap();
    let good = default_scene_text().replace(
        "dir = \"../data/anatomy/arch-to-cow\"",
        &format!(
            "dir = {:?}",
            data.join("anatomy/arch-to-cow").display().to_string()
        ),
    );
    std::fs::write(scenes.join("good.toml"), &good).unwrap();
    let config = dir.join("config.toml");
    std::fs::write(
        &config,
        format!(
            "data_roots = [{:?}, {:?}]\n",
            data.display().to_string(),
            scenes.display().to_string()
        ),
    )
    .unwrap();
    let run = || {
        std::process::Command::new(cathlab_tests::binary("cathlab-server"))
            .arg("--config")
            .arg(&config)
            .arg("--check-scenes")
            .arg(&scenes)
            .env("RUST_LOG", "warn")
            .output()
            .unwrap()
    };
    let out = run();
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{}", stdout.trim());
    assert!(out.status.success(), "{stdout}");
    assert!(stdout.starts_with("ok   good"), "{stdout}");
    // A second scene with a reach beyond its target branch: named, and the exit fails.
    std::fs::write(
        scenes.join("too_far.toml"),
        good.replace("reach_mm = 50.0", "reach_mm = 400.0"),
    )
    .unwrap();
    let out = run();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{}\n{}", stdout.trim(), stderr.trim());
    assert!(!out.status.success());
    assert!(stdout.contains("ok   good"), "{stdout}");
    assert!(
        stdout.contains("FAIL")
            && stdout.contains("too_far.toml")
            && stdout.contains("target.reach_mm"),
        "{stdout}"
    );
    assert!(stderr.contains("1 of 2 scenes failed"), "{stderr}");
}

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

type SimulatorClient = pb::simulator_client::SimulatorClient<tonic::transport::Channel>;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_victims_stop_goes_through_while_an_attacker_at_its_address_is_throttled() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("victim", "auth_failures_per_minute = 5\n");
    let mut client = server.client().await;
    let victim = create(&mut client).await;
    send(&mut client, &victim, 1, push(5.0)).await.unwrap();
    // The attacker, at the same address: wrong tokens for GetHistory count as guesses too.
    let mut answers = Vec::new();
    for i in 0..7 {
        let e = client
            .get_history(authed(
                pb::GetHistoryRequest::default(),
                &format!("not-a-token-{i}"),
            ))
            .await
            .unwrap_err();
        answers.push(e.code());
    }
    println!("7 wrong GetHistory tokens: {answers:?}");
    assert_eq!(
        answers,
        [
            [tonic::Code::Unauthenticated; 5].as_slice(),
            [tonic::Code::ResourceExhausted; 2].as_slice()
        ]
        .concat()
    );
    // The address is throttled: a wrong session token is refused before it is compared…
    let guess = client
        .get_session(authed(
            pb::GetSessionRequest {
                session_id: victim.session_id.clone(),
            },
            "guess",
        ))
        .await
        .unwrap_err();
    assert_eq!(guess.code(), tonic::Code::ResourceExhausted, "{guess:?}");
    // …and the victim's stop and close, with its own token, go through.
    let stop = send(&mut client, &victim, 2, push(0.0)).await;
    assert!(stop.is_ok(), "the victim's stop was refused: {stop:?}");
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    let a = state(&mut client, &victim.session_id, &victim.controller_token).await;
    tokio::time::sleep(std::time::Duration::from_millis(1000)).await;
    let b = state(&mut client, &victim.session_id, &victim.controller_token).await;
    println!(
        "inserted after the stop: {:.2} mm, a second later {:.2} mm",
        a.inserted_mm, b.inserted_mm
    );
    assert!((b.inserted_mm - a.inserted_mm).abs() < 0.5);
    close(&mut client, &victim).await;
    // GetHistory names the field it refuses.
    let named = client
        .get_history(authed(
            pb::GetHistoryRequest {
                account_id: "../x".into(),
            },
            INSTRUCTOR_KEY,
        ))
        .await;
    // The instructor key is throttled with the address (a human-chosen secret).
    assert_eq!(named.unwrap_err().code(), tonic::Code::ResourceExhausted);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn history_errors_name_account_id() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("history", "");
    let mut client = server.client().await;
    let e = client
        .get_history(authed(
            pb::GetHistoryRequest {
                account_id: "../x".into(),
            },
            INSTRUCTOR_KEY,
        ))
        .await
        .unwrap_err();
    println!("{:?}: {}", e.code(), e.message());
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(e.message().starts_with("account_id"), "{}", e.message());
    assert!(!e.message().contains("session_id"), "{}", e.message());
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
