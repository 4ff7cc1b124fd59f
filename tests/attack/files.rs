//! Hostile data files: a 150-byte header declaring 10¹⁵ voxels, counts that wrap a 64-bit
//! product, and decompression bombs (zlib MetaImage, gzip NIfTI, zlib VTK blocks), each
//! refused with an error naming the field, quickly and without the memory it asks for, by
//! `--check-scenes` and by a running server that keeps its other sessions.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use super::*;

/// `bytes` of zeros through `encoder`, written a mebibyte at a time.
fn zeros_into<W: std::io::Write>(mut encoder: W, bytes: usize) -> W {
    let chunk = vec![0u8; 1 << 20];
    for _ in 0..bytes >> 20 {
        encoder.write_all(&chunk).unwrap();
    }
    encoder
}

fn zlib_zeros(bytes: usize) -> Vec<u8> {
    zeros_into(
        flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best()),
        bytes,
    )
    .finish()
    .unwrap()
}

/// A MetaImage with the data inline.
fn metaimage(dims: &str, compressed: bool, data: &[u8]) -> Vec<u8> {
    let mut out = format!(
        "ObjectType = Image\nNDims = 3\nDimSize = {dims}\nElementType = MET_UCHAR\n\
         CompressedData = {}\nElementDataFile = LOCAL\n",
        if compressed { "True" } else { "False" }
    )
    .into_bytes();
    out.extend_from_slice(data);
    out
}

/// A gzip NIfTI-1 of 1024³ bytes declared (more voxels than the limit), whose data
/// inflates to `bytes`.
fn nifti_gzip_bomb(bytes: usize) -> Vec<u8> {
    let mut header = vec![0u8; 352];
    header[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (o, v) in [
        (40, 3i16),
        (42, 1024),
        (44, 1024),
        (46, 1024),
        (70, 2),
        (72, 8),
    ] {
        header[o..o + 2].copy_from_slice(&v.to_le_bytes());
    }
    for o in [80, 84, 88] {
        header[o..o + 4].copy_from_slice(&1.0f32.to_le_bytes());
    }
    header[108..112].copy_from_slice(&352.0f32.to_le_bytes());
    header[344..348].copy_from_slice(b"n+1\0");
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    gz.write_all(&header).unwrap();
    zeros_into(gz, bytes).finish().unwrap()
}

/// A VTK PolyData whose points are one zlib block declaring `declared` bytes and holding
/// `bytes` of zeros.
fn vtp_zlib_bomb(declared: u32, bytes: usize) -> Vec<u8> {
    use base64::Engine as _;
    let compressed = zlib_zeros(bytes);
    let mut head = Vec::new();
    for word in [1u32, declared, declared, compressed.len() as u32] {
        head.extend(word.to_le_bytes());
    }
    let b64 = base64::engine::general_purpose::STANDARD;
    format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"1.0\" \
         header_type=\"UInt32\" compressor=\"vtkZLibDataCompressor\">\n<PolyData>\n\
         <Piece NumberOfPoints=\"3\" NumberOfPolys=\"1\">\n<Points>\n\
         <DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"binary\">{}{}</DataArray>\n\
         </Points>\n</Piece>\n</PolyData>\n</VTKFile>\n",
        b64.encode(&head),
        b64.encode(&compressed)
    )
    .into_bytes()
}

/// The hostile files, each with the scene field it is named in and what its error must say.
fn hostile_files(dir: &Path) -> Vec<(PathBuf, &'static str, &'static str)> {
    let mut files = Vec::new();
    let mut put = |name: &str, bytes: Vec<u8>, field: &'static str, says: &'static str| {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        files.push((path, field, says));
    };
    let tiny = metaimage(
        "100000 100000 100000",
        true,
        &[0x78, 0x9c, 0x03, 0, 0, 0, 0, 1],
    );
    println!("the tiny bomb: {} bytes", tiny.len());
    assert!(tiny.len() <= 160, "{} bytes", tiny.len());
    put("tiny.mha", tiny, "ct.path", "max_voxels");
    put(
        "wraps.mha",
        metaimage("4294967296 4294967296 1", false, &[0; 16]),
        "ct.path",
        "overflow",
    );
    // 1024 MiB declared (more voxels than the limit) and 64³ declared that inflates past it.
    let zeros = zlib_zeros(256 << 20);
    put(
        "declared.mha",
        metaimage("1024 1024 1024", true, &zeros),
        "ct.path",
        "max_voxels",
    );
    put(
        "lying.mha",
        metaimage("64 64 64", true, &zeros),
        "ct.path",
        "inflates past the 262144 bytes its header declares",
    );
    put(
        "bomb.nii.gz",
        nifti_gzip_bomb(256 << 20),
        "ct.path",
        "max_voxels",
    );
    put(
        "bomb.vtp",
        vtp_zlib_bomb(1 << 30, 256 << 20),
        "anatomy.file",
        "max_inflated_bytes",
    );
    put(
        "lying.vtp",
        vtp_zlib_bomb(36, 256 << 20),
        "anatomy.file",
        "inflates to 37 bytes, the header says 36",
    );
    files
}

