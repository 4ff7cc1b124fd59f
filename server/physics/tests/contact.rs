//! Contact response: the O(M + N) Gauss–Seidel against the explicit-Delassus projected
//! Gauss–Seidel on random problems (with and without friction), the Signorini and Coulomb
//! conditions checked on the result, the analytic stick/slip threshold of a pressed wire, and
//! the coupled (several-chain) solver against its explicit Delassus matrix.

use cathlab_physics::contact::newton::residual;
use cathlab_physics::contact::{
    Contact, ContactMethod, ContactSettings, POLISH_EVERY, delassus_problem, dense_reference,
    gauss_seidel, newton_solve, solve_local,
};
use cathlab_physics::coupled::{ChainPoint, CoupledContact, coupled_gauss_seidel};
use cathlab_physics::{
    BeamModel, BeamProperties, CircularSection, Material, SolverSettings, Substructure,
};
use nalgebra::{Vector3, Vector6};
use proptest::prelude::*;

fn wire(elements: usize) -> BeamModel {
    let section = CircularSection::solid(0.2e-3);
    let material = Material {
        young_modulus_pa: 60e9,
        poisson_ratio: 0.33,
        density_kg_m3: 6450.0,
    };
    BeamModel::straight(
        BeamProperties::new(&section, &material),
        0.1,
        elements,
        SolverSettings::default(),
    )
    .unwrap()
}

fn tight() -> ContactSettings {
    ContactSettings {
        tolerance: 1e-13,
        absolute_tolerance_n: 0.0,
        max_iterations: 2_000_000,
        relaxation: 1.0,
        ..Default::default()
    }
}

