//! Analytic layers: chords through cylinders, cones, hollow tubes and mitred chains against
//! closed forms and brute-force point sampling; tile binning against testing every piece.

use cathlab_xray::layers::{
    ContrastTube, DeviceAppearance, DeviceBand, LayerMaterial, Layers, TileBins, TubePiece,
};
use cathlab_xray::{CArm, CpuRenderer, Renderer, XrayError};
use nalgebra::{Point3, Vector3};
use proptest::prelude::*;

fn solid(start: Point3<f64>, end: Point3<f64>, r0: f64, r1: f64) -> TubePiece {
    let u = (end - start).normalize();
    TubePiece {
        start,
        end,
        outer_radius_m: [r0, r1],
        inner_radius_m: [0.0, 0.0],
        start_cap: -u,
        end_cap: u,
        material: LayerMaterial::Nitinol,
        density: 1.0,
    }
}

/// Length of the ray inside `inside`, by midpoint sampling of [0, length] in n steps.
fn brute_chord(
    origin: &Point3<f64>,
    direction: &Vector3<f64>,
    length: f64,
    n: usize,
    inside: impl Fn(&Point3<f64>) -> usize,
) -> (f64, usize) {
    let h = length / n as f64;
    let mut total = 0.0;
    let mut worst_overlap = 0;
    for i in 0..n {
        let count = inside(&(origin + direction * ((i as f64 + 0.5) * h)));
        worst_overlap = worst_overlap.max(count);
        total += h * count.min(1) as f64;
    }
    (total, worst_overlap)
}

#[test]
fn cylinder_chords_are_the_closed_form() {
    let r = 0.45e-3;
    let piece = solid(
        Point3::new(0.0, 0.0, -0.05),
        Point3::new(0.0, 0.0, 0.05),
        r,
        r,
    );
    let mut worst: f64 = 0.0;
    for k in 0..=20 {
        let b = r * k as f64 / 20.0 * 0.999;
        for tilt_deg in [0.0, 15.0, 40.0, 70.0] {
            // In the plane x = b, tilted out of the cross-section by `tilt`.
            let t = f64::to_radians(tilt_deg);
            let direction = Vector3::new(0.0, t.cos(), t.sin());
            let origin = Point3::new(b, 0.0, 0.0) - direction * 0.8;
            let exact = 2.0 * (r * r - b * b).sqrt() / t.cos();
            let got = piece.chord(&origin, &direction);
            worst = worst.max((got - exact).abs() / (2.0 * r));
        }
    }
    println!("cylinder chords: worst error {worst:.1e} of the diameter");
    assert!(worst < 1e-8, "{worst}");
    // Along the axis: the full length; beside it: nothing.
    let along = piece.chord(&Point3::new(0.0, 0.0, -1.0), &Vector3::z());
    assert!((along - 0.1).abs() < 1e-12, "{along}");
    assert_eq!(
        piece.chord(&Point3::new(2.0 * r, 0.0, -1.0), &Vector3::z()),
        0.0
    );
}

