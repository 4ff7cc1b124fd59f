//! `SessionInfo` as the handlers answer it: of a running session (from the engine), and of a
//! recorded one (from the store).

use cathlab_api::{metrics_to_wire, pb, timing_to_wire};
use cathlab_engine::SceneSpec;
use cathlab_engine::session::Session;
use tonic::Status;

use super::state::SimulatorService;
use super::wire::guidance_to_wire;
use crate::reports::store_status;
use crate::store::StoredSession;

impl SimulatorService {
    pub(super) fn info_of(&self, session: &Session) -> pb::SessionInfo {
        let state = session.state().borrow().clone();
        pb::SessionInfo {
            session_id: session.id().to_owned(),
            scene_name: session.assets().spec.name.clone(),
            label: session.label().to_owned(),
            status: if session.is_running() {
                pb::SessionStatus::Running
            } else {
                pb::SessionStatus::Closed
            } as i32,
            created_unix_s: session.created_unix_s(),
            step_rate_hz: session.assets().spec.fidelity.step_rate_hz,
            metrics: Some(metrics_to_wire(&state.metrics)),
            timing: Some(timing_to_wire(&session.timing().summary())),
            commands: session.commands_recorded(),
            active_device: state.active_device,
            observer_token: String::new(),
            guidance: Some(guidance_to_wire(&session.assets().spec.guidance)),
            server_address: String::new(),
        }
    }

    pub(super) fn stored_info(&self, s: &StoredSession) -> Result<pb::SessionInfo, Status> {
        let metrics = self
            .store
            .last_checkpoint(&s.id)
            .map_err(store_status)?
            .map(|c| metrics_to_wire(&c.metrics));
        Ok(pb::SessionInfo {
            session_id: s.id.clone(),
            scene_name: s.scene_name.clone(),
            label: s.label.clone(),
            status: match s.status.as_str() {
                "running" => pb::SessionStatus::Running,
                "closed" => pb::SessionStatus::Closed,
                "lost" => pb::SessionStatus::Lost,
                _ => pb::SessionStatus::Interrupted,
            } as i32,
            created_unix_s: s.created_unix_s,
            step_rate_hz: s.step_rate_hz,
            metrics,
            timing: None,
            commands: self.store.command_count(&s.id).map_err(store_status)?,
            active_device: 0,
            observer_token: String::new(),
            guidance: serde_json::from_str::<SceneSpec>(&s.scene_json)
                .ok()
                .map(|spec| guidance_to_wire(&spec.guidance)),
            server_address: String::new(),
        })
    }
}
