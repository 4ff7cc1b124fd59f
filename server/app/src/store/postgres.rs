//! The PostgreSQL backend (the fleet's shared store): connections with timeouts, the schema's
//! migrations (versioned in a `cathlab_schema` table, applied under an advisory lock so that
//! servers starting together migrate once), and a small pool of reader threads (the `postgres`
//! client blocks on a runtime of its own, which must not run on the server's async threads).

use std::collections::HashMap;
use std::str::FromStr;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use bytes::BytesMut;
use postgres::types::{IsNull, ToSql, Type, to_sql_checked};
use postgres::{Client, Config, NoTls, Statement};

use super::sql::{Conn, Row, Value};

/// The schema's migrations, in order (the same versions as SQLite's): migration `i` takes a
/// database at version `i` to `i + 1`.
pub const MIGRATIONS: [&str; 3] = [SCHEMA_V1, SCHEMA_V2, SCHEMA_V3];

const SCHEMA_V1: &str = "
CREATE TABLE sessions (
    id TEXT PRIMARY KEY, label TEXT NOT NULL, scene_name TEXT NOT NULL,
    scene_json TEXT NOT NULL, base_dir TEXT NOT NULL,
    created_unix_s DOUBLE PRECISION NOT NULL, status TEXT NOT NULL,
    step_rate_hz DOUBLE PRECISION NOT NULL);
CREATE TABLE commands (
    session_id TEXT NOT NULL, ordinal BIGINT NOT NULL, step BIGINT NOT NULL,
    seq BIGINT NOT NULL, command TEXT NOT NULL, PRIMARY KEY (session_id, ordinal));
CREATE TABLE checkpoints (
    session_id TEXT NOT NULL, step BIGINT NOT NULL, digest TEXT NOT NULL,
    metrics TEXT NOT NULL, PRIMARY KEY (session_id, step));
CREATE TABLE events (
    id BIGINT GENERATED ALWAYS AS IDENTITY PRIMARY KEY, session_id TEXT NOT NULL,
    step BIGINT NOT NULL, time_s DOUBLE PRECISION NOT NULL, kind TEXT NOT NULL,
    message TEXT NOT NULL);
CREATE INDEX events_by_session ON events (session_id, id);
";

const SCHEMA_V2: &str = "
CREATE TABLE accounts (
    id TEXT PRIMARY KEY, name TEXT NOT NULL, role TEXT NOT NULL,
    token_hash TEXT NOT NULL UNIQUE, created_unix_s DOUBLE PRECISION NOT NULL);
ALTER TABLE sessions ADD COLUMN account_id TEXT REFERENCES accounts(id);
ALTER TABLE sessions ADD COLUMN controller_hash TEXT;
CREATE INDEX sessions_by_account ON sessions (account_id, created_unix_s);
CREATE TABLE reports (
    session_id TEXT PRIMARY KEY, version BIGINT NOT NULL, json TEXT NOT NULL,
    metrics TEXT NOT NULL, within BIGINT NOT NULL, judged BIGINT NOT NULL);
CREATE TABLE report_frames (
    session_id TEXT NOT NULL, idx BIGINT NOT NULL, time_s DOUBLE PRECISION NOT NULL,
    png BYTEA NOT NULL, PRIMARY KEY (session_id, idx));
";

const SCHEMA_V3: &str = "
CREATE TABLE servers (
    id TEXT PRIMARY KEY, address TEXT NOT NULL, capacity BIGINT NOT NULL,
    load BIGINT NOT NULL, started_unix_s DOUBLE PRECISION NOT NULL,
    heartbeat_unix_s DOUBLE PRECISION NOT NULL, status TEXT NOT NULL);
ALTER TABLE sessions ADD COLUMN server_id TEXT;
CREATE INDEX sessions_by_server ON sessions (server_id, status);
";

/// The advisory lock the migrations hold ("cathlab" in ASCII).
const MIGRATION_LOCK: i64 = 0x0063_6174_686c_6162;

/// A parsed database URL, and how it is named in messages (never with its password).
#[derive(Clone)]
pub struct PgTarget {
    config: Config,
    /// `postgres://user@host:port/db`.
    pub name: String,
}

impl std::fmt::Debug for PgTarget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name)
    }
}

