//! Contact response: Signorini non-penetration with Coulomb friction, solved by semismooth
//! Newton on the Delassus matrix ([`newton`]) or by Gauss–Seidel (the default)
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

use std::cell::RefCell;

use nalgebra::{Vector3, Vector6};

use crate::error::Result;
use crate::substructure::Flexibility;

pub mod delassus;
pub mod gauss_seidel;
pub mod newton;
mod problem;

pub use problem::{
    Contact, ContactMethod, ContactResponse, ContactSettings, NEWTON_ITERATIONS, perpendicular,
    point_displacement, solve_local,
};
use problem::{Prepared, accumulate_loads, prepare};
pub(crate) use problem::{
    contact_loads, force6, local_law, normal_with_fixed_tangent, project_on_cone, tip_ward_pass,
    top_left, translation,
};

pub use delassus::DelassusProblem;
pub(crate) use gauss_seidel::{Anderson, active_set_normals, relax};
pub use gauss_seidel::{POLISH_EVERY, dense_reference, gauss_seidel, gauss_seidel_observed};

/// A single chain's contact problem as a step posed it, to solve again by every method (the
/// contact solvers' convergence chart; stored as JSON without its settings).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RecordedProblem {
    /// The chain's flexibility blocks.
    pub flexibility: Flexibility,
    /// Free increment per unknown node.
    pub free: Vec<Vector6<f64>>,
    /// The contacts.
    pub contacts: Vec<Contact>,
    /// The settings the step solved it with (not stored: the defaults when read back).
    #[serde(skip)]
    pub settings: ContactSettings,
    /// The warm start the step gave it.
    pub warm_start: Option<Vec<Vector3<f64>>>,
}

/// Which problems [`record`] keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecordingPlan {
    /// Only problems with at least this many contacts.
    pub min_contacts: usize,
    /// Every `every`-th of those (1: all).
    pub every: usize,
    /// At most this many.
    pub limit: usize,
}

struct Recording {
    plan: RecordingPlan,
    seen: usize,
    kept: Vec<RecordedProblem>,
}

thread_local! {
    static RECORDING: RefCell<Option<Recording>> = const { RefCell::new(None) };
}

/// Runs `body` and returns, beside its result, the problems [`solve`] was given on this
/// thread meanwhile that `plan` keeps.
pub fn record<R>(plan: RecordingPlan, body: impl FnOnce() -> R) -> (R, Vec<RecordedProblem>) {
    let recording = Recording {
        plan,
        seen: 0,
        kept: Vec::new(),
    };
    let outer = RECORDING.with(|r| r.replace(Some(recording)));
    let result = body();
    let recorded = RECORDING.with(|r| r.replace(outer));
    (result, recorded.map(|r| r.kept).unwrap_or_default())
}

/// The most contacts [`ContactMethod::Newton`] solves by Newton at once (those that can
/// push: see [`newton_solve_observed`]); past it, Gauss–Seidel.
pub const NEWTON_MAX_CONTACTS: usize = 160;

