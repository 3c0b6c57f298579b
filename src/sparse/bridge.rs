//! Bridges from Bsr3 to faer (`SparseColMat`) and nalgebra-sparse (`CsrMatrix`).
//!
//! Scalar numbering is component-major, as everywhere: block (i, j) entry (r, c) is the
//! scalar entry (r n + i, c n + j). The faer matrix is built once per pattern with a map
//! from each CSC position to its Bsr3 value, so a refill is one gather over the values,
//! with no allocation and no search.

use super::{Bsr3, Bsr3Pattern};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat, SymbolicSparseColMatRef};
use nalgebra_sparse::CsrMatrix;

/// Which entries a CSC export keeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Triangle {
    /// Every stored entry.
    Full,
    /// Entries on or below the diagonal (what a Cholesky factorization with
    /// `Side::Lower` reads).
    Lower,
}

/// A faer CSC copy of Bsr3 matrices over one pattern: symbolic structure built once,
/// values refilled in place.
#[derive(Debug)]
pub struct FaerCsc {
    symbolic: SymbolicSparseColMat<usize>,
    val: Vec<f64>,
    map: Vec<usize>,
}

impl FaerCsc {
    /// Builds the CSC structure of `pattern` (values zero).
    pub fn new(pattern: &Bsr3Pattern, triangle: Triangle) -> Self {
        let n = pattern.n();
        let (row_ptr, col) = (pattern.row_ptr(), pattern.col());
        let mut col_ptr = Vec::with_capacity(3 * n + 1);
        let mut row_idx = Vec::new();
        let mut map = Vec::new();
        col_ptr.push(0usize);
        // The pattern is structurally symmetric, so the blocks of block column j are the
        // blocks (i, j) for i in row j's column list; slot(i, j) locates their values.
        for c in 0..3 {
            for j in 0..n {
                let scol = c * n + j;
                for r in 0..3 {
                    for &i in &col[row_ptr[j] as usize..row_ptr[j + 1] as usize] {
                        let i = i as usize;
                        let srow = r * n + i;
                        if triangle == Triangle::Lower && srow < scol {
                            continue;
                        }
                        let slot = pattern.slot(i, j).expect("structurally symmetric");
                        row_idx.push(srow);
                        map.push(9 * slot + 3 * r + c);
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let val = vec![0.0; row_idx.len()];
        let symbolic = SymbolicSparseColMat::new_checked(3 * n, 3 * n, col_ptr, None, row_idx);
        Self { symbolic, val, map }
    }

    /// Copies the values of `a` (which must use the pattern this was built from).
    pub fn refill(&mut self, a: &Bsr3) {
        let src = a.values();
        for (v, &m) in self.val.iter_mut().zip(&self.map) {
            *v = src[m];
        }
    }

    /// Sets every stored value to `f(row, col, index)`, with `index` the position of the
    /// entry among the Bsr3 values (`9 slot + 3 r + c`): for matrices made from several
    /// on the same pattern, or with rows changed (a shifted or constrained copy).
    pub fn refill_with(&mut self, mut f: impl FnMut(usize, usize, usize) -> f64) {
        let col_ptr = self.symbolic.col_ptr();
        let rows = self.symbolic.row_idx();
        for j in 0..col_ptr.len() - 1 {
            let range = col_ptr[j]..col_ptr[j + 1];
            for ((v, &r), &m) in self.val[range.clone()]
                .iter_mut()
                .zip(&rows[range.clone()])
                .zip(&self.map[range])
            {
                *v = f(r, j, m);
            }
        }
    }

    /// The matrix as a faer view.
    pub fn as_ref(&self) -> SparseColMatRef<'_, usize, f64> {
        SparseColMatRef::new(self.symbolic.as_ref(), &self.val)
    }

    /// The symbolic structure.
    pub fn symbolic(&self) -> SymbolicSparseColMatRef<'_, usize> {
        self.symbolic.as_ref()
    }

    /// Number of stored scalar entries.
    pub fn nnz(&self) -> usize {
        self.val.len()
    }
}

/// The matrix as a nalgebra-sparse CSR matrix (component-major numbering).
pub fn to_csr(a: &Bsr3) -> CsrMatrix<f64> {
    let p = a.pattern();
    let n = p.n();
    let (row_ptr, col) = (p.row_ptr(), p.col());
    let vals = a.values();
    let mut offsets = Vec::with_capacity(3 * n + 1);
    let mut cols = Vec::with_capacity(9 * p.nnz_blocks());
    let mut v = Vec::with_capacity(9 * p.nnz_blocks());
    offsets.push(0usize);
    for r in 0..3 {
        for i in 0..n {
            let blocks = row_ptr[i] as usize..row_ptr[i + 1] as usize;
            for c in 0..3 {
                for k in blocks.clone() {
                    cols.push(c * n + col[k] as usize);
                    v.push(vals[9 * k + 3 * r + c]);
                }
            }
            offsets.push(cols.len());
        }
    }
    CsrMatrix::try_from_csr_data(3 * n, 3 * n, offsets, cols, v)
        .expect("a Bsr3 pattern gives a valid CSR matrix")
}
