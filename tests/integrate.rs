//! Integrator validation: nominal orders, exact energy laws on the linear oscillator,
//! long-time behaviour of symplectic Euler, and the course notes' sample problem.

#[path = "../src/study/problems.rs"]
mod problems;

use largestep::integrate::*;
use largestep::solve::{PcgParams, Preconditioner, SolveError};
use problems::{Oscillator, Pendulum, Quadratic, StiffScalar};
use std::f64::consts::PI;

fn settings(method: Method, linear: LinearSolverKind) -> MechSettings {
    let mut s = MechSettings::new(method);
    s.linear = linear;
    s.newton.tolerance = 1e-13;
    s.newton.step_tolerance = 1e-14;
    s
}

/// Integrates a one-vertex system from (x0, v0) to T with N steps; returns (x, v).
fn run_mech(
    sys: &mut dyn Mechanical,
    method: Method,
    x0: f64,
    v0: f64,
    t_end: f64,
    steps: usize,
) -> (f64, f64) {
    let mut st = MechStepper::new(settings(method, LinearSolverKind::Cholesky), sys).unwrap();
    let (mut x, mut v) = ([x0, 0.0, 0.0], [v0, 0.0, 0.0]);
    let h = t_end / steps as f64;
    for k in 0..steps {
        st.step(sys, k as f64 * h, &mut x, &mut v, h).unwrap();
    }
    (x[0], v[0])
}

fn observed_order(errors: &[f64]) -> f64 {
    let n = errors.len();
    (errors[n - 2] / errors[n - 1]).log2()
}

#[test]
fn mechanical_methods_reach_nominal_order() {
    // Damped oscillator (exercises both Jacobians), one period.
    let osc = Oscillator::new(2.0 * PI, 0.1, 0.0);
    let t_end = 1.0;
    let (xe, ve) = osc.exact(1.0, 0.0, t_end);
    for method in Method::ALL {
        let errors: Vec<f64> = [100, 200, 400, 800]
            .iter()
            .map(|&n| {
                let (x, v) = run_mech(&mut osc.clone(), method, 1.0, 0.0, t_end, n);
                ((x - xe).powi(2) + ((v - ve) / osc.omega).powi(2)).sqrt()
            })
            .collect();
        let p = observed_order(&errors);
        assert!(
            (p - method.order() as f64).abs() < 0.1,
            "{method}: observed order {p:.3}, nominal {} (errors {errors:?})",
            method.order()
        );
    }
}

#[test]
fn nonlinear_pendulum_orders() {
    // Reference: RK4 at a far smaller step.
    let pend = Pendulum::new(9.81);
    let t_end = 2.0;
    let (xr, vr) = run_mech(&mut pend.clone(), Method::Rk4, 2.0, 0.0, t_end, 64_000);
    for method in Method::ALL {
        let errors: Vec<f64> = [200, 400, 800]
            .iter()
            .map(|&n| {
                let (x, v) = run_mech(&mut pend.clone(), method, 2.0, 0.0, t_end, n);
                ((x - xr).powi(2) + (v - vr).powi(2)).sqrt()
            })
            .collect();
        let p = observed_order(&errors);
        assert!(
            (p - method.order() as f64).abs() < 0.1,
            "{method}: order {p:.3} ({errors:?})"
        );
    }
}

#[test]
fn first_order_methods_reach_nominal_order() {
    let mut sys = StiffScalar { lambda: 2.0 };
    let t_end = 1.0;
    let exact = sys.exact(0.0, t_end);
    for method in Method::ALL.into_iter().filter(|m| m.supports_first_order()) {
        let errors: Vec<f64> = [100, 200, 400]
            .iter()
            .map(|&n| {
                let mut st = OdeStepper::new(method, 1).unwrap();
                let h = t_end / n as f64;
                let mut y = [0.0];
                for k in 0..n {
                    st.step(&mut sys, k as f64 * h, &mut y, h).unwrap();
                }
                (y[0] - exact).abs()
            })
            .collect();
        let p = observed_order(&errors);
        assert!(
            (p - method.order() as f64).abs() < 0.1,
            "{method}: order {p:.3}"
        );
    }
}

