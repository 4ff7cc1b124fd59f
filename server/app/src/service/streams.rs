//! The read-only streams of a session: its device state, its X-ray frames (encoded as the
//! reader asks, within the stream budget and the stall limit) and its events and metrics.

use std::time::Duration;

use cathlab_api::{event_to_wire, metrics_to_wire, pb, state_to_wire};
use cathlab_engine::Encoding;
use tokio::sync::mpsc;
use tokio_stream::StreamExt;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status};

use super::state::SimulatorService;
use super::wire::{ResponseStream, peer_of, unix_us};
use crate::connections;
use crate::streams::{FrameRequest, FrameStream};

fn encoding_of(request: &pb::StreamFramesRequest) -> Result<Encoding, Status> {
    Ok(match pb::FrameEncoding::try_from(request.encoding) {
        Ok(pb::FrameEncoding::Raw8) | Ok(pb::FrameEncoding::Unspecified) => Encoding::Raw8,
        Ok(pb::FrameEncoding::Raw16) => Encoding::Raw16,
        Ok(pb::FrameEncoding::Png) => Encoding::Png,
        Ok(pb::FrameEncoding::Jpeg) => {
            let q = if request.jpeg_quality == 0 {
                85
            } else {
                request.jpeg_quality
            };
            if q > 100 {
                return Err(Status::invalid_argument(format!(
                    "jpeg_quality: {q} is outside 1..=100"
                )));
            }
            Encoding::Jpeg(q as u8)
        }
        Err(_) => {
            return Err(Status::invalid_argument(format!(
                "encoding: {} is not a FrameEncoding",
                request.encoding
            )));
        }
    })
}

impl SimulatorService {
    /// `StreamState`: the session's newest device state, as each step makes it.
    pub(super) async fn stream_state(
        &self,
        request: Request<pb::StreamStateRequest>,
    ) -> Result<Response<ResponseStream<pb::DeviceState>>, Status> {
        let (session, attending) = self.watched(&request, &request.get_ref().session_id)?;
        let tip_only = request.get_ref().tip_only;
        let stream = tokio_stream::wrappers::WatchStream::new(session.state()).map(move |s| {
            let _attending = &attending;
            Ok(state_to_wire(&s, tip_only, unix_us()))
        });
        Ok(Response::new(Box::pin(stream)))
    }

    /// `StreamFrames`: the session's X-ray frames, encoded as the reader asks, within the
    /// stream budget and the stall limit.
    pub(super) async fn stream_frames(
        &self,
        request: Request<pb::StreamFramesRequest>,
    ) -> Result<Response<ResponseStream<pb::XrayFrame>>, Status> {
        let (session, attending) = self.watched(&request, &request.get_ref().session_id)?;
        let cutter = connections::peer(&request).map(|p| p.cutter.clone());
        let address = peer_of(&request);
        let r = request.into_inner();
        let encoding = encoding_of(&r)?;
        for (field, v) in [("width", r.width), ("height", r.height)] {
            if v != 0 && !(16..=2048).contains(&v) {
                return Err(Status::invalid_argument(format!(
                    "{field}: {v} is outside 16..=2048 (0 keeps the detector size)"
                )));
            }
        }
        if (r.width == 0) != (r.height == 0) {
            return Err(Status::invalid_argument(
                "width, height: give both or neither",
            ));
        }
        let stream = FrameStream::new(
            session.frames(),
            FrameRequest {
                encoding,
                width: r.width,
                height: r.height,
            },
            self.stream_budget.clone(),
            (address, self.stream_stall, cutter),
        );
        Ok(Response::new(Box::pin(stream.map(move |frame| {
            let _attending = &attending;
            frame
        }))))
    }

    /// `StreamMetrics`: the session's events so far, then live events and metrics once a
    /// second.
    pub(super) async fn stream_metrics(
        &self,
        request: Request<pb::StreamMetricsRequest>,
    ) -> Result<Response<ResponseStream<pb::SessionUpdate>>, Status> {
        let (session, attending) = self.watched(&request, &request.get_ref().session_id)?;
        let mut events = session.events();
        let state = session.state();
        // The timeline so far (subscribed first, so nothing falls between the two); live
        // events the store already held are not sent twice.
        let session_id = request.get_ref().session_id.clone();
        let store = self.store.clone();
        let history = tokio::task::spawn_blocking(move || store.events(&session_id))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(|e| Status::internal(e.to_string()))?;
        let (tx, rx) = mpsc::channel::<Result<pb::SessionUpdate, Status>>(16 + history.len());
        let mut sent = std::collections::HashSet::new();
        for (step, time_s, kind, message) in history {
            let event = pb::Event {
                step,
                time_s,
                kind,
                message,
            };
            sent.insert((event.step, event.kind.clone(), event.message.clone()));
            let update = pb::session_update::Kind::Event(event);
            // The channel holds the whole history: this cannot wait.
            let _ = tx.try_send(Ok(pb::SessionUpdate { kind: Some(update) }));
        }
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_secs(1));
            loop {
                let update = tokio::select! {
                    _ = tick.tick() => pb::session_update::Kind::Metrics(
                        metrics_to_wire(&state.borrow().metrics)),
                    event = events.recv() => match event {
                        Ok(e) => {
                            let event = event_to_wire(&e);
                            if sent.remove(&(event.step, event.kind.clone(), event.message.clone())) {
                                continue;
                            }
                            pb::session_update::Kind::Event(event)
                        }
                        Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                            pb::session_update::Kind::Event(pb::Event {
                                kind: "lagged".into(),
                                message: format!("{n} events skipped (slow reader)"),
                                ..pb::Event::default()
                            })
                        }
                        Err(_) => break,
                    },
                };
                if tx
                    .send(Ok(pb::SessionUpdate { kind: Some(update) }))
                    .await
                    .is_err()
                {
                    break;
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx).map(
            move |update| {
                let _attending = &attending;
                update
            },
        ))))
    }
}
