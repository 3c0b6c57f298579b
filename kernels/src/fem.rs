//! Linear tetrahedra with hyperelastic materials (Sifakis and Barbič, "FEM simulation of
//! 3D deformable solids", SIGGRAPH 2012 course notes; course notes section 4).
//!
//! A tetrahedron with rest vertices `X0..X3` and current ones `x0..x3` has the constant
//! deformation gradient `F = Ds Dm^-1`, `Ds = [x1 - x0, x2 - x0, x3 - x0]` (columns),
//! `Dm` the same of the rest vertices. Writing `g_a` for row `a - 1` of `Dm^-1`
//! (`a = 1..3`) and `g_0 = -(g_1 + g_2 + g_3)`, `F = sum_a x_a g_a^T`, so the element's
//! energy `W = V Psi(F)` (V the rest volume, Psi the energy density) gives the forces
//! `f_a = -V P g_a` (P = dPsi/dF, the first Piola-Kirchhoff stress) and the stiffness
//! blocks `K_ab = df_a/dx_b = -V sum_jl dP_ij/dF_kl g_a,j g_b,l` (rows i, columns k). For
//! a hyperelastic material `dP/dF` has major symmetry, so `K_ba = K_ab^T`: an element
//! writes its ten blocks with `a <= b` (`crate::` users assemble them with a symmetric
//! layout).
//!
//! 3x3 matrices are `[f64; 9]`, row-major. The materials ([`Material`]) share one
//! interface: energy density, P and the differential `dP[dF]` (the tangent applied to a
//! direction), from which the 9x9 tangent is formed column by column.

/// A 3x3 matrix, row-major.
pub type M3 = [f64; 9];

/// The identity.
pub const I3: M3 = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

/// Hyperelastic materials of the course notes and the literature they cite.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Material {
    /// Small-strain linear elasticity: `Psi = mu e:e + lambda/2 tr(e)^2`,
    /// `e = (F + F^T)/2 - I`. Not rotation invariant (a rotated element is strained).
    Linear,
    /// Corotational linear elasticity (Müller and Gross 2004), `F = R S` the polar
    /// decomposition: `Psi = mu |F - R|^2 + lambda/2 tr(R^T F - I)^2`, with the exact
    /// tangent (the rotation's differential included, Sifakis and Barbič section 5.2).
    Corotational,
    /// St. Venant-Kirchhoff: `Psi = mu E:E + lambda/2 tr(E)^2`, `E = (F^T F - I)/2`.
    StVenantKirchhoff,
    /// Neo-Hookean (Bonet and Wood): `Psi = mu/2 (I_C - 3) - mu log J + lambda/2 (log J)^2`,
    /// `I_C = |F|^2`, `J = det F`. Infinite for `J <= 0` (the kernels return NaN there).
    NeoHookean,
    /// Stable neo-Hookean (Smith, de Goes and Kim 2018, in the simplified form of Kim and
    /// Eberle's "Dynamic deformables" notes): `Psi = mu/2 (I_C - 3) - mu (J - 1) +
    /// lambda'/2 (J - 1)^2` with `lambda' = lambda + mu`, which matches linear elasticity
    /// at small strain. Finite and smooth through inversion (J <= 0).
    StableNeoHookean,
}

/// Lamé parameters (Pa).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lame {
    /// Shear modulus mu.
    pub mu: f64,
    /// First Lamé parameter lambda.
    pub lambda: f64,
}

impl Lame {
    /// From Young's modulus E (Pa) and Poisson's ratio nu (in (-1, 0.5)):
    /// `mu = E / (2 (1 + nu))`, `lambda = E nu / ((1 + nu)(1 - 2 nu))`.
    pub fn from_young_poisson(e: f64, nu: f64) -> Self {
        Self {
            mu: e / (2.0 * (1.0 + nu)),
            lambda: e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
        }
    }
}

/// `a b` (the generic product of the element kernels, at `f64`).
#[inline]
pub fn mul(a: &M3, b: &M3) -> M3 {
    crate::fem_diag::mul3(a, b)
}

