//! Spring elements: Hooke force with damping along the spring, and their Jacobians.
//!
//! Course notes, section 4: for a spring from B to A, `L = A - B`, rest length `R`,
//! the force on A is
//!
//! ```text
//! F_A = -k (|L| - R) L/|L|  -  kd ((v_A - v_B) . L/|L|) L/|L|,      F_B = -F_A.
//! ```
//!
//! Jacobians (l = L/|L|): the elastic part gives
//! `dF_A/dx_A = -k [ l l^T + (1 - R/|L|)(I - l l^T) ]` (symmetric), and the damping part
//! `dF_A/dv_A = -kd l l^T`. Element matrices are `[[J, -J], [-J, J]]` for both.
//!
//! Two choices, both stated in the docs:
//! - The damping force also depends on positions; that derivative is not symmetric and is
//!   left out, as Baraff and Witkin do (1998, section 5.2). So `dF/dx` is the elastic
//!   Jacobian (exact), `dF/dv` the damping Jacobian (exact).
//! - Under compression (`|L| < R`) the term `(1 - R/|L|)(I - l l^T)` is negative-definite
//!   in the wrong sense and can make `M - h^2 dF/dx` indefinite. With
//!   [`SpringParams::definiteness_fix`] that term is clamped to zero when negative
//!   (Choi and Ko 2002, "Stable but responsive cloth"); the Jacobian is then exact only for
//!   stretched springs.
//!
//! Coincident endpoints (`|L| = 0`) have no direction: the element gives zero force and
//! zero Jacobians there. Units: positions m, velocities m/s, k N/m, kd N s/m, force N.

use crate::get3;
use rayon::prelude::*;

/// Options of the spring element.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SpringParams {
    /// Clamp the compression term of the elastic Jacobian so it stays negative
    /// semi-definite (see the module docs).
    pub definiteness_fix: bool,
}

/// Unit direction `L/|L|` and length `|L|` of `L = A - B`, or `None` for coincident
/// endpoints (no direction).
#[inline]
fn axis(xa: [f64; 3], xb: [f64; 3]) -> Option<([f64; 3], f64)> {
    let l = [xa[0] - xb[0], xa[1] - xb[1], xa[2] - xb[2]];
    let len = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
    (len > 0.0).then(|| ([l[0] / len, l[1] / len, l[2] / len], len))
}

/// Rate of extension `(v_A - v_B) . d` along the unit direction d.
#[inline]
fn extension_rate(d: [f64; 3], va: [f64; 3], vb: [f64; 3]) -> f64 {
    (va[0] - vb[0]) * d[0] + (va[1] - vb[1]) * d[1] + (va[2] - vb[2]) * d[2]
}

/// Force on endpoint A along the unit direction d of a spring of length `len`.
#[inline]
#[allow(clippy::too_many_arguments)]
fn force_along(
    d: [f64; 3],
    len: f64,
    va: [f64; 3],
    vb: [f64; 3],
    k: f64,
    kd: f64,
    rest: f64,
) -> [f64; 3] {
    let s = -k * (len - rest) - kd * extension_rate(d, va, vb);
    [s * d[0], s * d[1], s * d[2]]
}

/// One spring: force on endpoint A (N) from endpoint positions and velocities.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn spring_force(
    xa: [f64; 3],
    xb: [f64; 3],
    va: [f64; 3],
    vb: [f64; 3],
    k: f64,
    kd: f64,
    rest: f64,
) -> [f64; 3] {
    axis(xa, xb).map_or([0.0; 3], |(d, len)| {
        force_along(d, len, va, vb, k, kd, rest)
    })
}

/// One spring: force on endpoint A, and the 3x3 blocks `dF_A/dx_A` and `dF_A/dv_A`
/// (row-major), computed from endpoint positions and velocities.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn spring_element(
    xa: [f64; 3],
    xb: [f64; 3],
    va: [f64; 3],
    vb: [f64; 3],
    k: f64,
    kd: f64,
    rest: f64,
    p: SpringParams,
) -> ([f64; 3], [f64; 9], [f64; 9]) {
    let Some((d, len)) = axis(xa, xb) else {
        return ([0.0; 3], [0.0; 9], [0.0; 9]);
    };
    let f = force_along(d, len, va, vb, k, kd, rest);
    let mut t = 1.0 - rest / len;
    if p.definiteness_fix && t < 0.0 {
        t = 0.0;
    }
    let mut kx = [0.0; 9];
    let mut kv = [0.0; 9];
    for r in 0..3 {
        for c in 0..3 {
            let dd = d[r] * d[c];
            let id = if r == c { 1.0 } else { 0.0 };
            kx[3 * r + c] = -k * (dd + t * (id - dd));
            kv[3 * r + c] = -kd * dd;
        }
    }
    (f, kx, kv)
}

/// Elastic energy `k/2 (|L| - R)^2` of one spring (J).
#[inline]
pub fn spring_energy(xa: [f64; 3], xb: [f64; 3], k: f64, rest: f64) -> f64 {
    let len = axis(xa, xb).map_or(0.0, |(_, len)| len);
    0.5 * k * (len - rest) * (len - rest)
}

