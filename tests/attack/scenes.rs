//! Hostile and careless scenes: inline scenes that fail (and must leave no memory behind),
//! scenes naming files outside the data roots, a catalogue scene naming a missing file,
//! `--check-scenes`.

use super::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failing_inline_scenes_need_the_key_and_leave_no_memory_behind() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("memory", "asset_cache_mib = 512\n");
    let mut client = server.client().await;
    // Without the instructor key an inline scene is refused before anything is read.
    let anonymous = client
        .create_session(inline(default_scene_text()))
        .await
        .unwrap_err();
    assert_eq!(
        anonymous.code(),
        tonic::Code::PermissionDenied,
        "{anonymous:?}"
    );
    assert!(anonymous.message().contains("instructor key"));
    // A listed scene warms the cache; then 6 inline scenes that fail only after their CT is
    // built (each with another spacing, so each builds a new one of about 16 MiB; the
    // isocenter branch is unknown): kept, they would pass the 50 MiB allowance.
    let warm = create(&mut client).await;
    close(&mut client, &warm).await;
    let pid = server.child.id();
    let start = rss_bytes(pid);
    for i in 0..6 {
        let text = default_scene_text()
            .replace(
                "spacing_mm = 2.0",
                &format!("spacing_mm = {}", 2.0 + 0.01 * f64::from(i + 1)),
            )
            .replace("isocenter_branch = \"LCCA\"", "isocenter_branch = \"nope\"");
        let error = client
            .create_session(authed(inline(text), INSTRUCTOR_KEY))
            .await
            .unwrap_err();
        assert_eq!(error.code(), tonic::Code::InvalidArgument, "{error:?}");
        assert!(
            error.message().contains("carm.isocenter_branch"),
            "{error:?}"
        );
    }
    let end = rss_bytes(pid);
    println!(
        "6 failing inline scenes: RSS {:.1} → {:.1} MiB",
        start as f64 / 1048576.0,
        end as f64 / 1048576.0
    );
    assert!(
        end < start + (50 << 20),
        "RSS grew {} MiB",
        (end - start) >> 20
    );
    // A phantom too fine for the asset budget (about 1 GiB at 0.5 mm, against 512 MiB) is
    // refused before loading.
    let fine = default_scene_text().replace("spacing_mm = 2.0", "spacing_mm = 0.5");
    let error = client
        .create_session(authed(inline(fine), INSTRUCTOR_KEY))
        .await
        .unwrap_err();
    println!("0.5 mm phantom: {:?} {}", error.code(), error.message());
    assert_eq!(error.code(), tonic::Code::ResourceExhausted);
    assert!(error.message().contains("budget"), "{error:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scenes_cannot_name_files_outside_the_data_roots_nor_echo_them() {
    let _exclusive = EXCLUSIVE.lock().await;
    // A data root of our own beside the bundled data, with a MetaImage header whose data file
    // points out of it.
    let outside = temp_dir("outside");
    std::fs::write(outside.join("secret.raw"), "top secret contents\n").unwrap();
    let root = temp_dir("root");
    std::fs::write(
        root.join("evil.mhd"),
        format!(
            "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\nElementDataFile = {}\n",
            outside.join("secret.raw").display()
        ),
    )
    .unwrap();
    std::fs::write(root.join("notes.mha"), "the first line of a text file\n").unwrap();
    std::os::unix::fs::symlink(outside.join("secret.raw"), root.join("link.mha")).unwrap();
    let config = format!(
        "data_roots = [{:?}, {:?}, {:?}]\n",
        repo_root().join("scenes").display().to_string(),
        repo_root().join("data").display().to_string(),
        root.display().to_string()
    );
    let (server, _dir) = server_with("paths", &config);
    let mut client = server.client().await;
    let ct_file = |path: &str| {
        default_scene_text().replace(
            "[ct]\nkind = \"phantom\"\nspacing_mm = 2.0",
            &format!("[ct]\nkind = \"file\"\npath = {path:?}"),
        )
    };
    assert_ne!(ct_file("x"), default_scene_text());
    let hostile = [
        ct_file("/etc/hostname"),
        ct_file("../../../../../../etc/passwd"),
        ct_file("../../x.mha"),
        ct_file(&root.join("evil.mhd").display().to_string()),
        ct_file(&root.join("notes.mha").display().to_string()),
        ct_file(&outside.join("secret.raw").display().to_string()),
        default_scene_text().replace("dir = \"../data/anatomy/arch-to-cow\"", "dir = \"/etc\""),
        ct_file(&root.join("link.mha").display().to_string()),
    ];
    for (i, text) in hostile.into_iter().enumerate() {
        let error = client
            .create_session(authed(inline(text), INSTRUCTOR_KEY))
            .await
            .unwrap_err();
        let message = error.message();
        println!("hostile scene {i}: {:?} {message}", error.code());
        assert_eq!(error.code(), tonic::Code::InvalidArgument, "{i}: {error:?}");
        assert!(
            message.contains("ct.path") || message.contains("anatomy.dir"),
            "{i}: names the field: {message}"
        );
        if [0, 1, 2, 5, 6, 7].contains(&i) {
            // Missing and outside read alike: no oracle for files outside the roots.
            assert!(message.contains("names no file in the server's data directories"));
        }
        for leak in [
            "/etc",
            "/tmp",
            "secret",
            "first line",
            "hostname",
            "passwd",
            repo_root().canonicalize().unwrap().to_str().unwrap(),
        ] {
            assert!(!message.contains(leak), "{i}: {message:?} shows {leak:?}");
        }
    }
}

