//! Matrix-free Poisson solves on a cell grid: the pressure projection of grid fluids
//! (issue 17; Bridson, "Fluid Simulation for Computer Graphics", chapter 5; McAdams,
//! Sifakis and Teran 2010, "A parallel multigrid Poisson solver for fluids simulation on
//! large grids").
//!
//! Cells are fluid, solid or empty ([`CellKind`]). The unknowns live on fluid cells; for
//! fluid cell i, `(A p)_i = (d_i p_i - sum_j p_j) / h^2` over its face neighbours j
//! that are fluid, with `d_i` the number of its neighbours that are fluid or empty: an
//! empty neighbour is a Dirichlet condition `p = 0` (a free surface, an open boundary),
//! a solid one a Neumann condition (a wall). Beyond the grid's edge each side is a wall,
//! open (as an empty cell) or periodic ([`Side`]). A is symmetric and
//! positive definite when some fluid cell touches an empty cell or an open side; otherwise it
//! is singular with the constant null space, and the solve keeps every iterate at zero
//! mean over the fluid cells (the right side must then have zero mean: it is projected
//! there, as a compatible divergence field has).
//!
//! [`GridPoisson::solve`] runs conjugate gradients preconditioned by Jacobi or by one
//! multigrid V-cycle (McAdams et al.): cells coarsened two by two by two (a coarse cell
//! is empty if any child is, else fluid if any child is, else solid), the operator
//! rediscretised on each level, trilinear (cell-centred; bilinear in 2-D) prolongation P
//! and restriction `P^T / 8` (`P^T / 4` in 2-D), the value beyond a wall mirrored and
//! beyond an open side zero (`taps`), applied row by row with the separable weights
//! where the parent cell's neighbours in the grid are all fluid (`box_interior`: the
//! grid's walls and open sides need no cell-by-cell rule, which cut the transfers'
//! boundary cells from 211,000 to 21,000 of the bench's 2.1 million and the transfers'
//! time by about 60%), damped Jacobi smoothing (omega = 6/7, three
//! sweeps before and after) with one more sweep over a band of cells near walls and open
//! boundaries (after the pre-smoothing, before the post-smoothing), and a fixed number
//! of sweeps on the coarsest level, so the cycle is a fixed symmetric positive definite
//! operator. By default the cycle runs in `f32` ([`Precision`]; McAdams et al. run
//! their whole solver so): half the bytes per sweep, the same iteration counts (8 at
//! 128^3 to 1e-6 in either precision). CG's own vectors stay `f64`, and its `beta` is
//! the Polak-Ribiere form, which tolerates the rounding's small change of the
//! preconditioner from one application to the next.
//! Measured on the unit cube with open faces (`tests/poisson.rs`, rough right side,
//! relative residual 1e-8): 8, 7 and 7 iterations at 15^3, 31^3 and 63^3 cells (7, 6
//! and 6 with four band sweeps in `f64`).
//! Earlier versions, measured on the smooth right side (the sine of that test) to 1e-10:
//! piecewise-constant transfers took 19, 27 and 38 iterations (the orders of the two
//! transfers add up to two, the operator's order, which is not enough for a V-cycle);
//! trilinear ones with two sweeps at omega = 2/3 and no band, 15, 18 and 21.
//! Work is parallel over z-slabs, in tasks of at least `TASK_CELLS` cells (so the
//! coarsest levels run on one thread), with reductions in a fixed order (fixed chunks of
//! cells): the same bits on any thread count.

use super::{SolveError, SolveInfo};
use crate::soa::{ZeroBits, ZeroedBuf};
use largestep_kernels::par::{chunk_count, chunk_range, par_reduce, Disjoint};
use largestep_kernels::vec::{axpy, dot, dot_par};
use rayon::prelude::*;
use std::time::Instant;

/// What a grid cell holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum CellKind {
    /// Fluid: an unknown.
    Fluid = 0,
    /// Solid: a wall (Neumann).
    Solid = 1,
    /// Empty: air or outside an open boundary (Dirichlet, p = 0).
    Empty = 2,
}

/// What lies beyond one side of the grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Side {
    /// A wall: Neumann, no flux.
    #[default]
    Wall,
    /// Open (outflow): Dirichlet `p = 0` half a cell outside, as an empty cell there.
    Open,
    /// Periodic: the opposite side's cells are the neighbours (both sides of the axis
    /// must say so).
    Periodic,
}

/// The preconditioner of [`GridPoisson::solve`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PoissonPreconditioner {
    /// The inverse diagonal.
    Jacobi,
    /// One multigrid V-cycle (module docs).
    Multigrid,
}

/// The floating-point precision of the preconditioner's vectors (CG's own vectors,
/// and so the residual the tolerance is checked on, are `f64` either way).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Precision {
    /// `f32`: half the bytes a sweep moves (McAdams et al. 2010).
    #[default]
    Single,
    /// `f64`.
    Double,
}

/// Settings of [`GridPoisson::solve`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoissonParams {
    /// Stop when `|b - A p| <= tolerance |b|`.
    pub tolerance: f64,
    /// Give up after this many iterations.
    pub max_iterations: usize,
    pub preconditioner: PoissonPreconditioner,
    /// The preconditioner's precision.
    pub precision: Precision,
}

impl Default for PoissonParams {
    fn default() -> Self {
        Self {
            tolerance: 1e-6,
            max_iterations: 1000,
            preconditioner: PoissonPreconditioner::Multigrid,
            precision: Precision::default(),
        }
    }
}

/// Levels stop coarsening at this many cells or fewer.
const COARSEST_CELLS: usize = 512;
/// Jacobi sweeps on the coarsest level.
const COARSE_SWEEPS: usize = 60;
/// Smoothing sweeps before and after the coarse correction.
const SWEEPS: usize = 3;
/// Extra sweeps on the boundary band, after the pre-smoothing and before the
/// post-smoothing (so the cycle stays symmetric). Measured on 32^3, 64^3 and 128^3 cells
/// to 1e-6 (the bench's problem, and a wavy free surface over a ball): none, 8-9 and 7-8
/// iterations; one, 8 and 7-8; two, 7-8 and 7; four, 7-8 and 6-7. A band sweep costs
/// about half a full sweep (gathers through stored neighbours), so one pays best:
/// 0.32-0.37 s against 0.35-0.46 s with four for the 128^3 solve with setup.
const BAND_SWEEPS: usize = 1;
/// Jacobi damping.
const OMEGA: f64 = 6.0 / 7.0;

/// Cells of a row that `Level::row_into` takes at a time (with their two x neighbours,
/// on the stack of each task).
const ROW_PIECE: usize = 512;

/// Cells a parallel task of the V-cycle takes at least: on the coarse levels, handing
/// out smaller tasks costs more than running them (the 60 sweeps of the 8^3 level took
/// 0.7-0.9 ms in parallel slabs, about 12 us a sweep).
const TASK_CELLS: usize = 16_384;

/// The least number of items of `cells` cells each that makes a task of the V-cycle
/// (`TASK_CELLS`), for rayon's `with_min_len`: a level below it runs on one thread.
fn grain(cells: usize) -> usize {
    TASK_CELLS.div_ceil(cells.max(1))
}

/// One level of the hierarchy.
#[derive(Clone, Debug)]
struct Level {
    n: [usize; 3],
    /// Beyond each side, low and high per axis.
    sides: [[Side; 2]; 3],
    /// 1 / h^2.
    inv_h2: f64,
    kind: Vec<CellKind>,
    /// 0 off the fluid cells, `1 + d_i` on them: the diagonal `d_i / h^2`
    /// (`mask_diag`), the fluid mask and the smoother's `omega / (d_i / h^2)` are
    /// computed from it where used. One byte a cell instead of three f64 arrays: the
    /// sweeps read 17 bytes a cell instead of 40 (a fine sweep over 128^3 cells ran at
    /// about a quarter of the triad bandwidth with the arrays).
    code: ZeroedBuf<u8>,
    /// Fluid cells whose neighbours in the grid (26 away from its edge) are all fluid
    /// cells, not at the end of a periodic axis (`box_interior`): interpolation from
    /// them is the product of each axis's `taps`, with no look at cell kinds.
    interior: ZeroedBuf<bool>,
    /// Fluid cells within two cells of a non-fluid cell or the grid's edge, in order:
    /// the band that gets extra smoothing (McAdams et al. 2010, section 4).
    band: Vec<usize>,
    /// The face neighbours of each band cell, in `for_neighbours` order, `u32::MAX`
    /// past the last: found once, as finding them costs three integer divisions a cell
    /// (a tenth of a 128^3 solve when done in every band sweep).
    band_nb: Vec<[u32; 6]>,
    /// Where each z-slab's cells start in `band` (`nz + 1` entries).
    band_start: Vec<usize>,
    /// `omega / (d_i / h^2)` of each band cell (0 for a fluid cell with no open face).
    band_inv: Vec<f64>,
    /// Fluid cells whose parent on the next level is not interior (the transfers'
    /// boundary rule, `weights`), in order, with each z-slab's start (`nz + 1` entries);
    /// empty on the coarsest level. Set by `GridPoisson::with_sides`.
    edge_cells: Vec<u32>,
    edge_start: Vec<usize>,
    /// Each edge cell's eight coarse cells and weights (`weights`; the weights are
    /// multiples of 1/64, exact in f32): found once, as finding them took most of the
    /// restriction's time when done in every V-cycle.
    edge_weights: Vec<([u32; 8], [f32; 8])>,
}

