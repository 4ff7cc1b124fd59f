//! The recorded sessions and what was recorded of each: the sessions (all, a page, one),
//! their events, commands (in application order) and checkpoints, and how many commands one
//! has.

use cathlab_engine::{Checkpoint, CommandRecord, Metrics};

use super::Store;
use super::records::{SELECT_SESSION, StoreError, StoredSession, row_to_session};

impl Store {
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
