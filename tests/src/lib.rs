//! The end-to-end suites' launcher: where the real binaries are (built first, so that
//! `cargo test` from the root builds what it runs), a server process on a free port, the
//! haptic rig; each suite in this folder drives them from outside, as clients do.

pub mod binaries;
pub mod haptic;
pub mod paths;
pub mod server;

pub use binaries::binary;
pub use paths::{asset_disk_cache, repo_root, temp_dir};
pub use server::*;
