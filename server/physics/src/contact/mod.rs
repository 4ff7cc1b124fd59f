//! Contact response: Signorini non-penetration with Coulomb friction, solved by semismooth
//! Newton on the Delassus matrix ([`newton`], the default) or by Gauss–Seidel
//! over contacts ordered along the device (the paper's Algorithm 3), with the compliance of
//! every contact taken from the substructure's flexibility blocks and the coupling between
//! contacts propagated along the chain (Algorithm 4), so one sweep costs O(M + N) for M
//! contacts on N nodes instead of the O(M²) of an assembled Delassus matrix.
//!
//! **Problem.** A step's free increment Δu_free (from K Δu = r) moves contact point k by
//! δ_free,k. Contact forces λ_k (normal n and tangents t1, t2 of contact k, world force
//! `R_k λ_k` with `R_k = [n t1 t2]`) add `K⁻¹ Hᵀ λ`, so the contact points move by
//! `δ = δ_free + W λ`, `W = H K⁻¹ Hᵀ`. Each contact requires
//! `0 ≤ λ_n ⊥ gap + δ_n ≥ 0` (Signorini) and `|λ_t| ≤ μ λ_n`, with `λ_t = −μ λ_n δ_t/|δ_t|`
//! when it slides (Coulomb, δ_t the tangential displacement over the step).
//!
//! **Propagation.** For a block-tridiagonal K factored from the base, `(K⁻¹)(i,j) =
//! H(i,i+1)…H(j−1,j) D(j)` for i < j (D = the diagonal blocks of K⁻¹, H the couplings). The
//! displacement of node i due to loads F is then `u_i = B_i + D_i A_i`, with the tip-ward part
//! `B_i = D_i F_i + H(i,i+1) B_{i+1}` and the base-ward accumulation
//! `A_{i+1} = H(i,i+1)ᵀ (A_i + F_i)`. A sweep computes B once (O(N)), then walks the contacts
//! in order along the device, advancing A and patching B locally as each contact's force
//! changes: O(1) block products per contact and per node.
//!
//! A contact lies on element `e` at parameter t: it acts on model nodes e and e+1 with weights
//! (1 − t) and t. Model node 0 is the driven base (fixed); unknown node i is model node i + 1.

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Vector3, Vector6};

use crate::error::{PhysicsError, Result};
use crate::substructure::Flexibility;

pub mod delassus;
pub mod newton;

pub use delassus::DelassusProblem;

/// One contact between the device and the vessel wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// Element index: the contact point lies between model nodes `element` and `element + 1`.
    pub element: usize,
    /// Position along the element, 0 (at node `element`) to 1 (at node `element + 1`).
    pub t: f64,
    /// Unit normal pointing away from the wall into the lumen: the direction the wall pushes.
    pub normal: Vector3<f64>,
    /// Current gap (m): clearance between the device surface and the wall; negative when the
    /// device penetrates.
    pub gap: f64,
    /// Coulomb friction coefficient (dimensionless).
    pub friction: f64,
}

impl Contact {
    /// The contact frame `[n t1 t2]` (columns), with tangents chosen deterministically.
    pub fn frame(&self) -> Matrix3<f64> {
        let n = self.normal;
        let t1 = perpendicular(&n);
        let t2 = n.cross(&t1);
        Matrix3::from_columns(&[n, t1, t2])
    }
}

/// A unit vector perpendicular to unit `n`, chosen deterministically (from whichever of x and
/// y is farther from `n`).
pub fn perpendicular(n: &Vector3<f64>) -> Vector3<f64> {
    let helper = if n.x.abs() < 0.6 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    (helper - n * n.dot(&helper)).normalize()
}

/// Translation of the point at parameter `t` of element `element` under node `increments`
/// (one per unknown node; model node 0, the driven base, does not move).
pub fn point_displacement(increments: &[Vector6<f64>], element: usize, t: f64) -> Vector3<f64> {
    let node = |n: usize| -> Vector3<f64> {
        if n == 0 {
            Vector3::zeros()
        } else {
            translation(&increments[n - 1])
        }
    };
    node(element) * (1.0 - t) + node(element + 1) * t
}

/// Which algorithm solves a step's contact problem.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ContactMethod {
    /// Semismooth Newton on the Delassus matrix ([`newton`]): a few iterations, each
    /// O(N + M²) to set up and O(A³) to factor (A the pushing contacts); Gauss–Seidel
    /// finishes a problem it does not converge on within [`ContactSettings::newton_iterations`].
    #[default]
    Newton,
    /// Projected Gauss–Seidel through the flexibility blocks, O(M + N) a sweep (the paper's
    /// Algorithm 3): the reference.
    GaussSeidel,
}

