//! libFuzzer target: DICOM CT series (a folder of slices). The body is `cathlab_fuzz::targets::dicom`
//! (`src/targets.rs`), which the replay test under `cargo test` runs too.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| cathlab_fuzz::targets::dicom(data));