/// Sweeps allowed to either solver in the property test. Ill-conditioned frictionless cases
/// (several contacts on one element) have needed up to 36,200 sweeps to reach 1e-13.
const SWEEP_BUDGET: usize = 200_000;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(40))]

    /// Random contact problems as a device in a vessel meets them: points anywhere along the
    /// device (several may share an element or a node), normals across the device axis from
    /// one side of the vessel (within ±60° of a random direction), gaps from 0.1 mm clear to
    /// 0.05 mm penetrating, a random push as the free motion.
    #[test]
    fn gauss_seidel_equals_the_explicit_delassus_solve(
        elements in 4usize..30,
        raw in proptest::collection::vec((0.0f64..1.0, 0.0f64..1.0, -1.0f64..1.0, -0.5e-4f64..1e-4, 0.0f64..0.5), 1..16),
        side in 0.0f64..std::f64::consts::TAU,
        with_friction in proptest::bool::ANY,
        push in proptest::array::uniform3(-1.0f64..1.0),
    ) {
        let (k, flexibility, free, contacts) = random_problem(elements, &raw, side, with_friction, push);
        let settings = ContactSettings { max_iterations: SWEEP_BUDGET, ..tight() };
        let fast = gauss_seidel(&flexibility, &free, &contacts, &settings, None).unwrap();
        let dense = dense_reference(&k.to_dense(), &free, &contacts, &settings).unwrap();
        if with_friction && !dense.converged {
            // Projected Gauss–Seidel on the Coulomb law is not a contraction: on some frictional
            // problems it cycles with no fixed point to find (seen in CI on 8 contacts: still
            // cycling after 2,000,000 sweeps). The O(N) solver must then say so and still
            // deliver exact non-penetration (its frozen-friction phase).
            prop_assert!(!fast.converged, "the fast solver claims a fixed point the dense one never reaches");
            let (w, delta_free) = delassus(&k.to_dense(), &free, &contacts);
            let lambda = nalgebra::DVector::from_iterator(3 * contacts.len(), fast.local.iter().flat_map(|l| l.iter().copied()));
            let after = &delta_free + &w * &lambda;
            let scale = fast.local.iter().map(|l| l.x).fold(1e-12, f64::max);
            // Gaps to 1e-9 of the problem's displacement scale (a frozen phase stopped by its
            // force tolerance leaves sub-picometre residuals).
            let reach = contacts
                .iter()
                .enumerate()
                .map(|(i, c)| c.gap.abs() + delta_free[3 * i].abs())
                .fold(0.0, f64::max);
            for (i, (c, l)) in contacts.iter().zip(&fast.local).enumerate() {
                let gap = c.gap + after[3 * i];
                prop_assert!(l.x >= 0.0 && l.y.hypot(l.z) <= c.friction * l.x * (1.0 + 1e-9) + 1e-15);
                prop_assert!(gap >= -1e-9 * reach, "contact {i} penetrates by {gap} m (scale {reach} m)");
                prop_assert!(l.x <= 1e-9 * scale || gap.abs() <= 1e-9 * reach, "contact {i} pushes ({} N) across a gap of {gap} m", l.x);
            }
            return Ok(());
        }
        // Otherwise both ran the same iteration: to the same fixed point, or (a frictionless
        // case too ill-conditioned for the budget) for the same number of sweeps.
        prop_assert_eq!(fast.converged, dense.converged, "iterations {} / {}", fast.iterations, dense.iterations);
        let scale = dense.local.iter().map(|l| l.norm()).fold(1e-12, f64::max);
        let mut worst: f64 = 0.0;
        for (a, b) in fast.local.iter().zip(&dense.local) {
            worst = worst.max((a - b).norm() / scale);
        }
        prop_assert!(worst <= 1e-6, "relative force difference {worst}");
        // Without friction the solution is unique: check it against every active set.
        if !with_friction && dense.converged && contacts.len() <= 10 {
            let exact = enumerate_frictionless(&k.to_dense(), &free, &contacts);
            for (a, b) in fast.local.iter().zip(&exact) {
                prop_assert!((a.x - b).abs() <= 1e-6 * scale, "{} vs exact {b}", a.x);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(60))]

    /// The Delassus matrix assembled from the flexibility blocks equals `H K⁻¹ Hᵀ` from a dense
    /// inverse, and the semismooth Newton solve on it reaches the explicit-Delassus
    /// Gauss–Seidel's solution (to 1e-6 of the largest force) wherever that converged, on the
    /// same random problems as above; where friction leaves more than one solution, both
    /// satisfy the contact law to 1e-6 of the largest force.
    #[test]
    fn newton_equals_the_explicit_delassus_solve(
        elements in 4usize..30,
        raw in proptest::collection::vec((0.0f64..1.0, 0.0f64..1.0, -1.0f64..1.0, -0.5e-4f64..1e-4, 0.0f64..0.5), 1..16),
        side in 0.0f64..std::f64::consts::TAU,
        with_friction in proptest::bool::ANY,
        push in proptest::array::uniform3(-1.0f64..1.0),
    ) {
        let (k, flexibility, free, contacts) = random_problem(elements, &raw, side, with_friction, push);
        let (w, delta_free) = delassus(&k.to_dense(), &free, &contacts);
        let problem = delassus_problem(&flexibility, &free, &contacts).unwrap();
        let w_scale = w.amax();
        prop_assert!((&problem.w - &w).amax() <= 1e-9 * w_scale, "W differs by {}", (&problem.w - &w).amax());
        for (i, c) in contacts.iter().enumerate() {
            let q = delta_free[3 * i] + c.gap;
            prop_assert!((problem.q[3 * i] - q).abs() <= 1e-12 + 1e-9 * q.abs());
        }
        let settings = ContactSettings { method: ContactMethod::Newton, newton_iterations: 50, max_iterations: SWEEP_BUDGET, ..tight() };
        let dense = dense_reference(&k.to_dense(), &free, &contacts, &settings).unwrap();
        prop_assume!(dense.converged);
        let newton = newton_solve(&flexibility, &free, &contacts, &ContactSettings { tolerance: 1e-10, ..settings }, None).unwrap();
        // Newton converges on its own, or (an ill-conditioned case: two contacts a hundredth
        // of an element apart) hands over to Gauss–Seidel, which then must converge too.
        prop_assert!(newton.converged, "{} iterations", newton.iterations);
        // Where contacts are redundant (three on one element carry nine force components
        // against six degrees of freedom), W is singular and the forces are not unique: the
        // contact points' displacements are. Compare those, and the forces where W is regular.
        let lambda = |l: &[Vector3<f64>]| nalgebra::DVector::from_iterator(3 * l.len(), l.iter().flat_map(|v| v.iter().copied()));
        let (a, b) = (lambda(&newton.local), lambda(&dense.local));
        let reach = delta_free.amax().max(contacts.iter().map(|c| c.gap.abs()).fold(0.0, f64::max));
        let moved = (&w * (&a - &b)).amax();
        let force_scale = a.amax().max(b.amax()).max(1e-12);
        if moved > 1e-6 * reach {
            // Coulomb friction on coupled contacts need not have one solution (two contacts
            // on one element, one sliding, the other sticking or not: the regression file's
            // case). Then both must be solutions, each to its own residual; without friction
            // the solution is unique.
            let (newton_residual, dense_residual) = (residual(&problem, &newton.local), residual(&problem, &dense.local));
            prop_assert!(
                with_friction && newton_residual <= 1e-6 * force_scale && dense_residual <= 1e-6 * force_scale,
                "contact displacements differ by {moved} m (scale {reach} m); residuals {newton_residual:e} and {dense_residual:e} N (scale {force_scale:e} N)"
            );
            return Ok(());
        }
        // The forces follow from the displacements to W's condition number: compared where
        // that is at most 1e6 (at 1e9 a case's forces differed by 2e-6 of the largest with
        // both solves converged).
        let regular = w.clone().symmetric_eigenvalues().min() > 1e-6 * w_scale;
        if regular {
            let scale = b.amax().max(1e-12);
            prop_assert!((&a - &b).amax() <= 1e-6 * scale, "forces differ by {} (scale {scale})", (&a - &b).amax());
        }
    }
}

