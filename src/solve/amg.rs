//! Smoothed aggregation multigrid with rigid-body modes: the PCG preconditioner for 3-D
//! elasticity (the FEM's implicit and static systems), whose iteration count stays
//! nearly flat as the mesh is refined.
//!
//! Why not [`super::Multigrid`]: its coarse spaces carry translations only and its
//! prolongator is piecewise constant. For 3-D elasticity the near null space of `K` also
//! holds the three infinitesimal rotations, and a piecewise-constant coarse space
//! represents smooth bending badly. On the cantilever's backward Euler matrices (567,
//! 3,075 and 19,683 unknowns, PCG to 1e-6) it took 86, 155 and 237 iterations; pyamg
//! 5.4.1's smoothed aggregation with the rotations added took 10, 10 and 12 (two levels).
//!
//! The method (Vaněk, Mandel and Brezina, "Algebraic multigrid by smoothed aggregation
//! for second and fourth order elliptic problems", Computing 56, 1996; the rigid-body
//! modes as in Vaněk, Brezina and Mandel, "Convergence of algebraic multigrid based on
//! smoothed aggregation", Numer. Math. 88, 2001):
//!
//! - **Aggregates** of the matrix graph, as [`super::Multigrid`] makes them (a seed with
//!   all its neighbours); they depend only on the pattern and are made once.
//! - **Near null space `B`** on the fine level: for vertex `i` of aggregate `a`, the three
//!   translations and the three rotations `e_k x (x_i - c_a)` about the aggregate's
//!   centroid, projected by the constraint filter (`S_i B_i`): pinned vertices add
//!   nothing, contact vertices only their free directions. Positions come from
//!   [`SmoothedAggregation::set_coordinates`]; without them the rotations are left out.
//! - **Tentative prolongator `T`:** per aggregate, the QR factorisation of its rows of
//!   `B` (modified Gram-Schmidt, twice): `T` holds Q, and R is the next level's `B`, so
//!   each coarse node has six unknowns. A column that vanishes (a pinned aggregate, a
//!   line of vertices with no rotation about it) stays zero and its unknown gets a unit
//!   diagonal: it is decoupled, and `P` maps it to nothing.
//! - **Smoothed prolongator** `P = (I - omega D^-1 A) T` with `D` the 3x3 (fine) or 6x6
//!   (coarse) diagonal blocks and `omega = 4 / (3 lambda)`, `lambda` the largest
//!   eigenvalue of `D^-1 A` from ten power iterations.
//! - **Coarse matrix** `P^T A P`, as `Q = A P` and then `P^T Q`, each row gathered in a fixed
//!   order through slot maps made with the pattern (the same bits on any thread count).
//!   `P^T Q` forms the blocks on and right of the diagonal only; those left of it are
//!   copied as their transposes (half of the larger product's work).
//! - **Smoother:** Chebyshev polynomials of degree [`DEGREE`] (1) in `D^-1 A` on the
//!   interval `[1.1 lambda / 30, 1.1 lambda]` (Adams, Brezina, Hu and Tuminaro, "Parallel
//!   multigrid smoothing: polynomial versus Gauss-Seidel", J. Comput. Phys. 188, 2003):
//!   as parallel as Jacobi, symmetric (so the V-cycle is, as CG needs). Each degree costs
//!   two products with the level's matrix a cycle, and the cycle streams its matrices
//!   from memory: degree 1 reads the fine matrix 3 times a PCG iteration (with PCG's own
//!   product) instead of 5, for about a fifth more iterations on tight solves and almost
//!   none under inexact Newton (see [`DEGREE`]).
//! - **The fine level's V-cycle products in `f32`**, as in [`super::Multigrid`]: the
//!   cycle's residuals on the fine level read a copy of the fine matrix rounded to `f32`
//!   (made by each setup and [`SmoothedAggregation::refresh_fine`]; the `f64` values when
//!   one overflows). The cycle is then the exact one for the rounded matrix, still
//!   symmetric positive definite, while PCG's own products use the `f64` matrix. The
//!   cycle streams from memory (on the beam of issue 15 it reads 84 MB, over twice this
//!   VM's L3, at 87-96% of the triad bandwidth), so the 29% fewer bytes took it from
//!   4.2-4.7 to 3.4-3.7 ms (`fem/sa/vcycle`, alternating builds); the PCG iteration counts
//!   of the refinement test did not change.
//! - **Coarsest level** (at most [`COARSE_DOFS`] unknowns, or where aggregation stops
//!   shrinking): faer's sparse Cholesky, its symbolic analysis made once.

use super::{
    cholesky::CholeskyCore,
    dense::{inverse_spd3, positive},
    filter::Filter,
    multigrid::{aggregate, fine_residual, round_to_f32, rounded},
    SolveError,
};
use crate::sparse::{csr, Bsr3, Bsr3Pattern};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use largestep_kernels::par::{chunk_count, chunk_range};
use largestep_kernels::sparse::{BlockValue, Bsr3Ref};
use largestep_kernels::vec as kv;
use rayon::prelude::*;
use std::sync::Arc;

/// Unknowns per coarse node: three translations and three rotations.
const M: usize = 6;
/// Values per coarse block.
const MM: usize = M * M;

/// Largest level solved directly by sparse Cholesky (unknowns).
pub const COARSE_DOFS: usize = 2000;

/// Most levels, the fine one included.
const MAX_LEVELS: usize = 10;

/// Power iterations for the largest eigenvalue of `D^-1 A` (as ML and MueLu use).
const POWER_ITERATIONS: usize = 10;

/// Chebyshev smoother: degree, the ratio of the interval's ends, and the factor on the
/// power estimate (which approaches the largest eigenvalue from below).
///
/// Degree 1 against 2, measured on the 100 x 10 x 10 beam of issue 15 (2 threads, six
/// rounds alternating builds, 120 steps each, the bench's `-rate-f32-skip` settings):
/// 3.97 PCG iterations a step instead of 3.91, mean step 16.2-21.1 ms instead of
/// 17.9-25.1 (1.4-4.5 ms less in every round); with Newton's systems solved to 1e-6
/// (`-keep-1e-3`), 31.2 PCG iterations a step instead of 27.2 and 55.6 ms instead of
/// 69.1. Alone, a system `M - h^2 K` of that beam solved from zero to 1e-10: 23 iterations
/// instead of 19 (h = 1/60 s), 28 instead of 24 (h = 1 s), each solve faster (62 against
/// 77 ms and 75 against 84, setup included). Degree 1 on a narrower interval (ratio 3,
/// Jacobi's classic weight `4 / (3 lambda)`) took more iterations and time. The
/// refinement test's counts stay flat (17, 15, 17 from 567 to 19,683 unknowns, against
/// 12, 13, 14 at degree 2).
const DEGREE: usize = 1;
const RATIO: f64 = 30.0;
const BOOST: f64 = 1.1;

/// Nodes per parallel task.
const ROWS: usize = 128;

/// A block sparse matrix with `M x M` blocks (row-major) in CSR over nodes.
#[derive(Clone, Debug, Default)]
struct Blocks {
    row_ptr: Vec<u32>,
    col: Vec<u32>,
    /// Slot of each row's diagonal block.
    diag: Vec<u32>,
    val: Vec<f64>,
    /// `val` rounded to `f32` for the V-cycle's smoothing, made by each setup (empty on
    /// the coarsest level, solved directly, and where a value does not fit in `f32`:
    /// the cycle then reads `val`).
    val32: Vec<f32>,
}

impl Blocks {
    fn n(&self) -> usize {
        self.row_ptr.len() - 1
    }
}

