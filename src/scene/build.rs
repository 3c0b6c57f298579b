//! A scene's simulation: the model, its state and a stepper, with a record of the stages
//! that were built and those left out (what `largestep run --explain` prints).

use super::{Scene, System};
use crate::integrate::{kinetic_energy, IntegrateError, MechStepper, Mechanical, Method, StepInfo};
use crate::io::MeshRef;
use crate::mass_spring::{MassSpring, MassSpringState};

/// One stage of a simulation: built or left out, and why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Stage {
    /// What it is.
    pub name: &'static str,
    /// Whether it was built.
    pub built: bool,
    /// Size when built, reason when left out.
    pub detail: String,
}

fn stage(name: &'static str, built: bool, detail: impl Into<String>) -> Stage {
    Stage {
        name,
        built,
        detail: detail.into(),
    }
}

/// A running simulation of a scene's system.
pub struct Simulation {
    model: MassSpring,
    state: MassSpringState,
    stepper: MechStepper,
    dt: f64,
    t: f64,
    stages: Vec<Stage>,
}

impl Simulation {
    /// Builds the stepper (and, for implicit methods only, the Jacobian structures).
    pub fn new(scene: Scene) -> Result<Self, IntegrateError> {
        let System::MassSpring(mut model, state) = scene.system;
        let stepper = MechStepper::new(scene.settings, &mut model)?;
        let method = scene.settings.method;
        let g = model.gravity();
        let mut stages = vec![
            stage(
                "spring forces",
                model.spring_count() > 0,
                if model.spring_count() > 0 {
                    format!(
                        "{} particles, {} springs",
                        model.particle_count(),
                        model.spring_count()
                    )
                } else {
                    format!("{} particles and no springs", model.particle_count())
                },
            ),
            stage(
                "spring damping",
                model.has_damping(),
                if model.has_damping() {
                    "damping along springs"
                } else {
                    "every damping coefficient is zero"
                },
            ),
            stage(
                "gravity",
                g != [0.0; 3],
                if g != [0.0; 3] {
                    format!("{g:?} m/s^2")
                } else {
                    "gravity is zero".into()
                },
            ),
            stage(
                "pinned-particle filter",
                model.pinned_count() > 0,
                if model.pinned_count() > 0 {
                    format!("{} pinned particles", model.pinned_count())
                } else {
                    "nothing is pinned".into()
                },
            ),
        ];
        if stepper.has_matrix() {
            stages.push(stage(
                "Jacobian assembly (Bsr3 pattern, element maps)",
                true,
                format!("for {method}"),
            ));
            stages.push(stage(
                "damping Jacobian",
                stepper.has_damping_matrix(),
                if stepper.has_damping_matrix() {
                    "df/dv"
                } else {
                    "no damping"
                },
            ));
            stages.push(stage(
                "linear solver",
                true,
                stepper.linear_solver_name().unwrap_or("none").to_string(),
            ));
            let newton = !matches!(method, Method::LinearizedBackwardEuler);
            stages.push(stage(
                "Newton iteration",
                newton,
                if newton {
                    "with backtracking line search"
                } else {
                    "one linearised step"
                },
            ));
        } else {
            stages.push(stage(
                "Jacobian assembly, system matrix and linear solver",
                false,
                format!("{method} is explicit"),
            ));
        }
        stages.push(match model.collisions() {
            Some(p) => stage(
                "penalty collisions",
                true,
                format!(
                    "{} surfaces, k_c = {} N/m, d_c = {} N s/m",
                    p.surfaces.len(),
                    p.stiffness,
                    p.damping
                ),
            ),
            None => stage("collision structures", false, "the scene has no colliders"),
        });
        stages.push(match model.force_field() {
            Some(f) => stage(
                "force field",
                true,
                format!("{:?} nodes, trilinear", f.grid.n),
            ),
            None => stage("force field", false, "the scene has none"),
        });
        Ok(Self {
            model,
            state,
            stepper,
            dt: scene.dt,
            t: 0.0,
            stages,
        })
    }

    /// Advances one time step.
    pub fn step(&mut self) -> Result<StepInfo, IntegrateError> {
        let info = self.stepper.step(
            &mut self.model,
            self.t,
            self.state.x.as_mut_slice(),
            self.state.v.as_mut_slice(),
            self.dt,
        )?;
        self.t += self.dt;
        Ok(info)
    }

    /// Simulated time (s).
    pub fn time(&self) -> f64 {
        self.t
    }

    /// Steps taken.
    pub fn steps(&self) -> u64 {
        self.stepper.steps()
    }

    /// Kinetic and potential energy (J).
    pub fn energy(&self) -> (f64, f64) {
        (
            kinetic_energy(self.model.mass(), self.state.v.as_slice()),
            self.model
                .potential_energy(self.t, self.state.x.as_slice())
                .unwrap_or(0.0),
        )
    }

    /// The deepest penetration into a collision surface (m), 0 without collisions.
    pub fn max_penetration(&self) -> f64 {
        self.model.max_penetration(self.state.x.as_slice())
    }

    /// The stages built and left out.
    pub fn stages(&self) -> &[Stage] {
        &self.stages
    }

    /// The integrator.
    pub fn method(&self) -> Method {
        self.stepper.settings().method
    }

    /// The linear solver of implicit steps.
    pub fn linear_solver(&self) -> Option<&'static str> {
        self.stepper.linear_solver_name()
    }

    /// The current state.
    pub fn state(&self) -> &MassSpringState {
        &self.state
    }

    /// The model.
    pub fn model(&self) -> &MassSpring {
        &self.model
    }

    /// The current geometry for output: triangles if the model has them, else springs.
    pub fn mesh(&self) -> MeshRef<'_> {
        let tris = self.model.triangles();
        MeshRef {
            positions: self.state.x.as_slice(),
            triangles: tris,
            segments: if tris.is_empty() {
                self.model.spring_ends()
            } else {
                &[]
            },
        }
    }
}
