//! The store: sessions, every applied command with its step, checkpoints (state digest and
//! metrics), events, accounts and reports, in SQLite (the embedded default: one file) or
//! PostgreSQL (shared by a fleet of servers). One writer thread batches what the physics
//! threads hand it into transactions and acknowledges commands only after their transaction
//! commits. The queries are written once, over [`sql::Conn`]; each backend keeps its own
//! versioned migrations.

pub mod cluster;
pub mod postgres;
pub mod sql;
pub mod sqlite;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;

use cathlab_engine::session::Ack;
use cathlab_engine::{Checkpoint, CommandRecord, EngineError, Event, Metrics, Recorder};

use self::postgres::{PgReaders, PgTarget};
use self::sql::{Conn, Dialect, Row, Value, transaction, values_list};
use self::sqlite::SqliteConn;

/// Store errors.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// The database refused something, or cannot be reached.
    #[error("{store}: {reason}")]
    Database {
        /// The database (a file, or a URL without its password).
        store: String,
        /// The cause.
        reason: String,
    },
    /// A stored value does not parse.
    #[error("{store}: corrupt {what}: {reason}")]
    Corrupt {
        /// The database.
        store: String,
        /// Which value.
        what: String,
        /// Why.
        reason: String,
    },
}

/// Where the store keeps its data.
#[derive(Debug, Clone, PartialEq)]
pub enum StoreLocation {
    /// A SQLite file (created with its directory if missing).
    Sqlite(PathBuf),
    /// A PostgreSQL database: `postgres://user:password@host:port/database`.
    Postgres(String),
}

/// A session as stored.
#[derive(Debug, Clone, PartialEq)]
pub struct StoredSession {
    /// Id.
    pub id: String,
    /// Label.
    pub label: String,
    /// Scene name.
    pub scene_name: String,
    /// The scene as JSON (what replay loads).
    pub scene_json: String,
    /// Directory the scene's relative paths start from.
    pub base_dir: PathBuf,
    /// Unix time of creation (s).
    pub created_unix_s: f64,
    /// `running`, `closed` or `interrupted`.
    pub status: String,
    /// Physics rate (Hz).
    pub step_rate_hz: f64,
    /// The trainee's account, if the session was created with an account token.
    pub account_id: Option<String>,
    /// SHA-256 of the session's controller token (hex): the trainee's key to the report of an
    /// anonymous session after it closed.
    pub controller_hash: Option<String>,
    /// The server that runs (or ran) it; none for sessions from before the fleet.
    pub server_id: Option<String>,
}

/// A server of the fleet as registered in the store.
#[derive(Debug, Clone, PartialEq)]
pub struct StoredServer {
    /// Id (unique in the fleet).
    pub id: String,
    /// Where clients reach it (`http://host:port`).
    pub address: String,
    /// Most sessions it runs at once.
    pub capacity: u32,
    /// Sessions it runs now.
    pub load: u32,
    /// Unix time it registered (s, the database's clock).
    pub started_unix_s: f64,
    /// Unix time of its last heartbeat (s, the database's clock).
    pub heartbeat_unix_s: f64,
    /// `serving`, `stopped` (shut down cleanly) or `lost` (stopped beating).
    pub status: String,
}

/// An account as stored (its token only as a hash).
#[derive(Debug, Clone, PartialEq)]
pub struct StoredAccount {
    /// Id.
    pub id: String,
    /// Display name.
    pub name: String,
    /// `trainee` or `instructor`.
    pub role: String,
    /// SHA-256 of the token (hex).
    pub token_hash: String,
    /// Unix time of creation (s).
    pub created_unix_s: f64,
}

/// A stored report's header and scores (the JSON is read only when asked for).
#[derive(Debug, Clone, PartialEq)]
pub struct StoredReport {
    /// Layout version ([`cathlab_engine::report::REPORT_VERSION`] when current).
    pub version: u32,
    /// The report (JSON).
    pub json: String,
    /// Scores by metric key.
    pub metrics: std::collections::BTreeMap<String, f64>,
    /// Verdicts within the expert range.
    pub within: u32,
    /// Metrics with a benchmark.
    pub judged: u32,
}

enum Write {
    Session(StoredSession, std::sync::mpsc::Sender<Result<(), String>>),
    Status(String, &'static str),
    Command(String, CommandRecord, Option<Ack>),
    Checkpoint(String, Checkpoint),
    Event(String, Event),
    Flush(std::sync::mpsc::Sender<()>),
}

/// How the store reads: a SQLite file opened per read (WAL lets reads run beside the
/// writer), or PostgreSQL's reader threads.
enum Backend {
    Sqlite(PathBuf),
    Postgres(PgReaders),
}

/// The store: a writer thread and the database.
pub struct Store {
    name: String,
    server_id: String,
    backend: Backend,
    writes: SyncSender<Write>,
    reachable: Arc<AtomicBool>,
    refused_writes: AtomicU64,
    _writer: JoinHandle<()>,
}

impl std::fmt::Debug for Store {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Store")
            .field("database", &self.name)
            .finish()
    }
}

/// The schema version this build writes (the same for both backends).
pub const SCHEMA_VERSION: usize = sqlite::MIGRATIONS.len();

const _: () = assert!(sqlite::MIGRATIONS.len() == postgres::MIGRATIONS.len());

/// Makes a writer's connection, migrating the schema to current (again, after one is lost).
type Connect = Box<dyn Fn() -> Result<Box<dyn Conn>, String> + Send>;

impl Store {
    /// Opens (or creates) the SQLite database `file`, marks sessions left running by a
    /// previous process as interrupted, and starts the writer.
    pub fn open(file: &Path) -> Result<Self, StoreError> {
        Self::at(&StoreLocation::Sqlite(file.to_owned()))
    }

    /// Opens the store at `location`: migrates it to [`SCHEMA_VERSION`], marks sessions left
    /// running by a previous process as interrupted, and starts the writer.
    pub fn at(location: &StoreLocation) -> Result<Self, StoreError> {
        Self::for_server(location, LOCAL_SERVER)
    }

    /// [`Store::at`] for server `server_id` of a fleet sharing the store: only the sessions
    /// this server left running (or that name no server) are marked interrupted.
    pub fn for_server(location: &StoreLocation, server_id: &str) -> Result<Self, StoreError> {
        Self::with_queue(location, server_id, QUEUE)
    }

