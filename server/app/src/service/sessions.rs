//! Sessions: the scenes to start from, sessions created (within each client's limits),
//! listed (with recorded ones a page at a time), read, closed (also when their controller
//! stayed away) and their anatomy; the shutdown that closes them all.

use std::sync::Arc;
use std::time::{Duration, Instant};

use cathlab_api::pb;
use cathlab_engine::SceneFormat;
use cathlab_engine::engine::SceneSource;
use cathlab_engine::scene::GuidanceSpec;
use cathlab_engine::session::Session;
use parking_lot::Mutex;
use tonic::{Request, Response, Status};

use super::state::{Attendance, ClientSessions, Role, SimulatorService, Tokens};
use super::wire::{bearer, checked_id, engine_status, peer_of, random_hex};
use crate::config::InlineScenes;
use crate::reports::{Caller, store_status, token_hash};
use crate::store::StoredSession;

/// Recorded sessions on a `ListSessions` page unless the caller asks for fewer.
pub const DEFAULT_PAGE_SIZE: usize = 100;

/// The most recorded sessions one `ListSessions` page holds.
pub const MAX_PAGE_SIZE: usize = 500;

/// The last session of the previous page, as `next_page_token` named it (its creation
/// time's bits in hex, a dot, its id).
fn parse_page_token(token: &str) -> Result<(f64, String), Status> {
    let bad = || Status::invalid_argument("page_token: not a next_page_token of this server");
    let (bits, id) = token.split_once('.').ok_or_else(bad)?;
    let created = f64::from_bits(u64::from_str_radix(bits, 16).map_err(|_| bad())?);
    checked_id(id).map_err(|_| bad())?;
    if !created.is_finite() {
        return Err(bad());
    }
    Ok((created, id.to_owned()))
}

/// A creation under way, counted against its client until it ends.
struct Creating {
    clients: Arc<Mutex<ClientSessions>>,
    client: String,
}

impl Drop for Creating {
    fn drop(&mut self) {
        let mut clients = self.clients.lock();
        if let Some(n) = clients.pending.get_mut(&self.client) {
            *n -= 1;
            if *n == 0 {
                clients.pending.remove(&self.client);
            }
        }
    }
}

impl SimulatorService {
    /// Counts a creation by `client` against its limits, or refuses it.
    fn creating(&self, client: &str) -> Result<Creating, Status> {
        let running: std::collections::HashSet<String> = self
            .engine
            .sessions()
            .iter()
            .map(|s| s.id().to_owned())
            .collect();
        let mut clients = self.clients.lock();
        clients.creator.retain(|id, _| running.contains(id));
        let holds = clients.creator.values().filter(|c| *c == client).count()
            + clients.pending.get(client).copied().unwrap_or(0);
        if holds >= self.max_sessions_per_client {
            return Err(Status::resource_exhausted(format!(
                "this client runs {holds} sessions, the most one client may \
                 (max_sessions_per_client); close one first"
            )));
        }
        let now = Instant::now();
        if clients.recent.len() > 10_000 {
            clients
                .recent
                .retain(|_, (since, _)| now.duration_since(*since) < Duration::from_secs(60));
        }
        let recent = clients.recent.entry(client.to_owned()).or_insert((now, 0));
        if now.duration_since(recent.0) >= Duration::from_secs(60) {
            *recent = (now, 0);
        }
        if recent.1 >= self.creations_per_minute {
            let wait = 60 - now.duration_since(recent.0).as_secs();
            return Err(Status::resource_exhausted(format!(
                "this client created {} sessions this minute, the most it may \
                 (session_creations_per_minute); retry in {wait} s",
                recent.1
            )));
        }
        recent.1 += 1;
        *clients.pending.entry(client.to_owned()).or_insert(0) += 1;
        Ok(Creating {
            clients: self.clients.clone(),
            client: client.to_owned(),
        })
    }

