//! The `[fluid]` scene table and [`FluidSim`], the fluid's [`Simulation`].
//!
//! ```toml
//! [fluid]
//! cells = [64, 128, 1]          # along x, y, z; z = 1 is a 2-D fluid
//! size = 1.0                    # m along x (cells are cubes: h = size / cells[0])
//! origin = [0.0, 0.0, 0.0]      # m, the lower corner
//! viscosity = 0.0               # m^2/s (kinematic); 0 builds no diffusion solve
//! density = 1.0                 # kg/m^3 (pressure and energy)
//! force = [0.0, 0.0, 0.0]       # m/s^2 on the fluid itself
//! vorticity = 0.0               # confinement strength epsilon
//! advection = "semi-lagrangian" # or "maccormack", "bfecc"
//! trace = "rk2"                 # or "rk3"
//! interpolation = "linear"      # or "monotone-cubic"
//! cfl = 1.0                     # cells a sub-step may move the fluid
//! max_substeps = 64             # a step needing more is refused with the dt that fits
//! tolerance = 1e-6              # pressure (and viscosity) CG, relative residual
//! preconditioner = "multigrid"  # or "jacobi"
//! precision = "single"          # the preconditioner's vectors: or "double"
//! initial = "rest"              # or "taylor-green" (speed), or "uniform" (velocity)
//! speed = 1.0
//! [fluid.boundary]              # per axis a name for both sides or [low, high]:
//! x = "wall"                    # wall (no-slip), slip, open, lid, periodic
//! y = ["wall", "lid"]
//! lid = [1.0, 0.0, 0.0]         # m/s, the velocity of every lid side
//! [fluid.buoyancy]              # Fedkiw et al. 2001: (-smoke d + heat (T - ambient)) up
//! smoke = 0.05                  # m/s^2 per unit density
//! heat = 1.0                    # m/s^2 per K
//! ambient = 0.0                 # K
//! up = [0.0, 1.0, 0.0]          # default: against [scene] gravity, else +y
//! [[fluid.source]]              # a sphere (center, radius) or a box (min, max)
//! center = [0.5, 0.1, 0.0]
//! radius = 0.08
//! density = 1.0                 # sets at least this much smoke
//! temperature = 1.0             # K
//! velocity = [0.0, 1.0, 0.0]    # m/s on the region's faces
//! until = 1e9                   # s it emits for (0: the initial state only)
//! [[fluid.sphere]]              # obstacles: sphere, box, capsule, plane, sdf
//! center = [0.5, 0.5, 0.0]
//! radius = 0.1
//! [[fluid.mesh]]                # a closed surface voxelised on the grid (solid inside)
//! file = "bowl.obj"
//! scale = 1.0                   # then
//! translate = [0.5, 0.5, 0.5]   # m
//! ```

use super::{
    bytes_per_cell, Advection, Boundary, Buoyancy, Correction, Fluid, FluidDesc, FluidError,
    FluidState, FluidStepInfo, FluidWork, Initial, Interp, Source, Trace,
};
use crate::collide::Obstacle;
use crate::integrate::{IntegrateError, StepInfo};
use crate::io::Mesh;
use crate::scene::shared::{
    obstacles, BoxTable, CapsuleTable, ObstacleTables, PlaneTable, SdfTable, SphereTable,
};
use crate::scene::{path, Context, Key, SceneError};
use crate::simulation::{Energy, FrameData, GridField, GridRef, Simulation, Stage};
use crate::solve::{PoissonPreconditioner, Precision};
use serde::Deserialize;
use std::sync::Arc;