/// Solves the contact problem with the method `settings` names (see [`ContactMethod`]).
pub fn solve(
    flexibility: &Flexibility,
    free: &[Vector6<f64>],
    contacts: &[Contact],
    settings: &ContactSettings,
    warm_start: Option<&[Vector3<f64>]>,
) -> Result<ContactResponse> {
    RECORDING.with(|r| {
        if let Some(recording) = r.borrow_mut().as_mut()
            && contacts.len() >= recording.plan.min_contacts
            && recording.kept.len() < recording.plan.limit
        {
            recording.seen += 1;
            if !(recording.seen - 1).is_multiple_of(recording.plan.every.max(1)) {
                return;
            }
            recording.kept.push(RecordedProblem {
                flexibility: flexibility.clone(),
                free: free.to_vec(),
                contacts: contacts.to_vec(),
                settings: *settings,
                warm_start: warm_start.map(<[_]>::to_vec),
            });
        }
    });
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
/// handing an unconverged problem to [`gauss_seidel()`] from where Newton stopped.
pub fn newton_solve(
    flexibility: &Flexibility,
    free: &[Vector6<f64>],
    contacts: &[Contact],
    settings: &ContactSettings,
    warm_start: Option<&[Vector3<f64>]>,
) -> Result<ContactResponse> {
    newton_solve_observed(
        flexibility,
        free,
        contacts,
        settings,
        warm_start,
        &mut |_| {},
    )
}

/// [`newton_solve`], with `observer` shown the forces after every Newton iteration (and
/// every sweep of a Gauss–Seidel finish).
///
/// Newton runs on the contacts that can push, not on every contact detected: a step in a
/// narrow vessel detects one contact per element near the wall (a hundred) of which about
/// ten push. The set starts from the contacts pushing at the warm start and those closed
/// with no force at all; after each solve the gaps of all the others under its forces come
/// from one O(N + M) propagation, and every contact they leave violated (by more than the
/// tolerance allows its residual) joins the set for the next pass. The Delassus matrix of
/// the set costs O(N + S²) (S its nodes), each Newton iteration O(A³): a pass is O(N + M +
/// A³) where the whole problem's matrix was O(N + M²).
pub fn newton_solve_observed(
    flexibility: &Flexibility,
    free: &[Vector6<f64>],
    contacts: &[Contact],
    settings: &ContactSettings,
    warm_start: Option<&[Vector3<f64>]>,
    observer: &mut dyn FnMut(&[Vector3<f64>]),
) -> Result<ContactResponse> {
    let prepared = prepare(flexibility, free, contacts)?;
    let m = prepared.len();
    let warm = warm_start.filter(|w| w.len() == m);
    let tolerance = newton_tolerance(settings);
    let mut candidate: Vec<bool> = (0..m)
        .map(|k| warm.is_some_and(|w| w[k].x > 0.0) || prepared[k].gap + prepared[k].free.x < 0.0)
        .collect();
    let mut local: Vec<Vector3<f64>> = vec![Vector3::zeros(); m];
    let mut iterations = 0;
    let mut converged = false;
    let mut loads = vec![Vector6::zeros(); flexibility.diagonal.len()];
    for _ in 0..ACTIVE_SET_PASSES {
        let set: Vec<usize> = (0..m).filter(|&k| candidate[k]).collect();
        if set.len() > NEWTON_MAX_CONTACTS {
            break;
        }
        let subset: Vec<Prepared> = set.iter().map(|&k| prepared[k]).collect();
        let problem = delassus::assemble(flexibility, &subset);
        let sub_warm: Option<Vec<Vector3<f64>>> = warm.map(|w| set.iter().map(|&k| w[k]).collect());
        let outcome = newton::solve(
            &problem,
            sub_warm.as_deref(),
            &tolerance,
            &mut |forces: &[Vector3<f64>]| {
                let mut all = vec![Vector3::zeros(); m];
                for (&k, f) in set.iter().zip(forces) {
                    all[k] = *f;
                }
                observer(&all);
            },
        );
        iterations += outcome.iterations;
        local.iter_mut().for_each(|l| *l = Vector3::zeros());
        for (&k, f) in set.iter().zip(&outcome.local) {
            local[k] = *f;
        }
        if !outcome.converged || !local.iter().all(|l| l.iter().all(|v| v.is_finite())) {
            break;
        }
        // The others' gaps under these forces: one propagation.
        loads.iter_mut().for_each(|l| *l = Vector6::zeros());
        accumulate_loads(&prepared, &local, &mut loads);
        let u = gauss_seidel::node_displacements(flexibility, &loads);
        let force = local.iter().map(|l| l.norm()).fold(0.0, f64::max);
        let allowed_force = (tolerance.relative * force).max(tolerance.absolute_n);
        let mut added = false;
        for k in 0..m {
            if candidate[k] {
                continue;
            }
            let p = &prepared[k];
            let w_nn = p.compliance[(0, 0)];
            if !(w_nn.is_finite() && w_nn > 0.0) {
                continue;
            }
            let gap = p.gap + p.free.x + gauss_seidel::normal_displacement(p, &u);
            // Its residual would be the force that closes the gap: −gap / W_nn.
            if gap < 0.0 && (-gap / w_nn > allowed_force || -gap > tolerance.violation_m) {
                candidate[k] = true;
                added = true;
            }
        }
        if !added {
            converged = true;
            break;
        }
    }
    if !converged {
        let finite = local.iter().all(|l| l.iter().all(|v| v.is_finite()));
        let start = if finite { Some(local.as_slice()) } else { warm };
        // The sweeps left of the budget (an overload governor's cap counts both).
        let rest = ContactSettings {
            max_iterations: settings.max_iterations.saturating_sub(iterations).max(1),
            ..*settings
        };
        let mut response =
            gauss_seidel_observed(flexibility, free, contacts, &rest, start, observer)?;
        response.iterations += iterations;
        return Ok(response);
    }
    loads.iter_mut().for_each(|l| *l = Vector6::zeros());
    accumulate_loads(&prepared, &local, &mut loads);
    Ok(ContactResponse {
        forces: prepared
            .iter()
            .zip(&local)
            .map(|(p, l)| p.frame * l)
            .collect(),
        local,
        nodal_loads: loads,
        iterations,
        converged: true,
        polished: false,
    })
}

/// Most Newton solves on a growing set of contacts before Gauss–Seidel takes over.
const ACTIVE_SET_PASSES: usize = 6;
