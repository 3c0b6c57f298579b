//! Mechanical systems `M x'' = f(t, x, v)` with a lumped (diagonal) mass matrix.
//!
//! Explicit Runge-Kutta methods run on the first-order form `y = [x; v]`,
//! `y' = [v; M^-1 f]`; symplectic Euler updates `v` with the old force, then `x` with the
//! new `v`. Constraints ([`Filter`]) are applied to velocities and accelerations.
//!
//! The three Newton-solved implicit methods share one residual in the unknown end
//! velocity `v1`:
//!
//! ```text
//! x* = x0 + h (a v0 + b v1),   v* = c v0 + d v1,
//! R(v1) = M (v1 - v0) - h (w0 f(t, x0, v0) + w1 f(t*, x*, v*))
//! dR/dv1 = M - h w1 (h b K + d D),     K = df/dx, D = df/dv at (x*, v*)
//! ```
//!
//! | method | a | b | c | d | w0 | w1 | t* | x1 |
//! |---|---|---|---|---|---|---|---|---|
//! | backward Euler | 0 | 1 | 0 | 1 | 0 | 1 | t + h | x0 + h v1 |
//! | implicit midpoint | 1/4 | 1/4 | 1/2 | 1/2 | 0 | 1 | t + h/2 | x0 + h (v0 + v1)/2 |
//! | Newmark (1/4, 1/2) | 1/2 | 1/2 | 0 | 1 | 1/2 | 1/2 | t + h | x0 + h (v0 + v1)/2 |
//!
//! (Newmark's `x1 = x0 + h v0 + h^2/4 (a0 + a1)`, `v1 = v0 + h/2 (a0 + a1)` give exactly
//! this.) The linearised backward Euler of Baraff and Witkin (1998, eq. 16) solves
//! `(M - h D - h^2 K) dv = h (f0 + h K v0)` once with K, D, f0 at `(x0, v0)`; it is one
//! Newton step of backward Euler in `(x, v)` from `(x0, v0)`.
//! Forces are evaluated at time `t + h` in the linearised step, as in one Newton step of
//! backward Euler.
//!
//! `R` is the gradient in `v1` of the incremental potential
//! `phi(v1) = 1/2 |v1 - v0|_M^2 - h w0 f0 . v1 + (w1 / b) U(t*, x*) + (h w1 / d) Psi(x*, v*)`
//! (U the potential, Psi the Rayleigh dissipation; exact up to the positions' influence
//! on the damping forces), which Newton's line search uses as its merit when the system
//! provides U.

use super::explicit::RkWork;
use super::{hint, solve_error, IntegrateError, Method, StepInfo};
use crate::solve::newton::rounding_floor;
use crate::solve::{
    Filter, Newton, NewtonParams, NewtonProblem, Pcg, PcgParams, SolveError, SolveInfo,
    SparseCholesky,
};
use crate::sparse::{Bsr3, Bsr3Pattern, SparseError};
use largestep_kernels::vec as kv;
use std::sync::Arc;

/// A mechanical system with lumped masses; positions and velocities are component-major
/// Vec3s data of its n vertices (3n values each).
pub trait Mechanical {
    /// Number of vertices n.
    fn vertex_count(&self) -> usize;
    /// Mass per vertex (kg), length n: > 0, or 0 for vertices the filter pins.
    fn mass(&self) -> &[f64];
    /// A consistent (non-diagonal) mass matrix over the Jacobian pattern, when the system
    /// uses one: implicit steps then use it in place of `mass` in their systems and
    /// residuals (contacts and explicit methods keep the lumped masses; explicit methods
    /// refuse it). Its row sums should be `mass`.
    fn mass_matrix(&self) -> Option<&Bsr3> {
        None
    }
    /// Writes the current constraints on vertex velocities (pinned vertices, planes,
    /// lines) into `filter`, which the stepper owns and clears before every step. Called
    /// before every step, so constraints may change (contacts); the default adds none.
    fn constraints(&self, filter: &mut Filter) {
        let _ = filter;
    }
    /// A norm (N) of the force terms that cancel in the net force at rest (elastic
    /// stresses times element areas): the net force rounds to a few eps times this, even
    /// where it should be zero, and Newton cannot reduce a residual below that.
    fn force_rounding(&self) -> f64 {
        0.0
    }
    /// `f = total force` (N) at time t, positions x (m) and velocities v (m/s).
    fn force(&mut self, t: f64, x: &[f64], v: &[f64], f: &mut [f64]);
    /// Potential energy (J) at time t and positions x, if the non-damping forces have one
    /// (`f_elastic = -dU/dx`). It serves energy reports and, with
    /// [`Mechanical::dissipation`], the line search of Newton-solved implicit steps.
    fn potential_energy(&self, t: f64, x: &[f64]) -> Option<f64> {
        let _ = (t, x);
        None
    }
    /// Rayleigh dissipation function `Psi` (W) of the damping forces, `f_damping =
    /// -dPsi/dv` at fixed x; 0 for undamped systems.
    fn dissipation(&self, x: &[f64], v: &[f64]) -> f64 {
        let _ = (x, v);
        0.0
    }
    /// Prepares Jacobian assembly (element maps, buffers) and returns the block pattern of
    /// `df/dx` and `df/dv`; `None` if the system provides no Jacobians (then only explicit
    /// methods run). Called once, by implicit steppers only, so explicit runs build nothing.
    fn prepare_jacobians(&mut self) -> Result<Option<Arc<Bsr3Pattern>>, SparseError> {
        Ok(None)
    }
    /// Whether `df/dv` can be non-zero (damping); if not, no damping matrix is built.
    fn has_velocity_jacobian(&self) -> bool {
        false
    }
    /// `f = force`, `dfdx = df/dx`, and `dfdv = df/dv` when asked, over the pattern of
    /// [`Mechanical::prepare_jacobians`] (values overwritten).
    fn force_jacobians(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut Bsr3,
        dfdv: Option<&mut Bsr3>,
    ) -> Result<(), IntegrateError> {
        let _ = (t, x, v, f, dfdx, dfdv);
        Err(IntegrateError::Unsupported {
            method: Method::BackwardEuler,
            reason: "the system provides no Jacobians",
        })
    }
    /// `f = force` and, in place of `df/dx`, an implicit step's matrix `a = diag(d) - ck
    /// df/dx` (`d_i I` on each diagonal block) written by the assembly in one pass, bit
    /// for bit what [`Mechanical::force_jacobians`] and the combination after give, where
    /// the system can. A system with a `df/dv` or a consistent mass matrix must decline,
    /// as must one that cannot (the default): `Ok(false)`, having done nothing, and the
    /// stepper then assembles `df/dx` and combines it.
    #[allow(clippy::too_many_arguments)]
    fn force_system(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        a: &mut Bsr3,
        ck: f64,
        d: &[f64],
    ) -> Result<bool, IntegrateError> {
        let _ = (t, x, v, f, a, ck, d);
        Ok(false)
    }
}

