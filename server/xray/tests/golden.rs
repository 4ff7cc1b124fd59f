//! Golden images: the real aorta CT at three C-arm poses and the arch-to-circle-of-Willis
//! vessels in the synthesized body (chest AP, neck lateral, head AP, roadmap) with contrast
//! and devices, noise off, against PNGs kept in `tests/golden/`
//! (mean difference ≤ 0.5 grey level, 99.9 % of pixels within 2). Both renderers are held
//! to the same images. `CATHLAB_BLESS=1` rewrites the PNGs after a deliberate change.

use std::path::{Path, PathBuf};

use cathlab_xray::scene::SceneSpec;
use cathlab_xray::{CpuRenderer, GpuRenderer, Renderer};

const SCENES: [&str; 7] = [
    "aorta_ap",
    "aorta_lateral",
    "aorta_cranial",
    "arch_to_cow_lcca",
    "arch_to_cow_lateral",
    "arch_to_cow_head",
    "arch_to_cow_roadmap",
];

fn scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.yaml"))
}

fn golden_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("tests/golden/{name}.png"))
}

#[test]
fn renders_match_the_golden_images() {
    let bless = std::env::var_os("CATHLAB_BLESS").is_some();
    let mut gpu = GpuRenderer::if_available().unwrap();
    for name in SCENES {
        let path = scene_path(name);
        let mut spec = SceneSpec::read(&path).unwrap();
        spec.carm.size_px = [256, 256];
        spec.detector.noise = Some(false);
        let scene = spec.load(&path).unwrap();
        let mut renderers: Vec<Box<dyn Renderer>> = vec![Box::new(CpuRenderer::default())];
        if let Some(g) = gpu.take() {
            renderers.push(Box::new(g));
        }
        for renderer in renderers {
            let label = renderer.name();
            let frame = scene.render(renderer).unwrap();
            let grey = frame.to_8bit();
            let golden = golden_path(name);
            if bless && label.starts_with("cpu") {
                std::fs::create_dir_all(golden.parent().unwrap()).unwrap();
                image::GrayImage::from_raw(256, 256, grey.clone())
                    .unwrap()
                    .save(&golden)
                    .unwrap();
            }
            let reference = image::open(&golden)
                .unwrap_or_else(|e| {
                    panic!("{}: {e} (bless with CATHLAB_BLESS=1)", golden.display())
                })
                .to_luma8()
                .into_raw();
            let (mean, far) = cathlab_xray::golden::difference(&grey, &reference);
            println!(
                "{name} on {label}: mean |Δ| {mean:.3} grey levels, {:.3} % beyond 2",
                far * 100.0
            );
            assert!(
                cathlab_xray::golden::within_tolerance((mean, far)),
                "{name} on {label}: {mean}, {far}"
            );
        }
        // The GPU renderer is opened once; get it back for the next scene.
        if gpu.is_none() {
            gpu = GpuRenderer::if_available().unwrap();
        }
    }
}

#[test]
fn bad_scenes_give_named_errors() {
    let dir = std::env::temp_dir().join(format!("cathlab-xray-scene-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let write = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    // The error of loading a scene that parses.
    let load_error = |name: &str, text: &str| {
        let p = write(name, text);
        SceneSpec::read(&p)
            .unwrap()
            .load(&p)
            .err()
            .unwrap()
            .to_string()
    };
    let p = write(
        "typo.yaml",
        "ct: !phantom\n  spacing_mm: 2\ncarm:\n  isocenter: volume_centre\n  primry_deg: 3\n",
    );
    let err = SceneSpec::read(&p).unwrap_err().to_string();
    assert!(err.contains("primry_deg"), "{err}");
    let err = load_error(
        "no_anatomy.yaml",
        "ct: !phantom\n  spacing_mm: 2\ncarm:\n  isocenter: volume_centre\n",
    );
    assert!(err.contains("phantom needs an anatomy"), "{err}");
    let err = load_error(
        "missing_ct.yaml",
        "ct: !file\n  path: nowhere.mha\ncarm:\n  isocenter: volume_centre\n",
    );
    assert!(err.contains("nowhere.mha"), "{err}");
    write(
        "cut.mha",
        "ObjectType = Image\nNDims = 3\nDimSize = 4 4 4\nElementType = MET_SHORT\nElementDataFile = LOCAL\n\x01\x02",
    );
    let err = load_error(
        "cut.yaml",
        "ct: !file\n  path: cut.mha\ncarm:\n  isocenter: volume_centre\n",
    );
    assert!(err.contains("truncated"), "{err}");
    write(
        "tiny.mha",
        "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n\x01\x02\x03\x04\x05\x06\x07\x08",
    );
    let err = load_error(
        "zero.yaml",
        "ct: !file\n  path: tiny.mha\ncarm:\n  isocenter: !point [0, 0, 0]\n  size_px: [0, 512]\n",
    );
    assert!(err.contains("width"), "{err}");
    let err = load_error(
        "device_without_anatomy.yaml",
        "ct: !file\n  path: tiny.mha\ncarm:\n  isocenter: volume_centre\ndevices:\n  - preset: catheter_5f\n    to: LCCA\n    length_m: 0.1\n",
    );
    assert!(err.contains("a device needs an anatomy"), "{err}");
    let err = load_error(
        "iso_without_anatomy.yaml",
        "ct: !file\n  path: tiny.mha\ncarm:\n  isocenter: !branch\n    name: LCCA\n    at: 0.5\n",
    );
    assert!(
        err.contains("isocenter on a branch needs an anatomy"),
        "{err}"
    );
}
