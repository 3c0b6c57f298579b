//! The generic simulation of a mechanical model: model + integrator + state + contacts +
//! step-size control.
//!
//! [`MechModel`] is what a mechanical domain implements: the immutable data its builder
//! computed, with evaluation methods taking `&self` and a separate `Work` of scratch
//! buffers. An integrator steps a [`Mechanical`] system; [`MechSimulation`] binds the
//! model, its work and its contacts into one for each step (`Bound`), so that the model
//! itself is never written and can be shared (`Arc`) between threads and between
//! several simulations of one asset.
//!
//! Each step of [`MechSimulation::step`]:
//! 1. saves `(x, v)` when step-size control is on;
//! 2. steps the integrator; the model's constraints (pins) and the current contacts go
//!    into the constraint filter, and every force evaluation records the force pulling
//!    on each contact (what releases it);
//! 3. with step-size control, rejects a step that failed or changed some element's strain
//!    by more than [`StepControl::max_strain_change`]: the state is restored and the step
//!    retried at half the size, down to `dt / 2^max_halvings` (Baraff and Witkin 1998,
//!    section 5.3); after two good sub-steps the size doubles back towards `dt`;
//! 4. places prescribed vertices ([`MechModel::prescribe`]) and resolves contacts with
//!    the model's contact obstacles ([`VertexContacts::resolve`]).

use super::{Energy, FrameData, Simulation, Stage};
use crate::collide::{
    max_penetration, Against, MovingObstacle, Obstacle, Penalty, SelfCollision, SelfStats,
    VertexContacts,
};
use crate::integrate::{
    kinetic_energy, kinetic_energy_matrix, IntegrateError, MechSettings, MechState, MechStepper,
    Mechanical, Method, StepInfo,
};
use crate::io::{Mesh, MeshRef};
use crate::solve::Filter;
use crate::sparse::{Bsr3, Bsr3Pattern, SparseError};
use std::sync::Arc;

/// Step-size control (Baraff and Witkin 1998, section 5.3): a step that fails (the solve
/// does not converge, the state is not finite) or stretches or compresses some element by
/// more than `max_strain_change` in one step ([`MechModel::strain_change`]: the
/// large-step artifact of a linearised step turning a rotation into stretch) is undone and
/// retried as two half steps, down to `dt / 2^max_halvings`; after two good steps the step
/// doubles back towards dt. The limit is on the change, not the strain itself, so a model
/// that is strained where it hangs from a pin is not rejected for it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepControl {
    /// Largest change of any element's strain in one step (0.25: 25%), > 0.
    pub max_strain_change: f64,
    /// Halvings allowed before the run fails.
    pub max_halvings: u32,
}

impl Default for StepControl {
    fn default() -> Self {
        StepControl {
            max_strain_change: 0.25,
            max_halvings: 6,
        }
    }
}

impl StepControl {
    /// The cloth's default: a strain change of at most 10% a step (fabric stretches by a
    /// few per cent; more in one step is the linearised step's artifact or a contact
    /// response that dragged the cloth: at 25% the tablecloth stored 2 J of stretch when
    /// it met the table's edges). The study `cloth-stability` shows its cost.
    pub const CLOTH: StepControl = StepControl {
        max_strain_change: 0.1,
        max_halvings: 6,
    };

    /// Checks the settings (a `step_control` error naming the field).
    pub fn validate(&self) -> Result<(), crate::validate::ModelError> {
        let sc = self.max_strain_change;
        crate::validate::check(
            "step_control",
            0,
            "max_strain_change",
            sc,
            crate::validate::Rule::Positive,
        )
    }
}

