//! Semismooth Newton solve of the Signorini–Coulomb problem on its Delassus matrix: the
//! Alart–Curnier function (Alart & Curnier 1991) with its generalized Jacobian, reduced to the
//! contacts that push, damped by a line search on the squared residual.
//!
//! With `u = W λ + q` and, per contact, `σ = λ − ρ u` (ρ = 1 / W_nn, so both terms are forces),
//! the conditions are `Φ(λ) = 0` where
//! `Φ_n = λ_n − max(0, σ_n)` (Signorini) and `Φ_t = λ_t − proj(σ_t, disc of radius μ max(0, σ_n))`
//! (Coulomb: sticking, `u_t = 0`, inside the disc; sliding against the slip on its rim).
//! Φ is piecewise smooth; Newton on one of its generalized Jacobians converges quadratically
//! once the contact states (separated, sticking, sliding) are right, so a warm-started step
//! takes two or three iterations where projected Gauss–Seidel takes tens of sweeps on stiff
//! coupled contacts. A contact that separates (`σ_n ≤ 0`) has the identity row (its force
//! goes to zero), so each iteration factors only the pushing contacts' 3A × 3A system.

use nalgebra::{DMatrix, DVector, Vector2, Vector3};

use super::delassus::DelassusProblem;

/// The outcome of a Newton solve.
#[derive(Debug, Clone, PartialEq)]
pub struct NewtonOutcome {
    /// Per contact: (normal, tangent 1, tangent 2) force in its frame (N).
    pub local: Vec<Vector3<f64>>,
    /// Newton iterations performed.
    pub iterations: usize,
    /// Whether the residual met the tolerance.
    pub converged: bool,
}

/// When a Newton solve stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonTolerance {
    /// Stop when every contact's residual |Φ_k| (N) is at most this fraction of the largest
    /// force …
    pub relative: f64,
    /// … or this many newtons, whichever is larger.
    pub absolute_n: f64,
    /// Also require every gap to be violated by at most this much (m).
    pub violation_m: f64,
    /// Iteration cap.
    pub max_iterations: usize,
}

/// The most Gauss–Seidel sweeps one escape from a kink takes.
const MAX_ESCAPE_SWEEPS: usize = 8;

/// The least Levenberg–Marquardt damping (dimensionless: J's rows are scaled to about one).
const REGULARIZATION: f64 = 1e-12;

/// Per contact: ρ, or `None` for a contact that cannot move (on the driven base).
fn scaling(problem: &DelassusProblem) -> Vec<Option<f64>> {
    (0..problem.contacts())
        .map(|k| {
            let wnn = problem.w[(3 * k, 3 * k)];
            (wnn.is_finite() && wnn > 0.0).then(|| 1.0 / wnn)
        })
        .collect()
}

/// How one contact's residual depends on the forces: which branch of Φ it is on.
#[derive(Debug, Clone, Copy)]
enum State {
    /// σ_n ≤ 0 (or a fixed contact): Φ = λ.
    Separated,
    /// σ_n > 0, |σ_t| ≤ μ σ_n: Φ = ρ u.
    Sticking,
    /// σ_n > 0, |σ_t| > μ σ_n: Φ_n = ρ u_n, Φ_t = λ_t − μ σ_n ŝ with ŝ = σ_t/|σ_t|.
    Sliding { direction: Vector2<f64>, ratio: f64 },
}

/// Φ at `lambda` (3M), with each contact's state; `u` is `W λ + q`.
fn evaluate(
    problem: &DelassusProblem,
    rho: &[Option<f64>],
    lambda: &DVector<f64>,
    u: &DVector<f64>,
) -> (DVector<f64>, Vec<State>) {
    let m = problem.contacts();
    let mut phi = DVector::zeros(3 * m);
    let mut states = Vec::with_capacity(m);
    for k in 0..m {
        let l = lambda.fixed_rows::<3>(3 * k);
        let Some(rho) = rho[k] else {
            phi.fixed_rows_mut::<3>(3 * k).copy_from(&l);
            states.push(State::Separated);
            continue;
        };
        let sigma = l - u.fixed_rows::<3>(3 * k) * rho;
        if sigma.x <= 0.0 {
            phi.fixed_rows_mut::<3>(3 * k).copy_from(&l);
            states.push(State::Separated);
            continue;
        }
        let mu = problem.friction[k];
        let radius = mu * sigma.x;
        let st = Vector2::new(sigma.y, sigma.z);
        let norm = st.norm();
        phi[3 * k] = l.x - sigma.x;
        if mu > 0.0 && norm <= radius {
            phi[3 * k + 1] = l.y - sigma.y;
            phi[3 * k + 2] = l.z - sigma.z;
            states.push(State::Sticking);
        } else {
            let direction = if norm > 0.0 {
                st / norm
            } else {
                Vector2::zeros()
            };
            phi[3 * k + 1] = l.y - radius * direction.x;
            phi[3 * k + 2] = l.z - radius * direction.y;
            let ratio = if norm > 0.0 { radius / norm } else { 0.0 };
            states.push(State::Sliding { direction, ratio });
        }
    }
    (phi, states)
}

