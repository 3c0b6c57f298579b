//! Newton's method with a backtracking line search.
//!
//! Solves `F(y) = 0`: at each iterate the problem supplies the step `dy` with `J dy = -F`
//! (it may reassemble and refactor there), then the step length `alpha` is halved from 1
//! until `|F(y + alpha dy)| <= (1 - c alpha) |F(y)|` (Armijo on the residual norm, c = 1e-4).
//! If no acceptable length above `min_step` exists the method stops with
//! [`SolveError::LineSearchFailed`]: the residual cannot be reduced along the Newton
//! direction, which is what happens when the equation has no real solution (course notes:
//! backward Euler on `y' = 4 y^2`, `y0 = 1`, `h = 1`).
//!
//! When the problem has a merit function whose gradient is F (an incremental potential,
//! see `integrate::MechStepper`), a step is also accepted when it satisfies the Armijo
//! condition on that merit, `phi(y + alpha dy) <= phi(y) + c alpha F.dy` (with `F.dy < 0`).
//! Any symmetric positive definite approximation of the Jacobian gives a descent direction
//! for the merit, so Newton with an approximate (say definiteness-fixed) Jacobian keeps
//! making progress where the residual norm alone would stall (Gast et al. 2015,
//! "Optimization integrator for large time steps").
//!
//! Convergence: `|F| <= max(abs_tolerance, tolerance |F(y0)|)`, or a full step with
//! `|dy| <= step_tolerance (1 + |y|)`.
//!
//! With [`NewtonParams::rate_test`] the step test measures the error left in the new
//! iterate instead of the step just taken (Hairer and Wanner 1996, "Solving ordinary
//! differential equations II", section IV.8, the stopping criterion of RADAU5): Newton
//! contracts the error by `theta_k = |dy_k| / |dy_(k-1)|` an iteration, so the error left
//! after step k is about `eta_k |dy_k|` with `eta_k = theta_k / (1 - theta_k)`, and the
//! iteration stops when a full step has `min(max(eta_k, r_k), 1) |dy_k| <= step_tolerance
//! (1 + |y|)`, where `r_k` is the relative residual the linear solve reached (an inexact
//! step leaves about that fraction of itself undone, whatever the rate). After a linear
//! solve looser than [`RATE_TEST_LINEAR`] the plain test judges the step: the residual is
//! measured in F, and the error it leaves in y can be many times larger.
//! The first step of a solve has no rate of its own: it uses the last rate measured
//! by this workspace, `eta_0 = max(eta_old, eps)^0.8`, which the exponent moves towards 1
//! (towards the plain step test) at every solve that does not measure a new one. A
//! sequence of similar solves (the steps of an implicit integrator) whose Newton
//! iterations contract fast then stops after one step once that step is small enough;
//! a solve that contracts slowly (`theta >= 1`) falls back to the plain test.
//!
//! Inexact Newton ([`NewtonParams::forcing`]): an iterative linear solver need only reduce
//! `|J dy + F|` to `eta_k |F|`. Far from the root a tight linear solve is wasted, since the
//! next residual is set by the nonlinearity (or, with a lagged Jacobian, by its error).
//! The forcing terms follow Eisenstat and Walker's "choice 2" with Kelley's safeguards
//! (Eisenstat and Walker 1996, "Choosing the forcing terms in an inexact Newton method";
//! Kelley 2003, "Solving nonlinear equations with Newton's method", section 3.2.3):
//! `eta_k = 0.9 (|F_k| / |F_(k-1)|)^2`, kept above `0.9 eta_(k-1)^2` when that exceeds 0.1,
//! capped at `eta_max`, and never below `0.5 target / |F_k|`, so the last step is not
//! solved tighter than the tolerance needs. With the rate test and `eta_max` at most
//! [`RATE_TEST_LINEAR`] the forcing term does not follow Eisenstat and Walker: the test
//! stops on the contraction it measures, and a fixed forcing term still contracts the
//! error by about `eta_max` an iteration (Dembo, Eisenstat and Steihaug 1982, "Inexact
//! Newton methods"), which a loose step tolerance does not need sharpened; tightening the
//! second linear solve tenfold or more (choice 2 after a tenfold fall in |F|) only made
//! the two-iteration steps dearer. A solve's first step gets `eta_max`; a later one,
//! expected to be `theta` times the step before, gets what leaves an error of half the
//! step tolerance in it, `0.5 tol / (theta |dy_prev|)`, within `eta_max` and
//! [`RATE_TEST_LATER_FORCING`] (Kelley's safeguard measured in the step).

