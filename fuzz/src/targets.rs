//! What each reader's fuzz target does with one input: the reader called as the server calls
//! it.
//! The libFuzzer binaries (`fuzz_targets/*.rs`) and the engine's replay test
//! (`server/engine/tests/fuzz_inputs.rs`, which runs every regression and seed, and seeded
//! mutations of the seeds, under `cargo test`) share these bodies.

use super::{report, split_files, start, write_scratch};
use cathlab_anatomy::io::{LengthUnit, obj, ply, slicer, stl, swc, vtp};

/// STL surfaces, binary and ASCII: `cathlab_anatomy::io::stl::parse`.
pub fn stl(data: &[u8]) {
    start();
    report("stl", &stl::parse(data, LengthUnit::Mm, "fuzz.stl"));
}

/// Wavefront OBJ surfaces: `cathlab_anatomy::io::obj::parse`.
pub fn obj(data: &[u8]) {
    start();
    report("obj", &obj::parse(data, LengthUnit::Mm, "fuzz.obj"));
}

/// PLY surfaces, ASCII and binary: `cathlab_anatomy::io::ply::parse`.
pub fn ply(data: &[u8]) {
    start();
    report("ply", &ply::parse(data, LengthUnit::Mm, "fuzz.ply"));
}

/// VTK PolyData (`.vtp`), with base64 and zlib-compressed arrays: `vtp::parse`.
pub fn vtp(data: &[u8]) {
    start();
    report("vtp", &vtp::parse(data, LengthUnit::Mm, "fuzz.vtp"));
}

/// SWC centerline trees: `cathlab_anatomy::io::swc::parse`.
pub fn swc(data: &[u8]) {
    start();
    report("swc", &swc::parse(data, LengthUnit::Mm, "fuzz.swc"));
}

/// 3D Slicer markup curves (JSON): `cathlab_anatomy::io::slicer::parse`.
pub fn slicer(data: &[u8]) {
    start();
    report("slicer", &slicer::parse(data, "fuzz", "fuzz.mrk.json"));
}

/// MetaImage volumes: `cathlab_imaging::read_metaimage`, which reads from a path only, so the
/// input is written to a scratch file `f.mha` first. An input of two files (split by
/// [`super::NEXT_FILE`]) is a `.mhd` header and the data file `f.raw` it may name.
pub fn metaimage(data: &[u8]) {
    start();
    let files = split_files(data);
    let paths = write_scratch(&files, &["f.mha", "f.raw"]);
    report("metaimage", &cathlab_imaging::read_metaimage(&paths[0]));
}

/// NIfTI-1 volumes, plain or gzip: `cathlab_imaging::read_nifti`, from a scratch file.
pub fn nifti(data: &[u8]) {
    start();
    let paths = write_scratch(&[data], &["f.nii"]);
    report("nifti", &cathlab_imaging::read_nifti(&paths[0]));
}

/// DICOM CT series: `cathlab_imaging::dicom::{list_series, read_series}` on a folder. The
/// input's files (split by [`super::NEXT_FILE`]; a volume needs two slices) are written into
/// an emptied scratch folder, which is then read as a series; a folder of several series is
/// read again naming the first.
pub fn dicom(data: &[u8]) {
    use cathlab_imaging::dicom::{list_series, read_series};
    start();
    let files = split_files(data);
    let paths = write_scratch(&files, &[]);
    let Some(dir) = paths[0].parent() else {
        return;
    };
    let listed = list_series(dir);
    report("dicom list_series", &listed);
    report("dicom read_series", &read_series(dir, None));
    if let Ok(series) = listed
        && series.len() > 1
    {
        report(
            "dicom read_series(first)",
            &read_series(dir, Some(&series[0].uid)),
        );
    }
}

/// The device catalogue's TOML: `cathlab_physics::Catalogue::from_toml_str` (the input as
/// UTF-8 text; other bytes are skipped, as a file read to a string would fail first).
pub fn devices(data: &[u8]) {
    use cathlab_physics::Catalogue;
    start();
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let result = Catalogue::from_toml_str(text);
    report("devices", &result);
    if let Ok(catalogue) = result {
        for entry in catalogue.entries() {
            let _ = catalogue.device(&entry.id);
        }
    }
}

/// A target: its name (the folder names under `corpus/`, `regressions/`, `dict/`) and its
/// body.
pub type Target = (&'static str, fn(&[u8]));

/// Every reader target; the scene target is `scene_input::scene`.
pub fn readers() -> [Target; 10] {
    [
        ("stl", stl),
        ("obj", obj),
        ("ply", ply),
        ("vtp", vtp),
        ("swc", swc),
        ("slicer", slicer),
        ("metaimage", metaimage),
        ("nifti", nifti),
        ("dicom", dicom),
        ("devices", devices),
    ]
}
