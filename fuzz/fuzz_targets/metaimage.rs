//! MetaImage volumes: `cathlab_imaging::read_metaimage`, which reads from a path only,
//! so the input is written to a scratch file `f.mha` first. An input of two files (split by
//! `cathlab_fuzz::NEXT_FILE`) is a `.mhd` header and the data file `f.raw` it may name.
#![no_main]

use cathlab_imaging::read_metaimage;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cathlab_fuzz::start();
    let files = cathlab_fuzz::split_files(data);
    let paths = cathlab_fuzz::write_scratch(&files, &["f.mha", "f.raw"]);
    let result = read_metaimage(&paths[0]);
    cathlab_fuzz::report("metaimage", &result);
});