use super::{SolveError, SolveInfo};
use largestep_kernels::vec as kv;

/// The loosest linear solve (relative residual) after which the rate test judges a step
/// ([`NewtonParams::rate_test`]).
pub const RATE_TEST_LINEAR: f64 = 0.1;

/// Residual norm below which rounding dominates, for a residual whose entries each sum
/// terms of total size `size_i`, given `sum_sq = sum_i size_i^2`: a few eps per entry.
pub fn rounding_floor(sum_sq: f64) -> f64 {
    16.0 * f64::EPSILON * sum_sq.sqrt()
}

/// Newton settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NewtonParams {
    /// Iteration limit.
    pub max_iterations: usize,
    /// Residual reduction to reach, relative to the initial residual.
    pub tolerance: f64,
    /// Residual norm that counts as converged whatever the initial one.
    pub abs_tolerance: f64,
    /// Relative step length that counts as converged.
    pub step_tolerance: f64,
    /// Smallest line-search step length tried.
    pub min_step: f64,
    /// Inexact Newton: `Some(eta_max)` sets the linear solver's relative tolerance each
    /// iteration from the nonlinear convergence (see the module docs), at most `eta_max`;
    /// `None` keeps the linear solver's own tolerance. Direct solvers ignore it.
    pub forcing: Option<f64>,
    /// Judge a full step by the error it leaves, estimated from the contraction rate
    /// (Hairer and Wanner's test, see the module docs), instead of by its own length.
    /// Never stricter than the plain step test. Off by default. It pays with inexact
    /// Newton only where `forcing` is at most [`RATE_TEST_LINEAR`] (0.1), since looser
    /// solves get the plain test. Without that bound, on the beam of issue 15
    /// (`benches/fem.rs`, backward Euler, Newton to 1e-3, the second-order predictor,
    /// errors against steps solved to 1e-10, worst of 120 steps) steps at `forcing` 0.5
    /// whose first linear solve stopped at a relative residual of 0.3-0.5 were accepted
    /// with velocity errors up to 3.5e-3. With it: 2.8e-4 at `forcing` 0.5 (2.0 Newton
    /// iterations a step), 2.5e-4 at 0.1 (1.3); the plain test at 0.5: 2.4e-4 (2.1).
    /// With it a `forcing` of at most [`RATE_TEST_LINEAR`] is held at its bound for a
    /// solve's first step instead of following Eisenstat and Walker (module docs): on the
    /// same beam at 0.1, 4.4 PCG iterations a step instead of 4.8, the same 1.3 Newton
    /// iterations, worst error 2.6e-4 instead of 2.5e-4; later steps solved only as
    /// tightly as their expected length needs (`later_forcing`): 3.9 PCG iterations a
    /// step, the same Newton iterations, worst error 4.1e-4.
    pub rate_test: bool,
    /// With the rate test: a full step that the test accepts from its length and the
    /// contraction rate alone is taken without evaluating the residual at its end, so
    /// without a line search on it (RADAU5's simplified Newton does not evaluate F at the
    /// iterate it accepts either; Hairer and Wanner 1996, section IV.8). Only where Newton
    /// contracts fast (`theta` below 1/2, measured in this solve or carried from the last);
    /// a step the test does not accept, or one it would judge without such a rate, is
    /// checked as usual. [`NewtonInfo::residual`] is then the residual at the start of
    /// that last step. Saves one residual evaluation a solve (one force evaluation a time
    /// step for the implicit integrators). Off by default. Without the rate guard, soft
    /// tissue at dt = 1/10 on the swinging 20x2x2 cantilever (`tests/fem.rs`) ended 0.10
    /// from steps solved to 1e-9 against 0.026 with the check; with it, the same steps.
    pub skip_last_residual: bool,
}

