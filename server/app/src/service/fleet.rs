//! The fleet as the service shows it: the sessions the fleet's other servers run, each with
//! the address of its server, beside this server's own in `ListSessions`.

use cathlab_api::pb;
use tonic::Status;

use super::state::SimulatorService;
use crate::reports::store_status;

impl SimulatorService {
    /// The running sessions of the fleet's other servers that still beat, each with its
    /// server's address (those of a server that stopped beating are left out).
    pub(super) fn fleet_sessions(&self) -> Result<Vec<pb::SessionInfo>, Status> {
        let mut sessions = Vec::new();
        let elsewhere = self.store.running_elsewhere().map_err(store_status)?;
        if !elsewhere.is_empty() {
            let servers: std::collections::HashMap<String, String> = self
                .store
                .servers()
                .map_err(store_status)?
                .into_iter()
                .filter(|s| s.status == "serving")
                .map(|s| (s.id, s.address))
                .collect();
            for stored in &elsewhere {
                // A server that stopped beating is about to be marked lost: its sessions are
                // not listed live meanwhile (nothing could be streamed from it).
                let Some(server_address) = stored
                    .server_id
                    .as_ref()
                    .and_then(|id| servers.get(id).cloned())
                else {
                    continue;
                };
                sessions.push(pb::SessionInfo {
                    server_address,
                    ..self.stored_info(stored)?
                });
            }
        }
        Ok(sessions)
    }
}