    /// [`Store::for_server`] with a queue of `queue` writes.
    fn with_queue(
        location: &StoreLocation,
        server_id: &str,
        queue: usize,
    ) -> Result<Self, StoreError> {
        let (name, backend, connect): (_, _, Connect) = match location {
            StoreLocation::Sqlite(file) => {
                let path = file.clone();
                // The first connection may create the file; one made again after the file
                // was removed must not (an empty database would take the writes instead).
                let opened = AtomicBool::new(false);
                (
                    file.display().to_string(),
                    Backend::Sqlite(file.clone()),
                    Box::new(move || {
                        let mut c = if opened.swap(true, Ordering::SeqCst) {
                            SqliteConn::open_existing(&path)?
                        } else {
                            SqliteConn::open(&path)?
                        };
                        c.migrate()?;
                        Ok(Box::new(c) as Box<dyn Conn>)
                    }),
                )
            }
            StoreLocation::Postgres(url) => {
                let target = PgTarget::parse(url).map_err(|reason| StoreError::Database {
                    store: "the PostgreSQL store".into(),
                    reason,
                })?;
                let readers =
                    PgReaders::new(target.clone(), 2).map_err(|reason| StoreError::Database {
                        store: target.name.clone(),
                        reason,
                    })?;
                (
                    target.name.clone(),
                    Backend::Postgres(readers),
                    Box::new(move || {
                        let mut c = target.connect()?;
                        c.migrate()?;
                        Ok(Box::new(c) as Box<dyn Conn>)
                    }),
                )
            }
        };
        let database = |reason| StoreError::Database {
            store: name.clone(),
            reason,
        };
        // The writer thread makes the first connection (it migrates the schema; a later one,
        // after a connection was lost, finds it current) and marks the sessions a previous
        // process left running; this waits for that. PostgreSQL's client blocks on a runtime
        // of its own, so it is used only on the store's own threads.
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let (tx, rx) = sync_channel(queue);
        let writer_name = name.clone();
        let me = server_id.to_owned();
        let reachable = Arc::new(AtomicBool::new(true));
        let writer_reachable = reachable.clone();
        let writer = std::thread::Builder::new()
            .name("store-writer".into())
            .spawn(move || {
                let first = connect().and_then(|mut c| {
                    // Its own sessions another server marked lost while it was away too.
                    c.execute(
                        "UPDATE sessions SET status = 'interrupted'
                         WHERE (status = 'running' AND (server_id = ?1 OR server_id IS NULL))
                         OR (status = 'lost' AND server_id = ?1)",
                        &[me.into()],
                    )?;
                    Ok(c)
                });
                match first {
                    Ok(conn) => {
                        let _ = ready_tx.send(Ok(()));
                        writer_loop(Some(conn), connect, rx, writer_name, &writer_reachable);
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                    }
                }
            })
            .map_err(|e| database(format!("cannot start the writer thread: {e}")))?;
        ready_rx
            .recv()
            .map_err(|_| database("the writer thread stopped while starting".into()))?
            .map_err(database)?;
        Ok(Self {
            name,
            server_id: server_id.to_owned(),
            backend,
            writes: tx,
            reachable,
            refused_writes: AtomicU64::new(0),
            _writer: writer,
        })
    }

    fn push(&self, write: Write) {
        match self.writes.try_send(write) {
            Ok(()) => {}
            // The writer is behind by a full queue (65,536 writes). While the database answers, wait rather
            // than lose one; while it cannot be reached, refuse instead (the physics threads
            // must not stop): a command is answered with the error, never acknowledged.
            Err(TrySendError::Full(w)) if self.is_reachable() => {
                let _ = self.writes.send(w);
            }
            Err(TrySendError::Full(w)) => self.refuse(
                w,
                "the database cannot be reached and the store's queue is full",
            ),
            Err(TrySendError::Disconnected(w)) => self.refuse(w, "the store is closed"),
        }
    }

    /// Answers a write that will not be made.
    fn refuse(&self, write: Write, why: &str) {
        match write {
            Write::Command(_, _, Some(ack)) => {
                let _ = ack.send(Err(EngineError::Store(why.into())));
            }
            Write::Session(_, done) => {
                let _ = done.send(Err(why.into()));
            }
            Write::Flush(_) => {}
            _ => {
                let n = self.refused_writes.fetch_add(1, Ordering::Relaxed) + 1;
                if n.is_power_of_two() {
                    tracing::warn!("{}: {why}: {n} writes not stored", self.name);
                }
            }
        }
    }

    /// Whether the last write to the database succeeded (false while it cannot be reached:
    /// health reports NOT_SERVING and no command is acknowledged).
    pub fn is_reachable(&self) -> bool {
        self.reachable.load(Ordering::Relaxed)
    }

    /// Checkpoints and events not stored because the database could not be reached.
    pub fn refused_writes(&self) -> u64 {
        self.refused_writes.load(Ordering::Relaxed)
    }

    /// Inserts a new session and waits until it is committed.
    pub fn insert_session(&self, session: StoredSession) -> Result<(), String> {
        let (tx, rx) = std::sync::mpsc::channel();
        self.push(Write::Session(session, tx));
        rx.recv().map_err(|_| "the store is closed".to_owned())?
    }

    /// Sets a session's status (`closed`).
    pub fn set_status(&self, id: &str, status: &'static str) {
        self.push(Write::Status(id.to_owned(), status));
    }

    /// Waits until everything queued so far is committed.
    pub fn flush(&self) {
        let (tx, rx) = std::sync::mpsc::channel();
        self.push(Write::Flush(tx));
        let _ = rx.recv();
    }

    /// The SQL dialect the backend speaks.
    fn dialect(&self) -> Dialect {
        match self.backend {
            Backend::Sqlite(_) => Dialect::Sqlite,
            Backend::Postgres(_) => Dialect::Postgres,
        }
    }

