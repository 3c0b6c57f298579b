//! The `[cloth]` scene table: a grid or an OBJ mesh, a material, pins, obstacles, wind,
//! paths and step-size control; its conversion to a [`ClothDesc`], and the mapping of the
//! cloth's validation errors to the keys they came from.
//!
//! ```toml
//! [cloth]
//! pinned = [0, 9]             # grid vertex (i, j) is i + nu j
//! friction = 0.3              # of contacts
//! [cloth.self_collision]      # the sheet does not pass through itself
//! thickness = 0.004           # gap kept between its layers (m)
//! [[cloth.sphere]]            # obstacles, wind, step control: see `scene::shared`
//! center = [0.0, 0.0, 0.0]
//! radius = 0.5
//! # [[cloth.path]] vertices = [0], times = [0.0, 1.0], offsets = [[0,0,0], [0.3,0,0]]
//! [cloth.grid]                # or [cloth.mesh] file = "sheet.obj" (with vt), uv_scale
//! nu = 10
//! nv = 10
//! size = [1.0, 1.0]           # rest (u, v) extent (m); origin, u_axis, v_axis optional
//! [cloth.material]
//! density = 0.2               # kg/m^2
//! stretch = 500.0             # shear, bend, *_damping optional
//! ```

use super::{cloth_grid, estimated_bytes, ClothDesc, ClothGridOptions, ClothMaterial, VertexPath};
use crate::scene::shared::{self, ObstacleTables};
use crate::scene::{path, Context, Key, PathPart, SceneError};
use crate::simulation::{MechSimulation, Simulation, StepControl};
use crate::validate::{ModelError, MAX_COORDINATE};
use serde::Deserialize;

/// `[cloth]`: a Baraff-Witkin sheet.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothTable {
    /// Pinned vertices (index `i + nu j` of grid vertex (i, j)).
    #[serde(default)]
    pub pinned: Vec<i64>,
    /// Project element stiffness matrices to keep implicit systems definite (default true).
    #[serde(default)]
    pub definiteness_fix: Option<bool>,
    /// Friction of contacts (default 0).
    #[serde(default)]
    pub friction: f64,
    /// `[[cloth.sphere]]` obstacles.
    #[serde(default)]
    pub sphere: Vec<shared::SphereTable>,
    /// `[[cloth.plane]]` obstacles.
    #[serde(default)]
    pub plane: Vec<shared::PlaneTable>,
    /// `[[cloth.box]]` obstacles.
    #[serde(default, rename = "box")]
    pub boxes: Vec<shared::BoxTable>,
    /// `[[cloth.capsule]]` obstacles.
    #[serde(default)]
    pub capsule: Vec<shared::CapsuleTable>,
    /// `[[cloth.sdf]]` obstacles (signed-distance grid files).
    #[serde(default)]
    pub sdf: Vec<shared::SdfTable>,
    /// `[cloth.wind]`
    #[serde(default)]
    pub wind: Option<shared::WindTable>,
    /// `[[cloth.path]]` vertices moved along prescribed paths.
    #[serde(default)]
    pub path: Vec<PathTable>,
    /// `[cloth.self_collision]`: the sheet does not pass through itself.
    #[serde(default)]
    pub self_collision: Option<SelfCollisionTable>,
    /// `[cloth.step_control]` (defaults apply when absent).
    #[serde(default)]
    pub step_control: Option<shared::StepControlTable>,
    /// `[cloth.grid]` (or `[cloth.mesh]`).
    #[serde(default)]
    pub grid: Option<ClothGridTable>,
    /// `[cloth.mesh]`: an OBJ triangle mesh with texture coordinates.
    #[serde(default)]
    pub mesh: Option<ClothMeshTable>,
    /// `[cloth.material]`
    pub material: ClothMaterialTable,
}

