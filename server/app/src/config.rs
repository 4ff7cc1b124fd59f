//! Server configuration: a TOML file, overridden by command-line flags and environment; every
//! limit and its default (the service and the rest of the server read them from here).

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

/// Which renderer the sessions share.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, clap::ValueEnum, Default)]
#[serde(rename_all = "snake_case")]
pub enum RendererChoice {
    /// wgpu when an adapter exists, else the CPU reference.
    #[default]
    Auto,
    /// The CPU reference renderer.
    Cpu,
    /// wgpu (an error when no adapter exists).
    Gpu,
}

/// Who may create a session from a scene text (an inline scene) rather than a listed scene.
/// Inline scenes can name heavy work (a CT segmented at load, a fine phantom), so they are
/// for instructors unless the server says otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, clap::ValueEnum, Default)]
#[serde(rename_all = "snake_case")]
pub enum InlineScenes {
    /// Nobody: only the listed scenes.
    Off,
    /// Callers with the instructor key.
    #[default]
    Instructors,
    /// Anyone (a trusted network).
    Anyone,
}

/// TLS certificate and key (PEM files).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlsFiles {
    /// Certificate chain.
    pub cert: PathBuf,
    /// Private key.
    pub key: PathBuf,
}

/// The configuration file's contents; every field optional.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConfigFile {
    /// Address to listen on (`127.0.0.1:50051`; port 0 picks a free port).
    pub listen: Option<String>,
    /// SQLite database file.
    pub database: Option<PathBuf>,
    /// A PostgreSQL database shared by a fleet of servers
    /// (`postgres://user:password@host:port/database`; also `CATHLAB_DATABASE_URL`); when set,
    /// it is the store and `database` is not used.
    pub database_url: Option<String>,
    /// This server's id in a fleet sharing a PostgreSQL store (default: the host name; `local`
    /// on SQLite). Stable across restarts; several servers on one host need their own.
    pub server_id: Option<String>,
    /// Where clients reach this server (`http://host:port`), as the fleet's other servers
    /// list it (default: the address it listens on).
    pub advertise: Option<String>,
    /// Speak the Agones SDK to the sidecar on `localhost:$AGONES_SDK_GRPC_PORT` (a
    /// GameServer of an Agones Fleet): Ready once warm, Health while the physics loops keep
    /// time, Allocated while it runs sessions, the `sessions` counter, Shutdown at exit.
    pub agones: Option<bool>,
    /// How long the Agones sidecar may take to answer at start, in seconds (default 30; it
    /// may start after the server's container).
    pub agones_connect_timeout_s: Option<u64>,
    /// Scenes to load at start, before the server counts as ready (their anatomy and CT
    /// built once, so the first trainee does not wait for them).
    pub warm_scenes: Option<Vec<String>>,
    /// Scene directory.
    pub scenes: Option<PathBuf>,
    /// The instructor key (also `CATHLAB_INSTRUCTOR_KEY`).
    pub instructor_key: Option<String>,
    /// TLS; plaintext when absent.
    pub tls: Option<TlsFiles>,
    /// Renderer.
    pub renderer: Option<RendererChoice>,
    /// Lower a session's fidelity when its steps cannot keep time (default on). Off, every
    /// session keeps its scene's fidelity and a slow machine runs it slower than real time
    /// (assessments where every trainee must get the same physics; tests of a procedure).
    pub overload_governor: Option<bool>,
    /// Most sessions at once.
    pub max_sessions: Option<usize>,
    /// Most replays at once.
    pub max_replays: Option<usize>,
    /// Most commands one session's recording holds.
    pub max_recorded_commands: Option<u64>,
    /// Largest request message (bytes).
    pub max_message_bytes: Option<usize>,
    /// The built web client (`client-web/dist`), served at `/`.
    pub web_root: Option<PathBuf>,
    /// Who may create sessions from scene texts.
    pub inline_scenes: Option<InlineScenes>,
    /// Memory the shared scene assets (anatomies, CT volumes) may hold beyond what running
    /// sessions use (MiB); a scene estimated larger is refused before loading.
    pub asset_cache_mib: Option<usize>,
    /// Directories whose files scenes may name (default: the scenes directory and `data`
    /// beside it).
    pub data_roots: Option<Vec<PathBuf>>,
    /// Where anatomies that take long to build (the neuro phantom's, ~30 s) are kept between
    /// runs, keyed by a hash of the code that builds them and their parameters, so that a
    /// restart reads them back in seconds (also `CATHLAB_ASSET_DISK_CACHE`; none by default:
    /// each is about 0.5 GB).
    pub asset_disk_cache: Option<PathBuf>,
    /// Most space the disk cache's files take together (MiB); past it the least recently
    /// used are removed.
    pub asset_disk_cache_mib: Option<u64>,
    /// Wrong instructor keys or tokens one address may send a minute before it is refused.
    pub auth_failures_per_minute: Option<u32>,
    /// How long a control stream may go quiet before its setpoints are zeroed (ms).
    pub control_timeout_ms: Option<u64>,
    /// Memory all frame streams' encoded frames may hold together (MiB).
    pub stream_buffer_mib: Option<usize>,
    /// Control inputs one stream may send a second.
    pub control_inputs_per_second: Option<u32>,
    /// Web origins whose pages may call the API (CORS); none by default.
    pub cors_origins: Option<Vec<String>>,
    /// How long a frame may wait for its reader before the reader's connection is cut (ms).
    pub stream_stall_timeout_ms: Option<u64>,
    /// The scene a client starts when its user names none (must be listed).
    pub default_scene: Option<String>,
    /// How long a running session may go without its controller (no stream open with its
    /// controller token, no call with it) before the server closes it (s; 0: never).
    pub unattended_session_timeout_s: Option<u64>,
    /// Most bytes one data file (a surface, a CT, a scene) may have (MiB).
    pub max_file_mib: Option<u64>,
    /// Most bytes compressed data (zlib, gzip, VTK blocks) may inflate to (MiB; never more
    /// than `asset_cache_mib`).
    pub max_inflated_mib: Option<u64>,
    /// Most voxels one CT volume may hold (never more than `asset_cache_mib` holds as f32).
    pub max_volume_voxels: Option<u64>,
    /// Most connections open at once.
    pub max_connections: Option<usize>,
    /// Most connections open at once from one address (a trusted proxy is not limited).
    pub max_connections_per_address: Option<usize>,
    /// How long a connection may pass no byte either way before it is closed (s).
    pub connection_idle_timeout_s: Option<u64>,
    /// Most concurrent HTTP/2 streams on one connection.
    pub http2_max_streams: Option<u32>,
    /// Memory the request messages still arriving may hold, all connections together (MiB).
    pub request_buffer_mib: Option<usize>,
    /// How long one request message may take to arrive once its first byte has (s).
    pub message_read_timeout_s: Option<u64>,
    /// Proxies (IP addresses, or ranges such as `10.0.0.0/8`) whose `X-Forwarded-For` header
    /// names the real client: behind them, throttles and per-address limits apply to that
    /// client, not to the proxy.
    pub trusted_proxies: Option<Vec<crate::connections::ProxyRange>>,
    /// Most running sessions one client (an account, else an address) may have created;
    /// instructors are not limited (default: half of `max_sessions`).
    pub max_sessions_per_client: Option<usize>,
    /// Most sessions one client may create a minute (instructors are not limited).
    pub session_creations_per_minute: Option<u32>,
    /// Ended anonymous sessions the store keeps (the oldest beyond are deleted with their
    /// recordings; a trainee account's go only by age).
    pub max_recorded_anonymous_sessions: Option<usize>,
    /// Days an ended session is kept (0: until pruned by count).
    pub recorded_session_retention_days: Option<f64>,
}

