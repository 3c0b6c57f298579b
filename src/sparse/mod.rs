//! Block-sparse 3x3 matrices (Bsr3): pattern, values, assembly, bridges and file I/O.
//!
//! A [`Bsr3Pattern`] is built once from a model's connectivity; matrices over it
//! ([`Bsr3`]) share it through an `Arc` and own only their values. Element assembly goes
//! through [`ElementAssembly`], which precomputes where every element block lands, so a
//! per-step assembly is a gather with no search and no allocation. The products run in
//! `largestep-kernels` (SIMD, parallel over fixed row chunks: thread-count independent).

mod assembly;
mod bridge;
pub mod examples;
mod mm;
pub mod order;

pub(crate) use assembly::csr;
pub use assembly::{
    ElementAssembly, LocalLayout, OrderedChunk, RankOneAssembly, Src, VectorGather, ORDERED_CHUNK,
};
pub use bridge::{to_csr, FaerCsc, Triangle};
pub use mm::{read_matrix_market, write_matrix_market, MatrixMarket};

use largestep_kernels::sparse::{bsr3_residual_par, bsr3_spmv_dot_par, Bsr3Ref};
use rayon::prelude::*;
use std::sync::Arc;

/// Errors of the sparse layer: malformed connectivity and malformed matrix files.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SparseError {
    /// An element names a vertex that does not exist.
    #[error("element {element} names vertex {vertex}, but there are only {n} vertices")]
    VertexOutOfRange {
        /// Element index.
        element: usize,
        /// The vertex it names.
        vertex: usize,
        /// Number of vertices.
        n: usize,
    },
    /// The pattern would need more blocks than 32-bit indices address.
    #[error("the pattern needs {blocks} blocks, more than 32-bit block indices address")]
    TooLarge {
        /// Blocks needed.
        blocks: usize,
    },
    /// A Matrix Market file could not be read.
    #[error("{file}:{line}: {}", crate::io::clip(message, crate::io::MAX_MESSAGE))]
    Parse {
        /// File name (or `<memory>`).
        file: String,
        /// 1-based line number.
        line: usize,
        /// What was expected.
        message: String,
    },
    /// I/O failure on a matrix file.
    #[error("{file}: {source}")]
    Io {
        /// File name.
        file: String,
        /// The I/O error.
        source: std::io::Error,
    },
}

/// The block pattern of a square block-sparse matrix with n x n blocks of 3x3.
///
/// Rows hold sorted, distinct block columns; every row holds its diagonal block (mass
/// matrices and preconditioners need it), and the pattern is structurally symmetric.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Bsr3Pattern {
    n: usize,
    row_ptr: Vec<u32>,
    col: Vec<u32>,
    diag: Vec<u32>,
}

impl Bsr3Pattern {
    /// Whether two shared patterns are the same: one allocation, or equal contents.
    pub fn same(a: &Arc<Self>, b: &Arc<Self>) -> bool {
        Arc::ptr_eq(a, b) || **a == **b
    }

    /// The pattern coupling every pair of vertices that share an element (both orders),
    /// plus all diagonal blocks. `K` is the number of vertices per element (2 for springs,
    /// 3 for triangles, 4 for tetrahedra).
    pub fn from_elements<const K: usize>(
        n: usize,
        elements: &[[u32; K]],
    ) -> Result<Self, SparseError> {
        let mut pairs: Vec<u64> = Vec::with_capacity(elements.len() * K * (K - 1) + n);
        for (e, el) in elements.iter().enumerate() {
            for &a in el {
                if a as usize >= n {
                    return Err(SparseError::VertexOutOfRange {
                        element: e,
                        vertex: a as usize,
                        n,
                    });
                }
                for &b in el {
                    if a != b {
                        pairs.push(((a as u64) << 32) | b as u64);
                    }
                }
            }
        }
        pairs.extend((0..n as u64).map(|i| (i << 32) | i));
        pairs.sort_unstable();
        pairs.dedup();
        if pairs.len() > u32::MAX as usize {
            return Err(SparseError::TooLarge {
                blocks: pairs.len(),
            });
        }
        let mut row_ptr = vec![0u32; n + 1];
        let mut col = Vec::with_capacity(pairs.len());
        let mut diag = vec![0u32; n];
        for (k, &p) in pairs.iter().enumerate() {
            let (i, j) = ((p >> 32) as usize, (p & 0xffff_ffff) as u32);
            row_ptr[i + 1] += 1;
            if i == j as usize {
                diag[i] = k as u32;
            }
            col.push(j);
        }
        for i in 0..n {
            row_ptr[i + 1] += row_ptr[i];
        }
        Ok(Self {
            n,
            row_ptr,
            col,
            diag,
        })
    }

