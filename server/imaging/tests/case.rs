//! Surfaces made into anatomy: open ends found and capped, placement, access choice,
//! centerlines computed, read back from a graph, branches renamed; bad cases named.

use std::collections::BTreeMap;
use std::path::PathBuf;

use cathlab_anatomy::io::LengthUnit;
use cathlab_imaging::case::{
    AccessChoice, Placement, SurfaceCase, load_surface_case, placed_surface,
};

fn open_surface() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../data/anatomy/arch-to-cow-open/vessels_open.vtp")
}

fn case() -> SurfaceCase {
    SurfaceCase {
        surface: open_surface(),
        unit: LengthUnit::Mm,
        placement: Placement {
            rotation_deg: [90.0, 90.0, 0.0],
            translation_mm: [0.0; 3],
        },
        centerlines: None,
        access: AccessChoice::NearMm([37.8, -3.1, 27.3]),
        names: BTreeMap::new(),
        voxel_m: Some(0.9e-3),
        max_voxels: 32_000_000,
    }
}

#[test]
fn the_opened_arch_to_cow_has_three_open_ends_with_their_radii() {
    let (capped, ends) = placed_surface(&case()).unwrap();
    for e in &ends {
        println!(
            "end {}: centre {:.1?} mm, radius {:.2} mm, normal {:.2?}",
            e.index,
            (e.centre.coords * 1e3).as_slice(),
            e.radius_m * 1e3,
            e.normal.as_slice()
        );
    }
    assert_eq!(ends.len(), 3);
    // The two vessels cut at x = −60 mm (LPS z = 60 mm after placement), then the neck end.
    assert!(
        (ends[0].radius_m - 9.5e-3).abs() < 0.5e-3 && (ends[1].radius_m - 8.1e-3).abs() < 0.5e-3
    );
    assert!((ends[0].centre.z - 57.5e-3).abs() < 3e-3 && (ends[1].centre.z - 56.4e-3).abs() < 3e-3);
    // Out of the vessels: towards the feet (−S), though this surface's faces point inward.
    assert!(
        ends[0].normal.z < -0.9 && ends[1].normal.z < -0.9,
        "{:?}",
        ends[0].normal
    );
    assert!(capped.topology().is_closed_oriented_manifold());
}

#[test]
fn the_clipped_arch_to_cow_becomes_anatomy() {
    let loaded = load_surface_case(&case()).unwrap();
    println!("{} branches", loaded.anatomy.graph.branches.len());
}
