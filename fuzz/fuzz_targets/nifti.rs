//! NIfTI-1 volumes, plain or gzip: `cathlab_imaging::read_nifti`, which reads from a
//! path only, so the input is written to a scratch file `f.nii` first.
#![no_main]

use cathlab_imaging::read_nifti;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cathlab_fuzz::start();
    let paths = cathlab_fuzz::write_scratch(&[data], &["f.nii"]);
    let result = read_nifti(&paths[0]);
    cathlab_fuzz::report("nifti", &result);
});
