//! The lowest modes of the generalized symmetric eigenproblem `K x = lambda M x` (stiffness
//! `K` symmetric positive semidefinite, mass `M` symmetric positive definite, lumped or
//! consistent), for modal analysis and modal sound (issue 16; course notes section 17).
//!
//! - **Dense path** (at most [`EigenParams::dense_max`] free unknowns, 200 by default):
//!   `M = L L^T`,
//!   `C = L^-1 K L^-T`, faer's symmetric eigensolver on C, `x = L^-T y`.
//! - **Sparse path: shift-invert block Lanczos in the M inner product** (Ericsson and
//!   Ruhe, "The spectral transformation Lanczos method", Math. Comp. 35, 1980; Grimes,
//!   Lewis and Simon, "A shifted block Lanczos algorithm for solving sparse symmetric
//!   generalized eigenproblems", SIAM J. Matrix Anal. Appl. 15, 1994): the operator
//!   `(K - sigma M)^-1 M` is self-adjoint in `<x, y>_M = x^T M y`, its eigenvalues are
//!   `theta = 1 / (lambda - sigma)`, so the modes nearest above the shift come first. One
//!   sparse Cholesky of `K - sigma M` serves every product, eight columns at a time (a
//!   solve reads the whole factor from memory, so a block of eight costs about twice one
//!   column). The basis is M-orthogonalised in full at every step, so no ghost copies
//!   appear; a Ritz pair has converged when `|B_j s_i| <= tol theta_i`. A block finds
//!   every copy of an eigenvalue that has fewer copies than it has columns (a free body's
//!   six rigid modes); if a cluster as large as the block turns up, a deflated repeat
//!   looks in the complement of the modes found for more copies. faer's own partial
//!   eigensolver works in the Euclidean inner product, which a consistent M does not give
//!   without its Cholesky factor applied on its own (faer's sparse LLT only solves with
//!   the whole product).
//! - **The shift.** `K` of a free body is singular (six rigid modes), so sigma must lie
//!   below zero; too close to zero and `K - sigma M` is nearly singular, too far and the
//!   wanted `theta` bunch together. Stiffness and mass set the scale: `r`, the mean
//!   ratio of K's to M's diagonal, is about the square of the highest frequency (units
//!   1/s^2, whatever the material). The first pass uses `sigma = -1e-5 r`: `K - sigma M`
//!   then has a condition number near 1e5 whether the body is rubber or steel (a fixed
//!   shift of -1 gives steel's `K + M` a condition number near 1e11 and loses the low
//!   modes to rounding). If the lowest non-rigid eigenvalue found lies more than a
//!   hundred times above `|sigma|` (a slender or finely meshed body), a second pass
//!   factors again at `sigma = -lambda_1 / 2`, where the wanted values are well spread.
//! - **Rigid modes:** eigenvalues below `1e-12 r` in magnitude are counted as rigid and
//!   reported first.
//! - **Fixed vertices** drop out: their rows and columns become the identity in
//!   `K - sigma M` and their entries of every vector stay zero.
//!
//! Each mode's residual is reported as `|K x - lambda M x| / (|K x| + |lambda| |M x|)`;
//! for a rigid mode, where both terms of that denominator vanish with the residual, as
//! the backward error `|K x| / (|K| |x|)`.

use super::{
    cholesky::CholeskyCore,
    dense::{inverse_spd3, positive},
    SolveError,
};
use crate::sparse::order::FillOrdering;
use crate::sparse::{Bsr3, FaerCsc, Triangle};
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatMut, MatRef, Par, Side};
use std::time::Instant;

/// The mass matrix of the problem.
#[derive(Clone, Copy, Debug)]
pub enum Mass<'a> {
    /// One mass per vertex (kg), the same for its three unknowns.
    Lumped(&'a [f64]),
    /// A consistent mass matrix on the stiffness's pattern.
    Consistent(&'a Bsr3),
}

impl Mass<'_> {
    /// `y = M x` (x and y component-major, 3n values).
    pub fn times(&self, y: &mut [f64], x: &[f64]) {
        match self {
            Mass::Lumped(m) => {
                let n = m.len();
                for (d, (yd, xd)) in y.iter_mut().zip(x).enumerate() {
                    *yd = m[d % n] * xd;
                }
            }
            Mass::Consistent(m) => m.spmv(y, x),
        }
    }
}

/// Settings of [`lowest_modes`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EigenParams {
    /// Modes wanted, rigid ones included.
    pub count: usize,
    /// Lanczos stops when each wanted Ritz pair of the shift-inverted operator has a
    /// residual below this fraction of its value theta. The residual reported in the
    /// problem's own terms (`Modes::residuals`) can be larger by up to the ratio of the
    /// largest eigenvalue of `K - sigma M` (over M) to the mode's `lambda - sigma`: 1e-10
    /// here gave residuals up to 3e-8 on the free bars of the tests; on the 36,663-unknown
    /// bar, 1e-8 instead moved no frequency by more than 6e-15 (relative).
    pub tolerance: f64,
    /// The shift; `None` chooses it (module docs). Must lie below the lowest eigenvalue.
    pub shift: Option<f64>,
    /// Free unknowns up to which the dense path runs. `largestep study modes` puts the
    /// crossover between 108 unknowns (dense 1 ms, sparse 3 ms) and 351 (18 against
    /// 14 ms); the dense path's cost grows as the cube.
    pub dense_max: usize,
    /// The sparse path's fill-reducing ordering of `K - sigma M`.
    pub ordering: FillOrdering,
}

