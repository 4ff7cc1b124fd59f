//! The thrombectomy models against analytic references: the stent's ring law and its
//! unsheathed chain (closed-form balances, the exact discrete transition), the neo-Hookean
//! ingestion pressure against its strain energy, and the retrieval and aspiration force
//! balances on both sides of their thresholds.

use cathlab_thrombectomy::*;
use std::f64::consts::PI;

fn stent() -> StentRetriever {
    StentRetriever::solitaire_class_4x20()
}

#[test]
fn the_ring_law_is_laplace_on_the_hoop_tension() {
    let s = stent();
    let r0 = s.nominal_radius_m();
    // The calibration point: the COF at the reference diameter.
    let at_ref = s.outward_force_n_per_m(s.reference_diameter_m / 2.0);
    assert!((at_ref - s.cof_n_per_m).abs() < 1e-12 * s.cof_n_per_m);
    for r in [0.3e-3, 1.0e-3, 1.5e-3, 1.9e-3] {
        // Hoop tension T = K (r0 − r)/r0; radial pressure T/r over the circumference 2πr.
        let tension = s.hoop_stiffness_n_per_m() * (r0 - r) / r0;
        let laplace = tension / r * 2.0 * PI * r;
        assert!((s.outward_force_n_per_m(r) - laplace).abs() < 1e-9 * laplace);
        assert!((s.resistive_force_n_per_m(r) - s.rrf_ratio * laplace).abs() < 1e-9 * laplace);
    }
    assert_eq!(s.outward_force_n_per_m(r0), 0.0);
    assert_eq!(s.outward_force_n_per_m(1.2 * r0), 0.0);
}

/// A long stent far from the mouth balances the wall as the two linear laws cross:
/// k (r₀ − r) = k_v (r − R).
#[test]
fn a_stent_in_an_elastic_tube_expands_to_where_the_laws_cross() {
    let s = stent();
    for (radius, wall) in [
        (1.5e-3, 1e5),
        (1.5e-3, cerebral_wall_stiffness(1.5e-3)),
        (1.2e-3, 3e4),
    ] {
        let around = Surroundings {
            vessel_radius_m: radius,
            wall_stiffness: wall,
            clot: None,
        };
        let k = s.radial_stiffness();
        let exact = (k * s.nominal_radius_m() + wall * radius) / (k + wall);
        assert!((around.balance_radius_m(&s) - exact).abs() < 1e-12);
        // The chain, far from the mouth (20 transition lengths), agrees.
        let d = Deployment::solve(&s, s.length_m, 0.25e-3, 0.1e-3, |_| around).unwrap();
        let far = *d.radii_m.last().unwrap();
        assert!((far - exact).abs() < 1e-9, "{far} vs {exact}");
        let pressed = d.force_n_per_m.last().unwrap();
        assert!((pressed - wall * (exact - radius)).abs() < 1e-6 * pressed);
    }
}

/// In free space the linear chain u_{i−1} − (2 + k h²/β) u_i + u_{i+1} = 0 (u = r − r₀) has
/// the exact solution A λⁱ + B λ⁻ⁱ, λ + 1/λ = 2 + k h²/β, with u₀ fixed at the mouth and a
/// free end: the solver must reproduce it to rounding, and its decay length must approach
/// the continuum ℓ = √(β/k) as h → 0.
#[test]
fn the_unsheathed_transition_matches_the_exact_discrete_chain() {
    let s = stent();
    let mouth = 0.27e-3;
    let free = Surroundings {
        vessel_radius_m: 1.0,
        wall_stiffness: 0.0,
        clot: None,
    };
    for h in [0.5e-3, 0.25e-3, 0.1e-3] {
        let unsheathed = 6e-3;
        let d = Deployment::solve(&s, unsheathed, mouth, h, |_| free).unwrap();
        let n = d.radii_m.len() - 1;
        let c = 2.0 + s.radial_stiffness() * h * h / s.link_stiffness_n();
        let lambda = (c - (c * c - 4.0f64).sqrt()) / 2.0;
        // Free end: β(u_{n−1} − u_n) − k h² u_n = 0 ⇔ u_{n−1} = (c − 1) u_n.
        let u0 = mouth - s.nominal_radius_m();
        // u_i = A λ^i + B λ^{-i}; A + B = u0; A λ^{n−1} + B λ^{1−n} = (c−1)(A λ^n + B λ^{−n}).
        let p = lambda.powi(n as i32 - 1) - (c - 1.0) * lambda.powi(n as i32);
        let q = lambda.powi(1 - n as i32) - (c - 1.0) * lambda.powi(-(n as i32));
        let a = u0 * q / (q - p);
        let b = u0 - a;
        for (i, r) in d.radii_m.iter().enumerate() {
            let exact =
                s.nominal_radius_m() + a * lambda.powi(i as i32) + b * lambda.powi(-(i as i32));
            assert!((r - exact).abs() < 1e-12, "h {h} ring {i}: {r} vs {exact}");
        }
        // Decay length per ring −h / ln λ → ℓ.
        let length = -h / lambda.ln();
        let rel = (length - s.transition_m).abs() / s.transition_m;
        assert!(rel < 0.02 + h / s.transition_m * 0.1, "h {h}: ℓ {length}");
    }
}

