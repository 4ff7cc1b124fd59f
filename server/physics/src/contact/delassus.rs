//! The Delassus matrix `W = H K⁻¹ Hᵀ` of a single chain's contacts, assembled from the
//! substructure's flexibility blocks in O(N + S² + M²) (S distinct contact nodes, M contacts)
//! instead of the O(M·N) of one propagation per column.
//!
//! The off-diagonal blocks of K⁻¹ are products along the chain, `(K⁻¹)(i,j) = H(i,i+1) ⋯
//! H(j−1,j) D(j)` for i < j (see [`crate::substructure`]). Contacts load forces only, and their
//! points move by translations only, so the block a pair of nodes needs is the top-left 3×3 of
//! that product: `[I 0] H(i,i+1) ⋯ H(j−1,j) D(j)[:, 0..3]`. Walking the contact nodes in
//! order, the row `[I 0] H(i,i+1) ⋯` is carried from one contact node to the next by the
//! product of the couplings between them (computed once per gap between contact nodes).

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, SMatrix};

use super::problem::Prepared;
use crate::substructure::Flexibility;

/// A contact problem in Delassus form: the contact points move by `u = W λ + q` (each contact's
/// block of three in its frame `[n t1 t2]`, the normal entry of `q` including the gap), and
/// each contact asks `0 ≤ λ_n ⊥ u_n ≥ 0` with Coulomb friction on `u_t`.
#[derive(Debug, Clone, PartialEq)]
pub struct DelassusProblem {
    /// `W` (m/N), 3M × 3M, symmetric positive semi-definite.
    pub w: DMatrix<f64>,
    /// `q` (m), 3M: gap plus free normal displacement, then the free tangential displacements.
    pub q: DVector<f64>,
    /// Coulomb coefficient per contact.
    pub friction: Vec<f64>,
}

impl DelassusProblem {
    /// Number of contacts.
    pub fn contacts(&self) -> usize {
        self.friction.len()
    }
}

/// The Delassus problem of prepared single-chain contacts.
pub(super) fn assemble(flexibility: &Flexibility, prepared: &[Prepared]) -> DelassusProblem {
    let m = prepared.len();
    // Distinct unknown nodes the contacts act on, in chain order.
    let mut nodes: Vec<usize> = prepared
        .iter()
        .flat_map(|p| p.first.into_iter().chain(std::iter::once(p.second)))
        .collect();
    nodes.sort_unstable();
    nodes.dedup();
    let s = nodes.len();
    let index = |node: usize| nodes.binary_search(&node).expect("a contact node");
    // Couplings from each contact node to the next one: H(a,a+1) ⋯ H(b−1,b).
    let h = &flexibility.coupling;
    let d = &flexibility.diagonal;
    let gaps: Vec<Matrix6<f64>> = nodes
        .windows(2)
        .map(|pair| (pair[0]..pair[1]).fold(Matrix6::identity(), |acc, i| acc * h[i]))
        .collect();
    // G(a, b): translation at node a from a force at node b, for every pair of contact nodes.
    let mut g = vec![Matrix3::<f64>::zeros(); s * s];
    for a in 0..s {
        let mut row: SMatrix<f64, 3, 6> = SMatrix::zeros();
        row.fixed_view_mut::<3, 3>(0, 0).fill_with_identity();
        for b in a..s {
            if b > a {
                row *= gaps[b - 1];
            }
            let block = row * d[nodes[b]].fixed_columns::<3>(0);
            g[a * s + b] = block;
            g[b * s + a] = block.transpose();
        }
    }
    let weights = |p: &Prepared| {
        let second = (index(p.second), p.t);
        let first = p.first.map(|i| (index(i), 1.0 - p.t));
        [Some(second), first]
    };
    let mut w = DMatrix::zeros(3 * m, 3 * m);
    for (k, pk) in prepared.iter().enumerate() {
        for (l, pl) in prepared.iter().enumerate().skip(k) {
            let mut world = Matrix3::zeros();
            for (a, wa) in weights(pk).into_iter().flatten() {
                for (b, wb) in weights(pl).into_iter().flatten() {
                    world += g[a * s + b] * (wa * wb);
                }
            }
            let block = pk.frame.transpose() * world * pl.frame;
            w.fixed_view_mut::<3, 3>(3 * k, 3 * l).copy_from(&block);
            if l != k {
                w.fixed_view_mut::<3, 3>(3 * l, 3 * k)
                    .copy_from(&block.transpose());
            }
        }
    }
    let q = DVector::from_iterator(
        3 * m,
        prepared
            .iter()
            .flat_map(|p| [p.free.x + p.gap, p.free.y, p.free.z]),
    );
    DelassusProblem {
        w,
        q,
        friction: prepared.iter().map(|p| p.friction).collect(),
    }
}