/// Positions and velocities (m, m/s) of a mechanical system's vertices.
#[derive(Clone, Debug, PartialEq)]
pub struct MechState {
    /// Positions (m).
    pub x: crate::soa::Vec3s,
    /// Velocities (m/s).
    pub v: crate::soa::Vec3s,
}

/// Kinetic energy `1/2 sum m |v|^2` (J).
pub fn kinetic_energy(mass: &[f64], v: &[f64]) -> f64 {
    let n = mass.len();
    assert_eq!(v.len(), 3 * n);
    (0..n)
        .map(|i| 0.5 * mass[i] * (v[i] * v[i] + v[n + i] * v[n + i] + v[2 * n + i] * v[2 * n + i]))
        .sum()
}

/// Writes the uniform-gravity force `f_i = m_i g` (N) of every vertex into `f`.
pub fn gravity_forces(mass: &[f64], g: [f64; 3], f: &mut [f64]) {
    let n = mass.len();
    assert_eq!(f.len(), 3 * n);
    for (c, gc) in g.iter().enumerate() {
        for (fi, m) in f[c * n..(c + 1) * n].iter_mut().zip(mass) {
            *fi = m * gc;
        }
    }
}

/// Gravitational potential energy `-sum m_i g . x_i` (J).
pub fn gravity_energy(mass: &[f64], g: [f64; 3], x: &[f64]) -> f64 {
    let n = mass.len();
    assert_eq!(x.len(), 3 * n);
    (0..n)
        .map(|i| -mass[i] * (g[0] * x[i] + g[1] * x[n + i] + g[2] * x[2 * n + i]))
        .sum()
}

/// Which linear solver implicit steps use.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LinearSolverKind {
    /// Preconditioned conjugate gradients (with the constraint filter inside).
    Pcg(PcgParams),
    /// Sparse Cholesky (constraints by projecting the system).
    Cholesky,
    /// Cholesky up to [`AUTO_CHOLESKY_MAX_DOFS`] unknowns, PCG with these settings above.
    Auto(PcgParams),
}

/// Largest system (unknowns) for which [`LinearSolverKind::Auto`] picks Cholesky: beyond
/// it, the fill of 3-D problems makes PCG faster per solve.
pub const AUTO_CHOLESKY_MAX_DOFS: usize = 30_000;

/// Settings of a [`MechStepper`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MechSettings {
    /// The method.
    pub method: Method,
    /// Linear solver for implicit methods.
    pub linear: LinearSolverKind,
    /// Newton settings for the Newton-solved implicit methods.
    pub newton: NewtonParams,
    /// How many steps one assembled and factored Jacobian may serve (the chord method):
    /// 0, full Newton (a new Jacobian every iteration, the default); 1, one per step,
    /// reused by the step's later iterations; k > 1, reused by up to k steps while the
    /// step size and the constraints' directions stay the same (a step that fails with an
    /// old one is redone with a new one). Each reusing iteration costs a force evaluation
    /// and a solve with the factor in hand instead of an assembly and a factorization;
    /// convergence is linear instead of quadratic, and every iterate is still checked
    /// against the same residual and tolerance, so steps converge to the same accuracy.
    /// It pays where the factorization dominates (large 3-D meshes, a direct solver).
    pub reuse_jacobian: usize,
    /// How many steps one multigrid hierarchy of PCG may serve (Newton-solved methods):
    /// 0, a new one for every new Jacobian (the default); k > 0, the coarse levels built
    /// for one step are kept by up to k later steps while the step size and the
    /// constraints' directions stay the same, and only the fine level's diagonal is
    /// taken from each new Jacobian ([`crate::solve::Pcg::resolve`]). Any fixed symmetric
    /// positive definite preconditioner leaves PCG exact, so the steps converge as
    /// before, perhaps in more iterations; a step whose solve fails with a kept hierarchy
    /// is redone with a new one, and a step after one whose PCG iterations per Newton
    /// iteration grew well past those of the step that made the hierarchy makes a new one
    /// (as the body turns, the rotations the coarse levels were built
    /// with fall behind). It pays where the setup is a large part of a step (smoothed
    /// aggregation on 3-D elasticity).
    pub reuse_preconditioner: usize,
    /// Whether PCG's products read the multigrid's `f32` copy of the system matrix
    /// ([`crate::solve::Pcg::set_rounded_products`]) in the Newton-solved methods
    /// (backward Euler, implicit midpoint, Newmark): their solves give only Newton's
    /// step directions, each checked against the residual in `f64`, so a matrix rounded
    /// by a relative 6e-8 costs little accuracy where A is well conditioned, and an
    /// iteration moves half the matrix's bytes. On the 60,000-tetrahedron beam of issue 15
    /// (`benches/fem.rs`, E = 10 MPa, nu = 0.3) with smoothed aggregation: the same Newton
    /// iterations, PCG iterations within 0.3% (10.22 against 10.25 a step), 15-25% off a
    /// step. Off by default: on the same beam of steel with nu = 0.49 the rounded Jacobian
    /// steered Newton worse (3.0 Newton and 75 PCG iterations a step against 1.3 and 28),
    /// and once lost its definiteness (PCG then solves again with A's values).
    /// Ignored by the other methods and preconditioners.
    pub rounded_products: bool,
    /// Whether the Newton-solved methods start Newton from the last step's velocity
    /// change carried on (`v1 = v0 + (v0 - v_prev)`, the constrained directions left
    /// out) rather than from `v0`, when the last step had the same size. Where the
    /// motion is smooth this guess is a step's change closer, and Newton converges to
    /// the same tolerance from it in fewer iterations: the swinging beam of issue 15
    /// (`benches/fem.rs`, Newton to 1e-3) took 2.3 Newton and 6.1-6.6 PCG iterations a step
    /// instead of 3.1 and 10.2. Where the motion is not smooth it can cost: the same
    /// beam of steel with nu = 0.49 took 1.7 Newton and 38 PCG iterations a step instead
    /// of 1.3 and 28. A step that fails from the guess is solved again from `v0`. The
    /// default, `true`; ignored by the other methods.
    pub predictor: bool,
    /// With the predictor: extrapolate the last two steps' velocity changes linearly
    /// (`v1 = v0 + 2 dv_last - dv_before`, second order in the step) where the last two
    /// steps both continued, instead of carrying the last change on. On the beam of
    /// issue 15 (`benches/fem.rs`) with Newton's rate test
    /// ([`NewtonParams::rate_test`]) and forcing 0.1 this guess left most steps one
    /// Newton iteration from done: 1.29 Newton and 4.4 PCG iterations a step against
    /// 2.13 and 5.0 with the plain test, forcing 0.5 and the first-order guess, and the
    /// same worst velocity error against steps solved to 1e-10 (2.6e-4 and 2.4e-4, to a
    /// tolerance of 1e-3). Off by default: where the motion turns quickly the
    /// extrapolation overshoots.
    pub second_order_predictor: bool,
}

