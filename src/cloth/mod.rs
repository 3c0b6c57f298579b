//! Baraff-Witkin cloth (SIGGRAPH 1998) on a triangle mesh with rest (u, v) coordinates.
//!
//! Every triangle carries a stretch and a shear condition, every interior edge (two
//! triangles) a bend condition on its dihedral angle (`kernels::cloth`); energies
//! `k/2 C^2`, forces `-k C dC/dx - k_d (dC/dt) dC/dx`, and exact Jacobians. Masses are
//! lumped: `density * (u, v) area / 3` to each vertex of a triangle.
//!
//! [`ClothDesc::build`] validates a description and computes everything that never
//! changes into an immutable [`Cloth`]: masses, the triangles' (u, v) coefficients and
//! their stiffness per unit area divided by each rest area (structure of arrays), hinges
//! and rest angles, the per-vertex gather maps. Forces and Jacobians take `&self` and
//! write into a [`ClothWork`] of scratch buffers, so one `Cloth` can serve several
//! simulations and threads. They run in parallel over fixed chunks of elements and are
//! gathered per vertex and per matrix slot in a fixed order, so results do not depend on
//! the thread count. The model implements [`MechModel`]: every integrator runs it through
//! [`crate::simulation::MechSimulation`], which also resolves its obstacle contacts
//! ([`crate::collide::VertexContacts`]), places its path vertices and runs its step-size
//! control; implicit integrators get `df/dx` and `df/dv` on one block pattern shared by
//! triangles and hinges. Gravity and wind are [`crate::loads`] terms.
//!
//! Rest: (u, v) as given (the stretch conditions use the rest stretch `b_u`, `b_v`, 1 by
//! default); rest angles are the dihedral angles of the initial positions.

mod generators;
pub mod scene;

pub use generators::{cloth_grid, ClothGridOptions};

use crate::collide::Obstacle;
use crate::integrate::{IntegrateError, MechState};
use crate::loads::{Body, Gravity, Loads, Wind};
use crate::simulation::{MechModel, Stage, StepControl};
use crate::soa::Vec3s;
use crate::sparse::{
    Bsr3, Bsr3Pattern, ElementAssembly, LocalLayout, RankOneAssembly, SparseError, VectorGather,
};
use crate::validate::{check, ModelError, Rule};
use largestep_kernels::cloth::{
    add_bend, add_shear, add_stretch, bend_force_gradient, bend_force_gradient_x4,
    decoupled_hinge_weight, dihedral_angle, triangle_jacobians, ConditionSink, ElementForces,
    ElementOut, TriangleParams, TriangleRest,
};
use largestep_kernels::v3::dot;
use largestep_kernels::{four, gather_nodes};
use rayon::prelude::*;
use std::sync::Arc;

/// Material constants. Stretch and shear are per unit (u, v) area: a triangle of rest
/// area `a` gets the element stiffness `k / a` on the paper's condition `C = a (|w_u| -
/// b_u, ...)`, so its energy is `k a / 2 (|w_u| - b_u)^2`, the integral of the energy
/// density `k / 2 strain^2` over the triangle. With the paper's `k` used directly the
/// energy carries `a^2` and a refined mesh gets softer (a 100 x 100 sheet would be 6x
/// softer than a 40 x 40 one of the same size); per unit area it behaves the same at any
/// resolution. Bend stiffness is per hinge (a regular mesh's bending energy per unit
/// area is then independent of resolution, as hinges per area grow like 1/edge^2 while
/// the angle of a given curvature shrinks like the edge).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClothMaterial {
    /// Mass per unit (u, v) area (kg/m^2), > 0.
    pub density: f64,
    /// Stretch stiffness per unit area (N/m = J/m^2 per unit strain squared), >= 0.
    pub stretch: f64,
    /// Shear stiffness per unit area (N/m), >= 0.
    pub shear: f64,
    /// Bend stiffness per hinge (N m per rad^2), >= 0; 0 leaves the bend elements out.
    pub bend: f64,
    /// Stretch damping per unit area (N s/m), >= 0.
    pub stretch_damping: f64,
    /// Shear damping per unit area (N s/m), >= 0.
    pub shear_damping: f64,
    /// Bend damping per hinge (N m s per rad^2), >= 0.
    pub bend_damping: f64,
    /// Rest stretch along u and v (1: unstretched at the given (u, v)), > 0.
    pub rest_stretch: [f64; 2],
}

pub use crate::simulation::path::VertexPath;

