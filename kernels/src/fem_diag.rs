//! Tetrahedron kernels in the singular-value frame, for the isotropic materials, one
//! element per lane: generic over [`Lane`], so the same code runs as the scalar twin
//! (`f64`), over four elements at once (`f64x4`, [`element_x4`]), over eight with two
//! SVDs in flight ([`Groups`], [`element_x8`]) and, with AVX-512, over sixteen in two
//! `f64x8` ([`element_x16`]).
//!
//! An isotropic energy density is a symmetric function of the singular values of F:
//! `Psi(F) = Psi^(sigma)` with `F = U diag(sigma) V^T`. Following Irving, Teran and Fedkiw
//! (2004, "Invertible finite elements for robust simulation of large deformation") U and V
//! are kept rotations, so an inverted element has one negative singular value, the
//! smallest. Then (Teran, Sifakis, Irving and Fedkiw 2005, "Robust quasistatic finite
//! elements and flesh simulation", section 5):
//!
//! - `P = U diag(p) V^T`, `p = dPsi^/dsigma`;
//! - `dP = U dP^ V^T` with `dF^ = U^T dF V`, and `dP^` decouples into one 3x3 block on the
//!   diagonal entries (the Hessian `A = d2Psi^/dsigma2`) and, for each pair i < j, a 2x2
//!   block `[[a, b], [b, a]]` on `(dF^_ij, dF^_ji)`, `a = (q- + q+)/2`, `b = (q- - q+)/2`,
//!   `q- = (p_i - p_j)/(sigma_i - sigma_j)`, `q+ = (p_i + p_j)/(sigma_i + sigma_j)`
//!   (written out per material so that equal singular values divide nothing);
//! - the definiteness fix projects each block onto the semi-definite cone (eigenvalues
//!   `a + b`, `a - b` of a pair block; a 3x3 Jacobi eigensolve of A, only when some lane's
//!   A is not positive definite), which projects the whole `dP/dF`;
//! - the invertible versions evaluate the material at the singular values clamped from
//!   below at a threshold c (`sigma^ = max(sigma, c)`), so the restoring stress of a flat
//!   or inverted element stays finite and points out of inversion (Irving et al. 2004,
//!   section 5); the energy is continued past the threshold to first order,
//!   `Psi^(sigma^) + p(sigma^) . (sigma - sigma^)`, and the stress is its exact gradient
//!   (see `clamped`), so forces and energy agree for the line searches.
//!
//! With rest shape gradients `g_a` and `g^_a = V^T g_a`, an element's forces are
//! `f_a = -vol U (p o g^_a)` and its stiffness blocks `K_ab = -vol U K^_ab U^T` with
//! `K^_ab[m][m] = A_mm g^_am g^_bm + sum_{n != m} a_mn g^_an g^_bn` and `K^_ab[m][p] =
//! A_mp g^_am g^_bp + b_mp g^_ap g^_bm` (m != p): no 9x9 tangent is formed.
//!
//! The SVD is branch-free (McAdams et al. 2011, "Computing the singular value
//! decomposition of 3x3 matrices with minimal branching", in outline): a fixed number of
//! cyclic Jacobi sweeps on `F^T F` gives V, a sort orders the singular values, and Givens
//! QR of `F V` gives U (a rotation) and the signed singular values on R's diagonal.
//!
//! The corotational material's forces alone ([`corotational_forces`]) skip the SVD: R
//! from Newton's iteration for the polar decomposition ([`polar_newton`]), for elements
//! neither flat, inverted nor strained past about a factor 1.8 (the caller sends the
//! others through the SVD kernel). So does the warped tangent's kernel
//! ([`corotational_warped`], [`Iso::warped`]): with `h_a = R g_a` each stiffness block is
//! `-vol (mu (g_a . g_b) I + lambda h_a h_b^T + mu h_b h_a^T)`, the linear material's
//! turned by R (Müller and Gross 2004), which in the singular-value frame is the pair
//! blocks with `q+ = 0`.

use crate::fem::{Lame, Material, M3};
use std::ops::{Add, Div, Mul, Neg, Sub};
use wide::{f64x4, f64x8};

pub use crate::lane::Lane;

macro_rules! wide_impl {
    ($t:ident, $n:literal, $transpose:path) => {
        impl Wide for $t {
            const LANES: usize = $n;
            #[inline(always)]
            fn from_fn(f: impl FnMut(usize) -> f64) -> Self {
                $t::new(std::array::from_fn(f))
            }
            #[inline(always)]
            fn store(self, out: &mut [f64]) {
                out.copy_from_slice(&self.to_array());
            }
            #[inline(always)]
            fn transpose_store(block: &[Self], out: &mut [f64], s: usize, at: usize) {
                let t = $transpose(std::array::from_fn(|i| block[i]));
                for (l, tl) in t.iter().enumerate() {
                    out[s * l + at..s * l + at + $n].copy_from_slice(&tl.to_array());
                }
            }
        }
    };
}

/// A SIMD vector of elements, one per lane, as the wide kernels load and store them.
pub trait Wide: Lane + Default {
    /// Elements per vector.
    const LANES: usize;
    /// Lane l is `f(l)`.
    fn from_fn(f: impl FnMut(usize) -> f64) -> Self;
    /// The lanes into `out` (`LANES` long).
    fn store(self, out: &mut [f64]);
    /// `LANES` vectors, transposed: lane l of `block[i]` into `out[s l + at + i]`.
    fn transpose_store(block: &[Self], out: &mut [f64], s: usize, at: usize);
}

wide_impl!(f64x4, 4, f64x4::transpose);
// One AVX-512 register where the build has it, two `f64x4` otherwise.
#[cfg(target_feature = "avx512f")]
wide_impl!(f64x8, 8, transpose8);
#[cfg(not(target_feature = "avx512f"))]
wide_impl!(f64x8, 8, f64x8::transpose);

