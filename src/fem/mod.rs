//! Tetrahedral finite elements: linear tetrahedra with hyperelastic materials
//! (`largestep_kernels::fem`: linear, corotational, St. Venant-Kirchhoff, neo-Hookean and
//! stable neo-Hookean, and the invertible versions of the nonlinear ones) per element
//! region, lumped or consistent mass, Rayleigh damping, gravity, pinned vertices,
//! prescribed paths and obstacle contacts. The nonlinear materials' forces and stiffness
//! come from the singular-value kernels (`largestep_kernels::fem_diag`), four elements
//! per call; linear elasticity from the F-form element.
//!
//! [`FemDesc`] (editable) is checked and built into an immutable [`Fem`] model: per
//! element `Dm^-1` (nine arrays, structure of arrays) and the rest volume, computed once;
//! per vertex a quarter of the mass of each element around it (`rho V / 4`, the lumped
//! mass matrix); the boundary surface (faces that belong to one element, oriented
//! outward), which frames write and loads see. Forces and stiffness blocks are computed
//! per element into element-major buffers and gathered per vertex and per matrix slot in
//! a fixed order (`crate::sparse::assembly`), so results do not depend on the thread
//! count. `Fem` implements [`MechModel`], so every integrator steps it through
//! [`crate::simulation::MechSimulation`].
//!
//! The rest mesh must have positive volumes: an inverted or flat element is an error
//! naming it and its signed volume ([`FemDesc::reorient`] swaps two vertices of each
//! inverted one first, for meshes written with the other orientation). Nodes no element
//! uses carry no mass; they are held fixed and listed in [`Fem::unused_nodes`].

pub mod gmsh;
pub mod mesh;
pub mod scene;
mod statics;
pub mod veg;
pub mod voxel;
pub mod vtk;
pub use statics::{StaticInfo, StaticSimulation, StaticSolver};

use crate::collide::Obstacle;
use crate::integrate::{kinetic_energy, IntegrateError, MechState};
use crate::loads::{Body, Gravity, Loads};
use crate::simulation::path::VertexPath;
use crate::simulation::{MechModel, Stage};
use crate::soa::Vec3s;
use crate::sparse::{Bsr3, Bsr3Pattern, SparseError};
use crate::sparse::{ElementAssembly, LocalLayout, VectorGather};
use crate::validate::{check, require, ModelError, Rule};
pub use largestep_kernels::fem::Material;
use largestep_kernels::fem::{element_energy, element_stiffness, signed_volume, Lame, M3};
use largestep_kernels::fem_diag::{element, element_x4, Elements, Iso};
use largestep_kernels::gather_nodes;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Arc;

/// Elements per parallel task (fixed: thread-count independent).
const CHUNK: usize = 1024;

/// Doubles per element in the stiffness buffer: the ten blocks `K_ab`, `a <= b`.
const TET_K: usize = 90;

/// Elements per kernel call (`element_group`): two groups of four, whose SVDs run
/// interleaved (`element_x8`), or with AVX-512 two groups of eight (`element_x16`, 15%
/// faster).
#[cfg(not(target_feature = "avx512f"))]
const GROUP: usize = 8;
#[cfg(target_feature = "avx512f")]
const GROUP: usize = 16;

#[cfg(target_feature = "avx512f")]
use largestep_kernels::fem_diag::{
    corotational_forces_x16 as polar_group, corotational_warped_x16 as warped_group,
    element_x16 as element_group,
};
#[cfg(not(target_feature = "avx512f"))]
use largestep_kernels::fem_diag::{
    corotational_forces_x8 as polar_group, corotational_warped_x8 as warped_group,
    element_x8 as element_group,
};
const _: () = assert!(CHUNK.is_multiple_of(GROUP), "chunks hold whole groups");

/// A material: the model and its constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FemMaterial {
    /// The constitutive model.
    pub model: Material,
    /// Young's modulus E (Pa), > 0.
    pub young: f64,
    /// Poisson's ratio nu, in (-1, 0.5).
    pub poisson: f64,
    /// Density (kg/m^3), > 0.
    pub density: f64,
}

impl FemMaterial {
    /// Structural steel: E = 200 GPa, nu = 0.30, 7850 kg/m^3 (typical handbook values,
    /// e.g. ASM Handbook vol. 1).
    pub fn steel(model: Material) -> Self {
        Self {
            model,
            young: 200e9,
            poisson: 0.30,
            density: 7850.0,
        }
    }
    /// Aluminium alloy: E = 69 GPa, nu = 0.33, 2700 kg/m^3.
    pub fn aluminium(model: Material) -> Self {
        Self {
            model,
            young: 69e9,
            poisson: 0.33,
            density: 2700.0,
        }
    }
    /// Soft rubber: E = 1 MPa (0.01 to 0.1 GPa for most rubbers; 1 MPa is a soft one),
    /// nu = 0.49 (nearly incompressible), 1100 kg/m^3.
    pub fn rubber(model: Material) -> Self {
        Self {
            model,
            young: 1e6,
            poisson: 0.49,
            density: 1100.0,
        }
    }
    /// Soft tissue (liver-like): E = 10 kPa, nu = 0.45, 1060 kg/m^3.
    pub fn soft_tissue(model: Material) -> Self {
        Self {
            model,
            young: 1e4,
            poisson: 0.45,
            density: 1060.0,
        }
    }

    /// The Lamé parameters.
    pub fn lame(&self) -> Lame {
        Lame::from_young_poisson(self.young, self.poisson)
    }

    fn validate(&self, index: usize) -> Result<(), ModelError> {
        check("material", index, "young", self.young, Rule::Positive)?;
        check("material", index, "density", self.density, Rule::Positive)?;
        let nu = self.poisson;
        require(
            "material",
            index,
            "poisson",
            nu,
            nu > -1.0 && nu < 0.5,
            "must lie in (-1, 0.5)",
        )
    }
}

/// The mass matrix of a model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FemMass {
    /// Diagonal: a quarter of each element's mass on each of its vertices.
    #[default]
    Lumped,
    /// The consistent mass matrix of linear tetrahedra, `M_ab = rho V (1 + delta_ab) / 20
    /// I` per element (Zienkiewicz and Taylor): the kinetic energy of the interpolated
    /// velocity field. Used by the implicit integrators (the explicit ones refuse it).
    Consistent,
}

impl std::str::FromStr for FemMass {
    type Err = String;

    /// `lumped` or `consistent` (scene tables and `largestep modes --mass`).
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "lumped" => Ok(FemMass::Lumped),
            "consistent" => Ok(FemMass::Consistent),
            other => Err(format!(
                "unknown mass `{other}`; expected lumped or consistent"
            )),
        }
    }
}