/// An immutable mechanical model `M x'' = f(t, x, v)` with lumped masses (see the module
/// docs). Positions, velocities and forces are component-major Vec3s data of its n
/// vertices. The evaluation methods mirror [`Mechanical`]'s, with the scratch buffers
/// passed in.
pub trait MechModel: Send + Sync + 'static {
    /// Scratch buffers of force and Jacobian evaluation.
    type Work: Send;
    /// Fresh scratch buffers for force evaluation (Jacobian buffers are added by
    /// [`MechModel::prepare_jacobians`], for implicit integrators only).
    fn work(&self) -> Self::Work;
    /// Number of vertices n.
    fn vertex_count(&self) -> usize;
    /// Mass per vertex (kg), length n: > 0, or 0 for vertices the filter fixes.
    fn mass(&self) -> &[f64];
    /// Writes the model's own constraints into `filter`: by default its fixed vertices
    /// ([`MechModel::fixed_vertices`]: pinned, prescribed, massless) held in every
    /// direction.
    fn constraints(&self, filter: &mut Filter) {
        for &p in self.fixed_vertices() {
            filter.fix(p as usize);
        }
    }
    /// A norm (N) of the force terms that cancel in the net force at rest (elastic
    /// stresses times element areas): the net force rounds to a few eps times this, even
    /// where it should be zero, and Newton cannot reduce a residual below that.
    fn force_rounding(&self) -> f64 {
        0.0
    }
    /// `f = total force` (N) at time t, positions x (m) and velocities v (m/s).
    fn force(&self, work: &mut Self::Work, t: f64, x: &[f64], v: &[f64], f: &mut [f64]);
    /// Potential energy (J) of the non-damping forces, if they have one (see
    /// [`Mechanical::potential_energy`]).
    fn potential_energy(&self, t: f64, x: &[f64]) -> Option<f64> {
        let _ = (t, x);
        None
    }
    /// Rayleigh dissipation function (W) of the damping forces.
    fn dissipation(&self, x: &[f64], v: &[f64]) -> f64 {
        let _ = (x, v);
        0.0
    }
    /// Builds the Jacobian structures into `work` (once) and returns their block pattern,
    /// or `None` if the model provides no Jacobians.
    fn prepare_jacobians(
        &self,
        work: &mut Self::Work,
    ) -> Result<Option<Arc<Bsr3Pattern>>, SparseError> {
        let _ = work;
        Ok(None)
    }
    /// Whether `df/dv` can be non-zero.
    fn has_velocity_jacobian(&self) -> bool {
        false
    }
    /// `f`, `dfdx = df/dx` and, when asked, `dfdv = df/dv` (values overwritten).
    #[allow(clippy::too_many_arguments)]
    fn force_jacobians(
        &self,
        work: &mut Self::Work,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut Bsr3,
        dfdv: Option<&mut Bsr3>,
    ) -> Result<(), IntegrateError> {
        let _ = (work, t, x, v, f, dfdx, dfdv);
        Err(IntegrateError::Unsupported {
            method: Method::BackwardEuler,
            reason: "the system provides no Jacobians",
        })
    }
    /// `f` and an implicit step's matrix `a = diag(d) - ck df/dx` in one pass, where the
    /// model can (see [`Mechanical::force_system`]); `Ok(false)` having done nothing
    /// where it cannot (the default).
    #[allow(clippy::too_many_arguments)]
    fn force_system(
        &self,
        work: &mut Self::Work,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        a: &mut Bsr3,
        ck: f64,
        d: &[f64],
    ) -> Result<bool, IntegrateError> {
        let _ = (work, t, x, v, f, a, ck, d);
        Ok(false)
    }

    /// Every obstacle the model collides with (for penetration reports and scenery).
    fn obstacles(&self) -> &[Obstacle] {
        &[]
    }
    /// `Some(friction)` when the simulation resolves [`MechModel::obstacles`] as
    /// constraint contacts after each step ([`VertexContacts`]); `None` when the model
    /// handles them inside its force (penalties) or has none.
    fn contact_friction(&self) -> Option<f64> {
        None
    }
    /// The model's consistent mass matrix, if it uses one (see
    /// [`Mechanical::mass_matrix`]).
    fn mass_matrix(&self) -> Option<&Bsr3> {
        None
    }
    /// The penalty law of the model's own obstacles, when it meets them with forces
    /// (collision springs inside [`MechModel::force`]): other systems' moving obstacles
    /// then act through the same law, with velocities relative to them.
    fn penalty(&self) -> Option<&Penalty> {
        None
    }
    /// Whether the model has a volume to write ([`MechModel::write_volume`]).
    fn has_volume(&self) -> bool {
        false
    }
    /// Writes the model's volume at positions x and velocities v (legacy VTK).
    fn write_volume(
        &self,
        w: &mut dyn std::io::Write,
        comment: &str,
        x: &[f64],
        v: &[f64],
    ) -> std::io::Result<()> {
        let _ = (w, comment, x, v);
        Ok(())
    }
    /// Vertices that contacts never move, sorted: pinned and prescribed ones.
    fn fixed_vertices(&self) -> &[u32] {
        &[]
    }
    /// `Some(thickness)` (m) when the model's surface ([`MechModel::triangles`]) must not
    /// pass through itself: the simulation then runs [`SelfCollision`] after each step.
    fn self_collision(&self) -> Option<f64> {
        None
    }
    /// Places prescribed vertices (position and velocity) at time `t`, after each step.
    fn prescribe(&self, t: f64, x: &mut [f64], v: &mut [f64]) {
        let _ = (t, x, v);
    }
    /// The largest change of any element's strain between positions `x0` and `x` (NaN if
    /// any is NaN): what [`StepControl`] limits.
    fn strain_change(&self, x0: &[f64], x: &[f64]) -> f64 {
        let _ = (x0, x);
        0.0
    }
    /// Step-size control, if the model asks for it.
    fn step_control(&self) -> Option<StepControl> {
        None
    }
    /// What the model found questionable in its input but runs with (see
    /// [`Simulation::warnings`]).
    fn warnings(&self) -> Vec<String> {
        Vec::new()
    }
    /// Whether loads without a potential (wind, force fields) act on the model.
    fn does_external_work(&self) -> bool {
        false
    }
    /// The rate (W) at which those loads do work at time `t` and state `(x, v)`.
    fn external_power(&self, t: f64, x: &[f64], v: &[f64]) -> f64 {
        let _ = (t, x, v);
        0.0
    }
    /// The model's stages for `--explain`: elements, damping, loads, pins, collisions.
    fn stages(&self) -> Vec<Stage>;
    /// Surface triangles written per frame (may be empty).
    fn triangles(&self) -> &[[u32; 3]] {
        &[]
    }
    /// Segments (springs) written per frame when there are no triangles.
    fn segments(&self) -> &[[u32; 2]] {
        &[]
    }
}