impl Default for EigenParams {
    fn default() -> Self {
        Self {
            count: 20,
            tolerance: 1e-10,
            shift: None,
            dense_max: 200,
            ordering: FillOrdering::default(),
        }
    }
}

/// The modes found, ascending by eigenvalue, rigid ones first.
#[derive(Clone, Debug, Default)]
pub struct Modes {
    /// Eigenvalues `lambda` (1/s^2), ascending.
    pub eigenvalues: Vec<f64>,
    /// Mode shapes, M-orthonormal, each `3n` long and component-major, one after another
    /// (zero at fixed vertices).
    pub vectors: Vec<f64>,
    /// `|K x - lambda M x| / (|K x| + |lambda| |M x|)` per mode; for rigid modes
    /// `|K x| / (|K| |x|)` (see [`lowest_modes`]'s module docs).
    pub residuals: Vec<f64>,
    /// How many of the first modes are rigid (`|lambda| < 1e-12 r`).
    pub rigid: usize,
    /// The shift of the last factorization (0 on the dense path).
    pub shift: f64,
    /// Lanczos steps (0 on the dense path).
    pub steps: usize,
    /// Whether the dense path ran.
    pub dense: bool,
    /// What the solver changed on its own (a nudged shift, a second pass).
    pub notes: Vec<String>,
    /// Seconds in sparse Cholesky factorizations (0 on the dense path).
    pub factor_seconds: f64,
    /// Seconds in the block solves with the factor, and how many blocks were solved
    /// (each reads the whole factor twice, forward and back).
    pub solve_seconds: f64,
    pub block_solves: usize,
    /// Wall time in seconds.
    pub seconds: f64,
}

impl Modes {
    /// Mode j's shape (`3n` values, component-major).
    pub fn mode(&self, j: usize) -> &[f64] {
        let len = self.vectors.len() / self.eigenvalues.len().max(1);
        &self.vectors[j * len..(j + 1) * len]
    }

    /// Frequencies `sqrt(lambda) / 2 pi` (Hz) of the non-rigid modes, ascending.
    pub fn frequencies_hz(&self) -> Vec<f64> {
        self.eigenvalues[self.rigid..]
            .iter()
            .map(|&l| l.max(0.0).sqrt() / (2.0 * std::f64::consts::PI))
            .collect()
    }
}

/// Rigid modes: eigenvalues below this fraction of the stiffness-to-mass scale `r`.
const RIGID: f64 = 1e-12;

/// The first shift, as a fraction of `r` (module docs). On the free steel bar of 36,663
/// unknowns (lowest elastic eigenvalue near 4e-5 r) 1e-4 took 105 Lanczos steps and 1e-5
/// 90, with the same frequencies to 1e-11; 1e-6 gave no fewer.
const SHIFT: f64 = 1e-5;

/// Most Lanczos runs per shift (the first and its deflated repeats).
const ROUNDS: usize = 4;

/// Modes a deflated repeat looks for.
const REPEAT: usize = 6;

/// Block size of the Lanczos runs: more than a free body's six rigid modes, so that
/// they are found in one run and no deflated repeat is needed for them.
const BLOCK: usize = 8;

/// Relative tolerance of the scout that checks for missed modes.
const SCOUT: f64 = 1e-4;

