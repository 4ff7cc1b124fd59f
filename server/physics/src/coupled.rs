//! Contact between chains: Gauss–Seidel over contacts that join two beam chains (an inner
//! instrument against the lumen of the one around it) as well as contacts of one chain with
//! the wall, each chain keeping its own O(N) flexibility propagation.
//!
//! A contact acts `+R λ` on its first side and `−R λ` on its second (if any), `R = [n t1 t2]`;
//! its gap closes with the relative displacement `n · (δ₁ − δ₂)`. The chains are independent
//! but for the contacts, so the Delassus block of a contact is the sum of both sides'
//! compliances, `W = Rᵀ (H₁ K₁⁻¹ H₁ᵀ + H₂ K₂⁻¹ H₂ᵀ) R` — for the normal, the issue's
//! `nᵀ (K₁⁻¹ + K₂⁻¹) n` — and the displacement each side sees comes from that chain's
//! propagation `u_i = B_i + D_i A_i` (see [`crate::contact`]). Contacts are swept in the order
//! given (along the path); a chain whose contacts come out of order along it restarts its
//! base-ward accumulation (O(N)), so any order is exact and the coaxial order is O(M + N) per
//! sweep. Projected Gauss–Seidel with the same local Coulomb law, Anderson acceleration and
//! frozen-friction second phase as [`crate::contact::gauss_seidel()`].

use nalgebra::{Matrix3, Vector3, Vector6};

use crate::contact::{
    Anderson, ContactSettings, active_set_normals, force6, local_law, normal_with_fixed_tangent,
    perpendicular, project_on_cone, relax, tip_ward_pass, top_left, translation,
};
use crate::error::{PhysicsError, Result};
use crate::substructure::Flexibility;

/// Active-set solves at most after Gauss–Seidel runs out of sweeps, each after turning the
/// lumen contacts' normals to where their points settled.
const LUMEN_POLISH_PASSES: usize = 6;
/// The passes stop when every active lumen point is on its circle to this fraction of the
/// clearance.
const LUMEN_POLISH_TOLERANCE: f64 = 1e-3;

/// Where a contact acts on one chain: between model nodes `element` and `element + 1` of
/// chain `chain`, at parameter `t` ∈ [0, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChainPoint {
    /// Chain index.
    pub chain: usize,
    /// Element index on that chain.
    pub element: usize,
    /// Position along the element (0 at node `element`, 1 at node `element + 1`).
    pub t: f64,
}

/// A contact on one chain (against a fixed wall) or between two chains.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoupledContact {
    /// The side the normal force pushes along `normal`.
    pub first: ChainPoint,
    /// The side pushed the other way; `None` for a wall.
    pub second: Option<ChainPoint>,
    /// Unit normal: the direction the contact pushes the first side.
    pub normal: Vector3<f64>,
    /// Current gap (m); negative when penetrating.
    pub gap: f64,
    /// Coulomb friction coefficient.
    pub friction: f64,
    /// For a point inside a lumen, the lumen's geometry: the solver then keeps the exact
    /// circular constraint, solving the contact's force and normal together at every visit
    /// (`lumen_solve`), instead of holding the half-plane of the detected normal.
    pub lumen: Option<Lumen>,
}

/// The lumen a contact's first side lies in (its second side is the lumen's centre line).
///
/// The constraint is `‖x‖ ≤ clearance` with `x = across − (δ₁ − δ₂)⊥` the offset of the point
/// from the centre line after the step (⊥: across `axis`). A fixed normal only keeps
/// `n · x ≤ clearance`, which lets the point slide round the lumen and out by `d² / 2c` for a
/// slide `d`: a 20 µm slide in a 38 µm clearance (a 0.035" wire in a 5 F catheter) is 5 µm
/// out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lumen {
    /// Unit tangent of the lumen's centre line at the contact.
    pub axis: Vector3<f64>,
    /// From the point to the lumen's centre line, across `axis`, now (m).
    pub across: Vector3<f64>,
    /// Radial clearance: the lumen's radius less the inner instrument's (m).
    pub clearance: f64,
}

impl Lumen {
    /// The part of `v` across the lumen's axis.
    pub fn across_axis(&self, v: &Vector3<f64>) -> Vector3<f64> {
        v - self.axis * self.axis.dot(v)
    }