/// `a^T`.
#[inline]
pub fn transpose(a: &M3) -> M3 {
    crate::fem_diag::transpose3(a)
}

/// `det a`.
#[inline]
pub fn det(a: &M3) -> f64 {
    a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6])
        + a[2] * (a[3] * a[7] - a[4] * a[6])
}

/// The cofactor matrix `det(a) a^-T` (defined for singular a too): column c is the cross
/// product of the other two columns of a, `cof a = [a1 x a2, a2 x a0, a0 x a1]`. For any
/// lane type (the wide kernels' polar decomposition, [`crate::fem_diag::polar_newton`]).
#[inline(always)]
pub fn cofactor<R: crate::lane::Lane>(a: &[R; 9]) -> [R; 9] {
    [
        a[4] * a[8] - a[5] * a[7],
        a[5] * a[6] - a[3] * a[8],
        a[3] * a[7] - a[4] * a[6],
        a[2] * a[7] - a[1] * a[8],
        a[0] * a[8] - a[2] * a[6],
        a[1] * a[6] - a[0] * a[7],
        a[1] * a[5] - a[2] * a[4],
        a[2] * a[3] - a[0] * a[5],
        a[0] * a[4] - a[1] * a[3],
    ]
}

/// The differential of the cofactor matrix at a in the direction d (linear in d).
#[inline]
fn cofactor_differential(a: &M3, d: &M3) -> M3 {
    // cof is bilinear in pairs of entries: cof(a + d) = cof a + D + cof d, D this.
    let s = add(a, d);
    let (cs, ca, cd) = (cofactor(&s), cofactor(a), cofactor(d));
    std::array::from_fn(|i| cs[i] - ca[i] - cd[i])
}

/// `a^-1` (NaN entries if a is singular).
#[inline]
pub fn inverse(a: &M3) -> M3 {
    let d = det(a);
    let c = cofactor(a);
    // a^-1 = cof(a)^T / det a.
    let ct = transpose(&c);
    ct.map(|v| v / d)
}

#[inline]
fn add(a: &M3, b: &M3) -> M3 {
    std::array::from_fn(|i| a[i] + b[i])
}

#[inline]
fn trace(a: &M3) -> f64 {
    a[0] + a[4] + a[8]
}

/// `a : b`, the sum of entrywise products.
#[inline]
pub fn ddot(a: &M3, b: &M3) -> f64 {
    (0..9).map(|i| a[i] * b[i]).sum()
}

/// The polar decomposition `F = R S` with R a rotation and S symmetric, from the
/// invertible SVD `F = U diag(sigma) V^T` ([`crate::fem_diag::svd3`]): `R = U V^T`, `S = V
/// diag(sigma) V^T`. For `det F < 0` R stays a rotation and S has one negative eigenvalue
/// (Irving et al. 2004), so the corotational model pushes an inverted element back rather
/// than towards its mirror image.
pub fn polar(f: &M3) -> (M3, M3) {
    let (u, sigma, v) = crate::fem_diag::svd3(f);
    let r = mul(&u, &transpose(&v));
    let s = std::array::from_fn(|k| {
        let (i, j) = (k / 3, k % 3);
        (0..3).map(|n| v[3 * i + n] * sigma[n] * v[3 * j + n]).sum()
    });
    (r, s)
}

/// `[w]x`, the cross-product matrix of w.
#[inline]
fn cross_matrix(w: [f64; 3]) -> M3 {
    [0.0, -w[2], w[1], w[2], 0.0, -w[0], -w[1], w[0], 0.0]
}

/// Solves `a x = b` for a 3x3 a (Cramer's rule).
#[inline]
fn solve3(a: &M3, b: [f64; 3]) -> [f64; 3] {
    let inv = inverse(a);
    std::array::from_fn(|r| inv[3 * r] * b[0] + inv[3 * r + 1] * b[1] + inv[3 * r + 2] * b[2])
}

