//! VTK XML PolyData: ascii, base64 and appended arrays, raw or zlib: `cathlab_anatomy::io::vtp::parse`, the bytes of a `.vtp` file.
#![no_main]

use cathlab_anatomy::io::{LengthUnit, vtp};

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cathlab_fuzz::start();
    let result = vtp::parse(data, LengthUnit::Mm, "fuzz.vtp");
    cathlab_fuzz::report("vtp", &result);
});
