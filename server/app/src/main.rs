//! `cathlab-server`: runs the simulation server (default), replays a recorded session, or
//! checks a folder of scenes (`--check-scenes DIR`).

use std::path::PathBuf;

use anyhow::Context;
use cathlab_app::config::{ConfigFile, InlineScenes, RendererChoice, ServerConfig, TlsFiles};
use clap::{Parser, Subcommand};

/// mimalloc gives freed memory back to the system (with [`ALLOCATOR_ENV`]); glibc's allocator
/// kept tens of MiB of freed frame buffers in its per-thread arenas for good (24 stalled 2048²
/// frame streams, then all closed: RSS +57 MiB with glibc).
/// `cap` counts the live bytes for `/metrics` (`cathlab_heap_bytes`); no limit is set.
#[global_allocator]
static ALLOCATOR: cap::Cap<mimalloc::MiMalloc> = cap::Cap::new(mimalloc::MiMalloc, usize::MAX);

/// mimalloc's settings for a long-running server, which it reads from the environment as the
/// process starts (before `main`). Its defaults back the arenas with transparent huge pages,
/// which `khugepaged` fills back in after frees, and give freed pages back a second later and
/// only when their heap allocates again: the soak's resting memory was 152–187 MiB anonymous
/// for a 40 MiB live heap, and drifted up. Without huge pages and with a 100 ms delay: 90–108
/// MiB, flat; no delay at all saved 30 MiB more but cost 10 % of the frames with 4 sessions
/// (docs/reliability.md). A variable already set is left as it is.
const ALLOCATOR_ENV: [(&str, &str); 2] =
    [("MIMALLOC_ALLOW_THP", "0"), ("MIMALLOC_PURGE_DELAY", "100")];

/// Restarts this process in place (same pid, arguments and descriptors) with
/// [`ALLOCATOR_ENV`] when any of it is missing; returns only when it need not or cannot
/// (then the allocator keeps its defaults, and says so).
#[cfg(unix)]
fn tune_allocator() {
    use std::os::unix::process::CommandExt;
    if ALLOCATOR_ENV
        .iter()
        .all(|(name, _)| std::env::var_os(name).is_some())
    {
        return;
    }
    let exe = match std::env::current_exe() {
        Ok(exe) => exe,
        Err(error) => {
            eprintln!(
                "cathlab-server: could not find its own binary to restart with the allocator's settings ({error}); its defaults hold more memory"
            );
            return;
        }
    };
    let mut command = std::process::Command::new(exe);
    command.args(std::env::args_os().skip(1));
    for (name, value) in ALLOCATOR_ENV {
        if std::env::var_os(name).is_none() {
            command.env(name, value);
        }
    }
    let error = command.exec();
    eprintln!(
        "cathlab-server: could not restart with the allocator's settings ({error}); its defaults hold more memory"
    );
}

#[cfg(not(unix))]
fn tune_allocator() {}

#[derive(Debug, Parser)]
#[command(name = "cathlab-server", about = "cathlab simulation server")]
struct Cli {
    #[command(subcommand)]
    command: Option<Action>,
    #[command(flatten)]
    options: Options,
}

