//! STL surfaces, binary and ASCII: `cathlab_anatomy::io::stl::parse`, the bytes of a `.stl` file.
#![no_main]

use cathlab_anatomy::io::{LengthUnit, stl};

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cathlab_fuzz::start();
    let result = stl::parse(data, LengthUnit::Mm, "fuzz.stl");
    cathlab_fuzz::report("stl", &result);
});