/// `[cloth.self_collision]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SelfCollisionTable {
    /// The gap kept between the sheet's layers (m, > 0; default 0.004).
    #[serde(default)]
    pub thickness: Option<f64>,
}

/// `[cloth.grid]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothGridTable {
    /// Vertices along u (>= 2).
    pub nu: i64,
    /// Vertices along v (>= 2).
    pub nv: i64,
    /// Extent along u and v (m); the rest (u, v).
    pub size: [f64; 2],
    /// Position of vertex (0, 0) (m).
    #[serde(default)]
    pub origin: Option<[f64; 3]>,
    /// Direction of u (default +x).
    #[serde(default)]
    pub u_axis: Option<[f64; 3]>,
    /// Direction of v (default +z).
    #[serde(default)]
    pub v_axis: Option<[f64; 3]>,
}

/// `[cloth.mesh]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothMeshTable {
    /// OBJ file with texture coordinates (relative to the scene file).
    pub file: String,
    /// Metres per texture unit: rest (u, v) = scale * (vt) (default 1).
    #[serde(default)]
    pub uv_scale: Option<f64>,
    /// Multiplies the positions (default 1).
    #[serde(default)]
    pub scale: Option<f64>,
    /// Added to the positions after scaling (m, default 0).
    #[serde(default)]
    pub offset: Option<[f64; 3]>,
}

/// `[cloth.material]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothMaterialTable {
    /// Mass per unit area (kg/m^2).
    pub density: f64,
    /// Stretch stiffness (N/m).
    pub stretch: f64,
    /// Shear stiffness (N/m).
    #[serde(default)]
    pub shear: f64,
    /// Bend stiffness (N m); 0 leaves bending out.
    #[serde(default)]
    pub bend: f64,
    /// Stretch damping.
    #[serde(default)]
    pub stretch_damping: f64,
    /// Shear damping.
    #[serde(default)]
    pub shear_damping: f64,
    /// Bend damping.
    #[serde(default)]
    pub bend_damping: f64,
}

/// `[[cloth.path]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathTable {
    /// Vertices moved.
    pub vertices: Vec<i64>,
    /// Keyframe times (s).
    pub times: Vec<f64>,
    /// Offsets from the initial positions (m), one per time.
    pub offsets: Vec<[f64; 3]>,
}

/// Builds the cloth of a scene's `[cloth]` table (the registry's entry).
pub fn build(ctx: &Context<'_>) -> Result<Box<dyn Simulation>, SceneError> {
    let t: ClothTable = ctx.table()?;
    let desc = desc(ctx, &t)?;
    let (cloth, state) = desc
        .build()
        .map_err(|e| ctx.model_error(&e, &error_key(&e)))?;
    let sim = MechSimulation::new(cloth, state, ctx.settings)
        .map_err(|e| ctx.error_at(&path(&[&"scene", &"integrator"]), e.to_string()))?;
    Ok(Box::new(sim))
}