/// An editable cloth description.
#[derive(Clone, Debug, PartialEq)]
pub struct ClothDesc {
    /// Initial positions (m).
    pub positions: Vec<[f64; 3]>,
    /// Initial velocities (m/s); empty means zero.
    pub velocities: Vec<[f64; 3]>,
    /// Rest (u, v) per vertex (m).
    pub uv: Vec<[f64; 2]>,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
    /// Material.
    pub material: ClothMaterial,
    /// Gravity (m/s^2).
    pub gravity: [f64; 3],
    /// Pinned vertices.
    pub pinned: Vec<usize>,
    /// Collision obstacles, resolved as contacts ([`crate::collide::VertexContacts`]).
    pub obstacles: Vec<Obstacle>,
    /// Coulomb-like friction coefficient of contacts, >= 0 (0: frictionless).
    pub friction: f64,
    /// Wind, if any.
    pub wind: Option<Wind>,
    /// Vertices on prescribed paths.
    pub paths: Vec<VertexPath>,
    /// Step-size control.
    pub step_control: StepControl,
    /// Drop each element condition's curvature term where it could make the stiffness
    /// indefinite (`kernels::cloth::ElementOut::project`: shear and bend always, stretch
    /// in compression), so implicit systems stay definite when the cloth compresses or
    /// buckles; the Jacobian is then exact only in stretched tension. Default on in
    /// [`cloth_grid`] and scenes.
    pub definiteness_fix: bool,
    /// `Some(thickness)` (m, > 0): the sheet does not pass through itself
    /// ([`crate::collide::SelfCollision`] after each step, with this gap kept between
    /// its layers); `None`: no self-collision structures are built.
    pub self_collision: Option<f64>,
}

/// Positions and velocities of the cloth's vertices.
pub type ClothState = MechState;

/// The memory (bytes) a cloth of `vertices` vertices is estimated to need in a simulation:
/// the model, its state and scratch, and with an `implicit` integrator its matrices and
/// solver (`cholesky`: a sparse factor, else PCG with multigrid). What a scene is checked
/// against before anything is built ([`crate::limits::Limits`]). Measured peak memory of
/// `largestep run` on regular sheets (2026-11-28): 5.6 kB per vertex implicit with PCG,
/// 9.9 kB with Cholesky (300 x 300), about 1 kB explicit (100 x 100, RK4); the estimate
/// rounds those up.
pub fn estimated_bytes(vertices: f64, implicit: bool, cholesky: bool) -> f64 {
    let per_vertex = match (implicit, cholesky) {
        (false, _) => 1_500.0,
        (true, false) => 6_000.0,
        (true, true) => 12_000.0,
    };
    vertices * per_vertex
}

/// Per-triangle stiffness: the material's per-area constants divided by each triangle's
/// rest area (see [`ClothMaterial`]), computed once (structure of arrays).
#[derive(Clone, Debug, Default)]
struct TriangleStiffness {
    stretch: Vec<f64>,
    stretch_damping: Vec<f64>,
    shear: Vec<f64>,
    shear_damping: Vec<f64>,
}

/// A validated cloth: everything its builder computed, never written again (see the
/// module docs).
#[derive(Clone, Debug)]
pub struct Cloth {
    n: usize,
    mass: Vec<f64>,
    material: ClothMaterial,
    loads: Loads,
    /// Vertices the solve fixes, sorted: pinned ones, path vertices and vertices in no
    /// triangle.
    pinned: Vec<u32>,
    triangles: Vec<[u32; 3]>,
    rest: Vec<TriangleRest>,
    stiffness: TriangleStiffness,
    hinges: Vec<[u32; 4]>,
    theta0: Vec<f64>,
    definiteness_fix: bool,
    obstacles: Vec<Obstacle>,
    friction: f64,
    self_collision: Option<f64>,
    paths: Vec<VertexPath>,
    /// Initial positions of path vertices, per path.
    path_rest: Vec<Vec<[f64; 3]>>,
    step_control: StepControl,
    tri_gather: VectorGather,
    hinge_gather: VectorGather,
}

/// The cloth's scratch buffers: element forces, and the Jacobian structures and element
/// Jacobians once an implicit integrator asked for them.
#[derive(Clone, Debug)]
pub struct ClothWork {
    tri_f: Vec<f64>,
    hinge_f: Vec<f64>,
    jac: Option<ClothJacobians>,
}

impl ClothWork {
    /// Whether the Jacobian structures were built.
    pub fn has_jacobians(&self) -> bool {
        self.jac.is_some()
    }
}

#[derive(Clone, Debug)]
struct ClothJacobians {
    tri: ElementAssembly,
    tri_kx: Vec<f64>,
    tri_kv: Vec<f64>,
    hinge: HingeJacobians,
}