#[test]
fn exact_energy_laws_on_the_linear_oscillator() {
    // Undamped oscillator; E = (v^2 + w^2 x^2)/2. Per-step energy factors:
    let w: f64 = 3.0;
    let h: f64 = 0.05;
    let z = w * h;
    let laws: [(Method, f64); 7] = [
        (Method::ExplicitEuler, 1.0 + z * z),
        (Method::BackwardEuler, 1.0 / (1.0 + z * z)),
        (Method::LinearizedBackwardEuler, 1.0 / (1.0 + z * z)),
        (Method::ImplicitMidpoint, 1.0),
        (Method::Newmark, 1.0),
        (Method::Midpoint, 1.0 + z.powi(4) / 4.0),
        (Method::Rk4, 1.0 - z.powi(6) / 72.0 + z.powi(8) / 576.0),
    ];
    for (method, factor) in laws {
        let mut osc = Oscillator::new(w, 0.0, 0.0);
        let mut st =
            MechStepper::new(settings(method, LinearSolverKind::Cholesky), &mut osc).unwrap();
        let (mut x, mut v) = ([0.7, 0.0, 0.0], [-1.3, 0.0, 0.0]);
        for k in 0..50 {
            let e0 = osc.energy(x[0], v[0]);
            st.step(&mut osc, k as f64 * h, &mut x, &mut v, h).unwrap();
            let e1 = osc.energy(x[0], v[0]);
            assert!(
                (e1 / e0 - factor).abs() < 1e-12,
                "{method} step {k}: E1/E0 = {} expected {factor}",
                e1 / e0
            );
        }
    }
    // Symplectic Euler conserves the modified energy v^2 + w^2 x^2 - h w^2 x v exactly.
    let mut osc = Oscillator::new(w, 0.0, 0.0);
    let mut st = MechStepper::new(
        settings(
            Method::SymplecticEuler,
            LinearSolverKind::Auto(Default::default()),
        ),
        &mut osc,
    )
    .unwrap();
    let (mut x, mut v) = ([0.7, 0.0, 0.0], [-1.3, 0.0, 0.0]);
    let q = |x: f64, v: f64| v * v + w * w * x * x - h * w * w * x * v;
    let q0 = q(x[0], v[0]);
    for k in 0..1000 {
        st.step(&mut osc, k as f64 * h, &mut x, &mut v, h).unwrap();
        assert!((q(x[0], v[0]) / q0 - 1.0).abs() < 1e-12);
    }
}

#[test]
fn symplectic_euler_energy_stays_bounded_for_1e5_steps() {
    let mut osc = Oscillator::new(1.0, 0.0, 0.0);
    let h = 0.1;
    let mut st = MechStepper::new(MechSettings::new(Method::SymplecticEuler), &mut osc).unwrap();
    let (mut x, mut v) = ([1.0, 0.0, 0.0], [0.0; 3]);
    let e0 = osc.energy(x[0], v[0]);
    let mut worst = 0.0f64;
    for k in 0..100_000 {
        st.step(&mut osc, k as f64 * h, &mut x, &mut v, h).unwrap();
        worst = worst.max((osc.energy(x[0], v[0]) / e0 - 1.0).abs());
    }
    // The shadow energy bounds the drift by about h w / 2 (no secular growth).
    assert!(worst < 0.06, "energy deviation {worst}");
    // Explicit Euler, in contrast, grows by (1 + h^2)^N.
    let mut st = MechStepper::new(MechSettings::new(Method::ExplicitEuler), &mut osc).unwrap();
    let (mut x, mut v) = ([1.0, 0.0, 0.0], [0.0; 3]);
    for k in 0..1000 {
        st.step(&mut osc, k as f64 * h, &mut x, &mut v, h).unwrap();
    }
    assert!(osc.energy(x[0], v[0]) / e0 > 1e4);
}

#[test]
fn course_notes_sample_forward_is_5_backward_has_no_real_solution() {
    let mut sys = Quadratic { c: 4.0 };
    let mut fe = OdeStepper::new(Method::ExplicitEuler, 1).unwrap();
    let mut y = [1.0];
    fe.step(&mut sys, 0.0, &mut y, 1.0).unwrap();
    assert_eq!(y[0], 5.0);

    let mut be = OdeStepper::new(Method::BackwardEuler, 1).unwrap();
    let mut y = [1.0];
    let err = be.step(&mut sys, 0.0, &mut y, 1.0).unwrap_err();
    let msg = err.to_string();
    assert!(
        matches!(
            err,
            IntegrateError::Solve {
                source: SolveError::LineSearchFailed { .. } | SolveError::Singular { .. },
                ..
            }
        ),
        "{msg}"
    );
    assert!(
        msg.contains("no real solution") || msg.contains("no solution"),
        "{msg}"
    );
    assert_eq!(y[0], 1.0, "the state is left untouched on failure");
    assert!(!msg.contains("NaN"));
}

