//! A running session: its world stepped by a physics thread at a fixed rate, a render thread
//! exposing at the fluoroscopy pulse rate, and latest-value channels out (a slow or stalled
//! reader gets the newest state or frame, never a backlog, and never slows the threads).
//! Commands queue in a bounded channel and apply at step boundaries; each applied command goes
//! to the [`Recorder`] with the step it applied at, and its acknowledgement is sent once the
//! recorder has made it durable.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use cathlab_xray::{Fluoroscope, ImagingMode, Layers};
use parking_lot::Mutex;
use serde::{Deserialize, Serialize};
use tokio::sync::{broadcast, oneshot, watch};

use crate::assets::SceneAssets;
use crate::error::{EngineError, Result};
use crate::imaging::{SharedRenderer, carm_of, layers_of};
// A session's frames and its fluoroscope's settings are the imaging's; re-exported here, where
// clients have found them.
pub use crate::imaging::{RenderedFrame, fluoroscope_settings};
use crate::metrics::{Event, EventKind, Metrics};
use crate::telemetry::{EngineMetrics, SessionTiming};
use crate::world::{Command, Mode, Snapshot, World};

/// An applied command as recorded: the session's `ordinal`-th command, applied at the start of
/// step `step`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CommandRecord {
    /// 0, 1, 2… in application order.
    pub ordinal: u64,
    /// Steps taken before it applied.
    pub step: u64,
    /// The client's sequence number.
    pub seq: u64,
    /// The command.
    pub command: Command,
}

/// The state digest and metrics after a step, recorded every second of simulated time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    /// Steps taken.
    pub step: u64,
    /// [`World::digest`].
    pub digest: u64,
    /// Metrics then.
    pub metrics: Metrics,
}

/// Resolved when a command is applied and durable (or refused).
pub type Ack = oneshot::Sender<Result<CommandRecord>>;

/// Where sessions write what must survive the process: commands, checkpoints, events.
/// Implementations must not block the caller (the physics thread) on I/O.
pub trait Recorder: Send + Sync {
    /// A command was applied; resolve `ack` once it is durable.
    fn command(&self, session: &str, record: CommandRecord, ack: Option<Ack>);
    /// A checkpoint.
    fn checkpoint(&self, session: &str, checkpoint: Checkpoint);
    /// An event.
    fn event(&self, session: &str, event: &Event);
}

/// A command waiting for the next step boundary.
#[derive(Debug)]
pub struct Queued {
    /// Client sequence number.
    pub seq: u64,
    /// The command.
    pub command: Command,
    /// Where to say it applied (and is durable) or was refused.
    pub ack: Option<Ack>,
}

/// Session threads' knobs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionSettings {
    /// Commands that may wait for a step boundary before new ones are refused.
    pub command_queue: usize,
    /// A loop this many periods behind drops the backlog (counted as missed steps) instead of
    /// running steps back to back.
    pub catch_up_periods: u32,
    /// Checkpoint every this many steps (0: one second of simulated time).
    pub checkpoint_every_steps: u64,
    /// How often the render thread looks for a due pulse (s).
    pub render_tick_s: f64,
    /// Commands a session's recording may hold; past it, clients' commands are refused
    /// (RESOURCE_EXHAUSTED) and the dead-man rule stops the device. Bounds the recording
    /// (about 100 bytes a command in SQLite) whatever a client sends.
    pub max_recorded_commands: u64,
    /// Lower the fidelity under load (the overload [`Governor`]); off, a session keeps its
    /// scene's fidelity and a slow machine runs it slower than real time instead.
    pub overload_governor: bool,
}

/// The default bound of a session's recording: an hour of a control stream at 1.1 kHz.
pub const MAX_RECORDED_COMMANDS: u64 = 4_000_000;

impl Default for SessionSettings {
    fn default() -> Self {
        Self {
            command_queue: 4096,
            catch_up_periods: 25,
            checkpoint_every_steps: 0,
            render_tick_s: 0.004,
            max_recorded_commands: MAX_RECORDED_COMMANDS,
            overload_governor: true,
        }
    }
}

/// A running session.
pub struct Session {
    id: String,
    label: String,
    assets: Arc<SceneAssets>,
    created_unix_s: f64,
    commands: SyncSender<Queued>,
    state: watch::Receiver<Arc<Snapshot>>,
    frames: watch::Receiver<Option<Arc<RenderedFrame>>>,
    events: broadcast::Sender<Event>,
    timing: Arc<SessionTiming>,
    stop: Arc<AtomicBool>,
    recorded: Arc<AtomicU64>,
    threads: Mutex<Vec<JoinHandle<()>>>,
    settings: SessionSettings,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session")
            .field("id", &self.id)
            .field("scene", &self.assets.spec.name)
            .finish_non_exhaustive()
    }
}

