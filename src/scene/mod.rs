//! Scenes: TOML files naming an integrator, outputs and one or more systems.
//!
//! [`Scene::parse`] reads and validates a scene and builds its simulations, so every
//! problem is reported before anything runs, as `file:line:column: field: message`
//! followed by the offending line. Syntax and type errors come from toml's spans; range
//! errors (NaN, negative mass, dt <= 0, springs naming missing particles) are found by the
//! models' own validation and located by walking the span-preserving document along the
//! field's path.
//!
//! This module knows no domain by name. It parses `[scene]`, `[solver]` and `[output]`
//! and hands every other top-level table to the domain registered for it
//! ([`registry::DOMAINS`]), with a [`Context`] holding the scene-wide settings and the
//! means to report located errors; the domain returns a [`Simulation`]. Other file formats
//! (the jello world files) are registered the same way ([`registry::FORMATS`]).
//!
//! A scene may hold several systems (a cloth and a jello), one per domain table. They are
//! independent: stepped one after the other with the scene's dt, each with its own
//! obstacles and loads, and none sees the others (no coupling, not even one-way). Their
//! frames are written as one mesh.
//!
//! [`Runner`] steps a scene frame by frame, writing frames and an energy log.

pub mod registry;
mod run;
pub mod schema;
pub mod shared;

pub use run::{diagonal, FrameFormat, FrameRecord, Output, Progress, RunError, Runner, Summary};

use crate::integrate::{LinearSolverKind, MechSettings, Method, AUTO_CHOLESKY_MAX_DOFS};
use crate::limits::Limits;
use crate::render::preview::PreviewSettings;
use crate::render::{
    Camera, CameraSpec, DEFAULT_AZIMUTH_DEG, DEFAULT_ELEVATION_DEG, DEFAULT_FOV_DEG,
};
use crate::simulation::Simulation;
use crate::solve::{PcgParams, Preconditioner};
use serde::de::DeserializeOwned;
use std::fmt;
use std::path::Path;
use toml::de::{DeTable, DeValue, ValueDeserializer};
use toml::Spanned;

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
            write!(f, ":{}", self.line)?;
            if self.column > 0 {
                write!(f, ":{}", self.column)?;
            }
        }
        let message = crate::io::clip(&self.message, crate::io::MAX_MESSAGE);
        if self.field.is_empty() {
            write!(f, ": {message}")?;
        } else {
            write!(f, ": {}: {message}", self.field)?;
        }
        if let Some(s) = &self.snippet {
            write!(f, "\n{:>5} | {}", self.line, crate::io::clip(s, 160))?;
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
pub fn stem_name(file: &str, default: &str) -> String {
    Path::new(file)
        .file_stem()
        .map_or(default.into(), |x| x.to_string_lossy().into_owned())
}

/// One step of a path into the TOML document.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Key {
    /// A table key.
    Field(String),
    /// An array index.
    Index(usize),
}

/// A key path from its parts: `path(&[&"cloth", &"sphere", &0, &"radius"])` is
/// `cloth.sphere[0].radius`.
pub fn path(keys: &[&dyn PathPart]) -> Vec<Key> {
    keys.iter().map(|k| k.key()).collect()
}

/// A part of a key path: a table key (`&str`) or an array index (`usize`).
pub trait PathPart {
    /// The key.
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

/// A key path as the scene writes it: `rigid.body[3].orientation`.
pub fn dotted_key(p: &[Key]) -> String {
    dotted(p)
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

/// One system of a scene: the table it came from and its simulation.
pub struct System {
    /// The scene table (`cloth`, `mass_spring`).
    pub table: &'static str,
    /// The simulation.
    pub sim: Box<dyn Simulation>,
}

impl fmt::Debug for System {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("System")
            .field("table", &self.table)
            .field("method", &self.sim.method())
            .finish_non_exhaustive()
    }
}

/// A validated scene with its simulations built.
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
    /// The systems, in registry order.
    pub systems: Vec<System>,
    /// The limits it was checked against (a run checks its steps against them too).
    pub limits: Limits,
    /// Outputs.
    pub output: Output,
}