/// The vectors of one level's part of a V-cycle, in the cycle's precision `T`.
#[derive(Clone, Debug)]
struct Work<T: ZeroBits> {
    /// The correction, right side and residual of this level (on huge pages where large:
    /// `ZeroedBuf`).
    x: ZeroedBuf<T>,
    b: ZeroedBuf<T>,
    r: ZeroedBuf<T>,
    /// The second buffer of the Jacobi sweeps.
    x2: ZeroedBuf<T>,
    /// The band's residuals.
    band_r: Vec<T>,
    /// Scratch of the restriction: each row of `r` restricted along x over the cells
    /// with an interior parent (`nz ny` rows of the next level's width); empty on the
    /// coarsest level.
    xr: Vec<T>,
    /// Scratch of the prolongation: one row of the next level per z-slab of this one
    /// (the coarse rows blended over y and z); empty on the coarsest level.
    rows: Vec<T>,
}

impl<T: Real> Work<T> {
    /// The vectors of every level of `levels`.
    fn for_levels(levels: &[Level]) -> Vec<Work<T>> {
        (0..levels.len())
            .map(|l| {
                let f = &levels[l];
                let cells = f.kind.len();
                let (xr, rows) = match levels.get(l + 1) {
                    Some(c) => (f.n[2] * f.n[1] * c.n[0], f.n[2] * c.n[0]),
                    None => (0, 0),
                };
                Work {
                    x: ZeroedBuf::new(cells),
                    b: ZeroedBuf::new(cells),
                    r: ZeroedBuf::new(cells),
                    x2: ZeroedBuf::new(cells),
                    band_r: vec![T::ZERO; f.band.len()],
                    xr: vec![T::ZERO; xr],
                    rows: vec![T::ZERO; rows],
                }
            })
            .collect()
    }
}

/// The numbers a V-cycle runs in: `f64`, or `f32`, which halves the bytes each sweep
/// moves (McAdams et al. 2010 run their whole solver in single precision; here only
/// the preconditioner is, and CG's own vectors stay `f64`).
trait Real:
    ZeroBits
    + PartialOrd
    + std::fmt::Debug
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
    + std::ops::AddAssign
    + std::ops::MulAssign
{
    const ZERO: Self;
    /// The nearest value to `v`.
    fn of(v: f64) -> Self;
    /// The value as `f64` (exact).
    fn get(self) -> f64;
    /// The smaller of two (neither NaN).
    fn min(self, o: Self) -> Self;
    /// The larger of two (neither NaN).
    fn max(self, o: Self) -> Self;
}

/// `Real` for a primitive float type.
macro_rules! real {
    ($t:ty) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            #[inline(always)]
            fn of(v: f64) -> Self {
                v as $t
            }
            #[inline(always)]
            fn get(self) -> f64 {
                f64::from(self)
            }
            #[inline(always)]
            fn min(self, o: Self) -> Self {
                <$t>::min(self, o)
            }
            #[inline(always)]
            fn max(self, o: Self) -> Self {
                <$t>::max(self, o)
            }
        }
    };
}
real!(f64);
real!(f32);

impl Level {
    /// A level; `coarse`: one that finer levels interpolate from (it needs `interior`).
    fn new(
        n: [usize; 3],
        sides: [[Side; 2]; 3],
        h: f64,
        kind: Vec<CellKind>,
        coarse: bool,
    ) -> Level {
        let inv_h2 = 1.0 / (h * h);
        let cells = kind.len();
        let per = periodic(&sides);
        // Each array below is one parallel pass over the cells (order-preserving, so the
        // same on any thread count); the neighbour counts add shifted rows of one-byte
        // masks (`neighbour_sum`), as the interior test adds boxes (`box_interior`).
        // Cell by cell, with the coordinates divided out of each index, these passes
        // took half the setup: it went from 0.072 to 0.040 s for the bench's 128^3
        // problem.
        let fluid: Vec<u8> = kind
            .par_iter()
            .map(|&k| u8::from(k == CellKind::Fluid))
            .collect();
        let not_solid: Vec<u8> = kind
            .par_iter()
            .map(|&k| u8::from(k != CellKind::Solid))
            .collect();
        let (nx, ny) = (n[0], n[1]);
        let rows = (4096 / nx).max(1);
        // `1 + d_i` on fluid cells: their faces towards cells that are not solid, and
        // towards open sides (at most six: the code fits a byte).
        let mut code = neighbour_sum(n, per, &not_solid);
        code.par_chunks_mut(nx)
            .enumerate()
            .with_min_len(rows)
            .for_each(|(r, cs)| {
                let (j, k) = (r % ny, r / ny);
                for (i, c) in cs.iter_mut().enumerate() {
                    let open = open_faces(n, &sides, [i, j, k]) as u8;
                    *c = fluid[r * nx + i] * (1 + open + *c);
                }
            });
        // The band: fluid cells with fewer fluid neighbours than a cell has (six in 3-D,
        // four in 2-D), dilated once.
        let full = (2 * n.iter().filter(|&&c| c > 1).count()) as u8;
        let mut edge = neighbour_sum(n, per, &fluid);
        edge.par_iter_mut()
            .zip(fluid.par_iter())
            .for_each(|(e, &f)| *e = u8::from(f == 1 && *e < full));
        let near = neighbour_sum(n, per, &edge);
        let band: Vec<usize> = (0..cells)
            .into_par_iter()
            .filter(|&i| fluid[i] == 1 && edge[i] + near[i] > 0)
            .collect();
        let band_nb = band
            .par_iter()
            .map(|&i| {
                let (mut nb, mut k) = ([u32::MAX; 6], 0);
                // Cell indices fit in u32 (`GridPoisson::with_sides` checks).
                for_neighbours(n, per, i, |j| {
                    nb[k] = j as u32;
                    k += 1;
                });
                nb
            })
            .collect();
        let band_start = slab_starts(&band, |i| i, n[0] * n[1], n[2]);
        let band_inv = band
            .par_iter()
            .map(|&i| smoother_weight(code[i], inv_h2))
            .collect();
        // An axis of one cell (2-D) has no neighbours to check along it. Only z may be
        // that axis: the interior transfers treat one coarse slab as a plane, but take
        // the neighbour rows along x and y to exist (a grid as long as 4097 x 8 cells
        // coarsens y to one cell while x goes on), so a level one cell wide along x or
        // y has no interior cells.
        let interior = if !coarse {
            ZeroedBuf::default()
        } else if n[0] == 1 || n[1] == 1 {
            ZeroedBuf::new(cells)
        } else {
            box_interior(n, &sides, &fluid)
        };
        Level {
            code,
            interior,
            n,
            sides,
            inv_h2,
            band,
            band_nb,
            band_start,
            band_inv,
            edge_cells: Vec::new(),
            edge_start: Vec::new(),
            edge_weights: Vec::new(),
            kind,
        }
    }

