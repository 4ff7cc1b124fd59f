//! The soak test runs end to end, briefly: two rounds of random clients, valid and invalid,
//! beside a watched session (`cathlab-soak`; the full 10⁶-step run is in the README). It fails
//! on a panic, an INTERNAL answer, the watched session missing more than 1 % of its steps
//! or resting memory more than 10 % over the first round's. The missed steps are a gross
//! check here, not the real-time figure: a debug server on CI's two cores, shared with the
//! other lane's tests, stalls for tens of milliseconds now and then (a fresh-clone `.ci/run`
//! of a head whose previous run had passed saw 25 and then 51 of 17,503 steps missed, 0.29 %,
//! against the 0.2 % this allowed before); the release soak in the README, alone on the
//! machine, allows none.

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
            "0.01",
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