/// One level below the fine one, with the transfer from the level above (`BF`
/// unknowns per node there: 3 on the fine level, [`M`] below it).
#[derive(Clone, Debug, Default)]
struct Level {
    /// Aggregate of each node above, and the nodes above in each aggregate.
    agg: Vec<u32>,
    member_ptr: Vec<u32>,
    members: Vec<u32>,
    /// Tentative prolongator: one `BF x M` block per node above.
    t: Vec<f64>,
    /// This level's near null space: one `M x M` block (the aggregate's R) per node.
    nullspace: Vec<f64>,
    /// Smoothed prolongator, `BF x M` blocks in CSR over the nodes above.
    p_ptr: Vec<u32>,
    p_col: Vec<u32>,
    p: Vec<f64>,
    /// `p` rounded to `f32` for the V-cycle's transfers, made by each setup (empty where
    /// a value does not fit in `f32`: the cycle then reads `p`).
    p32: Vec<f32>,
    /// Row (node above) of each slot of P.
    p_row: Vec<u32>,
    /// For each block slot `(i, k)` of the matrix above, P's slot `(i, agg[k])`.
    a_to_p: Vec<u32>,
    /// P by columns: the slots of P in each coarse node's column, by increasing row.
    pt_ptr: Vec<u32>,
    pt_slot: Vec<u32>,
    /// `Q = A P` (matrix above times P), `BF x M` blocks in CSR over the nodes above.
    q_ptr: Vec<u32>,
    q: Vec<f64>,
    /// Row i of Q: for each slot `(i, k)` of A and each slot of P's row k, in order, the
    /// slot of Q it adds to (from `q_map_ptr[i]`).
    q_map_ptr: Vec<u32>,
    q_map: Vec<u32>,
    /// Row I of `P^T Q`, its upper blocks: for each slot of P's column I (the k-th in
    /// `pt_slot`) and each slot of Q's row there from `q_from[k]` (the first right of or
    /// at column I), in order, the slot of this level's matrix it adds to (from
    /// `c_map_ptr[I]`).
    c_map_ptr: Vec<u32>,
    c_map: Vec<u32>,
    q_from: Vec<u32>,
    /// The blocks left of the diagonal, each with the slot of its transpose.
    c_mirror: Vec<(u32, u32)>,
    /// This level's matrix.
    a: Blocks,
    /// The restriction's partial sums: one coarse vector per task of
    /// [`RESTRICT_ROWS`] rows above.
    partial: Vec<f64>,
    /// Inverse diagonal blocks (`M x M`) and the largest eigenvalue of `D^-1 A` (none on
    /// the coarsest level).
    dinv: Vec<f64>,
    lambda: f64,
    x: Vec<f64>,
    b: Vec<f64>,
    r: Vec<f64>,
    d: Vec<f64>,
}

/// The coarsest level's sparse Cholesky: the lower triangle of its matrix in scalar CSC
/// form (unknown `M i + c` for component c of node i) and where each value comes from.
struct Direct {
    lower: SymbolicSparseColMat<usize>,
    val: Vec<f64>,
    map: Vec<usize>,
    core: CholeskyCore,
}

impl std::fmt::Debug for Direct {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Direct")
            .field("n", &self.lower.nrows())
            .field("nnz", &self.val.len())
            .finish()
    }
}

impl Clone for Direct {
    fn clone(&self) -> Self {
        Direct::new(&self.lower, self.map.clone()).expect("the pattern was analysed before")
    }
}

impl Direct {
    fn new(lower: &SymbolicSparseColMat<usize>, map: Vec<usize>) -> Result<Self, SolveError> {
        Ok(Self {
            core: CholeskyCore::new(lower.as_ref())?,
            lower: lower.clone(),
            val: vec![0.0; map.len()],
            map,
        })
    }