    /// Writes `emit(A x, b, x, code)` of the cells of row r (row `r % ny` of slab
    /// `r / ny`) into `out` (nx values, with `b` the row's values of a second vector and
    /// `code` the cells' `Level::code`; `A x` is zero off the fluid cells), x zero off
    /// the fluid cells (every vector the solver hands in is): then the sum over a
    /// cell's neighbours needs no look at their kinds. The row goes in pieces of at most
    /// `ROW_PIECE` cells, each copied into `pad` between its x neighbours (zero beyond
    /// a wall or an open side, wrapped across a periodic one), so every cell is one
    /// loop over zipped shifted slices, which the compiler vectorises with no scalar
    /// ends and no bounds checks; `emit` fuses the sweep's or the residual's update
    /// into the same pass. Counted by cachegrind on 64^3 cells: a sweep went from 20
    /// to 10.4 instructions a cell (the two ends of each row, cell by cell, took an
    /// eighth of it; indexed loops kept a scalar twin running), the V-cycle 28% fewer.
    #[inline]
    fn row_into<T: Real>(
        &self,
        r: usize,
        x: &[T],
        out: &mut [T],
        b: &[T],
        pad: &mut [T; ROW_PIECE + 2],
        emit: impl Fn(T, T, T, u8) -> T,
    ) {
        let [nx, ny, nz] = self.n;
        let s = nx * ny;
        let c = T::of(self.inv_h2);
        let (k, j) = (r / ny, r % ny);
        let base = r * nx;
        let per = periodic(&self.sides);
        // The rows beside this one along y and z (start index), wrapped along periodic
        // axes; a missing one (beyond a wall or an open side) adds nothing, as x is zero
        // off the fluid cells and the diagonal holds the boundary.
        let beside = |v: usize, n: usize, axis: usize, stride: usize| -> [Option<usize>; 2] {
            if n < 2 {
                return [None, None];
            }
            let lo = if v > 0 {
                Some(base - stride)
            } else {
                per[axis].then(|| base + (n - 1) * stride)
            };
            let hi = if v + 1 < n {
                Some(base + stride)
            } else {
                per[axis].then(|| base - (n - 1) * stride)
            };
            [lo, hi]
        };
        let [ys, yn] = beside(j, ny, 1, nx);
        let [zd, zu] = beside(k, nz, 2, s);
        let xr = &x[base..base + nx];
        let wrap = per[0] && nx > 1;
        let mut a = 0;
        while a < nx {
            let len = (nx - a).min(ROW_PIECE);
            pad[1..=len].copy_from_slice(&xr[a..a + len]);
            pad[0] = match a {
                0 if wrap => xr[nx - 1],
                0 => T::ZERO,
                _ => xr[a - 1],
            };
            pad[len + 1] = if a + len < nx {
                xr[a + len]
            } else if wrap {
                xr[0]
            } else {
                T::ZERO
            };
            let (xw, xc, xe) = (&pad[..len], &pad[1..=len], &pad[2..len + 2]);
            let code = &self.code[base + a..base + a + len];
            let bs = &b[a..a + len];
            let row = |r: usize| &x[r + a..r + a + len];
            let o = &mut out[a..a + len];
            match (ys, yn, zd, zu) {
                (Some(p), Some(q), Some(u), Some(v)) => {
                    let (xs, xn, xd, xu) = (row(p), row(q), row(u), row(v));
                    // Zipped slices, so no index needs a bounds check.
                    let cells = xw
                        .iter()
                        .zip(xe)
                        .zip(xs.iter().zip(xn))
                        .zip(xd.iter().zip(xu));
                    let own = xc.iter().zip(bs).zip(code);
                    for ((ot, (((w, e), (s, n)), (d, u))), ((&x, &b), &k)) in
                        o.iter_mut().zip(cells).zip(own)
                    {
                        let off = (*w + *e) + (*s + *n) + (*d + *u);
                        let (m, dg) = mask_diag(k, c);
                        *ot = emit(m * (dg * x - c * off), b, x, k);
                    }
                }
                (Some(p), Some(q), None, None) if nz == 1 => {
                    let (xs, xn) = (row(p), row(q));
                    let cells = xw.iter().zip(xe).zip(xs.iter().zip(xn));
                    let own = xc.iter().zip(bs).zip(code);
                    for ((ot, ((w, e), (s, n))), ((&x, &b), &k)) in o.iter_mut().zip(cells).zip(own)
                    {
                        let off = (*w + *e) + (*s + *n);
                        let (m, dg) = mask_diag(k, c);
                        *ot = emit(m * (dg * x - c * off), b, x, k);
                    }
                }
                rows => {
                    // A row on the grid's edge: the neighbours present, one pass each.
                    for (ot, (w, e)) in o.iter_mut().zip(xw.iter().zip(xe)) {
                        *ot = *w + *e;
                    }
                    for r in [rows.0, rows.1, rows.2, rows.3].into_iter().flatten() {
                        for (ot, xr) in o.iter_mut().zip(row(r)) {
                            *ot += *xr;
                        }
                    }
                    for (ot, ((&x, &b), &k)) in o.iter_mut().zip(xc.iter().zip(bs).zip(code)) {
                        let (m, dg) = mask_diag(k, c);
                        *ot = emit(m * (dg * x - c * *ot), b, x, k);
                    }
                }
            }
            a += len;
        }
    }

    /// `y = A x` (zero off the fluid cells; x zero there).
    fn apply<T: Real>(&self, y: &mut [T], x: &[T]) {
        let nx = self.n[0];
        let rows = self.task_rows();
        y.par_chunks_mut(rows * nx).enumerate().for_each(|(t, ys)| {
            let mut pad = [T::ZERO; ROW_PIECE + 2];
            for (lr, row) in ys.chunks_mut(nx).enumerate() {
                let r = t * rows + lr;
                let own = &x[r * nx..(r + 1) * nx];
                self.row_into(r, x, row, own, &mut pad, |ax, _, _, _| ax);
            }
        });
    }

    /// `y = A x` for CG's vectors, returning `x . y` (per task, added over
    /// `par_reduce`'s fixed tree).
    fn apply_dot(&self, y: &mut [f64], x: &[f64]) -> f64 {
        let nx = self.n[0];
        let task = self.task_rows() * nx;
        let len = y.len();
        let yd = Disjoint::new(y);
        let [s] = par_reduce(chunk_count(len, task), &|t| {
            let range = chunk_range(t, len, task);
            // SAFETY: the tasks' ranges are disjoint.
            let ys = unsafe { yd.slice(range.clone()) };
            let mut pad = [0.0; ROW_PIECE + 2];
            for (lr, row) in ys.chunks_mut(nx).enumerate() {
                let r = range.start / nx + lr;
                let own = &x[r * nx..(r + 1) * nx];
                self.row_into(r, x, row, own, &mut pad, |ax, _, _, _| ax);
            }
            [dot_lanes(&x[range], ys)]
        });
        s
    }

    /// Rows of x per parallel task: a z-slab in 3-D, in 2-D (one slab) enough rows for a
    /// task's work to outweigh handing it out.
    fn task_rows(&self) -> usize {
        // At least 16k cells a task: smaller ones cost more to hand out than to run.
        let (nx, ny) = (self.n[0], self.n[1]);
        if self.n[2] > 1 {
            ny
        } else {
            (16_384 / nx).clamp(1, ny)
        }
    }

    /// `out = f(A x, b, x, omega D^-1)` row by row for level vectors (the residual and
    /// the fused Jacobi sweep).
    fn rows_with<T: Real>(
        &self,
        x: &[T],
        b: &[T],
        out: &mut [T],
        f: impl Fn(T, T, T, T) -> T + Sync,
    ) {
        let nx = self.n[0];
        let rows = self.task_rows();
        let inv_h2 = T::of(self.inv_h2);
        out.par_chunks_mut(rows * nx)
            .enumerate()
            .with_min_len(grain(rows * nx))
            .for_each(|(t, os)| {
                let mut pad = [T::ZERO; ROW_PIECE + 2];
                for (lr, row) in os.chunks_mut(nx).enumerate() {
                    let r = t * rows + lr;
                    let b = &b[r * nx..(r + 1) * nx];
                    self.row_into(r, x, row, b, &mut pad, |ax, b, x, code| {
                        // Dead, and removed, where `f` does not read it (the residual).
                        f(ax, b, x, smoother_weight(code, inv_h2))
                    });
                }
            });
    }

    /// `(A x)_idx` for a fluid cell `idx` with the face neighbours `nb` (`band_nb`).
    #[inline]
    fn row<T: Real>(&self, idx: usize, nb: &[u32; 6], x: &[T]) -> T {
        let mut off = T::ZERO;
        for &j in nb.iter().take_while(|&&j| j != u32::MAX) {
            off += x[j as usize];
        }
        let c = T::of(self.inv_h2);
        mask_diag(self.code[idx], c).1 * x[idx] - c * off
    }

    /// `r = b - A x` (b is zero off the fluid cells, and so is A x).
    fn residual<T: Real>(&self, w: &mut Work<T>) {
        self.rows_with(&w.x, &w.b, &mut w.r, |ax, b, _, _| b - ax);
    }

    /// `sweeps` damped Jacobi sweeps on `A x = b` over the boundary band only.
    fn smooth_band<T: Real>(&self, w: &mut Work<T>, sweeps: usize) {
        // Band cells per parallel task (the residuals, then the updates; fixed chunks, so
        // the bits do not depend on the thread count).
        const CHUNK: usize = 4096;
        for _ in 0..sweeps {
            let (x, b) = (&w.x, &w.b);
            w.band_r
                .par_chunks_mut(CHUNK)
                .zip(self.band.par_chunks(CHUNK))
                .zip(self.band_nb.par_chunks(CHUNK))
                .with_min_len(grain(CHUNK))
                .for_each(|((rs, cells), nbs)| {
                    for ((r, &i), nb) in rs.iter_mut().zip(cells).zip(nbs) {
                        *r = b[i] - self.row(i, nb, x);
                    }
                });
            // The updates, parallel over z-slabs (the band is in cell order).
            let slab = self.n[0] * self.n[1];
            let (band, start, inv, br) = (&self.band, &self.band_start, &self.band_inv, &w.band_r);
            w.x.par_chunks_mut(slab)
                .enumerate()
                .with_min_len(grain(slab))
                .for_each(|(k, xs)| {
                    for m in start[k]..start[k + 1] {
                        xs[band[m] - k * slab] += T::of(inv[m]) * br[m];
                    }
                });
        }
    }

    /// `sweeps` damped Jacobi sweeps on `A x = b` from `x = 0`: the first is
    /// `x = omega D^-1 b` (A x vanishes), one pass over b with no stencil.
    fn smooth_from_zero<T: Real>(&self, w: &mut Work<T>, sweeps: usize) {
        if sweeps == 0 {
            w.x.fill(T::ZERO);
            return;
        }
        let inv_h2 = T::of(self.inv_h2);
        w.x.par_iter_mut()
            .zip(w.b.par_iter())
            .zip(self.code.par_iter())
            .with_min_len(TASK_CELLS)
            .for_each(|((x, &b), &code)| {
                *x = smoother_weight(code, inv_h2) * b;
            });
        self.smooth(w, sweeps - 1);
    }

    /// `sweeps` damped Jacobi sweeps on `A x = b` from the present x, each one pass:
    /// `x' = x + omega D^-1 (b - A x)` into the second buffer, then swapped.
    fn smooth<T: Real>(&self, w: &mut Work<T>, sweeps: usize) {
        for _ in 0..sweeps {
            self.rows_with(&w.x, &w.b, &mut w.x2, |ax, b, x, inv| x + inv * (b - ax));
            std::mem::swap(&mut w.x, &mut w.x2);
        }
    }
}

