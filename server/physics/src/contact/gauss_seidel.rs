//! Projected Gauss–Seidel over contacts ordered along the device (the paper's Algorithm 3),
//! O(M + N) a sweep through the flexibility blocks, with Anderson acceleration, an active-set
//! polish of the normal forces and a frozen-friction second phase; and its brute-force
//! reference on the explicit Delassus matrix.

use nalgebra::{DMatrix, DVector, Vector3, Vector6};

use super::problem::{
    Contact, ContactResponse, ContactSettings, Prepared, accumulate_loads, force6, local_law,
    normal_with_fixed_tangent, prepare, project_on_cone, solve_local, tip_ward_pass, translation,
};
use crate::error::{PhysicsError, Result};
use crate::substructure::Flexibility;

/// Displacements of every unknown node under nodal `loads`, u = K⁻¹ F, by the propagation
/// u_i = B_i + D_i A_i of the module documentation: O(N).
pub(super) fn node_displacements(
    flexibility: &Flexibility,
    loads: &[Vector6<f64>],
) -> Vec<Vector6<f64>> {
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
pub(super) fn normal_displacement(p: &Prepared, u: &[Vector6<f64>]) -> f64 {
    let mut delta = translation(&u[p.second]) * p.t;
    if let Some(i) = p.first {
        delta += translation(&u[i]) * (1.0 - p.t);
    }
    p.frame.column(0).dot(&delta)
}

/// Active-set solve of the normal forces with the tangential forces held, for the
/// single-chain solver (W from K⁻¹ by propagation, one O(N) solve per active contact, kept in
/// `columns` for the solve's later polishes); see [`active_set_normals`].
fn polish_normals(
    flexibility: &Flexibility,
    prepared: &[Prepared],
    columns: &mut [Option<Vec<f64>>],
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
    active_set_normals(&c, column, columns, local, |k| prepared[k].friction)
}

/// Active-set solve of the normal forces `local[k].x` with the tangential forces held:
/// `c[k]` is contact k's gap with zero normal forces and `column(j)` the normal
/// displacement of every contact under a unit normal force at j (W's column j), computed
/// once into `columns` (M entries, `None` until needed; kept by a caller that polishes the
/// same problem again). The problem λ ≥ 0, W λ + c ≥ 0, λ·(W λ + c) = 0 with W symmetric
/// positive definite is the convex quadratic programme min ½ λᵀWλ + cᵀλ over λ ≥ 0, solved
/// by the primal active-set method (as Lawson and Hanson's NNLS): from the forces given
/// (clipped at zero), the pushing set's forces move towards the solution of
/// W_AA λ_A = −c_A, stopping where a force would turn negative (that contact leaves the
/// set); at the set's own solution, the inactive contact penetrating most joins it. The
/// objective falls at every pass, so no set comes back, and starting from a Gauss–Seidel
/// iterate few passes are needed (the primal–dual method, changing every wrong contact at
/// once, went round for tens of passes on nearly redundant contacts a fraction of a
/// millimetre apart). The tangential forces are then projected on the cones of the new
/// normals. Returns false (leaving `local` alone) if it does not settle in
/// [`MAX_ACTIVE_SET_PASSES`] + 2M passes.
pub(crate) fn active_set_normals(
    c: &[f64],
    mut column: impl FnMut(usize) -> Vec<f64>,
    columns: &mut [Option<Vec<f64>>],
    local: &mut [Vector3<f64>],
    friction: impl Fn(usize) -> f64,
) -> bool {
    let m = c.len();
    debug_assert_eq!(columns.len(), m);
    let tolerance = 1e-9;
    let scale = c.iter().fold(1e-12f64, |a, b| a.max(b.abs()));
    let mut lambda: Vec<f64> = local.iter().map(|l| l.x.max(0.0)).collect();
    let mut active: Vec<bool> = lambda.iter().map(|&l| l > 0.0).collect();
    // The Cholesky factor of the last pass's W_AA, updated as contacts join and leave (a
    // coil's 100 pushing contacts were factored afresh every pass: 58 % of its steps).
    let mut factor: Option<SetFactor> = None;
    for _ in 0..MAX_ACTIVE_SET_PASSES + 2 * m.max(1) {
        let set: Vec<usize> = (0..m).filter(|&k| active[k]).collect();
        for &j in &set {
            if columns[j].is_none() {
                columns[j] = Some(column(j));
            }
        }
        // Every member's column is there now (borrowed, not copied each pass).
        let cols: Vec<&[f64]> = set.iter().filter_map(|&j| columns[j].as_deref()).collect();
        let target = if set.is_empty() {
            factor = None;
            DVector::zeros(0)
        } else if let Some(x) = factor
            .take()
            .and_then(|f| f.updated(&set, columns))
            .map(|f| factor.insert(f).solve(&set, c))
        {
            x
        } else {
            let w = DMatrix::from_fn(set.len(), set.len(), |a, b| cols[b][set[a]]);
            let rhs = DVector::from_iterator(set.len(), set.iter().map(|&k| -c[k]));
            match w.clone().cholesky() {
                Some(ch) => {
                    let x = ch.solve(&rhs);
                    factor = Some(SetFactor {
                        order: set.clone(),
                        cholesky: ch,
                    });
                    x
                }
                None => match w.lu().solve(&rhs) {
                    Some(x) => x,
                    None => return false,
                },
            }
        };
        // Towards the set's solution, as far as every force stays non-negative.
        let blocking = set
            .iter()
            .zip(target.iter())
            .filter(|(_, z)| **z < 0.0)
            .map(|(&k, &z)| (k, lambda[k] / (lambda[k] - z)))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((leaving, step)) = blocking {
            for (&k, &z) in set.iter().zip(target.iter()) {
                lambda[k] = (lambda[k] + step * (z - lambda[k])).max(0.0);
            }
            lambda[leaving] = 0.0;
            for &k in &set {
                if lambda[k] <= 0.0 {
                    active[k] = false;
                }
            }
            continue;
        }
        for (&k, &z) in set.iter().zip(target.iter()) {
            lambda[k] = z;
        }
        // The inactive contact penetrating most under the set's forces joins it.
        let gap = |k: usize| -> f64 {
            c[k] + cols
                .iter()
                .zip(set.iter())
                .map(|(col, &j)| col[k] * lambda[j])
                .sum::<f64>()
        };
        let worst = (0..m)
            .filter(|&k| !active[k])
            .map(|k| (k, gap(k)))
            .filter(|(_, g)| *g < -tolerance * scale)
            .min_by(|x, y| x.1.total_cmp(&y.1));
        if let Some((k, _)) = worst {
            active[k] = true;
            continue;
        }
        for (k, l) in local.iter_mut().enumerate() {
            l.x = if active[k] { lambda[k] } else { 0.0 };
            *l = project_on_cone(l, friction(k));
        }
        return true;
    }
    false
}

/// The Cholesky factor of W restricted to a set of contacts, in the order they joined.
struct SetFactor {
    /// The contacts, in the factor's order.
    order: Vec<usize>,
    cholesky: nalgebra::Cholesky<f64, nalgebra::Dyn>,
}

impl SetFactor {
    /// The factor of `set` (W's columns in `columns`, each present): the contacts that left
    /// removed (a rank-one update each), those that joined appended (a triangular solve
    /// each); `None` where an appended one makes W_AA not positive definite (a contact
    /// redundant with the set: the caller factors afresh).
    fn updated(mut self, set: &[usize], columns: &[Option<Vec<f64>>]) -> Option<Self> {
        for p in (0..self.order.len()).rev() {
            if set.binary_search(&self.order[p]).is_err() {
                self.cholesky = self.cholesky.remove_column(p);
                self.order.remove(p);
            }
        }
        for &k in set {
            if self.order.contains(&k) {
                continue;
            }
            let column = columns[k].as_deref()?;
            let n = self.order.len();
            let new = DVector::from_fn(n + 1, |a, _| column[if a < n { self.order[a] } else { k }]);
            // The new pivot, as the full factorization would find it: positive, or no factor.
            let mut l = new.rows(0, n).into_owned();
            if !self.cholesky.l_dirty().solve_lower_triangular_mut(&mut l) {
                return None;
            }
            let pivot = new[n] - l.norm_squared();
            if pivot.is_nan() || pivot <= 0.0 {
                return None;
            }
            self.cholesky = self.cholesky.insert_column(n, new);
            self.order.push(k);
        }
        Some(self)
    }

    /// The solution of W_AA x = −c_A, in the order of `set` (the factor's contacts).
    fn solve(&self, set: &[usize], c: &[f64]) -> DVector<f64> {
        let rhs = DVector::from_iterator(self.order.len(), self.order.iter().map(|&k| -c[k]));
        let x = self.cholesky.solve(&rhs);
        DVector::from_iterator(
            set.len(),
            set.iter().map(|k| {
                let p = self.order.iter().position(|o| o == k).unwrap_or_default();
                x[p]
            }),
        )
    }
}

/// Passes of [`active_set_normals`] beyond 2M before it gives up.
const MAX_ACTIVE_SET_PASSES: usize = 8;

/// Replaces `loads` by the nodal loads of contact forces `local` (after the forces jumped:
/// an acceleration or active-set step).
fn reload(prepared: &[Prepared], local: &[Vector3<f64>], loads: &mut [Vector6<f64>]) {
    loads.iter_mut().for_each(|l| l.fill(0.0));
    accumulate_loads(prepared, local, loads);
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

/// Sweeps between active-set solves of the normal forces when Gauss–Seidel is slow to
/// converge (with [`ContactSettings::polish`]). On the neuro phantom's recorded problems
/// (`CONTACT_ACCURACY`, docs/physics.md) every 10 sweeps solved them in 0.68 ms p50 (W's
/// columns kept between polishes) against 1.1 ms every 25, and as accurately.
pub const POLISH_EVERY: usize = 10;

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
    gauss_seidel_observed(
        flexibility,
        free,
        contacts,
        settings,
        warm_start,
        &mut |_| {},
    )
}

/// [`gauss_seidel()`], with `observer` shown the forces (per contact, its frame) after every
/// sweep: for convergence charts.
pub fn gauss_seidel_observed(
    flexibility: &Flexibility,
    free: &[Vector6<f64>],
    contacts: &[Contact],
    settings: &ContactSettings,
    warm_start: Option<&[Vector3<f64>]>,
    observer: &mut dyn FnMut(&[Vector3<f64>]),
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
    // W's columns, computed by the first polish that needs them.
    let mut columns: Vec<Option<Vec<f64>>> = vec![None; contacts.len()];
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
        observer(&local);
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
            if polish_normals(flexibility, &prepared, &mut columns, &mut local) {
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
        if polish_normals(flexibility, &prepared, &mut columns, &mut local) {
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

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector, Vector3};
    use proptest::prelude::*;

    use super::{SetFactor, active_set_normals};

    /// The solution of λ ≥ 0, W λ + c ≥ 0, λ·(W λ + c) = 0 by trying every active set (W
    /// symmetric positive definite: exactly one set gives it).
    fn every_set(w: &DMatrix<f64>, c: &[f64]) -> Vec<f64> {
        let m = c.len();
        let mut best: Option<(f64, Vec<f64>)> = None;
        for mask in 0u32..(1 << m) {
            let set: Vec<usize> = (0..m).filter(|k| mask & (1 << k) != 0).collect();
            let mut lambda = vec![0.0; m];
            if !set.is_empty() {
                let ws = DMatrix::from_fn(set.len(), set.len(), |a, b| w[(set[a], set[b])]);
                let rhs = nalgebra::DVector::from_iterator(set.len(), set.iter().map(|&k| -c[k]));
                let Some(x) = ws.cholesky().map(|ch| ch.solve(&rhs)) else {
                    continue;
                };
                for (&k, v) in set.iter().zip(x.iter()) {
                    lambda[k] = *v;
                }
            }
            // How far this set is from the conditions (0 for the solution).
            let gaps: Vec<f64> = (0..m)
                .map(|k| c[k] + (0..m).map(|j| w[(k, j)] * lambda[j]).sum::<f64>())
                .collect();
            let wrong = (0..m)
                .map(|k| (-lambda[k]).max(0.0) + (-gaps[k]).max(0.0))
                .sum::<f64>();
            if best.as_ref().is_none_or(|(b, _)| wrong < *b) {
                best = Some((wrong, lambda));
            }
        }
        best.map(|(_, l)| l).unwrap_or_default()
    }

    /// A Delassus-like matrix: contacts along a stiff rod (W_ij falling off with distance),
    /// some nearly redundant (a fraction of a millimetre apart), plus a small diagonal.
    fn rod_matrix(positions: &[f64], stiffness: f64) -> DMatrix<f64> {
        let m = positions.len();
        DMatrix::from_fn(m, m, |i, j| {
            let d = (positions[i] - positions[j]).abs();
            (-d / stiffness).exp() + if i == j { 1e-3 } else { 0.0 }
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        /// The Cholesky factor of W_AA updated from one set of contacts to another solves as
        /// a fresh factorization of the new set.
        #[test]
        fn an_updated_set_factor_solves_as_a_fresh_one(
            positions in proptest::collection::vec(0.0f64..20.0, 2..9),
            stiffness in 1.0f64..50.0,
            gaps in proptest::collection::vec(-1.0f64..1.0, 9),
            first in proptest::collection::vec(any::<bool>(), 9),
            second in proptest::collection::vec(any::<bool>(), 9),
        ) {
            // From the factor of one set to another's, contacts leaving and joining: the
            // solution of W_AA x = −c_A equals a fresh factorization's (where the update
            // declines, a redundant contact joining, there is nothing to compare).
            let m = positions.len();
            let w = rod_matrix(&positions, stiffness);
            let c = &gaps[..m];
            let set = |pick: &[bool]| -> Vec<usize> { (0..m).filter(|&k| pick[k]).collect() };
            let (a, b) = (set(&first), set(&second));
            prop_assume!(!a.is_empty() && !b.is_empty());
            let sub = |s: &[usize]| DMatrix::from_fn(s.len(), s.len(), |i, j| w[(s[i], s[j])]);
            let Some(cholesky) = sub(&a).cholesky() else {
                return Ok(());
            };
            let columns: Vec<Option<Vec<f64>>> =
                (0..m).map(|j| Some((0..m).map(|k| w[(k, j)]).collect())).collect();
            let factor = SetFactor { order: a, cholesky };
            let Some(updated) = factor.updated(&b, &columns) else {
                return Ok(());
            };
            let rhs = DVector::from_iterator(b.len(), b.iter().map(|&k| -c[k]));
            let fresh = sub(&b).lu().solve(&rhs).unwrap();
            let x = updated.solve(&b, c);
            let scale = fresh.iter().fold(1.0f64, |s, v| s.max(v.abs()));
            prop_assert!((x - &fresh).amax() <= 1e-8 * scale, "{fresh}");
        }

        /// The primal active-set solve finds the one solution, from any non-negative start.
        #[test]
        fn the_active_set_solve_finds_the_lcp_solution(
            positions in proptest::collection::vec(0.0f64..20.0, 1..9),
            stiffness in 1.0f64..50.0,
            gaps in proptest::collection::vec(-1.0f64..1.0, 9),
            start in proptest::collection::vec(prop_oneof![Just(0.0), 0.0f64..2.0], 9),
        ) {
            let m = positions.len();
            let w = rod_matrix(&positions, stiffness);
            let c = &gaps[..m];
            let reference = every_set(&w, c);
            let mut local: Vec<Vector3<f64>> =
                start[..m].iter().map(|&s| Vector3::new(s, 0.0, 0.0)).collect();
            let mut columns = vec![None; m];
            let column = |j: usize| (0..m).map(|k| w[(k, j)]).collect::<Vec<f64>>();
            prop_assert!(active_set_normals(c, column, &mut columns, &mut local, |_| 0.0));
            let scale = reference.iter().fold(1.0f64, |a, b| a.max(b.abs()));
            for (l, r) in local.iter().zip(&reference) {
                prop_assert!((l.x - r).abs() <= 1e-6 * scale, "{} vs {r}", l.x);
            }
        }
    }
}