/// An 8x8 transpose of `f64x8` rows in three rounds of shuffles (24 instructions:
/// pairs of rows interleaved, then 128-bit and 256-bit halves exchanged). `wide`'s
/// `f64x8::transpose` builds each column lane by lane; the x16 kernels store their 102
/// outputs through it, and with it the lane transposes were a quarter of the warped
/// kernel's samples (perf, the beam's steps).
#[cfg(target_feature = "avx512f")]
#[inline(always)]
fn transpose8(rows: [f64x8; 8]) -> [f64x8; 8] {
    use std::arch::x86_64::{
        __m512d, _mm512_shuffle_f64x2, _mm512_unpackhi_pd, _mm512_unpacklo_pd,
    };
    // SAFETY: with AVX-512 `f64x8` is one `__m512d` (wide's representation), so both
    // transmutes reinterpret eight 64-byte values as they are; the intrinsics need only
    // avx512f, which this function's cfg guarantees.
    unsafe {
        let r: [__m512d; 8] = std::mem::transmute(rows);
        // t_2k = [r_2k[0] r_2k+1[0] | r_2k[2] r_2k+1[2] | ...], t_2k+1 the odd entries.
        let t: [__m512d; 8] = std::array::from_fn(|i| {
            let (a, b) = (r[i & !1], r[i | 1]);
            if i % 2 == 0 {
                _mm512_unpacklo_pd(a, b)
            } else {
                _mm512_unpackhi_pd(a, b)
            }
        });
        // Four rows' entries c and c + 4 in 128-bit lanes: 0x88 takes lanes 0 and 2 of
        // each operand, 0xDD lanes 1 and 3.
        let u = [
            _mm512_shuffle_f64x2::<0x88>(t[0], t[2]),
            _mm512_shuffle_f64x2::<0x88>(t[1], t[3]),
            _mm512_shuffle_f64x2::<0xDD>(t[0], t[2]),
            _mm512_shuffle_f64x2::<0xDD>(t[1], t[3]),
            _mm512_shuffle_f64x2::<0x88>(t[4], t[6]),
            _mm512_shuffle_f64x2::<0x88>(t[5], t[7]),
            _mm512_shuffle_f64x2::<0xDD>(t[4], t[6]),
            _mm512_shuffle_f64x2::<0xDD>(t[5], t[7]),
        ];
        // Column c (c < 4) from u_c and u_c+4's lanes 0 and 2; column c + 4 from lanes 1, 3.
        let out: [__m512d; 8] = std::array::from_fn(|c| {
            let (a, b) = (u[c % 4], u[c % 4 + 4]);
            if c < 4 {
                _mm512_shuffle_f64x2::<0x88>(a, b)
            } else {
                _mm512_shuffle_f64x2::<0xDD>(a, b)
            }
        });
        std::mem::transmute(out)
    }
}

/// N groups of elements, one vector `L` each, every operation applied to all: the 3x3
/// eigensolves are one long chain of dependent square roots and divisions, and with
/// independent chains in flight each waits less ([`element_x8`], [`element_x16`]: two
/// groups).
#[derive(Clone, Copy, Debug)]
pub struct Groups<const N: usize, L = f64x4>(pub [L; N]);

impl<const N: usize, L: Lane> Groups<N, L> {
    #[inline(always)]
    fn each(self, f: impl Fn(L) -> L) -> Self {
        Groups(std::array::from_fn(|g| f(self.0[g])))
    }
    #[inline(always)]
    fn zip(self, o: Self, f: impl Fn(L, L) -> L) -> Self {
        Groups(std::array::from_fn(|g| f(self.0[g], o.0[g])))
    }
}

macro_rules! groups_op {
    ($tr:ident, $f:ident) => {
        impl<const N: usize, L: Lane> $tr for Groups<N, L> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                self.zip(o, |a, b| a.$f(b))
            }
        }
    };
}
groups_op!(Add, add);
groups_op!(Sub, sub);
groups_op!(Mul, mul);
groups_op!(Div, div);

impl<const N: usize, L: Lane> Neg for Groups<N, L> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.each(|a| -a)
    }
}

impl<const N: usize, L: Lane> Lane for Groups<N, L> {
    #[inline(always)]
    fn splat(v: f64) -> Self {
        Groups([L::splat(v); N])
    }
    #[inline(always)]
    fn fma(self, m: Self, a: Self) -> Self {
        Groups(std::array::from_fn(|g| self.0[g].fma(m.0[g], a.0[g])))
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        self.each(L::sqrt)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        self.each(L::abs)
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        self.zip(o, L::max)
    }
    #[inline(always)]
    fn ln(self) -> Self {
        self.each(L::ln)
    }
    #[inline(always)]
    fn if_lt(a: Self, b: Self, x: Self, y: Self) -> Self {
        Groups(std::array::from_fn(|g| {
            L::if_lt(a.0[g], b.0[g], x.0[g], y.0[g])
        }))
    }
    #[inline(always)]
    fn any_not_positive(self) -> bool {
        self.0.iter().any(|a| a.any_not_positive())
    }
}

/// How an element's isotropic material is evaluated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Iso {
    /// The material; [`Material::Linear`] is not isotropic in the singular values (not
    /// rotation invariant) and has no kernel here.
    pub material: Material,
    /// The invertible version's threshold c (singular values are clamped to at least c,
    /// `0 < c < 1`), or none.
    pub clamp: Option<f64>,
    /// Project the tangent onto the semi-definite cone (the definiteness fix).
    pub project: bool,
    /// The corotational material's tangent without the rotation's derivative: Müller and
    /// Gross's stiffness warping (2004, "Interactive virtual materials"), `K = R K0 R^T`
    /// per element, in the singular-value frame the pair blocks with `q+ = 0` (see
    /// [`corotational_warped`]). Symmetric positive semi-definite for any F; the forces
    /// and energy are unchanged. Only for [`Material::Corotational`].
    pub warped: bool,
}

/// A pair block's eigenvalues `(q-, q+)` as the tangent uses them: `q+` zero for the
/// warped tangent, both clamped at zero by the definiteness fix.
#[inline(always)]
fn pair_eigenvalues<R: Lane>(iso: &Iso, qm: R, qp: R) -> (R, R) {
    let zero = R::splat(0.0);
    let qp = if iso.warped { zero } else { qp };
    if iso.project {
        (qm.max(zero), qp.max(zero))
    } else {
        (qm, qp)
    }
}

/// Cyclic Jacobi sweeps of the 3x3 eigensolves: convergence is quadratic, and four sweeps
/// reproduce the F-form materials' stresses and tangents to 1e-9 and 1e-7 relative on
/// random F, inverted and nearly singular ones included (`tests/fem.rs`). Five cost 8%
/// more kernel time (measured in `benches/fem.rs`) for nothing those tests can see.
const SWEEPS: usize = 4;

