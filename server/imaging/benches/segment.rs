//! Time and peak memory of the whole segmentation pipeline (`cargo bench -p cathlab-imaging
//! --bench segment`): the real `data/ct/aorta.mha` from the README's seed, and a 256³
//! synthetic CT of the reference tree (0.5 mm voxels, noise and blur). Each case runs in a
//! fresh child process so that its peak resident memory (VmHWM) is its own.

use std::path::Path;
use std::time::Instant;

use cathlab_imaging::ScalarVolume;
use cathlab_imaging::segment::phantom::{SyntheticCt, reference_tree, synthetic_cta};
use cathlab_imaging::segment::{Seed, SegmentSettings, segment};
use nalgebra::{Point3, Vector3};

const CASE_VARIABLE: &str = "CATHLAB_SEGMENT_BENCH_CASE";

fn peak_resident_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn run(case: &str) {
    let (volume, seed) = match case {
        "aorta" => (
            ScalarVolume::load(
                &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/ct/aorta.mha"),
            )
            .expect("aorta.mha"),
            Seed::Voxel([72, 300, 17]),
        ),
        _ => {
            // The reference tree scaled ×2.13 fills a 128 mm cube: 256³ voxels of 0.5 mm.
            let scale = 128.0 / 60.0;
            let tree = reference_tree(scale).expect("tree");
            (
                synthetic_cta(
                    &tree,
                    Vector3::zeros(),
                    [256; 3],
                    0.5e-3,
                    &SyntheticCt::default(),
                )
                .expect("synthetic CT"),
                Seed::Position(Point3::new(31.5, 29.5, 8.0) * scale * 1e-3),
            )
        }
    };
    let loaded_mib = peak_resident_mib();
    let start = Instant::now();
    let result = segment(&volume, &seed, &SegmentSettings::default()).expect("segmentation");
    let seconds = start.elapsed().as_secs_f64();
    let r = &result.report;
    println!(
        "segment/{case}: {}×{}×{} voxels, {:.2} s, peak resident {:.0} MiB (input loaded: {:.0} MiB); \
         {} branches, {:.0} mm, {} surface triangles (decimated from {}); stages: {}",
        volume.dims[0],
        volume.dims[1],
        volume.dims[2],
        seconds,
        peak_resident_mib(),
        loaded_mib,
        r.branches,
        r.total_length_mm,
        r.surface_triangles,
        r.polygonised_triangles,
        r.stages_text()
    );
}

fn main() {
    if let Ok(case) = std::env::var(CASE_VARIABLE) {
        run(&case);
        return;
    }
    // `cargo bench` passes --bench; `cargo test --benches` does not: then only the smaller
    // case runs, as a smoke test.
    let full = std::env::args().any(|a| a == "--bench");
    let cases: &[&str] = if full {
        &["aorta", "synthetic256"]
    } else {
        &["aorta"]
    };
    let exe = std::env::current_exe().expect("own path");
    for case in cases {
        let status = std::process::Command::new(&exe)
            .env(CASE_VARIABLE, case)
            .status()
            .expect("child");
        assert!(status.success(), "case {case} failed");
    }
}
