//! The web client end to end: `client-web/e2e/run.mjs` drives headless Chromium against this
//! crate's real `cathlab-server` binary (serving the built client). Needs the client built
//! (`npm ci && npm run build` in client-web) and Chromium; `scripts/test.sh` provides both and
//! sets CATHLAB_REQUIRE_BROWSER=1, so there a missing piece fails instead of skipping.

use std::process::Command;

#[test]
fn the_web_client_works_in_a_real_browser() {
    let root = cathlab_tests::repo_root();
    let client = root.join("client-web");
    let chromium = std::env::var("CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    let missing: Vec<String> = [
        (
            client.join("node_modules/playwright-core"),
            "npm ci in client-web",
        ),
        (
            client.join("dist/index.html"),
            "npm run build in client-web",
        ),
        (std::path::PathBuf::from(&chromium), "Debian's chromium"),
    ]
    .into_iter()
    .filter(|(path, _)| !path.exists())
    .map(|(path, fix)| format!("{} ({fix})", path.display()))
    .collect();
    if !missing.is_empty() {
        let message = format!("browser test needs: {}", missing.join(", "));
        if std::env::var("CATHLAB_REQUIRE_BROWSER").as_deref() == Ok("1") {
            panic!("{message}");
        }
        eprintln!("skipped: {message}");
        return;
    }
    let output = Command::new("node")
        .arg(client.join("e2e/run.mjs"))
        .arg("--server")
        .arg(cathlab_tests::binary("cathlab-server"))
        .args(["--chromium", &chromium])
        .env(
            "CATHLAB_ASSET_DISK_CACHE",
            cathlab_tests::asset_disk_cache(),
        )
        .current_dir(&client)
        .output()
        .expect("running node (Node.js is needed for the web client)");
    let stdout = String::from_utf8_lossy(&output.stdout);
    println!("{stdout}");
    eprintln!("{}", String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "browser tests failed:\n{stdout}");
    assert!(stdout.contains("test result: ok."), "{stdout}");
}
