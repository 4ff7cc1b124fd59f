//! The Agones game-server SDK: a client of the Agones sidecar's gRPC service (the same calls
//! as Agones' own SDKs: Ready, Health, Allocate, Shutdown, labels, counters), generated from
//! Agones' protos (`proto/`, vendored), and [`standin`], a recording stand-in of the sidecar
//! for contract tests on machines without Kubernetes.
//!
//! In a GameServer's pod the sidecar listens on `localhost:$AGONES_SDK_GRPC_PORT` (9357 by
//! default). Calls are unary except Health, a client stream: each message sent on it is one
//! health ping, and the GameServer is marked Unhealthy when none arrives within the Fleet's
//! `health.periodSeconds` (times its `failureThreshold`).

pub mod standin;

use std::time::Duration;

use tokio::sync::mpsc;
use tonic::transport::{Channel, Endpoint};

/// Generated code of Agones' SDK protos.
pub mod pb {
    #![allow(missing_docs, clippy::all)]
    /// `agones.dev.sdk`: the stable SDK service.
    pub mod sdk {
        tonic::include_proto!("agones.dev.sdk");
        /// `agones.dev.sdk.beta`: counters and lists.
        pub mod beta {
            tonic::include_proto!("agones.dev.sdk.beta");
        }
    }
}

use pb::sdk::beta::sdk_client::SdkClient as BetaClient;
use pb::sdk::sdk_client::SdkClient;

/// The sidecar's port when `AGONES_SDK_GRPC_PORT` is not set.
pub const DEFAULT_PORT: u16 = 9357;

/// What went wrong talking to the sidecar.
#[derive(Debug, thiserror::Error)]
pub enum AgonesError {
    /// `AGONES_SDK_GRPC_PORT` is not a port number.
    #[error("AGONES_SDK_GRPC_PORT is {value:?}: not a port number")]
    BadPort {
        /// The variable's value.
        value: String,
    },
    /// The sidecar did not answer within the connection timeout.
    #[error("the Agones SDK sidecar at {address} did not answer within {seconds} s: {reason}")]
    Unreachable {
        /// Where it was looked for.
        address: String,
        /// How long it was tried (s).
        seconds: u64,
        /// The last connection error.
        reason: String,
    },
    /// A call the sidecar refused or that failed on the way.
    #[error("Agones SDK call {call} failed: {status}")]
    Call {
        /// The call (`Ready`, `Allocate`…).
        call: &'static str,
        /// The gRPC status.
        status: tonic::Status,
    },
}

/// The error of a failed `call`.
fn failed(call: &'static str) -> impl FnOnce(tonic::Status) -> AgonesError {
    move |status| AgonesError::Call { call, status }
}

/// The sidecar's port: `AGONES_SDK_GRPC_PORT`, else [`DEFAULT_PORT`].
pub fn port_from_env() -> Result<u16, AgonesError> {
    match std::env::var("AGONES_SDK_GRPC_PORT") {
        Ok(value) => value
            .trim()
            .parse()
            .map_err(|_| AgonesError::BadPort { value }),
        Err(_) => Ok(DEFAULT_PORT),
    }
}

/// A connection to the sidecar.
#[derive(Debug, Clone)]
pub struct Sdk {
    sdk: SdkClient<Channel>,
    beta: BetaClient<Channel>,
}

/// Each call waits at most this long for the sidecar's answer.
const CALL_TIMEOUT: Duration = Duration::from_secs(10);

impl Sdk {
    /// Connects to the sidecar on `localhost:port`, trying again every 250 ms for up to
    /// `timeout` (the sidecar may start after the game server's container).
    pub async fn connect(port: u16, timeout: Duration) -> Result<Self, AgonesError> {
        let address = format!("http://127.0.0.1:{port}");
        let endpoint = Endpoint::from_shared(address.clone())
            .map_err(|e| AgonesError::Unreachable {
                address: address.clone(),
                seconds: 0,
                reason: e.to_string(),
            })?
            .connect_timeout(Duration::from_secs(2))
            .timeout(CALL_TIMEOUT);
        let deadline = tokio::time::Instant::now() + timeout;
        let channel = loop {
            match endpoint.connect().await {
                Ok(channel) => break channel,
                Err(e) if tokio::time::Instant::now() >= deadline => {
                    return Err(AgonesError::Unreachable {
                        address,
                        seconds: timeout.as_secs(),
                        reason: e.to_string(),
                    });
                }
                Err(_) => tokio::time::sleep(Duration::from_millis(250)).await,
            }
        };
        Ok(Self {
            sdk: SdkClient::new(channel.clone()),
            beta: BetaClient::new(channel),
        })
    }