impl MechSettings {
    /// Defaults for `method`: automatic linear solver, Newton to a relative residual or
    /// velocity change of 1e-6 (animation accuracy; studies ask for more).
    pub fn new(method: Method) -> Self {
        Self {
            method,
            linear: LinearSolverKind::Auto(PcgParams::default()),
            newton: NewtonParams {
                tolerance: 1e-6,
                // Relative change of the velocities per iteration: with an approximate
                // (definiteness-fixed) Jacobian Newton converges linearly, and velocities
                // this close are done.
                step_tolerance: 1e-6,
                ..NewtonParams::default()
            },
            reuse_jacobian: 0,
            reuse_preconditioner: 0,
            rounded_products: false,
            predictor: true,
            second_order_predictor: false,
        }
    }
}

enum Linear {
    Pcg(Pcg),
    Cholesky(Box<SparseCholesky>),
}

impl Linear {
    /// The next solves' relative tolerance from inexact Newton (PCG only).
    fn set_forcing(&mut self, eta: f64) {
        if let Linear::Pcg(p) = self {
            p.set_forcing(Some(eta));
        }
    }

    /// The positions the next solve's preconditioner may use (the rotations of smoothed
    /// aggregation's coarse spaces).
    fn set_coordinates(&mut self, x: &[f64]) {
        if let Linear::Pcg(p) = self {
            p.set_coordinates(x);
        }
    }

    /// Solves with the matrix of the last [`Linear::solve`] (its factor, or PCG's matrix
    /// and preconditioner as they are): the chord method's later iterations.
    fn solve_lagged(
        &mut self,
        a: &mut Bsr3,
        b: &[f64],
        x: &mut [f64],
        filter: Option<&Filter>,
    ) -> Result<SolveInfo, SolveError> {
        match self {
            Linear::Pcg(p) => p.resolve(a, b, x, filter),
            Linear::Cholesky(c) => {
                let start = std::time::Instant::now();
                factor_solve(c, b, x, filter)?;
                Ok(SolveInfo {
                    seconds: start.elapsed().as_secs_f64(),
                    ..SolveInfo::default()
                })
            }
        }
    }

    /// Solves `a x = b` under the filter. PCG starts from `x` as given (filtered), and
    /// when `again` (the same step's system after constraints were freed) keeps the
    /// preconditioner it built for the first solve; Cholesky projects `a`.
    fn solve(
        &mut self,
        a: &mut Bsr3,
        b: &[f64],
        x: &mut [f64],
        filter: Option<&Filter>,
        again: bool,
    ) -> Result<SolveInfo, SolveError> {
        match self {
            Linear::Pcg(p) if again => p.resolve(a, b, x, filter),
            Linear::Pcg(p) => p.solve(a, b, x, filter),
            Linear::Cholesky(c) => {
                let start = std::time::Instant::now();
                if let Some(f) = filter {
                    f.project_matrix(a);
                }
                c.factorize(a)?;
                factor_solve(c, b, x, filter)?;
                Ok(SolveInfo {
                    seconds: start.elapsed().as_secs_f64(),
                    ..SolveInfo::default()
                })
            }
        }
    }
}

/// `x = A^-1 S b` with the factor in hand (the filtered right-hand side).
fn factor_solve(
    c: &mut SparseCholesky,
    b: &[f64],
    x: &mut [f64],
    filter: Option<&Filter>,
) -> Result<(), SolveError> {
    x.copy_from_slice(b);
    if let Some(f) = filter {
        f.apply(x);
    }
    c.solve_in_place(x)
}

struct Implicit {
    dfdx: Bsr3,
    dfdv: Option<Bsr3>,
    a: Bsr3,
    linear: Linear,
    newton: Newton,
    v1: Vec<f64>,
    xe: Vec<f64>,
    ve: Vec<f64>,
    f: Vec<f64>,
    f0: Vec<f64>,
    rhs: Vec<f64>,
    /// The last Newton-solved step's velocity change, the velocities it ended with and
    /// its step size (0: none yet), for the next step's first guess
    /// ([`MechSettings::predictor`]).
    dv: Vec<f64>,
    v_end: Vec<f64>,
    dv_h: f64,
    /// The velocity change of the step before the last, and whether the last step
    /// continued it (then both serve `MechSettings::second_order_predictor`).
    dv_prev: Vec<f64>,
    prev_continued: bool,
}