/// The random problem of the property tests: a wire of `elements` elements, contacts from
/// `raw` (position along the wire, parameter, normal spread, gap, friction), normals within
/// ±60° of `side` across the wire (along x), and as free motion the response to a tip load
/// `push` (so it is a real displacement).
#[allow(clippy::type_complexity)]
fn random_problem(
    elements: usize,
    raw: &[(f64, f64, f64, f64, f64)],
    side: f64,
    with_friction: bool,
    push: [f64; 3],
) -> (
    cathlab_physics::BlockTridiagonal,
    cathlab_physics::Flexibility,
    Vec<Vector6<f64>>,
    Vec<Contact>,
) {
    let mut model = wire(elements);
    let k = model.tangent_stiffness().clone();
    let flexibility = Substructure::new(&k).unwrap().flexibility();
    let mut load = vec![Vector6::zeros(); elements];
    load[elements - 1] = Vector6::new(
        push[0] * 0.05,
        push[1] * 0.002,
        push[2] * 0.002,
        0.0,
        0.0,
        0.0,
    );
    let free = Substructure::new(&k).unwrap().solve(&load);
    let contacts = raw
        .iter()
        .map(|&(e, t, spread, gap, mu)| {
            let angle = side + spread * std::f64::consts::FRAC_PI_3;
            Contact {
                element: ((e * elements as f64) as usize).min(elements - 1),
                t,
                normal: Vector3::new(0.0, angle.cos(), angle.sin()),
                gap,
                friction: if with_friction { mu } else { 0.0 },
                slip: Vector3::zeros(),
            }
        })
        .collect();
    (k, flexibility, free, contacts)
}

/// The explicit Delassus operator `W = H K⁻¹ Hᵀ` (3M × 3M, rows in each contact's
/// normal–tangent frame) and the free relative displacement `H u_free` (3M): the gaps after a
/// solve are `gap + (H u_free + W λ)_normal`.
fn delassus(
    k_dense: &nalgebra::DMatrix<f64>,
    free: &[Vector6<f64>],
    contacts: &[Contact],
) -> (nalgebra::DMatrix<f64>, nalgebra::DVector<f64>) {
    let k_inv = k_dense.clone().try_inverse().unwrap();
    let n = free.len();
    let mut h = nalgebra::DMatrix::<f64>::zeros(3 * contacts.len(), 6 * n);
    for (i, c) in contacts.iter().enumerate() {
        let frame_t = c.frame().transpose();
        for (node, weight) in [
            (c.element.checked_sub(1), 1.0 - c.t),
            (Some(c.element), c.t),
        ] {
            if let Some(node) = node {
                for r in 0..3 {
                    for d in 0..3 {
                        h[(3 * i + r, 6 * node + d)] += weight * frame_t[(r, d)];
                    }
                }
            }
        }
    }
    let u = nalgebra::DVector::from_iterator(6 * n, free.iter().flat_map(|v| v.iter().copied()));
    (&h * k_inv * h.transpose(), &h * u)
}

