//! Preconditioned conjugate gradients with the Baraff-Witkin constraint filter.
//!
//! The modified PCG of Baraff and Witkin (1998, section 5.3) with target `z = 0`: the
//! initial guess, the residual, every search direction and every `A p` are filtered, so the
//! iterate satisfies the constraints exactly at every iteration, whatever the count.
//!
//! Each iteration is three passes over memory (see `largestep-kernels::vec`):
//! 1. `q = A p` with `p . q` fused into the product,
//! 2. `x += alpha p`, `r -= alpha q`, `z = P^-1 r`, returning `r . z` and `r . r`,
//! 3. `p = z + beta p` (Jacobi recomputes `z = d * r` here instead of storing it).
//!
//! Stopping test: `|S r| <= tolerance |S b|` (relative 2-norm of the filtered residual).
//! All reductions use fixed chunks and a fixed tree, so iterates are bitwise the same for
//! any number of threads.

use super::dense::{inverse_spd3, positive};
use super::{
    amg::SmoothedAggregation, filter::Filter, multigrid::Multigrid, SolveError, SolveInfo,
};
use crate::sparse::Bsr3;
use largestep_kernels::sparse::bsr3_spmv_dot_par;
use largestep_kernels::vec as kv;
use std::time::Instant;

/// Preconditioner choice.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Preconditioner {
    /// None (plain CG).
    None,
    /// Inverse of the scalar diagonal.
    Jacobi,
    /// Inverse of each vertex's 3x3 diagonal block (the default: it absorbs the
    /// anisotropy of springs and elements at a vertex).
    #[default]
    BlockJacobi,
    /// One V-cycle of aggregation multigrid ([`Multigrid`]): several times the work of
    /// block Jacobi per iteration, and far fewer iterations on stiff systems (the draped
    /// 100x100 cloth: about 10 instead of 100 to 160).
    Multigrid,
    /// One V-cycle of smoothed aggregation multigrid with rigid-body modes
    /// ([`SmoothedAggregation`]): for 3-D elasticity (the FEM), where its iteration
    /// count stays nearly flat under refinement. Give it the vertex positions
    /// ([`Pcg::set_coordinates`]) for the rotations.
    SmoothedAggregation,
}

/// PCG settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PcgParams {
    /// Relative residual to reach, `|S r| / |S b|`.
    pub tolerance: f64,
    /// Iteration limit.
    pub max_iterations: usize,
    /// Preconditioner.
    pub preconditioner: Preconditioner,
}

impl Default for PcgParams {
    fn default() -> Self {
        Self {
            tolerance: 1e-8,
            max_iterations: 1000,
            preconditioner: Preconditioner::BlockJacobi,
        }
    }
}

/// A PCG solver with its workspace for systems of n vertices (3n unknowns). Allocates
/// once, in [`Pcg::new`].
#[derive(Clone, Debug)]
pub struct Pcg {
    n: usize,
    params: PcgParams,
    r: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
    z: Vec<f64>,
    d: Vec<f64>,
    mg: Box<Multigrid>,
    sa: Box<SmoothedAggregation>,
    /// The inexact Newton forcing term in force ([`Pcg::set_forcing`]).
    forcing: Option<f64>,
    /// Products with the multigrid's `f32` copy of the matrix ([`Pcg::set_rounded_products`]).
    rounded: bool,
}

impl Pcg {
    /// Workspace for n vertices.
    pub fn new(n: usize, params: PcgParams) -> Self {
        let block = matches!(
            params.preconditioner,
            Preconditioner::BlockJacobi
                | Preconditioner::Multigrid
                | Preconditioner::SmoothedAggregation
        );
        Self {
            n,
            params,
            r: vec![0.0; 3 * n],
            p: vec![0.0; 3 * n],
            q: vec![0.0; 3 * n],
            z: vec![0.0; if block { 3 * n } else { 0 }],
            d: vec![
                0.0;
                match params.preconditioner {
                    Preconditioner::None
                    | Preconditioner::Multigrid
                    | Preconditioner::SmoothedAggregation => 0,
                    Preconditioner::Jacobi => 3 * n,
                    Preconditioner::BlockJacobi => 6 * n,
                }
            ],
            mg: Box::new(Multigrid::new()),
            sa: Box::new(SmoothedAggregation::new()),
            forcing: None,
            rounded: false,
        }
    }