/// What a session thread needs from the server.
#[derive(Clone)]
pub struct SessionContext {
    /// Durable log.
    pub recorder: Arc<dyn Recorder>,
    /// The renderer all sessions share.
    pub renderer: SharedRenderer,
    /// Server-wide metrics.
    pub metrics: EngineMetrics,
    /// Thread knobs.
    pub settings: SessionSettings,
}

impl Session {
    /// Starts a session's threads on `assets`.
    pub fn start(
        id: String,
        label: String,
        assets: Arc<SceneAssets>,
        context: SessionContext,
    ) -> Result<Arc<Self>> {
        let world = World::new(assets.clone())?;
        let (command_tx, command_rx) = sync_channel(context.settings.command_queue);
        let (state_tx, state_rx) = watch::channel(Arc::new(world.snapshot()));
        let (frame_tx, frame_rx) = watch::channel(None);
        let (events_tx, _) = broadcast::channel(256);
        let timing = Arc::new(SessionTiming::default());
        let stop = Arc::new(AtomicBool::new(false));
        let recorded = Arc::new(AtomicU64::new(0));
        let fluoroscope = Fluoroscope::new(
            Box::new(context.renderer.clone()),
            fluoroscope_settings(&assets),
        )?;
        let short = &id[..8.min(id.len())];
        let physics = PhysicsLoop {
            id: id.clone(),
            world,
            commands: command_rx,
            state: state_tx,
            events: events_tx.clone(),
            timing: timing.clone(),
            stop: stop.clone(),
            recorded: recorded.clone(),
            ctx: context.clone(),
        };
        let render = RenderLoop {
            assets: assets.clone(),
            fluoroscope,
            state: state_rx.clone(),
            frames: frame_tx,
            events: events_tx.clone(),
            timing: timing.clone(),
            stop: stop.clone(),
            ctx: context.clone(),
        };
        let physics = spawn(format!("physics-{short}"), move || physics_loop(physics))?;
        let render = match spawn(format!("render-{short}"), move || render_loop(render)) {
            Ok(handle) => handle,
            Err(e) => {
                stop.store(true, Ordering::SeqCst);
                let _ = physics.join();
                return Err(e);
            }
        };
        context.metrics.sessions.inc();
        let created_unix_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        Ok(Arc::new(Self {
            id,
            label,
            assets,
            created_unix_s,
            commands: command_tx,
            state: state_rx,
            frames: frame_rx,
            events: events_tx,
            timing,
            stop,
            recorded,
            threads: Mutex::new(vec![physics, render]),
            settings: context.settings,
        }))
    }

    /// The session id.
    pub fn id(&self) -> &str {
        &self.id
    }

    /// The label given at creation.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The scene.
    pub fn assets(&self) -> &Arc<SceneAssets> {
        &self.assets
    }

    /// Unix time of creation (s).
    pub fn created_unix_s(&self) -> f64 {
        self.created_unix_s
    }

    /// Whether the threads still run.
    pub fn is_running(&self) -> bool {
        !self.stop.load(Ordering::Relaxed)
    }

    /// Commands applied and handed to the recorder.
    pub fn commands_recorded(&self) -> u64 {
        self.recorded.load(Ordering::Relaxed)
    }

    /// Queues a command for the next step boundary; `ack` hears when it applied and is
    /// durable, or why it was refused.
    pub fn send(&self, seq: u64, command: Command, ack: Option<Ack>) -> Result<()> {
        if !self.is_running() {
            return Err(EngineError::Closed(self.id.clone()));
        }
        if self.commands_recorded() >= self.settings.max_recorded_commands {
            return Err(EngineError::Exhausted(format!(
                "the session's recording is full ({} commands); start a new session",
                self.settings.max_recorded_commands
            )));
        }
        match self.commands.try_send(Queued { seq, command, ack }) {
            Ok(()) => Ok(()),
            Err(TrySendError::Full(_)) => Err(EngineError::QueueFull(self.settings.command_queue)),
            Err(TrySendError::Disconnected(_)) => Err(EngineError::Closed(self.id.clone())),
        }
    }

    /// Queues a command and waits until it applied and is durable.
    pub async fn command(&self, seq: u64, command: Command) -> Result<CommandRecord> {
        let (tx, rx) = oneshot::channel();
        self.send(seq, command, Some(tx))?;
        rx.await.map_err(|_| EngineError::Closed(self.id.clone()))?
    }