/// Steps mechanical systems with one method. All buffers are allocated in
/// [`MechStepper::new`]; matrices only for implicit methods, the damping Jacobian only for
/// systems with velocity-dependent forces.
pub struct MechStepper {
    settings: MechSettings,
    n: usize,
    inv_mass: Vec<f64>,
    mass: Vec<f64>,
    /// The Jacobian in hand for later steps (`MechSettings::reuse_jacobian` > 1): the step
    /// size and constraints it was made for, and the steps it has served.
    lag: Option<Lag>,
    /// PCG's hierarchy in hand for later steps (`MechSettings::reuse_preconditioner`).
    kept: Option<Lag>,
    /// Newton iterations of the last implicit step: a step after one that needed none
    /// (a body at rest) does not build its Jacobian with its first residual.
    last_newton: usize,
    /// PCG iterations per Newton iteration of the last implicit step (0 before one).
    last_rate: f64,
    filter: Filter,
    y: Vec<f64>,
    rk: Option<RkWork>,
    f: Vec<f64>,
    implicit: Option<Implicit>,
    steps: u64,
}

impl MechStepper {
    /// A stepper for `sys` (its size and masses are read here; implicit methods also ask it
    /// to prepare its Jacobians).
    pub fn new(settings: MechSettings, sys: &mut dyn Mechanical) -> Result<Self, IntegrateError> {
        let method = settings.method;
        let n = sys.vertex_count();
        let mass = sys.mass().to_vec();
        assert_eq!(mass.len(), n, "one mass per vertex");
        let inv_mass = mass
            .iter()
            .map(|&m| if m > 0.0 { 1.0 / m } else { 0.0 })
            .collect();
        if sys.mass_matrix().is_some() && !method.is_implicit() {
            return Err(IntegrateError::Unsupported {
                method,
                reason: "a consistent mass matrix needs an implicit method (explicit ones divide by lumped masses)",
            });
        }
        let rk = matches!(
            method,
            Method::ExplicitEuler | Method::Midpoint | Method::Rk4
        )
        .then(|| RkWork::new(method, 6 * n));
        let y = if rk.is_some() {
            vec![0.0; 6 * n]
        } else {
            Vec::new()
        };
        let f = if method == Method::SymplecticEuler {
            vec![0.0; 3 * n]
        } else {
            Vec::new()
        };
        let implicit = if method.is_implicit() {
            let pattern = sys
                .prepare_jacobians()
                .map_err(IntegrateError::Sparse)?
                .ok_or(IntegrateError::Unsupported {
                    method,
                    reason: "the system provides no Jacobians; use an explicit method",
                })?;
            assert_eq!(pattern.n(), n, "Jacobian pattern size");
            let pcg = |p| {
                let mut pcg = Pcg::new(n, p);
                pcg.set_rounded_products(method.is_newton() && settings.rounded_products);
                Linear::Pcg(pcg)
            };
            let linear = match settings.linear {
                LinearSolverKind::Pcg(p) => pcg(p),
                LinearSolverKind::Auto(p) if 3 * n > AUTO_CHOLESKY_MAX_DOFS => pcg(p),
                LinearSolverKind::Cholesky | LinearSolverKind::Auto(_) => Linear::Cholesky(
                    Box::new(SparseCholesky::new(&pattern).map_err(solve_error(0, method, true))?),
                ),
            };
            let v3 = || vec![0.0; 3 * n];
            Some(Implicit {
                dfdx: Bsr3::zeros(pattern.clone()),
                dfdv: sys
                    .has_velocity_jacobian()
                    .then(|| Bsr3::zeros(pattern.clone())),
                a: Bsr3::zeros(pattern),
                linear,
                newton: Newton::new(3 * n),
                v1: v3(),
                xe: v3(),
                ve: v3(),
                f: v3(),
                f0: if method == Method::Newmark {
                    v3()
                } else {
                    Vec::new()
                },
                rhs: v3(),
                dv: v3(),
                v_end: v3(),
                dv_h: 0.0,
                dv_prev: v3(),
                prev_continued: false,
            })
        } else {
            None
        };
        Ok(Self {
            settings,
            n,
            inv_mass,
            mass,
            lag: None,
            kept: None,
            last_newton: 1,
            last_rate: 0.0,
            filter: Filter::new(n),
            y,
            rk,
            f,
            implicit,
            steps: 0,
        })
    }

    /// The settings.
    pub fn settings(&self) -> &MechSettings {
        &self.settings
    }

