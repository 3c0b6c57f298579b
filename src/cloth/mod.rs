//! Baraff-Witkin cloth (SIGGRAPH 1998) on a triangle mesh with rest (u, v) coordinates.
//!
//! Every triangle carries a stretch and a shear condition, every interior edge (two
//! triangles) a bend condition on its dihedral angle (`kernels::cloth`); energies
//! `k/2 C^2`, forces `-k C dC/dx - k_d (dC/dt) dC/dx`, and exact Jacobians. Masses are
//! lumped: `density * (u, v) area / 3` to each vertex of a triangle. Per-element constants
//! (the (u, v) coefficients, areas, rest angles) are computed once; forces and Jacobians
//! run in parallel over fixed chunks of elements and are gathered per vertex and per
//! matrix slot in a fixed order, so results do not depend on the thread count. The model
//! implements [`Mechanical`], so every integrator runs it; implicit ones get
//! `df/dx` and `df/dv` on one block pattern shared by triangles and hinges.
//!
//! Rest: (u, v) as given (the stretch conditions use the rest stretch `b_u`, `b_v`, 1 by
//! default); rest angles are the dihedral angles of the initial positions.

mod generators;
mod obstacles;

pub use generators::{cloth_grid, ClothGridOptions};
pub use obstacles::{Obstacle, SdfGrid};

use crate::integrate::{IntegrateError, Mechanical};
use crate::soa::Vec3s;
use crate::solve::Filter;
use crate::sparse::{
    Bsr3, Bsr3Pattern, ElementAssembly, LocalLayout, RankOneAssembly, SparseError, VectorGather,
};
use largestep_kernels::cloth::{
    add_bend, add_shear, add_stretch, bend_force_gradient, bend_force_gradient_x4,
    decoupled_hinge_weight, dihedral_angle, triangle_jacobians, ConditionSink, ElementForces,
    ElementOut, TriangleParams, TriangleRest,
};
use largestep_kernels::v3::{cross, dot, sub};
use largestep_kernels::{four, gather_nodes, get3};
use rayon::prelude::*;
use std::collections::HashMap;
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

/// Wind: a drag force on every triangle towards the air's velocity relative to it, along
/// the triangle's normal, `f = drag A ((w - v) . n) n` (A the current area, v the mean of
/// its vertices' velocities), split equally among its vertices. The air velocity can
/// gust: `w(t, x) = velocity (1 + gust sin(2 pi (frequency t - x . d / wavelength)))`
/// with `d` the wind's direction and `wavelength = |velocity| / frequency` (gusts travel
/// with the wind). An external load: no potential, no Jacobian (like the jello's force
/// field), so the implicit step treats it explicitly.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wind {
    /// Mean air velocity (m/s).
    pub velocity: [f64; 3],
    /// Drag coefficient (N s/m^3 = kg/(m^2 s)), >= 0.
    pub drag: f64,
    /// Relative gust amplitude, >= 0 (0: steady).
    pub gust: f64,
    /// Gust frequency (Hz), >= 0.
    pub frequency: f64,
}

/// Vertices moved along a prescribed path: each listed vertex sits at its initial
/// position plus an offset interpolated linearly between keyframes (held before the first
/// and after the last). Path vertices are fixed in the implicit solve and placed on the
/// path after every step with the path's velocity.
#[derive(Clone, Debug, PartialEq)]
pub struct VertexPath {
    /// The vertices moved.
    pub vertices: Vec<usize>,
    /// Keyframe times (s), increasing.
    pub times: Vec<f64>,
    /// Offsets from the initial positions at those times (m).
    pub offsets: Vec<[f64; 3]>,
}

impl VertexPath {
    /// Offset and velocity at time `t` (the velocity of the segment `t` lies in, taking
    /// the later one at a keyframe).
    pub fn at(&self, t: f64) -> ([f64; 3], [f64; 3]) {
        let k = self.times.partition_point(|&tk| tk <= t);
        if k == 0 {
            return (self.offsets[0], [0.0; 3]);
        }
        if k == self.times.len() {
            return (self.offsets[k - 1], [0.0; 3]);
        }
        let (t0, t1) = (self.times[k - 1], self.times[k]);
        let (a, b) = (self.offsets[k - 1], self.offsets[k]);
        let s = (t - t0) / (t1 - t0);
        (
            std::array::from_fn(|c| a[c] + s * (b[c] - a[c])),
            std::array::from_fn(|c| (b[c] - a[c]) / (t1 - t0)),
        )
    }
}

