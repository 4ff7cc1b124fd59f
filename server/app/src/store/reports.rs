//! Reports: a session's stored report (header and scores, the JSON) and its replay frames,
//! written in one transaction.

use super::Store;
use super::records::{StoreError, StoredReport};

impl Store {
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
}
