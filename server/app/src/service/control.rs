//! Commanding a session: one command at a time (hold mode for speeds: a held speed lapses
//! unless renewed within the control timeout), and the control stream (inputs within their
//! rate, the dead-man rule, each new state sent back with the highest durable input).

use std::sync::Arc;

use cathlab_api::{command_from_wire, control_from_wire, pb, state_to_wire};
use cathlab_engine::CommandRecord;
use cathlab_engine::session::Session;
use cathlab_engine::world::Command;
use tokio::sync::{mpsc, oneshot};
use tokio_stream::StreamExt;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use super::state::{Axis, SimulatorService};
use super::wire::{ResponseStream, bearer, engine_status, peer_of, unix_us};

/// The axis a unary command drives, and whether it asks for hold mode with a non-zero speed
/// (targets and other commands: `None`, or the axis with `false`).
fn speed_axis(command: Option<&pb::Command>) -> Option<(Axis, bool)> {
    use pb::command::Kind;
    Some(match command?.kind.as_ref()? {
        Kind::Insertion(i) => match i.mode {
            Some(pb::insertion::Mode::VelocityMmS(v)) => (Axis::Push, i.hold && v != 0.0),
            _ => (Axis::Push, false),
        },
        Kind::Twist(t) => match t.mode {
            Some(pb::twist::Mode::RateDegS(w)) => (Axis::Twist, t.hold && w != 0.0),
            _ => (Axis::Twist, false),
        },
        _ => return None,
    })
}

/// How many instruments `session` has now (its last state; a stack's loads and unloads
/// change it, and the engine checks the index again where the command applies).
fn instrument_count(session: &Session) -> u32 {
    let now = session.state().borrow().instruments.len();
    let scene = session.assets().spec.stack.len();
    now.max(scene).max(1) as u32
}

impl SimulatorService {
    /// Hold mode for unary speed commands: a held speed lapses to zero unless a newer
    /// command on its axis comes within the control timeout (any newer command on the axis
    /// cancels the lapse).
    fn hold(
        &self,
        session: &Arc<Session>,
        (instrument, axis): (Option<u32>, Axis),
        hold: bool,
        seq: u64,
    ) {
        let key = (session.id().to_owned(), (instrument, axis));
        let generation = {
            let mut holds = self.holds.lock();
            let g = holds.entry(key.clone()).or_insert(0);
            *g += 1;
            *g
        };
        if !hold {
            return;
        }
        let (holds, session, timeout) = (self.holds.clone(), session.clone(), self.control_timeout);
        tokio::spawn(async move {
            tokio::time::sleep(timeout).await;
            if holds.lock().get(&key) != Some(&generation) {
                return;
            }
            tracing::info!(session = %session.id(), ?axis, "held speed not renewed: zeroed");
            let zero = match (instrument, axis) {
                (None, Axis::Push) => Command::PushVelocity(0.0),
                (None, Axis::Twist) => Command::TwistRate(0.0),
                (Some(index), Axis::Push) => Command::Instrument {
                    index,
                    drive: cathlab_engine::Drive::PushVelocity(0.0),
                },
                (Some(index), Axis::Twist) => Command::Instrument {
                    index,
                    drive: cathlab_engine::Drive::TwistRate(0.0),
                },
            };
            let _ = session.send(seq, zero, None);
        });
    }
}

impl SimulatorService {
    /// `SendCommand`: one command, answered once it has applied and is recorded; a held
    /// speed lapses unless renewed (see [`Self::hold`]).
    pub(super) async fn send_command(
        &self,
        request: Request<pb::SendCommandRequest>,
    ) -> Result<Response<pb::CommandAck>, Status> {
        let id = request.get_ref().session_id.clone();
        self.authorize(peer_of(&request), bearer(&request).as_deref(), &id, true)?;
        let r = request.into_inner();
        let command = command_from_wire(r.command.as_ref())?;
        let session = self.session(&id)?;
        let instruments = instrument_count(&session);
        let instrument = r.command.as_ref().and_then(|c| c.instrument);
        if let Some(index) = instrument
            && index >= instruments
        {
            return Err(Status::invalid_argument(format!(
                "command.instrument: {index} is not an instrument of this scene, which has \
                 {instruments} (0 is the outermost)"
            )));
        }
        let record = session
            .command(r.seq, command)
            .await
            .map_err(engine_status)?;
        if let Some((axis, hold)) = speed_axis(r.command.as_ref()) {
            self.hold(&session, (instrument, axis), hold, r.seq);
        }
        Ok(Response::new(pb::CommandAck {
            seq: record.seq,
            step: record.step,
        }))
    }

