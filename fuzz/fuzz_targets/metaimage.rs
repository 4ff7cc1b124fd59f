//! libFuzzer target: MetaImage volumes (`.mha`, or a `.mhd` header and its data file). The body is `cathlab_fuzz::targets::metaimage`
//! (`src/targets.rs`), which the replay test under `cargo test` runs too.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| cathlab_fuzz::targets::metaimage(data));