/// Contact solve: the method and its stopping rule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactSettings {
    /// The algorithm.
    pub method: ContactMethod,
    /// Newton iterations before Gauss–Seidel takes over ([`ContactMethod::Newton`]).
    pub newton_iterations: usize,
    /// Stop when no contact force changed by more than `tolerance` × the largest force (or
    /// by more than `absolute_tolerance_n`, whichever is larger) over a sweep.
    pub tolerance: f64,
    /// Absolute force tolerance (N).
    pub absolute_tolerance_n: f64,
    /// Sweep cap.
    pub max_iterations: usize,
    /// Also require every contact's gap, as the sweep found it, to be violated by at most this
    /// much (m) before stopping: a loose force tolerance then still keeps penetration small.
    /// Infinite disables the check.
    pub violation_tolerance_m: f64,
    /// Over-relaxation factor ω ∈ (0, 2): each contact moves ω times its Gauss–Seidel update,
    /// then is projected back onto the friction cone (projected SOR). 1 is plain Gauss–Seidel.
    pub relaxation: f64,
    /// Detection-and-solve rounds per beam step (see `BeamModel::step_with_contacts`).
    pub detection_rounds: usize,
    /// A new round runs when the solved configuration penetrates a wall by more than this (m).
    pub penetration_tolerance_m: f64,
    /// Anderson acceleration of the Gauss–Seidel iteration: how many past sweeps to mix
    /// (0 = plain Gauss–Seidel). The accelerated iterate is projected back onto the friction
    /// cones and the history restarts whenever the update grows; each sweep still costs
    /// O(M + N), plus O(depth² M) for the mixing.
    pub acceleration_depth: usize,
    /// When Gauss–Seidel runs out of sweeps, finish the normal forces with an active-set
    /// solve (the tangential forces held): exact non-penetration for O(A·N + A³) work, A the
    /// active contacts.
    pub polish: bool,
}

impl ContactSettings {
    /// Whether a sweep whose largest force change was `change` (N), largest force `force` (N)
    /// and largest gap violation `violation` (m) meets the tolerances.
    pub(crate) fn sweep_converged(&self, change: f64, force: f64, violation: f64) -> bool {
        change <= (self.tolerance * force).max(self.absolute_tolerance_n)
            && violation <= self.violation_tolerance_m
    }
}

impl Default for ContactSettings {
    fn default() -> Self {
        Self {
            method: ContactMethod::Newton,
            newton_iterations: NEWTON_ITERATIONS,
            tolerance: 1e-6,
            absolute_tolerance_n: 1e-9,
            max_iterations: 200,
            violation_tolerance_m: f64::INFINITY,
            relaxation: 1.0,
            detection_rounds: 1,
            penetration_tolerance_m: 1e-6,
            acceleration_depth: 0,
            polish: false,
        }
    }
}

/// The solved contact forces.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ContactResponse {
    /// Per contact: force components (normal, tangent 1, tangent 2) in its frame (N).
    pub local: Vec<Vector3<f64>>,
    /// Per contact: the force on the device in the world frame (N).
    pub forces: Vec<Vector3<f64>>,
    /// Per unknown node: the resulting nodal load (force N, moment N·m; moments are zero).
    pub nodal_loads: Vec<Vector6<f64>>,
    /// Sweeps performed.
    pub iterations: usize,
    /// Whether the tolerance was met.
    pub converged: bool,
    /// Whether the normal forces were finished by the active-set solve after Gauss–Seidel ran
    /// out of sweeps.
    pub polished: bool,
}

/// Per-contact data fixed during a solve.
#[derive(Debug, Clone, Copy)]
struct Prepared {
    /// Unknown index of the element's first node, if it is not the fixed base.
    first: Option<usize>,
    /// Unknown index of the element's second node.
    second: usize,
    t: f64,
    frame: Matrix3<f64>,
    /// Local 3×3 compliance in the contact frame.
    compliance: Matrix3<f64>,
    /// Its inverse, where it has one.
    compliance_inverse: Option<Matrix3<f64>>,
    /// Free displacement of the contact point in the contact frame.
    free: Vector3<f64>,
    gap: f64,
    friction: f64,
}

pub(crate) fn translation(v: &Vector6<f64>) -> Vector3<f64> {
    Vector3::new(v[0], v[1], v[2])
}

pub(crate) fn force6(f: &Vector3<f64>) -> Vector6<f64> {
    Vector6::new(f.x, f.y, f.z, 0.0, 0.0, 0.0)
}

pub(crate) fn top_left(m: &Matrix6<f64>) -> Matrix3<f64> {
    m.fixed_view::<3, 3>(0, 0).into_owned()
}

/// Checks contacts against the model size and returns them prepared, in input order.
fn prepare(
    flexibility: &Flexibility,
    free: &[Vector6<f64>],
    contacts: &[Contact],
) -> Result<Vec<Prepared>> {
    let unknowns = flexibility.diagonal.len();
    if free.len() != unknowns || flexibility.coupling.len() + 1 != unknowns.max(1) {
        return Err(PhysicsError::LengthMismatch {
            what: "free displacement per unknown node",
            expected: unknowns,
            actual: free.len(),
        });
    }
    contacts
        .iter()
        .enumerate()
        .map(|(k, c)| {
            if c.element >= unknowns {
                return Err(PhysicsError::LengthMismatch {
                    what: "contact element index (must be < element count)",
                    expected: unknowns,
                    actual: c.element,
                });
            }
            let finite = c.t.is_finite()
                && c.gap.is_finite()
                && c.friction.is_finite()
                && c.normal.iter().all(|v| v.is_finite());
            if !finite || !(0.0..=1.0).contains(&c.t) || c.friction < 0.0 {
                return Err(PhysicsError::OutOfRange {
                    what: format!("contact {k} (t, gap, friction, normal)"),
                    range: "finite, 0 <= t <= 1, friction >= 0",
                    value: c.t,
                });
            }
            if (c.normal.norm() - 1.0).abs() > 1e-6 {
                return Err(PhysicsError::OutOfRange {
                    what: format!("contact {k} normal length"),
                    range: "a unit vector",
                    value: c.normal.norm(),
                });
            }
            let first = c.element.checked_sub(1);
            let second = c.element;
            let (a, b) = (1.0 - c.t, c.t);
            let mut w = top_left(&flexibility.diagonal[second]) * (b * b);
            let mut d = translation(&free[second]) * b;
            if let Some(i) = first {
                // (K⁻¹)(i, i+1) = H(i,i+1) D(i+1).
                let cross = top_left(&(flexibility.coupling[i] * flexibility.diagonal[second]));
                w += top_left(&flexibility.diagonal[i]) * (a * a)
                    + (cross + cross.transpose()) * (a * b);
                d += translation(&free[i]) * a;
            }
            let frame = c.frame();
            let compliance = frame.transpose() * w * frame;
            Ok(Prepared {
                compliance_inverse: compliance.try_inverse(),
                first,
                second,
                t: c.t,
                frame,
                compliance,
                free: frame.transpose() * d,
                gap: c.gap,
                friction: c.friction,
            })
        })
        .collect()
}