/// A model, its scratch and its contacts, bound for one step: what the integrator sees.
struct Bound<'a, M: MechModel> {
    model: &'a M,
    work: &'a mut M::Work,
    contacts: &'a mut VertexContacts,
    /// Self-collision, whose start-of-step approaches the filter takes.
    self_collision: Option<&'a SelfCollision>,
    /// Other systems' moving obstacles, which a model with penalty contacts
    /// ([`MechModel::penalty`]) meets with its collision springs.
    moving: &'a [MovingObstacle],
}

/// The model's penalty law, when moving obstacles are there to meet with it.
fn moving_penalty<'a, M: MechModel>(
    model: &'a M,
    moving: &[MovingObstacle],
) -> Option<&'a Penalty> {
    model.penalty().filter(|_| !moving.is_empty())
}

impl<M: MechModel> Mechanical for Bound<'_, M> {
    fn vertex_count(&self) -> usize {
        self.model.vertex_count()
    }
    fn mass(&self) -> &[f64] {
        self.model.mass()
    }
    fn mass_matrix(&self) -> Option<&Bsr3> {
        self.model.mass_matrix()
    }
    fn force_rounding(&self) -> f64 {
        self.model.force_rounding()
    }
    fn constraints(&self, filter: &mut Filter) {
        // Contacts first, then the model's own: a pinned vertex in contact stays fixed.
        // Self contacts last, on the vertices still free.
        self.contacts.constraints(filter);
        self.model.constraints(filter);
        if let Some(sc) = self.self_collision {
            sc.constraints(filter);
        }
    }
    fn force(&mut self, t: f64, x: &[f64], v: &[f64], f: &mut [f64]) {
        self.model.force(self.work, t, x, v, f);
        if let Some(p) = moving_penalty(self.model, self.moving) {
            p.add_forces(Against::Moving(self.moving), x, v, f);
        }
        self.contacts.record_pull(f);
    }
    fn potential_energy(&self, t: f64, x: &[f64]) -> Option<f64> {
        let moving = moving_penalty(self.model, self.moving)
            .map_or(0.0, |p| p.energy(Against::Moving(self.moving), x));
        Some(self.model.potential_energy(t, x)? + moving)
    }
    fn dissipation(&self, x: &[f64], v: &[f64]) -> f64 {
        let moving = moving_penalty(self.model, self.moving)
            .map_or(0.0, |p| p.dissipation(Against::Moving(self.moving), x, v));
        self.model.dissipation(x, v) + moving
    }
    fn prepare_jacobians(&mut self) -> Result<Option<Arc<Bsr3Pattern>>, SparseError> {
        self.model.prepare_jacobians(self.work)
    }
    fn has_velocity_jacobian(&self) -> bool {
        self.model.has_velocity_jacobian()
    }
    fn force_jacobians(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut Bsr3,
        dfdv: Option<&mut Bsr3>,
    ) -> Result<(), IntegrateError> {
        let mut dfdv = dfdv;
        self.model
            .force_jacobians(self.work, t, x, v, f, dfdx, dfdv.as_deref_mut())?;
        if let Some(p) = moving_penalty(self.model, self.moving) {
            let against = Against::Moving(self.moving);
            p.add_forces(against, x, v, f);
            p.add_jacobians(against, x, dfdx, dfdv);
        }
        self.contacts.record_pull(f);
        Ok(())
    }
    fn force_system(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        a: &mut Bsr3,
        ck: f64,
        d: &[f64],
    ) -> Result<bool, IntegrateError> {
        // Moving obstacles' penalty Jacobians are added to df/dx on its own.
        if moving_penalty(self.model, self.moving).is_some() {
            return Ok(false);
        }
        let done = self.model.force_system(self.work, t, x, v, f, a, ck, d)?;
        if done {
            self.contacts.record_pull(f);
        }
        Ok(done)
    }
}