/// `[fluid]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FluidTable {
    pub cells: [i64; 3],
    pub size: f64,
    #[serde(default)]
    pub origin: Option<[f64; 3]>,
    #[serde(default)]
    pub viscosity: Option<f64>,
    #[serde(default)]
    pub density: Option<f64>,
    #[serde(default)]
    pub force: Option<[f64; 3]>,
    #[serde(default)]
    pub vorticity: Option<f64>,
    #[serde(default)]
    pub advection: Option<String>,
    #[serde(default)]
    pub trace: Option<String>,
    #[serde(default)]
    pub interpolation: Option<String>,
    #[serde(default)]
    pub cfl: Option<f64>,
    #[serde(default)]
    pub max_substeps: Option<i64>,
    #[serde(default)]
    pub tolerance: Option<f64>,
    #[serde(default)]
    pub preconditioner: Option<String>,
    #[serde(default)]
    pub precision: Option<String>,
    #[serde(default)]
    pub initial: Option<String>,
    #[serde(default)]
    pub speed: Option<f64>,
    #[serde(default)]
    pub velocity: Option<[f64; 3]>,
    #[serde(default)]
    pub boundary: Option<BoundaryTable>,
    #[serde(default)]
    pub buoyancy: Option<BuoyancyTable>,
    #[serde(default)]
    pub source: Vec<SourceTable>,
    #[serde(default)]
    pub sphere: Vec<SphereTable>,
    #[serde(default)]
    pub plane: Vec<PlaneTable>,
    #[serde(default, rename = "box")]
    pub boxes: Vec<BoxTable>,
    #[serde(default)]
    pub capsule: Vec<CapsuleTable>,
    #[serde(default)]
    pub sdf: Vec<SdfTable>,
    #[serde(default)]
    pub mesh: Vec<MeshObstacleTable>,
}

/// `[[fluid.mesh]]`: a closed surface (`.obj`, `.off`) whose inside is solid, voxelised
/// on the fluid's grid (cells whose centre is inside).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshObstacleTable {
    pub file: String,
    /// Scale, then translation (m), applied to the file's vertices.
    #[serde(default)]
    pub scale: Option<f64>,
    #[serde(default)]
    pub translate: Option<[f64; 3]>,
}

/// One axis of `[fluid.boundary]`: a name for both sides, or `[low, high]`.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub enum AxisSides {
    Both(String),
    Each([String; 2]),
}

/// `[fluid.boundary]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoundaryTable {
    #[serde(default)]
    pub x: Option<AxisSides>,
    #[serde(default)]
    pub y: Option<AxisSides>,
    #[serde(default)]
    pub z: Option<AxisSides>,
    #[serde(default)]
    pub lid: Option<[f64; 3]>,
}

/// `[fluid.buoyancy]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BuoyancyTable {
    #[serde(default)]
    pub smoke: Option<f64>,
    #[serde(default)]
    pub heat: Option<f64>,
    #[serde(default)]
    pub ambient: Option<f64>,
    #[serde(default)]
    pub up: Option<[f64; 3]>,
}

/// `[[fluid.source]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceTable {
    #[serde(default)]
    pub center: Option<[f64; 3]>,
    #[serde(default)]
    pub radius: Option<f64>,
    #[serde(default)]
    pub min: Option<[f64; 3]>,
    #[serde(default)]
    pub max: Option<[f64; 3]>,
    #[serde(default)]
    pub density: Option<f64>,
    #[serde(default)]
    pub temperature: Option<f64>,
    #[serde(default)]
    pub velocity: Option<[f64; 3]>,
    #[serde(default)]
    pub until: Option<f64>,
}

/// The boundary names.
pub const BOUNDARIES: [&str; 5] = ["wall", "slip", "open", "lid", "periodic"];

fn one_of<T: Copy>(
    ctx: &Context<'_>,
    at: &[Key],
    what: &str,
    given: Option<&str>,
    default: T,
    names: &[(&str, T)],
) -> Result<T, SceneError> {
    let Some(g) = given else {
        return Ok(default);
    };
    names
        .iter()
        .find(|(n, _)| *n == g)
        .map(|(_, v)| *v)
        .ok_or_else(|| {
            let all: Vec<&str> = names.iter().map(|(n, _)| *n).collect();
            ctx.error(
                at,
                format!("unknown {what} `{g}`; one of: {}", all.join(", ")),
            )
        })
}

