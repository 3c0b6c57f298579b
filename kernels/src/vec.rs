//! Vector operations over flat `f64` slices (any layout: they act element by element),
//! each with an `f64x4` body and a scalar twin, plus parallel drivers for long vectors.
//!
//! The SIMD bodies keep two accumulators in reductions so the FMA latency is hidden;
//! their sums therefore differ from the scalar twins' in rounding only (see the tests
//! for the bound used: relative to the sum of absolute terms, a few ULP times the length).

use crate::par::{chunk_count, chunk_range, par_reduce, Disjoint};
use crate::PAR_CHUNK;
use wide::f64x4;

#[inline(always)]
pub(crate) fn ld(s: &[f64]) -> f64x4 {
    f64x4::new([s[0], s[1], s[2], s[3]])
}

#[inline(always)]
pub(crate) fn st(s: &mut [f64], v: f64x4) {
    s[..4].copy_from_slice(&v.to_array());
}

/// `y += a x`.
pub fn axpy(y: &mut [f64], a: f64, x: &[f64]) {
    assert_eq!(y.len(), x.len());
    let av = f64x4::splat(a);
    let mut yc = y.chunks_exact_mut(4);
    let mut xc = x.chunks_exact(4);
    for (yy, xx) in (&mut yc).zip(&mut xc) {
        st(yy, ld(xx).mul_add(av, ld(yy)));
    }
    axpy_scalar(yc.into_remainder(), a, xc.remainder());
}

/// Scalar twin of [`axpy`].
pub fn axpy_scalar(y: &mut [f64], a: f64, x: &[f64]) {
    assert_eq!(y.len(), x.len());
    for (yy, xx) in y.iter_mut().zip(x) {
        *yy = xx.mul_add(a, *yy);
    }
}

/// `y = x + b y` (the conjugate-gradient direction update).
pub fn xpay(y: &mut [f64], x: &[f64], b: f64) {
    assert_eq!(y.len(), x.len());
    let bv = f64x4::splat(b);
    let mut yc = y.chunks_exact_mut(4);
    let mut xc = x.chunks_exact(4);
    for (yy, xx) in (&mut yc).zip(&mut xc) {
        st(yy, ld(yy).mul_add(bv, ld(xx)));
    }
    xpay_scalar(yc.into_remainder(), xc.remainder(), b);
}

/// Scalar twin of [`xpay`].
pub fn xpay_scalar(y: &mut [f64], x: &[f64], b: f64) {
    assert_eq!(y.len(), x.len());
    for (yy, xx) in y.iter_mut().zip(x) {
        *yy = yy.mul_add(b, *xx);
    }
}

/// `w = x + a y` (a scaled copy plus a vector: Runge-Kutta stages, trial states).
pub fn waxpy(w: &mut [f64], x: &[f64], a: f64, y: &[f64]) {
    assert!(w.len() == x.len() && x.len() == y.len());
    let av = f64x4::splat(a);
    let mut wc = w.chunks_exact_mut(4);
    let mut xc = x.chunks_exact(4);
    let mut yc = y.chunks_exact(4);
    for ((ww, xx), yy) in (&mut wc).zip(&mut xc).zip(&mut yc) {
        st(ww, ld(yy).mul_add(av, ld(xx)));
    }
    waxpy_scalar(wc.into_remainder(), xc.remainder(), a, yc.remainder());
}

/// Scalar twin of [`waxpy`].
pub fn waxpy_scalar(w: &mut [f64], x: &[f64], a: f64, y: &[f64]) {
    assert!(w.len() == x.len() && x.len() == y.len());
    for ((ww, xx), yy) in w.iter_mut().zip(x).zip(y) {
        *ww = yy.mul_add(a, *xx);
    }
}

/// `y = a x` (scaled copy).
pub fn scale_copy(y: &mut [f64], a: f64, x: &[f64]) {
    assert_eq!(y.len(), x.len());
    let av = f64x4::splat(a);
    let mut yc = y.chunks_exact_mut(4);
    let mut xc = x.chunks_exact(4);
    for (yy, xx) in (&mut yc).zip(&mut xc) {
        st(yy, ld(xx) * av);
    }
    scale_copy_scalar(yc.into_remainder(), a, xc.remainder());
}

/// Scalar twin of [`scale_copy`].
pub fn scale_copy_scalar(y: &mut [f64], a: f64, x: &[f64]) {
    assert_eq!(y.len(), x.len());
    for (yy, xx) in y.iter_mut().zip(x) {
        *yy = a * xx;
    }
}

