//! Retention: ended sessions deleted with everything recorded of them, by count (anonymous
//! ones) and by age.

use super::Store;
use super::records::StoreError;
use super::sql::{Value, transaction};

impl Store {
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
}

/// Now, in seconds since the Unix epoch.
fn unix_now_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}
