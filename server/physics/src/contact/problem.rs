//! The contact problem both solvers share: contacts, the solve's settings and response, the
//! per-contact data fixed during a solve (compliance, free motion, frame), the local
//! Signorini–Coulomb law, and the O(N) propagation helpers.

use nalgebra::{Matrix3, Matrix6, Vector2, Vector3, Vector6};

use crate::error::{PhysicsError, Result};
use crate::substructure::Flexibility;

/// One contact between the device and the vessel wall.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
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
    /// How far the device's material at the contact point has already moved this step before
    /// the solve (m, anatomy frame): the slide through the entry, which moves the material
    /// along the device's own path and so is not in the free motion. Its tangential part is
    /// sliding the friction law resists (Coulomb's law acts on the whole motion of the
    /// material past the wall, so a wire drawn round a bend feels the capstan law); its
    /// normal part is already in `gap`. Zero where nothing slid.
    #[serde(default)]
    pub slip: Vector3<f64>,
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
    /// Semismooth Newton on the Delassus matrix of the contacts that can push
    /// ([`super::newton`], [`super::newton_solve_observed`]): the set grown until no other
    /// contact is violated, each pass O(N + M + S²) to set up (S the set's nodes) and O(A³)
    /// an iteration (A the pushing contacts); Gauss–Seidel finishes a problem it does not
    /// converge on within [`ContactSettings::newton_iterations`].
    Newton,
    /// Projected Gauss–Seidel through the flexibility blocks, O(M + N) a sweep (the paper's
    /// Algorithm 3): the reference, and still the default (see docs/physics.md: on the
    /// bundled scenes Newton is not yet faster).
    #[default]
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
    /// Where a step's last detection round leaves the device past the wall by more than
    /// `penetration_tolerance_m`, move each penetrating element out along its contact's normal
    /// by its depth (positions only, no re-solve): the cheap way an overloaded step keeps the
    /// device inside the vessel, its strain corrected by the next step's solve. Single
    /// chains and merged stacks; the nested coupling (a reference mode) ignores it.
    pub project_penetration: bool,
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
            method: ContactMethod::GaussSeidel,
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
            project_penetration: false,
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
pub(crate) struct Prepared {
    /// Unknown index of the element's first node, if it is not the fixed base.
    pub(super) first: Option<usize>,
    /// Unknown index of the element's second node.
    pub(super) second: usize,
    pub(super) t: f64,
    pub(super) frame: Matrix3<f64>,
    /// Local 3×3 compliance in the contact frame.
    pub(super) compliance: Matrix3<f64>,
    /// Its inverse, where it has one.
    pub(super) compliance_inverse: Option<Matrix3<f64>>,
    /// Free displacement of the contact point in the contact frame.
    pub(super) free: Vector3<f64>,
    pub(super) gap: f64,
    pub(super) friction: f64,
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
pub(crate) fn prepare(
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
            // The slide already taken counts towards the tangential motion the law resists.
            let slip = frame.transpose() * c.slip;
            d = frame.transpose() * d + Vector3::new(0.0, slip.y, slip.z);
            Ok(Prepared {
                compliance_inverse: compliance.try_inverse(),
                first,
                second,
                t: c.t,
                frame,
                compliance,
                free: d,
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
        Some(s) if s.y.hypot(s.z) > 0.0 => Vector2::new(s.y, s.z).normalize(),
        _ => {
            let away = Vector2::new(-b.y, -b.z);
            let norm = away.norm();
            if norm > 0.0 {
                away / norm
            } else {
                Vector2::x()
            }
        }
    };
    // Fast path: Newton on the direction from the guess, steps capped at 0.5 rad. It finds the
    // sliding root in a few steps in all but about 1 in 20,000 cases, and every root it finds
    // is the one the bracket search below would (`newton_finds_most_slides_and_each_is_the_
    // searchs`: on random anisotropic coupled compliances the valid root was unique); where it
    // does not converge to a valid root within a quarter turn of the guess, the search runs.
    if let Some(force) = slide_by_newton(w, b, gap, mu, guess) {
        return force;
    }
    slide_by_search(w, b, gap, mu, guess).unwrap_or(Vector3::new(normal_only, 0.0, 0.0))
}

/// Angular samples of the bracket search over slip directions ([`slide_by_search`]).
const SLIDE_SAMPLES: i32 = 72;

/// The sliding force for slip direction `d` (unit, in the tangent plane): the normal force
/// from the normal equation, the tangential `μ λ_n d`. `None` where the normal equation has
/// no positive denominator.
fn sliding_force(
    w: &Matrix3<f64>,
    b: &Vector3<f64>,
    gap: f64,
    mu: f64,
    d: &Vector2<f64>,
) -> Option<Vector3<f64>> {
    let denominator = w[(0, 0)] + mu * (w[(0, 1)] * d.x + w[(0, 2)] * d.y);
    if denominator <= 0.0 {
        return None;
    }
    let lambda_n = -(b.x + gap) / denominator;
    Some(Vector3::new(
        lambda_n,
        mu * lambda_n * d.x,
        mu * lambda_n * d.y,
    ))
}

/// The sliding root by Newton's method on the slip direction, from `guess`: the force whose
/// slip `s = b + W λ` is anti-parallel to its tangential part, or `None` when Newton does not
/// converge to such a root within a quarter turn of the guess in 12 steps (the caller then
/// searches). Each step rotates the direction by `−f / f'` (capped at 0.5 rad), f = s × d.
pub(crate) fn slide_by_newton(
    w: &Matrix3<f64>,
    b: &Vector3<f64>,
    gap: f64,
    mu: f64,
    guess: Vector2<f64>,
) -> Option<Vector3<f64>> {
    let mut d = guess;
    for _ in 0..12 {
        let force = sliding_force(w, b, gap, mu, &d)?;
        if force.x <= 0.0 {
            return None;
        }
        // f(d) = s × d and its derivative along the rotation d' = d⊥.
        let p = Vector2::new(-d.y, d.x);
        let denominator = w[(0, 0)] + mu * (w[(0, 1)] * d.x + w[(0, 2)] * d.y);
        let lambda_n = force.x;
        let lambda_n_dot = -lambda_n * mu * (w[(0, 1)] * p.x + w[(0, 2)] * p.y) / denominator;
        let force_dot = Vector3::new(
            lambda_n_dot,
            mu * (lambda_n_dot * d.x + lambda_n * p.x),
            mu * (lambda_n_dot * d.y + lambda_n * p.y),
        );
        let slip = b + w * force;
        let slip_dot = w * force_dot;
        let f = slip.y * d.y - slip.z * d.x;
        let f_dot = slip_dot.y * d.y - slip_dot.z * d.x + slip.y * p.y - slip.z * p.x;
        if f == 0.0 || f_dot == 0.0 {
            let done = f == 0.0 && slip.y * d.x + slip.z * d.y <= 0.0;
            return (done && d.dot(&guess) > 0.0).then_some(force);
        }
        let step = (-f / f_dot).clamp(-0.5, 0.5);
        if !step.is_finite() {
            return None;
        }
        let (sin, cos) = step.sin_cos();
        d = (d * cos + p * sin).normalize();
        if step.abs() <= 1e-10 {
            let force = sliding_force(w, b, gap, mu, &d)?;
            let slip = b + w * force;
            let opposed = slip.y * d.x + slip.z * d.y <= 0.0;
            return (opposed && force.x > 0.0 && d.dot(&guess) > 0.0).then_some(force);
        }
    }
    None
}

/// The sliding root by a bracket search over slip directions outward from `guess` (the root
/// nearest it), each bracket refined by the Illinois method; `None` when no bracket holds one
/// (a tangential double root can slip between samples).
pub(crate) fn slide_by_search(
    w: &Matrix3<f64>,
    b: &Vector3<f64>,
    gap: f64,
    mu: f64,
    guess: Vector2<f64>,
) -> Option<Vector3<f64>> {
    let guess = guess.y.atan2(guess.x);
    let evaluate = |phi: f64| -> Option<(f64, f64, Vector3<f64>)> {
        let (dy, dz) = (phi.cos(), phi.sin());
        let force = sliding_force(w, b, gap, mu, &Vector2::new(dy, dz))?;
        let slip = b + w * force;
        Some((slip.y * dz - slip.z * dy, slip.y * dy + slip.z * dz, force))
    };
    let step = std::f64::consts::TAU / SLIDE_SAMPLES as f64;
    // Search brackets outward from the guess (k = 0, +1, −1, +2, …), so the first valid root
    // is the one nearest the sticking direction; refine it by the Illinois method.
    for k in 0..SLIDE_SAMPLES {
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
            return Some(force);
        }
    }
    None
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

/// Adds the nodal loads of contact forces `local` into `loads`.
pub(crate) fn accumulate_loads(
    prepared: &[Prepared],
    local: &[Vector3<f64>],
    loads: &mut [Vector6<f64>],
) {
    for (p, l) in prepared.iter().zip(local) {
        add_point_load(loads, p.second, p.t, &(p.frame * l));
    }
}

/// The nodal loads (one per unknown node, `unknowns` of them) of forces `local` (each in its
/// contact's frame, N) on `contacts`.
pub(crate) fn contact_loads(
    contacts: &[Contact],
    local: &[Vector3<f64>],
    unknowns: usize,
) -> Vec<Vector6<f64>> {
    let mut loads = vec![Vector6::zeros(); unknowns];
    for (c, l) in contacts.iter().zip(local) {
        add_point_load(&mut loads, c.element, c.t, &(c.frame() * l));
    }
    loads
}

/// Adds force `f` (N) at parameter `t` of element `element` into `loads` (per unknown node:
/// the element's second node is unknown `element`, its first `element − 1`, none for the
/// driven base), shared between the two nodes linearly.
fn add_point_load(loads: &mut [Vector6<f64>], element: usize, t: f64, f: &Vector3<f64>) {
    loads[element] += force6(&(f * t));
    if let Some(i) = element.checked_sub(1) {
        loads[i] += force6(&(f * (1.0 - t)));
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

/// Newton iterations a contact solve may take by default before Gauss–Seidel takes over.
pub const NEWTON_ITERATIONS: usize = 25;

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A random symmetric positive-definite 3×3 compliance (m/N): `A Aᵀ + ε I`, anisotropic and
    /// with normal–tangential coupling.
    fn compliance(entries: [f64; 9], epsilon: f64) -> Matrix3<f64> {
        let a = Matrix3::from_row_slice(&entries);
        (a * a.transpose() + Matrix3::identity() * epsilon) * 1e-3
    }

    proptest! {
        #![proptest_config(ProptestConfig { max_global_rejects: 100_000, ..ProptestConfig::with_cases(2000) })]

        /// Where Newton's fast path finds a sliding root it is the bracket search's (the
        /// search is the reference: Illinois-refined brackets outward from the same guess),
        /// and the slip opposes the tangential force. Sliding cases only, guessed from the
        /// sticking force as `local_law` does (where the valid root is unique, as it was on
        /// every case tried; Newton accepts any valid root within a quarter turn).
        #[test]
        fn newtons_sliding_root_is_the_bracket_searchs(
            entries in proptest::array::uniform9(-1.0f64..1.0),
            epsilon in 0.01f64..1.0,
            b in proptest::array::uniform3(-1e-3f64..1e-3),
            gap in -1e-4f64..1e-4,
            mu in 0.02f64..1.0,
        ) {
            let w = compliance(entries, epsilon);
            let b = Vector3::from(b);
            let stick = w.try_inverse().unwrap() * (Vector3::new(-gap, 0.0, 0.0) - b);
            let tangential = stick.y.hypot(stick.z);
            prop_assume!(-(b.x + gap) / w[(0, 0)] > 0.0);
            prop_assume!(!(stick.x > 0.0 && tangential <= mu * stick.x) && tangential > 0.0);
            let guess = Vector2::new(stick.y, stick.z).normalize();
            let Some(newton) = slide_by_newton(&w, &b, gap, mu, guess) else {
                return Ok(());
            };
            let slip = b + w * newton;
            // Where the search finds a root it is Newton's; where it finds none (its brackets
            // can step over a root: a seeded CI run found one), Newton's must still be a
            // sliding root by definition: the gap closed, on the cone (the slip's direction
            // is checked below for both).
            match slide_by_search(&w, &b, gap, mu, guess) {
                Some(search) => prop_assert!(
                    (newton - search).norm() <= 1e-9 * newton.norm(),
                    "Newton {newton:?} vs search {search:?}"
                ),
                None => {
                    prop_assert!(newton.x > 0.0, "Newton {newton:?}: not pushing");
                    prop_assert!(
                        (slip.x + gap).abs() <= 1e-9 * gap.abs().max(b.norm()),
                        "Newton {newton:?}: the gap left {}", slip.x + gap
                    );
                    prop_assert!(
                        (newton.y.hypot(newton.z) - mu * newton.x).abs() <= 1e-9 * newton.x,
                        "Newton {newton:?}: off the cone"
                    );
                }
            }
            let tangential = Vector2::new(newton.y, newton.z);
            let slip_t = Vector2::new(slip.y, slip.z);
            let cross = slip_t.x * tangential.y - slip_t.y * tangential.x;
            prop_assert!(cross.abs() <= 1e-9 * slip_t.norm() * tangential.norm() + 1e-18);
            prop_assert!(slip_t.dot(&tangential) <= 1e-18);
        }
    }

    /// Over 20,000 seeded sliding cases (anisotropic, coupled compliances; the guess is the
    /// sticking force's direction as `local_law` takes it), Newton finds the root in most and
    /// every root it finds is the search's.
    #[test]
    fn newton_finds_most_slides_and_each_is_the_searchs() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut uniform = |lo: f64, hi: f64| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            lo + (hi - lo) * (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut sliding, mut found) = (0, 0);
        while sliding < 20_000 {
            let entries: [f64; 9] = std::array::from_fn(|_| uniform(-1.0, 1.0));
            let w = compliance(entries, uniform(0.01, 1.0));
            let b = Vector3::new(
                uniform(-1e-3, 1e-3),
                uniform(-1e-3, 1e-3),
                uniform(-1e-3, 1e-3),
            );
            let (gap, mu) = (uniform(-1e-4, 1e-4), uniform(0.02, 1.0));
            let stick = w.try_inverse().unwrap() * (Vector3::new(-gap, 0.0, 0.0) - b);
            if -(b.x + gap) / w[(0, 0)] <= 0.0
                || (stick.x > 0.0 && stick.y.hypot(stick.z) <= mu * stick.x)
                || stick.y.hypot(stick.z) == 0.0
            {
                continue;
            }
            sliding += 1;
            let guess = Vector2::new(stick.y, stick.z).normalize();
            if let Some(newton) = slide_by_newton(&w, &b, gap, mu, guess) {
                found += 1;
                let search = slide_by_search(&w, &b, gap, mu, guess).expect("a root");
                assert!(
                    (newton - search).norm() <= 1e-9 * newton.norm(),
                    "Newton {newton:?} vs search {search:?} (w {w:?}, b {b:?}, gap {gap}, mu {mu})"
                );
            }
        }
        println!("Newton found {found} of {sliding} sliding roots");
        assert!(
            found * 10 >= sliding * 9,
            "Newton found only {found} of {sliding}"
        );
    }

    /// The fast path is not dead: on an anisotropic compliance with coupling (where the old
    /// fixed-point iteration on the direction failed) it finds the root itself.
    #[test]
    fn newton_takes_an_anisotropic_slide_without_the_search() {
        let w = Matrix3::new(2.0, 0.3, -0.2, 0.3, 5.0, 1.5, -0.2, 1.5, 1.0) * 1e-3;
        let b = Vector3::new(-2e-4, 3e-4, -1e-4);
        let mu = 0.1;
        let stick: Vector3<f64> = w.try_inverse().unwrap() * (Vector3::zeros() - b);
        assert!(stick.y.hypot(stick.z) > mu * stick.x, "the case slides");
        let guess = Vector2::new(stick.y, stick.z).normalize();
        let newton = slide_by_newton(&w, &b, 0.0, mu, guess).expect("Newton converges");
        let search = slide_by_search(&w, &b, 0.0, mu, guess).unwrap();
        assert!((newton - search).norm() <= 1e-9 * newton.norm());
    }
}