    /// Marks the GameServer Ready: it may be allocated (again, after being Allocated).
    pub async fn ready(&mut self) -> Result<(), AgonesError> {
        self.sdk
            .ready(pb::sdk::Empty {})
            .await
            .map(drop)
            .map_err(failed("Ready"))
    }

    /// Marks the GameServer Allocated (it took a session by itself): protected from
    /// scale-down and fleet updates until it is Ready again or shuts down.
    pub async fn allocate(&mut self) -> Result<(), AgonesError> {
        self.sdk
            .allocate(pb::sdk::Empty {})
            .await
            .map(drop)
            .map_err(failed("Allocate"))
    }

    /// Marks the GameServer Shutdown: Agones deletes its pod.
    pub async fn shutdown(&mut self) -> Result<(), AgonesError> {
        self.sdk
            .shutdown(pb::sdk::Empty {})
            .await
            .map(drop)
            .map_err(failed("Shutdown"))
    }

    /// The GameServer as Agones holds it (its address and ports among its status).
    pub async fn game_server(&mut self) -> Result<pb::sdk::GameServer, AgonesError> {
        self.sdk
            .get_game_server(pb::sdk::Empty {})
            .await
            .map(tonic::Response::into_inner)
            .map_err(failed("GetGameServer"))
    }

    /// Where clients reach the GameServer: its status' address and first port, once Agones
    /// has assigned them.
    pub async fn public_address(&mut self) -> Result<Option<(String, u16)>, AgonesError> {
        let gs = self.game_server().await?;
        Ok(gs.status.and_then(|s| {
            let port = s.ports.first().and_then(|p| u16::try_from(p.port).ok())?;
            (!s.address.is_empty() && port != 0).then_some((s.address, port))
        }))
    }

    /// Sets the GameServer's label `agones.dev/sdk-{key}` to `value`.
    pub async fn set_label(&mut self, key: &str, value: &str) -> Result<(), AgonesError> {
        self.sdk
            .set_label(pb::sdk::KeyValue {
                key: key.into(),
                value: value.into(),
            })
            .await
            .map(drop)
            .map_err(failed("SetLabel"))
    }

    /// Sets counter `name` to `count` of `capacity` (the Fleet must declare it); returns the
    /// counter as the sidecar holds it.
    pub async fn set_counter(
        &mut self,
        name: &str,
        count: i64,
        capacity: i64,
    ) -> Result<pb::sdk::beta::Counter, AgonesError> {
        self.beta
            .update_counter(pb::sdk::beta::UpdateCounterRequest {
                counter_update_request: Some(pb::sdk::beta::CounterUpdateRequest {
                    name: name.into(),
                    count: Some(count),
                    capacity: Some(capacity),
                    count_diff: 0,
                }),
            })
            .await
            .map(tonic::Response::into_inner)
            .map_err(failed("UpdateCounter"))
    }

    /// Opens the Health stream: each [`Health::ping`] is one health ping. A stream the
    /// sidecar ended is opened again on the next ping.
    pub fn health(&self) -> Health {
        Health {
            sdk: self.sdk.clone(),
            pings: None,
        }
    }
}

/// The Health client stream.
#[derive(Debug)]
pub struct Health {
    sdk: SdkClient<Channel>,
    pings: Option<mpsc::Sender<pb::sdk::Empty>>,
}

impl Health {
    /// Sends one health ping (opening the stream first if it is not open).
    pub fn ping(&mut self) {
        if let Some(tx) = &self.pings {
            match tx.try_send(pb::sdk::Empty {}) {
                // Full: the stream is still sending the last pings; this one is not needed.
                Ok(()) | Err(mpsc::error::TrySendError::Full(_)) => return,
                Err(mpsc::error::TrySendError::Closed(_)) => {}
            }
        }
        let (tx, rx) = mpsc::channel(4);
        let mut sdk = self.sdk.clone();
        tokio::spawn(async move {
            if let Err(status) = sdk
                .health(tokio_stream::wrappers::ReceiverStream::new(rx))
                .await
            {
                tracing::warn!("Agones health stream ended: {status}");
            }
        });
        let _ = tx.try_send(pb::sdk::Empty {});
        self.pings = Some(tx);
    }
}