/// The simulation of a mechanical model (see the module docs).
///
/// ```
/// use largestep::integrate::{MechSettings, Method};
/// use largestep::mass_spring::chain;
/// use largestep::simulation::{MechSimulation, Simulation};
///
/// let mut desc = chain(10, [0.0; 3], [1.0, 0.0, 0.0], 0.1, 0.01, 200.0, 0.01);
/// desc.gravity = [0.0, -9.81, 0.0];
/// let (model, state) = desc.build()?;
/// let settings = MechSettings::new(Method::BackwardEuler);
/// let mut sim = MechSimulation::new(model, state, settings)?;
/// for _ in 0..100 {
///     sim.step(0.01)?;
/// }
/// assert!(sim.state().x.get(9)[1] < 0.0); // the free end has swung down
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct MechSimulation<M: MechModel> {
    model: Arc<M>,
    state: MechState,
    contacts: VertexContacts,
    work: M::Work,
    stepper: MechStepper,
    control: Option<StepControl>,
    /// Step-size control: the current sub-step (NaN until the first step), good
    /// sub-steps in a row, and the state saved before each attempt.
    sub_dt: f64,
    good_steps: u32,
    saved: (Vec<f64>, Vec<f64>),
    saved_contacts: VertexContacts,
    t: f64,
    /// Work done by the loads without a potential so far (J), by the trapezoidal rule
    /// over accepted steps, and their power at the end of the last one (W).
    external_work: f64,
    power: f64,
    /// The moving obstacles' power through collision springs at the end of the last step
    /// (W; see [`Penalty::power`]), counted in `external_work`.
    moving_power: f64,
    /// The model's initial size (m): the diagonal of its vertices' bounding box, at least
    /// 1 m. A vertex moving ten times that in one step is a blow-up.
    size: f64,
    /// Contact impulses, while a listener wants them.
    impulses: Option<Box<ImpulseRecorder>>,
    /// Self-collision and the inverse masses it weighs impulses by (0 at fixed
    /// vertices), when the model asks for it; with what it did over the last step.
    self_collision: Option<(Box<SelfCollision>, Vec<f64>)>,
    self_stats: SelfStats,
    /// Obstacles of other systems (rigid bodies) at the poses of the present sub-step's
    /// end, with their motion: the contacts take them with the model's own (one-way
    /// coupling).
    moving: Vec<MovingObstacle>,
    /// The same at the end of the step they were handed over for ([`Self::moving`] is
    /// them taken back to each sub-step's end).
    moving_end: Vec<MovingObstacle>,
}

/// What recording contact impulses needs (see [`MechSimulation::record_contact_impulses`]).
#[derive(Clone, Debug, Default)]
struct ImpulseRecorder {
    /// Positions when recording began, less their centre of mass: the frame the impulses
    /// are given in.
    initial: Vec<f64>,
    /// Velocities at the start of the step.
    v0: Vec<f64>,
    /// Scratch: the force at the end of the last sub-step's solve.
    force: Vec<f64>,
    /// `h f(x1, v1)` summed over the accepted sub-steps of the step (N s).
    force_impulse: Vec<f64>,
    /// Vertices touching an obstacle before or after the step.
    touching: Vec<u32>,
    out: crate::simulation::ContactImpulses,
}

/// The diagonal of the bounding box of component-major positions (m), at least 1 m.
fn size_of(x: &[f64]) -> f64 {
    let n = x.len() / 3;
    let mut d2 = 0.0;
    for c in 0..3 {
        let s = &x[c * n..(c + 1) * n];
        let (lo, hi) = s
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        if hi > lo {
            d2 += (hi - lo) * (hi - lo);
        }
    }
    d2.sqrt().max(1.0)
}

/// The centre of mass (m) of the component-major positions `x` with `mass` per vertex.
fn centre_of_mass(mass: &[f64], x: &[f64]) -> [f64; 3] {
    let n = mass.len();
    let total: f64 = mass.iter().sum();
    std::array::from_fn(|c| (0..n).map(|i| mass[i] * x[c * n + i]).sum::<f64>() / total)
}

/// The largest speed in component-major velocities (m/s); NaN if any is NaN.
fn max_speed(v: &[f64]) -> f64 {
    let n = v.len() / 3;
    let mut m2 = 0.0f64;
    for i in 0..n {
        let s2 = v[i] * v[i] + v[n + i] * v[n + i] + v[2 * n + i] * v[2 * n + i];
        if s2.is_nan() {
            return f64::NAN;
        }
        m2 = m2.max(s2);
    }
    m2.sqrt()
}

impl<M: MechModel> MechSimulation<M> {
    /// A simulation of `model` from `state` with the integrator of `settings` (implicit
    /// methods build the Jacobian structures here). `model` may be shared: pass an
    /// `Arc<M>` to step several simulations of one model.
    pub fn new(
        model: impl Into<Arc<M>>,
        state: MechState,
        settings: MechSettings,
    ) -> Result<Self, IntegrateError> {
        let model = model.into();
        let n = model.vertex_count();
        for got in [state.x.len(), state.v.len()] {
            if got != n {
                return Err(IntegrateError::StateSize { expected: n, got });
            }
        }
        let mut work = model.work();
        let mut contacts = VertexContacts::new();
        let stepper = MechStepper::new(
            settings,
            &mut Bound {
                model: &*model,
                work: &mut work,
                contacts: &mut contacts,
                self_collision: None,
                moving: &[],
            },
        )?;
        let control = model.step_control();
        let saved = match control {
            Some(_) => (vec![0.0; 3 * n], vec![0.0; 3 * n]),
            None => (Vec::new(), Vec::new()),
        };
        let power = if model.does_external_work() {
            model.external_power(0.0, state.x.as_slice(), state.v.as_slice())
        } else {
            0.0
        };
        let size = size_of(state.x.as_slice());
        let self_collision = model.self_collision().map(|thickness| {
            let mut inv: Vec<f64> = model
                .mass()
                .iter()
                .map(|m| if *m > 0.0 { 1.0 / m } else { 0.0 })
                .collect();
            for &f in model.fixed_vertices() {
                inv[f as usize] = 0.0;
            }
            let tris: Arc<[[u32; 3]]> = model.triangles().into();
            (Box::new(SelfCollision::new(tris, thickness)), inv)
        });
        Ok(Self {
            model,
            state,
            contacts,
            work,
            stepper,
            control,
            sub_dt: f64::NAN,
            good_steps: 0,
            saved,
            saved_contacts: VertexContacts::new(),
            t: 0.0,
            external_work: 0.0,
            power,
            moving_power: 0.0,
            size,
            impulses: None,
            self_collision,
            self_stats: SelfStats::default(),
            moving: Vec::new(),
            moving_end: Vec::new(),
        })
    }