impl PgTarget {
    /// Parses a `postgres://` or `postgresql://` URL; the error names what is wrong.
    pub fn parse(url: &str) -> Result<Self, String> {
        if !(url.starts_with("postgres://") || url.starts_with("postgresql://")) {
            return Err(format!(
                "the database URL must start with postgres:// or postgresql:// (got {:?})",
                url.split("://").next().unwrap_or_default()
            ));
        }
        let mut config = Config::from_str(url)
            .map_err(|e| format!("the database URL does not parse: {}", chain(&e)))?;
        if config.get_hosts().is_empty() {
            return Err("the database URL names no host".into());
        }
        if config.get_connect_timeout().is_none() {
            config.connect_timeout(Duration::from_secs(5));
        }
        // A server that stops answering is noticed in seconds, not at the kernel's default
        // retransmission timeout (minutes).
        config
            .keepalives(true)
            .keepalives_idle(Duration::from_secs(5))
            .tcp_user_timeout(Duration::from_secs(10))
            .application_name("cathlab-server");
        let hosts: Vec<String> = config
            .get_hosts()
            .iter()
            .map(|h| match h {
                postgres::config::Host::Tcp(h) => h.clone(),
                #[cfg(unix)]
                postgres::config::Host::Unix(p) => p.display().to_string(),
            })
            .collect();
        let ports: Vec<String> = config.get_ports().iter().map(u16::to_string).collect();
        let name = format!(
            "postgres://{}@{}:{}/{}",
            config.get_user().unwrap_or(""),
            hosts.join(","),
            if ports.is_empty() {
                "5432".to_owned()
            } else {
                ports.join(",")
            },
            config.get_dbname().unwrap_or("")
        );
        Ok(Self { config, name })
    }

    /// A new connection.
    pub fn connect(&self) -> Result<PgConn, String> {
        let client = self
            .config
            .connect(NoTls)
            .map_err(|e| format!("cannot connect: {}", chain(&e)))?;
        Ok(PgConn {
            client,
            statements: HashMap::new(),
        })
    }
}

/// An error and its causes, in one line (`postgres::Error`'s own text is only "db error").
fn chain(e: &postgres::Error) -> String {
    if let Some(db) = e.as_db_error() {
        let mut s = format!("{}: {}", db.severity(), db.message());
        if let Some(detail) = db.detail() {
            s.push_str(&format!(" ({detail})"));
        }
        return s;
    }
    let mut s = e.to_string();
    let mut source = std::error::Error::source(e);
    while let Some(cause) = source {
        s.push_str(&format!(": {cause}"));
        source = cause.source();
    }
    s
}

/// A connection, with its prepared statements.
pub struct PgConn {
    client: Client,
    statements: HashMap<String, Statement>,
}

/// SQLite's `?N` placeholders as PostgreSQL's `$N`.
fn placeholders(sql: &str) -> String {
    let bytes = sql.as_bytes();
    let mut out = String::with_capacity(sql.len());
    for (i, c) in sql.char_indices() {
        if c == '?' && bytes.get(i + 1).is_some_and(u8::is_ascii_digit) {
            out.push('$');
        } else {
            out.push(c);
        }
    }
    out
}

impl ToSql for Value {
    fn to_sql(
        &self,
        ty: &Type,
        out: &mut BytesMut,
    ) -> Result<IsNull, Box<dyn std::error::Error + Sync + Send>> {
        // Each value is written as the type the statement's parameter has.
        match (self, ty) {
            (Value::Null, _) => Ok(IsNull::Yes),
            (Value::Int(v), &Type::INT4) => i32::try_from(*v)?.to_sql(ty, out),
            (Value::Int(v), &Type::INT2) => i16::try_from(*v)?.to_sql(ty, out),
            (Value::Int(v), &Type::FLOAT8) => (*v as f64).to_sql(ty, out),
            (Value::Int(v), _) => v.to_sql(ty, out),
            (Value::Real(v), &Type::FLOAT4) => (*v as f32).to_sql(ty, out),
            (Value::Real(v), _) => v.to_sql(ty, out),
            (Value::Text(v), _) => v.to_sql(ty, out),
            (Value::Blob(v), _) => v.to_sql(ty, out),
        }
    }

    fn accepts(_: &Type) -> bool {
        true
    }

    to_sql_checked!();
}

