//! Time integration of first-order systems `y' = G(t, y)` ([`OdeStepper`]) and of
//! mechanical systems `M x'' = f(x, v)` ([`MechStepper`]).
//!
//! | method | kind | order | systems |
//! |---|---|---|---|
//! | `explicit-euler` | explicit | 1 | both |
//! | `midpoint` (RK2) | explicit | 2 | both |
//! | `rk4` | explicit | 4 | both |
//! | `symplectic-euler` | explicit, symplectic | 1 | mechanical |
//! | `backward-euler` | implicit, Newton + line search | 1 | both |
//! | `linearized-backward-euler` | implicit, one Newton step (Baraff-Witkin 1998) | 1 | both |
//! | `implicit-midpoint` | implicit, Newton, symplectic | 2 | both |
//! | `newmark` (beta 1/4, gamma 1/2) | implicit, Newton | 2 | mechanical |
//!
//! Explicit methods never build a matrix; implicit mechanical methods assemble the model's
//! Jacobians into Bsr3 matrices over the model's pattern and solve with PCG or sparse
//! Cholesky. Every step ends with a finiteness check that turns a blow-up into
//! [`IntegrateError::NonFinite`] with the step number and a hint.

mod explicit;
mod mechanical;
mod ode;

pub use mechanical::{
    gravity_energy, gravity_forces, kinetic_energy, kinetic_energy_matrix, LinearSolverKind,
    MechSettings, MechState, MechStepper, Mechanical, AUTO_CHOLESKY_MAX_DOFS,
};
pub use ode::{OdeStepper, OdeSystem};

use crate::solve::SolveError;

/// An integration method (see the module docs for the table).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Method {
    /// Forward Euler.
    ExplicitEuler,
    /// The explicit midpoint rule (second-order Runge-Kutta).
    Midpoint,
    /// Classical fourth-order Runge-Kutta.
    Rk4,
    /// Symplectic (semi-implicit) Euler: velocity first, then position with the new velocity.
    SymplecticEuler,
    /// Backward Euler solved by Newton's method with a line search.
    BackwardEuler,
    /// Backward Euler linearised once (one Newton step): Baraff and Witkin 1998, eq. 16.
    LinearizedBackwardEuler,
    /// The implicit midpoint rule, solved by Newton's method.
    ImplicitMidpoint,
    /// Newmark with beta = 1/4, gamma = 1/2 (average acceleration), solved by Newton.
    Newmark,
}

impl Method {
    /// Every method, in the order of the module table.
    pub const ALL: [Method; 8] = [
        Method::ExplicitEuler,
        Method::Midpoint,
        Method::Rk4,
        Method::SymplecticEuler,
        Method::BackwardEuler,
        Method::LinearizedBackwardEuler,
        Method::ImplicitMidpoint,
        Method::Newmark,
    ];

