//! The `[rigid]` scene table and [`RigidSim`], the rigid bodies' [`Simulation`].
//!
//! ```toml
//! [scene]
//! name = "box-stack"
//! dt = 0.0166667
//! duration = 10.0
//!
//! [rigid]                       # every key optional
//! gravity = [0.0, -9.81, 0.0]   # m/s^2 (default: [scene] gravity, else -9.81 along y)
//! solver = "sequential-impulses" # or "impulse" (one-shot), "penalty" (springs)
//! iterations = 4                # sub-steps per step, one pass over the rows each
//! restitution = 0.0             # 0..=1
//! friction = 0.5                # Coulomb coefficient
//! integrator = "symplectic-euler" # or "explicit-euler", "rk4", "implicit-gyroscopic"
//! correction = "soft"           # or "split", "baumgarte"
//! stiffness = 1e6               # penalty only (N/m per point; default from the masses)
//! damping = 1e3                 # penalty only (N s/m)
//! sleeping = false              # bodies at rest sleep until touched (Box2D's thresholds)
//! contact_reuse = 0.005         # keep a pair's contacts while its pose moves less than
//!                               # this fraction of the size (and rad); 0: never
//!
//! [[rigid.body]]
//! shape = { box = [0.5, 0.5, 0.5] }  # half extents; or { sphere = r },
//!                               # { capsule = [half_height, radius] } (along y),
//!                               # { mesh = "t-handle.obj", scale = 1.0 } (closed)
//! density = 1000.0              # kg/m^3
//! position = [0.0, 0.5, 0.0]    # m, where the shape's origin goes
//! orientation = [1.0, 0.0, 0.0, 0.0]  # w, x, y, z (normalised; zero is an error)
//! velocity = [0.0, 0.0, 0.0]    # m/s
//! angular_velocity = [0.0, 0.0, 0.0]  # rad/s, world frame
//! static = false                # never moves
//! kinematic = false             # moves at its velocity, pushed by nothing
//!
//! [[rigid.array]]               # a block of equal bodies: the body keys, and
//! count = [10, 10, 10]          # along x, y, z
//! spacing = [1.1, 1.1, 1.1]     # m between neighbours' origins
//! jitter = 0.05                 # m, a fixed pseudo-random offset of each body
//! tilt = 0.3                    # rad, a fixed pseudo-random turn of each body
//!
//! # Witkin's constrained particles instead of bodies (a system holds one or the other):
//! feedback = [0.0, 0.0]         # [rigid]: ks (1/s^2) and kd (1/s) pulling drift back
//! [[rigid.particle]]
//! position = [1.0, 2.0, 0.0]    # m
//! velocity = [0.0, 0.0, 0.0]    # m/s
//! mass = 1.0                    # kg
//! pinned = false
//! [[rigid.constraint]]
//! type = "distance"             # distance (a, b), anchor (a, point), circle (a, center, normal)
//! a = 0
//! b = 1
//! length = 1.0                  # m (default: the start distance; the circle's radius)
//!
//! [[rigid.joint]]
//! type = "hinge"                # ball, hinge, fixed, distance
//! a = 1                         # body index (bodies first, then arrays' bodies in order)
//! b = 2                         # omitted: the world
//! anchor = [0.0, 1.0, 0.0]      # m (ball, hinge, fixed)
//! axis = [0.0, 0.0, 1.0]        # hinge
//! anchor_a = [0.0, 1.0, 0.0]    # distance: the anchors on a and on b (or the world)
//! anchor_b = [0.0, 2.0, 0.0]
//! ```

use super::sleep::Sleep;
use super::witkin::{Constraint, Witkin, WitkinError, WitkinIntegrator, WitkinState, WitkinWork};
use super::{
    BodyDesc, Correction, JointDesc, JointKind, Motion, Rigid, RigidDesc, RigidError,
    RigidIntegrator, RigidSolver, RigidState, RigidStepInfo, RigidWork, Shape,
};
use crate::integrate::{IntegrateError, StepInfo};
use crate::io::{Mesh, MeshRef};
use crate::scene::{path, Context, Key, SceneError};
use crate::simulation::{BodyImpulse, ContactImpulses, Energy, FrameData, Simulation, Stage};
use largestep_kernels::{quat, v3};
use serde::Deserialize;
use std::sync::Arc;
use std::time::Instant;

/// `[rigid]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigidTable {
    #[serde(default)]
    pub gravity: Option<[f64; 3]>,
    #[serde(default)]
    pub solver: Option<String>,
    #[serde(default)]
    pub iterations: Option<i64>,
    #[serde(default)]
    pub restitution: Option<f64>,
    #[serde(default)]
    pub friction: Option<f64>,
    #[serde(default)]
    pub integrator: Option<String>,
    #[serde(default)]
    pub correction: Option<String>,
    #[serde(default)]
    pub stiffness: Option<f64>,
    #[serde(default)]
    pub damping: Option<f64>,
    #[serde(default)]
    pub sleeping: Option<bool>,
    #[serde(default)]
    pub contact_reuse: Option<f64>,
    #[serde(default)]
    pub body: Vec<BodyTable>,
    #[serde(default)]
    pub array: Vec<ArrayTable>,
    #[serde(default)]
    pub joint: Vec<JointTable>,
    #[serde(default)]
    pub feedback: Option<[f64; 2]>,
    #[serde(default)]
    pub particle: Vec<ParticleTable>,
    #[serde(default)]
    pub constraint: Vec<ConstraintTable>,
}

