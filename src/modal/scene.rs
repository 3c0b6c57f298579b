//! The `[sound]` scene table: the modal sound of a tetrahedral mesh, struck by scripted
//! hits and, with `contacts = true`, by the contact impulses of the scene's other systems
//! (a FEM body dropped on the floor, made of the same mesh; or, with `body = k`, rigid
//! body k of a `[rigid]` system, whose contact points go to the nearest surface vertex of
//! the sound's mesh, given in the body's shape frame).
//!
//! Building it runs the modal analysis ([`super::analyse_desc`]: linear elasticity at
//! rest, the lowest `modes` non-rigid modes) and sets up the resonator bank
//! ([`super::sound::Synth`]); each scene step renders the samples of its interval, so a
//! contact heard in a step rings from that step on. The runner writes the sound as
//! `sound.wav` and, from the command line, its spectrogram (`spectrogram.png`).
//!
//! ```toml
//! [sound]
//! material = "steel"            # steel, aluminium, glass, wood, ceramic (E, nu, rho and
//!                               # Rayleigh damping); young, poisson, density, alpha
//!                               # (1/s) and beta (s) override the preset's
//! modes = 60                    # lowest non-rigid modes (default 60)
//! mass = "consistent"           # or "lumped"
//! # fixed = "x<=0"              # vertices held (as `largestep modes --fixed`)
//! sample_rate = 44100           # Hz
//! max_frequency = 20000.0       # Hz: modes above are culled
//! quiet = 1e-4                  # modes quieter than this fraction of the loudest: culled
//! contacts = false              # true: the other systems' contact impulses strike it
//! # body = 0                    # contacts from [rigid]: the index of the body that rings
//! contact_time = 1e-4           # s: the half-sine each contact impulse is spread over
//! [sound.beam]                  # or [sound.mesh], as [fem.beam] and [fem.mesh]
//! cells = [40, 4, 4]
//! size = [0.5, 0.02, 0.02]
//! [[sound.hit]]
//! time = 0.05                   # s
//! vertex = 12                   # or position = [x, y, z]: the nearest surface vertex
//! direction = [0.0, -1.0, 0.0]
//! impulse = 0.01                # N s
//! duration = 1e-4               # s of contact (half-sine force; default contact_time)
//! ```

use super::sound::{sound_material, Cull, Pulse, Rayleigh, SoundParams, Synth, SOUND_MATERIALS};
use super::{analyse_desc, Analysis, ModalError, Selector};
use crate::fem::scene::{estimated_bytes, BeamTable, MeshTable};
use crate::fem::{FemDesc, FemMass, FemMaterial, Material};
use crate::integrate::{IntegrateError, StepInfo};
use crate::io::{Mesh, MeshRef};
use crate::scene::{path, Context, PathPart, SceneError};
use crate::simulation::{Audio, ContactImpulses, Energy, FrameData, MechModel, Simulation, Stage};
use serde::Deserialize;
use std::time::Instant;

/// Modes computed unless `modes` says otherwise.
pub const DEFAULT_MODES: usize = 60;

/// `[sound]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SoundTable {
    /// A preset of [`SOUND_MATERIALS`] (default steel).
    #[serde(default)]
    pub material: Option<String>,
    #[serde(default)]
    pub young: Option<f64>,
    #[serde(default)]
    pub poisson: Option<f64>,
    #[serde(default)]
    pub density: Option<f64>,
    /// Rayleigh damping's mass factor (1/s).
    #[serde(default)]
    pub alpha: Option<f64>,
    /// Rayleigh damping's stiffness factor (s).
    #[serde(default)]
    pub beta: Option<f64>,
    #[serde(default)]
    pub modes: Option<i64>,
    #[serde(default)]
    pub mass: Option<String>,
    #[serde(default)]
    pub fixed: Option<String>,
    #[serde(default)]
    pub sample_rate: Option<i64>,
    #[serde(default)]
    pub max_frequency: Option<f64>,
    #[serde(default)]
    pub quiet: Option<f64>,
    #[serde(default)]
    pub contacts: bool,
    /// With `contacts`, from a rigid system: the index of the body that rings.
    #[serde(default)]
    pub body: Option<i64>,
    #[serde(default)]
    pub contact_time: Option<f64>,
    #[serde(default)]
    pub hit: Vec<HitTable>,
    #[serde(default)]
    pub beam: Option<BeamTable>,
    #[serde(default)]
    pub mesh: Option<MeshTable>,
}