/// The local contact law: given the contact's compliance `w` (its frame), the displacement `b`
/// it would have without its own force (its frame) and its gap, returns the force that closes
/// the gap with sticking friction, or slides on the friction cone, or separates.
pub fn solve_local(w: &Matrix3<f64>, b: &Vector3<f64>, gap: f64, mu: f64) -> Vector3<f64> {
    local_law(w, w.try_inverse().as_ref(), b, gap, mu)
}

/// [`solve_local`] with the inverse compliance supplied (computed once per solve).
pub(crate) fn local_law(
    w: &Matrix3<f64>,
    w_inverse: Option<&Matrix3<f64>>,
    b: &Vector3<f64>,
    gap: f64,
    mu: f64,
) -> Vector3<f64> {
    // A contact on the driven base cannot move: the base reaction takes it.
    if w[(0, 0)].is_nan() || w[(0, 0)] <= 0.0 {
        return Vector3::zeros();
    }
    // Frictionless normal force: δ_n = b_n + W_nn λ_n = −gap.
    let normal_only = -(b.x + gap) / w[(0, 0)];
    if normal_only <= 0.0 {
        return Vector3::zeros();
    }
    if mu == 0.0 {
        return Vector3::new(normal_only, 0.0, 0.0);
    }
    // Stick: δ = b + W λ = (−gap, 0, 0).
    let target = Vector3::new(-gap, 0.0, 0.0);
    let stick = w_inverse.map(|wi| wi * (target - b));
    if let Some(stick) = stick
        && stick.x > 0.0
        && stick.y.hypot(stick.z) <= mu * stick.x
    {
        return stick;
    }
    // Slide: λ_t = μ λ_n d(φ), d = (cos φ, sin φ) opposite to the slip. For each φ the normal
    // equation gives λ_n(φ); the slip s(φ) = b_t + W_tn λ_n + W_tt λ_t must be anti-parallel
    // to d: find the root of s × d (with s · d < 0) nearest the sticking force's direction.
    let guess = match stick {
        Some(s) if s.y.hypot(s.z) > 0.0 => s.z.atan2(s.y),
        _ => (-b.z).atan2(-b.y),
    };
    let evaluate = |phi: f64| -> Option<(f64, f64, Vector3<f64>)> {
        let (dy, dz) = (phi.cos(), phi.sin());
        let denominator = w[(0, 0)] + mu * (w[(0, 1)] * dy + w[(0, 2)] * dz);
        if denominator <= 0.0 {
            return None;
        }
        let lambda_n = -(b.x + gap) / denominator;
        let force = Vector3::new(lambda_n, mu * lambda_n * dy, mu * lambda_n * dz);
        let slip = b + w * force;
        Some((slip.y * dz - slip.z * dy, slip.y * dy + slip.z * dz, force))
    };
    const SAMPLES: i32 = 72;
    let step = std::f64::consts::TAU / SAMPLES as f64;
    // Fast path: from the sticking direction, iterate d ← −slip_t(d)/|slip_t(d)| (no
    // trigonometry). Where the tangential compliance is nearly isotropic this converges in a
    // few steps to the root nearest the guess, the one the bracket search below would find.
    {
        let (gy, gz) = (guess.cos(), guess.sin());
        let (mut dy, mut dz) = (gy, gz);
        for _ in 0..6 {
            let denominator = w[(0, 0)] + mu * (w[(0, 1)] * dy + w[(0, 2)] * dz);
            if denominator <= 0.0 {
                break;
            }
            let lambda_n = -(b.x + gap) / denominator;
            let force = Vector3::new(lambda_n, mu * lambda_n * dy, mu * lambda_n * dz);
            let slip = b + w * force;
            let norm = slip.y.hypot(slip.z);
            if norm == 0.0 || lambda_n <= 0.0 {
                break;
            }
            let (ny, nz) = (-slip.y / norm, -slip.z / norm);
            let change = (ny - dy).hypot(nz - dz);
            (dy, dz) = (ny, nz);
            if change <= 1e-13 {
                if dy * gy + dz * gz > (0.5 * step).cos() {
                    return force;
                }
                break;
            }
        }
    }
    // Search brackets outward from the guess (k = 0, +1, −1, +2, …), so the first valid root
    // is the one nearest the sticking direction; refine it by the Illinois method.
    let mut best: Option<(f64, Vector3<f64>)> = None;
    for k in 0..SAMPLES {
        let offset = if k % 2 == 0 { k / 2 } else { -(k + 1) / 2 };
        let lo = guess + (offset as f64 - 0.5) * step;
        let hi = lo + step;
        let (Some((f_lo, _, _)), Some((f_hi, _, _))) = (evaluate(lo), evaluate(hi)) else {
            continue;
        };
        if f_lo * f_hi > 0.0 {
            continue;
        }
        let (mut a, mut c, mut fa, mut fc) = (lo, hi, f_lo, f_hi);
        let mut side = 0i8;
        let mut phi = 0.5 * (a + c);
        for _ in 0..100 {
            phi = if fc != fa {
                (a * fc - c * fa) / (fc - fa)
            } else {
                0.5 * (a + c)
            };
            if !(phi > a.min(c) && phi < a.max(c)) {
                phi = 0.5 * (a + c);
            }
            let Some((fm, _, _)) = evaluate(phi) else {
                break;
            };
            if fm == 0.0 || (c - a).abs() < 1e-14 {
                break;
            }
            if fm * fc > 0.0 {
                c = phi;
                fc = fm;
                if side == -1 {
                    fa *= 0.5;
                }
                side = -1;
            } else {
                a = phi;
                fa = fm;
                if side == 1 {
                    fc *= 0.5;
                }
                side = 1;
            }
        }
        if let Some((_, along, force)) = evaluate(phi)
            && along <= 0.0
            && force.x > 0.0
        {
            best = Some(((phi - guess).abs(), force));
            break;
        }
    }
    match best {
        Some((_, force)) => force,
        // No sliding root found (a tangential double root can slip between samples): fall back
        // to the frictionless force, which is inside the cone.
        None => Vector3::new(normal_only, 0.0, 0.0),
    }
}