    /// Steps taken so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Which linear solver implicit steps use (`None` for explicit methods).
    pub fn linear_solver_name(&self) -> Option<&'static str> {
        self.implicit.as_ref().map(|w| match w.linear {
            Linear::Pcg(_) => "pcg",
            Linear::Cholesky(_) => "cholesky",
        })
    }

    /// Whether a system matrix was built (false for explicit methods).
    pub fn has_matrix(&self) -> bool {
        self.implicit.is_some()
    }

    /// Whether a damping Jacobian was built.
    pub fn has_damping_matrix(&self) -> bool {
        self.implicit.as_ref().is_some_and(|w| w.dfdv.is_some())
    }

    /// Advances `(x, v)` from `t` to `t + h`.
    pub fn step(
        &mut self,
        sys: &mut dyn Mechanical,
        t: f64,
        x: &mut [f64],
        v: &mut [f64],
        h: f64,
    ) -> Result<StepInfo, IntegrateError> {
        let n = self.n;
        assert!(x.len() == 3 * n && v.len() == 3 * n, "state length 3n");
        self.steps += 1;
        let step = self.steps;
        let method = self.settings.method;
        // Whether this step continues the last Newton-solved one (same step size, and the
        // velocities it ended with, before this step's constraints are imposed): the
        // state may have been set between steps, and then nothing is predicted from it.
        let continued = self.settings.predictor
            && method.is_newton()
            && self
                .implicit
                .as_ref()
                .is_some_and(|w| w.dv_h == h && w.v_end.as_slice() == &*v);
        self.filter.clear();
        sys.constraints(&mut self.filter);
        if !self.filter.unilateral().is_empty() {
            if let Some(w) = self.implicit.as_mut() {
                // The velocity before the approaches are imposed: what a released
                // approach goes back to (linearised step).
                w.ve.copy_from_slice(v);
            }
        }
        let filter = (!self.filter.is_empty()).then_some(&self.filter);
        if let Some(f) = filter {
            f.impose(v);
        }
        let solve_err = solve_error(step, method, true);
        let mut info = StepInfo::default();
        match method {
            Method::ExplicitEuler | Method::Midpoint | Method::Rk4 => {
                let (y, rk) = (&mut self.y, self.rk.as_mut().expect("explicit buffers"));
                y[..3 * n].copy_from_slice(x);
                y[3 * n..].copy_from_slice(v);
                let inv_mass = &self.inv_mass;
                let mut g = |t: f64, y: &[f64], d: &mut [f64]| {
                    let (yx, yv) = y.split_at(3 * n);
                    let (dx, dv) = d.split_at_mut(3 * n);
                    dx.copy_from_slice(yv);
                    sys.force(t, yx, yv, dv);
                    scale_by_inverse_mass(dv, inv_mass);
                    if let Some(f) = filter {
                        f.impose(dx);
                        f.apply(dv);
                    }
                    Ok(())
                };
                rk.step(method, t, y, h, &mut g)?;
                x.copy_from_slice(&y[..3 * n]);
                v.copy_from_slice(&y[3 * n..]);
            }
            Method::SymplecticEuler => {
                sys.force(t, x, v, &mut self.f);
                scale_by_inverse_mass(&mut self.f, &self.inv_mass);
                if let Some(f) = filter {
                    f.apply(&mut self.f);
                }
                kv::axpy(v, h, &self.f);
                kv::axpy(x, h, v);
            }
            Method::LinearizedBackwardEuler => {
                let w = self.implicit.as_mut().expect("implicit buffers");
                sys.force_jacobians(t + h, x, v, &mut w.f, &mut w.dfdx, w.dfdv.as_mut())?;
                // A dv = h (f0 + h K v0): solve A z = f0 + h K v0, then dv = h z. PCG
                // starts from the previous step's z (the acceleration changes little
                // from step to step: on a falling sheet with block Jacobi this takes a
                // few iterations where a zero guess takes hundreds); PCG drops it when
                // it is worse than zero (contacts changed).
                // One-sided approaches that pull are freed and the system solved again
                // (see `crate::solve::filter`), at most MAX_RELEASE_ROUNDS times.
                for round in 0.. {
                    w.dfdx.spmv(&mut w.rhs, v);
                    kv::xpay(&mut w.rhs, &w.f, h);
                    system_matrix(
                        &mut w.a,
                        &w.dfdx,
                        w.dfdv.as_ref(),
                        &self.mass,
                        sys.mass_matrix(),
                        h * h,
                        h,
                    );
                    let filter = (!self.filter.is_empty()).then_some(&self.filter);
                    w.linear.set_coordinates(x);
                    let li = w
                        .linear
                        .solve(&mut w.a, &w.rhs, &mut w.v1, filter, round > 0)
                        .map_err(&solve_err)?;
                    info.newton_iterations = 1;
                    info.linear_iterations += li.iterations;
                    info.residual = li.residual;
                    info.solve_seconds += li.seconds;
                    if round == MAX_RELEASE_ROUNDS
                        || !release_pulling(&mut self.filter, w, &self.mass, h, v)
                    {
                        break;
                    }
                }
                kv::axpy(v, h, &w.v1);
                kv::axpy(x, h, v);
            }
            Method::BackwardEuler | Method::ImplicitMidpoint | Method::Newmark => {
                let c = Coeffs::of(method);
                let w = self.implicit.as_mut().expect("implicit buffers");
                if method == Method::Newmark {
                    sys.force(t, x, v, &mut w.f0);
                }
                let reuse = self.settings.reuse_jacobian;
                // An earlier step's Jacobian, if it may serve this one.
                let mut lagged = reuse > 1
                    && self
                        .lag
                        .as_ref()
                        .is_some_and(|l| l.serves(h, reuse, &self.filter));
                // An earlier step's multigrid hierarchy, likewise (PCG only).
                let keep = self.settings.reuse_preconditioner;
                let last_rate = self.last_rate;
                let mut kept = keep > 0
                    && matches!(w.linear, Linear::Pcg(_))
                    && self
                        .kept
                        .as_ref()
                        .is_some_and(|l| l.serves(h, keep, &self.filter) && !l.slowed(last_rate));
                let Implicit {
                    dfdx,
                    dfdv,
                    a,
                    linear,
                    newton,
                    v1,
                    xe,
                    ve,
                    f,
                    f0,
                    rhs,
                    dv,
                    v_end,
                    dv_h,
                    dv_prev,
                    prev_continued,
                } = w;
                let second = continued && *prev_continued && self.settings.second_order_predictor;
                let mut predict = continued;
                loop {
                    // Newton's first guess (see `MechSettings::predictor`).
                    if predict {
                        if second {
                            // v0 + dv + (dv - dv_prev): the last two changes extrapolated.
                            kv::waxpy(v1, dv, -1.0, dv_prev);
                            kv::axpy(v1, 1.0, dv);
                        } else {
                            v1.copy_from_slice(dv);
                        }
                        if let Some(f) = filter {
                            f.apply(v1);
                        }
                        kv::axpy(v1, 1.0, v);
                    } else {
                        v1.copy_from_slice(v);
                    }
                    let mut prob = Residual {
                        sys,
                        c,
                        t: t + c.t * h,
                        h,
                        x0: x,
                        v0: v,
                        mass: &self.mass,
                        filter,
                        xe,
                        ve,
                        f,
                        f0,
                        rhs,
                        dfdx,
                        dfdv: dfdv.as_mut(),
                        a,
                        linear,
                        linear_iterations: 0,
                        solve_seconds: 0.0,
                        residual: 0.0,
                        noise: 0.0,
                        err: None,
                        reuse: reuse > 0,
                        factored: lagged,
                        refactored: false,
                        keep_preconditioner: kept,
                        new_preconditioner: false,
                        assemble_first: !lagged && self.last_newton > 0,
                        assembled: false,
                        system_ready: false,
                    };
                    // An old Jacobian gets a few iterations (as many as a new one usually
                    // needs, plus a margin); then the step starts over with a new one.
                    let mut params = self.settings.newton;
                    if lagged {
                        params.max_iterations = params.max_iterations.min(LAGGED_ITERATIONS);
                    }
                    let res = newton.solve(&mut prob, v1, &params);
                    let err = prob.err.take();
                    if predict && (err.is_some() || res.is_err()) {
                        // The guess did not serve (forces not finite there, or Newton did
                        // not get there from it): once more from v0.
                        predict = false;
                        continue;
                    }
                    if let Some(e) = err {
                        return Err(e);
                    }
                    if prob.refactored && reuse > 1 {
                        Lag::renew(&mut self.lag, h, &self.filter);
                    }
                    if prob.new_preconditioner && keep > 0 {
                        Lag::renew(&mut self.kept, h, &self.filter);
                    }
                    if res.is_err() && (lagged || kept) {
                        // The old Jacobian or hierarchy did not get there: once more with
                        // new ones.
                        for (old, l) in [(lagged, &mut self.lag), (kept, &mut self.kept)] {
                            if let Some(l) = l.as_mut().filter(|_| old) {
                                l.valid = false;
                            }
                        }
                        (lagged, kept) = (false, false);
                        continue;
                    }
                    let ni = res.map_err(solve_err)?;
                    self.last_newton = ni.iterations;
                    if ni.iterations > 0 {
                        self.last_rate = prob.linear_iterations as f64 / ni.iterations as f64;
                        if prob.new_preconditioner {
                            if let Some(l) = self.kept.as_mut() {
                                l.rate = self.last_rate;
                            }
                        }
                    }
                    for l in [&mut self.lag, &mut self.kept].into_iter().flatten() {
                        l.age += 1;
                    }
                    info = StepInfo {
                        newton_iterations: ni.iterations,
                        linear_iterations: prob.linear_iterations,
                        residual: prob.residual,
                        solve_seconds: prob.solve_seconds,
                    };
                    break;
                }
                std::mem::swap(dv, dv_prev);
                *prev_continued = continued;
                kv::waxpy(dv, v1, -1.0, v);
                v_end.copy_from_slice(v1);
                *dv_h = h;
                // x1 from v1 (table in the module docs).
                if method == Method::BackwardEuler {
                    kv::axpy(x, h, v1);
                } else {
                    kv::axpy(x, 0.5 * h, v);
                    kv::axpy(x, 0.5 * h, v1);
                }
                v.copy_from_slice(v1);
            }
        }
        for (field, s) in [("position", &*x), ("velocity", &*v)] {
            if !kv::all_finite(s) {
                return Err(IntegrateError::NonFinite {
                    step,
                    field,
                    hint: hint(method),
                });
            }
        }
        Ok(info)
    }
}