impl ConfigFile {
    /// Reads a configuration file; errors name the file and the field.
    pub fn read(file: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(file)
            .map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))?;
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))
    }
}

/// The resolved configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct ServerConfig {
    /// Address to listen on.
    pub listen: String,
    /// SQLite database file.
    pub database: PathBuf,
    /// A PostgreSQL database URL; when set, the store instead of `database`.
    pub database_url: Option<String>,
    /// This server's id in the fleet, if set.
    pub server_id: Option<String>,
    /// Where clients reach this server, if not where it listens.
    pub advertise: Option<String>,
    /// Speak the Agones SDK (see [`ConfigFile::agones`]).
    pub agones: bool,
    /// How long the sidecar may take to answer at start, in seconds.
    pub agones_connect_timeout_s: u64,
    /// Scenes loaded at start (see [`ConfigFile::warm_scenes`]).
    pub warm_scenes: Vec<String>,
    /// Scene directory.
    pub scenes: PathBuf,
    /// Instructor key, if any.
    pub instructor_key: Option<String>,
    /// TLS files, if any.
    pub tls: Option<TlsFiles>,
    /// Renderer.
    pub renderer: RendererChoice,
    /// Lower fidelity under load (see [`ConfigFile::overload_governor`]).
    pub overload_governor: bool,
    /// Most sessions at once.
    pub max_sessions: usize,
    /// Most replays at once (each takes a core, niced below live physics).
    pub max_replays: usize,
    /// Most commands one session's recording holds (about 100 bytes each); past it the
    /// session refuses commands (RESOURCE_EXHAUSTED).
    pub max_recorded_commands: u64,
    /// Largest request message (bytes).
    pub max_message_bytes: usize,
    /// The built web client, served at `/` (a note page when it is not built).
    pub web_root: PathBuf,
    /// Who may create sessions from scene texts.
    pub inline_scenes: InlineScenes,
    /// Memory budget of the shared scene assets (MiB).
    pub asset_cache_mib: usize,
    /// Directories whose files scenes may name; empty: the scenes directory and `data`
    /// beside it.
    pub data_roots: Vec<PathBuf>,
    /// Where anatomies that take long to build are kept between runs (none: rebuilt each run).
    pub asset_disk_cache: Option<PathBuf>,
    /// Most space the disk cache's files take together (MiB).
    pub asset_disk_cache_mib: u64,
    /// Wrong instructor keys or tokens one address may send a minute before it is refused.
    pub auth_failures_per_minute: u32,
    /// How long a control stream may go quiet before its setpoints are zeroed (ms).
    pub control_timeout_ms: u64,
    /// Memory all frame streams' encoded frames may hold together (MiB).
    pub stream_buffer_mib: usize,
    /// Control inputs one stream may send a second.
    pub control_inputs_per_second: u32,
    /// Web origins whose pages may call the API (CORS); the built-in web client is
    /// same-origin and needs none.
    pub cors_origins: Vec<String>,
    /// How long a frame may wait for its reader before the reader's connection is cut (ms).
    pub stream_stall_timeout_ms: u64,
    /// The scene a client starts when its user names none; `None`: `DEFAULT_SCENE` when
    /// the scene directory has it, else its first scene. A named scene must be listed.
    pub default_scene: Option<String>,
    /// How long a running session may go without its controller before the server closes
    /// it (s; 0: never).
    pub unattended_session_timeout_s: u64,
    /// Most bytes one data file may have (MiB).
    pub max_file_mib: u64,
    /// Most bytes compressed data may inflate to (MiB).
    pub max_inflated_mib: u64,
    /// Most voxels one CT volume may hold.
    pub max_volume_voxels: u64,
    /// Most connections open at once.
    pub max_connections: usize,
    /// Most connections open at once from one address (trusted proxies excepted).
    pub max_connections_per_address: usize,
    /// How long a connection may pass no byte either way before it is closed (s).
    pub connection_idle_timeout_s: u64,
    /// Most concurrent HTTP/2 streams on one connection.
    pub http2_max_streams: u32,
    /// Memory the request messages still arriving may hold together (MiB).
    pub request_buffer_mib: usize,
    /// How long one request message may take to arrive once its first byte has (s).
    pub message_read_timeout_s: u64,
    /// Proxies whose `X-Forwarded-For` names the real client.
    pub trusted_proxies: Vec<crate::connections::ProxyRange>,
    /// Most running sessions one client may have created (`None`: half of `max_sessions`).
    pub max_sessions_per_client: Option<usize>,
    /// Most sessions one client may create a minute.
    pub session_creations_per_minute: u32,
    /// Ended anonymous sessions the store keeps.
    pub max_recorded_anonymous_sessions: usize,
    /// Days an ended session is kept (0: until pruned by count).
    pub recorded_session_retention_days: f64,
}

