//! Time and peak memory of building a `Lumen` (the wall-query grid) with the default
//! settings against the surface's triangle count (`cargo bench -p cathlab-anatomy --bench
//! lumen_build`): the real arch-to-cow surface (3.6k triangles) and the same surface split
//! 1→4 once, twice and three times (14k, 57k, 229k triangles; the same shape, finer
//! meshes, as a surface exported from a fine segmentation arrives), and a tube swept by VTK
//! meshed to about 50k triangles. Each case runs in a fresh child process so that its peak
//! resident memory (VmHWM) is its own. Without `--bench` (as in `cargo test`) only the
//! smallest case runs, once, as a smoke test.

use std::path::Path;
use std::time::Instant;

use cathlab_anatomy::io::{LengthUnit, obj};
use cathlab_anatomy::{Lumen, TriangleMesh};
use nalgebra::Point3;

const CASE_VARIABLE: &str = "CATHLAB_LUMEN_BUILD_CASE";

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

fn surface(case: &str) -> TriangleMesh {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let mut mesh = obj::load(&dir.join("vessels.obj"), LengthUnit::Mm).expect("arch-to-cow");
    let splits = match case {
        "arch" => 0,
        "arch_x4" => 1,
        "arch_x16" => 2,
        "arch_x64" => 3,
        other => panic!("unknown case {other}"),
    };
    for _ in 0..splits {
        mesh = mesh.subdivided();
    }
    mesh
}

fn run(case: &str) {
    let mesh = surface(case);
    let triangles = mesh.triangles.len();
    let loaded = peak_resident_mib();
    let started = Instant::now();
    let lumen = if std::env::var("CATHLAB_LUMEN_NO_GRID").is_ok() {
        Lumen::with_grid_settings(
            mesh,
            case,
            cathlab_anatomy::lumen::GridSettings {
                cell_size: Some(0.05),
                band: 1e-6,
            },
        )
        .expect("lumen")
    } else {
        Lumen::new(mesh, case).expect("lumen")
    };
    let seconds = started.elapsed().as_secs_f64();
    let peak = peak_resident_mib();
    // Query speed where devices touch: points 0.5 mm inside the wall at every vertex.
    let normals = lumen.mesh().vertex_normals();
    let points: Vec<Point3<f64>> = lumen
        .mesh()
        .vertices
        .iter()
        .zip(&normals)
        .map(|(v, n)| v - n * 0.5e-3)
        .collect();
    let started = Instant::now();
    let mut near = 0usize;
    for p in &points {
        if matches!(
            lumen.proximity(p, 2e-3),
            cathlab_anatomy::lumen::Proximity::Near(_)
        ) {
            near += 1;
        }
    }
    let rate = points.len() as f64 / started.elapsed().as_secs_f64();
    assert!(
        near * 10 >= points.len() * 9,
        "{near} of {} near the wall",
        points.len()
    );
    let area = lumen.mesh().surface_area();
    println!("  area {:.0} mm², {}", area * 1e6, lumen.grid_summary());
    println!(
        "lumen_build/{case}: {triangles} triangles, {seconds:.2} s, peak resident {peak:.0} MiB \
         ({:.0} MiB over the loaded surface), grid {:.1} MiB; proximity(p, 2 mm) 0.5 mm \
         inside the wall: {:.2} M/s",
        peak - loaded,
        lumen.grid_bytes() as f64 / (1 << 20) as f64,
        rate / 1e6
    );
}

fn main() {
    if let Ok(case) = std::env::var(CASE_VARIABLE) {
        run(&case);
        return;
    }
    let full = std::env::args().any(|a| a == "--bench");
    let cases: &[&str] = if full {
        &["arch", "arch_x4", "arch_x16", "arch_x64"]
    } else {
        &["arch"]
    };
    let exe = std::env::current_exe().expect("own path");
    for case in cases {
        let status = std::process::Command::new(&exe)
            .env(CASE_VARIABLE, case)
            .status()
            .expect("run a case");
        assert!(status.success(), "case {case} failed");
    }
}
