//! Reports and replays: a session's report and its frames (for its trainee, or an
//! instructor), an account's history of scores, and a recorded session replayed against its
//! checkpoints ([`replay_stored`], also behind `cathlab-server replay`).

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use cathlab_api::{metrics_to_wire, pb};
use cathlab_engine::{Engine, SceneSpec};
use tokio::sync::oneshot;
use tonic::{Request, Response, Status};

use super::state::{Role, SimulatorService};
use super::wire::{account_to_wire, bearer, checked_id, engine_status, peer_of};
use crate::reports::{Caller, store_status, token_hash};
use crate::store::{Store, StoredSession};

impl SimulatorService {
    /// A caller that may read `id`'s report, and the stored session. A wrong token counts as
    /// a guess.
    pub(super) fn report_reader<T>(
        &self,
        request: &Request<T>,
        id: &str,
    ) -> Result<StoredSession, Status> {
        checked_id(id)?;
        let caller = self.caller(request)?;
        let session = self.reports.session(id)?;
        caller.may_read(&session).inspect_err(|e| {
            if e.code() != tonic::Code::Unauthenticated && matches!(caller, Caller::Other(_)) {
                self.throttle
                    .failed(peer_of(request), "a token of no session or account");
            }
        })?;
        Ok(session)
    }
}

impl SimulatorService {
    /// `ReplaySession`: the session's recording replayed on a niced thread (queued behind
    /// reports) and its checkpoints compared.
    pub(super) async fn replay_session(
        &self,
        request: Request<pb::ReplaySessionRequest>,
    ) -> Result<Response<pb::ReplayResult>, Status> {
        let id = checked_id(&request.get_ref().session_id)?.to_owned();
        if self.engine.get(&id).is_ok() {
            // A live session: its trainee or an instructor (an observer only watches).
            let role =
                self.authorize(peer_of(&request), bearer(&request).as_deref(), &id, false)?;
            if role == Role::Observer {
                return Err(Status::permission_denied(
                    "replay is for the session's trainee and instructors, not its observers",
                ));
            }
        } else if !self.instructor(&request)? {
            return Err(
                if self.store.session(&id).map_err(store_status)?.is_some() {
                    Status::permission_denied(
                        "replaying a recorded session needs the instructor key",
                    )
                } else {
                    Status::not_found(format!("session {id:?}"))
                },
            );
        }
        // A place among the replays, then a niced thread of its own; a caller that goes away
        // abandons the replay (the guard below is dropped with this handler).
        // Queued behind reports, one per caller (a token's hash, else an address).
        let caller =
            bearer(&request).map_or_else(|| peer_of(&request).to_string(), |t| token_hash(&t));
        let place = self
            .reports
            .queue()
            .enter(crate::replays::Priority::Replay, &caller)
            .await?;
        let permit = self.engine.replay_permit().map_err(engine_status)?;
        let cancel = CancelOnDrop(Arc::new(AtomicBool::new(false)));
        let (engine, store, flag) = (self.engine.clone(), self.store.clone(), cancel.0.clone());
        let (done_tx, done_rx) = oneshot::channel();
        std::thread::Builder::new()
            .name("replay".into())
            .spawn(move || {
                cathlab_engine::priority::lower_current_thread(
                    cathlab_engine::priority::REPLAY_NICE,
                );
                let outcome = replay_stored(&engine, &store, &id, &flag);
                // The place is given back before the answer goes out: a caller that starts
                // another replay on hearing it must find the place free (a niced thread
                // could otherwise hold it for a while after answering).
                drop(permit);
                drop(place);
                let _ = done_tx.send(outcome);
            })
            .map_err(|e| Status::internal(format!("cannot start a replay thread: {e}")))?;
        let outcome = done_rx
            .await
            .map_err(|_| Status::internal("the replay thread ended without an answer"))??;
        drop(cancel);
        Ok(Response::new(outcome))
    }

    /// `GetReport`: the session's report (made when first asked for, then stored).
    pub(super) async fn get_report(
        &self,
        request: Request<pb::GetReportRequest>,
    ) -> Result<Response<pb::Report>, Status> {
        let id = request.get_ref().session_id.clone();
        let session = self.report_reader(&request, &id)?;
        let report = self.reports.get(&session).await?;
        let trainee_name = match &session.account_id {
            Some(a) => self
                .store
                .account(a)
                .map_err(store_status)?
                .map(|a| a.name)
                .unwrap_or_default(),
            None => session.label.clone(),
        };
        Ok(Response::new(pb::Report {
            session_id: id,
            account_id: session.account_id.unwrap_or_default(),
            trainee_name,
            scene_name: session.scene_name,
            created_unix_s: session.created_unix_s,
            json: report.json,
        }))
    }

