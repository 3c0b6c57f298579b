//! A scene's simulation: the model, its state and a stepper, with a record of the stages
//! that were built and those left out (what `largestep run --explain` prints).

use super::{Scene, System};
use crate::cloth::Cloth;
use crate::integrate::MechState;
use crate::integrate::{kinetic_energy, IntegrateError, MechStepper, Mechanical, Method, StepInfo};
use crate::io::MeshRef;
use crate::mass_spring::MassSpring;

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

/// The system a simulation steps.
#[allow(clippy::large_enum_variant)] // one per simulation
enum Body {
    MassSpring(MassSpring),
    Cloth(Cloth),
}

impl Body {
    fn mech(&mut self) -> &mut dyn Mechanical {
        match self {
            Body::MassSpring(m) => m,
            Body::Cloth(c) => c,
        }
    }
    fn mech_ref(&self) -> &dyn Mechanical {
        match self {
            Body::MassSpring(m) => m,
            Body::Cloth(c) => c,
        }
    }
}

/// A running simulation of a scene's system.
pub struct Simulation {
    body: Body,
    state: MechState,
    stepper: MechStepper,
    dt: f64,
    /// Cloth step-size control: the current sub-step, good sub-steps in a row, and the
    /// state saved before each attempt.
    sub_dt: f64,
    good_steps: u32,
    saved: Option<(Vec<f64>, Vec<f64>)>,
    t: f64,
    stages: Vec<Stage>,
}

impl Simulation {
    /// Builds the stepper (and, for implicit methods only, the Jacobian structures).
    pub fn new(scene: Scene) -> Result<Self, IntegrateError> {
        let (mut body, state) = match scene.system {
            System::MassSpring(m, s) => (Body::MassSpring(m), s),
            System::Cloth(c, s) => (Body::Cloth(c), s),
        };
        let stepper = MechStepper::new(scene.settings, body.mech())?;
        let method = scene.settings.method;
        let mut stages = match &body {
            Body::MassSpring(model) => mass_spring_stages(model),
            Body::Cloth(cloth) => cloth_stages(cloth),
        };
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
        match &body {
            Body::MassSpring(model) => stages.extend(environment_stages(model)),
            Body::Cloth(c) => {
                stages.push(if c.obstacles().is_empty() {
                    stage("collision structures", false, "the scene has no colliders")
                } else {
                    let kinds: Vec<&str> = c.obstacles().iter().map(|o| o.kind()).collect();
                    stage(
                        "obstacle contacts (constraint filter + position correction)",
                        true,
                        kinds.join(", "),
                    )
                });
                stages.push(match c.wind() {
                    Some(w) => stage(
                        "wind",
                        true,
                        format!("air {:?} m/s, drag {}", w.velocity, w.drag),
                    ),
                    None => stage("wind", false, "no [cloth.wind]"),
                });
                stages.push(if c.paths().is_empty() {
                    stage("prescribed paths", false, "no [[cloth.path]]")
                } else {
                    stage(
                        "prescribed paths",
                        true,
                        format!("{} paths", c.paths().len()),
                    )
                });
                let sc = c.step_control();
                stages.push(stage(
                    "step-size control",
                    true,
                    format!(
                        "halve dt when a step fails or changes a strain by more than {} (at most {} times)",
                        sc.max_strain_change, sc.max_halvings
                    ),
                ));
            }
        }
        let saved = match &body {
            Body::Cloth(_) => Some((state.x.as_slice().to_vec(), state.v.as_slice().to_vec())),
            Body::MassSpring(_) => None,
        };
        Ok(Self {
            body,
            state,
            stepper,
            dt: scene.dt,
            sub_dt: scene.dt,
            good_steps: 0,
            saved,
            t: 0.0,
            stages,
        })
    }

