//! libFuzzer target: 3D Slicer markup curves (JSON). The body is `cathlab_fuzz::targets::slicer`
//! (`src/targets.rs`), which the replay test under `cargo test` runs too.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| cathlab_fuzz::targets::slicer(data));
