//! Assessment of a training session: the metrics instructors grade by, each defined once
//! with its units, formula and the study it comes from. A plain synchronous library over
//! recorded samples ([`trace`]): motion ([`motion`]: path length, path ratio, idle time),
//! smoothness ([`smoothness`]: spectral arc length), wall force by vessel class ([`force`]),
//! procedure phases and errors ([`procedure`]), and the scores with their benchmark verdicts
//! ([`summary`]). No threads, no clock: the same samples give the same figures.

pub mod error;
pub mod force;
pub mod motion;
pub mod procedure;
pub mod smoothness;
pub mod summary;
pub mod trace;

pub use error::{AssessmentError, Result};
pub use procedure::{
    ErrorKind, ErrorThresholds, EventRecord, Phase, PhaseSpec, ProcedureError, detect_errors,
    detect_phases,
};
pub use summary::{BenchmarkSpec, Better, Counts, MetricValue, Verdict, judge, summarize};
pub use trace::{Sample, Trace, VesselClass};
