//! Frame-rate benchmarks: a fluoroscopy frame at 512² and 1024² from a cached background
//! (contrast and device layers, transmission, Poisson noise, blur, log, 8-bit encoding) on
//! the CPU; background re-projection of a 256³ volume at 512² after a pose change, CPU and
//! wgpu; the memory a 256³ volume takes on each (printed); and the synthetic CT of the neuro
//! phantom's body at the stroke scenes' 2 mm (the largest part of loading a stroke scene).

use std::path::Path;
use std::sync::Arc;

use cathlab_xray::phantom::{BodyLandmarks, BodyPhantom};
use cathlab_xray::scene::SceneSpec;
use cathlab_xray::{
    CpuRenderer, Fluoroscope, FluoroscopeSettings, GpuRenderer, MarchSettings, Renderer, Scene,
    Volume,
};
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Point3, Vector3};

/// The arch-to-cow fluoroscopy scene (contrast in the LCCA, catheter and wire) at `size`².
fn frame(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/arch_to_cow_lcca.yaml");
    let mut group = c.benchmark_group("fluoroscopy_frame_cpu");
    group.sample_size(20);
    for size in [512u32, 1024] {
        let mut spec = SceneSpec::read(&path).unwrap();
        spec.carm.size_px = [size, size];
        let scene = spec.load(&path).unwrap();
        let mut chain =
            Fluoroscope::new(Box::new(CpuRenderer::default()), scene.settings.clone()).unwrap();
        let shot = Scene {
            volume: &scene.volume,
            carm: &scene.carm,
            layers: &scene.with_contrast,
        };
        // Warm the background cache: the benchmark is the per-frame work.
        chain.expose(0.0, shot).unwrap();
        let mut t = 0.0;
        group.bench_function(format!("{size}x{size}"), |b| {
            b.iter(|| {
                t += 1.0 / 30.0;
                let frame = chain.expose(t, shot).unwrap();
                std::hint::black_box(frame.to_8bit())
            })
        });
        assert_eq!(
            chain.stats().background_renders,
            1,
            "the background stayed cached"
        );
    }
    // The server's chain at 512²: exposure control, scatter and grid, recursive filter, edge
    // enhancement and the automatic window on top of the same frame.
    let mut spec = SceneSpec::read(&path).unwrap();
    spec.carm.size_px = [512, 512];
    let scene = spec.load(&path).unwrap();
    let suite = FluoroscopeSettings {
        spectrum: scene.settings.spectrum.clone(),
        march: scene.settings.march,
        ..FluoroscopeSettings::angio_suite()
    };
    let mut chain = Fluoroscope::new(Box::new(CpuRenderer::default()), suite).unwrap();
    let shot = Scene {
        volume: &scene.volume,
        carm: &scene.carm,
        layers: &scene.with_contrast,
    };
    chain.expose(0.0, shot).unwrap();
    let mut t = 0.0;
    group.bench_function("512x512_angio_suite_chain", |b| {
        b.iter(|| {
            t += 1.0 / 30.0;
            let frame = chain.expose(t, shot).unwrap();
            std::hint::black_box(frame.to_8bit())
        })
    });
    group.finish();
}

/// The synthesized body on a 256³ grid (1.4 mm voxels around a neck).
fn volume_256() -> Arc<Volume> {
    let landmarks = BodyLandmarks {
        circle_of_willis: Point3::new(0.0, 0.0, 0.1),
        arch_top_s: -0.1,
        bottom_s: -0.15,
        midline_l: 0.0,
        cervical_spine_p: 0.02,
        thoracic_spine_p: 0.04,
        aortic_knob_l: 0.035,
        lung_apex_s: -0.005,
        descending_aorta: None,
    };
    let body = BodyPhantom::new(landmarks);
    Arc::new(
        Volume::from_fn(
            [256; 3],
            Vector3::repeat(1.4e-3),
            Vector3::new(0.0, 0.0, 0.02),
            1,
            |p| body.hu(p),
        )
        .unwrap(),
    )
}

fn background(c: &mut Criterion) {
    let volume = volume_256();
    let mut carm = cathlab_xray::CArm {
        isocenter_m: Vector3::new(0.0, 0.0, 0.02),
        ..Default::default()
    };
    carm.detector.field_of_view_m = 0.4;
    let settings = MarchSettings::default();
    let mut gpu = GpuRenderer::if_available().unwrap();
    eprintln!(
        "memory of a 256³ volume: CPU {:.1} MiB (16-bit HU)",
        volume.memory_bytes() as f64 / 1048576.0
    );
    let mut group = c.benchmark_group("background_256cubed_512x512");
    group.sample_size(10);
    let mut angle = 0.0;
    let mut renderers: Vec<Box<dyn Renderer>> = vec![Box::new(CpuRenderer::default())];
    if let Some(g) = gpu.take() {
        renderers.push(Box::new(g));
    }
    for mut renderer in renderers {
        // Upload once (a pose change does not re-upload the volume).
        renderer.project_volume(&volume, &carm, &settings).unwrap();
        if renderer.device_memory_bytes() > 0 {
            eprintln!(
                "memory of a 256³ volume: GPU {:.1} MiB (R16Float 3D texture and 1 byte per 8³ air brick) on {}",
                renderer.device_memory_bytes() as f64 / 1048576.0,
                renderer.name()
            );
        }
        let label = if renderer.device_memory_bytes() > 0 {
            "wgpu"
        } else {
            "cpu"
        };
        group.bench_function(label, |b| {
            b.iter(|| {
                // A new pose every time: nothing can be cached.
                angle += 1.0;
                carm.primary_deg = angle % 90.0;
                std::hint::black_box(renderer.project_volume(&volume, &carm, &settings).unwrap())
            })
        });
    }
    group.finish();
}

/// The body phantom around the default neuro phantom, sampled at 2 mm with 2³ sub-samples
/// per voxel, as a stroke scene's `[ct] phantom` loads it (the default phantom, seed 1; the
/// stroke scenes' is seed 0). `-- synthetic_ct` runs this group alone, after the other
/// groups' set-up (scene, 256³ volume, renderers).
fn phantom_volume(c: &mut Criterion) {
    let graph = cathlab_anatomy::phantom::neuro_phantom(
        &cathlab_anatomy::phantom::NeuroPhantomParams::default(),
    )
    .unwrap();
    let body = BodyPhantom::around_graph(&graph, &nalgebra::Matrix3::identity()).unwrap();
    let mut group = c.benchmark_group("synthetic_ct");
    group.sample_size(10);
    group.bench_function("neuro_phantom_body_2mm", |b| {
        b.iter(|| body.volume(2e-3).unwrap())
    });
    group.finish();
}

criterion_group!(benches, frame, background, phantom_volume);
criterion_main!(benches);