/// Rayleigh dissipation `kd/2 ((v_A - v_B) . L/|L|)^2` of one spring's damping (W): the
/// damping force on A is minus its derivative in v_A.
#[inline]
pub fn spring_dissipation(xa: [f64; 3], xb: [f64; 3], va: [f64; 3], vb: [f64; 3], kd: f64) -> f64 {
    axis(xa, xb).map_or(0.0, |(d, _)| {
        let rate = extension_rate(d, va, vb);
        0.5 * kd * rate * rate
    })
}

/// Borrowed spring set: endpoints and per-spring constants (SoA).
#[derive(Clone, Copy, Debug)]
pub struct Springs<'a> {
    /// Endpoint vertex indices (A, B) of each spring.
    pub ends: &'a [[u32; 2]],
    /// Stiffness k per spring (N/m), >= 0.
    pub k: &'a [f64],
    /// Damping kd per spring (N s/m), >= 0.
    pub kd: &'a [f64],
    /// Rest length R per spring (m), >= 0.
    pub rest: &'a [f64],
}

impl Springs<'_> {
    /// Number of springs.
    pub fn len(&self) -> usize {
        self.ends.len()
    }
    /// Whether there are no springs.
    pub fn is_empty(&self) -> bool {
        self.ends.is_empty()
    }
    fn check(&self) {
        let m = self.ends.len();
        assert!(self.k.len() == m && self.kd.len() == m && self.rest.len() == m);
    }
    /// Endpoint positions and velocities of spring e: `[xa, xb, va, vb]`. Always inlined:
    /// as a call it returns 96 bytes through the stack, which doubled the cost of the
    /// force kernel (measured on a 2000-spring chain).
    #[inline(always)]
    fn ends_of(&self, e: usize, x: &[f64], v: &[f64], n: usize) -> [[f64; 3]; 4] {
        let [a, b] = self.ends[e];
        let (a, b) = (a as usize, b as usize);
        [get3(x, n, a), get3(x, n, b), get3(v, n, a), get3(v, n, b)]
    }
}

/// Springs per parallel task: fixed, so the output does not depend on the thread count.
const SPRING_CHUNK: usize = 4096;

/// Force on endpoint A of every spring, `fa[3e..3e+3]` (element-major; the force on B is
/// the negative). `x`, `v` are component-major Vec3s data of the n vertices.
///
/// SIMD over springs (`f64x4`, four springs per step: their endpoints are gathered into
/// lanes, the arithmetic runs in lanes, the forces are scattered back), in parallel over
/// fixed chunks of springs. Each spring's force depends on that spring only and the lanes
/// do the scalar twin's operations in the same order, so the result is bitwise that of
/// [`spring_forces_scalar`] whatever the thread count.
pub fn spring_forces(fa: &mut [f64], x: &[f64], v: &[f64], s: Springs<'_>) {
    s.check();
    let n = x.len() / 3;
    assert!(x.len() == 3 * n && v.len() == 3 * n && fa.len() == 3 * s.len());
    fa.par_chunks_mut(3 * SPRING_CHUNK)
        .enumerate()
        .for_each(|(c, out)| spring_forces_simd_range(out, c * SPRING_CHUNK, x, v, n, &s));
}

/// Scalar twin of [`spring_forces`] (same layout, same result, one thread).
pub fn spring_forces_scalar(fa: &mut [f64], x: &[f64], v: &[f64], s: Springs<'_>) {
    s.check();
    let n = x.len() / 3;
    assert!(x.len() == 3 * n && v.len() == 3 * n && fa.len() == 3 * s.len());
    spring_forces_scalar_range(fa, 0, x, v, n, &s);
}

fn spring_forces_scalar_range(
    out: &mut [f64],
    e0: usize,
    x: &[f64],
    v: &[f64],
    n: usize,
    s: &Springs<'_>,
) {
    for (le, f) in out.chunks_exact_mut(3).enumerate() {
        let e = e0 + le;
        let [xa, xb, va, vb] = s.ends_of(e, x, v, n);
        f.copy_from_slice(&spring_force(xa, xb, va, vb, s.k[e], s.kd[e], s.rest[e]));
    }
}