#[test]
fn a_catalog_scene_naming_a_missing_file_stops_the_server_at_start() {
    let dir = temp_dir("catalog");
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let scene = default_scene_text().replace(
        "dir = \"../data/anatomy/arch-to-cow\"",
        "dir = \"anatomy/moved-away\"",
    );
    assert!(scene.contains("moved-away"));
    std::fs::write(scenes.join("moved.toml"), scene).unwrap();
    let out = std::process::Command::new(cathlab_tests::binary("cathlab-server"))
        .args(["--listen", "127.0.0.1:0", "--database"])
        .arg(dir.join("db.sqlite"))
        .arg("--scenes")
        .arg(&scenes)
        .arg("--exit-on-stdin-eof")
        .env("CATHLAB_INSTRUCTOR_KEY", INSTRUCTOR_KEY)
        .env("RUST_LOG", "warn")
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{}", stderr.trim());
    assert!(!out.status.success());
    assert!(
        stderr.contains("moved.toml") && stderr.contains("anatomy.dir"),
        "{stderr}"
    );
}

#[test]
fn check_scenes_prints_a_line_per_scene_and_fails_if_one_fails() {
    // Alone, as the other suites here: its server's work beside a timing or memory test
    // would slow that test's server (missed steps, later frees).
    let _exclusive = EXCLUSIVE.blocking_lock();
    let dir = temp_dir("check-scenes");
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let data = repo_root().join("data").canonicalize().unwrap();
    let good = default_scene_text().replace(
        "dir = \"../data/anatomy/arch-to-cow\"",
        &format!(
            "dir = {:?}",
            data.join("anatomy/arch-to-cow").display().to_string()
        ),
    );
    std::fs::write(scenes.join("good.toml"), &good).unwrap();
    let config = dir.join("config.toml");
    std::fs::write(
        &config,
        format!(
            "data_roots = [{:?}, {:?}]\n",
            data.display().to_string(),
            scenes.display().to_string()
        ),
    )
    .unwrap();
    let run = || {
        std::process::Command::new(cathlab_tests::binary("cathlab-server"))
            .arg("--config")
            .arg(&config)
            .arg("--check-scenes")
            .arg(&scenes)
            .env("RUST_LOG", "warn")
            .env(
                "CATHLAB_ASSET_DISK_CACHE",
                cathlab_tests::asset_disk_cache(),
            )
            .output()
            .unwrap()
    };
    let out = run();
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{}", stdout.trim());
    assert!(out.status.success(), "{stdout}");
    assert!(stdout.starts_with("ok   good"), "{stdout}");
    // A second scene with a reach beyond its target branch: named, and the exit fails.
    std::fs::write(
        scenes.join("too_far.toml"),
        good.replace("reach_mm = 50.0", "reach_mm = 400.0"),
    )
    .unwrap();
    let out = run();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{}\n{}", stdout.trim(), stderr.trim());
    assert!(!out.status.success());
    assert!(stdout.contains("ok   good"), "{stdout}");
    assert!(
        stdout.contains("FAIL")
            && stdout.contains("too_far.toml")
            && stdout.contains("target.reach_mm"),
        "{stdout}"
    );
    assert!(stderr.contains("1 of 2 scenes failed"), "{stderr}");
}