/// The cloth description of a `[cloth]` table; files are relative to the scene's folder.
pub fn desc(ctx: &Context<'_>, t: &ClothTable) -> Result<ClothDesc, SceneError> {
    let at = |f: &[&dyn PathPart]| path(f);
    let m = &t.material;
    let mat = |name: &str| at(&[&"material", &name]);
    let material = ClothMaterial {
        density: ctx.positive(m.density, &mat("density"), "density")?,
        stretch: ctx.non_negative(m.stretch, &mat("stretch"), "stiffness")?,
        shear: ctx.non_negative(m.shear, &mat("shear"), "stiffness")?,
        bend: ctx.non_negative(m.bend, &mat("bend"), "stiffness")?,
        stretch_damping: ctx.non_negative(m.stretch_damping, &mat("stretch_damping"), "damping")?,
        shear_damping: ctx.non_negative(m.shear_damping, &mat("shear_damping"), "damping")?,
        bend_damping: ctx.non_negative(m.bend_damping, &mat("bend_damping"), "damping")?,
        rest_stretch: [1.0, 1.0],
    };
    let mut desc = match (&t.grid, &t.mesh) {
        (Some(g), None) => {
            for (name, v) in [("nu", g.nu), ("nv", g.nv)] {
                if !(2..=4096).contains(&v) {
                    return Err(ctx.error(
                        &at(&[&"grid", &name]),
                        format!("a cloth grid needs 2..=4096 vertices per side, not {v}"),
                    ));
                }
            }
            for (i, &s) in g.size.iter().enumerate() {
                ctx.positive(s, &at(&[&"grid", &"size", &i]), "size")?;
            }
            let n = g.nu as f64 * g.nv as f64;
            ctx.memory(
                &at(&[&"grid"]),
                &format!("a {} x {} cloth", g.nu, g.nv),
                estimated_bytes(n, ctx.implicit(), ctx.cholesky(n)),
            )?;
            let desc = cloth_grid(&ClothGridOptions {
                nu: g.nu as usize,
                nv: g.nv as usize,
                size: g.size,
                origin: g.origin.unwrap_or([0.0; 3]),
                u_axis: g.u_axis.unwrap_or([1.0, 0.0, 0.0]),
                v_axis: g.v_axis.unwrap_or([0.0, 0.0, 1.0]),
                material,
            });
            if !desc.positions.iter().flatten().all(|v| v.is_finite()) {
                return Err(ctx.error(&at(&[&"grid"]), "origin and axes must be finite"));
            }
            desc
        }
        (None, Some(mt)) => {
            let file = ctx.base.join(&mt.file);
            let (mesh, uv) = crate::io::read_obj_uv(&file, ctx.limits.max_file_bytes)
                .map_err(|e| ctx.error(&at(&[&"mesh", &"file"]), e.to_string()))?;
            let uv_scale = ctx.positive(
                mt.uv_scale.unwrap_or(1.0),
                &at(&[&"mesh", &"uv_scale"]),
                "uv_scale",
            )?;
            let scale =
                ctx.positive(mt.scale.unwrap_or(1.0), &at(&[&"mesh", &"scale"]), "scale")?;
            let offset = mt.offset.unwrap_or([0.0; 3]);
            if !offset.iter().all(|c| c.is_finite()) {
                return Err(ctx.error(&at(&[&"mesh", &"offset"]), "must be finite"));
            }
            let nv = mesh.positions.len() / 3;
            ctx.memory(
                &at(&[&"mesh", &"file"]),
                &format!("a cloth of {nv} vertices"),
                estimated_bytes(nv as f64, ctx.implicit(), ctx.cholesky(nv as f64)),
            )?;
            // A vertex out of range is reported at its line in the OBJ file; one that the
            // scale or offset puts out of range, at that key.
            let in_range = |x: f64| x.abs() <= MAX_COORDINATE;
            if let Some(i) = (0..nv).find(|&i| {
                !largestep_kernels::get3(&mesh.positions, nv, i)
                    .iter()
                    .all(|&x| in_range(x))
            }) {
                let p = largestep_kernels::get3(&mesh.positions, nv, i);
                let line = crate::io::read_text(&file, ctx.limits.max_file_bytes)
                    .ok()
                    .and_then(|text| crate::io::obj_vertex_line(&text, i))
                    .map_or(String::new(), |l| format!(":{l}"));
                return Err(ctx.error(
                    &at(&[&"mesh", &"file"]),
                    format!(
                        "{}{line}: vertex {} at {p:?}: coordinates must be finite and within 1e15 m of the origin",
                        file.display(),
                        i + 1
                    ),
                ));
            }
            let positions: Vec<[f64; 3]> = (0..nv)
                .map(|i| {
                    let p = largestep_kernels::get3(&mesh.positions, nv, i);
                    std::array::from_fn(|c| scale * p[c] + offset[c])
                })
                .collect();
            if !positions.iter().flatten().all(|&x| in_range(x)) {
                let key = if offset.iter().all(|&c| in_range(c)) {
                    "scale"
                } else {
                    "offset"
                };
                return Err(ctx.error(
                    &at(&[&"mesh", &key]),
                    format!("puts vertices beyond 1e15 m from the origin (scale {scale}, offset {offset:?})"),
                ));
            }
            let largest_uv = uv.iter().flatten().fold(0.0f64, |m, t| m.max(t.abs()));
            if !in_range(uv_scale * largest_uv) {
                return Err(ctx.error(
                    &at(&[&"mesh", &"uv_scale"]),
                    format!(
                        "uv_scale = {uv_scale:e} makes rest (u, v) coordinates of {:e} m: they must stay within 1e15 m",
                        uv_scale * largest_uv
                    ),
                ));
            }
            let mut desc = cloth_grid(&ClothGridOptions {
                nu: 2,
                nv: 2,
                size: [1.0, 1.0],
                origin: [0.0; 3],
                u_axis: [1.0, 0.0, 0.0],
                v_axis: [0.0, 0.0, 1.0],
                material,
            });
            desc.positions = positions;
            desc.uv = uv
                .iter()
                .map(|t| [uv_scale * t[0], uv_scale * t[1]])
                .collect();
            desc.triangles = mesh.triangles.to_vec();
            desc.velocities = Vec::new();
            desc
        }
        _ => return Err(ctx.error(&[], "give exactly one of [cloth.grid] or [cloth.mesh]")),
    };
    let n = desc.positions.len();
    let vertex = |v: i64, p: Vec<Key>| -> Result<usize, SceneError> {
        let i = ctx.index(v, &p, "vertex")?;
        if i >= n {
            return Err(ctx.error(
                &p,
                format!("vertex {i} does not exist: the cloth has {n} vertices"),
            ));
        }
        Ok(i)
    };
    let mut pinned = Vec::with_capacity(t.pinned.len());
    for (k, &p) in t.pinned.iter().enumerate() {
        pinned.push(vertex(p, at(&[&"pinned", &k]))?);
    }
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
    desc.wind = t.wind.as_ref().map(|w| shared::wind(ctx, w)).transpose()?;
    for (k, pt) in t.path.iter().enumerate() {
        let mut vertices = Vec::with_capacity(pt.vertices.len());
        for (j, &v) in pt.vertices.iter().enumerate() {
            vertices.push(vertex(v, at(&[&"path", &k, &"vertices", &j]))?);
        }
        desc.paths.push(VertexPath::translation(
            vertices,
            pt.times.clone(),
            pt.offsets.clone(),
        ));
    }
    if let Some(sc) = &t.step_control {
        desc.step_control = shared::step_control(ctx, sc, StepControl::CLOTH)?;
    }
    desc.friction = ctx.non_negative(t.friction, &at(&[&"friction"]), "friction")?;
    desc.self_collision = t
        .self_collision
        .as_ref()
        .map(|s| s.thickness.unwrap_or(0.004));
    desc.gravity = ctx.gravity;
    desc.definiteness_fix = t.definiteness_fix.unwrap_or(true);
    Ok(desc)
}

/// The key below `[cloth]` a cloth validation error refers to: the key where the table
/// has it, else the table. Obstacles, wind and step control
/// are validated by their converters, before the cloth is built.
fn error_key(e: &ModelError) -> Vec<Key> {
    let ModelError::Value {
        item, index, field, ..
    } = e
    else {
        return Vec::new();
    };
    let key = field.split('.').next().unwrap_or(field);
    match *item {
        "path" => path(&[&"path", index, &key]),
        "material" if key == "friction" => path(&[&"friction"]),
        "self_collision" => path(&[&"self_collision", &key]),
        "material" if key != "rest_stretch" => path(&[&"material", &key]),
        "pinned" => path(&[&"pinned", index]),
        _ => Vec::new(),
    }
}