#[test]
fn pcg_and_cholesky_give_the_same_implicit_steps() {
    let osc = Oscillator::new(5.0, 0.2, 0.3);
    for method in [
        Method::BackwardEuler,
        Method::LinearizedBackwardEuler,
        Method::ImplicitMidpoint,
        Method::Newmark,
    ] {
        let mut results = Vec::new();
        for linear in [
            LinearSolverKind::Cholesky,
            LinearSolverKind::Pcg(PcgParams {
                tolerance: 1e-14,
                max_iterations: 10,
                preconditioner: Preconditioner::BlockJacobi,
            }),
        ] {
            let mut sys = osc.clone();
            let mut st = MechStepper::new(settings(method, linear), &mut sys).unwrap();
            let (mut x, mut v) = ([1.0, 0.5, 0.0], [0.0, 0.0, 0.2]);
            for k in 0..20 {
                st.step(&mut sys, k as f64 * 0.05, &mut x, &mut v, 0.05)
                    .unwrap();
            }
            results.push((x, v));
        }
        let (a, b) = (results[0], results[1]);
        for c in 0..3 {
            assert!(
                (a.0[c] - b.0[c]).abs() < 1e-12 && (a.1[c] - b.1[c]).abs() < 1e-12,
                "{method}"
            );
        }
    }
}

#[test]
fn explosion_is_reported_with_the_step_not_as_nan() {
    let mut osc = Oscillator::new(1000.0, 0.0, 0.0);
    let mut st = MechStepper::new(MechSettings::new(Method::ExplicitEuler), &mut osc).unwrap();
    let (mut x, mut v) = ([1.0, 0.0, 0.0], [0.0; 3]);
    let mut failed = None;
    for k in 0..10_000 {
        if let Err(e) = st.step(&mut osc, k as f64 * 0.01, &mut x, &mut v, 0.01) {
            failed = Some(e);
            break;
        }
    }
    let e = failed.expect("explicit Euler at h w = 10 must blow up");
    assert!(matches!(e, IntegrateError::NonFinite { step, .. } if step > 1));
    assert!(e.to_string().contains("reduce dt"), "{e}");
}

#[test]
fn methods_without_jacobians_or_first_order_form_are_rejected_clearly() {
    let e = OdeStepper::new(Method::Newmark, 2).unwrap_err();
    assert!(e.to_string().contains("mechanical system"), "{e}");
    struct Free;
    impl Mechanical for Free {
        fn vertex_count(&self) -> usize {
            1
        }
        fn mass(&self) -> &[f64] {
            &[1.0]
        }
        fn force(&mut self, _: f64, _: &[f64], _: &[f64], f: &mut [f64]) {
            f.fill(0.0)
        }
    }
    let e = MechStepper::new(MechSettings::new(Method::BackwardEuler), &mut Free)
        .err()
        .unwrap();
    assert!(e.to_string().contains("no Jacobians"), "{e}");
    assert!(MechStepper::new(MechSettings::new(Method::Rk4), &mut Free).is_ok());
    // A first-order system without a Jacobian: implicit steps say so.
    struct NoJacobian;
    impl OdeSystem for NoJacobian {
        fn dim(&self) -> usize {
            1
        }
        fn rhs(&mut self, _: f64, y: &[f64], d: &mut [f64]) {
            d[0] = -y[0];
        }
    }
    let mut st = OdeStepper::new(Method::BackwardEuler, 1).unwrap();
    let e = st.step(&mut NoJacobian, 0.0, &mut [1.0], 0.1).unwrap_err();
    assert!(matches!(e, IntegrateError::Unsupported { .. }), "{e}");
    assert!(e.to_string().contains("no Jacobian"), "{e}");
}

/// A particle 1 cm above the plane y = 0 moving down at 1 m/s under a constant force, with
/// a speculative approach that would land it on the plane within the step (h = 1/60 s).
struct Approaching {
    fy: f64,
    pattern: std::sync::Arc<largestep::sparse::Bsr3Pattern>,
    h: f64,
    y0: f64,
}

