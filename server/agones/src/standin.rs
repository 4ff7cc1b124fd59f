//! A stand-in of the Agones sidecar's SDK service that records every call in order, for
//! contract tests: it checks which calls a game server makes and when, not what Agones does
//! with them (no GameServer state machine, no Kubernetes). Counters keep what was set.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};

use tokio_stream::StreamExt;
use tonic::{Request, Response, Status, Streaming};

use crate::pb::sdk::beta;
use crate::pb::sdk::{self, Empty, KeyValue};

/// One call the stand-in received.
#[derive(Debug, Clone, PartialEq)]
pub enum Call {
    /// `Ready`.
    Ready,
    /// `Allocate`.
    Allocate,
    /// `Shutdown`.
    Shutdown,
    /// One message on the `Health` stream.
    Health,
    /// `GetGameServer`.
    GetGameServer,
    /// `SetLabel(key, value)`.
    SetLabel(String, String),
    /// `UpdateCounter(name, count, capacity)` (count and capacity as sent, if set).
    UpdateCounter(String, Option<i64>, Option<i64>),
}

#[derive(Debug, Default)]
struct Recorded {
    calls: Vec<Call>,
    address: Option<(String, u16)>,
    counters: HashMap<String, beta::Counter>,
}

type Shared = Arc<Mutex<Recorded>>;

fn record(shared: &Shared, call: Call) {
    shared
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .calls
        .push(call);
}

struct Stable(Shared);

#[tonic::async_trait]
impl sdk::sdk_server::Sdk for Stable {
    async fn ready(&self, _: Request<Empty>) -> Result<Response<Empty>, Status> {
        record(&self.0, Call::Ready);
        Ok(Response::new(Empty {}))
    }

    async fn allocate(&self, _: Request<Empty>) -> Result<Response<Empty>, Status> {
        record(&self.0, Call::Allocate);
        Ok(Response::new(Empty {}))
    }

    async fn shutdown(&self, _: Request<Empty>) -> Result<Response<Empty>, Status> {
        record(&self.0, Call::Shutdown);
        Ok(Response::new(Empty {}))
    }

    async fn health(&self, request: Request<Streaming<Empty>>) -> Result<Response<Empty>, Status> {
        let mut pings = request.into_inner();
        while let Some(ping) = pings.next().await {
            ping?;
            record(&self.0, Call::Health);
        }
        Ok(Response::new(Empty {}))
    }

    async fn get_game_server(
        &self,
        _: Request<Empty>,
    ) -> Result<Response<sdk::GameServer>, Status> {
        let mut shared = self.0.lock().unwrap_or_else(|e| e.into_inner());
        shared.calls.push(Call::GetGameServer);
        let (address, port) = shared.address.clone().unwrap_or_default();
        Ok(Response::new(sdk::GameServer {
            status: Some(sdk::game_server::Status {
                state: "Ready".into(),
                address,
                ports: vec![sdk::game_server::status::Port {
                    name: "grpc".into(),
                    port: i32::from(port),
                }],
                ..Default::default()
            }),
            ..Default::default()
        }))
    }

    async fn set_label(&self, request: Request<KeyValue>) -> Result<Response<Empty>, Status> {
        let kv = request.into_inner();
        record(&self.0, Call::SetLabel(kv.key, kv.value));
        Ok(Response::new(Empty {}))
    }
}

struct Beta(Shared);

#[tonic::async_trait]
impl beta::sdk_server::Sdk for Beta {
    async fn update_counter(
        &self,
        request: Request<beta::UpdateCounterRequest>,
    ) -> Result<Response<beta::Counter>, Status> {
        let update = request
            .into_inner()
            .counter_update_request
            .ok_or_else(|| Status::invalid_argument("counterUpdateRequest is required"))?;
        let mut shared = self.0.lock().unwrap_or_else(|e| e.into_inner());
        shared.calls.push(Call::UpdateCounter(
            update.name.clone(),
            update.count,
            update.capacity,
        ));
        let counter = shared
            .counters
            .entry(update.name.clone())
            .or_insert_with(|| beta::Counter {
                name: update.name.clone(),
                count: 0,
                capacity: 0,
            });
        if let Some(capacity) = update.capacity {
            counter.capacity = capacity;
        }
        if let Some(count) = update.count {
            counter.count = count;
        }
        counter.count = (counter.count + update.count_diff).clamp(0, counter.capacity);
        Ok(Response::new(counter.clone()))
    }
}

