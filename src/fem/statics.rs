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

/// The solver's buffers, built once per model: scratch, the pins' filter, the gravity
/// forces, the matrices and the Cholesky factor's structure.
pub struct StaticSolver {
    work: <Fem as MechModel>::Work,
    filter: Filter,
    gravity: Vec<f64>,
    f: Vec<f64>,
    /// Velocities for the Jacobian evaluation (statics has none).
    zero: Vec<f64>,
    dfdx: Bsr3,
    a: Bsr3,
    chol: SparseCholesky,
    newton: Newton,
    load_scale: f64,
}

/// The Newton problem of one load increment.
struct Equilibrium<'a> {
    model: &'a Fem,
    s: &'a mut StaticSolver,
    lambda: f64,
}

impl Equilibrium<'_> {
    /// `f = f_el(y) + lambda f_g`.
    fn forces(&mut self, y: &[f64]) {
        let s = &mut *self.s;
        s.f.fill(0.0);
        self.model.element_forces_into(&mut s.work.f, y, None);
        self.model.gather.gather_vectors_add(&s.work.f, &mut s.f);
        kv::axpy(&mut s.f, self.lambda, &s.gravity);
    }
}

impl NewtonProblem for Equilibrium<'_> {
    fn residual(&mut self, y: &[f64], r: &mut [f64]) -> Result<(), SolveError> {
        self.forces(y);
        for (ri, fi) in r.iter_mut().zip(&self.s.f) {
            *ri = -fi;
        }
        self.s.filter.apply(r);
        Ok(())
    }

    fn newton_step(
        &mut self,
        y: &[f64],
        r: &[f64],
        dy: &mut [f64],
    ) -> Result<SolveInfo, SolveError> {
        let s = &mut *self.s;
        self.model
            .force_jacobians(&mut s.work, 0.0, y, &s.zero, &mut s.f, &mut s.dfdx, None)
            .map_err(|e| SolveError::Factorization(e.to_string()))?;
        s.a.assign_lincomb(&[(-1.0, &s.dfdx)]);
        s.filter.project_matrix(&mut s.a);
        for (d, ri) in dy.iter_mut().zip(r) {
            *d = -ri;
        }
        s.filter.apply(dy);
        let info = s.chol.factorize(&s.a)?;
        s.chol.solve_in_place(dy)?;
        Ok(info)
    }

    fn merit(&mut self, y: &[f64]) -> Option<f64> {
        let w = self.model.elastic_energy(y);
        // The pinned vertices do not move, so their load terms are constants.
        Some(w - self.lambda * kv::dot(&self.s.gravity, y))
    }
}

impl StaticSolver {
    /// The solver for `model` (its pattern, filter and factor structure).
    pub fn new(model: &Fem) -> Result<Self, SolveError> {
        let n = model.n;
        let mut work = model.work();
        let pattern = model
            .prepare_jacobians(&mut work)
            .map_err(|e| SolveError::Factorization(e.to_string()))?
            .expect("FEM models assemble Jacobians");
        let mut filter = Filter::new(n);
        model.constraints(&mut filter);
        let mut gravity = vec![0.0; 3 * n];
        model
            .loads
            .gravity
            .write_forces(&model.body(), &mut gravity);
        let mut fg = gravity.clone();
        filter.apply(&mut fg);
        let load_scale = (0..n)
            .map(|i| (0..3).map(|c| fg[c * n + i].powi(2)).sum::<f64>().sqrt())
            .fold(0.0, f64::max);
        Ok(Self {
            work,
            filter,
            gravity,
            f: vec![0.0; 3 * n],
            zero: vec![0.0; 3 * n],
            dfdx: Bsr3::zeros(pattern.clone()),
            a: Bsr3::zeros(pattern.clone()),
            chol: SparseCholesky::new(&pattern)?,
            newton: Newton::new(3 * n),
            load_scale,
        })
    }

    /// The largest load (gravity force) on a free vertex (N).
    pub fn load_scale(&self) -> f64 {
        self.load_scale
    }

    /// Solves for equilibrium under `lambda` times the loads from the positions in `x`,
    /// to a residual of `tolerance` times the load scale; returns Newton's count and the
    /// final residual.
    pub fn solve(
        &mut self,
        model: &Fem,
        x: &mut [f64],
        lambda: f64,
        tolerance: f64,
    ) -> Result<(usize, f64), SolveError> {
        let params = NewtonParams {
            max_iterations: 50,
            tolerance: 0.0,
            abs_tolerance: tolerance * self.load_scale.max(f64::MIN_POSITIVE),
            ..NewtonParams::default()
        };
        let mut newton = std::mem::replace(&mut self.newton, Newton::new(0));
        let result = newton.solve(
            &mut Equilibrium {
                model,
                s: self,
                lambda,
            },
            x,
            &params,
        );
        self.newton = newton;
        let ni = result?;
        Ok((ni.iterations, ni.residual))
    }
}

impl Fem {
    /// Solves for static equilibrium under gravity from the positions in `x` (pinned
    /// vertices stay where `x` has them), in `load_steps` increments (>= 1), each to a
    /// residual `tolerance` times the load scale. Errors when the stiffness is not
    /// definite (an unconstrained body: pin it) or Newton does not converge. Runs on a
    /// thread of rayon's pool ([`largestep_kernels::par::on_pool`]).
    pub fn solve_static(
        &self,
        x: &mut [f64],
        load_steps: usize,
        tolerance: f64,
    ) -> Result<StaticInfo, SolveError> {
        largestep_kernels::par::on_pool(|| self.solve_static_here(x, load_steps, tolerance))
    }

