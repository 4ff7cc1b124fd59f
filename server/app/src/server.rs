//! Putting the server together: the engine with the shared renderer and the store, the
//! Simulator service with health and reflection, gRPC-Web and CORS for browsers, the
//! Prometheus `/metrics` route and the built web client on the same port, TLS when
//! configured, and graceful shutdown.

use std::future::Future;
use std::sync::Arc;

use anyhow::Context;
use axum::routing::get;
use cathlab_api::pb::simulator_server::SimulatorServer;
use cathlab_engine::engine::EngineSettings;
use cathlab_engine::{Engine, EngineMetrics, SessionSettings, SharedRenderer};
use cathlab_xray::{CpuRenderer, GpuRenderer, Renderer};
use prometheus_client::registry::Registry;
use tonic::service::Routes;
use tonic::transport::{Identity, Server, ServerTlsConfig};
use tower_http::cors::{AllowOrigin, CorsLayer};

use crate::config::{RendererChoice, ServerConfig};
use crate::service::SimulatorService;
use crate::store::{Store, StoreLocation};

/// The renderer sessions share: for `auto`, wgpu on a hardware adapter, else the CPU
/// renderer (on a software rasterizer such as lavapipe the CPU renderer makes the cached-
/// background frames faster: `cathlab-load` measures both). Made on a niced thread so that a
/// software driver's workers run below the physics threads.
pub fn renderer(choice: RendererChoice) -> anyhow::Result<Box<dyn Renderer>> {
    cathlab_engine::priority::niced_rayon_pool();
    cathlab_engine::priority::on_niced_thread(move || -> anyhow::Result<Box<dyn Renderer>> {
        Ok(match choice {
            RendererChoice::Cpu => Box::new(CpuRenderer::default()),
            RendererChoice::Gpu => Box::new(GpuRenderer::new()?),
            RendererChoice::Auto => match GpuRenderer::if_available()? {
                Some(gpu) if !gpu.is_software() => Box::new(gpu),
                _ => Box::new(CpuRenderer::default()),
            },
        })
    })
}

