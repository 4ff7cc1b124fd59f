//! The fuzz targets' support, without unsafe code (the engine's replay test includes it): the
//! readers' limits and panic hook set once ([`start_common`]), what an input parsed to
//! ([`report`]), multi-file inputs ([`split_files`]) and scratch files ([`write_scratch`]).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Separates the files of one multi-file input (the same bytes as `NEXT_FILE` in
/// `make_corpus.py` and the targets' dictionaries).
pub const NEXT_FILE: &[u8] = b"\n\xffNEXT-FILE\xff\n";

/// Called at the start of every input (by the crate's `start`): sets the readers' limits
/// and the panic hook once.
pub fn start_common() {
    static ONCE: OnceLock<()> = OnceLock::new();
    ONCE.get_or_init(|| {
        // The readers' own limits, as a server would configure them (max_file_mib = 64,
        // max_inflated_mib = 256, max_volume_voxels = 2²⁴): what the readers may allocate
        // within them stays far below the 1 GiB an input may not pass.
        cathlab_anatomy::io::limits::set_read_limits(cathlab_anatomy::io::limits::ReadLimits {
            max_file_bytes: 64 << 20,
            max_inflated_bytes: 256 << 20,
            max_voxels: 1 << 24,
        });
        // A panic inside dicom-rs's codecs is caught by `cathlab_imaging::dicom` (it runs
        // them under `catch_unwind` and names the file); libfuzzer's hook would abort on it
        // first. Any other panic is still a crash.
        let libfuzzer_hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let in_codec = info.location().is_some_and(|l| {
                l.file().contains("dicom-transfer-syntax-registry-")
                    || l.file().contains("dicom-pixeldata-")
            });
            if !in_codec {
                libfuzzer_hook(info);
            }
        }));
    });
}

/// With `CATHLAB_FUZZ_VERBOSE=1`, prints what the reader made of the input (to check that
/// the seed corpora parse: `scripts/fuzz.sh check`).
pub fn report<T, E: std::fmt::Display>(what: &str, result: &Result<T, E>) {
    static VERBOSE: OnceLock<bool> = OnceLock::new();
    if *VERBOSE.get_or_init(|| std::env::var_os("CATHLAB_FUZZ_VERBOSE").is_some()) {
        match result {
            Ok(_) => eprintln!("cathlab-fuzz: {what}: ok"),
            Err(e) => {
                let text: String = e.to_string().chars().take(300).collect();
                eprintln!("cathlab-fuzz: {what}: error: {text}");
            }
        }
    }
}

/// The input's files: the bytes between [`NEXT_FILE`] separators (one file when there is
/// none).
pub fn split_files(data: &[u8]) -> Vec<&[u8]> {
    let mut parts = Vec::new();
    let mut rest = data;
    while let Some(at) = rest.windows(NEXT_FILE.len()).position(|w| w == NEXT_FILE) {
        parts.push(&rest[..at]);
        rest = &rest[at + NEXT_FILE.len()..];
    }
    parts.push(rest);
    parts
}

/// This process's scratch folder, emptied: in /dev/shm when there is one (memory, fast),
/// else the system's temporary folder. Each fuzzing process (`-jobs`, `-fork`) has its own;
/// those of processes that have ended are removed when the next one starts.
pub fn scratch_dir() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    let dir = DIR.get_or_init(|| {
        let base = if Path::new("/dev/shm").is_dir() {
            PathBuf::from("/dev/shm")
        } else {
            std::env::temp_dir()
        };
        // Folders of fuzzing processes that have ended (libFuzzer exits without unwinding,
        // so none removes its own): removed here.
        if let Ok(entries) = std::fs::read_dir(&base) {
            for entry in entries.flatten() {
                let name = entry.file_name();
                let Some(pid) = name
                    .to_str()
                    .and_then(|n| n.strip_prefix("cathlab-fuzz-"))
                    .and_then(|p| p.parse::<u32>().ok())
                else {
                    continue;
                };
                if !Path::new(&format!("/proc/{pid}")).exists() {
                    let _ = std::fs::remove_dir_all(entry.path());
                }
            }
        }
        let dir = base.join(format!("cathlab-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("scratch folder for the fuzz inputs");
        dir
    });
    if let Ok(entries) = std::fs::read_dir(dir) {
        for entry in entries.flatten() {
            let _ = std::fs::remove_file(entry.path());
        }
    }
    dir.clone()
}

/// Writes `files` into an emptied [`scratch_dir`] under `names` (cycled with a number when
/// there are more files than names) and returns their paths.
pub fn write_scratch(files: &[&[u8]], names: &[&str]) -> Vec<PathBuf> {
    let dir = scratch_dir();
    files
        .iter()
        .enumerate()
        .map(|(i, bytes)| {
            let name = match names.get(i) {
                Some(n) => (*n).to_owned(),
                None => format!("{i:04}"),
            };
            let path = dir.join(name);
            std::fs::write(&path, bytes).expect("write a fuzz input into the scratch folder");
            path
        })
        .collect()
}
