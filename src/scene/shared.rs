//! Tables of the shared services that domains put inside their own: obstacles
//! (`[[<domain>.sphere]]`, `plane`, `box`, `capsule`, `sdf`), wind, a force field and
//! step-size control, with their converters. Each converter validates what it builds and
//! reports errors at the key they came from.
//!
//! ```toml
//! [[cloth.sphere]]            # obstacles (any number of each)
//! center = [0.0, 0.0, 0.0]
//! radius = 0.5
//! # [[cloth.plane]] point, normal; [[cloth.box]] min, max; [[cloth.capsule]] a, b, radius
//! # [[cloth.sdf]] file = "shape.sdf"   (SDFGen text: ni nj nk / origin / dx / values)
//! # [cloth.wind] velocity = [3.0, 0.0, 0.0], drag = 0.5, gust = 0.5, frequency = 1.5
//! # [cloth.step_control] max_strain_change = 0.1, max_halvings = 6   (the cloth's defaults;
//! #                      a mass-spring model's are 0.25 and 6)
//! ```

use super::{path, Context, Key, PathPart, SceneError};
use crate::collide::{Obstacle, SdfGrid};
use crate::loads::{ForceField, Load, Wind};
use crate::simulation::StepControl;
use crate::validate::ModelError;
use serde::Deserialize;

/// `[[<domain>.sphere]]`: a solid ball.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphereTable {
    /// Centre (m).
    pub center: [f64; 3],
    /// Radius (m).
    pub radius: f64,
}

/// `[[<domain>.plane]]`: the half-space behind a plane.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneTable {
    /// A point on the plane (m).
    pub point: [f64; 3],
    /// Outward normal.
    pub normal: [f64; 3],
}

/// `[[<domain>.box]]`: a solid axis-aligned box.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxTable {
    /// Lower corner (m).
    pub min: [f64; 3],
    /// Upper corner (m).
    pub max: [f64; 3],
}

/// `[[<domain>.capsule]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CapsuleTable {
    /// Segment start (m).
    pub a: [f64; 3],
    /// Segment end (m).
    pub b: [f64; 3],
    /// Radius (m).
    pub radius: f64,
}

/// `[[<domain>.sdf]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SdfTable {
    /// An SDFGen text file (relative to the scene file).
    pub file: String,
}

/// `[<domain>.wind]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindTable {
    /// Air velocity (m/s).
    pub velocity: [f64; 3],
    /// Drag coefficient (N s/m^3).
    pub drag: f64,
    /// Relative gust amplitude (default 0).
    #[serde(default)]
    pub gust: f64,
    /// Gust frequency (Hz, default 0).
    #[serde(default)]
    pub frequency: f64,
}

/// `[<domain>.step_control]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepControlTable {
    /// Largest change of any triangle's strain in one step before the step is retried
    /// at half the size.
    #[serde(default)]
    pub max_strain_change: Option<f64>,
    /// How many times a step may be halved before the run fails.
    #[serde(default)]
    pub max_halvings: Option<i64>,
}

/// `[<domain>.force_field]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForceFieldTable {
    /// Box corner the grid spans from (m).
    pub min: [f64; 3],
    /// Opposite corner (m).
    pub max: [f64; 3],
    /// Nodes per axis r (>= 2).
    pub resolution: i64,
    /// r^3 forces `[fx, fy, fz]` (N), node (i, j, k) at entry `i r^2 + j r + k` (the
    /// world files' order: x outermost).
    pub forces: Vec<[f64; 3]>,
}

/// The obstacle tables of a domain table.
#[derive(Clone, Copy, Debug)]
pub struct ObstacleTables<'a> {
    /// `[[<domain>.sphere]]`
    pub sphere: &'a [SphereTable],
    /// `[[<domain>.plane]]`
    pub plane: &'a [PlaneTable],
    /// `[[<domain>.box]]`
    pub boxes: &'a [BoxTable],
    /// `[[<domain>.capsule]]`
    pub capsule: &'a [CapsuleTable],
    /// `[[<domain>.sdf]]`
    pub sdf: &'a [SdfTable],
}

/// The key below the domain's table of a validation error's field: `key` when the table
/// has it, else the table itself.
fn at_key(table: &[Key], field: &str, keys: &[&str]) -> Vec<Key> {
    // `velocity.x` is the key `velocity`.
    let key = field.split('.').next().unwrap_or(field);
    let mut p = table.to_vec();
    if keys.contains(&key) {
        p.extend(path(&[&key]));
    }
    p
}

