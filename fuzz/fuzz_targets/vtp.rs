//! libFuzzer target: VTK PolyData surfaces and centerlines (`.vtp`). The body is `cathlab_fuzz::targets::vtp`
//! (`src/targets.rs`), which the replay test under `cargo test` runs too.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| cathlab_fuzz::targets::vtp(data));