    /// The point's offset from the centre line (m) after a relative displacement `moved`
    /// (m) of its sides: `across − moved⊥`.
    pub fn offset(&self, moved: &Vector3<f64>) -> Vector3<f64> {
        self.across - self.across_axis(moved)
    }
}

impl CoupledContact {
    /// The contact frame `[n t1 t2]`: tangents chosen as for a wall contact, or for a lumen
    /// contact `t2` along the lumen (its friction acts only there) and `t1` round it.
    pub fn frame(&self) -> Matrix3<f64> {
        frame_of(&self.normal, self.lumen.as_ref().map(|l| &l.axis))
    }

    /// The relative displacement `δ₁ − δ₂` of the contact's sides under per-chain node
    /// `increments` (unknown nodes: model node 0, the base, does not move).
    pub fn relative_displacement(&self, increments: &[Vec<Vector6<f64>>]) -> Vector3<f64> {
        let at = |p: &ChainPoint| {
            crate::contact::point_displacement(&increments[p.chain], p.element, p.t)
        };
        at(&self.first) - self.second.as_ref().map_or(Vector3::zeros(), at)
    }
}

/// The frame `[n t1 t2]` of a contact with normal `n`, in a lumen along `axis` if any.
fn frame_of(n: &Vector3<f64>, axis: Option<&Vector3<f64>>) -> Matrix3<f64> {
    let along = axis
        .map(|a| a - n * n.dot(a))
        .filter(|a| a.norm() > 1e-6)
        .map(|a| a.normalize());
    let (t1, t2) = match along {
        Some(a) => (a.cross(n), a),
        None => {
            let t1 = perpendicular(n);
            (t1, n.cross(&t1))
        }
    };
    Matrix3::from_columns(&[*n, t1, t2])
}