/// Integrator settings for 3-D elasticity: [`crate::integrate::MechSettings::new`] with
/// [`elasticity_preconditioner`] applied. What the `[fem]` scene uses when `[solver]`
/// names no preconditioner; an engine stepping a [`Fem`] through
/// [`crate::simulation::MechSimulation`] gets the same by starting from these.
pub fn settings(method: crate::integrate::Method) -> crate::integrate::MechSettings {
    let mut s = crate::integrate::MechSettings::new(method);
    elasticity_preconditioner(&mut s);
    s
}

/// Where PCG runs (`LinearSolverKind::Pcg`, or `Auto` above its Cholesky limit), makes its
/// preconditioner smoothed aggregation with rigid-body modes instead of the general
/// default, block Jacobi: its iterations stay flat under refinement (14 on the
/// 19,683-unknown cantilever, where block Jacobi takes 986).
pub fn elasticity_preconditioner(settings: &mut crate::integrate::MechSettings) {
    use crate::integrate::LinearSolverKind;
    if let LinearSolverKind::Auto(p) | LinearSolverKind::Pcg(p) = &mut settings.linear {
        p.preconditioner = crate::solve::Preconditioner::SmoothedAggregation;
    }
}

/// An editable tetrahedral model (see the module docs).
#[derive(Clone, Debug)]
pub struct FemDesc {
    /// Rest (and initial) positions (m).
    pub positions: Vec<[f64; 3]>,
    /// Initial velocities (m/s); empty means zero.
    pub velocities: Vec<[f64; 3]>,
    /// Initial positions (m) when they differ from the rest positions (a body squashed or
    /// stretched at the start); empty means the rest positions.
    pub initial: Vec<[f64; 3]>,
    /// Tetrahedra, four vertex indices each, with positive rest volume.
    pub tets: Vec<[u32; 4]>,
    /// The materials: element e's is `materials[element_material[e]]`, every element's
    /// `materials[0]` when `element_material` is empty. They share one constitutive model
    /// (the model is a choice of method); E, nu and the density differ per region.
    pub materials: Vec<FemMaterial>,
    /// Each element's material (its region), or empty for one material.
    pub element_material: Vec<u32>,
    /// The invertible version of the material: singular values of F below this threshold
    /// (in (0, 1)) are clamped to it (Irving, Teran and Fedkiw 2004), so flat and inverted
    /// elements have finite restoring forces. None: the material as it is.
    pub inversion_threshold: Option<f64>,
    /// Gravity (m/s^2).
    pub gravity: [f64; 3],
    /// Pinned vertices.
    pub pinned: Vec<usize>,
    /// Vertices moved along prescribed rigid paths (a clamp twisted or pulled): fixed in
    /// the solves and placed on their path after every step.
    pub paths: Vec<VertexPath>,
    /// Collision obstacles, resolved as contacts ([`crate::collide::VertexContacts`]).
    pub obstacles: Vec<Obstacle>,
    /// Coulomb friction coefficient of contacts, >= 0.
    pub friction: f64,
    /// Rayleigh damping `C = alpha M + beta K` (1/s and s, >= 0): the damping force is
    /// `-C v` with K the stiffness at the current positions (definiteness-fixed), as in
    /// Vega's Rayleigh damping.
    pub rayleigh: [f64; 2],
    /// Lumped or consistent mass.
    pub mass: FemMass,
    /// What whoever made the mesh noticed (the voxel mesher's vertices left off the
    /// surface, say): reported with the model's warnings in the run summary.
    pub notes: Vec<String>,
    /// Make each element's tangent positive semi-definite (the definiteness fix, per
    /// block in the singular-value frame: `largestep_kernels::fem_diag`; it equals
    /// `largestep_kernels::fem::project_psd` of the 9x9 tangent), so implicit systems stay definite under
    /// compression and inversion; the Jacobian is then exact only where the material's
    /// tangent is definite. Default on.
    pub definiteness_fix: bool,
    /// The corotational material's tangent without the derivative of the rotation:
    /// stiffness warping, each element's linear stiffness turned by its rotation, `R K0
    /// R^T` (Müller and Gross 2004, "Interactive virtual materials"). The forces and the
    /// energy stay the exact corotational ones, so Newton converges to the same solution
    /// to the same tolerance; only the Jacobian that steers it differs (positive
    /// semi-definite for any deformation, and equal to the exact one at rest). Its kernel
    /// needs no SVD (`largestep_kernels::fem_diag::corotational_warped`, which takes the
    /// rotation from the polar decomposition's Newton iteration; flat, inverted and
    /// strongly strained elements go through the SVD kernel with the same tangent). On
    /// the swinging beam of issue 15 the implicit steps took the same Newton and PCG
    /// iterations as with the exact tangent (`benches/fem.rs`, `docs/benchmarks.md`).
    /// Only for [`Material::Corotational`]. Default off.
    pub warped_tangent: bool,
}

impl FemDesc {
    /// A model of `positions` and `tets` in `material`, with no gravity, pins or
    /// obstacles.
    pub fn new(positions: Vec<[f64; 3]>, tets: Vec<[u32; 4]>, material: FemMaterial) -> Self {
        Self {
            positions,
            velocities: Vec::new(),
            initial: Vec::new(),
            tets,
            materials: vec![material],
            element_material: Vec::new(),
            inversion_threshold: None,
            gravity: [0.0; 3],
            pinned: Vec::new(),
            paths: Vec::new(),
            obstacles: Vec::new(),
            friction: 0.0,
            rayleigh: [0.0, 0.0],
            mass: FemMass::Lumped,
            notes: Vec::new(),
            definiteness_fix: true,
            warped_tangent: false,
        }
    }

    /// A cantilever: a beam `size` (m) along x of `cells` cubes (`mesh::box_mesh`, centred
    /// on the x axis), every vertex at x = 0 pinned, under gravity `g` (m/s^2) along -y:
    /// the benchmark, study and test beam.
    pub fn cantilever(cells: [usize; 3], size: [f64; 3], material: FemMaterial, g: f64) -> Self {
        let m = mesh::box_mesh(cells, size, [0.0, -0.5 * size[1], -0.5 * size[2]]);
        let mut d = Self::new(m.positions, m.tets, material);
        d.gravity = [0.0, -g, 0.0];
        d.pinned = (0..d.positions.len())
            .filter(|&i| d.positions[i][0] == 0.0)
            .collect();
        d
    }