/// Converts the table into a description (errors located at their keys).
pub fn desc(ctx: &Context<'_>, t: &FluidTable) -> Result<FluidDesc, SceneError> {
    let at = |k: &str| path(&[&k]);
    let mut cells = [0usize; 3];
    for (a, &c) in t.cells.iter().enumerate() {
        let least = if a < 2 { 2 } else { 1 };
        if c < least || c > 1 << 16 {
            return Err(ctx.error(
                &at("cells"),
                format!(
                    "cells along {} must be {least} to 65,536, not {c}",
                    ["x", "y", "z"][a]
                ),
            ));
        }
        cells[a] = c as usize;
    }
    let size = ctx.positive(t.size, &at("size"), "size")?;
    let h = size / cells[0] as f64;
    let viscosity = ctx.non_negative(t.viscosity.unwrap_or(0.0), &at("viscosity"), "viscosity")?;
    let count = cells.iter().map(|&c| c as f64).product::<f64>();
    ctx.memory(
        &at("cells"),
        &format!(
            "a fluid of {} x {} x {} cells",
            cells[0], cells[1], cells[2]
        ),
        count * bytes_per_cell(viscosity > 0.0),
    )?;
    let lid = t.boundary.as_ref().and_then(|b| b.lid);
    let mut boundaries = [[Boundary::Wall; 2]; 3];
    if let Some(b) = &t.boundary {
        for (a, axis) in [&b.x, &b.y, &b.z].into_iter().enumerate() {
            let key = path(&[&"boundary", &["x", "y", "z"][a]]);
            let names: [&str; 2] = match axis {
                None => continue,
                Some(AxisSides::Both(n)) => [n, n],
                Some(AxisSides::Each([l, h])) => [l, h],
            };
            for (side, name) in names.iter().enumerate() {
                boundaries[a][side] = match *name {
                    "wall" => Boundary::Wall,
                    "slip" => Boundary::Slip,
                    "open" => Boundary::Open,
                    "periodic" => Boundary::Periodic,
                    "lid" => Boundary::Lid(lid.ok_or_else(|| {
                        ctx.error(
                            &key,
                            "a lid side needs `lid = [vx, vy, vz]` in [fluid.boundary]",
                        )
                    })?),
                    other => {
                        return Err(ctx.error(
                            &key,
                            format!(
                                "unknown boundary `{other}`; one of: {}",
                                BOUNDARIES.join(", ")
                            ),
                        ))
                    }
                };
            }
            if (boundaries[a][0] == Boundary::Periodic) != (boundaries[a][1] == Boundary::Periodic)
            {
                return Err(ctx.error(&key, "a periodic axis must be periodic on both sides"));
            }
        }
        if cells[2] == 1 && b.z.is_some() {
            return Err(ctx.error(
                &path(&[&"boundary", &"z"]),
                "a 2-D fluid (cells[2] = 1) has no z sides",
            ));
        }
    }
    let correction = one_of(
        ctx,
        &at("advection"),
        "advection",
        t.advection.as_deref(),
        Correction::None,
        &[
            ("semi-lagrangian", Correction::None),
            ("maccormack", Correction::MacCormack),
            ("bfecc", Correction::Bfecc),
        ],
    )?;
    let trace = one_of(
        ctx,
        &at("trace"),
        "trace",
        t.trace.as_deref(),
        Trace::Rk2,
        &[("rk2", Trace::Rk2), ("rk3", Trace::Rk3)],
    )?;
    let interp = one_of(
        ctx,
        &at("interpolation"),
        "interpolation",
        t.interpolation.as_deref(),
        Interp::Linear,
        &[
            ("linear", Interp::Linear),
            ("monotone-cubic", Interp::MonotoneCubic),
        ],
    )?;
    let preconditioner = one_of(
        ctx,
        &at("preconditioner"),
        "preconditioner",
        t.preconditioner.as_deref(),
        PoissonPreconditioner::Multigrid,
        &[
            ("multigrid", PoissonPreconditioner::Multigrid),
            ("jacobi", PoissonPreconditioner::Jacobi),
        ],
    )?;
    let precision = one_of(
        ctx,
        &at("precision"),
        "precision",
        t.precision.as_deref(),
        Precision::default(),
        &[("single", Precision::Single), ("double", Precision::Double)],
    )?;
    let initial = match t.initial.as_deref() {
        None | Some("rest") => Initial::Rest,
        Some("taylor-green") => {
            if cells[0] != cells[1] {
                return Err(ctx.error(
                    &at("initial"),
                    "the Taylor-Green vortex needs as many cells along x as along y",
                ));
            }
            Initial::TaylorGreen {
                speed: t.speed.unwrap_or(1.0),
            }
        }
        Some("uniform") => Initial::Uniform(t.velocity.ok_or_else(|| {
            ctx.error(
                &at("initial"),
                "initial = \"uniform\" needs `velocity = [vx, vy, vz]`",
            )
        })?),
        Some(o) => {
            return Err(ctx.error(
                &at("initial"),
                format!("unknown initial `{o}`; one of: rest, taylor-green, uniform"),
            ))
        }
    };
    let buoyancy = t.buoyancy.as_ref().map(|b| {
        let g = ctx.gravity;
        let up = b.up.unwrap_or(if g.iter().any(|&x| x != 0.0) {
            g.map(|x| -x)
        } else {
            [0.0, 1.0, 0.0]
        });
        Buoyancy {
            up,
            smoke: b.smoke.unwrap_or(0.0),
            heat: b.heat.unwrap_or(0.0),
            ambient: b.ambient.unwrap_or(0.0),
        }
    });
    let mut sources = Vec::new();
    for (k, s) in t.source.iter().enumerate() {
        let key = path(&[&"source", &k]);
        let shape = match (s.center, s.radius, s.min, s.max) {
            (Some(center), Some(radius), None, None) => Obstacle::Sphere { center, radius },
            (None, None, Some(min), Some(max)) => Obstacle::Box { min, max },
            _ => {
                return Err(ctx.error(
                    &key,
                    "a source is a sphere (center, radius) or a box (min, max)",
                ))
            }
        };
        if s.density.is_none() && s.temperature.is_none() && s.velocity.is_none() {
            return Err(ctx.error(&key, "a source sets density, temperature or velocity"));
        }
        sources.push(Source {
            shape,
            density: s.density,
            temperature: s.temperature,
            velocity: s.velocity,
            until: s.until.unwrap_or(f64::INFINITY),
        });
    }
    let max_substeps = match t.max_substeps {
        None => 64,
        Some(m) if (1..=100_000).contains(&m) => m as usize,
        Some(m) => {
            return Err(ctx.error(
                &at("max_substeps"),
                format!("max_substeps must be 1 to 100,000, not {m}"),
            ))
        }
    };
    let obstacles = obstacles(
        ctx,
        ObstacleTables {
            sphere: &t.sphere,
            plane: &t.plane,
            boxes: &t.boxes,
            capsule: &t.capsule,
            sdf: &t.sdf,
        },
    )?;
    let origin = t.origin.unwrap_or([0.0; 3]);
    let mut solid_cells: Option<Vec<bool>> = None;
    for (k, m) in t.mesh.iter().enumerate() {
        let key = path(&[&"mesh", &k]);
        let file = ctx.base.join(&m.file);
        if !crate::io::is_surface_file(&file) {
            return Err(ctx.error(
                &key,
                format!(
                    "{}: a mesh obstacle is a closed surface, .obj or .off",
                    m.file
                ),
            ));
        }
        let mut surface = crate::io::read_surface(&file, ctx.limits.max_file_bytes)
            .map_err(SceneError::from_read)?;
        let scale = ctx.positive(m.scale.unwrap_or(1.0), &key, "scale")?;
        let shift = m.translate.unwrap_or([0.0; 3]);
        if !shift.iter().all(|x| x.is_finite()) {
            return Err(ctx.error(&key, "translate must be finite"));
        }
        let nv = surface.positions.len() / 3;
        for (a, comp) in surface.positions.chunks_mut(nv.max(1)).enumerate().take(3) {
            for v in comp {
                *v = *v * scale + shift[a];
            }
        }
        if surface.triangles.is_empty() || !surface.positions.iter().all(|x| x.is_finite()) {
            return Err(ctx.error(
                &key,
                format!("{}: no triangles, or a vertex that is not finite", m.file),
            ));
        }
        let inside = crate::collide::cells_inside(&surface, origin, h, cells);
        if !inside.iter().any(|&b| b) {
            return Err(ctx.error(
                &key,
                format!(
                    "{}: no cell centre of the grid lies inside it (outside the domain, open, inside out, or thinner than a cell)",
                    m.file
                ),
            ));
        }
        let s = solid_cells.get_or_insert_with(|| vec![false; inside.len()]);
        for (a, b) in s.iter_mut().zip(inside) {
            *a |= b;
        }
    }
    let d = FluidDesc {
        cells,
        h,
        origin,
        boundaries,
        obstacles,
        solid_cells,
        viscosity,
        density: t.density.unwrap_or(1.0),
        force: t.force.unwrap_or([0.0; 3]),
        buoyancy,
        vorticity: t.vorticity.unwrap_or(0.0),
        advection: Advection {
            trace,
            interp,
            correction,
        },
        cfl: t.cfl.unwrap_or(1.0),
        max_substeps,
        poisson: crate::solve::PoissonParams {
            tolerance: t.tolerance.unwrap_or(1e-6),
            max_iterations: 1000,
            preconditioner,
            precision,
        },
        sources,
        initial,
    };
    d.validate().map_err(|e| {
        let key = match &e {
            crate::validate::ModelError::Value { item, field, .. } => match (*item, *field) {
                ("grid", "origin") => at("origin"),
                ("fluid", f) => at(f),
                ("buoyancy", _) => path(&[&"buoyancy"]),
                ("boundary", _) => path(&[&"boundary"]),
                ("initial", _) => at("initial"),
                ("source", _) => at("source"),
                _ => Vec::new(),
            },
            crate::validate::ModelError::Element {
                item: "obstacle",
                index,
                ..
            } => obstacle_key(t, *index),
            crate::validate::ModelError::Element {
                item: "source",
                index,
                ..
            } => path(&[&"source", index]),
            _ => Vec::new(),
        };
        ctx.error(&key, e.to_string())
    })?;
    Ok(d)
}

