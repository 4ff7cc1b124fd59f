//! Build script: `CATHLAB_ASSET_CODE_HASH`, a hash of the source of the code that builds the
//! assets the disk cache keeps (the anatomy and imaging crates, the X-ray crate's body phantom
//! and volume, the engine's asset loader)
//! and of the locked dependency versions, so that a cached asset built by other code is
//! never read back (`src/assets/disk.rs`).

use std::hash::{DefaultHasher, Hash, Hasher};
use std::path::{Path, PathBuf};

fn files(path: &Path, out: &mut Vec<PathBuf>) {
    if path.is_dir() {
        let mut entries: Vec<PathBuf> = std::fs::read_dir(path)
            .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
            .unwrap_or_default();
        entries.sort();
        for e in entries {
            files(&e, out);
        }
    } else if path.is_file() {
        out.push(path.to_owned());
    }
}

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default());
    let mut hasher = DefaultHasher::new();
    // Two hashes of different seeds make a 128-bit key: no collision between builds.
    let mut second = DefaultHasher::new();
    0xca7_u32.hash(&mut second);
    for root in [
        "../anatomy/src",
        "../imaging/src",
        "../xray/src/phantom",
        "../xray/src/volume.rs",
        "src/assets",
        "../../Cargo.lock",
    ] {
        let path = manifest.join(root);
        println!("cargo:rerun-if-changed={}", path.display());
        let mut found = Vec::new();
        files(&path, &mut found);
        for file in found {
            let relative = file.strip_prefix(&manifest).unwrap_or(&file);
            let bytes = std::fs::read(&file).unwrap_or_default();
            for h in [&mut hasher, &mut second] {
                relative.hash(h);
                bytes.hash(h);
            }
        }
    }
    println!(
        "cargo:rustc-env=CATHLAB_ASSET_CODE_HASH={:016x}{:016x}",
        hasher.finish(),
        second.finish()
    );
}
