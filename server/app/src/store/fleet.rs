//! The fleet's registry in the store: each server's heartbeat (address, capacity, load),
//! servers that stopped beating and their sessions marked lost, the servers, and the sessions
//! other servers run.

use super::Store;
use super::records::{
    SELECT_SERVER, SELECT_SESSION, StoreError, StoredServer, StoredSession, row_to_server,
    row_to_session,
};
use super::sql::Value;

impl Store {
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
}