/// Eigenvalues and eigenvectors (columns of the row-major `q`) of the symmetric 3x3
/// `[s00, s01, s02, s11, s12, s22]` by `SWEEPS` cyclic Jacobi sweeps (Golub and Van Loan,
/// algorithm 8.4.3); q is a rotation.
#[inline(always)]
pub fn sym_eig3<R: Lane>(s: [R; 6]) -> ([R; 3], [R; 9]) {
    let (zero, one) = (R::splat(0.0), R::splat(1.0));
    // a[i][j] symmetric, kept as a full 3x3 for index clarity; q = I.
    let mut a = [s[0], s[1], s[2], s[1], s[3], s[4], s[2], s[4], s[5]];
    let mut q = [one, zero, zero, zero, one, zero, zero, zero, one];
    for _ in 0..SWEEPS {
        for (p, r) in [(0usize, 1usize), (0, 2), (1, 2)] {
            let o = 3 - p - r;
            let apr = a[3 * p + r];
            // Golub and Van Loan's rotation (algorithm 8.4.2), tan t = sgn(d) e / (|d| +
            // h) with d = a_rr - a_pp, e = 2 a_pr, h = sqrt(d^2 + e^2): their theta = d / e
            // multiplied through by |e|, so no test for e = 0. With 1 + t^2 = 2h / (|d| +
            // h) and w = 2h (|d| + h): cos = (|d| + h) / sqrt(w), sin = sgn(d) e /
            // sqrt(w), t = 2h sin / sqrt(w). Two square roots and one division
            // on the chain of dependent operations that bounds this loop (the SVD is
            // half the kernel's time, benches/fem.rs), where tan, then cos took two of
            // each (7% faster kernel, measured). d = e = 0 (w below 1e-300, so entries
            // below about 1e-150 count as zero) gives cos = 1, sin = 0 through `flat`:
            // where F^T F rounds to the identity every rotation is that one, so a body at
            // rest keeps singular values of exactly 1.
            let (app, arr) = (a[3 * p + p], a[3 * r + r]);
            let d = arr - app;
            let e = apr + apr;
            let sd = R::if_lt(d, zero, -one, one);
            let h = d.fma(d, e * e).sqrt();
            let big = d.abs() + h;
            let h2 = h + h;
            let w = h2 * big;
            let flat = R::if_lt(w, R::splat(1e-300), one, zero);
            let inv = one / (w.sqrt() + flat);
            let c = big.fma(inv, flat);
            let sn = sd * e * inv;
            let nsn = -sn;
            let tapr = h2 * inv * sn * apr;
            a[3 * p + p] = app - tapr;
            a[3 * r + r] = arr + tapr;
            a[3 * p + r] = zero;
            a[3 * r + p] = zero;
            let (aop, aor) = (a[3 * o + p], a[3 * o + r]);
            let nop = c.fma(aop, nsn * aor);
            let nor = sn.fma(aop, c * aor);
            a[3 * o + p] = nop;
            a[3 * p + o] = nop;
            a[3 * o + r] = nor;
            a[3 * r + o] = nor;
            for k in 0..3 {
                let (qkp, qkr) = (q[3 * k + p], q[3 * k + r]);
                q[3 * k + p] = c.fma(qkp, nsn * qkr);
                q[3 * k + r] = sn.fma(qkp, c * qkr);
            }
        }
    }
    ([a[0], a[4], a[8]], q)
}

/// Swaps eigenpairs i and j where `l[i] < l[j]`, negating one column so q stays a rotation.
#[inline(always)]
fn order_pair<R: Lane>(l: &mut [R; 3], q: &mut [R; 9], i: usize, j: usize) {
    let (li, lj) = (l[i], l[j]);
    l[i] = R::if_lt(li, lj, lj, li);
    l[j] = R::if_lt(li, lj, li, lj);
    for k in 0..3 {
        let (qi, qj) = (q[3 * k + i], q[3 * k + j]);
        q[3 * k + i] = R::if_lt(li, lj, qj, qi);
        q[3 * k + j] = R::if_lt(li, lj, -qi, qj);
    }
}

/// Applies the Givens rotation that zeroes `b[r][c]` against `b[p][c]` to rows p and r of
/// b and of `ut` (which accumulates `U^T`).
#[inline(always)]
fn givens_rows<R: Lane>(b: &mut [R; 9], ut: &mut [R; 9], p: usize, r: usize, c: usize) {
    let (x, y) = (b[3 * p + c], b[3 * r + c]);
    let n = x.fma(x, y * y).sqrt();
    let degenerate = R::if_lt(n, R::splat(1e-300), R::splat(1.0), R::splat(0.0));
    let inv = R::splat(1.0) / (n + degenerate);
    // n = 0: (cos, sin) = (1, 0).
    let cs = x * inv + degenerate;
    let sn = y * inv;
    for m in [&mut *b, &mut *ut] {
        for k in 0..3 {
            let (u, v) = (m[3 * p + k], m[3 * r + k]);
            m[3 * p + k] = cs * u + sn * v;
            m[3 * r + k] = cs * v - sn * u;
        }
    }
}

/// `F = U diag(sigma) V^T` with U, V rotations, `sigma_0 >= sigma_1 >= |sigma_2|` up to
/// rounding and `sigma_2 < 0` when `det F < 0` (the invertible SVD of Irving et al. 2004).
/// Matrices row-major.
#[inline(always)]
pub fn svd3<R: Lane>(f: &[R; 9]) -> ([R; 9], [R; 3], [R; 9]) {
    // F^T F, upper triangle.
    let col = |i: usize, j: usize| f[i].fma(f[j], f[3 + i].fma(f[3 + j], f[6 + i] * f[6 + j]));
    let (mut l, mut v) = sym_eig3([
        col(0, 0),
        col(0, 1),
        col(0, 2),
        col(1, 1),
        col(1, 2),
        col(2, 2),
    ]);
    order_pair(&mut l, &mut v, 0, 1);
    order_pair(&mut l, &mut v, 1, 2);
    order_pair(&mut l, &mut v, 0, 1);
    let mut b = mul3(f, &v);
    let zero = R::splat(0.0);
    let one = R::splat(1.0);
    let mut ut = [one, zero, zero, zero, one, zero, zero, zero, one];
    givens_rows(&mut b, &mut ut, 0, 1, 0);
    givens_rows(&mut b, &mut ut, 0, 2, 0);
    givens_rows(&mut b, &mut ut, 1, 2, 1);
    (transpose3(&ut), [b[0], b[4], b[8]], v)
}

/// `a b` for 3x3 matrices (row-major) of any lane type.
#[inline(always)]
pub fn mul3<R: Lane>(a: &[R; 9], b: &[R; 9]) -> [R; 9] {
    std::array::from_fn(|i| {
        let (r, c) = (i / 3, i % 3);
        a[3 * r].fma(b[c], a[3 * r + 1].fma(b[3 + c], a[3 * r + 2] * b[6 + c]))
    })
}

/// `a^T` for a 3x3 matrix (row-major) of any lane type.
#[inline(always)]
pub fn transpose3<R: Lane>(a: &[R; 9]) -> [R; 9] {
    [a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8]]
}

/// What an isotropic material gives at singular values sigma: the energy density, its
/// gradient p, Hessian A (row-major 3x3) and, for the pairs (0,1), (0,2), (1,2), the
/// quotients `q- = (p_i - p_j)/(sigma_i - sigma_j)` and `q+ = (p_i + p_j)/(sigma_i +
/// sigma_j)`.
struct Diag<R> {
    psi: R,
    p: [R; 3],
    a: [R; 9],
    qm: [R; 3],
    qp: [R; 3],
}

const PAIRS: [(usize, usize, usize); 3] = [(0, 1, 2), (0, 2, 1), (1, 2, 0)];

