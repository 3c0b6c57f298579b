//! Penalty contacts (course notes, section 4): a vertex inside an obstacle gets a
//! collision spring of rest length zero from its projection on the surface, along the
//! surface normal n: with the signed distance g (< 0 when penetrating),
//! `F = -k_c g n - d_c (v.n) n`, active only while `g < 0`. Its Jacobians are
//! `dF/dx = -k_c n n^T` and `dF/dv = -d_c n n^T`: exact for planes, and for curved
//! obstacles without the curvature term `-k_c g dn/dx`, which is small at shallow
//! penetration and could make the stiffness indefinite. Its potential `k_c g^2 / 2` enters
//! the energy and `d_c (v.n)^2` the dissipation.
//!
//! Moving obstacles ([`MovingObstacle`], rigid bodies handed over each step, one-way) take
//! the same law with the vertex's velocity relative to the obstacle's material there,
//! `F = -k_c g n - d_c ((v - v_o).n) n`; their pose is held for the step, so the springs
//! keep a potential within it. They do work on the model at the rate `sum F . v_o`
//! ([`Penalty::moving_power`]).

use super::{MovingObstacle, Obstacle};
use crate::sparse::Bsr3;
use largestep_kernels::get3;
use largestep_kernels::v3::{dot, sub};

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
        self.for_each_contact(x, |i, nrm, g| {
            let fi = self.force_of(nrm, g, get3(v, n, i));
            for c in 0..3 {
                f[c * n + i] += fi[c];
            }
        });
    }

    /// Adds `-k_c n n^T` (to `dfdx`) and `-d_c n n^T` (to `dfdv`) of every active
    /// contact to its vertex's diagonal block.
    pub fn add_jacobians(&self, x: &[f64], dfdx: &mut Bsr3, mut dfdv: Option<&mut Bsr3>) {
        let diag = dfdx.pattern().clone();
        let diag = diag.diag_slots();
        self.for_each_contact(x, |i, nrm, _| {
            self.sub_nn(diag[i] as usize, nrm, dfdx, dfdv.as_deref_mut());
        });
    }

    /// Adds `-k_c n n^T` to block `slot` of dfdx and `-d_c n n^T` to that of dfdv.
    fn sub_nn(&self, slot: usize, n: [f64; 3], dfdx: &mut Bsr3, dfdv: Option<&mut Bsr3>) {
        let sub = |block: &mut [f64], coef: f64| {
            for r in 0..3 {
                for c in 0..3 {
                    block[3 * r + c] -= coef * n[r] * n[c];
                }
            }
        };
        sub(dfdx.block_mut(slot), self.stiffness);
        if let Some(dv) = dfdv {
            sub(dv.block_mut(slot), self.damping);
        }
    }

    /// Calls `f(i, n, g, v_o)` for every vertex i inside a moving obstacle at signed
    /// distance g < 0 with outward normal n, where the obstacle's material moves at v_o;
    /// obstacle by obstacle, vertices in order.
    fn for_each_moving_contact(
        moving: &[MovingObstacle],
        x: &[f64],
        mut f: impl FnMut(usize, [f64; 3], f64, [f64; 3]),
    ) {
        let n = x.len() / 3;
        for o in moving {
            for i in 0..n {
                let p = get3(x, n, i);
                if let Some((g, nrm)) = o.shape.distance(p) {
                    if g < 0.0 {
                        f(i, nrm, g, o.velocity_at(p));
                    }
                }
            }
        }
    }

    /// The contact force (N) of a vertex at depth g < 0, normal n, moving at v relative
    /// to the surface.
    #[inline]
    fn force_of(&self, nrm: [f64; 3], g: f64, v_rel: [f64; 3]) -> [f64; 3] {
        let mag = -self.stiffness * g - self.damping * dot(nrm, v_rel);
        nrm.map(|c| mag * c)
    }

    /// Adds the collision springs of the moving obstacles to `f`.
    pub fn add_moving_forces(
        &self,
        moving: &[MovingObstacle],
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
    ) {
        let n = x.len() / 3;
        Self::for_each_moving_contact(moving, x, |i, nrm, g, vo| {
            let fi = self.force_of(nrm, g, sub(get3(v, n, i), vo));
            for c in 0..3 {
                f[c * n + i] += fi[c];
            }
        });
    }

    /// [`Penalty::add_jacobians`] for the moving obstacles.
    pub fn add_moving_jacobians(
        &self,
        moving: &[MovingObstacle],
        x: &[f64],
        dfdx: &mut Bsr3,
        mut dfdv: Option<&mut Bsr3>,
    ) {
        let diag = dfdx.pattern().clone();
        let diag = diag.diag_slots();
        Self::for_each_moving_contact(moving, x, |i, nrm, _, _| {
            self.sub_nn(diag[i] as usize, nrm, dfdx, dfdv.as_deref_mut());
        });
    }

    /// The moving obstacles' collision springs' potential energy `sum k_c g^2 / 2` (J),
    /// at their present poses.
    pub fn moving_energy(&self, moving: &[MovingObstacle], x: &[f64]) -> f64 {
        let mut e = 0.0;
        Self::for_each_moving_contact(moving, x, |_, _, g, _| e += 0.5 * self.stiffness * g * g);
        e
    }

    /// The moving obstacles' contact dissipation `sum d_c ((v - v_o).n)^2` (W).
    pub fn moving_dissipation(&self, moving: &[MovingObstacle], x: &[f64], v: &[f64]) -> f64 {
        let n = x.len() / 3;
        let mut p = 0.0;
        Self::for_each_moving_contact(moving, x, |i, nrm, _, vo| {
            let vn = dot(nrm, sub(get3(v, n, i), vo));
            p += self.damping * vn * vn;
        });
        p
    }

    /// The rate (W) at which the moving obstacles do work on the model: `sum F . v_o` over
    /// their contacts (what moves the springs' anchors, and the damping's reference).
    pub fn moving_power(&self, moving: &[MovingObstacle], x: &[f64], v: &[f64]) -> f64 {
        let n = x.len() / 3;
        let mut p = 0.0;
        Self::for_each_moving_contact(moving, x, |i, nrm, g, vo| {
            p += dot(self.force_of(nrm, g, sub(get3(v, n, i), vo)), vo);
        });
        p
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
