//! Generic mass-spring systems (course notes, section 4).
//!
//! Particles with lumped masses, springs with Hooke's force and damping along the spring,
//! pinned particles, external loads (gravity, a force field: [`crate::loads`]) and penalty
//! collisions with obstacles ([`crate::collide::Penalty`]). An editable [`MassSpringDesc`]
//! is validated into an immutable [`MassSpring`] (per-spring constants as SoA arrays) plus
//! its initial [`MassSpringState`]; forces and Jacobians take `&self` and write into a
//! [`MassSpringWork`] of scratch buffers. The model implements [`MechModel`], so every
//! integrator runs it through [`crate::simulation::MechSimulation`].
//!
//! What is built depends on what is used: forces need only the per-vertex gather of spring
//! forces; the Jacobian pattern, element -> slot maps and element Jacobian buffers are
//! built when an implicit stepper asks for them ([`MechModel::prepare_jacobians`]); the
//! damping Jacobian only when some spring has damping.

mod generators;
pub mod scene;
pub mod world;

pub use generators::{chain, grid, lattice, GridOptions, LatticeOptions};

use crate::collide::{Against, Obstacle, Penalty};
use crate::integrate::{IntegrateError, MechState};
use crate::loads::{Body, ForceField, Gravity, Loads};
use crate::simulation::{MechModel, Stage, StepControl};
use crate::soa::Vec3s;
use crate::sparse::{Bsr3, Bsr3Pattern, ElementAssembly, LocalLayout, SparseError, VectorGather};
use crate::validate::{check, require, ModelError, Rule};
use largestep_kernels::mass_spring::{self as ks, SpringParams, Springs};
use std::sync::Arc;

/// A spring as described by a user: endpoints, stiffness (N/m), damping (N s/m) and an
/// optional rest length (m; the initial distance if absent).
#[derive(Clone, Debug, PartialEq)]
pub struct SpringDesc {
    /// First endpoint (particle index).
    pub a: usize,
    /// Second endpoint (particle index).
    pub b: usize,
    /// Hooke stiffness k (N/m), >= 0.
    pub stiffness: f64,
    /// Damping along the spring kd (N s/m), >= 0.
    pub damping: f64,
    /// Rest length (m), >= 0; `None`: the distance between the endpoints' initial positions.
    pub rest_length: Option<f64>,
}

/// The editable description of a mass-spring system.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MassSpringDesc {
    /// Initial positions (m).
    pub positions: Vec<[f64; 3]>,
    /// Initial velocities (m/s); empty means all zero.
    pub velocities: Vec<[f64; 3]>,
    /// Masses (kg), > 0, or 0 for pinned particles.
    pub masses: Vec<f64>,
    /// Springs.
    pub springs: Vec<SpringDesc>,
    /// Uniform gravitational acceleration (m/s^2).
    pub gravity: [f64; 3],
    /// Pinned particles (they never move).
    pub pinned: Vec<usize>,
    /// Clamp the compression term of spring Jacobians (keeps implicit systems definite).
    pub definiteness_fix: bool,
    /// Triangles over the particles for surface output (optional; not used by the physics).
    pub triangles: Vec<[u32; 3]>,
    /// An external force field (N per particle), if any.
    pub force_field: Option<ForceField>,
    /// Penalty collisions, if any.
    pub collisions: Option<CollisionDesc>,
    /// Step-size control, if wanted (see [`StepControl`]; the strain is each spring's
    /// relative change of length).
    pub step_control: Option<StepControl>,
}

/// Penalty collisions as a user describes them: a container box, planes and any other
/// obstacles, all with one collision spring stiffness and damping.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CollisionDesc {
    /// A bounding box `(lo, hi)` the particles must stay inside.
    pub bounds: Option<([f64; 3], [f64; 3])>,
    /// Planes `a x + b y + c z + d = 0`. Particles must stay on the side where most of
    /// them start (the side `a x + b y + c z + d >= 0` when they start on the plane).
    pub planes: Vec<[f64; 4]>,
    /// Further solid obstacles the particles stay out of.
    pub obstacles: Vec<Obstacle>,
    /// Collision spring stiffness k_c (N/m), >= 0.
    pub stiffness: f64,
    /// Collision spring damping d_c (N s/m), >= 0.
    pub damping: f64,
}

/// Positions and velocities (m, m/s) of the particles.
pub type MassSpringState = MechState;

