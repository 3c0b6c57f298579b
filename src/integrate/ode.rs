//! First-order systems `y' = G(t, y)`.
//!
//! Implicit methods solve `F(y1) = y1 - y0 - h G(t*, (1 - theta) y0 + theta y1) = 0` by
//! Newton's method with a dense Jacobian `I - h theta dG/dy`: backward Euler is
//! `theta = 1, t* = t + h`; the implicit midpoint rule `theta = 1/2, t* = t + h/2`; the
//! linearised backward Euler takes exactly one Newton step from `y1 = y0` with no line
//! search. First-order systems here are small (studies, control): the Jacobian is dense.

use super::explicit::RkWork;
use super::{hint, solve_error, IntegrateError, Method, StepInfo};
use crate::solve::dense::DenseLu;
use crate::solve::newton::rounding_floor;
use crate::solve::{Newton, NewtonParams, NewtonProblem, SolveError, SolveInfo};
use largestep_kernels::vec as kv;

/// A first-order system `y' = G(t, y)`.
pub trait OdeSystem {
    /// Dimension of y.
    fn dim(&self) -> usize;
    /// `dydt = G(t, y)`.
    fn rhs(&mut self, t: f64, y: &[f64], dydt: &mut [f64]);
    /// Dense Jacobian `dG/dy` at `(t, y)`, row-major `dim x dim`, for implicit methods.
    /// Returns `false` if the system does not provide one.
    fn jacobian(&mut self, t: f64, y: &[f64], jac: &mut [f64]) -> bool {
        let _ = (t, y, jac);
        false
    }
}

/// Steps first-order systems with one method; buffers allocated once in [`OdeStepper::new`].
#[derive(Clone, Debug)]
pub struct OdeStepper {
    method: Method,
    dim: usize,
    rk: RkWork,
    newton: Newton,
    lu: DenseLu,
    ymid: Vec<f64>,
    g: Vec<f64>,
    y1: Vec<f64>,
    /// Newton settings for the implicit methods.
    pub newton_params: NewtonParams,
    steps: u64,
}

impl OdeStepper {
    /// A stepper for systems of dimension `dim`.
    pub fn new(method: Method, dim: usize) -> Result<Self, IntegrateError> {
        if !method.supports_first_order() {
            return Err(IntegrateError::Unsupported {
                method,
                reason: "it needs a mechanical system (positions and velocities)",
            });
        }
        let implicit = method.is_implicit();
        let d = if implicit { dim } else { 0 };
        Ok(Self {
            method,
            dim,
            rk: RkWork::new(method, dim),
            newton: Newton::new(d),
            lu: DenseLu::new(d),
            ymid: vec![0.0; d],
            g: vec![0.0; d],
            y1: vec![0.0; d],
            newton_params: NewtonParams::default(),
            steps: 0,
        })
    }

    /// The method.
    pub fn method(&self) -> Method {
        self.method
    }

    /// Steps taken so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Advances `y` from `t` to `t + h`.
    pub fn step(
        &mut self,
        sys: &mut dyn OdeSystem,
        t: f64,
        y: &mut [f64],
        h: f64,
    ) -> Result<StepInfo, IntegrateError> {
        assert_eq!(y.len(), self.dim);
        assert_eq!(sys.dim(), self.dim);
        self.steps += 1;
        let step = self.steps;
        let method = self.method;
        let solve_err = solve_error(step, method, false);
        let mut info = StepInfo::default();
        match method {
            Method::ExplicitEuler | Method::Midpoint | Method::Rk4 => {
                let mut g = |t: f64, y: &[f64], d: &mut [f64]| {
                    sys.rhs(t, y, d);
                    Ok(())
                };
                self.rk.step(method, t, y, h, &mut g)?;
            }
            Method::BackwardEuler | Method::ImplicitMidpoint | Method::LinearizedBackwardEuler => {
                let (theta, t_eval) = if method == Method::ImplicitMidpoint {
                    (0.5, t + 0.5 * h)
                } else {
                    (1.0, t + h)
                };
                self.y1.copy_from_slice(y);
                let mut prob = Implicit {
                    sys,
                    y0: y,
                    h,
                    theta,
                    t_eval,
                    lu: &mut self.lu,
                    ymid: &mut self.ymid,
                    g: &mut self.g,
                    noise: 0.0,
                    missing_jacobian: false,
                };
                let res = if method == Method::LinearizedBackwardEuler {
                    self.newton.single_step(&mut prob, &mut self.y1)
                } else {
                    self.newton
                        .solve(&mut prob, &mut self.y1, &self.newton_params)
                };
                if prob.missing_jacobian {
                    return Err(IntegrateError::Unsupported {
                        method,
                        reason: "the system provides no Jacobian, which implicit methods need",
                    });
                }
                let ni = res.map_err(solve_err)?;
                info.newton_iterations = ni.iterations;
                y.copy_from_slice(&self.y1);
            }
            Method::SymplecticEuler | Method::Newmark => unreachable!("rejected in new"),
        }
        if !kv::all_finite(y) {
            return Err(IntegrateError::NonFinite {
                step,
                field: "state",
                hint: hint(method),
            });
        }
        Ok(info)
    }
}

/// The implicit step equation as a Newton problem in y1.
struct Implicit<'a> {
    sys: &'a mut dyn OdeSystem,
    y0: &'a [f64],
    h: f64,
    theta: f64,
    t_eval: f64,
    lu: &'a mut DenseLu,
    ymid: &'a mut [f64],
    g: &'a mut [f64],
    noise: f64,
    /// Set when the system turns out to provide no Jacobian.
    missing_jacobian: bool,
}

impl Implicit<'_> {
    fn mid(&mut self, y1: &[f64]) {
        for ((m, a), b) in self.ymid.iter_mut().zip(self.y0).zip(y1) {
            *m = (1.0 - self.theta) * a + self.theta * b;
        }
    }
}

impl NewtonProblem for Implicit<'_> {
    fn residual(&mut self, y1: &[f64], r: &mut [f64]) -> Result<(), SolveError> {
        self.mid(y1);
        self.sys.rhs(self.t_eval, self.ymid, self.g);
        let mut scale2 = 0.0;
        for i in 0..r.len() {
            let hg = self.h * self.g[i];
            r[i] = y1[i] - self.y0[i] - hg;
            let size = y1[i].abs() + self.y0[i].abs() + hg.abs();
            scale2 += size * size;
        }
        self.noise = rounding_floor(scale2);
        Ok(())
    }

    fn noise_floor(&self) -> f64 {
        self.noise
    }

    fn newton_step(
        &mut self,
        y1: &[f64],
        r: &[f64],
        dy: &mut [f64],
    ) -> Result<SolveInfo, SolveError> {
        let n = r.len();
        self.mid(y1);
        let jac = self.lu.matrix_mut();
        if !self.sys.jacobian(self.t_eval, self.ymid, jac) {
            self.missing_jacobian = true;
            return Err(SolveError::Factorization("no Jacobian".into()));
        }
        let c = -self.h * self.theta;
        for i in 0..n {
            for j in 0..n {
                jac[i * n + j] *= c;
            }
            jac[i * n + i] += 1.0;
        }
        self.lu.factor()?;
        for (d, v) in dy.iter_mut().zip(r) {
            *d = -v;
        }
        self.lu.solve(dy);
        Ok(SolveInfo::default())
    }
}
