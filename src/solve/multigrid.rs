//! Aggregation multigrid: a V-cycle preconditioner for PCG on the block systems of
//! implicit steps (`A = M - h D - h^2 K`).
//!
//! Why: block Jacobi leaves PCG's iteration count growing with stiffness and mesh size
//! (the draped 100x100 cloth needs 100 to 160 iterations), because it cannot move the
//! smooth, low-frequency part of the error. A coarse correction can.
//!
//! The method is algebraic multigrid by aggregation (Vaněk, Mandel and Brezina,
//! "Algebraic multigrid by smoothed aggregation for second and fourth order elliptic
//! problems", Computing 56, 1996), here without prolongator smoothing:
//!
//! - **Aggregates:** a seed vertex with all its matrix neighbours, where none of them is
//!   taken yet; left-over vertices join a neighbouring aggregate. The same is repeated on
//!   the coarse matrix until at most [`COARSEST`] vertices are left.
//! - **Prolongation `P`:** copies an aggregate's 3-vector to each of its vertices. These
//!   are the translations, the near-null space of `h^2 K`.
//! - **Coarse matrix `P^T A P`:** the sum of the fine blocks between two aggregates. The
//!   aggregates depend only on the pattern, so each solve recomputes the coarse values in
//!   one pass over the fine blocks, through a slot map built once per pattern.
//! - **Constraints:** the Baraff-Witkin filter enters as `P~ = S P`. Pinned vertices drop
//!   out of the coarse problem, and contact vertices keep only their free directions.
//! - **Smoothing:** damped block Jacobi (`omega` = 2/3), one sweep before the
//!   coarse correction and one after, which keeps the V-cycle symmetric, as CG needs.
//!   The first sweep starts from zero and needs no product, so each level but the last
//!   costs two passes over its matrix per cycle.
//! - **The fine level in `f32`:** its two passes read a copy of the fine matrix rounded
//!   to `f32`, remade on every setup (half the value bytes; accumulation stays in `f64`).
//!   A V-cycle on the rounded matrix, which is as symmetric as the matrix, is still a
//!   symmetric positive definite preconditioner; PCG's own products use the `f64`
//!   matrix, so the answer is unchanged. On the draped 100x100 cloth this took the
//!   solve from 10.4 to 9.0 ms at the same 16 iterations. A matrix with values beyond
//!   `f32`'s range keeps the `f64` values (tested). The rounding moves each entry by up
//!   to 6e-8 of itself, so a matrix whose condition number nears 1e7 can lose
//!   definiteness in `f32`, and the V-cycle with it: PCG then converges more slowly or
//!   reports that it did not (and the cloth's step control halves the step). Implicit
//!   cloth systems `M - h^2 K` are far better conditioned than that.
//! - **Coarsest level:** at most [`COARSEST`] vertices, solved by dense LU.
//!
//! Tamstorf, Jones and McCormick ("Smoothed aggregation multigrid for cloth
//! simulation", SIGGRAPH Asia 2015) take the same route for Baraff-Witkin cloth, with
//! smoothed aggregation and rotations in the coarse space. Why this version leaves both
//! out: on the draped 100x100 sheet (pyamg 5.4 on the dumped system, relative residual
//! 1e-2, zero initial guess) block Jacobi took 76 iterations, unsmoothed aggregation
//! with block Jacobi smoothing 19 to 24, and smoothed aggregation 15. Smoothed
//! aggregation would need a sparse triple product on every solve; here the coarse
//! matrix is a sum. Multicolour block Gauss-Seidel smoothing saved iterations (15
//! instead of 18) but each sweep cost twice as much (solve 13.5 against 10.5 ms).

use super::{
    dense::{inverse_spd3, DenseLu},
    filter::Filter,
    SolveError,
};
use crate::sparse::{csr, Bsr3, Bsr3Pattern};
use largestep_kernels::sparse::{bsr3_residual_par, Bsr3Ref};
use rayon::prelude::*;
use std::sync::Arc;

/// Largest level solved directly (vertices; 3 unknowns each).
pub const COARSEST: usize = 48;

/// Most levels, the fine one included.
const MAX_LEVELS: usize = 12;

/// Vertices per parallel task in the V-cycle's vector passes.
const VEC_CHUNK: usize = 2048;

/// No aggregate yet.
const NONE: u32 = u32::MAX;