    /// The scalar lower triangle of `a` and its symbolic analysis.
    fn of(a: &Blocks) -> Result<Self, SolveError> {
        let n = a.n();
        let mut col_ptr = vec![0usize];
        let (mut row_idx, mut map) = (Vec::new(), Vec::new());
        // Columns of the block column j are the rows of block row j (symmetric pattern):
        // entry (M i + r, M j + c) of block (i, j) lies in block (j, i), entry (c, r).
        for j in 0..n {
            for c in 0..M {
                for s in a.row_ptr[j] as usize..a.row_ptr[j + 1] as usize {
                    let i = a.col[s] as usize;
                    for r in 0..M {
                        if M * i + r >= M * j + c {
                            row_idx.push(M * i + r);
                            map.push(MM * s + M * c + r);
                        }
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let lower = SymbolicSparseColMat::new_checked(M * n, M * n, col_ptr, None, row_idx);
        Self::new(&lower, map)
    }

    fn factorize(&mut self, a: &Blocks) -> Result<(), SolveError> {
        for (v, &m) in self.val.iter_mut().zip(&self.map) {
            *v = a.val[m];
        }
        self.core
            .factorize(SparseColMatRef::new(self.lower.as_ref(), &self.val))
    }
}

/// The smoothed aggregation hierarchy for one fine pattern, with its buffers (see the
/// module docs). The pattern-dependent part (aggregates, patterns, slot maps, the
/// coarsest level's symbolic Cholesky) is built on the first [`SmoothedAggregation::setup`]
/// for a pattern; later setups recompute values only.
#[derive(Clone, Debug, Default)]
pub struct SmoothedAggregation {
    fine: Option<Arc<Bsr3Pattern>>,
    /// Vertex positions, component-major (empty: translations only).
    coords: Vec<f64>,
    /// The fine level's inverse diagonal blocks (3x3, row-major) and eigenvalue estimate.
    dinv: Vec<f64>,
    lambda: f64,
    /// The fine matrix's values rounded to `f32` for the V-cycle's fine-level products
    /// (empty when a value does not fit in `f32`; see [`SmoothedAggregation::setup`]).
    fine32: Vec<f32>,
    r: Vec<f64>,
    d: Vec<f64>,
    levels: Vec<Level>,
    direct: Option<Direct>,
}

impl SmoothedAggregation {
    /// An empty hierarchy (built on first use).
    pub fn new() -> Self {
        Self::default()
    }

    /// `a` with the values of the `f32` copy the last setup made of it (`None` when a
    /// value did not fit in `f32`, or before a setup).
    pub(super) fn fine32<'a>(&'a self, a: &'a Bsr3) -> Option<Bsr3Ref<'a, f32>> {
        rounded(&self.fine32, a)
    }

    /// The vertex positions (component-major, `3n`) that the rotations of the near null
    /// space are taken about; used by the next [`SmoothedAggregation::setup`]. Copied,
    /// into a buffer reused across calls.
    pub fn set_coordinates(&mut self, x: &[f64]) {
        self.coords.clear();
        self.coords.extend_from_slice(x);
    }

    /// Unknowns per level, fine first (empty before the first setup).
    pub fn level_sizes(&self) -> Vec<usize> {
        self.fine
            .iter()
            .map(|p| 3 * p.n())
            .chain(self.levels.iter().map(|l| M * l.a.n()))
            .collect()
    }

    /// Stored values of all coarse matrices over those of the fine one (the operator
    /// complexity, less one).
    pub fn coarse_fraction(&self, a: &Bsr3) -> f64 {
        let coarse: usize = self.levels.iter().map(|l| l.a.val.len()).sum();
        coarse as f64 / a.values().len().max(1) as f64
    }

    /// Bytes one V-cycle reads at least: each smoothed level's matrix `2 DEGREE` times
    /// (the Chebyshev sweeps and residuals; the fine one's `f32` copy when there is
    /// one), the prolongators twice (restriction and prolongation).
    pub fn cycle_bytes(&self, a: &Bsr3) -> usize {
        // Values as the cycle reads them (f32 where rounded), and a column index a block.
        let matrix = |values: usize, rounded: bool, blocks: usize| {
            (if rounded { 4 } else { 8 }) * values + 4 * blocks
        };
        let fine =
            rounded(&self.fine32, a).map_or(a.as_kernel().spmv_bytes(), |a32| a32.spmv_bytes());
        let mut bytes = 2 * DEGREE * fine;
        let smoothed = self.levels.len().saturating_sub(1);
        for (l, level) in self.levels.iter().enumerate() {
            if l < smoothed {
                let a = &level.a;
                bytes += 2 * DEGREE * matrix(a.val.len(), !a.val32.is_empty(), a.col.len());
            }
            let (p, rounded) = (level.p.len(), !level.p32.is_empty());
            bytes += 2 * matrix(p, rounded, level.p_col.len());
        }
        bytes
    }

    /// Builds the hierarchy for `a`'s pattern if it is new, then every level's values
    /// from `a`'s. `a` must already be projected by `filter`
    /// ([`Filter::project_matrix`]) when there is one.
    pub fn setup(&mut self, a: &Bsr3, filter: Option<&Filter>) -> Result<(), SolveError> {
        let same = self
            .fine
            .as_ref()
            .is_some_and(|p| Bsr3Pattern::same(p, a.pattern()));
        if !same {
            self.build(a.pattern().clone())?;
        }
        let n = a.n();
        fine_dinv(a, &mut self.dinv)?;
        round_to_f32(a.values(), &mut self.fine32);
        self.lambda = largest_eigenvalue(
            &FineOp {
                a,
                val32: &self.fine32,
                dinv: &self.dinv,
            },
            &mut self.r,
            &mut self.d,
            filter,
        );
        let count = self.levels.len();
        for l in 0..count {
            let (above, below) = self.levels.split_at_mut(l);
            let level = &mut below[0];
            match above.last() {
                None => {
                    fine_nullspace(level, &self.coords, n, filter);
                    let view = View {
                        row_ptr: a.pattern().row_ptr(),
                        col: a.pattern().col(),
                        val: a.values(),
                    };
                    coarsen::<3>(level, view, &self.dinv, self.lambda);
                }
                Some(up) => {
                    coarse_nullspace(level, &up.nullspace);
                    let view = View {
                        row_ptr: &up.a.row_ptr,
                        col: &up.a.col,
                        val: &up.a.val,
                    };
                    coarsen::<M>(level, view, &up.dinv, up.lambda);
                }
            }
            round_to_f32(&level.p, &mut level.p32);
            if l + 1 < count {
                // The coarsest level is solved directly, from `val`: no copy.
                round_to_f32(&level.a.val, &mut level.a.val32);
                coarse_dinv(&level.a, &mut level.dinv)?;
                level.lambda = largest_eigenvalue(
                    &CoarseOp {
                        a: &level.a,
                        dinv: &level.dinv,
                    },
                    &mut level.r,
                    &mut level.d,
                    None,
                );
            }
        }
        if let (Some(direct), Some(last)) = (self.direct.as_mut(), self.levels.last()) {
            direct.factorize(&last.a)?;
        }
        Ok(())
    }

    /// For `a` solved again after its filter lost a few constraints: remakes the fine
    /// level's diagonal blocks from `a` and keeps the rest (any fixed symmetric positive
    /// definite preconditioner leaves PCG exact).
    pub fn refresh_fine(&mut self, a: &Bsr3, filter: Option<&Filter>) -> Result<(), SolveError> {
        if self.fine.is_none() {
            return self.setup(a, filter);
        }
        round_to_f32(a.values(), &mut self.fine32);
        fine_dinv(a, &mut self.dinv)
    }

    fn build(&mut self, fine: Arc<Bsr3Pattern>) -> Result<(), SolveError> {
        self.levels.clear();
        self.direct = None;
        let n = fine.n();
        self.r = vec![0.0; 3 * n];
        self.d = vec![0.0; 3 * n];
        self.dinv = vec![0.0; 9 * n];
        // The matrix pattern of the level above, and the graph its aggregates are made
        // on: the same on the fine level; below, the graph of aggregates that touch (the
        // pattern of T^T A T), not the smoothed coarse matrix's, whose neighbourhoods are
        // two to three aggregates wide and would make aggregates far too large.
        let (mut row_ptr, mut col) = (fine.row_ptr().to_vec(), fine.col().to_vec());
        let (mut graph_ptr, mut graph) = (row_ptr.clone(), col.clone());
        let mut bf = 3;
        // At least one coarse level, however small the fine one: a V-cycle without one
        // is only a smoother.
        while (self.levels.is_empty() || bf * (row_ptr.len() - 1) > COARSE_DOFS)
            && self.levels.len() + 1 < MAX_LEVELS
        {
            let nodes = row_ptr.len() - 1;
            let (agg, nc) = aggregate(&graph_ptr, &graph);
            // A level that barely shrinks (a mesh of isolated vertices) ends the hierarchy.
            if 5 * nc > 4 * nodes {
                break;
            }
            let mut pairs: Vec<(usize, u32)> = Vec::with_capacity(graph.len());
            for i in 0..nodes {
                for &k in &graph[graph_ptr[i] as usize..graph_ptr[i + 1] as usize] {
                    pairs.push((agg[i] as usize, agg[k as usize]));
                }
            }
            pairs.sort_unstable();
            pairs.dedup();
            (graph_ptr, graph) = csr(nc, pairs.into_iter());
            let level = Level::symbolic(&row_ptr, &col, agg, nc, bf);
            row_ptr.clone_from(&level.a.row_ptr);
            col.clone_from(&level.a.col);
            self.levels.push(level);
            bf = M;
        }
        if let Some(last) = self.levels.last() {
            self.direct = Some(Direct::of(&last.a)?);
        }
        self.fine = Some(fine);
        Ok(())
    }

    /// `z = M^-1 r`: one V-cycle on the fine matrix `a` (the one given to
    /// [`SmoothedAggregation::setup`]) from a zero guess. With a filter, `r` must be
    /// filtered and `z` comes out filtered.
    pub fn apply(&mut self, a: &Bsr3, r: &[f64], z: &mut [f64], filter: Option<&Filter>) {
        let fine = FineOp {
            a,
            val32: &self.fine32,
            dinv: &self.dinv,
        };
        chebyshev(&fine, self.lambda, z, r, &mut self.r, &mut self.d, true);
        if !self.levels.is_empty() {
            fine.residual(&mut self.r, z, r);
            if let Some(f) = filter {
                f.apply(&mut self.r);
            }
            restrict::<3>(&mut self.levels[0], &self.r, Layout::Components(a.n()));
            let last = self.levels.len() - 1;
            for l in 0..last {
                let (above, below) = self.levels.split_at_mut(l + 1);
                let c = &mut above[l];
                let op = CoarseOp {
                    a: &c.a,
                    dinv: &c.dinv,
                };
                chebyshev(&op, c.lambda, &mut c.x, &c.b, &mut c.r, &mut c.d, true);
                coarse_residual(&c.a, &mut c.r, &c.x, &c.b);
                restrict::<M>(&mut below[0], &c.r, Layout::Nodes);
            }
            let bottom = &mut self.levels[last];
            bottom.x.copy_from_slice(&bottom.b);
            if let Some(d) = self.direct.as_mut() {
                // The factor was made by setup; a failure there would have been reported.
                if d.core.solve_in_place(&mut bottom.x).is_err() {
                    bottom.x.fill(0.0);
                }
            }
            for l in (0..last).rev() {
                let (above, below) = self.levels.split_at_mut(l + 1);
                let c = &mut above[l];
                prolong::<M>(&below[0], &mut c.x, Layout::Nodes);
                let op = CoarseOp {
                    a: &c.a,
                    dinv: &c.dinv,
                };
                chebyshev(&op, c.lambda, &mut c.x, &c.b, &mut c.r, &mut c.d, false);
            }
            prolong::<3>(&self.levels[0], z, Layout::Components(a.n()));
            if let Some(f) = filter {
                f.apply(z);
            }
            chebyshev(&fine, self.lambda, z, r, &mut self.r, &mut self.d, false);
        }
        if let Some(f) = filter {
            f.apply(z);
        }
    }
}

impl Level {
    /// The patterns and slot maps of the level made of aggregates `agg` (`nc` of them)
    /// of the graph `(row_ptr, col)` with `bf` unknowns per node; values zero.
    fn symbolic(row_ptr: &[u32], col: &[u32], agg: Vec<u32>, nc: usize, bf: usize) -> Self {
        let n = row_ptr.len() - 1;
        let row = |i: usize| row_ptr[i] as usize..row_ptr[i + 1] as usize;
        let (member_ptr, members) = csr(
            nc,
            agg.iter().enumerate().map(|(i, &a)| (a as usize, i as u32)),
        );
        // P's row i: the aggregates of i's neighbours.
        let mut p_ptr = vec![0u32];
        let mut p_col = Vec::new();
        let mut a_to_p = Vec::with_capacity(col.len());
        let mut buf = Vec::new();
        for i in 0..n {
            buf.clear();
            buf.extend(col[row(i)].iter().map(|&k| agg[k as usize]));
            buf.sort_unstable();
            buf.dedup();
            let base = p_col.len();
            for &k in &col[row(i)] {
                let at = buf.binary_search(&agg[k as usize]).expect("listed above");
                a_to_p.push((base + at) as u32);
            }
            p_col.extend_from_slice(&buf);
            p_ptr.push(p_col.len() as u32);
        }
        let mut p_row = vec![0u32; p_col.len()];
        for i in 0..n {
            for s in p_ptr[i]..p_ptr[i + 1] {
                p_row[s as usize] = i as u32;
            }
        }
        let (pt_ptr, pt_slot) = csr(
            nc,
            p_col
                .iter()
                .enumerate()
                .map(|(s, &c)| (c as usize, s as u32)),
        );
        let prow = |i: usize| p_ptr[i] as usize..p_ptr[i + 1] as usize;
        // Q = A P: row i gathers P's rows of i's neighbours.
        let (mut q_ptr, mut q_col) = (vec![0u32], Vec::new());
        let (mut q_map_ptr, mut q_map) = (vec![0u32], Vec::new());
        for i in 0..n {
            buf.clear();
            for &k in &col[row(i)] {
                buf.extend_from_slice(&p_col[prow(k as usize)]);
            }
            buf.sort_unstable();
            buf.dedup();
            let base = q_col.len();
            for &k in &col[row(i)] {
                for &c in &p_col[prow(k as usize)] {
                    q_map.push((base + buf.binary_search(&c).expect("listed above")) as u32);
                }
            }
            q_col.extend_from_slice(&buf);
            q_ptr.push(q_col.len() as u32);
            q_map_ptr.push(q_map.len() as u32);
        }
        // P^T Q: row I gathers Q's rows of the nodes in P's column I, from their first
        // column at or right of I (Q's rows are sorted): the upper blocks only.
        let (mut c_ptr, mut c_col, mut diag) = (vec![0u32], Vec::new(), Vec::with_capacity(nc));
        let (mut c_map_ptr, mut c_map, mut q_from) = (vec![0u32], Vec::new(), Vec::new());
        for ci in 0..nc {
            buf.clear();
            for &s in &pt_slot[pt_ptr[ci] as usize..pt_ptr[ci + 1] as usize] {
                let i = p_row[s as usize] as usize;
                buf.extend_from_slice(&q_col[q_ptr[i] as usize..q_ptr[i + 1] as usize]);
            }
            buf.sort_unstable();
            buf.dedup();
            let base = c_col.len();
            for &s in &pt_slot[pt_ptr[ci] as usize..pt_ptr[ci + 1] as usize] {
                let i = p_row[s as usize] as usize;
                let qrow = &q_col[q_ptr[i] as usize..q_ptr[i + 1] as usize];
                let from = qrow.partition_point(|&c| (c as usize) < ci);
                q_from.push(q_ptr[i] + from as u32);
                for &c in &qrow[from..] {
                    c_map.push((base + buf.binary_search(&c).expect("listed above")) as u32);
                }
            }
            let d = buf
                .binary_search(&(ci as u32))
                .expect("a node's aggregate is its neighbour");
            diag.push((base + d) as u32);
            c_col.extend_from_slice(&buf);
            c_ptr.push(c_col.len() as u32);
            c_map_ptr.push(c_map.len() as u32);
        }
        // Each block left of the diagonal and the slot of its transpose (the pattern is
        // symmetric: P^T A P with A's pattern symmetric).
        let mut c_mirror = Vec::new();
        for ci in 0..nc {
            for s in c_ptr[ci] as usize..c_ptr[ci + 1] as usize {
                let cj = c_col[s] as usize;
                if cj < ci {
                    let row = &c_col[c_ptr[cj] as usize..c_ptr[cj + 1] as usize];
                    let t = row
                        .binary_search(&(ci as u32))
                        .expect("the coarse pattern is symmetric");
                    c_mirror.push((s as u32, c_ptr[cj] + t as u32));
                }
            }
        }
        let nnz_c = c_col.len();
        Self {
            t: vec![0.0; bf * M * n],
            nullspace: vec![0.0; MM * nc],
            p: vec![0.0; bf * M * p_col.len()],
            p32: Vec::new(),
            q: vec![0.0; bf * M * q_col.len()],
            agg,
            member_ptr,
            members,
            p_ptr,
            p_col,
            p_row,
            a_to_p,
            pt_ptr,
            pt_slot,
            q_ptr,
            q_map_ptr,
            q_map,
            c_map_ptr,
            c_map,
            q_from,
            c_mirror,
            a: Blocks {
                row_ptr: c_ptr,
                col: c_col,
                diag,
                val: vec![0.0; MM * nnz_c],
                val32: Vec::new(),
            },
            dinv: vec![0.0; MM * nc],
            lambda: 0.0,
            x: vec![0.0; M * nc],
            b: vec![0.0; M * nc],
            r: vec![0.0; M * nc],
            d: vec![0.0; M * nc],
            partial: vec![0.0; chunk_count(n, RESTRICT_ROWS) * M * nc],
        }
    }
}

/// A borrowed block matrix with `B x B` blocks (row-major) in CSR over nodes.
#[derive(Clone, Copy)]
struct View<'a> {
    row_ptr: &'a [u32],
    col: &'a [u32],
    val: &'a [f64],
}

/// How a level's vectors are laid out: the fine level component-major (`c n + i`), the
/// coarse ones node-major (`M i + c`).
#[derive(Clone, Copy)]
enum Layout {
    Components(usize),
    Nodes,
}

impl Layout {
    #[inline]
    fn at(self, i: usize, c: usize, b: usize) -> usize {
        match self {
            Layout::Components(n) => c * n + i,
            Layout::Nodes => b * i + c,
        }
    }
}

/// The fine level's near null space, orthonormalised into the first level's tentative
/// prolongator: the rows `S_i [I | e_k x (x_i - c)]` of each aggregate's vertices.
fn fine_nullspace(level: &mut Level, coords: &[f64], n: usize, filter: Option<&Filter>) {
    let rotations = coords.len() == 3 * n && n > 0;
    // Rotations about one point for all aggregates (the centroid, for scale), so that the
    // columns are the body's rigid motions and each coarse node's R expresses the same
    // six: about each aggregate's own centroid, the coarse near null space would differ
    // from node to node by translations, and levels below the first would lose the
    // rotations (on the cantilever with three levels: 49 iterations instead of about 20).
    let mut c = [0.0; 3];
    if rotations {
        for (k, ck) in c.iter_mut().enumerate() {
            *ck = coords[k * n..(k + 1) * n].iter().sum::<f64>() / n as f64;
        }
    }
    for a in 0..level.member_ptr.len() - 1 {
        let members =
            &level.members[level.member_ptr[a] as usize..level.member_ptr[a + 1] as usize];
        for &i in members {
            let i = i as usize;
            let mut b = [0.0; 18];
            for r in 0..3 {
                b[M * r + r] = 1.0;
            }
            if rotations {
                let d = [
                    coords[i] - c[0],
                    coords[n + i] - c[1],
                    coords[2 * n + i] - c[2],
                ];
                // Columns 3..6: e_x x d = (0, -dz, dy), e_y x d = (dz, 0, -dx),
                // e_z x d = (-dy, dx, 0).
                b[M + 3] = -d[2];
                b[2 * M + 3] = d[1];
                b[4] = d[2];
                b[2 * M + 4] = -d[0];
                b[5] = -d[1];
                b[M + 5] = d[0];
            }
            let t = &mut level.t[18 * i..18 * i + 18];
            match filter {
                Some(f) => {
                    let s = f.projection(i);
                    t.fill(0.0);
                    mul_acc::<3, 3, M>(t, &s, &b);
                }
                None => t.copy_from_slice(&b),
            }
        }
        orthonormalise::<3>(level, a);
    }
}

/// A coarse level's near null space: the rows of each aggregate's nodes are the level
/// above's R blocks.
fn coarse_nullspace(level: &mut Level, above: &[f64]) {
    level.t.copy_from_slice(above);
    for a in 0..level.member_ptr.len() - 1 {
        orthonormalise::<M>(level, a);
    }
}

/// QR of aggregate `a`'s rows of `T` by modified Gram-Schmidt applied twice: Q into
/// `T`, R into the aggregate's near null space block. Columns that vanish against the
/// ones before (below 1e-10 of their own norm) stay zero, with zero rows in R.
fn orthonormalise<const BF: usize>(level: &mut Level, a: usize) {
    let members = &level.members[level.member_ptr[a] as usize..level.member_ptr[a + 1] as usize];
    let t = &mut level.t;
    let col_dot = |t: &[f64], j: usize, k: usize| -> f64 {
        let mut s = 0.0;
        for &i in members {
            let b = &t[BF * M * i as usize..BF * M * (i as usize + 1)];
            for r in 0..BF {
                s += b[M * r + j] * b[M * r + k];
            }
        }
        s
    };
    let mut rr = [0.0; MM];
    for k in 0..M {
        let norm0 = col_dot(t, k, k).sqrt();
        for _ in 0..2 {
            for j in 0..k {
                let proj = col_dot(t, j, k);
                rr[M * j + k] += proj;
                for &i in members {
                    let b = &mut t[BF * M * i as usize..BF * M * (i as usize + 1)];
                    for r in 0..BF {
                        b[M * r + k] -= proj * b[M * r + j];
                    }
                }
            }
        }
        let norm = col_dot(t, k, k).sqrt();
        let keep = norm > 1e-10 * norm0 && norm > 0.0;
        for &i in members {
            let b = &mut t[BF * M * i as usize..BF * M * (i as usize + 1)];
            for r in 0..BF {
                b[M * r + k] = if keep { b[M * r + k] / norm } else { 0.0 };
            }
        }
        if keep {
            rr[M * k + k] = norm;
        } else {
            for j in k..M {
                rr[M * k + j] = 0.0;
            }
        }
    }
    level.nullspace[MM * a..MM * (a + 1)].copy_from_slice(&rr);
}

/// The values of `level`: its smoothed prolongator from the matrix above `above`
/// (inverse diagonal blocks `dinv`, eigenvalue estimate `lambda`), then its matrix
/// `P^T A P`. `level.t` must hold the tentative prolongator.
fn coarsen<const BF: usize>(level: &mut Level, above: View, dinv: &[f64], lambda: f64) {
    let omega = if lambda > 0.0 {
        4.0 / (3.0 * lambda)
    } else {
        0.0
    };
    let w = BF * M;
    // P = T - omega D^-1 A T, row by row.
    {
        let Level {
            p,
            p_ptr,
            p_col,
            a_to_p,
            t,
            agg,
            ..
        } = level;
        par_rows(p, p_ptr, w, 0..p_ptr.len() - 1, &|rows, out| {
            let base = p_ptr[rows.start] as usize;
            out.fill(0.0);
            for i in rows {
                let slots = above.row_ptr[i] as usize..above.row_ptr[i + 1] as usize;
                for (s, &to) in slots.clone().zip(&a_to_p[slots]) {
                    let k = above.col[s] as usize;
                    let at = to as usize - base;
                    mul_acc::<BF, BF, M>(
                        &mut out[w * at..w * at + w],
                        &above.val[BF * BF * s..BF * BF * (s + 1)],
                        &t[w * k..w * (k + 1)],
                    );
                }
                let di = &dinv[BF * BF * i..BF * BF * (i + 1)];
                for s in p_ptr[i] as usize..p_ptr[i + 1] as usize {
                    let blk = &mut out[w * (s - base)..w * (s - base + 1)];
                    let mut tmp = [0.0; 36];
                    mul_acc::<BF, BF, M>(&mut tmp[..w], di, blk);
                    for (b, v) in blk.iter_mut().zip(&tmp[..w]) {
                        *b = -omega * v;
                    }
                }
                // T's block (i, agg[i]).
                let own = (p_ptr[i] as usize..p_ptr[i + 1] as usize)
                    .find(|&s| p_col[s] == agg[i])
                    .expect("a node's own aggregate is in its row");
                let blk = &mut out[w * (own - base)..w * (own - base + 1)];
                for (b, v) in blk.iter_mut().zip(&t[w * i..w * (i + 1)]) {
                    *b += v;
                }
            }
        });
    }
    // Q = A P.
    {
        let Level {
            q,
            q_ptr,
            q_map_ptr,
            q_map,
            p,
            p_ptr,
            ..
        } = level;
        par_rows(q, q_ptr, w, 0..q_ptr.len() - 1, &|rows, out| {
            let base = q_ptr[rows.start] as usize;
            out.fill(0.0);
            for i in rows {
                let mut m = q_map_ptr[i] as usize;
                for s in above.row_ptr[i] as usize..above.row_ptr[i + 1] as usize {
                    let k = above.col[s] as usize;
                    let ab = &above.val[BF * BF * s..BF * BF * (s + 1)];
                    for u in p_ptr[k] as usize..p_ptr[k + 1] as usize {
                        let at = q_map[m] as usize - base;
                        m += 1;
                        mul_acc::<BF, BF, M>(
                            &mut out[w * at..w * at + w],
                            ab,
                            &p[w * u..w * (u + 1)],
                        );
                    }
                }
            }
        });
    }
    // A_c = P^T Q.
    {
        let Level {
            a,
            pt_ptr,
            pt_slot,
            p_row,
            p,
            q,
            q_ptr,
            c_map_ptr,
            c_map,
            q_from,
            c_mirror,
            ..
        } = level;
        par_rows(
            &mut a.val,
            &a.row_ptr,
            MM,
            0..a.row_ptr.len() - 1,
            &|rows, out| {
                let base = a.row_ptr[rows.start] as usize;
                out.fill(0.0);
                for ci in rows {
                    let mut m = c_map_ptr[ci] as usize;
                    for k in pt_ptr[ci] as usize..pt_ptr[ci + 1] as usize {
                        let s = pt_slot[k] as usize;
                        let i = p_row[s] as usize;
                        let pb = &p[w * s..w * (s + 1)];
                        for u in q_from[k] as usize..q_ptr[i + 1] as usize {
                            let at = c_map[m] as usize - base;
                            m += 1;
                            mul_t_acc::<BF, M, M>(
                                &mut out[MM * at..MM * (at + 1)],
                                pb,
                                &q[w * u..w * (u + 1)],
                            );
                        }
                    }
                }
            },
        );
        // The blocks left of the diagonal are the transposes of those right of it (half
        // the products; the matrix comes out exactly symmetric).
        for &(lower, upper) in c_mirror.iter() {
            let (l, u) = (MM * lower as usize, MM * upper as usize);
            let src: [f64; MM] = a.val[u..u + MM].try_into().expect("a block");
            for r in 0..M {
                for c in 0..M {
                    a.val[l + M * r + c] = src[M * c + r];
                }
            }
        }
        // Unknowns whose prolongator column vanished are decoupled with a unit diagonal.
        for &d in &a.diag {
            let blk = &mut a.val[MM * d as usize..MM * (d as usize + 1)];
            for c in 0..M {
                if blk[M * c + c] == 0.0 {
                    blk[M * c + c] = 1.0;
                }
            }
        }
    }
}

/// Runs `f` on row ranges of about [`ROWS`] rows of a CSR matrix, with their values
/// (`width` per stored block; `val` holds those of `rows`), in parallel by halving
/// (`rayon::join`, which needs no allocation). Each row's result does not depend on how
/// the rows are split.
fn par_rows<F>(val: &mut [f64], ptr: &[u32], width: usize, rows: std::ops::Range<usize>, f: &F)
where
    F: Fn(std::ops::Range<usize>, &mut [f64]) + Sync,
{
    if rows.len() <= ROWS {
        f(rows, val);
        return;
    }
    let mid = rows.start + rows.len() / 2;
    let (left, right) = val.split_at_mut(width * (ptr[mid] - ptr[rows.start]) as usize);
    rayon::join(
        || par_rows(left, ptr, width, rows.start..mid, f),
        || par_rows(right, ptr, width, mid..rows.end, f),
    );
}

/// `out (R x C) += a (R x K) b (K x C)`, all row-major. Inlined and cut to the exact
/// lengths, so the bounds checks go and the products unroll into vector FMAs (called
/// out of line with the checks, these products were a seventh of a beam step).
#[inline(always)]
fn mul_acc<const R: usize, const K: usize, const C: usize>(out: &mut [f64], a: &[f64], b: &[f64]) {
    let (out, a, b) = (&mut out[..R * C], &a[..R * K], &b[..K * C]);
    for r in 0..R {
        for k in 0..K {
            let ark = a[K * r + k];
            for c in 0..C {
                out[C * r + c] = ark.mul_add(b[C * k + c], out[C * r + c]);
            }
        }
    }
}

/// `out (R x C) += a^T b` for `a` (K x R) and `b` (K x C), all row-major (inlined and
/// cut as [`mul_acc`]).
#[inline(always)]
fn mul_t_acc<const K: usize, const R: usize, const C: usize>(
    out: &mut [f64],
    a: &[f64],
    b: &[f64],
) {
    let (out, a, b) = (&mut out[..R * C], &a[..K * R], &b[..K * C]);
    for k in 0..K {
        for r in 0..R {
            let akr = a[R * k + r];
            for c in 0..C {
                out[C * r + c] = akr.mul_add(b[C * k + c], out[C * r + c]);
            }
        }
    }
}

/// The fine level's inverse diagonal blocks (3x3, row-major).
fn fine_dinv(a: &Bsr3, dinv: &mut [f64]) -> Result<(), SolveError> {
    for (i, &slot) in a.pattern().diag_slots().iter().enumerate() {
        let b = a.block(slot as usize);
        let m = inverse_spd3(b).ok_or(SolveError::NotPositiveDefinite {
            what: "smoothed aggregation: diagonal block of vertex",
            at: i,
            value: b[0],
        })?;
        dinv[9 * i..9 * i + 9]
            .copy_from_slice(&[m[0], m[1], m[2], m[1], m[3], m[4], m[2], m[4], m[5]]);
    }
    Ok(())
}

/// A coarse level's inverse diagonal blocks (6x6, row-major), by Cholesky.
fn coarse_dinv(a: &Blocks, dinv: &mut [f64]) -> Result<(), SolveError> {
    for (i, &d) in a.diag.iter().enumerate() {
        let b = &a.val[MM * d as usize..MM * (d as usize + 1)];
        let inv = inverse_spd::<M, MM>(b).ok_or(SolveError::NotPositiveDefinite {
            what: "smoothed aggregation: coarse diagonal block",
            at: i,
            value: b[0],
        })?;
        dinv[MM * i..MM * (i + 1)].copy_from_slice(&inv);
    }
    Ok(())
}

/// The inverse of a symmetric positive definite `N x N` block (row-major, `NN = N N`)
/// by Cholesky, or `None` if a pivot is not positive.
fn inverse_spd<const N: usize, const NN: usize>(b: &[f64]) -> Option<[f64; NN]> {
    let mut l = [0.0; NN];
    for j in 0..N {
        let mut d = b[N * j + j];
        for k in 0..j {
            d -= l[N * j + k] * l[N * j + k];
        }
        if !positive(d) || !d.is_finite() {
            return None;
        }
        let d = d.sqrt();
        l[N * j + j] = d;
        for i in j + 1..N {
            let mut s = b[N * i + j];
            for k in 0..j {
                s -= l[N * i + k] * l[N * j + k];
            }
            l[N * i + j] = s / d;
        }
    }
    // Columns of A^-1 from L L^T x = e_c.
    let mut inv = [0.0; NN];
    for c in 0..N {
        let mut y = [0.0; N];
        for i in 0..N {
            let mut s = if i == c { 1.0 } else { 0.0 };
            for k in 0..i {
                s -= l[N * i + k] * y[k];
            }
            y[i] = s / l[N * i + i];
        }
        for i in (0..N).rev() {
            let mut s = y[i];
            for k in i + 1..N {
                s -= l[N * k + i] * inv[N * k + c];
            }
            inv[N * i + c] = s / l[N * i + i];
        }
    }
    Some(inv)
}

/// What the smoother and the eigenvalue estimate need of a level.
trait Op: Sync {
    /// `r = b - A x`.
    fn residual(&self, r: &mut [f64], x: &[f64], b: &[f64]);
    /// `y = A x`.
    fn apply(&self, y: &mut [f64], x: &[f64]);
    /// `d = alpha d + beta D^-1 r` (`d` is not read when `alpha` is zero).
    fn precondition(&self, d: &mut [f64], alpha: f64, beta: f64, r: &[f64]);
}

/// The fine level: the Bsr3 matrix with component-major vectors. Its residuals (the
/// V-cycle's) read the `f32` copy `val32` when there is one; its products (the power
/// iterations' in setup) the `f64` values.
struct FineOp<'a> {
    a: &'a Bsr3,
    val32: &'a [f32],
    dinv: &'a [f64],
}

impl Op for FineOp<'_> {
    fn residual(&self, r: &mut [f64], x: &[f64], b: &[f64]) {
        fine_residual(self.val32, self.a, r, x, b);
    }

    fn apply(&self, y: &mut [f64], x: &[f64]) {
        self.a.spmv(y, x);
    }

    fn precondition(&self, d: &mut [f64], alpha: f64, beta: f64, r: &[f64]) {
        let n = self.a.n();
        let [d0, d1, d2] = largestep_kernels::split3_mut(d);
        let chunk = 16 * ROWS;
        d0.par_chunks_mut(chunk)
            .zip(d1.par_chunks_mut(chunk))
            .zip(d2.par_chunks_mut(chunk))
            .enumerate()
            .for_each(|(c, ((d0, d1), d2))| {
                for (l, ((d0, d1), d2)) in d0.iter_mut().zip(d1).zip(d2).enumerate() {
                    let i = c * chunk + l;
                    let m = &self.dinv[9 * i..9 * i + 9];
                    let v = [r[i], r[n + i], r[2 * n + i]];
                    let mut z = [0.0; 3];
                    for (k, zk) in z.iter_mut().enumerate() {
                        *zk = beta * (m[3 * k] * v[0] + m[3 * k + 1] * v[1] + m[3 * k + 2] * v[2]);
                    }
                    if alpha == 0.0 {
                        (*d0, *d1, *d2) = (z[0], z[1], z[2]);
                    } else {
                        *d0 = alpha * *d0 + z[0];
                        *d1 = alpha * *d1 + z[1];
                        *d2 = alpha * *d2 + z[2];
                    }
                }
            });
    }
}

/// A coarse level: `M x M` blocks with node-major vectors.
struct CoarseOp<'a> {
    a: &'a Blocks,
    dinv: &'a [f64],
}