/// The obstacles, in the order spheres, planes, boxes, capsules, distance grids (the
/// order contacts visit them), each validated; distance-grid files are relative to the
/// scene's folder.
pub fn obstacles(ctx: &Context<'_>, t: ObstacleTables<'_>) -> Result<Vec<Obstacle>, SceneError> {
    let mut out: Vec<(Vec<Key>, Obstacle)> = Vec::new();
    for (k, s) in t.sphere.iter().enumerate() {
        let o = Obstacle::Sphere {
            center: s.center,
            radius: s.radius,
        };
        out.push((path(&[&"sphere", &k]), o));
    }
    for (k, s) in t.plane.iter().enumerate() {
        let at = path(&[&"plane", &k]);
        if !s.point.iter().all(|c| c.is_finite()) {
            let mut p = at.clone();
            p.extend(path(&[&"point"]));
            return Err(ctx.error(&p, format!("must be finite, not {:?}", s.point)));
        }
        let Some(o) = Obstacle::plane_through(s.point, s.normal) else {
            let mut p = at.clone();
            p.extend(path(&[&"normal"]));
            let why = if s.normal.iter().all(|c| c.is_finite()) {
                "must not be zero"
            } else {
                "must be finite"
            };
            return Err(ctx.error(&p, format!("{why}, not {:?}", s.normal)));
        };
        out.push((at, o));
    }
    for (k, s) in t.boxes.iter().enumerate() {
        let o = Obstacle::Box {
            min: s.min,
            max: s.max,
        };
        out.push((path(&[&"box", &k]), o));
    }
    for (k, s) in t.capsule.iter().enumerate() {
        let o = Obstacle::Capsule {
            a: s.a,
            b: s.b,
            radius: s.radius,
        };
        out.push((path(&[&"capsule", &k]), o));
    }
    for (k, s) in t.sdf.iter().enumerate() {
        let file = path(&[&"sdf", &k, &"file"]);
        let grid = SdfGrid::read(&ctx.base.join(&s.file), ctx.limits.max_file_bytes)
            .map_err(|e| ctx.error(&file, e.to_string()))?;
        out.push((
            path(&[&"sdf", &k]),
            Obstacle::Sdf(std::sync::Arc::new(grid)),
        ));
    }
    let keys = ["center", "radius", "min", "max", "a", "b"];
    out.into_iter()
        .enumerate()
        .map(|(i, (at, o))| match o.validate(i) {
            Ok(()) => Ok(o),
            Err(e) => Err(ctx.error(&error_key(&at, &e, &keys), e.to_string())),
        })
        .collect()
}

/// The key of a validation error's field below `table`.
fn error_key(table: &[Key], e: &ModelError, keys: &[&str]) -> Vec<Key> {
    match e {
        ModelError::Value { field, .. } => at_key(table, field, keys),
        _ => table.to_vec(),
    }
}

/// The wind of a `[<domain>.wind]` table, validated.
pub fn wind(ctx: &Context<'_>, t: &WindTable) -> Result<Wind, SceneError> {
    let w = Wind {
        velocity: t.velocity,
        drag: t.drag,
        gust: t.gust,
        frequency: t.frequency,
    };
    let keys = ["velocity", "drag", "gust", "frequency"];
    w.validate()
        .map_err(|e| ctx.error(&error_key(&path(&[&"wind"]), &e, &keys), e.to_string()))?;
    Ok(w)
}

/// The force field of a `[<domain>.force_field]` table, validated.
pub fn force_field(ctx: &Context<'_>, f: &ForceFieldTable) -> Result<ForceField, SceneError> {
    let at = |rest: &[&dyn PathPart]| {
        let mut p = path(&[&"force_field"]);
        p.extend(path(rest));
        p
    };
    let r = f.resolution;
    if !(2..=1000).contains(&r) {
        return Err(ctx.error(
            &at(&[&"resolution"]),
            format!("must be an integer in 2..=1000, not {r}"),
        ));
    }
    let r = r as usize;
    if f.forces.len() != r * r * r {
        return Err(ctx.error(
            &at(&[&"forces"]),
            format!(
                "resolution {r} needs {} forces (r^3), found {}",
                r * r * r,
                f.forces.len()
            ),
        ));
    }
    let field = ForceField::from_samples(r, f.min, f.max, &f.forces);
    field
        .validate()
        .map_err(|e| ctx.error(&at(&[]), e.to_string()))?;
    Ok(field)
}

/// The step-size control of a `[<domain>.step_control]` table (the domain's defaults `d`
/// for what it leaves out).
pub fn step_control(
    ctx: &Context<'_>,
    sc: &StepControlTable,
    d: StepControl,
) -> Result<StepControl, SceneError> {
    let max_strain_change = ctx.positive(
        sc.max_strain_change.unwrap_or(d.max_strain_change),
        &path(&[&"step_control", &"max_strain_change"]),
        "max_strain_change",
    )?;
    let halvings = sc.max_halvings.unwrap_or(d.max_halvings as i64);
    if !(0..=30).contains(&halvings) {
        return Err(ctx.error(
            &path(&[&"step_control", &"max_halvings"]),
            format!("must lie in 0..=30, not {halvings}"),
        ));
    }
    Ok(StepControl {
        max_strain_change,
        max_halvings: halvings as u32,
    })
}
