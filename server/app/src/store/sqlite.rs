//! The SQLite backend (the embedded default): connections in WAL mode and the schema's
//! migrations, versioned by SQLite's `user_version`.

use std::path::Path;

use rusqlite::Connection;
use rusqlite::types::Value as SqlValue;

use super::sql::{Conn, Row, Value};

/// The schema's migrations, in order: migration `i` takes a database at version `i` (SQLite's
/// `user_version`) to `i + 1`, in one transaction. A database made before migrations existed
/// is at version 0 with the first migration's tables: its `IF NOT EXISTS` keeps them.
pub const MIGRATIONS: [&str; 3] = [SCHEMA_V1, SCHEMA_V2, SCHEMA_V3];

/// The first release's tables.
pub const SCHEMA_V1: &str = "
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

/// The fleet: servers sharing the store, and which runs each session.
const SCHEMA_V3: &str = "
CREATE TABLE servers (
    id TEXT PRIMARY KEY, address TEXT NOT NULL, capacity INTEGER NOT NULL,
    load INTEGER NOT NULL, started_unix_s REAL NOT NULL, heartbeat_unix_s REAL NOT NULL,
    status TEXT NOT NULL);
ALTER TABLE sessions ADD COLUMN server_id TEXT;
CREATE INDEX sessions_by_server ON sessions (server_id, status);
CREATE INDEX events_by_session ON events (session_id);
";

/// A connection to a SQLite file, and the file it opened (device and inode): a connection
/// whose file was removed or replaced under it is broken (it would go on writing into a file
/// no one can read again).
pub struct SqliteConn(Connection, std::path::PathBuf, Option<(u64, u64)>);

/// The device and inode of `file`.
fn identity(file: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(file).ok().map(|m| (m.dev(), m.ino()))
}

impl SqliteConn {
    /// Opens (or creates) `file` in WAL mode.
    pub fn open(file: &Path) -> Result<Self, String> {
        Self::open_with(file, true)
    }

    /// Opens `file` in WAL mode, which must exist: a database removed under a running server
    /// is not made again empty.
    pub fn open_existing(file: &Path) -> Result<Self, String> {
        Self::open_with(file, false)
    }

    fn open_with(file: &Path, create: bool) -> Result<Self, String> {
        use rusqlite::OpenFlags;
        let mut flags = OpenFlags::SQLITE_OPEN_READ_WRITE
            | OpenFlags::SQLITE_OPEN_URI
            | OpenFlags::SQLITE_OPEN_NO_MUTEX;
        if create {
            flags |= OpenFlags::SQLITE_OPEN_CREATE;
        } else if !file.is_file() {
            return Err("the database file is gone (removed while the server ran)".into());
        }
        let conn = Connection::open_with_flags(file, flags).map_err(|e| e.to_string())?;
        conn.pragma_update(None, "journal_mode", "WAL")
            .map_err(|e| e.to_string())?;
        // In WAL mode NORMAL syncs at checkpoints, not at every commit: a commit survives the
        // process being killed (it is in the WAL file) but not a power cut before the next
        // sync.
        conn.pragma_update(None, "synchronous", "NORMAL")
            .map_err(|e| e.to_string())?;
        conn.busy_timeout(std::time::Duration::from_secs(5))
            .map_err(|e| e.to_string())?;
        Ok(Self(conn, file.to_owned(), identity(file)))
    }

    /// Brings the database to the newest schema, one transaction per migration. A database
    /// of a newer version (a newer server wrote it) is refused rather than guessed at.
    pub fn migrate(&mut self) -> Result<(), String> {
        let version: i64 = self
            .0
            .query_row("PRAGMA user_version", [], |r| r.get(0))
            .map_err(|e| e.to_string())?;
        if version < 0 || version as usize > MIGRATIONS.len() {
            return Err(format!(
                "schema version {version}; this server knows up to {}",
                MIGRATIONS.len()
            ));
        }
        for (i, sql) in MIGRATIONS.iter().enumerate().skip(version as usize) {
            self.0
                .execute_batch(&format!(
                    "BEGIN; {sql}; PRAGMA user_version = {}; COMMIT;",
                    i + 1
                ))
                .map_err(|e| {
                    let _ = self.0.execute_batch("ROLLBACK");
                    format!("migration to schema version {}: {e}", i + 1)
                })?;
        }
        Ok(())
    }
}

fn to_sql(v: &Value) -> SqlValue {
    match v {
        Value::Null => SqlValue::Null,
        Value::Int(i) => SqlValue::Integer(*i),
        Value::Real(r) => SqlValue::Real(*r),
        Value::Text(t) => SqlValue::Text(t.clone()),
        Value::Blob(b) => SqlValue::Blob(b.clone()),
    }
}

fn from_sql(v: SqlValue) -> Value {
    match v {
        SqlValue::Null => Value::Null,
        SqlValue::Integer(i) => Value::Int(i),
        SqlValue::Real(r) => Value::Real(r),
        SqlValue::Text(t) => Value::Text(t),
        SqlValue::Blob(b) => Value::Blob(b),
    }
}

impl Conn for SqliteConn {
    fn query(&mut self, sql: &str, params: &[Value]) -> Result<Vec<Row>, String> {
        let mut stmt = self.0.prepare_cached(sql).map_err(|e| e.to_string())?;
        let columns = stmt.column_count();
        let params: Vec<SqlValue> = params.iter().map(to_sql).collect();
        stmt.query_map(rusqlite::params_from_iter(params), |r| {
            (0..columns)
                .map(|i| r.get::<_, SqlValue>(i).map(from_sql))
                .collect::<rusqlite::Result<Vec<_>>>()
                .map(Row)
        })
        .map_err(|e| e.to_string())?
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| e.to_string())
    }

    fn execute(&mut self, sql: &str, params: &[Value]) -> Result<u64, String> {
        let mut stmt = self.0.prepare_cached(sql).map_err(|e| e.to_string())?;
        let params: Vec<SqlValue> = params.iter().map(to_sql).collect();
        stmt.execute(rusqlite::params_from_iter(params))
            .map(|n| n as u64)
            .map_err(|e| e.to_string())
    }

    fn batch(&mut self, sql: &str) -> Result<(), String> {
        self.0.execute_batch(sql).map_err(|e| e.to_string())
    }

    fn is_broken(&self) -> bool {
        identity(&self.1) != self.2
    }
}