    /// Closes the running session `id`: the engine stops it, the store marks it closed, its
    /// tokens end, and a trainee's report is made in the background.
    async fn close(&self, id: &str) -> Result<Arc<Session>, Status> {
        let engine = self.engine.clone();
        let closing = id.to_owned();
        let session = tokio::task::spawn_blocking(move || engine.close(&closing))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(engine_status)?;
        self.store.set_status(id, "closed");
        self.store.flush();
        self.tokens.write().remove(id);
        self.attendance.lock().remove(id);
        self.holds.lock().retain(|(s, _), _| s != id);
        // A trainee's session: its report, made now in the background, so that the history
        // and the learning curve have its scores (an anonymous session's report is made when
        // someone asks for it).
        if let Ok(Some(stored)) = self.store.session(id)
            && stored.account_id.is_some()
        {
            let reports = self.reports.clone();
            tokio::spawn(async move {
                if let Err(e) = reports.get(&stored).await {
                    tracing::info!(session = %stored.id, "report not made at close: {}", e.message());
                }
            });
        }
        Ok(session)
    }

    /// Closes the running sessions whose controller has been away longer than the unattended
    /// timeout (no stream open with the controller token, no call with it), as their
    /// controller's CloseSession would; returns their ids. A session this service did not
    /// create counts as attended until now.
    pub async fn close_unattended(&self) -> Vec<String> {
        let Some(timeout) = self.unattended_timeout else {
            return Vec::new();
        };
        let running: Vec<String> = self
            .engine
            .sessions()
            .iter()
            .map(|s| s.id().to_owned())
            .collect();
        let now = Instant::now();
        let away: Vec<(String, Duration)> = {
            let mut attendance = self.attendance.lock();
            attendance.retain(|id, _| running.contains(id));
            running
                .iter()
                .filter_map(|id| {
                    let a = attendance.entry(id.clone()).or_insert(Attendance {
                        streams: 0,
                        last: now,
                    });
                    let away = now.saturating_duration_since(a.last);
                    (a.streams == 0 && away > timeout).then(|| (id.clone(), away))
                })
                .collect()
        };
        let mut closed = Vec::new();
        for (id, away) in away {
            match self.close(&id).await {
                Ok(_) => {
                    tracing::info!(
                        session = %id,
                        away_s = away.as_secs(),
                        "closed: its controller was away longer than the unattended timeout"
                    );
                    closed.push(id);
                }
                Err(e) => {
                    tracing::warn!(session = %id, "closing an unattended session: {}", e.message())
                }
            }
        }
        closed
    }

    /// Closes every session and waits for the store (graceful shutdown).
    pub fn shutdown(&self) {
        for s in self.engine.sessions() {
            self.store.set_status(s.id(), "closed");
        }
        self.engine.shutdown();
        self.store.flush();
    }
}

impl SimulatorService {
    /// `ListScenes`: the listed scenes, the device catalogue and the default scene.
    pub(super) async fn list_scenes(
        &self,
        _: Request<pb::ListScenesRequest>,
    ) -> Result<Response<pb::ListScenesResponse>, Status> {
        let scenes = self
            .engine
            .catalog()
            .scenes()
            .iter()
            .map(|(s, _)| pb::SceneSummary {
                name: s.name.clone(),
                description: s.description.clone(),
                devices: s.devices.iter().map(|d| d.label()).collect(),
                has_flow: s.flow.is_some(),
                target: s.target.branch.clone(),
                stack: s
                    .stack
                    .iter()
                    .map(|e| pb::StackInstrument {
                        device: e.label(),
                        inserted_mm: e.inserted_mm,
                    })
                    .collect(),
                spares: s.spares.iter().map(|e| e.label()).collect(),
            })
            .collect();
        let catalogue = cathlab_engine::scene::catalogue()
            .entries()
            .iter()
            .map(|e| {
                let tip = e.device.sections.last().map(|s| s.cross_section);
                pb::CatalogueDevice {
                    id: e.id.clone(),
                    name: e.device.name.clone(),
                    kind: format!("{:?}", e.kind),
                    length_mm: e.device.length_m() * 1e3,
                    outer_diameter_mm: tip.map_or(0.0, |c| 2e3 * c.outer_radius_m),
                    inner_diameter_mm: tip.map_or(0.0, |c| 2e3 * c.inner_radius_m),
                }
            })
            .collect();
        Ok(Response::new(pb::ListScenesResponse {
            scenes,
            catalogue,
            default_scene: self.default_scene.clone(),
        }))
    }

