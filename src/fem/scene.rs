//! The `[fem]` scene table: a tetrahedral mesh (a TetGen file pair or a generated box of
//! cubes), a material, Dirichlet vertices (by index, or every vertex inside a box or
//! behind a plane), obstacles and friction; its conversion to a [`FemDesc`], and the
//! mapping of the model's validation errors to the keys they came from. When `[solver]`
//! names no preconditioner, PCG (`linear = "pcg"`, or `"auto"` above 30,000 unknowns)
//! runs with smoothed aggregation, which suits elasticity, instead of block Jacobi.
//!
//! ```toml
//! [fem]
//! pinned = [0, 5]               # vertex indices
//! friction = 0.3                # of contacts
//! definiteness_fix = true       # project element tangents to semi-definite (default)
//! mass = "lumped"               # or "consistent" (implicit integrators)
//! initial_stretch = [1.0, 0.1, 1.0]  # start squashed to a tenth in y (rest shape kept)
//! [[fem.pin_box]]               # every vertex inside [min, max] (m) is held
//! min = [-0.01, -1.0, -1.0]
//! max = [0.01, 1.0, 1.0]
//! [[fem.pin_plane]]             # every vertex on or behind the plane (normal points out)
//! point = [0.0, 0.0, 0.0]
//! normal = [1.0, 0.0, 0.0]
//! [[fem.path]]                # prescribed motion of the vertices in [min, max] (or
//! min = [0.99, -1.0, -1.0]      # `vertices = [...]`): keyframes at `times`, each an
//! max = [1.01, 1.0, 1.0]        # offset (m, default 0) and, with `axis`, an angle (rad)
//! times = [0.0, 1.0]            # about the axis through `center` (default: the
//! angles = [0.0, 3.14159]       # selection's centroid)
//! axis = [1.0, 0.0, 0.0]
//! [[fem.plane]]                 # obstacles: sphere, plane, box, capsule, sdf (`scene::shared`)
//! point = [0.0, -0.5, 0.0]
//! normal = [0.0, 1.0, 0.0]
//! [fem.beam]                    # or [fem.mesh] file = "nut.node" (TetGen; .ele beside it)
//!                               #    or file = "beam.vtk" (legacy VTK, tets and hexes)
//!                               #    or file = "part.msh" (Gmsh 2.2 or 4.1, ASCII)
//!                               #    or file = "part.off" / "part.obj" with voxel = 0.05
//!                               #    (a closed surface, voxel-meshed with cubes of 0.05)
//!                               #    or file = "part.veg" (Vega; its materials and
//!                               #    regions, [fem.material] then gives only the model)
//! cells = [20, 2, 2]            #    scale, offset, reorient optional
//! size = [1.0, 0.1, 0.1]        # (m); origin optional
//! # [fem.damping]               # Rayleigh: C = mass M + stiffness K
//! # mass = 0.5                  # 1/s
//! # stiffness = 0.001            # s
//! # [fem.static]                # equilibrium instead of dynamics: step k applies load
//! # increments = 10             # increment k of `increments` (default 10)
//! # tolerance = 1e-8            # residual relative to the largest load on a vertex
//! [fem.material]
//! model = "corotational"        # linear, corotational, stvk, neo-hookean, stable-neo-hookean
//! preset = "rubber"             # steel, aluminium, rubber, soft-tissue; or give:
//! young = 1e6                   # Pa (overrides the preset's)
//! poisson = 0.45
//! density = 1100.0              # kg/m^3
//! # inversion_threshold = 0.3   # the invertible version: singular values of F clamped
//! # warped_tangent = true       # corotational: Newton's Jacobian R K0 R^T per element
//!                               # (stiffness warping; no SVD), forces exact
//! # [[fem.region]]              # elements whose centroid lies in [min, max] (m) take
//! # min = [0.5, -1.0, -1.0]     # these constants (the model is [fem.material]'s); later
//! # max = [1.0, 1.0, 1.0]       # regions win; preset, young, poisson, density as above
//! # preset = "steel"
//! ```

use super::mesh::{box_mesh, TetMesh};
use super::{FemDesc, FemMaterial, Material};
use crate::scene::shared::{self, ObstacleTables};
use crate::scene::{path, Context, Key, PathPart, SceneError};
use crate::simulation::path::{PathTurn, VertexPath};
use crate::simulation::{MechSimulation, Simulation};
use crate::validate::{ModelError, MAX_COORDINATE};
use serde::Deserialize;

