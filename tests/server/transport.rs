//! The server's other doors: gRPC-Web over HTTP/1.1 with CORS, reflection and health,
//! metrics and the event stream, the instructors' session list.

use super::*;

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