    /// `Control`: the control stream: inputs applied at the next step (within their rate and
    /// the dead-man rule), each new state sent back with the highest durable input.
    pub(super) async fn control(
        &self,
        request: Request<Streaming<pb::ControlInput>>,
    ) -> Result<Response<ResponseStream<pb::ControlOutput>>, Status> {
        let (token, peer) = (bearer(&request), peer_of(&request));
        let mut inputs = request.into_inner();
        let first = inputs
            .message()
            .await?
            .ok_or_else(|| Status::invalid_argument("session_id: the stream sent nothing"))?;
        let id = first.session_id.clone();
        // Authorized with the token from the stream's metadata.
        let role = self.authorize(peer, token.as_deref(), &id, true)?;
        let session = self.session(&id)?;
        let attending = self.attending(&id, role);
        let (out_tx, out_rx) = mpsc::channel::<Result<pb::ControlOutput, Status>>(64);
        let (pending_tx, mut pending_rx) = mpsc::channel::<(
            u64,
            oneshot::Receiver<cathlab_engine::Result<CommandRecord>>,
        )>(4096);
        // Dropped when the inputs end: the outputs then end too (a half-closed stream ends).
        let (inputs_done, mut inputs_ended) = oneshot::channel::<()>();
        // Inputs: validate and queue; a bad input ends the stream with its error.
        {
            let session = session.clone();
            let out_tx = out_tx.clone();
            let quiet_after = self.control_timeout;
            let per_second = self.control_inputs_per_second;
            tokio::spawn(async move {
                let _inputs_done = inputs_done;
                let mut next = Some(first);
                let (mut last_seq, mut driving) = (0, true);
                let mut previous: Option<u64> = None;
                // A token bucket: `per_second` inputs a second, a second's worth at once.
                let (mut tokens, mut refilled) = (per_second as f64, tokio::time::Instant::now());
                // The dead-man rule: a stream that goes quiet or away leaves the device still.
                // It zeroes the innermost's setpoints and those of every instrument a hand of
                // this stream drove (bit i: instrument i).
                let instruments = instrument_count(&session);
                let mut driven = 0u64;
                let stop = |seq: u64, why: &str, driven: u64| {
                    tracing::info!(session = %session.id(), "control stream {why}: setpoints zeroed");
                    let _ = session.send(
                        seq,
                        Command::Setpoints {
                            push_m_s: 0.0,
                            twist_rad_s: 0.0,
                        },
                        None,
                    );
                    for index in (0..instruments.min(64)).filter(|i| driven & (1 << i) != 0) {
                        let _ = session.send(
                            seq,
                            Command::Instrument {
                                index,
                                drive: cathlab_engine::world::Drive::Setpoints {
                                    push_m_s: 0.0,
                                    twist_rad_s: 0.0,
                                },
                            },
                            None,
                        );
                    }
                };
                loop {
                    let input = match next.take() {
                        Some(i) => i,
                        None => match tokio::time::timeout(quiet_after, inputs.message()).await {
                            Ok(Ok(Some(i))) => i,
                            Ok(Ok(None)) => {
                                stop(last_seq, "ended", driven);
                                break;
                            }
                            Ok(Err(e)) => {
                                stop(last_seq, "broke", driven);
                                let _ = out_tx.send(Err(e)).await;
                                break;
                            }
                            Err(_) => {
                                if driving {
                                    stop(last_seq, "went quiet", driven);
                                    driving = false;
                                }
                                continue;
                            }
                        },
                    };
                    if let Some(p) = previous
                        && input.seq <= p
                    {
                        stop(
                            last_seq,
                            "sent a sequence number that does not increase",
                            driven,
                        );
                        let _ = out_tx
                            .send(Err(Status::invalid_argument(format!(
                                "seq: {} does not increase (the last was {p})",
                                input.seq
                            ))))
                            .await;
                        break;
                    }
                    let now = tokio::time::Instant::now();
                    tokens = (tokens + (now - refilled).as_secs_f64() * per_second as f64)
                        .min(per_second as f64);
                    refilled = now;
                    if tokens < 1.0 {
                        stop(last_seq, "sent too fast", driven);
                        let _ = out_tx
                            .send(Err(Status::resource_exhausted(format!(
                                "control inputs: more than {per_second} a second"
                            ))))
                            .await;
                        break;
                    }
                    tokens -= 1.0;
                    previous = Some(input.seq);
                    (last_seq, driving) = (input.seq, true);
                    let commands = match control_from_wire(&input, instruments) {
                        Ok(c) => c,
                        Err(e) => {
                            stop(last_seq, "sent a bad input", driven);
                            let _ = out_tx.send(Err(e)).await;
                            break;
                        }
                    };
                    let mut sent = true;
                    for command in commands {
                        if let Command::Instrument { index, .. } = command {
                            driven |= 1 << index.min(63);
                        }
                        let (ack_tx, ack_rx) = oneshot::channel();
                        if let Err(e) = session.send(input.seq, command, Some(ack_tx)) {
                            let _ = out_tx.send(Err(engine_status(e))).await;
                            sent = false;
                            break;
                        }
                        if pending_tx.send((input.seq, ack_rx)).await.is_err() {
                            sent = false;
                            break;
                        }
                    }
                    if !sent {
                        break;
                    }
                }
            });
        }
        // Durability: the acknowledgements (committed to the store) in order; the highest
        // committed sequence number goes out with every state. A failed command ends the
        // stream with its error.
        let durable = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let (failed_tx, mut failed) = oneshot::channel::<Status>();
        let acks = {
            let durable = durable.clone();
            tokio::spawn(async move {
                while let Some((seq, ack)) = pending_rx.recv().await {
                    match ack.await {
                        Ok(Ok(_)) => durable.store(seq, std::sync::atomic::Ordering::Release),
                        Ok(Err(e)) => {
                            let _ = failed_tx.send(engine_status(e));
                            return;
                        }
                        // The session closed: its end reaches the state stream.
                        Err(_) => return,
                    }
                }
            })
        };
        // Outputs: every new state as soon as the step that made it is done (the hand feels
        // the wall within a step), with the durable sequence number beside it.
        {
            let mut state = session.state();
            tokio::spawn(async move {
                let durable_seq = || durable.load(std::sync::atomic::Ordering::Acquire);
                let message =
                    |snapshot: &cathlab_engine::Snapshot, durable_seq: u64| pb::ControlOutput {
                        state: Some(state_to_wire(snapshot, true, unix_us())),
                        durable_seq,
                    };
                // Set once the acknowledgements are all in without a failure.
                let mut acks_done = false;
                loop {
                    tokio::select! {
                        changed = state.changed() => if changed.is_err() { break },
                        status = &mut failed, if !acks_done => {
                            match status {
                                Ok(status) => {
                                    let _ = out_tx.send(Err(status)).await;
                                    return;
                                }
                                Err(_) => {
                                    acks_done = true;
                                    continue;
                                }
                            }
                        }
                        _ = &mut inputs_ended => {
                            // The inputs ended: once what was sent is durable (or failed),
                            // a last state says so, and the stream ends.
                            let _ = acks.await;
                            if !acks_done && let Ok(status) = failed.try_recv() {
                                let _ = out_tx.send(Err(status)).await;
                                return;
                            }
                            let snapshot = state.borrow_and_update().clone();
                            let _ = out_tx.send(Ok(message(&snapshot, durable_seq()))).await;
                            return;
                        }
                    }
                    let snapshot = state.borrow_and_update().clone();
                    if out_tx
                        .send(Ok(message(&snapshot, durable_seq())))
                        .await
                        .is_err()
                    {
                        break;
                    }
                }
            });
        }
        Ok(Response::new(Box::pin(ReceiverStream::new(out_rx).map(
            move |output| {
                let _attending = &attending;
                output
            },
        ))))
    }
}