    /// Swaps the last two vertices of every element with a negative rest volume (a mesh
    /// written with the other orientation convention); returns how many. Flat elements
    /// stay as they are (and are errors at build).
    pub fn reorient(&mut self) -> usize {
        let mut swapped = 0;
        for t in &mut self.tets {
            if t.iter().any(|&i| i as usize >= self.positions.len()) {
                continue;
            }
            let x = t.map(|i| self.positions[i as usize]);
            if signed_volume(&x) < 0.0 {
                t.swap(2, 3);
                swapped += 1;
            }
        }
        swapped
    }

    /// Takes a `.veg` file's materials and regions (`mesh::read_volume_mesh`), each
    /// material with the constitutive `model`.
    pub fn use_veg_materials(&mut self, model: Material, (materials, regions): mesh::VegParts) {
        self.materials = materials
            .iter()
            .map(|v| FemMaterial {
                model,
                young: v.young,
                poisson: v.poisson,
                density: v.density,
            })
            .collect();
        self.element_material = regions;
    }

    /// Checks the description and builds the model and its initial state.
    pub fn build(&self) -> Result<(Fem, MechState), ModelError> {
        let n = self.positions.len();
        if n == 0 {
            return Err(ModelError::Empty { what: "vertices" });
        }
        if self.tets.is_empty() {
            return Err(ModelError::Empty { what: "tetrahedra" });
        }
        for (what, got) in [
            ("velocities", self.velocities.len()),
            ("initial", self.initial.len()),
        ] {
            if got != 0 && got != n {
                return Err(ModelError::Length {
                    what,
                    got,
                    expected: n,
                    per: "vertex",
                });
            }
        }
        for (i, p) in self.initial.iter().enumerate() {
            for (c, &x) in p.iter().enumerate() {
                check(
                    "vertex",
                    i,
                    ["initial x", "initial y", "initial z"][c],
                    x,
                    Rule::Coordinate,
                )?;
            }
        }
        for (i, p) in self.positions.iter().enumerate() {
            for (c, &x) in p.iter().enumerate() {
                check("vertex", i, ["x", "y", "z"][c], x, Rule::Coordinate)?;
            }
        }
        for (i, p) in self.velocities.iter().enumerate() {
            for (c, &x) in p.iter().enumerate() {
                check("vertex", i, ["vx", "vy", "vz"][c], x, Rule::Finite)?;
            }
        }
        let Some(first) = self.materials.first() else {
            return Err(ModelError::Empty { what: "materials" });
        };
        for (r, m) in self.materials.iter().enumerate() {
            m.validate(r)?;
            if m.model != first.model {
                return Err(ModelError::Element {
                    item: "material",
                    index: r,
                    what: format!(
                        "is {:?} and material 0 is {:?}: the regions share one constitutive model",
                        m.model, first.model
                    ),
                });
            }
        }
        if !self.element_material.is_empty() && self.element_material.len() != self.tets.len() {
            return Err(ModelError::Length {
                what: "element_material",
                got: self.element_material.len(),
                expected: self.tets.len(),
                per: "tetrahedron",
            });
        }
        for (e, &r) in self.element_material.iter().enumerate() {
            if r as usize >= self.materials.len() {
                return Err(ModelError::Missing {
                    item: "tetrahedron",
                    index: e,
                    target: "material",
                    targets: "materials",
                    named: r as usize,
                    n: self.materials.len(),
                });
            }
        }
        if let Some(c) = self.inversion_threshold {
            require(
                "material",
                0,
                "inversion_threshold",
                c,
                c > 0.0 && c < 1.0,
                "must lie in (0, 1)",
            )?;
            require(
                "material",
                0,
                "inversion_threshold",
                c,
                first.model != Material::Linear,
                "applies to the nonlinear materials (linear elasticity has no inversion)",
            )?;
        }
        if self.warped_tangent {
            require(
                "material",
                0,
                "warped_tangent",
                1.0,
                first.model == Material::Corotational,
                "applies to the corotational material only",
            )?;
        }
        for (c, &g) in self.gravity.iter().enumerate() {
            check("gravity", c, "g", g, Rule::Finite)?;
        }
        check("contact", 0, "friction", self.friction, Rule::NonNegative)?;
        check("damping", 0, "mass", self.rayleigh[0], Rule::NonNegative)?;
        check(
            "damping",
            0,
            "stiffness",
            self.rayleigh[1],
            Rule::NonNegative,
        )?;
        for (k, &p) in self.pinned.iter().enumerate() {
            if p >= n {
                return Err(ModelError::Missing {
                    item: "pinned",
                    index: k,
                    target: "vertex",
                    targets: "vertices",
                    named: p,
                    n,
                });
            }
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            o.validate(i)?;
        }
        for (k, p) in self.paths.iter().enumerate() {
            p.validate(k, n)?;
        }
        let mut dm_inv: [Vec<f64>; 9] =
            std::array::from_fn(|_| Vec::with_capacity(self.tets.len()));
        let mut volume = Vec::with_capacity(self.tets.len());
        let mut mass = vec![0.0; n];
        let mut rounding = vec![0.0; n];
        let mut lame: [Vec<f64>; 2] = std::array::from_fn(|_| Vec::with_capacity(self.tets.len()));
        let region = |e: usize| self.element_material.get(e).map_or(0, |&r| r as usize);
        for (e, t) in self.tets.iter().enumerate() {
            crate::validate::vertices_exist("tetrahedron", e, t, n)?;
            let x = t.map(|i| self.positions[i as usize]);
            let v = signed_volume(&x);
            // A volume below 1e-12 of the element's bounding cube is flat for the
            // inverse of Dm (its condition number would pass 1e12).
            let size = (0..3)
                .map(|c| {
                    let (lo, hi) = x
                        .iter()
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                            (lo.min(p[c]), hi.max(p[c]))
                        });
                    hi - lo
                })
                .fold(0.0, f64::max);
            if v.is_nan() || v <= 1e-12 * size.powi(3) {
                return Err(ModelError::Element {
                    item: "tetrahedron",
                    index: e,
                    what: format!(
                        "(vertices {}, {}, {}, {}) has rest volume {v:e} m^3: {} (swap two of its vertices, or reorient the mesh)",
                        t[0],
                        t[1],
                        t[2],
                        t[3],
                        if v < 0.0 { "inverted" } else { "flat" }
                    ),
                });
            }
            let inv = largestep_kernels::fem::inverse(&largestep_kernels::fem::shape_matrix(&x));
            for (k, d) in dm_inv.iter_mut().enumerate() {
                d.push(inv[k]);
            }
            volume.push(v);
            let m = &self.materials[region(e)];
            let l = m.lame();
            lame[0].push(l.mu);
            lame[1].push(l.lambda);
            for &i in t {
                mass[i as usize] += 0.25 * m.density * v;
            }
            // Element force terms at rest: vol P g_a with |P| about (2 mu + 3 lambda) per
            // unit strain, so |P| ~ (2 mu + 3 lambda) |sigma| where sigma ~ 1 rounds.
            let modulus = 2.0 * l.mu + 3.0 * l.lambda.abs();
            for (a, g) in largestep_kernels::fem::shape_gradients(&inv)
                .iter()
                .enumerate()
            {
                rounding[t[a] as usize] += v * modulus * largestep_kernels::v3::dot(*g, *g).sqrt();
            }
        }
        let force_rounding = rounding.iter().map(|r| r * r).sum::<f64>().sqrt();
        let unused: Vec<u32> = (0..n as u32).filter(|&i| mass[i as usize] == 0.0).collect();
        let mut fixed: Vec<u32> = self
            .pinned
            .iter()
            .map(|&p| p as u32)
            .chain(unused.iter().copied())
            .chain(
                self.paths
                    .iter()
                    .flat_map(|p| p.vertices.iter().map(|&v| v as u32)),
            )
            .collect();
        fixed.sort_unstable();
        fixed.dedup();
        let mut on_path = vec![false; n];
        for p in &self.paths {
            for &i in &p.vertices {
                on_path[i] = true;
            }
        }
        let surface = boundary_faces(&self.tets);
        let sparse = |e: SparseError| ModelError::TooLarge(e.to_string());
        let gather = VectorGather::new(n, &self.tets, &LocalLayout::dense(4)).map_err(sparse)?;
        let model = Fem {
            n,
            rest: Vec3s::from_aos(&self.positions).as_slice().to_vec(),
            tets: self.tets.clone(),
            dm_inv,
            volume,
            mass,
            materials: self.materials.clone(),
            element_material: self.element_material.clone(),
            model: first.model,
            lame,
            iso: (first.model != Material::Linear).then_some(Iso {
                material: first.model,
                clamp: self.inversion_threshold,
                project: self.definiteness_fix,
                warped: self.warped_tangent,
            }),
            surface,
            fixed,
            pinned: self.pinned.len(),
            unused,
            loads: Loads {
                gravity: Gravity(self.gravity),
                wind: None,
                field: None,
            },
            obstacles: self.obstacles.clone(),
            paths: self.paths.clone(),
            on_path: on_path.clone(),
            path_elements: (0..self.tets.len() as u32)
                .filter(|&e| self.tets[e as usize].iter().any(|&i| on_path[i as usize]))
                .collect(),
            path_rest: self
                .paths
                .iter()
                .map(|p| p.vertices.iter().map(|&v| self.positions[v]).collect())
                .collect(),
            friction: self.friction,
            definiteness_fix: self.definiteness_fix,
            rayleigh: self.rayleigh,
            gather,
            mass_matrix: None,
            notes: self.notes.clone(),
            force_rounding,
        };
        let mut model = model;
        if self.mass == FemMass::Consistent {
            model.mass_matrix = Some(model.consistent_mass_matrix().map_err(sparse)?);
        }
        let x = Vec3s::from_aos(if self.initial.is_empty() {
            &self.positions
        } else {
            &self.initial
        });
        let mut v = if self.velocities.is_empty() {
            Vec3s::zeros(n)
        } else {
            Vec3s::from_aos(&self.velocities)
        };
        for p in &self.paths {
            for &i in &p.vertices {
                v.set(i, p.place(0.0, self.positions[i]).1);
            }
        }
        Ok((model, MechState { x, v }))
    }
}