#[derive(Debug, clap::Args, Clone)]
struct Options {
    /// Configuration file (TOML); flags override it.
    #[arg(long, global = true)]
    config: Option<PathBuf>,
    /// Address to listen on (port 0 picks a free port).
    #[arg(long, global = true)]
    listen: Option<String>,
    /// SQLite database file.
    #[arg(long, global = true)]
    database: Option<PathBuf>,
    /// A PostgreSQL database shared by a fleet (`postgres://user:password@host:port/db`;
    /// also CATHLAB_DATABASE_URL, which keeps the password off the command line); when
    /// given, the store instead of --database.
    #[arg(long, global = true)]
    database_url: Option<String>,
    /// This server's id in a fleet sharing a PostgreSQL store (default: the host name;
    /// several servers on one host need their own).
    #[arg(long, global = true)]
    server_id: Option<String>,
    /// Where clients reach this server (`http://host:port`; default: where it listens).
    #[arg(long, global = true)]
    advertise: Option<String>,
    /// Most sessions at once (also the capacity this server publishes to a fleet).
    #[arg(long, global = true)]
    max_sessions: Option<usize>,
    /// Most running sessions one client (an account, else an address) may have created
    /// (default: half of --max-sessions).
    #[arg(long, global = true)]
    max_sessions_per_client: Option<usize>,
    /// A proxy (an address or a range such as 10.0.0.0/8) whose X-Forwarded-For names the
    /// real client; repeatable.
    #[arg(long = "trusted-proxy", global = true)]
    trusted_proxies: Vec<cathlab_app::connections::ProxyRange>,
    /// Speak the Agones SDK to the sidecar (`AGONES_SDK_GRPC_PORT`, default 9357).
    #[arg(long, global = true)]
    agones: bool,
    /// How long the Agones sidecar may take to answer at start, in seconds (default 30).
    #[arg(long = "agones-connect-timeout", global = true, value_name = "SECONDS")]
    agones_connect_timeout_s: Option<u64>,
    /// A scene to load at start, before the server counts as ready (repeatable).
    #[arg(long = "warm", global = true, value_name = "SCENE")]
    warm_scenes: Vec<String>,
    /// Scene directory.
    #[arg(long, global = true)]
    scenes: Option<PathBuf>,
    /// The built web client directory (default client-web/dist).
    #[arg(long, global = true)]
    web_root: Option<PathBuf>,
    /// Keep anatomies that take long to build (the neuro phantom's) in this directory
    /// between runs.
    /// (also `CATHLAB_ASSET_DISK_CACHE`).
    #[arg(long, global = true)]
    asset_disk_cache: Option<PathBuf>,
    /// Renderer.
    #[arg(long, value_enum, global = true)]
    renderer: Option<RendererChoice>,
    /// Keep every session at its scene's fidelity under load (no overload governor).
    #[arg(long, global = true)]
    no_overload_governor: bool,
    /// Close a running session whose controller has been away this long: no stream open
    /// with its controller token, no call with it (default 600; 0: never).
    #[arg(long = "unattended-timeout", global = true, value_name = "SECONDS")]
    unattended_session_timeout_s: Option<u64>,
    /// TLS certificate (PEM); needs --tls-key.
    #[arg(long, global = true)]
    tls_cert: Option<PathBuf>,
    /// TLS private key (PEM).
    #[arg(long, global = true)]
    tls_key: Option<PathBuf>,
    /// Who may create sessions from scene texts (default: instructors).
    #[arg(long, value_enum, global = true)]
    inline_scenes: Option<InlineScenes>,
    /// A web origin (`https://host:port`) whose pages may call the API from the browser
    /// (repeatable; the built-in web client is same-origin and needs none).
    #[arg(long = "cors-origin", global = true)]
    cors_origins: Vec<String>,
    /// The scene clients start when their user names none (default: arch_to_cow_lcca_coaxial
    /// when listed, else the first scene).
    #[arg(long, global = true)]
    default_scene: Option<String>,
    /// Load every scene in DIR (parse, resolve files, build assets, one step), print one
    /// line per scene (ok, or the error naming the field) and exit: non-zero if any failed.
    #[arg(long, value_name = "DIR")]
    check_scenes: Option<PathBuf>,
    /// Shut down gracefully when standard input closes (for supervisors and test harnesses
    /// that hold the server's stdin).
    #[arg(long, global = true)]
    exit_on_stdin_eof: bool,
}

#[derive(Debug, Subcommand)]
enum Action {
    /// Run the server (the default).
    Serve,
    /// Replay a recorded session and compare its checkpoints.
    Replay {
        /// The session id.
        #[arg(long)]
        session: String,
    },
}