/// The trilinear (cell-centred) interpolation of fine cell `c` of a grid `fine` from the
/// coarse grid `coarse` with kinds `ckind`: the product of each axis's `taps` (its
/// parent's weight 27/64 and the parent's neighbours towards the cell 9/64, 3/64 and
/// 1/64 inside the grid; mirrored beyond a wall, zero beyond an open side, wrapped
/// across a periodic one). A coarse cell that is empty contributes zero (p = 0 there);
/// one that is solid hands its weight to the parent (the value reflected). Returns
/// eight coarse indices and weights (repeats allowed).
#[inline]
fn weights(
    c: [usize; 3],
    fine: [usize; 3],
    coarse: [usize; 3],
    sides: &[[Side; 2]; 3],
    ckind: &[CellKind],
) -> ([usize; 8], [f64; 8]) {
    let t: [[(usize, f64); 2]; 3] =
        std::array::from_fn(|a| taps(c[a], fine[a], coarse[a], sides[a]));
    let index = |q: [usize; 3]| q[0] + coarse[0] * (q[1] + coarse[1] * q[2]);
    let pidx = index(c.map(|v| v / 2));
    let mut cells = [pidx; 8];
    let mut w = [0.0; 8];
    for (m, (cm, wm)) in cells.iter_mut().zip(w.iter_mut()).enumerate() {
        let pick: [(usize, f64); 3] = std::array::from_fn(|a| t[a][m >> a & 1]);
        *wm = pick[0].1 * pick[1].1 * pick[2].1;
        if *wm == 0.0 {
            continue;
        }
        let qidx = index(pick.map(|p| p.0));
        match ckind[qidx] {
            CellKind::Fluid => *cm = qidx,
            CellKind::Empty => *wm = 0.0,
            CellKind::Solid => {} // the parent's
        }
    }
    (cells, w)
}

/// The fluid mask (1 or 0) and the diagonal `d_i / h^2` of a cell from its code (`1 + d_i`
/// on fluid cells, 0 elsewhere; [`Level::code`]) and `1 / h^2`: branch-free, so the row
/// loops stay vectorised. `(code - 1) inv_h2` is `d_i inv_h2` exactly.
#[inline(always)]
fn mask_diag<T: Real>(code: u8, inv_h2: T) -> (T, T) {
    let k = T::of(f64::from(code));
    let one = T::of(1.0);
    (k.min(one), (k - one).max(T::ZERO) * inv_h2)
}

/// The damped Jacobi weight `omega / (d_i / h^2)` of a cell from its code, 0 where the
/// diagonal is (off the fluid cells, and a fluid cell with no open face).
#[inline(always)]
fn smoother_weight<T: Real>(code: u8, inv_h2: T) -> T {
    let d = mask_diag(code, inv_h2).1;
    if d > T::ZERO {
        T::of(OMEGA) / d
    } else {
        T::ZERO
    }
}

/// Where each z-slab of `slab` cells starts in the ascending cell list `cells`
/// (`nz + 1` entries).
fn slab_starts<T: Copy>(
    cells: &[T],
    index: impl Fn(T) -> usize,
    slab: usize,
    nz: usize,
) -> Vec<usize> {
    (0..=nz)
        .map(|k| cells.partition_point(|&i| index(i) < k * slab))
        .collect()
}

/// Which axes are periodic.
fn periodic(sides: &[[Side; 2]; 3]) -> [bool; 3] {
    sides.map(|s| s[0] == Side::Periodic)
}

/// Which cells of the grid `n` (at least two cells along x and y; `sides` beyond it)
/// have only fluid cells (`fluid` set) in their 3 x 3 x 3 block (3 x 3 on a plane) as
/// far as it lies in the grid, and are not at the end of a periodic axis: the transfers
/// then need no boundary rule but each axis's `taps`. The box sum of the cells that are
/// not fluid, one axis at a time over shifted rows (a cell-by-cell walk over the 27
/// took most of the coarse levels' setup).
fn box_interior(n: [usize; 3], sides: &[[Side; 2]; 3], fluid: &[u8]) -> ZeroedBuf<bool> {
    let [nx, ny, nz] = n;
    let s = nx * ny;
    let rows = (4096 / nx).max(1);
    let per = periodic(sides);
    // Along x: the cell and its neighbours in the row.
    let mut sx = vec![0u8; fluid.len()];
    sx.par_chunks_mut(nx)
        .zip(fluid.par_chunks(nx))
        .with_min_len(rows)
        .for_each(|(o, m)| {
            for (i, o) in o.iter_mut().enumerate() {
                *o = (i.saturating_sub(1)..(i + 2).min(nx))
                    .map(|j| 1 - m[j])
                    .sum();
            }
        });
    // Along y, the rows in the grid.
    let mut sy = vec![0u8; fluid.len()];
    sy.par_chunks_mut(nx)
        .enumerate()
        .with_min_len(rows)
        .for_each(|(r, o)| {
            let (j, k) = (r % ny, r / ny);
            for y in j.saturating_sub(1)..(j + 2).min(ny) {
                let b = (k * ny + y) * nx;
                for (o, v) in o.iter_mut().zip(&sx[b..b + nx]) {
                    *o += v;
                }
            }
        });
    // Along z (none on a plane), and the test.
    let flat = nz == 1;
    let mut out = ZeroedBuf::new(fluid.len());
    out.par_chunks_mut(nx)
        .enumerate()
        .with_min_len(rows)
        .for_each(|(r, o)| {
            let (j, k) = (r % ny, r / ny);
            let end = |v: usize, n: usize, a: usize| per[a] && (v == 0 || v + 1 == n);
            if end(j, ny, 1) || (!flat && end(k, nz, 2)) {
                return;
            }
            let b = r * nx;
            let zs = if flat {
                k..k + 1
            } else {
                k.saturating_sub(1)..(k + 2).min(nz)
            };
            for (i, o) in o.iter_mut().enumerate() {
                let sum: u8 = zs.clone().map(|z| sy[b - k * s + z * s + i]).sum();
                *o = sum == 0 && !end(i, nx, 0);
            }
        });
    out
}

/// For every cell of the grid `n`, the sum of the one-byte mask `m` over its face
/// neighbours as [`for_neighbours`] finds them (a periodic axis of two cells counts its
/// other cell twice), by adding shifted rows: no per-cell indexing, so the loops
/// vectorise. At most six neighbours: a mask of 0 and 1 sums within a byte.
fn neighbour_sum(n: [usize; 3], per: [bool; 3], m: &[u8]) -> ZeroedBuf<u8> {
    let [nx, ny, nz] = n;
    let s = nx * ny;
    let mut out = ZeroedBuf::new(m.len());
    out.par_chunks_mut(nx)
        .enumerate()
        .with_min_len((4096 / nx).max(1))
        .for_each(|(r, o)| {
            let (j, k) = (r % ny, r / ny);
            let base = r * nx;
            let row = &m[base..base + nx];
            if nx >= 2 {
                for (a, b) in o[1..].iter_mut().zip(&row[..nx - 1]) {
                    *a += b;
                }
                for (a, b) in o[..nx - 1].iter_mut().zip(&row[1..]) {
                    *a += b;
                }
                if per[0] {
                    o[0] += row[nx - 1];
                    o[nx - 1] += row[0];
                }
            }
            let mut add = |start: usize| {
                for (a, b) in o.iter_mut().zip(&m[start..start + nx]) {
                    *a += b;
                }
            };
            // The rows beside along y and z (wrapped on a periodic axis).
            for (v, len, stride, p) in [(j, ny, nx, per[1]), (k, nz, s, per[2])] {
                if len < 2 {
                    continue;
                }
                if v > 0 {
                    add(base - stride);
                } else if p {
                    add(base + (len - 1) * stride);
                }
                if v + 1 < len {
                    add(base + stride);
                } else if p {
                    add(base - (len - 1) * stride);
                }
            }
        });
    out
}

/// How many faces of the cell at `c` lie on an open side of the grid.
fn open_faces(n: [usize; 3], sides: &[[Side; 2]; 3], c: [usize; 3]) -> usize {
    (0..3)
        .map(|a| {
            usize::from(c[a] == 0 && sides[a][0] == Side::Open)
                + usize::from(c[a] + 1 == n[a] && sides[a][1] == Side::Open)
        })
        .sum()
}

/// Calls `f` with the index of each face neighbour of cell `idx` in the grid `n`: inside
/// it, or across a periodic axis (`per`) at the other end (an axis of one cell has no
/// neighbours along it).
#[inline]
fn for_neighbours(n: [usize; 3], per: [bool; 3], idx: usize, mut f: impl FnMut(usize)) {
    let (nx, ny) = (n[0], n[1]);
    let c = [idx % nx, (idx / nx) % ny, idx / (nx * ny)];
    let stride = [1, nx, nx * ny];
    for a in 0..3 {
        if n[a] < 2 {
            continue;
        }
        if c[a] > 0 {
            f(idx - stride[a]);
        } else if per[a] {
            f(idx + (n[a] - 1) * stride[a]);
        }
        if c[a] + 1 < n[a] {
            f(idx + stride[a]);
        } else if per[a] {
            f(idx - (n[a] - 1) * stride[a]);
        }
    }
}