/// The memory (bytes) a mass-spring system of `particles` particles and `springs` springs
/// is estimated to need in a simulation, with an `implicit` integrator (`cholesky`: a
/// sparse factor, else PCG) or an explicit one. What a scene is checked against before
/// anything is built ([`crate::limits::Limits`]). Measured peak memory of `largestep run`
/// on jello lattices (about 15 springs per particle, 2026-11-28): 1.5 kB per particle
/// under RK4 (48^3), 11.2 kB with the linearised backward Euler and PCG (32^3 and 48^3),
/// 52 kB with Cholesky (16^3: the 3-D factor fills in); the estimate rounds those up.
pub fn estimated_bytes(particles: f64, springs: f64, implicit: bool, cholesky: bool) -> f64 {
    let per_spring = if implicit { 750.0 } else { 110.0 };
    let fill = if implicit && cholesky { 60_000.0 } else { 0.0 };
    particles * (300.0 + fill) + springs * per_spring
}

/// A validated mass-spring system: everything its builder computed, never written again
/// (see the module docs).
#[derive(Clone, Debug)]
pub struct MassSpring {
    n: usize,
    mass: Vec<f64>,
    springs: SpringSet,
    loads: Loads,
    pinned: Vec<u32>,
    params: SpringParams,
    triangles: Vec<[u32; 3]>,
    has_damping: bool,
    penalty: Option<Penalty>,
    step_control: Option<StepControl>,
    gather: VectorGather,
}

/// The mass-spring system's scratch buffers: per-spring forces, and the Jacobian
/// structures and per-spring Jacobian blocks once an implicit integrator asked for them.
#[derive(Clone, Debug)]
pub struct MassSpringWork {
    elem_f: Vec<f64>,
    jac: Option<Jacobians>,
}

impl MassSpringWork {
    /// Whether the Jacobian structures were built.
    pub fn has_jacobians(&self) -> bool {
        self.jac.is_some()
    }
}

/// Per-spring constants (SoA), owned; borrowed as the kernels' `Springs`.
#[derive(Clone, Debug)]
struct SpringSet {
    ends: Vec<[u32; 2]>,
    k: Vec<f64>,
    kd: Vec<f64>,
    rest: Vec<f64>,
}

impl SpringSet {
    fn view(&self) -> Springs<'_> {
        Springs {
            ends: &self.ends,
            k: &self.k,
            kd: &self.kd,
            rest: &self.rest,
        }
    }
}

#[derive(Clone, Debug)]
struct Jacobians {
    assembly: ElementAssembly,
    kx: Vec<f64>,
    kv: Vec<f64>,
}

/// `Ok` if `value` is finite and >= 0 (`require` with the usual reason).
fn non_negative(
    item: &'static str,
    index: usize,
    field: &'static str,
    value: f64,
) -> Result<(), ModelError> {
    let ok = value.is_finite() && value >= 0.0;
    require(item, index, field, value, ok, "must be finite and >= 0")
}

