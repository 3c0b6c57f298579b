//! World files (`.w`) of the jello-cube assignment: read, validate, write back, and turn
//! into a mass-spring system.
//!
//! The format (plain text, one record a line; see `../shared/data/jello-worlds/SOURCE.md`):
//!
//! ```text
//! RK4                      integrator: Euler or RK4 (any largestep integrator name is accepted)
//! 0.0005 1                 dt (s), display every n-th step
//! 200 0.25 400 0.25        kElastic dElastic kCollision dCollision
//! 0.001953                 mass of each point (kg)
//! 1                        inclined plane present (0 or 1)
//! -1 1 1 2                 a b c d of the plane a x + b y + c z + d = 0 (only when present)
//! 30                       force-field resolution r (0 = none), then r^3 lines "fx fy fz"
//! ...                      512 positions p[i][j][k] (i outer, k inner), 512 velocities
//! ```
//!
//! The field samples the box `[-2, 2]^3` on an r x r x r grid, line `i r^2 + j r + k`
//! holding node (i, j, k) at `-2 + 4 (i, j, k) / (r - 1)`. The cube is 8 x 8 x 8 points of
//! side 1 at rest; every spring gets kElastic and dElastic; the points must stay in the
//! box (and on their side of the plane), by penalty springs of kCollision and dCollision.

use super::{lattice, CollisionDesc, LatticeOptions, MassSpringDesc};
use crate::integrate::{MechSettings, Method};
use crate::io::ReadError;
use crate::limits::Limits;
use crate::loads::ForceField;
use crate::scene::{stem_name, FrameFormat, Output, Scene, SceneError, System};
use crate::simulation::MechSimulation;
use std::io::Write;

/// Points along each side of the cube.
pub const SIDE: usize = 8;
/// Half the side of the bounding box `[-2, 2]^3` (m).
pub const BOX_HALF: f64 = 2.0;

/// A parsed world file.
#[derive(Clone, Debug, PartialEq)]
pub struct World {
    /// The integrator as written.
    pub integrator: String,
    /// The integrator it names.
    pub method: Method,
    /// Time step (s).
    pub dt: f64,
    /// Display every n-th step.
    pub every: usize,
    /// Spring stiffness (N/m) and damping (N s/m).
    pub k_elastic: f64,
    /// Spring damping (N s/m).
    pub d_elastic: f64,
    /// Collision spring stiffness (N/m).
    pub k_collision: f64,
    /// Collision spring damping (N s/m).
    pub d_collision: f64,
    /// Mass of each point (kg).
    pub mass: f64,
    /// The inclined plane `a, b, c, d`, if present.
    pub plane: Option<[f64; 4]>,
    /// Force-field resolution r (0: none).
    pub resolution: usize,
    /// Force-field samples (N), r^3 of them in file order.
    pub field: Vec<[f64; 3]>,
    /// Initial positions (m), 512 in file order.
    pub positions: Vec<[f64; 3]>,
    /// Initial velocities (m/s), 512 in file order.
    pub velocities: Vec<[f64; 3]>,
}

struct Reader<'a> {
    name: &'a str,
    lines: std::iter::Peekable<std::iter::Enumerate<std::str::Lines<'a>>>,
    line: usize,
}

impl<'a> Reader<'a> {
    fn err(&self, line: usize, message: String) -> ReadError {
        ReadError {
            path: self.name.to_string(),
            line,
            message,
        }
    }

    /// The next non-empty line's fields, or an error naming what was expected.
    fn record(&mut self, what: &str) -> Result<Vec<&'a str>, ReadError> {
        for (i, l) in self.lines.by_ref() {
            if !l.trim().is_empty() {
                self.line = i + 1;
                return Ok(l.split_whitespace().collect());
            }
        }
        Err(self.err(
            self.line + 1,
            format!("unexpected end of file: expected {what}"),
        ))
    }

    /// The next line as exactly `N` finite numbers.
    fn numbers<const N: usize>(&mut self, what: &str) -> Result<[f64; N], ReadError> {
        let f = self.record(what)?;
        if f.len() != N {
            return Err(self.err(
                self.line,
                format!("expected {what} ({N} numbers), found {} fields", f.len()),
            ));
        }
        let mut out = [0.0; N];
        for (o, s) in out.iter_mut().zip(&f) {
            *o = s
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    self.err(
                        self.line,
                        format!("`{s}` is not a finite number (expected {what})"),
                    )
                })?;
        }
        Ok(out)
    }

    fn remaining(&mut self) -> usize {
        self.lines
            .clone()
            .filter(|(_, l)| !l.trim().is_empty())
            .count()
    }
}