/// `x . y`.
pub fn dot(x: &[f64], y: &[f64]) -> f64 {
    assert_eq!(x.len(), y.len());
    let mut a0 = f64x4::ZERO;
    let mut a1 = f64x4::ZERO;
    let mut xc = x.chunks_exact(8);
    let mut yc = y.chunks_exact(8);
    for (xx, yy) in (&mut xc).zip(&mut yc) {
        a0 = ld(xx).mul_add(ld(yy), a0);
        a1 = ld(&xx[4..]).mul_add(ld(&yy[4..]), a1);
    }
    (a0 + a1).reduce_add() + dot_scalar(xc.remainder(), yc.remainder())
}

/// Scalar twin of [`dot`].
pub fn dot_scalar(x: &[f64], y: &[f64]) -> f64 {
    assert_eq!(x.len(), y.len());
    x.iter().zip(y).fold(0.0, |s, (a, b)| a.mul_add(*b, s))
}

/// Euclidean norm `|x|`.
pub fn norm2(x: &[f64]) -> f64 {
    dot(x, x).sqrt()
}

/// Scalar twin of [`norm2`].
pub fn norm2_scalar(x: &[f64]) -> f64 {
    dot_scalar(x, x).sqrt()
}

/// Whether every entry is finite.
pub fn all_finite(x: &[f64]) -> bool {
    x.iter().all(|v| v.is_finite())
}

/// Parallel [`dot`] (deterministic: fixed chunks, fixed reduction tree).
pub fn dot_par(x: &[f64], y: &[f64]) -> f64 {
    assert_eq!(x.len(), y.len());
    let len = x.len();
    let [s] = par_reduce(chunk_count(len, PAR_CHUNK * 4), &|c| {
        let r = chunk_range(c, len, PAR_CHUNK * 4);
        [dot(&x[r.clone()], &y[r])]
    });
    s
}

/// One fused pass of preconditioned CG with a diagonal (Jacobi) preconditioner:
/// `x += alpha p`, `r -= alpha q`, and returns `[r . z, r . r]` for `z = dinv * r`
/// (elementwise), without storing `z`. With `dinv = None` the preconditioner is the
/// identity (`z = r`).
pub fn pcg_update_jacobi(
    x: &mut [f64],
    r: &mut [f64],
    p: &[f64],
    q: &[f64],
    dinv: Option<&[f64]>,
    alpha: f64,
) -> [f64; 2] {
    let len = x.len();
    assert!(r.len() == len && p.len() == len && q.len() == len);
    if let Some(d) = dinv {
        assert_eq!(d.len(), len);
    }
    let av = f64x4::splat(alpha);
    let (mut rz, mut rr) = (f64x4::ZERO, f64x4::ZERO);
    let body = len / 4 * 4;
    for i in (0..body).step_by(4) {
        let xi = ld(&p[i..]).mul_add(av, ld(&x[i..]));
        st(&mut x[i..], xi);
        let ri = ld(&q[i..]).mul_neg_add(av, ld(&r[i..]));
        st(&mut r[i..], ri);
        let zi = match dinv {
            Some(d) => ld(&d[i..]) * ri,
            None => ri,
        };
        rz = ri.mul_add(zi, rz);
        rr = ri.mul_add(ri, rr);
    }
    let [trz, trr] = pcg_update_jacobi_scalar(
        &mut x[body..],
        &mut r[body..],
        &p[body..],
        &q[body..],
        dinv.map(|d| &d[body..]),
        alpha,
    );
    [rz.reduce_add() + trz, rr.reduce_add() + trr]
}

/// Scalar twin of [`pcg_update_jacobi`].
pub fn pcg_update_jacobi_scalar(
    x: &mut [f64],
    r: &mut [f64],
    p: &[f64],
    q: &[f64],
    dinv: Option<&[f64]>,
    alpha: f64,
) -> [f64; 2] {
    let len = x.len();
    assert!(r.len() == len && p.len() == len && q.len() == len);
    let (mut rz, mut rr) = (0.0, 0.0);
    for i in 0..len {
        x[i] = p[i].mul_add(alpha, x[i]);
        r[i] = q[i].mul_add(-alpha, r[i]);
        let zi = dinv.map_or(r[i], |d| d[i] * r[i]);
        rz = r[i].mul_add(zi, rz);
        rr = r[i].mul_add(r[i], rr);
    }
    [rz, rr]
}

/// The CG direction update with a diagonal preconditioner: `p = dinv * r + beta p`
/// (`dinv = None`: `p = r + beta p`).
pub fn pcg_direction_jacobi(p: &mut [f64], r: &[f64], dinv: Option<&[f64]>, beta: f64) {
    let Some(d) = dinv else {
        return xpay(p, r, beta);
    };
    assert!(r.len() == p.len() && d.len() == p.len());
    let bv = f64x4::splat(beta);
    let mut pc = p.chunks_exact_mut(4);
    let mut rc = r.chunks_exact(4);
    let mut dc = d.chunks_exact(4);
    for ((pp, rr), dd) in (&mut pc).zip(&mut rc).zip(&mut dc) {
        st(pp, ld(pp).mul_add(bv, ld(dd) * ld(rr)));
    }
    pcg_direction_jacobi_scalar(
        pc.into_remainder(),
        rc.remainder(),
        Some(dc.remainder()),
        beta,
    );
}

