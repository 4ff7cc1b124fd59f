//! The embedded SQLite store: sessions, every applied command with its step, checkpoints
//! (state digest and metrics), events. One writer thread batches what the physics threads
//! hand it into transactions and acknowledges commands only after their transaction commits
//! (WAL mode: a commit survives the process being killed). Reads open their own connections.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;

use cathlab_engine::session::Ack;
use cathlab_engine::{Checkpoint, CommandRecord, EngineError, Event, Metrics, Recorder};
use rusqlite::{Connection, params};

/// Store errors.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// SQLite refused something.
    #[error("{file}: {source}")]
    Sqlite {
        /// The database.
        file: PathBuf,
        /// The cause.
        source: rusqlite::Error,
    },
    /// A stored value does not parse.
    #[error("{file}: corrupt {what}: {reason}")]
    Corrupt {
        /// The database.
        file: PathBuf,
        /// Which value.
        what: String,
        /// Why.
        reason: String,
    },
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

/// The store: a writer thread and the database file.
pub struct Store {
    file: PathBuf,
    writes: SyncSender<Write>,
    _writer: JoinHandle<()>,
}

impl std::fmt::Debug for Store {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Store").field("file", &self.file).finish()
    }
}

/// The schema's migrations, in order: migration `i` takes a database at version `i` (SQLite's
/// `user_version`) to `i + 1`, in one transaction. A database made before migrations existed
/// is at version 0 with the first migration's tables: its `IF NOT EXISTS` keeps them.
const MIGRATIONS: [&str; 2] = [SCHEMA_V1, SCHEMA_V2];

const SCHEMA_V2: &str = "
CREATE TABLE accounts (
    id TEXT PRIMARY KEY, name TEXT NOT NULL, role TEXT NOT NULL,
    token_hash TEXT NOT NULL UNIQUE, created_unix_s REAL NOT NULL);
ALTER TABLE sessions ADD COLUMN account_id TEXT REFERENCES accounts(id);
ALTER TABLE sessions ADD COLUMN controller_hash TEXT;
CREATE INDEX sessions_by_account ON sessions (account_id, created_unix_s);
CREATE TABLE reports (
    session_id TEXT PRIMARY KEY, version INTEGER NOT NULL, json TEXT NOT NULL,
    metrics TEXT NOT NULL, within INTEGER NOT NULL, judged INTEGER NOT NULL);
CREATE TABLE report_frames (
    session_id TEXT NOT NULL, idx INTEGER NOT NULL, time_s REAL NOT NULL, png BLOB NOT NULL,
    PRIMARY KEY (session_id, idx));
";

const SCHEMA_V1: &str = "
CREATE TABLE IF NOT EXISTS sessions (
    id TEXT PRIMARY KEY, label TEXT NOT NULL, scene_name TEXT NOT NULL,
    scene_json TEXT NOT NULL, base_dir TEXT NOT NULL, created_unix_s REAL NOT NULL,
    status TEXT NOT NULL, step_rate_hz REAL NOT NULL);
CREATE TABLE IF NOT EXISTS commands (
    session_id TEXT NOT NULL, ordinal INTEGER NOT NULL, step INTEGER NOT NULL,
    seq INTEGER NOT NULL, command TEXT NOT NULL, PRIMARY KEY (session_id, ordinal));
CREATE TABLE IF NOT EXISTS checkpoints (
    session_id TEXT NOT NULL, step INTEGER NOT NULL, digest TEXT NOT NULL,
    metrics TEXT NOT NULL, PRIMARY KEY (session_id, step));
CREATE TABLE IF NOT EXISTS events (
    session_id TEXT NOT NULL, step INTEGER NOT NULL, time_s REAL NOT NULL,
    kind TEXT NOT NULL, message TEXT NOT NULL);
";

/// The schema version this build writes.
pub const SCHEMA_VERSION: usize = MIGRATIONS.len();

/// Brings the database to [`SCHEMA_VERSION`], one transaction per migration. A database of a
/// newer version (a newer server wrote it) is refused rather than guessed at.
fn migrate(conn: &Connection) -> rusqlite::Result<()> {
    let version: i64 = conn.query_row("PRAGMA user_version", [], |r| r.get(0))?;
    if version < 0 || version as usize > MIGRATIONS.len() {
        return Err(rusqlite::Error::InvalidParameterName(format!(
            "schema version {version}; this server knows up to {}",
            MIGRATIONS.len()
        )));
    }
    for (i, sql) in MIGRATIONS.iter().enumerate().skip(version as usize) {
        conn.execute_batch(&format!(
            "BEGIN; {sql}; PRAGMA user_version = {}; COMMIT;",
            i + 1
        ))
        .inspect_err(|_| {
            let _ = conn.execute_batch("ROLLBACK");
        })?;
    }
    Ok(())
}