impl Op for CoarseOp<'_> {
    fn residual(&self, r: &mut [f64], x: &[f64], b: &[f64]) {
        coarse_residual(self.a, r, x, b);
    }

    fn apply(&self, y: &mut [f64], x: &[f64]) {
        coarse_times(self.a, &self.a.val, y, x, None);
    }

    fn precondition(&self, d: &mut [f64], alpha: f64, beta: f64, r: &[f64]) {
        d.par_chunks_mut(M * ROWS)
            .zip(r.par_chunks(M * ROWS))
            .enumerate()
            .for_each(|(c, (d, r))| {
                for (l, (d, r)) in d.chunks_exact_mut(M).zip(r.chunks_exact(M)).enumerate() {
                    let i = c * ROWS + l;
                    let m = &self.dinv[MM * i..MM * (i + 1)];
                    for (k, dk) in d.iter_mut().enumerate() {
                        let mut z = 0.0;
                        for (j, rj) in r.iter().enumerate() {
                            z += m[M * k + j] * rj;
                        }
                        *dk = if alpha == 0.0 {
                            beta * z
                        } else {
                            alpha * *dk + beta * z
                        };
                    }
                }
            });
    }
}

/// `y = A x`, or `y = b - A x` with `b`, on a coarse level (parallel over rows), with
/// the values `val` (`a.val` or its `f32` copy).
fn coarse_times<V: BlockValue>(a: &Blocks, val: &[V], y: &mut [f64], x: &[f64], b: Option<&[f64]>) {
    y.par_chunks_mut(M * ROWS).enumerate().for_each(|(c, out)| {
        for (l, o) in out.chunks_exact_mut(M).enumerate() {
            let i = c * ROWS + l;
            let mut acc = [0.0; M];
            for s in a.row_ptr[i] as usize..a.row_ptr[i + 1] as usize {
                let j = a.col[s] as usize;
                let blk = &val[MM * s..MM * (s + 1)];
                let xj = &x[M * j..M * (j + 1)];
                for (r, ar) in acc.iter_mut().enumerate() {
                    for (cc, xc) in xj.iter().enumerate() {
                        *ar += blk[M * r + cc].get() * xc;
                    }
                }
            }
            match b {
                Some(b) => {
                    for (k, ok) in o.iter_mut().enumerate() {
                        *ok = b[M * i + k] - acc[k];
                    }
                }
                None => o.copy_from_slice(&acc),
            }
        }
    });
}

