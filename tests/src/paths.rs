//! Where the suites find the repository and put their scratch files.

use std::path::{Path, PathBuf};

/// The workspace's root folder (scenes, data, deploy, client-web).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A fresh temporary directory for a test.
pub fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "cathlab-test-{name}-{}-{}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The disk cache of built anatomies the suites' servers share: `<target>/tmp/asset-cache`,
/// where the engine's own tests keep theirs, so the neuro phantom is built once per run.
pub fn asset_disk_cache() -> PathBuf {
    // <target>/<profile folder>/deps/<test>
    let exe = std::env::current_exe().expect("the test executable's path");
    exe.ancestors()
        .nth(3)
        .map(|target| target.join("tmp/asset-cache"))
        .unwrap_or_else(|| std::env::temp_dir().join("cathlab-asset-cache"))
}
