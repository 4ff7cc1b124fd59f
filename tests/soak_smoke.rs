//! The soak test runs end to end, briefly: two rounds of random clients, valid and invalid,
//! beside a watched session (`cathlab-soak`; the full 10⁶-step run is in the README). It fails
//! on a panic, an INTERNAL answer, the watched session missing more than 0.2 % of its steps
//! (a debug server on CI's two shared cores may stall once for tens of milliseconds; the
//! release soak in the README allows none) or resting memory more than 10 % over the first
//! round's.

#[test]
fn a_short_soak_passes() {
    let output = std::process::Command::new(cathlab_tests::binary("cathlab-soak"))
        .args([
            "--steps",
            "24000",
            "--round-seconds",
            "8",
            "--max-seconds",
            "300",
            "--missed-tolerance",
            "0.002",
        ])
        .arg("--server")
        .arg(cathlab_tests::binary("cathlab-server"))
        .arg("--scenes")
        .arg(cathlab_tests::repo_root().join("scenes"))
        // The servers it starts read the anatomy the other suites built.
        .env(
            "CATHLAB_ASSET_DISK_CACHE",
            cathlab_tests::asset_disk_cache(),
        )
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&output.stdout);
    println!("{text}");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    // The mix reached the server: sessions were made, bad commands refused, streams opened.
    for row in [
        "| create | OK |",
        "| invalid command | InvalidArgument |",
        "| frame stream | OK |",
        "| control stream | OK |",
        "| hostile scene |",
    ] {
        assert!(text.contains(row), "{row} in {text}");
    }
    // Two rounds at least: memory at rest is judged against the first round's.
    assert!(text.contains("round 1:"), "{text}");
    assert!(text.contains("soak passed"), "{text}");
}