    /// The database, as messages name it (a file, or a URL without its password).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Runs `f` on a read connection: a fresh SQLite connection, or a PostgreSQL reader's
    /// (again on a new connection if the database restarted under it: `f` may run twice).
    fn read<T: Send + 'static>(
        &self,
        f: impl Fn(&mut dyn Conn) -> Result<T, String> + Send + Sync + 'static,
    ) -> Result<T, StoreError> {
        match &self.backend {
            Backend::Sqlite(file) => SqliteConn::open_existing(file).and_then(|mut c| f(&mut c)),
            Backend::Postgres(readers) => readers.run(f),
        }
        .map_err(|reason| StoreError::Database {
            store: self.name.clone(),
            reason,
        })
    }

    /// The rows of `sql` with `params`, each turned into a `T` by `row` (a row that does
    /// not is reported as corrupt `what`).
    fn rows<T>(
        &self,
        sql: impl Into<String>,
        params: Vec<Value>,
        what: &str,
        row: impl Fn(&Row) -> Result<T, String>,
    ) -> Result<Vec<T>, StoreError> {
        let sql = sql.into();
        self.read(move |c| c.query(&sql, &params))?
            .iter()
            .map(|r| row(r).map_err(|e| self.corrupt(what.to_owned(), e)))
            .collect()
    }

    fn corrupt(&self, what: String, reason: impl std::fmt::Display) -> StoreError {
        StoreError::Corrupt {
            store: self.name.clone(),
            what,
            reason: reason.to_string(),
        }
    }

    /// Every stored session, newest first.
    pub fn sessions(&self) -> Result<Vec<StoredSession>, StoreError> {
        self.rows(
            format!("{SELECT_SESSION} ORDER BY created_unix_s DESC"),
            vec![],
            "session",
            row_to_session,
        )
    }

    /// One page of stored sessions, newest first: at most `limit` created before `after`
    /// (the last of the previous page: its creation time and id), and whether more follow.
    pub fn sessions_page(
        &self,
        after: Option<(f64, String)>,
        limit: usize,
    ) -> Result<(Vec<StoredSession>, bool), StoreError> {
        let (from, id) = after.unwrap_or((f64::INFINITY, String::new()));
        let mut page = self.rows(
            format!(
                "{SELECT_SESSION} WHERE created_unix_s < ?1 OR (created_unix_s = ?1 AND id < ?2) \
                 ORDER BY created_unix_s DESC, id DESC LIMIT ?3"
            ),
            vec![
                if from.is_finite() { from } else { f64::MAX }.into(),
                id.into(),
                (limit as i64 + 1).into(),
            ],
            "session",
            row_to_session,
        )?;
        let more = page.len() > limit;
        page.truncate(limit);
        Ok((page, more))
    }

    /// Deletes ended sessions (closed or interrupted: never one running, lost or being
    /// written) with everything recorded of them: anonymous ones past the newest
    /// `keep_anonymous`, and any older than `max_age_s` when set (a trainee's sessions, their
    /// history, go only by age). Returns how many went.
    pub fn prune(
        &self,
        keep_anonymous: usize,
        max_age_s: Option<f64>,
    ) -> Result<usize, StoreError> {
        let ended = self.rows(
            "SELECT id, created_unix_s, account_id IS NULL FROM sessions \
             WHERE status IN ('closed', 'interrupted') ORDER BY created_unix_s DESC, id DESC",
            vec![],
            "session",
            |r| Ok((r.text(0)?, r.real(1)?, r.int(2)? != 0)),
        )?;
        let cutoff = max_age_s.map(|age| unix_now_s() - age);
        let mut anonymous = 0usize;
        let doomed: Vec<String> = ended
            .into_iter()
            .filter(|(_, created, is_anonymous)| {
                let too_old = cutoff.is_some_and(|c| *created < c);
                let beyond = *is_anonymous && {
                    anonymous += 1;
                    anonymous > keep_anonymous
                };
                too_old || beyond
            })
            .map(|(id, _, _)| id)
            .collect();
        let count = doomed.len();
        for chunk in doomed.chunks(200) {
            let ids: Vec<Value> = chunk.iter().map(|id| id.clone().into()).collect();
            let list = (1..=ids.len())
                .map(|i| format!("?{i}"))
                .collect::<Vec<_>>()
                .join(", ");
            self.read(move |c| {
                transaction(c, |tx| {
                    for table in [
                        "commands",
                        "checkpoints",
                        "events",
                        "reports",
                        "report_frames",
                    ] {
                        tx.execute(
                            &format!("DELETE FROM {table} WHERE session_id IN ({list})"),
                            &ids,
                        )?;
                    }
                    tx.execute(&format!("DELETE FROM sessions WHERE id IN ({list})"), &ids)?;
                    Ok(())
                })
            })?;
        }
        Ok(count)
    }

    /// The sessions other servers of the fleet run (as the store last heard), newest first.
    pub fn running_elsewhere(&self) -> Result<Vec<StoredSession>, StoreError> {
        self.rows(
            format!(
                "{SELECT_SESSION} WHERE status = 'running' AND server_id IS NOT NULL \
                 AND server_id <> ?1 ORDER BY created_unix_s DESC"
            ),
            vec![self.server_id.as_str().into()],
            "session",
            row_to_session,
        )
    }

    /// One stored session.
    pub fn session(&self, id: &str) -> Result<Option<StoredSession>, StoreError> {
        Ok(self
            .rows(
                format!("{SELECT_SESSION} WHERE id = ?1"),
                vec![id.into()],
                &format!("session {id}"),
                row_to_session,
            )?
            .pop())
    }

    /// A session's recorded events in order: (step, simulated time s, kind, message).
    pub fn events(&self, id: &str) -> Result<Vec<(u64, f64, String, String)>, StoreError> {
        self.rows(
            format!(
                "SELECT step, time_s, kind, message FROM events WHERE session_id = ?1
                 ORDER BY {}",
                self.dialect().event_order()
            ),
            vec![id.into()],
            &format!("event of session {id}"),
            |r| Ok((r.int(0)?.max(0) as u64, r.real(1)?, r.text(2)?, r.text(3)?)),
        )
    }

    /// A session's commands in application order.
    pub fn commands(&self, id: &str) -> Result<Vec<CommandRecord>, StoreError> {
        self.rows(
            "SELECT ordinal, step, seq, command FROM commands WHERE session_id = ?1
             ORDER BY ordinal",
            vec![id.into()],
            &format!("command of session {id}"),
            |r| Ok((r.int(0)?, r.int(1)?, r.int(2)?, r.text(3)?)),
        )?
        .into_iter()
        .map(|(ordinal, step, seq, json)| {
            Ok(CommandRecord {
                ordinal: ordinal as u64,
                step: step as u64,
                seq: seq as u64,
                command: serde_json::from_str(&json)
                    .map_err(|e| self.corrupt(format!("command {ordinal} of session {id}"), e))?,
            })
        })
        .collect()
    }

    fn checkpoint_rows(&self, id: &str, order_limit: &str) -> Result<Vec<Checkpoint>, StoreError> {
        self.rows(
            format!(
                "SELECT step, digest, metrics FROM checkpoints WHERE session_id = ?1 {order_limit}"
            ),
            vec![id.into()],
            &format!("checkpoint of session {id}"),
            |r| Ok((r.int(0)?, r.text(1)?, r.text(2)?)),
        )?
        .into_iter()
        .map(|(step, digest, metrics)| {
            let what = |what: &str| format!("{what} at step {step} of session {id}");
            Ok(Checkpoint {
                step: step as u64,
                digest: u64::from_str_radix(&digest, 16)
                    .map_err(|e| self.corrupt(what("digest"), e))?,
                metrics: serde_json::from_str::<Metrics>(&metrics)
                    .map_err(|e| self.corrupt(what("metrics"), e))?,
            })
        })
        .collect()
    }

    /// A session's checkpoints by step.
    pub fn checkpoints(&self, id: &str) -> Result<Vec<Checkpoint>, StoreError> {
        self.checkpoint_rows(id, "ORDER BY step")
    }

    /// A session's latest checkpoint.
    pub fn last_checkpoint(&self, id: &str) -> Result<Option<Checkpoint>, StoreError> {
        Ok(self
            .checkpoint_rows(id, "ORDER BY step DESC LIMIT 1")?
            .pop())
    }

    /// Statements run in one transaction on a read connection (accounts and reports: rare,
    /// and not on the physics threads' path).
    fn write(&self, statements: Vec<(String, Vec<Value>)>) -> Result<(), StoreError> {
        self.read(move |c| {
            transaction(c, |c| {
                for (sql, params) in &statements {
                    c.execute(sql, params)?;
                }
                Ok(())
            })
        })
    }

    /// Adds an account.
    pub fn insert_account(&self, a: &StoredAccount) -> Result<(), StoreError> {
        self.write(vec![(
            "INSERT INTO accounts (id, name, role, token_hash, created_unix_s)
             VALUES (?1, ?2, ?3, ?4, ?5)"
                .into(),
            vec![
                (&a.id).into(),
                (&a.name).into(),
                (&a.role).into(),
                (&a.token_hash).into(),
                a.created_unix_s.into(),
            ],
        )])
    }

    /// The account whose token hashes to `token_hash`.
    pub fn account_by_token_hash(
        &self,
        token_hash: &str,
    ) -> Result<Option<StoredAccount>, StoreError> {
        Ok(self
            .rows(
                format!("{SELECT_ACCOUNT} WHERE token_hash = ?1"),
                vec![token_hash.into()],
                "account",
                row_to_account,
            )?
            .pop())
    }

    /// One account.
    pub fn account(&self, id: &str) -> Result<Option<StoredAccount>, StoreError> {
        Ok(self
            .rows(
                format!("{SELECT_ACCOUNT} WHERE id = ?1"),
                vec![id.into()],
                &format!("account {id}"),
                row_to_account,
            )?
            .pop())
    }

    /// Every account, oldest first.
    pub fn accounts(&self) -> Result<Vec<StoredAccount>, StoreError> {
        self.rows(
            format!("{SELECT_ACCOUNT} ORDER BY created_unix_s"),
            vec![],
            "account",
            row_to_account,
        )
    }

    /// An account's sessions, oldest first.
    pub fn sessions_of(&self, account_id: &str) -> Result<Vec<StoredSession>, StoreError> {
        self.rows(
            format!("{SELECT_SESSION} WHERE account_id = ?1 ORDER BY created_unix_s"),
            vec![account_id.into()],
            &format!("session of account {account_id}"),
            row_to_session,
        )
    }

    /// A session's stored report, if any.
    pub fn report(&self, session_id: &str) -> Result<Option<StoredReport>, StoreError> {
        let what = format!("report of session {session_id}");
        self.rows(
            "SELECT version, json, metrics, within, judged FROM reports WHERE session_id = ?1",
            vec![session_id.into()],
            &what,
            |r| Ok((r.int(0)?, r.text(1)?, r.text(2)?, r.int(3)?, r.int(4)?)),
        )?
        .into_iter()
        .next()
        .map(|(version, json, metrics, within, judged)| {
            Ok(StoredReport {
                version: version.max(0) as u32,
                json,
                metrics: serde_json::from_str(&metrics).map_err(|e| {
                    self.corrupt(format!("report scores of session {session_id}"), e)
                })?,
                within: within.max(0) as u32,
                judged: judged.max(0) as u32,
            })
        })
        .transpose()
    }

    /// Stores a session's report and its replay frames (replacing any before), in one
    /// transaction.
    pub fn put_report(
        &self,
        session_id: &str,
        report: &cathlab_engine::SessionReport,
    ) -> Result<(), StoreError> {
        let json = serde_json::to_string(report)
            .map_err(|e| self.corrupt(format!("report of session {session_id}"), e))?;
        let metrics: std::collections::BTreeMap<&str, f64> = report
            .metrics
            .iter()
            .map(|m| (m.key.as_str(), m.value))
            .collect();
        let metrics = serde_json::to_string(&metrics)
            .map_err(|e| self.corrupt(format!("report scores of session {session_id}"), e))?;
        let within = report.verdicts.iter().filter(|v| v.within).count() as i64;
        let mut statements = vec![
            (
                "DELETE FROM report_frames WHERE session_id = ?1".to_owned(),
                vec![session_id.into()],
            ),
            (
                "INSERT INTO reports (session_id, version, json, metrics, within, judged)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6)
                 ON CONFLICT (session_id) DO UPDATE SET version = excluded.version,
                 json = excluded.json, metrics = excluded.metrics, within = excluded.within,
                 judged = excluded.judged"
                    .to_owned(),
                vec![
                    session_id.into(),
                    i64::from(report.version).into(),
                    json.into(),
                    metrics.into(),
                    within.into(),
                    (report.verdicts.len() as i64).into(),
                ],
            ),
        ];
        for (i, f) in report.frames.iter().enumerate() {
            statements.push((
                "INSERT INTO report_frames (session_id, idx, time_s, png)
                 VALUES (?1, ?2, ?3, ?4)"
                    .to_owned(),
                vec![
                    session_id.into(),
                    (i as i64).into(),
                    f.time_s.into(),
                    f.png.clone().into(),
                ],
            ));
        }
        self.write(statements)
    }

    /// Replay frame `index` of a session's report: (time s, PNG).
    pub fn report_frame(
        &self,
        session_id: &str,
        index: u32,
    ) -> Result<Option<(f64, Vec<u8>)>, StoreError> {
        Ok(self
            .rows(
                "SELECT time_s, png FROM report_frames WHERE session_id = ?1 AND idx = ?2",
                vec![session_id.into(), i64::from(index).into()],
                &format!("frame {index} of session {session_id}'s report"),
                |r| Ok((r.real(0)?, r.blob(1)?)),
            )?
            .pop())
    }

    /// This store's server id.
    pub fn server_id(&self) -> &str {
        &self.server_id
    }

    /// Registers this server (or beats its heart): its address, capacity and load, stamped
    /// with the database's clock. Sessions of this process that another server marked lost
    /// while this one could not beat (the database unreachable, the process stalled) run
    /// again. (At start, the lost sessions of an earlier process under the same id were
    /// marked interrupted.)
    pub fn heartbeat(&self, address: &str, capacity: u32, load: u32) -> Result<(), StoreError> {
        let now = self.dialect().now_s();
        let me: Value = self.server_id.as_str().into();
        self.write(vec![
            (
                format!(
                    "INSERT INTO servers (id, address, capacity, load, started_unix_s,
                     heartbeat_unix_s, status) VALUES (?1, ?2, ?3, ?4, {now}, {now}, 'serving')
                     ON CONFLICT (id) DO UPDATE SET address = excluded.address,
                     capacity = excluded.capacity, load = excluded.load,
                     heartbeat_unix_s = excluded.heartbeat_unix_s, status = 'serving'"
                ),
                vec![
                    me.clone(),
                    address.into(),
                    i64::from(capacity).into(),
                    i64::from(load).into(),
                ],
            ),
            (
                "UPDATE sessions SET status = 'running' WHERE server_id = ?1 AND status = 'lost'"
                    .into(),
                vec![me],
            ),
        ])
    }

    /// Marks this server stopped (a clean shutdown: its sessions were closed).
    pub fn unregister(&self) -> Result<(), StoreError> {
        self.write(vec![(
            "UPDATE servers SET status = 'stopped', load = 0 WHERE id = ?1".into(),
            vec![self.server_id.as_str().into()],
        )])
    }

    /// Marks servers whose last heartbeat is older than `silent_s` (by the database's clock)
    /// lost, and the sessions they were running lost too (their recordings stay replayable).
    pub fn mark_lost(&self, silent_s: f64) -> Result<(), StoreError> {
        let now = self.dialect().now_s();
        self.write(vec![
            (
                format!(
                    "UPDATE servers SET status = 'lost', load = 0 WHERE status = 'serving'
                     AND heartbeat_unix_s < {now} - ?1"
                ),
                vec![silent_s.into()],
            ),
            (
                "UPDATE sessions SET status = 'lost' WHERE status = 'running' AND server_id IN
                 (SELECT id FROM servers WHERE status = 'lost')"
                    .into(),
                vec![],
            ),
        ])
    }

    /// Every server that ever registered, by id.
    pub fn servers(&self) -> Result<Vec<StoredServer>, StoreError> {
        self.rows(
            format!("{SELECT_SERVER} ORDER BY id"),
            vec![],
            "server",
            row_to_server,
        )
    }

    /// How many commands a session has recorded.
    pub fn command_count(&self, id: &str) -> Result<u64, StoreError> {
        let counts = self.rows(
            // The operator's commands: the overload governor's fidelity changes are recorded
            // for replay but are not the trainee's.
            "SELECT COUNT(*) FROM commands WHERE session_id = ?1 \
             AND command NOT LIKE '{\"fidelity\"%'",
            vec![id.into()],
            "command count",
            |r| r.int(0),
        )?;
        Ok(counts.first().copied().unwrap_or(0).max(0) as u64)
    }
}

