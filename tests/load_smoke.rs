//! The load benchmark runs end to end (one session, two seconds): the real server starts,
//! a session streams frames at the pulse rate, and the latency probes complete. The figures
//! in the README come from the full run (`cathlab-load`, see the README).

#[test]
fn the_load_benchmark_runs() {
    let output = std::process::Command::new(cathlab_tests::binary("cathlab-load"))
        .args([
            "--sessions",
            "1",
            "--seconds",
            "2",
            "--samples",
            "100",
            "--memory-sessions",
            "2",
            "--server",
        ])
        .arg(cathlab_tests::binary("cathlab-server"))
        .arg("--scenes")
        .arg(cathlab_tests::repo_root().join("scenes"))
        // The server it starts reads the anatomy the other suites built.
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
    let row = text
        .lines()
        .find(|l| l.starts_with("| 1 |"))
        .expect("a row for one session");
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    // One session at 500 Hz drops no physics periods.
    assert_eq!(cells[4], "0", "{row}");
    assert!(
        text.contains("control stream at 1 kHz (100 inputs)"),
        "{text}"
    );
}