/// What a domain's scene converter gets (see [`registry::Domain`]): its table, the
/// scene-wide settings, and the means to report errors at a key.
pub struct Context<'a> {
    /// The scene file's name, as given.
    pub file: &'a str,
    /// The folder files named in the scene are relative to.
    pub base: &'a Path,
    /// Gravity (m/s^2), from `[scene]`.
    pub gravity: [f64; 3],
    /// Time step (s).
    pub dt: f64,
    /// Simulated time (s), from `[scene]`.
    pub duration: f64,
    /// Integrator and solver settings, from `[scene]` and `[solver]`.
    pub settings: MechSettings,
    /// Whether `[solver]` names a preconditioner; when it does not, a domain may put in
    /// the one that suits its systems.
    pub preconditioner_given: bool,
    /// What the scene may ask for: its converter checks sizes against these before
    /// allocating.
    pub limits: Limits,
    src: &'a str,
    table: &'a str,
    value: Spanned<DeValue<'a>>,
}

impl Context<'_> {
    /// The domain's table, deserialized (type errors located at their key).
    pub fn table<T: DeserializeOwned>(&self) -> Result<T, SceneError> {
        T::deserialize(ValueDeserializer::from(self.value.clone()))
            .map_err(|e| syntax_error(self.file, self.src, &e))
    }

    /// The error `message` at the key `rest` below the domain's table.
    pub fn error(&self, rest: &[Key], message: impl Into<String>) -> SceneError {
        let mut p = vec![Key::Field(self.table.to_string())];
        p.extend_from_slice(rest);
        located(self.file, self.src, &p, message.into())
    }

    /// The error `message` at an absolute key path (`[scene] gravity`, say).
    pub fn error_at(&self, p: &[Key], message: impl Into<String>) -> SceneError {
        located(self.file, self.src, p, message.into())
    }

    /// `Ok` when a model estimated to need `bytes` fits the memory budget, else the
    /// error at `at` naming `what` needs them.
    pub fn memory(&self, at: &[Key], what: &str, bytes: f64) -> Result<(), SceneError> {
        self.limits
            .memory(what, bytes)
            .map_err(|m| self.error(at, m))
    }

    /// Whether the integrator solves systems (and so assembles matrices).
    pub fn implicit(&self) -> bool {
        self.settings.method.is_implicit()
    }

    /// Whether implicit steps of a model of `vertices` vertices solve with sparse Cholesky
    /// (whose factor fills in) rather than PCG.
    pub fn cholesky(&self, vertices: f64) -> bool {
        match self.settings.linear {
            LinearSolverKind::Cholesky => true,
            LinearSolverKind::Auto(_) => 3.0 * vertices <= AUTO_CHOLESKY_MAX_DOFS as f64,
            LinearSolverKind::Pcg(_) => false,
        }
    }

    /// A model's validation error, at `key` below the domain's table; gravity's at
    /// `[scene] gravity`, where it came from.
    pub fn model_error(&self, e: &crate::validate::ModelError, key: &[Key]) -> SceneError {
        match e {
            crate::validate::ModelError::Value {
                item: "gravity",
                index,
                ..
            } => self.error_at(&path(&[&"scene", &"gravity", index]), e.to_string()),
            _ => self.error(key, e.to_string()),
        }
    }

    /// `v` if it is finite and > 0, else the error at `at` naming `what`.
    pub fn positive(&self, v: f64, at: &[Key], what: &str) -> Result<f64, SceneError> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(self.error(at, format!("{what} must be a finite number > 0, not {v}")))
        }
    }

    /// `v` if it is finite and >= 0, else the error at `at` naming `what`.
    pub fn non_negative(&self, v: f64, at: &[Key], what: &str) -> Result<f64, SceneError> {
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            Err(self.error(at, format!("{what} must be a finite number >= 0, not {v}")))
        }
    }

    /// `v` as an index, or the error at `at` for a negative one.
    pub fn index(&self, v: i64, at: &[Key], what: &str) -> Result<usize, SceneError> {
        usize::try_from(v)
            .map_err(|_| self.error(at, format!("a {what} index must be >= 0, not {v}")))
    }
}

/// A syntax or type error from toml, at its span.
fn syntax_error(file: &str, src: &str, e: &toml::de::Error) -> SceneError {
    let (line, column) = e.span().map_or((0, 0), |s| line_col(src, s.start));
    SceneError {
        file: file.to_string(),
        line,
        column,
        field: String::new(),
        message: e.message().trim().to_string(),
        snippet: (line > 0).then(|| src.lines().nth(line - 1).unwrap_or("").to_string()),
    }
}