impl MassSpringDesc {
    /// Validates the description and builds the model and its initial state.
    pub fn build(&self) -> Result<(MassSpring, MassSpringState), ModelError> {
        let n = self.positions.len();
        if n == 0 {
            return Err(ModelError::Empty { what: "particles" });
        }
        if self.masses.len() != n {
            return Err(ModelError::Length {
                what: "masses",
                got: self.masses.len(),
                expected: n,
                per: "particle",
            });
        }
        if !self.velocities.is_empty() && self.velocities.len() != n {
            return Err(ModelError::Length {
                what: "velocities",
                got: self.velocities.len(),
                expected: n,
                per: "particle",
            });
        }
        let missing = |item, index, named| ModelError::Missing {
            item,
            index,
            target: "particle",
            targets: "particles",
            named,
            n,
        };
        let mut pinned = vec![false; n];
        for (k, &p) in self.pinned.iter().enumerate() {
            if p >= n {
                return Err(missing("pinned", k, p));
            }
            pinned[p] = true;
        }
        let vectors = [
            (
                &self.positions,
                ["position.x", "position.y", "position.z"],
                Rule::Coordinate,
            ),
            (
                &self.velocities,
                ["velocity.x", "velocity.y", "velocity.z"],
                Rule::Finite,
            ),
        ];
        for (values, fields, rule) in vectors {
            for (i, p) in values.iter().enumerate() {
                for (&x, field) in p.iter().zip(fields) {
                    check("particle", i, field, x, rule)?;
                }
            }
        }
        for (i, &m) in self.masses.iter().enumerate() {
            non_negative("particle", i, "mass", m)?;
            require(
                "particle",
                i,
                "mass",
                m,
                m > 0.0 || pinned[i],
                "only pinned particles may have zero mass",
            )?;
        }
        let loads = Loads {
            gravity: Gravity(self.gravity),
            wind: None,
            field: self.force_field.clone(),
        };
        loads.validate()?;
        let m = self.springs.len();
        let (mut ends, mut k, mut kd, mut rest) = (
            Vec::with_capacity(m),
            Vec::with_capacity(m),
            Vec::with_capacity(m),
            Vec::with_capacity(m),
        );
        for (e, s) in self.springs.iter().enumerate() {
            for p in [s.a, s.b] {
                if p >= n {
                    return Err(missing("spring", e, p));
                }
            }
            if s.a == s.b {
                return Err(ModelError::Element {
                    item: "spring",
                    index: e,
                    what: format!("connects particle {} to itself", s.a),
                });
            }
            non_negative("spring", e, "stiffness", s.stiffness)?;
            non_negative("spring", e, "damping", s.damping)?;
            let r = match s.rest_length {
                Some(r) => {
                    non_negative("spring", e, "rest_length", r)?;
                    r
                }
                None => {
                    let (pa, pb) = (self.positions[s.a], self.positions[s.b]);
                    ((pa[0] - pb[0]).powi(2) + (pa[1] - pb[1]).powi(2) + (pa[2] - pb[2]).powi(2))
                        .sqrt()
                }
            };
            ends.push([s.a as u32, s.b as u32]);
            k.push(s.stiffness);
            kd.push(s.damping);
            rest.push(r);
        }
        for (t, tri) in self.triangles.iter().enumerate() {
            if let Some(&p) = tri.iter().find(|&&p| p as usize >= n) {
                return Err(missing("triangle", t, p as usize));
            }
        }
        let penalty = match &self.collisions {
            Some(c) => Some(build_penalty(c, &self.positions)?),
            None => None,
        };
        if let Some(sc) = &self.step_control {
            sc.validate()?;
        }
        let mut pinned: Vec<u32> = self.pinned.iter().map(|&p| p as u32).collect();
        pinned.sort_unstable();
        pinned.dedup();
        let gather = VectorGather::new(n, &ends, &LocalLayout::pair())
            .map_err(|e| ModelError::TooLarge(e.to_string()))?;
        let has_damping = kd.iter().any(|&d| d > 0.0);
        let model = MassSpring {
            n,
            mass: self.masses.clone(),
            gather,
            springs: SpringSet { ends, k, kd, rest },
            loads,
            pinned,
            params: SpringParams {
                definiteness_fix: self.definiteness_fix,
            },
            triangles: self.triangles.clone(),
            has_damping,
            penalty,
            step_control: self.step_control,
        };
        let mut v = if self.velocities.is_empty() {
            Vec3s::zeros(n)
        } else {
            Vec3s::from_aos(&self.velocities)
        };
        for &p in &model.pinned {
            v.set(p as usize, [0.0; 3]);
        }
        let state = MassSpringState {
            x: Vec3s::from_aos(&self.positions),
            v,
        };
        Ok((model, state))
    }
}

/// The penalty obstacles: the box's six walls, the planes (each oriented so that most
/// particles start on its free side), then the other obstacles.
fn build_penalty(c: &CollisionDesc, positions: &[[f64; 3]]) -> Result<Penalty, ModelError> {
    non_negative("collisions", 0, "stiffness", c.stiffness)?;
    non_negative("collisions", 0, "damping", c.damping)?;
    let mut obstacles = Vec::new();
    if let Some((lo, hi)) = c.bounds {
        for a in 0..3 {
            require(
                "collisions.box",
                a,
                "min",
                lo[a],
                lo[a].is_finite(),
                "must be finite",
            )?;
            require(
                "collisions.box",
                a,
                "max",
                hi[a],
                hi[a].is_finite() && hi[a] > lo[a],
                "must be finite and larger than min",
            )?;
        }
        obstacles.extend(Obstacle::container(lo, hi));
    }
    for (i, p) in c.planes.iter().enumerate() {
        let Some(mut h) = Obstacle::plane(*p) else {
            let bad = if p[3].is_finite() { 0.0 } else { p[3] };
            return Err(ModelError::Value {
                item: "plane",
                index: i,
                field: if p[3].is_finite() {
                    "normal (a, b, c)"
                } else {
                    "d"
                },
                value: bad,
                why: "a plane needs a finite, non-zero normal (a, b, c) and a finite d",
            });
        };
        // The allowed side is where most particles start.
        let inside = |x: &[f64; 3]| h.distance(*x).is_some_and(|(d, _)| d < 0.0);
        let behind = positions.iter().filter(|x| inside(x)).count();
        if 2 * behind > positions.len() {
            h = h.flipped();
        }
        obstacles.push(h);
    }
    let first = obstacles.len();
    for (k, o) in c.obstacles.iter().enumerate() {
        o.validate(first + k)?;
        obstacles.push(o.clone());
    }
    Ok(Penalty {
        obstacles,
        stiffness: c.stiffness,
        damping: c.damping,
    })
}