#[inline(always)]
fn diag<R: Lane>(m: Material, mu: R, lambda: R, s: [R; 3]) -> Diag<R> {
    let (one, two, half) = (R::splat(1.0), R::splat(2.0), R::splat(0.5));
    let three = R::splat(3.0);
    let sq = s[0] * s[0] + s[1] * s[1] + s[2] * s[2];
    match m {
        Material::Corotational => {
            // Psi = mu sum (s - 1)^2 + lambda/2 (sum s - 3)^2.
            let tr = s[0] + s[1] + s[2] - three;
            let d: [R; 3] = std::array::from_fn(|i| s[i] - one);
            let psi = mu * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) + half * lambda * tr * tr;
            let p = std::array::from_fn(|i| two * mu * d[i] + lambda * tr);
            let a = std::array::from_fn(|k| {
                if k % 4 == 0 {
                    two * mu + lambda
                } else {
                    lambda
                }
            });
            let qm = [two * mu; 3];
            // q+ = 2 mu + (2 lambda tr - 4 mu) / (s_i + s_j); the sum vanishes only for an
            // inverted element at the edge of the rotation's definition (kept finite).
            let qp = PAIRS.map(|(i, j, _)| {
                let den = s[i] + s[j];
                let den = R::if_lt(den.abs(), R::splat(1e-12), R::splat(1e-12), den);
                two * mu + (two * lambda * tr - two * two * mu) / den
            });
            Diag { psi, p, a, qm, qp }
        }
        Material::StVenantKirchhoff => {
            // Psi = mu/4 sum (s^2 - 1)^2 + lambda/8 (sum s^2 - 3)^2.
            let t = sq - three;
            let e: [R; 3] = std::array::from_fn(|i| s[i] * s[i] - one);
            let psi = R::splat(0.25) * mu * (e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
                + R::splat(0.125) * lambda * t * t;
            let c = half * lambda * t - mu;
            let p = std::array::from_fn(|i| s[i] * (mu * s[i] * s[i] + c));
            let a = std::array::from_fn(|k| {
                let (i, j) = (k / 3, k % 3);
                if i == j {
                    three * mu * s[i] * s[i] + c + lambda * s[i] * s[i]
                } else {
                    lambda * s[i] * s[j]
                }
            });
            let qm = PAIRS.map(|(i, j, _)| mu * (s[i] * s[i] + s[i] * s[j] + s[j] * s[j]) + c);
            let qp = PAIRS.map(|(i, j, _)| mu * (s[i] * s[i] - s[i] * s[j] + s[j] * s[j]) + c);
            Diag { psi, p, a, qm, qp }
        }
        Material::NeoHookean => {
            // Psi = mu/2 (sum s^2 - 3) - mu log J + lambda/2 (log J)^2, NaN for J <= 0.
            let j = s[0] * s[1] * s[2];
            let lj = j.ln();
            let psi = half * mu * (sq - three) - mu * lj + half * lambda * lj * lj;
            let c = mu - lambda * lj;
            let p = std::array::from_fn(|i| mu * s[i] - c / s[i]);
            let a = std::array::from_fn(|k| {
                let (i, jj) = (k / 3, k % 3);
                if i == jj {
                    mu + (c + lambda) / (s[i] * s[i])
                } else {
                    lambda / (s[i] * s[jj])
                }
            });
            let qm = PAIRS.map(|(i, jj, _)| mu + c / (s[i] * s[jj]));
            let qp = PAIRS.map(|(i, jj, _)| mu - c / (s[i] * s[jj]));
            Diag { psi, p, a, qm, qp }
        }
        Material::StableNeoHookean => {
            // Psi = mu/2 (sum s^2 - 3) - mu (J - 1) + lambda'/2 (J - 1)^2, lambda' =
            // lambda + mu (as crate::fem::Material::StableNeoHookean).
            let lp = lambda + mu;
            let j = s[0] * s[1] * s[2];
            let psi = half * mu * (sq - three) - mu * (j - one) + half * lp * (j - one) * (j - one);
            let c = lp * (j - one) - mu;
            // J / s_i without dividing: the product of the other two.
            let other = [s[1] * s[2], s[0] * s[2], s[0] * s[1]];
            let p = std::array::from_fn(|i| mu * s[i] + c * other[i]);
            let a = std::array::from_fn(|k| {
                let (i, jj) = (k / 3, k % 3);
                if i == jj {
                    mu + lp * other[i] * other[i]
                } else {
                    lp * other[i] * other[jj] + c * s[3 - i - jj]
                }
            });
            let qm = PAIRS.map(|(_, _, k)| mu - c * s[k]);
            let qp = PAIRS.map(|(_, _, k)| mu + c * s[k]);
            Diag { psi, p, a, qm, qp }
        }
        Material::Linear => unreachable!("linear elasticity has no singular-value kernel"),
    }
}

/// The material at singular values sigma, for the invertible version continued past the
/// clamp c to first order: with `s^ = max(sigma, c)` and `d = sigma - s^` (nonzero on the
/// clamped values), `Psi~ = Psi^(s^) + p(s^) . d`, whose gradient is `p_k(s^)` on a
/// clamped k (the constant restoring stress of Irving et al. 2004) and `p_k(s^) + sum_j
/// A_kj(s^) d_j` on the others, so forces are exactly minus the energy's gradient (the
/// line searches on energy rely on it). The tangent is the material's at s^, A(s^) and the
/// pair quotients there, as Teran et al. (2005) take it: past the clamp not the exact
/// Hessian (which has no stiffness left along a clamped value, and is singular where an
/// inverted element's two singular values cancel), but a definite and bounded one that
/// keeps implicit steps short there.
#[inline(always)]
fn clamped<R: Lane>(iso: &Iso, mu: R, lambda: R, sigma: [R; 3]) -> Diag<R> {
    let Some(c) = iso.clamp else {
        return diag(iso.material, mu, lambda, sigma);
    };
    let c = R::splat(c);
    let (zero, one) = (R::splat(0.0), R::splat(1.0));
    let sh = sigma.map(|s| s.max(c));
    let mut d = diag(iso.material, mu, lambda, sh);
    let dl: [R; 3] = std::array::from_fn(|i| sigma[i] - sh[i]);
    // 1 where the value is free, 0 where clamped.
    let free: [R; 3] = sigma.map(|s| R::if_lt(s, c, zero, one));
    for (pk, dk) in d.p.iter().zip(&dl) {
        d.psi = pk.fma(*dk, d.psi);
    }
    let p = d.p;
    for k in 0..3 {
        let corr = d.a[3 * k].fma(dl[0], d.a[3 * k + 1].fma(dl[1], d.a[3 * k + 2] * dl[2]));
        d.p[k] = (free[k] * corr) + p[k];
    }
    d
}

/// A symmetric 3x3 (row-major) projected onto the semi-definite cone, when some lane is
/// not positive definite (Sylvester's criterion on the leading minors; a definite matrix
/// is its own projection).
#[inline(always)]
fn project3<R: Lane>(a: [R; 9]) -> [R; 9] {
    let m2 = a[0] * a[4] - a[1] * a[3];
    let m3 = a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6])
        + a[2] * (a[3] * a[7] - a[4] * a[6]);
    if !(a[0].any_not_positive() || m2.any_not_positive() || m3.any_not_positive()) {
        return a;
    }
    let (l, q) = sym_eig3([a[0], a[1], a[2], a[4], a[5], a[8]]);
    let l = l.map(|v| v.max(R::splat(0.0)));
    std::array::from_fn(|k| {
        let (i, j) = (k / 3, k % 3);
        q[3 * i] * l[0] * q[3 * j]
            + q[3 * i + 1] * l[1] * q[3 * j + 1]
            + q[3 * i + 2] * l[2] * q[3 * j + 2]
    })
}