/// The scene clients start by default: the coaxial approach to the left common carotid.
pub const DEFAULT_SCENE: &str = "arch_to_cow_lcca_coaxial";

/// Wrong keys or tokens one address may send a minute before it is refused.
pub const AUTH_FAILURES_PER_MINUTE: u32 = 20;

/// The bytes all frame streams' encoded frames may hold together (the configuration's
/// default).
pub const STREAM_BUFFER_BYTES: usize = 256 << 20;

/// How long an encoded frame may wait for its reader before the reader's connection is cut
/// (the configuration's default).
pub const STREAM_STALL: Duration = Duration::from_secs(10);

/// Control inputs one stream may send a second (the configuration's default): twice the
/// haptic bridge's 1 kHz, which is already more than the 500 Hz physics can apply.
pub const CONTROL_INPUTS_PER_SECOND: u32 = 2000;

/// How long a running session may go without its controller (no stream open with its
/// controller token, no call with it) before the server closes it (the configuration's
/// default): a trainee whose network dropped has this long to come back.
pub const UNATTENDED_SESSION_TIMEOUT: Duration = Duration::from_secs(600);

/// How long a control stream may go quiet before its setpoints are zeroed (the dead-man
/// rule; the configuration's default).
pub const CONTROL_TIMEOUT: Duration = Duration::from_millis(250);