/// The normal force that closes the gap with the tangential force `own.yz` held, the latter
/// clipped to the cone of the new normal force.
pub(crate) fn normal_with_fixed_tangent(
    w: &Matrix3<f64>,
    b: &Vector3<f64>,
    gap: f64,
    own: &Vector3<f64>,
    mu: f64,
) -> Vector3<f64> {
    if w[(0, 0)].is_nan() || w[(0, 0)] <= 0.0 {
        return Vector3::zeros();
    }
    let normal = (-(b.x + gap + w[(0, 1)] * own.y + w[(0, 2)] * own.z) / w[(0, 0)]).max(0.0);
    project_on_cone(&Vector3::new(normal, own.y, own.z), mu)
}

/// The tip-ward part of the propagation, B_i = D_i F_i + H(i,i+1) B_{i+1} from the tip, into
/// `out`: O(N).
pub(crate) fn tip_ward_pass(
    flexibility: &Flexibility,
    loads: &[Vector6<f64>],
    out: &mut [Vector6<f64>],
) {
    let d = &flexibility.diagonal;
    let h = &flexibility.coupling;
    let mut next = Vector6::zeros();
    for i in (0..d.len()).rev() {
        next = d[i] * loads[i]
            + if i + 1 < d.len() {
                h[i] * next
            } else {
                Vector6::zeros()
            };
        out[i] = next;
    }
}

/// Displacements of every unknown node under nodal `loads`, u = K⁻¹ F, by the propagation
/// u_i = B_i + D_i A_i of the module documentation: O(N).
fn node_displacements(flexibility: &Flexibility, loads: &[Vector6<f64>]) -> Vec<Vector6<f64>> {
    let d = &flexibility.diagonal;
    let h = &flexibility.coupling;
    let n = d.len();
    let mut u = vec![Vector6::zeros(); n];
    tip_ward_pass(flexibility, loads, &mut u);
    let mut base_ward = Vector6::zeros();
    for i in 0..n {
        if i > 0 {
            base_ward = h[i - 1].transpose() * (base_ward + loads[i - 1]);
        }
        u[i] += d[i] * base_ward;
    }
    u
}

/// Normal displacement of contact `p` (its frame's first axis) under node displacements `u`.
fn normal_displacement(p: &Prepared, u: &[Vector6<f64>]) -> f64 {
    let mut delta = translation(&u[p.second]) * p.t;
    if let Some(i) = p.first {
        delta += translation(&u[i]) * (1.0 - p.t);
    }
    p.frame.column(0).dot(&delta)
}

/// Active-set solve of the normal forces with the tangential forces held, for the
/// single-chain solver (W from K⁻¹ by propagation, one O(N) solve per active contact); see
/// [`active_set_normals`].
fn polish_normals(
    flexibility: &Flexibility,
    prepared: &[Prepared],
    local: &mut [Vector3<f64>],
) -> bool {
    let m = prepared.len();
    let n = flexibility.diagonal.len();
    // Gaps with zero normal forces: free motion plus the held tangential forces.
    let mut tangential_loads = vec![Vector6::zeros(); n];
    let tangential: Vec<Vector3<f64>> = local.iter().map(|l| Vector3::new(0.0, l.y, l.z)).collect();
    accumulate_loads(prepared, &tangential, &mut tangential_loads);
    let u_t = node_displacements(flexibility, &tangential_loads);
    let c: Vec<f64> = prepared
        .iter()
        .map(|p| p.gap + p.free.x + normal_displacement(p, &u_t))
        .collect();
    let column = |j: usize| -> Vec<f64> {
        let mut unit = vec![Vector3::zeros(); m];
        unit[j] = Vector3::x();
        let mut loads = vec![Vector6::zeros(); n];
        accumulate_loads(prepared, &unit, &mut loads);
        let u = node_displacements(flexibility, &loads);
        prepared
            .iter()
            .map(|p| normal_displacement(p, &u))
            .collect()
    };
    active_set_normals(&c, column, local, |k| prepared[k].friction)
}

