//! Block-sparse (3x3 blocks, CSR of blocks) matrix-vector products.
//!
//! Layout: block row `i` holds the blocks `row_ptr[i]..row_ptr[i+1]`; block `k` sits in
//! block column `col[k]` and its nine values `val[9k..9k+9]` are row-major. The vectors are
//! component-major Vec3s data: block (i, j) maps rows {i, n+i, 2n+i} to columns
//! {j, n+j, 2n+j}.
//!
//! Why blocks: one 32-bit column index serves nine values, so a product streams
//! 76 bytes per block (8.4 B per nonzero) against 16 B per nonzero for a scalar CSR with
//! 64-bit indices; SpMV is bound by memory bandwidth, so that ratio is the speed-up.
//!
//! SIMD body: the nine products of a block are two `f64x4` FMAs,
//! `(b00 b01 b02 b10)·(x0 x1 x2 x0)` and `(b11 b12 b20 b21)·(x1 x2 x0 x1)`, plus one
//! scalar FMA `b22·x2`, accumulated over the row and folded into three sums at its end.
//!
//! The product overwrites `y` (`y = A x`): not reading `y` saves a vector of traffic.

use crate::par::{chunk_count, chunk_range, par_reduce, Disjoint};
use crate::vec::ld;
use crate::PAR_CHUNK;
use core::ops::Range;
use wide::f64x4;

/// What a block-sparse matrix stores its values as: `f64`, or `f32` for a copy that
/// moves half the bytes (multigrid's fine-level smoothing: a V-cycle on the rounded
/// matrix is still a symmetric positive definite preconditioner). Products load the
/// values into `f64` and accumulate in `f64` either way.
pub trait BlockValue: Copy + Send + Sync + 'static {
    /// `[b[0], b[1], b[2], b[3]]` as `f64`.
    fn ld4(b: &[Self]) -> f64x4;
    /// The value as `f64`.
    fn get(self) -> f64;
}

impl BlockValue for f64 {
    #[inline(always)]
    fn ld4(b: &[f64]) -> f64x4 {
        ld(b)
    }
    #[inline(always)]
    fn get(self) -> f64 {
        self
    }
}

impl BlockValue for f32 {
    #[inline(always)]
    fn ld4(b: &[f32]) -> f64x4 {
        f64x4::new([b[0] as f64, b[1] as f64, b[2] as f64, b[3] as f64])
    }
    #[inline(always)]
    fn get(self) -> f64 {
        self as f64
    }
}

/// A borrowed block-sparse 3x3 matrix (square, `n` block rows and columns) with values
/// stored as `T`.
#[derive(Clone, Copy, Debug)]
pub struct Bsr3Ref<'a, T = f64> {
    /// Number of block rows (= block columns); the scalar size is 3n.
    pub n: usize,
    /// Block-row pointers, length n + 1, non-decreasing, `row_ptr[0] = 0`.
    pub row_ptr: &'a [u32],
    /// Block-column index of each block, each `< n`.
    pub col: &'a [u32],
    /// Nine row-major values per block.
    pub val: &'a [T],
}

impl<'a, T: BlockValue> Bsr3Ref<'a, T> {
    /// Checks the lengths and the pointer bounds (not the sortedness of columns, which the
    /// products do not need) and wraps the arrays.
    pub fn new(n: usize, row_ptr: &'a [u32], col: &'a [u32], val: &'a [T]) -> Self {
        assert_eq!(row_ptr.len(), n + 1, "row_ptr must have n + 1 entries");
        assert_eq!(row_ptr[0], 0);
        let nb = row_ptr[n] as usize;
        assert_eq!(col.len(), nb, "one column index per block");
        assert_eq!(val.len(), 9 * nb, "nine values per block");
        Self {
            n,
            row_ptr,
            col,
            val,
        }
    }

    /// Number of stored blocks.
    pub fn nnz_blocks(&self) -> usize {
        self.col.len()
    }

    /// Bytes a product moves at least: the blocks and their column indices, the row
    /// pointers, x read once and y written once.
    pub fn spmv_bytes(&self) -> usize {
        self.nnz_blocks() * (9 * core::mem::size_of::<T>() + 4)
            + (self.n + 1) * 4
            + 2 * 3 * self.n * 8
    }
}

