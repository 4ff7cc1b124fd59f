//! DICOM CT series: `cathlab_imaging::dicom::{list_series, read_series}` on a folder. The
//! input's files (split by `cathlab_fuzz::NEXT_FILE`; a volume needs two slices) are written
//! into an emptied scratch folder, which is then read as a series; a folder of several series
//! is read again naming the first.
#![no_main]

use cathlab_imaging::dicom::{list_series, read_series};

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cathlab_fuzz::start();
    let files = cathlab_fuzz::split_files(data);
    let paths = cathlab_fuzz::write_scratch(&files, &[]);
    let Some(dir) = paths[0].parent() else {
        return;
    };
    let listed = list_series(dir);
    cathlab_fuzz::report("dicom list_series", &listed);
    let result = read_series(dir, None);
    cathlab_fuzz::report("dicom read_series", &result);
    if let Ok(series) = listed
        && series.len() > 1
    {
        let result = read_series(dir, Some(&series[0].uid));
        cathlab_fuzz::report("dicom read_series(first)", &result);
    }
});