/// Active-set solve of the normal forces `local[k].x` with the tangential forces held: `c[k]`
/// is contact k's gap with zero normal forces and `column(j)` the normal displacement of every
/// contact under a unit normal force at j (W's column j). The set starts from the contacts
/// pushing or penetrating; each pass solves W_AA λ_A = −c_A exactly, drops the most negative
/// force or adds the most penetrated inactive contact, until neither exists; the tangential
/// forces are then projected on the cones of the new normals. Returns false (leaving `local`
/// alone) if it does not settle in 2M passes.
pub(crate) fn active_set_normals(
    c: &[f64],
    mut column: impl FnMut(usize) -> Vec<f64>,
    local: &mut [Vector3<f64>],
    friction: impl Fn(usize) -> f64,
) -> bool {
    let m = c.len();
    let mut columns: Vec<Option<Vec<f64>>> = vec![None; m];
    let tolerance = 1e-9;
    let scale = c.iter().fold(1e-12f64, |a, b| a.max(b.abs()));
    let mut active: Vec<bool> = (0..m).map(|k| local[k].x > 0.0 || c[k] < 0.0).collect();
    for _ in 0..2 * m.max(1) {
        let set: Vec<usize> = (0..m).filter(|&k| active[k]).collect();
        let cols: Vec<Vec<f64>> = set
            .iter()
            .map(|&j| columns[j].get_or_insert_with(|| column(j)).clone())
            .collect();
        let lambda = if set.is_empty() {
            DVector::zeros(0)
        } else {
            let w = DMatrix::from_fn(set.len(), set.len(), |a, b| cols[b][set[a]]);
            let rhs = DVector::from_iterator(set.len(), set.iter().map(|&k| -c[k]));
            match w.clone().cholesky() {
                Some(ch) => ch.solve(&rhs),
                None => match w.lu().solve(&rhs) {
                    Some(x) => x,
                    None => return false,
                },
            }
        };
        if let Some((a, _)) = lambda
            .iter()
            .enumerate()
            .filter(|(_, l)| **l < 0.0)
            .min_by(|x, y| x.1.total_cmp(y.1))
        {
            active[set[a]] = false;
            continue;
        }
        // Gaps of the inactive contacts under the active forces.
        let worst = (0..m)
            .filter(|&k| !active[k])
            .map(|k| {
                let g = c[k]
                    + cols
                        .iter()
                        .zip(lambda.iter())
                        .map(|(col, l)| col[k] * l)
                        .sum::<f64>();
                (k, g)
            })
            .filter(|(_, g)| *g < -tolerance * scale)
            .min_by(|x, y| x.1.total_cmp(&y.1));
        if let Some((k, _)) = worst {
            active[k] = true;
            continue;
        }
        for l in local.iter_mut() {
            l.x = 0.0;
        }
        for (&k, l) in set.iter().zip(lambda.iter()) {
            local[k].x = *l;
        }
        for (k, l) in local.iter_mut().enumerate() {
            *l = project_on_cone(l, friction(k));
        }
        return true;
    }
    false
}

/// Replaces `loads` by the nodal loads of contact forces `local` (after the forces jumped:
/// an acceleration or active-set step).
fn reload(prepared: &[Prepared], local: &[Vector3<f64>], loads: &mut [Vector6<f64>]) {
    loads.iter_mut().for_each(|l| l.fill(0.0));
    accumulate_loads(prepared, local, loads);
}

/// Adds the nodal loads of contact forces `local` into `loads`.
fn accumulate_loads(prepared: &[Prepared], local: &[Vector3<f64>], loads: &mut [Vector6<f64>]) {
    for (p, l) in prepared.iter().zip(local) {
        let f = p.frame * l;
        loads[p.second] += force6(&(f * p.t));
        if let Some(i) = p.first {
            loads[i] += force6(&(f * (1.0 - p.t)));
        }
    }
}

/// Projects a local force onto the friction cone (λ_n ≥ 0, |λ_t| ≤ μ λ_n, radially).
pub(crate) fn project_on_cone(l: &Vector3<f64>, mu: f64) -> Vector3<f64> {
    if l.x <= 0.0 {
        return Vector3::zeros();
    }
    let tangential = l.y.hypot(l.z);
    if tangential > mu * l.x {
        let scale = if tangential > 0.0 {
            mu * l.x / tangential
        } else {
            0.0
        };
        Vector3::new(l.x, l.y * scale, l.z * scale)
    } else {
        *l
    }
}

/// Anderson acceleration (type II) of a fixed-point iteration x ← G(x): mixes the last few
/// iterates to minimise the linearized residual G(x) − x.
pub(crate) struct Anderson {
    depth: usize,
    /// Past G(x) values and residuals G(x) − x, flattened.
    values: std::collections::VecDeque<DVector<f64>>,
    residuals: std::collections::VecDeque<DVector<f64>>,
    size: usize,
}

impl Anderson {
    pub(crate) fn new(depth: usize, size: usize) -> Self {
        Self {
            depth,
            values: Default::default(),
            residuals: Default::default(),
            size,
        }
    }