impl Mechanical for Approaching {
    fn vertex_count(&self) -> usize {
        1
    }
    fn mass(&self) -> &[f64] {
        &[1.0]
    }
    fn constraints(&self, filter: &mut largestep::solve::Filter) {
        filter.approach(0, [0.0, 1.0, 0.0], -self.y0 / self.h, 0.0);
    }
    fn force(&mut self, _: f64, _: &[f64], _: &[f64], f: &mut [f64]) {
        f.copy_from_slice(&[0.0, self.fy, 0.0]);
    }
    fn prepare_jacobians(
        &mut self,
    ) -> Result<
        Option<std::sync::Arc<largestep::sparse::Bsr3Pattern>>,
        largestep::sparse::SparseError,
    > {
        Ok(Some(self.pattern.clone()))
    }
    fn force_jacobians(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut largestep::sparse::Bsr3,
        _: Option<&mut largestep::sparse::Bsr3>,
    ) -> Result<(), IntegrateError> {
        self.force(t, x, v, f);
        dfdx.set_zero();
        Ok(())
    }
}

/// Speculative approaches are one-sided (issue 14): a particle pushed onto the plane
/// lands on it with the prescribed speed; one that the force holds back is freed and
/// moves as if unconstrained (ending above the plane, or moving away), instead of being
/// dragged down to it.
#[test]
fn an_approach_the_solve_finds_pulling_is_freed() {
    let h = 1.0 / 60.0;
    for linear in [
        LinearSolverKind::Cholesky,
        LinearSolverKind::Pcg(PcgParams::default()),
    ] {
        // (force, expected end height, expected end velocity)
        for (fy, y1, v1) in [
            (-10.0, 0.0, -0.6), // pushed on: lands, at -y0/h
            (30.0, 0.01 + h * (-1.0 + 30.0 * h), -1.0 + 30.0 * h), // held back: short of it
            (100.0, 0.01 + h * (-1.0 + 100.0 * h), -1.0 + 100.0 * h), // pulled away
        ] {
            let mut sys = Approaching {
                fy,
                pattern: std::sync::Arc::new(largestep::sparse::Bsr3Pattern::diagonal(1)),
                h,
                y0: 0.01,
            };
            let mut settings = MechSettings::new(Method::LinearizedBackwardEuler);
            settings.linear = linear;
            let mut st = MechStepper::new(settings, &mut sys).unwrap();
            let (mut x, mut v) = ([0.0, 0.01, 0.0], [0.0, -1.0, 0.0]);
            st.step(&mut sys, 0.0, &mut x, &mut v, h).unwrap();
            assert!(
                (x[1] - y1).abs() < 1e-9,
                "force {fy}: y = {}, expected {y1}",
                x[1]
            );
            assert!(
                (v[1] - v1).abs() < 1e-9,
                "force {fy}: v = {}, expected {v1}",
                v[1]
            );
        }
    }
}

/// A system that counts the force and Jacobian evaluations a stepper asks of it.
struct Counted<S> {
    sys: S,
    forces: usize,
    jacobians: usize,
}

impl<S: Mechanical> Mechanical for Counted<S> {
    fn vertex_count(&self) -> usize {
        self.sys.vertex_count()
    }
    fn mass(&self) -> &[f64] {
        self.sys.mass()
    }
    fn force(&mut self, t: f64, x: &[f64], v: &[f64], f: &mut [f64]) {
        self.forces += 1;
        self.sys.force(t, x, v, f);
    }
    fn potential_energy(&self, t: f64, x: &[f64]) -> Option<f64> {
        self.sys.potential_energy(t, x)
    }
    fn prepare_jacobians(
        &mut self,
    ) -> Result<
        Option<std::sync::Arc<largestep::sparse::Bsr3Pattern>>,
        largestep::sparse::SparseError,
    > {
        self.sys.prepare_jacobians()
    }
    fn force_jacobians(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut largestep::sparse::Bsr3,
        dfdv: Option<&mut largestep::sparse::Bsr3>,
    ) -> Result<(), IntegrateError> {
        self.jacobians += 1;
        self.sys.force_jacobians(t, x, v, f, dfdx, dfdv)
    }
}