/// `[[rigid.particle]]`: a point mass of Witkin's constrained dynamics.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParticleTable {
    pub position: [f64; 3],
    #[serde(default)]
    pub velocity: Option<[f64; 3]>,
    #[serde(default)]
    pub mass: Option<f64>,
    #[serde(default)]
    pub pinned: Option<bool>,
}

/// `[[rigid.constraint]]`: a constraint on particles.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConstraintTable {
    #[serde(rename = "type")]
    pub kind: String,
    pub a: i64,
    #[serde(default)]
    pub b: Option<i64>,
    #[serde(default)]
    pub point: Option<[f64; 3]>,
    #[serde(default)]
    pub center: Option<[f64; 3]>,
    #[serde(default)]
    pub normal: Option<[f64; 3]>,
    #[serde(default)]
    pub length: Option<f64>,
}

/// `shape = { box = [..] }` and the others.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShapeTable {
    #[serde(default, rename = "box")]
    pub cuboid: Option<[f64; 3]>,
    #[serde(default)]
    pub sphere: Option<f64>,
    #[serde(default)]
    pub capsule: Option<[f64; 2]>,
    #[serde(default)]
    pub mesh: Option<String>,
    /// Mesh only: a factor on the file's coordinates.
    #[serde(default)]
    pub scale: Option<f64>,
}

/// `[[rigid.body]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyTable {
    pub shape: ShapeTable,
    #[serde(default)]
    pub density: Option<f64>,
    #[serde(default)]
    pub position: Option<[f64; 3]>,
    #[serde(default)]
    pub orientation: Option<[f64; 4]>,
    #[serde(default)]
    pub velocity: Option<[f64; 3]>,
    #[serde(default)]
    pub angular_velocity: Option<[f64; 3]>,
    #[serde(default, rename = "static")]
    pub fixed: Option<bool>,
    #[serde(default)]
    pub kinematic: Option<bool>,
}

/// `[[rigid.array]]`: a body and how it repeats.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArrayTable {
    pub shape: ShapeTable,
    pub count: [i64; 3],
    pub spacing: [f64; 3],
    #[serde(default)]
    pub jitter: Option<f64>,
    #[serde(default)]
    pub tilt: Option<f64>,
    #[serde(default)]
    pub density: Option<f64>,
    #[serde(default)]
    pub position: Option<[f64; 3]>,
    #[serde(default)]
    pub orientation: Option<[f64; 4]>,
    #[serde(default)]
    pub velocity: Option<[f64; 3]>,
    #[serde(default)]
    pub angular_velocity: Option<[f64; 3]>,
    #[serde(default, rename = "static")]
    pub fixed: Option<bool>,
    #[serde(default)]
    pub kinematic: Option<bool>,
}

/// `[[rigid.joint]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointTable {
    #[serde(rename = "type")]
    pub kind: String,
    pub a: i64,
    #[serde(default)]
    pub b: Option<i64>,
    #[serde(default)]
    pub anchor: Option<[f64; 3]>,
    #[serde(default)]
    pub axis: Option<[f64; 3]>,
    #[serde(default)]
    pub anchor_a: Option<[f64; 3]>,
    #[serde(default)]
    pub anchor_b: Option<[f64; 3]>,
}

/// Bodies a scene may hold at most (each costs about a kilobyte with its contacts).
const BYTES_PER_BODY: f64 = 1024.0;

fn shape(ctx: &Context<'_>, at: &[Key], t: &ShapeTable) -> Result<Shape, SceneError> {
    let given = [
        t.cuboid.is_some(),
        t.sphere.is_some(),
        t.capsule.is_some(),
        t.mesh.is_some(),
    ];
    if given.iter().filter(|&&g| g).count() != 1 {
        return Err(ctx.error(
            at,
            "a shape is one of { box = [hx, hy, hz] }, { sphere = r }, { capsule = [half_height, radius] }, { mesh = \"file.obj\" }",
        ));
    }
    if t.scale.is_some() && t.mesh.is_none() {
        return Err(ctx.error(at, "scale applies to a mesh shape only"));
    }
    let pos = |v: f64, what: &str| ctx.positive(v, at, what);
    Ok(if let Some(h) = t.cuboid {
        for v in h {
            pos(v, "each half extent of a box")?;
        }
        Shape::Box { half: h }
    } else if let Some(r) = t.sphere {
        Shape::Sphere {
            radius: pos(r, "a sphere's radius")?,
        }
    } else if let Some([hh, r]) = t.capsule {
        Shape::Capsule {
            half_height: ctx.non_negative(hh, at, "a capsule's half height")?,
            radius: pos(r, "a capsule's radius")?,
        }
    } else {
        let name = t.mesh.as_deref().unwrap_or_default();
        let file = ctx.base.join(name);
        if !crate::io::is_surface_file(&file) {
            return Err(ctx.error(
                at,
                format!("{name}: a mesh shape is a closed surface, .obj or .off"),
            ));
        }
        // A file that cannot be read is reported at the shape that names it.
        let mut m = crate::io::read_surface(&file, ctx.limits.max_file_bytes)
            .map_err(|e| ctx.error(at, e.to_string()))?;
        let s = pos(t.scale.unwrap_or(1.0), "scale")?;
        for p in m.positions.iter_mut() {
            *p *= s;
        }
        // Mass properties need a closed, outward mesh: say which file is not.
        super::mass::mesh(&m, 1.0).map_err(|e| ctx.error(at, format!("{name}: {e}")))?;
        Shape::Mesh(Arc::new(m))
    })
}