    /// Advances one time step of the scene's dt. Cloth steps go through step-size control
    /// ([`crate::cloth::StepControl`]: a failed or over-stretched sub-step is undone and
    /// retried at half the size; sizes grow back after two good sub-steps), and after
    /// every sub-step path vertices are placed and contacts resolved (so frames and logs
    /// see corrected positions; the contacts found constrain the next solve). The
    /// returned counts sum over the sub-steps.
    pub fn step(&mut self) -> Result<StepInfo, IntegrateError> {
        let Body::Cloth(_) = &self.body else {
            let info = self.stepper.step(
                self.body.mech(),
                self.t,
                self.state.x.as_mut_slice(),
                self.state.v.as_mut_slice(),
                self.dt,
            )?;
            self.t += self.dt;
            return Ok(info);
        };
        let end = self.t + self.dt;
        let mut total = StepInfo::default();
        while self.t < end - 1e-12 * self.dt {
            let h = self.sub_dt.min(end - self.t);
            let Body::Cloth(c) = &mut self.body else {
                unreachable!()
            };
            let control = c.step_control();
            let (xs, vs) = self.saved.as_mut().expect("cloth keeps a saved state");
            xs.copy_from_slice(self.state.x.as_slice());
            vs.copy_from_slice(self.state.v.as_slice());
            let result = self.stepper.step(
                c,
                self.t,
                self.state.x.as_mut_slice(),
                self.state.v.as_mut_slice(),
                h,
            );
            let why = match result {
                Ok(info) => {
                    let (xs, _) = self.saved.as_ref().expect("cloth keeps a saved state");
                    let change = c.strain_change(xs, self.state.x.as_slice());
                    if change <= control.max_strain_change {
                        total.newton_iterations += info.newton_iterations;
                        total.linear_iterations += info.linear_iterations;
                        total.residual = info.residual;
                        total.solve_seconds += info.solve_seconds;
                        self.t += h;
                        let (x, v) = (self.state.x.as_mut_slice(), self.state.v.as_mut_slice());
                        c.after_step(self.t, h, x, v);
                        self.good_steps += 1;
                        if self.good_steps >= 2 && self.sub_dt < self.dt {
                            self.sub_dt = (2.0 * self.sub_dt).min(self.dt);
                            self.good_steps = 0;
                        }
                        continue;
                    }
                    format!(
                        "a triangle's strain changed by {change:.3} in one step, above max_strain_change = {}",
                        control.max_strain_change
                    )
                }
                Err(e) => e.to_string(),
            };
            // Undo and halve.
            let (xs, vs) = self.saved.as_ref().expect("cloth keeps a saved state");
            self.state.x.as_mut_slice().copy_from_slice(xs);
            self.state.v.as_mut_slice().copy_from_slice(vs);
            self.good_steps = 0;
            // Give up when the step that failed was already the smallest allowed.
            let smallest = self.dt / 2f64.powi(control.max_halvings as i32);
            if h <= smallest * (1.0 + 1e-9) {
                return Err(IntegrateError::StepControl {
                    step: self.stepper.steps(),
                    halvings: control.max_halvings,
                    dt: h,
                    why,
                });
            }
            self.sub_dt = h / 2.0;
        }
        self.t = end;
        Ok(total)
    }

    /// The current sub-step of cloth step-size control (s): the scene's dt unless steps
    /// were halved recently.
    pub fn sub_step(&self) -> f64 {
        self.sub_dt
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
            kinetic_energy(self.body.mech_ref().mass(), self.state.v.as_slice()),
            self.body
                .mech_ref()
                .potential_energy(self.t, self.state.x.as_slice())
                .unwrap_or(0.0),
        )
    }

    /// The deepest penetration into a collision surface (m), 0 without collisions.
    pub fn max_penetration(&self) -> f64 {
        match &self.body {
            Body::MassSpring(m) => m.max_penetration(self.state.x.as_slice()),
            Body::Cloth(c) => c.max_penetration(self.state.x.as_slice()),
        }
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

    /// The cloth, when the scene's system is one.
    pub fn cloth(&self) -> Option<&Cloth> {
        match &self.body {
            Body::Cloth(c) => Some(c),
            Body::MassSpring(_) => None,
        }
    }

    /// The current state.
    pub fn state(&self) -> &MechState {
        &self.state
    }

    /// The current geometry for output: triangles if the model has them, else springs.
    pub fn mesh(&self) -> MeshRef<'_> {
        let (tris, springs): (&[[u32; 3]], &[[u32; 2]]) = match &self.body {
            Body::MassSpring(m) => (m.triangles(), m.spring_ends()),
            Body::Cloth(c) => (c.triangles(), &[]),
        };
        MeshRef {
            positions: self.state.x.as_slice(),
            triangles: tris,
            segments: if tris.is_empty() { springs } else { &[] },
        }
    }
}

fn gravity_stage(g: [f64; 3]) -> Stage {
    stage(
        "gravity",
        g != [0.0; 3],
        if g != [0.0; 3] {
            format!("{g:?} m/s^2")
        } else {
            "gravity is zero".into()
        },
    )
}

fn pinned_stage(count: usize) -> Stage {
    stage(
        "pinned-particle filter",
        count > 0,
        if count > 0 {
            format!("{count} pinned particles")
        } else {
            "nothing is pinned".into()
        },
    )
}

fn mass_spring_stages(model: &MassSpring) -> Vec<Stage> {
    vec![
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
        gravity_stage(model.gravity()),
        pinned_stage(model.pinned_count()),
    ]
}

fn cloth_stages(cloth: &Cloth) -> Vec<Stage> {
    let m = cloth.material();
    let bend = !cloth.hinges().is_empty();
    vec![
        stage(
            "cloth stretch and shear elements",
            true,
            format!(
                "{} vertices, {} triangles",
                cloth.vertex_count(),
                cloth.triangles().len()
            ),
        ),
        stage(
            "bend elements (hinges)",
            bend,
            if bend {
                format!("{} hinges", cloth.hinges().len())
            } else {
                "bending is off (bend stiffness and damping are zero)".into()
            },
        ),
        stage(
            "cloth damping",
            cloth.has_velocity_jacobian(),
            if cloth.has_velocity_jacobian() {
                format!(
                    "stretch {}, shear {}, bend {}",
                    m.stretch_damping, m.shear_damping, m.bend_damping
                )
            } else {
                "every damping coefficient is zero".into()
            },
        ),
        gravity_stage(cloth.gravity()),
        pinned_stage(cloth.pinned().len()),
    ]
}

fn environment_stages(model: &MassSpring) -> [Stage; 2] {
    [
        match model.collisions() {
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
        },
        match model.force_field() {
            Some(f) => stage(
                "force field",
                true,
                format!("{:?} nodes, trilinear", f.grid.n),
            ),
            None => stage("force field", false, "the scene has none"),
        },
    ]
}