    /// `GetReportFrame`: one replay frame of the session's report.
    pub(super) async fn get_report_frame(
        &self,
        request: Request<pb::GetReportFrameRequest>,
    ) -> Result<Response<pb::ReportFrame>, Status> {
        let (id, index) = (
            request.get_ref().session_id.clone(),
            request.get_ref().index,
        );
        self.report_reader(&request, &id)?;
        let (time_s, png) = self
            .store
            .report_frame(&id, index)
            .map_err(store_status)?
            .ok_or_else(|| {
                Status::not_found(format!(
                    "frame {index} of session {id:?}'s report (is the report made?)"
                ))
            })?;
        Ok(Response::new(pb::ReportFrame { time_s, png }))
    }

    /// `GetHistory`: an account's sessions with their scores (its own, or any for an
    /// instructor).
    pub(super) async fn get_history(
        &self,
        request: Request<pb::GetHistoryRequest>,
    ) -> Result<Response<pb::History>, Status> {
        let caller = self.caller(&request)?;
        let wanted = request.get_ref().account_id.clone();
        let account = match (&caller, wanted.is_empty()) {
            (Caller::Account(a), true) => a.clone(),
            (Caller::Account(a), false) if a.id == wanted => a.clone(),
            (Caller::InstructorKey | Caller::Account(_), false) if caller.is_instructor() => {
                checked_id(&wanted).map_err(|e| {
                    Status::invalid_argument(e.message().replacen("session_id", "account_id", 1))
                })?;
                self.store
                    .account(&wanted)
                    .map_err(store_status)?
                    .ok_or_else(|| Status::not_found(format!("account {wanted:?}")))?
            }
            (Caller::Account(_) | Caller::InstructorKey, false) => {
                return Err(Status::permission_denied(
                    "another trainee's history needs the instructor role",
                ));
            }
            (Caller::InstructorKey, true) => {
                return Err(Status::invalid_argument(
                    "account_id: the instructor key has no history of its own; name a trainee",
                ));
            }
            (Caller::Other(token), _) => {
                // A token that is nobody's is a guess, counted as every other.
                if token.is_some() {
                    self.throttle
                        .failed(peer_of(&request), "a token of no account");
                }
                return Err(Status::unauthenticated(
                    "a history needs an account's token or the instructor role",
                ));
            }
        };
        let mut entries = Vec::new();
        for s in self.store.sessions_of(&account.id).map_err(store_status)? {
            let report = self.store.report(&s.id).ok().flatten();
            let expert = serde_json::from_str::<SceneSpec>(&s.scene_json)
                .map(|spec| spec.assessment.expert.into_iter().collect())
                .unwrap_or_default();
            entries.push(pb::HistoryEntry {
                session_id: s.id,
                scene_name: s.scene_name,
                created_unix_s: s.created_unix_s,
                assessed: report.is_some(),
                within: report.as_ref().map_or(0, |r| r.within),
                judged: report.as_ref().map_or(0, |r| r.judged),
                metrics: report
                    .map(|r| r.metrics.into_iter().collect())
                    .unwrap_or_default(),
                expert,
            });
        }
        Ok(Response::new(pb::History {
            account: Some(account_to_wire(&account)),
            entries,
        }))
    }
}

/// Sets its flag when dropped: work on another thread sees that its caller went away.
struct CancelOnDrop(Arc<AtomicBool>);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// Replays a stored session from the store (also used by `cathlab-server replay`).
/// `cancel` abandons it.
pub fn replay_stored(
    engine: &Engine,
    store: &Store,
    id: &str,
    cancel: &AtomicBool,
) -> Result<pb::ReplayResult, Status> {
    let stored = store
        .session(id)
        .map_err(store_status)?
        .ok_or_else(|| Status::not_found(format!("session {id:?}")))?;
    let spec: SceneSpec = serde_json::from_str(&stored.scene_json)
        .map_err(|e| Status::internal(format!("stored scene of {id}: {e}")))?;
    let assets = engine
        .load(&spec, Path::new(&stored.base_dir))
        .map_err(engine_status)?;
    let commands = store.commands(id).map_err(store_status)?;
    let checkpoints = store.checkpoints(id).map_err(store_status)?;
    let outcome = cathlab_engine::replay_until(assets, &commands, &checkpoints, cancel)
        .map_err(engine_status)?;
    Ok(pb::ReplayResult {
        steps: outcome.steps,
        commands: outcome.commands as u32,
        checkpoints: outcome.checkpoints as u32,
        matched: outcome.matched as u32,
        recorded_digest: format!("{:016x}", outcome.recorded_digest),
        replayed_digest: format!("{:016x}", outcome.replayed_digest),
        metrics: Some(metrics_to_wire(&outcome.metrics)),
    })
}
