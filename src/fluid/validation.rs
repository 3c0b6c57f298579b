//! Reference results the fluid is validated against, and the measurements compared with
//! them: the lid-driven cavity's centreline profiles at Re = 100 (Ghia, Ghia and Shin
//! 1982, "High-Re solutions for incompressible flow using the Navier-Stokes equations and
//! a multigrid method", J. Comput. Phys. 48, tables I and II) and the Taylor-Green
//! vortex's kinetic-energy decay, `E(t) = E(0) exp(-4 nu k^2 t)`.

use super::{Fluid, FluidState};

/// Ghia et al. 1982, table I, Re = 100: `(y, u)` along the vertical line `x = 0.5` of the
/// unit cavity, lid speed 1.
pub const GHIA_RE100_U: [(f64, f64); 17] = [
    (1.0000, 1.00000),
    (0.9766, 0.84123),
    (0.9688, 0.78871),
    (0.9609, 0.73722),
    (0.9531, 0.68717),
    (0.8516, 0.23151),
    (0.7344, 0.00332),
    (0.6172, -0.13641),
    (0.5000, -0.20581),
    (0.4531, -0.21090),
    (0.2813, -0.15662),
    (0.1719, -0.10150),
    (0.1016, -0.06434),
    (0.0703, -0.04775),
    (0.0625, -0.04192),
    (0.0547, -0.03717),
    (0.0000, 0.00000),
];

/// Ghia et al. 1982, table II, Re = 100: `(x, v)` along the horizontal line `y = 0.5`.
pub const GHIA_RE100_V: [(f64, f64); 17] = [
    (1.0000, 0.00000),
    (0.9688, -0.05906),
    (0.9609, -0.07391),
    (0.9531, -0.08864),
    (0.9453, -0.10313),
    (0.9063, -0.16914),
    (0.8594, -0.22445),
    (0.8047, -0.24533),
    (0.5000, 0.05454),
    (0.2344, 0.17527),
    (0.2266, 0.17507),
    (0.1563, 0.16077),
    (0.0938, 0.12317),
    (0.0781, 0.10890),
    (0.0703, 0.10091),
    (0.0625, 0.09233),
    (0.0000, 0.00000),
];

/// The centreline profiles of a 2-D cavity on the unit square (`cells` even along x and
/// y): `u` along `x = 0.5` as `(y, u)` and `v` along `y = 0.5` as `(x, v)`, from the faces
/// on those lines, with the wall values at the ends (`u = lid` at the top, 0 elsewhere).
pub fn centerlines(fluid: &Fluid, s: &FluidState, lid: f64) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let d = fluid.desc();
    let [nx, ny, _] = d.cells;
    let h = d.h;
    let mut u = vec![[0.0, 0.0]];
    let i = nx / 2;
    for j in 0..ny {
        // x-face (i, j): at x = i h (0.5 for even nx), y = (j + 1/2) h.
        u.push([(j as f64 + 0.5) * h, s.u[0][i + (nx + 1) * j]]);
    }
    u.push([ny as f64 * h, lid]);
    let mut v = vec![[0.0, 0.0]];
    let j = ny / 2;
    for i in 0..nx {
        v.push([(i as f64 + 0.5) * h, s.u[1][i + nx * j]]);
    }
    v.push([nx as f64 * h, 0.0]);
    (u, v)
}

/// The profile's value at `t` by linear interpolation (sorted by the first coordinate).
pub fn interpolate(profile: &[[f64; 2]], t: f64) -> f64 {
    let k = profile.partition_point(|p| p[0] < t);
    if k == 0 {
        return profile[0][1];
    }
    if k >= profile.len() {
        return profile[profile.len() - 1][1];
    }
    let (a, b) = (profile[k - 1], profile[k]);
    let w = if b[0] > a[0] {
        (t - a[0]) / (b[0] - a[0])
    } else {
        0.0
    };
    a[1] + w * (b[1] - a[1])
}

/// The largest and the root-mean-square difference between a profile and reference points.
pub fn profile_error(profile: &[[f64; 2]], reference: &[(f64, f64)]) -> (f64, f64) {
    let mut max = 0.0f64;
    let mut sq = 0.0;
    for &(t, r) in reference {
        let e = (interpolate(profile, t) - r).abs();
        max = max.max(e);
        sq += e * e;
    }
    (max, (sq / reference.len() as f64).sqrt())
}

/// The effective viscosity of a decaying Taylor-Green vortex from its kinetic energy at
/// the start and after `t` seconds: `-ln(E / E0) / (4 k^2 t)` with `k = 2 pi / L`.
pub fn taylor_green_viscosity(e0: f64, e: f64, t: f64, length: f64) -> f64 {
    let k = 2.0 * std::f64::consts::PI / length;
    -(e / e0).ln() / (4.0 * k * k * t)
}

/// The lid-driven cavity of the benchmark: the unit square in `n x n` cells, no-slip
/// walls, the lid (y = 1) sliding at 1 m/s along x, nu = 0.01 m^2/s (Re = 100).
pub fn cavity(n: usize) -> super::FluidDesc {
    use super::Boundary;
    super::FluidDesc {
        cells: [n, n, 1],
        h: 1.0 / n as f64,
        boundaries: [
            [Boundary::Wall; 2],
            [Boundary::Wall, Boundary::Lid([1.0, 0.0, 0.0])],
            [Boundary::Wall; 2],
        ],
        viscosity: 0.01,
        ..super::FluidDesc::default()
    }
}

/// The Taylor-Green vortex of speed 1 on the square of side 2 pi in `n x n` cells (k = 1)
/// with kinematic viscosity `nu`, its x and y sides all `sides` (periodic or slip).
pub fn taylor_green(n: usize, nu: f64, sides: super::Boundary) -> super::FluidDesc {
    use super::Boundary;
    super::FluidDesc {
        cells: [n, n, 1],
        h: 2.0 * std::f64::consts::PI / n as f64,
        boundaries: [[sides; 2], [sides; 2], [Boundary::Wall; 2]],
        viscosity: nu,
        initial: super::Initial::TaylorGreen { speed: 1.0 },
        ..super::FluidDesc::default()
    }
}
