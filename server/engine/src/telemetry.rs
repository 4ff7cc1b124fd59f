//! Timing of the session threads: per-session percentiles (HDR histograms) for the API and the
//! load benchmark, and server-wide Prometheus families (step and frame time histograms,
//! sessions, frames sent and skipped, late and missed steps).

use std::sync::atomic::{AtomicU64, Ordering};

use hdrhistogram::Histogram;
use parking_lot::Mutex;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram as PromHistogram, exponential_buckets};
use prometheus_client::registry::Registry;

/// Server-wide Prometheus metrics, shared by every session.
#[derive(Debug, Clone)]
pub struct EngineMetrics {
    /// Physics step wall time (s).
    pub step_seconds: PromHistogram,
    /// Exposure wall time: render, detector, window (s).
    pub frame_seconds: PromHistogram,
    /// Sessions running.
    pub sessions: Gauge,
    /// Frames sent to clients.
    pub frames_sent: Counter,
    /// Frames a slow client skipped.
    pub frames_skipped: Counter,
    /// Frames not encoded for a stream because the streams' byte budget was spent.
    pub frames_withheld: Counter,
    /// Bytes of encoded frames handed to the transport and not yet taken by their readers.
    pub stream_buffer_bytes: Gauge,
    /// Connections cut because a reader stalled a stream past its timeout.
    pub stalled_streams_cut: Counter,
    /// Times the overload governor changed a session's fidelity.
    pub fidelity_changes: Counter,
    /// Steps that started a whole period late.
    pub late_steps: Counter,
    /// Periods dropped when a physics loop fell too far behind.
    pub missed_steps: Counter,
    /// Physics resets after divergence.
    pub divergences: Counter,
    /// Commands applied.
    pub commands: Counter,
}

impl Default for EngineMetrics {
    fn default() -> Self {
        Self {
            step_seconds: PromHistogram::new(exponential_buckets(25e-6, 2.0, 14)),
            frame_seconds: PromHistogram::new(exponential_buckets(1e-3, 2.0, 12)),
            sessions: Gauge::default(),
            frames_sent: Counter::default(),
            frames_skipped: Counter::default(),
            frames_withheld: Counter::default(),
            stream_buffer_bytes: Gauge::default(),
            stalled_streams_cut: Counter::default(),
            fidelity_changes: Counter::default(),
            late_steps: Counter::default(),
            missed_steps: Counter::default(),
            divergences: Counter::default(),
            commands: Counter::default(),
        }
    }
}

impl EngineMetrics {
    /// Registers every family under the `cathlab_` prefix.
    pub fn register(&self, registry: &mut Registry) {
        let r = registry.sub_registry_with_prefix("cathlab");
        r.register(
            "physics_step_seconds",
            "Wall time of one physics step",
            self.step_seconds.clone(),
        );
        r.register(
            "frame_seconds",
            "Wall time of one X-ray exposure (render, detector, window)",
            self.frame_seconds.clone(),
        );
        r.register("sessions", "Sessions running", self.sessions.clone());
        r.register(
            "frames_sent",
            "Frames sent to clients",
            self.frames_sent.clone(),
        );
        r.register(
            "frames_skipped",
            "Frames slow clients skipped",
            self.frames_skipped.clone(),
        );
        r.register(
            "frames_withheld",
            "Frames not encoded because the streams' byte budget was spent",
            self.frames_withheld.clone(),
        );
        r.register(
            "stream_buffer_bytes",
            "Bytes of encoded frames waiting for their readers",
            self.stream_buffer_bytes.clone(),
        );
        r.register(
            "fidelity_changes",
            "Times the overload governor changed a session's fidelity",
            self.fidelity_changes.clone(),
        );
        r.register(
            "stalled_streams_cut",
            "Connections cut because a reader stalled a stream past its timeout",
            self.stalled_streams_cut.clone(),
        );
        r.register(
            "late_steps",
            "Physics steps started a whole period late",
            self.late_steps.clone(),
        );
        r.register(
            "missed_steps",
            "Physics periods dropped by loops that fell behind",
            self.missed_steps.clone(),
        );
        r.register(
            "divergences",
            "Physics resets after divergence",
            self.divergences.clone(),
        );
        r.register("commands", "Commands applied", self.commands.clone());
    }
}

/// Percentiles of one session's threads.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TimingSummary {
    /// Steps taken.
    pub steps: u64,
    /// Steps that started a whole period or more late.
    pub late_steps: u64,
    /// Periods dropped when the loop fell more than its catch-up window behind.
    pub missed_steps: u64,
    /// Step time percentiles and maximum (s).
    pub step_p50_s: f64,
    /// 99th percentile (s).
    pub step_p99_s: f64,
    /// Maximum (s).
    pub step_max_s: f64,
    /// Exposures made.
    pub frames: u64,
    /// Exposure time percentiles and maximum (s).
    pub frame_p50_s: f64,
    /// 99th percentile (s).
    pub frame_p99_s: f64,
    /// Maximum (s).
    pub frame_max_s: f64,
}

/// One session's timing, written by its threads.
#[derive(Debug)]
pub struct SessionTiming {
    steps: Mutex<Histogram<u64>>,
    frames: Mutex<Histogram<u64>>,
    late: AtomicU64,
    missed: AtomicU64,
}

impl Default for SessionTiming {
    fn default() -> Self {
        let histogram = || Histogram::new_with_bounds(1, 60_000_000, 3).expect("valid bounds");
        Self {
            steps: Mutex::new(histogram()),
            frames: Mutex::new(histogram()),
            late: AtomicU64::new(0),
            missed: AtomicU64::new(0),
        }
    }
}

fn micros(seconds: f64) -> u64 {
    (seconds * 1e6).round().clamp(1.0, 60e6) as u64
}

impl SessionTiming {
    /// Records one step's wall time (s).
    pub fn step(&self, seconds: f64) {
        let _ = self.steps.lock().record(micros(seconds));
    }

    /// Records one exposure's wall time (s).
    pub fn frame(&self, seconds: f64) {
        let _ = self.frames.lock().record(micros(seconds));
    }

    /// Counts a late step.
    pub fn late(&self) {
        self.late.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts dropped periods.
    pub fn missed(&self, periods: u64) {
        self.missed.fetch_add(periods, Ordering::Relaxed);
    }

    /// Percentiles now.
    pub fn summary(&self) -> TimingSummary {
        let s = self.steps.lock();
        let f = self.frames.lock();
        let q = |h: &Histogram<u64>, p: f64| {
            if h.is_empty() {
                0.0
            } else {
                h.value_at_quantile(p) as f64 * 1e-6
            }
        };
        TimingSummary {
            steps: s.len(),
            late_steps: self.late.load(Ordering::Relaxed),
            missed_steps: self.missed.load(Ordering::Relaxed),
            step_p50_s: q(&s, 0.5),
            step_p99_s: q(&s, 0.99),
            step_max_s: s.max() as f64 * 1e-6,
            frames: f.len(),
            frame_p50_s: q(&f, 0.5),
            frame_p99_s: q(&f, 0.99),
            frame_max_s: f.max() as f64 * 1e-6,
        }
    }
}