/// The running stand-in.
#[derive(Debug)]
pub struct StandIn {
    address: SocketAddr,
    shared: Shared,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
}

impl StandIn {
    /// Serves the stand-in on a free port of 127.0.0.1 (on the current tokio runtime).
    pub async fn start() -> std::io::Result<Self> {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let address = listener.local_addr()?;
        let shared = Shared::default();
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let router = tonic::transport::Server::builder()
            .add_service(sdk::sdk_server::SdkServer::new(Stable(shared.clone())))
            .add_service(beta::sdk_server::SdkServer::new(Beta(shared.clone())));
        tokio::spawn(async move {
            let incoming = tokio_stream::wrappers::TcpListenerStream::new(listener);
            if let Err(e) = router
                .serve_with_incoming_shutdown(incoming, async {
                    let _ = stopped.await;
                })
                .await
            {
                tracing::warn!("Agones stand-in stopped: {e}");
            }
        });
        Ok(Self {
            address,
            shared,
            stop: Some(stop),
        })
    }

    /// Its port (for `AGONES_SDK_GRPC_PORT`).
    pub fn port(&self) -> u16 {
        self.address.port()
    }

    /// Every call so far, in the order received.
    pub fn calls(&self) -> Vec<Call> {
        self.shared
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .calls
            .clone()
    }

    /// The address and port `GetGameServer` reports (none: empty, as before Agones assigns
    /// them).
    pub fn set_address(&self, address: &str, port: u16) {
        self.shared
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .address = Some((address.into(), port));
    }

    /// Counter `name` as last set.
    pub fn counter(&self, name: &str) -> Option<beta::Counter> {
        self.shared
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .counters
            .get(name)
            .cloned()
    }
}

impl Drop for StandIn {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Sdk;
    use std::time::Duration;

    #[tokio::test]
    async fn the_client_speaks_to_the_stand_in_and_every_call_is_recorded_in_order() {
        let standin = StandIn::start().await.unwrap();
        let mut sdk = Sdk::connect(standin.port(), Duration::from_secs(5))
            .await
            .unwrap();
        sdk.set_counter("sessions", 0, 4).await.unwrap();
        sdk.ready().await.unwrap();
        let mut health = sdk.health();
        health.ping();
        health.ping();
        let counter = sdk.set_counter("sessions", 1, 4).await.unwrap();
        assert_eq!((counter.count, counter.capacity), (1, 4));
        sdk.allocate().await.unwrap();
        sdk.set_label("scene", "stroke").await.unwrap();
        assert_eq!(sdk.public_address().await.unwrap(), None);
        standin.set_address("gs.example.org", 7777);
        assert_eq!(
            sdk.public_address().await.unwrap(),
            Some(("gs.example.org".into(), 7777))
        );
        sdk.shutdown().await.unwrap();
        // The health stream is asynchronous: wait for its two pings.
        for _ in 0..100 {
            if standin
                .calls()
                .iter()
                .filter(|c| **c == Call::Health)
                .count()
                == 2
            {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let calls = standin.calls();
        let unary: Vec<&Call> = calls.iter().filter(|c| **c != Call::Health).collect();
        assert_eq!(
            unary,
            [
                &Call::UpdateCounter("sessions".into(), Some(0), Some(4)),
                &Call::Ready,
                &Call::UpdateCounter("sessions".into(), Some(1), Some(4)),
                &Call::Allocate,
                &Call::SetLabel("scene".into(), "stroke".into()),
                &Call::GetGameServer,
                &Call::GetGameServer,
                &Call::Shutdown,
            ]
        );
        assert_eq!(calls.iter().filter(|c| **c == Call::Health).count(), 2);
        assert_eq!(standin.counter("sessions").unwrap().count, 1);
    }

    #[tokio::test]
    async fn no_sidecar_is_a_named_error_after_the_timeout() {
        // A port nothing listens on: bind one, then free it.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let e = Sdk::connect(port, Duration::from_millis(600))
            .await
            .unwrap_err()
            .to_string();
        assert!(e.contains(&format!("127.0.0.1:{port}")), "{e}");
        assert!(e.contains("did not answer"), "{e}");
    }
}