fn finite3(
    ctx: &Context<'_>,
    at: &[Key],
    v: Option<[f64; 3]>,
    what: &str,
) -> Result<[f64; 3], SceneError> {
    let v = v.unwrap_or([0.0; 3]);
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(ctx.error(at, format!("{what} must be finite, not {v:?}")))
    }
}

/// The body of a table's keys (shared by bodies and arrays), and a warning for a
/// non-unit orientation.
#[allow(clippy::too_many_arguments)]
fn body(
    ctx: &Context<'_>,
    at: &[Key],
    shape: Shape,
    density: Option<f64>,
    position: Option<[f64; 3]>,
    orientation: Option<[f64; 4]>,
    velocity: Option<[f64; 3]>,
    angular_velocity: Option<[f64; 3]>,
    fixed: Option<bool>,
    kinematic: Option<bool>,
    warnings: &mut Vec<String>,
) -> Result<BodyDesc, SceneError> {
    let key = |k: &str| {
        let mut p = at.to_vec();
        p.push(Key::Field(k.into()));
        p
    };
    let motion = match (fixed.unwrap_or(false), kinematic.unwrap_or(false)) {
        (true, true) => return Err(ctx.error(at, "a body is static or kinematic, not both")),
        (true, false) => Motion::Static,
        (false, true) => Motion::Kinematic,
        _ => Motion::Dynamic,
    };
    let density = ctx.positive(density.unwrap_or(1000.0), &key("density"), "density")?;
    let q = orientation.unwrap_or([1.0, 0.0, 0.0, 0.0]);
    let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
    if !(norm.is_finite() && norm > 0.0) {
        return Err(ctx.error(
            &key("orientation"),
            format!("orientation {q:?} is zero or not finite: a rotation needs a unit quaternion [w, x, y, z]"),
        ));
    }
    if (norm - 1.0).abs() > 1e-6 {
        warnings.push(format!(
            "{}: orientation {q:?} has norm {norm}; normalised",
            crate::scene::dotted_key(&key("orientation"))
        ));
    }
    Ok(BodyDesc {
        shape,
        density,
        position: finite3(ctx, &key("position"), position, "position")?,
        orientation: q.map(|c| c / norm),
        velocity: finite3(ctx, &key("velocity"), velocity, "velocity")?,
        angular_velocity: finite3(
            ctx,
            &key("angular_velocity"),
            angular_velocity,
            "angular_velocity",
        )?,
        motion,
    })
}

