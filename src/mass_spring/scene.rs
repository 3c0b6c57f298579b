//! The `[mass_spring]` scene table: a chain, a grid, a lattice (the jello cube) or
//! explicit particles and springs, with pins, penalty collisions, a force field and
//! optional step-size control; its conversion to a [`MassSpringDesc`], and the mapping of
//! the model's validation errors to the keys they came from.
//!
//! ```toml
//! [mass_spring]               # one of: chain, grid, lattice, or particle + spring lists
//! pinned = [0]
//! definiteness_fix = true
//! [mass_spring.chain]
//! count = 20                  # anchor, direction optional
//! spacing = 0.05
//! mass = 0.01
//! stiffness = 500.0
//!
//! [mass_spring.lattice]       # the jello cube: structural, shear and bend springs
//! n = [8, 8, 8]
//! size = [1.0, 1.0, 1.0]      # rest extent (m); origin = [x, y, z] optional
//! mass = 0.001953             # per particle (kg)
//! structural = 200.0          # shear, bend, damping, velocity optional
//! [mass_spring.collisions]    # penalty springs (rest length 0) while a point penetrates
//! box_min = [-2.0, -2.0, -2.0]
//! box_max = [2.0, 2.0, 2.0]
//! planes = [[-1.0, 1.0, 1.0, 2.0]]   # a x + b y + c z + d = 0; points stay where they start
//! stiffness = 400.0
//! damping = 0.25
//! [mass_spring.force_field]   # forces (N) on an r^3 grid over [min, max], trilinear
//! min = [-2.0, -2.0, -2.0]
//! max = [2.0, 2.0, 2.0]
//! resolution = 2
//! forces = [[0.0, -0.02, 0.0], ...]  # r^3 entries, x outermost, z innermost
//! ```

use super::{
    chain, estimated_bytes, grid, lattice, CollisionDesc, GridOptions, LatticeOptions,
    MassSpringDesc, SpringDesc,
};
use crate::scene::shared;
use crate::scene::{path, Context, Key, PathPart, SceneError};
use crate::simulation::{MechSimulation, Simulation, StepControl};
use crate::validate::ModelError;
use serde::Deserialize;

/// `[mass_spring]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MassSpringTable {
    /// Pinned particle indices.
    #[serde(default)]
    pub pinned: Vec<i64>,
    /// Clamp the compression term of spring Jacobians (default true).
    #[serde(default)]
    pub definiteness_fix: Option<bool>,
    /// A chain generator.
    #[serde(default)]
    pub chain: Option<ChainTable>,
    /// A grid generator.
    #[serde(default)]
    pub grid: Option<GridTable>,
    /// A 3-D lattice generator (the jello cube).
    #[serde(default)]
    pub lattice: Option<LatticeTable>,
    /// Penalty collisions.
    #[serde(default)]
    pub collisions: Option<CollisionsTable>,
    /// An external force field.
    #[serde(default)]
    pub force_field: Option<shared::ForceFieldTable>,
    /// `[mass_spring.step_control]`: step-size control (default: on for implicit
    /// integrators, off for explicit ones).
    #[serde(default)]
    pub step_control: Option<shared::StepControlTable>,
    /// Explicit particles.
    #[serde(default)]
    pub particle: Vec<ParticleTable>,
    /// Explicit springs.
    #[serde(default)]
    pub spring: Vec<SpringTable>,
}

/// `[mass_spring.chain]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChainTable {
    /// Particles (>= 2).
    pub count: i64,
    /// First particle (m).
    #[serde(default)]
    pub anchor: Option<[f64; 3]>,
    /// Direction of the chain.
    #[serde(default)]
    pub direction: Option<[f64; 3]>,
    /// Distance between particles (m).
    pub spacing: f64,
    /// Mass of each particle (kg).
    pub mass: f64,
    /// Spring stiffness (N/m).
    pub stiffness: f64,
    /// Spring damping (N s/m).
    #[serde(default)]
    pub damping: f64,
}

