//! PLY surfaces: ASCII and binary of either byte order: `cathlab_anatomy::io::ply::parse`, the bytes of a `.ply` file.
#![no_main]

use cathlab_anatomy::io::{LengthUnit, ply};

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cathlab_fuzz::start();
    let result = ply::parse(data, LengthUnit::Mm, "fuzz.ply");
    cathlab_fuzz::report("ply", &result);
});