/// `[fem]`: a tetrahedral solid.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FemTable {
    /// Pinned vertex indices.
    #[serde(default)]
    pub pinned: Vec<i64>,
    /// `[[fem.pin_box]]` selections.
    #[serde(default)]
    pub pin_box: Vec<PinBoxTable>,
    /// `[[fem.path]]`: prescribed motion.
    #[serde(default)]
    pub path: Vec<PathTable>,
    /// `[[fem.pin_plane]]` selections.
    #[serde(default)]
    pub pin_plane: Vec<PinPlaneTable>,
    /// Friction of contacts (default 0).
    #[serde(default)]
    pub friction: f64,
    /// Start from the rest shape stretched by these factors along x, y, z about its
    /// centre (default none: at rest); 0.1 squashes it to a tenth, a negative factor
    /// mirrors it (every element inverted).
    #[serde(default)]
    pub initial_stretch: Option<[f64; 3]>,
    /// `lumped` (default) or `consistent` mass.
    #[serde(default)]
    pub mass: Option<String>,
    /// Project each element's tangent to semi-definite (default true).
    #[serde(default)]
    pub definiteness_fix: Option<bool>,
    /// `[[fem.sphere]]` obstacles.
    #[serde(default)]
    pub sphere: Vec<shared::SphereTable>,
    /// `[[fem.plane]]` obstacles.
    #[serde(default)]
    pub plane: Vec<shared::PlaneTable>,
    /// `[[fem.box]]` obstacles.
    #[serde(default, rename = "box")]
    pub boxes: Vec<shared::BoxTable>,
    /// `[[fem.capsule]]` obstacles.
    #[serde(default)]
    pub capsule: Vec<shared::CapsuleTable>,
    /// `[[fem.sdf]]` obstacles.
    #[serde(default)]
    pub sdf: Vec<shared::SdfTable>,
    /// `[fem.beam]` (or `[fem.mesh]`).
    #[serde(default)]
    pub beam: Option<BeamTable>,
    /// `[fem.mesh]`: a TetGen mesh.
    #[serde(default)]
    pub mesh: Option<MeshTable>,
    /// `[fem.material]`
    pub material: MaterialTable,
    /// `[[fem.region]]`: elements with other constants.
    #[serde(default)]
    pub region: Vec<RegionTable>,
    /// `[fem.damping]`: Rayleigh damping.
    #[serde(default)]
    pub damping: Option<DampingTable>,
    /// `[fem.static]`: solve for equilibrium instead of stepping in time.
    #[serde(default, rename = "static")]
    pub statics: Option<StaticTable>,
}

/// `[fem.damping]`: Rayleigh damping `C = mass M + stiffness K`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DampingTable {
    /// Mass-proportional coefficient alpha (1/s, default 0).
    #[serde(default)]
    pub mass: f64,
    /// Stiffness-proportional coefficient beta (s, default 0).
    #[serde(default)]
    pub stiffness: f64,
}

/// `[fem.static]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StaticTable {
    /// Load increments, one per step (default 10).
    #[serde(default)]
    pub increments: Option<i64>,
    /// Residual to reach, relative to the largest load on a vertex (default 1e-8).
    #[serde(default)]
    pub tolerance: Option<f64>,
}

/// `[[fem.pin_box]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinBoxTable {
    /// Low corner (m).
    pub min: [f64; 3],
    /// High corner (m).
    pub max: [f64; 3],
}

/// `[[fem.path]]`: vertices moved along a keyframed rigid path.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathTable {
    /// Vertex indices moved (or a box selection).
    #[serde(default)]
    pub vertices: Vec<i64>,
    /// Low corner of the selection (m).
    #[serde(default)]
    pub min: Option<[f64; 3]>,
    /// High corner of the selection (m).
    #[serde(default)]
    pub max: Option<[f64; 3]>,
    /// Keyframe times (s), increasing.
    pub times: Vec<f64>,
    /// Offsets at the keyframes (m); default zero.
    #[serde(default)]
    pub offsets: Option<Vec<[f64; 3]>>,
    /// Angles at the keyframes (rad) about `axis`.
    #[serde(default)]
    pub angles: Option<Vec<f64>>,
    /// The rotation axis.
    #[serde(default)]
    pub axis: Option<[f64; 3]>,
    /// A point on the axis (m); default the selection's centroid.
    #[serde(default)]
    pub center: Option<[f64; 3]>,
}