fn column(row: &postgres::Row, i: usize) -> Result<Value, postgres::Error> {
    let ty = row.columns()[i].type_();
    Ok(match *ty {
        Type::INT8 => row
            .try_get::<_, Option<i64>>(i)?
            .map_or(Value::Null, Value::Int),
        Type::INT4 => row
            .try_get::<_, Option<i32>>(i)?
            .map_or(Value::Null, |v| Value::Int(v.into())),
        Type::INT2 => row
            .try_get::<_, Option<i16>>(i)?
            .map_or(Value::Null, |v| Value::Int(v.into())),
        Type::BOOL => row
            .try_get::<_, Option<bool>>(i)?
            .map_or(Value::Null, |v| Value::Int(v.into())),
        Type::FLOAT8 => row
            .try_get::<_, Option<f64>>(i)?
            .map_or(Value::Null, Value::Real),
        Type::FLOAT4 => row
            .try_get::<_, Option<f32>>(i)?
            .map_or(Value::Null, |v| Value::Real(v.into())),
        Type::BYTEA => row
            .try_get::<_, Option<Vec<u8>>>(i)?
            .map_or(Value::Null, Value::Blob),
        _ => row
            .try_get::<_, Option<String>>(i)?
            .map_or(Value::Null, Value::Text),
    })
}

impl PgConn {
    fn statement(&mut self, sql: &str) -> Result<Statement, String> {
        if let Some(s) = self.statements.get(sql) {
            return Ok(s.clone());
        }
        let prepared = self
            .client
            .prepare(&placeholders(sql))
            .map_err(|e| chain(&e))?;
        // The multi-row inserts come in many sizes: keep the cache from growing without end.
        if self.statements.len() >= 256 {
            self.statements.clear();
        }
        self.statements.insert(sql.to_owned(), prepared.clone());
        Ok(prepared)
    }

    /// Brings the database to the newest schema in one transaction, under an advisory lock
    /// (servers of a fleet starting together migrate once). A database of a newer version is
    /// refused rather than guessed at.
    pub fn migrate(&mut self) -> Result<(), String> {
        let mut tx = self.client.transaction().map_err(|e| chain(&e))?;
        tx.execute("SELECT pg_advisory_xact_lock($1)", &[&MIGRATION_LOCK])
            .map_err(|e| chain(&e))?;
        tx.batch_execute("CREATE TABLE IF NOT EXISTS cathlab_schema (version BIGINT NOT NULL)")
            .map_err(|e| chain(&e))?;
        let version: i64 = match tx
            .query_opt("SELECT version FROM cathlab_schema", &[])
            .map_err(|e| chain(&e))?
        {
            Some(row) => row.try_get(0).map_err(|e| chain(&e))?,
            None => {
                tx.execute("INSERT INTO cathlab_schema (version) VALUES (0)", &[])
                    .map_err(|e| chain(&e))?;
                0
            }
        };
        if version < 0 || version as usize > MIGRATIONS.len() {
            return Err(format!(
                "schema version {version}; this server knows up to {}",
                MIGRATIONS.len()
            ));
        }
        for (i, sql) in MIGRATIONS.iter().enumerate().skip(version as usize) {
            tx.batch_execute(sql)
                .map_err(|e| format!("migration to schema version {}: {}", i + 1, chain(&e)))?;
            tx.execute("UPDATE cathlab_schema SET version = $1", &[&(i as i64 + 1)])
                .map_err(|e| chain(&e))?;
        }
        tx.commit().map_err(|e| chain(&e))
    }
}

fn bind(params: &[Value]) -> Vec<&(dyn ToSql + Sync)> {
    params.iter().map(|p| p as &(dyn ToSql + Sync)).collect()
}

impl Conn for PgConn {
    fn query(&mut self, sql: &str, params: &[Value]) -> Result<Vec<Row>, String> {
        let statement = self.statement(sql)?;
        let rows = self
            .client
            .query(&statement, &bind(params))
            .map_err(|e| chain(&e))?;
        rows.iter()
            .map(|r| {
                (0..r.len())
                    .map(|i| column(r, i))
                    .collect::<Result<Vec<_>, _>>()
                    .map(Row)
                    .map_err(|e| chain(&e))
            })
            .collect()
    }

    fn execute(&mut self, sql: &str, params: &[Value]) -> Result<u64, String> {
        let statement = self.statement(sql)?;
        self.client
            .execute(&statement, &bind(params))
            .map_err(|e| chain(&e))
    }