/// `r = b - A x` on a coarse level, through the `f32` values when there are.
fn coarse_residual(a: &Blocks, r: &mut [f64], x: &[f64], b: &[f64]) {
    if a.val32.is_empty() {
        coarse_times(a, &a.val, r, x, Some(b));
    } else {
        coarse_times(a, &a.val32, r, x, Some(b));
    }
}

/// Chebyshev smoothing of `A x = b` in `D^-1 A` with eigenvalues up to about `lambda`
/// (the three-term recurrence of Saad, "Iterative methods for sparse linear systems",
/// algorithm 12.1, preconditioned) of degree [`DEGREE`]. From `x = 0` when `zero`. `r`,
/// `d`: scratch.
fn chebyshev(
    op: &dyn Op,
    lambda: f64,
    x: &mut [f64],
    b: &[f64],
    r: &mut [f64],
    d: &mut [f64],
    zero: bool,
) {
    let hi = BOOST * lambda;
    let lo = hi / RATIO;
    let (theta, delta) = ((hi + lo) / 2.0, (hi - lo) / 2.0);
    let sigma = theta / delta;
    let mut rho = 1.0 / sigma;
    if zero {
        op.precondition(d, 0.0, 1.0 / theta, b);
        x.copy_from_slice(d);
    } else {
        op.residual(r, x, b);
        op.precondition(d, 0.0, 1.0 / theta, r);
        kv::axpy(x, 1.0, d);
    }
    // Empty at degree 1 (one damped Jacobi sweep); kept for other degrees.
    #[allow(clippy::reversed_empty_ranges)]
    for _ in 1..DEGREE {
        op.residual(r, x, b);
        let next = 1.0 / (2.0 * sigma - rho);
        op.precondition(d, next * rho, 2.0 * next / delta, r);
        kv::axpy(x, 1.0, d);
        rho = next;
    }
}

