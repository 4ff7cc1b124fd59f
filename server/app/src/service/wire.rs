//! What the handlers share that needs no service state: the response stream type, the
//! caller's bearer token and address, session id checks, engine errors as statuses, random
//! tokens, the clock, and guidance and accounts as the wire has them.

use std::net::IpAddr;
use std::pin::Pin;
use std::time::{SystemTime, UNIX_EPOCH};

use cathlab_api::{pb, status_of};
use cathlab_engine::EngineError;
use cathlab_engine::scene::GuidanceSpec;
use tokio_stream::Stream;
use tonic::{Request, Status};

use crate::connections;
use crate::store::StoredAccount;

/// A boxed response stream.
pub type ResponseStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send + 'static>>;

/// The caller's address (unspecified for in-process callers).
pub(super) fn peer_of<T>(request: &Request<T>) -> IpAddr {
    connections::address(request)
}

pub(super) fn bearer<T>(request: &Request<T>) -> Option<String> {
    let value = request.metadata().get("authorization")?.to_str().ok()?;
    value
        .strip_prefix("Bearer ")
        .or_else(|| value.strip_prefix("bearer "))
        .map(|t| t.trim().to_owned())
}

/// `id` if it can be a session id (at most 64 letters, digits, `-` or `_`); else
/// INVALID_ARGUMENT that says what it is without echoing it.
pub(super) fn checked_id(id: &str) -> Result<&str, Status> {
    if id.is_empty() {
        return Err(Status::invalid_argument("session_id: missing"));
    }
    if id.len() > 64
        || !id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
    {
        return Err(Status::invalid_argument(format!(
            "session_id: {} bytes that are not a session id",
            id.len()
        )));
    }
    Ok(id)
}

pub(super) fn engine_status(e: EngineError) -> Status {
    status_of(&e)
}

pub(super) fn random_hex(bytes: usize) -> String {
    use rand::RngExt;
    let mut rng = rand::rng();
    (0..bytes)
        .map(|_| format!("{:02x}", rng.random::<u8>()))
        .collect()
}

pub(super) fn unix_us() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

pub(super) fn guidance_to_wire(g: &GuidanceSpec) -> pb::Guidance {
    pb::Guidance {
        target_marker: g.target_marker,
        target_distance: g.target_distance,
        prompts: g.prompts,
    }
}

pub(super) fn account_to_wire(a: &StoredAccount) -> pb::Account {
    pb::Account {
        account_id: a.id.clone(),
        name: a.name.clone(),
        role: a.role.clone(),
        token: String::new(),
        created_unix_s: a.created_unix_s,
    }
}