    /// The settings.
    pub fn params(&self) -> &PcgParams {
        &self.params
    }

    /// Changes tolerance and iteration limit (the preconditioner is fixed at creation).
    pub fn set_limits(&mut self, tolerance: f64, max_iterations: usize) {
        self.params.tolerance = tolerance;
        self.params.max_iterations = max_iterations;
    }

    /// Loosens the next solves' relative tolerance to `eta` (an inexact Newton forcing
    /// term, [`crate::solve::NewtonParams::forcing`]) where `eta` exceeds the configured
    /// tolerance, which stays the floor; `None` restores the configured tolerance.
    pub fn set_forcing(&mut self, eta: Option<f64>) {
        self.forcing = eta;
    }

    /// With `true`, and a multigrid preconditioner ([`Preconditioner::Multigrid`] or
    /// [`Preconditioner::SmoothedAggregation`]), the next solves' products `A p` read the
    /// copy of A rounded to `f32` that the V-cycle's fine level reads already (when every
    /// value fits): PCG then solves the rounded system, whose entries differ from A's by
    /// a relative 6e-8 at most, and moves half the matrix bytes an iteration. For
    /// systems whose solution is only a step direction checked against a residual in
    /// `f64` (Newton's, [`crate::integrate::MechSettings::rounded_products`]); not for a
    /// solve that must reach A's own residual below about 1e-7. Where the rounded system
    /// is not positive definite (an ill-conditioned A) the solve is done again with A's
    /// values. The other preconditioners keep no copy and ignore it.
    pub fn set_rounded_products(&mut self, rounded: bool) {
        self.rounded = rounded;
    }

    /// The multigrid hierarchy (empty unless the preconditioner is
    /// [`Preconditioner::Multigrid`] and a solve has run).
    pub fn multigrid(&self) -> &Multigrid {
        &self.mg
    }

    /// The smoothed aggregation hierarchy (empty unless the preconditioner is
    /// [`Preconditioner::SmoothedAggregation`] and a solve has run).
    pub fn smoothed_aggregation(&self) -> &SmoothedAggregation {
        &self.sa
    }

    /// The vertex positions (component-major, `3n`) for the rotations in the smoothed
    /// aggregation's coarse spaces, used by the next solve; ignored by the other
    /// preconditioners.
    pub fn set_coordinates(&mut self, x: &[f64]) {
        if self.params.preconditioner == Preconditioner::SmoothedAggregation {
            self.sa.set_coordinates(x);
        }
    }

    /// Bytes one iteration moves at least: the matrix product and the two vector passes,
    /// plus the V-cycle's passes over the level matrices with multigrid.
    pub fn iteration_bytes(&self, a: &Bsr3) -> usize {
        let n = self.n;
        let vec_doubles = match self.params.preconditioner {
            Preconditioner::None => 9 * 3 * n,
            Preconditioner::Jacobi => 11 * 3 * n,
            Preconditioner::BlockJacobi
            | Preconditioner::Multigrid
            | Preconditioner::SmoothedAggregation => 36 * n,
        };
        let cycle = match self.params.preconditioner {
            Preconditioner::Multigrid => self.mg.cycle_bytes(a),
            Preconditioner::SmoothedAggregation => self.sa.cycle_bytes(a),
            _ => 0,
        };
        a.as_kernel().spmv_bytes() + 8 * vec_doubles + cycle
    }

