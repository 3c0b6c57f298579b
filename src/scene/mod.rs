//! Scenes: TOML files naming a system, an integrator and outputs.
//!
//! [`Scene::parse`] reads and validates a scene and builds its model, so every problem is
//! reported before anything runs, as `file:line:column: field: message` followed by the
//! offending line. Syntax and type errors come from toml's spans; range errors (NaN,
//! negative mass, dt <= 0, springs naming missing particles) are found by the model's own
//! validation and located by walking the span-preserving document along the field's path.
//!
//! [`Simulation`] holds what a scene needs and nothing more (see [`Stage`]); [`Runner`]
//! steps it frame by frame, writing frames and an energy log.

mod build;
mod run;
pub mod schema;

pub use build::{Simulation, Stage};
pub use run::{FrameFormat, FrameRecord, Output, Progress, RunError, Runner, Summary};

use crate::integrate::{LinearSolverKind, MechSettings, Method};
use crate::mass_spring::world::World;
use crate::mass_spring::{self as ms, MassSpringDesc, ModelError, SpringDesc};
use crate::render::preview::PreviewSettings;
use crate::render::{
    Camera, CameraSpec, DEFAULT_AZIMUTH_DEG, DEFAULT_ELEVATION_DEG, DEFAULT_FOV_DEG,
};
use crate::solve::{PcgParams, Preconditioner};
use std::fmt;
use std::path::Path;

/// A located scene error.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    /// File name as given.
    pub file: String,
    /// 1-based line (0 if unknown).
    pub line: usize,
    /// 1-based column (0 if unknown).
    pub column: usize,
    /// Dotted field path (`mass_spring.spring[3].a`), empty for syntax errors.
    pub field: String,
    /// What is wrong and what is expected.
    pub message: String,
    /// The source line, if known.
    pub snippet: Option<String>,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if self.line > 0 {
            write!(f, ":{}:{}", self.line, self.column)?;
        }
        if self.field.is_empty() {
            write!(f, ": {}", self.message)?;
        } else {
            write!(f, ": {}: {}", self.field, self.message)?;
        }
        if let Some(s) = &self.snippet {
            write!(f, "\n{:>5} | {}", self.line, s)?;
        }
        Ok(())
    }
}

impl std::error::Error for SceneError {}

impl SceneError {
    /// A malformed input file's error (file and line, no field).
    pub fn from_read(e: crate::io::ReadError) -> SceneError {
        SceneError {
            file: e.path,
            line: e.line,
            column: 0,
            field: String::new(),
            message: e.message,
            snippet: None,
        }
    }
}

/// A scene's default name: its file name without the extension, or `default`.
fn stem_name(file: &str, default: &str) -> String {
    Path::new(file)
        .file_stem()
        .map_or(default.into(), |x| x.to_string_lossy().into_owned())
}

/// Simulated time (s) of a run of a world file, which has no duration of its own.
pub const WORLD_DURATION: f64 = 5.0;

/// One step of a path into the TOML document.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Key {
    /// A table key.
    Field(String),
    /// An array index.
    Index(usize),
}

fn path(keys: &[&dyn PathPart]) -> Vec<Key> {
    keys.iter().map(|k| k.key()).collect()
}

trait PathPart {
    fn key(&self) -> Key;
}
impl PathPart for &str {
    fn key(&self) -> Key {
        Key::Field(self.to_string())
    }
}
impl PathPart for usize {
    fn key(&self) -> Key {
        Key::Index(*self)
    }
}

fn dotted(p: &[Key]) -> String {
    let mut s = String::new();
    for k in p {
        match k {
            Key::Field(f) => {
                if !s.is_empty() {
                    s.push('.');
                }
                s.push_str(f);
            }
            Key::Index(i) => s.push_str(&format!("[{i}]")),
        }
    }
    s
}