    /// A block-diagonal pattern (no coupling), n blocks.
    pub fn diagonal(n: usize) -> Self {
        Self::from_elements::<1>(n, &[]).expect("a diagonal pattern is always valid")
    }

    /// Number of block rows n (the scalar size is 3n).
    pub fn n(&self) -> usize {
        self.n
    }

    /// Number of stored blocks.
    pub fn nnz_blocks(&self) -> usize {
        self.col.len()
    }

    /// Block-row pointers (n + 1).
    pub fn row_ptr(&self) -> &[u32] {
        &self.row_ptr
    }

    /// Block-column indices.
    pub fn col(&self) -> &[u32] {
        &self.col
    }

    /// Slot of the diagonal block of each row.
    pub fn diag_slots(&self) -> &[u32] {
        &self.diag
    }

    /// Slot of block (i, j), if stored.
    pub fn slot(&self, i: usize, j: usize) -> Option<usize> {
        let (s, e) = (self.row_ptr[i] as usize, self.row_ptr[i + 1] as usize);
        self.col[s..e]
            .binary_search(&(j as u32))
            .ok()
            .map(|k| s + k)
    }
}

/// A block-sparse 3x3 matrix: a shared pattern and nine row-major values per block.
#[derive(Clone, Debug)]
pub struct Bsr3 {
    pattern: Arc<Bsr3Pattern>,
    val: Vec<f64>,
}

impl Bsr3 {
    /// The zero matrix over `pattern`.
    pub fn zeros(pattern: Arc<Bsr3Pattern>) -> Self {
        let val = vec![0.0; 9 * pattern.nnz_blocks()];
        Self { pattern, val }
    }

    /// The shared pattern.
    pub fn pattern(&self) -> &Arc<Bsr3Pattern> {
        &self.pattern
    }

    /// Number of block rows n.
    pub fn n(&self) -> usize {
        self.pattern.n
    }

    /// All values (nine per block, row-major, in slot order).
    pub fn values(&self) -> &[f64] {
        &self.val
    }

    /// All values, mutable.
    pub fn values_mut(&mut self) -> &mut [f64] {
        &mut self.val
    }