/// Damping of the block Jacobi smoother: 2/3, the classic choice for Jacobi smoothing;
/// it keeps the smoother convergent while the largest eigenvalue of `D^-1 A` stays below
/// 3. On the draped 100x100 cloth 0.8 saves 4% of the iterations and 0.9 diverges
/// (250 iterations instead of 18): that eigenvalue is near 2.2 there.
const OMEGA: f64 = 2.0 / 3.0;

/// The damped block Jacobi smoother of one level: `x <- x + omega D^-1 (b - A x)`.
#[derive(Clone, Debug)]
struct Smoother {
    /// Inverse diagonal blocks, `[b00, b01, b02, b11, b12, b22]` per vertex.
    dinv: Vec<[f64; 6]>,
}

impl Smoother {
    fn new(n: usize) -> Self {
        Self {
            dinv: vec![[0.0; 6]; n],
        }
    }

    /// Inverts the diagonal blocks of `a`; `level` names the level in errors.
    fn factor(&mut self, a: &Bsr3, level: usize) -> Result<(), SolveError> {
        for (i, &slot) in a.pattern().diag_slots().iter().enumerate() {
            let b = a.block(slot as usize);
            self.dinv[i] = inverse_spd3(b).ok_or(SolveError::NotPositiveDefinite {
                what: if level == 0 {
                    "multigrid: diagonal block of vertex"
                } else {
                    "multigrid: coarse diagonal block"
                },
                at: i,
                value: b[0],
            })?;
        }
        Ok(())
    }

    /// `x += omega D^-1 d` for a defect `d` (`b - A x`, or `b` when x is zero).
    fn correct(&self, x: &mut [f64], d: &[f64]) {
        let n = self.dinv.len();
        let [x0, x1, x2] = largestep_kernels::split3_mut(x);
        let (d0, d1, d2) = (&d[..n], &d[n..2 * n], &d[2 * n..]);
        x0.par_chunks_mut(VEC_CHUNK)
            .zip(x1.par_chunks_mut(VEC_CHUNK))
            .zip(x2.par_chunks_mut(VEC_CHUNK))
            .enumerate()
            .for_each(|(c, ((x0, x1), x2))| {
                let start = c * VEC_CHUNK;
                for (l, ((x0, x1), x2)) in x0.iter_mut().zip(x1).zip(x2).enumerate() {
                    let i = start + l;
                    let m = &self.dinv[i];
                    let (a, b, c) = (d0[i], d1[i], d2[i]);
                    *x0 += OMEGA * (m[0] * a + m[1] * b + m[2] * c);
                    *x1 += OMEGA * (m[1] * a + m[3] * b + m[4] * c);
                    *x2 += OMEGA * (m[2] * a + m[4] * b + m[5] * c);
                }
            });
    }

    /// One sweep from `x = 0`: `x = omega D^-1 b`, no matrix product.
    fn first(&self, x: &mut [f64], b: &[f64]) {
        x.fill(0.0);
        self.correct(x, b);
    }

    /// One sweep, with `tmp` for the defect.
    fn sweep(&self, a: &Bsr3, x: &mut [f64], b: &[f64], tmp: &mut [f64]) {
        a.residual(tmp, x, b);
        self.correct(x, tmp);
    }
}

/// One level below the fine one: its matrix, how the level above maps onto it, its
/// smoother (none on the coarsest) and its vectors.
#[derive(Clone, Debug)]
struct Coarse {
    /// Aggregate of each vertex of the level above.
    agg: Vec<u32>,
    /// The vertices of the level above in each aggregate: `members[member_ptr[I]..
    /// member_ptr[I + 1]]` (restriction gathers over them).
    member_ptr: Vec<u32>,
    members: Vec<u32>,
    /// The block slots of the level above that sum into each slot here:
    /// `sources[source_ptr[s]..source_ptr[s + 1]]` (the Galerkin product gathers them).
    source_ptr: Vec<u32>,
    sources: Vec<u32>,
    a: Bsr3,
    smoother: Option<Smoother>,
    x: Vec<f64>,
    b: Vec<f64>,
    r: Vec<f64>,
}

/// The aggregation multigrid hierarchy for one fine pattern, with its buffers (see the
/// module docs). Built on the first [`Multigrid::setup`] for a pattern; later setups with
/// the same pattern only recompute values, without allocating.
#[derive(Clone, Debug, Default)]
pub struct Multigrid {
    fine: Option<Arc<Bsr3Pattern>>,
    /// The fine matrix's values rounded to `f32` for the fine level's two products per
    /// cycle (see [`Multigrid::setup`]); empty when a value does not fit in `f32`.
    fine32: Vec<f32>,
    smoother: Option<Smoother>,
    r: Vec<f64>,
    coarse: Vec<Coarse>,
    lu: Option<DenseLu>,
}

