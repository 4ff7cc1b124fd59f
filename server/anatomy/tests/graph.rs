//! Vessel graph queries and path finding, and the procedural neuro phantom's anatomy.

use cathlab_anatomy::graph::VesselKind;
use cathlab_anatomy::phantom::{ArchType, NeuroPhantomParams, neuro_phantom, y_bifurcation};
use nalgebra::Point3;

#[test]
fn nearest_point_on_the_graph_gives_branch_arc_length_radius_and_direction() {
    let g = y_bifurcation(3e-3, 2e-3, 20e-3, 15e-3, 0.5).unwrap();
    let at = g.nearest(&Point3::new(1e-3, 0.0, -5e-3)).unwrap();
    assert_eq!(g.branches[at.branch].name, "parent");
    assert!((at.arc_length - 15e-3).abs() < 1e-12);
    assert!((at.distance - 1e-3).abs() < 1e-12);
    assert!((at.radius - 3e-3).abs() < 1e-15);
    assert!((at.direction - nalgebra::Vector3::z()).norm() < 1e-12);
    let path = g.path_to(&g.landmarks["access"], "left").unwrap();
    assert!((path.length - 35e-3).abs() < 1e-12);
    assert_eq!(path.legs.len(), 2);
    assert!(g.path_to(&Point3::origin(), "nowhere").is_err());
}

#[test]
fn phantom_is_seeded_and_names_every_required_vessel() {
    let params = NeuroPhantomParams::default();
    let a = neuro_phantom(&params).unwrap();
    assert_eq!(
        a,
        neuro_phantom(&params).unwrap(),
        "same seed, same phantom"
    );
    assert_ne!(
        a,
        neuro_phantom(&NeuroPhantomParams { seed: 2, ..params }).unwrap()
    );
    for kind in [
        VesselKind::Aorta,
        VesselKind::Brachiocephalic,
        VesselKind::CommonCarotid,
        VesselKind::InternalCarotid,
        VesselKind::ExternalCarotid,
        VesselKind::Vertebral,
        VesselKind::Basilar,
        VesselKind::AnteriorCerebral,
        VesselKind::MiddleCerebral,
        VesselKind::PosteriorCerebral,
        VesselKind::AnteriorCommunicating,
        VesselKind::PosteriorCommunicating,
    ] {
        assert!(
            a.branches.iter().any(|b| b.kind == kind),
            "{kind:?} missing"
        );
    }
    let access = a.landmarks["access"];
    for target in [
        "left_common_carotid",
        "right_common_carotid",
        "right_vertebral",
        "left_middle_cerebral",
        "basilar",
        "anterior_communicating",
    ] {
        let path = a.path_to(&access, target).unwrap();
        assert!(
            path.length > 0.1 && path.length < 0.7,
            "{target}: {} m",
            path.length
        );
    }
}

#[test]
fn phantom_dimensions_are_physiological() {
    let g = neuro_phantom(&NeuroPhantomParams {
        variability: 1.0,
        seed: 9,
        ..Default::default()
    })
    .unwrap();
    // Diameters (mm) from NOTES.md, with the ±10 % variability.
    let expect = |name: &str, lo: f64, hi: f64| {
        let b = g.branch(name).unwrap();
        let d = 2e3 * b.radii[0];
        assert!(
            d >= lo && d <= hi,
            "{name} diameter {d} mm not in {lo}..{hi}"
        );
    };
    expect("ascending_aorta", 25.0, 31.0);
    expect("left_common_carotid", 6.0, 8.0);
    expect("right_internal_carotid", 4.5, 5.8);
    expect("left_middle_cerebral", 2.7, 3.5);
    expect("basilar", 3.2, 4.0);
    expect("right_vertebral", 3.3, 4.2);
}

#[test]
fn arch_type_sets_how_far_below_the_apex_the_brachiocephalic_arises() {
    let drop = |arch| {
        let g = neuro_phantom(&NeuroPhantomParams {
            arch,
            variability: 0.0,
            ..Default::default()
        })
        .unwrap();
        let apex = g
            .branches
            .iter()
            .filter(|b| b.kind == VesselKind::Aorta)
            .flat_map(|b| b.points.iter())
            .map(|p| p.z)
            .fold(f64::MIN, f64::max);
        apex - g.branch("brachiocephalic").unwrap().points[0].z
    };
    let cca = 7e-3;
    let (one, two, three) = (drop(ArchType::I), drop(ArchType::II), drop(ArchType::III));
    assert!(one < cca, "type I: {one}");
    assert!(two >= cca && two <= 2.0 * cca, "type II: {two}");
    assert!(three > 2.0 * cca, "type III: {three}");
}

