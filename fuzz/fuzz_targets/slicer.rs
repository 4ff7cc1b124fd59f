//! 3D Slicer markups (`.mrk.json`) curves: `cathlab_anatomy::io::slicer::parse`.
#![no_main]

use cathlab_anatomy::io::slicer;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cathlab_fuzz::start();
    let result = slicer::parse(data, "fuzz", "fuzz.mrk.json");
    cathlab_fuzz::report("slicer", &result);
});