impl World {
    /// Reads a world file of at most `max_bytes` bytes (through
    /// [`crate::io::read_text`]).
    pub fn read(path: &std::path::Path, max_bytes: u64) -> Result<World, ReadError> {
        let text = crate::io::read_text(path, max_bytes)?;
        World::parse(&text, &path.display().to_string())
    }

    /// Parses world-file text; `name` is used in errors, which give the line and what was
    /// expected there.
    pub fn parse(text: &str, name: &str) -> Result<World, ReadError> {
        let mut r = Reader {
            name,
            lines: text.lines().enumerate().peekable(),
            line: 0,
        };
        let f = r.record("the integrator name (Euler or RK4)")?;
        let integrator = f.join(" ");
        let method = match integrator.to_ascii_lowercase().as_str() {
            "euler" => Some(Method::ExplicitEuler),
            "rk4" => Some(Method::Rk4),
            other => Method::from_name(other),
        }
        .ok_or_else(|| {
            r.err(
                r.line,
                format!(
                    "unknown integrator `{integrator}`: expected Euler or RK4 (or one of {})",
                    Method::names()
                ),
            )
        })?;
        let [dt, every] = r.numbers::<2>("`dt n`: the time step and the display interval")?;
        if !(dt.is_finite() && dt > 0.0) {
            return Err(r.err(
                r.line,
                format!("the time step must be > 0 and finite, not {dt}"),
            ));
        }
        if every < 1.0 || every.fract() != 0.0 {
            return Err(r.err(
                r.line,
                format!("the display interval must be an integer >= 1, not {every}"),
            ));
        }
        let [k_elastic, d_elastic, k_collision, d_collision] =
            r.numbers::<4>("`kElastic dElastic kCollision dCollision`")?;
        for (v, what) in [
            (k_elastic, "kElastic"),
            (d_elastic, "dElastic"),
            (k_collision, "kCollision"),
            (d_collision, "dCollision"),
        ] {
            if v < 0.0 {
                return Err(r.err(r.line, format!("{what} must be >= 0, not {v}")));
            }
        }
        let [mass] = r.numbers::<1>("the mass of each point")?;
        if mass <= 0.0 {
            return Err(r.err(r.line, format!("the mass must be > 0, not {mass}")));
        }
        let [present] = r.numbers::<1>("`incPlanePresent` (0 or 1)")?;
        let plane = match present {
            0.0 => None,
            1.0 => {
                let p = r.numbers::<4>("`a b c d` of the inclined plane")?;
                if p[..3].iter().all(|c| *c == 0.0) {
                    return Err(r.err(
                        r.line,
                        "the plane's normal (a, b, c) is zero: no plane".into(),
                    ));
                }
                Some(p)
            }
            other => {
                return Err(r.err(
                    r.line,
                    format!("`incPlanePresent` must be 0 or 1, not {other}"),
                ))
            }
        };
        let [res] = r.numbers::<1>("the force-field resolution (0 for none)")?;
        if res < 0.0 || res.fract() != 0.0 || res == 1.0 || res > 1000.0 {
            return Err(r.err(
                r.line,
                format!(
                    "the force-field resolution must be 0 or an integer in 2..=1000, not {res}"
                ),
            ));
        }
        let resolution = res as usize;
        let res_line = r.line;
        let points = SIDE * SIDE * SIDE;
        let need = resolution.pow(3) + 2 * points;
        let have = r.remaining();
        if have != need {
            return Err(r.err(
                res_line,
                format!(
                    "force-field resolution {resolution} needs {need} more lines ({} field samples, {points} positions, {points} velocities), but the file has {have}: the resolution does not match the number of lines",
                    resolution.pow(3)
                ),
            ));
        }
        let mut field = Vec::with_capacity(resolution.pow(3));
        for i in 0..resolution.pow(3) {
            field.push(r.numbers::<3>(&format!("force-field sample {i} `fx fy fz`"))?);
        }
        let mut positions = Vec::with_capacity(points);
        for i in 0..points {
            positions.push(r.numbers::<3>(&format!("position {i} `x y z`"))?);
        }
        let mut velocities = Vec::with_capacity(points);
        for i in 0..points {
            velocities.push(r.numbers::<3>(&format!("velocity {i} `vx vy vz`"))?);
        }
        Ok(World {
            integrator,
            method,
            dt,
            every: every as usize,
            k_elastic,
            d_elastic,
            k_collision,
            d_collision,
            mass,
            plane,
            resolution,
            field,
            positions,
            velocities,
        })
    }