    pub(crate) fn active(&self) -> bool {
        self.depth > 0 && self.size > 0
    }

    /// Records the sweep `before → after` and replaces `after` by the mixed iterate; false when
    /// there is not yet enough history (or it was reset).
    pub(crate) fn mix(&mut self, before: &[Vector3<f64>], after: &mut [Vector3<f64>]) -> bool {
        let flat = |v: &[Vector3<f64>]| {
            DVector::from_iterator(self.size, v.iter().flat_map(|l| l.iter().copied()))
        };
        let g = flat(after);
        let f = &g - flat(before);
        if let Some(last) = self.residuals.back()
            && f.norm() > 2.0 * last.norm()
        {
            // The iteration is not contracting in this region: restart the history.
            self.values.clear();
            self.residuals.clear();
        }
        self.values.push_back(g.clone());
        self.residuals.push_back(f.clone());
        if self.values.len() > self.depth + 1 {
            self.values.pop_front();
            self.residuals.pop_front();
        }
        let m = self.values.len() - 1;
        if m == 0 {
            return false;
        }
        let delta_f = DMatrix::from_fn(self.size, m, |r, c| {
            self.residuals[c + 1][r] - self.residuals[c][r]
        });
        let delta_g = DMatrix::from_fn(self.size, m, |r, c| {
            self.values[c + 1][r] - self.values[c][r]
        });
        let mut normal = delta_f.transpose() * &delta_f;
        let scale = normal.diagonal().amax().max(f64::MIN_POSITIVE);
        for i in 0..m {
            normal[(i, i)] += 1e-12 * scale;
        }
        let Some(gamma) = normal
            .cholesky()
            .map(|c| c.solve(&(delta_f.transpose() * &f)))
        else {
            return false;
        };
        let mixed = &g - delta_g * gamma;
        if !mixed.iter().all(|v| v.is_finite()) {
            return false;
        }
        // Mix the normal forces only: the tangential ones follow the friction law of the
        // Gauss–Seidel sweep (mixing them can cycle between sliding directions).
        for (k, l) in after.iter_mut().enumerate() {
            l.x = mixed[3 * k];
        }
        true
    }
}

/// Over-relaxes a local update and projects it onto the friction cone.
pub(crate) fn relax(
    own: &Vector3<f64>,
    updated: Vector3<f64>,
    omega: f64,
    mu: f64,
) -> Vector3<f64> {
    if omega == 1.0 {
        return updated;
    }
    project_on_cone(&(own + (updated - own) * omega), mu)
}

/// Newton iterations a contact solve may take by default before Gauss–Seidel takes over.
pub const NEWTON_ITERATIONS: usize = 25;

/// Solves the contact problem with the method `settings` names (see [`ContactMethod`]).
pub fn solve(
    flexibility: &Flexibility,
    free: &[Vector6<f64>],
    contacts: &[Contact],
    settings: &ContactSettings,
    warm_start: Option<&[Vector3<f64>]>,
) -> Result<ContactResponse> {
    match settings.method {
        ContactMethod::GaussSeidel => {
            gauss_seidel(flexibility, free, contacts, settings, warm_start)
        }
        ContactMethod::Newton => newton_solve(flexibility, free, contacts, settings, warm_start),
    }
}

/// The contact problem of a single chain in Delassus form (for [`newton`] and for recording
/// problems).
pub fn delassus_problem(
    flexibility: &Flexibility,
    free: &[Vector6<f64>],
    contacts: &[Contact],
) -> Result<DelassusProblem> {
    Ok(delassus::assemble(
        flexibility,
        &prepare(flexibility, free, contacts)?,
    ))
}

/// The Newton tolerance of contact settings.
pub fn newton_tolerance(settings: &ContactSettings) -> newton::NewtonTolerance {
    newton::NewtonTolerance {
        relative: settings.tolerance,
        absolute_n: settings.absolute_tolerance_n,
        violation_m: settings.violation_tolerance_m,
        max_iterations: settings.newton_iterations,
    }
}

/// Solves the contact problem by semismooth Newton on its Delassus matrix ([`newton`]),
/// handing an unconverged problem to [`gauss_seidel`] from where Newton stopped.
pub fn newton_solve(
    flexibility: &Flexibility,
    free: &[Vector6<f64>],
    contacts: &[Contact],
    settings: &ContactSettings,
    warm_start: Option<&[Vector3<f64>]>,
) -> Result<ContactResponse> {
    let prepared = prepare(flexibility, free, contacts)?;
    let problem = delassus::assemble(flexibility, &prepared);
    let outcome = newton::solve(
        &problem,
        warm_start,
        &newton_tolerance(settings),
        &mut |_| {},
    );
    let finite = outcome
        .local
        .iter()
        .all(|l| l.iter().all(|v| v.is_finite()));
    if !outcome.converged || !finite {
        let start = finite.then_some(outcome.local.as_slice()).or(warm_start);
        // The sweeps left of the budget (an overload governor's cap counts both).
        let rest = ContactSettings {
            max_iterations: settings
                .max_iterations
                .saturating_sub(outcome.iterations)
                .max(1),
            ..*settings
        };
        let mut response = gauss_seidel(flexibility, free, contacts, &rest, start)?;
        response.iterations += outcome.iterations;
        return Ok(response);
    }
    let mut loads = vec![Vector6::zeros(); flexibility.diagonal.len()];
    accumulate_loads(&prepared, &outcome.local, &mut loads);
    Ok(ContactResponse {
        forces: prepared
            .iter()
            .zip(&outcome.local)
            .map(|(p, l)| p.frame * l)
            .collect(),
        local: outcome.local,
        nodal_loads: loads,
        iterations: outcome.iterations,
        converged: true,
        polished: false,
    })
}