/// The energy density Psi(F) (J/m^3).
pub fn energy_density(m: Material, l: Lame, f: &M3) -> f64 {
    match m {
        Material::Linear => {
            let e: M3 = std::array::from_fn(|i| 0.5 * (f[i] + f[3 * (i % 3) + i / 3]) - I3[i]);
            l.mu * ddot(&e, &e) + 0.5 * l.lambda * trace(&e).powi(2)
        }
        Material::Corotational => {
            let (r, s) = polar(f);
            let d: M3 = std::array::from_fn(|i| f[i] - r[i]);
            l.mu * ddot(&d, &d) + 0.5 * l.lambda * (trace(&s) - 3.0).powi(2)
        }
        Material::StVenantKirchhoff => {
            let e = green_strain(f);
            l.mu * ddot(&e, &e) + 0.5 * l.lambda * trace(&e).powi(2)
        }
        Material::NeoHookean => {
            let j = det(f);
            if j.is_nan() || j <= 0.0 {
                return f64::NAN;
            }
            let lj = j.ln();
            0.5 * l.mu * (ddot(f, f) - 3.0) - l.mu * lj + 0.5 * l.lambda * lj * lj
        }
        Material::StableNeoHookean => {
            let j = det(f);
            0.5 * l.mu * (ddot(f, f) - 3.0) - l.mu * (j - 1.0)
                + 0.5 * (l.lambda + l.mu) * (j - 1.0).powi(2)
        }
    }
}

fn green_strain(f: &M3) -> M3 {
    let c = mul(&transpose(f), f);
    std::array::from_fn(|i| 0.5 * (c[i] - I3[i]))
}

/// What the stress and its differential need of one F, computed once: the polar factors
/// (corotational), `F^-1` and `log J` (neo-Hookean), the cofactor matrix (stable
/// neo-Hookean), the second Piola-Kirchhoff stress (St. Venant-Kirchhoff). The tangent
/// takes nine differentials at one F; recomputing these for each (a polar decomposition
/// by iteration, for the corotational model) cost more than the differentials.
#[derive(Clone, Copy, Debug)]
struct AtF {
    f: M3,
    j: f64,
    /// R (corotational), F^-1 (neo-Hookean), cof F (stable neo-Hookean), S (StVK).
    a: M3,
    /// S of the polar decomposition (corotational).
    b: M3,
}

impl AtF {
    fn new(m: Material, l: Lame, f: &M3) -> Self {
        let mut at = AtF {
            f: *f,
            j: det(f),
            a: [0.0; 9],
            b: [0.0; 9],
        };
        match m {
            Material::Linear => {}
            Material::Corotational => (at.a, at.b) = polar(f),
            Material::StVenantKirchhoff => {
                let e = green_strain(f);
                let tr = trace(&e);
                at.a = std::array::from_fn(|i| 2.0 * l.mu * e[i] + l.lambda * tr * I3[i]);
            }
            Material::NeoHookean => at.a = inverse(f),
            Material::StableNeoHookean => at.a = cofactor(f),
        }
        at
    }
}

/// The first Piola-Kirchhoff stress `P = dPsi/dF` (Pa).
pub fn pk1(m: Material, l: Lame, f: &M3) -> M3 {
    pk1_at(m, l, &AtF::new(m, l, f))
}

fn pk1_at(m: Material, l: Lame, at: &AtF) -> M3 {
    let f = &at.f;
    match m {
        Material::Linear => {
            let tr = trace(f) - 3.0;
            std::array::from_fn(|i| {
                l.mu * (f[i] + f[3 * (i % 3) + i / 3] - 2.0 * I3[i]) + l.lambda * tr * I3[i]
            })
        }
        Material::Corotational => {
            let (r, s) = (&at.a, &at.b);
            let c = l.lambda * (trace(s) - 3.0);
            std::array::from_fn(|i| 2.0 * l.mu * (f[i] - r[i]) + c * r[i])
        }
        Material::StVenantKirchhoff => mul(f, &at.a),
        Material::NeoHookean => {
            let j = at.j;
            if j.is_nan() || j <= 0.0 {
                return [f64::NAN; 9];
            }
            let fit = transpose(&at.a);
            let c = l.lambda * j.ln() - l.mu;
            std::array::from_fn(|i| l.mu * f[i] + c * fit[i])
        }
        Material::StableNeoHookean => {
            let cof = &at.a;
            let c = (l.lambda + l.mu) * (at.j - 1.0) - l.mu;
            std::array::from_fn(|i| l.mu * f[i] + c * cof[i])
        }
    }
}

