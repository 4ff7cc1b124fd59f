//! Accounts and assessment reports: token hashing, who a caller is (the instructor key, an
//! account, or a session's own token), and each closed session's report, computed once by
//! replaying its recording (on a niced thread, holding one of the engine's replay places)
//! and kept in the store.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use cathlab_engine::report::REPORT_VERSION;
use cathlab_engine::{Engine, ReportOptions, SceneSpec};
use parking_lot::Mutex;
use sha2::{Digest, Sha256};
use tokio::sync::oneshot;
use tonic::Status;

use crate::replays::{Priority, ReplayQueue};
use crate::store::{Store, StoreError, StoredAccount, StoredReport, StoredSession};

/// SHA-256 of a token (hex): what the store keeps instead of the token.
pub fn token_hash(token: &str) -> String {
    Sha256::digest(token.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// An account's role.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AccountRole {
    /// Sees their own sessions.
    Trainee,
    /// Sees everyone's, creates accounts.
    Instructor,
}

impl AccountRole {
    /// Parses `trainee` or `instructor`.
    pub fn parse(text: &str) -> Result<Self, Status> {
        match text {
            "trainee" => Ok(Self::Trainee),
            "instructor" => Ok(Self::Instructor),
            other => Err(Status::invalid_argument(format!(
                "role: {other:?} is neither `trainee` nor `instructor`"
            ))),
        }
    }

    /// Its name.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Trainee => "trainee",
            Self::Instructor => "instructor",
        }
    }
}

/// Who is asking.
#[derive(Debug, Clone, PartialEq)]
pub enum Caller {
    /// The server's instructor key.
    InstructorKey,
    /// An account's token.
    Account(StoredAccount),
    /// Some other token (perhaps a session's), or none.
    Other(Option<String>),
}

impl Caller {
    /// Whether the caller may read everyone's sessions.
    pub fn is_instructor(&self) -> bool {
        match self {
            Caller::InstructorKey => true,
            Caller::Account(a) => a.role == AccountRole::Instructor.as_str(),
            Caller::Other(_) => false,
        }
    }

    /// May the caller read `session`'s report? Instructors may; a trainee their own; a
    /// session's controller token its own session.
    pub fn may_read(&self, session: &StoredSession) -> Result<(), Status> {
        if self.is_instructor() {
            return Ok(());
        }
        match self {
            Caller::InstructorKey => Ok(()),
            Caller::Account(a) if session.account_id.as_deref() == Some(a.id.as_str()) => Ok(()),
            Caller::Account(_) => Err(Status::permission_denied(format!(
                "session {:?} is another trainee's; reading it needs the instructor role",
                session.id
            ))),
            Caller::Other(Some(token))
                if session.controller_hash.as_deref() == Some(token_hash(token).as_str()) =>
            {
                Ok(())
            }
            Caller::Other(Some(_)) => Err(Status::permission_denied(format!(
                "the token is not one of session {:?}, nor an account's that may read it",
                session.id
            ))),
            Caller::Other(None) => Err(Status::unauthenticated(
                "missing `authorization: Bearer <token>` metadata",
            )),
        }
    }
}

/// What a client hears of a store error: what failed, never where the database is (the file
/// or URL goes to the log). A database that cannot answer is UNAVAILABLE (retry later); a
/// corrupt value is lost data.
pub(crate) fn store_status(e: StoreError) -> Status {
    tracing::warn!("{e}");
    match e {
        StoreError::Database { .. } => {
            Status::unavailable("the session store cannot be reached; try again shortly")
        }
        StoreError::Corrupt { what, reason, .. } => {
            Status::data_loss(format!("corrupt {what}: {reason}"))
        }
    }
}

/// On-demand replays that may wait for a place at once (reports always wait their turn).
pub const MAX_WAITING_REPLAYS: usize = 16;

/// Computes, stores and hands out reports; one computation per session at a time.
pub struct Reports {
    engine: Arc<Engine>,
    store: Arc<Store>,
    options: ReportOptions,
    busy: Mutex<HashMap<String, Arc<tokio::sync::Mutex<()>>>>,
    queue: Arc<ReplayQueue>,
}

impl std::fmt::Debug for Reports {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reports").finish_non_exhaustive()
    }
}

/// Sets its flag when dropped: the computation sees that its caller went away.
struct CancelOnDrop(Arc<AtomicBool>);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

