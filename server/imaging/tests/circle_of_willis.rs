//! The circle of Willis named in vessel surfaces: the neuro phantom's surface, whose arteries
//! are known by construction, and the real arch-to-cow surface, against its own given
//! centerlines and the anatomy's layout.

use std::collections::BTreeSet;
use std::path::PathBuf;

use cathlab_anatomy::graph::{BranchSpec, VesselGraph};
use cathlab_anatomy::io::slicer;
use cathlab_anatomy::lumen::GridSettings;
use cathlab_anatomy::phantom::{NeuroPhantomParams, neuro_phantom};
use cathlab_anatomy::real::load_arch_to_cow_trimmed;
use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};
use cathlab_anatomy::{Branch, Lumen};
use cathlab_imaging::circle_of_willis::{
    CircleInflows, CircleOfWillis, CircleSettings, circle_of_willis,
};
use nalgebra::{Point3, Vector3};

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow")
}

/// Distance from `p` to the polyline `line` (m).
fn to_polyline(p: &Point3<f64>, line: &[Point3<f64>]) -> f64 {
    line.windows(2)
        .map(|w| {
            let s = w[1] - w[0];
            let t = ((p - w[0]).dot(&s) / s.norm_squared()).clamp(0.0, 1.0);
            (p - (w[0] + s * t)).norm()
        })
        .fold(f64::INFINITY, f64::min)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn length(b: &BranchSpec) -> f64 {
    b.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
}

fn named(circle: &CircleOfWillis, name: &str) -> BranchSpec {
    circle
        .branches
        .iter()
        .find(|b| b.name == name)
        .unwrap_or_else(|| panic!("{name} is not named"))
        .clone()
}

/// The phantom's head arteries, from 178 mm up (the vessels below are long tubes the box
/// cuts anyway), and their surface.
fn phantom_head() -> (VesselGraph, Lumen) {
    let truth = neuro_phantom(&NeuroPhantomParams::default()).unwrap();
    let head = [
        "internal_carotid",
        "middle_cerebral",
        "anterior_cerebral_a1",
        "anterior_cerebral_a2",
        "vertebral",
        "posterior_cerebral_p1",
        "posterior_cerebral_p2",
        "posterior_communicating",
    ];
    let mut graph = VesselGraph::new();
    for b in &truth.branches {
        let keep = b.name == "basilar"
            || b.name == "anterior_communicating"
            || head
                .iter()
                .any(|h| b.name == format!("left_{h}") || b.name == format!("right_{h}"));
        if keep {
            let first = b.points.iter().position(|p| p.z > 0.178).unwrap();
            graph
                .add_branch(BranchSpec {
                    name: b.name.clone(),
                    kind: b.kind,
                    side: b.side,
                    points: b.points[first..].to_vec(),
                    radii: b.radii[first..].to_vec(),
                })
                .unwrap();
        }
    }
    let mesh = lumen_surface(
        &graph,
        &SurfaceSettings {
            cells_per_radius: 1.5,
            ..SurfaceSettings::default()
        },
    )
    .unwrap();
    let lumen = Lumen::with_grid_settings(
        mesh,
        "phantom head",
        GridSettings {
            cell_size: Some(0.5e-3),
            band: 1e-3,
        },
    )
    .unwrap();
    (graph, lumen)
}

#[test]
fn the_phantoms_circle_of_willis_is_named_as_it_was_built() {
    let (truth, lumen) = phantom_head();
    let before_end = |name: &str, back: f64| {
        let b = truth.branch(name).unwrap();
        b.point_at(b.length() - back)
    };
    let circle = circle_of_willis(
        &lumen,
        &CircleInflows {
            left_internal_carotid: before_end("left_internal_carotid", 20e-3),
            right_internal_carotid: before_end("right_internal_carotid", 20e-3),
            left_vertebral: before_end("left_vertebral", 15e-3),
            right_vertebral: before_end("right_vertebral", 15e-3),
            left: Vector3::x(),
            superior: Vector3::z(),
        },
        &CircleSettings {
            voxel_m: 0.3e-3,
            margin_m: 30e-3,
        },
    )
    .unwrap();
    // Every artery the phantom has in the box, and no other name (its communicating
    // arteries leave the carotids at their termini, so no communicating ICA segment).
    let names: BTreeSet<&str> = circle.branches.iter().map(|b| b.name.as_str()).collect();
    let expected: BTreeSet<&str> = truth.branches.iter().map(|b| b.name.as_str()).collect();
    assert_eq!(names, expected);
    assert!(circle.loops_closed >= 1, "the skeleton's tree broke a loop");
    let junctions: Vec<Point3<f64>> = circle.landmarks.values().copied().collect();
    for b in &circle.branches {
        let own: &Branch = truth.branch(&b.name).unwrap();
        let mut distances = Vec::new();
        for p in &b.points {
            let d = to_polyline(p, &own.points);
            distances.push(d);
            // Away from junctions, each point is nearest its namesake.
            if junctions.iter().all(|j| (p - j).norm() > 4e-3) {
                for other in truth.branches.iter().filter(|o| o.name != b.name) {
                    assert!(
                        d <= to_polyline(p, &other.points),
                        "a point of {} lies nearer {}",
                        b.name,
                        other.name
                    );
                }
            }
        }
        let m = median(distances);
        assert!(m < 0.35e-3, "{}: median {:.2} mm off", b.name, m * 1e3);
        let radius = median(b.radii.clone());
        let true_radius = median(own.radii.clone());
        assert!(
            (radius / true_radius - 1.0).abs() < 0.2,
            "{}: radius {:.2} mm, built {:.2} mm",
            b.name,
            radius * 1e3,
            true_radius * 1e3
        );
        println!(
            "{:32} {:5.1} mm (built {:5.1}), median {:.2} mm off, radius {:.2} mm (built {:.2})",
            b.name,
            length(b) * 1e3,
            own.length() * 1e3,
            m * 1e3,
            radius * 1e3,
            true_radius * 1e3
        );
    }
    // The arteries the box does not cut are as long as built, to within the junctions'
    // placement.
    for name in [
        "left_anterior_cerebral_a1",
        "right_anterior_cerebral_a1",
        "basilar",
        "left_posterior_cerebral_p1",
        "right_posterior_cerebral_p1",
        "left_posterior_communicating",
        "right_posterior_communicating",
    ] {
        let built = truth.branch(name).unwrap().length();
        let found = length(&named(&circle, name));
        assert!(
            (found / built - 1.0).abs() < 0.15,
            "{name}: {:.1} mm named, {:.1} mm built",
            found * 1e3,
            built * 1e3
        );
    }
}

#[test]
fn the_arch_to_cow_circle_of_willis_is_named_from_its_surface() {
    let trim = 20e-3;
    let (anatomy, ends) = load_arch_to_cow_trimmed(&data_dir(), trim).unwrap();
    let inflows = CircleInflows::arch_to_cow(&ends).unwrap();
    let (left, superior) = (inflows.left, inflows.superior);
    let anterior = left.cross(&superior);
    let circle = circle_of_willis(&anatomy.lumen, &inflows, &CircleSettings::default()).unwrap();
    let mut names: Vec<&str> = circle.branches.iter().map(|b| b.name.as_str()).collect();
    names.sort();
    println!("{names:?}");
    for side in ["left", "right"] {
        for artery in [
            "internal_carotid",
            "middle_cerebral",
            "anterior_cerebral_a1",
            "anterior_cerebral_a2",
            "posterior_communicating",
            "posterior_cerebral_p1",
            "posterior_cerebral_p2",
            "vertebral",
        ] {
            assert!(names.contains(&format!("{side}_{artery}").as_str()));
        }
    }
    assert!(names.contains(&"basilar") && names.contains(&"anterior_communicating"));
    // Inside the lumen, every point of every named artery.
    for b in &circle.branches {
        for p in &b.points {
            assert!(anatomy.lumen.query(p).signed_distance < 0.0, "{}", b.name);
        }
    }
    // The layout of a circle of Willis: middle cerebrals lateral of their termini, anterior
    // cerebrals in front of them, posterior cerebrals behind the basilar top, the basilar
    // running up, and left things left of right ones.
    let mark = |name: &str| circle.landmarks[name];
    let tip = |name: &str| *named(&circle, name).points.last().unwrap();
    let start = |name: &str| named(&circle, name).points[0];
    for (side, sign) in [("left", 1.0), ("right", -1.0)] {
        let terminus = mark(&format!("{side}_ica_terminus"));
        assert!(sign * (tip(&format!("{side}_middle_cerebral")) - terminus).dot(&left) > 5e-3);
        assert!((tip(&format!("{side}_anterior_cerebral_a2")) - terminus).dot(&anterior) > 5e-3);
        assert!(
            (tip(&format!("{side}_posterior_cerebral_p2")) - mark("basilar_top")).dot(&anterior)
                < 0.0
        );
    }
    assert!((mark("left_ica_terminus") - mark("right_ica_terminus")).dot(&left) > 10e-3);
    assert!((mark("basilar_top") - mark("vertebrobasilar_junction")).dot(&superior) > 15e-3);
    assert!(
        (start("anterior_communicating") - mark("left_acom_junction")).norm() < 1e-9
            || (start("anterior_communicating") - mark("right_acom_junction")).norm() < 1e-9
    );
    // Against the anatomy's own centerlines (3D Slicer's, given with the data): the named
    // carotids and vertebrals run along the 20 mm the trim took off them.
    for (curve, artery) in [
        ("LCCA", "left_internal_carotid"),
        ("RCCA", "right_internal_carotid"),
        ("LVA", "left_vertebral"),
        ("RVA", "right_vertebral"),
    ] {
        let given = slicer::load(&data_dir().join(format!("centerlines/{curve}.mrk.json")))
            .unwrap()
            .remove(0);
        let ours = named(&circle, artery);
        let cut = given
            .points
            .iter()
            .position(|p| (p - ours.points[0]).norm() < 1e-9)
            .unwrap();
        let trimmed = &given.points[cut..];
        let near: Vec<f64> = ours
            .points
            .iter()
            .filter(|p| to_polyline(p, trimmed) < 5e-3)
            .map(|p| to_polyline(p, trimmed))
            .collect();
        let m = median(near.clone());
        // Depth inside the lumen: ours are at least as central as the given points.
        let depth = |ps: &[Point3<f64>]| {
            median(
                ps.iter()
                    .map(|p| -anatomy.lumen.query(p).signed_distance)
                    .collect(),
            )
        };
        let (ours_deep, given_deep) = (depth(&ours.points), depth(trimmed));
        let radius = median(ours.radii.clone());
        println!(
            "{artery}: median {:.2} mm from {curve}'s last 20 mm ({} points), {:.2} mm deep \
             (given {:.2} mm), radius {:.2} mm",
            m * 1e3,
            near.len(),
            ours_deep * 1e3,
            given_deep * 1e3,
            radius * 1e3
        );
        assert!(m < 0.5 * radius, "{artery}: {:.2} mm from {curve}", m * 1e3);
        assert!(
            ours_deep > 0.95 * given_deep,
            "{artery} is less central than {curve}"
        );
        assert!(
            near.len() as f64 * 0.4e-3 > 0.7 * trim,
            "{artery} does not follow {curve}"
        );
    }
    println!(
        "{} arteries, {} loop(s) closed, {:.0} mm unnamed",
        circle.branches.len(),
        circle.loops_closed,
        circle.unnamed_length_m * 1e3
    );
}