/// How hinge Jacobians reach the matrices.
#[derive(Clone, Debug)]
enum HingeJacobians {
    /// Projected (definiteness fix): `-k g g^T` and `-k_d g g^T`, formed by the gather
    /// from each hinge's angle gradient `g` (12 values per hinge).
    RankOne { asm: RankOneAssembly, g: Vec<f64> },
    /// Exact: each hinge's ten upper blocks of `df/dx` (and of `df/dv` with bend damping,
    /// else `kv` is empty).
    Blocks {
        asm: ElementAssembly,
        kx: Vec<f64>,
        kv: Vec<f64>,
    },
}

/// Elements per parallel task (fixed: thread-count independent results).
const CHUNK: usize = 1024;

impl ClothDesc {
    /// Validates and builds the cloth and its initial state.
    pub fn build(&self) -> Result<(Cloth, ClothState), ModelError> {
        let n = self.positions.len();
        for (what, got) in [("uv", self.uv.len()), ("velocities", self.velocities.len())] {
            if got != n && !(what == "velocities" && got == 0) {
                return Err(ModelError::Length {
                    what,
                    got,
                    expected: n,
                    per: "vertex",
                });
            }
        }
        use Rule::{Coordinate, Finite, NonNegative, Positive};
        for (i, p) in self.positions.iter().enumerate() {
            for (c, &x) in p.iter().enumerate() {
                check("vertex", i, ["x", "y", "z"][c], x, Coordinate)?;
            }
        }
        for (i, p) in self.velocities.iter().enumerate() {
            for (c, &x) in p.iter().enumerate() {
                check("vertex", i, ["vx", "vy", "vz"][c], x, Finite)?;
            }
        }
        for (i, p) in self.uv.iter().enumerate() {
            for (c, &x) in p.iter().enumerate() {
                check("vertex", i, ["u", "v"][c], x, Coordinate)?;
            }
        }
        let m = &self.material;
        check("material", 0, "density", m.density, Positive)?;
        for (field, v) in [
            ("stretch", m.stretch),
            ("shear", m.shear),
            ("bend", m.bend),
            ("stretch_damping", m.stretch_damping),
            ("shear_damping", m.shear_damping),
            ("bend_damping", m.bend_damping),
            ("friction", self.friction),
        ] {
            check("material", 0, field, v, NonNegative)?;
        }
        for (c, &b) in m.rest_stretch.iter().enumerate() {
            check("material", c, "rest_stretch", b, Positive)?;
        }
        if let Some(t) = self.self_collision {
            check("self_collision", 0, "thickness", t, Positive)?;
        }
        let loads = Loads {
            gravity: Gravity(self.gravity),
            wind: self.wind,
            field: None,
        };
        loads.validate()?;
        for (k, o) in self.obstacles.iter().enumerate() {
            o.validate(k)?;
        }
        self.step_control.validate()?;
        for (k, p) in self.paths.iter().enumerate() {
            p.validate(k, n)?;
        }
        let nt = self.triangles.len();
        let mut rest = Vec::with_capacity(nt);
        let mut stiffness = TriangleStiffness::default();
        let mut mass = vec![0.0; n];
        for (t, tri) in self.triangles.iter().enumerate() {
            crate::validate::vertices_exist("triangle", t, tri, n)?;
            let r = TriangleRest::new(tri.map(|v| self.uv[v as usize])).ok_or_else(|| {
                ModelError::Element {
                    item: "triangle",
                    index: t,
                    what: format!(
                        "{tri:?} has zero rest (u, v) area: check its (u, v) coordinates"
                    ),
                }
            })?;
            for &v in tri {
                mass[v as usize] += m.density * r.area / 3.0;
            }
            let inv_a = 1.0 / r.area;
            stiffness.stretch.push(m.stretch * inv_a);
            stiffness.stretch_damping.push(m.stretch_damping * inv_a);
            stiffness.shear.push(m.shear * inv_a);
            stiffness.shear_damping.push(m.shear_damping * inv_a);
            rest.push(r);
        }
        let mut pinned: Vec<u32> = Vec::with_capacity(self.pinned.len());
        for (k, &p) in self.pinned.iter().enumerate() {
            if p >= n {
                return Err(ModelError::Value {
                    item: "pinned",
                    index: k,
                    field: "vertex",
                    value: p as f64,
                    why: "names a vertex that does not exist",
                });
            }
            pinned.push(p as u32);
        }
        // Path vertices are fixed in the solve like pins.
        pinned.extend(
            self.paths
                .iter()
                .flat_map(|p| p.vertices.iter().map(|&v| v as u32)),
        );
        pinned.sort_unstable();
        pinned.dedup();
        for (i, &mi) in mass.iter().enumerate() {
            if mi == 0.0 && pinned.binary_search(&(i as u32)).is_err() {
                // A vertex in no triangle has no mass: it is left where it is.
                pinned.push(i as u32);
            }
        }
        pinned.sort_unstable();
        let (hinges, theta0) = if m.bend > 0.0 || m.bend_damping > 0.0 {
            hinges_of(&self.triangles, &self.positions)?
        } else {
            (Vec::new(), Vec::new())
        };
        let sparse = |e: SparseError| ModelError::TooLarge(e.to_string());
        let tri_gather =
            VectorGather::new(n, &self.triangles, &LocalLayout::dense(3)).map_err(sparse)?;
        let hinge_gather = VectorGather::new(n, &hinges, &LocalLayout::dense(4)).map_err(sparse)?;
        let cloth = Cloth {
            n,
            mass,
            material: *m,
            loads,
            tri_gather,
            hinge_gather,
            pinned,
            triangles: self.triangles.clone(),
            rest,
            stiffness,
            hinges,
            theta0,
            definiteness_fix: self.definiteness_fix,
            obstacles: self.obstacles.clone(),
            paths: self.paths.clone(),
            step_control: self.step_control,
            path_rest: self
                .paths
                .iter()
                .map(|p| p.vertices.iter().map(|&v| self.positions[v]).collect())
                .collect(),
            friction: self.friction,
            self_collision: self.self_collision,
        };
        let mut v = if self.velocities.is_empty() {
            Vec3s::zeros(n)
        } else {
            Vec3s::from_aos(&self.velocities)
        };
        for &p in &cloth.pinned {
            v.set(p as usize, [0.0; 3]);
        }
        for path in &cloth.paths {
            for &i in &path.vertices {
                v.set(i, path.place(0.0, self.positions[i]).1);
            }
        }
        Ok((
            cloth,
            ClothState {
                x: Vec3s::from_aos(&self.positions),
                v,
            },
        ))
    }
}