/// The lowest `params.count` modes of `K x = lambda M x` with the vertices `fixed` held.
/// `k` is the stiffness (positive semidefinite: the negated force Jacobian).
pub fn lowest_modes(
    k: &Bsr3,
    mass: Mass<'_>,
    fixed: &[usize],
    params: &EigenParams,
) -> Result<Modes, SolveError> {
    let start = Instant::now();
    let n = k.n();
    let mut is_fixed = vec![false; n];
    for &v in fixed {
        if v >= n {
            return Err(SolveError::Invalid(format!(
                "fixed vertex {v} out of range ({n} vertices)"
            )));
        }
        is_fixed[v] = true;
    }
    let free: Vec<usize> = (0..3 * n).filter(|&d| !is_fixed[d % n]).collect();
    if params.count == 0 || params.count > free.len() {
        return Err(SolveError::Invalid(format!(
            "{} modes asked of a problem with {} free unknowns",
            params.count,
            free.len()
        )));
    }
    if !(params.tolerance > 0.0 && params.tolerance < 1.0) {
        return Err(SolveError::Invalid(format!(
            "eigen tolerance must be in (0, 1), not {}",
            params.tolerance
        )));
    }
    let scale = k.values().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if !scale.is_finite() {
        return Err(SolveError::NonFinite {
            what: "stiffness matrix",
            iteration: 0,
        });
    }
    let asym = k.max_asymmetry();
    if asym > 1e-10 * scale {
        return Err(SolveError::Invalid(format!(
            "the stiffness matrix is not symmetric (largest difference {asym:.3e} against entries up to {scale:.3e})"
        )));
    }
    check_mass(k, mass, &is_fixed)?;
    let r = stiffness_to_mass(k, mass, &is_fixed);
    let mut modes = if free.len() <= params.dense_max {
        dense(k, mass, &free, params.count)?
    } else {
        let sigma = params.shift.unwrap_or(-SHIFT * r);
        let mut solver = ShiftInvert::new(k, mass, is_fixed.clone(), r, params.ordering)?;
        let mut modes = solver.run(sigma, params)?;
        if params.shift.is_none() {
            let rigid = modes
                .eigenvalues
                .iter()
                .take_while(|l| l.abs() < RIGID * r)
                .count();
            if let Some(&l1) = modes.eigenvalues.get(rigid) {
                if l1 > 100.0 * modes.shift.abs() {
                    let again = solver.run(-0.5 * l1, params)?;
                    let mut notes = modes.notes;
                    notes.push(format!(
                        "second pass at shift {:.4e} (the first, {:.4e}, lay far below the lowest mode {l1:.4e})",
                        again.shift, modes.shift
                    ));
                    modes = again;
                    modes.notes.splice(0..0, notes);
                }
            }
        }
        modes
    };
    modes.rigid = modes
        .eigenvalues
        .iter()
        .take_while(|l| l.abs() < RIGID * r)
        .count();
    residuals(k, mass, &is_fixed, &mut modes);
    modes.seconds = start.elapsed().as_secs_f64();
    Ok(modes)
}

/// M must be positive definite on the free vertices: positive lumped masses, or
/// positive definite diagonal blocks of the consistent matrix (a necessary condition,
/// cheap; the factorizations catch the rest).
fn check_mass(k: &Bsr3, mass: Mass<'_>, fixed: &[bool]) -> Result<(), SolveError> {
    match mass {
        Mass::Lumped(m) => {
            if m.len() != k.n() {
                return Err(SolveError::Invalid(format!(
                    "{} lumped masses for {} vertices",
                    m.len(),
                    k.n()
                )));
            }
            for (i, &mi) in m.iter().enumerate() {
                let good = positive(mi) && mi.is_finite();
                if !fixed[i] && !good {
                    return Err(SolveError::NotPositiveDefinite {
                        what: "mass matrix: lumped mass of vertex",
                        at: i,
                        value: mi,
                    });
                }
            }
        }
        Mass::Consistent(m) => {
            if !crate::sparse::Bsr3Pattern::same(m.pattern(), k.pattern()) {
                return Err(SolveError::Invalid(
                    "the consistent mass matrix must share the stiffness's pattern".into(),
                ));
            }
            for (i, &slot) in m.pattern().diag_slots().iter().enumerate() {
                let b = m.block(slot as usize);
                if !fixed[i] && inverse_spd3(b).is_none() {
                    return Err(SolveError::NotPositiveDefinite {
                        what: "mass matrix: diagonal block of vertex",
                        at: i,
                        value: b[0],
                    });
                }
            }
        }
    }
    Ok(())
}

/// `r`: the mean over free unknowns of `K_ii / M_ii` (1/s^2), the scale of the highest
/// eigenvalues.
fn stiffness_to_mass(k: &Bsr3, mass: Mass<'_>, fixed: &[bool]) -> f64 {
    let (mut sum, mut count) = (0.0, 0usize);
    for (i, &slot) in k.pattern().diag_slots().iter().enumerate() {
        if fixed[i] {
            continue;
        }
        let kb = k.block(slot as usize);
        for c in 0..3 {
            let m = match mass {
                Mass::Lumped(m) => m[i],
                Mass::Consistent(m) => m.block(slot as usize)[4 * c],
            };
            sum += kb[4 * c] / m;
            count += 1;
        }
    }
    if count == 0 || !positive(sum) {
        1.0
    } else {
        sum / count as f64
    }
}

/// The dense path over the free unknowns `free`.
fn dense(k: &Bsr3, mass: Mass<'_>, free: &[usize], count: usize) -> Result<Modes, SolveError> {
    let n = k.n();
    let nf = free.len();
    let mut index = vec![usize::MAX; 3 * n];
    for (f, &d) in free.iter().enumerate() {
        index[d] = f;
    }
    let mut kd = Mat::<f64>::zeros(nf, nf);
    k.for_each_entry(|r, c, v| {
        if index[r] != usize::MAX && index[c] != usize::MAX {
            kd[(index[r], index[c])] += v;
        }
    });
    let mut md = Mat::<f64>::zeros(nf, nf);
    match mass {
        Mass::Lumped(m) => {
            for (f, &d) in free.iter().enumerate() {
                md[(f, f)] = m[d % n];
            }
        }
        Mass::Consistent(m) => m.for_each_entry(|r, c, v| {
            if index[r] != usize::MAX && index[c] != usize::MAX {
                md[(index[r], index[c])] += v;
            }
        }),
    }
    let llt = md
        .llt(Side::Lower)
        .map_err(|_| SolveError::NotPositiveDefinite {
            what: "mass matrix: Cholesky pivot of free unknown",
            at: 0,
            value: f64::NAN,
        })?;
    let l = llt.L();
    // C = L^-1 K L^-T: X = L^-1 K, then C = L^-1 X^T (K is symmetric).
    l.solve_lower_triangular_in_place(kd.as_mut());
    let mut c = kd.transpose().to_owned();
    l.solve_lower_triangular_in_place(c.as_mut());
    let (s, mut y) = symmetric_eigen(c.as_ref())?;
    let mut y = y.subcols_mut(0, count).to_owned();
    l.transpose().solve_upper_triangular_in_place(y.as_mut());
    let mut vectors = vec![0.0; 3 * n * count];
    for j in 0..count {
        for (f, &d) in free.iter().enumerate() {
            vectors[3 * n * j + d] = y[(f, j)];
        }
    }
    Ok(Modes {
        eigenvalues: (0..count).map(|j| s[j]).collect(),
        vectors,
        dense: true,
        ..Modes::default()
    })
}

