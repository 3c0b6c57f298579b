//! The lowest modes of the generalized symmetric eigenproblem `K x = lambda M x` (stiffness
//! `K` symmetric positive semidefinite, mass `M` symmetric positive definite, lumped or
//! consistent), for modal analysis and modal sound (issue 16; course notes section 17).
//!
//! - **Dense path** (at most [`EigenParams::dense_max`] free unknowns): `M = L L^T`,
//!   `C = L^-1 K L^-T`, faer's symmetric eigensolver on C, `x = L^-T y`.
//! - **Sparse path: shift-invert Lanczos in the M inner product** (Ericsson and Ruhe,
//!   "The spectral transformation Lanczos method", Math. Comp. 35, 1980; ARPACK's mode 3):
//!   the operator `(K - sigma M)^-1 M` is self-adjoint in `<x, y>_M = x^T M y`, its
//!   eigenvalues are `theta = 1 / (lambda - sigma)`, so the modes nearest above the shift
//!   come first. One sparse Cholesky of `K - sigma M` serves every product. The Lanczos
//!   vectors are M-orthogonalised in full (twice) at every step, so no ghost copies
//!   appear; Ritz values are checked every few steps by `beta_j |s_ji| <= tol theta_i`.
//!   faer's own partial eigensolver works in the Euclidean inner product, which a
//!   consistent M does not give without its Cholesky factor applied on its own (faer's
//!   sparse LLT only solves with the whole product).
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

/// Settings of [`lowest_modes`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EigenParams {
    /// Modes wanted, rigid ones included.
    pub count: usize,
    /// Relative residual of the Ritz pairs at which Lanczos stops.
    pub tolerance: f64,
    /// The shift; `None` chooses it (module docs). Must lie below the lowest eigenvalue.
    pub shift: Option<f64>,
    /// Free unknowns up to which the dense path runs.
    pub dense_max: usize,
}