/// The exact local solve of a lumen contact: the force `f` (world, N) on the point and the
/// normal it acts along, given the contact's relative compliance `w` (world, m/N) and the
/// relative displacement `without` (m) it would have under every other force.
///
/// The offset from the centre line is `x(f) = x₀ − P w f` (P: across the axis). Where
/// `‖x₀‖ ≤ c` the contact is open. Otherwise the radial force is `α u` along the settled
/// offset's direction `u = x / c`, so `(I + (α/c) A) x = x₀` with `A = P w P` (2×2, symmetric
/// positive): `‖x(α)‖` falls monotonically in α and Newton from α = 0 (convex, decreasing)
/// finds `‖x‖ = c` ([`radial_solve`]). Friction acts along the lumen only. Sticking (no
/// axial slip) is tried first, exactly: the axial force that cancels the slip is eliminated,
/// which leaves the radial problem on the Schur complement `w − (w a)(w a)ᵀ / aᵀw a`. If that
/// force lies outside `μ α`, the contact slides on the cone's edge, `t = s μ α`, and the
/// settled normal is `u(α) = (c I + α A)⁻¹ (x₀ − α s μ P w a)` with `‖u(α)‖ = 1`, a scalar
/// equation solved by bisection.
fn lumen_solve(
    w: &Matrix3<f64>,
    without: &Vector3<f64>,
    lumen: &Lumen,
    mu: f64,
) -> (Vector3<f64>, Vector3<f64>) {
    let a = lumen.axis;
    let (e1, e2) = {
        let e1 = perpendicular(&a);
        (e1, a.cross(&e1))
    };
    let basis = nalgebra::Matrix3x2::from_columns(&[e1, e2]);
    let c = lumen.clearance;
    let x0 = basis.transpose() * (lumen.across - without);
    let fallback = if x0.norm() > 0.0 {
        basis * x0.normalize()
    } else {
        e1
    };
    if x0.norm() <= c {
        // Open: no radial force, hence no friction either.
        return (fallback, Vector3::zeros());
    }
    let wa = w * a;
    let waa = a.dot(&wa);
    if mu == 0.0 || waa <= 0.0 {
        let (normal, alpha) = radial_solve(w, without, lumen, &basis, fallback);
        return (normal, normal * alpha);
    }
    // Sticking: the axial force t = −aᵀ(without + w u α) / aᵀw a cancels the slip.
    let stuck = w - wa * wa.transpose() / waa;
    let stuck_without = without - wa * (a.dot(without) / waa);
    let (normal, alpha) = radial_solve(&stuck, &stuck_without, lumen, &basis, fallback);
    let axial = -a.dot(&(without + w * (normal * alpha))) / waa;
    if axial.abs() <= mu * alpha {
        return (normal, normal * alpha + a * axial);
    }
    // Sliding on the cone's edge, t = s μ α: find α with ‖u(α)‖ = 1.
    let drift = basis.transpose() * wa * (axial.signum() * mu);
    let plane = basis.transpose() * w * basis;
    let direction = |alpha: f64| -> Option<nalgebra::Vector2<f64>> {
        (nalgebra::Matrix2::identity() * c + plane * alpha)
            .lu()
            .solve(&(x0 - drift * alpha))
    };
    let excess = |alpha: f64| direction(alpha).map_or(f64::NAN, |u| u.norm() - 1.0);
    // ‖u(0)‖ = ‖x₀‖ / c > 1 (the contact is closed); widen until it falls below 1.
    let frictionless = radial_solve(w, without, lumen, &basis, fallback);
    let scale = [alpha, frictionless.1]
        .into_iter()
        .filter(|s| s.is_finite())
        .fold(f64::MIN_POSITIVE, f64::max);
    let (mut lo, mut hi) = (0.0, scale);
    let mut bracketed = false;
    // Doubling from the smallest positive float reaches the largest in about 2,100 steps.
    for _ in 0..2200 {
        let e = excess(hi);
        if e <= 0.0 {
            bracketed = true;
            break;
        }
        if !e.is_finite() {
            break;
        }
        lo = hi;
        hi *= 2.0;
    }
    if !bracketed {
        // No sliding state on the circle: keep the frictionless radial force.
        let (normal, alpha) = frictionless;
        return (normal, normal * alpha);
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if excess(mid) > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let alpha = hi;
    let normal = match direction(alpha) {
        Some(u) if u.norm() > 0.0 => basis * u.normalize(),
        _ => fallback,
    };
    (normal, normal * alpha + a * (axial.signum() * mu * alpha))
}

/// The frictionless radial solve of a lumen contact with compliance `w` (m/N) and relative
/// displacement `without` (m): the unit normal (world) across the lumen and the force α ≥ 0
/// (N) along it that settles the offset on the circle of radius `lumen.clearance`, or α = 0
/// and the offset's own direction (`fallback` at the centre) where it is already inside.
fn radial_solve(
    w: &Matrix3<f64>,
    without: &Vector3<f64>,
    lumen: &Lumen,
    basis: &nalgebra::Matrix3x2<f64>,
    fallback: Vector3<f64>,
) -> (Vector3<f64>, f64) {
    let c = lumen.clearance;
    let x0 = basis.transpose() * (lumen.across - without);
    let eigen = nalgebra::SymmetricEigen::new(basis.transpose() * w * basis);
    // The offset without radial force, in the eigenbasis of A.
    let y = eigen.eigenvectors.transpose() * x0;
    let lambda = eigen.eigenvalues.map(|l| l.max(0.0));
    let settled = |alpha: f64| {
        nalgebra::Vector2::new(
            y[0] / (1.0 + alpha * lambda[0] / c),
            y[1] / (1.0 + alpha * lambda[1] / c),
        )
    };
    let mut alpha: f64 = 0.0;
    if x0.norm() > c {
        for _ in 0..100 {
            // ‖x(α)‖ − c is convex and decreasing: Newton from the left never overshoots.
            let z = settled(alpha);
            let n = z.norm();
            let d = -(z[0] * z[0] * lambda[0] / (1.0 + alpha * lambda[0] / c)
                + z[1] * z[1] * lambda[1] / (1.0 + alpha * lambda[1] / c))
                / (c * n);
            if n - c <= 1e-12 * c || d >= 0.0 {
                break;
            }
            alpha -= (n - c) / d;
        }
    }
    let x = eigen.eigenvectors * settled(alpha);
    let n = x.norm();
    (if n > 0.0 { basis * (x / n) } else { fallback }, alpha)
}

/// The solved forces of a coupled contact problem.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CoupledResponse {
    /// Per contact: (normal, tangent 1, tangent 2) force on the first side, its frame (N).
    pub local: Vec<Vector3<f64>>,
    /// Per chain, per unknown node: the contact load (force N; moments zero).
    pub nodal_loads: Vec<Vec<Vector6<f64>>>,
    /// Sweeps performed.
    pub iterations: usize,
    /// Whether the tolerance was met with the full Coulomb law.
    pub converged: bool,
    /// Whether the normal forces were finished by the active-set solve after Gauss–Seidel ran
    /// out of sweeps (`ContactSettings::polish`).
    pub polished: bool,
    /// Per contact: the normal its forces are given in (a lumen contact's, turned towards the
    /// solved offset) and the gap along it (m).
    pub normals: Vec<(Vector3<f64>, f64)>,
}