/// The sparse path: `K - sigma M` in faer's CSC form with its Cholesky, refactored per
/// shift, and the Lanczos workspace.
struct ShiftInvert<'a> {
    k: &'a Bsr3,
    /// Time in block solves and their count, since the last factorization.
    solve_seconds: f64,
    block_solves: usize,
    /// `r`, the stiffness-to-mass scale (1/s^2).
    scale: f64,
    mass: Mass<'a>,
    fixed: Vec<bool>,
    csc: FaerCsc,
    core: CholeskyCore,
}

impl<'a> ShiftInvert<'a> {
    fn new(
        k: &'a Bsr3,
        mass: Mass<'a>,
        fixed: Vec<bool>,
        scale: f64,
        ordering: FillOrdering,
    ) -> Result<Self, SolveError> {
        let csc = FaerCsc::new(k.pattern(), Triangle::Lower);
        // The block solves are the largest part of the time: split over two threads.
        let core = CholeskyCore::for_pattern(csc.symbolic(), k.pattern(), ordering)?.parallel();
        Ok(Self {
            k,
            solve_seconds: 0.0,
            block_solves: 0,
            scale,
            mass,
            fixed,
            csc,
            core,
        })
    }

    /// Factors `K - sigma M` (fixed rows and columns the identity); a shift at which it is
    /// not positive definite is moved down (at most four times) and the move noted.
    fn factor(&mut self, sigma: f64, notes: &mut Vec<String>) -> Result<f64, SolveError> {
        let n = self.k.n();
        let mut sigma = sigma;
        for attempt in 0..5 {
            let (kv, fixed, mass) = (self.k.values(), &self.fixed, self.mass);
            self.csc.refill_with(|r, c, at| {
                if fixed[r % n] || fixed[c % n] {
                    return if r == c { 1.0 } else { 0.0 };
                }
                let m = match mass {
                    Mass::Lumped(m) if r == c => m[r % n],
                    Mass::Lumped(_) => 0.0,
                    Mass::Consistent(m) => m.values()[at],
                };
                kv[at] - sigma * m
            });
            match self.core.factorize(self.csc.as_ref()) {
                Ok(()) => return Ok(sigma),
                Err(SolveError::NotPositiveDefinite { .. }) if attempt < 4 => {
                    // Down by a step that grows tenfold per attempt, from 1e-3 of the shift
                    // or 1e-8 of the stiffness-to-mass scale, whichever is larger.
                    let moved =
                        sigma - (1e-3 * sigma.abs()).max(1e-8 * self.scale) * 10f64.powi(attempt);
                    notes.push(format!(
                        "shift {sigma:.6e} made K - sigma M singular or indefinite (on or above an eigenvalue); moved to {moved:.6e}"
                    ));
                    sigma = moved;
                }
                Err(e) => return Err(e),
            }
        }
        unreachable!("the loop returns by its fifth attempt")
    }

    /// `y = M x` with fixed unknowns zero.
    fn mass_times(&self, y: &mut [f64], x: &[f64]) {
        let n = self.k.n();
        self.mass.times(y, x);
        for (d, yd) in y.iter_mut().enumerate() {
            if self.fixed[d % n] {
                *yd = 0.0;
            }
        }
    }