/// A Poisson problem on a cell grid, with its multigrid hierarchy and CG vectors (built
/// once; solves allocate nothing, except that the first solve in the precision that is
/// not the default makes its V-cycle vectors).
#[derive(Clone, Debug)]
pub struct GridPoisson {
    levels: Vec<Level>,
    /// No fluid cell touches an empty one: the constant null space.
    singular: bool,
    /// The number of fluid cells.
    fluid: usize,
    /// CG's residual, search direction and its product with A (the preconditioned
    /// residual is the fine level's `Work::x`).
    r: ZeroedBuf<f64>,
    p: ZeroedBuf<f64>,
    q: ZeroedBuf<f64>,
    /// The V-cycle's vectors in each precision: the default's made with the problem, the
    /// other's by the first solve that asks for it.
    work32: Vec<Work<f32>>,
    work64: Vec<Work<f64>>,
}

impl GridPoisson {
    /// The problem on `n[0] x n[1] x n[2]` cells of side `h` (x fastest) with the cell
    /// kinds `kind` and walls all round; 2-D grids have `n[2] = 1`.
    pub fn new(n: [usize; 3], h: f64, kind: Vec<CellKind>) -> Result<Self, SolveError> {
        Self::with_sides(n, h, kind, [[Side::Wall; 2]; 3])
    }

    /// [`GridPoisson::new`] with what lies beyond each side (`sides[axis][0]` low,
    /// `[1]` high). A periodic axis must be periodic on both sides.
    pub fn with_sides(
        n: [usize; 3],
        h: f64,
        kind: Vec<CellKind>,
        sides: [[Side; 2]; 3],
    ) -> Result<Self, SolveError> {
        let cells = n.iter().try_fold(1usize, |a, &b| a.checked_mul(b));
        if cells != Some(kind.len()) || kind.is_empty() {
            return Err(SolveError::Invalid(format!(
                "{} cell kinds for a grid of {} x {} x {} cells",
                kind.len(),
                n[0],
                n[1],
                n[2]
            )));
        }
        if kind.len() >= u32::MAX as usize {
            return Err(SolveError::Invalid(format!(
                "{} cells: more than 32-bit cell indices address",
                kind.len()
            )));
        }
        if !(h > 0.0 && h.is_finite()) {
            return Err(SolveError::Invalid(format!(
                "cell size must be positive and finite, not {h}"
            )));
        }
        if let Some(a) =
            (0..3).find(|&a| (sides[a][0] == Side::Periodic) != (sides[a][1] == Side::Periodic))
        {
            return Err(SolveError::Invalid(format!(
                "axis {a} is periodic on one side only"
            )));
        }
        let per = periodic(&sides);
        let singular = !kind.par_iter().enumerate().any(|(idx, &c)| {
            c == CellKind::Fluid && {
                let c = [idx % n[0], (idx / n[0]) % n[1], idx / (n[0] * n[1])];
                let mut open = open_faces(n, &sides, c) > 0;
                for_neighbours(n, per, idx, |j| open |= kind[j] == CellKind::Empty);
                open
            }
        });
        let mut levels = vec![Level::new(n, sides, h, kind, false)];
        let mut h = h;
        while levels.last().is_some_and(|l| l.kind.len() > COARSEST_CELLS) {
            let fine = levels.last().expect("one level at least");
            let nc = fine.n.map(|c| c.div_ceil(2));
            // A periodic axis coarsens only while it halves exactly.
            if nc == fine.n || (0..3).any(|a| per[a] && fine.n[a] % 2 == 1) {
                break;
            }
            let mut kind = vec![CellKind::Solid; nc[0] * nc[1] * nc[2]];
            kind.par_iter_mut().enumerate().for_each(|(c, kc)| {
                let (ci, cj, ck) = (c % nc[0], (c / nc[0]) % nc[1], c / (nc[0] * nc[1]));
                let (mut any_fluid, mut any_empty) = (false, false);
                for dz in 0..2 {
                    for dy in 0..2 {
                        for dx in 0..2 {
                            let (i, j, k) = (2 * ci + dx, 2 * cj + dy, 2 * ck + dz);
                            if i < fine.n[0] && j < fine.n[1] && k < fine.n[2] {
                                match fine.kind[i + fine.n[0] * (j + fine.n[1] * k)] {
                                    CellKind::Fluid => any_fluid = true,
                                    CellKind::Empty => any_empty = true,
                                    CellKind::Solid => {}
                                }
                            }
                        }
                    }
                }
                *kc = if any_empty {
                    CellKind::Empty
                } else if any_fluid {
                    CellKind::Fluid
                } else {
                    CellKind::Solid
                };
            });
            h *= 2.0;
            levels.push(Level::new(nc, sides, h, kind, true));
        }
        // Each level's cells that restrict through the boundary rule, and the x-restricted
        // rows' scratch.
        for l in 0..levels.len().saturating_sub(1) {
            let (fine, coarse) = levels.split_at_mut(l + 1);
            let (f, c) = (&mut fine[l], &coarse[0]);
            let (fnx, fny) = (f.n[0], f.n[1]);
            let (cnx, cny) = (c.n[0], c.n[1]);
            let slab = fnx * fny;
            // Row by row: each fine row's parents are one coarse row.
            let mut edge = vec![false; f.kind.len()];
            edge.par_chunks_mut(fnx)
                .enumerate()
                .with_min_len((4096 / fnx).max(1))
                .for_each(|(r, es)| {
                    let (j, k) = (r % fny, r / fny);
                    let prow = &c.interior[cnx * (j / 2 + cny * (k / 2))..][..cnx];
                    let kinds = &f.kind[r * fnx..][..fnx];
                    for (i, e) in es.iter_mut().enumerate() {
                        *e = kinds[i] == CellKind::Fluid && !prow[i / 2];
                    }
                });
            f.edge_cells = (0..f.kind.len() as u32)
                .into_par_iter()
                .filter(|&idx| edge[idx as usize])
                .collect();
            f.edge_start = slab_starts(&f.edge_cells, |i| i as usize, slab, f.n[2]);
            f.edge_weights = f
                .edge_cells
                .par_iter()
                .map(|&idx| {
                    let idx = idx as usize;
                    let c3 = [idx % fnx, (idx / fnx) % fny, idx / slab];
                    let (cells, w) = weights(c3, f.n, c.n, &c.sides, &c.kind);
                    // Coarse indices fit in u32: the fine ones do.
                    (cells.map(|q| q as u32), w.map(|v| v as f32))
                })
                .collect();
        }
        let l0 = &levels[0];
        let cells = l0.kind.len();
        let fluid = l0
            .kind
            .par_iter()
            .filter(|&&k| k == CellKind::Fluid)
            .count();
        let (work32, work64) = match Precision::default() {
            Precision::Single => (Work::for_levels(&levels), Vec::new()),
            Precision::Double => (Vec::new(), Work::for_levels(&levels)),
        };
        Ok(Self {
            levels,
            singular,
            fluid,
            r: ZeroedBuf::new(cells),
            p: ZeroedBuf::new(cells),
            q: ZeroedBuf::new(cells),
            work32,
            work64,
        })
    }

    /// Levels of the multigrid hierarchy (the grid itself included).
    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// Whether the problem has only walls (the constant null space).
    pub fn is_singular(&self) -> bool {
        self.singular
    }

    /// `y = A x` on the grid; x must be zero off the fluid cells (as every solution
    /// [`GridPoisson::solve`] returns is).
    pub fn apply(&self, y: &mut [f64], x: &[f64]) {
        self.levels[0].apply(y, x);
    }

    /// Solves `A p = b` from the initial guess in `p` (values off the fluid cells are
    /// set to zero; `b` there is ignored). For a singular problem `b` is taken with its
    /// mean over the fluid cells removed and `p` comes back with zero mean. Runs on a
    /// thread of rayon's pool ([`largestep_kernels::par::on_pool`]).
    pub fn solve(
        &mut self,
        p: &mut [f64],
        b: &[f64],
        params: &PoissonParams,
    ) -> Result<SolveInfo, SolveError> {
        largestep_kernels::par::on_pool(|| self.solve_here(p, b, params))
    }

    /// [`GridPoisson::solve`] on the calling thread.
    fn solve_here(
        &mut self,
        p: &mut [f64],
        b: &[f64],
        params: &PoissonParams,
    ) -> Result<SolveInfo, SolveError> {
        let start = Instant::now();
        let cells = self.levels[0].kind.len();
        if p.len() != cells || b.len() != cells {
            return Err(SolveError::Invalid(format!(
                "vectors of {} and {} values for {cells} cells",
                p.len(),
                b.len()
            )));
        }
        if let Some(i) = b.iter().position(|v| !v.is_finite()) {
            return Err(SolveError::Invalid(format!(
                "the right side is not finite at cell {i}: {}",
                b[i]
            )));
        }
        match params.precision {
            Precision::Single => self.cg_in(|g| &mut g.work32, p, b, params, start),
            Precision::Double => self.cg_in(|g| &mut g.work64, p, b, params, start),
        }
    }