fn open(file: &Path) -> Result<Connection, StoreError> {
    let sqlite = |source| StoreError::Sqlite {
        file: file.to_owned(),
        source,
    };
    let conn = Connection::open(file).map_err(sqlite)?;
    conn.pragma_update(None, "journal_mode", "WAL")
        .map_err(sqlite)?;
    // In WAL mode NORMAL syncs at checkpoints, not at every commit: a commit survives the
    // process being killed (it is in the WAL file) but not a power cut before the next sync.
    conn.pragma_update(None, "synchronous", "NORMAL")
        .map_err(sqlite)?;
    conn.busy_timeout(std::time::Duration::from_secs(5))
        .map_err(sqlite)?;
    Ok(conn)
}

impl Store {
    /// Opens (or creates) the database, marks sessions left running by a previous process as
    /// interrupted, and starts the writer.
    pub fn open(file: &Path) -> Result<Self, StoreError> {
        let conn = open(file)?;
        let sqlite = |source| StoreError::Sqlite {
            file: file.to_owned(),
            source,
        };
        migrate(&conn).map_err(sqlite)?;
        conn.execute(
            "UPDATE sessions SET status = 'interrupted' WHERE status = 'running'",
            [],
        )
        .map_err(sqlite)?;
        let (tx, rx) = sync_channel(1 << 16);
        let path = file.to_owned();
        let writer = std::thread::Builder::new()
            .name("store-writer".into())
            .spawn(move || writer_loop(conn, rx, path))
            .map_err(|e| StoreError::Corrupt {
                file: file.to_owned(),
                what: "writer thread".into(),
                reason: e.to_string(),
            })?;
        Ok(Self {
            file: file.to_owned(),
            writes: tx,
            _writer: writer,
        })
    }

    fn push(&self, write: Write) {
        match self.writes.try_send(write) {
            Ok(()) => {}
            // The writer is behind by 65,536 writes: wait rather than lose one.
            Err(TrySendError::Full(w)) => {
                let _ = self.writes.send(w);
            }
            Err(TrySendError::Disconnected(w)) => {
                if let Write::Command(_, _, Some(ack)) = w {
                    let _ = ack.send(Err(EngineError::Store("the store is closed".into())));
                }
            }
        }
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

    fn sqlite(&self) -> impl Fn(rusqlite::Error) -> StoreError + '_ {
        |source| StoreError::Sqlite {
            file: self.file.clone(),
            source,
        }
    }