/// The faces that belong to one tetrahedron, oriented outward (for a positively oriented
/// `(a, b, c, d)`: `(a, c, b)`, `(a, b, d)`, `(a, d, c)`, `(b, c, d)`), in element order.
pub fn boundary_faces(tets: &[[u32; 4]]) -> Vec<[u32; 3]> {
    let faces = |t: &[u32; 4]| {
        let [a, b, c, d] = *t;
        [[a, c, b], [a, b, d], [a, d, c], [b, c, d]]
    };
    let key = |f: &[u32; 3]| {
        let mut k = *f;
        k.sort_unstable();
        k
    };
    let mut count: HashMap<[u32; 3], u32> = HashMap::with_capacity(2 * tets.len());
    for t in tets {
        for f in faces(t) {
            *count.entry(key(&f)).or_insert(0) += 1;
        }
    }
    tets.iter()
        .flat_map(faces)
        .filter(|f| count[&key(f)] == 1)
        .collect()
}

/// `f_a += beta sum_b J_ab v_b` for an element's force Jacobian blocks `J_ab = df_a/dx_b`
/// stored as the ten blocks `a <= b` (`J_ba = J_ab^T`): the stiffness-proportional
/// Rayleigh damping force `-beta K v` with `K = -J`.
fn add_stiffness_damping(f: &mut [[f64; 3]; 4], k: &[f64], beta: f64, v: &[[f64; 3]; 4]) {
    let mut blk = 0;
    for a in 0..4 {
        for b in a..4 {
            let j = &k[9 * blk..9 * blk + 9];
            for i in 0..3 {
                f[a][i] +=
                    beta * (j[3 * i] * v[b][0] + j[3 * i + 1] * v[b][1] + j[3 * i + 2] * v[b][2]);
                if b != a {
                    // J_ba = J_ab^T: row i of J_ba is column i of J_ab.
                    f[b][i] += beta * (j[i] * v[a][0] + j[3 + i] * v[a][1] + j[6 + i] * v[a][2]);
                }
            }
            blk += 1;
        }
    }
}

/// An immutable tetrahedral model (see the module docs).
#[derive(Clone, Debug)]
pub struct Fem {
    n: usize,
    tets: Vec<[u32; 4]>,
    /// Rest positions, component-major (for displacements).
    rest: Vec<f64>,
    /// `Dm^-1` per element, entry k (row-major) in array k.
    dm_inv: [Vec<f64>; 9],
    /// Rest volume per element (m^3).
    volume: Vec<f64>,
    mass: Vec<f64>,
    materials: Vec<FemMaterial>,
    element_material: Vec<u32>,
    model: Material,
    /// `[mu, lambda]` per element (Pa), from its material.
    lame: [Vec<f64>; 2],
    /// The singular-value kernel's settings (the nonlinear materials), or none (linear
    /// elasticity, evaluated in the F form).
    iso: Option<Iso>,
    surface: Vec<[u32; 3]>,
    /// Pinned and unused vertices, sorted.
    fixed: Vec<u32>,
    pinned: usize,
    unused: Vec<u32>,
    loads: Loads,
    obstacles: Vec<Obstacle>,
    paths: Vec<VertexPath>,
    /// Each path's vertices' rest positions.
    path_rest: Vec<Vec<[f64; 3]>>,
    /// Whether each vertex is on a path, and the elements with a vertex on one (for the
    /// work the paths do).
    on_path: Vec<bool>,
    path_elements: Vec<u32>,
    friction: f64,
    definiteness_fix: bool,
    rayleigh: [f64; 2],
    /// The consistent mass matrix, when the description asks for it.
    mass_matrix: Option<Bsr3>,
    /// `FemDesc::notes`.
    notes: Vec<String>,
    gather: VectorGather,
    /// [`MechModel::force_rounding`] (N).
    force_rounding: f64,
}

