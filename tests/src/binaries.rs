//! The workspace binaries the suites run: built with the profile of the test executable
//! that asks for them, found beside it.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use crate::paths::repo_root;

/// The binaries the suites run, by package.
const BINARIES: &[(&str, &[&str])] = &[
    (
        "cathlab-app",
        &["cathlab-server", "cathlab-load", "cathlab-soak"],
    ),
    ("cathlab-haptic-bridge", &["cathlab-haptic-bridge"]),
];

/// The path of the workspace binary `name` (`cathlab-server`, `cathlab-load`,
/// `cathlab-soak`, `cathlab-haptic-bridge`), built beside this test executable with the
/// profile it was built with. The first call in a process runs `cargo build` for them
/// (a no-op when they are current; cargo does not hold its lock while tests run), so a
/// suite never runs a stale binary; `CATHLAB_TESTS_PREBUILT=1` skips that when the caller
/// (`scripts/test.sh`) has just built them.
pub fn binary(name: &str) -> PathBuf {
    assert!(
        BINARIES.iter().any(|(_, bins)| bins.contains(&name)),
        "{name} is not one of the binaries the suites build"
    );
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(build_binaries).join(name)
}

/// Builds [`BINARIES`] into the target folder this test executable lives in; the folder.
fn build_binaries() -> PathBuf {
    let exe = std::env::current_exe().expect("the test executable's path");
    // <target>/<profile folder>/deps/<test>
    let profile_dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("a test executable lives in <target>/<profile>/deps")
        .to_owned();
    if std::env::var_os("CATHLAB_TESTS_PREBUILT").is_some() {
        return profile_dir;
    }
    let target_dir = profile_dir.parent().expect("the target folder");
    // `cargo test` builds into target/debug with the test profile, `cargo bench` into
    // target/release with the bench profile: build the binaries the same way, so nothing
    // is compiled twice.
    let profile = match profile_dir.file_name().and_then(|n| n.to_str()) {
        Some("release") => "bench",
        _ => "test",
    };
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut command = Command::new(cargo);
    command
        .current_dir(repo_root())
        .args([
            "build",
            "--quiet",
            "--bins",
            "--profile",
            profile,
            "--target-dir",
        ])
        .arg(target_dir);
    for (package, _) in BINARIES {
        command.args(["-p", package]);
    }
    let output = command.output().expect("cargo runs");
    assert!(
        output.status.success(),
        "building the binaries under test failed:\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    profile_dir
}
