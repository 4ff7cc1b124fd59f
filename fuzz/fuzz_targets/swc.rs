//! libFuzzer target: SWC centerline trees. The body is `cathlab_fuzz::targets::swc`
//! (`src/targets.rs`), which the replay test under `cargo test` runs too.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| cathlab_fuzz::targets::swc(data));
