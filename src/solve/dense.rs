//! Small dense solvers: LU with partial pivoting in buffers allocated once, and the
//! inverse of a symmetric positive definite 3x3 block (the block-Jacobi and multigrid
//! smoothers' diagonal).
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

/// Inverse of the symmetric part of a 3x3 block, as `[b00, b01, b02, b11, b12, b22]`, or
/// `None` if it is not positive definite (a Cholesky pivot <= 0 or not finite).
pub(crate) fn inverse_spd3(b: &[f64]) -> Option<[f64; 6]> {
    let a00 = b[0];
    let a01 = 0.5 * (b[1] + b[3]);
    let a02 = 0.5 * (b[2] + b[6]);
    let a11 = b[4];
    let a12 = 0.5 * (b[5] + b[7]);
    let a22 = b[8];
    // Cholesky pivots decide definiteness robustly; the adjugate gives the inverse.
    let l00 = a00;
    if !positive(l00) {
        return None;
    }
    let p1 = a11 - a01 * a01 / l00;
    if !positive(p1) {
        return None;
    }
    let l21 = a12 - a01 * a02 / l00;
    let p2 = a22 - a02 * a02 / l00 - l21 * l21 / p1;
    if !positive(p2) {
        return None;
    }
    let c00 = a11 * a22 - a12 * a12;
    let c01 = a02 * a12 - a01 * a22;
    let c02 = a01 * a12 - a02 * a11;
    let c11 = a00 * a22 - a02 * a02;
    let c12 = a01 * a02 - a00 * a12;
    let c22 = a00 * a11 - a01 * a01;
    let det = a00 * c00 + a01 * c01 + a02 * c02;
    let inv = 1.0 / det;
    let out = [
        c00 * inv,
        c01 * inv,
        c02 * inv,
        c11 * inv,
        c12 * inv,
        c22 * inv,
    ];
    out.iter().all(|v| v.is_finite()).then_some(out)
}

/// `v > 0`: false for zero, negative and NaN pivots.
pub(crate) fn positive(v: f64) -> bool {
    v > 0.0
}
