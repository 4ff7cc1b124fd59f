//! What clients send: bad input answered with named errors, the haptic control stream's
//! setpoints and forces.

use super::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_gets_named_errors() {
    let server = shared();
    let mut client = server.client().await;
    let session = create(&mut client).await;
    for (bad, field) in [
        (push(f64::NAN), "command.insertion.velocity_mm_s"),
        (push(f64::INFINITY), "command.insertion.velocity_mm_s"),
        (push(1e9), "command.insertion.velocity_mm_s"),
        (
            command(pb::command::Kind::Carm(pb::CArmPose {
                primary_deg: 400.0,
                secondary_deg: 0.0,
            })),
            "command.carm.primary_deg",
        ),
        (
            command(pb::command::Kind::Inject(pb::Injection {
                volume_ml: f64::NAN,
                rate_ml_s: 3.0,
            })),
            "command.inject.volume_ml",
        ),
        (None, "command"),
        (
            command(pb::command::Kind::SelectDevice(99)),
            "select_device",
        ),
    ] {
        let error = send(&mut client, &session, 1, bad).await.unwrap_err();
        assert_eq!(error.code(), tonic::Code::InvalidArgument, "{error:?}");
        assert!(
            error.message().contains(field),
            "{field}: {}",
            error.message()
        );
    }
    // Roadmap before any DSA run.
    let error = send(
        &mut client,
        &session,
        2,
        command(pb::command::Kind::Roadmap(true)),
    )
    .await
    .unwrap_err();
    assert_eq!(error.code(), tonic::Code::FailedPrecondition, "{error:?}");

    // Unknown session.
    let error = client
        .send_command(authed(
            pb::SendCommandRequest {
                session_id: "no-such-session".into(),
                seq: 1,
                command: push(1.0),
            },
            &session.controller_token,
        ))
        .await
        .unwrap_err();
    assert_eq!(error.code(), tonic::Code::NotFound, "{error:?}");

    // Malformed scenes name the path and the reason.
    for (text, path, reason) in [
        (
            "[fidelity]\nstep_rate_hz = \"fast\"\n",
            "fidelity.step_rate_hz",
            "",
        ),
        (
            &std::fs::read_to_string(repo_root().join("scenes/arch_to_cow_lcca.toml"))
                .unwrap()
                .replace("step_rate_hz = 500", "step_rate_hz = 1e7"),
            "fidelity.step_rate_hz",
            "outside",
        ),
        (
            &std::fs::read_to_string(repo_root().join("scenes/arch_to_cow_lcca.toml"))
                .unwrap()
                .replace("bend_deg = 90.0", "bend_deg = 90.0\nstiffness = 3"),
            "devices",
            "unknown field",
        ),
    ] {
        let error = client
            .create_session(authed(
                pb::CreateSessionRequest {
                    scene: Some(pb::create_session_request::Scene::SceneToml(
                        text.to_owned(),
                    )),
                    label: String::new(),
                    ..Default::default()
                },
                INSTRUCTOR_KEY,
            ))
            .await
            .unwrap_err();
        assert_eq!(error.code(), tonic::Code::InvalidArgument, "{error:?}");
        assert!(
            error.message().contains(path) && error.message().contains(reason),
            "{path}/{reason}: {}",
            error.message()
        );
    }

    // Oversized messages are refused before they are parsed.
    let huge = "#".repeat(2 << 20);
    let error = client
        .create_session(pb::CreateSessionRequest {
            scene: Some(pb::create_session_request::Scene::SceneToml(huge)),
            label: String::new(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert!(
        matches!(
            error.code(),
            tonic::Code::OutOfRange | tonic::Code::ResourceExhausted
        ),
        "{error:?}"
    );

    // Frame requests with bad arguments.
    for (request, field) in [
        (
            pb::StreamFramesRequest {
                session_id: session.session_id.clone(),
                encoding: 99,
                ..Default::default()
            },
            "encoding",
        ),
        (
            pb::StreamFramesRequest {
                session_id: session.session_id.clone(),
                width: 5,
                height: 5,
                ..Default::default()
            },
            "width",
        ),
        (
            pb::StreamFramesRequest {
                session_id: session.session_id.clone(),
                width: 256,
                ..Default::default()
            },
            "width, height",
        ),
        (
            pb::StreamFramesRequest {
                session_id: session.session_id.clone(),
                encoding: pb::FrameEncoding::Jpeg as i32,
                jpeg_quality: 101,
                ..Default::default()
            },
            "jpeg_quality",
        ),
    ] {
        let Err(error) = client
            .stream_frames(authed(request, &session.observer_token))
            .await
        else {
            panic!("{field}: a bad frame request was accepted");
        };
        assert_eq!(error.code(), tonic::Code::InvalidArgument, "{error:?}");
        assert!(
            error.message().starts_with(field),
            "{field}: {}",
            error.message()
        );
    }

    // A control stream whose input is not finite ends with the field named.
    let (tx, rx) = tokio::sync::mpsc::channel(2);
    tx.send(pb::ControlInput {
        session_id: session.session_id.clone(),
        seq: 1,
        push_mm_s: f64::NAN,
        twist_deg_s: 0.0,
        hands: Vec::new(),
    })
    .await
    .unwrap();
    let request = authed(
        tokio_stream::wrappers::ReceiverStream::new(rx),
        &session.controller_token,
    );
    let mut outputs = client.control(request).await.unwrap().into_inner();
    let error = loop {
        match outputs.message().await {
            Ok(Some(_)) => continue,
            Ok(None) => panic!("the stream ended without an error"),
            Err(e) => break e,
        }
    };
    assert_eq!(error.code(), tonic::Code::InvalidArgument, "{error:?}");
    assert!(error.message().contains("push_mm_s"), "{}", error.message());
    drop(tx);

    // The session still runs after all that.
    send(&mut client, &session, 3, push(1.0)).await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_control_stream_applies_setpoints_and_returns_forces() {
    let server = shared();
    let mut client = server.client().await;
    let session = create(&mut client).await;
    let (tx, rx) = tokio::sync::mpsc::channel(16);
    let request = authed(
        tokio_stream::wrappers::ReceiverStream::new(rx),
        &session.controller_token,
    );
    let id = session.session_id.clone();
    let sender = tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(1));
        for seq in 1..=400u64 {
            tick.tick().await;
            let input = pb::ControlInput {
                session_id: if seq == 1 { id.clone() } else { String::new() },
                seq,
                push_mm_s: 30.0,
                twist_deg_s: 0.0,
                hands: Vec::new(),
            };
            if tx.send(input).await.is_err() {
                break;
            }
        }
        tx
    });
    let mut outputs = client.control(request).await.unwrap().into_inner();
    let mut last_seq = 0;
    let mut durable = 0;
    let mut count = 0;
    let mut inserted = 0.0;
    while last_seq < 400 {
        let out = tokio::time::timeout(Duration::from_secs(20), outputs.message())
            .await
            .expect("control output keeps coming")
            .unwrap()
            .unwrap();
        let state = out.state.unwrap();
        assert!(state.last_seq >= last_seq, "sequence numbers go back");
        // States go out as soon as they are stepped; durability is reported beside them and
        // never goes back.
        assert!(out.durable_seq >= durable, "the durable sequence goes back");
        durable = out.durable_seq;
        last_seq = state.last_seq;
        inserted = state.inserted_mm;
        assert!(state.proximal_force_n.is_some());
        count += 1;
    }
    let tx = sender.await.unwrap();
    assert!(count > 50, "only {count} outputs for 400 inputs");
    assert!(
        inserted > 15.0,
        "inserted {inserted} mm after pushing at 30 mm/s"
    );
    // The inputs end: the last output reports every input durable, then the stream ends.
    drop(tx);
    let mut last = None;
    while let Some(out) = tokio::time::timeout(Duration::from_secs(20), outputs.message())
        .await
        .expect("the stream ends")
        .unwrap()
    {
        assert!(out.durable_seq >= durable);
        durable = out.durable_seq;
        last = Some(out);
    }
    assert_eq!(last.map(|o| o.durable_seq), Some(400));
    // An observer cannot open the control stream.
    let (_tx2, rx2) = tokio::sync::mpsc::channel(1);
    _tx2.send(pb::ControlInput {
        session_id: session.session_id.clone(),
        seq: 1,
        push_mm_s: 1.0,
        twist_deg_s: 0.0,
        hands: Vec::new(),
    })
    .await
    .unwrap();
    let request = authed(
        tokio_stream::wrappers::ReceiverStream::new(rx2),
        &session.observer_token,
    );
    let refused = client.control(request).await.unwrap_err();
    assert_eq!(refused.code(), tonic::Code::PermissionDenied);
}