/// `[[fem.pin_plane]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinPlaneTable {
    /// A point on the plane (m).
    pub point: [f64; 3],
    /// Its normal; vertices on the plane or behind it (against the normal) are held.
    pub normal: [f64; 3],
}

/// `[fem.beam]`: a box of cubes split into tetrahedra.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BeamTable {
    /// Cubes along x, y, z (each >= 1).
    pub cells: [i64; 3],
    /// Extent (m).
    pub size: [f64; 3],
    /// Low corner (m, default the origin).
    #[serde(default)]
    pub origin: Option<[f64; 3]>,
}

/// `[fem.mesh]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshTable {
    /// The mesh file, relative to the scene file: a TetGen `.node` (its `.ele` beside it)
    /// or a legacy VTK unstructured grid `.vtk` (tetrahedra and hexahedra), or a Gmsh
    /// `.msh` (ASCII 2.2 or 4.1), a Vega `.veg`, or a closed triangle surface (`.obj`,
    /// `.off`) meshed by the voxel mesher with cubes of side `voxel`.
    pub file: String,
    /// The voxel mesher's cube size (the file's units) for a surface file.
    #[serde(default)]
    pub voxel: Option<f64>,
    /// Multiplies the positions (default 1).
    #[serde(default)]
    pub scale: Option<f64>,
    /// Added after scaling (m, default 0).
    #[serde(default)]
    pub offset: Option<[f64; 3]>,
    /// Swap two vertices of every inverted element (default false: they are errors).
    #[serde(default)]
    pub reorient: bool,
}

/// `[fem.material]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialTable {
    /// The constitutive model.
    pub model: String,
    /// Published constants to start from.
    #[serde(default)]
    pub preset: Option<String>,
    /// Young's modulus (Pa).
    #[serde(default)]
    pub young: Option<f64>,
    /// Poisson's ratio.
    #[serde(default)]
    pub poisson: Option<f64>,
    /// Density (kg/m^3).
    #[serde(default)]
    pub density: Option<f64>,
    /// The invertible version's clamp of the singular values of F, in (0, 1).
    #[serde(default)]
    pub inversion_threshold: Option<f64>,
    /// The corotational material's warped tangent `R K0 R^T` instead of the exact one
    /// ([`FemDesc::warped_tangent`]; default false).
    #[serde(default)]
    pub warped_tangent: Option<bool>,
}

/// `[[fem.region]]`: the elements whose centroid lies in `[min, max]` take these
/// constants.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionTable {
    /// Lower corner (m).
    pub min: [f64; 3],
    /// Upper corner (m).
    pub max: [f64; 3],
    /// Published constants to start from.
    #[serde(default)]
    pub preset: Option<String>,
    /// Young's modulus (Pa).
    #[serde(default)]
    pub young: Option<f64>,
    /// Poisson's ratio.
    #[serde(default)]
    pub poisson: Option<f64>,
    /// Density (kg/m^3).
    #[serde(default)]
    pub density: Option<f64>,
}

const MODELS: [(&str, Material); 5] = [
    ("linear", Material::Linear),
    ("corotational", Material::Corotational),
    ("stvk", Material::StVenantKirchhoff),
    ("neo-hookean", Material::NeoHookean),
    ("stable-neo-hookean", Material::StableNeoHookean),
];

/// A preset's constructor.
type Preset = fn(Material) -> FemMaterial;

const PRESETS: [(&str, Preset); 4] = [
    ("steel", FemMaterial::steel),
    ("aluminium", FemMaterial::aluminium),
    ("rubber", FemMaterial::rubber),
    ("soft-tissue", FemMaterial::soft_tissue),
];

/// The memory (bytes) a model of `vertices` vertices is estimated to need: state,
/// elements (about five per vertex) and scratch; with an implicit integrator the
/// matrices, and with Cholesky its factor, whose fill-in grows faster than the vertices
/// in 3-D (about 15 nonzero blocks per row for a 20 x 4 x 4 beam, up to hundreds for a
/// cube of 30^3): rounded up from those.
pub fn estimated_bytes(vertices: f64, implicit: bool, cholesky: bool) -> f64 {
    let per_vertex = match (implicit, cholesky) {
        (false, _) => 2_000.0,
        (true, false) => 12_000.0,
        (true, true) => 60_000.0,
    };
    vertices * per_vertex
}

