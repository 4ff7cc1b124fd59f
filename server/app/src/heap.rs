//! The heap in use: the bytes the server binary's counting allocator (`cap` around mimalloc)
//! reports live, for `/metrics` and the soak benchmark, which tell a leak (live bytes growing)
//! from memory an allocator keeps after it was freed (resident memory growing, live bytes flat).

use std::sync::OnceLock;

static READER: OnceLock<fn() -> usize> = OnceLock::new();

/// Installs the function that reads the live heap bytes (the binary's global allocator). The
/// first call wins.
pub fn count_with(reader: fn() -> usize) {
    let _ = READER.set(reader);
}

/// Bytes live on the heap now (allocated and not freed), or `None` when no counting allocator
/// was installed (in-process tests, other binaries).
pub fn live_bytes() -> Option<usize> {
    READER.get().map(|read| read())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_installed_reader_is_the_one_read() {
        count_with(|| 42);
        count_with(|| 7);
        assert_eq!(live_bytes(), Some(42));
    }
}