impl Multigrid {
    /// An empty hierarchy (built on first use).
    pub fn new() -> Self {
        Self::default()
    }

    /// Vertices per level, fine first (empty before the first setup).
    pub fn level_sizes(&self) -> Vec<usize> {
        self.fine
            .iter()
            .map(|p| p.n())
            .chain(self.coarse.iter().map(|c| c.a.n()))
            .collect()
    }

    /// Bytes one V-cycle reads at least: on every level but the last (solved by LU) two
    /// passes over the level's matrix, the residual after the first sweep (which starts
    /// from zero and needs no product) and the one inside the second sweep.
    /// The fine level's passes read its `f32` copy when there is one.
    pub fn cycle_bytes(&self, a: &Bsr3) -> usize {
        if self.coarse.is_empty() {
            return 0;
        }
        let fine = match rounded(&self.fine32, a) {
            Some(a32) => a32.spmv_bytes(),
            None => a.as_kernel().spmv_bytes(),
        };
        let coarse: usize = self.coarse[..self.coarse.len() - 1]
            .iter()
            .map(|c| c.a.as_kernel().spmv_bytes())
            .sum();
        2 * (fine + coarse)
    }

    /// For `a` solved again after its filter lost a few constraints (one-sided contacts
    /// freed): remakes what depends on single vertices, the fine level's smoother and its
    /// `f32` copy, and keeps the coarse levels. Kept, they lack the freed vertices'
    /// normal directions; the fine smoother, now from the freed vertices' real blocks
    /// (not the identity the projection had put there), corrects those locally. A
    /// hierarchy solved directly at the fine level is set up again in full.
    pub fn refresh_fine(&mut self, a: &Bsr3, filter: Option<&Filter>) -> Result<(), SolveError> {
        match self.smoother.as_mut() {
            Some(s) if !self.coarse.is_empty() => {
                s.factor(a, 0)?;
                round_to_f32(a.values(), &mut self.fine32);
                Ok(())
            }
            _ => self.setup(a, filter),
        }
    }

    /// Builds the hierarchy for `a`'s pattern if it is new, then the coarse matrices and
    /// smoothers from `a`'s values. `a` must already be projected by `filter`
    /// ([`Filter::project_matrix`]) when there is one.
    pub fn setup(&mut self, a: &Bsr3, filter: Option<&Filter>) -> Result<(), SolveError> {
        let same = self
            .fine
            .as_ref()
            .is_some_and(|p| Bsr3Pattern::same(p, a.pattern()));
        if !same {
            self.build(a.pattern().clone());
        }
        if let Some(s) = self.smoother.as_mut() {
            s.factor(a, 0)?;
            round_to_f32(a.values(), &mut self.fine32);
        }
        for l in 0..self.coarse.len() {
            let (above, below) = self.coarse.split_at_mut(l);
            let fine = above.last().map_or(a, |c| &c.a);
            let c = &mut below[0];
            galerkin(fine, c);
            if l == 0 {
                // P~ = S P: the (I - S) part of the projected diagonal is no stiffness.
                if let Some(f) = filter {
                    remove_constraint_identity(f, c);
                }
            }
            if let Some(s) = c.smoother.as_mut() {
                s.factor(&c.a, l + 1)?;
            }
        }
        // The last level, solved by LU: the coarsest, or the fine one when it is small.
        let last = self.coarse.last().map_or(a, |c| &c.a);
        if let Some(lu) = self.lu.as_mut() {
            let (m, n) = (last, last.n());
            let dense = lu.matrix_mut();
            dense.fill(0.0);
            m.for_each_entry(|r, c, v| dense[r * 3 * n + c] += v);
            lu.factor()?;
        }
        Ok(())
    }