impl Default for ServerConfig {
    fn default() -> Self {
        Self {
            listen: "127.0.0.1:50051".into(),
            database: PathBuf::from("var/cathlab.sqlite"),
            database_url: None,
            server_id: None,
            advertise: None,
            agones: false,
            agones_connect_timeout_s: 30,
            warm_scenes: Vec::new(),
            scenes: PathBuf::from("scenes"),
            instructor_key: None,
            tls: None,
            renderer: RendererChoice::Auto,
            overload_governor: true,
            max_sessions: 16,
            max_replays: 1,
            max_recorded_commands: cathlab_engine::session::MAX_RECORDED_COMMANDS,
            max_message_bytes: 1 << 20,
            web_root: PathBuf::from("client-web/dist"),
            inline_scenes: InlineScenes::Instructors,
            asset_cache_mib: 2048,
            data_roots: Vec::new(),
            asset_disk_cache: None,
            asset_disk_cache_mib: 8192,
            auth_failures_per_minute: AUTH_FAILURES_PER_MINUTE,
            control_timeout_ms: CONTROL_TIMEOUT.as_millis() as u64,
            stream_buffer_mib: STREAM_BUFFER_BYTES >> 20,
            control_inputs_per_second: CONTROL_INPUTS_PER_SECOND,
            cors_origins: Vec::new(),
            stream_stall_timeout_ms: STREAM_STALL.as_millis() as u64,
            default_scene: None,
            unattended_session_timeout_s: UNATTENDED_SESSION_TIMEOUT.as_secs(),
            max_file_mib: 2048,
            max_inflated_mib: 2048,
            max_volume_voxels: 1 << 28,
            max_connections: 512,
            max_connections_per_address: 32,
            connection_idle_timeout_s: 30,
            http2_max_streams: 32,
            request_buffer_mib: 128,
            message_read_timeout_s: 10,
            trusted_proxies: Vec::new(),
            max_sessions_per_client: None,
            session_creations_per_minute: 30,
            max_recorded_anonymous_sessions: 20_000,
            recorded_session_retention_days: 0.0,
        }
    }
}

impl ServerConfig {
    /// How long a running session may go without its controller before it is closed
    /// (`None`: never).
    pub fn unattended_timeout(&self) -> Option<std::time::Duration> {
        (self.unattended_session_timeout_s > 0)
            .then(|| std::time::Duration::from_secs(self.unattended_session_timeout_s))
    }

    /// The default scene among `listed` (scene names in the directory's order): the one
    /// named, `DEFAULT_SCENE` or the first; an error names a named scene that is not listed.
    pub fn resolve_default_scene(&self, listed: &[&str]) -> anyhow::Result<String> {
        match &self.default_scene {
            Some(name) if listed.contains(&name.as_str()) => Ok(name.clone()),
            Some(name) => anyhow::bail!(
                "default_scene: no scene named {name:?} in {} (it has: {})",
                self.scenes.display(),
                listed.join(", ")
            ),
            None if listed.contains(&DEFAULT_SCENE) => Ok(DEFAULT_SCENE.into()),
            None => Ok(listed.first().map_or_else(String::new, |s| (*s).to_owned())),
        }
    }

    /// Most running sessions one client may have created: as configured, else half of
    /// `max_sessions` (at least one), so that one client never holds every place.
    pub fn sessions_per_client(&self) -> usize {
        self.max_sessions_per_client
            .unwrap_or(self.max_sessions / 2)
            .max(1)
    }