    /// Shift-invert block Lanczos at `sigma` (module docs), with deflated repeats: a
    /// Krylov space with b vectors per block holds at most b copies of an eigenvalue, so
    /// of one with more (two free bodies' twelve rigid modes) it may find fewer (a
    /// single-vector Lanczos found five of a free bar's six). When the modes found
    /// include a cluster as large as the block, the search repeats in the M-orthogonal
    /// complement of the modes found, and whatever it finds above the wanted ones joins
    /// them, until a run adds nothing (at most [`ROUNDS`] runs).
    fn run(&mut self, sigma: f64, params: &EigenParams) -> Result<Modes, SolveError> {
        let mut notes = Vec::new();
        let start = Instant::now();
        let sigma = self.factor(sigma, &mut notes)?;
        let factor_seconds = start.elapsed().as_secs_f64();
        (self.solve_seconds, self.block_solves) = (0.0, 0);
        let n3 = 3 * self.k.n();
        let want = params.count;
        // The modes kept, by decreasing theta: (theta, vector).
        let mut kept: Vec<(f64, Vec<f64>)> = Vec::new();
        let mut steps = 0;
        for round in 0..ROUNDS {
            let locked: Vec<f64> = kept.iter().flat_map(|(_, v)| v.iter().copied()).collect();
            // A repeat looks for copies the first run missed: in the complement of the
            // modes kept, any mode that belongs among them has the largest theta there.
            // A scout to a loose tolerance tells whether that largest lies above the
            // kept ones (on the free bar, 4 block steps where the tight tolerance took
            // 14, the complement's top being the next mode up); only then does a run
            // to the full tolerance bring it, and whatever else of its top few (as
            // many as a rigid body has modes) has converged by then.
            if round > 0 && largest_cluster(&kept) < BLOCK {
                // Block Lanczos finds every copy of an eigenvalue that has fewer copies
                // than the block has columns: nothing can be missing.
                break;
            }
            if round > 0 {
                let scout = EigenParams {
                    tolerance: params.tolerance.max(SCOUT),
                    ..*params
                };
                let (top, s) = self.lanczos(1, 1, &locked, &scout)?;
                steps += s;
                let floor = kept.get(want - 1).map_or(f64::NEG_INFINITY, |k| k.0);
                if top
                    .first()
                    .is_none_or(|(t, _)| *t <= floor * (1.0 + 10.0 * SCOUT))
                {
                    break;
                }
            }
            let (ask, need) = if round == 0 {
                (want, want)
            } else {
                (want.min(REPEAT), 1)
            };
            let (found, s) = self.lanczos(ask, need, &locked, params)?;
            steps += s;
            let floor = if kept.len() >= want {
                kept[want - 1].0
            } else {
                f64::NEG_INFINITY
            };
            let new = found.iter().filter(|(t, _)| *t > floor).count();
            kept.extend(found);
            kept.sort_by(|a, b| b.0.total_cmp(&a.0));
            kept.truncate(want);
            if round > 0 && new == 0 {
                break;
            }
            if round == ROUNDS - 1 && new > 0 {
                notes.push(format!(
                    "the last of {ROUNDS} deflated Lanczos runs still found {new} new modes: a mode of high multiplicity may be missing"
                ));
            }
        }
        if kept.len() < want {
            return Err(SolveError::NotConverged {
                iterations: steps,
                residual: f64::NAN,
                tolerance: params.tolerance,
            });
        }
        let eigenvalues = kept.iter().map(|(t, _)| sigma + 1.0 / t).collect();
        let mut vectors = Vec::with_capacity(n3 * want);
        for (_, v) in &kept {
            vectors.extend_from_slice(v);
        }
        Ok(Modes {
            eigenvalues,
            vectors,
            shift: sigma,
            steps,
            notes,
            factor_seconds,
            solve_seconds: self.solve_seconds,
            block_solves: self.block_solves,
            ..Modes::default()
        })
    }

    /// `out = M x` for the `k` columns of `x` (column-major), fixed unknowns zero.
    fn mass_columns(&self, out: &mut [f64], x: &[f64], k: usize) {
        let n3 = 3 * self.k.n();
        for c in 0..k {
            self.mass_times(&mut out[c * n3..(c + 1) * n3], &x[c * n3..(c + 1) * n3]);
        }
    }

