//! The well-behaved session the soak watches: created, its frames read by a reader that keeps
//! up, driven in and out, and its timing (missed steps) read.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use anyhow::{Context, Result};
use cathlab_api::authorized as authed;
use cathlab_api::pb;
use cathlab_api::pb::simulator_client::SimulatorClient;
use tonic::transport::Channel;

use crate::common::{SCENE, command, speed};

/// The well-behaved session: fluoroscopy on, its frames read by a reader that keeps up, the
/// wire pushed in and out; its missed steps are what the soak watches.
pub(crate) struct Watched {
    pub(crate) session: pb::CreateSessionResponse,
    pub(crate) frames: Arc<AtomicU64>,
}

pub(crate) async fn watched_session(client: &mut SimulatorClient<Channel>) -> Result<Watched> {
    let session = client
        .create_session(pb::CreateSessionRequest {
            scene: Some(pb::create_session_request::Scene::SceneName(SCENE.into())),
            label: "soak control".into(),
            ..Default::default()
        })
        .await?
        .into_inner();
    let mut frames = client
        .stream_frames(authed(
            pb::StreamFramesRequest {
                session_id: session.session_id.clone(),
                encoding: pb::FrameEncoding::Raw8 as i32,
                ..Default::default()
            },
            &session.observer_token,
        ))
        .await?
        .into_inner();
    let count = Arc::new(AtomicU64::new(0));
    let counter = count.clone();
    tokio::spawn(async move {
        while let Ok(Some(_)) = frames.message().await {
            counter.fetch_add(1, Ordering::Relaxed);
        }
    });
    Ok(Watched {
        session,
        frames: count,
    })
}

pub(crate) async fn timing(
    client: &mut SimulatorClient<Channel>,
    w: &Watched,
) -> Result<pb::Timing> {
    client
        .get_session(authed(
            pb::GetSessionRequest {
                session_id: w.session.session_id.clone(),
            },
            &w.session.observer_token,
        ))
        .await?
        .into_inner()
        .timing
        .context("a live session has timing")
}

/// Drives the watched session: fluoroscopy on, then 10 mm/s in and out every 4 s, until `stop`.
pub(crate) async fn drive(
    mut client: SimulatorClient<Channel>,
    w: pb::CreateSessionResponse,
    stop: Arc<AtomicBool>,
) {
    let send = |client: &mut SimulatorClient<Channel>, seq: u64, kind| {
        let request = authed(
            pb::SendCommandRequest {
                session_id: w.session_id.clone(),
                seq,
                command: command(kind),
            },
            &w.controller_token,
        );
        let mut c = client.clone();
        async move { c.send_command(request).await }
    };
    let _ = send(&mut client, 1, pb::command::Kind::Fluoroscopy(true)).await;
    let mut seq = 1;
    while !stop.load(Ordering::Relaxed) {
        seq += 1;
        let mm_s = if seq % 2 == 0 { 10.0 } else { -10.0 };
        let _ = send(&mut client, seq, speed(mm_s, false)).await;
        tokio::time::sleep(Duration::from_secs(4)).await;
    }
}