/// The differential of P at F in the direction dF: `dP = (dP/dF)[dF]`.
pub fn pk1_differential(m: Material, l: Lame, f: &M3, df: &M3) -> M3 {
    pk1_differential_at(m, l, &AtF::new(m, l, f), df)
}

fn pk1_differential_at(m: Material, l: Lame, at: &AtF, df: &M3) -> M3 {
    let f = &at.f;
    match m {
        Material::Linear => {
            let tr = trace(df);
            std::array::from_fn(|i| {
                l.mu * (df[i] + df[3 * (i % 3) + i / 3]) + l.lambda * tr * I3[i]
            })
        }
        Material::Corotational => {
            let (r, s) = (&at.a, &at.b);
            // dR = R W, W = [w]x with (tr(S) I - S) w = axial(R^T dF - dF^T R) (from
            // R^T dF = W S + dS, S and dS symmetric: R^T dF - dF^T R = W S + S W).
            let rt_df = mul(&transpose(r), df);
            let axial = [
                rt_df[7] - rt_df[5],
                rt_df[2] - rt_df[6],
                rt_df[3] - rt_df[1],
            ];
            let ts = trace(s);
            let a: M3 = std::array::from_fn(|i| ts * I3[i] - s[i]);
            let w = solve3(&a, axial);
            let dr = mul(r, &cross_matrix(w));
            let c = l.lambda * (ts - 3.0);
            let dc = l.lambda * trace(&rt_df);
            std::array::from_fn(|i| 2.0 * l.mu * (df[i] - dr[i]) + dc * r[i] + c * dr[i])
        }
        Material::StVenantKirchhoff => {
            let s = &at.a;
            let ftdf = mul(&transpose(f), df);
            let de: M3 = std::array::from_fn(|i| 0.5 * (ftdf[i] + ftdf[3 * (i % 3) + i / 3]));
            let dtr = trace(&de);
            let ds: M3 = std::array::from_fn(|i| 2.0 * l.mu * de[i] + l.lambda * dtr * I3[i]);
            add(&mul(df, s), &mul(f, &ds))
        }
        Material::NeoHookean => {
            let j = at.j;
            if j.is_nan() || j <= 0.0 {
                return [f64::NAN; 9];
            }
            let fi = &at.a;
            let fit = transpose(fi);
            // dP = mu dF + (mu - lambda log J) F^-T dF^T F^-T + lambda tr(F^-1 dF) F^-T.
            let t = mul(&mul(&fit, &transpose(df)), &fit);
            let c = l.mu - l.lambda * j.ln();
            let tr = l.lambda * trace(&mul(fi, df));
            std::array::from_fn(|i| l.mu * df[i] + c * t[i] + tr * fit[i])
        }
        Material::StableNeoHookean => {
            let cof = &at.a;
            let dcof = cofactor_differential(f, df);
            let lam = l.lambda + l.mu;
            // dJ = cof(F) : dF.
            let dj = ddot(cof, df);
            let c = lam * (at.j - 1.0) - l.mu;
            std::array::from_fn(|i| l.mu * df[i] + lam * dj * cof[i] + c * dcof[i])
        }
    }
}

/// The tangent `dP/dF` as 81 values: entry `(3 i + j) * 9 + 3 k + l` is `dP_ij / dF_kl`.
pub fn pk1_derivative(m: Material, l: Lame, f: &M3) -> [f64; 81] {
    pk1_derivative_at(m, l, &AtF::new(m, l, f))
}

fn pk1_derivative_at(m: Material, l: Lame, at: &AtF) -> [f64; 81] {
    let mut out = [0.0; 81];
    for kl in 0..9 {
        let mut d = [0.0; 9];
        d[kl] = 1.0;
        let dp = pk1_differential_at(m, l, at, &d);
        for ij in 0..9 {
            out[ij * 9 + kl] = dp[ij];
        }
    }
    out
}

