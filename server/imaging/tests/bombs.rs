//! Hostile volume files through the `cathlab` CLI and the readers: a 150-byte MetaImage that
//! declares 10¹⁵ voxels, a voxel count that wraps a 64-bit product, zlib and gzip data that
//! inflate past what their headers declare, a device file. Each is refused with an error that
//! names the field and the limit, quickly, in a process held to 256 MiB of data (one that
//! tried to allocate what the header asks for would abort with 134).

use std::io::Write as _;
use std::path::{Path, PathBuf};

use cathlab_imaging::{read_metaimage, read_nifti};

fn dir() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("cathlab-bombs-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn metaimage(path: &Path, dims: &str, compressed: bool, data: &[u8]) {
    let mut out = format!(
        "ObjectType = Image\nNDims = 3\nDimSize = {dims}\nElementType = MET_UCHAR\n\
         CompressedData = {}\nElementDataFile = LOCAL\n",
        if compressed { "True" } else { "False" }
    )
    .into_bytes();
    out.extend_from_slice(data);
    std::fs::write(path, out).unwrap();
}

fn zeros(bytes: usize, gzip: Option<&[u8]>) -> Vec<u8> {
    let chunk = vec![0u8; 1 << 20];
    if let Some(header) = gzip {
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
        e.write_all(header).unwrap();
        for _ in 0..bytes >> 20 {
            e.write_all(&chunk).unwrap();
        }
        return e.finish().unwrap();
    }
    let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best());
    for _ in 0..bytes >> 20 {
        e.write_all(&chunk).unwrap();
    }
    e.finish().unwrap()
}

/// A NIfTI-1 header of `n`³ bytes at offset 352.
fn nifti_header(n: i16) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (o, v) in [(40, 3i16), (42, n), (44, n), (46, n), (70, 2), (72, 8)] {
        h[o..o + 2].copy_from_slice(&v.to_le_bytes());
    }
    for o in [80, 84, 88] {
        h[o..o + 4].copy_from_slice(&1.0f32.to_le_bytes());
    }
    h[108..112].copy_from_slice(&352.0f32.to_le_bytes());
    h[344..348].copy_from_slice(b"n+1\0");
    h
}

#[test]
fn the_readers_refuse_bombs_before_allocating_and_name_the_limit() {
    let dir = dir();
    let tiny = dir.join("tiny.mha");
    metaimage(
        &tiny,
        "100000 100000 100000",
        true,
        &[0x78, 0x9c, 3, 0, 0, 0, 0, 1],
    );
    assert!(std::fs::metadata(&tiny).unwrap().len() < 160);
    let e = read_metaimage(&tiny).unwrap_err().to_string();
    assert!(e.contains("DimSize") && e.contains("max_voxels"), "{e}");
    let wraps = dir.join("wraps.mha");
    metaimage(&wraps, "4294967296 4294967296 1", false, &[0; 8]);
    let e = read_metaimage(&wraps).unwrap_err().to_string();
    assert!(e.contains("DimSize") && e.contains("overflow"), "{e}");
    let lying = dir.join("lying.mha");
    metaimage(&lying, "16 16 16", true, &zeros(64 << 20, None));
    let e = read_metaimage(&lying).unwrap_err().to_string();
    assert!(
        e.contains("inflates past the 4096 bytes its header declares"),
        "{e}"
    );
    // A NIfTI whose gzip data goes on past its voxels is read to them and no further.
    let long = dir.join("long.nii.gz");
    std::fs::write(&long, zeros(64 << 20, Some(&nifti_header(16)))).unwrap();
    let v = read_nifti(&long).unwrap();
    assert_eq!(v.dims, [16, 16, 16]);
    let big = dir.join("big.nii.gz");
    std::fs::write(&big, zeros(1 << 20, Some(&nifti_header(2048)))).unwrap();
    let e = read_nifti(&big).unwrap_err().to_string();
    assert!(e.contains("dim") && e.contains("max_voxels"), "{e}");
    // Only regular files are read.
    let e = read_metaimage(Path::new("/dev/zero"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("not a regular file"), "{e}");
}

#[test]
fn the_cli_refuses_a_150_byte_bomb_in_a_second_within_256_mib() {
    let dir = dir();
    let tiny = dir.join("cli-tiny.mha");
    metaimage(
        &tiny,
        "100000 100000 100000",
        true,
        &[0x78, 0x9c, 3, 0, 0, 0, 0, 1],
    );
    let started = std::time::Instant::now();
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg("ulimit -d 262144 && exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_cathlab"))
        .arg("case")
        .arg(&tiny)
        .arg("--out")
        .arg(dir.join("case-out"))
        .output()
        .unwrap();
    let took = started.elapsed();
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!(
        "cathlab case on a {}-byte bomb: exit {:?} in {:.0} ms: {}",
        std::fs::metadata(&tiny).unwrap().len(),
        out.status.code(),
        took.as_secs_f64() * 1e3,
        stderr.trim()
    );
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("DimSize") && stderr.contains("max_voxels"),
        "{stderr}"
    );
    assert!(took.as_secs_f64() < 5.0);
}