/// Sweeps between active-set solves of the normal forces when Gauss–Seidel is slow to
/// converge (with [`ContactSettings::polish`]).
pub const POLISH_EVERY: usize = 25;

/// Solves the contact problem by Gauss–Seidel over the contacts in order along the device,
/// with O(M + N) work per sweep. `free` is the free increment of every unknown node (from the
/// step's linear solve); `warm_start` (local forces per contact) speeds up repeated solves.
pub fn gauss_seidel(
    flexibility: &Flexibility,
    free: &[Vector6<f64>],
    contacts: &[Contact],
    settings: &ContactSettings,
    warm_start: Option<&[Vector3<f64>]>,
) -> Result<ContactResponse> {
    let prepared = prepare(flexibility, free, contacts)?;
    let n = flexibility.diagonal.len();
    let mut order: Vec<usize> = (0..contacts.len()).collect();
    order.sort_by(|&a, &b| {
        (contacts[a].element, contacts[a].t)
            .partial_cmp(&(contacts[b].element, contacts[b].t))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let mut local: Vec<Vector3<f64>> = match warm_start {
        Some(w) if w.len() == contacts.len() => w.to_vec(),
        _ => vec![Vector3::zeros(); contacts.len()],
    };
    // Nodal loads of the current forces.
    let mut loads = vec![Vector6::<f64>::zeros(); n];
    accumulate_loads(&prepared, &local, &mut loads);
    let mut anderson = Anderson::new(settings.acceleration_depth, 3 * contacts.len());
    let d = &flexibility.diagonal;
    let h = &flexibility.coupling;
    let mut tip_ward = vec![Vector6::<f64>::zeros(); n];
    let mut response = ContactResponse::default();
    // Phase 1: the full Coulomb law. Gauss–Seidel on frictional contact can cycle instead of
    // converging; then phase 2 freezes the tangential forces (clipped to the cones) and solves
    // the normal forces alone, a convex problem, so non-penetration holds whatever friction did.
    let with_friction = prepared.iter().any(|p| p.friction > 0.0);
    let budget = settings.max_iterations.max(1);
    let mut frozen = false;
    let mut sweep = 0;
    while sweep < if with_friction { 2 * budget } else { budget } {
        if sweep == budget {
            frozen = true;
            anderson = Anderson::new(settings.acceleration_depth, 3 * contacts.len());
        }
        let before = anderson.active().then(|| local.clone());
        tip_ward_pass(flexibility, &loads, &mut tip_ward);
        // A_i: base-ward accumulation, advanced lazily up to `cursor`.
        let mut cursor = 0usize;
        let mut base_ward = Vector6::<f64>::zeros();
        let mut largest_change: f64 = 0.0;
        let mut largest_force: f64 = 0.0;
        let mut largest_violation: f64 = 0.0;
        for &k in &order {
            let p = &prepared[k];
            let window = p.first.unwrap_or(p.second);
            while cursor < window {
                base_ward = h[cursor].transpose() * (base_ward + loads[cursor]);
                cursor += 1;
            }
            // Displacements of the element's nodes under the current contact loads (their
            // translations only: the top three rows of D).
            let (u_first, a_second) = match p.first {
                Some(i) => (
                    translation(&tip_ward[i]) + d[i].fixed_rows::<3>(0) * base_ward,
                    h[i].transpose() * (base_ward + loads[i]),
                ),
                None => (Vector3::zeros(), base_ward),
            };
            let u_second =
                translation(&tip_ward[p.second]) + d[p.second].fixed_rows::<3>(0) * a_second;
            let point = u_first * (1.0 - p.t) + u_second * p.t;
            let own = local[k];
            largest_violation =
                largest_violation.max(-(p.gap + p.free.x + p.frame.column(0).dot(&point)));
            let b = p.free + p.frame.transpose() * point - p.compliance * own;
            let updated = if frozen {
                normal_with_fixed_tangent(&p.compliance, &b, p.gap, &own, p.friction)
            } else {
                relax(
                    &own,
                    local_law(
                        &p.compliance,
                        p.compliance_inverse.as_ref(),
                        &b,
                        p.gap,
                        p.friction,
                    ),
                    settings.relaxation,
                    p.friction,
                )
            };
            let change = updated - own;
            if change != Vector3::zeros() {
                // Contact loads are forces: only the first three columns of D act on them.
                let df = p.frame * change;
                let df_second = df * p.t;
                loads[p.second] += force6(&df_second);
                let db_second = d[p.second].fixed_columns::<3>(0) * df_second;
                tip_ward[p.second] += db_second;
                if let Some(i) = p.first {
                    let df_first = df * (1.0 - p.t);
                    loads[i] += force6(&df_first);
                    tip_ward[i] += d[i].fixed_columns::<3>(0) * df_first + h[i] * db_second;
                }
            }
            local[k] = updated;
            largest_change = largest_change.max(change.norm());
            largest_force = largest_force.max(updated.norm());
        }
        sweep += 1;
        response.iterations = sweep;
        if settings.sweep_converged(largest_change, largest_force, largest_violation) {
            // Converged; with frozen friction only the normal forces are exact.
            response.converged = !frozen;
            break;
        }
        if sweep == budget && !with_friction {
            break;
        }
        if settings.polish && !frozen && (sweep % POLISH_EVERY == 0 || sweep == budget) {
            // Slow: contacts a fraction of a millimetre apart on a stiff wire are nearly
            // redundant, and Gauss–Seidel passes the load between them for hundreds of
            // sweeps. The active-set solve sets the normal forces exactly for the current
            // friction; the sweeps go on from there for the friction. After the last sweep
            // of the budget it is the answer (friction held), instead of a frozen phase.
            if polish_normals(flexibility, &prepared, &mut local) {
                reload(&prepared, &local, &mut loads);
                anderson = Anderson::new(settings.acceleration_depth, 3 * contacts.len());
                if sweep == budget {
                    response.polished = true;
                    break;
                }
                continue;
            }
        }
        if let Some(before) = before
            && anderson.mix(&before, &mut local)
        {
            for (p, l) in prepared.iter().zip(local.iter_mut()) {
                *l = project_on_cone(l, p.friction);
            }
            reload(&prepared, &local, &mut loads);
        }
    }
    if !response.converged && !response.polished && settings.polish {
        // Gauss–Seidel ran out of sweeps: solve the normal forces of the active set directly.
        if polish_normals(flexibility, &prepared, &mut local) {
            reload(&prepared, &local, &mut loads);
            response.polished = true;
        }
    }
    if local.iter().any(|l| !l.iter().all(|v| v.is_finite())) {
        // The step number is the caller's to fill in (`BeamModel::step_with_contacts` does).
        return Err(PhysicsError::Diverged {
            check: crate::error::DivergenceCheck::NonFinite("contact force"),
            node: 0,
            step: 0,
        });
    }
    response.forces = prepared
        .iter()
        .zip(&local)
        .map(|(p, l)| p.frame * l)
        .collect();
    response.local = local;
    response.nodal_loads = loads;
    Ok(response)
}

/// The brute-force reference: the explicit Delassus matrix `W = H K⁻¹ Hᵀ` from a dense
/// inverse of the stiffness `k_dense` (6N × 6N, unknown nodes), then projected Gauss–Seidel
/// with the same local law, in the same contact order. O(M²) per sweep, O(N³) to set up: for
/// tests only.
pub fn dense_reference(
    k_dense: &DMatrix<f64>,
    free: &[Vector6<f64>],
    contacts: &[Contact],
    settings: &ContactSettings,
) -> Result<ContactResponse> {
    let n = free.len();
    let k_inv = k_dense
        .clone()
        .try_inverse()
        .ok_or(PhysicsError::SingularBlock { node: 0 })?;
    let m = contacts.len();
    // H: 3M × 6N, rows in each contact's frame.
    let mut hm = DMatrix::<f64>::zeros(3 * m, 6 * n);
    for (k, c) in contacts.iter().enumerate() {
        let frame_t = c.frame().transpose();
        for (node, weight) in [
            (c.element.checked_sub(1), 1.0 - c.t),
            (Some(c.element), c.t),
        ] {
            if let Some(node) = node {
                for r in 0..3 {
                    for col in 0..3 {
                        hm[(3 * k + r, 6 * node + col)] += weight * frame_t[(r, col)];
                    }
                }
            }
        }
    }
    let w = &hm * &k_inv * hm.transpose();
    let u_free = DVector::from_iterator(6 * n, free.iter().flat_map(|v| v.iter().copied()));
    let delta_free = &hm * u_free;
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| {
        (contacts[a].element, contacts[a].t)
            .partial_cmp(&(contacts[b].element, contacts[b].t))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let mut lambda = DVector::<f64>::zeros(3 * m);
    let mut response = ContactResponse::default();
    for sweep in 0..settings.max_iterations.max(1) {
        let mut largest_change: f64 = 0.0;
        let mut largest_force: f64 = 0.0;
        for &k in &order {
            let wkk = w.fixed_view::<3, 3>(3 * k, 3 * k).into_owned();
            let own = Vector3::new(lambda[3 * k], lambda[3 * k + 1], lambda[3 * k + 2]);
            let row = w.rows(3 * k, 3);
            let total = row * &lambda;
            let b = Vector3::new(
                delta_free[3 * k] + total[0],
                delta_free[3 * k + 1] + total[1],
                delta_free[3 * k + 2] + total[2],
            ) - wkk * own;
            let c = &contacts[k];
            let updated = relax(
                &own,
                solve_local(&wkk, &b, c.gap, c.friction),
                settings.relaxation,
                c.friction,
            );
            largest_change = largest_change.max((updated - own).norm());
            largest_force = largest_force.max(updated.norm());
            lambda[3 * k] = updated.x;
            lambda[3 * k + 1] = updated.y;
            lambda[3 * k + 2] = updated.z;
        }
        response.iterations = sweep + 1;
        if largest_change <= (settings.tolerance * largest_force).max(settings.absolute_tolerance_n)
        {
            response.converged = true;
            break;
        }
    }
    response.local = (0..m)
        .map(|k| Vector3::new(lambda[3 * k], lambda[3 * k + 1], lambda[3 * k + 2]))
        .collect();
    response.forces = contacts
        .iter()
        .zip(&response.local)
        .map(|(c, l)| c.frame() * l)
        .collect();
    Ok(response)
}