/// Now, in seconds since the Unix epoch.
fn unix_now_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

const SELECT_SESSION: &str = "SELECT id, label, scene_name, scene_json, base_dir, \
    created_unix_s, status, step_rate_hz, account_id, controller_hash, server_id FROM sessions";

fn row_to_session(r: &Row) -> Result<StoredSession, String> {
    Ok(StoredSession {
        id: r.text(0)?,
        label: r.text(1)?,
        scene_name: r.text(2)?,
        scene_json: r.text(3)?,
        base_dir: PathBuf::from(r.text(4)?),
        created_unix_s: r.real(5)?,
        status: r.text(6)?,
        step_rate_hz: r.real(7)?,
        account_id: r.opt_text(8)?,
        controller_hash: r.opt_text(9)?,
        server_id: r.opt_text(10)?,
    })
}

const SELECT_SERVER: &str = "SELECT id, address, capacity, load, started_unix_s, \
    heartbeat_unix_s, status FROM servers";

fn row_to_server(r: &Row) -> Result<StoredServer, String> {
    Ok(StoredServer {
        id: r.text(0)?,
        address: r.text(1)?,
        capacity: r.int(2)?.clamp(0, i64::from(u32::MAX)) as u32,
        load: r.int(3)?.clamp(0, i64::from(u32::MAX)) as u32,
        started_unix_s: r.real(4)?,
        heartbeat_unix_s: r.real(5)?,
        status: r.text(6)?,
    })
}