    /// What the file readers may read and allocate: the configured limits, the inflated
    /// bytes and the voxels (as f32) never more than the asset budget.
    pub fn read_limits(&self) -> cathlab_anatomy::io::limits::ReadLimits {
        let budget = (self.asset_cache_mib as u64) << 20;
        cathlab_anatomy::io::limits::ReadLimits {
            max_file_bytes: self.max_file_mib << 20,
            max_inflated_bytes: (self.max_inflated_mib << 20).min(budget),
            max_voxels: self.max_volume_voxels.min(budget / 4),
        }
    }

    /// Where the store is: the PostgreSQL database if a URL is set, else the SQLite file.
    pub fn store_location(&self) -> crate::store::StoreLocation {
        match &self.database_url {
            Some(url) => crate::store::StoreLocation::Postgres(url.clone()),
            None => crate::store::StoreLocation::Sqlite(self.database.clone()),
        }
    }

    /// This server's id in the fleet: as configured; else `local` on SQLite (one server per
    /// file) and the host name on PostgreSQL — stable across restarts, so that a server
    /// started again marks the sessions its previous process left running interrupted (a pod
    /// keeps its name; several servers on one host need their own `--server-id`).
    pub fn resolved_server_id(&self) -> String {
        match (&self.server_id, &self.database_url) {
            (Some(id), _) => id.clone(),
            (None, None) => crate::store::LOCAL_SERVER.to_owned(),
            (None, Some(_)) => std::env::var("HOSTNAME")
                .ok()
                .filter(|h| !h.is_empty())
                .or_else(|| {
                    std::fs::read_to_string("/etc/hostname")
                        .ok()
                        .map(|h| h.trim().to_owned())
                })
                .unwrap_or_else(|| "cathlab".into()),
        }
    }