    /// Builds the preconditioner for `a`; with `full` false (a re-solve, see
    /// [`Pcg::resolve`]) multigrid keeps its coarse levels.
    fn setup(&mut self, a: &Bsr3, filter: Option<&Filter>, full: bool) -> Result<(), SolveError> {
        let n = self.n;
        let diag = a.pattern().diag_slots();
        // The matrix is projected under the filter (see `solve`): pinned vertices' blocks
        // are the identity and contact vertices' are definite, so no vertex needs a
        // special case here.
        match self.params.preconditioner {
            Preconditioner::None => {}
            Preconditioner::Multigrid if full => self.mg.setup(a, filter)?,
            Preconditioner::Multigrid => self.mg.refresh_fine(a, filter)?,
            Preconditioner::SmoothedAggregation if full => self.sa.setup(a, filter)?,
            Preconditioner::SmoothedAggregation => self.sa.refresh_fine(a, filter)?,
            Preconditioner::Jacobi => {
                for (i, &slot) in diag.iter().enumerate() {
                    let b = a.block(slot as usize);
                    for c in 0..3 {
                        let v = b[4 * c];
                        if !positive(v) {
                            return Err(not_pd("diagonal", c * n + i, v));
                        }
                        self.d[c * n + i] = 1.0 / v;
                    }
                }
            }
            Preconditioner::BlockJacobi => {
                for (i, &slot) in diag.iter().enumerate() {
                    let b = a.block(slot as usize);
                    let inv = inverse_spd3(b)
                        .ok_or_else(|| not_pd("diagonal block of vertex", i, b[0]))?;
                    for (k, v) in inv.into_iter().enumerate() {
                        self.d[k * n + i] = v;
                    }
                }
            }
        }
        Ok(())
    }

    /// Solves `A x = b` (with the filter: `S A S x = S b`, `(I - S) x = 0`). `x` holds the
    /// initial guess on entry (it is filtered first) and the solution on return.
    ///
    /// With a filter, `a` is projected in place first, `A <- S A S + (I - S)`
    /// ([`Filter::project_matrix`]): the filtered system is the same, and the
    /// preconditioner is built from the constrained problem (pinned vertices fixed,
    /// contact vertices free only along their surface) instead of the free one.
    pub fn solve(
        &mut self,
        a: &mut Bsr3,
        b: &[f64],
        x: &mut [f64],
        filter: Option<&Filter>,
    ) -> Result<SolveInfo, SolveError> {
        self.solve_with(a, b, x, filter, true)
    }

    /// [`Pcg::solve`] of a system solved again after its filter lost a few constraints
    /// (a one-sided contact freed, `crate::solve::Filter::approach`): multigrid keeps the
    /// coarse levels of the previous solve ([`Multigrid::refresh_fine`]), whose Galerkin
    /// products cost as much as the re-solve's iterations; block Jacobi and Jacobi are
    /// remade (one pass over the diagonal). Any fixed symmetric positive definite
    /// preconditioner leaves PCG exact. Call only after a successful [`Pcg::solve`] of a
    /// matrix on the same pattern.
    pub fn resolve(
        &mut self,
        a: &mut Bsr3,
        b: &[f64],
        x: &mut [f64],
        filter: Option<&Filter>,
    ) -> Result<SolveInfo, SolveError> {
        self.solve_with(a, b, x, filter, false)
    }

    fn solve_with(
        &mut self,
        a: &mut Bsr3,
        b: &[f64],
        x: &mut [f64],
        filter: Option<&Filter>,
        full: bool,
    ) -> Result<SolveInfo, SolveError> {
        let start = Instant::now();
        let n = self.n;
        assert_eq!(a.n(), n, "matrix and solver sizes differ");
        assert!(b.len() == 3 * n && x.len() == 3 * n);
        if let Some(f) = filter {
            f.project_matrix(a);
        }
        let a = &*a;
        self.setup(a, filter, full)?;
        let rounded = self.rounded.then_some(self.params.preconditioner);
        let result = match self.iterate(a, b, x, filter, rounded) {
            // Rounding can cost an ill-conditioned matrix its definiteness (seen on a
            // steel beam with Poisson's ratio 0.49): then A's own values, from zero, with
            // the same preconditioner. The failed iterations count.
            Err(
                SolveError::NotPositiveDefinite { at: spent, .. }
                | SolveError::NonFinite {
                    iteration: spent, ..
                },
            ) if rounded.is_some() => {
                x.fill(0.0);
                self.iterate(a, b, x, filter, None).map(|info| SolveInfo {
                    iterations: info.iterations + spent,
                    ..info
                })
            }
            result => result,
        };
        result.map(|info| SolveInfo {
            seconds: start.elapsed().as_secs_f64(),
            ..info
        })
    }