/// Line and column (1-based) of a byte offset.
fn line_col(src: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(src.len());
    let before = &src[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rfind('\n').map_or(offset, |p| offset - p - 1) + 1;
    (line, col)
}

/// The byte span of the value at `p` in the document, or of the deepest prefix found.
fn locate(src: &str, p: &[Key]) -> Option<std::ops::Range<usize>> {
    use toml::de::{DeTable, DeValue};
    let root = DeTable::parse(src).ok()?;
    let root_span = root.span();
    let root = DeValue::Table(root.into_inner());
    let mut cur: Option<&toml::Spanned<DeValue<'_>>> = None;
    let mut best = root_span;
    for k in p {
        let value = cur.map_or(&root, |c| c.get_ref());
        let next = match k {
            Key::Field(f) => value.get(f.as_str()),
            Key::Index(i) => value.get(*i),
        };
        match next {
            Some(n) => {
                best = n.span();
                cur = Some(n);
            }
            None => break,
        }
    }
    Some(best)
}

fn located(file: &str, src: &str, p: &[Key], message: String) -> SceneError {
    let span = locate(src, p);
    let (line, column) = span.map_or((0, 0), |s| line_col(src, s.start));
    SceneError {
        file: file.to_string(),
        line,
        column,
        field: dotted(p),
        message,
        snippet: (line > 0).then(|| src.lines().nth(line - 1).unwrap_or("").to_string()),
    }
}

/// A validated scene with its model built.
#[derive(Debug)]
pub struct Scene {
    /// File name.
    pub file: String,
    /// Scene name.
    pub name: String,
    /// Time step (s).
    pub dt: f64,
    /// Simulated time (s).
    pub duration: f64,
    /// Integrator and solver settings.
    pub settings: MechSettings,
    /// The system.
    pub system: System,
    /// Outputs.
    pub output: Output,
}

/// The systems a scene can hold.
#[derive(Debug)]
#[allow(clippy::large_enum_variant)] // one per scene
pub enum System {
    /// A mass-spring system.
    MassSpring(ms::MassSpring, ms::MassSpringState),
    /// A Baraff-Witkin cloth.
    Cloth(crate::cloth::Cloth, crate::cloth::ClothState),
}

impl Scene {
    /// Reads and validates a scene file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let file = path.display().to_string();
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("w"))
        {
            let world = World::read(path).map_err(SceneError::from_read)?;
            return Self::from_world(&world, &file);
        }
        let src = std::fs::read_to_string(path).map_err(|e| SceneError {
            file: file.clone(),
            line: 0,
            column: 0,
            field: String::new(),
            message: format!("cannot read the scene: {e}"),
            snippet: None,
        })?;
        Self::parse(&src, &file)
    }

    /// The scene of a jello world file: its integrator, dt, springs, plane and force
    /// field in the box `[-2, 2]^3`, run for [`WORLD_DURATION`] seconds with a frame every
    /// `max(n, 1/30 s)` steps (the file's display interval n, but not more than 30 frames
    /// per simulated second).
    pub fn from_world(world: &World, file: &str) -> Result<Scene, SceneError> {
        let (model, state) = world.to_desc().build().map_err(|e| SceneError {
            file: file.to_string(),
            line: 0,
            column: 0,
            field: String::new(),
            message: e.to_string(),
            snippet: None,
        })?;
        let every = world
            .every
            .max(((1.0 / 30.0) / world.dt).round() as usize)
            .max(1);
        Ok(Scene {
            file: file.to_string(),
            name: stem_name(file, "world"),
            dt: world.dt,
            duration: WORLD_DURATION,
            settings: MechSettings::new(world.method),
            system: System::MassSpring(model, state),
            output: Output {
                frames: FrameFormat::Obj,
                every,
                preview: PreviewSettings {
                    frame_interval: every as f64 * world.dt,
                    ..PreviewSettings::default()
                },
            },
        })
    }

    /// Parses and validates scene text; `file` names it in errors.
    pub fn parse(src: &str, file: &str) -> Result<Scene, SceneError> {
        let raw: schema::File = toml::from_str(src).map_err(|e| {
            let (line, column) = e.span().map_or((0, 0), |s| line_col(src, s.start));
            SceneError {
                file: file.to_string(),
                line,
                column,
                field: String::new(),
                message: e.message().trim().to_string(),
                snippet: (line > 0).then(|| src.lines().nth(line - 1).unwrap_or("").to_string()),
            }
        })?;
        let err = |p: Vec<Key>, m: String| located(file, src, &p, m);
        let s = &raw.scene;
        let positive = |v: f64, name: &str| -> Result<f64, SceneError> {
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                Err(err(
                    path(&[&"scene", &name]),
                    format!("must be a finite number > 0, not {v}"),
                ))
            }
        };
        let dt = positive(s.dt, "dt")?;
        let duration = positive(s.duration, "duration")?;
        let method = Method::from_name(&s.integrator).ok_or_else(|| {
            err(
                path(&[&"scene", &"integrator"]),
                format!(
                    "unknown integrator `{}`; expected one of {}",
                    s.integrator,
                    Method::names()
                ),
            )
        })?;
        let gravity = s.gravity.unwrap_or([0.0; 3]);
        let settings = solver_settings(method, raw.solver.as_ref(), &err)?;
        let output = output_settings(raw.output.as_ref(), dt, gravity, &err)?;

        let system = match (&raw.mass_spring, &raw.cloth) {
            (Some(table), None) => {
                let (desc, pinned_from_table) = mass_spring_desc(table, gravity, &err)?;
                let (model, state) = desc.build().map_err(|e| {
                    let p = model_error_path(&e, table, pinned_from_table);
                    err(p, e.to_string())
                })?;
                System::MassSpring(model, state)
            }
            (None, Some(table)) => {
                let base = Path::new(file).parent().unwrap_or(Path::new(""));
                let (desc, obstacle_paths) = cloth_desc(table, gravity, base, &err)?;
                let (cloth, state) = desc
                    .build()
                    .map_err(|e| err(cloth_error_path(&e, &obstacle_paths), e.to_string()))?;
                System::Cloth(cloth, state)
            }
            (Some(_), Some(_)) => {
                return Err(err(
                    path(&[&"cloth"]),
                    "a scene holds one system: [mass_spring] or [cloth], not both".into(),
                ))
            }
            (None, None) => {
                return Err(err(
                    path(&[&"scene"]),
                    "the scene has no system: add a [mass_spring] or [cloth] table".into(),
                ))
            }
        };
        Ok(Scene {
            file: file.to_string(),
            name: s.name.clone().unwrap_or_else(|| stem_name(file, "scene")),
            dt,
            duration,
            settings,
            system,
            output,
        })
    }
}

