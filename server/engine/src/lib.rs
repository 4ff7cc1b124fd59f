//! The cathlab engine: scenes, a session's deterministic world (device physics, flow and
//! contrast, imaging state, metrics), the threads that run it (a fixed-rate physics loop and a
//! render loop per session) with latest-value channels out, recording through a [`Recorder`],
//! and replay. The only crate that knows both the simulation and the renderer; no networking.

pub mod assets;
pub mod check;
pub mod engine;
pub mod error;
pub mod imaging;
pub mod metrics;
pub mod priority;
pub mod replay;
pub mod report;
pub mod scene;
pub mod session;
pub mod strand;
pub mod stress;
pub mod telemetry;
pub mod thrombectomy;
pub mod world;

pub use assets::{AssetCache, SceneAssets};
pub use engine::{Engine, EngineSettings, ReplayPermit};
pub use error::{EngineError, Result};
pub use imaging::{Encoded, Encoding, RenderedFrame, SharedRenderer, encode_frame, encode_in_pool};
pub use metrics::{Event, EventKind, Metrics};
pub use replay::{ReplayOutcome, replay, replay_until};
pub use report::{ReplayFrame, ReportOptions, SessionReport, assess, expert_run};
pub use scene::{SceneCatalog, SceneFormat, SceneSpec};
pub use session::{Checkpoint, CommandRecord, Recorder, Session, SessionSettings};
pub use strand::Strand;
pub use telemetry::{EngineMetrics, TimingSummary};
pub use world::{Command, Drive, InstrumentState, Mode, Snapshot, World};
