//! The contact problem both solvers share: contacts, the solve's settings and response, the
//! per-contact data fixed during a solve (compliance, free motion, frame), the local
//! Signorini–Coulomb law, and the O(N) propagation helpers.

use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};

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

/// Adds the nodal loads of contact forces `local` into `loads`.
pub(crate) fn accumulate_loads(
    prepared: &[Prepared],
    local: &[Vector3<f64>],
    loads: &mut [Vector6<f64>],
) {
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

/// Newton iterations a contact solve may take by default before Gauss–Seidel takes over.
pub const NEWTON_ITERATIONS: usize = 25;