/// Step-size control of Baraff and Witkin (1998, section 5.3), applied by
/// `scene::Simulation`: a step that fails (the solve does not converge, the state is not
/// finite) or stretches or compresses some triangle by more than `max_strain_change` in
/// one step ([`Cloth::strain_change`]: the large-step artifact of a linearised step
/// turning a rotation into stretch) is undone and retried as two half steps, down to
/// `dt / 2^max_halvings`; after two good steps the step doubles back towards the scene's
/// dt. The limit is on the change, not the strain itself, so cloth that is strained where
/// it hangs from a pin is not rejected for it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepControl {
    /// Largest change of any triangle's strain in one step (0.25: 25%), > 0.
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
    /// Collision obstacles; see [`Cloth::resolve_contacts`].
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
}

/// Invalid cloth input, naming the element.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ClothError {
    /// Array lengths disagree.
    #[error("{what} has {got} entries, expected {expected} (one per vertex)")]
    Length {
        /// The array.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The vertex count.
        expected: usize,
    },
    /// A value out of range.
    #[error("{item} {index}: {field} = {value} is invalid ({why})")]
    Value {
        /// `vertex`, `material`, `gravity`.
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
    /// A triangle names a missing vertex.
    #[error("triangle {triangle} names vertex {vertex}, but there are only {n} vertices")]
    MissingVertex {
        /// Triangle index.
        triangle: usize,
        /// The vertex named.
        vertex: usize,
        /// Vertex count.
        n: usize,
    },
    /// A triangle with zero (u, v) area (or repeated vertices).
    #[error(
        "triangle {triangle} {vertices:?} has zero rest (u, v) area: check its (u, v) coordinates"
    )]
    Degenerate {
        /// Triangle index.
        triangle: usize,
        /// Its vertices.
        vertices: [u32; 3],
    },
    /// An edge shared by more than two triangles (bending needs a hinge of two).
    #[error("edge ({a}, {b}) is shared by triangles {triangles:?}: bending needs every edge in at most two triangles")]
    NonManifold {
        /// Edge endpoints.
        a: u32,
        /// Edge endpoints.
        b: u32,
        /// The triangles sharing it.
        triangles: Vec<usize>,
    },
    /// A hinge whose triangles are degenerate in the initial positions (no rest angle).
    #[error("the hinge of edge ({a}, {b}) has a degenerate triangle in the initial positions: no rest angle")]
    DegenerateHinge {
        /// Edge endpoints.
        a: u32,
        /// Edge endpoints.
        b: u32,
    },
    /// Pattern too large.
    #[error("{0}")]
    Sparse(String),
}

/// Positions and velocities of the cloth's vertices.
pub type ClothState = crate::integrate::MechState;