/// The engine and store of a configuration.
pub fn engine(config: &ServerConfig) -> anyhow::Result<(Arc<Engine>, Arc<Store>, EngineMetrics)> {
    let location = config.store_location();
    if let StoreLocation::Sqlite(file) = &location
        && let Some(dir) = file.parent()
        && !dir.as_os_str().is_empty()
    {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    // Every reader of anatomy and CT files is bounded from here on.
    cathlab_anatomy::io::limits::set_read_limits(config.read_limits());
    let store = Arc::new(Store::for_server(&location, &config.resolved_server_id())?);
    let metrics = EngineMetrics::default();
    let renderer = SharedRenderer::new(renderer(config.renderer)?);
    let engine = Engine::new(
        EngineSettings {
            scenes_dir: config.scenes.clone(),
            session: SessionSettings {
                max_recorded_commands: config.max_recorded_commands,
                overload_governor: config.overload_governor,
                ..SessionSettings::default()
            },
            max_sessions: config.max_sessions,
            max_replays: config.max_replays,
            asset_budget_bytes: config.asset_cache_mib << 20,
            data_roots: config.data_roots.clone(),
            asset_disk_cache: config.asset_disk_cache.clone(),
            asset_disk_cache_bytes: config.asset_disk_cache_mib.saturating_mul(1 << 20),
        },
        store.clone(),
        renderer,
        metrics.clone(),
    )?;
    Ok((Arc::new(engine), store, metrics))
}

/// Instructor keys too weak to stand on a network: the default of `scripts/run.sh` and
/// anything shorter than 16 characters.
const WEAK_KEYS: [&str; 2] = ["instructor", "changeme"];

/// Refuses to listen beyond the loopback interface with a weak instructor key: a key that
/// guards every session's data must be a secret there.
pub fn check_exposure(config: &ServerConfig) -> anyhow::Result<()> {
    let loopback = config
        .listen
        .parse::<std::net::SocketAddr>()
        .map(|a| a.ip().is_loopback())
        .unwrap_or_else(|_| config.listen.starts_with("localhost:"));
    if let Some(key) = &config.instructor_key
        && !loopback
        && (key.chars().count() < 16 || WEAK_KEYS.contains(&key.as_str()))
    {
        anyhow::bail!(
            "refusing to listen on {} (beyond this machine) with a weak instructor key: set \
             CATHLAB_INSTRUCTOR_KEY (or instructor_key in the configuration file) to a random \
             secret of 16 characters or more, e.g. `openssl rand -hex 16`",
            config.listen
        );
    }
    Ok(())
}

/// Runs the server until `shutdown` resolves, then closes every session and flushes the
/// store. Prints `cathlab-server listening on ADDR` once the socket is bound.
pub async fn serve(
    config: ServerConfig,
    shutdown: impl Future<Output = ()> + Send,
) -> anyhow::Result<()> {
    check_exposure(&config)?;
    // An Agones GameServer without its sidecar would never be Ready: stop here, saying so.
    let agones = if config.agones {
        Some(
            crate::agones::connect(std::time::Duration::from_secs(
                config.agones_connect_timeout_s,
            ))
            .await?,
        )
    } else {
        None
    };
    let (engine, store, metrics) = engine(&config)?;
    tracing::info!(
        renderer = %format!("{:?}", config.renderer),
        scenes = engine.catalog().scenes().len(),
        "engine ready"
    );
    // The scenes to warm, named now (a wrong name stops the server), loaded in the
    // background: the server answers meanwhile, and counts as ready (to Agones) once done.
    let mut warm = Vec::new();
    for name in &config.warm_scenes {
        let (spec, base) = engine
            .scene(&cathlab_engine::engine::SceneSource::Named(name.clone()))
            .with_context(|| format!("warm_scenes: {name:?}"))?;
        warm.push((spec, base));
    }
    let warming = {
        let engine = engine.clone();
        tokio::task::spawn_blocking(move || {
            for (spec, base) in warm {
                let started = std::time::Instant::now();
                match engine.load(&spec, &base) {
                    Ok(_) => tracing::info!(
                        scene = %spec.name,
                        seconds = started.elapsed().as_secs_f64(),
                        "scene warm"
                    ),
                    Err(e) => tracing::warn!(scene = %spec.name, "warming: {e}"),
                }
            }
        })
    };
    let default_scene = config.resolve_default_scene(&engine.catalog().names())?;
    let service = Arc::new(
        SimulatorService::new(engine.clone(), store.clone(), config.instructor_key.clone())
            .with_default_scene(default_scene)
            .with_inline_scenes(config.inline_scenes)
            .with_auth_failures_per_minute(config.auth_failures_per_minute)
            .with_control_timeout(std::time::Duration::from_millis(config.control_timeout_ms))
            .with_unattended_timeout(config.unattended_timeout())
            .with_max_sessions_per_client(config.sessions_per_client())
            .with_session_creations_per_minute(config.session_creations_per_minute)
            .with_control_inputs_per_second(config.control_inputs_per_second)
            .with_stream_limits(
                config.stream_buffer_mib << 20,
                std::time::Duration::from_millis(config.stream_stall_timeout_ms),
            ),
    );
    // Sessions whose controller went away are closed once the unattended timeout passes:
    // an abandoned session would otherwise hold its place and its core until the server
    // stops.
    if let Some(timeout) = config.unattended_timeout() {
        let service = service.clone();
        let period = timeout.div_f64(4.0).clamp(
            std::time::Duration::from_millis(250),
            std::time::Duration::from_secs(10),
        );
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(period);
            loop {
                tick.tick().await;
                service.close_unattended().await;
            }
        });
    }
    // The store keeps what its retention settings say: ended anonymous sessions past the
    // count, any past the age, pruned once a minute (and at start).
    {
        let store = store.clone();
        let keep = config.max_recorded_anonymous_sessions;
        let max_age_s = (config.recorded_session_retention_days > 0.0)
            .then_some(config.recorded_session_retention_days * 86_400.0);
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(std::time::Duration::from_secs(60));
            loop {
                tick.tick().await;
                let store = store.clone();
                match tokio::task::spawn_blocking(move || store.prune(keep, max_age_s)).await {
                    Ok(Ok(0)) => {}
                    Ok(Ok(n)) => tracing::info!(sessions = n, "store: pruned ended sessions"),
                    Ok(Err(e)) => tracing::warn!("store: pruning: {e}"),
                    Err(e) => tracing::warn!("store: pruning: {e}"),
                }
            }
        });
    }
    let simulator = SimulatorServer::from_arc(service.clone())
        .max_decoding_message_size(config.max_message_bytes)
        .max_encoding_message_size(64 << 20);
    let (health, health_service) = tonic_health::server::health_reporter();
    health
        .set_serving::<SimulatorServer<SimulatorService>>()
        .await;
    // Health follows the store: NOT_SERVING while the database cannot be reached (sessions
    // keep simulating, but no command is acknowledged), SERVING again when it can.
    let (watched, reporter) = (store.clone(), health.clone());
    tokio::spawn(async move {
        let mut serving = true;
        let mut tick = tokio::time::interval(std::time::Duration::from_millis(250));
        loop {
            tick.tick().await;
            let reachable = watched.is_reachable();
            if reachable == serving {
                continue;
            }
            serving = reachable;
            let status = if reachable {
                tonic_health::ServingStatus::Serving
            } else {
                tracing::warn!("{}: unreachable; health is NOT_SERVING", watched.name());
                tonic_health::ServingStatus::NotServing
            };
            reporter.set_service_status("", status).await;
            if reachable {
                reporter
                    .set_serving::<SimulatorServer<SimulatorService>>()
                    .await;
            } else {
                reporter
                    .set_not_serving::<SimulatorServer<SimulatorService>>()
                    .await;
            }
        }
    });
    let reflection = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(cathlab_api::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
        .build_v1()?;
    let mut registry = Registry::default();
    metrics.register(&mut registry);
    let heap = prometheus_client::metrics::gauge::Gauge::<i64>::default();
    registry.register(
        "cathlab_heap_bytes",
        "Bytes live on the heap (allocated and not freed; 0 when not counted)",
        heap.clone(),
    );
    let registry = Arc::new(registry);
    let allocating = store.clone();
    let router = Routes::new(simulator)
        .add_service(health_service)
        .add_service(reflection)
        .into_axum_router()
        .layer(crate::intake::IntakeLayer::new(
            crate::intake::RequestBuffer::new(config.request_buffer_mib << 20),
            std::time::Duration::from_secs(config.message_read_timeout_s),
        ))
        .layer(axum::middleware::map_response(undecodable_is_invalid))
        // gRPC-Web for the gRPC routes only: tonic-web answers 400 to any other HTTP/1.1
        // request, and /metrics (added after the layer) is plain HTTP.
        .layer(tonic_web::GrpcWebLayer::new())
        .route(
            "/allocate",
            get(move |uri: axum::http::Uri| allocate(allocating.clone(), uri)),
        )
        .route("/fleet-origins", {
            let store = store.clone();
            get(move || fleet_origins(store.clone()))
        })
        .route(
            "/metrics",
            get(move || {
                let (registry, heap) = (registry.clone(), heap.clone());
                async move {
                    heap.set(crate::heap::live_bytes().map_or(0, |b| b as i64));
                    let mut text = String::new();
                    match prometheus_client::encoding::text::encode(&mut text, &registry) {
                        Ok(()) => (
                            [(
                                "content-type",
                                "application/openmetrics-text; version=1.0.0; charset=utf-8",
                            )],
                            text,
                        ),
                        Err(e) => ([("content-type", "text/plain")], format!("error: {e}")),
                    }
                }
            }),
        );
    let web_client = config.web_root.join("index.html").is_file();
    let router = if web_client {
        router.fallback_service(
            tower_http::services::ServeDir::new(&config.web_root)
                .append_index_html_on_directories(true),
        )
    } else {
        tracing::warn!(
            web_root = %config.web_root.display(),
            "web client not built (scripts/run.sh builds it); serving the API only"
        );
        let note = format!(
            "cathlab-server: the web client is not built in {} (scripts/run.sh builds it, or \
             `npm ci && npm run build` in client-web)\n",
            config.web_root.display()
        );
        router.fallback(move || {
            let note = note.clone();
            async move { (axum::http::StatusCode::NOT_FOUND, note) }
        })
    };
    // CORS only for the configured origins, with the headers gRPC-Web and Connect send.
    let origins = config
        .cors_origins
        .iter()
        .map(|o| {
            o.parse::<axum::http::HeaderValue>()
                .with_context(|| format!("cors_origins: {o:?} is not an origin"))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let cors = CorsLayer::new()
        .allow_origin(AllowOrigin::list(origins))
        .allow_methods([
            http_method("POST"),
            http_method("GET"),
            http_method("OPTIONS"),
        ])
        .allow_headers(
            [
                "authorization",
                "content-type",
                "x-grpc-web",
                "x-user-agent",
                "grpc-timeout",
                "connect-protocol-version",
                "connect-timeout-ms",
            ]
            .map(axum::http::HeaderName::from_static),
        )
        .expose_headers([
            "grpc-status".parse()?,
            "grpc-message".parse()?,
            "grpc-status-details-bin".parse()?,
        ]);
    // HTTP/2: a bounded number of streams a connection, flow-control windows the size of a
    // request message; what arrives is held within the intake layer's buffer.
    let window =
        u32::try_from(config.max_message_bytes.clamp(64 << 10, 16 << 20)).unwrap_or(1 << 20);
    let mut builder = Server::builder()
        .accept_http1(true)
        .max_concurrent_streams(Some(config.http2_max_streams))
        .initial_stream_window_size(Some(window))
        .initial_connection_window_size(Some(window.saturating_mul(2)))
        .http2_max_pending_accept_reset_streams(Some(config.http2_max_streams as usize));
    if let Some(tls) = &config.tls {
        let cert = std::fs::read(&tls.cert).with_context(|| format!("{}", tls.cert.display()))?;
        let key = std::fs::read(&tls.key).with_context(|| format!("{}", tls.key.display()))?;
        builder =
            builder.tls_config(ServerTlsConfig::new().identity(Identity::from_pem(cert, key)))?;
    }
    let listener = tokio::net::TcpListener::bind(&config.listen)
        .await
        .with_context(|| format!("binding {}", config.listen))?;
    let address = listener.local_addr()?;
    println!("cathlab-server listening on {address}");
    let scheme = if config.tls.is_some() {
        "https"
    } else {
        "http"
    };
    // In the fleet's registry (on SQLite, a fleet of one).
    let advertised = config
        .advertise
        .clone()
        .unwrap_or_else(|| format!("{scheme}://{address}"));
    let mut registration = crate::fleet::Registration::start(
        store.clone(),
        engine.clone(),
        advertised,
        config.max_sessions,
    )?;
    let lifecycle = agones.clone().map(|sdk| {
        let (engine, capacity) = (engine.clone(), config.max_sessions);
        // Unless told where clients reach it, a GameServer is reached where Agones says.
        let advertise = config
            .advertise
            .is_none()
            .then(|| (registration.address(), scheme));
        tokio::spawn(async move {
            let _ = warming.await;
            crate::agones::run(sdk, engine, capacity, advertise).await;
        })
    });
    if web_client {
        let host = if address.ip().is_unspecified() {
            std::net::SocketAddr::new(std::net::Ipv4Addr::LOCALHOST.into(), address.port())
        } else {
            address
        };
        println!(
            "cathlab web client: {scheme}://{host}/ (trainee), {scheme}://{host}/dashboard.html (instructor)"
        );
    }
    // Each connection can be cut (a reader that stalls a frame stream loses its connection).
    let admission = crate::connections::Admission::new(crate::connections::ConnectionLimits {
        max_total: config.max_connections,
        max_per_address: config.max_connections_per_address,
        idle_timeout: std::time::Duration::from_secs(config.connection_idle_timeout_s.max(1)),
        trusted_proxies: config.trusted_proxies.clone(),
    });
    let incoming = crate::connections::tracked(
        tonic::transport::server::TcpIncoming::from(listener).with_nodelay(Some(true)),
        admission,
    );
    // On shutdown, close the sessions first: that ends their streams, which the server's
    // graceful drain would otherwise wait on for ever.
    let closing = service.clone();
    // The Agones lifecycle stops before the sessions close (no Ready on the way out).
    let lifecycle_stop = lifecycle
        .as_ref()
        .map(tokio::task::JoinHandle::abort_handle);
    let shutdown = async move {
        shutdown.await;
        if let Some(stop) = lifecycle_stop {
            stop.abort();
        }
        tracing::info!("shutting down: closing sessions, flushing the store");
        let _ = tokio::task::spawn_blocking(move || closing.shutdown()).await;
    };
    let result = builder
        .layer(cors)
        .add_routes(Routes::from(router))
        .serve_with_incoming_shutdown(incoming, shutdown)
        .await;
    // Also after a serve error (nothing to close after a clean shutdown).
    let closing = service.clone();
    tokio::task::spawn_blocking(move || closing.shutdown()).await?;
    tokio::task::spawn_blocking(move || registration.stop()).await?;
    // Drained (every session closed and stored): Agones may delete the pod.
    if let (Some(task), Some(mut sdk)) = (lifecycle, agones) {
        task.abort();
        match sdk.shutdown().await {
            Ok(()) => tracing::info!("Agones: Shutdown"),
            Err(e) => tracing::warn!("{e}"),
        }
    }
    result?;
    Ok(())
}

/// `GET /allocate[?query]`: a new trainee's way in. Redirects (303) to the web client on the
/// serving server of the fleet with the most room, the query kept (`?scene=…&label=…`);
/// 503 if none has room. The registry is the fleet's store, so any server answers alike.
async fn allocate(
    store: Arc<Store>,
    uri: axum::http::Uri,
) -> axum::response::Response<axum::body::Body> {
    use axum::http::{StatusCode, header};
    use axum::response::IntoResponse;
    let servers = tokio::task::spawn_blocking(move || store.servers()).await;
    let servers = match servers {
        Ok(Ok(s)) => s,
        // The detail (a database path or address) is for the log, not for anyone who asks.
        Ok(Err(e)) => {
            tracing::warn!("/allocate: the fleet's registry: {e}");
            return (
                StatusCode::SERVICE_UNAVAILABLE,
                [
                    (header::RETRY_AFTER, "30"),
                    (header::CACHE_CONTROL, "no-store"),
                ],
                "the fleet's registry cannot be read; try again shortly\n",
            )
                .into_response();
        }
        Err(e) => {
            tracing::warn!("/allocate: {e}");
            return (StatusCode::INTERNAL_SERVER_ERROR, "internal error\n").into_response();
        }
    };
    let Some(server) = crate::fleet::with_most_room(&servers) else {
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            [
                (header::RETRY_AFTER, "30"),
                (header::CACHE_CONTROL, "no-store"),
            ],
            "no server of the fleet has room for another session; try again shortly\n",
        )
            .into_response();
    };
    let query = allocation_query(uri.query().unwrap_or(""));
    let location = format!("{}/{query}", server.address.trim_end_matches('/'));
    (
        StatusCode::SEE_OTHER,
        [
            (header::LOCATION, location),
            (header::CACHE_CONTROL, "no-store".to_owned()),
        ],
    )
        .into_response()
}

/// `GET /fleet-origins`: the advertised addresses of the fleet's serving servers (this one
/// included; on SQLite a fleet of one), `{"origins": [...]}`: the only servers other than
/// its own to which the web client sends a stored credential. Never a redirect, never
/// cached.
async fn fleet_origins(store: Arc<Store>) -> axum::response::Response<axum::body::Body> {
    use axum::http::{StatusCode, header};
    use axum::response::IntoResponse;
    let servers = tokio::task::spawn_blocking(move || store.servers()).await;
    let origins: Vec<String> = match servers {
        Ok(Ok(servers)) => servers
            .into_iter()
            .filter(|s| s.status == "serving")
            .map(|s| s.address)
            .collect(),
        Ok(Err(e)) => {
            tracing::warn!("/fleet-origins: the fleet's registry: {e}");
            Vec::new()
        }
        Err(e) => {
            tracing::warn!("/fleet-origins: {e}");
            Vec::new()
        }
    };
    (
        StatusCode::OK,
        [
            (header::CONTENT_TYPE, "application/json"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        serde_json::json!({ "origins": origins }).to_string(),
    )
        .into_response()
}

/// The query keys `/allocate` passes on to the server it sends a trainee to: the scene and
/// the label (nothing else, so that no link can carry a `server`, an `account` or a token
/// through it).
const ALLOCATION_KEYS: [&str; 2] = ["scene", "label"];

/// `?scene=…&label=…` of a query, its other keys dropped (each kept pair as it was
/// encoded).
fn allocation_query(query: &str) -> String {
    let kept: Vec<&str> = query
        .split('&')
        .filter(|pair| {
            let key = pair.split('=').next().unwrap_or("");
            ALLOCATION_KEYS.contains(&key)
        })
        .collect();
    if kept.is_empty() {
        String::new()
    } else {
        format!("?{}", kept.join("&"))
    }
}

/// tonic answers a request message that does not decode with INTERNAL; it is the caller's
/// fault: INVALID_ARGUMENT.
/// How tonic's INTERNAL answers about a request's bytes begin (plain and percent-encoded):
/// a message that does not decode, a body with no message.
const CALLERS_FRAMING: [&str; 4] = [
    "failed to decode Protobuf message",
    "failed%20to%20decode",
    "Missing request message",
    "Missing%20request%20message",
];

async fn undecodable_is_invalid(
    mut response: axum::response::Response,
) -> axum::response::Response {
    let headers = response.headers_mut();
    let undecodable = headers.get("grpc-status").is_some_and(|s| s == "13")
        && headers
            .get("grpc-message")
            .and_then(|m| m.to_str().ok())
            .is_some_and(|m| CALLERS_FRAMING.iter().any(|start| m.starts_with(start)));
    if undecodable {
        headers.insert("grpc-status", axum::http::HeaderValue::from_static("3"));
    }
    response
}

fn http_method(name: &str) -> axum::http::Method {
    axum::http::Method::from_bytes(name.as_bytes()).expect("valid method")
}

/// Resolves on SIGINT or SIGTERM.
pub async fn shutdown_signal() {
    let interrupt = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        let mut terminate =
            tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
                .expect("SIGTERM handler");
        tokio::select! {
            _ = interrupt => {}
            _ = terminate.recv() => {}
        }
    }
    #[cfg(not(unix))]
    {
        let _ = interrupt.await;
    }
}

/// Resolves when standard input reaches its end (the parent process went away).
pub async fn stdin_closed() {
    use tokio::io::AsyncReadExt;
    let mut stdin = tokio::io::stdin();
    let mut buffer = [0u8; 256];
    while let Ok(n) = stdin.read(&mut buffer).await {
        if n == 0 {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::allocation_query;

    #[test]
    fn allocate_passes_on_only_the_scene_and_the_label() {
        assert_eq!(
            allocation_query("scene=neuro_phantom_m1&label=Rita%20T"),
            "?scene=neuro_phantom_m1&label=Rita%20T"
        );
        assert_eq!(
            allocation_query("server=https://evil.example&scene=a&account=T0K&token=x&key=k"),
            "?scene=a"
        );
        assert_eq!(allocation_query("server=https://evil.example"), "");
        assert_eq!(allocation_query(""), "");
    }
}