    /// The canonical name used in scene files and reports.
    pub fn name(self) -> &'static str {
        match self {
            Method::ExplicitEuler => "explicit-euler",
            Method::Midpoint => "midpoint",
            Method::Rk4 => "rk4",
            Method::SymplecticEuler => "symplectic-euler",
            Method::BackwardEuler => "backward-euler",
            Method::LinearizedBackwardEuler => "linearized-backward-euler",
            Method::ImplicitMidpoint => "implicit-midpoint",
            Method::Newmark => "newmark",
        }
    }

    /// Parses a canonical name or a common alias (`euler`, `rk2`, `baraff-witkin`, ...).
    pub fn from_name(s: &str) -> Option<Self> {
        let s = s.trim().to_ascii_lowercase().replace('_', "-");
        Some(match s.as_str() {
            "explicit-euler" | "euler" | "forward-euler" => Method::ExplicitEuler,
            "midpoint" | "rk2" | "explicit-midpoint" => Method::Midpoint,
            "rk4" => Method::Rk4,
            "symplectic-euler" | "semi-implicit-euler" => Method::SymplecticEuler,
            "backward-euler" | "implicit-euler" => Method::BackwardEuler,
            "linearized-backward-euler" | "linearised-backward-euler" | "baraff-witkin" => {
                Method::LinearizedBackwardEuler
            }
            "implicit-midpoint" => Method::ImplicitMidpoint,
            "newmark" => Method::Newmark,
            _ => return None,
        })
    }

    /// Canonical names, comma-separated (for error messages).
    pub fn names() -> String {
        Method::ALL.map(Method::name).join(", ")
    }

    /// Whether the method solves a system (and so needs Jacobians).
    pub fn is_implicit(self) -> bool {
        matches!(
            self,
            Method::BackwardEuler
                | Method::LinearizedBackwardEuler
                | Method::ImplicitMidpoint
                | Method::Newmark
        )
    }

    /// Whether the method iterates Newton to a tolerance (backward Euler, implicit
    /// midpoint, Newmark; the linearised backward Euler takes one step).
    pub fn is_newton(self) -> bool {
        matches!(
            self,
            Method::BackwardEuler | Method::ImplicitMidpoint | Method::Newmark
        )
    }

    /// Nominal order of accuracy.
    pub fn order(self) -> u32 {
        match self {
            Method::ExplicitEuler
            | Method::SymplecticEuler
            | Method::BackwardEuler
            | Method::LinearizedBackwardEuler => 1,
            Method::Midpoint | Method::ImplicitMidpoint | Method::Newmark => 2,
            Method::Rk4 => 4,
        }
    }

    /// Whether the method applies to general first-order systems (the others need the
    /// position/velocity split of a mechanical system).
    pub fn supports_first_order(self) -> bool {
        !matches!(self, Method::SymplecticEuler | Method::Newmark)
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What one step reports.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepInfo {
    /// Newton iterations (0 for explicit methods, 1 for the linearised step).
    pub newton_iterations: usize,
    /// Linear-solver iterations (PCG) summed over the step.
    pub linear_iterations: usize,
    /// Final relative residual of the last linear solve (0 when none).
    pub residual: f64,
    /// Wall time of the linear solves (s), including Cholesky factorizations: the rest
    /// of an implicit step is mostly force and Jacobian assembly.
    pub solve_seconds: f64,
}

/// Integration failures.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IntegrateError {
    /// The state became NaN or infinite.
    #[error("step {step}: {field} is not finite (the simulation blew up); {hint}")]
    NonFinite {
        /// Step number (1-based) at which it happened.
        step: u64,
        /// Which field: `position`, `velocity`, `state`, `force`.
        field: &'static str,
        /// What to try.
        hint: &'static str,
    },
    /// A solver inside an implicit step failed.
    #[error("step {step} ({method}): {source}{}", if hint.is_empty() { String::new() } else { format!("; {hint}") })]
    Solve {
        /// Step number (1-based).
        step: u64,
        /// The method.
        method: Method,
        /// The solver's error.
        source: SolveError,
        /// What to try (may be empty).
        hint: &'static str,
    },
    /// A static solve (equilibrium under a load increment) failed.
    #[error("load increment {increment} of {increments} (static equilibrium): {source}; apply the load in more increments, or pin the body so that it cannot move freely")]
    Static {
        /// The increment (1-based).
        increment: usize,
        /// Increments in all.
        increments: usize,
        /// The solver's error.
        source: SolveError,
    },
    /// Step-size control gave up: the step still failed at the smallest size allowed.
    #[error("step {step}: still failing after halving the time step {halvings} times (last try dt = {dt:e} s): {why}")]
    StepControl {
        /// Steps taken so far (sub-steps included).
        step: u64,
        /// Halvings allowed (all used).
        halvings: u32,
        /// The last step size tried (s).
        dt: f64,
        /// Why the last try failed (the solver's error, with its iterations and residual,
        /// or the strain).
        why: String,
    },
    /// Building the Jacobian structures failed.
    #[error("Jacobian structure: {0}")]
    Sparse(crate::sparse::SparseError),
    /// The method cannot run on this system.
    #[error("{method} cannot be used here: {reason}")]
    Unsupported {
        /// The method.
        method: Method,
        /// Why.
        reason: &'static str,
    },
    /// The state grew out of all proportion (a blow-up caught before it is not finite).
    #[error("step {step}: a vertex moves at {speed:.3e} m/s, {:.3e} m in one step of {dt:e} s, more than ten times the model's size ({size:.3} m): the simulation is blowing up; {hint}", speed * dt)]
    Diverged {
        /// Step number (1-based, sub-steps included).
        step: u64,
        /// The largest speed (m/s).
        speed: f64,
        /// The step (s).
        dt: f64,
        /// The model's initial size: the diagonal of its bounding box, at least 1 m.
        size: f64,
        /// What to try.
        hint: &'static str,
    },
    /// A system's own step failed (a fluid's CFL refusal, a non-finite cell), with its
    /// message naming where.
    #[error("{why}")]
    Failed {
        /// Step number (1-based).
        step: u64,
        /// What failed and where, with what to try.
        why: String,
    },
    /// A state whose size does not match the model's.
    #[error("the state has {got} vertices, the model {expected}")]
    StateSize {
        /// Vertices in the model.
        expected: usize,
        /// Vertices in the positions or velocities given.
        got: usize,
    },
}

/// Wraps a solver error with the step and method it happened in, and a hint for
/// Newton failures in mechanical systems.
pub(crate) fn solve_error(
    step: u64,
    method: Method,
    mechanical: bool,
) -> impl Fn(SolveError) -> IntegrateError {
    move |source| {
        let newton = matches!(
            source,
            SolveError::NotConverged { .. } | SolveError::LineSearchFailed { .. }
        );
        let hint = if mechanical && newton && method != Method::LinearizedBackwardEuler {
            HINT_NEWTON
        } else {
            ""
        };
        IntegrateError::Solve {
            step,
            method,
            source,
            hint,
        }
    }
}

/// Newton converges only linearly when the definiteness fix changes the Jacobian a lot
/// (buckling sheets, crushed springs).
pub(crate) const HINT_NEWTON: &str = "Newton converges slowly where the definiteness fix changes the Jacobian (buckling, compression): \
     loosen [solver] newton_tolerance or raise newton_max_iterations, reduce dt, or use \
     linearized-backward-euler (one solve per step)";

/// What to try when an explicit method blows up.
pub const HINT_EXPLICIT: &str =
    "reduce dt, or use an implicit integrator (backward-euler, implicit-midpoint, newmark)";
/// What to try when an implicit method blows up.
pub const HINT_IMPLICIT: &str =
    "reduce dt, or check the inputs for extreme values (stiffness, mass)";

/// What to try when `method` blows up.
pub fn hint(method: Method) -> &'static str {
    if method.is_implicit() {
        HINT_IMPLICIT
    } else {
        HINT_EXPLICIT
    }
}
