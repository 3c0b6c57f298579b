//! # largestep-kernels
//!
//! The hot loops of largestep as pure functions over flat structure-of-arrays slices.
//!
//! Conventions (see `docs/architecture.md` in the workspace):
//! - A set of n 3-vectors is one `&[f64]` of length 3n, **component-major**:
//!   `[x0..x(n-1), y0..y(n-1), z0..z(n-1)]`.
//! - Outputs come first, then inputs, then a `Copy` parameter struct where there is one.
//! - Kernels never allocate, never do I/O and never return errors: lengths are checked
//!   once at entry with `assert!`, other preconditions are documented.
//! - Every SIMD kernel (`wide::f64x4`) has a scalar twin with the same signature and the
//!   suffix `_scalar`; property tests hold the two together.
//! - Parallel drivers (suffix `_par`) split work into fixed ranges decided by the data,
//!   never by the number of threads, so their results are bitwise independent of it.

pub mod bsr3;
pub mod interp;
pub mod par;
pub mod spring;
pub mod vec;

/// Rows (or vertices) per task in the parallel drivers. Fixed, so that partial sums are
/// formed over the same ranges whatever the thread count (determinism), and large enough
/// (a few hundred kB of matrix per task) that scheduling costs stay far below the work.
pub const PAR_CHUNK: usize = 2048;