/// Hinges `[x0, x1, x2, x3]` of every edge shared by two triangles (x0-x1 the edge, x2 and
/// x3 the opposite vertices), with their rest angles at `positions`.
fn hinges_of(
    triangles: &[[u32; 3]],
    positions: &[[f64; 3]],
) -> Result<(Vec<[u32; 4]>, Vec<f64>), ModelError> {
    // A triangle's use of edge e: (edge start, edge end, opposite vertex), the edge in
    // the triangle's winding.
    let used = |e: [u32; 2], t: usize| {
        let tri = triangles[t];
        let k = (0..3)
            .find(|&k| {
                let (p, q) = (tri[k], tri[(k + 1) % 3]);
                [p.min(q), p.max(q)] == e
            })
            .unwrap_or(0); // edge_uses found e in tri

        (tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3])
    };
    let mut hinges = Vec::new();
    let mut theta0 = Vec::new();
    for uses in crate::io::edge_uses(triangles).chunk_by(|a, b| a.0 == b.0) {
        let [a, b] = uses[0].0;
        match uses {
            [_] => {}
            [(e, s), (_, t)] => {
                let (x0, x1, x2) = used(*e, *s);
                let x3 = used(*e, *t).2;
                let h = [x0, x1, x2, x3];
                let theta = dihedral_angle(&h.map(|v| positions[v as usize]));
                if !theta.is_finite() {
                    return Err(ModelError::Connectivity(format!(
                        "the hinge of edge ({a}, {b}) has a degenerate triangle in the initial positions: no rest angle"
                    )));
                }
                hinges.push(h);
                theta0.push(theta);
            }
            _ => {
                let triangles: Vec<usize> = uses.iter().map(|u| u.1).collect();
                return Err(ModelError::Connectivity(format!(
                    "edge ({a}, {b}) is shared by triangles {triangles:?}: bending needs every edge in at most two triangles"
                )));
            }
        }
    }
    Ok((hinges, theta0))
}

impl Cloth {
    /// Vertex count.
    pub fn vertex_count(&self) -> usize {
        self.n
    }
    /// Triangles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// Hinges (interior edges with their two opposite vertices).
    pub fn hinges(&self) -> &[[u32; 4]] {
        &self.hinges
    }
    /// Vertices the solve fixes: pinned ones, path vertices and vertices in no triangle.
    pub fn pinned(&self) -> &[u32] {
        &self.pinned
    }
    /// The material.
    pub fn material(&self) -> &ClothMaterial {
        &self.material
    }
    /// The external loads (gravity, wind).
    pub fn loads(&self) -> &Loads {
        &self.loads
    }
    /// The obstacles.
    pub fn obstacles(&self) -> &[Obstacle] {
        &self.obstacles
    }
    /// The vertices on prescribed paths.
    pub fn paths(&self) -> &[VertexPath] {
        &self.paths
    }

    /// Each triangle's constants from its rest (u, v), in triangle order.
    pub fn triangle_rest(&self) -> &[TriangleRest] {
        &self.rest
    }