    fn build(&mut self, fine: Arc<Bsr3Pattern>) {
        self.coarse.clear();
        self.r = vec![0.0; 3 * fine.n()];
        let mut pattern = fine.clone();
        while pattern.n() > COARSEST && self.coarse.len() + 1 < MAX_LEVELS {
            let (agg, nc) = aggregate(pattern.row_ptr(), pattern.col());
            // A level that barely shrinks (a mesh of isolated vertices) ends the hierarchy.
            if 5 * nc > 4 * pattern.n() {
                break;
            }
            let mut pairs: Vec<[u32; 2]> = Vec::new();
            let (row_ptr, col) = (pattern.row_ptr(), pattern.col());
            for i in 0..pattern.n() {
                for &j in &col[row_ptr[i] as usize..row_ptr[i + 1] as usize] {
                    let (ai, aj) = (agg[i], agg[j as usize]);
                    if ai < aj {
                        pairs.push([ai, aj]);
                    }
                }
            }
            pairs.sort_unstable();
            pairs.dedup();
            // Aggregates are numbered below nc and there are fewer pairs than fine blocks,
            // so the pattern is always valid.
            let cp = Arc::new(
                Bsr3Pattern::from_elements(nc, &pairs).expect("aggregate pairs form a pattern"),
            );
            let mut slot_map = Vec::with_capacity(col.len());
            for i in 0..pattern.n() {
                for &j in &col[row_ptr[i] as usize..row_ptr[i + 1] as usize] {
                    let s = cp
                        .slot(agg[i] as usize, agg[j as usize] as usize)
                        .expect("every aggregate pair is in the coarse pattern");
                    slot_map.push(s as u32);
                }
            }
            let (source_ptr, sources) = invert(&slot_map, cp.nnz_blocks());
            let (member_ptr, members) = invert(&agg, nc);
            self.coarse.push(Coarse {
                agg,
                member_ptr,
                members,
                source_ptr,
                sources,
                a: Bsr3::zeros(cp.clone()),
                smoother: None,
                x: vec![0.0; 3 * nc],
                b: vec![0.0; 3 * nc],
                r: vec![0.0; 3 * nc],
            });
            pattern = cp;
        }
        // Every level but the last is smoothed; the last is solved by LU.
        let levels = self.coarse.len();
        self.smoother = (levels > 0).then(|| Smoother::new(fine.n()));
        for l in 0..levels.saturating_sub(1) {
            let s = Smoother::new(self.coarse[l].a.n());
            self.coarse[l].smoother = Some(s);
        }
        let nl = self.coarse.last().map_or(fine.n(), |c| c.a.n());
        self.lu = Some(DenseLu::new(3 * nl));
        self.fine = Some(fine);
    }

    /// `z = M^-1 r`: one V-cycle on the fine matrix `a` (the one given to
    /// [`Multigrid::setup`]) from a zero guess. With a filter, `r` must be filtered and `z`
    /// comes out filtered.
    pub fn apply(&mut self, a: &Bsr3, r: &[f64], z: &mut [f64], filter: Option<&Filter>) {
        let Some(lu) = self.lu.as_ref() else {
            z.copy_from_slice(r);
            return;
        };
        if self.coarse.is_empty() {
            z.copy_from_slice(r);
            lu.solve(z);
            return;
        }
        // Down: smooth, restrict the residual.
        let smoother = self.smoother.as_ref().expect("smoothed fine level");
        smoother.first(z, r);
        fine_residual(&self.fine32, a, &mut self.r, z, r);
        if let Some(f) = filter {
            f.apply(&mut self.r);
        }
        restrict(&self.r, &mut self.coarse[0]);
        let levels = self.coarse.len();
        for l in 0..levels - 1 {
            let (above, below) = self.coarse.split_at_mut(l + 1);
            let c = &mut above[l];
            let s = c.smoother.as_ref().expect("smoothed level");
            s.first(&mut c.x, &c.b);
            c.a.residual(&mut c.r, &c.x, &c.b);
            restrict(&c.r, &mut below[0]);
        }
        let last = &mut self.coarse[levels - 1];
        last.x.copy_from_slice(&last.b);
        lu.solve(&mut last.x);
        // Up: prolong the correction, smooth backwards.
        for l in (0..levels - 1).rev() {
            let (above, below) = self.coarse.split_at_mut(l + 1);
            let c = &mut above[l];
            prolong(&below[0], &mut c.x);
            let s = c.smoother.as_ref().expect("smoothed level");
            s.sweep(&c.a, &mut c.x, &c.b, &mut c.r);
        }
        prolong(&self.coarse[0], z);
        if let Some(f) = filter {
            f.apply(z);
        }
        let smoother = self.smoother.as_ref().expect("smoothed fine level");
        // The fine level's sweep, its product on the `f32` copy.
        fine_residual(&self.fine32, a, &mut self.r, z, r);
        smoother.correct(z, &self.r);
        if let Some(f) = filter {
            f.apply(z);
        }
    }

