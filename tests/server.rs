//! The real server on 127.0.0.1 driven by a real gRPC client (and a raw HTTP/1.1 gRPC-Web
//! request): sessions, pushing, frames, roles, gRPC-Web, reflection and health, bad input,
//! the haptic control stream, metrics and events.

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use cathlab_api::pb;
use cathlab_tests::*;
use prost::Message;

fn shared() -> &'static ServerProcess {
    static SERVER: OnceLock<ServerProcess> = OnceLock::new();
    SERVER.get_or_init(|| {
        let dir = temp_dir("shared");
        ServerProcess::start(
            &dir.join("cathlab.sqlite"),
            &["--cors-origin", "http://localhost:8080"],
        )
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn push_advances_the_tip_frames_decode_and_observers_see_the_same_state() {
    let server = shared();
    let mut client = server.client().await;
    let session = create(&mut client).await;
    let id = session.session_id.clone();
    let start = state(&mut client, &id, &session.controller_token).await;
    assert!(
        (start.inserted_mm - 10.0).abs() < 1e-6,
        "{}",
        start.inserted_mm
    );

    // Push at 20 mm/s for about half a second of simulated time.
    let ack = send(&mut client, &session, 1, push(20.0)).await.unwrap();
    assert_eq!(ack.seq, 1);
    let target_step = ack.step + 250;
    let mut stream = client
        .stream_state(authed(
            pb::StreamStateRequest {
                session_id: id.clone(),
                tip_only: false,
            },
            &session.observer_token,
        ))
        .await
        .unwrap()
        .into_inner();
    let deadline = Instant::now() + Duration::from_secs(30);
    let observed = loop {
        let s = stream.message().await.unwrap().unwrap();
        if s.step >= target_step {
            break s;
        }
        assert!(Instant::now() < deadline, "the session does not step");
    };
    assert_eq!(observed.last_seq, 1);
    let pushed = observed.inserted_mm - start.inserted_mm;
    let expected = (observed.step - ack.step) as f64 / 500.0 * 20.0;
    assert!(
        (pushed - expected).abs() < 0.05,
        "pushed {pushed} mm in {} steps, expected {expected}",
        observed.step - ack.step
    );
    let tip = |s: &pb::DeviceState| {
        let p = s.tip_position_mm.unwrap();
        [p.x, p.y, p.z]
    };
    let moved = tip(&observed)
        .iter()
        .zip(tip(&start))
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(
        moved > 0.5 * pushed,
        "tip moved {moved} mm for {pushed} mm pushed"
    );
    assert_eq!(observed.nodes_mm.len() % 3, 0);

    // Stop; controller and observer then read the same state.
    send(&mut client, &session, 2, push(0.0)).await.unwrap();
    let a = state(&mut client, &id, &session.controller_token).await;
    let b = state(&mut client, &id, &session.observer_token).await;
    let c = state(&mut client, &id, INSTRUCTOR_KEY).await;
    assert!(
        (a.inserted_mm - b.inserted_mm).abs() < 1e-9
            && (a.inserted_mm - c.inserted_mm).abs() < 1e-9
    );

    // The observer and the instructor may not command.
    for token in [&session.observer_token, &INSTRUCTOR_KEY.to_owned()] {
        let refused = client
            .send_command(authed(
                pb::SendCommandRequest {
                    session_id: id.clone(),
                    seq: 3,
                    command: push(5.0),
                },
                token,
            ))
            .await
            .unwrap_err();
        assert_eq!(refused.code(), tonic::Code::PermissionDenied, "{refused:?}");
    }
    // No token, or another session's token.
    let mut anonymous = tonic::Request::new(pb::GetSessionRequest {
        session_id: id.clone(),
    });
    anonymous.metadata_mut().remove("authorization");
    assert_eq!(
        client.get_session(anonymous).await.unwrap_err().code(),
        tonic::Code::Unauthenticated
    );

    // Fluoroscopy on: PNG, JPEG and resized raw frames arrive and decode.
    send(
        &mut client,
        &session,
        3,
        command(pb::command::Kind::Fluoroscopy(true)),
    )
    .await
    .unwrap();
    for (encoding, size) in [
        (pb::FrameEncoding::Png, 0),
        (pb::FrameEncoding::Jpeg, 256),
        (pb::FrameEncoding::Raw8, 128),
        (pb::FrameEncoding::Raw16, 0),
    ] {
        let frame = first_frame(
            &mut client,
            pb::StreamFramesRequest {
                session_id: id.clone(),
                encoding: encoding as i32,
                width: size,
                height: size,
                jpeg_quality: 80,
            },
            &session.observer_token,
        )
        .await;
        let side = if size == 0 { 512 } else { size };
        assert_eq!((frame.width, frame.height), (side, side));
        let grey: Vec<u16> = match encoding {
            pb::FrameEncoding::Png | pb::FrameEncoding::Jpeg => {
                let image = image::load_from_memory(&frame.data).expect("decodes");
                assert_eq!((image.width(), image.height()), (side, side));
                image
                    .to_luma8()
                    .into_raw()
                    .into_iter()
                    .map(u16::from)
                    .collect()
            }
            pb::FrameEncoding::Raw8 => frame.data.iter().map(|&v| v as u16).collect(),
            _ => frame
                .data
                .chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]))
                .collect(),
        };
        assert_eq!(grey.len(), (side * side) as usize);
        let (lo, hi) = (grey.iter().min().unwrap(), grey.iter().max().unwrap());
        assert!(hi > lo, "{encoding:?}: a flat image");
        assert_eq!(frame.mode, pb::ImagingMode::Fluoroscopy as i32);
        // The guided scene outlines its target: the LCCA's first 50 mm, inside the image.
        let outline = &frame.target_outline;
        assert!(
            outline.len() >= 2 * 10 && outline.len() % 2 == 0,
            "{outline:?}"
        );
        assert!(
            outline.iter().all(|f| (0.0..=1.0).contains(f)),
            "{outline:?}"
        );
    }
    let info = client
        .get_session(authed(
            pb::GetSessionRequest {
                session_id: id.clone(),
            },
            &session.observer_token,
        ))
        .await
        .unwrap()
        .into_inner();
    let guidance = info.guidance.expect("guidance");
    assert!(guidance.target_marker && guidance.target_distance && guidance.prompts);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_assessment_session_runs_without_guidance() {
    let server = shared();
    let mut client = server.client().await;
    let session = client
        .create_session(pb::CreateSessionRequest {
            scene: Some(pb::create_session_request::Scene::SceneName(
                "arch_to_cow_lcca".into(),
            )),
            label: "assessment".into(),
            assessment: true,
        })
        .await
        .unwrap()
        .into_inner();
    let guidance = session.info.clone().unwrap().guidance.expect("guidance");
    assert!(!guidance.target_marker && !guidance.target_distance && !guidance.prompts);
    send(
        &mut client,
        &session,
        1,
        command(pb::command::Kind::Fluoroscopy(true)),
    )
    .await
    .unwrap();
    let frame = first_frame(
        &mut client,
        pb::StreamFramesRequest {
            session_id: session.session_id.clone(),
            encoding: pb::FrameEncoding::Raw8 as i32,
            width: 64,
            height: 64,
            jpeg_quality: 0,
        },
        &session.observer_token,
    )
    .await;
    assert!(
        frame.target_outline.is_empty(),
        "no marker in an assessment"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_web_over_http1_and_cors() {
    use http_body_util::{BodyExt, Full};
    use hyper::body::Bytes;
    let server = shared();
    let connect = || async {
        let stream = tokio::net::TcpStream::connect(&server.address)
            .await
            .unwrap();
        let (sender, connection) =
            hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(stream))
                .await
                .unwrap();
        tokio::spawn(connection);
        sender
    };
    let message = pb::ListScenesRequest {}.encode_to_vec();
    let mut body = vec![0u8];
    body.extend_from_slice(&(message.len() as u32).to_be_bytes());
    body.extend_from_slice(&message);
    let request = hyper::Request::post("/cathlab.v1.Simulator/ListScenes")
        .header("host", &server.address)
        .header("content-type", "application/grpc-web+proto")
        .header("x-grpc-web", "1")
        .header("origin", "http://localhost:8080")
        .body(Full::new(Bytes::from(body)))
        .unwrap();
    let mut sender = connect().await;
    let response = sender.send_request(request).await.unwrap();
    assert_eq!(response.version(), hyper::Version::HTTP_11);
    assert_eq!(response.status(), 200);
    assert_eq!(
        response.headers()["content-type"],
        "application/grpc-web+proto"
    );
    assert_eq!(
        response.headers()["access-control-allow-origin"],
        "http://localhost:8080"
    );
    let bytes = response.into_body().collect().await.unwrap().to_bytes();
    // A data frame (flag 0) with the message, then a trailer frame (flag 0x80).
    assert_eq!(bytes[0], 0);
    let length = u32::from_be_bytes(bytes[1..5].try_into().unwrap()) as usize;
    let reply = pb::ListScenesResponse::decode(&bytes[5..5 + length]).unwrap();
    assert!(reply.scenes.iter().any(|s| s.name == "arch_to_cow_lcca"));
    // The scene a client starts by default: the coaxial approach to the LCCA.
    assert_eq!(reply.default_scene, "arch_to_cow_lcca_coaxial");
    let trailer = &bytes[5 + length..];
    assert_eq!(trailer[0], 0x80);
    let text = String::from_utf8_lossy(&trailer[5..]);
    assert!(text.contains("grpc-status:0"), "{text}");

    // CORS preflight.
    let preflight = hyper::Request::options("/cathlab.v1.Simulator/SendCommand")
        .header("host", &server.address)
        .header("origin", "http://localhost:8080")
        .header("access-control-request-method", "POST")
        .header(
            "access-control-request-headers",
            "content-type,x-grpc-web,authorization",
        )
        .body(Full::new(Bytes::new()))
        .unwrap();
    let mut sender = connect().await;
    let response = sender.send_request(preflight).await.unwrap();
    assert!(response.status().is_success(), "{}", response.status());
    assert_eq!(
        response.headers()["access-control-allow-origin"],
        "http://localhost:8080"
    );

    // A message that does not decode is the caller's error, not the server's.
    let garbage = [0u8, 0, 0, 0, 3, 0x0a, 0xff, 0xff];
    let request = hyper::Request::post("/cathlab.v1.Simulator/GetSession")
        .header("host", &server.address)
        .header("content-type", "application/grpc-web+proto")
        .header("x-grpc-web", "1")
        .body(Full::new(Bytes::copy_from_slice(&garbage)))
        .unwrap();
    let mut sender = connect().await;
    let response = sender.send_request(request).await.unwrap();
    let status = response
        .headers()
        .get("grpc-status")
        .map(|v| v.to_str().unwrap().to_owned());
    let bytes = response.into_body().collect().await.unwrap().to_bytes();
    let text = format!("{status:?} {}", String::from_utf8_lossy(&bytes));
    assert!(
        status.as_deref() == Some("3") || text.contains("grpc-status:3"),
        "{text}"
    );

    // An origin the server was not told of gets no CORS grant (it used to be mirrored).
    let foreign = hyper::Request::options("/cathlab.v1.Simulator/SendCommand")
        .header("host", &server.address)
        .header("origin", "http://evil.example")
        .header("access-control-request-method", "POST")
        .header("access-control-request-headers", "authorization")
        .body(Full::new(Bytes::new()))
        .unwrap();
    let mut sender = connect().await;
    let response = sender.send_request(foreign).await.unwrap();
    assert!(
        !response
            .headers()
            .contains_key("access-control-allow-origin"),
        "{:?}",
        response.headers()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reflection_lists_the_services_and_health_says_serving() {
    use tonic_health::pb::health_client::HealthClient;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
    let server = shared();
    let channel = tonic::transport::Endpoint::from_shared(server.url())
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut reflection = ServerReflectionClient::new(channel.clone());
    let request = tonic_reflection::pb::v1::ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut replies = reflection
        .server_reflection_info(tokio_stream::iter([request]))
        .await
        .unwrap()
        .into_inner();
    let reply = replies.message().await.unwrap().unwrap();
    let Some(MessageResponse::ListServicesResponse(list)) = reply.message_response else {
        panic!("not a service list: {reply:?}");
    };
    let names: Vec<String> = list.service.into_iter().map(|s| s.name).collect();
    assert!(
        names.contains(&"cathlab.v1.Simulator".to_owned()),
        "{names:?}"
    );
    assert!(
        names.contains(&"grpc.health.v1.Health".to_owned()),
        "{names:?}"
    );

    let mut health = HealthClient::new(channel);
    let status = health
        .check(tonic_health::pb::HealthCheckRequest {
            service: "cathlab.v1.Simulator".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        status.status,
        tonic_health::pb::health_check_response::ServingStatus::Serving as i32
    );
}

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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_and_events_stream_and_instructors_list_sessions() {
    let server = shared();
    let mut client = server.client().await;
    let session = create(&mut client).await;
    let id = session.session_id.clone();
    let mut updates = client
        .stream_metrics(authed(
            pb::StreamMetricsRequest {
                session_id: id.clone(),
            },
            INSTRUCTOR_KEY,
        ))
        .await
        .unwrap()
        .into_inner();
    send(
        &mut client,
        &session,
        1,
        command(pb::command::Kind::Dsa(true)),
    )
    .await
    .unwrap();
    send(
        &mut client,
        &session,
        2,
        command(pb::command::Kind::Inject(pb::Injection {
            volume_ml: 2.0,
            rate_ml_s: 4.0,
        })),
    )
    .await
    .unwrap();
    // The 2 mL bolus takes half a second at 4 mL/s; then reset.
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut metrics = None;
    while !metrics
        .as_ref()
        .is_some_and(|m: &pb::Metrics| m.contrast_volume_ml >= 1.999)
    {
        assert!(Instant::now() < deadline, "the injection does not finish");
        if let pb::session_update::Kind::Metrics(m) =
            updates.message().await.unwrap().unwrap().kind.unwrap()
        {
            metrics = Some(m);
        }
    }
    send(
        &mut client,
        &session,
        3,
        command(pb::command::Kind::Reset(true)),
    )
    .await
    .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "no reset event");
        if let pb::session_update::Kind::Event(e) =
            updates.message().await.unwrap().unwrap().kind.unwrap()
            && e.kind == "reset"
        {
            break;
        }
    }
    let m = metrics.unwrap();
    assert_eq!(m.dsa_runs, 1);
    assert!(
        (m.contrast_volume_ml - 2.0).abs() < 1e-6,
        "{}",
        m.contrast_volume_ml
    );
    assert!(m.procedure_time_s > 0.4);

    // Listing needs the instructor key.
    let refused = client
        .list_sessions(authed(
            pb::ListSessionsRequest::default(),
            &session.controller_token,
        ))
        .await
        .unwrap_err();
    assert_eq!(refused.code(), tonic::Code::PermissionDenied);
    let listed = client
        .list_sessions(authed(pb::ListSessionsRequest::default(), INSTRUCTOR_KEY))
        .await
        .unwrap()
        .into_inner();
    assert!(listed.sessions.iter().any(|s| s.session_id == id));

    // Prometheus text on the same port.
    let body = reqwest_free_get(&server.address, "/metrics").await;
    assert!(
        body.contains("cathlab_physics_step_seconds_bucket"),
        "{body}"
    );
    assert!(body.contains("cathlab_sessions"), "{body}");
}

/// GET over HTTP/1.1 with hyper.
async fn reqwest_free_get(address: &str, path: &str) -> String {
    let (status, _, body) = http_get(address, path).await;
    assert_eq!(status, 200);
    body
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_diverging_session_is_reset_and_reported_while_others_go_on() {
    let server = shared();
    let mut client = server.client().await;
    let healthy = create(&mut client).await;
    // The coarse scene (100 Hz, 10/50 mm elements, loose contact, a sharply hooked wire)
    // diverges when pushed and twisted hard; the default fidelity does not.
    let coarse = std::fs::read_to_string(repo_root().join("scenes/arch_to_cow_lcca.toml"))
        .unwrap()
        .replace(
            "step_rate_hz = 500",
            "step_rate_hz = 100\ntip_element_mm = 10\nshaft_element_mm = 50\n\
             contact_tolerance = 0.5\nrefine = false",
        )
        // A 180° hook over 10 mm: one coarse element bent by 180°. (With the 90°-over-30 mm
        // wire this scene stopped diverging once elements took the exact mean of the rest
        // curvature instead of its mid-point value.)
        .replace("bend_deg = 90.0", "bend_deg = 180.0")
        .replace("bend_length_mm = 30.0", "bend_length_mm = 10.0")
        // A hand that pushes through anything (the 10 N default holds the push back
        // before the hook breaks the coarse elements).
        + "\n[limits]\npush_force_n = 10000.0\nunsupported_mm = 5.0\n";
    let fragile = client
        .create_session(authed(
            pb::CreateSessionRequest {
                scene: Some(pb::create_session_request::Scene::SceneToml(coarse)),
                label: "coarse".into(),
                ..Default::default()
            },
            INSTRUCTOR_KEY,
        ))
        .await
        .unwrap()
        .into_inner();
    let mut updates = client
        .stream_metrics(authed(
            pb::StreamMetricsRequest {
                session_id: fragile.session_id.clone(),
            },
            &fragile.observer_token,
        ))
        .await
        .unwrap()
        .into_inner();
    let before = state(&mut client, &healthy.session_id, &healthy.observer_token).await;
    // Twisting first, then pushing (the push meets its force limit soon; the twist must
    // already be turning the hook by then).
    send(
        &mut client,
        &fragile,
        1,
        command(pb::command::Kind::Twist(pb::Twist {
            mode: Some(pb::twist::Mode::RateDegS(1700.0)),
            hold: false,
        })),
    )
    .await
    .unwrap();
    send(&mut client, &fragile, 2, push(500.0)).await.unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    let event = loop {
        assert!(Instant::now() < deadline, "no divergence reported");
        if let pb::session_update::Kind::Event(e) =
            updates.message().await.unwrap().unwrap().kind.unwrap()
            && e.kind == "divergence"
        {
            break e;
        }
    };
    assert!(event.message.contains("diverged"), "{}", event.message);
    // The reset session streams finite state and keeps running.
    let after = state(&mut client, &fragile.session_id, &fragile.observer_token).await;
    assert!(after.nodes_mm.iter().all(|v| v.is_finite()));
    send(&mut client, &fragile, 3, push(0.0)).await.unwrap();
    // The other session went on stepping.
    let later = state(&mut client, &healthy.session_id, &healthy.observer_token).await;
    assert!(
        later.step > before.step + 100,
        "{} → {}",
        before.step,
        later.step
    );
    let info = client
        .get_session(authed(
            pb::GetSessionRequest {
                session_id: fragile.session_id.clone(),
            },
            INSTRUCTOR_KEY,
        ))
        .await
        .unwrap()
        .into_inner();
    assert!(info.metrics.unwrap().divergence_resets >= 1);
}

/// Waits until the session's state is past `step` and returns it.
async fn state_after(
    client: &mut cathlab_api::pb::simulator_client::SimulatorClient<tonic::transport::Channel>,
    session: &pb::CreateSessionResponse,
    step: u64,
) -> pb::DeviceState {
    let mut stream = client
        .stream_state(authed(
            pb::StreamStateRequest {
                session_id: session.session_id.clone(),
                tip_only: false,
            },
            &session.observer_token,
        ))
        .await
        .unwrap()
        .into_inner();
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let s = stream.message().await.unwrap().unwrap();
        if s.step >= step {
            return s;
        }
        assert!(Instant::now() < deadline, "the session does not step");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_hands_drive_their_own_instruments_of_a_coaxial_scene() {
    let server = shared();
    let mut client = server.client().await;
    let scenes = client
        .list_scenes(pb::ListScenesRequest {})
        .await
        .unwrap()
        .into_inner();
    let coaxial = scenes
        .scenes
        .iter()
        .find(|s| s.name == "arch_to_cow_lcca_coaxial")
        .expect("the coaxial scene is listed");
    let stack: Vec<&str> = coaxial.stack.iter().map(|i| i.device.as_str()).collect();
    assert_eq!(stack[0], "catheter-5f-vertebral");
    assert!(stack[1].starts_with("guidewire_035_shaped"), "{stack:?}");
    assert!(
        scenes
            .catalogue
            .iter()
            .any(|d| d.id == "microwire-014-angled")
    );
    let session = client
        .create_session(pb::CreateSessionRequest {
            scene: Some(pb::create_session_request::Scene::SceneName(
                "arch_to_cow_lcca_coaxial".into(),
            )),
            label: "two hands".into(),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    let on = |instrument: u32, mm_s: f64| {
        let mut c = push(mm_s).unwrap();
        c.instrument = Some(instrument);
        Some(c)
    };
    // The right hand pushes the wire 20 mm/s; the catheter stays.
    let ack = send(&mut client, &session, 1, on(1, 20.0)).await.unwrap();
    let after = state_after(&mut client, &session, ack.step + 250).await;
    assert_eq!(after.instruments.len(), 2);
    let (catheter, wire) = (&after.instruments[0], &after.instruments[1]);
    assert!(
        (catheter.inserted_mm - 10.0).abs() < 1e-6,
        "{}",
        catheter.inserted_mm
    );
    let expected = 30.0 + (after.step - ack.step) as f64 / 500.0 * 20.0;
    assert!(
        (wire.inserted_mm - expected).abs() < 0.1,
        "{} {expected}",
        wire.inserted_mm
    );
    assert!((wire.beyond_outer_mm - (wire.inserted_mm - 10.0)).abs() < 1e-9);
    assert!(!wire.nodes_mm.is_empty() && wire.nodes_mm.len() > catheter.nodes_mm.len());
    // The left hand pushes the catheter; the wire stays.
    let ack = send(&mut client, &session, 2, on(1, 0.0)).await.unwrap();
    send(&mut client, &session, 3, on(0, 20.0)).await.unwrap();
    let later = state_after(&mut client, &session, ack.step + 250).await;
    let moved = later.instruments[0].inserted_mm - catheter.inserted_mm;
    assert!(moved > 4.0, "the catheter moved {moved} mm");
    assert!(
        (later.instruments[1].inserted_mm - after.instruments[1].inserted_mm).abs() < 1.0,
        "the wire held"
    );
    // An instrument the scene does not have is refused, naming it.
    let err = send(&mut client, &session, 4, on(2, 5.0))
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::InvalidArgument);
    assert!(
        err.message().starts_with("command.instrument: 2"),
        "{}",
        err.message()
    );
    // An exchange for a device that does not fit is refused, naming both.
    let exchange = |id: &str| {
        command(pb::command::Kind::Exchange(pb::Exchange {
            instrument: 1,
            device: Some(pb::exchange::Device::CatalogueId(id.into())),
        }))
    };
    let err = send(&mut client, &session, 5, exchange("guide-6f-071-90"))
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::FailedPrecondition, "{err:?}");
    assert!(err.message().contains("does not fit"), "{}", err.message());
    // One that fits: the wire still in the vessels is drawn back through the catheter first.
    let ack = send(
        &mut client,
        &session,
        6,
        exchange("guidewire-035-angled-hydrophilic"),
    )
    .await
    .unwrap();
    let withdrawing = state_after(&mut client, &session, ack.step + 250).await;
    let drawn = later.instruments[1].inserted_mm - withdrawing.instruments[1].inserted_mm;
    // At the hand's top speed (150 mm/s).
    assert!(drawn > 60.0, "the wire was drawn back {drawn} mm in 0.5 s");
    assert!(
        withdrawing.instruments[1].catalogue_id.is_empty(),
        "not yet replaced"
    );
    close(&mut client, &session).await;
}