/// Projects a symmetric 9x9 matrix (row-major) onto the positive semi-definite cone in
/// place: eigenvalues below zero are set to zero (Teran et al. 2005 project the tangent
/// per element so; here the whole 9x9 `dP/dF` is diagonalised by cyclic Jacobi rotations,
/// which needs no structure of the material). With a semi-definite `dP/dF` the element
/// stiffness `-V G^T (dP/dF) G` is negative semi-definite, so `M - h^2 K` stays positive
/// definite however far the element is compressed. Returns whether anything changed.
pub fn project_psd(a: &mut [f64; 81]) -> bool {
    const N: usize = 9;
    let mut d = *a;
    let mut q = [0.0f64; 81];
    for i in 0..N {
        q[i * N + i] = 1.0;
    }
    let norm: f64 = d.iter().map(|v| v * v).sum::<f64>().sqrt();
    if norm == 0.0 || !norm.is_finite() {
        return false;
    }
    for _sweep in 0..30 {
        let off: f64 = (0..N)
            .flat_map(|i| (0..N).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| d[i * N + j] * d[i * N + j])
            .sum::<f64>()
            .sqrt();
        if off <= 1e-15 * norm {
            break;
        }
        for p in 0..N - 1 {
            for r in p + 1..N {
                let apr = d[p * N + r];
                if apr.abs() <= 1e-300 {
                    continue;
                }
                // The rotation that zeroes (p, r) (Golub and Van Loan, algorithm 8.4.1).
                let theta = (d[r * N + r] - d[p * N + p]) / (2.0 * apr);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let sn = t * c;
                for k in 0..N {
                    let (dkp, dkr) = (d[k * N + p], d[k * N + r]);
                    d[k * N + p] = c * dkp - sn * dkr;
                    d[k * N + r] = sn * dkp + c * dkr;
                }
                for k in 0..N {
                    let (dpk, drk) = (d[p * N + k], d[r * N + k]);
                    d[p * N + k] = c * dpk - sn * drk;
                    d[r * N + k] = sn * dpk + c * drk;
                }
                for k in 0..N {
                    let (qkp, qkr) = (q[k * N + p], q[k * N + r]);
                    q[k * N + p] = c * qkp - sn * qkr;
                    q[k * N + r] = sn * qkp + c * qkr;
                }
            }
        }
    }
    let lambda: [f64; N] = std::array::from_fn(|i| d[i * N + i]);
    if lambda.iter().all(|&l| l >= 0.0) {
        return false;
    }
    for i in 0..N {
        for j in 0..N {
            a[i * N + j] = (0..N)
                .map(|k| q[i * N + k] * lambda[k].max(0.0) * q[j * N + k])
                .sum();
        }
    }
    true
}

/// The rest shape matrix `Dm = [X1 - X0, X2 - X0, X3 - X0]` (columns) of a tetrahedron.
#[inline]
pub fn shape_matrix(x: &[[f64; 3]; 4]) -> M3 {
    let mut d = [0.0; 9];
    for c in 0..3 {
        for r in 0..3 {
            d[3 * r + c] = x[c + 1][r] - x[0][r];
        }
    }
    d
}

/// The signed volume `det(Dm) / 6` of a tetrahedron: positive when `X1 - X0`, `X2 - X0`,
/// `X3 - X0` form a right-handed frame.
#[inline]
pub fn signed_volume(x: &[[f64; 3]; 4]) -> f64 {
    det(&shape_matrix(x)) / 6.0
}

/// The deformation gradient `F = Ds Dm^-1` of an element with current vertices x and
/// `dm_inv = Dm^-1`.
#[inline]
pub fn deformation_gradient(x: &[[f64; 3]; 4], dm_inv: &M3) -> M3 {
    mul(&shape_matrix(x), dm_inv)
}

