//! Model problems with exact solutions, for validating and studying integrators: the
//! integrator study's problem set, and the fixtures of `tests/integrate.rs`, which includes
//! this file by path (so it names the crate `largestep` and allows items one of the two
//! does not use). Not public API.
//!
//! The mechanical ones are one-vertex [`Mechanical`] systems that move along x only (the
//! y and z components stay at zero), with unit mass; their Jacobians are exact.
//!
//! - [`Oscillator`]: `x'' = -w^2 x - 2 zeta w x' + w^2 forcing cos(t)`, exact solution in
//!   closed form (under-, critically and over-damped).
//! - [`Pendulum`]: `theta'' = -(g/L) sin theta`, no elementary closed form: references come
//!   from a converged run.
//! - [`StiffScalar`]: `y' = -lambda (y - cos t)`, a first-order stiff ODE with exact solution
//!   `y = A cos t + B sin t + (y0 - A) e^(-lambda t)`, `A = lambda^2/(1+lambda^2)`,
//!   `B = lambda/(1+lambda^2)`.
//! - [`Quadratic`]: `y' = c y^2` (the course notes' sample problem, c = 4).

#![allow(dead_code)]

use largestep::integrate::{IntegrateError, Mechanical, OdeSystem};
use largestep::sparse::{Bsr3, Bsr3Pattern, SparseError};
use std::sync::Arc;

/// The damped, optionally driven, harmonic oscillator of unit mass (see the module docs).
#[derive(Clone, Debug)]
pub struct Oscillator {
    /// Natural angular frequency w (rad/s).
    pub omega: f64,
    /// Damping ratio zeta (0: undamped, 1: critical).
    pub zeta: f64,
    /// Amplitude of the drive `w^2 forcing cos t` relative to the stiffness (0: free).
    pub forcing: f64,
    mass: [f64; 1],
    pattern: Arc<Bsr3Pattern>,
}

impl Oscillator {
    /// An oscillator with the given frequency, damping ratio and drive.
    pub fn new(omega: f64, zeta: f64, forcing: f64) -> Self {
        Self {
            omega,
            zeta,
            forcing,
            mass: [1.0],
            pattern: Arc::new(Bsr3Pattern::diagonal(1)),
        }
    }

    /// Energy `1/2 (v^2 + w^2 x^2)` of the x motion.
    pub fn energy(&self, x: f64, v: f64) -> f64 {
        0.5 * (v * v + self.omega * self.omega * x * x)
    }

    fn particular(&self) -> (f64, f64) {
        // x_p = A cos t + B sin t solves the driven equation.
        let (w2, c) = (self.omega * self.omega, 2.0 * self.zeta * self.omega);
        let f = self.forcing * w2;
        let den = (w2 - 1.0).powi(2) + c * c;
        ((w2 - 1.0) * f / den, c * f / den)
    }

    /// Exact `(x(t), v(t))` from `(x0, v0)` at time 0.
    pub fn exact(&self, x0: f64, v0: f64, t: f64) -> (f64, f64) {
        let (w, z) = (self.omega, self.zeta);
        let (a, b) = self.particular();
        let (xp, vp) = (a * t.cos() + b * t.sin(), -a * t.sin() + b * t.cos());
        // Homogeneous part with x_h(0) = x0 - A, x_h'(0) = v0 - B.
        let (p, q) = (x0 - a, v0 - b);
        let (xh, vh) = if z < 1.0 {
            let wd = w * (1.0 - z * z).sqrt();
            let e = (-z * w * t).exp();
            let (s, c) = (wd * t).sin_cos();
            let k = (q + z * w * p) / wd;
            let x = e * (p * c + k * s);
            let v = e * (-z * w * (p * c + k * s) + (-p * wd * s + k * wd * c));
            (x, v)
        } else if z == 1.0 {
            let e = (-w * t).exp();
            let c2 = q + w * p;
            (e * (p + c2 * t), e * (c2 - w * (p + c2 * t)))
        } else {
            let s = (z * z - 1.0).sqrt();
            let (r1, r2) = (-w * (z - s), -w * (z + s));
            let c1 = (q - r2 * p) / (r1 - r2);
            let c2 = p - c1;
            let (e1, e2) = ((r1 * t).exp(), (r2 * t).exp());
            (c1 * e1 + c2 * e2, c1 * r1 * e1 + c2 * r2 * e2)
        };
        (xh + xp, vh + vp)
    }
}

