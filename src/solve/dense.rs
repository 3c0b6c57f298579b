//! Small dense LU with partial pivoting, in buffers allocated once.
//!
//! For the Jacobians of small first-order systems (studies, tests, control problems);
//! mechanical systems use the sparse solvers. A pivot below `eps * max|A|` counts as zero
//! and gives [`SolveError::Singular`].

use super::SolveError;

/// An n x n dense matrix (row-major) and its LU factors, in place.
#[derive(Clone, Debug)]
pub struct DenseLu {
    n: usize,
    a: Vec<f64>,
    piv: Vec<usize>,
}

impl DenseLu {
    /// Buffers for n x n.
    pub fn new(n: usize) -> Self {
        Self {
            n,
            a: vec![0.0; n * n],
            piv: vec![0; n],
        }
    }

    /// The matrix to fill (row-major, n x n) before [`DenseLu::factor`].
    pub fn matrix_mut(&mut self) -> &mut [f64] {
        &mut self.a
    }

    /// Factors the matrix in place (`P A = L U`).
    pub fn factor(&mut self) -> Result<(), SolveError> {
        let n = self.n;
        let a = &mut self.a;
        let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if !scale.is_finite() {
            return Err(SolveError::NonFinite {
                what: "Jacobian",
                iteration: 0,
            });
        }
        for k in 0..n {
            let (mut p, mut best) = (k, a[k * n + k].abs());
            for i in k + 1..n {
                if a[i * n + k].abs() > best {
                    best = a[i * n + k].abs();
                    p = i;
                }
            }
            if best <= f64::EPSILON * scale || best == 0.0 {
                return Err(SolveError::Singular { column: k });
            }
            self.piv[k] = p;
            if p != k {
                for j in 0..n {
                    a.swap(k * n + j, p * n + j);
                }
            }
            let inv = 1.0 / a[k * n + k];
            for i in k + 1..n {
                let l = a[i * n + k] * inv;
                a[i * n + k] = l;
                for j in k + 1..n {
                    a[i * n + j] -= l * a[k * n + j];
                }
            }
        }
        Ok(())
    }

    /// Overwrites `b` with `A^-1 b` (after [`DenseLu::factor`]).
    pub fn solve(&self, b: &mut [f64]) {
        let n = self.n;
        assert_eq!(b.len(), n);
        let a = &self.a;
        for k in 0..n {
            b.swap(k, self.piv[k]);
        }
        for i in 0..n {
            let s: f64 = (0..i).map(|j| a[i * n + j] * b[j]).sum();
            b[i] -= s;
        }
        for i in (0..n).rev() {
            let s: f64 = (i + 1..n).map(|j| a[i * n + j] * b[j]).sum();
            b[i] = (b[i] - s) / a[i * n + i];
        }
    }
}