/// Scratch buffers of a [`Fem`] model's evaluations.
#[derive(Debug)]
pub struct FemWork {
    /// Element forces (12 per element).
    f: Vec<f64>,
    /// Stiffness blocks, the 10 local blocks of each element on and above the diagonal
    /// in the assembly's gather order ([`ElementAssembly::par_write_ordered`]: on the
    /// 60,000-element beam the streamed gather and the scattered stores took its
    /// assembly from 14.6 to 12.9 ms, medians of six alternating runs, with all 16
    /// blocks; the 10 and the mirrored slots 13.2-14.6 ms against 14.6-17.7 ms for the
    /// 16, three alternating runs in a slower spell), empty until their assembly is
    /// built for an implicit method; their precision is chosen with the scratch
    /// ([`Fem::exact_work`]).
    blocks: ElementBlocks,
    asm: Option<ElementAssembly>,
}

/// The element stiffness blocks between the kernels and the gather.
///
/// Why `f32` for stepping: the implicit step's Jacobian only steers Newton (its residual,
/// the forces, stays `f64`, so the steps converge to the same tolerance), and rounding the
/// 43 MB of blocks of the 60,000-element beam to 21.6 MB took its assembly from 32-40 to
/// 23-25 ms (alternating builds): the gather, half the assembly, waited on memory for
/// the blocks. Each block is moved by at most 6e-8 of its size; the sums are `f64`.
/// Modal analysis needs the exact `K` (a free body's six rigid modes sit near 1e-7 of
/// the largest eigenvalue once rounded), so [`Fem::exact_work`] keeps `f64`.
#[derive(Debug)]
enum ElementBlocks {
    Single(Vec<f32>),
    Double(Vec<f64>),
}

impl Fem {
    /// Tetrahedra.
    pub fn tets(&self) -> &[[u32; 4]] {
        &self.tets
    }

    /// Rest volume of each element (m^3).
    pub fn volumes(&self) -> &[f64] {
        &self.volume
    }

    /// The consistent mass matrix (see [`FemMass::Consistent`]), assembled over the
    /// stiffness pattern through the deterministic element gather; its row sums are the
    /// lumped masses.
    pub fn consistent_mass_matrix(&self) -> Result<Bsr3, SparseError> {
        let asm = ElementAssembly::new(self.n, &self.tets, LocalLayout::symmetric(4))?;
        let mut blocks = vec![0.0; asm.block_buffer_len()];
        for (e, b) in blocks.chunks_exact_mut(TET_K).enumerate() {
            let rho = self.material_of(e).density;
            let m = rho * self.volume[e] / 20.0;
            // Blocks (a, b), a <= b, in the symmetric layout's order.
            let mut k = 0;
            for a in 0..4 {
                for bb in a..4 {
                    let v = if a == bb { 2.0 * m } else { m };
                    for c in 0..3 {
                        b[9 * k + 4 * c] = v;
                    }
                    k += 1;
                }
            }
        }
        let mut m = Bsr3::zeros(asm.pattern().clone());
        asm.gather_blocks(&blocks, &mut m);
        Ok(m)
    }

    /// The materials (one per region).
    pub fn materials(&self) -> &[FemMaterial] {
        &self.materials
    }

    /// The constitutive model every region shares.
    pub fn model(&self) -> Material {
        self.model
    }

    /// Element e's material.
    pub fn material_of(&self, e: usize) -> &FemMaterial {
        &self.materials[self.element_material.get(e).map_or(0, |&r| r as usize)]
    }

    /// Element e's Lamé parameters.
    pub fn lame_of(&self, e: usize) -> Lame {
        Lame {
            mu: self.lame[0][e],
            lambda: self.lame[1][e],
        }
    }

    /// Nodes no element uses (held fixed, massless).
    pub fn unused_nodes(&self) -> &[u32] {
        &self.unused
    }

    /// `Dm^-1` of element e.
    pub fn dm_inv(&self, e: usize) -> M3 {
        std::array::from_fn(|k| self.dm_inv[k][e])
    }

    /// The elements with positions x, as the wide kernels read them.
    pub fn elements<'a>(&'a self, x: &'a [f64]) -> Elements<'a> {
        let n = self.n;
        Elements {
            x: [&x[..n], &x[n..2 * n], &x[2 * n..3 * n]],
            tets: &self.tets,
            dm_inv: std::array::from_fn(|k| &self.dm_inv[k][..]),
            vol: &self.volume,
            mu: &self.lame[0],
            lambda: &self.lame[1],
        }
    }

    /// The deformation gradient of element e at positions x.
    pub fn deformation_gradient(&self, e: usize, x: &[f64]) -> M3 {
        largestep_kernels::fem::deformation_gradient(
            &gather_nodes(x, self.n, &self.tets[e]),
            &self.dm_inv(e),
        )
    }

    /// The first Piola-Kirchhoff stress of element e at positions x (Pa), as the forces
    /// see it (the invertible version's where the singular values are clamped).
    pub fn stress(&self, e: usize, x: &[f64]) -> M3 {
        self.stress_at(e, &self.deformation_gradient(e, x))
    }

    /// Element e's first Piola-Kirchhoff stress (Pa) at deformation gradient f.
    pub fn stress_at(&self, e: usize, f: &M3) -> M3 {
        match &self.iso {
            Some(iso) => largestep_kernels::fem_diag::evaluate(iso, self.lame_of(e), f).1,
            None => largestep_kernels::fem::pk1(self.model, self.lame_of(e), f),
        }
    }

    /// The smallest volume ratio `J = det F` of any element at positions x (negative when
    /// an element is inverted), and that element.
    pub fn min_volume_ratio(&self, x: &[f64]) -> (f64, usize) {
        (0..self.tets.len())
            .map(|e| {
                (
                    largestep_kernels::fem::det(&self.deformation_gradient(e, x)),
                    e,
                )
            })
            .fold((f64::INFINITY, 0), |a, b| if b.0 < a.0 { b } else { a })
    }

