//! Sessions end to end: a push advancing the tip with frames that decode and observers that
//! see the same state, an assessment session, a diverging session reset while others go on,
//! two hands on a coaxial stack.

use super::*;

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
async fn a_diverging_session_is_reset_and_reported_while_others_go_on() {
    let server = shared();
    let mut client = server.client().await;
    let healthy = create(&mut client).await;
    // The coarse scene (100 Hz, 2/50 mm elements, loose contact, a sharply hooked wire)
    // diverges when pushed and twisted hard; the default fidelity does not.
    let coarse = std::fs::read_to_string(repo_root().join("scenes/arch_to_cow_lcca.toml"))
        .unwrap()
        .replace(
            "step_rate_hz = 500",
            "step_rate_hz = 100\ntip_element_mm = 2\nshaft_element_mm = 50\n\
             contact_tolerance = 0.5\nrefine = false",
        )
        // A 180° hook over 10 mm on 2 mm tip elements, each bent by 36°. (One 10 mm element
        // bent by 180° stopped diverging once the hand's limit held within the step; with
        // the 90°-over-30 mm wire the scene stopped once elements took the exact mean of the
        // rest curvature instead of its mid-point value; on 5 mm elements once a hand at its
        // strength gave way within the step.)
        .replace("bend_deg = 90.0", "bend_deg = 180.0")
        .replace("bend_length_mm = 30.0", "bend_length_mm = 10.0")
        // A hand that pushes and twists through anything (the 10 N and 0.1 N·m defaults
        // hold the push and the twist back before the hook breaks the coarse elements).
        + "\n[limits]\npush_force_n = 10000.0\nunsupported_mm = 5.0\ntwist_torque_nm = 10.0\n";
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