impl Mechanical for Oscillator {
    fn vertex_count(&self) -> usize {
        1
    }
    fn mass(&self) -> &[f64] {
        &self.mass
    }
    fn force(&mut self, t: f64, x: &[f64], v: &[f64], f: &mut [f64]) {
        let (w2, c) = (self.omega * self.omega, 2.0 * self.zeta * self.omega);
        for k in 0..3 {
            f[k] = -w2 * x[k] - c * v[k];
        }
        f[0] += w2 * self.forcing * t.cos();
    }
    fn potential_energy(&self, t: f64, x: &[f64]) -> Option<f64> {
        let w2 = self.omega * self.omega;
        Some(
            0.5 * w2 * (x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
                - w2 * self.forcing * t.cos() * x[0],
        )
    }
    fn dissipation(&self, _x: &[f64], v: &[f64]) -> f64 {
        self.zeta * self.omega * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    }
    fn prepare_jacobians(&mut self) -> Result<Option<Arc<Bsr3Pattern>>, SparseError> {
        Ok(Some(self.pattern.clone()))
    }
    fn has_velocity_jacobian(&self) -> bool {
        self.zeta != 0.0
    }
    fn force_jacobians(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut Bsr3,
        dfdv: Option<&mut Bsr3>,
    ) -> Result<(), IntegrateError> {
        self.force(t, x, v, f);
        let (w2, c) = (self.omega * self.omega, 2.0 * self.zeta * self.omega);
        dfdx.values_mut()
            .copy_from_slice(&[-w2, 0.0, 0.0, 0.0, -w2, 0.0, 0.0, 0.0, -w2]);
        if let Some(d) = dfdv {
            d.values_mut()
                .copy_from_slice(&[-c, 0.0, 0.0, 0.0, -c, 0.0, 0.0, 0.0, -c]);
        }
        Ok(())
    }
}

/// The nonlinear pendulum `theta'' = -(g/L) sin theta`, theta in the x component.
#[derive(Clone, Debug)]
pub struct Pendulum {
    /// g / L (1/s^2).
    pub g_over_l: f64,
    mass: [f64; 1],
    pattern: Arc<Bsr3Pattern>,
}

impl Pendulum {
    /// A pendulum with `g / L`.
    pub fn new(g_over_l: f64) -> Self {
        Self {
            g_over_l,
            mass: [1.0],
            pattern: Arc::new(Bsr3Pattern::diagonal(1)),
        }
    }

    /// Energy per unit `m L^2`: `1/2 theta'^2 + (g/L)(1 - cos theta)`.
    pub fn energy(&self, theta: f64, omega: f64) -> f64 {
        0.5 * omega * omega + self.g_over_l * (1.0 - theta.cos())
    }
}

impl Mechanical for Pendulum {
    fn vertex_count(&self) -> usize {
        1
    }
    fn mass(&self) -> &[f64] {
        &self.mass
    }
    fn force(&mut self, _t: f64, x: &[f64], _v: &[f64], f: &mut [f64]) {
        f.fill(0.0);
        f[0] = -self.g_over_l * x[0].sin();
    }
    fn potential_energy(&self, _t: f64, x: &[f64]) -> Option<f64> {
        Some(self.g_over_l * (1.0 - x[0].cos()))
    }
    fn prepare_jacobians(&mut self) -> Result<Option<Arc<Bsr3Pattern>>, SparseError> {
        Ok(Some(self.pattern.clone()))
    }
    fn force_jacobians(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut Bsr3,
        _dfdv: Option<&mut Bsr3>,
    ) -> Result<(), IntegrateError> {
        self.force(t, x, v, f);
        let k = -self.g_over_l * x[0].cos();
        dfdx.values_mut()
            .copy_from_slice(&[k, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        Ok(())
    }
}

/// `y' = -lambda (y - cos t)` (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct StiffScalar {
    /// Stiffness lambda (1/s), > 0.
    pub lambda: f64,
}

impl StiffScalar {
    /// Exact y(t) from y(0) = y0.
    pub fn exact(&self, y0: f64, t: f64) -> f64 {
        let l = self.lambda;
        let a = l * l / (1.0 + l * l);
        let b = l / (1.0 + l * l);
        a * t.cos() + b * t.sin() + (y0 - a) * (-l * t).exp()
    }
}

impl OdeSystem for StiffScalar {
    fn dim(&self) -> usize {
        1
    }
    fn rhs(&mut self, t: f64, y: &[f64], dydt: &mut [f64]) {
        dydt[0] = -self.lambda * (y[0] - t.cos());
    }
    fn jacobian(&mut self, _t: f64, _y: &[f64], jac: &mut [f64]) -> bool {
        jac[0] = -self.lambda;
        true
    }
}

/// `y' = c y^2` (the course notes' sample with c = 4); exact `y = y0 / (1 - c y0 t)`.
#[derive(Clone, Copy, Debug)]
pub struct Quadratic {
    /// The coefficient c.
    pub c: f64,
}

impl OdeSystem for Quadratic {
    fn dim(&self) -> usize {
        1
    }
    fn rhs(&mut self, _t: f64, y: &[f64], dydt: &mut [f64]) {
        dydt[0] = self.c * y[0] * y[0];
    }
    fn jacobian(&mut self, _t: f64, y: &[f64], jac: &mut [f64]) -> bool {
        jac[0] = 2.0 * self.c * y[0];
        true
    }
}