/// One side of a contact with its fixed data.
#[derive(Debug, Clone, Copy)]
struct Side {
    chain: usize,
    /// Unknown index of the element's first node, if it is not the base.
    first: Option<usize>,
    second: usize,
    t: f64,
    /// +1 on the first side, −1 on the second.
    sign: f64,
}

/// The running propagation state of one chain.
struct ChainState<'a> {
    flexibility: &'a Flexibility,
    loads: Vec<Vector6<f64>>,
    tip_ward: Vec<Vector6<f64>>,
    cursor: usize,
    base_ward: Vector6<f64>,
}

impl<'a> ChainState<'a> {
    fn new(flexibility: &'a Flexibility) -> Self {
        let n = flexibility.diagonal.len();
        Self {
            flexibility,
            loads: vec![Vector6::zeros(); n],
            tip_ward: vec![Vector6::zeros(); n],
            cursor: 0,
            base_ward: Vector6::zeros(),
        }
    }

    fn restart(&mut self) {
        tip_ward_pass(self.flexibility, &self.loads, &mut self.tip_ward);
        self.cursor = 0;
        self.base_ward = Vector6::zeros();
    }

    /// Translation of the side's point under the current loads.
    fn displacement(&mut self, side: &Side) -> Vector3<f64> {
        let window = side.first.unwrap_or(side.second);
        if window < self.cursor {
            self.restart();
        }
        let (d, h) = (&self.flexibility.diagonal, &self.flexibility.coupling);
        while self.cursor < window {
            self.base_ward =
                h[self.cursor].transpose() * (self.base_ward + self.loads[self.cursor]);
            self.cursor += 1;
        }
        let (u_first, a_second) = match side.first {
            Some(i) => (
                translation(&self.tip_ward[i]) + d[i].fixed_rows::<3>(0) * self.base_ward,
                h[i].transpose() * (self.base_ward + self.loads[i]),
            ),
            None => (Vector3::zeros(), self.base_ward),
        };
        let u_second =
            translation(&self.tip_ward[side.second]) + d[side.second].fixed_rows::<3>(0) * a_second;
        u_first * (1.0 - side.t) + u_second * side.t
    }

    /// Adds world force `df` at the side's point, patching the tip-ward part locally.
    fn add(&mut self, side: &Side, df: &Vector3<f64>) {
        let (d, h) = (&self.flexibility.diagonal, &self.flexibility.coupling);
        let df_second = df * side.t;
        self.loads[side.second] += force6(&df_second);
        let db_second = d[side.second].fixed_columns::<3>(0) * df_second;
        self.tip_ward[side.second] += db_second;
        if let Some(i) = side.first {
            let df_first = df * (1.0 - side.t);
            self.loads[i] += force6(&df_first);
            self.tip_ward[i] += d[i].fixed_columns::<3>(0) * df_first + h[i] * db_second;
        }
    }
}

/// Local compliance (world frame, translations) and free displacement of a side.
fn side_data(
    flexibility: &Flexibility,
    free: &[Vector6<f64>],
    side: &Side,
) -> (Matrix3<f64>, Vector3<f64>) {
    let (a, b) = (1.0 - side.t, side.t);
    let d = &flexibility.diagonal;
    let mut w = top_left(&d[side.second]) * (b * b);
    let mut delta = translation(&free[side.second]) * b;
    if let Some(i) = side.first {
        let cross = top_left(&(flexibility.coupling[i] * d[side.second]));
        w += top_left(&d[i]) * (a * a) + (cross + cross.transpose()) * (a * b);
        delta += translation(&free[i]) * a;
    }
    (w, delta * side.sign)
}

/// A contact's prepared data.
#[derive(Clone)]
struct Prepared {
    sides: Vec<Side>,
    /// `[n t1 t2]`.
    frame: Matrix3<f64>,
    /// Compliance of the relative displacement (world frame).
    world: Matrix3<f64>,
    /// Compliance in the contact frame, and its inverse.
    compliance: Matrix3<f64>,
    inverse: Option<Matrix3<f64>>,
    /// Free relative displacement (world), and in the contact frame.
    delta: Vector3<f64>,
    free_local: Vector3<f64>,
    gap: f64,
}