/// The shape gradients `g_0..g_3` (rows of `Dm^-1`, and minus their sum first): `F =
/// sum_a x_a g_a^T`.
#[inline]
pub fn shape_gradients(dm_inv: &M3) -> [[f64; 3]; 4] {
    let g1 = [dm_inv[0], dm_inv[1], dm_inv[2]];
    let g2 = [dm_inv[3], dm_inv[4], dm_inv[5]];
    let g3 = [dm_inv[6], dm_inv[7], dm_inv[8]];
    let g0 = std::array::from_fn(|j| -(g1[j] + g2[j] + g3[j]));
    [g0, g1, g2, g3]
}

/// `f_a = -V P g_a` (N) for the shape gradients of `dm_inv`.
fn write_forces(f: &mut [[f64; 3]; 4], p: &M3, dm_inv: &M3, volume: f64) {
    let g = shape_gradients(dm_inv);
    for (fa, ga) in f.iter_mut().zip(&g) {
        for (i, fai) in fa.iter_mut().enumerate() {
            *fai = -volume * (p[3 * i] * ga[0] + p[3 * i + 1] * ga[1] + p[3 * i + 2] * ga[2]);
        }
    }
}

/// An element's forces `f_a = -V P g_a` (N) into `f` (four 3-vectors), for current
/// vertices x.
pub fn element_forces(
    f: &mut [[f64; 3]; 4],
    m: Material,
    l: Lame,
    x: &[[f64; 3]; 4],
    dm_inv: &M3,
    volume: f64,
) {
    write_forces(
        f,
        &pk1(m, l, &deformation_gradient(x, dm_inv)),
        dm_inv,
        volume,
    );
}

/// An element's energy `V Psi(F)` (J) at current vertices x.
pub fn element_energy(m: Material, l: Lame, x: &[[f64; 3]; 4], dm_inv: &M3, volume: f64) -> f64 {
    volume * energy_density(m, l, &deformation_gradient(x, dm_inv))
}

/// An element's forces (as [`element_forces`]) and its ten stiffness blocks `K_ab =
/// df_a/dx_b`, `a <= b`, in row order `(0,0) (0,1) (0,2) (0,3) (1,1) (1,2) (1,3) (2,2)
/// (2,3) (3,3)`, each 3x3 row-major, into `k` (90 values). With `project`, the tangent is
/// made positive semi-definite first ([`project_psd`], the definiteness fix): the blocks
/// are then exact only where the material's tangent is already definite. What the stress
/// and the tangent need of F (a polar decomposition, an inverse) is computed once.
#[allow(clippy::too_many_arguments)]
pub fn element_stiffness(
    f: &mut [[f64; 3]; 4],
    k: &mut [f64],
    m: Material,
    l: Lame,
    x: &[[f64; 3]; 4],
    dm_inv: &M3,
    volume: f64,
    project: bool,
) {
    assert_eq!(k.len(), 90, "ten 3x3 blocks");
    let at = AtF::new(m, l, &deformation_gradient(x, dm_inv));
    write_forces(f, &pk1_at(m, l, &at), dm_inv, volume);
    let mut dp = pk1_derivative_at(m, l, &at);
    if project {
        project_psd(&mut dp);
    }
    let g = shape_gradients(dm_inv);
    // t[a][i][k][l] = sum_j dP_ij/dF_kl g_a,j, then K_ab,ik = -V sum_l t g_b,l.
    let mut t = [[0.0f64; 27]; 4];
    for (a, ta) in t.iter_mut().enumerate() {
        for i in 0..3 {
            for kl in 0..9 {
                ta[i * 9 + kl] = (0..3).map(|j| dp[(3 * i + j) * 9 + kl] * g[a][j]).sum();
            }
        }
    }
    let mut out = 0;
    for (a, ta) in t.iter().enumerate() {
        for gb in &g[a..] {
            for i in 0..3 {
                for kk in 0..3 {
                    let s: f64 = (0..3).map(|ll| ta[i * 9 + 3 * kk + ll] * gb[ll]).sum();
                    k[out + 3 * i + kk] = -volume * s;
                }
            }
            out += 9;
        }
    }
}