/// One element (outputs first, as every kernel): its forces `f_a = -vol P g_a` into f,
/// with k its ten stiffness blocks
/// `K_ab = df_a/dx_b` (a <= b, the order of `crate::fem::element_stiffness`, 3x3
/// row-major each), and its energy `vol Psi` returned (J). x: current vertices, `dm_inv`:
/// `Dm^-1` row-major, vol: rest volume, lame: `[mu, lambda]` (Pa).
#[inline(always)]
pub fn element<R: Lane>(
    f: &mut [[R; 3]; 4],
    k: Option<&mut [R; 90]>,
    x: &[[R; 3]; 4],
    dm_inv: &[R; 9],
    vol: R,
    lame: [R; 2],
    iso: &Iso,
) -> R {
    let (u, sigma, v) = svd3(&gradient(x, dm_inv));
    element_in_frame(f, k, (&u, sigma, &v), dm_inv, vol, lame, iso)
}

/// An element's shape gradients `g_a`: the rows of `Dm^-1` for vertices 1 to 3, and
/// `g_0` minus their sum.
#[inline(always)]
fn shape_gradients<R: Lane>(dm_inv: &[R; 9]) -> [[R; 3]; 4] {
    let row = |a: usize| -> [R; 3] { std::array::from_fn(|j| dm_inv[3 * a + j]) };
    let (g1, g2, g3) = (row(0), row(1), row(2));
    [
        std::array::from_fn(|j| -(g1[j] + g2[j] + g3[j])),
        g1,
        g2,
        g3,
    ]
}

/// `F = Ds Dm^-1` of an element with vertices x.
#[inline(always)]
fn gradient<R: Lane>(x: &[[R; 3]; 4], dm_inv: &[R; 9]) -> [R; 9] {
    let ds: [R; 9] = std::array::from_fn(|i| {
        let (r, c) = (i / 3, i % 3);
        x[c + 1][r] - x[0][r]
    });
    mul3(&ds, dm_inv)
}

/// [`element`] from the SVD `(U, sigma, V)` of its deformation gradient on.
#[inline(always)]
fn element_in_frame<R: Lane>(
    f: &mut [[R; 3]; 4],
    k: Option<&mut [R; 90]>,
    (u, sigma, v): (&[R; 9], [R; 3], &[R; 9]),
    dm_inv: &[R; 9],
    vol: R,
    lame: [R; 2],
    iso: &Iso,
) -> R {
    let d = clamped(iso, lame[0], lame[1], sigma);
    let psi = d.psi;
    // Shape gradients in V's frame.
    let gh: [[R; 3]; 4] = shape_gradients(dm_inv)
        .map(|g| std::array::from_fn(|n| g[0].fma(v[n], g[1].fma(v[3 + n], g[2] * v[6 + n]))));
    let nvol = -vol;
    for (fa, ga) in f.iter_mut().zip(&gh) {
        let w: [R; 3] = std::array::from_fn(|n| d.p[n] * ga[n]);
        for (i, fai) in fa.iter_mut().enumerate() {
            *fai = nvol * u[3 * i].fma(w[0], u[3 * i + 1].fma(w[1], u[3 * i + 2] * w[2]));
        }
    }
    let Some(k) = k else {
        return vol * psi;
    };
    let zero = R::splat(0.0);
    let half = R::splat(0.5);
    let mut a = d.a;
    // Pair blocks [[pa, pb], [pb, pa]] on (dF^_ij, dF^_ji), stored symmetric per pair.
    let mut pa = [zero; 3];
    let mut pb = [zero; 3];
    for n in 0..3 {
        // Eigenvalues a + b = q-, a - b = q+.
        let (e1, e2) = pair_eigenvalues(iso, d.qm[n], d.qp[n]);
        pa[n] = half * (e1 + e2);
        pb[n] = half * (e1 - e2);
    }
    if iso.project {
        a = project3(a);
    }
    // a_mn and b_mn by index pair.
    let pair = |m: usize, n: usize| -> usize {
        match (m.min(n), m.max(n)) {
            (0, 1) => 0,
            (0, 2) => 1,
            _ => 2,
        }
    };
    let nu: [R; 9] = std::array::from_fn(|i| nvol * u[i]);
    let mut out = 0;
    for ai in 0..4 {
        for bi in ai..4 {
            let (ga, gb) = (&gh[ai], &gh[bi]);
            // o[3 m + p] = g^_am g^_bp.
            let o: [R; 9] = std::array::from_fn(|i| ga[i / 3] * gb[i % 3]);
            let kh: [R; 9] = std::array::from_fn(|i| {
                let (m, p) = (i / 3, i % 3);
                if m == p {
                    let (n1, n2) = ((m + 1) % 3, (m + 2) % 3);
                    pa[pair(m, n1)].fma(
                        o[4 * n1],
                        pa[pair(m, n2)].fma(o[4 * n2], a[4 * m] * o[4 * m]),
                    )
                } else {
                    a[3 * m + p].fma(o[3 * m + p], pb[pair(m, p)] * o[3 * p + m])
                }
            });
            // K_ab = (-vol U) K^ U^T.
            let uk = mul3(&nu, &kh);
            for i in 0..3 {
                for c in 0..3 {
                    k[out + 3 * i + c] = uk[3 * i].fma(
                        u[3 * c],
                        uk[3 * i + 1].fma(u[3 * c + 1], uk[3 * i + 2] * u[3 * c + 2]),
                    );
                }
            }
            out += 9;
        }
    }
    vol * psi
}

/// The inputs of a mesh's elements as the wide kernels read them, structure of arrays:
/// element e's vertices are `tets[e]`, vertex i at `(x[0][i], x[1][i], x[2][i])` (m), its
/// `Dm^-1` entry k (row-major) `dm_inv[k][e]` (1/m), rest volume `vol[e]` (m^3) and Lame
/// constants `mu[e]`, `lambda[e]` (Pa). Loaded a vector's elements (four or eight) as
/// they lie, only the positions gathered.
#[derive(Clone, Copy, Debug)]
pub struct Elements<'a> {
    /// Current positions, one array per coordinate.
    pub x: [&'a [f64]; 3],
    /// Vertex indices of each element, all below the position arrays' length.
    pub tets: &'a [[u32; 4]],
    /// `Dm^-1`, one array per entry.
    pub dm_inv: [&'a [f64]; 9],
    /// Rest volumes.
    pub vol: &'a [f64],
    /// First Lame constants.
    pub mu: &'a [f64],
    /// Second Lame constants.
    pub lambda: &'a [f64],
}

/// One group's lanes: positions, `Dm^-1`, volume, `[mu, lambda]`.
type GroupInputs<W> = ([[W; 3]; 4], [W; 9], W, [W; 2]);

impl Elements<'_> {
    /// Elements `e0..e0 + W::LANES` in lanes. Panics where they or their vertices are out
    /// of range (a caller's bug: meshes are checked when built).
    #[inline(always)]
    fn group<W: Wide>(&self, e0: usize) -> GroupInputs<W> {
        let load = |v: &[f64]| {
            let w = &v[e0..e0 + W::LANES];
            W::from_fn(|l| w[l])
        };
        let tets = &self.tets[e0..e0 + W::LANES];
        // `from_fn`, not `map`: array maps stayed out-of-line calls (`try_map`) here,
        // 10% of the kernel's time.
        let x = std::array::from_fn(|a| {
            std::array::from_fn(|c| W::from_fn(|l| self.x[c][tets[l][a] as usize]))
        });
        (
            x,
            std::array::from_fn(|k| load(self.dm_inv[k])),
            load(self.vol),
            [load(self.mu), load(self.lambda)],
        )
    }
}

