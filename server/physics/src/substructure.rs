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
    let inv = match m.cholesky() {
        Some(c) => c.inverse(),
        None => m.try_inverse()?,
    };
    inv.iter().all(|v| v.is_finite()).then_some(inv)
}