    /// PCG proper, with the preconditioner set up for `a`: the products with the `f32`
    /// copy of the multigrid `rounded` names, if any. The reported time is left to the
    /// caller (zero here).
    fn iterate(
        &mut self,
        a: &Bsr3,
        b: &[f64],
        x: &mut [f64],
        filter: Option<&Filter>,
        rounded: Option<Preconditioner>,
    ) -> Result<SolveInfo, SolveError> {
        let filt = |v: &mut [f64]| {
            if let Some(f) = filter {
                f.apply(v)
            }
        };
        let pre = self.params.preconditioner;
        filt(x);
        // r = S (b - A x); a zero initial guess (the usual case) needs no product.
        // |S b| is measured in p, which is overwritten below.
        // Every product of one solve reads the same matrix (see `set_rounded_products`), as
        // CG's recurrences assume.
        if x.iter().any(|&v| v != 0.0) {
            product(rounded, &self.mg, &self.sa, a, &mut self.q, x);
            kv::waxpy(&mut self.r, b, -1.0, &self.q);
        } else {
            self.r.copy_from_slice(b);
        }
        filt(&mut self.r);
        self.p.copy_from_slice(b);
        filt(&mut self.p);
        let bnorm = kv::norm2(&self.p);
        if !bnorm.is_finite() || !kv::all_finite(x) {
            return Err(SolveError::NonFinite {
                what: "right-hand side or initial guess",
                iteration: 0,
            });
        }
        if bnorm == 0.0 {
            x.fill(0.0);
            return Ok(SolveInfo {
                iterations: 0,
                residual: 0.0,
                seconds: 0.0,
            });
        }
        // A guess worse than none (its residual larger than the zero guess's, as when
        // contacts change between implicit steps) is dropped, and PCG starts from zero.
        // On the draped 100x100 cloth with multigrid: 16.8 iterations per step instead of
        // 18.4 with the previous step's answer always kept.
        if kv::norm2(&self.r) > bnorm {
            x.fill(0.0);
            self.r.copy_from_slice(&self.p);
        }
        // p = S P^-1 r
        let mut rz = match pre {
            Preconditioner::None => {
                self.p.copy_from_slice(&self.r);
                kv::dot(&self.r, &self.r)
            }
            Preconditioner::Jacobi => {
                for ((p, r), d) in self.p.iter_mut().zip(&self.r).zip(&self.d) {
                    *p = d * r;
                }
                kv::dot(&self.r, &self.p)
            }
            Preconditioner::BlockJacobi => {
                let [rz, _] = kv::block_jacobi_apply(&mut self.z, &self.r, &self.d);
                self.p.copy_from_slice(&self.z);
                rz
            }
            Preconditioner::Multigrid => {
                self.mg.apply(a, &self.r, &mut self.z, filter);
                self.p.copy_from_slice(&self.z);
                kv::dot_par(&self.r, &self.z)
            }
            Preconditioner::SmoothedAggregation => {
                self.sa.apply(a, &self.r, &mut self.z, filter);
                self.p.copy_from_slice(&self.z);
                kv::dot_par(&self.r, &self.z)
            }
        };
        filt(&mut self.p);
        let mut residual = kv::norm2(&self.r) / bnorm;
        let tol = self
            .forcing
            .map_or(self.params.tolerance, |eta| eta.max(self.params.tolerance));
        if residual <= tol {
            return Ok(SolveInfo {
                iterations: 0,
                residual,
                seconds: 0.0,
            });
        }
        for it in 1..=self.params.max_iterations {
            // p is filtered, so p . S A p = p . A p: the fused dot stays valid.
            let pq = product(rounded, &self.mg, &self.sa, a, &mut self.q, &self.p);
            filt(&mut self.q);
            if !positive(pq) {
                return Err(if pq.is_nan() {
                    SolveError::NonFinite {
                        what: "curvature p.Ap",
                        iteration: it,
                    }
                } else {
                    not_pd("curvature p.Ap at iteration", it, pq)
                });
            }
            let alpha = rz / pq;
            let [rz_new, rr] = match pre {
                Preconditioner::BlockJacobi => kv::pcg_update_block_jacobi_par(
                    x,
                    &mut self.r,
                    &mut self.z,
                    &self.p,
                    &self.q,
                    &self.d,
                    alpha,
                ),
                Preconditioner::Jacobi => kv::pcg_update_jacobi_par(
                    x,
                    &mut self.r,
                    &self.p,
                    &self.q,
                    Some(&self.d),
                    alpha,
                ),
                Preconditioner::None => {
                    kv::pcg_update_jacobi_par(x, &mut self.r, &self.p, &self.q, None, alpha)
                }
                Preconditioner::Multigrid | Preconditioner::SmoothedAggregation => {
                    let [_, rr] =
                        kv::pcg_update_jacobi_par(x, &mut self.r, &self.p, &self.q, None, alpha);
                    // The V-cycle only when the test below does not stop here.
                    if rr.sqrt() / bnorm <= tol {
                        [rr, rr]
                    } else {
                        if pre == Preconditioner::Multigrid {
                            self.mg.apply(a, &self.r, &mut self.z, filter);
                        } else {
                            self.sa.apply(a, &self.r, &mut self.z, filter);
                        }
                        [kv::dot_par(&self.r, &self.z), rr]
                    }
                }
            };
            residual = rr.sqrt() / bnorm;
            if !residual.is_finite() || !rz_new.is_finite() {
                return Err(SolveError::NonFinite {
                    what: "residual",
                    iteration: it,
                });
            }
            if residual <= tol {
                return Ok(SolveInfo {
                    iterations: it,
                    residual,
                    seconds: 0.0,
                });
            }
            let beta = rz_new / rz;
            rz = rz_new;
            match pre {
                Preconditioner::BlockJacobi
                | Preconditioner::Multigrid
                | Preconditioner::SmoothedAggregation => kv::xpay_par(&mut self.p, &self.z, beta),
                Preconditioner::Jacobi => {
                    kv::pcg_direction_jacobi_par(&mut self.p, &self.r, Some(&self.d), beta)
                }
                Preconditioner::None => {
                    kv::pcg_direction_jacobi_par(&mut self.p, &self.r, None, beta)
                }
            }
            filt(&mut self.p);
        }
        Err(SolveError::NotConverged {
            iterations: self.params.max_iterations,
            residual,
            tolerance: tol,
        })
    }
}

/// `q = A p`, returning `p . q`, with A's `f32` copy in the multigrid preconditioner
/// `rounded` names (when it has one; see [`Pcg::set_rounded_products`]), else with A.
fn product(
    rounded: Option<Preconditioner>,
    mg: &Multigrid,
    sa: &SmoothedAggregation,
    a: &Bsr3,
    q: &mut [f64],
    p: &[f64],
) -> f64 {
    let a32 = match rounded {
        Some(Preconditioner::Multigrid) => mg.fine32(a),
        Some(Preconditioner::SmoothedAggregation) => sa.fine32(a),
        _ => None,
    };
    match a32 {
        Some(a32) => bsr3_spmv_dot_par(q, a32, p),
        None => a.spmv_dot(q, p),
    }
}

/// `v > 0`, false for NaN: the form every definiteness test here needs.
fn not_pd(what: &'static str, at: usize, value: f64) -> SolveError {
    SolveError::NotPositiveDefinite { what, at, value }
}