/// [`element`] over elements `e0..e0 + 4` of `els` at once, one per `f64x4` lane:
/// element `e0 + l`'s 12 forces land at `f[12 l..]` (vertex-major) and, with k, its 90
/// stiffness values at `k[90 l..]`; the four energies are returned. Tested equal to
/// four [`element`] calls at `f64` (`tests/fem.rs`).
pub fn element_x4(
    f: &mut [f64; 48],
    k: Option<&mut [f64; 360]>,
    els: &Elements,
    e0: usize,
    iso: &Iso,
) -> [f64; 4] {
    let inputs = els.group::<f64x4>(e0);
    let (u, s, v) = svd3(&gradient(&inputs.0, &inputs.1));
    let mut kl = [f64x4::ZERO; 90];
    let mut energy = [0.0; 4];
    group_outputs(
        f,
        k.map(|k| &mut k[..]),
        (&u, s, &v),
        &inputs,
        &mut kl,
        iso,
        &mut energy,
    );
    energy
}

/// [`element_x4`] over elements `e0..e0 + 8`, as two groups of four whose SVDs run
/// interleaved ([`Groups`]): the SVD is a chain of dependent square roots and divisions
/// (latency-bound, about half of a group's time), and two chains in flight take 0.6 of
/// the time of two in turn. Measured: three groups gained 3% more, not worth a third
/// group size; the whole kernel over two groups at once is twice as slow with AVX2
/// (sixteen vector registers, spilled). Element `e0 + l`'s outputs at `f[12 l..]` and
/// `k[90 l..]`.
pub fn element_x8(
    f: &mut [f64; 96],
    k: Option<&mut [f64; 720]>,
    els: &Elements,
    e0: usize,
    iso: &Iso,
) -> [f64; 8] {
    let mut energy = [0.0; 8];
    two_groups::<f64x4>(f, k.map(|k| &mut k[..]), els, e0, iso, &mut energy);
    energy
}

/// [`element_x8`] over elements `e0..e0 + 16`, as two groups of eight (`f64x8`), for
/// builds with AVX-512 (32 vector registers of eight lanes): on an Intel Xeon core the
/// bench's 60,000 elements took 6.11 ms against 7.26 ms with `element_x8` (outputs in
/// cache), where one group of eight in an AVX-512 register took as long as
/// `element_x8` (7.11 against 7.18 ms in a scratch build: one dependent chain in flight
/// waits as long at either width).
/// Without AVX-512 an `f64x8` is two `f64x4`, and this is four groups at once.
pub fn element_x16(
    f: &mut [f64; 192],
    k: Option<&mut [f64; 1440]>,
    els: &Elements,
    e0: usize,
    iso: &Iso,
) -> [f64; 16] {
    let mut energy = [0.0; 16];
    two_groups::<f64x8>(f, k.map(|k| &mut k[..]), els, e0, iso, &mut energy);
    energy
}

/// Elements `e0..e0 + 2 W::LANES` as two groups whose SVDs run interleaved: forces into
/// f (12 per element), stiffness into k (90 per element), energies into `energy`.
#[inline(always)]
fn two_groups<W: Wide>(
    f: &mut [f64],
    mut k: Option<&mut [f64]>,
    els: &Elements,
    e0: usize,
    iso: &Iso,
    energy: &mut [f64],
) {
    let n = W::LANES;
    let inputs = [els.group::<W>(e0), els.group::<W>(e0 + n)];
    let fg: [_; 2] = std::array::from_fn(|g| gradient(&inputs[g].0, &inputs[g].1));
    let (u2, s2, v2) = svd3(&std::array::from_fn(|i| Groups([fg[0][i], fg[1][i]])));
    // Overwritten by each group: zeroed once.
    let mut kl = [W::default(); 90];
    for (g, input) in inputs.iter().enumerate() {
        let u: [W; 9] = std::array::from_fn(|i| u2[i].0[g]);
        let v: [W; 9] = std::array::from_fn(|i| v2[i].0[g]);
        let s: [W; 3] = std::array::from_fn(|i| s2[i].0[g]);
        let kg = k.as_mut().map(|k| &mut k[90 * n * g..90 * n * (g + 1)]);
        group_outputs(
            &mut f[12 * n * g..12 * n * (g + 1)],
            kg,
            (&u, s, &v),
            input,
            &mut kl,
            iso,
            &mut energy[n * g..n * (g + 1)],
        );
    }
}

/// One group from the SVD of its deformation gradients on: forces into f (`12 LANES`,
/// element-major), with k its stiffness (`90 LANES`, built in the lanes of `kl` first),
/// the energies into `energy`.
#[inline(always)]
fn group_outputs<W: Wide>(
    f: &mut [f64],
    k: Option<&mut [f64]>,
    frame: (&[W; 9], [W; 3], &[W; 9]),
    (_, dl, vl, ll): &GroupInputs<W>,
    kl: &mut [W; 90],
    iso: &Iso,
    energy: &mut [f64],
) {
    let mut fl = [[W::default(); 3]; 4];
    let e = match k {
        Some(k) => {
            let e = element_in_frame(&mut fl, Some(kl), frame, dl, *vl, *ll, iso);
            scatter_lanes(&kl[..], k);
            e
        }
        None => element_in_frame(&mut fl, None, frame, dl, *vl, *ll, iso),
    };
    scatter_lanes(fl.as_flattened(), f);
    e.store(energy);
}

/// Lane l of every value into `out[S l..S (l + 1)]`, in order (`S = values.len()`; a
/// group's outputs, element-major): `LANES` values at a time through transposes, the
/// rest one by one.
#[inline(always)]
fn scatter_lanes<W: Wide>(values: &[W], out: &mut [f64]) {
    let (s, n) = (values.len(), W::LANES);
    let whole = s / n * n;
    for (q, block) in values[..whole].chunks_exact(n).enumerate() {
        W::transpose_store(block, out, s, n * q);
    }
    let mut lanes = [0.0; 8];
    for (i, v) in values.iter().enumerate().skip(whole) {
        v.store(&mut lanes[..n]);
        for (l, x) in lanes[..n].iter().enumerate() {
            out[s * l + i] = *x;
        }
    }
}