impl Default for NewtonParams {
    fn default() -> Self {
        Self {
            max_iterations: 50,
            tolerance: 1e-10,
            abs_tolerance: 1e-300,
            step_tolerance: 1e-13,
            min_step: 1.0 / 1024.0,
            forcing: None,
            rate_test: false,
            skip_last_residual: false,
        }
    }
}

/// What Newton's method reports.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NewtonInfo {
    /// Newton iterations (steps taken).
    pub iterations: usize,
    /// Linear-solver iterations summed over the steps.
    pub linear_iterations: usize,
    /// Final residual norm `|F|`.
    pub residual: f64,
}

/// A nonlinear system for [`Newton`].
pub trait NewtonProblem {
    /// `r = F(y)`.
    fn residual(&mut self, y: &[f64], r: &mut [f64]) -> Result<(), SolveError>;
    /// Solves `J(y) dy = -r` for `dy`, where `r = F(y)`.
    fn newton_step(
        &mut self,
        y: &[f64],
        r: &[f64],
        dy: &mut [f64],
    ) -> Result<SolveInfo, SolveError>;
    /// Residual norm below which rounding dominates at the last evaluated point (0 if
    /// unknown): reaching it counts as converged.
    fn noise_floor(&self) -> f64 {
        0.0
    }
    /// The relative tolerance `eta` of the next linear solve, `|J dy + F| <= eta |F|`
    /// (inexact Newton, [`NewtonParams::forcing`]); ignored by direct solvers.
    fn set_linear_tolerance(&mut self, eta: f64) {
        let _ = eta;
    }
    /// A merit function whose gradient is F, if the problem has one.
    fn merit(&mut self, y: &[f64]) -> Option<f64> {
        let _ = y;
        None
    }
}

/// Eisenstat and Walker's choice 2 with Kelley's safeguards (see the module docs): the
/// forcing term for residual norm `fnorm`, after `last` = the previous iteration's norm
/// and forcing term (none on the first), for a Newton target norm `target`.
fn forcing_term(eta_max: f64, last: Option<(f64, f64)>, fnorm: f64, target: f64) -> f64 {
    const GAMMA: f64 = 0.9;
    let eta = match last {
        None => eta_max,
        Some((prev, eta_prev)) => {
            let a = GAMMA * (fnorm / prev).powi(2);
            let safeguard = GAMMA * eta_prev * eta_prev;
            if safeguard > 0.1 {
                a.max(safeguard)
            } else {
                a
            }
        }
    };
    eta.max(0.5 * target / fnorm).min(eta_max)
}

/// The loosest linear solve of a later step under the rate test ([`later_forcing`]).
pub const RATE_TEST_LATER_FORCING: f64 = 0.5;

/// The forcing term of a step under the rate test, given `eta_max` (at most
/// [`RATE_TEST_LINEAR`]), the error factor in hand `eta` (`theta / (1 - theta)`), the
/// length of the full step before it in this solve (none for a solve's first step) and
/// the step tolerance `tol` (absolute). A solve's first step gets `eta_max`, which the
/// rate test needs to judge it. A later one is expected to be `theta` times the step
/// before; the test judges it by its length (the plain test, after a solve looser than
/// [`RATE_TEST_LINEAR`]), and its linear solve need only leave an error in it of half the
/// tolerance: `0.5 tol / (theta |dy_prev|)`, kept within `eta_max` and
/// [`RATE_TEST_LATER_FORCING`] (Kelley's safeguard, section 3.2.3 of "Solving nonlinear
/// equations with Newton's method", 2003, measured in the step instead of the residual).
fn later_forcing(eta_max: f64, eta: f64, last_step: Option<f64>, tol: f64) -> f64 {
    let Some(prev) = last_step else {
        return eta_max;
    };
    let loosest = RATE_TEST_LATER_FORCING.max(eta_max);
    let expected = eta / (1.0 + eta) * prev;
    if expected > 0.0 {
        (0.5 * tol / expected).clamp(eta_max, loosest)
    } else {
        loosest
    }
}