/// The key of obstacle `i` (obstacles come in the order sphere, plane, box, capsule, sdf).
fn obstacle_key(t: &FluidTable, i: usize) -> Vec<Key> {
    let counts = [
        ("sphere", t.sphere.len()),
        ("plane", t.plane.len()),
        ("box", t.boxes.len()),
        ("capsule", t.capsule.len()),
        ("sdf", t.sdf.len()),
    ];
    let mut i = i;
    for (name, n) in counts {
        if i < n {
            return path(&[&name, &i]);
        }
        i -= n;
    }
    Vec::new()
}

/// Builds the `[fluid]` system.
pub fn build(ctx: &Context<'_>) -> Result<Box<dyn Simulation>, SceneError> {
    let t: FluidTable = ctx.table()?;
    let d = desc(ctx, &t)?;
    let sim = FluidSim::new(&d).map_err(|e| ctx.error(&[], e.to_string()))?;
    Ok(Box::new(sim))
}

/// A running fluid: the model, its state and work (see [`super`]).
pub struct FluidSim {
    fluid: Arc<Fluid>,
    state: FluidState,
    work: FluidWork,
    last: FluidStepInfo,
    /// Steps that were split by the CFL condition, and the most sub-steps one took.
    split_steps: u64,
    most_substeps: usize,
    /// Cell velocity and vorticity of the present state, computed when a frame asks.
    fields: std::sync::OnceLock<(Vec<f64>, Vec<f64>)>,
}

