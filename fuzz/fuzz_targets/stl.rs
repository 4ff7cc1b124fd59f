//! libFuzzer target: STL surfaces, binary and ASCII. The body is `cathlab_fuzz::targets::stl`
//! (`src/targets.rs`), which the replay test under `cargo test` runs too.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| cathlab_fuzz::targets::stl(data));