impl Prepared {
    /// Sets the normal (and gap) the contact works along.
    fn turn(&mut self, normal: Vector3<f64>, gap: f64, lumen: Option<&Lumen>) {
        self.frame = frame_of(&normal, lumen.map(|l| &l.axis));
        self.compliance = self.frame.transpose() * self.world * self.frame;
        self.inverse = self.compliance.try_inverse();
        self.free_local = self.frame.transpose() * self.delta;
        self.gap = gap;
    }

    /// Turns a lumen contact to work along `normal` (unit, across the lumen): the gap along
    /// it is the clearance less the point's present offset.
    fn turn_in_lumen(&mut self, normal: Vector3<f64>, lumen: &Lumen) {
        self.turn(
            normal,
            lumen.clearance - normal.dot(&lumen.across),
            Some(lumen),
        );
    }
}

/// Sets every chain's loads to the contacts' forces `local` (their frames).
fn load_all(chains: &mut [ChainState], prepared: &[Prepared], local: &[Vector3<f64>]) {
    for chain in chains.iter_mut() {
        chain.loads.iter_mut().for_each(|l| l.fill(0.0));
    }
    for (p, l) in prepared.iter().zip(local) {
        for side in &p.sides {
            chains[side.chain].add(side, &(p.frame * l * side.sign));
        }
    }
}

/// Every contact's relative displacement (world, m) under contact forces `local` (their
/// frames), by one propagation per chain in the contacts' order.
fn relative_displacements(
    prepared: &[Prepared],
    flexibilities: &[&Flexibility],
    local: &[Vector3<f64>],
) -> Vec<Vector3<f64>> {
    let mut chains: Vec<ChainState> = flexibilities.iter().map(|f| ChainState::new(f)).collect();
    load_all(&mut chains, prepared, local);
    chains.iter_mut().for_each(ChainState::restart);
    prepared
        .iter()
        .map(|p| {
            p.sides
                .iter()
                .map(|side| chains[side.chain].displacement(side) * side.sign)
                .sum()
        })
        .collect()
}

/// Every contact's normal relative displacement (m) under contact forces `local`.
fn normal_displacements(
    prepared: &[Prepared],
    flexibilities: &[&Flexibility],
    local: &[Vector3<f64>],
) -> Vec<f64> {
    relative_displacements(prepared, flexibilities, local)
        .iter()
        .zip(prepared)
        .map(|(u, p)| p.frame.column(0).dot(u))
        .collect()
}