/// ½ Σ W_nn,k |Φ_k|²: the squared residual in the scaled variables of [`direction`].
fn scaled_merit(phi: &DVector<f64>, rho: &[Option<f64>]) -> f64 {
    (0..rho.len())
        .map(|k| phi.fixed_rows::<3>(3 * k).norm_squared() * rho[k].map_or(1.0, f64::recip))
        .sum::<f64>()
        * 0.5
}

/// The largest contact residual |Φ_k| (N).
fn worst(phi: &DVector<f64>) -> f64 {
    (0..phi.len() / 3)
        .map(|k| phi.fixed_rows::<3>(3 * k).norm())
        .fold(0.0, f64::max)
}

/// The Alart–Curnier residual of forces `local` (N, per contact the largest |Φ_k|): zero
/// exactly at a solution of the contact problem, whichever method found it.
pub fn residual(problem: &DelassusProblem, local: &[Vector3<f64>]) -> f64 {
    let lambda = DVector::from_iterator(
        3 * local.len(),
        local.iter().flat_map(|l| l.iter().copied()),
    );
    let u = &problem.w * &lambda + &problem.q;
    worst(&evaluate(problem, &scaling(problem), &lambda, &u).0)
}

/// Solves `problem` from `warm` (forces per contact, or zeros) by damped semismooth Newton;
/// `observer` sees the forces after every iteration.
///
/// Without a warm start, a frictional problem starts from its frictionless solution: the
/// Coulomb problem's merit has stationary points that are no solution (a contact pushed and
/// sliding where the solution separates it), and the frictionless solution is near the
/// right contact states.
pub fn solve(
    problem: &DelassusProblem,
    warm: Option<&[Vector3<f64>]>,
    tolerance: &NewtonTolerance,
    observer: &mut dyn FnMut(&[Vector3<f64>]),
) -> NewtonOutcome {
    if warm.is_none() && problem.friction.iter().any(|&mu| mu > 0.0) {
        let frictionless = DelassusProblem {
            friction: vec![0.0; problem.contacts()],
            ..problem.clone()
        };
        let start = newton(&frictionless, None, tolerance, observer);
        let mut outcome = newton(problem, Some(&start.local), tolerance, observer);
        outcome.iterations += start.iterations;
        return outcome;
    }
    newton(problem, warm, tolerance, observer)
}