/// The rate test's error factor for a full step of length `step` after a linear solve
/// that reached the relative residual `linear` (see [`NewtonParams::rate_test`]), and
/// the new contraction factor `theta / (1 - theta)` if the step measures one (there was
/// a full step of length `last_step` before it); `eta` is the factor in hand.
fn rate_factor(eta: f64, last_step: Option<f64>, step: f64, linear: f64) -> (f64, Option<f64>) {
    let rate = last_step.filter(|&p| p > 0.0).map(|prev| {
        let theta = step / prev;
        if theta < 1.0 {
            theta / (1.0 - theta)
        } else {
            1.0
        }
    });
    // An inexact linear solve leaves about its own relative residual of the step undone,
    // whatever the rate, and after a loose one the error in y may be many times that (the
    // residual is measured in F): then the plain test (factor 1).
    let factor = if linear <= RATE_TEST_LINEAR {
        rate.unwrap_or(eta).max(linear).min(1.0)
    } else {
        1.0
    };
    (factor, rate)
}

/// Newton workspace for systems of a given dimension (allocated once).
#[derive(Clone, Debug)]
pub struct Newton {
    r: Vec<f64>,
    rt: Vec<f64>,
    yt: Vec<f64>,
    dy: Vec<f64>,
    /// The last contraction factor `eta = theta / (1 - theta)` measured by a solve
    /// ([`NewtonParams::rate_test`]); none before the first.
    eta_old: Option<f64>,
}

impl Newton {
    /// Workspace for `dim` unknowns.
    pub fn new(dim: usize) -> Self {
        Self {
            r: vec![0.0; dim],
            rt: vec![0.0; dim],
            yt: vec![0.0; dim],
            dy: vec![0.0; dim],
            eta_old: None,
        }
    }

    /// One full Newton step `y += dy`, `J dy = -F(y)`, with no line search and no
    /// convergence test (a linearly implicit method). Reports the residual before the step.
    pub fn single_step(
        &mut self,
        problem: &mut dyn NewtonProblem,
        y: &mut [f64],
    ) -> Result<NewtonInfo, SolveError> {
        assert_eq!(y.len(), self.r.len());
        problem.residual(y, &mut self.r)?;
        let lin = problem.newton_step(y, &self.r, &mut self.dy)?;
        kv::axpy(y, 1.0, &self.dy);
        Ok(NewtonInfo {
            iterations: 1,
            linear_iterations: lin.iterations,
            residual: kv::norm2(&self.r),
        })
    }