    /// Writes the world in the same format (numbers in shortest round-trip form, so that
    /// reading it back gives the same world).
    pub fn write(&self, w: &mut dyn Write) -> std::io::Result<()> {
        writeln!(w, "{}", self.integrator)?;
        writeln!(w, "{} {}", self.dt, self.every)?;
        writeln!(
            w,
            "{} {} {} {}",
            self.k_elastic, self.d_elastic, self.k_collision, self.d_collision
        )?;
        writeln!(w, "{}", self.mass)?;
        match self.plane {
            Some([a, b, c, d]) => writeln!(w, "1\n{a} {b} {c} {d}")?,
            None => writeln!(w, "0")?,
        }
        writeln!(w, "{}", self.resolution)?;
        for p in self
            .field
            .iter()
            .chain(&self.positions)
            .chain(&self.velocities)
        {
            writeln!(w, "{} {} {}", p[0], p[1], p[2])?;
        }
        Ok(())
    }

    /// The force field on our grid layout (x fastest), if the world has one.
    pub fn force_field(&self) -> Option<ForceField> {
        (self.resolution >= 2).then(|| {
            ForceField::from_samples(self.resolution, [-BOX_HALF; 3], [BOX_HALF; 3], &self.field)
        })
    }

    /// The lattice of the assignment: 8 x 8 x 8 points, rest side 1 m, every spring
    /// kElastic/dElastic.
    pub fn lattice_options(&self) -> LatticeOptions {
        LatticeOptions {
            n: [SIDE; 3],
            origin: [0.0; 3],
            size: [1.0; 3],
            mass: self.mass,
            structural: self.k_elastic,
            shear: self.k_elastic,
            bend: self.k_elastic,
            damping: self.d_elastic,
        }
    }

    /// The mass-spring system: the lattice with the file's positions and velocities (rest
    /// lengths from the rest lattice), the force field, and penalty collisions with the
    /// box `[-2, 2]^3` and the plane. No gravity (the assignment's worlds put any in the
    /// field).
    pub fn to_desc(&self) -> MassSpringDesc {
        let mut desc = lattice(&self.lattice_options());
        desc.positions = self.positions.clone();
        desc.velocities = self.velocities.clone();
        desc.force_field = self.force_field();
        desc.collisions = Some(CollisionDesc {
            bounds: Some(([-BOX_HALF; 3], [BOX_HALF; 3])),
            planes: self.plane.into_iter().collect(),
            obstacles: Vec::new(),
            stiffness: self.k_collision,
            damping: self.d_collision,
        });
        desc
    }

    /// The scene of this world: its integrator, dt, springs, plane and force field in the
    /// box `[-2, 2]^3`, run for [`WORLD_DURATION`] seconds with a frame every
    /// `max(n, 1/30 s)` steps (the file's display interval n, but not more than 30 frames
    /// per simulated second). `file` names it in errors and gives the scene its name.
    pub fn to_scene(&self, file: &str, limits: &Limits) -> Result<Scene, SceneError> {
        let whole = |message: String| SceneError {
            file: file.to_string(),
            line: 0,
            column: 0,
            field: String::new(),
            message,
            snippet: None,
        };
        limits
            .steps(
                &format!(
                    "dt = {:e} s over the {WORLD_DURATION} s of a world run",
                    self.dt
                ),
                WORLD_DURATION / self.dt,
            )
            .map_err(whole)?;
        let (model, state) = self.to_desc().build().map_err(|e| whole(e.to_string()))?;
        let sim = MechSimulation::new(model, state, MechSettings::new(self.method))
            .map_err(|e| whole(e.to_string()))?;
        let every = self
            .every
            .max(((1.0 / 30.0) / self.dt).round() as usize)
            .max(1);
        Ok(Scene {
            file: file.to_string(),
            name: stem_name(file, "world"),
            dt: self.dt,
            duration: WORLD_DURATION,
            systems: vec![System {
                table: "mass_spring",
                sim: Box::new(sim),
            }],
            output: Output::new(FrameFormat::Obj, every, self.dt),
            limits: *limits,
        })
    }
}

/// Simulated time (s) of a run of a world file, which has no duration of its own.
pub const WORLD_DURATION: f64 = 5.0;

/// Reads a world file as a scene (the scene registry's loader for `.w` files).
pub fn load_scene(path: &std::path::Path, limits: &Limits) -> Result<Scene, SceneError> {
    let world = World::read(path, limits.max_file_bytes).map_err(SceneError::from_read)?;
    world.to_scene(&path.display().to_string(), limits)
}
