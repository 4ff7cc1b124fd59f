//! Accounts and reports through the real server: an instructor creates trainees; a trainee's
//! session is theirs; its report (replayed from the recording) is theirs and instructors' but
//! refused to another trainee; the history lists it with the report's scores; a corrupt
//! recording gives a report error that names what is corrupt.

use std::time::Duration;

use cathlab_api::pb;
use cathlab_api::pb::simulator_client::SimulatorClient;
use cathlab_tests::*;
use tonic::Code;
use tonic::transport::Channel;

async fn account(client: &mut SimulatorClient<Channel>, name: &str, role: &str) -> pb::Account {
    client
        .create_account(authed(
            pb::CreateAccountRequest {
                name: name.into(),
                role: role.into(),
            },
            INSTRUCTOR_KEY,
        ))
        .await
        .expect("account created")
        .into_inner()
}

async fn session_of(
    client: &mut SimulatorClient<Channel>,
    token: &str,
) -> pb::CreateSessionResponse {
    client
        .create_session(authed(
            pb::CreateSessionRequest {
                scene: Some(pb::create_session_request::Scene::SceneName(
                    "arch_to_cow_lcca".into(),
                )),
                label: "assessed".into(),
                ..Default::default()
            },
            token,
        ))
        .await
        .expect("session created")
        .into_inner()
}

async fn report(
    client: &mut SimulatorClient<Channel>,
    id: &str,
    token: &str,
) -> Result<pb::Report, tonic::Status> {
    client
        .get_report(authed(
            pb::GetReportRequest {
                session_id: id.into(),
            },
            token,
        ))
        .await
        .map(|r| r.into_inner())
}