    /// The elastic energy (J) at positions x, without loads.
    pub fn elastic_energy(&self, x: &[f64]) -> f64 {
        // Summed in fixed chunks, then in order: the same bits for any thread count.
        let chunks: Vec<f64> = (0..self.tets.len().div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut f = [0.0; 12 * GROUP];
                let mut e = 0.0;
                for g in (c * CHUNK..((c + 1) * CHUNK).min(self.tets.len())).step_by(GROUP) {
                    let n = (self.tets.len() - g).min(GROUP);
                    e += self.group(g, n, x, &mut f[..12 * n], None)[..n]
                        .iter()
                        .sum::<f64>();
                }
                e
            })
            .collect();
        chunks.iter().sum()
    }

    fn body(&self) -> Body<'_> {
        Body {
            mass: &self.mass,
            triangles: &self.surface,
        }
    }

    /// Elements `e0..e0 + n` (n <= `GROUP`) at positions x: forces into f (12 per
    /// element, vertex-major), stiffness blocks into k (90 per element) when given; their
    /// energies (J) in the first n entries. `GROUP` elements of a nonlinear material go
    /// through the wide kernel (`element_group`), fewer by fours (`quad`).
    fn group(
        &self,
        e0: usize,
        n: usize,
        x: &[f64],
        f: &mut [f64],
        mut k: Option<&mut [f64]>,
    ) -> [f64; GROUP] {
        let mut energy = [0.0; GROUP];
        if let (Some(iso), GROUP) = (&self.iso, n) {
            let fg: &mut [f64; 12 * GROUP] = f.try_into().expect("12 forces per element");
            // Forces alone of the corotational material: the polar decomposition by
            // Newton instead of the SVD (`polar_group`), unless an element of the group
            // is flat, inverted or strained past it.
            // With the warped tangent, also the stiffness (`warped_group`).
            let mut kg: Option<&mut [f64; TET_K * GROUP]> =
                k.map(|k| k.try_into().expect("90 stiffness values per element"));
            let els = self.elements(x);
            if iso.material == Material::Corotational && iso.clamp.is_none() {
                let polar = match kg.as_deref_mut() {
                    None => polar_group(fg, &els, e0),
                    Some(kg) if iso.warped => warped_group(fg, kg, &els, e0),
                    Some(_) => None,
                };
                if let Some(e) = polar {
                    return e;
                }
            }
            return element_group(fg, kg, &els, e0, iso);
        }
        for q in (0..n).step_by(4) {
            let m = (n - q).min(4);
            let kq = k.as_mut().map(|k| &mut k[TET_K * q..TET_K * (q + m)]);
            let e = self.quad(e0 + q, m, x, &mut f[12 * q..12 * (q + m)], kq);
            energy[q..q + m].copy_from_slice(&e[..m]);
        }
        energy
    }

    /// [`Self::group`] for n <= 4 elements: four of a nonlinear material through the
    /// four-lane kernel, others one by one (the scalar twin; linear elasticity in the F
    /// form).
    fn quad(
        &self,
        e0: usize,
        n: usize,
        x: &[f64],
        f: &mut [f64],
        k: Option<&mut [f64]>,
    ) -> [f64; 4] {
        let xs = |e: usize| gather_nodes(x, self.n, &self.tets[e]);
        let mut energy = [0.0; 4];
        match &self.iso {
            Some(iso) if n == 4 => {
                let f4: &mut [f64; 48] = f.try_into().expect("12 forces per element");
                let k4: Option<&mut [f64; 360]> =
                    k.map(|k| k.try_into().expect("90 stiffness values per element"));
                energy = element_x4(f4, k4, &self.elements(x), e0, iso);
            }
            Some(iso) => {
                let mut k = k;
                for l in 0..n {
                    let e = e0 + l;
                    let mut fe = [[0.0; 3]; 4];
                    let lame = [self.lame[0][e], self.lame[1][e]];
                    let ke: Option<&mut [f64; 90]> = k
                        .as_mut()
                        .map(|k| (&mut k[90 * l..90 * l + 90]).try_into().expect("90 values"));
                    energy[l] = element(
                        &mut fe,
                        ke,
                        &xs(e),
                        &self.dm_inv(e),
                        self.volume[e],
                        lame,
                        iso,
                    );
                    f[12 * l..12 * l + 12].copy_from_slice(fe.as_flattened());
                }
            }
            None => {
                let mut kbuf = [0.0; TET_K];
                let mut k = k;
                for l in 0..n {
                    let e = e0 + l;
                    let (xe, dm, vol, lame) =
                        (xs(e), self.dm_inv(e), self.volume[e], self.lame_of(e));
                    let mut fe = [[0.0; 3]; 4];
                    let ke = match k.as_mut() {
                        Some(k) => &mut k[90 * l..90 * l + 90],
                        None => &mut kbuf[..],
                    };
                    element_stiffness(&mut fe, ke, self.model, lame, &xe, &dm, vol, false);
                    energy[l] = element_energy(self.model, lame, &xe, &dm, vol);
                    f[12 * l..12 * l + 12].copy_from_slice(fe.as_flattened());
                }
            }
        }
        energy
    }

    /// `scale dfdx_e v_e` for element e (`-scale K_e v_e`, the stiffness-damping force
    /// for `scale = beta`) from its stiffness blocks k (90 values).
    fn stiffness_times(&self, e: usize, k: &[f64], scale: f64, v: &[f64]) -> [[f64; 3]; 4] {
        let mut fe = [[0.0; 3]; 4];
        add_stiffness_damping(&mut fe, k, scale, &gather_nodes(v, self.n, &self.tets[e]));
        fe
    }

    /// Every element's forces (with stiffness damping) into `ef` (12 each) and its
    /// stiffness blocks into `kbuf` in the gather order of `asm`
    /// ([`ElementAssembly::par_write_ordered`]), stored through `store`; in fixed chunks.
    /// Each group (`GROUP` elements) is computed into `f64` scratch first, so the damping
    /// reads unrounded blocks.
    fn element_jacobians<T: Send>(
        &self,
        asm: &ElementAssembly,
        ef: &mut [f64],
        kbuf: &mut [T],
        x: &[f64],
        v: &[f64],
        store: impl Fn(f64) -> T + Sync,
    ) {
        let beta = self.rayleigh[1];
        asm.par_write_ordered(kbuf, ef, 12, |range, fo, sink| {
            let mut k = [0.0; GROUP * TET_K];
            for (g, fg) in fo.chunks_mut(12 * GROUP).enumerate() {
                let (e0, cnt) = (range.start + GROUP * g, fg.len() / 12);
                let k = &mut k[..TET_K * cnt];
                self.group(e0, cnt, x, fg, Some(k));
                if beta > 0.0 {
                    self.add_group_damping(e0, k, v, fg);
                }
                for (l, kl) in k.chunks_exact(TET_K).enumerate() {
                    sink.put(e0 + l, kl, &store);
                }
            }
        });
    }

    /// The forces into `f` and `scale df/dx + diag(d)` into `out` (see
    /// `ElementAssembly::gather_ordered_affine`): [`MechModel::force_jacobians`] with
    /// scale 1 and no diagonal, [`MechModel::force_system`] with an implicit step's.
    #[allow(clippy::too_many_arguments)]
    fn assemble(
        &self,
        work: &mut FemWork,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        out: &mut Bsr3,
        scale: f64,
        diag: Option<&[f64]>,
    ) -> Result<(), IntegrateError> {
        self.prepare_jacobians(work)
            .map_err(IntegrateError::Sparse)?;
        self.loads.forces(t, &self.body(), x, v, f);
        let FemWork { f: ef, blocks, asm } = work;
        let asm = asm.as_ref().expect("prepared above");
        match blocks {
            ElementBlocks::Single(kbuf) => {
                self.element_jacobians(asm, ef, kbuf, x, v, |k| k as f32);
                asm.gather_ordered_affine(kbuf, out, scale, diag);
            }
            ElementBlocks::Double(kbuf) => {
                self.element_jacobians(asm, ef, kbuf, x, v, |k| k);
                asm.gather_ordered_affine(kbuf, out, scale, diag);
            }
        }
        self.gather.gather_vectors_add(ef, f);
        self.add_mass_damping(v, f);
        Ok(())
    }

    /// Scratch for evaluations whose stiffness matrix must be exact (modal analysis,
    /// eigenvalue estimates): [`MechModel::work`] with the element blocks kept in `f64`
    /// (see `ElementBlocks` for why stepping rounds them).
    pub fn exact_work(&self) -> FemWork {
        FemWork {
            blocks: ElementBlocks::Double(Vec::new()),
            ..self.work()
        }
    }

    /// Adds the stiffness-damping forces `beta dfdx_e v_e` of elements `e0..` (their
    /// stiffness blocks in k, 90 each) to their element forces f (12 each).
    fn add_group_damping(&self, e0: usize, k: &[f64], v: &[f64], f: &mut [f64]) {
        let beta = self.rayleigh[1];
        for (l, fl) in f.chunks_exact_mut(12).enumerate() {
            let fd = self.stiffness_times(e0 + l, &k[TET_K * l..TET_K * (l + 1)], beta, v);
            for (o, d) in fl.iter_mut().zip(fd.as_flattened()) {
                *o += d;
            }
        }
    }

    /// Element forces into `out` (12 per element, element-major), in fixed chunks: the
    /// elastic ones, and with stiffness damping (`v` given, beta > 0) `beta K_e v_e`.
    fn element_forces_into(&self, out: &mut [f64], x: &[f64], v: Option<&[f64]>) {
        let beta = self.rayleigh[1];
        let damped = v.filter(|_| beta > 0.0);
        out.par_chunks_mut(12 * CHUNK)
            .enumerate()
            .for_each(|(c, o)| {
                let mut k = [0.0; GROUP * TET_K];
                for (g, og) in o.chunks_mut(12 * GROUP).enumerate() {
                    let (e0, n) = (c * CHUNK + GROUP * g, og.len() / 12);
                    match damped {
                        Some(v) => {
                            self.group(e0, n, x, og, Some(&mut k[..TET_K * n]));
                            self.add_group_damping(e0, &k, v, og);
                        }
                        None => {
                            self.group(e0, n, x, og, None);
                        }
                    }
                }
            });
    }

    /// `f -= alpha m_i v_i`: mass-proportional damping.
    fn add_mass_damping(&self, v: &[f64], f: &mut [f64]) {
        let (alpha, n) = (self.rayleigh[0], self.n);
        if alpha > 0.0 {
            for c in 0..3 {
                for i in 0..n {
                    f[c * n + i] -= alpha * self.mass[i] * v[c * n + i];
                }
            }
        }
    }
}

