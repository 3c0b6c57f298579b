//! Penalty contacts (course notes, section 4): a vertex inside an obstacle gets a
//! collision spring of rest length zero from its projection on the surface, along the
//! surface normal n: with the signed distance g (< 0 when penetrating),
//! `F = -k_c g n - d_c (v.n) n`, active only while `g < 0`. Its Jacobians are
//! `dF/dx = -k_c n n^T` and `dF/dv = -d_c n n^T`: exact for planes, and for curved
//! obstacles without the curvature term `-k_c g dn/dx`, which is small at shallow
//! penetration and could make the stiffness indefinite. Its potential `k_c g^2 / 2` enters
//! the energy and `d_c (v.n)^2` the dissipation.

use super::Obstacle;
use crate::sparse::Bsr3;
use largestep_kernels::get3;
use largestep_kernels::v3::dot;

/// Penalty contacts against obstacles.
#[derive(Clone, Debug, PartialEq)]
pub struct Penalty {
    /// The obstacles.
    pub obstacles: Vec<Obstacle>,
    /// Collision spring stiffness k_c (N/m), >= 0.
    pub stiffness: f64,
    /// Collision spring damping d_c (N s/m), >= 0.
    pub damping: f64,
}

impl Penalty {
    /// Calls `f(i, n, g)` for every vertex i inside an obstacle at signed distance g < 0
    /// with outward normal n, obstacle by obstacle, vertices in order within each (the
    /// order forces are summed in).
    ///
    /// Planes (the jello's box walls) take their own loop, `n . x + d` with the plane's
    /// constants hoisted: the same value as [`Obstacle::distance`], but a loop the
    /// compiler vectorizes; through the general `distance` (a match and an `Option` per
    /// vertex) the 7 planes of the 32^3 jello made an RK4 step 1.6x slower.
    #[inline]
    fn for_each_contact(&self, x: &[f64], mut f: impl FnMut(usize, [f64; 3], f64)) {
        let n = x.len() / 3;
        let (xs, ys, zs) = (&x[..n], &x[n..2 * n], &x[2 * n..3 * n]);
        for o in &self.obstacles {
            match o {
                Obstacle::Plane { normal, offset } => {
                    let [a, b, c] = *normal;
                    for i in 0..n {
                        let g = a * xs[i] + b * ys[i] + c * zs[i] + offset;
                        if g < 0.0 {
                            f(i, *normal, g);
                        }
                    }
                }
                _ => {
                    for i in 0..n {
                        if let Some((g, nrm)) = o.distance(get3(x, n, i)) {
                            if g < 0.0 {
                                f(i, nrm, g);
                            }
                        }
                    }
                }
            }
        }
    }

    /// Adds the collision springs' forces to `f` (component-major, like `x` and `v`).
    pub fn add_forces(&self, x: &[f64], v: &[f64], f: &mut [f64]) {
        let n = x.len() / 3;
        let (k, d) = (self.stiffness, self.damping);
        self.for_each_contact(x, |i, nrm, g| {
            let vn = dot(nrm, get3(v, n, i));
            let mag = -k * g - d * vn;
            for c in 0..3 {
                f[c * n + i] += mag * nrm[c];
            }
        });
    }

    /// Adds `-k_c n n^T` (to `dfdx`) and `-d_c n n^T` (to `dfdv`) of every active
    /// contact to its vertex's diagonal block.
    pub fn add_jacobians(&self, x: &[f64], dfdx: &mut Bsr3, mut dfdv: Option<&mut Bsr3>) {
        let (k, d) = (self.stiffness, self.damping);
        let pattern = dfdx.pattern().clone();
        let diag = pattern.diag_slots();
        // Adds -coef n n^T to a 3x3 block.
        let sub_nn = |block: &mut [f64], coef: f64, n: [f64; 3]| {
            for r in 0..3 {
                for c in 0..3 {
                    block[3 * r + c] -= coef * n[r] * n[c];
                }
            }
        };
        self.for_each_contact(x, |i, nrm, _| {
            let slot = diag[i] as usize;
            sub_nn(dfdx.block_mut(slot), k, nrm);
            if let Some(dv) = dfdv.as_deref_mut() {
                sub_nn(dv.block_mut(slot), d, nrm);
            }
        });
    }

    /// The collision springs' potential energy `sum k_c g^2 / 2` (J).
    pub fn energy(&self, x: &[f64]) -> f64 {
        let mut e = 0.0;
        self.for_each_contact(x, |_, _, g| e += 0.5 * self.stiffness * g * g);
        e
    }

    /// The collision springs' Rayleigh dissipation `sum d_c (v.n)^2` (W).
    pub fn dissipation(&self, x: &[f64], v: &[f64]) -> f64 {
        let n = x.len() / 3;
        let mut p = 0.0;
        self.for_each_contact(x, |i, nrm, _| {
            let vn = dot(nrm, get3(v, n, i));
            p += self.damping * vn * vn;
        });
        p
    }
}