    /// One block Lanczos run (block size [`BLOCK`]) in the M-orthogonal complement of
    /// `locked` (vectors one after another, M-orthonormal), until the `need` largest Ritz
    /// values have converged: those of the `want` largest that have, with their
    /// M-normalised vectors, and the block steps taken.
    ///
    /// Blocks because each step's solve with `K - sigma M` reads the whole Cholesky factor
    /// from memory (142 MB for the 36,663-unknown bar: 20 ms a solve), and one pass serves
    /// the six columns of a block; six also covers a free body's six rigid modes at once.
    /// Full block reorthogonalisation (classical Gram-Schmidt twice, as matrix products) in
    /// the M inner product; each new block M-orthonormalised by Cholesky QR, twice. The
    /// projected matrix is the block tridiagonal of the coefficients; a Ritz pair converges
    /// when `|B_j s_i| <= tol theta_i` over the last block's rows of its vector.
    #[allow(clippy::type_complexity, clippy::needless_range_loop)]
    fn lanczos(
        &mut self,
        want: usize,
        need: usize,
        locked: &[f64],
        params: &EigenParams,
    ) -> Result<(Vec<(f64, Vec<f64>)>, usize), SolveError> {
        let n = self.k.n();
        let n3 = 3 * n;
        let free = (0..n3).filter(|&d| !self.fixed[d % n]).count();
        let nl = locked.len() / n3.max(1);
        let room = free.saturating_sub(nl);
        let want = want.min(room);
        if want == 0 {
            return Ok((Vec::new(), 0));
        }
        let p = BLOCK.min(room);
        let max_blocks = (room / p).clamp(1, (10 * want).max(200).div_ceil(p));
        // The basis Q and M Q (column after column): the locked vectors, then the blocks.
        let mut q: Vec<f64> = Vec::with_capacity(n3 * (nl + (4 * want + 3 * p).min(room)));
        let mut mq: Vec<f64> = Vec::with_capacity(q.capacity());
        q.extend_from_slice(locked);
        mq.resize(locked.len(), 0.0);
        self.mass_columns(&mut mq, locked, nl);
        // A start block with every free unknown excited, no structure, columns distinct.
        let mut v: Vec<f64> = (0..n3 * p)
            .map(|e| {
                let (c, d) = (e / n3, e % n3);
                if self.fixed[d % n] {
                    0.0
                } else {
                    let a = 0.618_033_988_7 + 0.141_421_356 * c as f64;
                    1.0 + 0.5 * (d as f64 * a + 0.1 * nl as f64).fract()
                }
            })
            .collect();
        let mut mv = vec![0.0; n3 * p];
        let mut coef: Vec<f64> = Vec::new();
        reorthogonalise(&q, &mq, nl, &mut v, p, &mut coef, |_, _, _| {});
        self.mass_columns(&mut mv, &v, p);
        if m_orthonormalise(&mut v, &mut mv, n3, p).is_none() {
            return Ok((Vec::new(), 0));
        }
        let dim = (max_blocks + 1) * p;
        let mut h = Mat::<f64>::zeros(dim, dim);
        let mut w = vec![0.0; n3 * p];
        let mut mw = vec![0.0; n3 * p];
        let mut result: Option<(Vec<f64>, Mat<f64>, Vec<bool>)> = None;
        let mut steps = 0;
        while steps < max_blocks {
            q.extend_from_slice(&v);
            mq.extend_from_slice(&mv);
            let j0 = steps * p;
            steps += 1;
            // W = (K - sigma M)^-1 M V, all columns in one pass over the factor.
            w.copy_from_slice(&mv);
            let solve = Instant::now();
            self.core.solve_columns(&mut w, p)?;
            self.solve_seconds += solve.elapsed().as_secs_f64();
            self.block_solves += 1;
            let cols = nl + steps * p;
            reorthogonalise(&q, &mq, cols, &mut w, p, &mut coef, |r, c, x| {
                if r >= nl {
                    h[(r - nl, j0 + c)] += x;
                }
            });
            self.mass_columns(&mut mw, &w, p);
            let b = m_orthonormalise(&mut w, &mut mw, n3, p);
            let breakdown = b.is_none();
            let b = b.unwrap_or([[0.0; BLOCK]; BLOCK]);
            if steps < max_blocks {
                for r in 0..p {
                    for c in 0..p {
                        h[(steps * p + r, j0 + c)] = b[r][c];
                    }
                }
            }
            let k = steps * p;
            if k >= want {
                // The projected matrix: symmetric in exact arithmetic; its lower triangle.
                let t = Mat::<f64>::from_fn(k, k, |i, j| 0.5 * (h[(i, j)] + h[(j, i)]));
                let (theta, s) = symmetric_eigen(t.as_ref())?;
                let converged: Vec<bool> = (k - want..k)
                    .map(|i| {
                        let mut r2 = 0.0;
                        for r in 0..p {
                            let mut x = 0.0;
                            for c in r..p {
                                x += b[r][c] * s[(j0 + c, i)];
                            }
                            r2 += x * x;
                        }
                        breakdown || r2.sqrt() <= params.tolerance * theta[i].abs()
                    })
                    .collect();
                // Largest theta last.
                if converged[want - need..].iter().all(|&c| c) {
                    result = Some((theta, s, converged));
                    break;
                }
            }
            if breakdown {
                break;
            }
            std::mem::swap(&mut v, &mut w);
            std::mem::swap(&mut mv, &mut mw);
        }
        let Some((theta, s, converged)) = result else {
            return Err(SolveError::NotConverged {
                iterations: steps,
                residual: f64::NAN,
                tolerance: params.tolerance,
            });
        };
        let k = theta.len();
        // Ritz vectors X = Q_L S of the converged among the wanted, largest theta first.
        let chosen: Vec<usize> = (k - want..k)
            .rev()
            .filter(|&i| converged[i - (k - want)])
            .collect();
        let ql = MatRef::from_column_major_slice(&q[nl * n3..(nl + k) * n3], n3, k);
        let sel = Mat::<f64>::from_fn(k, chosen.len(), |r, c| s[(r, chosen[c])]);
        let mut x = Mat::<f64>::zeros(n3, chosen.len());
        matmul(x.as_mut(), Accum::Replace, ql, sel.as_ref(), 1.0, Par::Seq);
        let mut found = Vec::with_capacity(chosen.len());
        let mut mx = vec![0.0; n3];
        for (c, &i) in chosen.iter().enumerate() {
            let mut col: Vec<f64> = (0..n3).map(|r| x[(r, c)]).collect();
            self.mass_times(&mut mx, &col);
            let norm = dot(&col, &mx).sqrt();
            col.iter_mut().for_each(|v| *v /= norm);
            found.push((theta[i], col));
        }
        Ok((found, steps))
    }
}