    /// Defaults, overridden by the file's fields.
    pub fn from_file(file: ConfigFile) -> Self {
        let d = Self::default();
        Self {
            listen: file.listen.unwrap_or(d.listen),
            database: file.database.unwrap_or(d.database),
            database_url: file.database_url,
            server_id: file.server_id,
            advertise: file.advertise,
            agones: file.agones.unwrap_or(d.agones),
            agones_connect_timeout_s: file
                .agones_connect_timeout_s
                .unwrap_or(d.agones_connect_timeout_s),
            warm_scenes: file.warm_scenes.unwrap_or(d.warm_scenes),
            scenes: file.scenes.unwrap_or(d.scenes),
            instructor_key: file.instructor_key,
            tls: file.tls,
            renderer: file.renderer.unwrap_or(d.renderer),
            overload_governor: file.overload_governor.unwrap_or(d.overload_governor),
            max_sessions: file.max_sessions.unwrap_or(d.max_sessions),
            max_replays: file.max_replays.unwrap_or(d.max_replays),
            max_recorded_commands: file
                .max_recorded_commands
                .unwrap_or(d.max_recorded_commands),
            max_message_bytes: file.max_message_bytes.unwrap_or(d.max_message_bytes),
            web_root: file.web_root.unwrap_or(d.web_root),
            inline_scenes: file.inline_scenes.unwrap_or(d.inline_scenes),
            asset_cache_mib: file.asset_cache_mib.unwrap_or(d.asset_cache_mib),
            data_roots: file.data_roots.unwrap_or(d.data_roots),
            asset_disk_cache: file.asset_disk_cache.or(d.asset_disk_cache),
            asset_disk_cache_mib: file.asset_disk_cache_mib.unwrap_or(d.asset_disk_cache_mib),
            auth_failures_per_minute: file
                .auth_failures_per_minute
                .unwrap_or(d.auth_failures_per_minute),
            control_timeout_ms: file.control_timeout_ms.unwrap_or(d.control_timeout_ms),
            stream_buffer_mib: file.stream_buffer_mib.unwrap_or(d.stream_buffer_mib),
            control_inputs_per_second: file
                .control_inputs_per_second
                .unwrap_or(d.control_inputs_per_second),
            cors_origins: file.cors_origins.unwrap_or(d.cors_origins),
            stream_stall_timeout_ms: file
                .stream_stall_timeout_ms
                .unwrap_or(d.stream_stall_timeout_ms),
            default_scene: file.default_scene,
            unattended_session_timeout_s: file
                .unattended_session_timeout_s
                .unwrap_or(d.unattended_session_timeout_s),
            max_file_mib: file.max_file_mib.unwrap_or(d.max_file_mib),
            max_inflated_mib: file.max_inflated_mib.unwrap_or(d.max_inflated_mib),
            max_volume_voxels: file.max_volume_voxels.unwrap_or(d.max_volume_voxels),
            max_connections: file.max_connections.unwrap_or(d.max_connections),
            max_connections_per_address: file
                .max_connections_per_address
                .unwrap_or(d.max_connections_per_address),
            connection_idle_timeout_s: file
                .connection_idle_timeout_s
                .unwrap_or(d.connection_idle_timeout_s),
            http2_max_streams: file.http2_max_streams.unwrap_or(d.http2_max_streams),
            request_buffer_mib: file.request_buffer_mib.unwrap_or(d.request_buffer_mib),
            message_read_timeout_s: file
                .message_read_timeout_s
                .unwrap_or(d.message_read_timeout_s),
            trusted_proxies: file.trusted_proxies.unwrap_or(d.trusted_proxies),
            max_sessions_per_client: file.max_sessions_per_client,
            session_creations_per_minute: file
                .session_creations_per_minute
                .unwrap_or(d.session_creations_per_minute),
            max_recorded_anonymous_sessions: file
                .max_recorded_anonymous_sessions
                .unwrap_or(d.max_recorded_anonymous_sessions),
            recorded_session_retention_days: file
                .recorded_session_retention_days
                .unwrap_or(d.recorded_session_retention_days),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_configuration_files_name_the_file_and_the_field() {
        let dir = std::env::temp_dir().join(format!("cathlab-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("server.toml");
        for (text, expected) in [
            ("max_sessions = \"many\"\n", "max_sessions"),
            ("listen = \"127.0.0.1:1\"\nport = 3\n", "port"),
            ("renderer = \"quantum\"\n", "renderer"),
            ("[tls]\ncert = \"a.pem\"\n", "key"),
            (
                "unattended_session_timeout_s = -5\n",
                "unattended_session_timeout_s",
            ),
        ] {
            std::fs::write(&file, text).unwrap();
            let message = ConfigFile::read(&file).unwrap_err().to_string();
            assert!(message.contains("server.toml"), "{message}");
            assert!(message.contains(expected), "{expected}: {message}");
        }
        let missing = ConfigFile::read(&dir.join("absent.toml")).unwrap_err();
        assert!(missing.to_string().contains("absent.toml"));
        std::fs::write(&file, "listen = \"0.0.0.0:50051\"\nmax_sessions = 3\n").unwrap();
        let config = ServerConfig::from_file(ConfigFile::read(&file).unwrap());
        assert_eq!(
            (config.listen.as_str(), config.max_sessions),
            ("0.0.0.0:50051", 3)
        );
        assert_eq!(config.database, ServerConfig::default().database);
        assert_eq!(
            config.unattended_timeout(),
            Some(std::time::Duration::from_secs(600))
        );
        std::fs::write(&file, "unattended_session_timeout_s = 0\n").unwrap();
        let never = ServerConfig::from_file(ConfigFile::read(&file).unwrap());
        assert_eq!(never.unattended_timeout(), None, "0 turns the sweep off");
    }

    #[test]
    fn the_default_scene_is_named_listed_or_first() {
        let listed = ["arch_to_cow_lcca", DEFAULT_SCENE, "neuro_phantom_m1"];
        let mut config = ServerConfig::default();
        assert_eq!(
            config.resolve_default_scene(&listed).unwrap(),
            DEFAULT_SCENE
        );
        assert_eq!(
            config
                .resolve_default_scene(&["b_scene", "a_scene"])
                .unwrap(),
            "b_scene"
        );
        assert_eq!(config.resolve_default_scene(&[]).unwrap(), "");
        config.default_scene = Some("neuro_phantom_m1".into());
        assert_eq!(
            config.resolve_default_scene(&listed).unwrap(),
            "neuro_phantom_m1"
        );
        config.default_scene = Some("nowhere".into());
        let message = config
            .resolve_default_scene(&listed)
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("default_scene") && message.contains("\"nowhere\""),
            "{message}"
        );
    }
}