/// Builds the solid of a scene's `[fem]` table (the registry's entry).
pub fn build(ctx: &Context<'_>) -> Result<Box<dyn Simulation>, SceneError> {
    let t: FemTable = ctx.table()?;
    let desc = desc(ctx, &t)?;
    let mesh_key = if t.beam.is_some() { "beam" } else { "mesh" };
    let (model, state) = desc
        .build()
        .map_err(|e| ctx.model_error(&e, &error_key(&e, mesh_key)))?;
    if let Some(st) = &t.statics {
        let at = |k: &str| path(&[&"static", &k]);
        if !desc.obstacles.is_empty() {
            return Err(ctx.error(&path(&[&"static"]), "static solves do not handle obstacle contact yet: remove the obstacles or [fem.static]"));
        }
        let increments = st.increments.unwrap_or(10);
        if !(1..=100_000).contains(&increments) {
            return Err(ctx.error(
                &at("increments"),
                format!("1..=100000 load increments, not {increments}"),
            ));
        }
        let tolerance =
            ctx.positive(st.tolerance.unwrap_or(1e-8), &at("tolerance"), "tolerance")?;
        let sim = super::StaticSimulation::new(
            model,
            state.x.as_slice().to_vec(),
            increments as usize,
            tolerance,
        )
        .map_err(|e| ctx.error(&path(&[&"static"]), e.to_string()))?;
        return Ok(Box::new(sim));
    }
    let mut settings = ctx.settings;
    if !ctx.preconditioner_given {
        super::elasticity_preconditioner(&mut settings);
    }
    let sim = MechSimulation::new(model, state, settings)
        .map_err(|e| ctx.error_at(&path(&[&"scene", &"integrator"]), e.to_string()))?;
    Ok(Box::new(sim))
}

/// The tetrahedral mesh of a `beam` or `mesh` table below the domain's table (the FEM's,
/// and modal sound's): generated, read, or voxel-meshed from a closed surface, scaled
/// and offset; `bytes` estimates the memory of a model of that many vertices, checked
/// before anything large is made; notes of the voxel mesher go to `notes`.
pub fn mesh(
    ctx: &Context<'_>,
    beam: Option<&BeamTable>,
    mesh: Option<&MeshTable>,
    bytes: &dyn Fn(f64) -> f64,
    notes: &mut Vec<String>,
) -> Result<(TetMesh, Option<super::mesh::VegParts>), SceneError> {
    let at = |f: &[&dyn PathPart]| path(f);
    let mut veg: Option<super::mesh::VegParts> = None;
    let mesh = match (beam, mesh) {
        (Some(b), None) => {
            let mut cells = [0usize; 3];
            for (c, &v) in b.cells.iter().enumerate() {
                if !(1..=1024).contains(&v) {
                    return Err(ctx.error(
                        &at(&[&"beam", &"cells", &c]),
                        format!("a beam needs 1..=1024 cubes along each axis, not {v}"),
                    ));
                }
                cells[c] = v as usize;
            }
            for (c, &s) in b.size.iter().enumerate() {
                ctx.positive(s, &at(&[&"beam", &"size", &c]), "size")?;
            }
            let origin = b.origin.unwrap_or([0.0; 3]);
            if !origin.iter().all(|c| c.abs() <= MAX_COORDINATE) {
                return Err(ctx.error(
                    &at(&[&"beam", &"origin"]),
                    "must be finite and within 1e15 m",
                ));
            }
            let vertices = cells.iter().map(|&c| c as f64 + 1.0).product::<f64>();
            ctx.memory(
                &at(&[&"beam", &"cells"]),
                &format!("a beam of {} x {} x {} cubes", cells[0], cells[1], cells[2]),
                bytes(vertices),
            )?;
            box_mesh(cells, b.size, origin)
        }
        (None, Some(m)) => {
            let file = ctx.base.join(&m.file);
            let read = if super::voxel::is_surface_file(&file) {
                let h = m.voxel.ok_or_else(|| {
                    ctx.error(
                        &at(&[&"mesh", &"file"]),
                        "a surface mesh needs `voxel`, the cube size of the voxel mesher",
                    )
                })?;
                let surface = super::voxel::read_surface(&file, ctx.limits.max_file_bytes)
                    .map_err(|e| ctx.error(&at(&[&"mesh", &"file"]), e.to_string()))?;
                let max_cells = (ctx.limits.max_memory / super::voxel::BYTES_PER_CUBE)
                    .min(u32::MAX as u64 / 8) as usize;
                let v = super::voxel::voxel_mesh(&surface, h, max_cells)
                    .map_err(|e| ctx.error(&at(&[&"mesh", &"voxel"]), e.to_string()))?;
                notes.extend(v.note());
                Ok(v.mesh)
            } else {
                super::mesh::read_volume_mesh(&file, ctx.limits.max_file_bytes).map(|(m, v)| {
                    veg = v;
                    m
                })
            };
            let TetMesh { positions, tets } =
                read.map_err(|e| ctx.error(&at(&[&"mesh", &"file"]), e.to_string()))?;
            ctx.memory(
                &at(&[&"mesh", &"file"]),
                &format!("a mesh of {} vertices", positions.len()),
                bytes(positions.len() as f64),
            )?;
            let scale = ctx.positive(m.scale.unwrap_or(1.0), &at(&[&"mesh", &"scale"]), "scale")?;
            let offset = m.offset.unwrap_or([0.0; 3]);
            if !offset.iter().all(|c| c.abs() <= MAX_COORDINATE) {
                return Err(ctx.error(
                    &at(&[&"mesh", &"offset"]),
                    "must be finite and within 1e15 m",
                ));
            }
            let positions: Vec<[f64; 3]> = positions
                .iter()
                .map(|p| std::array::from_fn(|c| scale * p[c] + offset[c]))
                .collect();
            if !positions
                .iter()
                .flatten()
                .all(|x| x.abs() <= MAX_COORDINATE)
            {
                return Err(ctx.error(
                    &at(&[&"mesh", &"scale"]),
                    format!("puts vertices beyond 1e15 m from the origin (scale {scale}, offset {offset:?})"),
                ));
            }
            TetMesh { positions, tets }
        }
        _ => return Err(ctx.error(&[], "give exactly one of the tables `beam` and `mesh`")),
    };
    Ok((mesh, veg))
}

