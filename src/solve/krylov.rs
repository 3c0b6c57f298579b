//! Matrix-free preconditioned conjugate gradients over plain slices: the Krylov solver of
//! operators that are no assembled matrix (the fluid's implicit viscosity).
//!
//! Hestenes and Stiefel's PCG: `r = b - A x`, `z = M^-1 r`, `p = z`; then per iteration
//! `alpha = r.z / p.Ap`, `x += alpha p`, `r -= alpha Ap`, stop at `|r| <= tol |b|`,
//! `z = M^-1 r`, `p = z + (r.z new / r.z old) p`. Dot products use the fixed-order
//! parallel reduction, so the iterates do not depend on the thread count.

use super::{SolveError, SolveInfo};
use largestep_kernels::vec::dot_par;
use std::time::Instant;

/// Solves `A x = b` from the guess in `x`, with `apply(y, x)` writing `y = A x` and
/// `precondition(z, r)` writing `z = M^-1 r` (both symmetric positive definite), to
/// `|b - A x| <= tolerance |b|` in at most `max_iterations`. `work` holds r, z, p and q,
/// each as long as `x`. Allocates nothing.
pub fn cg(
    apply: &dyn Fn(&mut [f64], &[f64]),
    precondition: &dyn Fn(&mut [f64], &[f64]),
    x: &mut [f64],
    b: &[f64],
    work: [&mut [f64]; 4],
    tolerance: f64,
    max_iterations: usize,
) -> Result<SolveInfo, SolveError> {
    let start = Instant::now();
    let [r, z, p, q] = work;
    let n = x.len();
    if b.len() != n || r.len() != n || z.len() != n || p.len() != n || q.len() != n {
        return Err(SolveError::Invalid(format!(
            "CG vectors of different lengths: x {n}, b {}",
            b.len()
        )));
    }
    apply(q, x);
    for ((ri, bi), qi) in r.iter_mut().zip(b).zip(q.iter()) {
        *ri = bi - qi;
    }
    let bnorm = dot_par(b, b).sqrt();
    let target = tolerance * bnorm;
    let mut rnorm = dot_par(r, r).sqrt();
    let done = |iterations, rnorm: f64| SolveInfo {
        iterations,
        residual: if bnorm > 0.0 { rnorm / bnorm } else { 0.0 },
        seconds: start.elapsed().as_secs_f64(),
    };
    if rnorm <= target || bnorm == 0.0 {
        return Ok(done(0, rnorm));
    }
    precondition(z, r);
    p.copy_from_slice(z);
    let mut rz = dot_par(r, z);
    for it in 1..=max_iterations {
        apply(q, p);
        let pq = dot_par(p, q);
        if pq.is_nan() || pq <= 0.0 {
            return Err(SolveError::NotPositiveDefinite {
                what: "curvature p.Ap",
                at: it,
                value: pq,
            });
        }
        let alpha = rz / pq;
        for (xi, pi) in x.iter_mut().zip(p.iter()) {
            *xi += alpha * pi;
        }
        for (ri, qi) in r.iter_mut().zip(q.iter()) {
            *ri -= alpha * qi;
        }
        rnorm = dot_par(r, r).sqrt();
        if !rnorm.is_finite() {
            return Err(SolveError::NonFinite {
                what: "CG residual",
                iteration: it,
            });
        }
        if rnorm <= target {
            return Ok(done(it, rnorm));
        }
        precondition(z, r);
        let rz_new = dot_par(r, z);
        let beta = rz_new / rz;
        rz = rz_new;
        for (pi, zi) in p.iter_mut().zip(z.iter()) {
            *pi = zi + beta * *pi;
        }
    }
    Err(SolveError::NotConverged {
        iterations: max_iterations,
        residual: rnorm / bnorm,
        tolerance,
    })
}
