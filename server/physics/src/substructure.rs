//! The O(N) substructure solver of Cotin et al. (2005), Algorithms 1 and 2, for the
//! block-tridiagonal stiffness of a serially linked beam.
//!
//! Nodes are numbered 0..n. `K` has diagonal blocks `K(n,n)` and upper blocks `K(n,n+1)`
//! (the lower ones are their transposes: `K` is symmetric).
//!
//! *Forward sweep (boundary fixation).* Each node in turn becomes internal; its Schur
//! complement is passed to the next node:
//! `S(0) = K(0,0)`, `S(n+1) = K(n+1,n+1) − K(n+1,n) S(n)⁻¹ K(n,n+1)` (the paper's Alg. 2
//! prints `=` instead of `−=`, an erratum), and the accumulated force
//! `f_acc(n+1) = f(n+1) − K(n+1,n) S(n)⁻¹ f_acc(n)`.
//!
//! *Backward sweep (boundary relaxation).* With the coupling blocks
//! `H(n,n+1) = −S(n)⁻¹ K(n,n+1)`:
//! `u(N) = S(N)⁻¹ f_acc(N)`, `u(n) = S(n)⁻¹ f_acc(n) + H(n,n+1) u(n+1)`.
//!
//! *Flexibility assembling.* The diagonal blocks of `K⁻¹` follow from
//! `C(N) = S(N)⁻¹`, `C(n) = S(n)⁻¹ + H(n,n+1) C(n+1) H(n,n+1)ᵀ`; the paper's Alg. 2 drops the
//! `S(n)⁻¹` term. Off-diagonal blocks are products along the chain:
//! `(K⁻¹)(i,j) = H(i,i+1) H(i+1,i+2) ⋯ H(j−1,j) C(j)` for i < j.
//! Each sweep costs O(N) 6×6 products.

use nalgebra::{Matrix6, Vector6};

use crate::error::{PhysicsError, Result};

/// A symmetric block-tridiagonal matrix with 6×6 blocks.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockTridiagonal {
    /// Diagonal blocks K(n,n), one per node.
    pub diagonal: Vec<Matrix6<f64>>,
    /// Upper blocks K(n,n+1), one fewer than nodes.
    pub upper: Vec<Matrix6<f64>>,
}

impl BlockTridiagonal {
    /// A zero matrix for `nodes` nodes.
    pub fn zeros(nodes: usize) -> Self {
        Self {
            diagonal: vec![Matrix6::zeros(); nodes],
            upper: vec![Matrix6::zeros(); nodes.saturating_sub(1)],
        }
    }

    /// Number of block rows (nodes).
    pub fn nodes(&self) -> usize {
        self.diagonal.len()
    }

    /// Sets every block to zero, keeping the size.
    pub fn clear(&mut self) {
        self.diagonal.iter_mut().for_each(|b| b.fill(0.0));
        self.upper.iter_mut().for_each(|b| b.fill(0.0));
    }

    /// Matrix–vector product K·u (for residual checks and tests).
    pub fn multiply(&self, u: &[Vector6<f64>]) -> Vec<Vector6<f64>> {
        let n = self.nodes();
        let mut out: Vec<Vector6<f64>> = (0..n).map(|i| self.diagonal[i] * u[i]).collect();
        for i in 0..n.saturating_sub(1) {
            out[i] += self.upper[i] * u[i + 1];
            out[i + 1] += self.upper[i].transpose() * u[i];
        }
        out
    }

    /// The dense (6n × 6n) form, for tests and small brute-force references.
    pub fn to_dense(&self) -> nalgebra::DMatrix<f64> {
        let n = self.nodes();
        let mut k = nalgebra::DMatrix::zeros(6 * n, 6 * n);
        for i in 0..n {
            k.fixed_view_mut::<6, 6>(6 * i, 6 * i)
                .copy_from(&self.diagonal[i]);
            if i + 1 < n {
                k.fixed_view_mut::<6, 6>(6 * i, 6 * i + 6)
                    .copy_from(&self.upper[i]);
                k.fixed_view_mut::<6, 6>(6 * i + 6, 6 * i)
                    .copy_from(&self.upper[i].transpose());
            }
        }
        k
    }
}

/// The result of the forward sweep: inverse Schur complements and coupling blocks.
#[derive(Debug, Clone, Default)]
pub struct Substructure {
    /// S(n)⁻¹, inverse of each node's apparent stiffness after eliminating nodes 0..n−1.
    schur_inverse: Vec<Matrix6<f64>>,
    /// H(n,n+1) = −S(n)⁻¹ K(n,n+1).
    coupling: Vec<Matrix6<f64>>,
    /// Scratch: accumulated forces of the last solve.
    accumulated: Vec<Vector6<f64>>,
}