    /// The newest state, and a receiver that hears of newer ones.
    pub fn state(&self) -> watch::Receiver<Arc<Snapshot>> {
        self.state.clone()
    }

    /// The newest frame (None before the first exposure).
    pub fn frames(&self) -> watch::Receiver<Option<Arc<RenderedFrame>>> {
        self.frames.clone()
    }

    /// Events from now on.
    pub fn events(&self) -> broadcast::Receiver<Event> {
        self.events.subscribe()
    }

    /// Thread timing.
    pub fn timing(&self) -> &SessionTiming {
        &self.timing
    }

    /// Stops the threads and waits for them; the last state stays readable.
    pub fn close(&self) {
        if !self.stop.swap(true, Ordering::SeqCst) {
            let _ = self.events.send(Event {
                step: self.state.borrow().step,
                time_s: self.state.borrow().time_s,
                kind: EventKind::Closed,
                message: "session closed".into(),
            });
        }
        let threads: Vec<_> = self.threads.lock().drain(..).collect();
        for t in threads {
            let _ = t.join();
        }
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

fn spawn(name: String, body: impl FnOnce() + Send + 'static) -> Result<JoinHandle<()>> {
    std::thread::Builder::new()
        .name(name.clone())
        .spawn(body)
        .map_err(|e| EngineError::Spawn(format!("{name}: {e}")))
}

/// The world's checkpoint now.
fn checkpoint_of(world: &World) -> Checkpoint {
    Checkpoint {
        step: world.step_index(),
        digest: world.digest(),
        metrics: *world.metrics(),
    }
}

/// The overload governor: watches each step's cost against its period and how far the loop
/// is behind, lowers the world's fidelity (a recorded command, so replays agree) before steps
/// are missed, and raises it again once the load has stayed low.
#[derive(Debug)]
pub struct Governor {
    level: u8,
    /// Exponentially weighted step cost over its period (≈ the last 20 steps).
    load: f64,
    /// Steps before the level may change again.
    cooldown: u32,
    /// Steps the load has stayed low.
    calm: u32,
    /// Steps of low load before the level goes back up.
    calm_steps: u32,
    /// The backlog (periods) when the level last dropped for one: a backlog lowers it again
    /// only if it has not shrunk since (a loop catching up after one stall is not
    /// overloaded).
    backlog_at_drop: f64,
}

impl Governor {
    /// Load above which (or a backlog of more than `BEHIND_PERIODS` steps) the level drops.
    pub const HIGH: f64 = 0.7;
    /// Load below which the level may rise again.
    pub const LOW: f64 = 0.25;
    /// Backlog (periods) that lowers the level at once.
    pub const BEHIND_PERIODS: f64 = 5.0;

    /// A governor for a loop at `rate_hz`: the level rises again after 5 s of low load.
    pub fn new(rate_hz: f64) -> Self {
        Self {
            level: 0,
            load: 0.0,
            cooldown: 0,
            calm: 0,
            calm_steps: (5.0 * rate_hz) as u32,
            backlog_at_drop: 0.0,
        }
    }

    /// After a step that took `load` of its period with the loop `behind` periods late:
    /// the new level, when it changes.
    pub fn update(&mut self, load: f64, behind: f64) -> Option<u8> {
        self.load = 0.95 * self.load + 0.05 * load;
        self.cooldown = self.cooldown.saturating_sub(1);
        if self.load < Self::LOW && behind < 1.0 {
            self.calm += 1;
        } else {
            self.calm = 0;
        }
        if behind < 1.0 {
            self.backlog_at_drop = 0.0;
        }
        if self.cooldown > 0 {
            return None;
        }
        let backlog = behind > Self::BEHIND_PERIODS && behind >= self.backlog_at_drop;
        if (self.load > Self::HIGH || backlog) && self.level < crate::world::MAX_FIDELITY_LEVEL {
            if backlog {
                self.backlog_at_drop = behind;
            }
            self.level += 1;
            // Give the cheaper steps time to show in the load before judging again.
            self.cooldown = 50;
            self.load = Self::HIGH * 0.9;
            return Some(self.level);
        }
        if self.calm >= self.calm_steps && self.level > 0 {
            self.level -= 1;
            self.calm = 0;
            self.cooldown = 50;
            return Some(self.level);
        }
        None
    }
}

struct PhysicsLoop {
    id: String,
    world: World,
    commands: Receiver<Queued>,
    state: watch::Sender<Arc<Snapshot>>,
    events: broadcast::Sender<Event>,
    timing: Arc<SessionTiming>,
    stop: Arc<AtomicBool>,
    recorded: Arc<AtomicU64>,
    ctx: SessionContext,
}

fn physics_loop(mut p: PhysicsLoop) {
    let dt = p.world.assets().spec.time_step_s();
    let period = Duration::from_secs_f64(dt);
    let every = match p.ctx.settings.checkpoint_every_steps {
        0 => (1.0 / dt).round().max(1.0) as u64,
        n => n,
    };
    let catch_up = period * p.ctx.settings.catch_up_periods;
    let mut governor = Governor::new(1.0 / dt);
    let mut ordinal = 0u64;
    let mut next = Instant::now();
    while !p.stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        }
        let started = Instant::now();
        let lag = started.saturating_duration_since(next);
        if lag >= period {
            p.timing.late();
            p.ctx.metrics.late_steps.inc();
        }
        if lag > catch_up {
            let dropped = (lag.as_secs_f64() / dt) as u64;
            p.timing.missed(dropped);
            p.ctx.metrics.missed_steps.inc_by(dropped);
            next = started;
        }
        // Commands apply at the step boundary, in arrival order.
        while let Ok(q) = p.commands.try_recv() {
            let step = p.world.step_index();
            match p.world.apply(q.seq, &q.command) {
                Ok(()) => {
                    let record = CommandRecord {
                        ordinal,
                        step,
                        seq: q.seq,
                        command: q.command,
                    };
                    ordinal += 1;
                    p.recorded.fetch_add(1, Ordering::Relaxed);
                    p.ctx.metrics.commands.inc();
                    p.ctx.recorder.command(&p.id, record, q.ack);
                }
                Err(e) => {
                    if let Some(ack) = q.ack {
                        let _ = ack.send(Err(e));
                    }
                }
            }
        }
        let outcome = p.world.step();
        for event in p.world.take_events() {
            if event.kind == EventKind::Divergence {
                p.ctx.metrics.divergences.inc();
                tracing::warn!(session = %p.id, "{}", event.message);
            }
            p.ctx.recorder.event(&p.id, &event);
            let _ = p.events.send(event);
        }
        if let Err(e) = outcome {
            // Only flow/contrast errors reach here (physics divergence resets inside); report
            // and stop stepping rather than stream a broken state.
            tracing::error!(session = %p.id, "session stopped: {e}");
            let event = Event {
                step: p.world.step_index(),
                time_s: p.world.metrics().procedure_time_s,
                kind: EventKind::Divergence,
                message: format!("session stopped: {e}"),
            };
            p.ctx.recorder.event(&p.id, &event);
            let _ = p.events.send(event);
            p.stop.store(true, Ordering::SeqCst);
            break;
        }
        p.state.send_replace(Arc::new(p.world.snapshot()));
        if p.world.step_index().is_multiple_of(every) {
            p.ctx.recorder.checkpoint(&p.id, checkpoint_of(&p.world));
        }
        let took = started.elapsed().as_secs_f64();
        p.timing.step(took);
        p.ctx.metrics.step_seconds.observe(took);
        next += period;
        // The governor's command applies at this step boundary, recorded like the others.
        let behind = Instant::now().saturating_duration_since(next).as_secs_f64() / dt;
        let change = if p.ctx.settings.overload_governor {
            governor.update(took / dt, behind)
        } else {
            None
        };
        if let Some(level) = change {
            let (step, seq, command) = (
                p.world.step_index(),
                p.world.last_seq(),
                Command::Fidelity(level),
            );
            if p.world.apply(seq, &command).is_ok() {
                let record = CommandRecord {
                    ordinal,
                    step,
                    seq,
                    command,
                };
                ordinal += 1;
                // Not counted among the operator's commands.
                p.ctx.metrics.fidelity_changes.inc();
                p.ctx.recorder.command(&p.id, record, None);
                for event in p.world.take_events() {
                    tracing::warn!(session = %p.id, "{}", event.message);
                    p.ctx.recorder.event(&p.id, &event);
                    let _ = p.events.send(event);
                }
            }
        }
    }
    // Refuse what is still queued.
    while let Ok(q) = p.commands.try_recv() {
        if let Some(ack) = q.ack {
            let _ = ack.send(Err(EngineError::Closed(p.id.clone())));
        }
    }
    p.ctx.recorder.checkpoint(&p.id, checkpoint_of(&p.world));
    p.ctx.metrics.sessions.dec();
}

