//! Wavefront OBJ surfaces: `cathlab_anatomy::io::obj::parse`, the bytes of a `.obj` file.
#![no_main]

use cathlab_anatomy::io::{LengthUnit, obj};

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cathlab_fuzz::start();
    let result = obj::parse(data, LengthUnit::Mm, "fuzz.obj");
    cathlab_fuzz::report("obj", &result);
});
