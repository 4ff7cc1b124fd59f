//! libFuzzer target: the device catalogue's TOML. The body is `cathlab_fuzz::targets::devices`
//! (`src/targets.rs`), which the replay test under `cargo test` runs too.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| cathlab_fuzz::targets::devices(data));