/// Exact frictionless solution by enumerating active sets: for each subset A, solve
/// W_AA λ_A = −(gap + δ_free)_A and accept the first λ ≥ 0 with every gap ≥ 0. An
/// independent brute force (no iteration at all).
fn enumerate_frictionless(
    k_dense: &nalgebra::DMatrix<f64>,
    free: &[Vector6<f64>],
    contacts: &[Contact],
) -> Vec<f64> {
    let m = contacts.len();
    let (w3, delta_free) = delassus(k_dense, free, contacts);
    // The normal rows only.
    let w = nalgebra::DMatrix::from_fn(m, m, |i, j| w3[(3 * i, 3 * j)]);
    let q = nalgebra::DVector::from_fn(m, |i, _| delta_free[3 * i] + contacts[i].gap);
    let mut best: Option<(f64, Vec<f64>)> = None;
    for mask in 0u32..(1 << m) {
        let active: Vec<usize> = (0..m).filter(|i| mask & (1 << i) != 0).collect();
        let mut lambda = vec![0.0; m];
        if !active.is_empty() {
            let waa = nalgebra::DMatrix::from_fn(active.len(), active.len(), |a, b| {
                w[(active[a], active[b])]
            });
            let rhs = nalgebra::DVector::from_iterator(active.len(), active.iter().map(|&i| -q[i]));
            let Some(solution) = waa.lu().solve(&rhs) else {
                continue;
            };
            for (a, &i) in active.iter().enumerate() {
                lambda[i] = solution[a];
            }
        }
        let gaps = &q + &w * nalgebra::DVector::from_vec(lambda.clone());
        let scale = q.amax().max(1e-12);
        // Feasibility violation of this active set (0 for the solution).
        let violation = lambda.iter().map(|l| (-l).max(0.0)).fold(0.0, f64::max)
            + gaps
                .iter()
                .map(|g| (-g / scale).max(0.0))
                .fold(0.0, f64::max);
        if best.as_ref().is_none_or(|b| violation < b.0) {
            best = Some((violation, lambda));
        }
    }
    best.unwrap().1
}

/// Regression (the iliac tail): contacts a fraction of a millimetre apart along a stiff wire
/// (the end of one element, the start of the next, with nearly the same normal) are almost
/// redundant, and plain Gauss–Seidel passes the load between them for hundreds of sweeps
/// (up to 600 per step in the segmented iliac artery). With the active-set steps every
/// [`POLISH_EVERY`] sweeps it converges within a few of them, to the exact solution.
#[test]
fn near_redundant_contacts_converge_in_a_few_active_set_steps() {
    let elements = 20;
    let mut model = wire(elements);
    let k = model.tangent_stiffness().clone();
    let flexibility = Substructure::new(&k).unwrap().flexibility();
    let mut load = vec![Vector6::zeros(); elements];
    load[elements - 1] = Vector6::new(0.0, -0.01, 0.002, 0.0, 0.0, 0.0);
    let free = Substructure::new(&k).unwrap().solve(&load);
    let normal = |degrees: f64| {
        let a = degrees.to_radians();
        Vector3::new(0.0, a.cos(), a.sin())
    };
    // Pairs around nodes 10, 14 and 18 (elements 5 mm long: 0.5 mm apart), gaps closing.
    let mut contacts = Vec::new();
    for (node, tilt) in [(10, 0.0), (14, 20.0), (18, -15.0)] {
        contacts.push(Contact {
            element: node - 1,
            t: 0.9,
            normal: normal(tilt),
            gap: 2e-6,
            friction: 0.0,
            slip: Vector3::zeros(),
        });
        contacts.push(Contact {
            element: node,
            t: 0.0,
            normal: normal(tilt + 10.0),
            gap: 1e-6,
            friction: 0.0,
            slip: Vector3::zeros(),
        });
    }
    let settings = |polish| ContactSettings {
        tolerance: 1e-9,
        absolute_tolerance_n: 0.0,
        max_iterations: 1_000_000,
        polish,
        ..Default::default()
    };
    let plain = gauss_seidel(&flexibility, &free, &contacts, &settings(false), None).unwrap();
    let stepped = gauss_seidel(&flexibility, &free, &contacts, &settings(true), None).unwrap();
    println!(
        "plain Gauss–Seidel {} sweeps, with active-set steps {} sweeps",
        plain.iterations, stepped.iterations
    );
    assert!(plain.converged && stepped.converged);
    assert!(
        stepped.iterations <= 3 * POLISH_EVERY && stepped.iterations * 10 < plain.iterations,
        "{} vs {} sweeps",
        stepped.iterations,
        plain.iterations
    );
    let exact = enumerate_frictionless(&k.to_dense(), &free, &contacts);
    let scale = exact.iter().fold(1e-12, |a: f64, b| a.max(b.abs()));
    assert!(exact.iter().filter(|&&l| l > 0.0).count() >= 2, "{exact:?}");
    for (a, b) in stepped.local.iter().zip(&exact) {
        assert!((a.x - b).abs() <= 1e-6 * scale, "{} vs exact {b}", a.x);
    }
}