/// The most modes in `kept` (by decreasing theta) whose theta agree to 1e-8: copies of
/// one eigenvalue, as far as rounding tells.
fn largest_cluster(kept: &[(f64, Vec<f64>)]) -> usize {
    let mut best = 0;
    let mut run = 0;
    for i in 0..kept.len() {
        run = if i > 0 && (kept[i - 1].0 - kept[i].0).abs() <= 1e-8 * kept[i - 1].0.abs() {
            run + 1
        } else {
            1
        };
        best = best.max(run);
    }
    best
}

/// Where the long vectors' rows split in two for the threads: the same split whatever
/// the thread count (the two halves run one after the other on one thread), so the
/// sums over rows, partial per half and added in order, give the same bits on any
/// number of threads. A multiple of 8 (the dot kernel's stride).
fn row_split(n3: usize) -> usize {
    (n3 / 2) & !7
}

/// Runs `f` on the two row halves `[0, h)` and `[h, n3)` ([`row_split`]), side by side.
fn on_halves<R: Send>(n3: usize, f: impl Fn(std::ops::Range<usize>) -> R + Sync) -> (R, R) {
    let h = row_split(n3);
    rayon::join(|| f(0..h), || f(h..n3))
}

/// Removes from the `p` columns of `w` (column-major, `n3` rows, as the basis vectors)
/// their M-components along the first `cols` basis vectors `q` (with `mq = M q`):
/// classical Gram-Schmidt twice, as two matrix products per pass, each over the two row
/// halves on two threads ([`on_halves`]). `record(r, c, x)` receives each coefficient
/// (basis vector r, column c), both passes.
fn reorthogonalise(
    q: &[f64],
    mq: &[f64],
    cols: usize,
    w: &mut [f64],
    p: usize,
    coef: &mut Vec<f64>,
    mut record: impl FnMut(usize, usize, f64),
) {
    if cols == 0 {
        return;
    }
    let n3 = w.len() / p;
    let qm = MatRef::from_column_major_slice(&q[..cols * n3], n3, cols);
    let mqm = MatRef::from_column_major_slice(&mq[..cols * n3], n3, cols);
    // The coefficients, then the second half's partial sums.
    coef.resize(2 * cols * p, 0.0);
    for _ in 0..2 {
        {
            let (first, second) = coef.split_at_mut(cols * p);
            let wm = MatRef::from_column_major_slice(w, n3, p);
            let part = |out: &mut [f64], rows: std::ops::Range<usize>| {
                matmul(
                    MatMut::from_column_major_slice_mut(out, cols, p),
                    Accum::Replace,
                    mqm.subrows(rows.start, rows.len()).transpose(),
                    wm.subrows(rows.start, rows.len()),
                    1.0,
                    Par::Seq,
                )
            };
            let h = row_split(n3);
            rayon::join(|| part(first, 0..h), || part(second, h..n3));
            for (a, b) in first.iter_mut().zip(second.iter()) {
                *a += b;
            }
        }
        for c in 0..p {
            for r in 0..cols {
                record(r, c, coef[c * cols + r]);
            }
        }
        let h = row_split(n3);
        let (top, bottom) = MatMut::from_column_major_slice_mut(w, n3, p).split_at_row_mut(h);
        let cm = MatRef::from_column_major_slice(&coef[..cols * p], cols, p);
        let update = |part: MatMut<'_, f64>, r0: usize| {
            let rows = part.nrows();
            matmul(part, Accum::Add, qm.subrows(r0, rows), cm, -1.0, Par::Seq)
        };
        rayon::join(|| update(top, 0), || update(bottom, h));
    }
}

/// M-orthonormalises the `p` columns of `w` (with `mw = M w`, updated alike) by Cholesky
/// QR twice: `w = V B`, V into `w`, B (upper triangular, `p x p`) returned; `None` when
/// the columns are (nearly) dependent. The Gram matrix's dot products and the column
/// updates run over the two row halves on two threads ([`on_halves`]).
// Small dense algebra on p x p blocks reads plainest with indices.
#[allow(clippy::needless_range_loop)]
fn m_orthonormalise(
    w: &mut [f64],
    mw: &mut [f64],
    n3: usize,
    p: usize,
) -> Option<[[f64; BLOCK]; BLOCK]> {
    let mut b = [[0.0; BLOCK]; BLOCK];
    for i in 0..p {
        b[i][i] = 1.0;
    }
    for _ in 0..2 {
        // G = W^T M W and its Cholesky factor R (upper): G = R^T R.
        let gram = |rows: std::ops::Range<usize>| {
            let mut g = [[0.0; BLOCK]; BLOCK];
            for i in 0..p {
                for j in i..p {
                    g[i][j] = dot(&w[i * n3..][rows.clone()], &mw[j * n3..][rows.clone()]);
                }
            }
            g
        };
        let (g0, g1) = on_halves(n3, gram);
        let g: [[f64; BLOCK]; BLOCK] =
            std::array::from_fn(|i| std::array::from_fn(|j| g0[i][j] + g1[i][j]));
        let scale = (0..p).map(|i| g[i][i]).fold(0.0f64, f64::max);
        let mut r = [[0.0; BLOCK]; BLOCK];
        for j in 0..p {
            let mut d = g[j][j];
            for k in 0..j {
                d -= r[k][j] * r[k][j];
            }
            if !positive(d) || d <= 1e-24 * scale {
                return None;
            }
            r[j][j] = d.sqrt();
            for i in j + 1..p {
                let mut x = g[j][i];
                for k in 0..j {
                    x -= r[k][j] * r[k][i];
                }
                r[j][i] = x / r[j][j];
            }
        }
        // W <- W R^-1 column by column (and M W alike), each row half on its own
        // thread: the columns cut at the split into a top and a bottom part.
        let h = row_split(n3);
        let (mut top, mut bottom): (Vec<&mut [f64]>, Vec<&mut [f64]>) = w[..p * n3]
            .chunks_mut(n3)
            .chain(mw[..p * n3].chunks_mut(n3))
            .map(|col| col.split_at_mut(h))
            .unzip();
        let solve = |cols: &mut [&mut [f64]]| {
            // Columns 0..p are W's, p..2p M W's.
            for base in [0, p] {
                for c in 0..p {
                    let (done, rest) = cols[base..base + p].split_at_mut(c);
                    for k in 0..c {
                        axpy(rest[0], -r[k][c], done[k]);
                    }
                    let inv = 1.0 / r[c][c];
                    rest[0].iter_mut().for_each(|v| *v *= inv);
                }
            }
        };
        rayon::join(|| solve(&mut top), || solve(&mut bottom));
        // B <- R B.
        let mut nb = [[0.0; BLOCK]; BLOCK];
        for i in 0..p {
            for j in 0..p {
                for k in 0..p {
                    nb[i][j] += r[i][k] * b[k][j];
                }
            }
        }
        b = nb;
    }
    Some(b)
}