impl FluidSim {
    /// Builds the fluid of `d`.
    pub fn new(d: &FluidDesc) -> Result<FluidSim, FluidError> {
        let (fluid, state, work) = d.build()?;
        let mut sim = FluidSim {
            fluid: Arc::new(fluid),
            state,
            work,
            last: FluidStepInfo::default(),
            split_steps: 0,
            most_substeps: 0,
            fields: std::sync::OnceLock::new(),
        };
        sim.refresh_fields();
        Ok(sim)
    }

    /// One step of `dt` with the fluid's own errors.
    pub fn advance(&mut self, dt: f64) -> Result<FluidStepInfo, FluidError> {
        let info = self.fluid.step(&mut self.state, &mut self.work, dt)?;
        if info.substeps > 1 {
            self.split_steps += 1;
            self.most_substeps = self.most_substeps.max(info.substeps);
        }
        self.last = info;
        self.refresh_fields();
        Ok(info)
    }

    fn refresh_fields(&mut self) {
        self.fields = std::sync::OnceLock::new();
    }

    /// The cell-centred velocity and the vorticity of the present state.
    fn fields(&self) -> &(Vec<f64>, Vec<f64>) {
        self.fields.get_or_init(|| {
            (
                self.fluid.cell_velocity(&self.state),
                self.fluid.vorticity(&self.state),
            )
        })
    }

