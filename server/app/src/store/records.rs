//! What the store holds and answers with: where it is, its errors, stored sessions, servers,
//! accounts and reports, and how each is read from its row.

use std::path::PathBuf;

use super::sql::Row;

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

pub(super) const SELECT_SESSION: &str = "SELECT id, label, scene_name, scene_json, base_dir, \
    created_unix_s, status, step_rate_hz, account_id, controller_hash, server_id FROM sessions";

pub(super) fn row_to_session(r: &Row) -> Result<StoredSession, String> {
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

pub(super) const SELECT_SERVER: &str = "SELECT id, address, capacity, load, started_unix_s, \
    heartbeat_unix_s, status FROM servers";

pub(super) fn row_to_server(r: &Row) -> Result<StoredServer, String> {
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

pub(super) const SELECT_ACCOUNT: &str =
    "SELECT id, name, role, token_hash, created_unix_s FROM accounts";

pub(super) fn row_to_account(r: &Row) -> Result<StoredAccount, String> {
    Ok(StoredAccount {
        id: r.text(0)?,
        name: r.text(1)?,
        role: r.text(2)?,
        token_hash: r.text(3)?,
        created_unix_s: r.real(4)?,
    })
}