#[test]
fn hollow_catheter_chords_are_outer_minus_inner() {
    let look = DeviceAppearance::catheter_5f();
    let (ro, ri) = (look.outer_radius_m, look.inner_radius_m);
    let mut piece = solid(
        Point3::new(-0.05, 0.0, 0.0),
        Point3::new(0.05, 0.0, 0.0),
        ro,
        ro,
    );
    piece.inner_radius_m = [ri, ri];
    for k in 0..=20 {
        let b = ro * k as f64 / 20.0 * 0.999;
        let origin = Point3::new(0.0, b, -0.7);
        let got = piece.chord(&origin, &Vector3::z());
        let exact = 2.0 * ((ro * ro - b * b).sqrt() - (ri * ri - b * b).max(0.0).sqrt());
        assert!((got - exact).abs() < 1e-12, "b {b}: {got} vs {exact}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Tapered pieces with oblique caps against brute-force sampling of their inside test,
    /// on random rays through their neighbourhood, including rays close to the axis.
    #[test]
    fn cone_chords_match_brute_force(
        r0 in 0.2e-3..3e-3f64, r1 in 0.2e-3..3e-3f64, hollow in 0.0..0.8f64,
        tilt_a in -0.5..0.5f64, tilt_b in -0.5..0.5f64,
        theta in 0.0..std::f64::consts::PI, phi in 0.0..std::f64::consts::TAU,
        offset_x in -4e-3..4e-3f64, offset_y in -4e-3..4e-3f64,
    ) {
        let start = Point3::new(0.001, -0.002, -0.006);
        let end = Point3::new(-0.001, 0.001, 0.007);
        let mut piece = solid(start, end, r0, r1);
        let u = (end - start).normalize();
        let side = u.cross(&Vector3::x()).normalize();
        piece.start_cap = (-u + side * tilt_a).normalize();
        piece.end_cap = (u + side * tilt_b).normalize();
        piece.inner_radius_m = [r0 * hollow, r1 * hollow];
        let direction = Vector3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
        let across = direction.cross(&Vector3::new(0.3, 0.5, 0.7)).normalize();
        let across2 = direction.cross(&across);
        let centre = Point3::new(0.0, 0.0, 0.0) + across * offset_x + across2 * offset_y;
        let origin = centre - direction * 0.03;
        let (exact, _) = brute_chord(&origin, &direction, 0.06, 600_000, |p| usize::from(piece.contains(p)));
        let got = piece.chord(&origin, &direction);
        // Sampling resolves 1e-7 m per boundary crossing.
        prop_assert!((got - exact).abs() < 5e-7, "chord {got} vs brute force {exact}");
    }
}

#[test]
fn mitred_chains_neither_overlap_nor_leave_gaps() {
    // A wire bent through 40° in three steps: pieces meet on bisector planes.
    let points: Vec<Point3<f64>> = (0..5)
        .map(|i| {
            let a = f64::to_radians(10.0 * (i as f64 - 1.0).max(0.0));
            Point3::new(0.0, 0.0, 0.0)
                + Vector3::new(0.0, 0.0, -0.004)
                + Vector3::new(a.sin(), 0.0, a.cos()) * (0.004 * i as f64)
        })
        .collect();
    let look = DeviceAppearance {
        bands: vec![],
        ..DeviceAppearance::guidewire_035()
    };
    let mut layers = Layers::new();
    layers.add_device(&points, &look).unwrap();
    assert_eq!(layers.pieces().len(), 4);
    let count = |p: &Point3<f64>| layers.pieces().iter().filter(|q| q.contains(p)).count();
    let r = look.outer_radius_m;
    let mut worst: f64 = 0.0;
    for k in 0..40 {
        let a = k as f64 * 0.157;
        let direction = Vector3::new(a.cos(), 0.6, a.sin()).normalize();
        let centre = points[2] + Vector3::new(0.0, 0.0, 1e-4 * k as f64);
        let origin = centre - direction * 0.02;
        let (brute, overlap) = brute_chord(&origin, &direction, 0.04, 400_000, count);
        assert!(overlap <= 1, "pieces overlap on ray {k}");
        let got = layers.paths_along(&origin, &direction)[1];
        worst = worst.max((got - brute).abs());
        // No gap: every point well inside the tube of the polyline is in exactly one piece.
        for i in 0..200 {
            let p = origin + direction * (0.02 - 0.5 * r + r * i as f64 / 200.0);
            let near_axis = points.windows(2).any(|s| {
                let (a, b) = (s[0], s[1]);
                let t = ((p - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
                (p - (a + (b - a) * t)).norm() < 0.95 * r
            });
            let beyond_ends = (p - points[0]).dot(&(points[1] - points[0])) < 0.0
                || (p - points[4]).dot(&(points[4] - points[3])) > 0.0;
            if near_axis && !beyond_ends {
                assert_eq!(count(&p), 1, "gap at {p:?}");
            }
        }
    }
    println!("bent wire: worst chord error {worst:.1e} m against brute force");
    assert!(worst < 5e-7, "{worst}");
}

/// Regression: a wire folded back on itself (a 178° kink, as a device compressed at a
/// catheter's tip) drew a square of metal over its pieces' bounding boxes, because the mitre
/// plane of the kink lay almost along the axes. Past the mitre limit the joint is square:
/// rays beside the wire cross nothing, and rays through it at most two wires' thickness.
#[test]
fn a_folded_wire_draws_no_metal_beside_itself() {
    let fold = f64::to_radians(178.0);
    let points = vec![
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(0.0, 0.0, 0.004),
        Point3::new(
            0.004 * (std::f64::consts::PI - fold).sin(),
            0.0,
            0.004 - 0.004 * (std::f64::consts::PI - fold).cos(),
        ),
    ];
    let look = DeviceAppearance {
        bands: vec![],
        ..DeviceAppearance::guidewire_035()
    };
    let mut layers = Layers::new();
    layers.add_device(&points, &look).unwrap();
    let r = look.outer_radius_m;
    // Rays parallel to y, across a grid in x–z around the fold.
    let direction = Vector3::new(0.0, 1.0, 0.0);
    let count = |p: &Point3<f64>| layers.pieces().iter().filter(|q| q.contains(p)).count();
    for ix in -20..=20 {
        for iz in -10..=30 {
            let (x, z) = (f64::from(ix) * 0.25e-3, f64::from(iz) * 0.25e-3);
            let origin = Point3::new(x, -0.01, z);
            let got = layers.paths_along(&origin, &direction)[1];
            let near = points.windows(2).any(|s| {
                let (a, b) = (s[0], s[1]);
                let q = Point3::new(x, 0.0, z);
                let t = ((q - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
                (q - (a + (b - a) * t)).norm() < 1.05 * r
            });
            if !near {
                assert_eq!(got, 0.0, "metal beside the fold at x {x}, z {z}");
            } else {
                // The two halves overlap at the fold: at most twice the wire's thickness, and
                // never less than the union of the pieces.
                let (brute, _) = brute_chord(&origin, &direction, 0.02, 20_000, count);
                assert!(
                    got <= 4.0 * r + 1e-9,
                    "x {x}, z {z}: {got} is more than two wires"
                );
                assert!(got >= brute - 2e-6, "x {x}, z {z}: {got} vs {brute}");
            }
        }
    }
}

/// Regression: a tip coil ending where a marker band starts (the stent retriever's coil to
/// 5 mm and its band from 5 mm) cut the wire twice at the same place; the zero-length piece
/// between the cuts had no axis, an infinite chord, and drew a square over its box.
#[test]
fn adjoining_bands_leave_no_zero_length_piece() {
    let points: Vec<Point3<f64>> = (0..=10)
        .map(|i| Point3::new(0.0, 0.0, 0.002 * f64::from(i)))
        .collect();
    let look = DeviceAppearance {
        bands: vec![
            DeviceBand {
                from_tip_m: 0.0,
                length_m: 0.005,
                material: LayerMaterial::Platinum,
                fill: 0.6,
            },
            DeviceBand {
                from_tip_m: 0.005,
                length_m: 0.0008,
                material: LayerMaterial::Platinum,
                fill: 1.0,
            },
        ],
        ..DeviceAppearance::guidewire_035()
    };
    let mut layers = Layers::new();
    layers.add_device(&points, &look).unwrap();
    for piece in layers.pieces() {
        assert!((piece.end - piece.start).norm() > 1e-9, "{piece:?}");
    }
    // Beside the wire nothing; through it, the wire's diameter in one channel.
    let r = look.outer_radius_m;
    for iz in 0..=80 {
        let z = 0.00025 * f64::from(iz) + 0.0001; // off the joints (shared cap planes)
        let beside = layers.paths_along(&Point3::new(0.01, 0.0, z), &Vector3::new(0.0, 1.0, 0.0));
        assert_eq!(beside, [0.0; 3], "z {z}");
        let through = layers.paths_along(&Point3::new(0.0, -0.01, z), &Vector3::new(0.0, 1.0, 0.0));
        let total: f64 = through.iter().sum();
        assert!(
            total.is_finite() && total <= 2.0 * r + 1e-12,
            "z {z}: {through:?}"
        );
    }
}

#[test]
fn a_straight_contrast_chain_is_one_cylinder_weighted_by_concentration() {
    let r = 2e-3;
    let tubes: Vec<ContrastTube> = (0..5)
        .map(|i| ContrastTube {
            start: Point3::new(0.0, 0.0, 0.004 * i as f64),
            end: Point3::new(0.0, 0.0, 0.004 * (i + 1) as f64),
            start_radius_m: r,
            end_radius_m: r,
            concentration_mg_per_ml: 150.0,
        })
        .collect();
    let mut layers = Layers::new();
    layers.add_contrast(&tubes, 1.0).unwrap();
    // An oblique ray crossing the joint between the 2nd and 3rd tubes.
    let tilt = 30f64.to_radians();
    let direction = Vector3::new(tilt.cos(), 0.0, tilt.sin());
    for b in [0.0, 0.5e-3, 1.5e-3] {
        let origin = Point3::new(0.0, b, 0.008) - direction * 0.5;
        let got = layers.paths_along(&origin, &direction)[0];
        let exact = 0.5 * 2.0 * (r * r - b * b).sqrt() / tilt.cos();
        assert!((got - exact).abs() < 1e-12, "b {b}: {got} vs {exact}");
    }
    // Below the threshold nothing is drawn.
    let mut faint = Layers::new();
    faint.add_contrast(&tubes, 200.0).unwrap();
    assert!(faint.pieces().is_empty());
}

#[test]
fn tip_coils_and_markers_split_the_device_by_distance_from_the_tip() {
    let points: Vec<Point3<f64>> = (0..=10)
        .map(|i| Point3::new(0.0, 0.0, 0.01 * i as f64))
        .collect();
    let mut look = DeviceAppearance::guidewire_035();
    look.bands.push(DeviceBand {
        from_tip_m: 0.05,
        length_m: 0.002,
        material: LayerMaterial::Platinum,
        fill: 1.0,
    });
    let mut layers = Layers::new();
    layers.add_device(&points, &look).unwrap();
    let r = look.outer_radius_m;
    let platinum = |z: f64| {
        let origin = Point3::new(-0.5, 0.0, z);
        layers.paths_along(&origin, &Vector3::x())
    };
    // Inside the 30 mm coil (0.07–0.1 m): platinum at fill 0.6; at the marker: fill 1.
    let coil = platinum(0.085);
    assert!(
        (coil[2] - 0.6 * 2.0 * r).abs() < 1e-12 && coil[1] == 0.0,
        "{coil:?}"
    );
    let marker = platinum(0.049);
    assert!((marker[2] - 2.0 * r).abs() < 1e-12, "{marker:?}");
    let shaft = platinum(0.025);
    assert!(
        (shaft[1] - 2.0 * r).abs() < 1e-12 && shaft[2] == 0.0,
        "{shaft:?}"
    );
}

#[test]
fn tile_binning_loses_no_piece_coverage() {
    let mut carm = CArm {
        primary_deg: 25.0,
        secondary_deg: -10.0,
        ..CArm::default()
    };
    carm.detector.width_px = 96;
    carm.detector.height_px = 80;
    let mut layers = Layers::new();
    let points: Vec<Point3<f64>> = (0..40)
        .map(|i| {
            let s = i as f64 * 0.004;
            Point3::new(0.06 * (s * 20.0).sin(), 0.02 * s, -0.08 + s)
        })
        .collect();
    layers
        .add_device(&points, &DeviceAppearance::catheter_5f())
        .unwrap();
    let bins = TileBins::build(&layers, &carm, 16);
    let grid = carm.ray_grid();
    let mut binned = Vec::new();
    let mut all = Vec::new();
    for v in 0..80u32 {
        for u in 0..96u32 {
            let ray = grid.ray(f64::from(u), f64::from(v));
            let every: f64 = layers
                .pieces()
                .iter()
                .map(|p| p.chord(&ray.origin, &ray.direction))
                .sum();
            let through_bins: f64 = bins
                .pieces_at(u, v)
                .iter()
                .map(|&i| layers.pieces()[i as usize].chord(&ray.origin, &ray.direction))
                .sum();
            all.push(every);
            binned.push(through_bins);
        }
    }
    assert!(
        all.iter().filter(|&&x| x > 0.0).count() > 30,
        "the catheter is in view"
    );
    assert_eq!(all, binned);
    // The renderer's images are the density-weighted sums over every piece.
    let image = CpuRenderer::default()
        .project_layers(&layers, &carm)
        .unwrap();
    for v in 0..80u32 {
        for u in 0..96u32 {
            let ray = grid.ray(f64::from(u), f64::from(v));
            let exact = layers.paths_along(&ray.origin, &ray.direction);
            let i = (v * 96 + u) as usize;
            for (c, (plane, exact)) in image.channels.iter().zip(exact).enumerate() {
                let got = f64::from(plane[i]);
                assert!((got - exact).abs() <= 1e-6 * exact + 1e-12, "{u},{v},{c}");
            }
        }
    }
}

#[test]
fn bad_layers_give_named_errors() {
    let mut layers = Layers::new();
    let points = [Point3::new(0.0, 0.0, 0.0), Point3::new(0.0, 0.0, f64::NAN)];
    let err = layers
        .add_device(&points, &DeviceAppearance::guidewire_035())
        .unwrap_err();
    assert!(matches!(err, XrayError::NotFinite { .. }), "{err}");
    assert!(err.to_string().contains("device node 1"), "{err}");
    let mut look = DeviceAppearance::catheter_5f();
    look.inner_radius_m = look.outer_radius_m;
    let err = layers.add_device(&points[..1], &look).unwrap_err();
    assert!(err.to_string().contains("inner radius"), "{err}");
    let tube = ContrastTube {
        start: Point3::origin(),
        end: Point3::new(0.0, 0.0, 0.01),
        start_radius_m: -1e-3,
        end_radius_m: 1e-3,
        concentration_mg_per_ml: 100.0,
    };
    let err = layers.add_contrast(&[tube], 1.0).unwrap_err();
    assert!(
        err.to_string().contains("contrast tube 0 start radius"),
        "{err}"
    );
}
