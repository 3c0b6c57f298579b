//! Six-degree-of-freedom haptic rendering of a rigid tool against a distance field, after
//! Barbič and James 2008: the tool is a **point shell** (points on its surface, in its
//! own frame), the environment a signed-distance grid; every shell point below the
//! surface (`phi < 0`) is pushed out by a penalty spring `-k_c phi grad(phi)`.
//!
//! The tool is coupled to the device pose by a six-DoF virtual coupling (a translational
//! spring `k_t` and a rotational one `k_r`). Each tick solves for the tool pose where the
//! coupling and the contact springs balance (quasi-static virtual coupling): Gauss-Newton
//! on `1/2 k_t |x - x_d|^2 + 1/2 k_r |theta|^2 + sum 1/2 k_c phi_i^2` over the pose, a
//! 6 x 6 solve per iteration, from the last tick's pose. The user feels the coupling: the
//! force `k_t (x - x_d)` and torque `k_r theta` (theta: the rotation from the device's
//! orientation to the tool's).

use crate::collide::SdfGrid;
use crate::kernels::interp::sample3_grad;
use crate::kernels::quat::{
    conj, exp as quat_exp, log as quat_log, mul as quat_mul, rotate, Quat, IDENTITY,
};
use crate::kernels::v3::{add, cross, dot, length_and_unit, scale};
use nalgebra::{Matrix6, Vector6};
use std::sync::Arc;

/// Gauss-Newton iterations per tick at most.
const ITERATIONS: usize = 8;

/// What one tick of [`SixDof::tick`] gives the user.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wrench {
    /// Force (N).
    pub force: [f64; 3],
    /// Torque (N m).
    pub torque: [f64; 3],
    /// Shell points in contact at the solved pose.
    pub contacts: usize,
}

/// A rigid point-shell tool against a distance field (see the module docs).
#[derive(Clone, Debug)]
pub struct SixDof {
    shell: Vec<[f64; 3]>,
    env: Arc<SdfGrid>,
    position: [f64; 3],
    orientation: Quat,
    /// Translational coupling stiffness (N/m).
    pub k_translation: f64,
    /// Rotational coupling stiffness (N m/rad).
    pub k_rotation: f64,
    /// Contact stiffness per shell point (N/m).
    pub k_contact: f64,
}

impl SixDof {
    /// A tool of shell points `shell` (m, in the tool's frame) against `env`, with the
    /// coupling and contact stiffnesses (each > 0), at the identity pose at the origin.
    pub fn new(
        shell: Vec<[f64; 3]>,
        env: Arc<SdfGrid>,
        k_translation: f64,
        k_rotation: f64,
        k_contact: f64,
    ) -> Result<SixDof, String> {
        if shell.is_empty() {
            return Err("the point shell has no points".into());
        }
        if let Some((i, p)) = shell
            .iter()
            .enumerate()
            .find(|(_, p)| !p.iter().all(|c| c.is_finite()))
        {
            return Err(format!("shell point {i} = {p:?} is not finite"));
        }
        for (name, k) in [
            ("k_translation", k_translation),
            ("k_rotation", k_rotation),
            ("k_contact", k_contact),
        ] {
            if k.is_nan() || k <= 0.0 || k.is_infinite() {
                return Err(format!("{name} = {k}: must be finite and > 0"));
            }
        }
        Ok(SixDof {
            shell,
            env,
            position: [0.0; 3],
            orientation: IDENTITY,
            k_translation,
            k_rotation,
            k_contact,
        })
    }

    /// Places the tool at a pose.
    pub fn reset(&mut self, position: [f64; 3], orientation: Quat) {
        self.position = position;
        self.orientation = orientation;
    }

    /// The tool's pose.
    pub fn pose(&self) -> ([f64; 3], Quat) {
        (self.position, self.orientation)
    }

    /// The deepest penetration of a shell point at the current pose (m, >= 0).
    pub fn penetration(&self) -> f64 {
        self.shell
            .iter()
            .filter_map(|s| {
                let p = add(self.position, rotate(self.orientation, *s));
                self.env
                    .grid
                    .contains(p)
                    .then(|| sample3_grad(&self.env.phi, self.env.grid, p).0)
            })
            .fold(0.0, |m: f64, phi| m.max(-phi))
    }

    /// One tick with the device at `position` and `orientation`: solves the tool's pose
    /// and returns the coupling wrench on the user. A non-finite device pose changes
    /// nothing and gives no wrench.
    pub fn tick(&mut self, position: [f64; 3], orientation: Quat) -> Wrench {
        if !position.iter().chain(&orientation).all(|c| c.is_finite()) {
            return Wrench {
                force: [0.0; 3],
                torque: [0.0; 3],
                contacts: 0,
            };
        }
        let mut contacts = 0;
        for _ in 0..ITERATIONS {
            let mut h = Matrix6::<f64>::zeros();
            let mut g = Vector6::<f64>::zeros();
            for a in 0..3 {
                h[(a, a)] += self.k_translation;
                h[(a + 3, a + 3)] += self.k_rotation;
                g[a] += self.k_translation * (self.position[a] - position[a]);
            }
            let theta = quat_log(quat_mul(self.orientation, conj(orientation)));
            for a in 0..3 {
                g[a + 3] += self.k_rotation * theta[a];
            }
            contacts = 0;
            for s in &self.shell {
                let r = rotate(self.orientation, *s);
                let p = add(self.position, r);
                if !self.env.grid.contains(p) {
                    continue;
                }
                let (phi, grad) = sample3_grad(&self.env.phi, self.env.grid, p);
                if phi >= 0.0 {
                    continue;
                }
                let Some((_, n)) = length_and_unit(grad) else {
                    continue;
                };
                contacts += 1;
                let rn = cross(r, n);
                let j = Vector6::new(n[0], n[1], n[2], rn[0], rn[1], rn[2]);
                h += self.k_contact * j * j.transpose();
                g += self.k_contact * phi * j;
            }
            let Some(ch) = h.cholesky() else { break };
            let d = ch.solve(&(-g));
            self.position = add(self.position, [d[0], d[1], d[2]]);
            let q = quat_mul(quat_exp([d[3], d[4], d[5]]), self.orientation);
            let l = dot([q[1], q[2], q[3]], [q[1], q[2], q[3]]) + q[0] * q[0];
            self.orientation = q.map(|c| c / l.sqrt());
            if d.norm() < 1e-12 {
                break;
            }
        }
        let theta = quat_log(quat_mul(self.orientation, conj(orientation)));
        Wrench {
            force: [0, 1, 2].map(|a| self.k_translation * (self.position[a] - position[a])),
            torque: scale(theta, self.k_rotation),
            contacts,
        }
    }
}