#[test]
fn solution_satisfies_signorini_and_coulomb() {
    // Contacts along a wire pushed sideways into a wall at y = -0.5 mm, with friction.
    let elements = 40;
    let mut model = wire(elements);
    let k = model.tangent_stiffness().clone();
    let mut substructure = Substructure::new(&k).unwrap();
    let flexibility = substructure.flexibility();
    let mut load = vec![Vector6::zeros(); elements];
    for (i, l) in load.iter_mut().enumerate() {
        *l = Vector6::new(
            0.002,
            -0.0005 * (i as f64 / elements as f64),
            0.0003,
            0.0,
            0.0,
            0.0,
        );
    }
    let free = substructure.solve(&load);
    let contacts: Vec<Contact> = (0..elements)
        .filter(|e| e % 4 == 1)
        .map(|e| Contact {
            element: e,
            t: 0.5,
            normal: Vector3::y(),
            gap: 0.5e-3 - 1e-6 * e as f64,
            friction: 0.3,
            slip: Vector3::zeros(),
        })
        .collect();
    let response = gauss_seidel(&flexibility, &free, &contacts, &tight(), None).unwrap();
    assert!(response.converged);
    // Independent check: apply the forces, solve the beam, measure each contact point.
    let u = substructure.solve(
        &free
            .iter()
            .zip(&response.nodal_loads)
            .map(|(_, f)| *f)
            .collect::<Vec<_>>(),
    );
    let total: Vec<Vector6<f64>> = free.iter().zip(&u).map(|(a, b)| a + b).collect();
    let mut active = 0;
    for (c, (l, f)) in contacts
        .iter()
        .zip(response.local.iter().zip(&response.forces))
    {
        let node = |i: usize| {
            if i == 0 {
                Vector3::zeros()
            } else {
                total[i - 1].fixed_rows::<3>(0).into_owned()
            }
        };
        let delta = node(c.element) * (1.0 - c.t) + node(c.element + 1) * c.t;
        let gap_after = c.gap + c.normal.dot(&delta);
        assert!(gap_after >= -1e-9 * 0.5e-3, "penetration {gap_after}");
        assert!(l.x >= 0.0);
        let tangential = (delta - c.normal * c.normal.dot(&delta)).norm();
        if l.x > 0.0 {
            active += 1;
            assert!(
                gap_after.abs() < 1e-9 * 0.5e-3,
                "active contact not closed: {gap_after}"
            );
            let ft = l.y.hypot(l.z);
            assert!(ft <= 0.3 * l.x * (1.0 + 1e-9));
            if ft < 0.3 * l.x * (1.0 - 1e-6) {
                assert!(tangential < 1e-9, "sticking contact slipped {tangential}");
            } else if tangential > 1e-12 {
                // Sliding: friction opposes the slip.
                let slip = (delta - c.normal * c.normal.dot(&delta)) / tangential;
                let friction = f - c.normal * c.normal.dot(f);
                assert!(friction.normalize().dot(&slip) < -0.999);
            }
        }
    }
    println!(
        "{active} of {} contacts active after {} sweeps",
        contacts.len(),
        response.iterations
    );
    assert!(active >= 3);
}

#[test]
fn a_pressed_wire_slides_only_past_mu_n() {
    // Cantilever along x; its tip pressed down (−y) onto a wall with normal +y by N = 10 mN,
    // then pushed sideways (z) by T. Coulomb: it sticks for T ≤ μN and slides by
    // W_tt (T − μN) beyond.
    let elements = 20;
    let mut model = wire(elements);
    let k = model.tangent_stiffness().clone();
    let mut substructure = Substructure::new(&k).unwrap();
    let flexibility = substructure.flexibility();
    let mu = 0.2;
    let normal_force = 0.01;
    let compliance_z = flexibility.diagonal[elements - 1][(2, 2)];
    for ratio in [0.5, 0.99, 1.01, 1.5] {
        let tangential_force = ratio * mu * normal_force;
        let mut load = vec![Vector6::zeros(); elements];
        load[elements - 1] = Vector6::new(0.0, -normal_force, tangential_force, 0.0, 0.0, 0.0);
        let free = substructure.solve(&load);
        let contact = Contact {
            element: elements - 1,
            t: 1.0,
            normal: Vector3::y(),
            gap: 0.0,
            friction: mu,
            slip: Vector3::zeros(),
        };
        let response = gauss_seidel(&flexibility, &free, &[contact], &tight(), None).unwrap();
        let force = response.forces[0];
        let slip = free[elements - 1].z + compliance_z * force.z;
        println!(
            "T = {ratio:.2} μN: normal {:.6} N, friction {:.6} N, tip slip {:.3e} m",
            force.y, force.z, slip
        );
        assert!((force.y - normal_force).abs() < 1e-9 * normal_force);
        if ratio <= 1.0 {
            assert!(
                (force.z + tangential_force).abs() < 1e-9 * normal_force,
                "sticks"
            );
            assert!(slip.abs() < 1e-12, "no slip below μN");
        } else {
            assert!(
                (force.z + mu * normal_force).abs() < 1e-9 * normal_force,
                "friction at μN"
            );
            let expected = compliance_z * (tangential_force - mu * normal_force);
            assert!(
                (slip - expected).abs() < 1e-9 * expected,
                "slip {slip} vs {expected}"
            );
        }
    }
}