/// The cloth of a `[cloth]` table: a grid generator or an OBJ mesh, a material,
/// obstacles, wind, paths and step control, and the TOML path of each obstacle (for
/// [`cloth_error_path`]). Files are relative to `base` (the scene's folder).
fn cloth_desc(
    t: &schema::ClothTable,
    gravity: [f64; 3],
    base: &Path,
    err: &ErrFn<'_>,
) -> Result<(crate::cloth::ClothDesc, Vec<Vec<Key>>), SceneError> {
    use crate::cloth::{Obstacle, SdfGrid, StepControl, VertexPath, Wind};
    let at = |f: &[&dyn PathPart]| {
        let mut p = path(&[&"cloth"]);
        p.extend(path(f));
        p
    };
    let m = &t.material;
    let material = crate::cloth::ClothMaterial {
        density: finite_positive(m.density, at(&[&"material", &"density"]), "density", err)?,
        stretch: finite_nonneg(m.stretch, at(&[&"material", &"stretch"]), "stiffness", err)?,
        shear: finite_nonneg(m.shear, at(&[&"material", &"shear"]), "stiffness", err)?,
        bend: finite_nonneg(m.bend, at(&[&"material", &"bend"]), "stiffness", err)?,
        stretch_damping: finite_nonneg(
            m.stretch_damping,
            at(&[&"material", &"stretch_damping"]),
            "damping",
            err,
        )?,
        shear_damping: finite_nonneg(
            m.shear_damping,
            at(&[&"material", &"shear_damping"]),
            "damping",
            err,
        )?,
        bend_damping: finite_nonneg(
            m.bend_damping,
            at(&[&"material", &"bend_damping"]),
            "damping",
            err,
        )?,
        rest_stretch: [1.0, 1.0],
    };
    let mut desc = match (&t.grid, &t.mesh) {
        (Some(g), None) => {
            for (name, v) in [("nu", g.nu), ("nv", g.nv)] {
                if !(2..=4096).contains(&v) {
                    return Err(err(
                        at(&[&"grid", &name]),
                        format!("a cloth grid needs 2..=4096 vertices per side, not {v}"),
                    ));
                }
            }
            for (i, &s) in g.size.iter().enumerate() {
                finite_positive(s, at(&[&"grid", &"size", &i]), "size", err)?;
            }
            let desc = crate::cloth::cloth_grid(&crate::cloth::ClothGridOptions {
                nu: g.nu as usize,
                nv: g.nv as usize,
                size: g.size,
                origin: g.origin.unwrap_or([0.0; 3]),
                u_axis: g.u_axis.unwrap_or([1.0, 0.0, 0.0]),
                v_axis: g.v_axis.unwrap_or([0.0, 0.0, 1.0]),
                material,
            });
            if !desc.positions.iter().flatten().all(|v| v.is_finite()) {
                return Err(err(at(&[&"grid"]), "origin and axes must be finite".into()));
            }
            desc
        }
        (None, Some(mt)) => {
            let file = base.join(&mt.file);
            let (mesh, uv) = crate::io::read_obj_uv(&file)
                .map_err(|e| err(at(&[&"mesh", &"file"]), e.to_string()))?;
            let uv_scale = finite_positive(
                mt.uv_scale.unwrap_or(1.0),
                at(&[&"mesh", &"uv_scale"]),
                "uv_scale",
                err,
            )?;
            let scale = finite_positive(
                mt.scale.unwrap_or(1.0),
                at(&[&"mesh", &"scale"]),
                "scale",
                err,
            )?;
            let offset = mt.offset.unwrap_or([0.0; 3]);
            if !offset.iter().all(|c| c.is_finite()) {
                return Err(err(at(&[&"mesh", &"offset"]), "must be finite".into()));
            }
            let nv = mesh.positions.len() / 3;
            let positions = (0..nv)
                .map(|i| {
                    let p = largestep_kernels::get3(&mesh.positions, nv, i);
                    std::array::from_fn(|c| scale * p[c] + offset[c])
                })
                .collect();
            let mut desc = crate::cloth::cloth_grid(&crate::cloth::ClothGridOptions {
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
        _ => {
            return Err(err(
                at(&[]),
                "give exactly one of [cloth.grid] or [cloth.mesh]".into(),
            ))
        }
    };
    let n = desc.positions.len();
    let vertex = |v: i64, p: Vec<Key>| -> Result<usize, SceneError> {
        let i = index(v, p.clone(), err)?;
        if i >= n {
            return Err(err(
                p,
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
    // Obstacles, each validated where it is written.
    let mut obstacles: Vec<(Vec<Key>, Obstacle)> = Vec::new();
    for (k, s) in t.sphere.iter().enumerate() {
        obstacles.push((
            at(&[&"sphere", &k]),
            Obstacle::Sphere {
                center: s.center,
                radius: s.radius,
            },
        ));
    }
    for (k, s) in t.plane.iter().enumerate() {
        obstacles.push((
            at(&[&"plane", &k]),
            Obstacle::Plane {
                point: s.point,
                normal: s.normal,
            },
        ));
    }
    for (k, s) in t.boxes.iter().enumerate() {
        obstacles.push((
            at(&[&"box", &k]),
            Obstacle::Box {
                min: s.min,
                max: s.max,
            },
        ));
    }
    for (k, s) in t.capsule.iter().enumerate() {
        obstacles.push((
            at(&[&"capsule", &k]),
            Obstacle::Capsule {
                a: s.a,
                b: s.b,
                radius: s.radius,
            },
        ));
    }
    for (k, s) in t.sdf.iter().enumerate() {
        let grid = SdfGrid::read(&base.join(&s.file))
            .map_err(|e| err(at(&[&"sdf", &k, &"file"]), e.to_string()))?;
        obstacles.push((at(&[&"sdf", &k]), Obstacle::Sdf(std::sync::Arc::new(grid))));
    }
    // Obstacles, wind and paths are validated by `ClothDesc::build`; its errors are
    // located by `cloth_error_path` (obstacles by the table each came from).
    let obstacle_paths = obstacles.iter().map(|(p, _)| p.clone()).collect();
    desc.obstacles = obstacles.into_iter().map(|(_, o)| o).collect();
    desc.wind = t.wind.as_ref().map(|w| Wind {
        velocity: w.velocity,
        drag: w.drag,
        gust: w.gust,
        frequency: w.frequency,
    });
    for (k, pt) in t.path.iter().enumerate() {
        let mut vertices = Vec::with_capacity(pt.vertices.len());
        for (j, &v) in pt.vertices.iter().enumerate() {
            vertices.push(vertex(v, at(&[&"path", &k, &"vertices", &j]))?);
        }
        desc.paths.push(VertexPath {
            vertices,
            times: pt.times.clone(),
            offsets: pt.offsets.clone(),
        });
    }
    if let Some(sc) = &t.step_control {
        let d = StepControl::default();
        let max_strain_change = finite_positive(
            sc.max_strain_change.unwrap_or(d.max_strain_change),
            at(&[&"step_control", &"max_strain_change"]),
            "max_strain_change",
            err,
        )?;
        let halvings = sc.max_halvings.unwrap_or(d.max_halvings as i64);
        if !(0..=30).contains(&halvings) {
            return Err(err(
                at(&[&"step_control", &"max_halvings"]),
                format!("must lie in 0..=30, not {halvings}"),
            ));
        }
        desc.step_control = StepControl {
            max_strain_change,
            max_halvings: halvings as u32,
        };
    }
    desc.friction = finite_nonneg(t.friction, at(&[&"friction"]), "friction", err)?;
    desc.gravity = gravity;
    desc.definiteness_fix = t.definiteness_fix.unwrap_or(true);
    Ok((desc, obstacle_paths))
}

/// The TOML path a cloth validation error refers to: the key where the table has it,
/// else its table. `obstacle_paths`: each obstacle's table, in the description's order.
fn cloth_error_path(e: &crate::cloth::ClothError, obstacle_paths: &[Vec<Key>]) -> Vec<Key> {
    let cloth = |rest: &[&dyn PathPart]| {
        let mut p = path(&[&"cloth"]);
        p.extend(path(rest));
        p
    };
    let crate::cloth::ClothError::Value {
        item, index, field, ..
    } = e
    else {
        return cloth(&[]);
    };
    // `velocity.x` is the key `velocity`.
    let key = field.split('.').next().unwrap_or(field);
    match *item {
        "obstacle" => {
            let mut p = obstacle_paths
                .get(*index)
                .cloned()
                .unwrap_or_else(|| cloth(&[]));
            if [
                "point", "normal", "center", "radius", "min", "max", "a", "b",
            ]
            .contains(&key)
            {
                p.extend(path(&[&key]));
            }
            p
        }
        "wind" => cloth(&[&"wind", &key]),
        "path" => cloth(&[&"path", index, &key]),
        "step_control" => cloth(&[&"step_control", &key]),
        "material" if key == "friction" => cloth(&[&"friction"]),
        "material" if key != "rest_stretch" => cloth(&[&"material", &key]),
        "gravity" => path(&[&"scene", &"gravity", index]),
        "pinned" => cloth(&[&"pinned", index]),
        _ => cloth(&[]),
    }
}

type ErrFn<'a> = dyn Fn(Vec<Key>, String) -> SceneError + 'a;

fn solver_settings(
    method: Method,
    t: Option<&schema::SolverTable>,
    err: &ErrFn<'_>,
) -> Result<MechSettings, SceneError> {
    let mut settings = MechSettings::new(method);
    let Some(t) = t else { return Ok(settings) };
    let at = |f: &str| path(&[&"solver", &f]);
    let mut pcg = PcgParams::default();
    if let Some(tol) = t.tolerance {
        if !(tol.is_finite() && tol > 0.0 && tol < 1.0) {
            return Err(err(
                at("tolerance"),
                format!("must be in (0, 1), not {tol}"),
            ));
        }
        pcg.tolerance = tol;
    }
    if let Some(m) = t.max_iterations {
        if m < 1 {
            return Err(err(at("max_iterations"), format!("must be >= 1, not {m}")));
        }
        pcg.max_iterations = m as usize;
    }
    if let Some(p) = &t.preconditioner {
        pcg.preconditioner = match p.as_str() {
            "none" => Preconditioner::None,
            "jacobi" => Preconditioner::Jacobi,
            "block-jacobi" => Preconditioner::BlockJacobi,
            "multigrid" => Preconditioner::Multigrid,
            other => {
                return Err(err(
                    at("preconditioner"),
                    format!(
                        "unknown preconditioner `{other}`; expected none, jacobi, block-jacobi or multigrid"
                    ),
                ))
            }
        };
    }
    settings.linear = match t.linear.as_deref() {
        None | Some("auto") => LinearSolverKind::Auto(pcg),
        Some("pcg") => LinearSolverKind::Pcg(pcg),
        Some("cholesky") => LinearSolverKind::Cholesky,
        Some(other) => {
            return Err(err(
                at("linear"),
                format!("unknown linear solver `{other}`; expected auto, pcg or cholesky"),
            ))
        }
    };
    if let Some(tol) = t.newton_tolerance {
        if !(tol.is_finite() && tol > 0.0 && tol < 1.0) {
            return Err(err(
                at("newton_tolerance"),
                format!("must be in (0, 1), not {tol}"),
            ));
        }
        // Relative residual reduction, and relative velocity change per iteration.
        settings.newton.tolerance = tol;
        settings.newton.step_tolerance = tol;
    }
    if let Some(m) = t.newton_max_iterations {
        if m < 1 {
            return Err(err(
                at("newton_max_iterations"),
                format!("must be >= 1, not {m}"),
            ));
        }
        settings.newton.max_iterations = m as usize;
    }
    Ok(settings)
}

fn output_settings(
    t: Option<&schema::OutputTable>,
    dt: f64,
    gravity: [f64; 3],
    err: &ErrFn<'_>,
) -> Result<Output, SceneError> {
    let default_every = ((1.0 / 30.0) / dt).round().max(1.0) as usize;
    let empty = schema::OutputTable::default();
    let t = t.unwrap_or(&empty);
    let frames = match t.frames.as_deref() {
        None | Some("obj") => FrameFormat::Obj,
        Some("ply") => FrameFormat::Ply,
        Some("none") => FrameFormat::None,
        Some(other) => {
            return Err(err(
                path(&[&"output", &"frames"]),
                format!("unknown frame format `{other}`; expected obj, ply or none"),
            ))
        }
    };
    let every = match t.every {
        None => default_every,
        Some(e) if e >= 1 => e as usize,
        Some(e) => {
            return Err(err(
                path(&[&"output", &"every"]),
                format!("must be >= 1 step per frame, not {e}"),
            ))
        }
    };
    let mut preview = PreviewSettings {
        frame_interval: every as f64 * dt,
        ..PreviewSettings::default()
    };
    let int_in = |v: Option<i64>, name: &str, lo: i64, hi: i64, default: u32| match v {
        None => Ok(default),
        Some(v) if (lo..=hi).contains(&v) => Ok(v as u32),
        Some(v) => Err(err(
            path(&[&"output", &name]),
            format!("must be an integer in {lo}..={hi}, not {v}"),
        )),
    };
    let r = &mut preview.render;
    r.width = int_in(t.width, "width", 1, 16384, r.width)?;
    r.height = int_in(t.height, "height", 1, 16384, r.height)?;
    r.supersample = int_in(t.supersample, "supersample", 1, 4, r.supersample)?;
    r.ground = t.ground.unwrap_or(r.ground);
    preview.wireframe = t.wireframe.unwrap_or(false);
    preview.camera = camera_spec(t.camera.as_ref(), gravity, err)?;
    Ok(Output {
        frames,
        every,
        preview,
    })
}

/// The camera of `[output.camera]`: fixed when `eye` is given (then `target` is required
/// and azimuth/elevation are not allowed), auto-framed otherwise. Up defaults to against
/// gravity, or +y without gravity. Problems a renderer would work round with a warning
/// (an up vector along the view) are errors here, where the user can fix them.
fn camera_spec(
    t: Option<&schema::CameraTable>,
    gravity: [f64; 3],
    err: &ErrFn<'_>,
) -> Result<CameraSpec, SceneError> {
    let g = gravity.map(|c| -c);
    let g_len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    let default_up = if g_len > 0.0 {
        g.map(|c| c / g_len)
    } else {
        [0.0, 1.0, 0.0]
    };
    let empty = schema::CameraTable::default();
    let t = t.unwrap_or(&empty);
    let at = |name: &str| path(&[&"output", &"camera", &name]);
    let up = t.up.unwrap_or(default_up);
    let fov = t.fov.unwrap_or(DEFAULT_FOV_DEG);
    if !(fov > 0.0 && fov < 180.0) {
        return Err(err(
            at("fov"),
            format!("must lie in (0, 180) degrees, not {fov}"),
        ));
    }
    if t.up.is_some() && !(up.iter().all(|c| c.is_finite()) && up.iter().any(|c| *c != 0.0)) {
        return Err(err(
            at("up"),
            format!("must be a finite non-zero vector, not {up:?}"),
        ));
    }
    match (t.eye, t.target) {
        (Some(eye), Some(target)) => {
            if t.azimuth.is_some() || t.elevation.is_some() {
                let which = if t.azimuth.is_some() { "azimuth" } else { "elevation" };
                return Err(err(
                    at(which),
                    "a fixed camera (eye, target) has no azimuth or elevation; give one or the other".into(),
                ));
            }
            let camera = Camera {
                eye,
                target,
                up,
                fov_y_deg: fov,
            };
            let mut warnings = Vec::new();
            let problem = match camera.basis(&mut warnings) {
                Err(e) => Some(e.to_string()),
                Ok(_) => warnings.pop(),
            };
            if let Some(message) = problem {
                return Err(err(at("eye"), message));
            }
            Ok(CameraSpec::Fixed(camera))
        }
        (Some(_), None) => Err(err(at("eye"), "a fixed camera needs `target` as well as `eye`".into())),
        (None, Some(_)) => Err(err(
            at("target"),
            "`target` needs `eye` (without eye the camera frames the scene from azimuth and elevation)".into(),
        )),
        (None, None) => {
            let (azimuth_deg, elevation_deg) = (
                t.azimuth.unwrap_or(DEFAULT_AZIMUTH_DEG),
                t.elevation.unwrap_or(DEFAULT_ELEVATION_DEG),
            );
            if !azimuth_deg.is_finite() {
                return Err(err(at("azimuth"), format!("must be finite, not {azimuth_deg}")));
            }
            if elevation_deg.is_nan() || elevation_deg.abs() >= 90.0 {
                return Err(err(at("elevation"), format!("must lie in (-90, 90) degrees, not {elevation_deg}")));
            }
            Ok(CameraSpec::Auto {
                azimuth_deg,
                elevation_deg,
                fov_y_deg: fov,
                up,
            })
        }
    }
}

fn finite_positive(v: f64, p: Vec<Key>, what: &str, err: &ErrFn<'_>) -> Result<f64, SceneError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(err(
            p,
            format!("{what} must be a finite number > 0, not {v}"),
        ))
    }
}

fn finite_nonneg(v: f64, p: Vec<Key>, what: &str, err: &ErrFn<'_>) -> Result<f64, SceneError> {
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(err(
            p,
            format!("{what} must be a finite number >= 0, not {v}"),
        ))
    }
}

fn index(v: i64, p: Vec<Key>, err: &ErrFn<'_>) -> Result<usize, SceneError> {
    usize::try_from(v).map_err(|_| err(p, format!("a particle index must be >= 0, not {v}")))
}

/// The mass-spring description, and how many of its pinned entries come from the
/// `pinned` list (the rest come from `particle.pinned` flags).
fn mass_spring_desc(
    t: &schema::MassSpringTable,
    gravity: [f64; 3],
    err: &ErrFn<'_>,
) -> Result<(MassSpringDesc, usize), SceneError> {
    let at = |f: &[&dyn PathPart]| {
        let mut p = path(&[&"mass_spring"]);
        p.extend(path(f));
        p
    };
    let sources = t.chain.is_some() as usize
        + t.grid.is_some() as usize
        + t.lattice.is_some() as usize
        + (!t.particle.is_empty()) as usize;
    if sources != 1 {
        return Err(err(
            at(&[]),
            "give exactly one of [mass_spring.chain], [mass_spring.grid], [mass_spring.lattice] or [[mass_spring.particle]] lists".into(),
        ));
    }
    let mut desc = if let Some(c) = &t.chain {
        if c.count < 2 {
            return Err(err(
                at(&[&"chain", &"count"]),
                format!("a chain needs at least 2 particles, not {}", c.count),
            ));
        }
        let spacing = finite_positive(c.spacing, at(&[&"chain", &"spacing"]), "spacing", err)?;
        let mass = finite_positive(c.mass, at(&[&"chain", &"mass"]), "mass", err)?;
        let k = finite_nonneg(c.stiffness, at(&[&"chain", &"stiffness"]), "stiffness", err)?;
        let kd = finite_nonneg(c.damping, at(&[&"chain", &"damping"]), "damping", err)?;
        let dir = c.direction.unwrap_or([1.0, 0.0, 0.0]);
        if !dir.iter().all(|v| v.is_finite()) || dir.iter().all(|&v| v == 0.0) {
            return Err(err(
                at(&[&"chain", &"direction"]),
                "must be a finite, non-zero vector".into(),
            ));
        }
        ms::chain(
            c.count as usize,
            c.anchor.unwrap_or([0.0; 3]),
            dir,
            spacing,
            mass,
            k,
            kd,
        )
    } else if let Some(g) = &t.grid {
        for (name, v) in [("nu", g.nu), ("nv", g.nv)] {
            if v < 2 {
                return Err(err(
                    at(&[&"grid", &name]),
                    format!("a grid needs at least 2 particles per side, not {v}"),
                ));
            }
        }
        for (i, &s) in g.size.iter().enumerate() {
            finite_positive(s, at(&[&"grid", &"size", &i]), "size", err)?;
        }
        let mass = finite_positive(g.mass, at(&[&"grid", &"mass"]), "mass", err)?;
        let structural = finite_nonneg(
            g.structural,
            at(&[&"grid", &"structural"]),
            "stiffness",
            err,
        )?;
        let shear = finite_nonneg(g.shear, at(&[&"grid", &"shear"]), "stiffness", err)?;
        let bend = finite_nonneg(g.bend, at(&[&"grid", &"bend"]), "stiffness", err)?;
        let damping = finite_nonneg(g.damping, at(&[&"grid", &"damping"]), "damping", err)?;
        let d = ms::grid(&ms::GridOptions {
            nu: g.nu as usize,
            nv: g.nv as usize,
            size: g.size,
            origin: g.origin.unwrap_or([0.0; 3]),
            u_axis: g.u_axis.unwrap_or([1.0, 0.0, 0.0]),
            v_axis: g.v_axis.unwrap_or([0.0, -1.0, 0.0]),
            total_mass: mass,
            structural,
            shear,
            bend,
            damping,
        });
        if !d.positions.iter().flatten().all(|v| v.is_finite()) {
            return Err(err(at(&[&"grid"]), "origin and axes must be finite".into()));
        }
        d
    } else if let Some(l) = &t.lattice {
        for (a, &v) in l.n.iter().enumerate() {
            if !(2..=1024).contains(&v) {
                return Err(err(
                    at(&[&"lattice", &"n", &a]),
                    format!("a lattice needs 2..=1024 particles per side, not {v}"),
                ));
            }
        }
        for (i, &s) in l.size.iter().enumerate() {
            finite_positive(s, at(&[&"lattice", &"size", &i]), "size", err)?;
        }
        let mass = finite_positive(l.mass, at(&[&"lattice", &"mass"]), "mass", err)?;
        let k = |name: &str, v: f64| finite_nonneg(v, at(&[&"lattice", &name]), "stiffness", err);
        let (structural, shear, bend) = (
            k("structural", l.structural)?,
            k("shear", l.shear)?,
            k("bend", l.bend)?,
        );
        let damping = finite_nonneg(l.damping, at(&[&"lattice", &"damping"]), "damping", err)?;
        let origin = l.origin.unwrap_or([0.0; 3]);
        if !origin.iter().all(|v| v.is_finite()) {
            return Err(err(at(&[&"lattice", &"origin"]), "must be finite".into()));
        }
        let mut d = ms::lattice(&ms::LatticeOptions {
            n: l.n.map(|v| v as usize),
            origin,
            size: l.size,
            mass,
            structural,
            shear,
            bend,
            damping,
        });
        if let Some(v) = l.velocity {
            d.velocities = vec![v; d.positions.len()];
        }
        d
    } else {
        let mut d = MassSpringDesc::default();
        for p in &t.particle {
            d.positions.push(p.position);
            d.velocities.push(p.velocity.unwrap_or([0.0; 3]));
            d.masses.push(p.mass);
        }
        d
    };
    if (t.chain.is_some() || t.grid.is_some() || t.lattice.is_some()) && !t.spring.is_empty() {
        return Err(err(
            at(&[&"spring"]),
            "springs come from the generator; list springs only with explicit particles".into(),
        ));
    }
    for (k, s) in t.spring.iter().enumerate() {
        let a = index(s.a, at(&[&"spring", &k, &"a"]), err)?;
        let b = index(s.b, at(&[&"spring", &k, &"b"]), err)?;
        desc.springs.push(SpringDesc {
            a,
            b,
            stiffness: s.stiffness,
            damping: s.damping,
            rest_length: s.rest_length,
        });
    }
    let mut pinned = Vec::new();
    for (k, &p) in t.pinned.iter().enumerate() {
        pinned.push(index(p, at(&[&"pinned", &k]), err)?);
    }
    let from_table = pinned.len();
    pinned.extend(
        t.particle
            .iter()
            .enumerate()
            .filter(|(_, p)| p.pinned)
            .map(|(i, _)| i),
    );
    // An explicit list wins; otherwise the generator's default stands (a chain pins its
    // first particle, a grid nothing).
    if !pinned.is_empty() {
        desc.pinned = pinned;
    }
    if let Some(c) = &t.collisions {
        let bounds = match (c.box_min, c.box_max) {
            (Some(lo), Some(hi)) => Some((lo, hi)),
            (None, None) => None,
            (Some(_), None) => {
                return Err(err(
                    at(&[&"collisions", &"box_min"]),
                    "needs box_max as well".into(),
                ))
            }
            (None, Some(_)) => {
                return Err(err(
                    at(&[&"collisions", &"box_max"]),
                    "needs box_min as well".into(),
                ))
            }
        };
        desc.collisions = Some(ms::CollisionDesc {
            bounds,
            planes: c.planes.clone(),
            stiffness: c.stiffness,
            damping: c.damping,
        });
    }
    if let Some(f) = &t.force_field {
        let r = f.resolution;
        if !(2..=1000).contains(&r) {
            return Err(err(
                at(&[&"force_field", &"resolution"]),
                format!("must be an integer in 2..=1000, not {r}"),
            ));
        }
        let r = r as usize;
        if f.forces.len() != r * r * r {
            return Err(err(
                at(&[&"force_field", &"forces"]),
                format!(
                    "resolution {r} needs {} forces (r^3), found {}",
                    r * r * r,
                    f.forces.len()
                ),
            ));
        }
        let world = ms::world::World::field_from_samples(r, f.min, f.max, &f.forces);
        desc.force_field = Some(world);
    }
    desc.gravity = gravity;
    desc.definiteness_fix = t.definiteness_fix.unwrap_or(true);
    Ok((desc, from_table))
}

/// The TOML path a model validation error refers to.
fn model_error_path(
    e: &ModelError,
    t: &schema::MassSpringTable,
    pinned_from_table: usize,
) -> Vec<Key> {
    let ms = |rest: &[&dyn PathPart]| {
        let mut p = path(&[&"mass_spring"]);
        p.extend(path(rest));
        p
    };
    match e {
        ModelError::Value {
            item: "particle",
            index,
            field,
            ..
        } => {
            let f = field.split('.').next().unwrap_or(field);
            ms(&[&"particle", index, &f])
        }
        ModelError::Value {
            item: "spring",
            index,
            field,
            ..
        } => ms(&[&"spring", index, field]),
        ModelError::Value {
            item: "gravity",
            index,
            ..
        } => path(&[&"scene", &"gravity", index]),
        ModelError::MissingParticle {
            item: "spring",
            index,
            particle,
            ..
        } => {
            let end = if t
                .spring
                .get(*index)
                .is_some_and(|s| s.a == *particle as i64)
            {
                "a"
            } else {
                "b"
            };
            ms(&[&"spring", index, &end])
        }
        ModelError::SelfSpring { index, .. } => ms(&[&"spring", index, &"b"]),
        ModelError::Value {
            item: "plane",
            index,
            ..
        } => ms(&[&"collisions", &"planes", index]),
        ModelError::Value {
            item: "collisions",
            field,
            ..
        } => ms(&[&"collisions", field]),
        ModelError::Value {
            item: "collisions.box",
            index,
            field,
            ..
        } => ms(&[&"collisions", &format!("box_{field}").as_str(), index]),
        ModelError::Value { item, .. } | ModelError::Length { what: item, .. }
            if item.starts_with("force_field") =>
        {
            ms(&[&"force_field"])
        }
        ModelError::MissingParticle {
            item: "pinned",
            index,
            ..
        } if *index < pinned_from_table => ms(&[&"pinned", index]),
        _ => ms(&[]),
    }
}