/// Inside a clot layer the stent balances k (r₀ − r) = 2πE r (r − r_c)/(R − r_c): a quadratic.
#[test]
fn a_stent_opens_into_a_clot_as_the_quadratic_balance_says() {
    let s = stent();
    let (radius, channel) = (1.5e-3, 0.27e-3);
    let k = s.radial_stiffness();
    let mut previous_depth = 0.0;
    for fraction in [0.0, 0.3, 0.6, 0.9] {
        let modulus = ClotMechanics::of(ClotComposition {
            red_cell_fraction: fraction,
        })
        .modulus_pa;
        let around = Surroundings {
            vessel_radius_m: radius,
            wall_stiffness: cerebral_wall_stiffness(radius),
            clot: Some((modulus, channel)),
        };
        let a = 2.0 * PI * modulus / (radius - channel);
        let b = k - 2.0 * PI * modulus * channel / (radius - channel);
        let c = -k * s.nominal_radius_m();
        let exact = (-b + (b * b - 4.0 * a * c).sqrt()) / (2.0 * a);
        assert!(exact < radius, "the clot keeps the stent off the wall");
        let d = Deployment::solve(&s, s.length_m, channel, 0.1e-3, |_| around).unwrap();
        let far = *d.radii_m.last().unwrap();
        assert!((far - exact).abs() < 1e-9, "{fraction}: {far} vs {exact}");
        // Softer (redder) clots let it open deeper.
        let depth = (exact - channel) / (radius - channel);
        assert!(depth > previous_depth);
        previous_depth = depth;
    }
}

/// E ln(D/d) against the energy W(ε) = E ε²/2 of the logarithmic strain ε = ln(D/d):
/// p = dW/dε (central differences).
#[test]
fn the_ingestion_pressure_is_the_drained_hencky_squeeze() {
    let m = ClotMechanics::of(ClotComposition {
        red_cell_fraction: 0.5,
    });
    let energy = |strain: f64| m.modulus_pa * strain * strain / 2.0;
    for stretch in [0.5, 0.6, 0.75, 0.9, 0.99] {
        let strain = -f64::ln(stretch);
        let h = 1e-7;
        let reference = (energy(strain + h) - energy(strain - h)) / (2.0 * h);
        let p = m.ingestion_pressure_pa(3e-3, 3e-3 * stretch);
        assert!(
            (p - reference).abs() < 1e-6 * reference,
            "{stretch}: {p} vs {reference}"
        );
    }
    assert_eq!(m.ingestion_pressure_pa(3e-3, 3.1e-3), 0.0);
    // Stiffer clots need more; wider bores less.
    let white = ClotMechanics::of(ClotComposition {
        red_cell_fraction: 0.0,
    });
    assert!(white.ingestion_pressure_pa(3e-3, 1.8e-3) > m.ingestion_pressure_pa(3e-3, 1.8e-3));
    assert!(m.ingestion_pressure_pa(3e-3, 2.2e-3) < m.ingestion_pressure_pa(3e-3, 1.8e-3));
    // Crossing: the cavity limit pressure 5E/6 over the tip.
    let f = white.crossing_force_n(0.6e-3);
    assert!((f - 5.0 / 6.0 * 200e3 * PI * 0.09e-6).abs() < 1e-12);
}

fn red_clot() -> Clot {
    Clot::new(
        ClotComposition {
            red_cell_fraction: 0.8,
        },
        10e-3,
        1.5e-3,
        0.1,
    )
}

fn setup(clot: Clot) -> StentSetup {
    StentSetup {
        stent: stent(),
        clot,
        distal_offset_m: 5e-3,
        channel_radius_m: 0.27e-3,
        receiving_bore_m: 4e-3, // wider than the clot: nothing to squeeze at the tip
        suction_pa: 0.0,
        pressure_drop_pa: 8e3,
    }
}

fn pull(pass: &mut StentPass, path: &RetrievalPath, speed: f64) -> PassOutcome {
    loop {
        if let Some(o) = pass.advance(0.1e-3, speed, path, path.length_m()) {
            return o;
        }
    }
}