/// `[[sound.hit]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HitTable {
    pub time: f64,
    #[serde(default)]
    pub vertex: Option<i64>,
    #[serde(default)]
    pub position: Option<[f64; 3]>,
    pub direction: [f64; 3],
    pub impulse: f64,
    #[serde(default)]
    pub duration: Option<f64>,
}

/// A body that rings: its modes, the resonator bank, and the sound so far.
pub struct ModalSound {
    analysis: Analysis,
    synth: Synth,
    samples: Vec<f64>,
    sample_rate: u32,
    /// Boundary triangles, for frames.
    triangles: Vec<[u32; 3]>,
    contacts: bool,
    contact_time: f64,
    t: f64,
    steps: u64,
    /// Modes asked for, the time the analysis took (s).
    asked: usize,
    seconds: f64,
    /// Contact impulses heard, strikes they made, and their sum (N s, rest frame).
    heard: u64,
    strikes: u64,
    heard_impulse: [f64; 3],
    /// Steps that rendered nothing because the sound reached [`super::sound::MAX_SECONDS`].
    clipped: bool,
    /// Each vertex's contact impulse at the last step it was heard in (N s), and the
    /// vertices where that is not zero.
    prev: Vec<[f64; 3]>,
    pushed: Vec<u32>,
    /// The rigid body whose contacts strike it (`body`), the surface vertices they go
    /// to, the mesh's diagonal (m) and the step's impulses per vertex.
    body: Option<u32>,
    surface: Vec<u32>,
    diagonal: f64,
    gathered: Vec<(u32, [f64; 3])>,
    /// The DC blocker's state (last input and output) and pole.
    dc: (f64, f64),
    dc_pole: f64,
}

/// A rigid body's contact point farther than this fraction of the sound mesh's diagonal
/// from its surface means the mesh is not the body's shape ([`ModalSound`] with `body`).
pub const MATCH_FRACTION: f64 = 0.05;

/// Corner of the DC blocker on the rendered sound (Hz): below hearing, far below any mode
/// a body that rings has.
pub const DC_CORNER_HZ: f64 = 20.0;

impl ModalSound {
    /// The sound so far (one value per sample).
    pub fn samples(&self) -> &[f64] {
        &self.samples
    }

    /// The modes and the model they are of.
    pub fn analysis(&self) -> &Analysis {
        &self.analysis
    }

    /// What rings and what was culled.
    pub fn synth(&self) -> &Synth {
        &self.synth
    }

    /// Contact impulses heard so far, and their sum (N s, in the mesh's rest frame).
    pub fn heard(&self) -> (u64, [f64; 3]) {
        (self.heard, self.heard_impulse)
    }

    /// Strikes the modes with one step's `(vertex, impulse)` contacts (N s, rest frame),
    /// from `time` (s), `dt` long.
    fn hear(&mut self, time: f64, dt: f64, impulses: &[(u32, [f64; 3])]) -> Result<(), String> {
        let n = self.synth.vertex_count();
        // A contact that keeps pushing as it pushed the step before is a steady push (a
        // body resting on the floor): that part goes in as a constant force over the
        // step, so consecutive steps join into a steady input; only what exceeds it is an
        // impact, a half-sine of the contact time. (As half-sines every step, a resting
        // body buzzed at the step rate: a comb at 1, 2, 3 kHz with dt = 1 ms.)
        if self.prev.len() != n {
            self.prev = vec![[0.0; 3]; n];
        }
        for &(v, j) in impulses {
            self.heard += 1;
            for (sum, jc) in self.heard_impulse.iter_mut().zip(j) {
                *sum += jc;
            }
            let vi = v as usize;
            if vi >= n {
                return Err(format!("vertex {v} out of range ({n} vertices)"));
            }
            let p = self.prev[vi];
            let len = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            let steady: [f64; 3] = if len > 0.0 {
                let along = (j[0] * p[0] + j[1] * p[1] + j[2] * p[2]) / len;
                let keep = along.clamp(0.0, len) / len;
                p.map(|c| c * keep)
            } else {
                [0.0; 3]
            };
            let impact: [f64; 3] = std::array::from_fn(|c| j[c] - steady[c]);
            if steady != [0.0; 3] {
                self.synth.strike(time, vi, steady, Pulse::Box(dt))?;
            }
            if impact != [0.0; 3] {
                self.strikes += 1;
                self.synth
                    .strike(time, vi, impact, Pulse::HalfSine(self.contact_time))?;
            }
        }
        // Vertices that stopped touching push no more.
        for &v in &self.pushed {
            self.prev[v as usize] = [0.0; 3];
        }
        self.pushed.clear();
        for &(v, j) in impulses {
            self.prev[v as usize] = j;
            if j != [0.0; 3] {
                self.pushed.push(v);
            }
        }
        Ok(())
    }