    /// `CreateSession`: a session from a listed scene (or an inline one, as
    /// `inline_scenes` allows), recorded, with its controller and observer tokens.
    pub(super) async fn create_session(
        &self,
        request: Request<pb::CreateSessionRequest>,
    ) -> Result<Response<pb::CreateSessionResponse>, Status> {
        let caller = self.caller(&request)?;
        let instructor = caller.is_instructor();
        let account_id = match &caller {
            Caller::Account(a) => Some(a.id.clone()),
            _ => None,
        };
        let client = match &account_id {
            Some(a) => format!("account {a}"),
            None => format!("address {}", peer_of(&request)),
        };
        let creating = if instructor {
            None
        } else {
            Some(self.creating(&client)?)
        };
        let r = request.into_inner();
        let inline = matches!(
            r.scene,
            Some(
                pb::create_session_request::Scene::SceneToml(_)
                    | pb::create_session_request::Scene::SceneJson(_)
            )
        );
        match (inline, self.inline_scenes) {
            (true, InlineScenes::Off) => {
                return Err(Status::permission_denied(
                    "scene: this server takes only its listed scenes (inline scenes are off)",
                ));
            }
            (true, InlineScenes::Instructors) if !instructor => {
                return Err(Status::permission_denied(
                    "scene: an inline scene needs the instructor key (or a listed scene)",
                ));
            }
            _ => {}
        }
        let source = match r.scene {
            Some(pb::create_session_request::Scene::SceneName(name)) => SceneSource::Named(name),
            Some(pb::create_session_request::Scene::SceneToml(text)) => {
                SceneSource::Inline(text, SceneFormat::Toml)
            }
            Some(pb::create_session_request::Scene::SceneJson(text)) => {
                SceneSource::Inline(text, SceneFormat::Json)
            }
            None => return Err(Status::invalid_argument("scene: missing")),
        };
        if r.label.len() > 200 {
            return Err(Status::invalid_argument("label: longer than 200 bytes"));
        }
        let (mut spec, base) = self.engine.scene(&source).map_err(engine_status)?;
        if r.assessment {
            spec.guidance = GuidanceSpec::off();
        }
        let id = random_hex(16);
        let tokens = Tokens {
            controller: random_hex(24),
            observer: random_hex(24),
        };
        let engine = self.engine.clone();
        let (label, session_id) = (r.label.clone(), id.clone());
        let spec_for_load = spec.clone();
        let base_for_load = base.clone();
        let session = tokio::task::spawn_blocking(move || {
            engine.create(session_id, label, &spec_for_load, &base_for_load)
        })
        .await
        .map_err(|e| Status::internal(e.to_string()))?
        .map_err(engine_status)?;
        self.store
            .insert_session(StoredSession {
                id: id.clone(),
                label: r.label,
                scene_name: spec.name.clone(),
                scene_json: serde_json::to_string(&spec)
                    .map_err(|e| Status::internal(format!("scene: {e}")))?,
                base_dir: base,
                created_unix_s: session.created_unix_s(),
                status: "running".into(),
                step_rate_hz: spec.fidelity.step_rate_hz,
                account_id,
                controller_hash: Some(token_hash(&tokens.controller)),
                server_id: Some(self.store.server_id().to_owned()),
            })
            .map_err(|e| {
                tracing::warn!("recording a new session: {e}");
                Status::unavailable("the session store cannot be written; try again shortly")
            })?;
        self.tokens.write().insert(id.clone(), tokens.clone());
        if let Some(creating) = creating {
            self.clients.lock().creator.insert(id.clone(), client);
            drop(creating);
        }
        self.attended(&id, 0);
        tracing::info!(session = %id, scene = %spec.name, "session created");
        Ok(Response::new(pb::CreateSessionResponse {
            session_id: id,
            controller_token: tokens.controller,
            observer_token: tokens.observer,
            info: Some(self.info_of(&session)),
        }))
    }

