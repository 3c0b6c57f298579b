//! Generic mass-spring systems (course notes, section 4).
//!
//! Particles with lumped masses, springs with Hooke's force and damping along the spring,
//! uniform gravity and pinned particles. An editable [`MassSpringDesc`] is validated into
//! an immutable [`MassSpring`] (per-spring constants as SoA arrays) plus its initial
//! [`MassSpringState`]. The model implements [`Mechanical`], so every integrator runs it.
//!
//! What is built depends on what is used: forces need only the per-vertex gather of spring
//! forces; the Jacobian pattern, element -> slot maps and element Jacobian buffers are
//! built when an implicit stepper asks for them ([`Mechanical::prepare_jacobians`]); the
//! damping Jacobian only when some spring has damping.

mod environment;
mod generators;
pub mod world;

pub use environment::{ForceField, HalfSpace, Penalty};
pub use generators::{chain, grid, lattice, GridOptions, LatticeOptions};

use crate::integrate::{IntegrateError, Mechanical};
use crate::soa::Vec3s;
use crate::solve::Filter;
use crate::sparse::{Bsr3, Bsr3Pattern, ElementAssembly, LocalLayout, SparseError, VectorGather};
use largestep_kernels::spring::{self as ks, SpringParams, Springs};
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
}

/// Penalty collision surfaces as a user describes them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CollisionDesc {
    /// A bounding box `(lo, hi)` the particles must stay inside.
    pub bounds: Option<([f64; 3], [f64; 3])>,
    /// Planes `a x + b y + c z + d = 0`. Particles must stay on the side where most of
    /// them start (the side `a x + b y + c z + d >= 0` when they start on the plane).
    pub planes: Vec<[f64; 4]>,
    /// Collision spring stiffness k_c (N/m), >= 0.
    pub stiffness: f64,
    /// Collision spring damping d_c (N s/m), >= 0.
    pub damping: f64,
}

/// Invalid model input, naming the item and its index.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ModelError {
    /// A model needs at least one particle.
    #[error("the model has no particles")]
    Empty,
    /// Array lengths disagree.
    #[error("{what} has {got} entries, expected {expected} (one per particle)")]
    Length {
        /// The array.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The particle count.
        expected: usize,
    },
    /// A value is out of its range.
    #[error("{item} {index}: {field} = {value} is invalid ({why})")]
    Value {
        /// `particle`, `spring`, `pinned`, `gravity`.
        item: &'static str,
        /// Its index.
        index: usize,
        /// The field.
        field: &'static str,
        /// The value.
        value: f64,
        /// What is expected.
        why: &'static str,
    },
    /// A spring or pin names a particle that does not exist.
    #[error("{item} {index} names particle {particle}, but there are only {n} particles")]
    MissingParticle {
        /// `spring` or `pinned`.
        item: &'static str,
        /// Its index.
        index: usize,
        /// The particle named.
        particle: usize,
        /// Particle count.
        n: usize,
    },
    /// A spring connects a particle to itself.
    #[error("spring {index} connects particle {particle} to itself")]
    SelfSpring {
        /// Spring index.
        index: usize,
        /// The particle.
        particle: usize,
    },
    /// The connectivity is too large to index.
    #[error("{0}")]
    Sparse(String),
}

/// Positions and velocities (m, m/s) of the particles.
pub type MassSpringState = crate::integrate::MechState;