/// The largest eigenvalue of `D^-1 A` by [`POWER_ITERATIONS`] power iterations from a
/// fixed pseudo-random start (filtered by `filter`); `v`, `w`: scratch.
fn largest_eigenvalue(op: &dyn Op, v: &mut [f64], w: &mut [f64], filter: Option<&Filter>) -> f64 {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    for vi in v.iter_mut() {
        // xorshift64: any fixed sequence with no structure serves.
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        *vi = (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
    }
    if let Some(f) = filter {
        f.apply(v);
    }
    let mut lambda = 0.0;
    for _ in 0..POWER_ITERATIONS {
        let norm = kv::norm2(v);
        if !positive(norm) || !norm.is_finite() {
            return lambda;
        }
        kv::scale_copy(w, 1.0 / norm, v);
        op.apply(v, w);
        // w = D^-1 A w for the unit w; then v = w.
        op.precondition(w, 0.0, 1.0, v);
        lambda = kv::norm2(w);
        v.copy_from_slice(w);
    }
    lambda
}

/// Rows of the level above per task of the restriction ([`restrict`]): a fixed size, so
/// that the partial sums, and so the result, are the same for any number of threads.
const RESTRICT_ROWS: usize = 2048;

/// `level.b = P^T r` for the level above's residual `r` (laid out as `layout`).
///
/// Each task streams its rows of P in storage order and adds them into its own copy of
/// the coarse vector (`level.partial`); the copies are then added in task order. The
/// column-wise gather this replaced visited P's blocks through `pt_slot`, out of order:
/// a quarter of a V-cycle on the 36,663-unknown FEM beam, against 6% now (perf).
fn restrict<const BF: usize>(level: &mut Level, r: &[f64], layout: Layout) {
    let Level {
        b,
        partial,
        p_ptr,
        p_col,
        p,
        p32,
        ..
    } = level;
    if p32.is_empty() {
        restrict_with::<BF, _>(b, partial, p_ptr, p_col, p, r, layout);
    } else {
        restrict_with::<BF, _>(b, partial, p_ptr, p_col, p32, r, layout);
    }
}

/// [`restrict`] with P's values `p` (`f64` or the `f32` copy).
fn restrict_with<const BF: usize, V: BlockValue>(
    b: &mut [f64],
    partial: &mut [f64],
    p_ptr: &[u32],
    p_col: &[u32],
    p: &[V],
    r: &[f64],
    layout: Layout,
) {
    let w = BF * M;
    let len = b.len();
    let rows = p_ptr.len() - 1;
    partial
        .par_chunks_mut(len)
        .enumerate()
        .for_each(|(task, out)| {
            out.fill(0.0);
            for i in chunk_range(task, rows, RESTRICT_ROWS) {
                let ri: [f64; BF] = std::array::from_fn(|k| r[layout.at(i, k, BF)]);
                for s in p_ptr[i] as usize..p_ptr[i + 1] as usize {
                    let j = p_col[s] as usize;
                    let blk = &p[w * s..w * (s + 1)];
                    let o = &mut out[M * j..M * (j + 1)];
                    for (k, rk) in ri.iter().enumerate() {
                        for (oc, bc) in o.iter_mut().zip(&blk[M * k..M * (k + 1)]) {
                            *oc += bc.get() * rk;
                        }
                    }
                }
            }
        });
    let partial = &*partial;
    b.par_chunks_mut(M * ROWS).enumerate().for_each(|(c, out)| {
        let at = c * M * ROWS;
        out.fill(0.0);
        for part in partial.chunks_exact(len) {
            for (o, v) in out.iter_mut().zip(&part[at..]) {
                *o += v;
            }
        }
    });
}

/// `x += P level.x` on the level above (laid out as `layout`).
fn prolong<const BF: usize>(level: &Level, x: &mut [f64], layout: Layout) {
    if level.p32.is_empty() {
        prolong_with::<BF, _>(level, &level.p, x, layout);
    } else {
        prolong_with::<BF, _>(level, &level.p32, x, layout);
    }
}

/// [`prolong`] with P's values `p` (`level.p` or its `f32` copy).
fn prolong_with<const BF: usize, V: BlockValue>(
    level: &Level,
    p: &[V],
    x: &mut [f64],
    layout: Layout,
) {
    let w = BF * M;
    let row = |i: usize| -> [f64; BF] {
        let mut y = [0.0; BF];
        for s in level.p_ptr[i] as usize..level.p_ptr[i + 1] as usize {
            let j = level.p_col[s] as usize;
            let blk = &p[w * s..w * (s + 1)];
            let xj = &level.x[M * j..M * (j + 1)];
            for (k, yk) in y.iter_mut().enumerate() {
                for (cc, xc) in xj.iter().enumerate() {
                    *yk += blk[M * k + cc].get() * xc;
                }
            }
        }
        y
    };
    match layout {
        Layout::Nodes => x
            .par_chunks_mut(BF * ROWS)
            .enumerate()
            .for_each(|(c, out)| {
                for (l, o) in out.chunks_exact_mut(BF).enumerate() {
                    for (ok, yk) in o.iter_mut().zip(row(c * ROWS + l)) {
                        *ok += yk;
                    }
                }
            }),
        Layout::Components(n) => {
            assert_eq!(BF, 3, "component-major vectors have three components");
            let [x0, x1, x2] = largestep_kernels::split3_mut(&mut x[..3 * n]);
            let chunk = 16 * ROWS;
            x0.par_chunks_mut(chunk)
                .zip(x1.par_chunks_mut(chunk))
                .zip(x2.par_chunks_mut(chunk))
                .enumerate()
                .for_each(|(c, ((x0, x1), x2))| {
                    for (l, ((x0, x1), x2)) in x0.iter_mut().zip(x1).zip(x2).enumerate() {
                        let y = row(c * chunk + l);
                        *x0 += y[0];
                        *x1 += y[1];
                        *x2 += y[2];
                    }
                });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sparse::examples::grid_spd;

    /// Every coarse matrix (its upper blocks from `P^T (A P)`, the lower ones mirrored)
    /// equals the dense product `P^T A P` of the level above's matrix and the level's
    /// smoothed prolongator, and its blocks off the diagonal are exactly symmetric.
    #[test]
    fn coarse_matrices_are_the_galerkin_products() {
        let dims = [10, 6, 5];
        let a = grid_spd(&dims, 1.0, 0.05);
        let n = a.n();
        let mut coords = vec![0.0; 3 * n];
        for v in 0..n {
            let p = [v % 10, (v / 10) % 6, v / 60];
            for c in 0..3 {
                coords[c * n + v] = p[c] as f64;
            }
        }
        let mut sa = SmoothedAggregation::new();
        sa.set_coordinates(&coords);
        sa.setup(&a, None).unwrap();
        assert!(!sa.levels.is_empty(), "levels {:?}", sa.level_sizes());
        // The matrix above as dense, node-major (unknown bf i + c) for both layouts.
        let mut above: Vec<f64> = {
            let d = a.to_dense();
            let m = 3 * n;
            let mut out = vec![0.0; m * m];
            for (i, row) in d.chunks_exact(m).enumerate() {
                for (j, v) in row.iter().enumerate() {
                    // Component-major (c n + i) to node-major (3 i + c).
                    let (ri, rc) = (i % n, i / n);
                    let (cj, cc) = (j % n, j / n);
                    out[(3 * ri + rc) * m + 3 * cj + cc] = *v;
                }
            }
            out
        };
        let mut bf = 3;
        for level in &sa.levels {
            let (na, nc) = (level.p_ptr.len() - 1, level.a.n());
            let (ma, mc) = (bf * na, M * nc);
            let mut p = vec![0.0; ma * mc];
            for i in 0..na {
                for s in level.p_ptr[i] as usize..level.p_ptr[i + 1] as usize {
                    let c = level.p_col[s] as usize;
                    for r in 0..bf {
                        for k in 0..M {
                            p[(bf * i + r) * mc + M * c + k] = level.p[bf * M * s + M * r + k];
                        }
                    }
                }
            }
            // Dense `a (rows x inner) b (inner x cols)`.
            let product = |a: &[f64], b: &[f64], rows: usize, inner: usize, cols: usize| {
                let mut out = vec![0.0; rows * cols];
                for r in 0..rows {
                    for k in (0..inner).filter(|&k| a[r * inner + k] != 0.0) {
                        for c in 0..cols {
                            out[r * cols + c] += a[r * inner + k] * b[k * cols + c];
                        }
                    }
                }
                out
            };
            let pt: Vec<f64> = (0..mc * ma).map(|e| p[(e % ma) * mc + e / ma]).collect();
            let want = product(&pt, &product(&above, &p, ma, ma, mc), mc, ma, mc);
            let mut got = vec![0.0; mc * mc];
            for i in 0..nc {
                for s in level.a.row_ptr[i] as usize..level.a.row_ptr[i + 1] as usize {
                    let j = level.a.col[s] as usize;
                    for r in 0..M {
                        for c in 0..M {
                            got[(M * i + r) * mc + M * j + c] = level.a.val[MM * s + M * r + c];
                        }
                    }
                }
            }
            let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for i in 0..mc {
                for j in 0..mc {
                    // Decoupled unknowns (a vanished prolongator column) get a unit diagonal.
                    let w = if i == j && want[i * mc + j] == 0.0 {
                        1.0
                    } else {
                        want[i * mc + j]
                    };
                    assert!(
                        (got[i * mc + j] - w).abs() <= 1e-12 * scale,
                        "({i}, {j}): {} against {w}",
                        got[i * mc + j]
                    );
                    // Blocks off the diagonal are mirrored; the diagonal ones are
                    // computed whole.
                    let (g, gt) = (got[i * mc + j], got[j * mc + i]);
                    if i / M != j / M {
                        assert_eq!(g, gt, "symmetric at ({i}, {j})");
                    } else {
                        assert!((g - gt).abs() <= 1e-14 * scale, "({i}, {j}): {g} {gt}");
                    }
                }
            }
            above = got;
            bf = M;
        }
    }
}