impl MechModel for Fem {
    type Work = FemWork;

    fn work(&self) -> FemWork {
        FemWork {
            f: vec![0.0; self.gather.vector_buffer_len()],
            blocks: ElementBlocks::Single(Vec::new()),
            asm: None,
        }
    }

    fn force_rounding(&self) -> f64 {
        self.force_rounding
    }

    fn vertex_count(&self) -> usize {
        self.n
    }

    fn mass(&self) -> &[f64] {
        &self.mass
    }

    fn force(&self, work: &mut FemWork, t: f64, x: &[f64], v: &[f64], f: &mut [f64]) {
        self.loads.forces(t, &self.body(), x, v, f);
        self.element_forces_into(&mut work.f, x, Some(v));
        self.gather.gather_vectors_add(&work.f, f);
        self.add_mass_damping(v, f);
    }

    fn potential_energy(&self, _t: f64, x: &[f64]) -> Option<f64> {
        Some(self.elastic_energy(x) + self.loads.potential(&self.body(), x))
    }

    fn prepare_jacobians(
        &self,
        work: &mut FemWork,
    ) -> Result<Option<Arc<Bsr3Pattern>>, SparseError> {
        if work.asm.is_none() {
            let asm =
                ElementAssembly::new(self.n, &self.tets, LocalLayout::symmetric(4))?.with_ordered();
            let len = asm.ordered_buffer_len();
            match &mut work.blocks {
                ElementBlocks::Single(b) => b.resize(len, 0.0),
                ElementBlocks::Double(b) => b.resize(len, 0.0),
            }
            work.asm = Some(asm);
        }
        Ok(work.asm.as_ref().map(|a| a.pattern().clone()))
    }

    fn force_jacobians(
        &self,
        work: &mut FemWork,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        dfdx: &mut Bsr3,
        dfdv: Option<&mut Bsr3>,
    ) -> Result<(), IntegrateError> {
        self.assemble(work, t, x, v, f, dfdx, 1.0, None)?;
        let beta = self.rayleigh[1];
        // df/dv of the damping force -(alpha M + beta K) v, K = -df_el/dx: beta dfdx -
        // alpha M (its dependence on x through K is left out, as usual for Rayleigh
        // damping).
        if let Some(d) = dfdv {
            d.assign_lincomb(&[(beta, dfdx)]);
            d.add_scaled_diagonal(-self.rayleigh[0], &self.mass);
        }
        Ok(())
    }

    fn force_system(
        &self,
        work: &mut FemWork,
        t: f64,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        a: &mut Bsr3,
        ck: f64,
        d: &[f64],
    ) -> Result<bool, IntegrateError> {
        if self.has_velocity_jacobian() || self.mass_matrix.is_some() {
            return Ok(false);
        }
        self.assemble(work, t, x, v, f, a, -ck, Some(d))?;
        Ok(true)
    }