    /// The model.
    pub fn fluid(&self) -> &Fluid {
        &self.fluid
    }

    /// The state.
    pub fn state(&self) -> &FluidState {
        &self.state
    }

    /// The state, to set a field (the next step starts from it).
    pub fn state_mut(&mut self) -> &mut FluidState {
        self.refresh_fields();
        &mut self.state
    }

    /// What the last step did.
    pub fn last_step(&self) -> FluidStepInfo {
        self.last
    }

    /// The pressure of the last projection (Pa).
    pub fn pressure(&self) -> Vec<f64> {
        let rho = self.fluid.desc().density;
        self.state.pressure.iter().map(|p| rho * p).collect()
    }

    /// Smoke in the domain: the sum of density times cell volume.
    pub fn smoke_mass(&self) -> f64 {
        self.state.density.iter().sum::<f64>() * self.fluid.desc().h.powi(3)
    }

    /// Writes the grid as legacy VTK structured points with cell data: velocity,
    /// pressure, vorticity and the scalars carried.
    pub fn write_vtk(&self, w: &mut dyn std::io::Write, title: &str) -> std::io::Result<()> {
        let d = self.fluid.desc();
        let n = d.cells;
        let cells = d.cell_count();
        writeln!(w, "# vtk DataFile Version 3.0")?;
        writeln!(w, "{}", title.replace('\n', " "))?;
        writeln!(w, "ASCII\nDATASET STRUCTURED_POINTS")?;
        // Points are the cell corners; cell data holds the fields.
        writeln!(w, "DIMENSIONS {} {} {}", n[0] + 1, n[1] + 1, n[2] + 1)?;
        writeln!(w, "ORIGIN {} {} {}", d.origin[0], d.origin[1], d.origin[2])?;
        writeln!(w, "SPACING {} {} {}", d.h, d.h, d.h)?;
        writeln!(w, "CELL_DATA {cells}")?;
        writeln!(w, "VECTORS velocity double")?;
        let (v, vorticity) = self.fields();
        for c in 0..cells {
            writeln!(w, "{} {} {}", v[c], v[cells + c], v[2 * cells + c])?;
        }
        let pressure = self.pressure();
        let mut scalars: Vec<(&str, &[f64])> =
            vec![("pressure", &pressure), ("vorticity", vorticity)];
        if !self.state.density.is_empty() {
            scalars.push(("density", &self.state.density));
        }
        if !self.state.temperature.is_empty() {
            scalars.push(("temperature", &self.state.temperature));
        }
        let solid: Vec<f64>;
        if let Some(s) = self.fluid.solid() {
            solid = s.iter().map(|&b| f64::from(u8::from(b))).collect();
            scalars.push(("solid", &solid));
        }
        for (name, v) in scalars {
            writeln!(w, "SCALARS {name} double 1\nLOOKUP_TABLE default")?;
            for x in v {
                writeln!(w, "{x}")?;
            }
        }
        Ok(())
    }
}

impl Simulation for FluidSim {
    fn step(&mut self, dt: f64) -> Result<StepInfo, IntegrateError> {
        let step = self.state.steps + 1;
        let info = self.advance(dt).map_err(|e| IntegrateError::Failed {
            step,
            why: e.to_string(),
        })?;
        Ok(StepInfo {
            newton_iterations: 0,
            linear_iterations: info.pressure_iterations + info.viscosity_iterations,
            residual: info.residual,
            solve_seconds: info.solve_seconds,
        })
    }

    fn time(&self) -> f64 {
        self.state.time
    }

    fn steps(&self) -> u64 {
        self.state.steps
    }

    fn energy(&self) -> Energy {
        Energy {
            kinetic: self.fluid.kinetic_energy(&self.state),
            potential: 0.0,
            external_work: self.state.external_work,
        }
    }

    fn max_penetration(&self) -> f64 {
        0.0
    }