impl Reports {
    /// Reports of `engine`'s sessions, kept in `store`.
    pub fn new(engine: Arc<Engine>, store: Arc<Store>) -> Self {
        Self {
            store,
            options: ReportOptions::default(),
            busy: Mutex::new(HashMap::new()),
            queue: ReplayQueue::new(engine.max_replays(), MAX_WAITING_REPLAYS),
            engine,
        }
    }

    /// The queue for the replay places, which reports share with on-demand replays.
    pub fn queue(&self) -> &Arc<ReplayQueue> {
        &self.queue
    }

    /// The stored session `id`, NOT_FOUND if none.
    pub fn session(&self, id: &str) -> Result<StoredSession, Status> {
        self.store
            .session(id)
            .map_err(store_status)?
            .ok_or_else(|| Status::not_found(format!("session {id:?}")))
    }

    /// `session`'s report: the stored one, or computed now from the recording (a closed
    /// or interrupted session only: a running one is still being written). A caller that goes
    /// away abandons the computation.
    pub async fn get(&self, session: &StoredSession) -> Result<StoredReport, Status> {
        let id = session.id.as_str();
        let lock = self.busy.lock().entry(id.to_owned()).or_default().clone();
        let _held = lock.lock().await;
        if let Some(r) = self.store.report(id).map_err(store_status)?
            && r.version == REPORT_VERSION
        {
            return Ok(r);
        }
        if session.status == "running" && self.engine.get(id).is_ok() {
            return Err(Status::failed_precondition(format!(
                "session {id:?} is still running; its report is made when it closes"
            )));
        }
        // A report waits its turn (before on-demand replays), never refused for want of a
        // place.
        let place = self.queue.enter(Priority::Report, id).await?;
        let permit = self
            .engine
            .replay_permit()
            .map_err(|e| Status::resource_exhausted(e.to_string()))?;
        let cancel = CancelOnDrop(Arc::new(AtomicBool::new(false)));
        let (engine, store, flag, options, session) = (
            self.engine.clone(),
            self.store.clone(),
            cancel.0.clone(),
            self.options,
            session.clone(),
        );
        let id_owned = id.to_owned();
        let (done_tx, done_rx) = oneshot::channel();
        std::thread::Builder::new()
            .name("report".into())
            .spawn(move || {
                cathlab_engine::priority::lower_current_thread(
                    cathlab_engine::priority::REPLAY_NICE,
                );
                let outcome = compute(&engine, &store, &session, &options, &flag);
                drop(permit);
                drop(place);
                let _ = done_tx.send(outcome);
            })
            .map_err(|e| Status::internal(format!("cannot start a report thread: {e}")))?;
        let outcome = done_rx
            .await
            .map_err(|_| Status::internal("the report thread ended without an answer"))?;
        drop(cancel);
        self.busy.lock().remove(&id_owned);
        outcome?;
        self.store
            .report(id)
            .map_err(store_status)?
            .ok_or_else(|| Status::internal(format!("the report of {id:?} was not stored")))
    }
}

/// Replays `session`'s recording into a report and stores it.
fn compute(
    engine: &Engine,
    store: &Store,
    session: &StoredSession,
    options: &ReportOptions,
    cancel: &AtomicBool,
) -> Result<(), Status> {
    let id = &session.id;
    // What the session's last moments queued is committed first.
    store.flush();
    let spec: SceneSpec = serde_json::from_str(&session.scene_json).map_err(|e| {
        Status::data_loss(format!("the stored scene of session {id} is corrupt: {e}"))
    })?;
    let commands = store.commands(id).map_err(|e| {
        Status::data_loss(format!(
            "the recording of session {id} cannot be assessed: {e}"
        ))
    })?;
    let checkpoints = store.checkpoints(id).map_err(|e| {
        Status::data_loss(format!(
            "the recording of session {id} cannot be assessed: {e}"
        ))
    })?;
    let end = checkpoints
        .iter()
        .map(|c| c.step)
        .chain(commands.iter().map(|c| c.step))
        .max()
        .unwrap_or(0);
    let assets = engine
        .load(&spec, Path::new(&session.base_dir))
        .map_err(|e| Status::failed_precondition(format!("session {id}'s scene: {e}")))?;
    let report = cathlab_engine::assess(assets, &commands, end, options, cancel).map_err(|e| {
        Status::failed_precondition(format!("session {id} cannot be assessed: {e}"))
    })?;
    store.put_report(id, &report).map_err(store_status)
}