/// Solves the coupled contact problem by projected Gauss–Seidel, sweeping the contacts in the
/// order given. `flexibilities[c]` and `free[c]` are chain `c`'s flexibility blocks and free
/// increment per unknown node; `warm_start` (local forces per contact) speeds up repeated
/// solves.
pub fn coupled_gauss_seidel(
    flexibilities: &[&Flexibility],
    free: &[&[Vector6<f64>]],
    contacts: &[CoupledContact],
    settings: &ContactSettings,
    warm_start: Option<&[Vector3<f64>]>,
) -> Result<CoupledResponse> {
    if free.len() != flexibilities.len() {
        return Err(PhysicsError::LengthMismatch {
            what: "free increments per chain",
            expected: flexibilities.len(),
            actual: free.len(),
        });
    }
    for (f, u) in flexibilities.iter().zip(free) {
        if u.len() != f.diagonal.len() {
            return Err(PhysicsError::LengthMismatch {
                what: "free displacement per unknown node",
                expected: f.diagonal.len(),
                actual: u.len(),
            });
        }
    }
    // Per contact: its sides, frame, compliance (its frame) and free displacement.
    let mut prepared: Vec<Prepared> = Vec::with_capacity(contacts.len());
    for (k, c) in contacts.iter().enumerate() {
        let finite = c.gap.is_finite()
            && c.friction.is_finite()
            && c.friction >= 0.0
            && (c.normal.norm() - 1.0).abs() <= 1e-6;
        if !finite {
            return Err(PhysicsError::OutOfRange {
                what: format!("coupled contact {k} (gap, friction, unit normal)"),
                range: "finite gap, friction >= 0, a unit normal",
                value: c.gap,
            });
        }
        let mut sides = Vec::with_capacity(2);
        for (point, sign) in [(Some(c.first), 1.0), (c.second, -1.0)] {
            let Some(p) = point else { continue };
            let chain = flexibilities
                .get(p.chain)
                .ok_or(PhysicsError::LengthMismatch {
                    what: "contact chain index (must be < chain count)",
                    expected: flexibilities.len(),
                    actual: p.chain,
                })?;
            if p.element >= chain.diagonal.len() || !(0.0..=1.0).contains(&p.t) {
                return Err(PhysicsError::OutOfRange {
                    what: format!("coupled contact {k}: element {} at t", p.element),
                    range: "an element of the chain, 0 <= t <= 1",
                    value: p.t,
                });
            }
            sides.push(Side {
                chain: p.chain,
                first: p.element.checked_sub(1),
                second: p.element,
                t: p.t,
                sign,
            });
        }
        if sides.len() == 2 && sides[0].chain == sides[1].chain {
            return Err(PhysicsError::Stack(format!(
                "coupled contact {k} joins chain {} to itself",
                sides[0].chain
            )));
        }
        if let Some(l) = c.lumen {
            let fine = l.clearance.is_finite()
                && l.clearance >= 0.0
                && l.across.iter().all(|v| v.is_finite())
                && (l.axis.norm() - 1.0).abs() <= 1e-6
                && sides.len() == 2;
            if !fine {
                return Err(PhysicsError::OutOfRange {
                    what: format!(
                        "coupled contact {k}: lumen (axis, offset, clearance, two sides)"
                    ),
                    range: "a unit axis, a finite offset, clearance >= 0, between two chains",
                    value: l.clearance,
                });
            }
        }
        let mut w = Matrix3::zeros();
        let mut delta = Vector3::zeros();
        for side in &sides {
            let (ws, ds) = side_data(flexibilities[side.chain], free[side.chain], side);
            w += ws;
            delta += ds;
        }
        let mut p = Prepared {
            sides,
            frame: Matrix3::identity(),
            world: w,
            compliance: Matrix3::identity(),
            inverse: None,
            delta,
            free_local: Vector3::zeros(),
            gap: c.gap,
        };
        p.turn(c.normal, c.gap, c.lumen.as_ref());
        prepared.push(p);
    }
    let mut local: Vec<Vector3<f64>> = match warm_start {
        Some(w) if w.len() == contacts.len() => w.to_vec(),
        _ => vec![Vector3::zeros(); contacts.len()],
    };
    let mut chains: Vec<ChainState> = flexibilities.iter().map(|f| ChainState::new(f)).collect();
    load_all(&mut chains, &prepared, &local);
    let with_friction = contacts.iter().any(|c| c.friction > 0.0);
    let budget = settings.max_iterations.max(1);
    let mut response = CoupledResponse::default();
    let mut anderson = Anderson::new(settings.acceleration_depth, 3 * contacts.len());
    let mut sweep = 0;
    while sweep < if with_friction { 2 * budget } else { budget } {
        let frozen = sweep >= budget;
        if sweep == budget {
            anderson = Anderson::new(settings.acceleration_depth, 3 * contacts.len());
        }
        // Anderson mixes world-frame forces: a lumen contact's frame turns between sweeps.
        let world = |prepared: &[Prepared], local: &[Vector3<f64>]| -> Vec<Vector3<f64>> {
            prepared
                .iter()
                .zip(local)
                .map(|(p, l)| p.frame * l)
                .collect()
        };
        let before = anderson.active().then(|| world(&prepared, &local));
        chains.iter_mut().for_each(ChainState::restart);
        let mut largest_change: f64 = 0.0;
        let mut largest_force: f64 = 0.0;
        let mut largest_violation: f64 = 0.0;
        for (k, p) in prepared.iter_mut().enumerate() {
            let c = &contacts[k];
            let mut relative = Vector3::zeros();
            for side in &p.sides {
                relative += chains[side.chain].displacement(side) * side.sign;
            }
            // A lumen contact is solved exactly on its circle: the force, its normal (towards
            // where the point settles) and the axial friction together.
            let exact = c.lumen.as_ref().filter(|_| !frozen).map(|lumen| {
                let own_world = p.frame * local[k];
                let without = p.delta + relative - p.world * own_world;
                let (normal, force) = lumen_solve(&p.world, &without, lumen, c.friction);
                p.turn_in_lumen(normal, lumen);
                local[k] = p.frame.transpose() * own_world;
                p.frame.transpose() * force
            });
            let own = local[k];
            let total = p.free_local + p.frame.transpose() * relative;
            largest_violation = largest_violation.max(-(p.gap + total.x));
            let b = total - p.compliance * own;
            let updated = if frozen {
                normal_with_fixed_tangent(&p.compliance, &b, p.gap, &own, c.friction)
            } else if let Some(exact) = exact {
                let mut updated = relax(&own, exact, settings.relaxation, c.friction);
                updated.y = 0.0;
                updated
            } else {
                relax(
                    &own,
                    local_law(&p.compliance, p.inverse.as_ref(), &b, p.gap, c.friction),
                    settings.relaxation,
                    c.friction,
                )
            };
            let change = updated - own;
            if change != Vector3::zeros() {
                let df = p.frame * change;
                for side in &p.sides {
                    chains[side.chain].add(side, &(df * side.sign));
                }
            }
            local[k] = updated;
            largest_change = largest_change.max(change.norm());
            largest_force = largest_force.max(updated.norm());
        }
        sweep += 1;
        response.iterations = sweep;
        if settings.sweep_converged(largest_change, largest_force, largest_violation) {
            response.converged = !frozen;
            break;
        }
        if sweep == budget && !with_friction {
            break;
        }
        let mut mixed = before.as_ref().map(|_| world(&prepared, &local));
        if let (Some(before), Some(mixed)) = (before, mixed.as_mut())
            && anderson.mix(&before, mixed)
        {
            // The mixed iterate, projected on the cones, with every chain's loads rebuilt.
            for (((c, p), l), f) in contacts
                .iter()
                .zip(&prepared)
                .zip(local.iter_mut())
                .zip(mixed.iter())
            {
                let mut mixed = p.frame.transpose() * f;
                if c.lumen.is_some() {
                    mixed.y = 0.0;
                }
                *l = project_on_cone(&mixed, c.friction);
            }
            load_all(&mut chains, &prepared, &local);
        }
    }
    if !response.converged && settings.polish && !contacts.is_empty() {
        // Gauss–Seidel ran out of sweeps (two compliant chains pressed together make W
        // ill-conditioned): solve the active set's normal forces directly. A lumen contact's
        // normal is then turned to where its point settled and the solve repeated, until the
        // points lie on their circles (the linear solve along a fixed normal leaves them off
        // it by the square of the sideways slip). The pass whose points lie nearest their
        // circles is kept: the turned normals need not converge when the active set changes
        // between passes.
        let mut best: Option<(f64, Vec<Prepared>, Vec<Vector3<f64>>)> = None;
        for _ in 0..LUMEN_POLISH_PASSES {
            let tangential: Vec<Vector3<f64>> =
                local.iter().map(|l| Vector3::new(0.0, l.y, l.z)).collect();
            let held = normal_displacements(&prepared, flexibilities, &tangential);
            let c: Vec<f64> = contacts
                .iter()
                .zip(&prepared)
                .zip(&held)
                .map(|((_, p), u)| p.gap + p.free_local.x + u)
                .collect();
            let column = |j: usize| {
                let mut unit = vec![Vector3::zeros(); contacts.len()];
                unit[j] = Vector3::x();
                normal_displacements(&prepared, flexibilities, &unit)
            };
            let mut columns = vec![None; contacts.len()];
            if !active_set_normals(&c, column, &mut columns, &mut local, |k| {
                contacts[k].friction
            }) {
                break;
            }
            // Where each lumen point settled: pressed ones belong on their circles, the others
            // inside them.
            let moved = relative_displacements(&prepared, flexibilities, &local);
            let settled: Vec<Option<Vector3<f64>>> = contacts
                .iter()
                .zip(&prepared)
                .zip(local.iter().zip(&moved))
                .map(|((c, p), (l, moved))| {
                    let lumen = c.lumen.as_ref()?;
                    let x = lumen.offset(&(moved + p.delta));
                    (x.norm() > 0.0 && (l.x > 0.0 || x.norm() > lumen.clearance)).then_some(x)
                })
                .collect();
            let off_circle = settled
                .iter()
                .zip(contacts)
                .filter_map(|(x, c)| Some((x.as_ref()?.norm() / c.lumen?.clearance - 1.0).abs()))
                .fold(0.0, f64::max);
            if best.as_ref().is_some_and(|b| off_circle >= b.0) {
                break;
            }
            best = Some((off_circle, prepared.clone(), local.clone()));
            if off_circle <= LUMEN_POLISH_TOLERANCE {
                break;
            }
            // Turn each pressed or violated lumen normal to its settled point; the force keeps
            // its world radial size and axial part.
            for ((p, l), (c, x)) in prepared
                .iter_mut()
                .zip(local.iter_mut())
                .zip(contacts.iter().zip(&settled))
            {
                let (Some(lumen), Some(x)) = (&c.lumen, x) else {
                    continue;
                };
                let world = p.frame * *l;
                let radial = lumen.across_axis(&world).norm();
                p.turn_in_lumen(x.normalize(), lumen);
                *l = Vector3::new(radial, 0.0, lumen.axis.dot(&world));
            }
        }
        if let Some((_, kept, forces)) = best {
            prepared = kept;
            local = forces;
            load_all(&mut chains, &prepared, &local);
            response.polished = true;
        }
    }
    if local.iter().any(|l| !l.iter().all(|v| v.is_finite())) {
        return Err(PhysicsError::Diverged {
            check: crate::error::DivergenceCheck::NonFinite("contact force"),
            node: 0,
            step: 0,
        });
    }
    response.normals = prepared
        .iter()
        .map(|p| (p.frame.column(0).into_owned(), p.gap))
        .collect();
    response.local = local;
    response.nodal_loads = chains.into_iter().map(|c| c.loads).collect();
    Ok(response)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A symmetric positive definite 3×3 compliance from a random matrix (m/N).
    fn compliance(entries: &[f64]) -> Matrix3<f64> {
        let m = Matrix3::from_iterator(entries.iter().copied());
        (m * m.transpose() + Matrix3::identity() * 0.05) * 1e-3
    }

    proptest! {
        /// The exact lumen solve meets its own definition (Karush–Kuhn–Tucker conditions of
        /// the circular constraint, checked directly): the settled offset is within the
        /// clearance, the radial force is along it and non-negative, it is zero where the
        /// point is off the wall, and the axial force is inside the cone and sticks where it is
        /// inside.
        #[test]
        fn lumen_solve_meets_the_circular_constraint(
            entries in proptest::collection::vec(-1.0..1.0f64, 9),
            without in proptest::collection::vec(-2e-4..2e-4f64, 3),
            across in proptest::collection::vec(-1e-4..1e-4f64, 2),
            clearance in 1e-5..3e-4f64,
            mu in prop_oneof![Just(0.0), 0.0..0.5f64],
        ) {
            let w = compliance(&entries);
            let without = Vector3::from_column_slice(&without);
            let lumen = Lumen {
                axis: Vector3::x(),
                across: Vector3::new(0.0, across[0], across[1]),
                clearance,
            };
            let (normal, force) = lumen_solve(&w, &without, &lumen, mu);
            let moved = without + w * force;
            let x = lumen.across - Vector3::new(0.0, moved.y, moved.z);
            let radial = Vector3::new(0.0, force.y, force.z);
            let alpha = radial.dot(&normal);
            prop_assert!((normal.norm() - 1.0).abs() < 1e-9 && normal.x.abs() < 1e-12);
            prop_assert!(alpha >= 0.0 && (radial - normal * alpha).norm() <= 1e-9 * radial.norm().max(1e-12));
            prop_assert!(x.norm() <= clearance * (1.0 + 1e-6), "offset {} of {}", x.norm(), clearance);
            if alpha > 0.0 {
                prop_assert!((x.norm() - clearance).abs() <= 1e-6 * clearance);
                prop_assert!((x.normalize() - normal).norm() < 1e-6);
            }
            prop_assert!(force.x.abs() <= mu * alpha * (1.0 + 1e-12) + 1e-300);
            if mu > 0.0 && alpha > 0.0 {
                if force.x.abs() < (1.0 - 1e-9) * mu * alpha {
                    // Inside the cone the contact sticks: no axial slip.
                    prop_assert!(moved.x.abs() <= 1e-9 * moved.norm().max(1e-12), "axial slip {}", moved.x);
                } else {
                    // On the cone's edge it slides against the axial force.
                    prop_assert!(force.x * moved.x <= 1e-9 * (force.x * moved.norm()).abs(), "slip {} with force {}", moved.x, force.x);
                }
            }
        }
    }
}