/// Newton iterations a step gives a Jacobian kept from an earlier step before it makes
/// a new one. Measured on the 60,000-tetrahedron beam (`benches/fem.rs`, up to ten steps
/// per Jacobian), where a step converges in about 5 iterations with its own Jacobian: no
/// cap (50) gave a mean step of 773 ms, 8 gave 425 ms, 5 gave 663 ms (every old
/// Jacobian gave up, then a new one was made); one Jacobian per step gave 491 ms.
const LAGGED_ITERATIONS: usize = 8;

/// How much slower than the step that made it (PCG iterations per Newton iteration) a
/// kept hierarchy may let a step run before the next step makes a new one
/// ([`MechSettings::reuse_preconditioner`]): `SLOWED` times its rate plus `SLOWED_SLACK`
/// iterations (against a hierarchy's first rate of 2, a step of 2 Newton iterations with
/// 7 PCG iterations makes a new one; with 6 it does not). Measured on the swinging
/// 60,000-tetrahedron beam of issue 15 (120 steps of `benches/fem.rs`'s defaults, up to 30
/// steps a hierarchy): 1.25 and 0.5 made 12-13 hierarchies with 4.96 PCG iterations a
/// step; 1.5 and 0.5, 12 with 5.12; 1.25 and 0, 21 with 4.64; a new one every 10 steps
/// without the test, 15 with 5.33 (and every 20 steps, in an earlier measurement, 9.8 PCG
/// iterations a step instead of 5.6).
const SLOWED: f64 = 1.25;
const SLOWED_SLACK: f64 = 0.5;

/// A Jacobian kept for later steps (see [`MechSettings::reuse_jacobian`]), or PCG's
/// hierarchy ([`MechSettings::reuse_preconditioner`]): the step size and constraints it
/// was made for, and the steps it has served.
struct Lag {
    h: f64,
    filter: Filter,
    age: usize,
    /// False once a step gave up on it (its buffers stay for the next one).
    valid: bool,
    /// A kept hierarchy's PCG iterations per Newton iteration in the step that made it
    /// (0 until known).
    rate: f64,
}

impl Lag {
    /// Whether it may serve a step of size h under `filter`, given the steps it may serve.
    fn serves(&self, h: f64, most: usize, filter: &Filter) -> bool {
        self.valid && self.h == h && self.age < most && self.filter.same_projection(filter)
    }

    /// Whether a kept hierarchy has fallen behind the matrices: the last step took more
    /// than [`SLOWED`] times the PCG iterations per Newton iteration of the step that made
    /// it, plus [`SLOWED_SLACK`]. Then the next step makes a new one, as SUNDIALS' CVODE
    /// sets its preconditioner up again when the linear solver slows (Hindmarsh et al.,
    /// "SUNDIALS: Suite of nonlinear and differential/algebraic equation solvers", ACM
    /// TOMS 31, 2005).
    fn slowed(&self, last_rate: f64) -> bool {
        self.rate > 0.0 && last_rate > SLOWED * self.rate + SLOWED_SLACK
    }

    /// Records a new one made for a step of size h under `filter` (kept buffers: no
    /// allocation once the first is kept).
    fn renew(lag: &mut Option<Lag>, h: f64, filter: &Filter) {
        let l = lag.get_or_insert_with(|| Lag {
            h,
            filter: Filter::new(0),
            age: 0,
            valid: true,
            rate: 0.0,
        });
        l.h = h;
        l.filter.clone_from(filter);
        l.age = 0;
        l.valid = true;
        l.rate = 0.0;
    }
}

/// Most re-solves of a linearised step after freeing pulling approaches (one usually
/// settles it: freed vertices are those the cloth holds back, and freeing them rarely
/// makes another pull).
const MAX_RELEASE_ROUNDS: usize = 2;