/// `[mass_spring.grid]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridTable {
    /// Particles along the first axis (>= 2).
    pub nu: i64,
    /// Particles along the second axis (>= 2).
    pub nv: i64,
    /// Extent (m).
    pub size: [f64; 2],
    /// Corner particle position (m).
    #[serde(default)]
    pub origin: Option<[f64; 3]>,
    /// First axis direction.
    #[serde(default)]
    pub u_axis: Option<[f64; 3]>,
    /// Second axis direction.
    #[serde(default)]
    pub v_axis: Option<[f64; 3]>,
    /// Total mass (kg).
    pub mass: f64,
    /// Structural stiffness (N/m).
    pub structural: f64,
    /// Shear stiffness (N/m).
    #[serde(default)]
    pub shear: f64,
    /// Bend stiffness (N/m).
    #[serde(default)]
    pub bend: f64,
    /// Damping of every spring (N s/m).
    #[serde(default)]
    pub damping: f64,
}

/// `[mass_spring.lattice]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LatticeTable {
    /// Particles along x, y, z (each >= 2).
    pub n: [i64; 3],
    /// Rest position of particle (0, 0, 0) (m).
    #[serde(default)]
    pub origin: Option<[f64; 3]>,
    /// Rest extent (m).
    pub size: [f64; 3],
    /// Mass of each particle (kg).
    pub mass: f64,
    /// Structural stiffness (N/m).
    pub structural: f64,
    /// Shear stiffness (N/m).
    #[serde(default)]
    pub shear: f64,
    /// Bend stiffness (N/m).
    #[serde(default)]
    pub bend: f64,
    /// Damping of every spring (N s/m).
    #[serde(default)]
    pub damping: f64,
    /// Initial velocity of every particle (m/s).
    #[serde(default)]
    pub velocity: Option<[f64; 3]>,
}

/// `[mass_spring.collisions]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollisionsTable {
    /// Bounding box corner (m), with `box_max`.
    #[serde(default)]
    pub box_min: Option<[f64; 3]>,
    /// Bounding box corner (m), with `box_min`.
    #[serde(default)]
    pub box_max: Option<[f64; 3]>,
    /// Planes `[a, b, c, d]` of `a x + b y + c z + d = 0`.
    #[serde(default)]
    pub planes: Vec<[f64; 4]>,
    /// Collision spring stiffness (N/m).
    pub stiffness: f64,
    /// Collision spring damping (N s/m).
    #[serde(default)]
    pub damping: f64,
}

/// `[[mass_spring.particle]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParticleTable {
    /// Position (m).
    pub position: [f64; 3],
    /// Velocity (m/s).
    #[serde(default)]
    pub velocity: Option<[f64; 3]>,
    /// Mass (kg).
    pub mass: f64,
    /// Pinned.
    #[serde(default)]
    pub pinned: bool,
}

/// `[[mass_spring.spring]]`
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpringTable {
    /// First particle.
    pub a: i64,
    /// Second particle.
    pub b: i64,
    /// Stiffness (N/m).
    pub stiffness: f64,
    /// Damping (N s/m).
    #[serde(default)]
    pub damping: f64,
    /// Rest length (m); default the initial distance.
    #[serde(default)]
    pub rest_length: Option<f64>,
}

/// Builds the mass-spring system of a scene's `[mass_spring]` table (the registry's
/// entry).
pub fn build(ctx: &Context<'_>) -> Result<Box<dyn Simulation>, SceneError> {
    let t: MassSpringTable = ctx.table()?;
    let (desc, pinned_from_table) = desc(ctx, &t)?;
    let (model, state) = desc
        .build()
        .map_err(|e| ctx.model_error(&e, &error_key(&e, &t, pinned_from_table)))?;
    let sim = MechSimulation::new(model, state, ctx.settings)
        .map_err(|e| ctx.error_at(&path(&[&"scene", &"integrator"]), e.to_string()))?;
    Ok(Box::new(sim))
}