/// [`solve`] from `warm`.
fn newton(
    problem: &DelassusProblem,
    warm: Option<&[Vector3<f64>]>,
    tolerance: &NewtonTolerance,
    observer: &mut dyn FnMut(&[Vector3<f64>]),
) -> NewtonOutcome {
    let m = problem.contacts();
    let rho = scaling(problem);
    let mut lambda = match warm {
        Some(w) if w.len() == m => {
            DVector::from_iterator(3 * m, w.iter().flat_map(|l| l.iter().copied()))
        }
        _ => DVector::zeros(3 * m),
    };
    let to_local = |lambda: &DVector<f64>| -> Vec<Vector3<f64>> {
        (0..m)
            .map(|k| lambda.fixed_rows::<3>(3 * k).into_owned())
            .collect()
    };
    let mut u = &problem.w * &lambda + &problem.q;
    let (mut phi, mut states) = evaluate(problem, &rho, &lambda, &u);
    let mut merit = scaled_merit(&phi, &rho);
    // The forces' natural size in the scaled variables: Σ W_nn (ρ q_n)², the pushes that
    // would close every gap alone.
    let natural: f64 = (0..m)
        .filter_map(|k| rho[k].map(|rho| rho * problem.q[3 * k] * problem.q[3 * k]))
        .sum();
    let mut adaptive: f64 = 1e-3;
    // Gauss–Seidel sweeps to take where Newton finds no descent: doubled each time.
    let mut escape = 1;
    let mut outcome = NewtonOutcome {
        local: Vec::new(),
        iterations: 0,
        converged: false,
    };
    loop {
        let force = (0..m)
            .map(|k| lambda.fixed_rows::<3>(3 * k).norm())
            .fold(0.0, f64::max);
        let violation = (0..m)
            .filter(|&k| rho[k].is_some())
            .map(|k| -u[3 * k])
            .fold(0.0, f64::max);
        if worst(&phi) <= (tolerance.relative * force).max(tolerance.absolute_n)
            && violation <= tolerance.violation_m
        {
            outcome.converged = true;
            break;
        }
        if outcome.iterations >= tolerance.max_iterations {
            break;
        }
        // The Levenberg–Marquardt damping: the residual relative to the forces' size (both
        // scaled), and smaller after a full step, larger after a cut one.
        let size: f64 = (0..m)
            .map(|k| lambda.fixed_rows::<3>(3 * k).norm_squared() * rho[k].map_or(1.0, f64::recip))
            .sum();
        let relative = (2.0 * merit / size.max(natural).max(f64::MIN_POSITIVE)).sqrt();
        let damping = relative.min(1.0).min(adaptive);
        let step = direction(problem, &rho, &states, &lambda, &phi, damping);
        // Backtracking (Armijo) on ½|Φ|²; the full step is the Newton step.
        let mut alpha = 1.0;
        let mut accepted = None;
        for _ in 0..(if step.is_some() { 12 } else { 0 }) {
            let trial = &lambda + step.as_ref().expect("a direction") * alpha;
            let trial_u = &problem.w * &trial + &problem.q;
            let (trial_phi, trial_states) = evaluate(problem, &rho, &trial, &trial_u);
            let trial_merit = scaled_merit(&trial_phi, &rho);
            if trial_merit.is_finite() && trial_merit <= (1.0 - 1e-4 * alpha) * merit {
                accepted = Some((trial, trial_u, trial_phi, trial_states, trial_merit));
                break;
            }
            alpha *= 0.5;
        }
        let (next, next_u, next_phi, next_states, next_merit) = match accepted {
            Some(next) => next,
            None => {
                // No descent along the Newton direction: Φ has a kink there (a contact with
                // neither force nor gap, or on the rim of its cone). One projected Gauss–Seidel
                // sweep on W moves off it (more sweeps each time it happens again: a stationary
                // point of the merit that is no solution); Newton goes on from there.
                let mut next = lambda.clone();
                for _ in 0..escape {
                    sweep(problem, &rho, &mut next);
                }
                escape = (escape * 2).min(MAX_ESCAPE_SWEEPS);
                let next_u = &problem.w * &next + &problem.q;
                let (next_phi, next_states) = evaluate(problem, &rho, &next, &next_u);
                let next_merit = scaled_merit(&next_phi, &rho);
                if !next_merit.is_finite() {
                    break;
                }
                alpha = 0.75;
                (next, next_u, next_phi, next_states, next_merit)
            }
        };
        adaptive = if alpha == 1.0 {
            (adaptive * 0.1).max(REGULARIZATION)
        } else if alpha < 0.5 {
            (adaptive * 10.0).min(1.0)
        } else {
            adaptive
        };
        (lambda, u, phi, states, merit) = (next, next_u, next_phi, next_states, next_merit);
        outcome.iterations += 1;
        observer(&to_local(&lambda));
    }
    outcome.local = to_local(&lambda);
    outcome
}