/// Deserializes one top-level table of the document.
fn table<T: DeserializeOwned>(
    file: &str,
    src: &str,
    value: &Spanned<DeValue<'_>>,
) -> Result<T, SceneError> {
    T::deserialize(ValueDeserializer::from(value.clone())).map_err(|e| syntax_error(file, src, &e))
}

impl Scene {
    /// Reads and validates a scene file: TOML, or a format of [`registry::FORMATS`] by
    /// its extension; within the default [`Limits`] of this machine.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        Self::load_with(path, &Limits::default())
    }

    /// [`Scene::load`] within `limits`: the file's size, and every size and step count
    /// the scene asks for, are checked against them before anything is allocated.
    pub fn load_with(path: &Path, limits: &Limits) -> Result<Scene, SceneError> {
        let file = path.display().to_string();
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        if let Some(format) = registry::FORMATS
            .iter()
            .find(|f| ext.as_deref() == Some(f.extension))
        {
            return (format.load)(path, limits);
        }
        let src = crate::io::read_text(path, limits.max_file_bytes).map_err(|e| {
            let mut e = SceneError::from_read(e);
            if e.line == 0 {
                e.message = format!("cannot read the scene: {}", e.message);
            }
            e
        })?;
        Self::parse_with(&src, &file, limits)
    }

    /// Parses and validates scene text; `file` names it in errors and its folder is where
    /// files named in the scene are looked for.
    pub fn parse(src: &str, file: &str) -> Result<Scene, SceneError> {
        Self::parse_with(src, file, &Limits::default())
    }

    /// [`Scene::parse`] within `limits` (see [`Scene::load_with`]).
    pub fn parse_with(src: &str, file: &str, limits: &Limits) -> Result<Scene, SceneError> {
        let root = DeTable::parse(src).map_err(|e| syntax_error(file, src, &e))?;
        let err = |p: Vec<Key>, m: String| located(file, src, &p, m);
        let domains: Vec<&str> = registry::DOMAINS.iter().map(|d| d.table).collect();
        for (key, _) in root.get_ref().iter() {
            let k = key.get_ref().as_ref();
            if !(["scene", "solver", "output"].contains(&k) || domains.contains(&k)) {
                return Err(err(
                    path(&[&k]),
                    format!(
                        "unknown table `{k}`; expected scene, solver, output or a system: {}",
                        domains.join(", ")
                    ),
                ));
            }
        }
        let get = |k: &str| root.get_ref().get(k);
        let Some(scene_value) = get("scene") else {
            return Err(err(
                Vec::new(),
                "missing [scene] table (dt, duration; integrator optional)".into(),
            ));
        };
        let s: schema::SceneTable = table(file, src, scene_value)?;
        let solver: Option<schema::SolverTable> =
            get("solver").map(|v| table(file, src, v)).transpose()?;
        let output: Option<schema::OutputTable> =
            get("output").map(|v| table(file, src, v)).transpose()?;
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
        limits
            .steps(
                &format!("a duration of {duration} s at dt = {dt:e} s"),
                duration / dt,
            )
            .map_err(|m| err(path(&[&"scene", &"dt"]), m))?;
        let integrator = s.integrator.as_deref().unwrap_or("backward-euler");
        let method = Method::from_name(integrator).ok_or_else(|| {
            err(
                path(&[&"scene", &"integrator"]),
                format!(
                    "unknown integrator `{integrator}`; expected one of {}",
                    Method::names()
                ),
            )
        })?;
        let gravity = s.gravity.unwrap_or([0.0; 3]);
        let settings = solver_settings(method, solver.as_ref(), &err)?;
        let output = output_settings(output.as_ref(), dt, gravity, &err)?;
        // A preview holds a frame's image (3 bytes a pixel) and the contact sheet's.
        let r = output.preview.render;
        limits
            .memory(
                &format!("a {} x {} preview", r.width, r.height),
                6.0 * r.width as f64 * r.height as f64,
            )
            .map_err(|m| err(path(&[&"output", &"width"]), m))?;
        let base = Path::new(file).parent().unwrap_or(Path::new(""));
        let mut systems = Vec::new();
        for domain in registry::DOMAINS {
            let Some(value) = get(domain.table) else {
                continue;
            };
            let ctx = Context {
                file,
                base,
                limits: *limits,
                gravity,
                dt,
                duration,
                settings,
                preconditioner_given: solver.as_ref().is_some_and(|t| t.preconditioner.is_some()),
                src,
                table: domain.table,
                value: value.clone(),
            };
            systems.push(System {
                table: domain.table,
                sim: (domain.build)(&ctx)?,
            });
        }
        if output.frames == FrameFormat::Vtk && !systems.iter().any(|s| s.sim.has_volume()) {
            return Err(err(
                path(&[&"output", &"frames"]),
                "VTK frames write volumes: the scene needs a volumetric system such as [fem]"
                    .to_string(),
            ));
        }
        if systems.is_empty() {
            return Err(err(
                path(&[&"scene"]),
                format!(
                    "the scene has no system: add a table of one of {}",
                    domains
                        .iter()
                        .map(|d| format!("[{d}]"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        }
        Ok(Scene {
            file: file.to_string(),
            name: s.name.clone().unwrap_or_else(|| stem_name(file, "scene")),
            dt,
            duration,
            systems,
            output,
            limits: *limits,
        })
    }

    /// The scene's name as one safe folder name, for the default output folder
    /// `out/<name>`: letters, digits, `-`, `_` and `.` kept, anything else (a `/`, a
    /// space) made `_`, no leading `.` (so never `..`), at most 100 characters; `scene`
    /// when nothing is left. A name can never put the output outside `out/`.
    pub fn folder_name(&self) -> String {
        let s: String = self
            .name
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || "-_.".contains(c) {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        let s: String = s.trim_start_matches('.').chars().take(100).collect();
        if s.is_empty() {
            "scene".into()
        } else {
            s
        }
    }

    /// Meshes of every system's fixed scenery (obstacles), for previews, planes cut to
    /// `around`.
    pub fn scenery(&self, around: ([f64; 3], [f64; 3])) -> Vec<crate::io::Mesh> {
        self.systems
            .iter()
            .flat_map(|s| s.sim.scenery(around))
            .collect()
    }

    /// The simulation of a scene with one system (`None` with several).
    pub fn into_simulation(self) -> Option<Box<dyn Simulation>> {
        let mut systems = self.systems;
        (systems.len() == 1).then(|| systems.remove(0).sim)
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
    // A relative tolerance, in (0, 1).
    let fraction = |key: &str, v: f64| {
        if v.is_finite() && v > 0.0 && v < 1.0 {
            Ok(v)
        } else {
            Err(err(at(key), format!("must be in (0, 1), not {v}")))
        }
    };
    // Steps something may be reused for, 0 meaning `zero`.
    let steps = |key: &str, r: i64, zero: &str| {
        if (0..=1000).contains(&r) {
            Ok(r as usize)
        } else {
            Err(err(
                at(key),
                format!("must be 0 ({zero}) to 1000 steps, not {r}"),
            ))
        }
    };
    let mut pcg = PcgParams::default();
    if let Some(tol) = t.tolerance {
        pcg.tolerance = fraction("tolerance", tol)?;
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
            "smoothed-aggregation" => Preconditioner::SmoothedAggregation,
            other => {
                return Err(err(
                    at("preconditioner"),
                    format!(
                        "unknown preconditioner `{other}`; expected none, jacobi, block-jacobi, multigrid or smoothed-aggregation"
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
        let tol = fraction("newton_tolerance", tol)?;
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
    if let Some(r) = t.reuse_jacobian {
        settings.reuse_jacobian = steps("reuse_jacobian", r, "full Newton")?;
    }
    if let Some(eta) = t.forcing {
        settings.newton.forcing = Some(fraction("forcing", eta)?);
    }
    if let Some(r) = t.reuse_preconditioner {
        settings.reuse_preconditioner = steps(
            "reuse_preconditioner",
            r,
            "a new hierarchy for each Jacobian",
        )?;
    }
    if let Some(p) = t.predictor {
        settings.predictor = p;
    }
    if let Some(p) = t.second_order_predictor {
        settings.second_order_predictor = p;
    }
    if let Some(r) = t.newton_rate_test {
        settings.newton.rate_test = r;
    }
    if let Some(r) = t.newton_skip_last_residual {
        settings.newton.skip_last_residual = r;
    }
    if let Some(r) = t.rounded_products {
        settings.rounded_products = r;
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
        Some("vtk") => FrameFormat::Vtk,
        Some(other) => {
            return Err(err(
                path(&[&"output", &"frames"]),
                format!("unknown frame format `{other}`; expected obj, ply, vtk or none"),
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