    /// What self-collision did over the last step (all zero without it).
    pub fn self_stats(&self) -> SelfStats {
        self.self_stats
    }

    /// A second simulation of the same (shared) model from this one's state, contacts and
    /// time, with its own integrator settings (a comparison of solvers from one state).
    pub fn fork(&self, settings: MechSettings) -> Result<Self, IntegrateError> {
        let mut sim = Self::new(self.model.clone(), self.state.clone(), settings)?;
        sim.contacts = self.contacts.clone();
        sim.control = self.control;
        sim.saved = self.saved.clone();
        sim.t = self.t;
        Ok(sim)
    }

    /// Simulated time (s).
    pub fn time(&self) -> f64 {
        self.t
    }

    /// Integrator steps taken, sub-steps included.
    pub fn steps(&self) -> u64 {
        self.stepper.steps()
    }

    /// The model.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// The shared model (to start another simulation of it).
    pub fn shared_model(&self) -> Arc<M> {
        self.model.clone()
    }

    /// The state: positions and velocities.
    pub fn state(&self) -> &MechState {
        &self.state
    }

    /// The state, to change between steps (an engine moving vertices by hand).
    pub fn state_mut(&mut self) -> &mut MechState {
        &mut self.state
    }

    /// The scratch buffers.
    pub fn work(&self) -> &M::Work {
        &self.work
    }

    /// The stepper (integrator settings, matrices built).
    pub fn stepper(&self) -> &MechStepper {
        &self.stepper
    }

    /// Replaces the model's step-size control (`None`: every step at the dt asked for).
    pub fn set_step_control(&mut self, control: Option<StepControl>) {
        let n = self.model.vertex_count();
        if control.is_some() && self.saved.0.len() != 3 * n {
            self.saved = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
        }
        self.control = control;
    }

    /// Writes the constraints the next step solves under: the current contacts, then the
    /// model's own (pins).
    pub fn constraints(&self, filter: &mut Filter) {
        self.contacts.constraints(filter);
        self.model.constraints(filter);
    }

    /// Vertices in contact after the last step.
    pub fn contact_count(&self) -> usize {
        self.contacts.count()
    }

    /// The current sub-step of step-size control (s): the last dt unless steps were
    /// halved recently (NaN before the first step).
    pub fn sub_step(&self) -> f64 {
        self.sub_dt
    }

    /// One integrator step of size h from the current time, then prescribed motion and
    /// contacts.
    fn integrate(&mut self, h: f64) -> Result<StepInfo, IntegrateError> {
        if let Some((sc, inv_mass)) = &mut self.self_collision {
            sc.begin(
                self.state.x.as_slice(),
                self.state.v.as_slice(),
                inv_mass,
                h,
            );
        }
        let (x, v) = (self.state.x.as_mut_slice(), self.state.v.as_mut_slice());
        let info = self.stepper.step(
            &mut Bound {
                model: &*self.model,
                work: &mut self.work,
                contacts: &mut self.contacts,
                self_collision: self.self_collision.as_ref().map(|(sc, _)| &**sc),
                moving: &self.moving,
            },
            self.t,
            x,
            v,
            h,
        )?;
        if let Some(r) = &mut self.impulses {
            // The force the solve balanced, before the contact response moves anything.
            r.force.fill(0.0);
            let t1 = self.t + h;
            self.model.force(&mut self.work, t1, x, v, &mut r.force);
            r.force.iter_mut().for_each(|f| *f *= h);
        }
        Ok(info)
    }

    /// Counts an accepted sub-step's `h f(x1, v1)` into the step's contact impulses.
    fn accept_force_impulse(&mut self) {
        if let Some(r) = &mut self.impulses {
            for (acc, f) in r.force_impulse.iter_mut().zip(&r.force) {
                *acc += f;
            }
        }
    }