    fn has_velocity_jacobian(&self) -> bool {
        self.rayleigh.iter().any(|&c| c > 0.0)
    }

    fn dissipation(&self, x: &[f64], v: &[f64]) -> f64 {
        // Psi = 1/2 v^T (alpha M + beta K) v, so that -dPsi/dv is the damping force.
        let (alpha, beta, n) = (self.rayleigh[0], self.rayleigh[1], self.n);
        let mut psi = alpha * kinetic_energy(&self.mass, v);
        if beta > 0.0 {
            let (mut k, mut f) = ([0.0; GROUP * TET_K], [0.0; 12 * GROUP]);
            for e0 in (0..self.tets.len()).step_by(GROUP) {
                let cnt = (self.tets.len() - e0).min(GROUP);
                self.group(e0, cnt, x, &mut f[..12 * cnt], Some(&mut k[..TET_K * cnt]));
                for l in 0..cnt {
                    let ve = gather_nodes(v, n, &self.tets[e0 + l]);
                    let fd = self.stiffness_times(e0 + l, &k[TET_K * l..TET_K * (l + 1)], 1.0, v);
                    // fd = dfdx_e v_e = -K_e v_e: Psi_e = -1/2 v_e . fd.
                    psi -= 0.5
                        * beta
                        * (0..4)
                            .map(|a| (0..3).map(|c| ve[a][c] * fd[a][c]).sum::<f64>())
                            .sum::<f64>();
                }
            }
        }
        psi
    }

    fn obstacles(&self) -> &[Obstacle] {
        &self.obstacles
    }

    fn contact_friction(&self) -> Option<f64> {
        (!self.obstacles.is_empty()).then_some(self.friction)
    }

    fn fixed_vertices(&self) -> &[u32] {
        &self.fixed
    }

    fn mass_matrix(&self) -> Option<&Bsr3> {
        self.mass_matrix.as_ref()
    }

    fn does_external_work(&self) -> bool {
        !self.paths.is_empty()
    }

    /// The power (W) the prescribed paths put in: minus the elastic, gravity and
    /// mass-damping forces on the path vertices dotted with their velocities (the
    /// clamp's reaction; the path vertices' own inertia, which matters only where the
    /// path's velocity jumps at a keyframe, and stiffness damping are left out).
    fn external_power(&self, _t: f64, x: &[f64], v: &[f64]) -> f64 {
        let n = self.n;
        let g = self.loads.gravity.0;
        let mut p = 0.0;
        let mut f = [0.0; 12];
        for &e in &self.path_elements {
            let e = e as usize;
            self.group(e, 1, x, &mut f, None);
            for (a, &i) in self.tets[e].iter().enumerate() {
                let i = i as usize;
                if self.on_path[i] {
                    p -= (0..3).map(|c| f[3 * a + c] * v[c * n + i]).sum::<f64>();
                }
            }
        }
        for i in (0..n).filter(|&i| self.on_path[i]) {
            let vv: f64 = (0..3).map(|c| v[c * n + i] * v[c * n + i]).sum();
            let gv: f64 = (0..3).map(|c| g[c] * v[c * n + i]).sum();
            p += self.mass[i] * (self.rayleigh[0] * vv - gv);
        }
        p
    }

    fn prescribe(&self, t: f64, x: &mut [f64], v: &mut [f64]) {
        crate::simulation::path::prescribe(&self.paths, &self.path_rest, t, x, v);
    }

    fn stages(&self) -> Vec<Stage> {
        let m = &self.materials[0];
        let mut stages = vec![Stage::built(
            "tetrahedral elements",
            format!(
                "{} vertices, {} tetrahedra, {:?}, E = {} Pa, nu = {}{}",
                self.n,
                self.tets.len(),
                self.model,
                m.young,
                m.poisson,
                match self.materials.len() {
                    1 => String::new(),
                    r => format!(" and {} more regions", r - 1),
                }
            ),
        )];
        if let Some(c) = self.iso.and_then(|i| i.clamp) {
            stages.push(Stage::built(
                "invertible material",
                format!("singular values of F clamped at {c}"),
            ));
        }
        if self.iso.is_some_and(|i| i.warped) {
            stages.push(Stage::built(
                "warped tangent",
                "each element's linear stiffness turned by its rotation, R K0 R^T",
            ));
        }
        stages.push(if self.definiteness_fix {
            Stage::built(
                "definiteness fix",
                "each element's tangent projected to semi-definite",
            )
        } else {
            Stage::left_out("definiteness fix", "definiteness_fix = false")
        });
        stages.push(if self.mass_matrix.is_some() {
            Stage::built(
                "consistent mass matrix",
                "rho V (1 + delta_ab) / 20 per element, in the implicit systems",
            )
        } else {
            Stage::left_out("consistent mass matrix", "lumped masses ([fem] mass)")
        });
        let [alpha, beta] = self.rayleigh;
        stages.push(if alpha > 0.0 || beta > 0.0 {
            Stage::built(
                "Rayleigh damping",
                format!("alpha = {alpha} 1/s (mass), beta = {beta} s (stiffness)"),
            )
        } else {
            Stage::left_out("Rayleigh damping", "no [fem.damping]")
        });
        stages.extend(self.loads.stages());
        stages.push(Stage::pinned(self.pinned));
        stages.push(if self.paths.is_empty() {
            Stage::left_out("prescribed paths", "no [[fem.path]]")
        } else {
            Stage::built("prescribed paths", format!("{} paths", self.paths.len()))
        });
        if !self.unused.is_empty() {
            stages.push(Stage::built(
                "unused nodes held fixed",
                format!("{} nodes in no element", self.unused.len()),
            ));
        }
        stages.push(Stage::obstacle_contacts(&self.obstacles));
        stages
    }

    fn triangles(&self) -> &[[u32; 3]] {
        &self.surface
    }

    fn has_volume(&self) -> bool {
        true
    }

    fn write_volume(
        &self,
        w: &mut dyn std::io::Write,
        comment: &str,
        x: &[f64],
        v: &[f64],
    ) -> std::io::Result<()> {
        self.write_vtk(w, comment, &self.rest, x, v)
    }

    fn warnings(&self) -> Vec<String> {
        let mut w = self.notes.clone();
        if let [first, ..] = self.unused.as_slice() {
            w.push(format!(
                "{} of {} nodes belong to no element (first: node {first}): they carry no mass and are held where they are",
                self.unused.len(),
                self.n,
            ));
        }
        w
    }
}