struct RenderLoop {
    assets: Arc<SceneAssets>,
    fluoroscope: Fluoroscope,
    state: watch::Receiver<Arc<Snapshot>>,
    frames: watch::Sender<Option<Arc<RenderedFrame>>>,
    events: broadcast::Sender<Event>,
    timing: Arc<SessionTiming>,
    stop: Arc<AtomicBool>,
    ctx: SessionContext,
}

fn render_loop(mut r: RenderLoop) {
    crate::priority::lower_current_thread(crate::priority::RENDER_NICE);
    let tick = Duration::from_secs_f64(r.ctx.settings.render_tick_s);
    let empty = Layers::new();
    let mut mode = Mode::Fluoroscopy;
    let mut dsa_run = 0;
    let mut pulse_rate = r.fluoroscope.settings().pulse_rate;
    let mut last_index = None;
    let mut last_held = false;
    while !r.stop.load(Ordering::Relaxed) {
        std::thread::sleep(tick);
        let snapshot = r.state.borrow().clone();
        let carm = carm_of(&r.assets, &snapshot);
        let imaging = snapshot.imaging;
        if imaging.pulse_rate != pulse_rate {
            r.fluoroscope.set_pulse_rate(imaging.pulse_rate);
            pulse_rate = imaging.pulse_rate;
        }
        if imaging.mode != mode || imaging.dsa_run != dsa_run {
            let wanted = match imaging.mode {
                Mode::Fluoroscopy => ImagingMode::Fluoroscopy,
                Mode::Subtraction => ImagingMode::Subtraction,
                Mode::Roadmap => ImagingMode::Roadmap,
            };
            if let Err(e) = r.fluoroscope.set_mode(wanted, &carm) {
                let _ = r.events.send(Event {
                    step: snapshot.step,
                    time_s: snapshot.time_s,
                    kind: EventKind::Imaging,
                    message: e.to_string(),
                });
            }
            mode = imaging.mode;
            dsa_run = imaging.dsa_run;
        }
        // A DSA run exposes whether or not the fluoroscopy pedal is down.
        let exposing = imaging.pedal || imaging.mode == Mode::Subtraction;
        let due = exposing && r.fluoroscope.pulse_due(snapshot.time_s);
        let layers = if due {
            match layers_of(&r.assets, &snapshot) {
                Ok(l) => l,
                Err(e) => {
                    tracing::warn!("layers: {e}");
                    continue;
                }
            }
        } else {
            Layers::new()
        };
        let started = Instant::now();
        let shot = cathlab_xray::Scene {
            volume: &r.assets.volume,
            carm: &carm,
            layers: if due { &layers } else { &empty },
        };
        match r.fluoroscope.update(snapshot.time_s, exposing, shot) {
            Ok(Some(frame)) => {
                let fresh = last_index != Some(frame.index) || last_held != frame.held;
                if due {
                    let took = started.elapsed().as_secs_f64();
                    r.timing.frame(took);
                    r.ctx.metrics.frame_seconds.observe(took);
                }
                if fresh {
                    last_index = Some(frame.index);
                    last_held = frame.held;
                    r.frames.send_replace(Some(Arc::new(RenderedFrame {
                        frame: frame.clone(),
                        last_seq: snapshot.last_seq,
                        step: snapshot.step,
                        dose: r.fluoroscope.dose(),
                        target_outline: target_outline(&r.assets, &carm),
                    })));
                }
            }
            Ok(None) => {}
            Err(e) => {
                let _ = r.events.send(Event {
                    step: snapshot.step,
                    time_s: snapshot.time_s,
                    kind: EventKind::Imaging,
                    message: format!("exposure failed: {e}"),
                });
            }
        }
    }
}

/// The scene's target path projected by `carm` into image fractions (empty when the scene's
/// guidance hides the marker).
pub fn target_outline(assets: &SceneAssets, carm: &cathlab_xray::CArm) -> Vec<[f32; 2]> {
    if !assets.spec.guidance.target_marker {
        return Vec::new();
    }
    let (w, h) = (
        f64::from(carm.detector.width_px),
        f64::from(carm.detector.height_px),
    );
    let projection = carm.projection_matrix();
    assets
        .target_path_lps
        .iter()
        .filter_map(|p| {
            let q = projection * p.to_homogeneous();
            (q.z > 0.0).then(|| {
                [
                    ((q.x / q.z + 0.5) / w) as f32,
                    ((q.y / q.z + 0.5) / h) as f32,
                ]
            })
        })
        .collect()
}