    /// Solves `F(y) = 0` from the initial guess in `y`; the root is left in `y`.
    pub fn solve(
        &mut self,
        problem: &mut dyn NewtonProblem,
        y: &mut [f64],
        params: &NewtonParams,
    ) -> Result<NewtonInfo, SolveError> {
        assert_eq!(y.len(), self.r.len());
        problem.residual(y, &mut self.r)?;
        let mut fnorm = kv::norm2(&self.r);
        if !fnorm.is_finite() {
            return Err(SolveError::NonFinite {
                what: "Newton residual",
                iteration: 0,
            });
        }
        let rel_target = params.abs_tolerance.max(params.tolerance * fnorm);
        let target = |p: &dyn NewtonProblem| rel_target.max(p.noise_floor());
        let mut info = NewtonInfo {
            residual: fnorm,
            ..Default::default()
        };
        // The previous residual norm and forcing term (inexact Newton).
        let mut last: Option<(f64, f64)> = None;
        // The error factor of the first full step (rate test): the last rate measured,
        // moved towards 1 (Hairer and Wanner's `FACCON = max(FACCON, eps)^0.8`), and
        // stored so, so that solves which measure no rate of their own compound it.
        let mut eta = 1.0;
        if params.rate_test {
            if let Some(old) = self.eta_old {
                eta = old.max(f64::EPSILON).powf(0.8).min(1.0);
                self.eta_old = Some(eta);
            }
        }
        // The length of the last full step, for the next contraction rate.
        let mut last_step: Option<f64> = None;
        for it in 1..=params.max_iterations {
            if fnorm <= target(problem) {
                return Ok(info);
            }
            if let Some(eta_max) = params.forcing {
                // The rate test measures the contraction it gets, so it needs no
                // tightening towards a quadratic rate: the linear tolerance stays at
                // eta_max for a solve's first step, and later ones are solved only as
                // tightly as their expected length needs (see `NewtonParams::rate_test`).
                // A looser bound would leave every step to the plain test, at a
                // contraction of eta_max.
                let eta = if params.rate_test && eta_max <= RATE_TEST_LINEAR {
                    let tol = params.step_tolerance * (1.0 + kv::norm2(y));
                    later_forcing(eta_max, eta, last_step, tol)
                } else {
                    forcing_term(eta_max, last, fnorm, target(problem))
                };
                problem.set_linear_tolerance(eta);
                last = Some((fnorm, eta));
            }
            let lin = problem.newton_step(y, &self.r, &mut self.dy)?;
            info.linear_iterations += lin.iterations;
            if !kv::all_finite(&self.dy) {
                return Err(SolveError::NonFinite {
                    what: "Newton step",
                    iteration: it,
                });
            }
            // The full step's length and, under the rate test, its error factor and the
            // rate it measures: the same whether the step is judged before its residual
            // is evaluated (skip_last_residual) or after the line search takes it whole.
            let full = kv::norm2(&self.dy);
            let (full_factor, full_rate) = if params.rate_test {
                rate_factor(eta, last_step, full, lin.residual)
            } else {
                (1.0, None)
            };
            let within = |factor: f64, step: f64, y: &[f64]| {
                factor * step <= params.step_tolerance * (1.0 + kv::norm2(y))
            };
            // Only where Newton contracts fast (theta below 1/2, measured in this solve or
            // carried): where it does not, the line search's check stays.
            if params.rate_test && params.skip_last_residual && full_rate.unwrap_or(eta) < 1.0 {
                kv::waxpy(&mut self.yt, y, 1.0, &self.dy);
                if within(full_factor, full, &self.yt) {
                    if let Some(rate) = full_rate {
                        self.eta_old = Some(rate);
                    }
                    y.copy_from_slice(&self.yt);
                    info.iterations = it;
                    return Ok(info);
                }
            }
            let slope = kv::dot(&self.r, &self.dy);
            // The merit at y, computed only if some trial fails the residual test.
            let mut merit0: Option<Option<f64>> = None;
            let mut alpha = 1.0;
            loop {
                kv::waxpy(&mut self.yt, y, alpha, &self.dy);
                problem.residual(&self.yt, &mut self.rt)?;
                let trial = kv::norm2(&self.rt);
                let mut ok = trial.is_finite() && trial <= (1.0 - 1e-4 * alpha) * fnorm;
                if !ok && trial.is_finite() && slope < 0.0 {
                    let m0 = *merit0.get_or_insert_with(|| problem.merit(y));
                    ok = m0.is_some_and(|m0| {
                        problem
                            .merit(&self.yt)
                            .is_some_and(|m| m <= m0 + 1e-4 * alpha * slope)
                    });
                }
                if ok {
                    fnorm = trial;
                    break;
                }
                alpha *= 0.5;
                if alpha < params.min_step {
                    // Close to the rounding floor a decrease may be impossible: converged.
                    if fnorm <= 1e3 * problem.noise_floor() {
                        return Ok(info);
                    }
                    return Err(SolveError::LineSearchFailed {
                        iteration: it,
                        residual: fnorm,
                    });
                }
            }
            y.copy_from_slice(&self.yt);
            std::mem::swap(&mut self.r, &mut self.rt);
            info.iterations = it;
            info.residual = fnorm;
            let step = alpha * full;
            if params.rate_test {
                if alpha == 1.0 {
                    if let Some(rate) = full_rate {
                        eta = rate;
                        self.eta_old = Some(rate);
                    }
                    last_step = Some(step);
                } else {
                    // A shortened step says nothing of the rate of full ones.
                    last_step = None;
                }
            }
            // The error the step test judges is `full_factor` times the step (1 without
            // the rate test).
            if fnorm <= target(problem) || (alpha == 1.0 && within(full_factor, step, y)) {
                return Ok(info);
            }
        }
        Err(SolveError::NotConverged {
            iterations: params.max_iterations,
            residual: fnorm,
            tolerance: rel_target,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::{
        forcing_term, later_forcing, Newton, NewtonParams, NewtonProblem, RATE_TEST_LATER_FORCING,
        RATE_TEST_LINEAR,
    };
    use crate::solve::{SolveError, SolveInfo};

    /// `F(y) = y - b` solved with the approximate inverse `c I`: Newton contracts the
    /// error by exactly `1 - c` an iteration, and the linear solve reports the relative
    /// residual `linear`.
    struct Damped {
        b: Vec<f64>,
        c: f64,
        linear: f64,
        /// Each linear tolerance Newton set, in order.
        tolerances: Vec<f64>,
        /// Residual evaluations.
        residuals: usize,
    }

    impl NewtonProblem for Damped {
        fn set_linear_tolerance(&mut self, eta: f64) {
            self.tolerances.push(eta);
        }
        fn residual(&mut self, y: &[f64], r: &mut [f64]) -> Result<(), SolveError> {
            self.residuals += 1;
            for ((r, y), b) in r.iter_mut().zip(y).zip(&self.b) {
                *r = y - b;
            }
            Ok(())
        }
        fn newton_step(
            &mut self,
            _y: &[f64],
            r: &[f64],
            dy: &mut [f64],
        ) -> Result<SolveInfo, SolveError> {
            for (d, r) in dy.iter_mut().zip(r) {
                *d = -self.c * r;
            }
            Ok(SolveInfo {
                iterations: 1,
                residual: self.linear,
                seconds: 0.0,
            })
        }
    }

    /// Solves from `y0`; the iterations and the error left, `|y - b| / (1 + |y|)`.
    fn solve(newton: &mut Newton, p: &mut Damped, y0: &[f64], rate: bool) -> (usize, f64) {
        let params = NewtonParams {
            tolerance: 1e-30,
            step_tolerance: 1e-6,
            rate_test: rate,
            ..NewtonParams::default()
        };
        let mut y = y0.to_vec();
        let info = newton.solve(p, &mut y, &params).unwrap();
        let err = y
            .iter()
            .zip(&p.b)
            .map(|(y, b)| (y - b).powi(2))
            .sum::<f64>();
        let norm = y.iter().map(|y| y * y).sum::<f64>().sqrt();
        (info.iterations, err.sqrt() / (1.0 + norm))
    }

    /// Hairer and Wanner's test stops once the error left, `theta / (1 - theta)` of the
    /// step, is within the tolerance; the plain test waits for the step itself. Both
    /// leave an error within the tolerance; a solve after a measured rate stops sooner
    /// still; a linear solve looser than `RATE_TEST_LINEAR` falls back to the plain test.
    #[test]
    fn the_rate_test_stops_on_the_error_left() {
        let b = vec![3.0, -4.0, 12.0];
        let y0 = [0.0; 3];
        // Contraction 0.05 an iteration: steps 0.95 e, error after the step 0.05 e.
        let mut p = Damped {
            b: b.clone(),
            c: 0.95,
            linear: 1e-3,
            tolerances: Vec::new(),
            residuals: 0,
        };
        let (plain_its, plain_err) = solve(&mut Newton::new(3), &mut p, &y0, false);
        let mut rate = Newton::new(3);
        let (rate_its, rate_err) = solve(&mut rate, &mut p, &y0, true);
        assert!(
            plain_err <= 1e-6 && rate_err <= 1e-6,
            "{plain_err} {rate_err}"
        );
        assert!(
            rate_its < plain_its,
            "rate test {rate_its} iterations, plain {plain_its}"
        );
        // Every error is 0.05 of the one before: the estimate is close to exact.
        assert!(rate_err > 0.01e-6, "the rate test stopped late: {rate_err}");
        // The next solve from nearby starts with the measured rate (0.0526^0.8 = 0.095):
        // its first step, 6.1e-5, is above 1e-6 (1 + |y|) = 1.4e-5, but 0.095 of it is
        // not (the error left: 3.2e-6). One iteration.
        let near = [3.0 + 5e-5, -4.0 - 4e-5, 12.0];
        let (its, err) = solve(&mut rate, &mut p, &near, true);
        assert_eq!(its, 1);
        assert!(err <= 1e-6, "{err}");
        let (its, _) = solve(&mut Newton::new(3), &mut p, &near, true);
        assert!(its > 1, "no rate measured yet: the plain test");
        // A loose linear solve: the plain test, iteration for iteration.
        p.linear = 2.0 * RATE_TEST_LINEAR;
        let (loose_its, loose_err) = solve(&mut Newton::new(3), &mut p, &y0, true);
        assert_eq!(loose_its, plain_its);
        assert!(loose_err <= 1e-6);
        // Slow contraction (0.6, eta > 1): the plain test too.
        p.linear = 1e-3;
        p.c = 0.4;
        let (slow_plain, _) = solve(&mut Newton::new(3), &mut p, &y0, false);
        let (slow_rate, _) = solve(&mut Newton::new(3), &mut p, &y0, true);
        assert_eq!(slow_rate, slow_plain);
    }

    /// `skip_last_residual` takes the same steps to the same bits, with one residual
    /// evaluation fewer a solve: the step the rate test accepts is not evaluated.
    #[test]
    fn skipping_the_last_residual_saves_one_evaluation_and_nothing_else() {
        let run = |skip: bool| {
            let mut p = Damped {
                b: vec![3.0, -4.0, 12.0],
                c: 0.95,
                linear: 1e-3,
                tolerances: Vec::new(),
                residuals: 0,
            };
            let params = NewtonParams {
                tolerance: 1e-30,
                step_tolerance: 1e-6,
                rate_test: true,
                skip_last_residual: skip,
                ..NewtonParams::default()
            };
            let mut newton = Newton::new(3);
            let mut out = Vec::new();
            // A solve from afar (the rate measured on the way), then one from nearby
            // (accepted after one step on the rate carried over).
            for y0 in [[0.0; 3], [3.0 + 5e-5, -4.0 - 4e-5, 12.0]] {
                let mut y = y0.to_vec();
                p.residuals = 0;
                let info = newton.solve(&mut p, &mut y, &params).unwrap();
                out.push((info.iterations, y, p.residuals));
            }
            out
        };
        let (checked, skipped) = (run(false), run(true));
        for ((its, y, evals), (its_s, y_s, evals_s)) in checked.iter().zip(&skipped) {
            assert_eq!(its, its_s);
            assert_eq!(y, y_s, "the same bits");
            assert_eq!(
                *evals,
                its + 1,
                "checked: one residual a step, plus the first"
            );
            assert_eq!(*evals_s, *evals - 1);
        }
        assert_eq!(skipped[1].0, 1);
    }

    /// Plain inexact Newton tightens the linear tolerance as |F| falls (Eisenstat and
    /// Walker); with the rate test the first is eta_max and none is tighter, unless
    /// eta_max is looser than the rate test accepts (then the tightening is what brings
    /// the rate test in).
    #[test]
    fn the_rate_test_holds_the_forcing_term_at_its_bound() {
        let run = |rate: bool, eta_max: f64| {
            let mut p = Damped {
                b: vec![3.0, -4.0, 12.0],
                c: 0.9,
                linear: 0.05,
                tolerances: Vec::new(),
                residuals: 0,
            };
            let params = NewtonParams {
                tolerance: 1e-30,
                step_tolerance: 1e-6,
                forcing: Some(eta_max),
                rate_test: rate,
                ..NewtonParams::default()
            };
            let mut y = vec![0.0; 3];
            Newton::new(3).solve(&mut p, &mut y, &params).unwrap();
            p.tolerances
        };
        let plain = run(false, 0.1);
        assert!(
            plain.len() > 2 && plain[0] == 0.1 && plain[1] < 0.05,
            "{plain:?}"
        );
        let rate = run(true, 0.1);
        assert!(
            rate.len() > 1 && rate[0] == 0.1 && rate.iter().all(|&t| (0.1..=0.5).contains(&t)),
            "{rate:?}"
        );
        let loose = run(true, 0.5);
        assert!(loose.len() > 1 && loose[1] < 0.5, "{loose:?}");
    }

    /// Under the rate test a later step's linear solve leaves an error of half the
    /// tolerance in the step expected (theta times the last one), within eta_max and
    /// `RATE_TEST_LATER_FORCING`; a solve's first step gets eta_max.
    #[test]
    fn later_steps_are_solved_as_tightly_as_their_expected_length_needs() {
        let eta = 1.0 / 9.0; // theta = 0.1
        assert_eq!(later_forcing(0.1, eta, None, 1.0), 0.1);
        // Expected step 2: half the tolerance is 0.25 of it.
        assert!((later_forcing(0.1, eta, Some(20.0), 1.0) - 0.25).abs() < 1e-12);
        // Expected step 10: 0.05, kept at eta_max.
        assert_eq!(later_forcing(0.1, eta, Some(100.0), 1.0), 0.1);
        // Expected step 0.1: 5, kept at the loosest.
        assert_eq!(
            later_forcing(0.1, eta, Some(1.0), 1.0),
            RATE_TEST_LATER_FORCING
        );
        assert_eq!(
            later_forcing(0.1, eta, Some(0.0), 1.0),
            RATE_TEST_LATER_FORCING
        );
    }

    #[test]
    fn forcing_terms_follow_eisenstat_walker_with_kelleys_safeguards() {
        // First iteration: eta_max.
        assert_eq!(forcing_term(0.5, None, 1.0, 1e-9), 0.5);
        // Residual fell tenfold: 0.9 * 0.01, the safeguard 0.9 * 0.25 = 0.225 > 0.1 wins.
        assert!((forcing_term(0.5, Some((10.0, 0.5)), 1.0, 1e-9) - 0.225).abs() < 1e-15);
        // With a small previous term the safeguard is off: 0.9 * 0.01.
        assert!((forcing_term(0.5, Some((10.0, 0.1)), 1.0, 1e-9) - 0.009).abs() < 1e-15);
        // Slow progress is capped at eta_max.
        assert_eq!(forcing_term(0.5, Some((1.1, 0.1)), 1.0, 1e-9), 0.5);
        // Near the target the linear solve need not go past half of it.
        assert!((forcing_term(0.5, Some((1e3, 0.1)), 1.0, 0.1) - 0.05).abs() < 1e-15);
    }
}