/// A validated mass-spring system (immutable constants; see the module docs).
#[derive(Clone, Debug)]
pub struct MassSpring {
    n: usize,
    mass: Vec<f64>,
    springs: SpringSet,
    gravity: [f64; 3],
    pinned: Vec<u32>,
    params: SpringParams,
    triangles: Vec<[u32; 3]>,
    has_damping: bool,
    field: Option<ForceField>,
    penalty: Option<Penalty>,
    gather: VectorGather,
    elem_f: Vec<f64>,
    jac: Option<Jacobians>,
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

fn check(
    item: &'static str,
    index: usize,
    field: &'static str,
    value: f64,
    ok: bool,
    why: &'static str,
) -> Result<(), ModelError> {
    if ok {
        Ok(())
    } else {
        Err(ModelError::Value {
            item,
            index,
            field,
            value,
            why,
        })
    }
}

impl MassSpringDesc {
    /// Validates the description and builds the model and its initial state.
    pub fn build(&self) -> Result<(MassSpring, MassSpringState), ModelError> {
        let n = self.positions.len();
        if n == 0 {
            return Err(ModelError::Empty);
        }
        if self.masses.len() != n {
            return Err(ModelError::Length {
                what: "masses",
                got: self.masses.len(),
                expected: n,
            });
        }
        if !self.velocities.is_empty() && self.velocities.len() != n {
            return Err(ModelError::Length {
                what: "velocities",
                got: self.velocities.len(),
                expected: n,
            });
        }
        let mut pinned = vec![false; n];
        for (k, &p) in self.pinned.iter().enumerate() {
            if p >= n {
                return Err(ModelError::MissingParticle {
                    item: "pinned",
                    index: k,
                    particle: p,
                    n,
                });
            }
            pinned[p] = true;
        }
        let vectors = [
            (&self.positions, ["position.x", "position.y", "position.z"]),
            (&self.velocities, ["velocity.x", "velocity.y", "velocity.z"]),
        ];
        for (values, fields) in vectors {
            for (i, p) in values.iter().enumerate() {
                for (&x, field) in p.iter().zip(fields) {
                    check("particle", i, field, x, x.is_finite(), "must be finite")?;
                }
            }
        }
        for (i, &m) in self.masses.iter().enumerate() {
            check(
                "particle",
                i,
                "mass",
                m,
                m.is_finite() && m >= 0.0,
                "must be finite and >= 0",
            )?;
            check(
                "particle",
                i,
                "mass",
                m,
                m > 0.0 || pinned[i],
                "only pinned particles may have zero mass",
            )?;
        }
        for (c, &g) in self.gravity.iter().enumerate() {
            check(
                "gravity",
                c,
                "component",
                g,
                g.is_finite(),
                "must be finite",
            )?;
        }
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
                    return Err(ModelError::MissingParticle {
                        item: "spring",
                        index: e,
                        particle: p,
                        n,
                    });
                }
            }
            if s.a == s.b {
                return Err(ModelError::SelfSpring {
                    index: e,
                    particle: s.a,
                });
            }
            check(
                "spring",
                e,
                "stiffness",
                s.stiffness,
                s.stiffness.is_finite() && s.stiffness >= 0.0,
                "must be finite and >= 0",
            )?;
            check(
                "spring",
                e,
                "damping",
                s.damping,
                s.damping.is_finite() && s.damping >= 0.0,
                "must be finite and >= 0",
            )?;
            let r = match s.rest_length {
                Some(r) => {
                    check(
                        "spring",
                        e,
                        "rest_length",
                        r,
                        r.is_finite() && r >= 0.0,
                        "must be finite and >= 0",
                    )?;
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
                return Err(ModelError::MissingParticle {
                    item: "triangle",
                    index: t,
                    particle: p as usize,
                    n,
                });
            }
        }
        let field = match &self.force_field {
            Some(f) => Some(validate_field(f)?),
            None => None,
        };
        let penalty = match &self.collisions {
            Some(c) => Some(build_penalty(c, &self.positions)?),
            None => None,
        };
        let mut pinned: Vec<u32> = self.pinned.iter().map(|&p| p as u32).collect();
        pinned.sort_unstable();
        pinned.dedup();
        let gather = VectorGather::new(n, &ends, &LocalLayout::pair())
            .map_err(|e| ModelError::Sparse(e.to_string()))?;
        let has_damping = kd.iter().any(|&d| d > 0.0);
        let model = MassSpring {
            n,
            mass: self.masses.clone(),
            elem_f: vec![0.0; gather.vector_buffer_len()],
            gather,
            springs: SpringSet { ends, k, kd, rest },
            gravity: self.gravity,
            pinned,
            params: SpringParams {
                definiteness_fix: self.definiteness_fix,
            },
            triangles: self.triangles.clone(),
            has_damping,
            field,
            penalty,
            jac: None,
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

fn validate_field(f: &ForceField) -> Result<ForceField, ModelError> {
    let g = f.grid;
    for a in 0..3 {
        check(
            "force_field",
            a,
            "resolution",
            g.n[a] as f64,
            g.n[a] >= 2,
            "needs at least 2 nodes along each axis",
        )?;
        check(
            "force_field",
            a,
            "spacing",
            g.spacing[a],
            g.spacing[a].is_finite() && g.spacing[a] > 0.0,
            "must be finite and > 0",
        )?;
        check(
            "force_field",
            a,
            "origin",
            g.origin[a],
            g.origin[a].is_finite(),
            "must be finite",
        )?;
    }
    for (c, comp) in f.force.iter().enumerate() {
        if comp.len() != g.len() {
            return Err(ModelError::Length {
                what: ["force_field.fx", "force_field.fy", "force_field.fz"][c],
                got: comp.len(),
                expected: g.len(),
            });
        }
        if let Some(i) = comp.iter().position(|v| !v.is_finite()) {
            return Err(ModelError::Value {
                item: "force_field node",
                index: i,
                field: ["fx", "fy", "fz"][c],
                value: comp[i],
                why: "must be finite",
            });
        }
    }
    Ok(f.clone())
}

fn build_penalty(c: &CollisionDesc, positions: &[[f64; 3]]) -> Result<Penalty, ModelError> {
    check(
        "collisions",
        0,
        "stiffness",
        c.stiffness,
        c.stiffness.is_finite() && c.stiffness >= 0.0,
        "must be finite and >= 0",
    )?;
    check(
        "collisions",
        0,
        "damping",
        c.damping,
        c.damping.is_finite() && c.damping >= 0.0,
        "must be finite and >= 0",
    )?;
    let mut surfaces = Vec::new();
    if let Some((lo, hi)) = c.bounds {
        for a in 0..3 {
            check(
                "collisions.box",
                a,
                "min",
                lo[a],
                lo[a].is_finite(),
                "must be finite",
            )?;
            check(
                "collisions.box",
                a,
                "max",
                hi[a],
                hi[a].is_finite() && hi[a] > lo[a],
                "must be finite and larger than min",
            )?;
        }
        surfaces.extend(HalfSpace::box_walls(lo, hi));
    }
    for (i, p) in c.planes.iter().enumerate() {
        let Some(mut h) = HalfSpace::from_plane(*p) else {
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
        let behind = positions.iter().filter(|x| h.distance(**x) < 0.0).count();
        if 2 * behind > positions.len() {
            h = HalfSpace {
                normal: h.normal.map(|c| -c),
                offset: -h.offset,
            };
        }
        surfaces.push(h);
    }
    Ok(Penalty {
        surfaces,
        stiffness: c.stiffness,
        damping: c.damping,
    })
}

impl MassSpring {
    /// The force field, if any.
    pub fn force_field(&self) -> Option<&ForceField> {
        self.field.as_ref()
    }

    /// The penalty collisions, if any.
    pub fn collisions(&self) -> Option<&Penalty> {
        self.penalty.as_ref()
    }

    /// The deepest penetration into a collision surface (m), 0 without collisions.
    pub fn max_penetration(&self, x: &[f64]) -> f64 {
        self.penalty.as_ref().map_or(0.0, |p| p.max_penetration(x))
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

    /// Surface triangles for output (may be empty).
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Gravity (m/s^2).
    pub fn gravity(&self) -> [f64; 3] {
        self.gravity
    }

    /// Whether any spring has damping (and so a damping Jacobian is assembled).
    pub fn has_damping(&self) -> bool {
        self.has_damping
    }

    /// Number of pinned particles.
    pub fn pinned_count(&self) -> usize {
        self.pinned.len()
    }

    /// Whether Jacobian structures have been built.
    pub fn has_jacobians(&self) -> bool {
        self.jac.is_some()
    }

    fn environment_forces(&self, x: &[f64], v: &[f64], f: &mut [f64]) {
        if let Some(field) = &self.field {
            field.add_forces(x, f);
        }
        if let Some(p) = &self.penalty {
            p.add_forces(x, v, f);
        }
    }

    fn gravity_force(&self, f: &mut [f64]) {
        crate::integrate::gravity_forces(&self.mass, self.gravity, f);
    }
}

impl Mechanical for MassSpring {
    fn vertex_count(&self) -> usize {
        self.n
    }

    fn mass(&self) -> &[f64] {
        &self.mass
    }

    fn constraints(&self, filter: &mut Filter) {
        for &p in &self.pinned {
            filter.fix(p as usize);
        }
    }

    fn force(&mut self, _t: f64, x: &[f64], v: &[f64], f: &mut [f64]) {
        self.gravity_force(f);
        if !self.springs.ends.is_empty() {
            ks::spring_forces(&mut self.elem_f, x, v, self.springs.view());
            self.gather.gather_vectors_add(&self.elem_f, f);
        }
        self.environment_forces(x, v, f);
    }

    fn potential_energy(&self, _t: f64, x: &[f64]) -> Option<f64> {
        let gravity = crate::integrate::gravity_energy(&self.mass, self.gravity, x);
        // The force field is left out: a sampled field need not have a potential.
        let penalty = self.penalty.as_ref().map_or(0.0, |p| p.energy(x));
        Some(gravity + ks::springs_energy(x, self.springs.view()) + penalty)
    }

    fn dissipation(&self, x: &[f64], v: &[f64]) -> f64 {
        let springs = if self.has_damping {
            ks::springs_dissipation(x, v, self.springs.view())
        } else {
            0.0
        };
        springs + self.penalty.as_ref().map_or(0.0, |p| p.dissipation(x, v))
    }

    fn prepare_jacobians(&mut self) -> Result<Option<Arc<Bsr3Pattern>>, SparseError> {
        if self.jac.is_none() {
            let assembly = ElementAssembly::new(self.n, &self.springs.ends, LocalLayout::pair())?;
            let m = self.springs.ends.len();
            self.jac = Some(Jacobians {
                assembly,
                kx: vec![0.0; 9 * m],
                kv: vec![0.0; if self.has_damping { 9 * m } else { 0 }],
            });
        }
        Ok(self.jac.as_ref().map(|j| j.assembly.pattern().clone()))
    }

    fn has_velocity_jacobian(&self) -> bool {
        self.has_damping || self.penalty.as_ref().is_some_and(|p| p.damping > 0.0)
    }

    fn force_jacobians(
        &mut self,
        _t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut Bsr3,
        dfdv: Option<&mut Bsr3>,
    ) -> Result<(), IntegrateError> {
        self.prepare_jacobians().map_err(IntegrateError::Sparse)?;
        self.gravity_force(f);
        let springs = self.springs.view();
        let jac = self.jac.as_mut().expect("prepared above");
        let want_kv = dfdv.is_some() && self.has_damping;
        ks::spring_forces_jacobians(
            &mut self.elem_f,
            &mut jac.kx,
            want_kv.then_some(&mut jac.kv[..]),
            x,
            v,
            springs,
            self.params,
        );
        self.gather.gather_vectors_add(&self.elem_f, f);
        jac.assembly.gather_blocks(&jac.kx, dfdx);
        let mut dfdv = dfdv;
        if let Some(d) = dfdv.as_deref_mut() {
            if want_kv {
                jac.assembly.gather_blocks(&jac.kv, d);
            } else {
                d.set_zero();
            }
        }
        self.environment_forces(x, v, f);
        if let Some(p) = &self.penalty {
            // The field's gradient is left out of the Jacobian: it is an external load.
            p.add_jacobians(x, dfdx, dfdv);
        }
        Ok(())
    }
}
