//! The synthesized body is registered to the vessel trees it is built around: every
//! centerline point lies in soft tissue (not air, lung or bone), the aorta in the
//! mediastinum and the cervical carotids in the neck; and the body's own anatomy sits where
//! textbooks put it relative to those vessels (lungs either side of the heart, brain inside a
//! closed skull, vertebrae behind the vertebral arteries).

use std::path::Path;

use cathlab_anatomy::graph::VesselGraph;
use cathlab_anatomy::phantom::{ArchType, NeuroPhantomParams, neuro_phantom};
use cathlab_xray::phantom::{BodyPhantom, Region, Tissue};
use cathlab_xray::scene::ARCH_TO_COW_TO_LPS;
use nalgebra::{Matrix3, Point3};

fn arch_to_cow() -> (VesselGraph, Matrix3<f64>) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let anatomy = cathlab_anatomy::real::load_arch_to_cow(&dir).expect("bundled anatomy");
    (
        anatomy.graph,
        Matrix3::from_fn(|r, c| ARCH_TO_COW_TO_LPS[r][c]),
    )
}

fn neuro(seed: u64, arch: ArchType, tortuosity: f64) -> (VesselGraph, Matrix3<f64>) {
    let graph = neuro_phantom(&NeuroPhantomParams {
        seed,
        arch,
        tortuosity,
        ..NeuroPhantomParams::default()
    })
    .expect("phantom");
    (graph, Matrix3::identity())
}

/// Checks every centerline point of `graph` against the body built around it; returns the
/// failures as readable lines.
fn misplaced(name: &str, graph: &VesselGraph, to_lps: &Matrix3<f64>) -> Vec<String> {
    let body = BodyPhantom::around_graph(graph, to_lps).expect("body");
    let m = *body.landmarks();
    let mut bad = Vec::new();
    let (mut aorta, mut carotid) = (0, 0);
    for b in &graph.branches {
        for (p, &r) in b.points.iter().zip(&b.radii) {
            let p = Point3::from(to_lps * p.coords);
            let s = body.sample(&p);
            let at = format!(
                "{name} {} at L{:.0} P{:.0} S{:.0} mm",
                b.name,
                p.x * 1e3,
                p.y * 1e3,
                p.z * 1e3
            );
            if !s.tissue.is_soft() {
                bad.push(format!("{at}: in {:?} ({:?})", s.tissue, s.region));
            }
            if r >= 7e-3 {
                aorta += 1;
                if s.region != Region::Mediastinum {
                    bad.push(format!("{at}: aorta in {:?}", s.region));
                }
            }
            let cervical = p.z > m.arch_top_s + 0.04 && p.z < m.arch_top_s + 0.10;
            let name = b.name.to_ascii_uppercase();
            if cervical
                && (name.contains("CCA") || name.contains("CAROTID") || name.contains("ICA"))
            {
                carotid += 1;
                if s.region != Region::Neck {
                    bad.push(format!("{at}: carotid in {:?}", s.region));
                }
            }
        }
    }
    if aorta < 20 {
        bad.push(format!("{name}: only {aorta} aorta points checked"));
    }
    if carotid < 20 {
        bad.push(format!(
            "{name}: only {carotid} cervical carotid points checked"
        ));
    }
    bad
}

#[test]
fn every_vessel_of_the_bundled_anatomy_lies_in_soft_tissue_where_it_belongs() {
    let (graph, to_lps) = arch_to_cow();
    let bad = misplaced("arch-to-cow", &graph, &to_lps);
    assert!(
        bad.is_empty(),
        "{} misplaced:\n{}",
        bad.len(),
        bad.join("\n")
    );
}

#[test]
fn every_vessel_of_the_neuro_phantoms_lies_in_soft_tissue_where_it_belongs() {
    let mut bad = Vec::new();
    for (seed, arch, tortuosity) in [
        (1, ArchType::I, 0.3),
        (2, ArchType::II, 0.6),
        (3, ArchType::III, 1.0),
        (4, ArchType::I, 0.0),
    ] {
        let (graph, to_lps) = neuro(seed, arch, tortuosity);
        bad.extend(misplaced(
            &format!("neuro {seed} {arch:?}"),
            &graph,
            &to_lps,
        ));
    }
    assert!(
        bad.is_empty(),
        "{} misplaced:\n{}",
        bad.len(),
        bad.join("\n")
    );
}

#[test]
fn the_body_has_its_anatomy_where_textbooks_put_it() {
    let (graph, to_lps) = arch_to_cow();
    let body = BodyPhantom::around_graph(&graph, &to_lps).expect("body");
    let m = *body.landmarks();
    let at = |l: f64, p: f64, s: f64| body.sample(&Point3::new(m.midline_l + l, p, s));
    // Lungs either side of the mediastinum at the level of the heart (5 cm below the arch).
    let s = m.arch_top_s - 0.05;
    let p = m.thoracic_spine_p - 0.06;
    let scan: Vec<_> = (-14..=14).map(|i| at(f64::from(i) * 0.01, p, s)).collect();
    let lung_right = scan[..10]
        .iter()
        .filter(|x| x.tissue == Tissue::Lung)
        .count();
    let lung_left = scan[19..]
        .iter()
        .filter(|x| x.tissue == Tissue::Lung)
        .count();
    assert!(
        lung_right >= 4 && lung_left >= 3,
        "lungs {lung_right} / {lung_left}: {scan:?}"
    );
    assert_eq!(
        scan[14].region,
        Region::Mediastinum,
        "the midline is mediastinum"
    );
    // A ray from the top of the head down to the circle of Willis crosses scalp, bone, brain.
    let cow = m.circle_of_willis;
    let column: Vec<Tissue> = (0..140)
        .map(|i| {
            body.sample(&Point3::new(
                cow.x,
                cow.y + 0.01,
                cow.z + 0.14 - f64::from(i) * 1e-3,
            ))
            .tissue
        })
        .collect();
    let first_bone = column
        .iter()
        .position(|t| *t == Tissue::CorticalBone)
        .expect("skull");
    assert!(
        column[..first_bone]
            .iter()
            .all(|t| matches!(t, Tissue::Air | Tissue::Soft | Tissue::Fat))
    );
    assert!(
        column[first_bone + 10..]
            .iter()
            .all(|t| *t == Tissue::Brain),
        "{column:?}"
    );
    // A cervical vertebral body behind the vertebral arteries' depth, at the midline.
    let neck_s = m.arch_top_s + 0.08;
    let spine = at(0.0, m.cervical_spine_p, neck_s);
    assert!(
        matches!(
            spine.tissue,
            Tissue::CancellousBone | Tissue::CorticalBone | Tissue::Cartilage
        ),
        "{spine:?}"
    );
    // Air in front of the neck's skin, and air beside the head.
    assert_eq!(
        at(0.0, m.cervical_spine_p - 0.12, neck_s).tissue,
        Tissue::Air
    );
    assert_eq!(at(0.1, cow.y, cow.z + 0.03).tissue, Tissue::Air);
}