/// The description of a `[fem]` table; files are relative to the scene's folder.
pub fn desc(ctx: &Context<'_>, t: &FemTable) -> Result<FemDesc, SceneError> {
    let at = |f: &[&dyn PathPart]| path(f);
    let m = &t.material;
    let kind = model(ctx, &m.model)?;
    // A .veg file's materials and regions.
    let mut notes = Vec::new();
    let bytes = |v: f64| estimated_bytes(v, ctx.implicit(), ctx.cholesky(v));
    let (mesh, veg) = mesh(ctx, t.beam.as_ref(), t.mesh.as_ref(), &bytes, &mut notes)?;
    let material = match &veg {
        None => constants(
            ctx,
            kind,
            [m.young, m.poisson, m.density],
            &m.preset,
            &[&"material"],
        )?,
        Some(_) if m.preset.is_some() || m.young.is_some() || m.poisson.is_some() || m.density.is_some() => {
            return Err(ctx.error(
                &at(&[&"material"]),
                "the .veg file gives the materials: [fem.material] gives only the model (and inversion_threshold)",
            ))
        }
        Some((mats, _)) => FemMaterial {
            model: kind,
            young: mats[0].young,
            poisson: mats[0].poisson,
            density: mats[0].density,
        },
    };
    let n = mesh.positions.len();
    let mut desc = FemDesc::new(mesh.positions, mesh.tets, material);
    if let Some(parts) = veg {
        desc.use_veg_materials(kind, parts);
    }
    desc.inversion_threshold = m.inversion_threshold;
    desc.warped_tangent = m.warped_tangent.unwrap_or(false);
    desc.notes = notes;
    for (k, r) in t.region.iter().enumerate() {
        let key = at(&[&"region", &k]);
        if !r.min.iter().chain(&r.max).all(|c| c.is_finite()) {
            return Err(ctx.error(&key, "min and max must be finite"));
        }
        let c = constants(
            ctx,
            material.model,
            [r.young, r.poisson, r.density],
            &r.preset,
            &[&"region", &k],
        )?;
        if desc.element_material.is_empty() {
            desc.element_material = vec![0; desc.tets.len()];
        }
        let id = desc.materials.len() as u32;
        let mut any = false;
        for (e, tet) in desc.tets.iter().enumerate() {
            let centroid: [f64; 3] = std::array::from_fn(|c| {
                tet.iter()
                    .map(|&i| desc.positions.get(i as usize).map_or(f64::NAN, |p| p[c]))
                    .sum::<f64>()
                    / 4.0
            });
            if (0..3).all(|c| centroid[c] >= r.min[c] && centroid[c] <= r.max[c]) {
                desc.element_material[e] = id;
                any = true;
            }
        }
        if !any {
            return Err(ctx.error(&key, "selects no element (by centroid)"));
        }
        desc.materials.push(c);
    }
    if t.mesh.as_ref().is_some_and(|m| m.reorient) {
        desc.reorient();
    }
    let mut pinned = Vec::new();
    for (k, &p) in t.pinned.iter().enumerate() {
        let key = at(&[&"pinned", &k]);
        let i = ctx.index(p, &key, "vertex")?;
        if i >= n {
            return Err(ctx.error(
                &key,
                format!("vertex {i} does not exist: the mesh has {n} vertices"),
            ));
        }
        pinned.push(i);
    }
    for (k, b) in t.pin_box.iter().enumerate() {
        let key = at(&[&"pin_box", &k]);
        if !b.min.iter().chain(&b.max).all(|c| c.is_finite()) {
            return Err(ctx.error(&key, "min and max must be finite"));
        }
        let inside = |p: &[f64; 3]| (0..3).all(|c| p[c] >= b.min[c] && p[c] <= b.max[c]);
        let before = pinned.len();
        pinned.extend((0..n).filter(|&i| inside(&desc.positions[i])));
        if pinned.len() == before {
            return Err(ctx.error(&key, "selects no vertex"));
        }
    }
    for (k, p) in t.path.iter().enumerate() {
        let key = at(&[&"path", &k]);
        let mut vertices = Vec::new();
        for (j, &v) in p.vertices.iter().enumerate() {
            let kv = at(&[&"path", &k, &"vertices", &j]);
            let i = ctx.index(v, &kv, "vertex")?;
            if i >= n {
                return Err(ctx.error(
                    &kv,
                    format!("vertex {i} does not exist: the mesh has {n} vertices"),
                ));
            }
            vertices.push(i);
        }
        match (p.min, p.max) {
            (Some(lo), Some(hi)) => {
                if !lo.iter().chain(&hi).all(|c| c.is_finite()) {
                    return Err(ctx.error(&key, "min and max must be finite"));
                }
                let inside = |q: &[f64; 3]| (0..3).all(|c| q[c] >= lo[c] && q[c] <= hi[c]);
                vertices.extend((0..n).filter(|&i| inside(&desc.positions[i])));
            }
            (None, None) => {}
            _ => return Err(ctx.error(&key, "give both min and max, or neither")),
        }
        if vertices.is_empty() {
            return Err(ctx.error(&key, "selects no vertex"));
        }
        let turn = match (&p.angles, p.axis) {
            (Some(angles), Some(axis)) => Some(PathTurn {
                center: p.center.unwrap_or_else(|| {
                    let m = vertices.len() as f64;
                    std::array::from_fn(|c| {
                        vertices.iter().map(|&i| desc.positions[i][c]).sum::<f64>() / m
                    })
                }),
                axis,
                angles: angles.clone(),
            }),
            (None, None) => None,
            _ => return Err(ctx.error(&key, "give both angles and axis, or neither")),
        };
        desc.paths.push(VertexPath {
            vertices,
            offsets: p
                .offsets
                .clone()
                .unwrap_or_else(|| vec![[0.0; 3]; p.times.len()]),
            times: p.times.clone(),
            turn,
        });
    }
    for (k, p) in t.pin_plane.iter().enumerate() {
        let key = at(&[&"pin_plane", &k]);
        let len = p.normal.iter().map(|c| c * c).sum::<f64>().sqrt();
        if !(len.is_finite() && len > 0.0 && p.point.iter().all(|c| c.is_finite())) {
            return Err(ctx.error(&key, "point must be finite and normal finite and non-zero"));
        }
        // On the plane within a millionth of the mesh's size counts as on it.
        let size = desc
            .positions
            .iter()
            .flatten()
            .fold(0.0f64, |m, c| m.max(c.abs()))
            .max(1e-300);
        let behind = |x: &[f64; 3]| {
            (0..3)
                .map(|c| (x[c] - p.point[c]) * p.normal[c] / len)
                .sum::<f64>()
                <= 1e-6 * size
        };
        let before = pinned.len();
        pinned.extend((0..n).filter(|&i| behind(&desc.positions[i])));
        if pinned.len() == before {
            return Err(ctx.error(&key, "selects no vertex"));
        }
    }
    pinned.sort_unstable();
    pinned.dedup();
    desc.pinned = pinned;
    desc.obstacles = shared::obstacles(
        ctx,
        ObstacleTables {
            sphere: &t.sphere,
            plane: &t.plane,
            boxes: &t.boxes,
            capsule: &t.capsule,
            sdf: &t.sdf,
        },
    )?;
    desc.friction = ctx.non_negative(t.friction, &at(&[&"friction"]), "friction")?;
    if let Some(s) = t.initial_stretch {
        if !s.iter().all(|c| c.is_finite() && c.abs() <= 1e3) {
            return Err(ctx.error(
                &at(&[&"initial_stretch"]),
                "factors must be finite, within -1000 to 1000",
            ));
        }
        let nf = n.max(1) as f64;
        let centre: [f64; 3] =
            std::array::from_fn(|c| desc.positions.iter().map(|p| p[c]).sum::<f64>() / nf);
        desc.initial = desc
            .positions
            .iter()
            .map(|p| std::array::from_fn(|c| centre[c] + s[c] * (p[c] - centre[c])))
            .collect();
    }
    if let Some(d) = &t.damping {
        desc.rayleigh = [
            ctx.non_negative(d.mass, &at(&[&"damping", &"mass"]), "mass damping")?,
            ctx.non_negative(
                d.stiffness,
                &at(&[&"damping", &"stiffness"]),
                "stiffness damping",
            )?,
        ];
    }
    desc.gravity = ctx.gravity;
    desc.definiteness_fix = t.definiteness_fix.unwrap_or(true);
    desc.mass = match &t.mass {
        None => super::FemMass::Lumped,
        Some(m) => m.parse().map_err(|e| ctx.error(&at(&[&"mass"]), e))?,
    };
    Ok(desc)
}

