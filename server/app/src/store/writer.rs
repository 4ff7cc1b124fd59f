//! The writer thread: the writes the physics threads queue, batched into transactions (a run
//! of commands in one multi-row insert), committed, then acknowledged; the connection made
//! again after it is lost, and whether the database can be reached.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Receiver;

use cathlab_engine::session::Ack;
use cathlab_engine::{Checkpoint, CommandRecord, EngineError, Event};

use super::records::StoredSession;
use super::sql::{Conn, transaction, values_list};

pub(super) enum Write {
    Session(StoredSession, std::sync::mpsc::Sender<Result<(), String>>),
    Status(String, &'static str),
    Command(String, CommandRecord, Option<Ack>),
    Checkpoint(String, Checkpoint),
    Event(String, Event),
    Flush(std::sync::mpsc::Sender<()>),
}

/// Makes a writer's connection, migrating the schema to current (again, after one is lost).
pub(super) type Connect = Box<dyn Fn() -> Result<Box<dyn Conn>, String> + Send>;

/// Most writes in one transaction.
const BATCH: usize = 512;

/// Writes the physics threads may queue ahead of the writer.
pub(super) const QUEUE: usize = 1 << 16;

pub(super) fn writer_loop(
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