    /// The rows of `sql` with `parameters`, mapped by `row`, on a fresh read connection (WAL
    /// lets reads run beside the writer).
    fn rows<T>(
        &self,
        sql: &str,
        parameters: impl rusqlite::Params,
        row: impl FnMut(&rusqlite::Row<'_>) -> rusqlite::Result<T>,
    ) -> Result<Vec<T>, StoreError> {
        let conn = open(&self.file)?;
        let mut stmt = conn.prepare(sql).map_err(self.sqlite())?;
        stmt.query_map(parameters, row)
            .map_err(self.sqlite())?
            .collect::<Result<Vec<_>, _>>()
            .map_err(self.sqlite())
    }

    fn corrupt(&self, what: String, reason: impl std::fmt::Display) -> StoreError {
        StoreError::Corrupt {
            file: self.file.clone(),
            what,
            reason: reason.to_string(),
        }
    }

    /// Every stored session, newest first.
    pub fn sessions(&self) -> Result<Vec<StoredSession>, StoreError> {
        self.rows(
            &format!("{SELECT_SESSION} ORDER BY created_unix_s DESC"),
            (),
            row_to_session,
        )
    }

    /// One stored session.
    pub fn session(&self, id: &str) -> Result<Option<StoredSession>, StoreError> {
        Ok(self
            .rows(
                &format!("{SELECT_SESSION} WHERE id = ?1"),
                [id],
                row_to_session,
            )?
            .pop())
    }

    /// A session's recorded events in order: (step, simulated time s, kind, message).
    pub fn events(&self, id: &str) -> Result<Vec<(u64, f64, String, String)>, StoreError> {
        self.rows(
            "SELECT step, time_s, kind, message FROM events WHERE session_id = ?1
             ORDER BY rowid",
            [id],
            |r| {
                Ok((
                    r.get::<_, i64>(0)?.max(0) as u64,
                    r.get(1)?,
                    r.get(2)?,
                    r.get(3)?,
                ))
            },
        )
    }

    /// A session's commands in application order.
    pub fn commands(&self, id: &str) -> Result<Vec<CommandRecord>, StoreError> {
        let rows = self.rows(
            "SELECT ordinal, step, seq, command FROM commands WHERE session_id = ?1
             ORDER BY ordinal",
            [id],
            |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, i64>(2)?,
                    r.get::<_, String>(3)?,
                ))
            },
        )?;
        rows.into_iter()
            .map(|(ordinal, step, seq, json)| {
                Ok(CommandRecord {
                    ordinal: ordinal as u64,
                    step: step as u64,
                    seq: seq as u64,
                    command: serde_json::from_str(&json).map_err(|e| {
                        self.corrupt(format!("command {ordinal} of session {id}"), e)
                    })?,
                })
            })
            .collect()
    }

    fn checkpoint_rows(&self, id: &str, order_limit: &str) -> Result<Vec<Checkpoint>, StoreError> {
        let rows = self.rows(
            &format!(
                "SELECT step, digest, metrics FROM checkpoints WHERE session_id = ?1 {order_limit}"
            ),
            [id],
            |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, String>(2)?,
                ))
            },
        )?;
        rows.into_iter()
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

    /// A write on a connection of its own (accounts and reports: rare, and not on the
    /// physics threads' path).
    fn write(&self, sql: &str, parameters: impl rusqlite::Params) -> Result<usize, StoreError> {
        open(&self.file)?
            .execute(sql, parameters)
            .map_err(self.sqlite())
    }

    /// Adds an account.
    pub fn insert_account(&self, a: &StoredAccount) -> Result<(), StoreError> {
        self.write(
            "INSERT INTO accounts (id, name, role, token_hash, created_unix_s)
             VALUES (?1, ?2, ?3, ?4, ?5)",
            params![a.id, a.name, a.role, a.token_hash, a.created_unix_s],
        )
        .map(|_| ())
    }

    /// The account whose token hashes to `token_hash`.
    pub fn account_by_token_hash(
        &self,
        token_hash: &str,
    ) -> Result<Option<StoredAccount>, StoreError> {
        Ok(self
            .rows(
                &format!("{SELECT_ACCOUNT} WHERE token_hash = ?1"),
                [token_hash],
                row_to_account,
            )?
            .pop())
    }

    /// One account.
    pub fn account(&self, id: &str) -> Result<Option<StoredAccount>, StoreError> {
        Ok(self
            .rows(
                &format!("{SELECT_ACCOUNT} WHERE id = ?1"),
                [id],
                row_to_account,
            )?
            .pop())
    }

    /// Every account, oldest first.
    pub fn accounts(&self) -> Result<Vec<StoredAccount>, StoreError> {
        self.rows(
            &format!("{SELECT_ACCOUNT} ORDER BY created_unix_s"),
            (),
            row_to_account,
        )
    }

    /// An account's sessions, oldest first.
    pub fn sessions_of(&self, account_id: &str) -> Result<Vec<StoredSession>, StoreError> {
        self.rows(
            &format!("{SELECT_SESSION} WHERE account_id = ?1 ORDER BY created_unix_s"),
            [account_id],
            row_to_session,
        )
    }

    /// A session's stored report, if any.
    pub fn report(&self, session_id: &str) -> Result<Option<StoredReport>, StoreError> {
        let rows = self.rows(
            "SELECT version, json, metrics, within, judged FROM reports WHERE session_id = ?1",
            [session_id],
            |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, String>(2)?,
                    r.get::<_, i64>(3)?,
                    r.get::<_, i64>(4)?,
                ))
            },
        )?;
        rows.into_iter()
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
        let mut conn = open(&self.file)?;
        let tx = conn.transaction().map_err(self.sqlite())?;
        let run = || -> rusqlite::Result<()> {
            tx.execute(
                "DELETE FROM report_frames WHERE session_id = ?1",
                [session_id],
            )?;
            tx.execute(
                "INSERT OR REPLACE INTO reports (session_id, version, json, metrics, within,
                 judged) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
                params![
                    session_id,
                    report.version,
                    json,
                    metrics,
                    within,
                    report.verdicts.len() as i64
                ],
            )?;
            for (i, f) in report.frames.iter().enumerate() {
                tx.execute(
                    "INSERT INTO report_frames (session_id, idx, time_s, png)
                     VALUES (?1, ?2, ?3, ?4)",
                    params![session_id, i as i64, f.time_s, f.png],
                )?;
            }
            Ok(())
        };
        run().map_err(self.sqlite())?;
        tx.commit().map_err(self.sqlite())
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
                params![session_id, index],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )?
            .pop())
    }

    /// How many commands a session has recorded.
    pub fn command_count(&self, id: &str) -> Result<u64, StoreError> {
        let counts = self.rows(
            // The operator's commands: the overload governor's fidelity changes are recorded
            // for replay but are not the trainee's.
            "SELECT COUNT(*) FROM commands WHERE session_id = ?1 \
             AND command NOT LIKE '{\"fidelity\"%'",
            [id],
            |r| r.get::<_, i64>(0),
        )?;
        Ok(counts.first().copied().unwrap_or(0) as u64)
    }
}