    /// The kernel view.
    pub fn as_kernel(&self) -> Bsr3Ref<'_> {
        Bsr3Ref::new(
            self.pattern.n,
            &self.pattern.row_ptr,
            &self.pattern.col,
            &self.val,
        )
    }

    /// The nine values of the block in `slot`.
    pub fn block(&self, slot: usize) -> &[f64] {
        &self.val[9 * slot..9 * slot + 9]
    }

    /// The nine values of the block in `slot`, mutable.
    pub fn block_mut(&mut self, slot: usize) -> &mut [f64] {
        &mut self.val[9 * slot..9 * slot + 9]
    }

    /// Sets every value to zero.
    pub fn set_zero(&mut self) {
        self.val.fill(0.0);
    }

    /// `y = A x` (parallel, deterministic). `x`, `y`: component-major, length 3n.
    pub fn spmv(&self, y: &mut [f64], x: &[f64]) {
        bsr3_spmv_dot_par(y, self.as_kernel(), x);
    }

    /// Block row i times x: component c of `(A x)_i` (x component-major, length 3n).
    pub fn row_times(&self, i: usize, x: &[f64]) -> [f64; 3] {
        let n = self.n();
        let (s, e) = (
            self.pattern.row_ptr[i] as usize,
            self.pattern.row_ptr[i + 1] as usize,
        );
        let mut y = [0.0; 3];
        for k in s..e {
            let j = self.pattern.col[k] as usize;
            let b = self.block(k);
            for (r, yr) in y.iter_mut().enumerate() {
                *yr += b[3 * r] * x[j] + b[3 * r + 1] * x[n + j] + b[3 * r + 2] * x[2 * n + j];
            }
        }
        y
    }

    /// `r = b - A x` in one pass (parallel, deterministic).
    pub fn residual(&self, r: &mut [f64], x: &[f64], b: &[f64]) {
        bsr3_residual_par(r, self.as_kernel(), x, b);
    }

    /// `y = A x`, returning `x . y` (parallel, deterministic).
    pub fn spmv_dot(&self, y: &mut [f64], x: &[f64]) -> f64 {
        bsr3_spmv_dot_par(y, self.as_kernel(), x)
    }

    /// `self = sum_k c_k A_k` over matrices sharing this pattern (one pass).
    pub fn assign_lincomb(&mut self, terms: &[(f64, &Bsr3)]) {
        for (_, m) in terms {
            assert!(
                Arc::ptr_eq(&m.pattern, &self.pattern) || *m.pattern == *self.pattern,
                "linear combinations need one pattern"
            );
        }
        match terms {
            [] => self.set_zero(),
            [(c0, a0), rest @ ..] => {
                // In parallel over fixed chunks, each chunk through all terms while it is
                // in cache (elementwise: the same bits on any thread count). Serial, the
                // implicit step's system matrix of the FEM beam of issue 15 took 1.3% of
                // its step on a thread the other waited for.
                const CHUNK: usize = 1 << 14;
                self.val
                    .par_chunks_mut(CHUNK)
                    .enumerate()
                    .for_each(|(k, out)| {
                        let r = k * CHUNK..k * CHUNK + out.len();
                        largestep_kernels::vec::scale_copy(out, *c0, &a0.val[r.clone()]);
                        for (c, a) in rest {
                            largestep_kernels::vec::axpy(out, *c, &a.val[r.clone()]);
                        }
                    });
            }
        }
    }

    /// Adds `d_i I` to every diagonal block i (a lumped mass matrix when `d` holds the
    /// vertex masses).
    pub fn add_diagonal(&mut self, d: &[f64]) {
        self.add_scaled_diagonal(1.0, d);
    }

    /// Adds `s d_i I` to every diagonal block i.
    pub fn add_scaled_diagonal(&mut self, s: f64, d: &[f64]) {
        assert_eq!(d.len(), self.n());
        for (i, &di) in d.iter().enumerate() {
            let slot = self.pattern.diag[i] as usize;
            for c in 0..3 {
                self.val[9 * slot + 4 * c] += s * di;
            }
        }
    }

    /// The dense 3n x 3n matrix, row-major, in the component-major numbering
    /// (row `c n + i` is component c of vertex i). For tests and small problems.
    pub fn to_dense(&self) -> Vec<f64> {
        let n = self.n();
        let m = 3 * n;
        let mut d = vec![0.0; m * m];
        self.for_each_entry(|r, c, v| d[r * m + c] += v);
        d
    }

    /// Calls `f(row, col, value)` for every stored scalar entry, in the component-major
    /// numbering (see [`Bsr3::to_dense`]).
    pub fn for_each_entry(&self, mut f: impl FnMut(usize, usize, f64)) {
        let n = self.n();
        let p = &self.pattern;
        for i in 0..n {
            for k in p.row_ptr[i] as usize..p.row_ptr[i + 1] as usize {
                let j = p.col[k] as usize;
                for r in 0..3 {
                    for c in 0..3 {
                        f(r * n + i, c * n + j, self.val[9 * k + 3 * r + c]);
                    }
                }
            }
        }
    }

    /// Largest `|A_ij - A_ji|` over all entries (0 for a symmetric matrix).
    pub fn max_asymmetry(&self) -> f64 {
        let p = &self.pattern;
        let mut worst = 0.0f64;
        for i in 0..p.n {
            for k in p.row_ptr[i] as usize..p.row_ptr[i + 1] as usize {
                let j = p.col[k] as usize;
                let t = p.slot(j, i).expect("the pattern is structurally symmetric");
                for r in 0..3 {
                    for c in 0..3 {
                        let a = self.val[9 * k + 3 * r + c];
                        let b = self.val[9 * t + 3 * c + r];
                        worst = worst.max((a - b).abs());
                    }
                }
            }
        }
        worst
    }

    /// Builds a matrix from scalar triplets `(row, col, value)` in the component-major
    /// numbering (duplicates summed). The size must be a multiple of 3.
    pub fn from_triplets(
        size: usize,
        triplets: &[(usize, usize, f64)],
    ) -> Result<Self, SparseError> {
        assert!(size.is_multiple_of(3), "a Bsr3 matrix has size 3n");
        let n = size / 3;
        let pairs: Vec<[u32; 2]> = triplets
            .iter()
            .map(|&(r, c, _)| [(r % n) as u32, (c % n) as u32])
            .collect();
        let pattern = Arc::new(Bsr3Pattern::from_elements(n, &pairs)?);
        let mut m = Bsr3::zeros(pattern);
        for &(r, c, v) in triplets {
            let s = m
                .pattern
                .slot(r % n, c % n)
                .expect("every triplet's block is in the pattern");
            m.val[9 * s + 3 * (r / n) + c / n] += v;
        }
        Ok(m)
    }
}