    /// [`GridPoisson::cg`] in the V-cycle vectors that `slot` picks, made first if this
    /// is the first solve in their precision.
    fn cg_in<T: Real>(
        &mut self,
        slot: fn(&mut GridPoisson) -> &mut Vec<Work<T>>,
        p: &mut [f64],
        b: &[f64],
        params: &PoissonParams,
        start: Instant,
    ) -> Result<SolveInfo, SolveError> {
        if slot(self).is_empty() {
            let made = Work::for_levels(&self.levels);
            *slot(self) = made;
        }
        let mut work = std::mem::take(slot(self));
        let out = self.cg(&mut work, p, b, params, start);
        *slot(self) = work;
        out
    }

    /// [`GridPoisson::solve`] after its checks, with the preconditioner's vectors in `T`.
    ///
    /// The search directions take the Polak-Ribiere `beta = z_k+1 . (r_k+1 - r_k) /
    /// z_k . r_k` (here `-alpha z_k+1 . A p_k / z_k . r_k`), which equals the usual
    /// `z_k+1 . r_k+1 / z_k . r_k` for a fixed preconditioner and keeps CG converging
    /// when the preconditioner varies a little from one application to the next, as one
    /// rounded to `f32` does (Notay 2000, "Flexible conjugate gradients").
    fn cg<T: Real>(
        &mut self,
        work: &mut [Work<T>],
        p: &mut [f64],
        b: &[f64],
        params: &PoissonParams,
        start: Instant,
    ) -> Result<SolveInfo, SolveError> {
        let GridPoisson {
            levels,
            singular,
            fluid,
            r,
            p: d,
            q,
            ..
        } = self;
        let levels = &levels[..];
        let (singular, fluid) = (*singular, *fluid);
        let mean = |v: &mut [f64]| {
            if singular {
                zero_mean(&levels[0], fluid, v);
            }
        };
        let code = &levels[0].code;
        // p zero off the fluid cells (and where not finite), and q = b there.
        p.par_iter_mut()
            .zip(q.par_iter_mut())
            .zip(b.par_iter())
            .zip(code.par_iter())
            .with_min_len(CG_CHUNK)
            .for_each(|(((p, q), &b), &c)| {
                let fluid = c > 0;
                if !fluid || !p.is_finite() {
                    *p = 0.0;
                }
                *q = if fluid { b } else { 0.0 };
            });
        mean(q);
        let bnorm = dot_par(q, q).sqrt();
        // r = b - A p.
        levels[0].apply(r, p);
        r.par_iter_mut()
            .zip(q.par_iter())
            .with_min_len(CG_CHUNK)
            .for_each(|(r, q)| *r = q - *r);
        mean(r);
        let target = params.tolerance * bnorm;
        let mut rnorm = dot_par(r, r).sqrt();
        if rnorm <= target || bnorm == 0.0 {
            return Ok(SolveInfo {
                iterations: 0,
                residual: if bnorm > 0.0 { rnorm / bnorm } else { 0.0 },
                seconds: start.elapsed().as_secs_f64(),
            });
        }
        work[0]
            .b
            .par_iter_mut()
            .zip(r.par_iter())
            .with_min_len(CG_CHUNK)
            .for_each(|(b, &r)| *b = T::of(r));
        let pre = params.preconditioner;
        let precondition = |work: &mut [Work<T>]| precondition(levels, work, pre, singular, fluid);
        precondition(work);
        d.par_iter_mut()
            .zip(work[0].x.par_iter())
            .with_min_len(CG_CHUNK)
            .for_each(|(d, &z)| *d = z.get());
        let [mut rz, _] = cg_dots(r, q, &work[0].x);
        for it in 1..=params.max_iterations {
            let pq = levels[0].apply_dot(q, d);
            if pq.is_nan() || pq <= 0.0 {
                return Err(SolveError::NotPositiveDefinite {
                    what: "curvature p.Ap",
                    at: it,
                    value: pq,
                });
            }
            let alpha = rz / pq;
            rnorm = cg_update(p, r, &mut work[0].b, d, q, alpha).sqrt();
            if !rnorm.is_finite() {
                return Err(SolveError::NonFinite {
                    what: "Poisson residual",
                    iteration: it,
                });
            }
            if rnorm <= target {
                mean(p);
                return Ok(SolveInfo {
                    iterations: it,
                    residual: rnorm / bnorm,
                    seconds: start.elapsed().as_secs_f64(),
                });
            }
            precondition(work);
            let z = &work[0].x;
            let [rz_new, zq] = cg_dots(r, q, z);
            let beta = -alpha * zq / rz;
            rz = rz_new;
            d.par_chunks_mut(CG_CHUNK)
                .zip(z.par_chunks(CG_CHUNK))
                .for_each(|(d, z)| {
                    for (d, &z) in d.iter_mut().zip(z) {
                        *d = z.get() + beta * *d;
                    }
                });
        }
        Err(SolveError::NotConverged {
            iterations: params.max_iterations,
            residual: rnorm / bnorm,
            tolerance: params.tolerance,
        })
    }
}

/// Cells per chunk of CG's vector passes, whose sums `par_reduce` adds over a fixed
/// tree: the same bits on any thread count.
const CG_CHUNK: usize = 16_384;

/// `sum a_i b_i` with eight running sums, added in a fixed order (so the loop
/// vectorises, whichever of `f32` and `f64` each side is).
#[inline]
fn dot_lanes<T: Real, U: Real>(a: &[T], b: &[U]) -> f64 {
    let mut acc = [0.0f64; 8];
    let (ac, bc) = (a.chunks_exact(8), b.chunks_exact(8));
    let mut s = 0.0;
    for (x, y) in ac.remainder().iter().zip(bc.remainder()) {
        s += x.get() * y.get();
    }
    for (x, y) in ac.zip(bc) {
        for k in 0..8 {
            acc[k] += x[k].get() * y[k].get();
        }
    }
    acc.iter().sum::<f64>() + s
}

/// One pass of CG: `x += alpha p`, `r -= alpha q`, the preconditioner's right side
/// `b = r` rounded to `T`; returns `r . r`.
fn cg_update<T: Real>(
    x: &mut [f64],
    r: &mut [f64],
    b: &mut [T],
    p: &[f64],
    q: &[f64],
    alpha: f64,
) -> f64 {
    let len = x.len();
    let (xd, rd, bd) = (Disjoint::new(x), Disjoint::new(r), Disjoint::new(b));
    let [s] = par_reduce(chunk_count(len, CG_CHUNK), &|c| {
        let range = chunk_range(c, len, CG_CHUNK);
        // SAFETY: the chunks' ranges are disjoint.
        let (x, r, b) = unsafe {
            (
                xd.slice(range.clone()),
                rd.slice(range.clone()),
                bd.slice(range.clone()),
            )
        };
        axpy(x, alpha, &p[range.clone()]);
        axpy(r, -alpha, &q[range]);
        for (b, &r) in b.iter_mut().zip(r.iter()) {
            *b = T::of(r);
        }
        // The chunk is still in cache.
        [dot(r, r)]
    });
    s
}

/// `[r . z, z . q]` in one pass.
fn cg_dots<T: Real>(r: &[f64], q: &[f64], z: &[T]) -> [f64; 2] {
    let len = r.len();
    par_reduce(chunk_count(len, CG_CHUNK), &|c| {
        let range = chunk_range(c, len, CG_CHUNK);
        let z = &z[range.clone()];
        [dot_lanes(&r[range.clone()], z), dot_lanes(z, &q[range])]
    })
}

/// Sets the mean of `v` over the `fluid` fluid cells of `level` to zero (singular
/// problems: the constant null space).
fn zero_mean<T: Real>(level: &Level, fluid: usize, v: &mut [T]) {
    if fluid == 0 {
        return;
    }
    let len = v.len();
    let [sum] = par_reduce(chunk_count(len, CG_CHUNK), &|c| {
        let range = chunk_range(c, len, CG_CHUNK);
        [v[range.clone()]
            .iter()
            .zip(&level.code[range])
            .filter(|(_, &c)| c > 0)
            .map(|(v, _)| v.get())
            .sum()]
    });
    let mean = T::of(sum / fluid as f64);
    v.par_chunks_mut(CG_CHUNK)
        .zip(level.code.par_chunks(CG_CHUNK))
        .for_each(|(v, c)| {
            for (v, &c) in v.iter_mut().zip(c) {
                if c > 0 {
                    *v = *v - mean;
                }
            }
        });
}

/// `z = M^-1 b` for the preconditioner `pre`, from the fine level's right side into its
/// correction (`work[0].b` to `work[0].x`), with zero mean for a singular problem.
fn precondition<T: Real>(
    levels: &[Level],
    work: &mut [Work<T>],
    pre: PoissonPreconditioner,
    singular: bool,
    fluid: usize,
) {
    match pre {
        PoissonPreconditioner::Jacobi => {
            let l0 = &levels[0];
            let c = T::of(l0.inv_h2);
            let w = &mut work[0];
            w.x.par_iter_mut()
                .zip(w.b.par_iter())
                .zip(l0.code.par_iter())
                .with_min_len(CG_CHUNK)
                .for_each(|((x, &b), &code)| {
                    let d = mask_diag(code, c).1;
                    *x = if d > T::ZERO { b / d } else { T::ZERO };
                });
        }
        PoissonPreconditioner::Multigrid => v_cycle(levels, work, 0),
    }
    if singular {
        zero_mean(&levels[0], fluid, &mut work[0].x);
    }
}