/// Scalar twin of [`pcg_direction_jacobi`].
pub fn pcg_direction_jacobi_scalar(p: &mut [f64], r: &[f64], dinv: Option<&[f64]>, beta: f64) {
    assert_eq!(r.len(), p.len());
    for i in 0..p.len() {
        let z = dinv.map_or(r[i], |d| d[i] * r[i]);
        p[i] = p[i].mul_add(beta, z);
    }
}

/// Applies symmetric 3x3 blocks stored as six component-major arrays
/// `b = [b00 | b01 | b02 | b11 | b12 | b22]` (each of length m) to the 3-vectors of `r`
/// (vertex range given by the slices): `z_i = B_i r_i`, written into `z`.
/// Returns `[r . z, r . r]` over the range.
#[inline]
fn block_apply_dot(z: [&mut [f64]; 3], r: [&[f64]; 3], b: [&[f64]; 6]) -> [f64; 2] {
    let m = r[0].len();
    let mut acc = f64x4::ZERO;
    let mut acc_rr = f64x4::ZERO;
    let body = m / 4 * 4;
    let [zx, zy, zz] = z;
    for i in (0..body).step_by(4) {
        let (r0, r1, r2) = (ld(&r[0][i..]), ld(&r[1][i..]), ld(&r[2][i..]));
        let (b00, b01, b02) = (ld(&b[0][i..]), ld(&b[1][i..]), ld(&b[2][i..]));
        let (b11, b12, b22) = (ld(&b[3][i..]), ld(&b[4][i..]), ld(&b[5][i..]));
        let z0 = b02.mul_add(r2, b01.mul_add(r1, b00 * r0));
        let z1 = b12.mul_add(r2, b11.mul_add(r1, b01 * r0));
        let z2 = b22.mul_add(r2, b12.mul_add(r1, b02 * r0));
        st(&mut zx[i..], z0);
        st(&mut zy[i..], z1);
        st(&mut zz[i..], z2);
        acc = r2.mul_add(z2, r1.mul_add(z1, r0.mul_add(z0, acc)));
        acc_rr = r2.mul_add(r2, r1.mul_add(r1, r0.mul_add(r0, acc_rr)));
    }
    let [trz, trr] = block_apply_dot_scalar(
        [&mut zx[body..], &mut zy[body..], &mut zz[body..]],
        r.map(|c| &c[body..]),
        b.map(|c| &c[body..]),
    );
    [acc.reduce_add() + trz, acc_rr.reduce_add() + trr]
}

/// Scalar twin of [`block_apply_dot`].
fn block_apply_dot_scalar(z: [&mut [f64]; 3], r: [&[f64]; 3], b: [&[f64]; 6]) -> [f64; 2] {
    let [zx, zy, zz] = z;
    let (mut s, mut s_rr) = (0.0, 0.0);
    for i in 0..r[0].len() {
        let (r0, r1, r2) = (r[0][i], r[1][i], r[2][i]);
        let z0 = b[2][i].mul_add(r2, b[1][i].mul_add(r1, b[0][i] * r0));
        let z1 = b[4][i].mul_add(r2, b[3][i].mul_add(r1, b[1][i] * r0));
        let z2 = b[5][i].mul_add(r2, b[4][i].mul_add(r1, b[2][i] * r0));
        zx[i] = z0;
        zy[i] = z1;
        zz[i] = z2;
        s = r2.mul_add(z2, r1.mul_add(z1, r0.mul_add(z0, s)));
        s_rr = r2.mul_add(r2, r1.mul_add(r1, r0.mul_add(r0, s_rr)));
    }
    [s, s_rr]
}

/// Per-component slices of the arguments of a block apply: z, r and the six block arrays.
type BlockArgs<'a> = ([&'a mut [f64]; 3], [&'a [f64]; 3], [&'a [f64]; 6]);

/// Splits component-major `z`, `r` (3n) and `binv` (6n) into per-component slices.
fn block_args<'a>(z: &'a mut [f64], r: &'a [f64], binv: &'a [f64]) -> BlockArgs<'a> {
    let n = r.len() / 3;
    assert!(r.len() == 3 * n && z.len() == 3 * n && binv.len() == 6 * n);
    (
        crate::split3_mut(z),
        [&r[..n], &r[n..2 * n], &r[2 * n..]],
        core::array::from_fn(|k| &binv[k * n..(k + 1) * n]),
    )
}