const SELECT_ACCOUNT: &str = "SELECT id, name, role, token_hash, created_unix_s FROM accounts";

fn row_to_account(r: &Row) -> Result<StoredAccount, String> {
    Ok(StoredAccount {
        id: r.text(0)?,
        name: r.text(1)?,
        role: r.text(2)?,
        token_hash: r.text(3)?,
        created_unix_s: r.real(4)?,
    })
}

impl Recorder for Store {
    fn command(&self, session: &str, record: CommandRecord, ack: Option<Ack>) {
        self.push(Write::Command(session.to_owned(), record, ack));
    }

    fn checkpoint(&self, session: &str, checkpoint: Checkpoint) {
        self.push(Write::Checkpoint(session.to_owned(), checkpoint));
    }

    fn event(&self, session: &str, event: &Event) {
        self.push(Write::Event(session.to_owned(), event.clone()));
    }
}

/// Most writes in one transaction.
const BATCH: usize = 512;

/// The server id of a store used by one server alone.
pub const LOCAL_SERVER: &str = "local";

/// Writes the physics threads may queue ahead of the writer.
const QUEUE: usize = 1 << 16;

fn writer_loop(
    mut conn: Option<Box<dyn Conn>>,
    connect: Connect,
    rx: Receiver<Write>,
    name: String,
    reachable: &AtomicBool,
) {
    let mut batch = Vec::with_capacity(BATCH);
    let mut last_error: Option<String> = None;
    while let Ok(first) = rx.recv() {
        batch.push(first);
        while batch.len() < BATCH {
            match rx.try_recv() {
                Ok(w) => batch.push(w),
                Err(_) => break,
            }
        }
        // A lost connection is made again before the batch (each batch tries once).
        let mut unreachable = None;
        if conn.as_ref().is_none_or(|c| c.is_broken()) {
            conn = connect().map_err(|e| unreachable = Some(e)).ok();
        }
        let result = match (conn.as_deref_mut(), unreachable) {
            (Some(c), _) => write_batch(c, &batch),
            (None, why) => Err(why.unwrap_or_else(|| "the database cannot be reached".into())),
        };
        // Each new failure once (an outage fails every batch the same way).
        match &result {
            Err(e) if last_error.as_ref() != Some(e) => {
                tracing::error!("{name}: {e}");
                last_error = Some(e.clone());
            }
            Err(_) => {}
            Ok(()) => {
                if last_error.take().is_some() {
                    tracing::info!("{name}: writing again");
                }
            }
        }
        let lost = conn.as_ref().is_none_or(|c| c.is_broken());
        reachable.store(result.is_ok() || !lost, Ordering::Relaxed);
        // Acknowledge after the commit (or report the failure).
        for w in batch.drain(..) {
            match w {
                Write::Command(_, record, Some(ack)) => {
                    let _ = ack.send(match &result {
                        Ok(()) => Ok(record),
                        Err(e) => Err(EngineError::Store(e.clone())),
                    });
                }
                Write::Session(_, done) => {
                    let _ = done.send(result.clone());
                }
                Write::Flush(done) => {
                    let _ = done.send(());
                }
                _ => {}
            }
        }
    }
}

