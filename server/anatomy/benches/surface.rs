//! Surface generation time for the full arch-to-circle-of-Willis phantom (one run per
//! setting; `cargo bench -p cathlab-anatomy --bench surface`). Without `--bench` (as in
//! `cargo test --all-targets`) it only builds a small Y bifurcation.

use std::time::Instant;

use cathlab_anatomy::phantom::{NeuroPhantomParams, neuro_phantom, y_bifurcation};
use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    if !full {
        let g = y_bifurcation(3e-3, 2e-3, 10e-3, 10e-3, 0.5).unwrap();
        let mesh = lumen_surface(&g, &SurfaceSettings::default()).unwrap();
        assert!(mesh.topology().is_closed_oriented_manifold());
        return;
    }
    let graph = neuro_phantom(&NeuroPhantomParams::default()).unwrap();
    println!(
        "phantom: {} branches, {:.0} mm of centerline, {} loops",
        graph.branches.len(),
        graph.total_length() * 1e3,
        graph.cycle_rank()
    );
    println!(
        "| cells per radius | smoothing passes | time (s) | triangles | closed manifold | genus |"
    );
    println!("|---|---|---|---|---|---|");
    for (cells, passes) in [(1.5, 1), (2.0, 2)] {
        let settings = SurfaceSettings {
            cells_per_radius: cells,
            smoothing_iterations: passes,
            ..Default::default()
        };
        let start = Instant::now();
        let mesh = lumen_surface(&graph, &settings).unwrap();
        let seconds = start.elapsed().as_secs_f64();
        let t = mesh.topology();
        println!(
            "| {cells} | {passes} | {seconds:.1} | {} | {} | {} |",
            mesh.triangles.len(),
            t.is_closed_oriented_manifold(),
            t.genus()
        );
    }
}
