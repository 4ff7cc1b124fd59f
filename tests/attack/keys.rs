//! Keys and throttles: guessing the instructor key, a weak key beyond loopback, a victim's
//! stop while an attacker at the same address is throttled, `GetHistory`'s errors.

use super::*;

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