/// Columns of a `commands` row.
const COMMAND_COLUMNS: usize = 5;

fn write_batch(conn: &mut dyn Conn, batch: &[Write]) -> Result<(), String> {
    transaction(conn, |tx| {
        let mut i = 0;
        while i < batch.len() {
            // A run of commands goes in as one multi-row insert.
            let run = batch[i..]
                .iter()
                .take_while(|w| matches!(w, Write::Command(..)))
                .count();
            if run > 0 {
                let mut params = Vec::with_capacity(run * COMMAND_COLUMNS);
                for w in &batch[i..i + run] {
                    if let Write::Command(id, r, _) = w {
                        params.extend([
                            id.into(),
                            (r.ordinal as i64).into(),
                            (r.step as i64).into(),
                            (r.seq as i64).into(),
                            serde_json::to_string(&r.command).unwrap_or_default().into(),
                        ]);
                    }
                }
                tx.execute(
                    &format!(
                        "INSERT INTO commands (session_id, ordinal, step, seq, command) VALUES {}",
                        values_list(run, COMMAND_COLUMNS)
                    ),
                    &params,
                )?;
                i += run;
                continue;
            }
            match &batch[i] {
                Write::Session(s, _) => {
                    tx.execute(
                        "INSERT INTO sessions (id, label, scene_name, scene_json, base_dir,
                         created_unix_s, status, step_rate_hz, account_id, controller_hash,
                         server_id)
                         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)",
                        &[
                            (&s.id).into(),
                            (&s.label).into(),
                            (&s.scene_name).into(),
                            (&s.scene_json).into(),
                            s.base_dir.to_string_lossy().into_owned().into(),
                            s.created_unix_s.into(),
                            (&s.status).into(),
                            s.step_rate_hz.into(),
                            s.account_id.clone().into(),
                            s.controller_hash.clone().into(),
                            s.server_id.clone().into(),
                        ],
                    )?;
                }
                Write::Status(id, status) => {
                    tx.execute(
                        "UPDATE sessions SET status = ?2 WHERE id = ?1",
                        &[id.into(), (*status).into()],
                    )?;
                }
                Write::Checkpoint(id, c) => {
                    tx.execute(
                        "INSERT INTO checkpoints (session_id, step, digest, metrics)
                         VALUES (?1, ?2, ?3, ?4)
                         ON CONFLICT (session_id, step) DO UPDATE SET digest = excluded.digest,
                         metrics = excluded.metrics",
                        &[
                            id.into(),
                            (c.step as i64).into(),
                            format!("{:016x}", c.digest).into(),
                            serde_json::to_string(&c.metrics).unwrap_or_default().into(),
                        ],
                    )?;
                }
                Write::Event(id, e) => {
                    tx.execute(
                        "INSERT INTO events (session_id, step, time_s, kind, message)
                         VALUES (?1, ?2, ?3, ?4, ?5)",
                        &[
                            id.into(),
                            (e.step as i64).into(),
                            e.time_s.into(),
                            e.kind.as_str().into(),
                            (&e.message).into(),
                        ],
                    )?;
                }
                Write::Command(..) | Write::Flush(_) => {}
            }
            i += 1;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use cathlab_engine::world::Command;

    fn sqlite(name: &str) -> StoreLocation {
        let dir = std::env::temp_dir().join(format!("cathlab-store-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join(format!("{name}.sqlite"));
        let _ = std::fs::remove_file(&file);
        StoreLocation::Sqlite(file)
    }

    /// A connection beside the store's, to write what the store would not.
    fn raw(location: &StoreLocation) -> Box<dyn Conn> {
        match location {
            StoreLocation::Sqlite(file) => Box::new(SqliteConn::open(file).unwrap()),
            StoreLocation::Postgres(url) => {
                Box::new(PgTarget::parse(url).unwrap().connect().unwrap())
            }
        }
    }

    fn session(id: &str, status: &str) -> StoredSession {
        StoredSession {
            id: id.into(),
            label: String::new(),
            scene_name: "scene".into(),
            scene_json: "{}".into(),
            base_dir: PathBuf::from("."),
            created_unix_s: 0.0,
            status: status.into(),
            step_rate_hz: 500.0,
            account_id: None,
            controller_hash: None,
            server_id: None,
        }
    }

    fn the_governors_commands_are_replayed_but_not_counted(location: &StoreLocation) {
        let store = Store::at(location).unwrap();
        let commands = [
            Command::PushVelocity(0.1),
            Command::Fidelity(2),
            Command::TwistRate(1.0),
            Command::Fidelity(1),
        ];
        for (ordinal, command) in commands.iter().enumerate() {
            let record = CommandRecord {
                ordinal: ordinal as u64,
                step: 10 * ordinal as u64,
                seq: 1,
                command: *command,
            };
            Recorder::command(&store, "s1", record, None);
        }
        store.flush();
        assert_eq!(store.command_count("s1").unwrap(), 2);
        let stored: Vec<Command> = store
            .commands("s1")
            .unwrap()
            .into_iter()
            .map(|c| c.command)
            .collect();
        assert_eq!(stored, commands);
    }

    fn corrupt_rows_are_named(location: &StoreLocation) {
        let store = Store::at(location).unwrap();
        store.insert_session(session("s1", "running")).unwrap();
        let mut conn = raw(location);
        conn.execute(
            "INSERT INTO commands VALUES ('s1', 0, 5, 1, '{\"no_such_command\": 1}')",
            &[],
        )
        .unwrap();
        conn.execute(
            "INSERT INTO checkpoints VALUES ('s1', 500, 'not-hex', '{}')",
            &[],
        )
        .unwrap();
        let command = store.commands("s1").unwrap_err().to_string();
        assert!(
            command.contains("corrupt command 0 of session s1"),
            "{command}"
        );
        let checkpoint = store.checkpoints("s1").unwrap_err().to_string();
        assert!(checkpoint.contains("digest at step 500"), "{checkpoint}");
        assert_eq!(store.command_count("s1").unwrap(), 1);
        // A store opened again marks the running session interrupted.
        drop(store);
        let store = Store::at(location).unwrap();
        assert_eq!(store.session("s1").unwrap().unwrap().status, "interrupted");
        assert!(store.session("s2").unwrap().is_none());
    }

    fn stored_numbers_come_back_bit_for_bit(location: &StoreLocation) {
        // Regression: serde_json's default parser read 0.012097896199016495 back one unit in
        // the last place off (a stored score differed from the report's; a stored command
        // could replay differently).
        let store = Store::at(location).unwrap();
        let awkward = [
            0.012097896199016495,
            0.1 + 0.2,
            1.0 / 3.0,
            2.2250738585072014e-308,
        ];
        for (ordinal, v) in awkward.iter().enumerate() {
            let record = CommandRecord {
                ordinal: ordinal as u64,
                step: ordinal as u64,
                seq: 1,
                command: Command::PushVelocity(*v),
            };
            Recorder::command(&store, "s1", record, None);
        }
        store.flush();
        let back: Vec<u64> = store
            .commands("s1")
            .unwrap()
            .iter()
            .map(|c| match c.command {
                Command::PushVelocity(v) => v.to_bits(),
                _ => 0,
            })
            .collect();
        let sent: Vec<u64> = awkward.iter().map(|v| v.to_bits()).collect();
        assert_eq!(back, sent);
        // A session's numbers too (a double column, not a single-precision one).
        let mut s = session("s2", "closed");
        s.created_unix_s = 1_790_000_000.123_456_7;
        s.step_rate_hz = 1.0 / 3.0;
        store.insert_session(s.clone()).unwrap();
        assert_eq!(store.session("s2").unwrap().unwrap(), s);
    }

    fn a_batch_keeps_its_order_and_a_failed_batch_acknowledges_nothing(location: &StoreLocation) {
        let store = Store::at(location).unwrap();
        store.insert_session(session("s1", "running")).unwrap();
        let mut acks = Vec::new();
        for ordinal in 0..1500u64 {
            let (tx, rx) = tokio::sync::oneshot::channel();
            let record = CommandRecord {
                ordinal,
                step: ordinal,
                seq: ordinal,
                command: Command::PushVelocity(ordinal as f64 * 1e-3),
            };
            Recorder::command(&store, "s1", record, Some(tx));
            acks.push(rx);
        }
        store.event(
            "s1",
            &Event {
                step: 1,
                time_s: 0.002,
                kind: cathlab_engine::EventKind::Device,
                message: "first".into(),
            },
        );
        store.event(
            "s1",
            &Event {
                step: 1,
                time_s: 0.002,
                kind: cathlab_engine::EventKind::Device,
                message: "second".into(),
            },
        );
        store.set_status("s1", "closed");
        store.flush();
        for (i, ack) in acks.into_iter().enumerate() {
            assert_eq!(ack.blocking_recv().unwrap().unwrap().ordinal, i as u64);
        }
        let ordinals: Vec<u64> = store
            .commands("s1")
            .unwrap()
            .iter()
            .map(|c| c.ordinal)
            .collect();
        assert_eq!(ordinals, (0..1500).collect::<Vec<_>>());
        let events: Vec<String> = store
            .events("s1")
            .unwrap()
            .into_iter()
            .map(|e| e.3)
            .collect();
        assert_eq!(events, ["first", "second"]);
        assert_eq!(store.session("s1").unwrap().unwrap().status, "closed");
        // A command whose ordinal is already stored fails its batch (whichever other writes
        // share it): an acknowledgement says stored exactly when the command is.
        let (tx, rx) = tokio::sync::oneshot::channel();
        let (tx2, rx2) = tokio::sync::oneshot::channel();
        for (ordinal, tx) in [(1500, tx), (7, tx2)] {
            let record = CommandRecord {
                ordinal,
                step: ordinal,
                seq: 1,
                command: Command::PushVelocity(0.5),
            };
            Recorder::command(&store, "s1", record, Some(tx));
        }
        store.flush();
        let (fresh, duplicate) = (rx.blocking_recv().unwrap(), rx2.blocking_recv().unwrap());
        assert!(duplicate.is_err(), "{duplicate:?}");
        let stored = store.commands("s1").unwrap();
        assert_eq!(
            fresh.is_ok(),
            stored.iter().any(|c| c.ordinal == 1500),
            "{fresh:?}"
        );
        assert_eq!(stored[7].command, Command::PushVelocity(0.007));
    }

    /// Two servers on one store: each marks only its own sessions interrupted at start; a
    /// silent server is marked lost by the other's clock check, with its running sessions;
    /// its heartbeat brings them back; another process under its id finds them interrupted.
    fn the_fleet_registry_keeps_servers_and_their_sessions_apart(location: &StoreLocation) {
        let a = Store::for_server(location, "a").unwrap();
        let b = Store::for_server(location, "b").unwrap();
        let on = |id: &str, server: &str| StoredSession {
            server_id: Some(server.into()),
            ..session(id, "running")
        };
        a.insert_session(on("a1", "a")).unwrap();
        b.insert_session(on("b1", "b")).unwrap();
        b.insert_session(on("b2", "b")).unwrap();
        a.heartbeat("http://a:1", 4, 1).unwrap();
        b.heartbeat("http://b:1", 4, 2).unwrap();
        let servers = a.servers().unwrap();
        assert_eq!(
            servers
                .iter()
                .map(|s| (s.id.as_str(), s.address.as_str(), s.load, s.status.as_str()))
                .collect::<Vec<_>>(),
            [
                ("a", "http://a:1", 1, "serving"),
                ("b", "http://b:1", 2, "serving")
            ]
        );
        assert!(servers[0].heartbeat_unix_s >= servers[0].started_unix_s);
        let elsewhere = |s: &Store| -> Vec<String> {
            s.running_elsewhere()
                .unwrap()
                .into_iter()
                .map(|s| s.id)
                .collect::<Vec<_>>()
        };
        assert_eq!(elsewhere(&a).len(), 2);
        assert_eq!(elsewhere(&b), ["a1"]);
        // Nobody is silent for an hour: nothing lost.
        a.mark_lost(3600.0).unwrap();
        assert_eq!(b.session("b1").unwrap().unwrap().status, "running");
        // Everyone is "silent" for a negative time: both lost, with their sessions.
        a.mark_lost(-1.0).unwrap();
        assert_eq!(b.session("b1").unwrap().unwrap().status, "lost");
        assert_eq!(a.session("a1").unwrap().unwrap().status, "lost");
        assert!(a.servers().unwrap().iter().all(|s| s.status == "lost"));
        // A's heartbeat: a serves again, its session runs again; b's stay lost.
        a.heartbeat("http://a:1", 4, 1).unwrap();
        assert_eq!(a.session("a1").unwrap().unwrap().status, "running");
        assert_eq!(a.session("b2").unwrap().unwrap().status, "lost");
        // A new process as b: its lost sessions were interrupted; a's untouched.
        drop(b);
        let b = Store::for_server(location, "b").unwrap();
        assert_eq!(b.session("b1").unwrap().unwrap().status, "interrupted");
        assert_eq!(b.session("a1").unwrap().unwrap().status, "running");
        b.heartbeat("http://b:2", 4, 0).unwrap();
        assert_eq!(b.session("b2").unwrap().unwrap().status, "interrupted");
        // A clean stop.
        a.unregister().unwrap();
        let a_row = b
            .servers()
            .unwrap()
            .into_iter()
            .find(|s| s.id == "a")
            .unwrap();
        assert_eq!((a_row.status.as_str(), a_row.load), ("stopped", 0));
    }

    fn check_all(location: impl Fn(&str) -> StoreLocation) {
        the_fleet_registry_keeps_servers_and_their_sessions_apart(&location("fleet"));
        the_governors_commands_are_replayed_but_not_counted(&location("governor"));
        corrupt_rows_are_named(&location("corrupt"));
        stored_numbers_come_back_bit_for_bit(&location("bits"));
        a_batch_keeps_its_order_and_a_failed_batch_acknowledges_nothing(&location("batch"));
    }

    #[test]
    fn the_sqlite_store_records_and_reads_back() {
        check_all(sqlite);
    }

    #[test]
    fn the_postgres_store_records_and_reads_back_as_the_sqlite_one() {
        let cluster = cluster::PgCluster::start().unwrap();
        check_all(|name| StoreLocation::Postgres(cluster.database(name).unwrap()));
    }

    #[test]
    fn an_unreachable_postgres_database_never_blocks_the_recorder_and_acknowledges_nothing() {
        let cluster = cluster::PgCluster::start().unwrap();
        let location = StoreLocation::Postgres(cluster.database("outage").unwrap());
        let store = Store::with_queue(&location, LOCAL_SERVER, 16).unwrap();
        assert!(store.is_reachable());
        cluster.stop();
        let mut acks = Vec::new();
        // Far more writes than the queue holds, as the physics threads would make them.
        for step in 0..20_000u64 {
            store.checkpoint(
                "s1",
                Checkpoint {
                    step,
                    digest: step,
                    metrics: Metrics::default(),
                },
            );
            if step % 100 == 0 {
                let (tx, rx) = tokio::sync::oneshot::channel();
                let record = CommandRecord {
                    ordinal: step / 100,
                    step,
                    seq: step / 100,
                    command: Command::PushVelocity(0.0),
                };
                Recorder::command(&store, "s1", record, Some(tx));
                acks.push(rx);
            }
        }
        assert!(!store.is_reachable());
        assert!(store.refused_writes() > 0);
        for ack in acks {
            let answer = ack.blocking_recv().unwrap();
            assert!(
                answer.is_err(),
                "acknowledged while unreachable: {answer:?}"
            );
        }
        // Back again: written and acknowledged.
        cluster.restart().unwrap();
        let (tx, rx) = tokio::sync::oneshot::channel();
        let record = CommandRecord {
            ordinal: 1000,
            step: 1,
            seq: 1,
            command: Command::PushVelocity(0.0),
        };
        Recorder::command(&store, "s1", record, Some(tx));
        assert!(rx.blocking_recv().unwrap().is_ok());
        assert!(store.is_reachable());
        assert_eq!(store.commands("s1").unwrap().len(), 1);
    }

    #[test]
    fn an_old_sqlite_database_is_migrated_and_keeps_its_sessions_and_a_newer_one_is_refused() {
        let location = sqlite("old");
        let StoreLocation::Sqlite(file) = &location else {
            unreachable!()
        };
        // As the first release left it: the first schema, user_version 0, one session.
        let mut conn = SqliteConn::open(file).unwrap();
        conn.batch(sqlite::SCHEMA_V1).unwrap();
        conn.execute(
            "INSERT INTO sessions VALUES ('s1', 'old', 'scene', '{}', '.', 1.0, 'closed', 500.0)",
            &[],
        )
        .unwrap();
        drop(conn);
        let version = || {
            SqliteConn::open(file)
                .unwrap()
                .query("PRAGMA user_version", &[])
                .unwrap()[0]
                .int(0)
                .unwrap()
        };
        migrated_then_refused(&location, &|| version() as usize, &|| {
            SqliteConn::open(file)
                .unwrap()
                .batch("PRAGMA user_version = 99")
                .unwrap()
        });
    }

    #[test]
    fn an_old_postgres_database_is_migrated_and_keeps_its_sessions_and_a_newer_one_is_refused() {
        let cluster = cluster::PgCluster::start().unwrap();
        let location = StoreLocation::Postgres(cluster.database("old").unwrap());
        let raw = || {
            PgTarget::parse(&cluster.url("old"))
                .unwrap()
                .connect()
                .unwrap()
        };
        // A database at version 1, with one session.
        let mut conn = raw();
        conn.batch(&format!(
            "CREATE TABLE cathlab_schema (version BIGINT NOT NULL);
             INSERT INTO cathlab_schema VALUES (1); {}",
            postgres::MIGRATIONS[0]
        ))
        .unwrap();
        conn.execute(
            "INSERT INTO sessions VALUES ('s1', 'old', 'scene', '{}', '.', 1.0, 'closed', 500.0)",
            &[],
        )
        .unwrap();
        drop(conn);
        migrated_then_refused(
            &location,
            &|| {
                raw()
                    .query("SELECT version FROM cathlab_schema", &[])
                    .unwrap()[0]
                    .int(0)
                    .unwrap() as usize
            },
            &|| {
                raw()
                    .batch("UPDATE cathlab_schema SET version = 99")
                    .unwrap()
            },
        );
    }

    fn migrated_then_refused(
        location: &StoreLocation,
        version: &dyn Fn() -> usize,
        make_newer: &dyn Fn(),
    ) {
        let store = Store::at(location).unwrap();
        let old = store.session("s1").unwrap().unwrap();
        assert_eq!((old.label.as_str(), old.account_id), ("old", None));
        assert_eq!(version(), SCHEMA_VERSION);
        store
            .insert_account(&StoredAccount {
                id: "a1".into(),
                name: "Ada".into(),
                role: "trainee".into(),
                token_hash: "ff".into(),
                created_unix_s: 2.0,
            })
            .unwrap();
        drop(store);
        // Opening again changes nothing.
        let store = Store::at(location).unwrap();
        assert_eq!(
            store.account_by_token_hash("ff").unwrap().unwrap().name,
            "Ada"
        );
        drop(store);
        make_newer();
        let e = Store::at(location).unwrap_err().to_string();
        assert!(e.contains("schema version 99"), "{e}");
    }
}