/// One V-cycle on level `l` of `levels` for `A x = b` from `x = 0`, in the vectors
/// `work` (one per level).
fn v_cycle<T: Real>(levels: &[Level], work: &mut [Work<T>], l: usize) {
    let lv = &levels[l];
    if l + 1 == levels.len() {
        lv.smooth_from_zero(&mut work[l], COARSE_SWEEPS);
        return;
    }
    lv.smooth_from_zero(&mut work[l], SWEEPS);
    lv.smooth_band(&mut work[l], BAND_SWEEPS);
    lv.residual(&mut work[l]);
    restrict(levels, work, l);
    v_cycle(levels, work, l + 1);
    prolong(levels, work, l);
    lv.smooth_band(&mut work[l], BAND_SWEEPS);
    lv.smooth(&mut work[l], SWEEPS);
}

/// Along one axis, the two coarse cells that fine cell `i` of a row of `fine` cells
/// interpolates from (a grid of `coarse` cells along it, `sides` beyond its ends), with
/// their weights: its parent `i / 2` with 3/4 and the parent's neighbour towards the
/// cell with 1/4. Beyond a wall the neighbour is the parent mirrored (weights 1 and 0),
/// beyond an open side it is zero (3/4 and 0), beyond a periodic side the cell at the
/// other end; an axis of one fine cell (2-D) has no neighbour (1 and 0). A neighbour
/// with weight 0 is named as the parent.
#[inline]
fn taps(i: usize, fine: usize, coarse: usize, sides: [Side; 2]) -> [(usize, f64); 2] {
    let q = i / 2;
    if fine == 1 {
        return [(q, 1.0), (q, 0.0)];
    }
    let (inside, side) = if i.is_multiple_of(2) {
        (q.checked_sub(1), sides[0])
    } else {
        ((q + 1 < coarse).then_some(q + 1), sides[1])
    };
    match (inside, side) {
        (Some(nb), _) => [(q, 0.75), (nb, 0.25)],
        (None, Side::Periodic) if coarse > 1 => [
            (q, 0.75),
            (if i.is_multiple_of(2) { coarse - 1 } else { 0 }, 0.25),
        ],
        (None, Side::Open) => [(q, 0.75), (q, 0.0)],
        // A wall, or a periodic axis of one coarse cell: the parent itself.
        (None, _) => [(q, 1.0), (q, 0.0)],
    }
}

/// `taps` of fine cell `i` along `axis` of level `f` into level `c`, in `T`.
#[inline]
fn taps_of<T: Real>(f: &Level, c: &Level, axis: usize, i: usize) -> [(usize, T); 2] {
    taps(i, f.n[axis], c.n[axis], f.sides[axis]).map(|(q, w)| (q, T::of(w)))
}

/// The coarse right side of level `l + 1`: R r with R = P^T / 8 (module docs; / 4 in
/// 2-D) of level `l`'s residual, in two passes. First each fine row's cells with an
/// interior parent are restricted along x (`taps`), once per row; then each coarse
/// slab adds the x-restricted rows of the fine slabs that reach it over y and z (the
/// same taps), and the cells with a parent that is not interior (`edge_cells`) scatter
/// through `weights`. Fixed orders throughout: the same bits on any thread count.
fn restrict<T: Real>(levels: &[Level], work: &mut [Work<T>], l: usize) {
    let (f, c) = (&levels[l], &levels[l + 1]);
    let (wf, wc) = work.split_at_mut(l + 1);
    let (wf, wc) = (&mut wf[l], &mut wc[0]);
    let (cnx, cny) = (c.n[0], c.n[1]);
    let cslab = cnx * cny;
    let (fnx, fny) = (f.n[0], f.n[1]);
    let fslab = fnx * fny;
    let (ccode, cint) = (&c.code, &c.interior);
    // R = P^T / (children per coarse cell): 8 in 3-D, 4 in 2-D.
    let scale = T::of(1.0 / (1usize << f.n.iter().filter(|&&v| v > 1).count()) as f64);
    let fr = &wf.r;
    let (w34, w14) = (T::of(0.75), T::of(0.25));
    let one = T::of(1.0);
    wf.xr
        .par_chunks_mut(fny * cnx)
        .enumerate()
        .with_min_len(grain(fslab))
        .for_each(|(k, xs)| {
            for (j, t) in xs.chunks_mut(cnx).enumerate() {
                let prow = &cint[cnx * (j / 2 + cny * (k / 2))..][..cnx];
                let r = &fr[k * fslab + j * fnx..][..fnx];
                // A row's end: the fine cells that reach coarse cell q, by their taps.
                let end = |q: usize| {
                    let mut v = T::ZERO;
                    for i in (2 * q).saturating_sub(1)..(2 * q + 3).min(fnx) {
                        if prow[i / 2] {
                            for (cq, w) in taps_of::<T>(f, c, 0, i) {
                                if cq == q {
                                    v += w * r[i];
                                }
                            }
                        }
                    }
                    v
                };
                if cnx < 3 {
                    for (q, tq) in t.iter_mut().enumerate() {
                        *tq = end(q);
                    }
                    continue;
                }
                t[0] = end(0);
                t[cnx - 1] = end(cnx - 1);
                // The row's middle, q in 1..cnx - 1: cells 2q - 1 to 2q + 2 are in the
                // row and their neighbours towards q too, so the taps are 3/4 and 1/4.
                // Branch-free (the masks as factors), so the loop vectorises.
                let m = cnx - 2;
                let (pl, pc, pr) = (&prow[..m], &prow[1..=m], &prow[2..m + 2]);
                let (ra, rb) = (&r[2..2 * m + 2], &r[1..2 * m + 3]);
                let mask = |b: bool| if b { one } else { T::ZERO };
                for (q, tq) in t[1..=m].iter_mut().enumerate() {
                    let mut v = w34 * mask(pc[q]) * (ra[2 * q] + ra[2 * q + 1]);
                    v += w14 * mask(pl[q]) * rb[2 * q];
                    v += w14 * mask(pr[q]) * rb[2 * q + 3];
                    *tq = v;
                }
            }
        });
    let (xr, edges, edge_start) = (&wf.xr, &f.edge_cells, &f.edge_start);
    let edge_weights = &f.edge_weights;
    // Each coarse slab reads up to four fine ones.
    wc.b.par_chunks_mut(cslab)
        .enumerate()
        .with_min_len(grain(4 * fslab))
        .for_each(|(ck, bs)| {
            bs.fill(T::ZERO);
            let base = ck * cslab;
            for k in (2 * ck).saturating_sub(1)..(2 * ck + 3).min(f.n[2]) {
                // Fine slab k's weight in coarse slab ck (z's taps).
                let wz = taps_of::<T>(f, c, 2, k)
                    .into_iter()
                    .filter(|&(q, _)| q == ck)
                    .fold(T::ZERO, |a, (_, w)| a + w);
                if wz != T::ZERO {
                    for j in 0..fny {
                        let t = &xr[(k * fny + j) * cnx..][..cnx];
                        for (row, wy) in taps_of::<T>(f, c, 1, j) {
                            if wy == T::ZERO {
                                continue;
                            }
                            let w = wz * wy;
                            let b = &mut bs[row * cnx..(row + 1) * cnx];
                            for (bb, tt) in b.iter_mut().zip(t) {
                                *bb += w * *tt;
                            }
                        }
                    }
                }
                let range = edge_start[k]..edge_start[k + 1];
                for (&fidx, (cells, w)) in edges[range.clone()].iter().zip(&edge_weights[range]) {
                    let rf = fr[fidx as usize];
                    if rf == T::ZERO {
                        continue;
                    }
                    for (&cc, &wc) in cells.iter().zip(w) {
                        let cc = cc as usize;
                        if (base..base + cslab).contains(&cc) {
                            bs[cc - base] += T::of(f64::from(wc)) * rf;
                        }
                    }
                }
            }
            // Only fluid cells carry unknowns (a fluid child's empty parent got a
            // share that the coarse problem has no place for).
            for (b, &m) in bs.iter_mut().zip(&ccode[base..base + cslab]) {
                *b *= mask_diag(m, T::of(1.0)).0 * scale;
            }
        });
}