fn config(options: &Options) -> anyhow::Result<ServerConfig> {
    let file = match &options.config {
        Some(f) => ConfigFile::read(f)?,
        None => ConfigFile::default(),
    };
    let mut config = ServerConfig::from_file(file);
    if let Some(v) = &options.listen {
        config.listen = v.clone();
    }
    if let Some(v) = &options.database {
        config.database = v.clone();
    }
    if let Some(v) = options
        .database_url
        .clone()
        .or_else(|| std::env::var("CATHLAB_DATABASE_URL").ok())
    {
        config.database_url = Some(v);
    }
    if let Some(v) = &options.server_id {
        config.server_id = Some(v.clone());
    }
    if let Some(v) = &options.advertise {
        config.advertise = Some(v.clone());
    }
    if let Some(v) = options.max_sessions {
        config.max_sessions = v;
    }
    if let Some(v) = options.max_sessions_per_client {
        config.max_sessions_per_client = Some(v);
    }
    if !options.trusted_proxies.is_empty() {
        config.trusted_proxies = options.trusted_proxies.clone();
    }
    if options.agones {
        config.agones = true;
    }
    if let Some(v) = options.agones_connect_timeout_s {
        config.agones_connect_timeout_s = v;
    }
    if !options.warm_scenes.is_empty() {
        config.warm_scenes = options.warm_scenes.clone();
    }
    if let Some(v) = &options.scenes {
        config.scenes = v.clone();
    }
    if let Some(v) = &options.web_root {
        config.web_root = v.clone();
    }
    if let Some(v) = options
        .asset_disk_cache
        .clone()
        .or_else(|| std::env::var_os("CATHLAB_ASSET_DISK_CACHE").map(PathBuf::from))
    {
        config.asset_disk_cache = Some(v);
    }
    if let Some(v) = options.renderer {
        config.renderer = v;
    }
    if options.no_overload_governor {
        config.overload_governor = false;
    }
    if let Some(v) = options.unattended_session_timeout_s {
        config.unattended_session_timeout_s = v;
    }
    if let Some(v) = options.inline_scenes {
        config.inline_scenes = v;
    }
    if !options.cors_origins.is_empty() {
        config.cors_origins = options.cors_origins.clone();
    }
    if let Some(v) = &options.default_scene {
        config.default_scene = Some(v.clone());
    }
    match (&options.tls_cert, &options.tls_key) {
        (Some(cert), Some(key)) => {
            config.tls = Some(TlsFiles {
                cert: cert.clone(),
                key: key.clone(),
            })
        }
        (None, None) => {}
        _ => anyhow::bail!("--tls-cert and --tls-key go together"),
    }
    if let Ok(key) = std::env::var("CATHLAB_INSTRUCTOR_KEY") {
        config.instructor_key = Some(key);
    }
    Ok(config)
}

fn main() -> anyhow::Result<()> {
    tune_allocator();
    cathlab_app::heap::count_with(|| ALLOCATOR.allocated());
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let config = config(&cli.options)?;
    if let Some(dir) = &cli.options.check_scenes {
        let checks = cathlab_engine::check::check_scenes(
            dir,
            &config.data_roots,
            config.asset_disk_cache.as_deref(),
        )
        .with_context(|| format!("reading {}", dir.display()))?;
        for check in &checks {
            println!("{}", check.line());
        }
        let failed = checks.iter().filter(|c| c.outcome.is_err()).count();
        if checks.is_empty() {
            anyhow::bail!("{} holds no scene (.toml or .json)", dir.display());
        }
        if failed > 0 {
            anyhow::bail!("{failed} of {} scenes failed", checks.len());
        }
        return Ok(());
    }
    match cli.command.unwrap_or(Action::Serve) {
        Action::Serve => {
            let runtime = tokio::runtime::Runtime::new().context("starting tokio")?;
            let watch_stdin = cli.options.exit_on_stdin_eof;
            let result = runtime.block_on(cathlab_app::server::serve(config, async move {
                if watch_stdin {
                    tokio::select! {
                        _ = cathlab_app::server::shutdown_signal() => {}
                        _ = cathlab_app::server::stdin_closed() => {}
                    }
                } else {
                    cathlab_app::server::shutdown_signal().await
                }
            }));
            // Sessions are closed and the store flushed by now; do not wait for blocking
            // readers (the stdin watcher) that never return.
            runtime.shutdown_timeout(std::time::Duration::from_secs(2));
            result
        }
        Action::Replay { session } => {
            let (engine, store, _) = cathlab_app::server::engine(&config)?;
            let result =
                cathlab_app::service::replay_stored(&engine, &store, &session, &Default::default())
                    .map_err(|s| anyhow::anyhow!("{}: {}", s.code(), s.message()))?;
            println!(
                "replayed {} steps, {} commands: {}/{} checkpoints match; last digest recorded \
                 {} replayed {}",
                result.steps,
                result.commands,
                result.matched,
                result.checkpoints,
                result.recorded_digest,
                result.replayed_digest
            );
            if result.matched != result.checkpoints {
                anyhow::bail!("replay diverged from the recording");
            }
            Ok(())
        }
    }
}