/// A straight vessel: the clot comes out iff the grip beats the drag
/// μ(v)(p_w 2πRL + F_r) + Δp πR², computed here from the formula, on both sides.
#[test]
fn retrieval_succeeds_exactly_when_the_grip_beats_the_drag() {
    let path = RetrievalPath::straight(30e-3, 1.5e-3);
    let speed = 2e-3;
    let base = red_clot();
    let grip = Engagement::of(&setup(base)).unwrap();
    assert!(grip.overlap_m == (0.0, 10e-3), "{:?}", grip.overlap_m);
    assert!(grip.embedding > 0.3 && grip.embedding < 1.0);
    // Find the wall friction at which drag equals grip, then step 2 % either side.
    let drag_for = |mu: f64| {
        let mut c = base;
        c.mechanics.wall_friction = mu;
        let mu_v = c.mechanics.wall_friction_at(speed);
        let wedge = c.mechanics.modulus_pa * 0.1;
        mu_v * (wedge * 2.0 * PI * 1.5e-3 * 10e-3 + grip.radial_n) + 8e3 * PI * 1.5e-3 * 1.5e-3
    };
    let (mut lo, mut hi) = (0.0, 5.0);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if drag_for(mid) < grip.grip_n {
            lo = mid
        } else {
            hi = mid
        }
    }
    for (factor, expect) in [(0.98, true), (1.02, false)] {
        let mut c = base;
        c.mechanics.wall_friction = lo * factor;
        let mut pass = StentPass::new(setup(c)).unwrap();
        let outcome = pull(&mut pass, &path, speed);
        assert_eq!(
            outcome.retrieved(),
            expect,
            "friction × {factor}: {outcome:?}"
        );
        assert!(outcome.emboli_m().is_empty());
    }
    // Faster pulls raise the friction: the clot held at 2 mm/s slips at 30 mm/s.
    let mut c = base;
    c.mechanics.wall_friction = lo * 0.9;
    assert!(pull(&mut StentPass::new(setup(c)).unwrap(), &path, speed).retrieved());
    assert!(!pull(&mut StentPass::new(setup(c)).unwrap(), &path, 30e-3).retrieved());
}

/// Around a bend the drag grows by exp(μΘ): the clot held on a straight path is lost past
/// Θ* = ln(grip / drag₀)/μ, and kept short of it.
#[test]
fn the_capstan_factor_of_the_bends_sets_where_the_clot_is_lost() {
    let speed = 2e-3;
    let clot = red_clot();
    let grip = Engagement::of(&setup(clot)).unwrap();
    let mu = clot.mechanics.wall_friction_at(speed);
    let wedge = clot.mechanics.modulus_pa * 0.1;
    let straight =
        mu * (wedge * 2.0 * PI * 1.5e-3 * 10e-3 + grip.radial_n) + 8e3 * PI * 1.5e-3 * 1.5e-3;
    assert!(straight < grip.grip_n);
    let critical = (grip.grip_n / straight).ln() / mu;
    // An arc of radius 10 mm turning Θ over its length, radius constant.
    let arc = |theta: f64| {
        let n = 400;
        let points: Vec<_> = (0..=n)
            .map(|i| {
                let t = theta * i as f64 / n as f64;
                nalgebra::Point3::new(10e-3 * t.sin(), 10e-3 * (1.0 - t.cos()), 0.0)
            })
            .collect();
        RetrievalPath::from_centerline(&points, &vec![1.5e-3; n + 1]).unwrap()
    };
    for (factor, expect) in [(0.95, true), (1.05, false)] {
        // The polyline of n chords turns (n − 1)/n of the arc's angle.
        let path = arc(critical * factor * 400.0 / 399.0);
        assert!((path.turning_rad() - critical * factor).abs() < 1e-9);
        let outcome = pull(&mut StentPass::new(setup(clot)).unwrap(), &path, speed);
        assert_eq!(outcome.retrieved(), expect, "Θ = {factor} Θ*: {outcome:?}");
    }
}

/// A tail beyond the stent's distal end breaks off when its drag exceeds the clot's strength
/// over its section; short of that it comes along.
#[test]
fn a_distal_tail_breaks_off_when_its_drag_beats_the_clot_strength() {
    let speed = 2e-3;
    let path = RetrievalPath::straight(30e-3, 1.5e-3);
    let clot = red_clot();
    let tail = 4e-3;
    let load = drag_n(&clot, tail, 1.5e-3, 0.0, 0.0, speed, 8e3);
    for (factor, breaks) in [(1.05, false), (0.95, true)] {
        let mut c = clot;
        c.mechanics.strength_pa = load / c.area_m2() * factor;
        let mut s = setup(c);
        s.distal_offset_m = -tail;
        let outcome = pull(&mut StentPass::new(s).unwrap(), &path, speed);
        if breaks {
            assert_eq!(outcome.emboli_m(), &[tail]);
        } else {
            assert!(outcome.emboli_m().is_empty(), "{outcome:?}");
        }
    }
}