    /// Each hinge's rest angle (rad), in hinge order.
    pub fn rest_angles(&self) -> &[f64] {
        &self.theta0
    }

    /// Triangle `t`'s element constants: the per-area material constants over its rest
    /// area (see [`ClothMaterial`]), computed once by the builder.
    #[inline]
    pub fn triangle_params(&self, t: usize) -> TriangleParams {
        let s = &self.stiffness;
        TriangleParams {
            stretch: s.stretch[t],
            stretch_damping: s.stretch_damping[t],
            shear: s.shear[t],
            shear_damping: s.shear_damping[t],
            rest_stretch: self.material.rest_stretch,
            project: self.definiteness_fix,
        }
    }

    /// Adds triangle `t`'s stretch and shear conditions to `out` (forces only, into an
    /// `ElementForces`; Jacobians into an `ElementOut`).
    fn triangle_into<S: ConditionSink<3>>(
        &self,
        out: &mut S,
        t: usize,
        x: &[[f64; 3]; 3],
        v: &[[f64; 3]; 3],
    ) {
        let p = self.triangle_params(t);
        let r = &self.rest[t];
        add_stretch(out, r, x, v, p.stretch, p.stretch_damping, p.rest_stretch);
        add_shear(out, r, x, v, p.shear, p.shear_damping);
    }

    /// What the loads act on.
    fn body(&self) -> Body<'_> {
        Body {
            mass: &self.mass,
            triangles: &self.triangles,
        }
    }

    /// Triangle `t`'s stretch strain, `max(| |w_u| - b_u |, | |w_v| - b_v |)` (0 at
    /// rest; 0.1 is 10% stretched or compressed).
    fn strain(&self, t: usize, x: &[f64]) -> f64 {
        let b = self.material.rest_stretch;
        let (wu, wv) = self.rest[t].wuv(&gather_nodes(x, self.n, &self.triangles[t]));
        let (lu, lv) = (dot(wu, wu).sqrt(), dot(wv, wv).sqrt());
        (lu - b[0]).abs().max((lv - b[1]).abs())
    }

    /// The largest stretch strain of any triangle (NaN if any is NaN).
    pub fn max_strain(&self, x: &[f64]) -> f64 {
        nan_max((0..self.triangles.len()).map(|t| self.strain(t, x)))
    }
}

impl MechModel for Cloth {
    type Work = ClothWork;

    fn work(&self) -> ClothWork {
        ClothWork {
            tri_f: vec![0.0; self.tri_gather.vector_buffer_len()],
            hinge_f: vec![0.0; self.hinge_gather.vector_buffer_len()],
            jac: None,
        }
    }

    fn vertex_count(&self) -> usize {
        self.n
    }

    fn mass(&self) -> &[f64] {
        &self.mass
    }

    fn force(&self, work: &mut ClothWork, t: f64, x: &[f64], v: &[f64], f: &mut [f64]) {
        self.loads.forces(t, &self.body(), x, v, f);
        let n = self.n;
        work.tri_f
            .par_chunks_mut(9 * CHUNK)
            .enumerate()
            .for_each(|(c, out)| {
                for (lt, o) in out.chunks_exact_mut(9).enumerate() {
                    let t = c * CHUNK + lt;
                    let el = &self.triangles[t];
                    let mut e = ElementForces::zero();
                    self.triangle_into(&mut e, t, &gather_nodes(x, n, el), &gather_nodes(v, n, el));
                    o.copy_from_slice(e.f.as_flattened());
                }
            });
        self.tri_gather.gather_vectors_add(&work.tri_f, f);
        if !self.hinges.is_empty() {
            let m = self.material;
            work.hinge_f
                .par_chunks_mut(12 * CHUNK)
                .enumerate()
                .for_each(|(c, out)| {
                    for (lh, o) in out.chunks_exact_mut(12).enumerate() {
                        let h = c * CHUNK + lh;
                        let el = &self.hinges[h];
                        let xs = gather_nodes(x, n, el);
                        let vs = gather_nodes(v, n, el);
                        let mut e = ElementForces::zero();
                        add_bend(&mut e, &xs, &vs, m.bend, m.bend_damping, self.theta0[h]);
                        o.copy_from_slice(e.f.as_flattened());
                    }
                });
            self.hinge_gather.gather_vectors_add(&work.hinge_f, f);
        }
    }

