//! Sparse Cholesky (LL^T) of Bsr3 matrices through faer, with no allocation after setup.
//!
//! Built once per pattern: the lower-triangular CSC copy and its value map
//! ([`FaerCsc`]), faer's symbolic factorization in a fill-reducing order of the vertex
//! graph (`factorize_symbolic_cholesky`; [`FillOrdering`], by default the better of
//! minimum degree and nested dissection), the factor's value buffer (`len_val`) and one scratch
//! buffer sized for both factorization and solve. Each [`SparseCholesky::factorize`] then
//! refills the CSC values and runs `factorize_numeric_llt` into the owned buffers;
//! [`SparseCholesky::solve_in_place`] runs the two triangular solves in the owned scratch.
//! Sequential (`Par::Seq`), so results do not depend on the thread count.
//! [`CholeskyCore::parallel`] (the eigensolver's choice) splits block solves into two
//! column groups solved side by side, split the same way on one thread, so the bits do
//! not change either. (faer's own threads in the supernodal factorization gained nothing
//! on the 36,663-unknown bar: 0.49 s on two threads against 0.45 s on one.)

use super::{SolveError, SolveInfo};
use crate::sparse::order::{dof_permutation, FillOrdering};
use crate::sparse::{Bsr3, Bsr3Pattern, FaerCsc, Triangle};
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltError as DenseLltError;
use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymbolicCholeskyRaw, SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use std::time::Instant;

/// Right-hand sides from which a parallel block solve splits its columns into two groups.
pub(crate) const SPLIT_COLUMNS: usize = 4;

/// A sparse Cholesky factorization reused across numeric refactorizations.
pub struct SparseCholesky {
    csc: FaerCsc,
    core: CholeskyCore,
}

/// faer's symbolic analysis of one scalar pattern with the factor's values and scratch:
/// the part of [`SparseCholesky`] that does not know where the matrix comes from (the
/// smoothed aggregation's coarsest level uses it on its own scalar copy).
pub(crate) struct CholeskyCore {
    symbolic: SymbolicCholesky<usize>,
    l: Vec<f64>,
    mem: MemBuffer,
    /// What `mem` holds room for.
    req: StackReq,
    /// Scratch of the second column group of a split block solve
    /// ([`CholeskyCore::solve_columns`]), empty until one runs.
    mem_split: MemBuffer,
    req_split: StackReq,
    factored: bool,
    /// Use the current rayon pool's threads (see the module docs).
    parallel: bool,
}

impl std::fmt::Debug for SparseCholesky {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SparseCholesky")
            .field("n", &self.core.symbolic.nrows())
            .field("factor_nnz", &self.core.l.len())
            .field("factored", &self.core.factored)
            .finish()
    }
}

impl SparseCholesky {
    /// Symbolic analysis of `pattern` in the default fill-reducing order
    /// ([`FillOrdering::Auto`]); allocates every buffer used later.
    pub fn new(pattern: &Bsr3Pattern) -> Result<Self, SolveError> {
        Self::with_ordering(pattern, FillOrdering::default())
    }

    /// Symbolic analysis of `pattern` with the fill-reducing ordering `ordering`.
    pub fn with_ordering(
        pattern: &Bsr3Pattern,
        ordering: FillOrdering,
    ) -> Result<Self, SolveError> {
        let csc = FaerCsc::new(pattern, Triangle::Lower);
        let core = CholeskyCore::for_pattern(csc.symbolic(), pattern, ordering)?;
        Ok(Self { csc, core })
    }

    /// Number of stored values of the factor L (its fill).
    pub fn factor_nnz(&self) -> usize {
        self.core.l.len()
    }

    /// Floating-point operations of one numeric factorization, `sum_j c_j (c_j + 2)` over
    /// the columns of L with `c_j` entries below the diagonal (the outer-product updates,
    /// counted as two flops per multiply-add, plus the column scaling).
    pub fn factor_flops(&self) -> f64 {
        let col = |c: usize| (c * (c + 2)) as f64;
        match self.core.symbolic.raw() {
            SymbolicCholeskyRaw::Simplicial(s) => s
                .col_ptr()
                .windows(2)
                .map(|w| col((w[1] - w[0]).saturating_sub(1)))
                .sum(),
            SymbolicCholeskyRaw::Supernodal(s) => {
                let (begin, end, rows) = (
                    s.supernode_begin(),
                    s.supernode_end(),
                    s.col_ptr_for_row_idx(),
                );
                (0..s.n_supernodes())
                    .map(|k| {
                        let width = end[k] - begin[k];
                        let below = rows[k + 1] - rows[k];
                        (0..width).map(|j| col(width - 1 - j + below)).sum::<f64>()
                    })
                    .sum()
            }
        }
    }

