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
//! ([`Penalty::power`]).

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

/// Which obstacles a [`Penalty`] evaluation meets: the model's own (at rest), or moving
/// ones handed over for the step.
#[derive(Clone, Copy, Debug)]
pub enum Against<'a> {
    /// [`Penalty::obstacles`].
    Own,
    /// Other systems' bodies, with their motion.
    Moving(&'a [MovingObstacle]),
}

impl Penalty {
    /// Calls `f(i, n, g, v_o)` for every vertex i inside an obstacle at signed distance
    /// g < 0 with outward normal n, where the obstacle's material moves at v_o (zero for
    /// the model's own); obstacle by obstacle, vertices in order within each (the order
    /// forces are summed in).
    ///
    /// Planes (the jello's box walls) take their own loop, `n . x + d` with the plane's
    /// constants hoisted: the same value as [`Obstacle::distance`], but a loop the
    /// compiler vectorizes; through the general `distance` (a match and an `Option` per
    /// vertex) the 7 planes of the 32^3 jello made an RK4 step 1.6x slower.
    #[inline]
    fn for_each_contact(
        &self,
        against: Against<'_>,
        x: &[f64],
        mut f: impl FnMut(usize, [f64; 3], f64, [f64; 3]),
    ) {
        let n = x.len() / 3;
        let (xs, ys, zs) = (&x[..n], &x[n..2 * n], &x[2 * n..3 * n]);
        let (own, moving): (&[Obstacle], &[MovingObstacle]) = match against {
            Against::Own => (&self.obstacles, &[]),
            Against::Moving(m) => (&[], m),
        };
        for o in own {
            match o {
                Obstacle::Plane { normal, offset } => {
                    let [a, b, c] = *normal;
                    for i in 0..n {
                        let g = a * xs[i] + b * ys[i] + c * zs[i] + offset;
                        if g < 0.0 {
                            f(i, *normal, g, [0.0; 3]);
                        }
                    }
                }
                _ => {
                    for i in 0..n {
                        if let Some((g, nrm)) = o.distance(get3(x, n, i)) {
                            if g < 0.0 {
                                f(i, nrm, g, [0.0; 3]);
                            }
                        }
                    }
                }
            }
        }
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

    /// Adds the collision springs' forces to `f` (component-major, like `x` and `v`).
    pub fn add_forces(&self, against: Against<'_>, x: &[f64], v: &[f64], f: &mut [f64]) {
        let n = x.len() / 3;
        self.for_each_contact(against, x, |i, nrm, g, vo| {
            let fi = self.force_of(nrm, g, sub(get3(v, n, i), vo));
            for c in 0..3 {
                f[c * n + i] += fi[c];
            }
        });
    }

    /// Adds `-k_c n n^T` (to `dfdx`) and `-d_c n n^T` (to `dfdv`) of every active
    /// contact to its vertex's diagonal block.
    pub fn add_jacobians(
        &self,
        against: Against<'_>,
        x: &[f64],
        dfdx: &mut Bsr3,
        mut dfdv: Option<&mut Bsr3>,
    ) {
        let pattern = dfdx.pattern().clone();
        let diag = pattern.diag_slots();
        let sub_nn = |block: &mut [f64], coef: f64, n: [f64; 3]| {
            for r in 0..3 {
                for c in 0..3 {
                    block[3 * r + c] -= coef * n[r] * n[c];
                }
            }
        };
        self.for_each_contact(against, x, |i, nrm, _, _| {
            let slot = diag[i] as usize;
            sub_nn(dfdx.block_mut(slot), self.stiffness, nrm);
            if let Some(dv) = dfdv.as_deref_mut() {
                sub_nn(dv.block_mut(slot), self.damping, nrm);
            }
        });
    }

    /// The collision springs' potential energy `sum k_c g^2 / 2` (J), moving obstacles at
    /// their present poses.
    pub fn energy(&self, against: Against<'_>, x: &[f64]) -> f64 {
        let mut e = 0.0;
        self.for_each_contact(against, x, |_, _, g, _| e += 0.5 * self.stiffness * g * g);
        e
    }

    /// The collision springs' Rayleigh dissipation `sum d_c ((v - v_o).n)^2` (W).
    pub fn dissipation(&self, against: Against<'_>, x: &[f64], v: &[f64]) -> f64 {
        let n = x.len() / 3;
        let mut p = 0.0;
        self.for_each_contact(against, x, |i, nrm, _, vo| {
            let vn = dot(nrm, sub(get3(v, n, i), vo));
            p += self.damping * vn * vn;
        });
        p
    }

    /// The rate (W) at which the obstacles do work on the model: `sum F . v_o` over their
    /// contacts (what moves the springs' anchors, and the damping's reference); zero for
    /// the model's own, which rest.
    pub fn power(&self, against: Against<'_>, x: &[f64], v: &[f64]) -> f64 {
        let n = x.len() / 3;
        let mut p = 0.0;
        self.for_each_contact(against, x, |i, nrm, g, vo| {
            p += dot(self.force_of(nrm, g, sub(get3(v, n, i), vo)), vo);
        });
        p
    }
}