/// Level `l`'s correction plus P times level `l + 1`'s: row by row, the coarse rows
/// blended over y and z (`taps`) into one row of the next level's width, then the fine
/// cells with an interior parent take their x taps of it; the cells whose parent is not
/// interior (`edge_cells`) gather through `weights`.
fn prolong<T: Real>(levels: &[Level], work: &mut [Work<T>], l: usize) {
    let (f, c) = (&levels[l], &levels[l + 1]);
    let (wf, wc) = work.split_at_mut(l + 1);
    let (wf, wc) = (&mut wf[l], &wc[0]);
    let (fnx, fny) = (f.n[0], f.n[1]);
    let fslab = fnx * fny;
    let (cx, fcode, cint) = (&wc.x, &f.code, &c.interior);
    let (edges, edge_start, edge_weights) = (&f.edge_cells, &f.edge_start, &f.edge_weights);
    let (cnx, cny) = (c.n[0], c.n[1]);
    let frow = wf.rows.len() / f.n[2];
    let (w34, w14) = (T::of(0.75), T::of(0.25));
    wf.x.par_chunks_mut(fslab)
        .zip(wf.rows.par_chunks_mut(frow))
        .enumerate()
        .with_min_len(grain(fslab))
        .for_each(|(k, (xs, r))| {
            let tz = taps_of::<T>(f, c, 2, k);
            let pk = tz[0].0;
            for j in 0..fny {
                let ty = taps_of::<T>(f, c, 1, j);
                let pj = ty[0].0;
                let row = |y: usize, z: usize| &cx[cnx * (y + cny * z)..][..cnx];
                let r = &mut r[..cnx];
                // The four coarse rows' weights, products of the y and z taps (9/16,
                // 3/16, 3/16 and 1/16 away from the grid's edge; a neighbour with weight
                // 0 is the parent's row).
                let (a, b) = (row(pj, pk), row(ty[1].0, pk));
                let (c2, d) = (row(pj, tz[1].0), row(ty[1].0, tz[1].0));
                let [(_, wy0), (_, wy1)] = ty;
                let [(_, wz0), (_, wz1)] = tz;
                let w = [wy0 * wz0, wy1 * wz0, wy0 * wz1, wy1 * wz1];
                let rows4 = a.iter().zip(b).zip(c2.iter().zip(d));
                for (ri, ((a, b), (c2, d))) in r.iter_mut().zip(rows4) {
                    *ri = w[0] * *a + w[1] * *b + w[2] * *c2 + w[3] * *d;
                }
                let prow = &cint[cnx * (pj + cny * pk)..][..cnx];
                let base = k * fslab + j * fnx;
                let code = &fcode[base..base + fnx];
                let xrow = &mut xs[j * fnx..(j + 1) * fnx];
                // A row's end: fine cell i by its x taps.
                let mut end = |i: usize| {
                    if prow[i / 2] && code[i] > 0 {
                        let [(a, wa), (b, wb)] = taps_of::<T>(f, c, 0, i);
                        xrow[i] += wa * r[a] + wb * r[b];
                    }
                };
                if cnx < 3 {
                    (0..fnx).for_each(end);
                    continue;
                }
                (0..2).for_each(&mut end);
                (2 * cnx - 2..fnx).for_each(&mut end);
                // The row's middle, fine cells 2 to 2 cnx - 3: parents 1 to cnx - 2,
                // whose neighbours are in the row. Branch-free, so it vectorises.
                let m = cnx - 2;
                let code = &code[2..2 * m + 2];
                let xm = &mut xrow[2..2 * m + 2];
                let (pc, rl, rc, rr) = (&prow[1..=m], &r[..m], &r[1..=m], &r[2..m + 2]);
                for q in 0..m {
                    let e = w34 * rc[q] + w14 * rl[q];
                    let o = w34 * rc[q] + w14 * rr[q];
                    let fe = pc[q] & (code[2 * q] > 0);
                    let fo = pc[q] & (code[2 * q + 1] > 0);
                    xm[2 * q] += if fe { e } else { T::ZERO };
                    xm[2 * q + 1] += if fo { o } else { T::ZERO };
                }
            }
            // The fluid cells whose parent is not interior: the boundary rule.
            let range = edge_start[k]..edge_start[k + 1];
            for (&fidx, (cells, w)) in edges[range.clone()].iter().zip(&edge_weights[range]) {
                let mut v = T::ZERO;
                for (&cc, &wc) in cells.iter().zip(w) {
                    v += T::of(f64::from(wc)) * cx[cc as usize];
                }
                xs[fidx as usize - k * fslab] += v;
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A few problems, each with one to three coarser levels: walls, an open side, a
    /// periodic axis, odd sizes, solid and empty cells, a plane, a level two cells wide.
    fn problems() -> Vec<GridPoisson> {
        let ball = |n: [usize; 3], centre: [f64; 3], radius: f64| -> Vec<CellKind> {
            (0..n[0] * n[1] * n[2])
                .map(|i| {
                    let c = [i % n[0], (i / n[0]) % n[1], i / (n[0] * n[1])];
                    let d: f64 = (0..3)
                        .map(|a| (c[a] as f64 + 0.5 - centre[a]).powi(2))
                        .sum();
                    if d < radius * radius {
                        CellKind::Solid
                    } else {
                        CellKind::Fluid
                    }
                })
                .collect()
        };
        let mut out = Vec::new();
        let w = [Side::Wall; 2];
        let (o, p) = ([Side::Open; 2], [Side::Periodic; 2]);
        out.push(GridPoisson::with_sides(
            [24, 20, 18],
            0.1,
            ball([24, 20, 18], [0.0; 3], 0.0),
            [w; 3],
        ));
        out.push(GridPoisson::with_sides(
            [32, 32, 32],
            0.1,
            ball([32; 3], [16.0; 3], 7.0),
            [w, [Side::Wall, Side::Open], w],
        ));
        // Periodic along x, the top rows empty (a free surface).
        let n = [32, 16, 16];
        let mut kind = ball(n, [10.0, 6.0, 8.0], 4.0);
        for (i, k) in kind.iter_mut().enumerate() {
            if (i / n[0]) % n[1] >= 12 {
                *k = CellKind::Empty;
            }
        }
        out.push(GridPoisson::with_sides(n, 0.1, kind, [p, w, w]));
        out.push(GridPoisson::with_sides(
            [80, 60, 1],
            0.1,
            ball([80, 60, 1], [36.0, 28.0, 0.5], 12.0),
            [o, w, w],
        ));
        // Four cells along x: the next level has two, all row ends.
        out.push(GridPoisson::with_sides(
            [4, 64, 8],
            0.1,
            ball([4, 64, 8], [2.0, 30.0, 4.0], 3.0),
            [w, [Side::Wall, Side::Open], w],
        ));
        // Odd sizes, an open low x side, scattered solid and empty cells.
        let n = [19, 13, 11];
        let kind = (0..n[0] * n[1] * n[2])
            .map(|i| match (i * 2_654_435_761) % 97 {
                0..=8 => CellKind::Solid,
                9..=12 => CellKind::Empty,
                _ => CellKind::Fluid,
            })
            .collect();
        out.push(GridPoisson::with_sides(
            n,
            0.1,
            kind,
            [[Side::Open, Side::Wall], w, [Side::Wall, Side::Open]],
        ));
        out.into_iter()
            .map(|g| g.expect("a valid problem"))
            .collect()
    }

    /// Values in [-1, 1) from a hash of the index, zero off the cells `keep`.
    fn field(len: usize, seed: usize, keep: impl Fn(usize) -> bool) -> Vec<f64> {
        (0..len)
            .map(|i| {
                if keep(i) {
                    (((i + seed).wrapping_mul(2_654_435_761) >> 5) % 1000) as f64 / 500.0 - 1.0
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// The row-by-row prolongation is the boundary rule (`weights`) applied cell by
    /// cell, and the restriction is its transpose over the children per coarse cell,
    /// on every level of every problem: so the V-cycle is symmetric.
    #[test]
    fn the_transfers_are_the_boundary_rule_and_its_transpose() {
        let (mut transfers, mut edge, mut interior) = (0, 0, 0);
        for (pi, g) in problems().iter().enumerate() {
            let levels = &g.levels;
            let mut work: Vec<Work<f64>> = Work::for_levels(levels);
            for l in 0..levels.len() - 1 {
                let (f, c) = (&levels[l], &levels[l + 1]);
                transfers += 1;
                edge += f.edge_cells.len();
                interior += c.interior.iter().filter(|&&i| i).count();
                let xc = field(c.kind.len(), 7, |i| c.code[i] > 0);
                // P xc, row by row and cell by cell.
                work[l + 1].x.copy_from_slice(&xc);
                work[l].x.fill(0.0);
                prolong(levels, &mut work, l);
                let px = work[l].x.clone();
                let (nx, ny) = (f.n[0], f.n[1]);
                for (i, &v) in px.iter().enumerate() {
                    let want = if f.code[i] > 0 {
                        let c3 = [i % nx, (i / nx) % ny, i / (nx * ny)];
                        let (cells, w) = weights(c3, f.n, c.n, &f.sides, &c.kind);
                        cells.iter().zip(w).map(|(&q, w)| w * xc[q]).sum()
                    } else {
                        0.0
                    };
                    assert!(
                        (v - want).abs() <= 1e-12,
                        "problem {pi}, level {l}, cell {i}: prolonged {v}, the rule gives {want}"
                    );
                }
                // R r . xc = (P xc . r) / children.
                let r = field(f.kind.len(), 3, |i| f.code[i] > 0);
                work[l].r.copy_from_slice(&r);
                restrict(levels, &mut work, l);
                let children = (1usize << f.n.iter().filter(|&&v| v > 1).count()) as f64;
                let lhs: f64 = work[l + 1].b.iter().zip(&xc).map(|(a, b)| a * b).sum();
                let rhs: f64 = px.iter().zip(&r).map(|(a, b)| a * b).sum::<f64>() / children;
                assert!(
                    (lhs - rhs).abs() <= 1e-12 * rhs.abs().max(1.0),
                    "problem {pi}, level {l}: R r . x = {lhs}, P x . r / {children} = {rhs}"
                );
            }
        }
        // Both paths ran: rows through interior parents, cells through the rule.
        assert!(
            transfers >= 10 && edge > 0 && interior > 0,
            "{transfers} transfers, {edge} boundary-rule cells, {interior} interior parents"
        );
    }
}