#[test]
fn bad_contacts_give_clear_errors() {
    let elements = 5;
    let mut model = wire(elements);
    let k = model.tangent_stiffness().clone();
    let flexibility = Substructure::new(&k).unwrap().flexibility();
    let free = vec![Vector6::zeros(); elements];
    let good = Contact {
        element: 2,
        t: 0.5,
        normal: Vector3::y(),
        gap: 0.0,
        friction: 0.1,
        slip: Vector3::zeros(),
    };
    let cases = [
        (Contact { element: 9, ..good }, "element index"),
        (Contact { t: 1.5, ..good }, "contact 0"),
        (
            Contact {
                gap: f64::NAN,
                ..good
            },
            "contact 0",
        ),
        (
            Contact {
                friction: -0.1,
                ..good
            },
            "contact 0",
        ),
        (
            Contact {
                normal: Vector3::new(0.0, 2.0, 0.0),
                ..good
            },
            "normal",
        ),
    ];
    for (contact, needle) in cases {
        let err = gauss_seidel(
            &flexibility,
            &free,
            &[contact],
            &ContactSettings::default(),
            None,
        )
        .unwrap_err();
        assert!(err.to_string().contains(needle), "{err}");
    }
    let err = gauss_seidel(
        &flexibility,
        &free[..3],
        &[good],
        &ContactSettings::default(),
        None,
    )
    .unwrap_err();
    assert!(err.to_string().contains("free displacement"), "{err}");
}