    fn potential_energy(&self, _t: f64, x: &[f64]) -> Option<f64> {
        let n = self.n;
        let loads = self.loads.potential(&self.body(), x);
        let tris: f64 = (0..self.triangles.len())
            .map(|t| {
                let xs = gather_nodes(x, n, &self.triangles[t]);
                let mut e = ElementForces::zero();
                self.triangle_into(&mut e, t, &xs, &[[0.0; 3]; 3]);
                e.energy
            })
            .sum();
        let bends: f64 = self
            .hinges
            .iter()
            .zip(&self.theta0)
            .map(|(h, t0)| {
                let theta = dihedral_angle(&gather_nodes(x, n, h));
                if theta.is_finite() {
                    0.5 * self.material.bend * (theta - t0).powi(2)
                } else {
                    0.0
                }
            })
            .sum();
        Some(loads + tris + bends)
    }

    fn prepare_jacobians(
        &self,
        work: &mut ClothWork,
    ) -> Result<Option<Arc<Bsr3Pattern>>, SparseError> {
        if work.jac.is_none() {
            // One pattern for both element kinds. Element matrices are symmetric: only
            // their upper blocks are written. With the definiteness fix the hinges'
            // opposite-vertex coupling is moved onto the diagonal
            // (`decoupled_hinge_weight`), so the triangles' pattern holds everything;
            // exact Jacobians need the hinges' (x2, x3) pairs too.
            let mut all: Vec<[u32; 4]> = self
                .triangles
                .iter()
                .map(|t| [t[0], t[1], t[2], t[2]])
                .collect();
            if !self.definiteness_fix {
                all.extend_from_slice(&self.hinges);
            }
            let pattern = Arc::new(Bsr3Pattern::from_elements(self.n, &all)?);
            let tri = ElementAssembly::with_pattern(
                pattern.clone(),
                &self.triangles,
                LocalLayout::symmetric(3),
            )?;
            let (nt, nh) = (self.triangles.len(), self.hinges.len());
            let hinge = if self.definiteness_fix {
                // The decoupled hinge: no (2, 3) coupling, its weight moved onto the
                // (2, 2) and (3, 3) blocks.
                let asm =
                    RankOneAssembly::with_pattern(pattern, &self.hinges, decoupled_hinge_weight)?;
                HingeJacobians::RankOne {
                    g: vec![0.0; asm.vector_buffer_len()],
                    asm,
                }
            } else {
                let asm = ElementAssembly::with_pattern(
                    pattern,
                    &self.hinges,
                    LocalLayout::symmetric(4),
                )?;
                HingeJacobians::Blocks {
                    asm,
                    kx: vec![0.0; HINGE_K * nh],
                    kv: if self.material.bend_damping > 0.0 {
                        vec![0.0; HINGE_K * nh]
                    } else {
                        Vec::new()
                    },
                }
            };
            let tri_damping =
                self.material.stretch_damping > 0.0 || self.material.shear_damping > 0.0;
            work.jac = Some(ClothJacobians {
                tri,
                tri_kx: vec![0.0; TRI_K * nt],
                // Without stretch and shear damping the triangles' df/dv is zero: not
                // written, not gathered.
                tri_kv: if tri_damping {
                    vec![0.0; TRI_K * nt]
                } else {
                    Vec::new()
                },
                hinge,
            });
        }
        Ok(work.jac.as_ref().map(|j| j.tri.pattern().clone()))
    }

    fn has_velocity_jacobian(&self) -> bool {
        let m = &self.material;
        m.stretch_damping > 0.0 || m.shear_damping > 0.0 || m.bend_damping > 0.0
    }

