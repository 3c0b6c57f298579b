//! Linear and nonlinear solvers. Each returns `Result<Info, SolveError>`; the errors carry
//! the numbers a user needs to act (iteration, residual, index, value).
//!
//! - [`Pcg`]: preconditioned conjugate gradients on a Bsr3 matrix, with Jacobi or
//!   block-Jacobi or aggregation-multigrid ([`Multigrid`]) preconditioning and the
//!   Baraff-Witkin constraint filter ([`Filter`]).
//! - [`SparseCholesky`]: faer's supernodal/simplicial LL^T with one symbolic analysis (AMD
//!   ordering) reused by every numeric refactorization, into buffers owned here.
//! - [`Newton`]: Newton's method with a backtracking (Armijo) line search on `|F|^2 / 2`.
//! - [`dense`]: a small dense LU with partial pivoting for tiny Jacobians.

pub mod amg;
pub mod cholesky;
pub mod dense;
pub mod eigen;
pub mod filter;
pub mod krylov;
pub mod multigrid;
pub mod newton;
pub mod pcg;
pub mod poisson;

pub use amg::SmoothedAggregation;
pub use cholesky::SparseCholesky;
pub use eigen::{lowest_modes, EigenParams, Mass, Modes};
pub use filter::{Approach, Filter};
pub use multigrid::Multigrid;
pub use newton::{Newton, NewtonParams, NewtonProblem};
pub use pcg::{Pcg, PcgParams, Preconditioner};
pub use poisson::{CellKind, GridPoisson, PoissonParams, PoissonPreconditioner, Precision, Side};

/// What a solver reports on success.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SolveInfo {
    /// Iterations taken (0 for direct solves).
    pub iterations: usize,
    /// Final relative residual `|r| / |b|` (of the filtered system where there is one).
    pub residual: f64,
    /// Wall time in seconds.
    pub seconds: f64,
}

/// Solver failures.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SolveError {
    /// The iteration limit was reached first.
    #[error("not converged after {iterations} iterations: residual {residual:.3e} > tolerance {tolerance:.1e}")]
    NotConverged {
        /// Iterations taken.
        iterations: usize,
        /// Residual reached (PCG: relative `|r|/|b|`; Newton: `|F|`).
        residual: f64,
        /// Residual asked for (same measure).
        tolerance: f64,
    },
    /// The matrix is not positive definite (a non-positive pivot, diagonal or curvature).
    #[error("matrix is not positive definite: {what} {at}{}; the stiffness Jacobian may be indefinite (enable the definiteness fix) or the step too large (reduce dt)", value_suffix(*.value))]
    NotPositiveDefinite {
        /// Which quantity was not positive (`pivot`, `diagonal`, `curvature p.Ap`).
        what: &'static str,
        /// Where: scalar index, vertex or iteration.
        at: usize,
        /// Its value (NaN where the solver does not report it).
        value: f64,
    },
    /// A zero pivot in a dense LU.
    #[error("singular Jacobian (zero pivot in column {column}); the implicit equation may have no solution here (reduce the step size)")]
    Singular {
        /// Column of the zero pivot.
        column: usize,
    },
    /// Newton's line search found no decrease of the residual.
    #[error("Newton's method stalled at iteration {iteration}: |F| = {residual:.6e} could not be reduced (the implicit equation may have no real solution; reduce the step size)")]
    LineSearchFailed {
        /// Newton iteration.
        iteration: usize,
        /// Residual norm where it stalled.
        residual: f64,
    },
    /// A NaN or infinity appeared.
    #[error("non-finite value in {what} at iteration {iteration}")]
    NonFinite {
        /// The quantity.
        what: &'static str,
        /// Iteration.
        iteration: usize,
    },
    /// faer failed for a reason other than definiteness (out of memory, index overflow).
    #[error("sparse factorization failed: {0}")]
    Factorization(String),
    /// The problem as given cannot be solved (sizes, indices, a matrix that is not
    /// symmetric); the text says what.
    #[error("{0}")]
    Invalid(String),
}

fn value_suffix(v: f64) -> String {
    if v.is_nan() {
        String::new()
    } else {
        format!(" (value {v:.3e})")
    }
}