/// The mass-spring description of a `[mass_spring]` table, and how many of its pinned
/// entries come from the `pinned` list (the rest come from `particle.pinned` flags).
pub fn desc(ctx: &Context<'_>, t: &MassSpringTable) -> Result<(MassSpringDesc, usize), SceneError> {
    let at = |f: &[&dyn PathPart]| path(f);
    let sources = t.chain.is_some() as usize
        + t.grid.is_some() as usize
        + t.lattice.is_some() as usize
        + (!t.particle.is_empty()) as usize;
    if sources != 1 {
        return Err(ctx.error(
            &[],
            "give exactly one of [mass_spring.chain], [mass_spring.grid], [mass_spring.lattice] or [[mass_spring.particle]] lists",
        ));
    }
    let mut desc = if let Some(c) = &t.chain {
        if c.count < 2 {
            return Err(ctx.error(
                &at(&[&"chain", &"count"]),
                format!("a chain needs at least 2 particles, not {}", c.count),
            ));
        }
        let n = c.count as f64;
        ctx.memory(
            &at(&[&"chain", &"count"]),
            &format!("a chain of {} particles", c.count),
            estimated(ctx, n, n - 1.0),
        )?;
        let spacing = ctx.positive(c.spacing, &at(&[&"chain", &"spacing"]), "spacing")?;
        let mass = ctx.positive(c.mass, &at(&[&"chain", &"mass"]), "mass")?;
        let k = ctx.non_negative(c.stiffness, &at(&[&"chain", &"stiffness"]), "stiffness")?;
        let kd = ctx.non_negative(c.damping, &at(&[&"chain", &"damping"]), "damping")?;
        let dir = c.direction.unwrap_or([1.0, 0.0, 0.0]);
        if !dir.iter().all(|v| v.is_finite()) || dir.iter().all(|&v| v == 0.0) {
            return Err(ctx.error(
                &at(&[&"chain", &"direction"]),
                "must be a finite, non-zero vector",
            ));
        }
        chain(
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
                return Err(ctx.error(
                    &at(&[&"grid", &name]),
                    format!("a grid needs at least 2 particles per side, not {v}"),
                ));
            }
        }
        for (i, &s) in g.size.iter().enumerate() {
            ctx.positive(s, &at(&[&"grid", &"size", &i]), "size")?;
        }
        // Structural, shear and bend springs: about 6 per particle.
        let n = g.nu as f64 * g.nv as f64;
        ctx.memory(
            &at(&[&"grid"]),
            &format!("a {} x {} spring grid", g.nu, g.nv),
            estimated(ctx, n, 6.0 * n),
        )?;
        let [mass, structural, shear, bend, damping] = constants(
            ctx,
            "grid",
            [g.mass, g.structural, g.shear, g.bend, g.damping],
        )?;
        let d = grid(&GridOptions {
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
            return Err(ctx.error(&at(&[&"grid"]), "origin and axes must be finite"));
        }
        d
    } else if let Some(l) = &t.lattice {
        for (a, &v) in l.n.iter().enumerate() {
            if !(2..=1024).contains(&v) {
                return Err(ctx.error(
                    &at(&[&"lattice", &"n", &a]),
                    format!("a lattice needs 2..=1024 particles per side, not {v}"),
                ));
            }
        }
        for (i, &s) in l.size.iter().enumerate() {
            ctx.positive(s, &at(&[&"lattice", &"size", &i]), "size")?;
        }
        // Structural, face and body diagonal, and bend springs: about 16 per particle.
        let n = l.n.iter().map(|&v| v as f64).product::<f64>();
        ctx.memory(
            &at(&[&"lattice", &"n"]),
            &format!("a {} x {} x {} lattice", l.n[0], l.n[1], l.n[2]),
            estimated(ctx, n, 16.0 * n),
        )?;
        let [mass, structural, shear, bend, damping] = constants(
            ctx,
            "lattice",
            [l.mass, l.structural, l.shear, l.bend, l.damping],
        )?;
        let origin = l.origin.unwrap_or([0.0; 3]);
        if !origin.iter().all(|v| v.is_finite()) {
            return Err(ctx.error(&at(&[&"lattice", &"origin"]), "must be finite"));
        }
        let mut d = lattice(&LatticeOptions {
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
        return Err(ctx.error(
            &at(&[&"spring"]),
            "springs come from the generator; list springs only with explicit particles",
        ));
    }
    for (k, s) in t.spring.iter().enumerate() {
        let a = ctx.index(s.a, &at(&[&"spring", &k, &"a"]), "particle")?;
        let b = ctx.index(s.b, &at(&[&"spring", &k, &"b"]), "particle")?;
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
        pinned.push(ctx.index(p, &at(&[&"pinned", &k]), "particle")?);
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
                return Err(ctx.error(&at(&[&"collisions", &"box_min"]), "needs box_max as well"))
            }
            (None, Some(_)) => {
                return Err(ctx.error(&at(&[&"collisions", &"box_max"]), "needs box_min as well"))
            }
        };
        desc.collisions = Some(CollisionDesc {
            bounds,
            planes: c.planes.clone(),
            obstacles: Vec::new(),
            stiffness: c.stiffness,
            damping: c.damping,
        });
    }
    if let Some(f) = &t.force_field {
        desc.force_field = Some(shared::force_field(ctx, f)?);
    }
    // Implicit steps get step-size control by default, as the cloth's do: one linearised
    // step of a chain at dt = 1 s stretched it from 0.95 m to 58.7 m and back without a
    // word. Explicit steps are limited by stability, not by strain: off unless asked.
    desc.step_control = match &t.step_control {
        Some(sc) => Some(shared::step_control(ctx, sc, StepControl::default())?),
        None => ctx.implicit().then(StepControl::default),
    };
    desc.gravity = ctx.gravity;
    desc.definiteness_fix = t.definiteness_fix.unwrap_or(true);
    Ok((desc, from_table))
}