    /// `ListSessions` (instructors): the running sessions here and on the fleet's other
    /// servers, and a page of the recorded ones when asked for.
    pub(super) async fn list_sessions(
        &self,
        request: Request<pb::ListSessionsRequest>,
    ) -> Result<Response<pb::ListSessionsResponse>, Status> {
        if !self.instructor(&request)? {
            return Err(Status::permission_denied(
                "listing sessions needs the instructor key",
            ));
        }
        let page_size = match request.get_ref().page_size {
            0 => DEFAULT_PAGE_SIZE,
            n => (n as usize).min(MAX_PAGE_SIZE),
        };
        let after = match request.get_ref().page_token.as_str() {
            "" => None,
            token => Some(parse_page_token(token)?),
        };
        let first_page = after.is_none();
        let tokens = self.tokens.read().clone();
        let mut sessions: Vec<pb::SessionInfo> = self
            .engine
            .sessions()
            .iter()
            .map(|s| pb::SessionInfo {
                observer_token: tokens
                    .get(s.id())
                    .map(|t| t.observer.clone())
                    .unwrap_or_default(),
                ..self.info_of(s)
            })
            .collect();
        // The fleet's other servers' running sessions always (with where they run), the
        // recorded ones when asked for.
        sessions.extend(self.fleet_sessions()?);
        if !first_page {
            sessions.clear();
        }
        let mut next_page_token = String::new();
        if request.get_ref().include_recorded {
            let listed: std::collections::HashSet<String> =
                sessions.iter().map(|s| s.session_id.clone()).collect();
            let (page, more) = self
                .store
                .sessions_page(after, page_size)
                .map_err(store_status)?;
            if more && let Some(last) = page.last() {
                next_page_token = format!("{:x}.{}", last.created_unix_s.to_bits(), last.id);
            }
            for stored in &page {
                if !listed.contains(&stored.id) {
                    sessions.push(self.stored_info(stored)?);
                }
            }
        }
        Ok(Response::new(pb::ListSessionsResponse {
            sessions,
            next_page_token,
        }))
    }

    /// `GetSession`: a running session (any of its tokens) or a recorded one (instructors).
    pub(super) async fn get_session(
        &self,
        request: Request<pb::GetSessionRequest>,
    ) -> Result<Response<pb::SessionInfo>, Status> {
        let id = checked_id(&request.get_ref().session_id)?.to_owned();
        if let Ok(session) = self.engine.get(&id) {
            self.authorize(peer_of(&request), bearer(&request).as_deref(), &id, false)?;
            return Ok(Response::new(self.info_of(&session)));
        }
        // A recorded session (closed, or from before a restart): instructors only.
        let stored = self
            .store
            .session(&id)
            .map_err(store_status)?
            .ok_or_else(|| Status::not_found(format!("session {id:?}")))?;
        if !self.instructor(&request)? {
            return Err(Status::permission_denied(
                "recorded sessions are for the instructor key",
            ));
        }
        Ok(Response::new(self.stored_info(&stored)?))
    }

    /// `CloseSession`: the session's controller or an instructor closes it.
    pub(super) async fn close_session(
        &self,
        request: Request<pb::CloseSessionRequest>,
    ) -> Result<Response<pb::CloseSessionResponse>, Status> {
        let id = request.get_ref().session_id.clone();
        let role = self.authorize(peer_of(&request), bearer(&request).as_deref(), &id, false)?;
        if role == Role::Observer {
            return Err(Status::permission_denied(
                "an observer cannot close a session",
            ));
        }
        let session = self.close(&id).await?;
        Ok(Response::new(pb::CloseSessionResponse {
            info: Some(self.info_of(&session)),
        }))
    }

    /// `GetAnatomy`: the session's vessels (centerlines, radii, lumen mesh) in patient LPS
    /// (mm), its access point and its target.
    pub(super) async fn get_anatomy(
        &self,
        request: Request<pb::GetAnatomyRequest>,
    ) -> Result<Response<pb::Anatomy>, Status> {
        let session = self.readable(&request, &request.get_ref().session_id)?;
        let assets = session.assets();
        let to_lps = |p: &nalgebra::Point3<f64>| {
            let v = assets.to_lps * p.coords;
            [v.x as f32 * 1e3, v.y as f32 * 1e3, v.z as f32 * 1e3]
        };
        let graph = &assets.anatomy.graph;
        let branches = graph
            .branches
            .iter()
            .map(|b| pb::Branch {
                name: b.name.clone(),
                points_mm: b.points.iter().flat_map(to_lps).collect(),
                radii_mm: b.radii.iter().map(|r| *r as f32 * 1e3).collect(),
            })
            .collect();
        let mesh = assets.anatomy.lumen.mesh();
        let access = assets.point_to_lps(&assets.entry.0) * 1e3;
        Ok(Response::new(pb::Anatomy {
            branches,
            vertices_mm: mesh.vertices.iter().flat_map(to_lps).collect(),
            triangles: mesh
                .triangles
                .iter()
                .flat_map(|t| t.iter().copied())
                .collect(),
            access_mm: Some(pb::Vec3 {
                x: access.x,
                y: access.y,
                z: access.z,
            }),
            target: assets.spec.target.branch.clone(),
        }))
    }
}
