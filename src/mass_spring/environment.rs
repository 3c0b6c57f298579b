//! What surrounds a mass-spring system: an external force field sampled on a grid, and
//! penalty collisions with half-spaces (the walls of a bounding box, inclined planes).
//!
//! Course notes, section 4: the field force at a particle is the trilinear interpolation
//! of the grid values around it (`kernels::interp`); a particle behind a surface gets a
//! collision spring of rest length zero along the surface normal n, from its projection
//! on the surface: with the signed distance `g = n.x + d` (< 0 when penetrating),
//! `F = -k_c g n - d_c (v.n) n`, active only while `g < 0`. Its Jacobians are
//! `dF/dx = -k_c n n^T` and `dF/dv = -d_c n n^T` (the contact point does not move), and
//! its potential `k_c g^2 / 2` enters the energy.

use crate::sparse::Bsr3;
use largestep_kernels::interp::{sample3_vec_add, Grid3};

/// An external force field (N per particle) on a regular grid of nodes, x fastest: node
/// (i, j, k) at `i + nx (j + ny k)`; clamped to the grid's boundary values outside it.
#[derive(Clone, Debug, PartialEq)]
pub struct ForceField {
    /// The grid.
    pub grid: Grid3,
    /// Force components at the nodes (N).
    pub force: [Vec<f64>; 3],
}

impl ForceField {
    /// Adds the field's force at every particle to `f` (component-major, like `x`).
    pub fn add_forces(&self, x: &[f64], f: &mut [f64]) {
        sample3_vec_add(
            f,
            [&self.force[0], &self.force[1], &self.force[2]],
            self.grid,
            x,
            1.0,
        );
    }
}

/// A half-space `n.x + d >= 0` that particles must stay in (unit normal n).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfSpace {
    /// Unit normal, pointing into the allowed side.
    pub normal: [f64; 3],
    /// Offset (m).
    pub offset: f64,
}

impl HalfSpace {
    /// The half-space `a x + b y + c z + d >= 0`, normalised; `None` for a zero or
    /// non-finite normal.
    pub fn from_plane(p: [f64; 4]) -> Option<HalfSpace> {
        let len = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        (len > 0.0 && len.is_finite() && p[3].is_finite()).then(|| HalfSpace {
            normal: [p[0] / len, p[1] / len, p[2] / len],
            offset: p[3] / len,
        })
    }

    /// The six inward-facing walls of the box `[lo, hi]`.
    pub fn box_walls(lo: [f64; 3], hi: [f64; 3]) -> [HalfSpace; 6] {
        std::array::from_fn(|w| {
            let axis = w / 2;
            let mut normal = [0.0; 3];
            if w % 2 == 0 {
                normal[axis] = 1.0;
                HalfSpace {
                    normal,
                    offset: -lo[axis],
                }
            } else {
                normal[axis] = -1.0;
                HalfSpace {
                    normal,
                    offset: hi[axis],
                }
            }
        })
    }

    /// Signed distance of `p` (m), negative behind the surface.
    #[inline]
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        self.normal[0] * p[0] + self.normal[1] * p[1] + self.normal[2] * p[2] + self.offset
    }
}

/// Penalty collisions against half-spaces.
#[derive(Clone, Debug, PartialEq)]
pub struct Penalty {
    /// The surfaces.
    pub surfaces: Vec<HalfSpace>,
    /// Collision spring stiffness k_c (N/m), >= 0.
    pub stiffness: f64,
    /// Collision spring damping d_c (N s/m), >= 0.
    pub damping: f64,
}

impl Penalty {
    /// Calls `f(i, s, g)` for every particle i behind surface s at signed distance g < 0.
    #[inline]
    fn for_each_contact(&self, x: &[f64], mut f: impl FnMut(usize, &HalfSpace, f64)) {
        let n = x.len() / 3;
        for s in &self.surfaces {
            for i in 0..n {
                let g = s.distance(largestep_kernels::get3(x, n, i));
                if g < 0.0 {
                    f(i, s, g);
                }
            }
        }
    }

    /// Adds the collision springs' forces to `f`.
    pub fn add_forces(&self, x: &[f64], v: &[f64], f: &mut [f64]) {
        let n = x.len() / 3;
        let (k, d) = (self.stiffness, self.damping);
        self.for_each_contact(x, |i, s, g| {
            let vn = dot(s.normal, largestep_kernels::get3(v, n, i));
            let mag = -k * g - d * vn;
            for c in 0..3 {
                f[c * n + i] += mag * s.normal[c];
            }
        });
    }

    /// Adds `-k_c n n^T` (to `dfdx`) and `-d_c n n^T` (to `dfdv`) of every active
    /// contact to the particle's diagonal block.
    pub fn add_jacobians(&self, x: &[f64], dfdx: &mut Bsr3, mut dfdv: Option<&mut Bsr3>) {
        let (k, d) = (self.stiffness, self.damping);
        let diag = dfdx.pattern().clone();
        let diag = diag.diag_slots();
        // Adds -coef n n^T to a 3x3 block.
        let sub_nn = |block: &mut [f64], coef: f64, n: [f64; 3]| {
            for r in 0..3 {
                for c in 0..3 {
                    block[3 * r + c] -= coef * n[r] * n[c];
                }
            }
        };
        self.for_each_contact(x, |i, s, _| {
            let slot = diag[i] as usize;
            sub_nn(dfdx.block_mut(slot), k, s.normal);
            if let Some(dv) = dfdv.as_deref_mut() {
                sub_nn(dv.block_mut(slot), d, s.normal);
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
        self.for_each_contact(x, |i, s, _| {
            let vn = dot(s.normal, largestep_kernels::get3(v, n, i));
            p += self.damping * vn * vn;
        });
        p
    }

    /// The deepest penetration (m, >= 0) over all particles and surfaces.
    pub fn max_penetration(&self, x: &[f64]) -> f64 {
        let mut worst = 0.0f64;
        self.for_each_contact(x, |_, _, g| worst = worst.max(-g));
        worst
    }
}

use largestep_kernels::v3::dot;