impl MassSpring {
    /// The external loads (gravity, force field).
    pub fn loads(&self) -> &Loads {
        &self.loads
    }

    /// The deepest penetration into a collision obstacle (m), 0 without collisions.
    pub fn max_penetration(&self, x: &[f64]) -> f64 {
        crate::collide::max_penetration(self.obstacles(), x)
    }

    /// The penalty collisions, if any.
    pub fn collisions(&self) -> Option<&Penalty> {
        self.penalty.as_ref()
    }

    /// Number of particles.
    pub fn particle_count(&self) -> usize {
        self.n
    }

    /// Number of springs.
    pub fn spring_count(&self) -> usize {
        self.springs.ends.len()
    }

    /// Spring endpoints.
    pub fn spring_ends(&self) -> &[[u32; 2]] {
        &self.springs.ends
    }

    /// Rest lengths (m).
    pub fn rest_lengths(&self) -> &[f64] {
        &self.springs.rest
    }

    /// Whether any spring has damping (and so a damping Jacobian is assembled).
    pub fn has_damping(&self) -> bool {
        self.has_damping
    }

    /// Number of pinned particles.
    pub fn pinned_count(&self) -> usize {
        self.pinned.len()
    }

    /// What the loads act on.
    fn body(&self) -> Body<'_> {
        Body {
            mass: &self.mass,
            triangles: &self.triangles,
        }
    }

    /// Spring `e`'s length at `x` (m).
    fn length(&self, e: usize, x: &[f64]) -> f64 {
        let [a, b] = self.springs.ends[e];
        let (pa, pb) = (
            largestep_kernels::get3(x, self.n, a as usize),
            largestep_kernels::get3(x, self.n, b as usize),
        );
        let d = largestep_kernels::v3::sub(pa, pb);
        largestep_kernels::v3::dot(d, d).sqrt()
    }
}

impl MechModel for MassSpring {
    type Work = MassSpringWork;

    fn work(&self) -> MassSpringWork {
        MassSpringWork {
            elem_f: vec![0.0; self.gather.vector_buffer_len()],
            jac: None,
        }
    }

    fn vertex_count(&self) -> usize {
        self.n
    }

    fn mass(&self) -> &[f64] {
        &self.mass
    }

    fn force(&self, work: &mut MassSpringWork, t: f64, x: &[f64], v: &[f64], f: &mut [f64]) {
        self.loads.forces(t, &self.body(), x, v, f);
        if !self.springs.ends.is_empty() {
            ks::spring_forces(&mut work.elem_f, x, v, self.springs.view());
            self.gather.gather_vectors_add(&work.elem_f, f);
        }
        if let Some(p) = &self.penalty {
            p.add_forces(Against::Own, x, v, f);
        }
    }

    fn potential_energy(&self, _t: f64, x: &[f64]) -> Option<f64> {
        // The force field is left out: a sampled field need not have a potential.
        let loads = self.loads.potential(&self.body(), x);
        let penalty = self
            .penalty
            .as_ref()
            .map_or(0.0, |p| p.energy(Against::Own, x));
        Some(loads + ks::springs_energy(x, self.springs.view()) + penalty)
    }

    fn dissipation(&self, x: &[f64], v: &[f64]) -> f64 {
        let springs = if self.has_damping {
            ks::springs_dissipation(x, v, self.springs.view())
        } else {
            0.0
        };
        springs
            + self
                .penalty
                .as_ref()
                .map_or(0.0, |p| p.dissipation(Against::Own, x, v))
    }