    /// `a` with the values of the `f32` copy the last setup made of it (`None` when a
    /// value did not fit in `f32`, or before a setup).
    pub(super) fn fine32<'a>(&'a self, a: &'a Bsr3) -> Option<Bsr3Ref<'a, f32>> {
        rounded(&self.fine32, a)
    }
}

/// The matrix `a` with the values `val32` ([`round_to_f32`] of its values), if they fit.
pub(super) fn rounded<'a>(val32: &'a [f32], a: &'a Bsr3) -> Option<Bsr3Ref<'a, f32>> {
    let k = a.as_kernel();
    (val32.len() == k.val.len()).then(|| Bsr3Ref::new(k.n, k.row_ptr, k.col, val32))
}

/// `res = b - A x` on the fine level: through the `f32` values `val32` when they fit,
/// else through `a`'s own.
pub(super) fn fine_residual(val32: &[f32], a: &Bsr3, res: &mut [f64], x: &[f64], b: &[f64]) {
    match rounded(val32, a) {
        Some(a32) => bsr3_residual_par(res, a32, x, b),
        None => a.residual(res, x, b),
    }
}

/// `out = val` rounded to `f32` (parallel; allocates only when the length changes), or
/// `out` emptied when a finite value overflows `f32`: the fine level then uses `val`.
pub(super) fn round_to_f32(val: &[f64], out: &mut Vec<f32>) {
    out.resize(val.len(), 0.0);
    let fits = out
        .par_chunks_mut(9 * 1024)
        .zip(val.par_chunks(9 * 1024))
        .map(|(o, v)| {
            let mut fits = true;
            for (o, v) in o.iter_mut().zip(v) {
                *o = *v as f32;
                fits &= o.is_finite() || !v.is_finite();
            }
            fits
        })
        .reduce(|| true, |a, b| a && b);
    if !fits {
        out.clear();
    }
}

/// Aggregates of a pattern's vertex graph: each vertex's aggregate and their count.
///
/// 1. A vertex whose neighbours are all free seeds an aggregate with all of them.
/// 2. Every vertex still free joins the aggregate of its first neighbour seeded in 1.
/// 3. Any vertex still free (all its neighbours joined in 2, or none) seeds an aggregate
///    with its free neighbours.
///
/// The graph is given in CSR form (`col[row_ptr[i]..row_ptr[i + 1]]` are i's neighbours,
/// i itself among them or not); the smoothed aggregation uses it on its coarse levels too.
pub(super) fn aggregate(row_ptr: &[u32], col: &[u32]) -> (Vec<u32>, usize) {
    let n = row_ptr.len() - 1;
    let nbrs = |i: usize| {
        col[row_ptr[i] as usize..row_ptr[i + 1] as usize]
            .iter()
            .map(|&j| j as usize)
            .filter(move |&j| j != i)
    };
    let mut agg = vec![NONE; n];
    let mut count = 0u32;
    for i in 0..n {
        if agg[i] == NONE && nbrs(i).next().is_some() && nbrs(i).all(|j| agg[j] == NONE) {
            agg[i] = count;
            for j in nbrs(i) {
                agg[j] = count;
            }
            count += 1;
        }
    }
    let seeded = agg.clone();
    for (i, a) in agg.iter_mut().enumerate() {
        if *a == NONE {
            if let Some(j) = nbrs(i).find(|&j| seeded[j] != NONE) {
                *a = seeded[j];
            }
        }
    }
    for i in 0..n {
        if agg[i] == NONE {
            agg[i] = count;
            for j in nbrs(i) {
                if agg[j] == NONE {
                    agg[j] = count;
                }
            }
            count += 1;
        }
    }
    (agg, count as usize)
}

/// For a map from items to `0..m`, the items of each target in CSR form (items in
/// increasing order within each target).
fn invert(map: &[u32], m: usize) -> (Vec<u32>, Vec<u32>) {
    csr(
        m,
        map.iter().enumerate().map(|(i, &t)| (t as usize, i as u32)),
    )
}