/// A short procedure: fluoroscopy on, push 20 mm/s for about a second, stop, close.
async fn short_procedure(client: &mut SimulatorClient<Channel>, s: &pb::CreateSessionResponse) {
    send(client, s, 1, command(pb::command::Kind::Fluoroscopy(true)))
        .await
        .unwrap();
    send(client, s, 2, push(20.0)).await.unwrap();
    tokio::time::sleep(Duration::from_millis(1000)).await;
    send(client, s, 3, push(0.0)).await.unwrap();
    close(client, s).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reports_are_the_trainees_and_instructors_and_a_corrupt_recording_is_named() {
    let dir = temp_dir("assessment");
    let server = ServerProcess::start(&dir.join("cathlab.sqlite"), &[]);
    let mut client = server.client().await;
    let ada = account(&mut client, "Ada", "trainee").await;
    let ben = account(&mut client, "Ben", "trainee").await;
    let ines = account(&mut client, "Ines", "instructor").await;
    assert!(!ada.token.is_empty() && ada.role == "trainee");
    // A trainee creates no accounts; a bad role is named.
    let refused = client
        .create_account(authed(
            pb::CreateAccountRequest {
                name: "Eve".into(),
                role: "trainee".into(),
            },
            &ada.token,
        ))
        .await
        .unwrap_err();
    assert_eq!(refused.code(), Code::PermissionDenied);
    let bad = client
        .create_account(authed(
            pb::CreateAccountRequest {
                name: "Eve".into(),
                role: "admin".into(),
            },
            &ines.token,
        ))
        .await
        .unwrap_err();
    assert!(bad.message().contains("\"admin\""), "{}", bad.message());
    let me = client
        .who_am_i(authed(pb::WhoAmIRequest {}, &ada.token))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        (me.name.as_str(), me.account_id.as_str()),
        ("Ada", ada.account_id.as_str())
    );

    let session = session_of(&mut client, &ada.token).await;
    let id = session.session_id.clone();
    short_procedure(&mut client, &session).await;

    let own = report(&mut client, &id, &ada.token)
        .await
        .expect("Ada's report");
    assert_eq!(
        (own.trainee_name.as_str(), own.account_id.as_str()),
        ("Ada", ada.account_id.as_str())
    );
    let json: serde_json::Value = serde_json::from_str(&own.json).unwrap();
    let metrics = json["metrics"].as_array().unwrap();
    let value = |key: &str| {
        metrics
            .iter()
            .find(|m| m["key"] == key)
            .and_then(|m| m["value"].as_f64())
            .unwrap()
    };
    assert!(
        value("fluoroscopy_time_s") > 0.5,
        "{}",
        value("fluoroscopy_time_s")
    );
    assert!(value("air_kerma_mgy") > 0.0);
    assert!(value("tip_path_m") > 0.01);
    let frames = json["frames"].as_array().unwrap().len();
    assert!(frames >= 2, "{frames} frames");
    let frame = client
        .get_report_frame(authed(
            pb::GetReportFrameRequest {
                session_id: id.clone(),
                index: 1,
            },
            &ada.token,
        ))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(&frame.png[1..4], b"PNG");

    // Another trainee is refused; an instructor's account and the key are not; no token is
    // unauthenticated.
    let denied = report(&mut client, &id, &ben.token).await.unwrap_err();
    assert_eq!(denied.code(), Code::PermissionDenied);
    assert!(
        denied.message().contains("instructor role"),
        "{}",
        denied.message()
    );
    assert_eq!(
        report(&mut client, &id, &ines.token).await.unwrap().json,
        own.json
    );
    assert!(report(&mut client, &id, INSTRUCTOR_KEY).await.is_ok());
    let anonymous = client
        .get_report(pb::GetReportRequest {
            session_id: id.clone(),
        })
        .await
        .unwrap_err();
    assert_eq!(anonymous.code(), Code::Unauthenticated);

    // The history lists the session with the report's scores; Ben may not read it.
    let history = client
        .get_history(authed(pb::GetHistoryRequest::default(), &ada.token))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(history.entries.len(), 1);
    let entry = &history.entries[0];
    assert!(entry.assessed && entry.session_id == id);
    assert_eq!(
        entry.metrics["fluoroscopy_time_s"],
        value("fluoroscopy_time_s")
    );
    let other = client
        .get_history(authed(
            pb::GetHistoryRequest {
                account_id: ada.account_id.clone(),
            },
            &ben.token,
        ))
        .await
        .unwrap_err();
    assert_eq!(other.code(), Code::PermissionDenied);

    // An anonymous session's controller token reads its own report after the close.
    let anonymous = create(&mut client).await;
    short_procedure(&mut client, &anonymous).await;
    assert!(
        report(
            &mut client,
            &anonymous.session_id,
            &anonymous.controller_token
        )
        .await
        .is_ok()
    );

    // A corrupt recording: the report names the corrupt command instead of showing nothing.
    let broken = session_of(&mut client, &ada.token).await;
    short_procedure(&mut client, &broken).await;
    // The report the close makes in the background is awaited and dropped, and a command
    // row is spoiled.
    for _ in 0..600 {
        let history = client
            .get_history(authed(pb::GetHistoryRequest::default(), &ada.token))
            .await
            .unwrap()
            .into_inner();
        if history
            .entries
            .iter()
            .any(|e| e.session_id == broken.session_id && e.assessed)
        {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let conn = rusqlite::Connection::open(&server.database).unwrap();
    conn.busy_timeout(Duration::from_secs(5)).unwrap();
    conn.execute(
        "UPDATE commands SET command = '{\"warp\": 9}' WHERE session_id = ?1 AND ordinal = 1",
        [&broken.session_id],
    )
    .unwrap();
    conn.execute(
        "DELETE FROM reports WHERE session_id = ?1",
        [&broken.session_id],
    )
    .unwrap();
    let e = report(&mut client, &broken.session_id, &ada.token)
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::DataLoss, "{e:?}");
    assert!(
        e.message().contains("corrupt command 1 of session"),
        "{}",
        e.message()
    );
}