impl Substructure {
    /// Runs the forward sweep (boundary fixation by accumulation) on `k`, reusing buffers.
    pub fn factor(&mut self, k: &BlockTridiagonal) -> Result<()> {
        let n = k.nodes();
        self.schur_inverse.resize(n, Matrix6::zeros());
        self.coupling.resize(n.saturating_sub(1), Matrix6::zeros());
        let mut schur = k.diagonal.first().copied().unwrap_or_else(Matrix6::zeros);
        for i in 0..n {
            let inv = invert_block(&schur).ok_or(PhysicsError::SingularBlock { node: i })?;
            self.schur_inverse[i] = inv;
            if i + 1 < n {
                let h = -(inv * k.upper[i]);
                // S(n+1) = K(n+1,n+1) − K(n,n+1)ᵀ S(n)⁻¹ K(n,n+1) = K(n+1,n+1) + K(n,n+1)ᵀ H.
                schur = k.diagonal[i + 1] + k.upper[i].transpose() * h;
                self.coupling[i] = h;
            }
        }
        Ok(())
    }

    /// Factors a fresh copy of `k`.
    pub fn new(k: &BlockTridiagonal) -> Result<Self> {
        let mut s = Self::default();
        s.factor(k)?;
        Ok(s)
    }

    /// Number of nodes factored.
    pub fn nodes(&self) -> usize {
        self.schur_inverse.len()
    }

    /// Solves K·u = f (Algorithm 1) in place: `f` is overwritten with `u`.
    pub fn solve_in_place(&mut self, f: &mut [Vector6<f64>]) {
        let n = self.nodes();
        debug_assert_eq!(f.len(), n);
        self.accumulated.resize(n, Vector6::zeros());
        // Forward: f_acc(n+1) = f(n+1) + H(n,n+1)ᵀ f_acc(n)   [−K(n+1,n)S(n)⁻¹ = H(n,n+1)ᵀ].
        let mut acc = Vector6::zeros();
        for i in 0..n {
            acc = if i == 0 {
                f[0]
            } else {
                f[i] + self.coupling[i - 1].transpose() * acc
            };
            self.accumulated[i] = acc;
        }
        // Backward: u(n) = S(n)⁻¹ f_acc(n) + H(n,n+1) u(n+1).
        let mut next = Vector6::zeros();
        for i in (0..n).rev() {
            let mut u = self.schur_inverse[i] * self.accumulated[i];
            if i + 1 < n {
                u += self.coupling[i] * next;
            }
            f[i] = u;
            next = u;
        }
    }

    /// Solves K·u = f and returns u.
    pub fn solve(&mut self, f: &[Vector6<f64>]) -> Vec<Vector6<f64>> {
        let mut u = f.to_vec();
        self.solve_in_place(&mut u);
        u
    }

    /// Solves K·u = f followed by one step of iterative refinement (u += K⁻¹(f − K·u)),
    /// which recovers the digits lost to the stiffness ratio of long, slender devices
    /// (axial EA against bending EI/l²) for one extra O(N) sweep. `k` must be the matrix
    /// that was factored.
    pub fn solve_refined(&mut self, k: &BlockTridiagonal, f: &[Vector6<f64>]) -> Vec<Vector6<f64>> {
        let mut u = self.solve(f);
        let mut residual: Vec<Vector6<f64>> =
            f.iter().zip(k.multiply(&u)).map(|(f, ku)| f - ku).collect();
        self.solve_in_place(&mut residual);
        u.iter_mut().zip(&residual).for_each(|(u, du)| *u += du);
        u
    }

    /// Flexibility assembling by accumulation (Algorithm 2, corrected): fills `flex` with the
    /// diagonal blocks of K⁻¹ and the coupling blocks H(n,n+1).
    pub fn flexibility_into(&self, flex: &mut Flexibility) {
        let n = self.nodes();
        flex.diagonal.resize(n, Matrix6::zeros());
        flex.coupling.clone_from(&self.coupling);
        for i in (0..n).rev() {
            flex.diagonal[i] = if i + 1 == n {
                self.schur_inverse[i]
            } else {
                let h = &self.coupling[i];
                self.schur_inverse[i] + h * flex.diagonal[i + 1] * h.transpose()
            };
        }
    }

    /// The flexibility blocks of the factored matrix.
    pub fn flexibility(&self) -> Flexibility {
        let mut f = Flexibility::default();
        self.flexibility_into(&mut f);
        f
    }
}