/// `c.a = P^T a P`: each coarse block is the sum of the fine blocks between its two
/// aggregates, gathered in parallel over coarse blocks (in a fixed order: the same bits
/// on any thread count).
fn galerkin(a: &Bsr3, c: &mut Coarse) {
    let src = a.values();
    let (ptr, sources) = (&c.source_ptr, &c.sources);
    c.a.values_mut()
        .par_chunks_mut(9 * 256)
        .enumerate()
        .for_each(|(chunk, dst)| {
            for (l, d) in dst.chunks_exact_mut(9).enumerate() {
                let slot = 256 * chunk + l;
                let mut sum = [0.0; 9];
                for &s in &sources[ptr[slot] as usize..ptr[slot + 1] as usize] {
                    let b = &src[9 * s as usize..9 * s as usize + 9];
                    for k in 0..9 {
                        sum[k] += b[k];
                    }
                }
                d.copy_from_slice(&sum);
            }
        });
}

/// Removes `I - S_i` of each constrained fine vertex from its aggregate's diagonal
/// block, so that the first coarse matrix is `(S P)^T A (S P)` (the projected fine
/// matrix is `S A S + I - S`).
fn remove_constraint_identity(f: &Filter, c: &mut Coarse) {
    for (i, s) in f.constrained() {
        let slot = c.a.pattern().diag_slots()[c.agg[i] as usize] as usize;
        let b = c.a.block_mut(slot);
        for (k, bk) in b.iter_mut().enumerate() {
            let identity = if k % 4 == 0 { 1.0 } else { 0.0 };
            *bk -= identity - s[k];
        }
    }
    // A direction every vertex of an aggregate is constrained in (a flat patch resting on
    // a floor, a clamped face) is outside `S P`: the coarse block has nothing there and
    // is singular. The correction along it is filtered out on the way back, so any
    // stiffness serves; it gets the block's own scale along the average constrained part
    // `D = sum (I - S_i) / k` of its k vertices (exactly the dead directions when they
    // are all constrained alike; 1 when the aggregate is pinned). Blocks that are already
    // definite are left alone.
    for (i, _) in f.constrained() {
        let ag = c.agg[i] as usize;
        let slot = c.a.pattern().diag_slots()[ag] as usize;
        if super::dense::inverse_spd3(c.a.block(slot)).is_some() {
            continue;
        }
        let members = &c.members[c.member_ptr[ag] as usize..c.member_ptr[ag + 1] as usize];
        let mut d = [0.0f64; 9];
        for &m in members {
            let s = f.projection(m as usize);
            for (k, dk) in d.iter_mut().enumerate() {
                let identity = if k % 4 == 0 { 1.0 } else { 0.0 };
                *dk += (identity - s[k]) / members.len() as f64;
            }
        }
        let b = c.a.block_mut(slot);
        let dead = d[0] + d[4] + d[8];
        let live = 3.0 - dead;
        let scale = if live > 0.5 && b[0] + b[4] + b[8] > 0.0 {
            (b[0] + b[4] + b[8]) / live
        } else {
            1.0
        };
        for (bk, dk) in b.iter_mut().zip(d) {
            *bk += scale * dk;
        }
    }
}

/// `c.b = P^T r`: each aggregate sums its vertices' residuals (gathered per aggregate,
/// in parallel over components and aggregates).
fn restrict(r: &[f64], c: &mut Coarse) {
    let n = c.agg.len();
    let nc = c.b.len() / 3;
    let (ptr, members) = (&c.member_ptr, &c.members);
    c.b.par_chunks_mut(VEC_CHUNK)
        .enumerate()
        .for_each(|(chunk, out)| {
            for (l, o) in out.iter_mut().enumerate() {
                let row = VEC_CHUNK * chunk + l;
                let (k, ag) = (row / nc, row % nc);
                let rk = &r[k * n..(k + 1) * n];
                *o = members[ptr[ag] as usize..ptr[ag + 1] as usize]
                    .iter()
                    .map(|&i| rk[i as usize])
                    .sum();
            }
        });
}

/// `x += P c.x`: each vertex takes its aggregate's correction.
fn prolong(c: &Coarse, x: &mut [f64]) {
    let n = c.agg.len();
    let nc = c.x.len() / 3;
    let agg = &c.agg;
    x.par_chunks_mut(VEC_CHUNK)
        .enumerate()
        .for_each(|(chunk, out)| {
            for (l, o) in out.iter_mut().enumerate() {
                let row = VEC_CHUNK * chunk + l;
                let (k, i) = (row / n, row % n);
                *o += c.x[k * nc + agg[i] as usize];
            }
        });
}