/// An implicit step builds its Jacobian with its first residual (the forces come with it),
/// so a step costs one assembly and one force evaluation per Newton iteration, not one
/// more; a step after one that needed no iteration (at rest) builds none.
#[test]
fn an_implicit_step_builds_its_jacobian_with_its_first_residual() {
    let h = 0.01;
    for method in [Method::BackwardEuler, Method::ImplicitMidpoint] {
        let mut sys = Counted {
            sys: Pendulum::new(9.81),
            forces: 0,
            jacobians: 0,
        };
        let mut s = settings(method, LinearSolverKind::Cholesky);
        s.reuse_jacobian = 1;
        let mut st = MechStepper::new(s, &mut sys).unwrap();
        let (mut x, mut v) = ([1.0, 0.0, 0.0], [0.0; 3]);
        for k in 0..20 {
            let (f0, j0) = (sys.forces, sys.jacobians);
            let info = st.step(&mut sys, k as f64 * h, &mut x, &mut v, h).unwrap();
            assert!(info.newton_iterations > 0, "{method:?} step {k}");
            assert_eq!(sys.jacobians - j0, 1, "{method:?} step {k}");
            assert_eq!(
                sys.forces - f0,
                info.newton_iterations,
                "{method:?} step {k}"
            );
        }
        // At rest: Newton has nothing to do, and after the first such step no Jacobian
        // is built.
        let (mut x, mut v) = ([0.0; 3], [0.0; 3]);
        for k in 0..3 {
            let (f0, j0) = (sys.forces, sys.jacobians);
            let info = st.step(&mut sys, k as f64 * h, &mut x, &mut v, h).unwrap();
            assert_eq!(info.newton_iterations, 0);
            let expected = if k == 0 { (0, 1) } else { (1, 0) };
            assert_eq!(
                (sys.forces - f0, sys.jacobians - j0),
                expected,
                "at rest, step {k}"
            );
        }
    }
}

/// A particle kicked by a force for its first step only (backward Euler evaluates it at
/// the step's end, t = 0.1 s), whose forces are not finite beyond x = 0.25 m (as an
/// element model's past inversion): Newton's first guess from the last step's velocity
/// change (`MechSettings::predictor`) lands there in the second step, and the step is
/// then solved again from v0 instead of failing.
#[test]
fn a_first_guess_with_no_finite_forces_falls_back_to_the_start_velocity() {
    use largestep::sparse::{Bsr3, Bsr3Pattern, SparseError};
    use std::sync::Arc;
    struct Kicked {
        mass: [f64; 1],
        pattern: Arc<Bsr3Pattern>,
        forces: usize,
    }
    impl Mechanical for Kicked {
        fn vertex_count(&self) -> usize {
            1
        }
        fn mass(&self) -> &[f64] {
            &self.mass
        }
        fn force(&mut self, t: f64, x: &[f64], _v: &[f64], f: &mut [f64]) {
            self.forces += 1;
            f.fill(0.0);
            f[0] = if x[0] > 0.25 {
                f64::NAN
            } else if t < 0.15 {
                10.0
            } else {
                0.0
            };
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
            dfdx.set_zero();
            Ok(())
        }
    }
    for predictor in [true, false] {
        let mut sys = Kicked {
            mass: [1.0],
            pattern: Arc::new(Bsr3Pattern::diagonal(1)),
            forces: 0,
        };
        let mut s = settings(Method::BackwardEuler, LinearSolverKind::Cholesky);
        s.predictor = predictor;
        let mut st = MechStepper::new(s, &mut sys).unwrap();
        let (mut x, mut v) = ([0.0; 3], [0.0; 3]);
        let h = 0.1;
        st.step(&mut sys, 0.0, &mut x, &mut v, h).unwrap();
        assert!((v[0] - 1.0).abs() < 1e-12 && (x[0] - 0.1).abs() < 1e-12);
        let before = sys.forces;
        st.step(&mut sys, h, &mut x, &mut v, h).unwrap();
        assert!((v[0] - 1.0).abs() < 1e-12, "{predictor}: v {}", v[0]);
        assert!((x[0] - 0.2).abs() < 1e-12, "{predictor}: x {}", x[0]);
        // With the predictor: the guess (not finite), then the step from v0.
        assert_eq!(sys.forces - before, if predictor { 2 } else { 1 });
    }
}