    fn force_jacobians(
        &self,
        work: &mut ClothWork,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut Bsr3,
        mut dfdv: Option<&mut Bsr3>,
    ) -> Result<(), IntegrateError> {
        self.prepare_jacobians(work)
            .map_err(IntegrateError::Sparse)?;
        self.loads.forces(t, &self.body(), x, v, f);
        let n = self.n;
        let ClothWork {
            tri_f,
            hinge_f,
            jac,
        } = work;
        let jac = jac.as_mut().expect("prepared above");
        let m = self.material;
        // Closed form (the condition-by-condition `triangle_into` gives the same, tested;
        // it serves the force-only path and the energy), one triangle per call: the
        // four-lane `triangle_jacobians_x4` gives the same bits (tested) but took 1.5 ms
        // here against 0.9 ms (draped 100x100 sheet, 2 threads): a triangle writes 936 B
        // of forces and blocks, the kernel is bound by those writes, and the lanes'
        // interleaved stores cost more than the arithmetic they save (see
        // `cloth/kernel/triangles` in benches/cloth.rs).
        for_each_element_chunk(
            (tri_f, 9),
            (&mut jac.tri_kx, &mut jac.tri_kv, TRI_K),
            |t0, fo, kxo, mut kvo| {
                for lt in 0..fo.len() / 9 {
                    let t = t0 + lt;
                    let el = &self.triangles[t];
                    let k = TRI_K * lt;
                    triangle_jacobians(
                        &self.rest[t],
                        &gather_nodes(x, n, el),
                        &gather_nodes(v, n, el),
                        &self.triangle_params(t),
                        &mut fo[9 * lt..9 * lt + 9],
                        &mut kxo[k..k + TRI_K],
                        kvo.as_deref_mut().map(|kv| &mut kv[k..k + TRI_K]),
                    );
                }
            },
        );
        self.tri_gather.gather_vectors_add(tri_f, f);
        let nodes = |h: usize| {
            let el = &self.hinges[h];
            (gather_nodes(x, n, el), gather_nodes(v, n, el))
        };
        let (k, kd) = (m.bend, m.bend_damping);
        match &mut jac.hinge {
            // Projected: forces and the angle gradient; the gather forms -k g g^T. Four
            // hinges per call in SIMD lanes, the chunk's last (< 4) one by one: the same
            // bits either way (tested).
            HingeJacobians::RankOne { g, .. } => {
                for_each_element_chunk((hinge_f, 12), (g, &mut [], 12), |h0, fo, go, _| {
                    let count = fo.len() / 12;
                    let full = count / 4 * 4;
                    for lh in (0..full).step_by(4) {
                        let h = h0 + lh;
                        let r = 12 * lh..12 * lh + 48;
                        bend_force_gradient_x4(
                            &four(h, |h| gather_nodes(x, n, &self.hinges[h])),
                            &four(h, |h| gather_nodes(v, n, &self.hinges[h])),
                            k,
                            kd,
                            self.theta0[h..h + 4].try_into().expect("four hinges"),
                            &mut fo[r.clone()],
                            &mut go[r],
                        );
                    }
                    for lh in full..count {
                        let h = h0 + lh;
                        let (xs, vs) = nodes(h);
                        let r = 12 * lh..12 * lh + 12;
                        let (f, g) = (&mut fo[r.clone()], &mut go[r]);
                        bend_force_gradient(&xs, &vs, k, kd, self.theta0[h], f, g);
                    }
                })
            }
            // Exact: the automatic-differentiation Hessian through an `ElementOut`
            // (`kv` only with bend damping: without it the hinges' df/dv is zero and is
            // neither written nor gathered).
            HingeJacobians::Blocks { kx, kv, .. } => {
                for_each_element_chunk((hinge_f, 12), (kx, kv, HINGE_K), |h0, fo, kxo, mut kvo| {
                    for lh in 0..fo.len() / 12 {
                        let h = h0 + lh;
                        let (xs, vs) = nodes(h);
                        let mut e = ElementOut::new(false);
                        add_bend(&mut e, &xs, &vs, k, kd, self.theta0[h]);
                        let kr = HINGE_K * lh..HINGE_K * (lh + 1);
                        write_element(
                            &e,
                            &mut fo[12 * lh..12 * lh + 12],
                            &mut kxo[kr.clone()],
                            kvo.as_deref_mut().map(|kv| &mut kv[kr]),
                        );
                    }
                })
            }
        }
        self.hinge_gather.gather_vectors_add(hinge_f, f);
        jac.tri.gather_blocks(&jac.tri_kx, dfdx);
        if let Some(d) = dfdv.as_deref_mut() {
            // Without stretch and shear damping the triangles write no df/dv.
            if jac.tri_kv.is_empty() {
                d.set_zero();
            } else {
                jac.tri.gather_blocks(&jac.tri_kv, d);
            }
        }
        match &jac.hinge {
            HingeJacobians::RankOne { asm, g } => {
                asm.gather_add(g, -m.bend, dfdx);
                if let Some(d) = dfdv.filter(|_| m.bend_damping > 0.0) {
                    asm.gather_add(g, -m.bend_damping, d);
                }
            }
            HingeJacobians::Blocks { asm, kx, kv } => {
                asm.gather_blocks_add(kx, dfdx);
                if let Some(d) = dfdv.filter(|_| !kv.is_empty()) {
                    asm.gather_blocks_add(kv, d);
                }
            }
        }
        Ok(())
    }

    fn obstacles(&self) -> &[Obstacle] {
        &self.obstacles
    }

    fn contact_friction(&self) -> Option<f64> {
        Some(self.friction)
    }

    fn fixed_vertices(&self) -> &[u32] {
        &self.pinned
    }

    fn self_collision(&self) -> Option<f64> {
        self.self_collision
    }

    /// Path vertices at their initial positions plus the path's offset at `t`, with the
    /// path's velocity.
    fn prescribe(&self, t: f64, x: &mut [f64], v: &mut [f64]) {
        crate::simulation::path::prescribe(&self.paths, &self.path_rest, t, x, v);
    }

    /// The largest change of any triangle's stretch strain.
    fn strain_change(&self, x0: &[f64], x: &[f64]) -> f64 {
        nan_max((0..self.triangles.len()).map(|t| (self.strain(t, x) - self.strain(t, x0)).abs()))
    }