/// y = A x over the block rows `rows`; `y` holds the three component slices of those rows.
/// Returns `sum_i x_i . y_i` over the rows (the `p . Ap` of conjugate gradients).
#[inline]
fn rows_simd<T: BlockValue>(
    y: [&mut [f64]; 3],
    a: Bsr3Ref<'_, T>,
    x: &[f64],
    rows: Range<usize>,
) -> f64 {
    let n = a.n;
    let (xs, ys, zs) = (&x[..n], &x[n..2 * n], &x[2 * n..3 * n]);
    let [y0, y1, y2] = y;
    let mut dot = 0.0;
    for (local, i) in rows.enumerate() {
        let (s, e) = (a.row_ptr[i] as usize, a.row_ptr[i + 1] as usize);
        let mut acc0 = f64x4::ZERO;
        let mut acc1 = f64x4::ZERO;
        let mut acc2 = 0.0f64;
        for k in s..e {
            let j = a.col[k] as usize;
            let (x0, x1, x2) = (xs[j], ys[j], zs[j]);
            let b = &a.val[9 * k..9 * k + 9];
            acc0 = T::ld4(b).mul_add(f64x4::new([x0, x1, x2, x0]), acc0);
            acc1 = T::ld4(&b[4..]).mul_add(f64x4::new([x1, x2, x0, x1]), acc1);
            acc2 = b[8].get().mul_add(x2, acc2);
        }
        let a0 = acc0.to_array();
        let a1 = acc1.to_array();
        let r0 = a0[0] + a0[1] + a0[2];
        let r1 = a0[3] + a1[0] + a1[1];
        let r2 = a1[2] + a1[3] + acc2;
        y0[local] = r0;
        y1[local] = r1;
        y2[local] = r2;
        dot += xs[i] * r0 + ys[i] * r1 + zs[i] * r2;
    }
    dot
}

#[inline]
fn rows_scalar(y: [&mut [f64]; 3], a: Bsr3Ref<'_>, x: &[f64], rows: Range<usize>) -> f64 {
    let n = a.n;
    let [y0, y1, y2] = y;
    let mut dot = 0.0;
    for (local, i) in rows.enumerate() {
        let (mut r0, mut r1, mut r2) = (0.0, 0.0, 0.0);
        for k in a.row_ptr[i] as usize..a.row_ptr[i + 1] as usize {
            let j = a.col[k] as usize;
            let (x0, x1, x2) = (x[j], x[n + j], x[2 * n + j]);
            let b = &a.val[9 * k..9 * k + 9];
            r0 += b[0] * x0 + b[1] * x1 + b[2] * x2;
            r1 += b[3] * x0 + b[4] * x1 + b[5] * x2;
            r2 += b[6] * x0 + b[7] * x1 + b[8] * x2;
        }
        y0[local] = r0;
        y1[local] = r1;
        y2[local] = r2;
        dot += x[i] * r0 + x[n + i] * r1 + x[2 * n + i] * r2;
    }
    dot
}

fn check<T>(y: &[f64], a: &Bsr3Ref<'_, T>, x: &[f64]) {
    assert_eq!(x.len(), 3 * a.n, "x must hold 3n values");
    assert_eq!(y.len(), 3 * a.n, "y must hold 3n values");
}

/// `y = A x` (serial, SIMD).
pub fn bsr3_spmv(y: &mut [f64], a: Bsr3Ref<'_>, x: &[f64]) {
    check(y, &a, x);
    rows_simd(crate::split3_mut(y), a, x, 0..a.n);
}

/// Scalar twin of [`bsr3_spmv`].
pub fn bsr3_spmv_scalar(y: &mut [f64], a: Bsr3Ref<'_>, x: &[f64]) {
    check(y, &a, x);
    rows_scalar(crate::split3_mut(y), a, x, 0..a.n);
}

/// `y = A x`, returning `x . y`; parallel over fixed chunks of block rows, so the result
/// is bitwise the same for any number of threads.
pub fn bsr3_spmv_dot_par<T: BlockValue>(y: &mut [f64], a: Bsr3Ref<'_, T>, x: &[f64]) -> f64 {
    check(y, &a, x);
    let n = a.n;
    let yd = Disjoint::new(y);
    let [d] = par_reduce(chunk_count(n, PAR_CHUNK), &|c| {
        let range = chunk_range(c, n, PAR_CHUNK);
        // SAFETY: the row ranges of distinct chunks are disjoint.
        let yc = unsafe { yd.components(n, range.clone()) };
        [rows_simd(yc, a, x, range)]
    });
    d
}

/// `r = b - A x` (the residual a multigrid smoother and its restriction need), parallel
/// over the same fixed chunks as [`bsr3_spmv_dot_par`]; each chunk subtracts its rows
/// while they are still in cache, so the residual costs one product, not a product and a
/// vector pass.
pub fn bsr3_residual_par<T: BlockValue>(r: &mut [f64], a: Bsr3Ref<'_, T>, x: &[f64], b: &[f64]) {
    check(r, &a, x);
    assert_eq!(b.len(), 3 * a.n, "b must hold 3n values");
    let n = a.n;
    let rd = Disjoint::new(r);
    par_reduce::<0, _>(chunk_count(n, PAR_CHUNK), &|c| {
        let range = chunk_range(c, n, PAR_CHUNK);
        // SAFETY: the row ranges of distinct chunks are disjoint.
        let [r0, r1, r2] = unsafe { rd.components(n, range.clone()) };
        rows_simd([&mut *r0, &mut *r1, &mut *r2], a, x, range.clone());
        for (k, rk) in [r0, r1, r2].into_iter().enumerate() {
            let bk = &b[k * n + range.start..k * n + range.end];
            for (ri, bi) in rk.iter_mut().zip(bk) {
                *ri = bi - *ri;
            }
        }
        []
    });
}