/// Frees the one-sided approaches whose constraint pulled towards the obstacle over the
/// step, and gives them back the velocity they had before the approach was imposed
/// (`w.ve`). The constraint's impulse along the outward normal n is what imposing the
/// approach speed took, `m (v_i - w.ve_i) . n`, plus `h` times its force in the last solve
/// of `A y = b` (`w.v1`, `w.rhs`; `A = M - h dfdv - h^2 dfdx`, rebuilt from the
/// Jacobians since a direct solve projects `w.a`), `(A y - b)_i . n`; it pulls when that
/// sum is below `-m slack` (the cloth would have held the vertex back short of the
/// obstacle by more than the slack allows). Returns whether any was freed.
fn release_pulling(filter: &mut Filter, w: &Implicit, mass: &[f64], h: f64, v: &mut [f64]) -> bool {
    let n = mass.len();
    let mut freed = false;
    let mut k = 0;
    while let Some(&a) = filter.unilateral().get(k) {
        let (i, p) = (a.vertex as usize, a.normal);
        let kx = w.dfdx.row_times(i, &w.v1);
        let kv = w.dfdv.as_ref().map_or([0.0; 3], |d| d.row_times(i, &w.v1));
        let impulse: f64 = (0..3)
            .map(|c| {
                let ay = mass[i] * w.v1[c * n + i] - h * h * kx[c] - h * kv[c];
                let imposed = mass[i] * (v[c * n + i] - w.ve[c * n + i]);
                (imposed + h * (ay - w.rhs[c * n + i])) * p[c]
            })
            .sum();
        if impulse < -mass[i] * a.slack {
            filter.free(i);
            for c in 0..3 {
                v[c * n + i] = w.ve[c * n + i];
            }
            freed = true;
        } else {
            k += 1;
        }
    }
    freed
}

fn scale_by_inverse_mass(f: &mut [f64], inv_mass: &[f64]) {
    let n = inv_mass.len();
    for c in 0..3 {
        for (fi, im) in f[c * n..(c + 1) * n].iter_mut().zip(inv_mass) {
            *fi *= im;
        }
    }
}

/// `a = M - ck K - cd D` from the assembled Jacobians, M the consistent mass matrix when
/// given, else the lumped masses.
fn system_matrix(
    a: &mut Bsr3,
    dfdx: &Bsr3,
    dfdv: Option<&Bsr3>,
    mass: &[f64],
    mass_matrix: Option<&Bsr3>,
    ck: f64,
    cd: f64,
) {
    let mut terms = [(-ck, dfdx); 3];
    let mut k = 1;
    for t in [dfdv.map(|d| (-cd, d)), mass_matrix.map(|m| (1.0, m))]
        .into_iter()
        .flatten()
    {
        terms[k] = t;
        k += 1;
    }
    a.assign_lincomb(&terms[..k]);
    if mass_matrix.is_none() {
        a.add_diagonal(mass);
    }
}

/// Kinetic energy `1/2 v^T M v` (J) with a consistent mass matrix M.
pub fn kinetic_energy_matrix(m: &Bsr3, v: &[f64]) -> f64 {
    0.5 * quadratic(m, v)
}

/// `sum_i x_i . (A x)_i`, without a buffer.
fn quadratic(a: &Bsr3, x: &[f64]) -> f64 {
    let n = a.n();
    (0..n)
        .map(|i| {
            let y = a.row_times(i, x);
            y[0] * x[i] + y[1] * x[n + i] + y[2] * x[2 * n + i]
        })
        .sum()
}

#[derive(Clone, Copy, Debug)]
struct Coeffs {
    a: f64,
    b: f64,
    c: f64,
    d: f64,
    w0: f64,
    w1: f64,
    t: f64,
}

impl Coeffs {
    fn of(method: Method) -> Self {
        match method {
            Method::BackwardEuler => Self {
                a: 0.0,
                b: 1.0,
                c: 0.0,
                d: 1.0,
                w0: 0.0,
                w1: 1.0,
                t: 1.0,
            },
            Method::ImplicitMidpoint => Self {
                a: 0.25,
                b: 0.25,
                c: 0.5,
                d: 0.5,
                w0: 0.0,
                w1: 1.0,
                t: 0.5,
            },
            Method::Newmark => Self {
                a: 0.5,
                b: 0.5,
                c: 0.0,
                d: 1.0,
                w0: 0.5,
                w1: 0.5,
                t: 1.0,
            },
            _ => unreachable!("not a Newton-solved mechanical method"),
        }
    }
}

/// The implicit step residual `R(v1)` as a Newton problem (see the module docs).
struct Residual<'a> {
    sys: &'a mut dyn Mechanical,
    c: Coeffs,
    t: f64,
    h: f64,
    x0: &'a [f64],
    v0: &'a [f64],
    mass: &'a [f64],
    filter: Option<&'a Filter>,
    xe: &'a mut Vec<f64>,
    ve: &'a mut Vec<f64>,
    f: &'a mut Vec<f64>,
    f0: &'a [f64],
    rhs: &'a mut Vec<f64>,
    dfdx: &'a mut Bsr3,
    dfdv: Option<&'a mut Bsr3>,
    a: &'a mut Bsr3,
    linear: &'a mut Linear,
    linear_iterations: usize,
    solve_seconds: f64,
    residual: f64,
    noise: f64,
    err: Option<IntegrateError>,
    /// Reuse the Jacobian in hand (`MechSettings::reuse_jacobian`), whether there is one
    /// (from this step's first iteration, or an earlier step), and whether this step made
    /// a new one.
    reuse: bool,
    factored: bool,
    refactored: bool,
    /// Keep PCG's hierarchy from an earlier step (`MechSettings::reuse_preconditioner`);
    /// whether this step built a new one.
    keep_preconditioner: bool,
    new_preconditioner: bool,
    /// Whether `a` holds the system matrix of the last assembly already (written by
    /// [`Mechanical::force_system`]), so the Newton step need not combine it.
    system_ready: bool,
    /// Build the Jacobian with the first residual (`Residual::residual`), as the first
    /// Newton step would at the same point: the forces then come with it, one force
    /// evaluation fewer a step. Whether the last assembly (`dfdx`, or `a` when
    /// `system_ready`) is that of the last residual's point.
    assemble_first: bool,
    assembled: bool,
}

