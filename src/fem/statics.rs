//! Static equilibrium of a [`Fem`] model: the positions where the elastic forces balance
//! the loads, with the pinned vertices held.
//!
//! The equilibrium minimises the total potential energy `Pi(x) = W(x) - lambda f_g . x`
//! (W the elastic energy, `f_g` the gravity forces, which do not depend on x) over the
//! free vertices. Newton's method solves `grad Pi = -(f_el(x) + lambda f_g) = 0` with the
//! stiffness `K = -df_el/dx` (the definiteness fix keeps it positive semi-definite,
//! [`FemDesc::definiteness_fix`](super::FemDesc)) projected by the filter of the pinned
//! vertices and factorised by sparse Cholesky, and a backtracking line search on `Pi`
//! (`crate::solve::Newton`). Loads are applied in `load_steps` equal increments of
//! lambda up to 1 (load stepping), each solved from the last one's answer, so a large
//! deflection is reached through equilibria instead of in one Newton step from rest
//! (Sifakis and Barbič 2012, section 7; Vega's static solver does the same).

use super::Fem;
use crate::simulation::MechModel;
use crate::solve::{
    Filter, Newton, NewtonParams, NewtonProblem, SolveError, SolveInfo, SparseCholesky,
};
use crate::sparse::Bsr3;
use largestep_kernels::vec as kv;

/// What a static solve did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StaticInfo {
    /// Load increments.
    pub load_steps: usize,
    /// Newton iterations over all increments.
    pub newton_iterations: usize,
    /// The final residual norm `|S (f_el + f_g)|` (N).
    pub residual: f64,
    /// The largest force on any free vertex from the loads alone (N): the scale the
    /// residual compares to.
    pub load_scale: f64,
}

/// The Newton problem of one load increment.
struct Equilibrium<'a> {
    model: &'a Fem,
    work: &'a mut <Fem as MechModel>::Work,
    filter: &'a Filter,
    lambda: f64,
    gravity: &'a [f64],
    f: Vec<f64>,
    /// Velocities for the Jacobian evaluation (statics has none).
    zero: Vec<f64>,
    dfdx: Bsr3,
    a: Bsr3,
    chol: SparseCholesky,
}

impl Equilibrium<'_> {
    /// `f = f_el(y) + lambda f_g`.
    fn forces(&mut self, y: &[f64]) {
        self.f.fill(0.0);
        self.model.element_forces_into(&mut self.work.f, y);
        self.model
            .gather
            .gather_vectors_add(&self.work.f, &mut self.f);
        kv::axpy(&mut self.f, self.lambda, self.gravity);
    }
}

impl NewtonProblem for Equilibrium<'_> {
    fn residual(&mut self, y: &[f64], r: &mut [f64]) -> Result<(), SolveError> {
        self.forces(y);
        for (ri, fi) in r.iter_mut().zip(&self.f) {
            *ri = -fi;
        }
        self.filter.apply(r);
        Ok(())
    }

    fn newton_step(
        &mut self,
        y: &[f64],
        r: &[f64],
        dy: &mut [f64],
    ) -> Result<SolveInfo, SolveError> {
        self.model
            .force_jacobians(
                self.work,
                0.0,
                y,
                &self.zero,
                &mut self.f,
                &mut self.dfdx,
                None,
            )
            .map_err(|e| SolveError::Factorization(e.to_string()))?;
        self.a.assign_lincomb(&[(-1.0, &self.dfdx)]);
        self.filter.project_matrix(&mut self.a);
        for (d, ri) in dy.iter_mut().zip(r) {
            *d = -ri;
        }
        self.filter.apply(dy);
        let info = self.chol.factorize(&self.a)?;
        self.chol.solve_in_place(dy)?;
        Ok(info)
    }

    fn merit(&mut self, y: &[f64]) -> Option<f64> {
        let w = self.model.elastic_energy(y);
        // The pinned vertices do not move, so their load terms are constants.
        Some(w - self.lambda * kv::dot(self.gravity, y))
    }
}

impl Fem {
    /// Solves for static equilibrium under gravity from the positions in `x` (pinned
    /// vertices stay where `x` has them), in `load_steps` increments (>= 1), each to a
    /// residual `tolerance` times the load scale. Errors when the stiffness is not
    /// definite (an unconstrained body: pin it) or Newton does not converge.
    pub fn solve_static(
        &self,
        x: &mut [f64],
        load_steps: usize,
        tolerance: f64,
    ) -> Result<StaticInfo, SolveError> {
        let n = self.n;
        assert_eq!(x.len(), 3 * n, "positions of every vertex");
        let load_steps = load_steps.max(1);
        let mut work = self.work();
        let pattern = self
            .prepare_jacobians(&mut work)
            .map_err(|e| SolveError::Factorization(e.to_string()))?
            .expect("FEM models assemble Jacobians");
        let mut filter = Filter::new(n);
        self.constraints(&mut filter);
        let mut gravity = vec![0.0; 3 * n];
        self.loads.gravity.write_forces(&self.body(), &mut gravity);
        let mut fg = gravity.clone();
        filter.apply(&mut fg);
        let load_scale = (0..n)
            .map(|i| (0..3).map(|c| fg[c * n + i].powi(2)).sum::<f64>().sqrt())
            .fold(0.0, f64::max);
        let mut problem = Equilibrium {
            model: self,
            work: &mut work,
            filter: &filter,
            lambda: 0.0,
            gravity: &gravity,
            f: vec![0.0; 3 * n],
            zero: vec![0.0; 3 * n],
            dfdx: Bsr3::zeros(pattern.clone()),
            a: Bsr3::zeros(pattern.clone()),
            chol: SparseCholesky::new(&pattern)?,
        };
        let mut newton = Newton::new(3 * n);
        let params = NewtonParams {
            max_iterations: 50,
            tolerance: 0.0,
            abs_tolerance: tolerance * load_scale.max(f64::MIN_POSITIVE),
            ..NewtonParams::default()
        };
        let mut info = StaticInfo {
            load_steps,
            load_scale,
            ..StaticInfo::default()
        };
        for k in 1..=load_steps {
            problem.lambda = k as f64 / load_steps as f64;
            let ni = newton.solve(&mut problem, x, &params)?;
            info.newton_iterations += ni.iterations;
            info.residual = ni.residual;
        }
        Ok(info)
    }
}