/// The default scene with its CT or anatomy taken from `file`.
fn scene_naming(file: &Path, field: &str) -> String {
    let path = file.display().to_string();
    if field == "ct.path" {
        default_scene_text().replace(
            "[ct]\nkind = \"phantom\"\nspacing_mm = 2.0",
            &format!("[ct]\nkind = \"file\"\npath = {path:?}"),
        )
    } else {
        default_scene_text().replace(
            "[anatomy]\nkind = \"arch_to_cow\"\ndir = \"../data/anatomy/arch-to-cow\"",
            &format!("[anatomy]\nkind = \"surface\"\nfile = {path:?}"),
        )
    }
}

/// The largest the process's resident memory was (bytes), from /proc.
fn peak_rss_bytes(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let kb: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("VmHWM");
    kb * 1024
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bomb_files_are_refused_by_check_scenes_and_a_running_server_that_keeps_its_sessions() {
    let _exclusive = EXCLUSIVE.lock().await;
    let root = temp_dir("bombs");
    let files = hostile_files(&root);
    let config = format!(
        "data_roots = [{:?}, {:?}, {:?}]\n",
        repo_root().join("scenes").display().to_string(),
        repo_root().join("data").display().to_string(),
        root.display().to_string()
    );

    // `--check-scenes`: one scene per file, each a FAIL line naming its field, no abort,
    // under a data limit of 1 GiB (a process that tried to allocate what the bombs ask for,
    // 2–16 GiB, would abort with 134).
    let scenes = root.join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    for (file, field, _) in &files {
        let stem = file
            .file_name()
            .unwrap()
            .to_string_lossy()
            .replace('.', "_");
        let text = scene_naming(file, field).replace(
            "dir = \"../data/anatomy/arch-to-cow\"",
            &format!(
                "dir = {:?}",
                repo_root()
                    .join("data/anatomy/arch-to-cow")
                    .display()
                    .to_string()
            ),
        );
        std::fs::write(scenes.join(format!("{stem}.toml")), text).unwrap();
    }
    let config_file = root.join("check.toml");
    std::fs::write(&config_file, &config).unwrap();
    let started = std::time::Instant::now();
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg("ulimit -d 1048576 && exec \"$0\" \"$@\"")
        .arg(cathlab_tests::binary("cathlab-server"))
        .arg("--config")
        .arg(&config_file)
        .arg("--check-scenes")
        .arg(&scenes)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let took = started.elapsed();
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!(
        "--check-scenes on {} bomb scenes in {:.2} s (data limit 1 GiB), exit {:?}:\n{}",
        files.len(),
        took.as_secs_f64(),
        out.status.code(),
        stdout.trim()
    );
    assert_eq!(out.status.code(), Some(1), "{stdout}");
    assert_eq!(stdout.matches("FAIL").count(), files.len(), "{stdout}");
    assert!(took.as_secs_f64() < 2.0 * files.len() as f64, "{took:?}");

    // A running server: a session first, then each bomb as an instructor's inline scene.
    let (server, _dir) = server_with("bombs", &config);
    let mut client = server.client().await;
    let bystander = create(&mut client).await;
    let pid = server.child.id();
    let before = rss_bytes(pid);
    let peak_before = peak_rss_bytes(pid);
    for (file, field, says) in &files {
        let started = std::time::Instant::now();
        let error = client
            .create_session(authed(inline(scene_naming(file, field)), INSTRUCTOR_KEY))
            .await
            .unwrap_err();
        let took = started.elapsed();
        let message = error.message();
        println!(
            "{}: {:?} in {:.0} ms: {message}",
            file.file_name().unwrap().to_string_lossy(),
            error.code(),
            took.as_secs_f64() * 1e3
        );
        assert_eq!(error.code(), tonic::Code::InvalidArgument, "{error:?}");
        assert!(message.contains(field), "names the field: {message}");
        assert!(message.contains(says), "says {says:?}: {message}");
        assert!(!message.contains("/tmp"), "shows a path: {message}");
        assert!(took.as_secs_f64() < 5.0, "{took:?}");
    }
    let (after, peak) = (rss_bytes(pid), peak_rss_bytes(pid));
    println!(
        "server RSS {} → {} MiB, peak {} → {} MiB",
        before >> 20,
        after >> 20,
        peak_before >> 20,
        peak >> 20
    );
    assert!(
        peak < peak_before.max(before) + (100 << 20),
        "the bombs took {} MiB",
        (peak - peak_before.max(before)) >> 20
    );
    // The server and its session live on.
    send(&mut client, &bystander, 1, push(10.0)).await.unwrap();
    close(&mut client, &bystander).await;
}
