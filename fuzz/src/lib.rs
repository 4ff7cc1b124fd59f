//! Shared parts of cathlab's fuzz targets (`fuzz_targets/*.rs`, run by `scripts/fuzz.sh`):
//!
//! - an allocation limit: libFuzzer's `-malloc_limit_mb` needs a sanitizer's malloc hooks,
//!   which a build without sanitizers (stable Rust) lacks, so the global allocator here aborts
//!   the run (a crash, with the input saved) when one allocation, or all live ones together,
//!   pass [`ALLOC_LIMIT_BYTES`] — also when the pages were never touched, which
//!   `-rss_limit_mb` cannot see;
//! - scratch files for the readers that only read from a path;
//! - multi-file inputs: [`NEXT_FILE`] separates the files of one input (a DICOM series, a
//!   `.mhd` header and its data file).

// The engine's replay test (`server/engine/tests/fuzz_inputs.rs`) includes `support.rs`,
// `targets.rs` and `scene_input.rs` by their paths: they hold no unsafe code (the workspace
// forbids it) and reach what they use as `super::`.
mod support;
pub use support::*;

mod alloc_limit;
pub use alloc_limit::{ALLOC_LIMIT_BYTES, LimitedAlloc};

/// Called at the start of every input: the readers' limits and panic hook, and the
/// allocation limit's override, set once; with `CATHLAB_FUZZ_VERBOSE` set, [`report`] prints
/// each input's outcome.
pub fn start() {
    start_common();
    alloc_limit::read_override();
}

pub mod targets;

#[cfg(feature = "scene")]
pub mod scene_input;