    /// What follows every accepted step ending at `self.t`: prescribed vertices, then
    /// contacts; then the loads' work over the step, and the check for a blow-up (a
    /// vertex moving more than ten times the model's size in the step).
    fn after_step(&mut self, h: f64) -> Result<(), IntegrateError> {
        self.model.prescribe(
            self.t,
            self.state.x.as_mut_slice(),
            self.state.v.as_mut_slice(),
        );
        // Moving obstacles do work on the model: what their contacts change of its energy
        // is counted as external work (with them, the static obstacles' small losses at
        // contact are counted there too).
        let coupled = !self.moving.is_empty() && self.model.contact_friction().is_some();
        let before = if coupled { self.energy().total() } else { 0.0 };
        let (x, v) = (self.state.x.as_mut_slice(), self.state.v.as_mut_slice());
        if let Some(friction) = self.model.contact_friction() {
            let m = &*self.model;
            self.contacts.resolve(
                m.obstacles(),
                &self.moving,
                m.triangles(),
                m.fixed_vertices(),
                m.mass(),
                friction,
                x,
                v,
                h,
            );
        }
        if coupled {
            self.external_work += self.energy().total() - before;
        }
        let (x, v) = (self.state.x.as_mut_slice(), self.state.v.as_mut_slice());
        // Self-collision last: the obstacles' corrections are part of the motion it
        // keeps free of crossings.
        if let Some((sc, inv_mass)) = &mut self.self_collision {
            let s = sc.resolve(x, v, inv_mass, h);
            self.self_stats.approaches += sc.approaches().len();
            self.self_stats.repulsions += s.repulsions;
            self.self_stats.impulses += s.impulses;
            self.self_stats.zone_rounds += s.zone_rounds;
            self.self_stats.unresolved = s.unresolved;
        }
        if self.model.does_external_work() {
            let p = self.model.external_power(self.t, x, v);
            self.external_work += 0.5 * h * (self.power + p);
            self.power = p;
        }
        // Moving obstacles met by collision springs work on the model through them (the
        // trapezoidal rule over the step, the obstacles held at their end-of-step poses).
        if let Some(pen) = moving_penalty(&*self.model, &self.moving) {
            let p = pen.power(Against::Moving(&self.moving), x, v);
            self.external_work += 0.5 * h * (self.moving_power + p);
            self.moving_power = p;
        }
        let speed = max_speed(v);
        if speed * h > 10.0 * self.size {
            return Err(IntegrateError::Diverged {
                step: self.stepper.steps(),
                speed,
                dt: h,
                size: self.size,
                hint: crate::integrate::hint(self.stepper.settings().method),
            });
        }
        Ok(())
    }

    /// Starts (with the present positions as the frame impulses are given in) or stops
    /// recording the impulses contacts give vertices at each step
    /// ([`MechSimulation::contact_impulses`]).
    pub fn record_contact_impulses(&mut self, on: bool) {
        if !on || self.model.contact_friction().is_none() {
            self.impulses = None;
        } else if self.impulses.is_none() {
            let n = self.model.vertex_count();
            let centre = centre_of_mass(self.model.mass(), self.state.x.as_slice());
            let mut initial = self.state.x.as_slice().to_vec();
            for (c, part) in initial.chunks_mut(n.max(1)).enumerate() {
                part.iter_mut().for_each(|p| *p -= centre[c]);
            }
            self.impulses = Some(Box::new(ImpulseRecorder {
                initial,
                v0: vec![0.0; 3 * n],
                force: vec![0.0; 3 * n],
                force_impulse: vec![0.0; 3 * n],
                out: crate::simulation::ContactImpulses {
                    vertex_count: n,
                    ..Default::default()
                },
                ..Default::default()
            }));
        }
    }

    /// The impulses contacts gave vertices over the last step, while recording: for each
    /// vertex touching an obstacle before or after the step, `m (v - v0) - h f(x1, v1)`
    /// with `(x1, v1)` the solve's result before the contact response and `v` the
    /// velocity after it: the momentum balance of backward Euler (exact for it, at
    /// convergence; the other integrators evaluate their forces elsewhere in the step, so
    /// it is an estimate there), which counts the constraint's impulse inside the solve
    /// and the velocity the contact response removed after it. Turned into the initial frame by the
    /// rotation that best fits the positions to the initial ones (the polar factor of
    /// `sum m (x - c)(X - C)^T`, Müller et al. 2005's shape matching).
    pub fn contact_impulses(&self) -> Option<&crate::simulation::ContactImpulses> {
        self.impulses.as_ref().map(|r| &r.out)
    }

    /// Advances by `dt` (s); see the module docs. Runs on a thread of rayon's pool
    /// ([`largestep_kernels::par::on_pool`]).
    pub fn step(&mut self, dt: f64) -> Result<StepInfo, IntegrateError> {
        largestep_kernels::par::on_pool(|| self.step_here(dt))
    }

    /// [`MechSimulation::step`] on the calling thread.
    fn step_here(&mut self, dt: f64) -> Result<StepInfo, IntegrateError> {
        let t0 = self.t;
        self.self_stats = SelfStats::default();
        if let Some(r) = &mut self.impulses {
            r.v0.copy_from_slice(self.state.v.as_slice());
            r.force_impulse.fill(0.0);
            r.touching.clear();
            self.contacts.touching(&mut r.touching);
        }
        let info = self.step_inner(dt)?;
        if self.impulses.is_some() {
            self.measure_impulses(t0, dt);
        }
        Ok(info)
    }