    /// Numeric factorization of `a` (same pattern as at creation).
    pub fn factorize(&mut self, a: &Bsr3) -> Result<SolveInfo, SolveError> {
        let start = Instant::now();
        self.csc.refill(a);
        self.core.factorize(self.csc.as_ref())?;
        Ok(SolveInfo {
            iterations: 0,
            residual: 0.0,
            seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// Overwrites `b` with `A^-1 b` using the last factorization.
    pub fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), SolveError> {
        self.core.solve_in_place(b)
    }
}

impl CholeskyCore {
    /// Symbolic analysis of the lower triangle `lower` (AMD ordering); allocates every
    /// buffer used later.
    pub(crate) fn new(lower: SymbolicSparseColMatRef<'_, usize>) -> Result<Self, SolveError> {
        Self::with_ordering(lower, SymmetricOrdering::Amd)
    }

    /// Symbolic analysis of `lower`, the lower triangle of a matrix over the block
    /// pattern `pattern` (3 unknowns per vertex), in the order `ordering`.
    pub(crate) fn for_pattern(
        lower: SymbolicSparseColMatRef<'_, usize>,
        pattern: &Bsr3Pattern,
        ordering: FillOrdering,
    ) -> Result<Self, SolveError> {
        match ordering.vertex_order(pattern) {
            None => Self::new(lower),
            Some(order) => {
                let (forward, inverse) = dof_permutation(&order);
                let perm = PermRef::new_checked(&forward, &inverse, lower.nrows());
                Self::with_ordering(lower, SymmetricOrdering::Custom(perm))
            }
        }
    }

    fn with_ordering(
        lower: SymbolicSparseColMatRef<'_, usize>,
        ordering: SymmetricOrdering<'_, usize>,
    ) -> Result<Self, SolveError> {
        let symbolic = factorize_symbolic_cholesky(
            lower,
            Side::Lower,
            ordering,
            CholeskySymbolicParams::default(),
        )
        .map_err(|e| SolveError::Factorization(format!("{e:?}")))?;
        let req = symbolic
            .factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default())
            .or(symbolic.solve_in_place_scratch::<f64>(1, Par::Seq));
        let l = vec![0.0; symbolic.len_val()];
        Ok(Self {
            symbolic,
            l,
            mem: MemBuffer::new(req),
            req,
            mem_split: MemBuffer::new(StackReq::empty()),
            req_split: StackReq::empty(),
            factored: false,
            parallel: false,
        })
    }

    /// Splits block solves over the threads of the current rayon pool (module docs).
    pub(crate) fn parallel(mut self) -> Self {
        self.parallel = true;
        self
    }

    /// Grows `mem` (held requirement `req`) to hold `need`.
    fn reserve(mem: &mut MemBuffer, req: &mut StackReq, need: StackReq) {
        if req.or(need) != *req {
            *req = req.or(need);
            *mem = MemBuffer::new(*req);
        }
    }

    /// Numeric factorization of the lower triangle `lower` (the pattern given to
    /// [`CholeskyCore::new`]).
    pub(crate) fn factorize(
        &mut self,
        lower: SparseColMatRef<'_, usize, f64>,
    ) -> Result<(), SolveError> {
        self.factored = false;
        let res = self.symbolic.factorize_numeric_llt(
            &mut self.l,
            lower,
            Side::Lower,
            Default::default(),
            Par::Seq,
            MemStack::new(&mut self.mem),
            Default::default(),
        );
        match res {
            Ok(_) => {
                if !self.l.iter().all(|v| v.is_finite()) {
                    return Err(SolveError::NonFinite {
                        what: "Cholesky factor",
                        iteration: 0,
                    });
                }
                self.factored = true;
                Ok(())
            }
            Err(DenseLltError::NonPositivePivot { index }) => {
                Err(SolveError::NotPositiveDefinite {
                    what: "Cholesky pivot (in fill-reducing order)",
                    at: index,
                    value: f64::NAN,
                })
            }
        }
    }

    /// Overwrites the `k` columns of `b` (column-major, `n k` values) with `A^-1 b`: one
    /// pass over the factor for all of them (the triangular solves read the factor from
    /// memory, so k columns cost far less than k single solves). Grows the scratch buffer
    /// the first time k exceeds what it holds.
    ///
    /// Parallel ([`CholeskyCore::parallel`]) with at least [`SPLIT_COLUMNS`] columns, the
    /// columns go in two groups, each solved in its own pass over the factor on its own
    /// thread (`rayon::join`; one after the other on one thread, so the bits do not
    /// depend on the thread count). The passes are latency-bound (a quarter of one
    /// thread's triad bandwidth on the 36,663-unknown bar), so two run side by side in
    /// little more than the time of one.
    pub(crate) fn solve_columns(&mut self, b: &mut [f64], k: usize) -> Result<(), SolveError> {
        assert!(
            self.factored,
            "solve_columns needs a successful factorize first"
        );
        let n = self.symbolic.nrows();
        assert_eq!(b.len(), n * k, "right-hand sides length");
        let llt = LltRef::new(&self.symbolic, &self.l);
        if self.parallel && k >= SPLIT_COLUMNS {
            let k1 = k / 2;
            let need = |k| self.symbolic.solve_in_place_scratch::<f64>(k, Par::Seq);
            let (need0, need1) = (need(k1), need(k - k1));
            Self::reserve(&mut self.mem, &mut self.req, need0);
            Self::reserve(&mut self.mem_split, &mut self.req_split, need1);
            let (b0, b1) = b.split_at_mut(n * k1);
            let (mem0, mem1) = (&mut self.mem, &mut self.mem_split);
            let solve = |b: &mut [f64], cols: usize, mem: &mut MemBuffer| {
                llt.solve_in_place_with_conj(
                    Conj::No,
                    MatMut::from_column_major_slice_mut(b, n, cols),
                    Par::Seq,
                    MemStack::new(mem),
                )
            };
            rayon::join(|| solve(b0, k1, mem0), || solve(b1, k - k1, mem1));
        } else {
            let need = self.symbolic.solve_in_place_scratch::<f64>(k, Par::Seq);
            Self::reserve(&mut self.mem, &mut self.req, need);
            llt.solve_in_place_with_conj(
                Conj::No,
                MatMut::from_column_major_slice_mut(b, n, k),
                Par::Seq,
                MemStack::new(&mut self.mem),
            );
        }
        if b.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(SolveError::NonFinite {
                what: "Cholesky solution",
                iteration: 0,
            })
        }
    }

    /// Overwrites `b` with `A^-1 b` using the last factorization.
    pub(crate) fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), SolveError> {
        let n = self.symbolic.nrows();
        assert_eq!(b.len(), n, "right-hand side length");
        self.solve_columns(b, 1)
    }
}