const SELECT_SESSION: &str = "SELECT id, label, scene_name, scene_json, base_dir, \
    created_unix_s, status, step_rate_hz, account_id, controller_hash FROM sessions";

fn row_to_session(r: &rusqlite::Row<'_>) -> rusqlite::Result<StoredSession> {
    Ok(StoredSession {
        id: r.get(0)?,
        label: r.get(1)?,
        scene_name: r.get(2)?,
        scene_json: r.get(3)?,
        base_dir: PathBuf::from(r.get::<_, String>(4)?),
        created_unix_s: r.get(5)?,
        status: r.get(6)?,
        step_rate_hz: r.get(7)?,
        account_id: r.get(8)?,
        controller_hash: r.get(9)?,
    })
}

const SELECT_ACCOUNT: &str = "SELECT id, name, role, token_hash, created_unix_s FROM accounts";

fn row_to_account(r: &rusqlite::Row<'_>) -> rusqlite::Result<StoredAccount> {
    Ok(StoredAccount {
        id: r.get(0)?,
        name: r.get(1)?,
        role: r.get(2)?,
        token_hash: r.get(3)?,
        created_unix_s: r.get(4)?,
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

fn writer_loop(mut conn: Connection, rx: Receiver<Write>, file: PathBuf) {
    let mut batch = Vec::with_capacity(BATCH);
    while let Ok(first) = rx.recv() {
        batch.push(first);
        while batch.len() < BATCH {
            match rx.try_recv() {
                Ok(w) => batch.push(w),
                Err(_) => break,
            }
        }
        let result = write_batch(&mut conn, &batch);
        if let Err(e) = &result {
            tracing::error!("{}: {e}", file.display());
        }
        // Acknowledge after the commit (or report the failure).
        for w in batch.drain(..) {
            match w {
                Write::Command(_, record, Some(ack)) => {
                    let _ = ack.send(match &result {
                        Ok(()) => Ok(record),
                        Err(e) => Err(EngineError::Store(e.to_string())),
                    });
                }
                Write::Session(_, done) => {
                    let _ = done.send(result.as_ref().map(|_| ()).map_err(|e| e.to_string()));
                }
                Write::Flush(done) => {
                    let _ = done.send(());
                }
                _ => {}
            }
        }
    }
}

fn write_batch(conn: &mut Connection, batch: &[Write]) -> rusqlite::Result<()> {
    let tx = conn.transaction()?;
    for w in batch {
        match w {
            Write::Session(s, _) => {
                tx.execute(
                    "INSERT INTO sessions (id, label, scene_name, scene_json, base_dir,
                     created_unix_s, status, step_rate_hz, account_id, controller_hash)
                     VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
                    params![
                        s.id,
                        s.label,
                        s.scene_name,
                        s.scene_json,
                        s.base_dir.to_string_lossy(),
                        s.created_unix_s,
                        s.status,
                        s.step_rate_hz,
                        s.account_id,
                        s.controller_hash
                    ],
                )?;
            }
            Write::Status(id, status) => {
                tx.execute(
                    "UPDATE sessions SET status = ?2 WHERE id = ?1",
                    params![id, status],
                )?;
            }
            Write::Command(id, r, _) => {
                tx.execute(
                    "INSERT INTO commands (session_id, ordinal, step, seq, command)
                     VALUES (?1, ?2, ?3, ?4, ?5)",
                    params![
                        id,
                        r.ordinal as i64,
                        r.step as i64,
                        r.seq as i64,
                        serde_json::to_string(&r.command).unwrap_or_default()
                    ],
                )?;
            }
            Write::Checkpoint(id, c) => {
                tx.execute(
                    "INSERT OR REPLACE INTO checkpoints (session_id, step, digest, metrics)
                     VALUES (?1, ?2, ?3, ?4)",
                    params![
                        id,
                        c.step as i64,
                        format!("{:016x}", c.digest),
                        serde_json::to_string(&c.metrics).unwrap_or_default()
                    ],
                )?;
            }
            Write::Event(id, e) => {
                tx.execute(
                    "INSERT INTO events (session_id, step, time_s, kind, message)
                     VALUES (?1, ?2, ?3, ?4, ?5)",
                    params![id, e.step as i64, e.time_s, e.kind.as_str(), e.message],
                )?;
            }
            Write::Flush(_) => {}
        }
    }
    tx.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_governors_commands_are_replayed_but_not_counted_as_the_operators() {
        use cathlab_engine::world::Command;
        let dir = std::env::temp_dir().join(format!("cathlab-store-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("governor.sqlite");
        let _ = std::fs::remove_file(&file);
        let store = Store::open(&file).unwrap();
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

    #[test]
    fn corrupt_rows_are_named_not_trusted() {
        let dir = std::env::temp_dir().join(format!("cathlab-store-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("corrupt.sqlite");
        let _ = std::fs::remove_file(&file);
        let store = Store::open(&file).unwrap();
        store
            .insert_session(StoredSession {
                id: "s1".into(),
                label: String::new(),
                scene_name: "scene".into(),
                scene_json: "{}".into(),
                base_dir: PathBuf::from("."),
                created_unix_s: 0.0,
                status: "running".into(),
                step_rate_hz: 500.0,
                account_id: None,
                controller_hash: None,
            })
            .unwrap();
        let conn = open(&file).unwrap();
        conn.execute(
            "INSERT INTO commands VALUES ('s1', 0, 5, 1, '{\"no_such_command\": 1}')",
            [],
        )
        .unwrap();
        conn.execute(
            "INSERT INTO checkpoints VALUES ('s1', 500, 'not-hex', '{}')",
            [],
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
        let store = Store::open(&file).unwrap();
        assert_eq!(store.session("s1").unwrap().unwrap().status, "interrupted");
        assert!(store.session("s2").unwrap().is_none());
    }

    #[test]
    fn stored_numbers_come_back_bit_for_bit() {
        // Regression: serde_json's default parser read 0.012097896199016495 back one unit in
        // the last place off (a stored score differed from the report's; a stored command
        // could replay differently).
        use cathlab_engine::world::Command;
        let dir = std::env::temp_dir().join(format!("cathlab-store-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("bits.sqlite");
        let _ = std::fs::remove_file(&file);
        let store = Store::open(&file).unwrap();
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
    }

    #[test]
    fn an_old_database_is_migrated_and_keeps_its_sessions_and_a_newer_one_is_refused() {
        let dir = std::env::temp_dir().join(format!("cathlab-store-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("old.sqlite");
        let _ = std::fs::remove_file(&file);
        // As the first release left it: the first schema, user_version 0, one session.
        let conn = Connection::open(&file).unwrap();
        conn.execute_batch(SCHEMA_V1).unwrap();
        conn.execute(
            "INSERT INTO sessions VALUES ('s1', 'old', 'scene', '{}', '.', 1.0, 'closed', 500.0)",
            [],
        )
        .unwrap();
        drop(conn);
        let store = Store::open(&file).unwrap();
        let old = store.session("s1").unwrap().unwrap();
        assert_eq!((old.label.as_str(), old.account_id), ("old", None));
        let version: i64 = open(&file)
            .unwrap()
            .query_row("PRAGMA user_version", [], |r| r.get(0))
            .unwrap();
        assert_eq!(version as usize, SCHEMA_VERSION);
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
        let store = Store::open(&file).unwrap();
        assert_eq!(
            store.account_by_token_hash("ff").unwrap().unwrap().name,
            "Ada"
        );
        drop(store);
        open(&file)
            .unwrap()
            .execute_batch("PRAGMA user_version = 99")
            .unwrap();
        let e = Store::open(&file).unwrap_err().to_string();
        assert!(e.contains("schema version 99"), "{e}");
    }
}