/// The coupled solver's brute-force reference: the explicit Delassus matrix of several chains
/// (block-diagonal K⁻¹, each contact acting +R on its first side and −R on its second), then
/// projected Gauss–Seidel with the same local law in the same order.
fn coupled_dense(
    k_dense: &[nalgebra::DMatrix<f64>],
    free: &[Vec<Vector6<f64>>],
    contacts: &[CoupledContact],
    settings: &ContactSettings,
) -> (
    Vec<Vector3<f64>>,
    bool,
    nalgebra::DMatrix<f64>,
    nalgebra::DVector<f64>,
) {
    let offsets: Vec<usize> = k_dense
        .iter()
        .scan(0, |at, k| {
            let here = *at;
            *at += k.nrows();
            Some(here)
        })
        .collect();
    let size: usize = k_dense.iter().map(|k| k.nrows()).sum();
    let mut k_inv = nalgebra::DMatrix::<f64>::zeros(size, size);
    for (k, &o) in k_dense.iter().zip(&offsets) {
        let inv = k.clone().try_inverse().unwrap();
        k_inv.view_mut((o, o), inv.shape()).copy_from(&inv);
    }
    let m = contacts.len();
    let mut h = nalgebra::DMatrix::<f64>::zeros(3 * m, size);
    for (i, c) in contacts.iter().enumerate() {
        let frame_t = c.frame().transpose();
        for (side, sign) in [(Some(c.first), 1.0), (c.second, -1.0)] {
            let Some(p) = side else { continue };
            for (node, weight) in [
                (p.element.checked_sub(1), 1.0 - p.t),
                (Some(p.element), p.t),
            ] {
                if let Some(node) = node {
                    for r in 0..3 {
                        for d in 0..3 {
                            h[(3 * i + r, offsets[p.chain] + 6 * node + d)] +=
                                sign * weight * frame_t[(r, d)];
                        }
                    }
                }
            }
        }
    }
    let u = nalgebra::DVector::from_iterator(
        size,
        free.iter().flatten().flat_map(|v| v.iter().copied()),
    );
    let w = &h * k_inv * h.transpose();
    let delta_free = &h * u;
    let mut lambda = nalgebra::DVector::<f64>::zeros(3 * m);
    let mut converged = false;
    for _ in 0..settings.max_iterations {
        let (mut change, mut largest): (f64, f64) = (0.0, 0.0);
        for (k, c) in contacts.iter().enumerate() {
            let wkk = w.fixed_view::<3, 3>(3 * k, 3 * k).into_owned();
            let own = Vector3::new(lambda[3 * k], lambda[3 * k + 1], lambda[3 * k + 2]);
            let total = w.rows(3 * k, 3) * &lambda;
            let b = Vector3::new(
                delta_free[3 * k] + total[0],
                delta_free[3 * k + 1] + total[1],
                delta_free[3 * k + 2] + total[2],
            ) - wkk * own;
            let updated = solve_local(&wkk, &b, c.gap, c.friction);
            change = change.max((updated - own).norm());
            largest = largest.max(updated.norm());
            for r in 0..3 {
                lambda[3 * k + r] = updated[r];
            }
        }
        if change <= settings.tolerance * largest {
            converged = true;
            break;
        }
    }
    let local = (0..m)
        .map(|k| Vector3::new(lambda[3 * k], lambda[3 * k + 1], lambda[3 * k + 2]))
        .collect();
    (local, converged, w, delta_free)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(40))]

    /// Two chains side by side (an inner wire and the tube around it, different element
    /// counts): wall contacts on either, lumen contacts joining them, in random order (so a
    /// chain's contacts come out of order along it). The coupled O(M + N) sweep must run the
    /// same iteration as the explicit-Delassus one.
    #[test]
    fn coupled_gauss_seidel_equals_the_explicit_delassus_solve(
        elements in (3usize..16, 3usize..16),
        raw in proptest::collection::vec((0.0f64..1.0, 0.0f64..1.0, -1.0f64..1.0, -0.5e-4f64..1e-4, 0.0f64..0.5, 0u8..3), 1..12),
        with_friction in proptest::bool::ANY,
        push in proptest::array::uniform3(-1.0f64..1.0),
    ) {
        let counts = [elements.0, elements.1];
        let mut k_dense = Vec::new();
        let mut flexibilities = Vec::new();
        let mut free = Vec::new();
        for (c, &n) in counts.iter().enumerate() {
            let mut model = wire(n);
            let k = model.tangent_stiffness().clone();
            flexibilities.push(Substructure::new(&k).unwrap().flexibility());
            let mut load = vec![Vector6::zeros(); n];
            let sign = if c == 0 { 1.0 } else { -0.5 };
            load[n - 1] = Vector6::new(push[0] * 0.05, push[1] * 0.002 * sign, push[2] * 0.002, 0.0, 0.0, 0.0);
            free.push(Substructure::new(&k).unwrap().solve(&load));
            k_dense.push(k.to_dense());
        }
        // No point nearer the driven base node than a quarter of the first element: the
        // detection puts none nearer than its sample spacing (`push_element_samples`). A point
        // at t ≈ 0.01 with a penetrating gap asks its node to move a hundred times the gap,
        // and with friction the sweeps then cycle with millimetres of amplitude (proptest
        // seed d9b4b785… shrank to one at t = 0.0098 whose last iterate penetrated 0.23 mm
        // with a gap of 0.024 mm; it is kept in contact.proptest-regressions).
        let point = |chain: usize, s: f64| {
            let x = 0.25 + s * (counts[chain] as f64 - 0.25);
            let element = (x as usize).min(counts[chain] - 1);
            ChainPoint { chain, element, t: (x - element as f64).clamp(0.0, 1.0) }
        };
        let contacts: Vec<CoupledContact> = raw
            .iter()
            .map(|&(s, _, spread, gap, mu, kind)| {
                let angle = spread * std::f64::consts::PI;
                let (first, second) = match kind {
                    0 => (point(0, s), None),
                    1 => (point(1, s), None),
                    _ => (point(1, s), Some(point(0, s))),
                };
                CoupledContact {
                    first,
                    second,
                    normal: Vector3::new(0.0, angle.cos(), angle.sin()),
                    gap,
                    friction: if with_friction { mu } else { 0.0 },
                    lumen: None,
                }
            })
            .collect();
        let settings = ContactSettings { max_iterations: SWEEP_BUDGET, ..tight() };
        let flex: Vec<_> = flexibilities.iter().collect();
        let slices: Vec<&[Vector6<f64>]> = free.iter().map(Vec::as_slice).collect();
        let fast = coupled_gauss_seidel(&flex, &slices, &contacts, &settings, None).unwrap();
        let (dense, dense_converged, w, delta_free) = coupled_dense(&k_dense, &free, &contacts, &settings);
        if !dense_converged {
            // No solution within the budget. Either the contacts ask for positions no
            // displacement reaches (infeasible: e.g. three contacts on the first element, which
            // moves with one node, with normals no single translation meets; the fresh-clone
            // case in contact.proptest-regressions), or a Coulomb iteration cycles. The
            // frictionless problem tells them apart: its LCP (W positive semi-definite) is
            // solvable exactly when the gaps can all be met.
            // Its sweeps stopping is not enough: a contact on a chain's driven base node has no
            // compliance (its Delassus row is zero), so no force changes and the sweeps stop
            // with that gap still open (proptest seed d9b4b785…, kept in
            // contact.proptest-regressions). Feasible means every gap met.
            let frictionless: Vec<CoupledContact> = contacts.iter().map(|c| CoupledContact { friction: 0.0, ..*c }).collect();
            let (lambda0, stopped, _, _) = coupled_dense(&k_dense, &free, &frictionless, &settings);
            let lambda0 = nalgebra::DVector::from_iterator(3 * contacts.len(), lambda0.iter().flat_map(|l| l.iter().copied()));
            let after0 = &delta_free + &w * &lambda0;
            let reach = contacts.iter().enumerate().map(|(i, c)| c.gap.abs() + delta_free[3 * i].abs()).fold(0.0, f64::max);
            let feasible = stopped && contacts.iter().enumerate().all(|(i, c)| c.gap + after0[3 * i] >= -1e-6 * reach);
            if !feasible {
                // Infeasible: the fast solver must not report a solution either.
                prop_assert!(!fast.converged);
                return Ok(());
            }
        }
        let coulomb = contacts.iter().any(|c| c.friction > 0.0);
        if coulomb && !dense_converged {
            // A cycling Coulomb iteration: the fast solver must say so and still not penetrate
            // beyond a millionth of the problem's reach. Its last iterate meets each contact
            // at that contact's own visit; the visits after it move the point by the cycle's
            // amplitude (CI found 1.4e-8 of the reach, 0.5 pm, on two nearly opposed normals
            // at one point; the case is in contact.proptest-regressions).
            prop_assert!(!fast.converged);
            let lambda = nalgebra::DVector::from_iterator(3 * contacts.len(), fast.local.iter().flat_map(|l| l.iter().copied()));
            let after = &delta_free + &w * &lambda;
            let reach = contacts.iter().enumerate().map(|(i, c)| c.gap.abs() + delta_free[3 * i].abs()).fold(0.0, f64::max);
            for (i, c) in contacts.iter().enumerate() {
                prop_assert!(c.gap + after[3 * i] >= -1e-6 * reach, "{} of {reach}", c.gap + after[3 * i]);
            }
            return Ok(());
        }
        prop_assert_eq!(fast.converged, dense_converged, "sweeps {}", fast.iterations);
        let scale = dense.iter().map(|l| l.norm()).fold(1e-12, f64::max);
        for (a, b) in fast.local.iter().zip(&dense) {
            prop_assert!((a - b).norm() <= 1e-6 * scale, "{a:?} vs {b:?}");
        }
        // The nodal loads are the contact forces put on each chain.
        for (c, loads) in fast.nodal_loads.iter().enumerate() {
            let total: Vector3<f64> = loads.iter().map(|l| Vector3::new(l[0], l[1], l[2])).sum();
            let expected: Vector3<f64> = contacts
                .iter()
                .zip(&fast.local)
                .map(|(k, l)| {
                    let f = k.frame() * l;
                    let on_first = if k.first.chain == c && k.first.element > 0 { 1.0 } else if k.first.chain == c { k.first.t } else { 0.0 };
                    let on_second = k.second.filter(|p| p.chain == c).map_or(0.0, |p| if p.element > 0 { 1.0 } else { p.t });
                    f * (on_first - on_second)
                })
                .sum();
            prop_assert!((total - expected).norm() <= 1e-9 * scale.max(expected.norm()));
        }
    }
}
