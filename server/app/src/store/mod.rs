//! The store: sessions, every applied command with its step, checkpoints (state digest and
//! metrics), events, accounts and reports, in SQLite (the embedded default: one file) or
//! PostgreSQL (shared by a fleet of servers). One writer thread batches what the physics
//! threads hand it into transactions and acknowledges commands only after their transaction
//! commits. The queries are written once, over [`sql::Conn`]; each backend keeps its own
//! versioned migrations. This file owns the [`Store`] itself: opening it, the writer's queue
//! and the read connections the queries in the files beside it run on.

mod accounts;
pub mod cluster;
mod fleet;
pub mod postgres;
mod records;
mod reports;
mod retention;
mod sessions;
pub mod sql;
pub mod sqlite;
#[cfg(test)]
mod tests;
mod writer;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;

use cathlab_engine::session::Ack;
use cathlab_engine::{Checkpoint, CommandRecord, EngineError, Event, Recorder};

use self::postgres::{PgReaders, PgTarget};
pub use self::records::{
    StoreError, StoreLocation, StoredAccount, StoredReport, StoredServer, StoredSession,
};
use self::sql::{Conn, Dialect, Row, Value, transaction};
use self::sqlite::SqliteConn;
use self::writer::{Connect, QUEUE, Write, writer_loop};

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

    /// This store's server id.
    pub fn server_id(&self) -> &str {
        &self.server_id
    }
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

/// The server id of a store used by one server alone.
pub const LOCAL_SERVER: &str = "local";