/// A fixed pseudo-random number in [-1, 1] of `k` (splitmix64).
fn hash_unit(k: u64) -> f64 {
    let mut z = k.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Converts the table into a description (errors located at their keys) and the
/// warnings it raised.
pub fn desc(ctx: &Context<'_>, t: &RigidTable) -> Result<(RigidDesc, Vec<String>), SceneError> {
    let at = |k: &str| path(&[&k]);
    let mut warnings = Vec::new();
    let gravity = match t.gravity {
        Some(g) => finite3(ctx, &at("gravity"), Some(g), "gravity")?,
        None if ctx.gravity != [0.0; 3] => ctx.gravity,
        None => [0.0, -9.81, 0.0],
    };
    let solver = match t.solver.as_deref().unwrap_or("sequential-impulses") {
        "sequential-impulses" => RigidSolver::SequentialImpulses,
        "impulse" => RigidSolver::Impulse,
        "penalty" => RigidSolver::Penalty {
            stiffness: t
                .stiffness
                .map(|k| ctx.positive(k, &at("stiffness"), "stiffness"))
                .transpose()?,
            damping: t
                .damping
                .map(|c| ctx.non_negative(c, &at("damping"), "damping"))
                .transpose()?,
        },
        o => {
            return Err(ctx.error(
                &at("solver"),
                format!("unknown solver `{o}`; one of: sequential-impulses, impulse, penalty"),
            ))
        }
    };
    if !matches!(solver, RigidSolver::Penalty { .. }) {
        for (k, v) in [("stiffness", t.stiffness), ("damping", t.damping)] {
            if v.is_some() {
                return Err(ctx.error(&at(k), format!("{k} applies to solver = \"penalty\" only")));
            }
        }
    }
    let iterations = match t.iterations.unwrap_or(4) {
        i @ 1..=1000 => i as usize,
        i => {
            return Err(ctx.error(
                &at("iterations"),
                format!("iterations must be 1 to 1,000, not {i}"),
            ))
        }
    };
    let unit = |v: Option<f64>, k: &str, default: f64, hi: f64| -> Result<f64, SceneError> {
        let v = v.unwrap_or(default);
        if v.is_finite() && (0.0..=hi).contains(&v) {
            Ok(v)
        } else {
            Err(ctx.error(
                &at(k),
                if hi == 1.0 {
                    format!("{k} must be in 0..=1, not {v}")
                } else {
                    format!("{k} must be a finite number >= 0, not {v}")
                },
            ))
        }
    };
    let restitution = unit(t.restitution, "restitution", 0.0, 1.0)?;
    let friction = unit(t.friction, "friction", 0.5, f64::INFINITY)?;
    let contact_reuse = unit(t.contact_reuse, "contact_reuse", super::contact::REUSE, 1.0)?;
    let name = t.integrator.as_deref().unwrap_or("symplectic-euler");
    let integrator = RigidIntegrator::from_name(name).ok_or_else(|| {
        ctx.error(
            &at("integrator"),
            format!(
                "unknown integrator `{name}`; one of: {}",
                RigidIntegrator::NAMES.join(", ")
            ),
        )
    })?;
    let correction = match t.correction.as_deref().unwrap_or("soft") {
        "soft" => Correction::Soft,
        "split" => Correction::Split,
        "baumgarte" => Correction::Baumgarte,
        o => {
            return Err(ctx.error(
                &at("correction"),
                format!("unknown correction `{o}`; one of: soft, split, baumgarte"),
            ))
        }
    };
    // Count before building anything.
    let mut total = t.body.len() as f64;
    for (k, a) in t.array.iter().enumerate() {
        let key = path(&[&"array", &k, &"count"]);
        if a.count.iter().any(|&c| !(1..=1_000_000).contains(&c)) {
            return Err(ctx.error(
                &key,
                format!("each count must be 1 to 1,000,000, not {:?}", a.count),
            ));
        }
        total += a.count.iter().map(|&c| c as f64).product::<f64>();
        ctx.memory(
            &path(&[&"array", &k]),
            &format!("{total} rigid bodies"),
            total * BYTES_PER_BODY,
        )?;
    }
    ctx.memory(
        &at("body"),
        &format!("{total} rigid bodies"),
        total * BYTES_PER_BODY,
    )?;
    let mut bodies = Vec::with_capacity(total as usize);
    for (k, b) in t.body.iter().enumerate() {
        let key = path(&[&"body", &k]);
        let mut sk = key.clone();
        sk.push(Key::Field("shape".into()));
        let s = shape(ctx, &sk, &b.shape)?;
        bodies.push(body(
            ctx,
            &key,
            s,
            b.density,
            b.position,
            b.orientation,
            b.velocity,
            b.angular_velocity,
            b.fixed,
            b.kinematic,
            &mut warnings,
        )?);
    }
    for (k, a) in t.array.iter().enumerate() {
        let key = path(&[&"array", &k]);
        let mut sk = key.clone();
        sk.push(Key::Field("shape".into()));
        let s = shape(ctx, &sk, &a.shape)?;
        let first = body(
            ctx,
            &key,
            s,
            a.density,
            a.position,
            a.orientation,
            a.velocity,
            a.angular_velocity,
            a.fixed,
            a.kinematic,
            &mut warnings,
        )?;
        let spacing = finite3(
            ctx,
            &path(&[&"array", &k, &"spacing"]),
            Some(a.spacing),
            "spacing",
        )?;
        let jitter = ctx.non_negative(
            a.jitter.unwrap_or(0.0),
            &path(&[&"array", &k, &"jitter"]),
            "jitter",
        )?;
        let tilt = ctx.non_negative(
            a.tilt.unwrap_or(0.0),
            &path(&[&"array", &k, &"tilt"]),
            "tilt",
        )?;
        let [nx, ny, nz] = a.count.map(|c| c as usize);
        for j in 0..ny {
            for kz in 0..nz {
                for i in 0..nx {
                    let id = bodies.len() as u64;
                    let mut b = first.clone();
                    let cell = [i, j, kz];
                    for c in 0..3 {
                        b.position[c] +=
                            cell[c] as f64 * spacing[c] + jitter * hash_unit(3 * id + c as u64);
                    }
                    if tilt > 0.0 {
                        let turn = [0, 1, 2].map(|c| tilt * hash_unit((3 * id + c) ^ 0x5EED));
                        b.orientation = largestep_kernels::quat::mul(
                            largestep_kernels::quat::exp(turn),
                            b.orientation,
                        );
                    }
                    bodies.push(b);
                }
            }
        }
    }
    let n = bodies.len();
    let mut joints = Vec::with_capacity(t.joint.len());
    for (k, j) in t.joint.iter().enumerate() {
        let key = |f: &str| path(&[&"joint", &k, &f]);
        let index = |v: i64, f: &str| -> Result<usize, SceneError> {
            let i = ctx.index(v, &key(f), "body")?;
            if i >= n {
                return Err(ctx.error(
                    &key(f),
                    format!(
                        "body {i} does not exist: the scene has {n} bodies (0 to {})",
                        n.saturating_sub(1)
                    ),
                ));
            }
            Ok(i)
        };
        let a = index(j.a, "a")?;
        let b = j.b.map(|b| index(b, "b")).transpose()?;
        let need = |v: Option<[f64; 3]>, f: &str| -> Result<[f64; 3], SceneError> {
            let v = v.ok_or_else(|| {
                ctx.error(
                    &path(&[&"joint", &k]),
                    format!("a {} joint needs `{f}`", j.kind),
                )
            })?;
            finite3(ctx, &key(f), Some(v), f)
        };
        let kind = match j.kind.as_str() {
            "ball" => JointKind::Ball {
                anchor: need(j.anchor, "anchor")?,
            },
            "fixed" => JointKind::Fixed {
                anchor: need(j.anchor, "anchor")?,
            },
            "hinge" => JointKind::Hinge {
                anchor: need(j.anchor, "anchor")?,
                axis: need(j.axis, "axis")?,
            },
            "distance" => JointKind::Distance {
                anchor_a: need(j.anchor_a, "anchor_a")?,
                anchor_b: need(j.anchor_b, "anchor_b")?,
            },
            o => {
                return Err(ctx.error(
                    &key("type"),
                    format!("unknown joint type `{o}`; one of: ball, hinge, fixed, distance"),
                ))
            }
        };
        joints.push(JointDesc { a, b, kind });
    }
    if n == 0 {
        return Err(ctx.error(
            &[],
            "the rigid system has no bodies: add [[rigid.body]] or [[rigid.array]]",
        ));
    }
    Ok((
        RigidDesc {
            bodies,
            joints,
            gravity,
            solver,
            integrator,
            iterations,
            restitution,
            friction,
            correction,
            beta: None,
            // About 2 kB a pair (contacts and solver rows): what the memory budget holds.
            max_pairs: ((ctx.limits.max_memory / 2048) as usize).max(1024),
            sleep: t.sleeping.unwrap_or(false).then(Sleep::default),
            contact_reuse,
        },
        warnings,
    ))
}

/// Builds the `[rigid]` system: rigid bodies, or Witkin's constrained particles.
pub fn build(ctx: &Context<'_>) -> Result<Box<dyn Simulation>, SceneError> {
    let t: RigidTable = ctx.table()?;
    if !t.particle.is_empty() || !t.constraint.is_empty() {
        return Ok(Box::new(witkin(ctx, &t)?));
    }
    if t.feedback.is_some() {
        return Err(ctx.error(
            &path(&[&"feedback"]),
            "feedback applies to [[rigid.particle]] systems",
        ));
    }
    let (d, warnings) = desc(ctx, &t)?;
    let mut sim = RigidSim::new(&d).map_err(|e| {
        let key = match &e {
            RigidError::Body { body, .. } => body_key(&t, *body),
            RigidError::Joint { joint, .. } => path(&[&"joint", joint]),
            _ => Vec::new(),
        };
        ctx.error(&key, e.to_string())
    })?;
    sim.warnings = warnings;
    Ok(Box::new(sim))
}

/// The Witkin system of `[[rigid.particle]]` and `[[rigid.constraint]]`.
fn witkin(ctx: &Context<'_>, t: &RigidTable) -> Result<WitkinSim, SceneError> {
    if !t.body.is_empty() || !t.array.is_empty() || !t.joint.is_empty() {
        return Err(ctx.error(
            &path(&[&"particle"]),
            "a [rigid] system holds bodies (with joints) or Witkin particles (with constraints), not both",
        ));
    }
    for k in [
        "solver",
        "correction",
        "stiffness",
        "damping",
        "restitution",
        "friction",
        "iterations",
        "sleeping",
        "contact_reuse",
    ] {
        let given = match k {
            "solver" => t.solver.is_some(),
            "correction" => t.correction.is_some(),
            "stiffness" => t.stiffness.is_some(),
            "damping" => t.damping.is_some(),
            "restitution" => t.restitution.is_some(),
            "friction" => t.friction.is_some(),
            "sleeping" => t.sleeping.is_some(),
            "contact_reuse" => t.contact_reuse.is_some(),
            _ => t.iterations.is_some(),
        };
        if given {
            return Err(ctx.error(
                &path(&[&k]),
                format!("{k} applies to rigid bodies, not to Witkin particles"),
            ));
        }
    }
    let n = t.particle.len();
    if n == 0 {
        return Err(ctx.error(
            &path(&[&"constraint"]),
            "constraints need [[rigid.particle]]",
        ));
    }
    ctx.memory(
        &path(&[&"particle"]),
        &format!("{n} particles"),
        n as f64 * 256.0,
    )?;
    let rows: f64 = t
        .constraint
        .iter()
        .map(|c| if c.kind == "circle" { 2.0 } else { 1.0 })
        .sum();
    // J W Jᵀ is dense: rows² doubles.
    ctx.memory(
        &path(&[&"constraint"]),
        &format!("{rows} constraint rows"),
        8.0 * rows * rows,
    )?;
    let mut s = WitkinState::default();
    let mut inv_mass = Vec::with_capacity(n);
    for (k, p) in t.particle.iter().enumerate() {
        let key = path(&[&"particle", &k]);
        s.x.push(finite3(ctx, &key, Some(p.position), "position")?);
        s.v.push(finite3(ctx, &key, p.velocity, "velocity")?);
        let m = ctx.positive(p.mass.unwrap_or(1.0), &key, "mass")?;
        inv_mass.push(if p.pinned.unwrap_or(false) {
            0.0
        } else {
            1.0 / m
        });
        if p.pinned.unwrap_or(false) {
            s.v[k] = [0.0; 3];
        }
    }
    let mut constraints = Vec::with_capacity(t.constraint.len());
    for (k, c) in t.constraint.iter().enumerate() {
        let key = |f: &str| path(&[&"constraint", &k, &f]);
        let particle = |v: i64, f: &str| -> Result<usize, SceneError> {
            let i = ctx.index(v, &key(f), "particle")?;
            if i >= n {
                return Err(ctx.error(
                    &key(f),
                    format!("particle {i} does not exist: there are {n}"),
                ));
            }
            Ok(i)
        };
        let a = particle(c.a, "a")?;
        let need = |v: Option<[f64; 3]>, f: &str| -> Result<[f64; 3], SceneError> {
            let v = v.ok_or_else(|| {
                ctx.error(
                    &path(&[&"constraint", &k]),
                    format!("a {} constraint needs `{f}`", c.kind),
                )
            })?;
            finite3(ctx, &key(f), Some(v), f)
        };
        let dist = |p: [f64; 3], q: [f64; 3]| {
            let d = largestep_kernels::v3::sub(p, q);
            largestep_kernels::v3::dot(d, d).sqrt()
        };
        let length = |start: f64| -> Result<f64, SceneError> {
            ctx.positive(c.length.unwrap_or(start), &key("length"), "length")
        };
        constraints.push(match c.kind.as_str() {
            "distance" => {
                let b = particle(
                    c.b.ok_or_else(|| {
                        ctx.error(
                            &path(&[&"constraint", &k]),
                            "a distance constraint needs `b`",
                        )
                    })?,
                    "b",
                )?;
                Constraint::Distance {
                    a,
                    b,
                    length: length(dist(s.x[a], s.x[b]))?,
                }
            }
            "anchor" => {
                let point = need(c.point, "point")?;
                Constraint::Anchor {
                    a,
                    point,
                    length: length(dist(s.x[a], point))?,
                }
            }
            "circle" => {
                let center = need(c.center, "center")?;
                let normal = need(c.normal, "normal")?;
                let normal = largestep_kernels::v3::length_and_unit(normal)
                    .ok_or_else(|| ctx.error(&key("normal"), "the normal must not be zero"))?
                    .1;
                // The radius defaults to the start distance from the centre.
                Constraint::Circle {
                    a,
                    center,
                    normal,
                    radius: length(dist(s.x[a], center))?,
                }
            }
            o => {
                return Err(ctx.error(
                    &key("type"),
                    format!("unknown constraint type `{o}`; one of: distance, anchor, circle"),
                ))
            }
        });
    }
    let [ks, kd] = t.feedback.unwrap_or([0.0, 0.0]);
    let ks = ctx.non_negative(ks, &path(&[&"feedback"]), "ks")?;
    let kd = ctx.non_negative(kd, &path(&[&"feedback"]), "kd")?;
    let integrator = match t.integrator.as_deref().unwrap_or("rk4") {
        "explicit-euler" => WitkinIntegrator::ExplicitEuler,
        "symplectic-euler" => WitkinIntegrator::SymplecticEuler,
        "rk4" => WitkinIntegrator::Rk4,
        o => {
            return Err(ctx.error(
                &path(&[&"integrator"]),
                format!(
                "`{o}` does not integrate particles; one of: explicit-euler, symplectic-euler, rk4"
            ),
            ))
        }
    };
    let gravity = match t.gravity {
        Some(g) => finite3(ctx, &path(&[&"gravity"]), Some(g), "gravity")?,
        None if ctx.gravity != [0.0; 3] => ctx.gravity,
        None => [0.0, -9.81, 0.0],
    };
    let w = Witkin {
        inv_mass,
        constraints,
        gravity,
        ks,
        kd,
        integrator,
    };
    w.validate(&s).map_err(|e| {
        let key = match &e {
            WitkinError::Constraint { index, .. } => path(&[&"constraint", index]),
            WitkinError::Particle { index, .. } => path(&[&"particle", index]),
            _ => Vec::new(),
        };
        ctx.error(&key, e.to_string())
    })?;
    Ok(WitkinSim::new(w, s))
}

/// A running Witkin system (see [`super::witkin`]).
pub struct WitkinSim {
    model: Witkin,
    state: WitkinState,
    work: WitkinWork,
    /// Particles, then the fixed points drawn (anchors, wire circles), component-major:
    /// formed when a frame asks for them.
    positions: std::sync::OnceLock<Vec<f64>>,
    fixed: Vec<[f64; 3]>,
    segments: Arc<[[u32; 2]]>,
    drift: f64,
    start_drift: f64,
}

impl WitkinSim {
    /// The simulation of `model` from `state`.
    pub fn new(model: Witkin, state: WitkinState) -> WitkinSim {
        let n = state.x.len() as u32;
        let mut fixed = Vec::new();
        let mut segments = Vec::new();
        for c in &model.constraints {
            match *c {
                Constraint::Distance { a, b, .. } => segments.push([a as u32, b as u32]),
                Constraint::Anchor { a, point, .. } => {
                    segments.push([a as u32, n + fixed.len() as u32]);
                    fixed.push(point);
                }
                Constraint::Circle {
                    center,
                    normal,
                    radius,
                    ..
                } => {
                    // The wire: a 48-gon in the circle's plane.
                    let (u, v) = largestep_kernels::v3::tangent_frame(normal);
                    let first = n + fixed.len() as u32;
                    for k in 0..48 {
                        let t = 2.0 * std::f64::consts::PI * k as f64 / 48.0;
                        let (sn, cs) = t.sin_cos();
                        fixed.push([0, 1, 2].map(|a| center[a] + radius * (cs * u[a] + sn * v[a])));
                        segments.push([first + k, first + (k + 1) % 48]);
                    }
                }
            }
        }
        let drift = model.drift(&state.x);
        WitkinSim {
            model,
            state,
            work: WitkinWork::default(),
            positions: std::sync::OnceLock::new(),
            fixed,
            segments: segments.into(),
            drift,
            start_drift: drift,
        }
    }

    /// The frame's positions (see `positions`).
    fn positions(&self) -> &[f64] {
        self.positions.get_or_init(|| {
            let total = self.state.x.len() + self.fixed.len();
            let mut out = vec![0.0; 3 * total];
            for (i, p) in self.state.x.iter().chain(&self.fixed).enumerate() {
                for (a, c) in p.iter().enumerate() {
                    out[a * total + i] = *c;
                }
            }
            out
        })
    }

    /// The model.
    pub fn model(&self) -> &Witkin {
        &self.model
    }

    /// The state.
    pub fn state(&self) -> &WitkinState {
        &self.state
    }

    /// The largest constraint violation seen so far (m).
    pub fn max_drift(&self) -> f64 {
        self.drift
    }
}

impl Simulation for WitkinSim {
    fn step(&mut self, dt: f64) -> Result<StepInfo, IntegrateError> {
        let t0 = Instant::now();
        self.model
            .step(&mut self.state, &mut self.work, dt)
            .map_err(|e| IntegrateError::Failed {
                step: self.state.steps + 1,
                why: e.to_string(),
            })?;
        self.drift = self
            .drift
            .max(self.model.drift_with(&self.state.x, &mut self.work));
        self.positions = std::sync::OnceLock::new();
        Ok(StepInfo {
            newton_iterations: 0,
            linear_iterations: 0,
            residual: 0.0,
            solve_seconds: t0.elapsed().as_secs_f64(),
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
            kinetic: self.model.kinetic_energy(&self.state),
            potential: self.model.potential_energy(&self.state),
            external_work: 0.0,
        }
    }

    fn max_penetration(&self) -> f64 {
        0.0
    }

    fn frame(&self) -> FrameData<'_> {
        FrameData::Mesh(MeshRef {
            positions: self.positions(),
            triangles: &[],
            segments: &self.segments,
        })
    }

    fn stages(&self) -> Vec<Stage> {
        let m = &self.model;
        vec![
            Stage::built(
                "Witkin constrained dynamics",
                format!(
                    "{} particles, {} scalar constraints, dense Cholesky of J W J^T, {:?}",
                    m.inv_mass.len(),
                    m.rows(),
                    m.integrator
                ),
            ),
            Stage::new(
                "drift feedback",
                m.ks > 0.0 || m.kd > 0.0,
                if m.ks > 0.0 || m.kd > 0.0 {
                    format!("ks = {} 1/s^2, kd = {} 1/s", m.ks, m.kd)
                } else {
                    "feedback = [0, 0]".to_string()
                },
            ),
            Stage::left_out(
                "collision structures",
                "particles under constraints collide with nothing",
            ),
        ]
    }

    fn scenery(&self, _around: ([f64; 3], [f64; 3])) -> Vec<Mesh> {
        Vec::new()
    }

    fn method(&self) -> String {
        format!("Witkin {:?}", self.model.integrator)
    }

    fn linear_solver(&self) -> Option<&'static str> {
        Some("dense Cholesky (J W J^T)")
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn warnings(&self) -> Vec<String> {
        vec![format!(
            "constraint drift: at most {:.3e} m over the run (from {:.1e} m at the start)",
            self.drift, self.start_drift
        )]
    }
}

/// The key of body `i`: bodies first, then the arrays' bodies.
fn body_key(t: &RigidTable, i: usize) -> Vec<Key> {
    if i < t.body.len() {
        return path(&[&"body", &i]);
    }
    let mut i = i - t.body.len();
    for (k, a) in t.array.iter().enumerate() {
        let n = a
            .count
            .iter()
            .map(|&c| c.max(0) as usize)
            .product::<usize>();
        if i < n {
            return path(&[&"array", &k]);
        }
        i -= n;
    }
    Vec::new()
}

/// A running rigid-body world: the model, its state and work (see [`super`]).
pub struct RigidSim {
    model: Arc<Rigid>,
    state: RigidState,
    work: RigidWork,
    last: RigidStepInfo,
    /// The posed surfaces of the present state (component-major), formed when a frame
    /// asks for them, and the distance joints' strings.
    positions: std::sync::OnceLock<Vec<f64>>,
    segments: Vec<[u32; 2]>,
    warnings: Vec<String>,
    deepest: f64,
    /// The last step's contact impulses per body, while a listener records them
    /// ([`Simulation::record_contact_impulses`]).
    impulses: Option<ContactImpulses>,
}

impl RigidSim {
    /// Builds the world of `d`.
    pub fn new(d: &RigidDesc) -> Result<RigidSim, RigidError> {
        let (model, state, work) = d.build()?;
        let mut sim = RigidSim {
            model: Arc::new(model),
            state,
            work,
            last: RigidStepInfo::default(),
            positions: std::sync::OnceLock::new(),
            segments: Vec::new(),
            warnings: Vec::new(),
            deepest: 0.0,
            impulses: None,
        };
        sim.segments = sim.model.joint_segments();
        Ok(sim)
    }

    /// The model.
    pub fn model(&self) -> &Rigid {
        &self.model
    }

    /// The state.
    pub fn state(&self) -> &RigidState {
        &self.state
    }

    /// What the last step did.
    pub fn last_step(&self) -> RigidStepInfo {
        self.last
    }

    /// The contact points of the last step with their impulses.
    pub fn contacts(&self) -> &[super::ContactPoint] {
        &self.work.contacts
    }

    /// Fills the recorded impulses from the step just taken (from `t0`, `dt` long): each
    /// contact's impulse on b, and its opposite on a, at the contact point, turned into
    /// each body's shape frame at its pose after the step (the point moved by at most the
    /// body's travel over one step, far less than a surface's feature size).
    fn record(&mut self, t0: f64, dt: f64) {
        let Some(out) = &mut self.impulses else {
            return;
        };
        out.time = t0;
        out.dt = dt;
        out.points.clear();
        let (m, s) = (&self.model, &self.state);
        for c in &self.work.contacts {
            if c.impulse == [0.0; 3] {
                continue;
            }
            for (body, sign) in [(c.b, 1.0), (c.a, -1.0)] {
                let (x, q) = m.shape_pose(s, body as usize);
                out.points.push(BodyImpulse {
                    body,
                    point: quat::rotate_inv(q, v3::sub(c.point, x)),
                    impulse: quat::rotate_inv(q, v3::scale(c.impulse, sign)),
                });
            }
        }
    }
}

impl Simulation for RigidSim {
    fn step(&mut self, dt: f64) -> Result<StepInfo, IntegrateError> {
        let t0 = Instant::now();
        let time = self.state.time;
        let info = self
            .model
            .step(&mut self.state, &mut self.work, dt)
            .map_err(|e| IntegrateError::Failed {
                step: self.state.steps,
                why: e.to_string(),
            })?;
        self.last = info;
        self.deepest = info.max_depth.max(0.0);
        self.positions = std::sync::OnceLock::new();
        self.record(time, dt);
        Ok(StepInfo {
            newton_iterations: 0,
            linear_iterations: self.model.desc().iterations,
            residual: 0.0,
            solve_seconds: t0.elapsed().as_secs_f64(),
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
            kinetic: self.model.kinetic_energy(&self.state),
            potential: self.model.potential_energy(&self.state),
            external_work: 0.0,
        }
    }

    fn max_penetration(&self) -> f64 {
        self.deepest
    }

    fn frame(&self) -> FrameData<'_> {
        let positions = self.positions.get_or_init(|| {
            let mut out = Vec::new();
            self.model.posed_surfaces(&self.state, &mut out);
            out
        });
        FrameData::Mesh(MeshRef {
            positions,
            triangles: self.model.surface_triangles(),
            segments: &self.segments,
        })
    }

    fn stages(&self) -> Vec<Stage> {
        let m = &self.model;
        let d = m.desc();
        let n = m.len();
        let dynamic = (0..n).filter(|&i| m.is_dynamic(i)).count();
        let collides = m.collides();
        let mut kinds: Vec<&str> = d.bodies.iter().map(|b| b.shape.kind()).collect();
        kinds.sort_unstable();
        kinds.dedup();
        vec![
            Stage::built(
                "rigid bodies",
                format!(
                    "{n} {} ({dynamic} dynamic; {}), {} integrator",
                    if n == 1 { "body" } else { "bodies" },
                    kinds.join(", "),
                    d.integrator.name()
                ),
            ),
            Stage::new(
                "collision structures",
                collides,
                if collides {
                    format!(
                        "sweep and prune over body boxes, contact manifolds (kept while a pair moves less than {} of its size)",
                        d.contact_reuse
                    )
                } else {
                    "fewer than two bodies, or none that moves".to_string()
                },
            ),
            Stage::new(
                "contact solver",
                collides,
                if collides {
                    format!(
                        "{}, {} sub-steps, {:?} correction, friction {}",
                        d.solver.name(),
                        d.iterations,
                        d.correction,
                        d.friction
                    )
                } else {
                    "no contacts possible".to_string()
                },
            ),
            Stage::new(
                "restitution",
                collides && d.restitution > 0.0,
                if d.restitution > 0.0 {
                    format!("e = {}", d.restitution)
                } else {
                    "restitution = 0".to_string()
                },
            ),
            Stage::new(
                "joints",
                !d.joints.is_empty(),
                if d.joints.is_empty() {
                    "no [[rigid.joint]]".to_string()
                } else {
                    format!("{} joints", d.joints.len())
                },
            ),
        ]
    }

    fn scenery(&self, _around: ([f64; 3], [f64; 3])) -> Vec<Mesh> {
        Vec::new()
    }

    fn method(&self) -> String {
        format!("rigid {}", self.model.desc().integrator.name())
    }

    fn linear_solver(&self) -> Option<&'static str> {
        None
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    fn moving_obstacles(&self, out: &mut Vec<crate::collide::MovingObstacle>) {
        self.model.obstacles(&self.state, out);
    }

    fn record_contact_impulses(&mut self, on: bool) {
        if !on {
            self.impulses = None;
        } else if self.impulses.is_none() {
            self.impulses = Some(ContactImpulses {
                bodies: self.model.len(),
                ..ContactImpulses::default()
            });
        }
    }

    fn contact_impulses(&self) -> Option<&ContactImpulses> {
        self.impulses.as_ref()
    }

    fn frame_table(&self) -> Option<crate::simulation::FrameTable> {
        Some(crate::simulation::FrameTable {
            file: "bodies.csv",
            header: "frame,time,body,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz",
        })
    }

    fn write_frame_rows(&self, frame: usize, w: &mut dyn std::io::Write) -> std::io::Result<()> {
        let s = &self.state;
        for i in 0..self.model.len() {
            // The shape's frame (the one the scene placed), its origin's velocity.
            let (x, q) = self.model.shape_pose(s, i);
            let r = largestep_kernels::v3::sub(x, s.x[i]);
            let v = largestep_kernels::v3::add(s.v[i], largestep_kernels::v3::cross(s.w[i], r));
            writeln!(
                w,
                "{frame},{},{i},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                s.time,
                x[0],
                x[1],
                x[2],
                q[0],
                q[1],
                q[2],
                q[3],
                v[0],
                v[1],
                v[2],
                s.w[i][0],
                s.w[i][1],
                s.w[i][2]
            )?;
        }
        Ok(())
    }
}
