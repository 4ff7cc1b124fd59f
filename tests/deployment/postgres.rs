//! The server on PostgreSQL (a real server: a throwaway local cluster from Debian's
//! packages): a wrong or unreachable database URL stops it at start with an error naming the
//! cause and never the password; an outage mid-session leaves the sessions simulating,
//! reports NOT_SERVING, and acknowledges no command it has not stored; when the database is
//! back, so is the server.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use cathlab_app::store::cluster::PgCluster;
use cathlab_tests::*;
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::health_client::HealthClient;

/// Runs the server with `url` and returns its exit status and standard error (it must not
/// start).
fn refused_start(url: &str) -> (bool, String) {
    let out = Command::new(cathlab_tests::binary("cathlab-server"))
        .args(["--listen", "127.0.0.1:0", "--database-url", url, "--scenes"])
        .arg(repo_root().join("scenes"))
        .args(["--renderer", "cpu"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_wrong_or_unreachable_postgres_url_stops_the_server_with_a_named_error() {
    let (ok, err) = refused_start("mysql://root:hunter2@db.example/cathlab");
    assert!(!ok);
    assert!(err.contains("must start with postgres://"), "{err}");
    assert!(!err.contains("hunter2"), "the password was printed: {err}");
    let (ok, err) = refused_start("postgres://cathlab:hunter2@db.example:notaport/cathlab");
    assert!(!ok);
    assert!(err.contains("does not parse"), "{err}");
    assert!(!err.contains("hunter2"), "the password was printed: {err}");
    // Nothing listens on this port.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let started = Instant::now();
    let (ok, err) = refused_start(&format!(
        "postgres://cathlab:hunter2@127.0.0.1:{port}/cathlab"
    ));
    assert!(!ok);
    assert!(
        err.contains("cannot connect") && err.contains(&format!("127.0.0.1:{port}")),
        "{err}"
    );
    assert!(!err.contains("hunter2"), "the password was printed: {err}");
    assert!(started.elapsed() < Duration::from_secs(30));
}

async fn health(address: &str) -> i32 {
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{address}"))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut client = HealthClient::new(channel);
    client
        .check(tonic_health::pb::HealthCheckRequest {
            service: String::new(),
        })
        .await
        .unwrap()
        .into_inner()
        .status
}

async fn wait_for_health(address: &str, wanted: ServingStatus) {
    let until = Instant::now() + Duration::from_secs(15);
    while health(address).await != wanted as i32 {
        assert!(Instant::now() < until, "health never became {wanted:?}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_postgres_outage_mid_session_keeps_simulating_and_acknowledges_only_what_is_stored() {
    let cluster = PgCluster::start().unwrap();
    let url = cluster.database("outage").unwrap();
    let unused = temp_dir("postgres-outage").join("unused.sqlite");
    let server = ServerProcess::start(&unused, &["--database-url", &url, "--renderer", "cpu"]);
    let mut client = server.client().await;
    let session = create(&mut client).await;
    let mut seq = 0;
    let mut acknowledged = 0;
    for _ in 0..3 {
        seq += 1;
        send(&mut client, &session, seq, push(5.0)).await.unwrap();
        acknowledged += 1;
    }
    assert_eq!(health(&server.address).await, ServingStatus::Serving as i32);
    // The store's readers have connections (each learns of a restart only when a query fails
    // on it: such a read once reached the client as INTERNAL "connection closed").
    for _ in 0..4 {
        list_all(&mut client).await;
    }

    // The database goes away (as a crash would).
    cluster.stop();
    let before = state(&mut client, &session.session_id, &session.controller_token)
        .await
        .step;
    let mut refused = 0;
    for _ in 0..5 {
        seq += 1;
        match send(&mut client, &session, seq, push(5.0)).await {
            Ok(_) => acknowledged += 1,
            Err(status) => {
                assert_eq!(status.code(), tonic::Code::Unavailable, "{status:?}");
                refused += 1;
            }
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(refused >= 4, "only {refused} of 5 commands were refused");
    wait_for_health(&server.address, ServingStatus::NotServing).await;
    let during = state(&mut client, &session.session_id, &session.controller_token)
        .await
        .step;
    assert!(
        during > before + 100,
        "the session stopped simulating: step {before} → {during}"
    );

    // The database comes back: so do acknowledgements and health.
    cluster.restart().unwrap();
    let until = Instant::now() + Duration::from_secs(20);
    loop {
        seq += 1;
        if send(&mut client, &session, seq, push(0.0)).await.is_ok() {
            acknowledged += 1;
            break;
        }
        assert!(
            Instant::now() < until,
            "no command acknowledged after the restart"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    wait_for_health(&server.address, ServingStatus::Serving).await;
    // Reads work at once, on new connections.
    for _ in 0..4 {
        list_all(&mut client).await;
    }
    // What was acknowledged is exactly what is stored.
    close(&mut client, &session).await;
    let recorded = listed_session(&mut client, &session.session_id).await;
    assert_eq!(recorded.commands, acknowledged);
}
