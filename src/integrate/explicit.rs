//! Explicit Runge-Kutta steps shared by first-order and mechanical systems.
//!
//! Forward Euler `y += h k1`; the midpoint rule `y += h G(t + h/2, y + h/2 k1)`; classical
//! RK4 `y += h/6 (k1 + 2 k2 + 2 k3 + k4)`. Buffers are allocated once per method.

use super::{IntegrateError, Method};
use largestep_kernels::vec as kv;

/// Derivative callback: `dydt = G(t, y)`.
pub(crate) type Deriv<'a> = dyn FnMut(f64, &[f64], &mut [f64]) -> Result<(), IntegrateError> + 'a;

/// Stage buffers for one explicit method.
#[derive(Clone, Debug)]
pub(crate) struct RkWork {
    k: Vec<Vec<f64>>,
    yt: Vec<f64>,
}

impl RkWork {
    pub(crate) fn new(method: Method, dim: usize) -> Self {
        let (stages, trial) = match method {
            Method::ExplicitEuler => (1, 0),
            Method::Midpoint => (1, dim),
            Method::Rk4 => (4, dim),
            _ => (0, 0),
        };
        Self {
            k: (0..stages).map(|_| vec![0.0; dim]).collect(),
            yt: vec![0.0; trial],
        }
    }

    /// One step of `method` (ExplicitEuler, Midpoint or Rk4) from `(t, y)`.
    pub(crate) fn step(
        &mut self,
        method: Method,
        t: f64,
        y: &mut [f64],
        h: f64,
        g: &mut Deriv<'_>,
    ) -> Result<(), IntegrateError> {
        let yt = &mut self.yt;
        match method {
            Method::ExplicitEuler => {
                let k1 = &mut self.k[0];
                g(t, y, k1)?;
                kv::axpy(y, h, k1);
            }
            Method::Midpoint => {
                let k1 = &mut self.k[0];
                g(t, y, k1)?;
                kv::waxpy(yt, y, 0.5 * h, k1);
                g(t + 0.5 * h, yt, k1)?;
                kv::axpy(y, h, k1);
            }
            Method::Rk4 => {
                let [k1, k2, k3, k4] = &mut self.k[..] else {
                    unreachable!("RK4 has four stage buffers")
                };
                g(t, y, k1)?;
                kv::waxpy(yt, y, 0.5 * h, k1);
                g(t + 0.5 * h, yt, k2)?;
                kv::waxpy(yt, y, 0.5 * h, k2);
                g(t + 0.5 * h, yt, k3)?;
                kv::waxpy(yt, y, h, k3);
                g(t + h, yt, k4)?;
                kv::axpy(y, h / 6.0, k1);
                kv::axpy(y, h / 3.0, k2);
                kv::axpy(y, h / 3.0, k3);
                kv::axpy(y, h / 6.0, k4);
            }
            _ => unreachable!("not an explicit Runge-Kutta method: {method}"),
        }
        Ok(())
    }
}