impl Residual<'_> {
    /// The forces and their Jacobians at the point `eval_point` set.
    fn assemble(&mut self) -> Result<(), SolveError> {
        // The system matrix straight from the assembly, where the system can (it
        // declines with a damping Jacobian or a consistent mass matrix).
        let (ck, _) = self.coefficients();
        let fused = self
            .sys
            .force_system(self.t, self.xe, self.ve, self.f, self.a, ck, self.mass);
        let done = fused.and_then(|fused| {
            self.system_ready = fused;
            if fused {
                return Ok(());
            }
            self.sys.force_jacobians(
                self.t,
                self.xe,
                self.ve,
                self.f,
                self.dfdx,
                self.dfdv.as_deref_mut(),
            )
        });
        done.map_err(|e| {
            self.err = Some(e);
            SolveError::Factorization("Jacobian assembly failed".into())
        })
    }

    /// The coefficients `(ck, cd)` of the step's matrix `M - ck df/dx - cd df/dv`.
    fn coefficients(&self) -> (f64, f64) {
        let (h, c) = (self.h, self.c);
        (h * c.w1 * h * c.b, h * c.w1 * c.d)
    }

    fn eval_point(&mut self, v1: &[f64]) {
        let (c, h) = (self.c, self.h);
        let states = self.xe.iter_mut().zip(self.ve.iter_mut());
        for ((((xe, ve), x0), v0), v1) in states.zip(self.x0).zip(self.v0).zip(v1) {
            *xe = x0 + h * (c.a * v0 + c.b * v1);
            *ve = c.c * v0 + c.d * v1;
        }
    }
}

impl NewtonProblem for Residual<'_> {
    fn residual(&mut self, v1: &[f64], r: &mut [f64]) -> Result<(), SolveError> {
        self.eval_point(v1);
        self.assembled = std::mem::take(&mut self.assemble_first);
        if self.assembled {
            self.assemble()?;
        } else {
            self.sys.force(self.t, self.xe, self.ve, self.f);
        }
        let (n, h, c) = (self.mass.len(), self.h, self.c);
        // M (v1 - v0) with the consistent mass matrix (rhs is free until newton_step).
        let consistent = self.sys.mass_matrix().is_some();
        if let Some(mm) = self.sys.mass_matrix() {
            for ((d, a), b) in self.rhs.iter_mut().zip(v1).zip(self.v0) {
                *d = a - b;
            }
            mm.spmv(r, self.rhs);
        }
        let mut scale2 = 0.0f64;
        for comp in 0..3 {
            for i in 0..n {
                let k = comp * n + i;
                let m = self.mass[i];
                let f0 = if c.w0 != 0.0 { self.f0[k] } else { 0.0 };
                let force = h * (c.w0 * f0 + c.w1 * self.f[k]);
                let inertia = if consistent {
                    r[k]
                } else {
                    m * (v1[k] - self.v0[k])
                };
                r[k] = inertia - force;
                let size = (m * v1[k]).abs() + (m * self.v0[k]).abs() + force.abs();
                scale2 += size * size;
            }
        }
        // The terms that cancel inside the forces round too (zero net force at rest).
        let cancelled = h * (c.w0.abs() + c.w1.abs()) * self.sys.force_rounding();
        scale2 += cancelled * cancelled;
        if let Some(f) = self.filter {
            f.apply(r);
        }
        self.noise = rounding_floor(scale2);
        Ok(())
    }

    fn newton_step(
        &mut self,
        v1: &[f64],
        r: &[f64],
        dy: &mut [f64],
    ) -> Result<SolveInfo, SolveError> {
        if self.reuse && self.factored {
            kv::scale_copy(self.rhs, -1.0, r);
            dy.fill(0.0);
            let li = self
                .linear
                .solve_lagged(self.a, self.rhs, dy, self.filter)?;
            self.linear_iterations += li.iterations;
            self.solve_seconds += li.seconds;
            self.residual = li.residual;
            return Ok(li);
        }
        self.eval_point(v1);
        // Newton steps from the point of its last residual.
        if !std::mem::take(&mut self.assembled) {
            self.assemble()?;
        }
        let (ck, cd) = self.coefficients();
        if !std::mem::take(&mut self.system_ready) {
            system_matrix(
                self.a,
                self.dfdx,
                self.dfdv.as_deref(),
                self.mass,
                self.sys.mass_matrix(),
                ck,
                cd,
            );
        }
        kv::scale_copy(self.rhs, -1.0, r);
        dy.fill(0.0);
        self.linear.set_coordinates(self.xe);
        let li = self
            .linear
            .solve(self.a, self.rhs, dy, self.filter, self.keep_preconditioner)?;
        self.new_preconditioner |= !self.keep_preconditioner;
        self.factored = true;
        self.refactored = true;
        self.linear_iterations += li.iterations;
        self.solve_seconds += li.seconds;
        self.residual = li.residual;
        Ok(li)
    }

    fn noise_floor(&self) -> f64 {
        self.noise
    }

    fn set_linear_tolerance(&mut self, eta: f64) {
        self.linear.set_forcing(eta);
    }

    fn merit(&mut self, v1: &[f64]) -> Option<f64> {
        self.eval_point(v1);
        let (h, c) = (self.h, self.c);
        let u = self.sys.potential_energy(self.t, self.xe)?;
        let psi = self.sys.dissipation(self.xe, self.ve);
        let n = self.mass.len();
        let mut kinetic = 0.0;
        let mut work0 = 0.0;
        for comp in 0..3 {
            for i in 0..n {
                let k = comp * n + i;
                let dv = v1[k] - self.v0[k];
                kinetic += 0.5 * self.mass[i] * dv * dv;
                if c.w0 != 0.0 {
                    work0 += self.f0[k] * v1[k];
                }
            }
        }
        if let Some(mm) = self.sys.mass_matrix() {
            // rhs is scratch between Newton steps.
            for ((d, a), b) in self.rhs.iter_mut().zip(v1).zip(self.v0) {
                *d = a - b;
            }
            kinetic = 0.5 * quadratic(mm, self.rhs);
        }
        Some(kinetic - h * c.w0 * work0 + (c.w1 / c.b) * u + (h * c.w1 / c.d) * psi)
    }
}
