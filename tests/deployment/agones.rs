//! The Agones SDK contract, against a stand-in of the sidecar that records the calls (not
//! Agones itself: no GameServer states, no Kubernetes; see docs/deploy.md for a real
//! cluster). A server started with `--agones` and a scene to warm: the `sessions` counter
//! (0 of its capacity) and Ready only once the scene is warm, then the GameServer's address
//! (which `/allocate` sends new trainees to); health pings while its physics
//! keeps time; a session makes it Allocated with the counter at 1; the session's end puts it
//! back to Ready at 0; a clean exit with a session running ends with Shutdown after the
//! session was closed.
//! Without a sidecar, `--agones` stops the server at start, naming where it looked.

use std::time::{Duration, Instant};

use cathlab_agones::standin::{Call, StandIn};
use cathlab_tests::*;

async fn wait_for(standin: &StandIn, what: &str, seconds: u64, done: impl Fn(&[Call]) -> bool) {
    let deadline = Instant::now() + Duration::from_secs(seconds);
    loop {
        let calls = standin.calls();
        if done(&calls) {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "{what} within {seconds} s: {calls:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

fn unary(calls: &[Call]) -> Vec<Call> {
    calls
        .iter()
        .filter(|c| **c != Call::Health)
        .cloned()
        .collect()
}

fn counter(n: i64) -> Call {
    Call::UpdateCounter("sessions".into(), Some(n), Some(3))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_server_follows_the_agones_lifecycle_against_a_recording_stand_in() {
    let standin = StandIn::start().await.unwrap();
    let port = standin.port().to_string();
    let dir = temp_dir("agones");
    let mut server = ServerProcess::start_with_env(
        &dir.join("cathlab.sqlite"),
        &[
            "--agones",
            "--warm",
            "arch_to_cow_lcca_coaxial",
            "--max-sessions",
            "3",
            "--max-sessions-per-client",
            "3",
            "--renderer",
            "cpu",
        ],
        &[("AGONES_SDK_GRPC_PORT", &port)],
    );
    // Agones has placed the GameServer: the fleet's registry gets its address.
    standin.set_address("gs-1.example.org", 7777);
    wait_for(&standin, "Ready", 60, |c| c.contains(&Call::GetGameServer)).await;
    assert_eq!(
        unary(&standin.calls()),
        [counter(0), Call::Ready, Call::GetGameServer]
    );
    // A new trainee is sent there (the query kept) by the allocation endpoint.
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let (status, headers, body) = http_get(&server.address, "/allocate?scene=x").await;
        let location = headers
            .get("location")
            .map(|l| l.to_str().unwrap().to_owned());
        if location.as_deref() == Some("http://gs-1.example.org:7777/?scene=x") {
            assert_eq!(status, 303, "{body}");
            break;
        }
        assert!(Instant::now() < deadline, "{status} {location:?} {body}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    wait_for(&standin, "a health ping", 10, |c| c.contains(&Call::Health)).await;

    let mut client = server.client().await;
    let session = create(&mut client).await;
    wait_for(&standin, "Allocated", 10, |c| c.contains(&Call::Allocate)).await;
    close(&mut client, &session).await;
    wait_for(&standin, "Ready again", 10, |c| {
        c.iter().filter(|c| **c == Call::Ready).count() == 2
    })
    .await;
    let pings_before = standin
        .calls()
        .iter()
        .filter(|c| **c == Call::Health)
        .count();
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert!(
        standin
            .calls()
            .iter()
            .filter(|c| **c == Call::Health)
            .count()
            > pings_before,
        "health pings go on while idle"
    );

    // A second trainee; the server is stopped while the session runs: it closes and stores
    // the session, then Shutdown (not Ready on the way out).
    let _running = create(&mut client).await;
    wait_for(&standin, "Allocated again", 10, |c| {
        c.iter().filter(|c| **c == Call::Allocate).count() == 2
    })
    .await;
    assert!(server.stop(), "the server exits on a clean stop");
    assert_eq!(
        unary(&standin.calls()),
        [
            counter(0),
            Call::Ready,
            Call::GetGameServer,
            counter(1),
            Call::Allocate,
            counter(0),
            Call::Ready,
            counter(1),
            Call::Allocate,
            Call::Shutdown
        ]
    );
}

#[test]
fn without_a_sidecar_agones_mode_stops_the_server_naming_where_it_looked() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
        .to_string();
    let dir = temp_dir("agones-none");
    let output = std::process::Command::new(cathlab_tests::binary("cathlab-server"))
        .args(["--listen", "127.0.0.1:0", "--agones", "--database"])
        .arg(dir.join("cathlab.sqlite"))
        .args(["--agones-connect-timeout", "2"])
        .arg("--scenes")
        .arg(repo_root().join("scenes"))
        .env("AGONES_SDK_GRPC_PORT", &port)
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains(&format!("127.0.0.1:{port}")) && stderr.contains("did not answer"),
        "{stderr}"
    );
    let output = std::process::Command::new(cathlab_tests::binary("cathlab-server"))
        .args(["--listen", "127.0.0.1:0", "--agones", "--database"])
        .arg(dir.join("cathlab.sqlite"))
        .env("AGONES_SDK_GRPC_PORT", "ninety")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains("AGONES_SDK_GRPC_PORT is \"ninety\""),
        "{stderr}"
    );
}