/// The Newton direction: `J d = −Φ` with J the generalized Jacobian at the current states.
/// Separated contacts have identity rows, so their step is `−λ_k` and only the others' system
/// is factored. `None` when that system is singular.
fn direction(
    problem: &DelassusProblem,
    rho: &[Option<f64>],
    states: &[State],
    lambda: &DVector<f64>,
    phi: &DVector<f64>,
    damping: f64,
) -> Option<DVector<f64>> {
    let m = problem.contacts();
    let mut step = DVector::zeros(3 * m);
    let active: Vec<usize> = (0..m)
        .filter(|&k| !matches!(states[k], State::Separated))
        .collect();
    for (k, state) in states.iter().enumerate() {
        if matches!(state, State::Separated) {
            step.fixed_rows_mut::<3>(3 * k)
                .copy_from(&(-lambda.fixed_rows::<3>(3 * k)));
        }
    }
    if active.is_empty() {
        return Some(step);
    }
    let size = 3 * active.len();
    // Rows of contact k scaled by √W_nn,k and columns by 1/√W_nn,l: the normal block becomes
    // W_kl / √(W_kk W_ll), whatever the contacts' compliances (a contact beside the driven
    // base is a thousand times stiffer than one at the tip).
    let scale: Vec<f64> = rho
        .iter()
        .map(|r| r.map_or(1.0, |r| r.recip().sqrt()))
        .collect();
    // Row r of contact k, over the full 3M columns: dσ_k = E_k dλ − ρ W_k dλ.
    let w = &problem.w;
    let sigma_row = |k: usize, r: usize, rho: f64, col: usize| -> f64 {
        let identity = if col == 3 * k + r { 1.0 } else { 0.0 };
        identity - rho * w[(3 * k + r, col)]
    };
    let mut jacobian = DMatrix::zeros(size, size);
    let mut rhs = DVector::zeros(size);
    for (a, &k) in active.iter().enumerate() {
        let rho = rho[k].expect("an active contact moves");
        let mu = problem.friction[k];
        // Full rows of J for contact k, then split into the active columns (kept) and the
        // separated ones (their known step moved to the right-hand side).
        let row = |r: usize, col: usize| -> f64 {
            let identity = if col == 3 * k + r { 1.0 } else { 0.0 };
            match (r, states[k]) {
                // Φ_n = λ_n − σ_n and, sticking, Φ_t = λ_t − σ_t.
                (0, _) | (_, State::Sticking) => identity - sigma_row(k, r, rho, col),
                (_, State::Sliding { direction, ratio }) => {
                    // Φ_t = λ_t − μ σ_n ŝ: dΦ_t = dλ_t − μ ŝ dσ_n − (r/|σ_t|)(I − ŝŝᵀ) dσ_t.
                    let i = r - 1;
                    let mut value = identity - mu * direction[i] * sigma_row(k, 0, rho, col);
                    for j in 0..2 {
                        let projector =
                            if i == j { 1.0 } else { 0.0 } - direction[i] * direction[j];
                        if projector != 0.0 {
                            value -= ratio * projector * sigma_row(k, j + 1, rho, col);
                        }
                    }
                    value
                }
                (_, State::Separated) => identity,
            }
        };
        for r in 0..3 {
            let mut right = -phi[3 * k + r];
            for (col, value) in (0..3 * m).map(|col| (col, row(r, col))) {
                if value == 0.0 {
                    continue;
                }
                let contact = col / 3;
                match active.binary_search(&contact) {
                    Ok(b) => {
                        jacobian[(3 * a + r, 3 * b + col % 3)] = value * scale[k] / scale[contact]
                    }
                    Err(_) => right -= value * step[col],
                }
            }
            rhs[3 * a + r] = right * scale[k];
        }
    }
    // Redundant contacts (three on one element carry nine force components against six
    // degrees of freedom; two points of one element pushed along one normal) make J singular,
    // and with the wrong contacts pushing, the Newton system has no solution. The
    // Levenberg–Marquardt step (JᵀJ + νI) d = Jᵀ r, with ν the residual relative to the
    // forces' scale, is defined always, turns towards the merit's descent direction far from
    // the solution, and is the Newton step at it (ν → 0: quadratic convergence where J is
    // regular).
    let nu = damping.max(REGULARIZATION);
    let mut normal = jacobian.transpose() * &jacobian;
    for i in 0..size {
        normal[(i, i)] += nu;
    }
    let rhs = jacobian.transpose() * rhs;
    let solved = normal.cholesky()?.solve(&rhs);
    if !solved.iter().all(|v| v.is_finite()) {
        return None;
    }
    for (a, &k) in active.iter().enumerate() {
        step.fixed_rows_mut::<3>(3 * k)
            .copy_from(&(solved.fixed_rows::<3>(3 * a) / scale[k]));
    }
    Some(step)
}

/// One projected Gauss–Seidel sweep over the contacts on the dense W, with the local
/// Coulomb law of [`super::problem::local_law`].
fn sweep(problem: &DelassusProblem, rho: &[Option<f64>], lambda: &mut DVector<f64>) {
    let w = &problem.w;
    for (k, rho) in rho.iter().enumerate() {
        if rho.is_none() {
            lambda.fixed_rows_mut::<3>(3 * k).fill(0.0);
            continue;
        }
        let wkk = w.fixed_view::<3, 3>(3 * k, 3 * k).into_owned();
        let own = lambda.fixed_rows::<3>(3 * k).into_owned();
        let b = (w.rows(3 * k, 3) * &*lambda) + problem.q.fixed_rows::<3>(3 * k) - wkk * own;
        let b = Vector3::new(b[0], b[1], b[2]);
        let updated = super::problem::local_law(
            &wkk,
            wkk.try_inverse().as_ref(),
            &b,
            0.0,
            problem.friction[k],
        );
        lambda.fixed_rows_mut::<3>(3 * k).copy_from(&updated);
    }
}
