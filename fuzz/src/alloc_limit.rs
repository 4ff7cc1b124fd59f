//! The allocation limit: libFuzzer's `-malloc_limit_mb` needs a sanitizer's malloc hooks,
//! which a build without sanitizers (stable Rust) lacks, so the global allocator here aborts
//! the run (a crash, with the input saved) when one allocation, or all live ones together,
//! pass [`ALLOC_LIMIT_BYTES`] — also when the pages were never touched, which `-rss_limit_mb`
//! cannot see.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write as _;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Most bytes one allocation, or all live allocations together, may take: 1 GiB, as
/// `-malloc_limit_mb=1024` would enforce with a sanitizer. `CATHLAB_FUZZ_ALLOC_LIMIT_MB`
/// overrides it (read once, at the first input).
pub const ALLOC_LIMIT_BYTES: usize = 1 << 30;

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

/// Reads `CATHLAB_FUZZ_ALLOC_LIMIT_MB` once (at the first input), which overrides
/// [`ALLOC_LIMIT_BYTES`].
pub fn read_override() {
    static ONCE: OnceLock<()> = OnceLock::new();
    ONCE.get_or_init(|| {
        if let Some(mb) = std::env::var("CATHLAB_FUZZ_ALLOC_LIMIT_MB")
            .ok()
            .and_then(|v| v.parse::<usize>().ok())
        {
            LIMIT.store(mb << 20, Ordering::Relaxed);
        }
    });
}