    /// Body `k`'s contact impulses of `impulses` onto the nearest surface vertex of the
    /// sound's mesh (which is in the body's shape frame), summed per vertex into `out`. A
    /// contact point farther from the surface than [`MATCH_FRACTION`] of the mesh's
    /// diagonal means the mesh is not the body's shape: an error saying where.
    fn gather(
        &mut self,
        k: u32,
        impulses: &ContactImpulses,
        out: &mut Vec<(u32, [f64; 3])>,
    ) -> Result<(), String> {
        out.clear();
        for bi in impulses.points.iter().filter(|b| b.body == k) {
            let Some((v, far)) =
                nearest_surface_vertex(&self.analysis.rest, &self.surface, bi.point)
            else {
                return Err("the sound's mesh has no surface".into());
            };
            if far > MATCH_FRACTION * self.diagonal {
                return Err(format!(
                    "body {k}'s contact at {:?} m (its shape frame) lies {far:.3e} m from the sound's mesh (diagonal {:.3e} m): give [sound] the body's shape in its own frame (a box centred on the origin: [sound.beam] origin = -size / 2; a mesh: the same file and scale)",
                    bi.point, self.diagonal
                ));
            }
            match out.iter_mut().find(|(u, _)| *u == v) {
                Some((_, j)) => (0..3).for_each(|c| j[c] += bi.impulse[c]),
                None => out.push((v, bi.impulse)),
            }
        }
        Ok(())
    }
}