/// Eigenvalues (ascending) and eigenvectors of a symmetric matrix (its lower triangle),
/// by faer's tridiagonal QR iteration at every size. Why not faer's default: above 128
/// unknowns it switches to divide and conquer, which on stiffness matrices of free bodies
/// (a six-fold cluster at zero, eigenvalues over sixteen orders of magnitude) returned
/// some pairs with residuals near 1e-5 of the matrix's norm (faer 0.24.4; a free-free
/// 10x1x1 bar, 132 unknowns).
fn symmetric_eigen(a: MatRef<'_, f64>) -> Result<(Vec<f64>, Mat<f64>), SolveError> {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::linalg::evd::{self, ComputeEigenvectors, SelfAdjointEvdParams};
    let n = a.nrows();
    let mut params: SelfAdjointEvdParams = <SelfAdjointEvdParams as faer::Auto<f64>>::auto();
    params.recursion_threshold = usize::MAX;
    let mut s = faer::diag::Diag::<f64>::zeros(n);
    let mut u = Mat::<f64>::zeros(n, n);
    let mut mem = MemBuffer::new(evd::self_adjoint_evd_scratch::<f64>(
        n,
        ComputeEigenvectors::Yes,
        Par::Seq,
        params.into(),
    ));
    evd::self_adjoint_evd(
        a,
        s.as_mut(),
        Some(u.as_mut()),
        Par::Seq,
        MemStack::new(&mut mem),
        params.into(),
    )
    .map_err(|e| SolveError::Factorization(format!("symmetric eigensolver: {e:?}")))?;
    let s = s.column_vector();
    Ok(((0..n).map(|i| s[i]).collect(), u))
}

/// Each mode's relative residual over the free unknowns (at fixed ones `K x` is the
/// reaction, not part of the problem): `|K x - lambda M x| / (|K x| + |lambda| |M x|)`.
/// For a rigid mode both terms below vanish with the residual, so the measure there is
/// `|K x| / (|K| |x|)` (|K|: the largest absolute row sum), the backward error.
fn residuals(k: &Bsr3, mass: Mass<'_>, fixed: &[bool], modes: &mut Modes) {
    let n = k.n();
    let mut rows = vec![0.0f64; 3 * n];
    k.for_each_entry(|r, _, v| rows[r] += v.abs());
    let knorm = rows.iter().fold(0.0f64, |m, &v| m.max(v));
    let (mut kx, mut mx) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
    modes.residuals = (0..modes.eigenvalues.len())
        .map(|j| {
            let x = modes.mode(j);
            k.spmv(&mut kx, x);
            mass.times(&mut mx, x);
            let l = modes.eigenvalues[j];
            let (mut num, mut nk, mut nm, mut nx) = (0.0, 0.0, 0.0, 0.0);
            for d in (0..3 * n).filter(|d| !fixed[d % n]) {
                num += (kx[d] - l * mx[d]).powi(2);
                nk += kx[d] * kx[d];
                nm += mx[d] * mx[d];
                nx += x[d] * x[d];
            }
            let den = if j < modes.rigid {
                knorm * nx.sqrt() + l.abs() * nm.sqrt()
            } else {
                nk.sqrt() + l.abs() * nm.sqrt()
            };
            num.sqrt() / den.max(f64::MIN_POSITIVE)
        })
        .collect();
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    largestep_kernels::vec::dot(a, b)
}

fn axpy(y: &mut [f64], a: f64, x: &[f64]) {
    largestep_kernels::vec::axpy(y, a, x);
}