/// Block-Jacobi preconditioner apply: `z_i = B_i r_i` for every vertex, returning
/// `[r . z, r . r]`.
/// `binv` holds the symmetric inverse blocks as six component-major arrays
/// (`[b00 | b01 | b02 | b11 | b12 | b22]`, length 6n); `r`, `z` are component-major (3n).
pub fn block_jacobi_apply(z: &mut [f64], r: &[f64], binv: &[f64]) -> [f64; 2] {
    let (z, r, b) = block_args(z, r, binv);
    block_apply_dot(z, r, b)
}

/// Scalar twin of [`block_jacobi_apply`].
pub fn block_jacobi_apply_scalar(z: &mut [f64], r: &[f64], binv: &[f64]) -> [f64; 2] {
    let (z, r, b) = block_args(z, r, binv);
    block_apply_dot_scalar(z, r, b)
}

/// Parallel [`pcg_update_jacobi`] (deterministic).
pub fn pcg_update_jacobi_par(
    x: &mut [f64],
    r: &mut [f64],
    p: &[f64],
    q: &[f64],
    dinv: Option<&[f64]>,
    alpha: f64,
) -> [f64; 2] {
    let len = x.len();
    assert!(r.len() == len && p.len() == len && q.len() == len);
    let (xd, rd) = (Disjoint::new(x), Disjoint::new(r));
    let chunk = PAR_CHUNK * 4;
    par_reduce(chunk_count(len, chunk), &|c| {
        let rg = chunk_range(c, len, chunk);
        // SAFETY: chunk ranges are disjoint.
        let (xs, rs) = unsafe { (xd.slice(rg.clone()), rd.slice(rg.clone())) };
        pcg_update_jacobi(
            xs,
            rs,
            &p[rg.clone()],
            &q[rg.clone()],
            dinv.map(|d| &d[rg.clone()]),
            alpha,
        )
    })
}

/// Parallel [`pcg_direction_jacobi`] (deterministic).
pub fn pcg_direction_jacobi_par(p: &mut [f64], r: &[f64], dinv: Option<&[f64]>, beta: f64) {
    let len = p.len();
    assert_eq!(r.len(), len);
    let pd = Disjoint::new(p);
    let chunk = PAR_CHUNK * 4;
    par_reduce::<0, _>(chunk_count(len, chunk), &|c| {
        let rg = chunk_range(c, len, chunk);
        // SAFETY: chunk ranges are disjoint.
        let ps = unsafe { pd.slice(rg.clone()) };
        pcg_direction_jacobi(ps, &r[rg.clone()], dinv.map(|d| &d[rg.clone()]), beta);
        []
    });
}

/// One fused pass of preconditioned CG with a block-Jacobi preconditioner, parallel and
/// deterministic: `x += alpha p`, `r -= alpha q`, `z = B r` blockwise (see
/// [`block_jacobi_apply`] for the layout of `binv`); returns `[r . z, r . r]`.
/// All vectors are component-major Vec3s data of the same length 3n.
pub fn pcg_update_block_jacobi_par(
    x: &mut [f64],
    r: &mut [f64],
    z: &mut [f64],
    p: &[f64],
    q: &[f64],
    binv: &[f64],
    alpha: f64,
) -> [f64; 2] {
    let n = x.len() / 3;
    assert!(x.len() == 3 * n && r.len() == 3 * n && z.len() == 3 * n);
    assert!(p.len() == 3 * n && q.len() == 3 * n && binv.len() == 6 * n);
    let (xd, rd, zd) = (Disjoint::new(x), Disjoint::new(r), Disjoint::new(z));
    par_reduce(chunk_count(n, PAR_CHUNK), &|c| {
        let vr = chunk_range(c, n, PAR_CHUNK);
        // SAFETY: vertex ranges of distinct chunks are disjoint.
        let (xc, rc, zc) = unsafe {
            (
                xd.components(n, vr.clone()),
                rd.components(n, vr.clone()),
                zd.components(n, vr.clone()),
            )
        };
        let pc = crate::par::components(p, n, vr.clone());
        let qc = crate::par::components(q, n, vr.clone());
        let [rx, ry, rz] = rc;
        for (k, xk) in xc.into_iter().enumerate() {
            axpy(xk, alpha, pc[k]);
        }
        axpy(rx, -alpha, qc[0]);
        axpy(ry, -alpha, qc[1]);
        axpy(rz, -alpha, qc[2]);
        let b: [&[f64]; 6] = core::array::from_fn(|k| &binv[k * n + vr.start..k * n + vr.end]);
        block_apply_dot(zc, [&*rx, &*ry, &*rz], b)
    })
}

/// Parallel [`xpay`] (deterministic; no reduction).
pub fn xpay_par(y: &mut [f64], x: &[f64], b: f64) {
    pcg_direction_jacobi_par(y, x, None, b);
}