/// The surface vertex of `surface` nearest `p` in the component-major `rest` positions,
/// and its distance (m); `None` for no surface. For hits given by position and for
/// rigid bodies' contact points.
fn nearest_surface_vertex(rest: &[f64], surface: &[u32], p: [f64; 3]) -> Option<(u32, f64)> {
    let n = rest.len() / 3;
    surface
        .iter()
        .map(|&v| {
            let d2: f64 = (0..3)
                .map(|c| (rest[c * n + v as usize] - p[c]).powi(2))
                .sum();
            (v, d2)
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(v, d2)| (v, d2.sqrt()))
}

/// Builds `[sound]` (see the module docs).
pub fn build(ctx: &Context<'_>) -> Result<Box<dyn Simulation>, SceneError> {
    let t: SoundTable = ctx.table()?;
    let at = |f: &[&dyn PathPart]| path(f);
    // Material.
    let name = t.material.as_deref().unwrap_or("steel");
    let preset = sound_material(name).ok_or_else(|| {
        let names: Vec<&str> = SOUND_MATERIALS.iter().map(|(n, _)| *n).collect();
        ctx.error(
            &at(&[&"material"]),
            format!("unknown material `{name}`; one of: {}", names.join(", ")),
        )
    })?;
    let young = ctx.positive(t.young.unwrap_or(preset.young), &at(&[&"young"]), "young")?;
    let poisson = t.poisson.unwrap_or(preset.poisson);
    if !(poisson > -1.0 && poisson < 0.5) {
        return Err(ctx.error(
            &at(&[&"poisson"]),
            format!("Poisson's ratio must lie in (-1, 0.5), not {poisson}"),
        ));
    }
    let density = ctx.positive(
        t.density.unwrap_or(preset.density),
        &at(&[&"density"]),
        "density",
    )?;
    let damping = Rayleigh {
        alpha: ctx.non_negative(
            t.alpha.unwrap_or(preset.damping.alpha),
            &at(&[&"alpha"]),
            "alpha",
        )?,
        beta: ctx.non_negative(
            t.beta.unwrap_or(preset.damping.beta),
            &at(&[&"beta"]),
            "beta",
        )?,
    };
    let count = match t.modes {
        None => DEFAULT_MODES,
        Some(k) if (1..=100_000).contains(&k) => k as usize,
        Some(k) => {
            return Err(ctx.error(
                &at(&[&"modes"]),
                format!("modes must be 1 to 100,000, not {k}"),
            ))
        }
    };
    let mass = match &t.mass {
        None => FemMass::Consistent,
        Some(m) => m.parse().map_err(|e| ctx.error(&at(&[&"mass"]), e))?,
    };
    let rate = match t.sample_rate {
        None => 44_100,
        Some(r) if (8_000..=384_000).contains(&r) => r as u32,
        Some(r) => {
            return Err(ctx.error(
                &at(&[&"sample_rate"]),
                format!("sample_rate must be 8,000 to 384,000 Hz, not {r}"),
            ))
        }
    };
    let params = SoundParams {
        sample_rate: rate,
        max_frequency: ctx.positive(
            t.max_frequency.unwrap_or(20_000.0),
            &at(&[&"max_frequency"]),
            "max_frequency",
        )?,
        quiet: ctx.non_negative(t.quiet.unwrap_or(1e-4), &at(&[&"quiet"]), "quiet")?,
        ..SoundParams::default()
    };
    // The sound's samples, held until the run ends (its last step may pass the
    // duration by up to dt).
    let sound_seconds = (ctx.duration + ctx.dt).min(super::sound::MAX_SECONDS);
    ctx.memory(
        &at(&[&"sample_rate"]),
        &format!("{sound_seconds} s of sound at {rate} Hz"),
        8.0 * sound_seconds * rate as f64,
    )?;
    let contact_time = ctx.non_negative(
        t.contact_time.unwrap_or(1e-4),
        &at(&[&"contact_time"]),
        "contact_time",
    )?;
    if contact_time > 1.0 {
        return Err(ctx.error(&at(&[&"contact_time"]), "contact_time must be at most 1 s"));
    }
    // Mesh: the modal analysis holds a Cholesky factor, like an implicit FEM step, and
    // the Lanczos basis: about (modes + 40) vectors of 3n doubles, twice.
    let bytes = |v: f64| estimated_bytes(v, true, true) + 48.0 * v * (count as f64 + 40.0);
    let mut notes = Vec::new();
    let (mesh, veg) =
        crate::fem::scene::mesh(ctx, t.beam.as_ref(), t.mesh.as_ref(), &bytes, &mut notes)?;
    let fixed = match &t.fixed {
        None => Vec::new(),
        Some(s) => s
            .parse::<Selector>()
            .and_then(|sel| sel.select(&mesh.positions))
            .map_err(|e| ctx.error(&at(&[&"fixed"]), e))?,
    };
    let material = FemMaterial {
        model: Material::Linear,
        young,
        poisson,
        density,
    };
    let mut desc = FemDesc::new(mesh.positions, mesh.tets, material);
    if veg.is_some() {
        return Err(ctx.error(
            &at(&[&"mesh", &"file"]),
            "[sound] takes its material from `material` (and its overrides): give the mesh as TetGen, Gmsh, VTK or a surface, not .veg",
        ));
    }
    desc.mass = mass;
    desc.notes = notes;
    let start = Instant::now();
    let analysis = analyse_desc(desc, fixed, count).map_err(|e| match e {
        ModalError::Model(e) => ctx.model_error(&e, &[]),
        e => ctx.error(&at(&[&"modes"]), format!("modal analysis: {e}")),
    })?;
    let seconds = start.elapsed().as_secs_f64();
    let triangles = analysis.fem.triangles().to_vec();
    let n = analysis.fem.vertex_count();
    // The surface: hits by position go to its nearest vertex; contacts cull against it.
    let mut surface: Vec<u32> = triangles.iter().flatten().copied().collect();
    surface.sort_unstable();
    surface.dedup();
    let mut hits = Vec::with_capacity(t.hit.len());
    for (k, h) in t.hit.iter().enumerate() {
        let key = |f: &str| at(&[&"hit", &k, &f]);
        let vertex = match (h.vertex, h.position) {
            (Some(v), None) => {
                let v = ctx.index(v, &key("vertex"), "vertex")?;
                if v >= n {
                    return Err(ctx.error(
                        &key("vertex"),
                        format!("vertex {v} does not exist: the mesh has {n} vertices"),
                    ));
                }
                v
            }
            (None, Some(p)) => {
                if !p.iter().all(|c| c.is_finite()) {
                    return Err(ctx.error(&key("position"), "must be finite"));
                }
                nearest_surface_vertex(&analysis.rest, &surface, p)
                    .ok_or_else(|| ctx.error(&key("position"), "the mesh has no surface"))?
                    .0 as usize
            }
            _ => {
                return Err(ctx.error(
                    &at(&[&"hit", &k]),
                    "give exactly one of `vertex` and `position`",
                ))
            }
        };
        if !(h.time >= 0.0 && h.time.is_finite()) {
            return Err(ctx.error(&key("time"), format!("time must be >= 0 s, not {}", h.time)));
        }
        let len = h.direction.iter().map(|c| c * c).sum::<f64>().sqrt();
        if !(len > 0.0 && len.is_finite()) {
            return Err(ctx.error(&key("direction"), "must be finite and not zero"));
        }
        if !h.impulse.is_finite() {
            return Err(ctx.error(&key("impulse"), "must be finite"));
        }
        let duration = ctx.non_negative(
            h.duration.unwrap_or(contact_time),
            &key("duration"),
            "duration",
        )?;
        if duration > 1.0 {
            return Err(ctx.error(&key("duration"), "must be at most 1 s"));
        }
        hits.push(super::sound::Hit {
            time: h.time,
            vertex,
            direction: h.direction.map(|c| c / len),
            impulse: h.impulse,
            duration,
        });
    }
    if hits.is_empty() && !t.contacts {
        return Err(ctx.error(
            &[],
            "nothing strikes it: give [[sound.hit]] entries or contacts = true",
        ));
    }
    let body = match t.body {
        None => None,
        Some(_) if !t.contacts => {
            return Err(ctx.error(
                &at(&[&"body"]),
                "`body` picks whose contacts strike it: give contacts = true too",
            ))
        }
        Some(k) => Some(
            u32::try_from(ctx.index(k, &at(&[&"body"]), "body")?)
                .map_err(|_| ctx.error(&at(&[&"body"]), format!("body {k} is out of range")))?,
        ),
    };
    let diagonal = crate::scene::diagonal(&analysis.rest);
    let cull = if t.contacts {
        Cull::Anywhere(&surface)
    } else {
        Cull::Hits(&hits)
    };
    let mut synth = Synth::new(&analysis.modes, damping, &params, cull)
        .map_err(|e| ctx.error(&[], e.to_string()))?;
    for (k, h) in hits.iter().enumerate() {
        let impulse = h.direction.map(|c| c * h.impulse);
        synth
            .strike(h.time, h.vertex, impulse, Pulse::HalfSine(h.duration))
            .map_err(|e| ctx.error(&at(&[&"hit", &k]), e))?;
    }
    Ok(Box::new(ModalSound {
        analysis,
        synth,
        // The whole sound, checked against the memory budget above: no reallocation
        // while it plays.
        samples: Vec::with_capacity((sound_seconds * rate as f64).ceil() as usize + 1),
        sample_rate: rate,
        triangles,
        contacts: t.contacts,
        contact_time,
        t: 0.0,
        steps: 0,
        asked: count,
        seconds,
        heard: 0,
        strikes: 0,
        heard_impulse: [0.0; 3],
        clipped: false,
        prev: Vec::new(),
        pushed: Vec::new(),
        body,
        diagonal,
        surface,
        gathered: Vec::new(),
        dc: (0.0, 0.0),
        dc_pole: (-2.0 * std::f64::consts::PI * DC_CORNER_HZ / rate as f64).exp(),
    }))
}

impl Simulation for ModalSound {
    fn step(&mut self, dt: f64) -> Result<StepInfo, IntegrateError> {
        let end = self.t + dt;
        let rate = self.sample_rate as f64;
        let limit = (super::sound::MAX_SECONDS * rate) as u64;
        let target = self.synth.sample_at(end).min(limit);
        let have = self.synth.rendered();
        if target > have {
            let from = self.samples.len();
            self.samples.resize(from + (target - have) as usize, 0.0);
            self.synth.render(&mut self.samples[from..]);
            // A DC blocker, y[n] = x[n] - x[n-1] + p y[n-1]: a steady push deflects the
            // body, which the acceleration proxy `w^2 q` would hear as an offset.
            let (mut x1, mut y1) = self.dc;
            for s in &mut self.samples[from..] {
                let y = *s - x1 + self.dc_pole * y1;
                x1 = *s;
                y1 = y;
                *s = y;
            }
            self.dc = (x1, y1);
        } else if self.synth.sample_at(end) > limit {
            self.clipped = true;
        }
        self.t = end;
        self.steps += 1;
        Ok(StepInfo::default())
    }

    fn time(&self) -> f64 {
        self.t
    }

    fn steps(&self) -> u64 {
        self.steps
    }

    fn energy(&self) -> Energy {
        Energy::default()
    }

    fn max_penetration(&self) -> f64 {
        0.0
    }

    /// The body at rest, when scripted hits strike it; nothing when it listens to
    /// another system's contacts (that system shows the body).
    fn frame(&self) -> FrameData<'_> {
        if self.contacts {
            return FrameData::Mesh(MeshRef {
                positions: &[],
                triangles: &[],
                segments: &[],
            });
        }
        FrameData::Mesh(MeshRef {
            positions: &self.analysis.rest,
            triangles: &self.triangles,
            segments: &[],
        })
    }

    fn stages(&self) -> Vec<Stage> {
        let m = &self.analysis.modes;
        let f = m.frequencies_hz();
        let info = self.synth.info();
        let n = self.analysis.fem.vertex_count();
        vec![
            Stage::built(
                "modal analysis",
                format!(
                    "{} of {} modes asked, {} to {} Hz ({} rigid), of {n} vertices, {} path, {:.2} s",
                    f.len(),
                    self.asked,
                    f.first().map_or(0.0, |v| (v * 10.0).round() / 10.0),
                    f.last().map_or(0.0, |v| (v * 10.0).round() / 10.0),
                    m.rigid,
                    if m.dense { "dense" } else { "shift-invert Lanczos" },
                    self.seconds
                ),
            ),
            Stage::built(
                "resonators",
                format!(
                    "{} modes ring at {} Hz; culled: {} above the frequency limit or Nyquist, {} over-damped, {} quiet",
                    info.frequencies_hz.len(),
                    self.sample_rate,
                    info.culled_high,
                    info.culled_overdamped,
                    info.culled_quiet
                ),
            ),
            if self.contacts {
                Stage::built(
                    "contact impulses",
                    format!(
                        "from the other systems, each a half-sine of {} s",
                        self.contact_time
                    ),
                )
            } else {
                Stage::left_out("contact impulses", "contacts = false")
            },
        ]
    }

    fn scenery(&self, _around: ([f64; 3], [f64; 3])) -> Vec<Mesh> {
        Vec::new()
    }

    fn method(&self) -> String {
        "modal synthesis".into()
    }

    fn linear_solver(&self) -> Option<&'static str> {
        None
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn warnings(&self) -> Vec<String> {
        let mut w = self.analysis.fem.warnings();
        if self.clipped {
            w.push(format!(
                "the sound stops at {} s ({} kept at most)",
                super::sound::MAX_SECONDS,
                super::sound::MAX_SECONDS
            ));
        }
        if self.contacts {
            w.push(format!(
                "sound: {} contact impulses heard ({} strikes)",
                self.heard, self.strikes
            ));
        }
        w
    }

    fn listens(&self) -> bool {
        self.contacts
    }

    fn listen(&mut self, impulses: &ContactImpulses) -> Result<(), String> {
        let n = self.synth.vertex_count();
        match (self.body, impulses.bodies) {
            // A system of vertices: the body itself, on the same mesh.
            (None, 0) => {
                if impulses.vertex_count != n {
                    return Err(format!(
                        "it has {} vertices and the sound's mesh {n}: give [sound] the same mesh",
                        impulses.vertex_count
                    ));
                }
                self.hear(impulses.time, impulses.dt, &impulses.impulses)
            }
            (None, _) => Err(
                "its contacts are rigid bodies': give [sound] `body`, the index of the body that rings".into(),
            ),
            // Another system's vertices do not strike a rigid body's sound.
            (Some(_), 0) => Ok(()),
            (Some(k), bodies) => {
                if k as usize >= bodies {
                    return Err(format!(
                        "[sound] body = {k} does not exist: the system has {bodies} bodies"
                    ));
                }
                let mut heard = std::mem::take(&mut self.gathered);
                let r = self
                    .gather(k, impulses, &mut heard)
                    .and_then(|()| self.hear(impulses.time, impulses.dt, &heard));
                self.gathered = heard;
                r
            }
        }
    }

    fn audio(&self) -> Option<Audio<'_>> {
        Some(Audio {
            samples: &self.samples,
            sample_rate: self.sample_rate,
        })
    }
}