    /// The momentum balance of [`MechSimulation::contact_impulses`] after a step of `dt`
    /// from `t0`.
    fn measure_impulses(&mut self, t0: f64, dt: f64) {
        let Some(mut r) = self.impulses.take() else {
            return;
        };
        self.contacts.touching(&mut r.touching);
        r.touching.sort_unstable();
        r.touching.dedup();
        let (x, v) = (self.state.x.as_slice(), self.state.v.as_slice());
        let n = self.model.vertex_count();
        let mass = self.model.mass();
        // The best-fit rotation: polar factor of A = sum m (x - c)(X - C)^T (X - C kept
        // from when recording began).
        let c = centre_of_mass(mass, x);
        let mut a = [0.0; 9];
        for i in 0..n {
            for j in 0..3 {
                for k in 0..3 {
                    a[3 * j + k] += mass[i] * (x[j * n + i] - c[j]) * r.initial[k * n + i];
                }
            }
        }
        let rot = if a.iter().all(|v| v.is_finite()) && a.iter().any(|&v| v != 0.0) {
            largestep_kernels::fem::polar(&a).0
        } else {
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        };
        r.out.time = t0;
        r.out.dt = dt;
        r.out.impulses.clear();
        for &i in &r.touching {
            let i = i as usize;
            let j: [f64; 3] = std::array::from_fn(|k| {
                mass[i] * (v[k * n + i] - r.v0[k * n + i]) - r.force_impulse[k * n + i]
            });
            // R^T j: from the present frame to the initial one.
            let local: [f64; 3] =
                std::array::from_fn(|k| (0..3).map(|l| rot[3 * l + k] * j[l]).sum());
            if local.iter().all(|v| v.is_finite()) {
                r.out.impulses.push((i as u32, local));
            }
        }
        self.impulses = Some(r);
    }