#[test]
fn bad_parameters_and_branches_are_refused_by_name() {
    use cathlab_anatomy::graph::{BranchSpec, Side, VesselGraph};
    use cathlab_anatomy::phantom::{straight_tube, torus_segment};
    use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};
    let says = |err: cathlab_anatomy::AnatomyError, words: &str| {
        assert!(
            err.to_string().contains(words),
            "{err} should mention {words}"
        );
    };
    says(
        neuro_phantom(&NeuroPhantomParams {
            tortuosity: 2.0,
            ..Default::default()
        })
        .unwrap_err(),
        "tortuosity",
    );
    says(
        neuro_phantom(&NeuroPhantomParams {
            variability: f64::NAN,
            ..Default::default()
        })
        .unwrap_err(),
        "variability",
    );
    says(straight_tube(-1e-3, 1e-2).unwrap_err(), "radius");
    says(torus_segment(1e-3, 2e-3, 1.0).unwrap_err(), "major_radius");
    let tube = straight_tube(1e-3, 1e-2).unwrap();
    says(
        lumen_surface(
            &tube,
            &SurfaceSettings {
                cells_per_radius: 0.0,
                ..Default::default()
            },
        )
        .unwrap_err(),
        "cells_per_radius",
    );
    let mut g = VesselGraph::new();
    let spec = |points: Vec<Point3<f64>>, radius: f64| BranchSpec {
        name: "v".into(),
        kind: VesselKind::Other,
        side: Side::Midline,
        radii: vec![radius; points.len()],
        points,
    };
    says(
        g.add_branch(spec(vec![Point3::origin()], 1e-3))
            .unwrap_err(),
        "1 centerline points",
    );
    says(
        g.add_branch(spec(
            vec![Point3::origin(), Point3::new(0.0, 0.0, 1e-2)],
            f64::NAN,
        ))
        .unwrap_err(),
        "radius 0",
    );
    says(
        g.add_branch(spec(vec![Point3::origin(), Point3::origin()], 1e-3))
            .unwrap_err(),
        "zero length",
    );
}

/// Two ways from the access to a target: up a 30 mm carotid, or over a 5 mm vertebral and a
/// 5 mm communicating artery. The route takes the carotid, unless the short way is an
/// ordinary vessel or the only way.
#[test]
fn routes_cross_a_communicating_artery_only_where_nothing_else_leads() {
    use cathlab_anatomy::graph::{BranchSpec, Side, VesselGraph};
    let mm = |x: f64, y: f64| Point3::new(x * 1e-3, y * 1e-3, 0.0);
    let build = |short_way: VesselKind, with_carotid: bool| {
        let mut g = VesselGraph::new();
        let mut vessels = vec![
            (
                "vertebral",
                VesselKind::Vertebral,
                vec![mm(0.0, 0.0), mm(0.0, 5.0)],
            ),
            ("short_way", short_way, vec![mm(0.0, 5.0), mm(0.0, 10.0)]),
            (
                "target",
                VesselKind::MiddleCerebral,
                vec![mm(0.0, 10.0), mm(0.0, 20.0)],
            ),
        ];
        if with_carotid {
            vessels.push((
                "carotid",
                VesselKind::InternalCarotid,
                vec![mm(0.0, 0.0), mm(10.0, 0.0), mm(10.0, 10.0), mm(0.0, 10.0)],
            ));
        }
        for (name, kind, points) in vessels {
            g.add_branch(BranchSpec {
                name: name.into(),
                kind,
                side: Side::Left,
                radii: vec![1e-3; points.len()],
                points,
            })
            .unwrap();
        }
        let path = g.path_to(&mm(0.0, 0.0), "target").unwrap();
        let legs: Vec<String> = path
            .legs
            .iter()
            .map(|l| g.branches[l.branch].name.clone())
            .collect();
        (legs, path.length)
    };
    let (legs, length) = build(VesselKind::Other, true);
    assert_eq!(legs, ["vertebral", "short_way", "target"]);
    assert!((length - 20e-3).abs() < 1e-12);
    let (legs, length) = build(VesselKind::PosteriorCommunicating, true);
    assert_eq!(legs, ["carotid", "target"]);
    assert!((length - 40e-3).abs() < 1e-12, "the length is the real one");
    let (legs, _) = build(VesselKind::PosteriorCommunicating, false);
    assert_eq!(legs, ["vertebral", "short_way", "target"]);
}
