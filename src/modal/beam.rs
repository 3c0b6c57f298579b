//! Beam theory references for the modal validations and study: the first bending
//! frequency of a uniform bar of square section by Euler-Bernoulli and by Timoshenko
//! (shear deformation and rotary inertia; Timoshenko 1921, Cowper's shear coefficient,
//! "The shear coefficient in Timoshenko's beam theory", J. Appl. Mech. 33, 1966).

use crate::fem::FemMaterial;
use std::f64::consts::PI;

/// `beta L` of the first bending mode, free at both ends and clamped-free.
pub const FREE_FREE_BETA_L: f64 = 4.730_040_745;
pub const CLAMPED_FREE_BETA_L: f64 = 1.875_104_069;

/// The Euler-Bernoulli bending frequency (Hz) `(beta L)^2 / (2 pi L^2) sqrt(E I / (rho A))` of a
/// square bar of side t.
pub fn euler_bernoulli(beta_l: f64, len: f64, t: f64, m: &FemMaterial) -> f64 {
    beta_l * beta_l / (2.0 * PI * len * len) * (m.young / m.density).sqrt() * t / 12f64.sqrt()
}

/// The first bending frequency (Hz) of a Timoshenko beam of square section t x t and
/// length `len`, free-free (`clamped` false) or clamped-free, with Cowper's shear
/// coefficient `kappa = 10 (1 + nu) / (12 + 11 nu)`. For a frequency w the deflection is
/// `A cosh(a x) + B sinh(a x) + C cos(b x) + D sin(b x)` and the section's rotation
/// `k_a (A sinh + B cosh) + k_b (C sin - D cos)`, with `a^2` and `-b^2` the roots of
/// `kappa G A EI s^4 + w^2 rho (kappa G A I + E I A) s^2 + rho A w^2 (rho I w^2 - kappa G A)
/// = 0` (below the cutoff frequency), `k_a = (kappa G A a^2 + rho A w^2) / (kappa G A a)`
/// and `k_b = (rho A w^2 - kappa G A b^2) / (kappa G A b)`. The end conditions (free: no
/// moment `psi' = 0` and no shear `w' - psi = 0`; clamped: `w = 0`, `psi = 0`) give a 4 x 4
/// determinant in w, whose first root above zero is found by a scan and bisection.
pub fn timoshenko(len: f64, t: f64, mat: &FemMaterial, clamped: bool) -> f64 {
    let (e, nu, rho) = (mat.young, mat.poisson, mat.density);
    let g = e / (2.0 * (1.0 + nu));
    let kappa = 10.0 * (1.0 + nu) / (12.0 + 11.0 * nu);
    let (area, inertia) = (t * t, t.powi(4) / 12.0);
    let kga = kappa * g * area;
    let det = |w: f64| {
        let (qa, qb, qc) = (
            kga * e * inertia,
            w * w * rho * (kga * inertia + e * inertia * area),
            rho * area * w * w * (rho * inertia * w * w - kga),
        );
        // Roots of qa z^2 + qb z + qc = 0 in z = s^2.
        let disc = (qb * qb - 4.0 * qa * qc).sqrt();
        let (z1, z2) = ((-qb + disc) / (2.0 * qa), (-qb - disc) / (2.0 * qa));
        let (a, b) = (z1.sqrt(), (-z2).sqrt());
        let ka = (kga * a * a + rho * area * w * w) / (kga * a);
        let kb = (rho * area * w * w - kga * b * b) / (kga * b);
        // Rows: the conditions at x, as coefficients of (A, B, C, D).
        let wrow = |x: f64| [(a * x).cosh(), (a * x).sinh(), (b * x).cos(), (b * x).sin()];
        let dwrow = |x: f64| {
            [
                a * (a * x).sinh(),
                a * (a * x).cosh(),
                -b * (b * x).sin(),
                b * (b * x).cos(),
            ]
        };
        let psirow = |x: f64| {
            [
                ka * (a * x).sinh(),
                ka * (a * x).cosh(),
                kb * (b * x).sin(),
                -kb * (b * x).cos(),
            ]
        };
        let dpsirow = |x: f64| {
            [
                ka * a * (a * x).cosh(),
                ka * a * (a * x).sinh(),
                kb * b * (b * x).cos(),
                kb * b * (b * x).sin(),
            ]
        };
        let shear = |x: f64| {
            let (d, p) = (dwrow(x), psirow(x));
            [d[0] - p[0], d[1] - p[1], d[2] - p[2], d[3] - p[3]]
        };
        let rows = if clamped {
            [wrow(0.0), psirow(0.0), dpsirow(len), shear(len)]
        } else {
            [dpsirow(0.0), shear(0.0), dpsirow(len), shear(len)]
        };
        det4(rows)
    };
    // Scan up from 0.3 of Euler-Bernoulli's first frequency for a sign change (shear
    // and rotary inertia only lower it).
    let beta_l = if clamped {
        CLAMPED_FREE_BETA_L
    } else {
        FREE_FREE_BETA_L
    };
    let w0 = 2.0 * PI * euler_bernoulli(beta_l, len, t, mat);
    let (mut lo, mut dlo) = (0.3 * w0, det(0.3 * w0));
    let mut hi = lo;
    loop {
        hi *= 1.01;
        let dhi = det(hi);
        if dhi.signum() != dlo.signum() {
            break;
        }
        (lo, dlo) = (hi, dhi);
        if hi > 2.0 * w0 {
            // Not for the beams this is used on; no root where theory puts one.
            return f64::NAN;
        }
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        let dm = det(mid);
        if dm.signum() == dlo.signum() {
            (lo, dlo) = (mid, dm);
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi) / (2.0 * PI)
}

/// The determinant of a 4 x 4 matrix (rows), by cofactors.
fn det4(m: [[f64; 4]; 4]) -> f64 {
    let det3 = |r: [[f64; 3]; 3]| {
        r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
            - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0])
    };
    (0..4)
        .map(|c| {
            let minor: [[f64; 3]; 3] = std::array::from_fn(|i| {
                let cols: Vec<usize> = (0..4).filter(|&k| k != c).collect();
                std::array::from_fn(|j| m[i + 1][cols[j]])
            });
            let sign = if c % 2 == 0 { 1.0 } else { -1.0 };
            sign * m[0][c] * det3(minor)
        })
        .sum()
}