fn spring_forces_simd_range(
    out: &mut [f64],
    e0: usize,
    x: &[f64],
    v: &[f64],
    n: usize,
    s: &Springs<'_>,
) {
    use wide::f64x4;
    let m = out.len() / 3;
    let full = m / 4 * 4;
    for g in (0..full).step_by(4) {
        // Gather: lane l holds spring e0 + g + l.
        let mut p = [[[0.0f64; 4]; 3]; 4]; // [xa, xb, va, vb][component][lane]
        let (mut k, mut kd, mut rest) = ([0.0f64; 4], [0.0f64; 4], [0.0f64; 4]);
        for l in 0..4 {
            let e = e0 + g + l;
            let ends = s.ends_of(e, x, v, n);
            for (q, end) in ends.iter().enumerate() {
                for c in 0..3 {
                    p[q][c][l] = end[c];
                }
            }
            k[l] = s.k[e];
            kd[l] = s.kd[e];
            rest[l] = s.rest[e];
        }
        let lane = |q: usize, c: usize| f64x4::from(p[q][c]);
        let l = [0, 1, 2].map(|c| lane(0, c) - lane(1, c));
        let len = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        let d = l.map(|c| c / len);
        let rate = (lane(2, 0) - lane(3, 0)) * d[0]
            + (lane(2, 1) - lane(3, 1)) * d[1]
            + (lane(2, 2) - lane(3, 2)) * d[2];
        let sc = -f64x4::from(k) * (len - f64x4::from(rest)) - f64x4::from(kd) * rate;
        // Coincident endpoints (len = 0) have no direction: zero force, as the scalar twin.
        let live = len.simd_gt(f64x4::ZERO);
        let f = d.map(|dc| live.bitselect(sc * dc, f64x4::ZERO).to_array());
        for (l, o) in out[3 * g..3 * g + 12].chunks_exact_mut(3).enumerate() {
            o.copy_from_slice(&[f[0][l], f[1][l], f[2][l]]);
        }
    }
    spring_forces_scalar_range(&mut out[3 * full..], e0 + full, x, v, n, s);
}

/// Forces on endpoint A (`fa[3e..]`) and the blocks `dF_A/dx_A` (`kx[9e..]`) and, when
/// `kv` is given, `dF_A/dv_A` (`kv[9e..]`) of every spring; see [`spring_forces`] for the
/// layout.
pub fn spring_forces_jacobians(
    fa: &mut [f64],
    kx: &mut [f64],
    kv: Option<&mut [f64]>,
    x: &[f64],
    v: &[f64],
    s: Springs<'_>,
    p: SpringParams,
) {
    s.check();
    let n = x.len() / 3;
    let m = s.len();
    assert!(x.len() == 3 * n && v.len() == 3 * n);
    assert!(fa.len() == 3 * m && kx.len() == 9 * m);
    let run = |c: usize, fo: &mut [f64], kxo: &mut [f64], mut kvo: Option<&mut [f64]>| {
        let e0 = c * SPRING_CHUNK;
        for le in 0..fo.len() / 3 {
            let e = e0 + le;
            let [xa, xb, va, vb] = s.ends_of(e, x, v, n);
            let (fe, kxe, kve) = spring_element(xa, xb, va, vb, s.k[e], s.kd[e], s.rest[e], p);
            fo[3 * le..3 * le + 3].copy_from_slice(&fe);
            kxo[9 * le..9 * le + 9].copy_from_slice(&kxe);
            if let Some(kvo) = kvo.as_deref_mut() {
                kvo[9 * le..9 * le + 9].copy_from_slice(&kve);
            }
        }
    };
    let fk = fa
        .par_chunks_mut(3 * SPRING_CHUNK)
        .zip(kx.par_chunks_mut(9 * SPRING_CHUNK))
        .enumerate();
    match kv {
        Some(kv) => {
            assert_eq!(kv.len(), 9 * m);
            fk.zip(kv.par_chunks_mut(9 * SPRING_CHUNK))
                .for_each(|((c, (fo, kxo)), kvo)| run(c, fo, kxo, Some(kvo)));
        }
        None => fk.for_each(|(c, (fo, kxo))| run(c, fo, kxo, None)),
    }
}

/// Sum of `term(spring, A, B)` over the springs; deterministic parallel sum.
fn sum_over_springs(s: &Springs<'_>, term: &(dyn Fn(usize, usize, usize) -> f64 + Sync)) -> f64 {
    let m = s.len();
    let [e] = crate::par::par_reduce(crate::par::chunk_count(m, SPRING_CHUNK), &|c| {
        let mut sum = 0.0;
        for e in crate::par::chunk_range(c, m, SPRING_CHUNK) {
            let [a, b] = s.ends[e];
            sum += term(e, a as usize, b as usize);
        }
        [sum]
    });
    e
}

/// Total elastic energy of the springs (J); deterministic parallel sum.
pub fn springs_energy(x: &[f64], s: Springs<'_>) -> f64 {
    s.check();
    let n = x.len() / 3;
    assert_eq!(x.len(), 3 * n);
    sum_over_springs(&s, &|e, a, b| {
        spring_energy(get3(x, n, a), get3(x, n, b), s.k[e], s.rest[e])
    })
}

/// Total Rayleigh dissipation of the spring damping (W); deterministic parallel sum.
pub fn springs_dissipation(x: &[f64], v: &[f64], s: Springs<'_>) -> f64 {
    s.check();
    let n = x.len() / 3;
    assert!(x.len() == 3 * n && v.len() == 3 * n);
    sum_over_springs(&s, &|e, _, _| {
        let [xa, xb, va, vb] = s.ends_of(e, x, v, n);
        spring_dissipation(xa, xb, va, vb, s.kd[e])
    })
}
