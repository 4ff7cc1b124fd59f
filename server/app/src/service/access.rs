//! Who may do what: the caller behind a request's bearer token (the instructor key, an
//! account, a session's controller or observer token), the throttle of wrong guesses, and the
//! running sessions a caller may read or command.

use std::net::IpAddr;
use std::sync::Arc;

use cathlab_engine::session::Session;
use tonic::{Request, Status};

use super::state::{Attending, Role, SimulatorService};
use super::wire::{bearer, checked_id, engine_status, peer_of};
use crate::auth::same_secret;
use crate::reports::{AccountRole, Caller, token_hash};
use crate::store::StoredAccount;

impl SimulatorService {
    fn is_instructor_key(&self, token: Option<&str>) -> bool {
        matches!((token, &self.instructor_key), (Some(t), Some(k)) if same_secret(t, k))
    }

    /// The instructor key or an instructor account's token.
    fn is_instructor(&self, token: Option<&str>) -> bool {
        self.is_instructor_key(token)
            || token.is_some_and(|t| {
                matches!(self.account_of(t), Some(a) if a.role == AccountRole::Instructor.as_str())
            })
    }

    /// The account `token` belongs to (a store error reads as none).
    fn account_of(&self, token: &str) -> Option<StoredAccount> {
        self.store
            .account_by_token_hash(&token_hash(token))
            .ok()
            .flatten()
    }

    /// Who the request comes from. An address that guessed wrong too often is refused.
    pub(super) fn caller<T>(&self, request: &Request<T>) -> Result<Caller, Status> {
        let token = bearer(request);
        // An account's token is random (nothing to guess): never throttled.
        if let Some(account) = token.as_deref().and_then(|t| self.account_of(t)) {
            return Ok(Caller::Account(account));
        }
        self.throttle.check(peer_of(request))?;
        Ok(if self.is_instructor_key(token.as_deref()) {
            Caller::InstructorKey
        } else {
            Caller::Other(token)
        })
    }

    /// Whether the caller is an instructor (the key or an instructor account). An address
    /// that guessed wrong too often is refused; a token of nobody counts as a guess.
    pub(super) fn instructor<T>(&self, request: &Request<T>) -> Result<bool, Status> {
        let caller = self.caller(request)?;
        if let Caller::Other(Some(_)) = caller {
            self.throttle
                .failed(peer_of(request), "a wrong instructor key");
        }
        Ok(caller.is_instructor())
    }

    /// Checks the caller's bearer token for `session_id`: NOT_FOUND for an unknown session,
    /// UNAUTHENTICATED without a valid token, PERMISSION_DENIED when reading is not enough.
    pub(super) fn authorize(
        &self,
        peer: IpAddr,
        token: Option<&str>,
        session_id: &str,
        control: bool,
    ) -> Result<Role, Status> {
        checked_id(session_id)?;
        let known = self.tokens.read().get(session_id).cloned();
        // The session's own tokens first: a controller's every command and stream is checked
        // here, and only a token that is neither reads the account store.
        let own = match (token, known.as_ref()) {
            (Some(t), Some(k)) if same_secret(t, &k.controller) => Some(Role::Controller),
            (Some(t), Some(k)) if same_secret(t, &k.observer) => Some(Role::Observer),
            _ => None,
        };
        // A session's own token (random, 192 bits: nothing to guess) is never throttled, so
        // that a trainee's stop or close goes through while someone at the same address
        // (behind the same proxy) guesses; everything else is refused once the address has
        // used up its guesses.
        if own.is_none() {
            self.throttle.check(peer)?;
        }
        let role = if let Some(role) = own {
            role
        } else if self.is_instructor(token) {
            Role::Instructor
        } else {
            if known.is_none() {
                return Err(Status::not_found(format!("session {session_id:?}")));
            }
            match token {
                Some(_) => {
                    self.throttle.failed(peer, "a token of no session");
                    return Err(Status::unauthenticated(format!(
                        "the token is not one of session {session_id:?}"
                    )));
                }
                None => {
                    return Err(Status::unauthenticated(
                        "missing `authorization: Bearer <token>` metadata",
                    ));
                }
            }
        };
        // A command keeps a session attended; a read does not (a client holding sessions
        // with one cheap GetSession each would keep them from everyone).
        if control && role == Role::Controller {
            self.attended(session_id, 0);
        }
        if control && role != Role::Controller {
            return Err(Status::permission_denied(format!(
                "{} may watch session {session_id:?} but not command it",
                match role {
                    Role::Observer => "an observer",
                    _ => "an instructor",
                }
            )));
        }
        Ok(role)
    }

    pub(super) fn session(&self, id: &str) -> Result<Arc<Session>, Status> {
        self.engine.get(id).map_err(engine_status)
    }

    /// The running session `id` if the request's token may read it.
    pub(super) fn readable<T>(
        &self,
        request: &Request<T>,
        id: &str,
    ) -> Result<Arc<Session>, Status> {
        self.authorize(peer_of(request), bearer(request).as_deref(), id, false)?;
        self.session(id)
    }

    /// The running session `id` if the request's token may read it, and the guard that
    /// counts the stream as its controller's while it lives (see [`Self::attending`]).
    pub(super) fn watched<T>(
        &self,
        request: &Request<T>,
        id: &str,
    ) -> Result<(Arc<Session>, Option<Attending>), Status> {
        let role = self.authorize(peer_of(request), bearer(request).as_deref(), id, false)?;
        let session = self.session(id)?;
        Ok((session, self.attending(id, role)))
    }
}