impl Default for EigenParams {
    fn default() -> Self {
        Self {
            count: 20,
            tolerance: 1e-10,
            shift: None,
            dense_max: 600,
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
        let mut solver = ShiftInvert::new(k, mass, is_fixed.clone(), r)?;
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
    /// `r`, the stiffness-to-mass scale (1/s^2).
    scale: f64,
    mass: Mass<'a>,
    fixed: Vec<bool>,
    csc: FaerCsc,
    core: CholeskyCore,
}

impl<'a> ShiftInvert<'a> {
    fn new(k: &'a Bsr3, mass: Mass<'a>, fixed: Vec<bool>, scale: f64) -> Result<Self, SolveError> {
        let csc = FaerCsc::new(k.pattern(), Triangle::Lower);
        let core = CholeskyCore::new(csc.symbolic())?;
        Ok(Self {
            k,
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
        match self.mass {
            Mass::Lumped(m) => {
                for (d, (yd, xd)) in y.iter_mut().zip(x).enumerate() {
                    *yd = m[d % n] * xd;
                }
            }
            Mass::Consistent(m) => m.spmv(y, x),
        }
        for (d, yd) in y.iter_mut().enumerate() {
            if self.fixed[d % n] {
                *yd = 0.0;
            }
        }
    }

    /// Shift-invert Lanczos at `sigma` (module docs), with deflated restarts: a
    /// single-vector Krylov space holds one vector per eigenvalue, so of a multiple
    /// eigenvalue (the six rigid modes, the degenerate modes of symmetric bodies) it may
    /// find fewer copies than there are (on a free-free bar it found five of the six
    /// rigid modes). So after the first run the search repeats in the M-orthogonal
    /// complement of the modes found, and whatever it finds above the wanted ones joins
    /// them, until a run adds nothing (at most [`ROUNDS`] runs).
    fn run(&mut self, sigma: f64, params: &EigenParams) -> Result<Modes, SolveError> {
        let mut notes = Vec::new();
        let start = Instant::now();
        let sigma = self.factor(sigma, &mut notes)?;
        let factor_seconds = start.elapsed().as_secs_f64();
        let n3 = 3 * self.k.n();
        let want = params.count;
        // The modes kept, by decreasing theta: (theta, vector).
        let mut kept: Vec<(f64, Vec<f64>)> = Vec::new();
        let mut steps = 0;
        for round in 0..ROUNDS {
            let locked: Vec<f64> = kept.iter().flat_map(|(_, v)| v.iter().copied()).collect();
            // A repeat looks for copies the first run missed: in the complement of the
            // modes kept, any mode that belongs among them has the largest theta there,
            // so the repeat needs its top few only (as many as a rigid body has modes).
            let ask = if round == 0 { want } else { want.min(REPEAT) };
            let (found, s) = self.lanczos(ask, &locked, params)?;
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
            ..Modes::default()
        })
    }

    /// One Lanczos run in the M-orthogonal complement of `locked` (vectors one after
    /// another, M-orthonormal): the `want` largest converged Ritz values theta with their
    /// M-normalised vectors, and the steps taken.
    #[allow(clippy::type_complexity)]
    fn lanczos(
        &mut self,
        want: usize,
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
        let max_steps = room.min((10 * want).max(200));
        // The locked vectors and their M products come first in Q and M Q: every new
        // vector is M-orthogonalised against them too.
        let mut q: Vec<f64> = Vec::with_capacity(n3 * (nl + (2 * want + 40).min(max_steps + 1)));
        let mut mq: Vec<f64> = Vec::with_capacity(q.capacity());
        let mut mv = vec![0.0; n3];
        for l in 0..nl {
            let v = &locked[l * n3..(l + 1) * n3];
            self.mass_times(&mut mv, v);
            q.extend_from_slice(v);
            mq.extend_from_slice(&mv);
        }
        let (mut alpha, mut beta) = (Vec::new(), Vec::new());
        // A start with every free unknown excited and no structure.
        let mut v: Vec<f64> = (0..n3)
            .map(|d| {
                if self.fixed[d % n] {
                    0.0
                } else {
                    1.0 + 0.5 * ((d as f64) * 0.618_033_988_7 + 0.1 * nl as f64).fract()
                }
            })
            .collect();
        for l in 0..nl {
            let c = dot(&mq[l * n3..(l + 1) * n3], &v);
            axpy(&mut v, -c, &q[l * n3..(l + 1) * n3]);
        }
        self.mass_times(&mut mv, &v);
        let norm = dot(&v, &mv).max(0.0).sqrt();
        if !positive(norm) {
            return Ok((Vec::new(), 0));
        }
        v.iter_mut().for_each(|x| *x /= norm);
        mv.iter_mut().for_each(|x| *x /= norm);
        let mut w = vec![0.0; n3];
        let mut coef: Vec<f64> = Vec::new();
        let mut result: Option<(Vec<f64>, Mat<f64>)> = None;
        let mut steps = 0;
        while steps < max_steps {
            q.extend_from_slice(&v);
            mq.extend_from_slice(&mv);
            let j = nl + steps;
            steps += 1;
            // w = (K - sigma M)^-1 M q_j.
            w.copy_from_slice(&mv);
            self.core.solve_in_place(&mut w)?;
            // M-orthogonalise against every earlier vector: classical Gram-Schmidt twice
            // (as stable as the modified form run twice, and two matrix-vector products
            // over the basis instead of 2j passes: 28 ms a step became 12 ms on a
            // 36,663-unknown bar); alpha is the part along q_j.
            let cols = j + 1;
            let qm = MatRef::from_column_major_slice(&q[..cols * n3], n3, cols);
            let mqm = MatRef::from_column_major_slice(&mq[..cols * n3], n3, cols);
            coef.resize(cols, 0.0);
            let mut a = 0.0;
            for _ in 0..2 {
                matmul(
                    MatMut::from_column_major_slice_mut(&mut coef[..], cols, 1),
                    Accum::Replace,
                    mqm.transpose(),
                    MatRef::from_column_major_slice(&w, n3, 1),
                    1.0,
                    Par::Seq,
                );
                a += coef[j];
                matmul(
                    MatMut::from_column_major_slice_mut(&mut w, n3, 1),
                    Accum::Add,
                    qm,
                    MatRef::from_column_major_slice(&coef, cols, 1),
                    -1.0,
                    Par::Seq,
                );
            }
            alpha.push(a);
            self.mass_times(&mut mv, &w);
            let b = dot(&w, &mv).max(0.0).sqrt();
            let breakdown = b <= 1e-14 * a.abs().max(f64::MIN_POSITIVE);
            if steps >= want && (steps % 5 == 0 || steps == max_steps || breakdown) {
                let (theta, s) = tridiagonal_eigen(&alpha, &beta)?;
                let m = theta.len();
                let ok = breakdown
                    || (m - want..m)
                        .all(|i| b * s[(m - 1, i)].abs() <= params.tolerance * theta[i].abs());
                if ok {
                    result = Some((theta, s));
                    break;
                }
            }
            if breakdown {
                break;
            }
            beta.push(b);
            for (x, y) in v.iter_mut().zip(&w) {
                *x = y / b;
            }
            mv.iter_mut().for_each(|x| *x /= b);
        }
        let Some((theta, s)) = result else {
            return Err(SolveError::NotConverged {
                iterations: steps,
                residual: f64::NAN,
                tolerance: params.tolerance,
            });
        };
        let m = theta.len();
        let mut found = Vec::with_capacity(want);
        for i in (m.saturating_sub(want)..m).rev() {
            let mut x = vec![0.0; n3];
            for l in 0..m {
                axpy(&mut x, s[(l, i)], &q[(nl + l) * n3..(nl + l + 1) * n3]);
            }
            self.mass_times(&mut mv, &x);
            let norm = dot(&x, &mv).sqrt();
            x.iter_mut().for_each(|v| *v /= norm);
            found.push((theta[i], x));
        }
        Ok((found, steps))
    }
}

/// Eigenvalues (ascending) and eigenvectors of the symmetric tridiagonal matrix with
/// diagonal `alpha` and off-diagonal `beta`.
fn tridiagonal_eigen(alpha: &[f64], beta: &[f64]) -> Result<(Vec<f64>, Mat<f64>), SolveError> {
    let m = alpha.len();
    let t = Mat::<f64>::from_fn(m, m, |i, j| {
        if i == j {
            alpha[i]
        } else if i == j + 1 {
            beta[j]
        } else if j == i + 1 {
            beta[i]
        } else {
            0.0
        }
    });
    symmetric_eigen(t.as_ref())
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
            match mass {
                Mass::Lumped(m) => {
                    for (d, (y, v)) in mx.iter_mut().zip(x).enumerate() {
                        *y = m[d % n] * v;
                    }
                }
                Mass::Consistent(m) => m.spmv(&mut mx, x),
            }
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
