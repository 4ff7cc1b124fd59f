//! SWC centerline trees: `cathlab_anatomy::io::swc::parse`, the bytes of a `.swc` file.
#![no_main]

use cathlab_anatomy::io::{LengthUnit, swc};

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cathlab_fuzz::start();
    let result = swc::parse(data, LengthUnit::Mm, "fuzz.swc");
    cathlab_fuzz::report("swc", &result);
});