    /// [`Fem::solve_static`] on the calling thread.
    fn solve_static_here(
        &self,
        x: &mut [f64],
        load_steps: usize,
        tolerance: f64,
    ) -> Result<StaticInfo, SolveError> {
        assert_eq!(x.len(), 3 * self.n, "positions of every vertex");
        let load_steps = load_steps.max(1);
        let mut solver = StaticSolver::new(self)?;
        let mut info = StaticInfo {
            load_steps,
            load_scale: solver.load_scale(),
            ..StaticInfo::default()
        };
        for k in 1..=load_steps {
            let (its, residual) = solver.solve(self, x, k as f64 / load_steps as f64, tolerance)?;
            info.newton_iterations += its;
            info.residual = residual;
        }
        Ok(info)
    }
}

/// A static scene as a simulation (`[fem.static]`): step k applies load increment k of
/// `increments` and solves for equilibrium, so frame k shows the equilibrium under k /
/// increments of the loads; once the whole load is on, later steps change nothing. Time
/// is the scene's, and only counts frames.
pub struct StaticSimulation {
    model: std::sync::Arc<Fem>,
    solver: StaticSolver,
    x: Vec<f64>,
    t: f64,
    steps: u64,
    increments: usize,
    done: usize,
    tolerance: f64,
}

impl StaticSimulation {
    /// The static simulation of `model` from positions `x`, the load applied in
    /// `increments` steps, each solved to `tolerance` times the load scale.
    pub fn new(
        model: impl Into<std::sync::Arc<Fem>>,
        x: Vec<f64>,
        increments: usize,
        tolerance: f64,
    ) -> Result<Self, SolveError> {
        let model = model.into();
        let solver = StaticSolver::new(&model)?;
        Ok(Self {
            model,
            solver,
            x,
            t: 0.0,
            steps: 0,
            increments: increments.max(1),
            done: 0,
            tolerance,
        })
    }

    /// The model.
    pub fn model(&self) -> &Fem {
        &self.model
    }

    /// Positions now (component-major).
    pub fn positions(&self) -> &[f64] {
        &self.x
    }

    /// The load fraction applied so far.
    pub fn load_fraction(&self) -> f64 {
        self.done as f64 / self.increments as f64
    }
}

impl crate::simulation::Simulation for StaticSimulation {
    fn step(
        &mut self,
        dt: f64,
    ) -> Result<crate::integrate::StepInfo, crate::integrate::IntegrateError> {
        let mut info = crate::integrate::StepInfo::default();
        if self.done < self.increments {
            let start = std::time::Instant::now();
            let lambda = (self.done + 1) as f64 / self.increments as f64;
            let (its, residual) = self
                .solver
                .solve(&self.model, &mut self.x, lambda, self.tolerance)
                .map_err(|source| crate::integrate::IntegrateError::Static {
                    increment: self.done + 1,
                    increments: self.increments,
                    source,
                })?;
            self.done += 1;
            info.newton_iterations = its;
            info.residual = residual;
            info.solve_seconds = start.elapsed().as_secs_f64();
        }
        self.t += dt;
        self.steps += 1;
        Ok(info)
    }

    fn time(&self) -> f64 {
        self.t
    }

    fn steps(&self) -> u64 {
        self.steps
    }

    fn energy(&self) -> crate::simulation::Energy {
        // The potential of the loads applied so far: elastic energy minus their work.
        crate::simulation::Energy {
            kinetic: 0.0,
            potential: self.model.elastic_energy(&self.x)
                - self.load_fraction() * kv::dot(&self.solver.gravity, &self.x),
            external_work: 0.0,
        }
    }

    fn max_penetration(&self) -> f64 {
        crate::collide::max_penetration(self.model.obstacles(), &self.x)
    }

    fn frame(&self) -> crate::simulation::FrameData<'_> {
        crate::simulation::FrameData::Mesh(crate::io::MeshRef {
            positions: &self.x,
            triangles: self.model.triangles(),
            segments: &[],
        })
    }

    fn stages(&self) -> Vec<crate::simulation::Stage> {
        use crate::simulation::Stage;
        let mut stages = self.model.stages();
        stages.push(Stage::left_out(
            "time integration",
            "[fem.static]: static equilibrium",
        ));
        stages.push(Stage::built(
            crate::simulation::NEWTON_STAGE,
            format!(
                "static equilibrium with a line search on the energy, the load in {} increments, to {:e} of the load",
                self.increments, self.tolerance
            ),
        ));
        stages.push(Stage::built("linear solver", "cholesky"));
        stages
    }

    fn scenery(&self, around: ([f64; 3], [f64; 3])) -> Vec<crate::io::Mesh> {
        let obstacles = self.model.obstacles();
        let mut meshes: Vec<crate::io::Mesh> =
            obstacles.iter().filter_map(|o| o.preview_mesh()).collect();
        meshes.extend(crate::collide::Obstacle::plane_faces(obstacles, around));
        meshes
    }

    fn method(&self) -> String {
        "static".to_string()
    }

    fn linear_solver(&self) -> Option<&'static str> {
        Some("cholesky")
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn warnings(&self) -> Vec<String> {
        self.model.warnings()
    }
}