/// Newton iterations of [`polar_newton`]: from singular values within a factor of two of one
/// the iteration's error falls below rounding in five (`s <- (s + 1/s) / 2`: 2, 1.25,
/// 1.025, 1.0003, 1 + 5e-8, 1 + 1e-15).
const POLAR_ITERATIONS: usize = 5;
/// The largest change of an entry of R in the last iteration for which [`polar_newton`]'s R is
/// taken: Newton's error then squares, below 1e-16.
const POLAR_TOLERANCE: f64 = 1e-8;
/// The smallest `det F` [`corotational_forces`] takes: flatter and inverted elements go
/// through the SVD, whose signed frame keeps R a rotation (Newton's iteration would
/// converge to a reflection for `det F < 0`).
const POLAR_MIN_DET: f64 = 0.2;

/// The rotation of the polar decomposition `F = R S` by Newton's iteration
/// `X <- (X + X^-T) / 2` from `X = F` (Higham 1986, "Computing the polar decomposition,
/// with applications", SIAM J. Sci. Stat. Comput. 7), `POLAR_ITERATIONS` (5) times, with
/// `X^-T = cof(X) / det X`: one division an iteration, where the SVD's chain has
/// twenty-four square roots and fifteen divisions. Returns R, `det F` and the largest
/// change of an entry in the last iteration (how far from converged). For `det F > 0`
/// R is the SVD's `U V^T` ([`crate::fem::polar`], which also gives S and keeps R a
/// rotation for inverted F).
#[inline(always)]
pub fn polar_newton<R: Lane>(f: &[R; 9]) -> ([R; 9], R, R) {
    let half = R::splat(0.5);
    let mut x = *f;
    let mut det_f = R::splat(0.0);
    let mut change = R::splat(0.0);
    for it in 0..POLAR_ITERATIONS {
        let c = crate::fem::cofactor(&x);
        let det = x[0].fma(c[0], x[1].fma(c[1], x[2] * c[2]));
        if it == 0 {
            det_f = det;
        }
        let h = half / det;
        let next: [R; 9] = std::array::from_fn(|i| half.fma(x[i], h * c[i]));
        if it + 1 == POLAR_ITERATIONS {
            change = (0..9).fold(R::splat(0.0), |a, i| a.max((next[i] - x[i]).abs()));
        }
        x = next;
    }
    (x, det_f, change)
}

/// The corotational material's element forces and energy without the tangent, through
/// [`polar_newton`] instead of the SVD: `P = 2 mu (F - R) + lambda (tr(R^T F) - 3) R`, the
/// energy `vol (mu |F - R|^2 + lambda/2 (tr(R^T F) - 3)^2)`, forces `f_a = -vol P g_a`:
/// the same material as [`element`] with `Material::Corotational` (not clamped), to
/// rounding. Returns the energy and a value positive in each lane whose result stands
/// (`det F` at least `POLAR_MIN_DET` = 0.2, Newton converged); where it is not, the caller
/// evaluates the element through the SVD.
#[inline(always)]
pub fn corotational_forces<R: Lane>(
    f: &mut [[R; 3]; 4],
    x: &[[R; 3]; 4],
    dm_inv: &[R; 9],
    vol: R,
    lame: [R; 2],
) -> (R, R) {
    let (e, ok, _) = polar_forces(f, x, dm_inv, vol, lame);
    (e, ok)
}

/// [`corotational_forces`] with the element's ten warped stiffness blocks
/// `K_ab = df_a/dx_b = -vol (mu (g_a . g_b) I + lambda h_a h_b^T + mu h_b h_a^T)`, `h_a =
/// R g_a` (a <= b, the order of [`element`]): the linear material's blocks `K0` turned by
/// the element's rotation, `R K0 R^T` (Müller and Gross 2004), which is
/// [`element`]'s tangent with [`Iso::warped`] (to rounding) at a fraction of its cost: no
/// SVD, and a block is two outer products. Returns the energy and the same validity as
/// [`corotational_forces`]; where a lane's is not positive the caller evaluates the
/// element through the SVD (with [`Iso::warped`]).
#[inline(always)]
pub fn corotational_warped<R: Lane>(
    f: &mut [[R; 3]; 4],
    k: &mut [R; 90],
    x: &[[R; 3]; 4],
    dm_inv: &[R; 9],
    vol: R,
    [mu, lambda]: [R; 2],
) -> (R, R) {
    let (e, ok, r) = polar_forces(f, x, dm_inv, vol, [mu, lambda]);
    let g = shape_gradients(dm_inv);
    let h: [[R; 3]; 4] = std::array::from_fn(|a| {
        let g = g[a];
        std::array::from_fn(|i| r[3 * i].fma(g[0], r[3 * i + 1].fma(g[1], r[3 * i + 2] * g[2])))
    });
    let nvol = -vol;
    let (nl, nm) = (nvol * lambda, nvol * mu);
    let mut out = 0;
    for a in 0..4 {
        // -vol lambda h_a and -vol mu h_a, the row factors of the outer products.
        let la: [R; 3] = std::array::from_fn(|i| nl * h[a][i]);
        let ma: [R; 3] = std::array::from_fn(|i| nm * h[a][i]);
        for b in a..4 {
            let gg = g[a][0].fma(g[b][0], g[a][1].fma(g[b][1], g[a][2] * g[b][2]));
            let diag = nm * gg;
            for i in 0..3 {
                for c in 0..3 {
                    let v = la[i].fma(h[b][c], h[b][i] * ma[c]);
                    k[out + 3 * i + c] = if i == c { v + diag } else { v };
                }
            }
            out += 9;
        }
    }
    (e, ok)
}

/// The polar part of [`corotational_forces`]: forces into f, and the energy, the validity
/// and R returned.
#[inline(always)]
fn polar_forces<R: Lane>(
    f: &mut [[R; 3]; 4],
    x: &[[R; 3]; 4],
    dm_inv: &[R; 9],
    vol: R,
    [mu, lambda]: [R; 2],
) -> (R, R, [R; 9]) {
    let fg = gradient(x, dm_inv);
    let (r, det, change) = polar_newton(&fg);
    // Positive where both hold: -max(change - tolerance, min det - det). A NaN F makes
    // det NaN, and so both terms and the result.
    let ok = -(change - R::splat(POLAR_TOLERANCE)).max(R::splat(POLAR_MIN_DET) - det);
    let d: [R; 9] = std::array::from_fn(|i| fg[i] - r[i]);
    // tr(R^T F) - 3 = tr(S) - 3.
    let tr = (0..9).fold(R::splat(-3.0), |a, i| r[i].fma(fg[i], a));
    let dd = (0..9).fold(R::splat(0.0), |a, i| d[i].fma(d[i], a));
    let (two_mu, lt) = (mu + mu, lambda * tr);
    let p: [R; 9] = std::array::from_fn(|i| two_mu.fma(d[i], lt * r[i]));
    let psi = mu.fma(dd, R::splat(0.5) * lt * tr);
    // f_a = -vol P g_a for the rows g_1..g_3 of Dm^-1, f_0 = -(f_1 + f_2 + f_3).
    let nvol = -vol;
    for a in 1..4 {
        let g = [
            dm_inv[3 * (a - 1)],
            dm_inv[3 * (a - 1) + 1],
            dm_inv[3 * (a - 1) + 2],
        ];
        for i in 0..3 {
            f[a][i] = nvol * p[3 * i].fma(g[0], p[3 * i + 1].fma(g[1], p[3 * i + 2] * g[2]));
        }
    }
    f[0] = std::array::from_fn(|i| -(f[1][i] + f[2][i] + f[3][i]));
    (vol * psi, ok, r)
}

