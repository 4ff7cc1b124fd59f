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
//! frozen-friction second phase as [`crate::contact::gauss_seidel`].

use nalgebra::{Matrix3, Vector3, Vector6};

use crate::contact::{
    Anderson, ContactSettings, force6, local_law, normal_with_fixed_tangent, perpendicular,
    project_on_cone, relax, tip_ward_pass, top_left, translation,
};
use crate::error::{PhysicsError, Result};
use crate::substructure::Flexibility;

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
}

impl CoupledContact {
    /// The contact frame `[n t1 t2]`, tangents chosen as for a wall contact.
    pub fn frame(&self) -> Matrix3<f64> {
        let n = self.normal;
        let t1 = perpendicular(&n);
        Matrix3::from_columns(&[n, t1, n.cross(&t1)])
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

impl ChainState<'_> {
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
    let mut prepared = Vec::with_capacity(contacts.len());
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
        let frame = c.frame();
        let mut w = Matrix3::zeros();
        let mut delta = Vector3::zeros();
        for side in &sides {
            let (ws, ds) = side_data(flexibilities[side.chain], free[side.chain], side);
            w += ws;
            delta += ds;
        }
        let compliance = frame.transpose() * w * frame;
        prepared.push((
            sides,
            frame,
            compliance,
            compliance.try_inverse(),
            frame.transpose() * delta,
        ));
    }
    let mut local: Vec<Vector3<f64>> = match warm_start {
        Some(w) if w.len() == contacts.len() => w.to_vec(),
        _ => vec![Vector3::zeros(); contacts.len()],
    };
    let mut chains: Vec<ChainState> = flexibilities
        .iter()
        .map(|f| ChainState {
            flexibility: f,
            loads: vec![Vector6::zeros(); f.diagonal.len()],
            tip_ward: vec![Vector6::zeros(); f.diagonal.len()],
            cursor: 0,
            base_ward: Vector6::zeros(),
        })
        .collect();
    for ((sides, frame, ..), l) in prepared.iter().zip(&local) {
        for side in sides {
            let df = frame * l * side.sign;
            chains[side.chain].add(side, &df);
        }
    }
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
        let before = anderson.active().then(|| local.clone());
        chains.iter_mut().for_each(ChainState::restart);
        let mut largest_change: f64 = 0.0;
        let mut largest_force: f64 = 0.0;
        let mut largest_violation: f64 = 0.0;
        for (k, (sides, frame, compliance, inverse, free_local)) in prepared.iter().enumerate() {
            let c = &contacts[k];
            let mut relative = Vector3::zeros();
            for side in sides {
                relative += chains[side.chain].displacement(side) * side.sign;
            }
            let own = local[k];
            let total = free_local + frame.transpose() * relative;
            largest_violation = largest_violation.max(-(c.gap + total.x));
            let b = total - compliance * own;
            let updated = if frozen {
                normal_with_fixed_tangent(compliance, &b, c.gap, &own, c.friction)
            } else {
                relax(
                    &own,
                    local_law(compliance, inverse.as_ref(), &b, c.gap, c.friction),
                    settings.relaxation,
                    c.friction,
                )
            };
            let change = updated - own;
            if change != Vector3::zeros() {
                let df = frame * change;
                for side in sides {
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
        if let Some(before) = before
            && anderson.mix(&before, &mut local)
        {
            // The mixed iterate, projected on the cones, with every chain's loads rebuilt.
            for (c, l) in contacts.iter().zip(local.iter_mut()) {
                *l = project_on_cone(l, c.friction);
            }
            for chain in &mut chains {
                chain.loads.iter_mut().for_each(|l| l.fill(0.0));
            }
            for ((sides, frame, ..), l) in prepared.iter().zip(&local) {
                for side in sides {
                    chains[side.chain].add(side, &(frame * l * side.sign));
                }
            }
        }
    }
    if local.iter().any(|l| !l.iter().all(|v| v.is_finite())) {
        return Err(PhysicsError::Diverged {
            check: crate::error::DivergenceCheck::NonFinite("contact force"),
            node: 0,
            step: 0,
        });
    }
    response.local = local;
    response.nodal_loads = chains.into_iter().map(|c| c.loads).collect();
    Ok(response)
}