    fn frame(&self) -> FrameData<'_> {
        let d = self.fluid.desc();
        let (v, w) = self.fields();
        let mut fields = vec![GridField::Speed(v), GridField::Vorticity(w)];
        if !self.state.density.is_empty() {
            fields.push(GridField::Density(&self.state.density));
        }
        FrameData::Grid(GridRef {
            cells: d.cells,
            h: d.h,
            origin: d.origin,
            solid: self.fluid.solid(),
            fields,
        })
    }

    fn stages(&self) -> Vec<Stage> {
        let f = &self.fluid;
        let d = f.desc();
        let n = d.cells;
        let sides: Vec<String> = (0..f.dims())
            .map(|a| {
                let [lo, hi] = d.boundaries[a];
                format!("{} {}/{}", ["x", "y", "z"][a], lo.name(), hi.name())
            })
            .collect();
        let adv = &d.advection;
        vec![
            Stage::built(
                "MAC grid",
                format!(
                    "{}-D, {} x {} x {} cells of {} m; {}",
                    f.dims(),
                    n[0],
                    n[1],
                    n[2],
                    crate::io::human(d.h),
                    sides.join(", ")
                ),
            ),
            Stage::built(
                "semi-Lagrangian advection",
                format!(
                    "{:?} trace, {:?} interpolation, correction {:?}, CFL {}",
                    adv.trace, adv.interp, adv.correction, d.cfl
                ),
            ),
            match f.solid() {
                Some(s) => Stage::built(
                    "solid cell flags",
                    format!("{} solid cells", s.iter().filter(|&&b| b).count()),
                ),
                None => Stage::left_out("solid cell flags", "the scene has no obstacles"),
            },
            Stage::new(
                "viscosity solve",
                f.has_viscosity(),
                if f.has_viscosity() {
                    format!(
                        "implicit, nu = {} m^2/s, Jacobi-preconditioned CG",
                        d.viscosity
                    )
                } else {
                    "viscosity is zero".into()
                },
            ),
            Stage::built(
                "pressure projection",
                format!(
                    "{:?}-preconditioned CG to {:e} ({:?} precision preconditioner), {} multigrid levels",
                    d.poisson.preconditioner,
                    d.poisson.tolerance,
                    d.poisson.precision,
                    self.work.poisson.levels()
                ),
            ),
            Stage::new(
                "smoke density",
                f.has_density(),
                if f.has_density() {
                    "advected"
                } else {
                    "no source or buoyancy uses it"
                },
            ),
            Stage::new(
                "temperature",
                f.has_temperature(),
                if f.has_temperature() {
                    "advected"
                } else {
                    "no source or buoyancy uses it"
                },
            ),
            Stage::new(
                "buoyancy",
                d.buoyancy.is_some(),
                match d.buoyancy {
                    Some(b) => format!("smoke {} m/s^2, heat {} m/s^2/K", b.smoke, b.heat),
                    None => "no [fluid.buoyancy]".into(),
                },
            ),
            Stage::new(
                "vorticity confinement",
                d.vorticity > 0.0,
                if d.vorticity > 0.0 {
                    format!("epsilon = {}", d.vorticity)
                } else {
                    "vorticity = 0".into()
                },
            ),
        ]
    }

    fn scenery(&self, around: ([f64; 3], [f64; 3])) -> Vec<Mesh> {
        let d = self.fluid.desc();
        let mut out: Vec<Mesh> = d
            .obstacles
            .iter()
            .filter_map(|o| o.preview_mesh())
            .collect();
        if let Some(m) = Obstacle::plane_faces(&d.obstacles, around) {
            out.push(m);
        }
        out
    }

    fn method(&self) -> String {
        "stable fluids".into()
    }

    fn linear_solver(&self) -> Option<&'static str> {
        Some(match self.fluid.desc().poisson.preconditioner {
            PoissonPreconditioner::Multigrid => "multigrid-preconditioned CG (pressure)",
            PoissonPreconditioner::Jacobi => "Jacobi-preconditioned CG (pressure)",
        })
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn warnings(&self) -> Vec<String> {
        if self.split_steps == 0 {
            return Vec::new();
        }
        vec![format!(
            "{} steps moved the fluid more than {} cells and were split by the CFL condition (up to {} sub-steps)",
            self.split_steps,
            self.fluid.desc().cfl,
            self.most_substeps
        )]
    }

    fn has_volume(&self) -> bool {
        true
    }

    fn write_volume(&self, w: &mut dyn std::io::Write, comment: &str) -> std::io::Result<()> {
        self.write_vtk(w, comment)
    }
}