/// [`corotational_forces`] over elements `e0..e0 + 8` as two groups of four
/// (`f64x4`) in flight, forces into f (12 per element, vertex-major) and the energies
/// returned; `None` (f untouched) where some element needs the SVD.
pub fn corotational_forces_x8(f: &mut [f64; 96], els: &Elements, e0: usize) -> Option<[f64; 8]> {
    let mut energy = [0.0; 8];
    polar_groups::<f64x4>(f, None, els, e0, &mut energy).then_some(energy)
}

/// [`corotational_forces_x8`] over elements `e0..e0 + 16`, two groups of eight (`f64x8`).
pub fn corotational_forces_x16(f: &mut [f64; 192], els: &Elements, e0: usize) -> Option<[f64; 16]> {
    let mut energy = [0.0; 16];
    polar_groups::<f64x8>(f, None, els, e0, &mut energy).then_some(energy)
}

/// [`corotational_warped`] over elements `e0..e0 + 8` as two groups of four (`f64x4`):
/// forces into f (12 per element), the warped stiffness into k (90 per element), the
/// energies returned; `None` (f and k untouched) where some element needs the SVD.
pub fn corotational_warped_x8(
    f: &mut [f64; 96],
    k: &mut [f64; 720],
    els: &Elements,
    e0: usize,
) -> Option<[f64; 8]> {
    let mut energy = [0.0; 8];
    polar_groups::<f64x4>(f, Some(k), els, e0, &mut energy).then_some(energy)
}

/// [`corotational_warped_x8`] over elements `e0..e0 + 16`, two groups of eight (`f64x8`).
pub fn corotational_warped_x16(
    f: &mut [f64; 192],
    k: &mut [f64; 1440],
    els: &Elements,
    e0: usize,
) -> Option<[f64; 16]> {
    let mut energy = [0.0; 16];
    polar_groups::<f64x8>(f, Some(k), els, e0, &mut energy).then_some(energy)
}

/// Two groups of `W::LANES` elements through [`corotational_forces`], or with k through
/// [`corotational_warped`] (90 values per element); false, with nothing written, where a
/// lane's result does not stand.
#[inline(always)]
fn polar_groups<W: Wide>(
    f: &mut [f64],
    k: Option<&mut [f64]>,
    els: &Elements,
    e0: usize,
    energy: &mut [f64],
) -> bool {
    let n = W::LANES;
    let inputs = [els.group::<W>(e0), els.group::<W>(e0 + n)];
    let two = |a: W, b: W| Groups([a, b]);
    let x =
        std::array::from_fn(|a| std::array::from_fn(|c| two(inputs[0].0[a][c], inputs[1].0[a][c])));
    let dm = std::array::from_fn(|k| two(inputs[0].1[k], inputs[1].1[k]));
    let vol = two(inputs[0].2, inputs[1].2);
    let lame = [0, 1].map(|k| two(inputs[0].3[k], inputs[1].3[k]));
    let mut fl = [[Groups::<2, W>::splat(0.0); 3]; 4];
    let Some(k) = k else {
        let (e, ok) = corotational_forces(&mut fl, &x, &dm, vol, lame);
        if ok.any_not_positive() {
            return false;
        }
        store_groups(&fl, e, f, energy);
        return true;
    };
    let mut kl = [Groups::<2, W>::splat(0.0); 90];
    let (e, ok) = corotational_warped(&mut fl, &mut kl, &x, &dm, vol, lame);
    if ok.any_not_positive() {
        return false;
    }
    store_groups(&fl, e, f, energy);
    for g in 0..2 {
        let kg: [W; 90] = std::array::from_fn(|i| kl[i].0[g]);
        scatter_lanes(&kg, &mut k[90 * n * g..90 * n * (g + 1)]);
    }
    true
}

/// Both groups' forces (12 per element) into f and energies into `energy`.
#[inline(always)]
fn store_groups<W: Wide>(
    fl: &[[Groups<2, W>; 3]; 4],
    e: Groups<2, W>,
    f: &mut [f64],
    energy: &mut [f64],
) {
    let n = W::LANES;
    for g in 0..2 {
        let fg: [W; 12] = std::array::from_fn(|i| fl[i / 3][i % 3].0[g]);
        scatter_lanes(&fg, &mut f[12 * n * g..12 * n * (g + 1)]);
        e.0[g].store(&mut energy[n * g..n * (g + 1)]);
    }
}

/// The material of `iso` at one deformation gradient F, through the singular-value frame
/// as the element kernel evaluates it: the energy density (J/m^3, continued to first order
/// past the clamp), the first Piola-Kirchhoff stress P (Pa) and the tangent `dP/dF` (81
/// values, entry `(3 i + j) * 9 + 3 k + l` is `dP_ij / dF_kl`, projected when
/// `iso.project`). Without clamping or projection these equal `crate::fem::energy_density`,
/// `crate::fem::pk1` and `crate::fem::pk1_derivative` (tested), so the invertible versions
/// share the materials' one interface.
pub fn evaluate(iso: &Iso, lame: Lame, f: &M3) -> (f64, M3, [f64; 81]) {
    let (u, sigma, v) = svd3(f);
    let d = clamped(iso, lame.mu, lame.lambda, sigma);
    let psi = d.psi;
    let p: M3 = std::array::from_fn(|k| {
        let (i, j) = (k / 3, k % 3);
        (0..3).map(|n| u[3 * i + n] * d.p[n] * v[3 * j + n]).sum()
    });
    let a = if iso.project { project3(d.a) } else { d.a };
    let mut t = [0.0; 81];
    for kl in 0..9 {
        let (kk, ll) = (kl / 3, kl % 3);
        // dF^ = U^T E_kl V: dF^_pq = U_kp V_lq.
        let dfh: M3 = std::array::from_fn(|pq| u[3 * kk + pq / 3] * v[3 * ll + pq % 3]);
        let mut dph = [0.0; 9];
        for m in 0..3 {
            dph[4 * m] = (0..3).map(|q| a[3 * m + q] * dfh[4 * q]).sum();
        }
        for (n, &(i, j, _)) in PAIRS.iter().enumerate() {
            let (e1, e2) = pair_eigenvalues(iso, d.qm[n], d.qp[n]);
            let (pa, pb) = (0.5 * (e1 + e2), 0.5 * (e1 - e2));
            dph[3 * i + j] = pa * dfh[3 * i + j] + pb * dfh[3 * j + i];
            dph[3 * j + i] = pb * dfh[3 * i + j] + pa * dfh[3 * j + i];
        }
        let dp = mul3(&mul3(&u, &dph), &transpose3(&v));
        for ij in 0..9 {
            t[ij * 9 + kl] = dp[ij];
        }
    }
    (psi, p, t)
}