/// A validated cloth (see the module docs).
#[derive(Clone, Debug)]
pub struct Cloth {
    n: usize,
    mass: Vec<f64>,
    material: ClothMaterial,
    gravity: [f64; 3],
    pinned: Vec<u32>,
    triangles: Vec<[u32; 3]>,
    rest: Vec<TriangleRest>,
    hinges: Vec<[u32; 4]>,
    theta0: Vec<f64>,
    definiteness_fix: bool,
    obstacles: Vec<Obstacle>,
    friction: f64,
    wind: Option<Wind>,
    paths: Vec<VertexPath>,
    step_control: StepControl,
    /// Initial positions of path vertices, per path.
    path_rest: Vec<Vec<[f64; 3]>>,
    /// Current contacts: vertex and outward unit normal, in vertex order.
    contacts: Vec<(u32, [f64; 3])>,
    /// For each contact, the normal component of the force on its vertex at the last
    /// force evaluation (N): positive means the cloth pulls it off the surface.
    contact_pull: Vec<f64>,
    /// Scratch: the previous step's contacts and pulls while resolving new ones.
    prev_contacts: Vec<(u32, [f64; 3])>,
    prev_pull: Vec<f64>,
    tri_gather: VectorGather,
    hinge_gather: VectorGather,
    tri_f: Vec<f64>,
    hinge_f: Vec<f64>,
    jac: Option<ClothJacobians>,
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

/// What a value must be.
#[derive(Clone, Copy)]
enum Rule {
    Finite,
    NonNegative,
    Positive,
}

/// `Ok` if `value` obeys `rule`, else the error naming item, index and field.
fn check(
    item: &'static str,
    index: usize,
    field: &'static str,
    value: f64,
    rule: Rule,
) -> Result<(), ClothError> {
    let (ok, why) = match rule {
        Rule::Finite => (value.is_finite(), "must be finite"),
        Rule::NonNegative => (value.is_finite() && value >= 0.0, "must be finite and >= 0"),
        Rule::Positive => (value.is_finite() && value > 0.0, "must be finite and > 0"),
    };
    require(item, index, field, value, ok, why)
}

/// `Ok` if `ok`, else the error naming item, index, field and `why`.
fn require(
    item: &'static str,
    index: usize,
    field: &'static str,
    value: f64,
    ok: bool,
    why: &'static str,
) -> Result<(), ClothError> {
    if ok {
        Ok(())
    } else {
        Err(ClothError::Value {
            item,
            index,
            field,
            value,
            why,
        })
    }
}

impl ClothDesc {
    /// Validates and builds the cloth and its initial state.
    pub fn build(&self) -> Result<(Cloth, ClothState), ClothError> {
        let n = self.positions.len();
        for (what, got) in [("uv", self.uv.len()), ("velocities", self.velocities.len())] {
            if got != n && !(what == "velocities" && got == 0) {
                return Err(ClothError::Length {
                    what,
                    got,
                    expected: n,
                });
            }
        }
        use Rule::{Finite, NonNegative, Positive};
        for (i, p) in self.positions.iter().enumerate() {
            for (c, &x) in p.iter().enumerate() {
                check("vertex", i, ["x", "y", "z"][c], x, Finite)?;
            }
        }
        for (i, p) in self.velocities.iter().enumerate() {
            for (c, &x) in p.iter().enumerate() {
                check("vertex", i, ["vx", "vy", "vz"][c], x, Finite)?;
            }
        }
        for (i, p) in self.uv.iter().enumerate() {
            for (c, &x) in p.iter().enumerate() {
                check("vertex", i, ["u", "v"][c], x, Finite)?;
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
        for (c, &g) in self.gravity.iter().enumerate() {
            check("gravity", c, "component", g, Finite)?;
        }
        for (k, o) in self.obstacles.iter().enumerate() {
            o.validate(k)?;
        }
        if let Some(w) = &self.wind {
            for (c, &x) in w.velocity.iter().enumerate() {
                check(
                    "wind",
                    0,
                    ["velocity.x", "velocity.y", "velocity.z"][c],
                    x,
                    Finite,
                )?;
            }
            for (field, x) in [
                ("drag", w.drag),
                ("gust", w.gust),
                ("frequency", w.frequency),
            ] {
                check("wind", 0, field, x, NonNegative)?;
            }
        }
        let sc = self.step_control.max_strain_change;
        check("step_control", 0, "max_strain_change", sc, Positive)?;
        for (k, p) in self.paths.iter().enumerate() {
            if p.times.is_empty() || p.times.len() != p.offsets.len() {
                return Err(ClothError::Value {
                    item: "path",
                    index: k,
                    field: "offsets",
                    value: p.offsets.len() as f64,
                    why: "needs one offset per keyframe time, and at least one",
                });
            }
            for w in p.times.windows(2) {
                require("path", k, "times", w[1], w[1] > w[0], "must be increasing")?;
            }
            for &t in &p.times {
                check("path", k, "times", t, Finite)?;
            }
            for &x in p.offsets.iter().flatten() {
                check("path", k, "offsets", x, Finite)?;
            }
            for &v in &p.vertices {
                let why = "names a vertex that does not exist";
                require("path", k, "vertices", v as f64, v < n, why)?;
            }
        }
        let mut rest = Vec::with_capacity(self.triangles.len());
        let mut mass = vec![0.0; n];
        for (t, tri) in self.triangles.iter().enumerate() {
            if let Some(&v) = tri.iter().find(|&&v| v as usize >= n) {
                return Err(ClothError::MissingVertex {
                    triangle: t,
                    vertex: v as usize,
                    n,
                });
            }
            let r = TriangleRest::new(tri.map(|v| self.uv[v as usize])).ok_or(
                ClothError::Degenerate {
                    triangle: t,
                    vertices: *tri,
                },
            )?;
            for &v in tri {
                mass[v as usize] += m.density * r.area / 3.0;
            }
            rest.push(r);
        }
        let mut pinned: Vec<u32> = Vec::with_capacity(self.pinned.len());
        for (k, &p) in self.pinned.iter().enumerate() {
            if p >= n {
                return Err(ClothError::Value {
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
        let sparse = |e: SparseError| ClothError::Sparse(e.to_string());
        let tri_gather =
            VectorGather::new(n, &self.triangles, &LocalLayout::dense(3)).map_err(sparse)?;
        let hinge_gather = VectorGather::new(n, &hinges, &LocalLayout::dense(4)).map_err(sparse)?;
        let cloth = Cloth {
            n,
            mass,
            material: *m,
            gravity: self.gravity,
            tri_f: vec![0.0; tri_gather.vector_buffer_len()],
            hinge_f: vec![0.0; hinge_gather.vector_buffer_len()],
            tri_gather,
            hinge_gather,
            pinned,
            triangles: self.triangles.clone(),
            rest,
            hinges,
            theta0,
            definiteness_fix: self.definiteness_fix,
            obstacles: self.obstacles.clone(),
            wind: self.wind,
            paths: self.paths.clone(),
            step_control: self.step_control,
            path_rest: self
                .paths
                .iter()
                .map(|p| p.vertices.iter().map(|&v| self.positions[v]).collect())
                .collect(),
            friction: self.friction,
            contacts: Vec::new(),
            contact_pull: Vec::new(),
            prev_contacts: Vec::new(),
            prev_pull: Vec::new(),
            jac: None,
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
            let vel = path.at(0.0).1;
            for &i in &path.vertices {
                v.set(i, vel);
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

/// A triangle using an edge: (triangle, edge start, edge end, opposite vertex), the edge
/// in the triangle's winding.
type EdgeUse = (usize, u32, u32, u32);

/// Hinges `[x0, x1, x2, x3]` of every edge shared by two triangles (x0-x1 the edge, x2 and
/// x3 the opposite vertices), with their rest angles at `positions`.
fn hinges_of(
    triangles: &[[u32; 3]],
    positions: &[[f64; 3]],
) -> Result<(Vec<[u32; 4]>, Vec<f64>), ClothError> {
    let mut edges: HashMap<(u32, u32), Vec<EdgeUse>> = HashMap::new();
    for (t, tri) in triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b, opp) = (tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]);
            edges
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push((t, a, b, opp));
        }
    }
    let mut list: Vec<((u32, u32), Vec<EdgeUse>)> = edges.into_iter().collect();
    list.sort_unstable_by_key(|(k, _)| *k);
    let mut hinges = Vec::new();
    let mut theta0 = Vec::new();
    for ((a, b), ts) in list {
        match ts.len() {
            1 => {}
            2 => {
                let (_, x0, x1, x2) = ts[0];
                let x3 = ts[1].3;
                let h = [x0, x1, x2, x3];
                let theta = dihedral_angle(&h.map(|v| positions[v as usize]));
                if !theta.is_finite() {
                    return Err(ClothError::DegenerateHinge { a, b });
                }
                hinges.push(h);
                theta0.push(theta);
            }
            _ => {
                return Err(ClothError::NonManifold {
                    a,
                    b,
                    triangles: ts.iter().map(|t| t.0).collect(),
                })
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
    /// Pinned vertices (including vertices in no triangle).
    pub fn pinned(&self) -> &[u32] {
        &self.pinned
    }
    /// Whether the Jacobian structures were built.
    pub fn has_jacobians(&self) -> bool {
        self.jac.is_some()
    }
    /// The material.
    pub fn material(&self) -> &ClothMaterial {
        &self.material
    }
    /// Gravity (m/s^2).
    pub fn gravity(&self) -> [f64; 3] {
        self.gravity
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
    /// area (see [`ClothMaterial`]).
    pub fn triangle_params(&self, t: usize) -> TriangleParams {
        let m = &self.material;
        let inv_a = 1.0 / self.rest[t].area;
        TriangleParams {
            stretch: m.stretch * inv_a,
            stretch_damping: m.stretch_damping * inv_a,
            shear: m.shear * inv_a,
            shear_damping: m.shear_damping * inv_a,
            rest_stretch: m.rest_stretch,
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

    /// Gravity and wind (external loads) into `f`, overwriting it.
    fn external_forces(&self, t: f64, x: &[f64], v: &[f64], f: &mut [f64]) {
        crate::integrate::gravity_forces(&self.mass, self.gravity, f);
        let Some(w) = self.wind else { return };
        let n = self.n;
        let speed = dot(w.velocity, w.velocity).sqrt();
        for tri in &self.triangles {
            let xs = gather_nodes(x, n, tri);
            // N = e1 x e2 = 2 A n.
            let nn = cross(sub(xs[1], xs[0]), sub(xs[2], xs[0]));
            let len2 = dot(nn, nn);
            if len2.is_nan() || len2 <= 0.0 {
                continue;
            }
            let mut air = w.velocity;
            if w.gust > 0.0 && w.frequency > 0.0 && speed > 0.0 {
                let centre: [f64; 3] =
                    std::array::from_fn(|c| (xs[0][c] + xs[1][c] + xs[2][c]) / 3.0);
                let along = dot(centre, w.velocity) / speed;
                let phase = std::f64::consts::TAU * (w.frequency * t - along * w.frequency / speed);
                let s = 1.0 + w.gust * phase.sin();
                air = air.map(|c| c * s);
            }
            let vs = gather_nodes(v, n, tri);
            let rel: [f64; 3] =
                std::array::from_fn(|c| air[c] - (vs[0][c] + vs[1][c] + vs[2][c]) / 3.0);
            // drag A (rel . n) n = drag (rel . N) N / (2 |N|), a third to each vertex.
            let s = w.drag * dot(rel, nn) / (2.0 * len2.sqrt()) / 3.0;
            for &i in tri {
                for c in 0..3 {
                    f[c * n + i as usize] += s * nn[c];
                }
            }
        }
    }
}

/// Collision thickness: vertices are kept this far outside obstacles (m).
pub const CONTACT_THICKNESS: f64 = 2e-3;

impl Cloth {
    /// Contacts with the obstacles, by Baraff and Witkin's constraint filtering (1998,
    /// section 5) plus position correction, called after each step of size `h` with the
    /// state: every free vertex closer than [`CONTACT_THICKNESS`] to an obstacle (signed
    /// distance) is moved out along the obstacle's normal to that thickness, loses the
    /// velocity that points into it, has its tangential velocity scaled by
    /// `max(0, 1 - friction dv_n / |v_t|)` (Coulomb: `dv_n` is the normal velocity removed
    /// at impact plus `h |f_n| / m` from the force pressing a resting vertex onto the
    /// surface), and is constrained to the tangent plane for the next implicit solve
    /// ([`Mechanical::constraints`]), so it cannot move into the obstacle whatever the
    /// solver's iteration count. A vertex is released when it moves away or when the
    /// force on it at the last evaluation pulled it off the surface (the filter keeps a
    /// constrained vertex's normal velocity at zero, so velocity alone would never
    /// release it). Obstacles are visited in order; a vertex touching two gets both
    /// constraints (`S = I - p p^T - q q^T`). Returns the number of contacts.
    pub fn resolve_contacts(&mut self, x: &mut [f64], v: &mut [f64], h: f64) -> usize {
        std::mem::swap(&mut self.contacts, &mut self.prev_contacts);
        std::mem::swap(&mut self.contact_pull, &mut self.prev_pull);
        self.contacts.clear();
        self.contact_pull.clear();
        if self.obstacles.is_empty() {
            return 0;
        }
        let n = self.n;
        let mut prev = 0; // walks the previous contacts (vertex order) alongside i
        for i in 0..n {
            if self.pinned.binary_search(&(i as u32)).is_ok() {
                continue;
            }
            // Was it held by a contact the cloth is pulling it away from? The filter kept
            // its normal velocity at zero, so velocity alone would never release it
            // (Baraff and Witkin release a constraint when its force pulls the particle
            // off the surface).
            let mut pulled = false;
            // Normal force pressing it onto the surface during the step (N, >= 0).
            let mut press = 0.0f64;
            while prev < self.prev_contacts.len() && self.prev_contacts[prev].0 as usize <= i {
                if self.prev_contacts[prev].0 as usize == i {
                    let pull = self.prev_pull[prev];
                    pulled |= pull > 0.0;
                    press = press.max(-pull);
                }
                prev += 1;
            }
            for o in &self.obstacles {
                let p = get3(x, n, i);
                let Some((d, nrm)) = o.distance(p) else {
                    continue;
                };
                if d.is_nan() || d >= CONTACT_THICKNESS || (pulled && d >= 0.0) {
                    continue;
                }
                for k in 0..3 {
                    x[k * n + i] = p[k] + (CONTACT_THICKNESS - d) * nrm[k];
                }
                let vel = get3(v, n, i);
                let vn = dot(vel, nrm);
                if vn > 0.0 {
                    continue; // moving away: released
                }
                let vt: [f64; 3] = std::array::from_fn(|k| vel[k] - vn * nrm[k]);
                let vt_len = dot(vt, vt).sqrt();
                // Coulomb: the tangential velocity change is at most friction times the
                // normal one, which is the impact (-vn) plus what the pressing force
                // delivered over the step (resting contact, where vn is zero).
                let dvn = -vn + press * h / self.mass[i];
                let keep = if vt_len > 0.0 {
                    (1.0 - self.friction * dvn / vt_len).max(0.0)
                } else {
                    0.0
                };
                for k in 0..3 {
                    v[k * n + i] = keep * vt[k];
                }
                self.contacts.push((i as u32, nrm));
                self.contact_pull.push(0.0);
            }
        }
        self.contacts.len()
    }

    /// Records, for every contact, the normal component of the force `f` on its vertex
    /// (see `contact_pull`).
    fn record_contact_pull(&mut self, f: &[f64]) {
        let n = self.n;
        for ((i, nrm), pull) in self.contacts.iter().zip(&mut self.contact_pull) {
            let fi = get3(f, n, *i as usize);
            *pull = dot(fi, *nrm);
        }
    }

    /// What follows every step, with `t` the time at its end and `h` its size: path vertices are placed on
    /// their paths (position and velocity), then contacts are resolved
    /// ([`Cloth::resolve_contacts`]). Returns the number of contacts.
    pub fn after_step(&mut self, t: f64, h: f64, x: &mut [f64], v: &mut [f64]) -> usize {
        let n = self.n;
        for (path, rest) in self.paths.iter().zip(&self.path_rest) {
            let (off, vel) = path.at(t);
            for (&i, p0) in path.vertices.iter().zip(rest) {
                for c in 0..3 {
                    x[c * n + i] = p0[c] + off[c];
                    v[c * n + i] = vel[c];
                }
            }
        }
        self.resolve_contacts(x, v, h)
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

    /// The largest change of any triangle's strain between `x0` and `x` (NaN if any is
    /// NaN): what step-size control limits ([`StepControl`]).
    pub fn strain_change(&self, x0: &[f64], x: &[f64]) -> f64 {
        nan_max((0..self.triangles.len()).map(|t| (self.strain(t, x) - self.strain(t, x0)).abs()))
    }

    /// The deepest penetration into an obstacle (m, >= 0).
    pub fn max_penetration(&self, x: &[f64]) -> f64 {
        let n = self.n;
        let mut worst = 0.0f64;
        for i in 0..n {
            let p = get3(x, n, i);
            for o in &self.obstacles {
                if let Some((d, _)) = o.distance(p) {
                    worst = worst.max(-d);
                }
            }
        }
        worst
    }

    /// Vertices in contact since the last [`Cloth::resolve_contacts`].
    pub fn contact_count(&self) -> usize {
        self.contacts.len()
    }

    /// The obstacles.
    pub fn obstacles(&self) -> &[Obstacle] {
        &self.obstacles
    }

    /// The step-size control settings.
    pub fn step_control(&self) -> StepControl {
        self.step_control
    }

    /// The wind, if any.
    pub fn wind(&self) -> Option<Wind> {
        self.wind
    }

    /// The vertices on prescribed paths.
    pub fn paths(&self) -> &[VertexPath] {
        &self.paths
    }
}

impl Mechanical for Cloth {
    fn vertex_count(&self) -> usize {
        self.n
    }

    fn mass(&self) -> &[f64] {
        &self.mass
    }

    fn constraints(&self, filter: &mut Filter) {
        // Contacts are in vertex order: one normal constrains to the tangent plane, two
        // independent ones to their common line, three or more fix the vertex.
        for group in self.contacts.chunk_by(|a, b| a.0 == b.0) {
            let i = group[0].0 as usize;
            let p = group[0].1;
            let mut line: Option<[f64; 3]> = None;
            let mut fixed = false;
            for &(_, q) in &group[1..] {
                let c = cross(p, q);
                if dot(c, c) < 1e-12 {
                    continue; // (anti)parallel: the same plane
                }
                match line {
                    None => line = Some(c),
                    Some(l) => {
                        if dot(l, q).abs() > 1e-6 * dot(l, l).sqrt() {
                            fixed = true;
                        }
                    }
                }
            }
            match (fixed, line) {
                (true, _) => filter.fix(i),
                (false, Some(l)) => filter.constrain_line(i, l),
                (false, None) => filter.constrain_normal(i, p),
            }
        }
        // Pins last: a pinned vertex in contact stays fixed.
        for &p in &self.pinned {
            filter.fix(p as usize);
        }
    }

    fn force(&mut self, t: f64, x: &[f64], v: &[f64], f: &mut [f64]) {
        self.external_forces(t, x, v, f);
        let n = self.n;
        let mut tri_f = std::mem::take(&mut self.tri_f);
        let this = &*self;
        tri_f
            .par_chunks_mut(9 * CHUNK)
            .enumerate()
            .for_each(|(c, out)| {
                for (lt, o) in out.chunks_exact_mut(9).enumerate() {
                    let t = c * CHUNK + lt;
                    let el = &this.triangles[t];
                    let mut e = ElementForces::zero();
                    this.triangle_into(&mut e, t, &gather_nodes(x, n, el), &gather_nodes(v, n, el));
                    o.copy_from_slice(e.f.as_flattened());
                }
            });
        self.tri_gather.gather_vectors_add(&tri_f, f);
        self.tri_f = tri_f;
        if !self.hinges.is_empty() {
            let m = self.material;
            let mut hinge_f = std::mem::take(&mut self.hinge_f);
            let this = &*self;
            hinge_f
                .par_chunks_mut(12 * CHUNK)
                .enumerate()
                .for_each(|(c, out)| {
                    for (lh, o) in out.chunks_exact_mut(12).enumerate() {
                        let h = c * CHUNK + lh;
                        let el = &this.hinges[h];
                        let xs = gather_nodes(x, n, el);
                        let vs = gather_nodes(v, n, el);
                        let mut e = ElementForces::zero();
                        add_bend(&mut e, &xs, &vs, m.bend, m.bend_damping, this.theta0[h]);
                        o.copy_from_slice(e.f.as_flattened());
                    }
                });
            self.hinge_gather.gather_vectors_add(&hinge_f, f);
            self.hinge_f = hinge_f;
        }
        self.record_contact_pull(f);
    }

    fn potential_energy(&self, _t: f64, x: &[f64]) -> Option<f64> {
        let n = self.n;
        let gravity = crate::integrate::gravity_energy(&self.mass, self.gravity, x);
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
        Some(gravity + tris + bends)
    }

    fn prepare_jacobians(&mut self) -> Result<Option<Arc<Bsr3Pattern>>, SparseError> {
        if self.jac.is_none() {
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
            self.jac = Some(ClothJacobians {
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
        Ok(self.jac.as_ref().map(|j| j.tri.pattern().clone()))
    }

    fn has_velocity_jacobian(&self) -> bool {
        let m = &self.material;
        m.stretch_damping > 0.0 || m.shear_damping > 0.0 || m.bend_damping > 0.0
    }

    fn force_jacobians(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut Bsr3,
        mut dfdv: Option<&mut Bsr3>,
    ) -> Result<(), IntegrateError> {
        self.prepare_jacobians().map_err(IntegrateError::Sparse)?;
        self.external_forces(t, x, v, f);
        let n = self.n;
        let mut jac = self.jac.take().expect("prepared above");
        let m = self.material;
        let mut tri_f = std::mem::take(&mut self.tri_f);
        let this = &*self;
        // Closed form (the condition-by-condition `triangle_into` gives the same, tested;
        // it serves the force-only path and the energy), one triangle per call: the
        // four-lane `triangle_jacobians_x4` gives the same bits (tested) but took 1.5 ms
        // here against 0.9 ms (draped 100x100 sheet, 2 threads): a triangle writes 936 B
        // of forces and blocks, the kernel is bound by those writes, and the lanes'
        // interleaved stores cost more than the arithmetic they save (see
        // `cloth/kernel/triangles` in benches/cloth.rs).
        for_each_element_chunk(
            (&mut tri_f, 9),
            (&mut jac.tri_kx, &mut jac.tri_kv, TRI_K),
            |t0, fo, kxo, mut kvo| {
                for lt in 0..fo.len() / 9 {
                    let t = t0 + lt;
                    let el = &this.triangles[t];
                    let k = TRI_K * lt;
                    triangle_jacobians(
                        &this.rest[t],
                        &gather_nodes(x, n, el),
                        &gather_nodes(v, n, el),
                        &this.triangle_params(t),
                        &mut fo[9 * lt..9 * lt + 9],
                        &mut kxo[k..k + TRI_K],
                        kvo.as_deref_mut().map(|kv| &mut kv[k..k + TRI_K]),
                    );
                }
            },
        );
        self.tri_gather.gather_vectors_add(&tri_f, f);
        self.tri_f = tri_f;
        let mut hinge_f = std::mem::take(&mut self.hinge_f);
        let this = &*self;
        let nodes = |h: usize| {
            let el = &this.hinges[h];
            (gather_nodes(x, n, el), gather_nodes(v, n, el))
        };
        let (k, kd) = (m.bend, m.bend_damping);
        match &mut jac.hinge {
            // Projected: forces and the angle gradient; the gather forms -k g g^T. Four
            // hinges per call in SIMD lanes, the chunk's last (< 4) one by one: the same
            // bits either way (tested).
            HingeJacobians::RankOne { g, .. } => {
                for_each_element_chunk((&mut hinge_f, 12), (g, &mut [], 12), |h0, fo, go, _| {
                    let count = fo.len() / 12;
                    let full = count / 4 * 4;
                    for lh in (0..full).step_by(4) {
                        let h = h0 + lh;
                        let r = 12 * lh..12 * lh + 48;
                        bend_force_gradient_x4(
                            &four(h, |h| gather_nodes(x, n, &this.hinges[h])),
                            &four(h, |h| gather_nodes(v, n, &this.hinges[h])),
                            k,
                            kd,
                            this.theta0[h..h + 4].try_into().expect("four hinges"),
                            &mut fo[r.clone()],
                            &mut go[r],
                        );
                    }
                    for lh in full..count {
                        let h = h0 + lh;
                        let (xs, vs) = nodes(h);
                        let r = 12 * lh..12 * lh + 12;
                        let (f, g) = (&mut fo[r.clone()], &mut go[r]);
                        bend_force_gradient(&xs, &vs, k, kd, this.theta0[h], f, g);
                    }
                })
            }
            // Exact: the automatic-differentiation Hessian through an `ElementOut`
            // (`kv` only with bend damping: without it the hinges' df/dv is zero and is
            // neither written nor gathered).
            HingeJacobians::Blocks { kx, kv, .. } => for_each_element_chunk(
                (&mut hinge_f, 12),
                (kx, kv, HINGE_K),
                |h0, fo, kxo, mut kvo| {
                    for lh in 0..fo.len() / 12 {
                        let h = h0 + lh;
                        let (xs, vs) = nodes(h);
                        let mut e = ElementOut::new(false);
                        add_bend(&mut e, &xs, &vs, k, kd, this.theta0[h]);
                        let kr = HINGE_K * lh..HINGE_K * (lh + 1);
                        write_element(
                            &e,
                            &mut fo[12 * lh..12 * lh + 12],
                            &mut kxo[kr.clone()],
                            kvo.as_deref_mut().map(|kv| &mut kv[kr]),
                        );
                    }
                },
            ),
        }
        self.hinge_gather.gather_vectors_add(&hinge_f, f);
        self.hinge_f = hinge_f;
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
        self.jac = Some(jac);
        self.record_contact_pull(f);
        Ok(())
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