    fn step_inner(&mut self, dt: f64) -> Result<StepInfo, IntegrateError> {
        let Some(control) = self.control else {
            let info = self.integrate(dt)?;
            self.t += dt;
            self.after_step(dt)?;
            self.accept_force_impulse();
            return Ok(info);
        };
        // First step (NaN), or a dt smaller than the current sub-step: start at dt.
        if self.sub_dt.is_nan() || self.sub_dt > dt {
            self.sub_dt = dt;
        }
        let end = self.t + dt;
        let mut total = StepInfo::default();
        while self.t < end - 1e-12 * dt {
            // The sub-step, or what remains of dt when that is shorter; a remainder within
            // rounding of the sub-step is the sub-step, so an undivided step is exactly dt
            // ((t + dt) - t is not dt in floating point).
            let remaining = end - self.t;
            let h = if remaining < self.sub_dt * (1.0 - 1e-9) {
                remaining
            } else {
                self.sub_dt
            };
            // Moving obstacles where they are at the sub-step's end: a halved step then
            // meets half their motion, so that halving shrinks what the contacts must
            // move as well as what the solve does.
            if !self.moving_end.is_empty() {
                let back = end - (self.t + h);
                self.moving.clear();
                self.moving
                    .extend(self.moving_end.iter().map(|m| m.earlier(back.max(0.0))));
            }
            self.saved.0.copy_from_slice(self.state.x.as_slice());
            self.saved.1.copy_from_slice(self.state.v.as_slice());
            self.saved_contacts.clone_from(&self.contacts);
            let saved_work = (self.external_work, self.power, self.moving_power);
            // The strain change is measured after the contact response too: moving
            // vertices out of an obstacle can stretch the model as much as the step.
            let why = match self.integrate(h).and_then(|info| {
                self.t += h;
                self.after_step(h).map(|()| info)
            }) {
                Ok(info) => {
                    let change = self
                        .model
                        .strain_change(&self.saved.0, self.state.x.as_slice());
                    if change <= control.max_strain_change {
                        self.accept_force_impulse();
                        total.newton_iterations += info.newton_iterations;
                        total.linear_iterations += info.linear_iterations;
                        total.residual = info.residual;
                        total.solve_seconds += info.solve_seconds;
                        self.good_steps += 1;
                        if self.good_steps >= 2 && self.sub_dt < dt {
                            self.sub_dt = (2.0 * self.sub_dt).min(dt);
                            self.good_steps = 0;
                        }
                        continue;
                    }
                    format!(
                        "an element's strain changed by {change:.3} in one step, above max_strain_change = {}",
                        control.max_strain_change
                    )
                }
                Err(e) => e.to_string(),
            };
            self.t = end - remaining;
            self.contacts.clone_from(&self.saved_contacts);
            (self.external_work, self.power, self.moving_power) = saved_work;
            // Undo and halve.
            self.state.x.as_mut_slice().copy_from_slice(&self.saved.0);
            self.state.v.as_mut_slice().copy_from_slice(&self.saved.1);
            self.good_steps = 0;
            // Give up when the step that failed was already the smallest allowed.
            let smallest = dt / 2f64.powi(control.max_halvings as i32);
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

    /// Kinetic and potential energy (J), and the work of loads without a potential so
    /// far.
    pub fn energy(&self) -> Energy {
        Energy {
            kinetic: match self.model.mass_matrix() {
                Some(m) => kinetic_energy_matrix(m, self.state.v.as_slice()),
                None => kinetic_energy(self.model.mass(), self.state.v.as_slice()),
            },
            // With the springs of the moving obstacles, whose work `external_work` counts.
            potential: self
                .model
                .potential_energy(self.t, self.state.x.as_slice())
                .unwrap_or(0.0)
                + moving_penalty(&*self.model, &self.moving).map_or(0.0, |p| {
                    p.energy(Against::Moving(&self.moving), self.state.x.as_slice())
                }),
            external_work: self.external_work,
        }
    }

    /// The stepper's stages: matrices, linear solver and Newton iteration, or why they are
    /// left out; and step-size control.
    fn solver_stages(&self) -> Vec<Stage> {
        let s = &self.stepper;
        let method = s.settings().method;
        let mut stages = Vec::new();
        if s.has_matrix() {
            stages.push(Stage::built(
                "Jacobian assembly (Bsr3 pattern, element maps)",
                format!("for {method}"),
            ));
            stages.push(if s.has_damping_matrix() {
                Stage::built("damping Jacobian", "df/dv")
            } else {
                Stage::left_out("damping Jacobian", "no damping")
            });
            stages.push(Stage::built(
                "linear solver",
                s.linear_solver_name().unwrap_or("none"),
            ));
            stages.push(if method == Method::LinearizedBackwardEuler {
                Stage::left_out(super::NEWTON_STAGE, "one linearised step")
            } else {
                Stage::built(super::NEWTON_STAGE, "with backtracking line search")
            });
        } else {
            stages.push(Stage::left_out(
                "Jacobian assembly, system matrix and linear solver",
                format!("{method} is explicit"),
            ));
        }
        stages.push(match self.control {
            Some(sc) => Stage::built(
                "step-size control",
                format!(
                    "halve dt when a step fails or changes a strain by more than {} (at most {} times)",
                    sc.max_strain_change, sc.max_halvings
                ),
            ),
            None => Stage::left_out("step-size control", "not asked for"),
        });
        stages
    }
}

impl<M: MechModel> Simulation for MechSimulation<M> {
    fn step(&mut self, dt: f64) -> Result<StepInfo, IntegrateError> {
        MechSimulation::step(self, dt)
    }

    fn time(&self) -> f64 {
        MechSimulation::time(self)
    }

    fn steps(&self) -> u64 {
        MechSimulation::steps(self)
    }

    fn energy(&self) -> Energy {
        MechSimulation::energy(self)
    }

    fn max_penetration(&self) -> f64 {
        max_penetration(self.model.obstacles(), self.state.x.as_slice())
    }

    fn has_volume(&self) -> bool {
        self.model.has_volume()
    }

    fn write_volume(&self, w: &mut dyn std::io::Write, comment: &str) -> std::io::Result<()> {
        self.model
            .write_volume(w, comment, self.state.x.as_slice(), self.state.v.as_slice())
    }

    fn frame(&self) -> FrameData<'_> {
        let triangles = self.model.triangles();
        FrameData::Mesh(MeshRef {
            positions: self.state.x.as_slice(),
            triangles,
            segments: if triangles.is_empty() {
                self.model.segments()
            } else {
                &[]
            },
        })
    }

    fn stages(&self) -> Vec<Stage> {
        let mut stages = self.model.stages();
        stages.extend(self.solver_stages());
        stages
    }

    fn scenery(&self, around: ([f64; 3], [f64; 3])) -> Vec<Mesh> {
        let obstacles = self.model.obstacles();
        let mut meshes: Vec<Mesh> = obstacles.iter().filter_map(|o| o.preview_mesh()).collect();
        meshes.extend(Obstacle::plane_faces(obstacles, around));
        meshes
    }

    fn method(&self) -> String {
        self.stepper.settings().method.to_string()
    }

    fn linear_solver(&self) -> Option<&'static str> {
        self.stepper.linear_solver_name()
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn takes_moving_obstacles(&self) -> bool {
        self.model.contact_friction().is_some() || self.model.penalty().is_some()
    }

    fn set_moving_obstacles(&mut self, obstacles: &[MovingObstacle]) {
        self.moving.clear();
        self.moving.extend_from_slice(obstacles);
        self.moving_end.clear();
        self.moving_end.extend_from_slice(obstacles);
    }

    fn record_contact_impulses(&mut self, on: bool) {
        MechSimulation::record_contact_impulses(self, on);
    }

    fn contact_impulses(&self) -> Option<&crate::simulation::ContactImpulses> {
        MechSimulation::contact_impulses(self)
    }

    fn warnings(&self) -> Vec<String> {
        self.model.warnings()
    }
}