    fn prepare_jacobians(
        &self,
        work: &mut MassSpringWork,
    ) -> Result<Option<Arc<Bsr3Pattern>>, SparseError> {
        if work.jac.is_none() {
            let assembly = ElementAssembly::new(self.n, &self.springs.ends, LocalLayout::pair())?;
            let m = self.springs.ends.len();
            work.jac = Some(Jacobians {
                assembly,
                kx: vec![0.0; 9 * m],
                kv: vec![0.0; if self.has_damping { 9 * m } else { 0 }],
            });
        }
        Ok(work.jac.as_ref().map(|j| j.assembly.pattern().clone()))
    }

    fn has_velocity_jacobian(&self) -> bool {
        self.has_damping || self.penalty.as_ref().is_some_and(|p| p.damping > 0.0)
    }

    fn force_jacobians(
        &self,
        work: &mut MassSpringWork,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut Bsr3,
        dfdv: Option<&mut Bsr3>,
    ) -> Result<(), IntegrateError> {
        self.prepare_jacobians(work)
            .map_err(IntegrateError::Sparse)?;
        self.loads.forces(t, &self.body(), x, v, f);
        let springs = self.springs.view();
        let jac = work.jac.as_mut().expect("prepared above");
        let want_kv = dfdv.is_some() && self.has_damping;
        ks::spring_forces_jacobians(
            &mut work.elem_f,
            &mut jac.kx,
            want_kv.then_some(&mut jac.kv[..]),
            x,
            v,
            springs,
            self.params,
        );
        self.gather.gather_vectors_add(&work.elem_f, f);
        jac.assembly.gather_blocks(&jac.kx, dfdx);
        let mut dfdv = dfdv;
        if let Some(d) = dfdv.as_deref_mut() {
            if want_kv {
                jac.assembly.gather_blocks(&jac.kv, d);
            } else {
                d.set_zero();
            }
        }
        if let Some(p) = &self.penalty {
            // The loads' gradients are left out of the Jacobian: they are external.
            p.add_forces(Against::Own, x, v, f);
            p.add_jacobians(Against::Own, x, dfdx, dfdv);
        }
        Ok(())
    }

    fn obstacles(&self) -> &[Obstacle] {
        self.penalty.as_ref().map_or(&[], |p| &p.obstacles)
    }

    fn penalty(&self) -> Option<&Penalty> {
        self.penalty.as_ref()
    }

    fn fixed_vertices(&self) -> &[u32] {
        &self.pinned
    }

    /// The largest change of any spring's length relative to its rest length (absolute
    /// for springs of zero rest length).
    fn strain_change(&self, x0: &[f64], x: &[f64]) -> f64 {
        let mut worst = 0.0f64;
        for (e, &r) in self.springs.rest.iter().enumerate() {
            let change = (self.length(e, x) - self.length(e, x0)).abs() / r.max(f64::MIN_POSITIVE);
            if change.is_nan() {
                return f64::NAN;
            }
            worst = worst.max(change);
        }
        worst
    }

    fn does_external_work(&self) -> bool {
        self.loads.does_work()
    }

    fn external_power(&self, t: f64, x: &[f64], v: &[f64]) -> f64 {
        self.loads.work_rate(t, &self.body(), x, v)
    }

    fn step_control(&self) -> Option<StepControl> {
        self.step_control
    }

    fn stages(&self) -> Vec<Stage> {
        let (n, m) = (self.n, self.springs.ends.len());
        let mut stages = vec![
            if m > 0 {
                Stage::built("spring forces", format!("{n} particles, {m} springs"))
            } else {
                Stage::left_out("spring forces", format!("{n} particles and no springs"))
            },
            if self.has_damping {
                Stage::built("spring damping", "damping along springs")
            } else {
                Stage::left_out("spring damping", "every damping coefficient is zero")
            },
        ];
        stages.extend(self.loads.stages());
        if self.loads.field.is_none() {
            stages.push(Stage::left_out("force field", "the scene has none"));
        }
        stages.push(Stage::pinned(self.pinned.len()));
        stages.push(match &self.penalty {
            Some(p) => Stage::built(
                "penalty collisions",
                format!(
                    "{} surfaces, k_c = {} N/m, d_c = {} N s/m",
                    p.obstacles.len(),
                    p.stiffness,
                    p.damping
                ),
            ),
            None => Stage::left_out("collision structures", "the scene has no colliders"),
        });
        stages
    }

    fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    fn segments(&self) -> &[[u32; 2]] {
        &self.springs.ends
    }
}
