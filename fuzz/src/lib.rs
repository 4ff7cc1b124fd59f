//! Shared parts of cathlab's fuzz targets (`fuzz_targets/*.rs`, run by `scripts/fuzz.sh`):
//!
//! - an allocation limit: libFuzzer's `-malloc_limit_mb` needs a sanitizer's malloc hooks,
//!   which a build without sanitizers (stable Rust) lacks, so the global allocator here aborts
//!   the run (a crash, with the input saved) when one allocation, or all live ones together,
//!   pass [`ALLOC_LIMIT_BYTES`] — also when the pages were never touched, which
//!   `-rss_limit_mb` cannot see;
//! - scratch files for the readers that only read from a path;
//! - multi-file inputs: [`NEXT_FILE`] separates the files of one input (a DICOM series, a
//!   `.mhd` header and its data file).

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Most bytes one allocation, or all live allocations together, may take: 1 GiB, as
/// `-malloc_limit_mb=1024` would enforce with a sanitizer. `CATHLAB_FUZZ_ALLOC_LIMIT_MB`
/// overrides it (read once, at the first input).
pub const ALLOC_LIMIT_BYTES: usize = 1 << 30;

/// Separates the files of one multi-file input (the same bytes as `NEXT_FILE` in
/// `make_corpus.py` and the targets' dictionaries).
pub const NEXT_FILE: &[u8] = b"\n\xffNEXT-FILE\xff\n";

/// The global allocator of every fuzz target: the system allocator, counting live bytes.
pub struct LimitedAlloc;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static LIMIT: AtomicUsize = AtomicUsize::new(ALLOC_LIMIT_BYTES);
/// Set while a limit breach is being reported (the report itself allocates, unlimited).
static REPORTING: AtomicBool = AtomicBool::new(false);

#[global_allocator]
static ALLOCATOR: LimitedAlloc = LimitedAlloc;

/// A fixed buffer that `write!` fills without allocating.
struct StackText {
    buf: [u8; 200],
    len: usize,
}

impl std::fmt::Write for StackText {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        let n = s.len().min(self.buf.len() - self.len);
        self.buf[self.len..self.len + n].copy_from_slice(&s.as_bytes()[..n]);
        self.len += n;
        Ok(())
    }
}

#[cold]
fn over_limit(size: usize, live: usize) -> ! {
    if !REPORTING.swap(true, Ordering::SeqCst) {
        let mut text = StackText {
            buf: [0; 200],
            len: 0,
        };
        let _ = std::fmt::Write::write_fmt(
            &mut text,
            format_args!(
                "\n==cathlab-fuzz== allocation of {size} bytes with {live} bytes live passes \
                 the limit of {} bytes (no allocation over 1 GiB)\n",
                LIMIT.load(Ordering::Relaxed)
            ),
        );
        let _ = std::io::stderr().write_all(&text.buf[..text.len]);
        // Allocations from here on are not limited (REPORTING is set).
        let trace = std::backtrace::Backtrace::force_capture();
        let _ = writeln!(std::io::stderr(), "{trace}");
    }
    std::process::abort();
}

#[inline]
fn admit(size: usize) {
    let live = LIVE.fetch_add(size, Ordering::Relaxed) + size;
    let limit = LIMIT.load(Ordering::Relaxed);
    if (size > limit || live > limit) && !REPORTING.load(Ordering::Relaxed) {
        over_limit(size, live);
    }
}

// SAFETY: every call is forwarded to the system allocator with the caller's own arguments;
// the counting around it touches no memory of the allocation.
unsafe impl GlobalAlloc for LimitedAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        admit(layout.size());
        // SAFETY: the caller's layout, as GlobalAlloc::alloc requires.
        let p = unsafe { System.alloc(layout) };
        if p.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        admit(layout.size());
        // SAFETY: as in alloc.
        let p = unsafe { System.alloc_zeroed(layout) };
        if p.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: ptr was allocated by System with this layout (every allocation goes there).
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > layout.size() {
            admit(new_size - layout.size());
        }
        // SAFETY: the caller's pointer, layout and size, as GlobalAlloc::realloc requires.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if p.is_null() {
            if new_size > layout.size() {
                LIVE.fetch_sub(new_size - layout.size(), Ordering::Relaxed);
            }
        } else if new_size < layout.size() {
            LIVE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
        }
        p
    }
}

/// Called at the start of every input: reads the limit's override once, and with
/// `CATHLAB_FUZZ_VERBOSE` set, lets [`report`] print each input's outcome.
pub fn start() {
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
        if let Some(mb) = std::env::var("CATHLAB_FUZZ_ALLOC_LIMIT_MB")
            .ok()
            .and_then(|v| v.parse::<usize>().ok())
        {
            LIMIT.store(mb << 20, Ordering::Relaxed);
        }
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