fn model(ctx: &Context<'_>, name: &str) -> Result<Material, SceneError> {
    MODELS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|&(_, model)| model)
        .ok_or_else(|| {
            let names: Vec<&str> = MODELS.iter().map(|(n, _)| *n).collect();
            ctx.error(
                &path(&[&"material", &"model"]),
                format!(
                    "unknown material model `{name}`; one of: {}",
                    names.join(", ")
                ),
            )
        })
}

/// A material of `model` from a preset and `[young, poisson, density]` (each overriding
/// the preset's), for the table at `table`.
fn constants(
    ctx: &Context<'_>,
    model: Material,
    given: [Option<f64>; 3],
    preset: &Option<String>,
    table: &[&dyn PathPart],
) -> Result<FemMaterial, SceneError> {
    let at = |f: &str| {
        let mut p = path(table);
        p.extend(path(&[&f]));
        p
    };
    let base = match preset {
        Some(p) => {
            let make = PRESETS
                .iter()
                .find(|(name, _)| name == p)
                .map(|&(_, f)| f)
                .ok_or_else(|| {
                    let names: Vec<&str> = PRESETS.iter().map(|(n, _)| *n).collect();
                    ctx.error(
                        &at("preset"),
                        format!("unknown preset `{p}`; one of: {}", names.join(", ")),
                    )
                })?;
            Some(make(model))
        }
        None => None,
    };
    let value = |v: Option<f64>, preset: Option<f64>, key: &str| {
        v.or(preset)
            .ok_or_else(|| ctx.error(&at(key), format!("give {key} or a preset")))
    };
    Ok(FemMaterial {
        model,
        young: value(given[0], base.map(|b| b.young), "young")?,
        poisson: value(given[1], base.map(|b| b.poisson), "poisson")?,
        density: value(given[2], base.map(|b| b.density), "density")?,
    })
}

/// The key below `[fem]` a validation error refers to.
fn error_key(e: &ModelError, mesh: &str) -> Vec<Key> {
    match e {
        ModelError::Value {
            item: "material",
            index: 0,
            field,
            ..
        } => path(&[&"material", field]),
        ModelError::Value {
            item: "material",
            index,
            field,
            ..
        } => path(&[&"region", &(index - 1), field]),
        ModelError::Value {
            item: "contact", ..
        } => path(&[&"friction"]),
        ModelError::Value {
            item: "path",
            index,
            field,
            ..
        } => path(&[&"path", index, field]),
        ModelError::Element { .. }
        | ModelError::Missing {
            item: "tetrahedron",
            ..
        } => path(&[&mesh]),
        _ => Vec::new(),
    }
}