    fn does_external_work(&self) -> bool {
        self.loads.does_work()
    }

    fn external_power(&self, t: f64, x: &[f64], v: &[f64]) -> f64 {
        self.loads.work_rate(t, &self.body(), x, v)
    }

    fn step_control(&self) -> Option<StepControl> {
        Some(self.step_control)
    }

    fn stages(&self) -> Vec<Stage> {
        let m = &self.material;
        let bend = !self.hinges.is_empty();
        let mut stages = vec![
            Stage::built(
                "cloth stretch and shear elements",
                format!("{} vertices, {} triangles", self.n, self.triangles.len()),
            ),
            if bend {
                Stage::built(
                    "bend elements (hinges)",
                    format!("{} hinges", self.hinges.len()),
                )
            } else {
                Stage::left_out(
                    "bend elements (hinges)",
                    "bending is off (bend stiffness and damping are zero)",
                )
            },
            if self.has_velocity_jacobian() {
                Stage::built(
                    "cloth damping",
                    format!(
                        "stretch {}, shear {}, bend {}",
                        m.stretch_damping, m.shear_damping, m.bend_damping
                    ),
                )
            } else {
                Stage::left_out("cloth damping", "every damping coefficient is zero")
            },
        ];
        stages.extend(self.loads.stages());
        if self.loads.wind.is_none() {
            stages.push(Stage::left_out("wind", "no [cloth.wind]"));
        }
        stages.push(Stage::pinned(self.pinned.len()));
        stages.push(Stage::obstacle_contacts(&self.obstacles));
        stages.push(match self.self_collision {
            Some(t) => Stage::built(
                "self-collision",
                format!("repulsion within {t} m, continuous collision impulses, impact zones (BVH broad phase)"),
            ),
            None => Stage::left_out("self-collision", "no [cloth.self_collision]"),
        });
        stages.push(if self.paths.is_empty() {
            Stage::left_out("prescribed paths", "no [[cloth.path]]")
        } else {
            Stage::built("prescribed paths", format!("{} paths", self.paths.len()))
        });
        stages
    }

    fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
}

/// The largest of non-negative values, 0 for none, NaN if any is NaN (`f64::max` would
/// skip it: a blown-up state must not look unstrained).
fn nan_max(values: impl Iterator<Item = f64>) -> f64 {
    values.fold(0.0, |m, s| {
        if s.is_nan() || m.is_nan() {
            f64::NAN
        } else {
            m.max(s)
        }
    })
}

/// Runs `body(first element, f, kx, kv)` in parallel over fixed chunks of [`CHUNK`]
/// elements of element-major buffers: `f` with `nf` values per element, `kx` and `kv`
/// with `nk` (an empty `kv`, for a zero `df/dv`, gives `None`). The chunks depend on the
/// element count only, so results do not depend on the thread count.
fn for_each_element_chunk(
    (f, nf): (&mut [f64], usize),
    (kx, kv, nk): (&mut [f64], &mut [f64], usize),
    body: impl Fn(usize, &mut [f64], &mut [f64], Option<&mut [f64]>) + Sync + Send,
) {
    let chunks = f
        .par_chunks_mut(nf * CHUNK)
        .zip(kx.par_chunks_mut(nk * CHUNK))
        .enumerate();
    if kv.is_empty() {
        chunks.for_each(|(c, (f, kx))| body(c * CHUNK, f, kx, None));
    } else {
        chunks
            .zip(kv.par_chunks_mut(nk * CHUNK))
            .for_each(|((c, (f, kx)), kv)| body(c * CHUNK, f, kx, Some(kv)));
    }
}

/// Doubles per element in the Jacobian buffers: the upper blocks of the symmetric local
/// matrix ([`LocalLayout::symmetric`]), 6 for a triangle, 10 for a hinge.
const TRI_K: usize = 9 * 6;
const HINGE_K: usize = 9 * 10;

/// The forces and the upper blocks (p <= q, in [`LocalLayout::symmetric`] order) of an
/// element's symmetric Jacobians into element-major buffers.
fn write_element<const K: usize>(
    e: &ElementOut<K>,
    f: &mut [f64],
    kx: &mut [f64],
    mut kv: Option<&mut [f64]>,
) {
    for i in 0..K {
        f[3 * i..3 * i + 3].copy_from_slice(&e.f[i]);
        for j in i..K {
            let b = 9 * LocalLayout::symmetric_index(K, i, j);
            kx[b..b + 9].copy_from_slice(&e.kx[i][j]);
            if let Some(kv) = kv.as_deref_mut() {
                kv[b..b + 9].copy_from_slice(&e.kv[i][j]);
            }
        }
    }
}