/// At the receiving catheter the clot is squeezed into the bore: with the grip and suction
/// short of entry + drag, what the struts do not hold is stripped off as an embolus; with
/// suction past it, the clot comes in whole.
#[test]
fn a_clot_too_big_for_the_bore_is_stripped_at_the_tip_unless_suction_helps() {
    let path = RetrievalPath::straight(20e-3, 1.5e-3);
    let mut clot = red_clot();
    clot.composition.red_cell_fraction = 0.0;
    clot.mechanics = ClotMechanics::of(clot.composition);
    clot.mechanics.wall_friction = 0.02;
    let bore = 1.473e-3;
    let mut s = setup(clot);
    s.receiving_bore_m = bore;
    let pass = StentPass::new(s).unwrap();
    let e = *pass.engagement();
    let area = PI * bore * bore / 4.0;
    let entry = clot
        .mechanics
        .ingestion_pressure_pa(clot.free_diameter_m(), bore)
        * area;
    let drag = drag_n(&clot, clot.length_m, 1.5e-3, 0.0, e.radial_n, 2e-3, 8e3);
    let short = entry + drag - e.grip_n;
    assert!(short > 0.0, "the stent alone cannot pull it in");
    let stripped = pull(&mut pass.clone(), &path, 2e-3);
    assert!(stripped.retrieved());
    assert_eq!(stripped.emboli_m().len(), 1, "{stripped:?}");
    assert!((stripped.emboli_m()[0] - clot.length_m * (1.0 - e.embedding)).abs() < 1e-15);
    for (factor, clean) in [(1.02, true), (0.98, false)] {
        s.suction_pa = short / area * factor;
        let o = pull(&mut StentPass::new(s).unwrap(), &path, 2e-3);
        assert!(o.retrieved());
        assert_eq!(o.emboli_m().is_empty(), clean, "suction × {factor}: {o:?}");
    }
}

/// Aspiration ingests when the sealed suction reaches the ingestion pressure, on both sides.
#[test]
fn aspiration_ingests_on_one_side_of_the_threshold_and_corks_on_the_other() {
    let clot = red_clot();
    for bore in [1.473e-3, 1.803e-3, 2.235e-3] {
        let needed = clot
            .mechanics
            .ingestion_pressure_pa(clot.free_diameter_m(), bore);
        for (factor, ingested) in [(1.01, true), (0.99, false)] {
            let pass = AspirationPass::new(AspirationSetup {
                clot,
                bore_m: bore,
                suction_pa: needed * factor,
                apposition: 1.0,
                pressure_drop_pa: 8e3,
            })
            .unwrap();
            assert_eq!(pass.ingested(), ingested, "bore {bore}, × {factor}");
        }
    }
    // Corked: it comes out while the hold beats the drag, and is lost where it does not. A
    // fibrin-rich clot that slides easily: too stiff to ingest at the suction that holds it.
    let path = RetrievalPath::straight(30e-3, 1.5e-3);
    let mut white = Clot::new(
        ClotComposition {
            red_cell_fraction: 0.0,
        },
        10e-3,
        1.5e-3,
        0.1,
    );
    white.mechanics.wall_friction = 0.02;
    let bore = 1.803e-3;
    let drag = drag_n(&white, white.length_m, 1.5e-3, 0.0, 0.0, 2e-3, 8e3);
    let area = PI * bore * bore / 4.0;
    for (factor, out) in [(1.02, true), (0.98, false)] {
        let suction = drag / area * factor;
        assert!(
            suction
                < white
                    .mechanics
                    .ingestion_pressure_pa(white.free_diameter_m(), bore)
        );
        let mut p = AspirationPass::new(AspirationSetup {
            clot: white,
            bore_m: bore,
            suction_pa: suction,
            apposition: 1.0,
            pressure_drop_pa: 8e3,
        })
        .unwrap();
        assert!(!p.ingested());
        let outcome = loop {
            if let Some(o) = p.advance(0.1e-3, 2e-3, &path, 30e-3) {
                break o;
            }
        };
        assert_eq!(outcome.retrieved(), out, "hold × {factor}: {outcome:?}");
    }
}

#[test]
fn bad_parameters_are_named() {
    let mut s = setup(red_clot());
    s.clot.length_m = -1.0;
    let e = StentPass::new(s).unwrap_err().to_string();
    assert!(e.contains("clot length"), "{e}");
    let mut s = setup(red_clot());
    s.stent.reference_diameter_m = 5e-3;
    assert!(
        StentPass::new(s)
            .unwrap_err()
            .to_string()
            .contains("reference diameter")
    );
    let e = AspirationPass::new(AspirationSetup {
        clot: red_clot(),
        bore_m: 1.8e-3,
        suction_pa: 9e4,
        apposition: 1.5,
        pressure_drop_pa: 0.0,
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("apposition"), "{e}");
    assert!(RetrievalPath::from_centerline(&[nalgebra::Point3::origin()], &[1.0]).is_err());
}