/// Diagonal blocks of K⁻¹ and the coupling blocks that reach every other block of K⁻¹:
/// what contact response needs (Delassus operator W = Cᵀ K⁻¹ C).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Flexibility {
    /// (K⁻¹)(n,n), in metres per newton / radians per newton-metre.
    pub diagonal: Vec<Matrix6<f64>>,
    /// H(n,n+1) = −S(n)⁻¹ K(n,n+1) (dimensionless couplings between neighbours).
    pub coupling: Vec<Matrix6<f64>>,
}

impl Flexibility {
    /// Any block (K⁻¹)(i,j), in O(|i−j|) products.
    pub fn block(&self, i: usize, j: usize) -> Matrix6<f64> {
        if i > j {
            return self.block(j, i).transpose();
        }
        let mut m = self.diagonal[j];
        for n in (i..j).rev() {
            m = self.coupling[n] * m;
        }
        m
    }
}

/// Inverts a 6×6 block: Cholesky when symmetric positive definite, LU otherwise.
fn invert_block(m: &Matrix6<f64>) -> Option<Matrix6<f64>> {
    let inv = match spd_inverse(m) {
        Some(inv) => inv,
        None => m.try_inverse()?,
    };
    inv.iter().all(|v| v.is_finite()).then_some(inv)
}

/// The inverse of a symmetric positive definite 6×6 block from its lower triangle, by its
/// Cholesky factor L written out: A⁻¹ = L⁻ᵀ L⁻¹ (nalgebra's `Cholesky::inverse` solves
/// against the identity column by column, and was 8–10 % of a step of a long wire looped
/// against the wall). None where a pivot is not positive.
fn spd_inverse(m: &Matrix6<f64>) -> Option<Matrix6<f64>> {
    let mut l = [[0.0f64; 6]; 6];
    for j in 0..6 {
        let pivot = m[(j, j)] - l[j][..j].iter().map(|x| x * x).sum::<f64>();
        if pivot.is_nan() || pivot <= 0.0 {
            return None;
        }
        let d = pivot.sqrt();
        l[j][j] = d;
        for i in j + 1..6 {
            let s = m[(i, j)]
                - l[i][..j]
                    .iter()
                    .zip(&l[j][..j])
                    .map(|(a, b)| a * b)
                    .sum::<f64>();
            l[i][j] = s / d;
        }
    }
    // L⁻¹, lower triangular, column by column.
    let mut inv_l = [[0.0f64; 6]; 6];
    for j in 0..6 {
        inv_l[j][j] = 1.0 / l[j][j];
        for i in j + 1..6 {
            let mut s = 0.0;
            for k in j..i {
                s -= l[i][k] * inv_l[k][j];
            }
            inv_l[i][j] = s / l[i][i];
        }
    }
    // (A⁻¹)(r, c) = Σ_k L⁻¹(k, r) L⁻¹(k, c) over k ≥ max(r, c).
    let mut inv = Matrix6::zeros();
    for r in 0..6 {
        for c in 0..=r {
            let s: f64 = (r..6).map(|k| inv_l[k][r] * inv_l[k][c]).sum();
            inv[(r, c)] = s;
            inv[(c, r)] = s;
        }
    }
    Some(inv)
}

#[cfg(test)]
mod tests {
    use nalgebra::Matrix6;
    use proptest::prelude::*;

    use super::spd_inverse;

    proptest! {
        /// The written-out inverse is nalgebra's Cholesky inverse, on random symmetric
        /// positive definite blocks scaled over twelve orders of magnitude (a beam's axial
        /// against its bending stiffness), and refuses what nalgebra's factor refuses.
        #[test]
        fn spd_inverse_is_the_cholesky_inverse(
            entries in proptest::collection::vec(-1.0f64..1.0, 36),
            shift in 1e-3f64..2.0,
            exponent in -6.0f64..6.0,
            indefinite in any::<bool>(),
        ) {
            let b = Matrix6::from_iterator(entries);
            let scale = 10f64.powf(exponent);
            let mut a = (b * b.transpose() + Matrix6::identity() * shift) * scale;
            if indefinite {
                a[(3, 3)] = -a[(3, 3)];
            }
            let reference = a.cholesky().map(|c| c.inverse());
            let fast = spd_inverse(&a);
            prop_assert_eq!(fast.is_some(), reference.is_some());
            if let (Some(fast), Some(reference)) = (fast, reference) {
                let error = (fast - reference).norm() / reference.norm();
                prop_assert!(error < 1e-10, "relative error {}", error);
                prop_assert!((fast * a - Matrix6::identity()).norm() < 1e-8);
            }
        }
    }
}
