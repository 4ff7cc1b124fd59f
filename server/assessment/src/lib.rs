//! Assessment of a training session: the metrics instructors grade by, each defined once
//! with its units, formula and the study it comes from. A plain synchronous library over
//! recorded samples ([`trace`]): motion ([`motion`]: path length, path ratio, idle time),
//! smoothness ([`smoothness`]: spectral arc length) and wall force by vessel class
//! ([`force`]). No threads, no clock: the same samples give the same figures.

pub mod error;
pub mod force;
pub mod motion;
pub mod smoothness;
pub mod trace;

pub use error::{AssessmentError, Result};
pub use trace::{Sample, Trace, VesselClass};
