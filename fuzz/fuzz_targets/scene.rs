//! libFuzzer target: scene files, TOML and JSON. The body is `cathlab_fuzz::scene_input::scene`
//! (`src/scene_input.rs`), which the replay test under `cargo test` runs too.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| cathlab_fuzz::scene_input::scene(data));