/// The memory a system of `particles` and `springs` needs with the scene's integrator.
fn estimated(ctx: &Context<'_>, particles: f64, springs: f64) -> f64 {
    estimated_bytes(particles, springs, ctx.implicit(), ctx.cholesky(particles))
}

/// A grid's or lattice's `[mass, structural, shear, bend, damping]`, checked at their keys
/// in `[mass_spring.<generator>]`: the mass > 0, the stiffnesses and damping >= 0.
fn constants(ctx: &Context<'_>, generator: &str, v: [f64; 5]) -> Result<[f64; 5], SceneError> {
    let names = ["mass", "structural", "shear", "bend", "damping"];
    let mut out = [0.0; 5];
    for (k, (&x, name)) in v.iter().zip(names).enumerate() {
        let at = path(&[&generator, &name]);
        out[k] = match name {
            "mass" => ctx.positive(x, &at, "mass")?,
            "damping" => ctx.non_negative(x, &at, "damping")?,
            _ => ctx.non_negative(x, &at, "stiffness")?,
        };
    }
    Ok(out)
}

/// The key below `[mass_spring]` a model validation error refers to.
fn error_key(e: &ModelError, t: &MassSpringTable, pinned_from_table: usize) -> Vec<Key> {
    match e {
        ModelError::Value {
            item: "particle",
            index,
            field,
            ..
        } => {
            let f = field.split('.').next().unwrap_or(field);
            path(&[&"particle", index, &f])
        }
        ModelError::Value {
            item: "spring",
            index,
            field,
            ..
        } => path(&[&"spring", index, field]),
        ModelError::Missing {
            item: "spring",
            index,
            named,
            ..
        } => {
            let end = if t.spring.get(*index).is_some_and(|s| s.a == *named as i64) {
                "a"
            } else {
                "b"
            };
            path(&[&"spring", index, &end])
        }
        ModelError::Element {
            item: "spring",
            index,
            ..
        } => path(&[&"spring", index, &"b"]),
        ModelError::Value {
            item: "plane",
            index,
            ..
        } => path(&[&"collisions", &"planes", index]),
        ModelError::Value {
            item: "collisions",
            field,
            ..
        } => path(&[&"collisions", field]),
        ModelError::Value {
            item: "collisions.box",
            index,
            field,
            ..
        } => path(&[&"collisions", &format!("box_{field}").as_str(), index]),
        ModelError::Value { item, .. } | ModelError::Length { what: item, .. }
            if item.starts_with("force_field") =>
        {
            path(&[&"force_field"])
        }
        ModelError::Missing {
            item: "pinned",
            index,
            ..
        } if *index < pinned_from_table => path(&[&"pinned", index]),
        _ => Vec::new(),
    }
}