    fn batch(&mut self, sql: &str) -> Result<(), String> {
        self.client.batch_execute(sql).map_err(|e| chain(&e))
    }

    fn is_broken(&self) -> bool {
        self.client.is_closed()
    }
}

type Job = Box<dyn FnOnce(Result<&mut PgConn, String>) + Send>;

/// Reader threads, each with a connection made when first needed and made again when lost.
pub struct PgReaders {
    jobs: SyncSender<Job>,
    threads: usize,
}

impl PgReaders {
    /// `threads` readers of `target`.
    pub fn new(target: PgTarget, threads: usize) -> Result<Self, String> {
        let (tx, rx) = sync_channel::<Job>(64);
        let rx = Arc::new(Mutex::new(rx));
        for i in 0..threads.max(1) {
            let (rx, target) = (rx.clone(), target.clone());
            std::thread::Builder::new()
                .name(format!("store-reader-{i}"))
                .spawn(move || reader_loop(&rx, &target))
                .map_err(|e| format!("cannot start a store reader: {e}"))?;
        }
        Ok(Self {
            jobs: tx,
            threads: threads.max(1),
        })
    }

    /// Runs `f` on a reader's connection and waits for its answer. A reader learns that its
    /// connection was closed (the database restarted since its last job) only when a query
    /// fails on it: `f` then runs again, on a new connection (as many times as there are
    /// readers, each of which may hold such a connection), so `f` must be safe to repeat.
    pub fn run<T: Send + 'static>(
        &self,
        f: impl Fn(&mut dyn Conn) -> Result<T, String> + Send + Sync + 'static,
    ) -> Result<T, String> {
        let f = Arc::new(f);
        let mut tries = 0;
        loop {
            tries += 1;
            let g = f.clone();
            match self.once(move |c| g(c))? {
                (Err(_), true) if tries <= self.threads => continue,
                (answer, _) => return answer,
            }
        }
    }

    /// Runs `f` once: its answer, and whether it left the reader's connection closed.
    fn once<T: Send + 'static>(
        &self,
        f: impl FnOnce(&mut dyn Conn) -> Result<T, String> + Send + 'static,
    ) -> Result<(Result<T, String>, bool), String> {
        let (tx, rx) = std::sync::mpsc::channel();
        let job: Job = Box::new(move |conn| {
            let _ = tx.send(match conn {
                Ok(c) => {
                    let answer = f(c);
                    (answer, c.is_broken())
                }
                Err(e) => (Err(e), false),
            });
        });
        self.jobs
            .send(job)
            .map_err(|_| "the store's readers have stopped".to_owned())?;
        rx.recv()
            .map_err(|_| "a store reader stopped without an answer".to_owned())
    }
}

fn reader_loop(jobs: &Mutex<Receiver<Job>>, target: &PgTarget) {
    let mut conn: Option<PgConn> = None;
    loop {
        let job = match jobs.lock() {
            Ok(rx) => match rx.recv() {
                Ok(job) => job,
                Err(_) => return,
            },
            Err(_) => return,
        };
        if conn.as_ref().is_none_or(|c| c.is_broken()) {
            conn = None;
            match target.connect() {
                Ok(c) => conn = Some(c),
                Err(e) => {
                    job(Err(e));
                    continue;
                }
            }
        }
        if let Some(c) = conn.as_mut() {
            job(Ok(c));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placeholders_are_rewritten_and_question_marks_in_text_are_not() {
        assert_eq!(
            placeholders("SELECT a FROM t WHERE b = ?1 AND c = ?12 AND d = '?'"),
            "SELECT a FROM t WHERE b = $1 AND c = $12 AND d = '?'"
        );
    }

    #[test]
    fn database_urls_are_checked_and_never_named_with_their_password() {
        let t = PgTarget::parse("postgres://cathlab:s3cret@db.example:6543/fleet").unwrap();
        assert_eq!(t.name, "postgres://cathlab@db.example:6543/fleet");
        assert!(!format!("{t:?}").contains("s3cret"));
        let e = PgTarget::parse("mysql://root@db/cathlab").unwrap_err();
        assert!(e.contains("must start with postgres://"), "{e}");
        let e = PgTarget::parse("postgres://db:notaport/x").unwrap_err();
        assert!(e.contains("does not parse"), "{e}");
    }
}
