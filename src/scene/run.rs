//! Running a scene: steps, frames, the energy log and the closing summary.
//!
//! Frame k (k = 0 is the initial state) is written after `k * every` steps as
//! `frames/frame_NNNNN.obj` (or `.ply`), atomically; `energy.csv` gets one line per frame,
//! flushed as it is written. A failure (a blow-up, an I/O error) stops the run with an
//! error naming the step; every frame and log line written before it stays valid.

use super::{Scene, System};
use crate::integrate::{IntegrateError, StepInfo};
use crate::io::{write_atomically, write_obj, write_ply, Mesh, MeshRef};
use crate::limits::Limits;
use crate::render::preview::PreviewSettings;
use crate::render::volume::{slice, Slice, VolumeRenderer, VolumeSettings};
use crate::simulation::{Audio, Energy, FrameData, Simulation};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Frame file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameFormat {
    /// Wavefront OBJ.
    Obj,
    /// ASCII PLY.
    Ply,
    /// Legacy VTK unstructured grids of the volumetric systems (FEM), with their fields
    /// (displacement, velocity, von Mises stress), for ParaView: `frame_NNNNN.vtk`, or
    /// `frame_NNNNN_<table>.vtk` when several systems have a volume. Surfaces of the
    /// others are not written.
    Vtk,
    /// No frame files.
    None,
}

/// Output settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Output {
    /// Frame format.
    pub frames: FrameFormat,
    /// Steps per frame.
    pub every: usize,
    /// Preview images, camera and animation timing (used when frames are kept, see
    /// [`Runner::keep_frames`]).
    pub preview: PreviewSettings,
}

impl Output {
    /// `frames` every `every` steps of `dt` (s), previews with the default camera and
    /// size at that frame rate.
    pub fn new(frames: FrameFormat, every: usize, dt: f64) -> Output {
        Output {
            frames,
            every,
            preview: PreviewSettings {
                frame_interval: every as f64 * dt,
                ..PreviewSettings::default()
            },
        }
    }
}

/// Progress of a run, reported after every frame.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Frames done.
    pub frame: usize,
    /// Frames in the run.
    pub frames: usize,
    /// Steps done.
    pub steps: u64,
    /// Simulated time (s).
    pub time: f64,
}

/// One line of the run log (`energy.csv`), recorded for every frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameRecord {
    /// Frame number (0 is the initial state).
    pub frame: usize,
    /// Simulated time (s).
    pub time: f64,
    /// Kinetic energy (J).
    pub kinetic: f64,
    /// Potential energy (J).
    pub potential: f64,
    /// Deepest penetration into a collision surface (m).
    pub penetration: f64,
    /// Newton iterations over the frame's steps.
    pub newton_iterations: usize,
    /// Linear-solver iterations over the frame's steps.
    pub linear_iterations: usize,
    /// Steps in the frame.
    pub steps: usize,
    /// Wall time of the frame's steps (s).
    pub step_seconds: f64,
    /// Work done since the start by loads without a potential (wind, force fields), J.
    pub external_work: f64,
}

impl FrameRecord {
    const CSV_HEADER: &'static str = "frame,time_s,kinetic_J,potential_J,total_J,penetration_m,newton_iterations,linear_iterations,step_seconds,external_work_J";

    fn write_csv(&self, w: &mut dyn Write) -> std::io::Result<()> {
        writeln!(
            w,
            "{},{},{},{},{},{},{},{},{},{}",
            self.frame,
            self.time,
            self.kinetic,
            self.potential,
            self.kinetic + self.potential,
            self.penetration,
            self.newton_iterations,
            self.linear_iterations,
            self.step_seconds,
            self.external_work
        )
    }
}

/// What a finished run reports.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    /// Scene name.
    pub name: String,
    /// Integrator.
    pub method: String,
    /// Linear solver of implicit steps, if any.
    pub linear_solver: Option<&'static str>,
    /// Steps taken.
    pub steps: u64,
    /// Frame files written (including the initial frame).
    pub frames_written: usize,
    /// Simulated time (s).
    pub sim_time: f64,
    /// Wall time of the stepping (s), excluding output.
    pub step_seconds: f64,
    /// Wall time of the whole run (s).
    pub wall_seconds: f64,
    /// Total energy at the start and the end (J).
    pub energy: (f64, f64),
    /// Work done by loads without a potential over the run (J).
    pub external_work: f64,
    /// The deepest penetration into an obstacle seen in any frame (m).
    pub max_penetration: f64,
    /// The size of the scene's systems at the start: the diagonal of their bounding box
    /// (m).
    pub size: f64,
    /// `(E_end - E_start - W) / energy_scale`, W the work of loads without a potential
    /// and of prescribed motion:
    /// what the system gained that nothing put in.
    pub energy_drift: f64,
    /// The scale energy changes are measured against: `max(|E_start|, largest kinetic
    /// energy at any frame, |W|)` (J).
    pub energy_scale: f64,
    /// The largest gain at any frame, `(E(t) - E_start - W(t)) / energy_scale`, and the
    /// time it was reached (s): a transient jump that the end value hides.
    pub energy_peak: (f64, f64),
    /// Whether a Newton iteration ran (else each implicit step is one linear solve).
    pub newton: bool,
    /// Newton iterations, summed (1 per step for the linearised step).
    pub newton_iterations: usize,
    /// Linear-solver iterations, summed.
    pub linear_iterations: usize,
    /// Most linear-solver iterations in one step.
    pub max_linear_iterations: usize,
    /// What the systems found questionable in their input but ran with.
    pub warnings: Vec<String>,
    /// The output folder.
    pub out_dir: PathBuf,
}

impl std::fmt::Display for Summary {
    /// For people: rounded numbers with their units and what they are relative to
    /// (`summary.json` and `energy.csv` keep full precision).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        use crate::io::human;
        let pct = |x: f64| format!("{:+.1}%", 100.0 * x);
        writeln!(
            f,
            "{}: {} steps of {} ({} s simulated)",
            self.name,
            self.steps,
            self.method,
            human(self.sim_time)
        )?;
        writeln!(
            f,
            "  wall time      {} s ({} s stepping, {} ms per step)",
            human(self.wall_seconds),
            human(self.step_seconds),
            human(1e3 * self.step_seconds / self.steps.max(1) as f64)
        )?;
        writeln!(
            f,
            "  energy         {} J at the start, {} J at the end (kinetic + potential)",
            human(self.energy.0),
            human(self.energy.1)
        )?;
        if self.external_work != 0.0 {
            writeln!(
                f,
                "                 loads without a potential and prescribed motion put in {} J",
                human(self.external_work)
            )?;
        }
        if self.energy_scale <= (1e-12 * self.energy.1.abs()).max(f64::MIN_POSITIVE) {
            // Nothing to measure a change against (a static solve: no motion, and a
            // start with no energy): the change itself.
            writeln!(
                f,
                "                 change {} J (no energy scale: the start has none and nothing moved)",
                human(self.energy.1 - self.energy.0 - self.external_work)
            )?;
        } else {
            writeln!(
                f,
                "                 change{} {} of the energy scale {} J (the largest of the start's energy, the most kinetic energy{})",
                if self.external_work != 0.0 { " less that work" } else { "" },
                pct(self.energy_drift),
                human(self.energy_scale),
                if self.external_work != 0.0 { " and that work" } else { "" }
            )?;
        }
        if self.energy_drift > 0.1 {
            writeln!(
                f,
                "  warning        total energy grew by {} of its scale: the integrator is probably unstable at this dt (reduce dt or use an implicit integrator)",
                pct(self.energy_drift)
            )?;
        } else if self.energy_peak.0 > 0.1 {
            writeln!(
                f,
                "  warning        total energy rose by {} of its scale at t = {} s and fell back: a contact or a large step put energy in (reduce dt, or let step control halve it)",
                pct(self.energy_peak.0),
                human(self.energy_peak.1)
            )?;
        }
        for w in &self.warnings {
            writeln!(f, "  warning        {w}")?;
        }
        if self.max_penetration > 0.5 * self.size {
            writeln!(
                f,
                "  warning        the model sank up to {} m into an obstacle, half its size ({} m) or more: the collision stiffness is too small for the masses, or dt too large",
                human(self.max_penetration),
                human(self.size)
            )?;
        }
        match self.linear_solver {
            Some(ls) => {
                let per_step = |n: usize| human(n as f64 / self.steps.max(1) as f64);
                if self.newton {
                    write!(
                        f,
                        "  solver         {ls}: {} Newton iterations ({} per step)",
                        self.newton_iterations,
                        per_step(self.newton_iterations)
                    )?;
                } else {
                    write!(f, "  solver         {ls}: one linear solve per step (linearised, no Newton iteration)")?;
                }
                if self.linear_iterations > 0 {
                    write!(
                        f,
                        "; {} solver iterations ({} per step, at most {})",
                        self.linear_iterations,
                        per_step(self.linear_iterations),
                        self.max_linear_iterations
                    )?;
                }
                writeln!(f)?;
            }
            None => writeln!(f, "  solver         none (explicit)")?,
        }
        write!(
            f,
            "  frames         {} written to {}",
            self.frames_written,
            self.out_dir.display()
        )
    }
}

/// Why a run stopped.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RunError {
    /// The simulation failed (blow-up, solver failure).
    #[error("{source}\n  {frames_written} frames written before the failure remain valid in {}", out.display())]
    Integrate {
        /// The integrator's error (names the step).
        source: IntegrateError,
        /// Frames written before it.
        frames_written: usize,
        /// The output folder.
        out: PathBuf,
    },
    /// A system's contact impulses do not fit the system listening to them.
    #[error("{message}\n  {frames_written} frames written before the failure remain valid in {}", out.display())]
    Listen {
        /// What does not fit, with the step.
        message: String,
        /// Frames written before it.
        frames_written: usize,
        /// The output folder.
        out: PathBuf,
    },
    /// Output could not be written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The path.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The run would exceed a limit (steps); nothing was run.
    #[error("{0}")]
    Limit(String),
    /// A picture could not be made (a camera that sees nothing, say).
    #[error("preview: {0}")]
    Render(String),
    /// The energy is not finite although every position and velocity is: values beyond
    /// what f64 can square and sum (a mass of 1e308 kg, say).
    #[error("frame {frame} (t = {time} s): the energy is not finite (kinetic {kinetic:e} J, potential {potential:e} J) although every position and velocity is: masses, velocities or stiffnesses too large for double precision; check them{}", if *frame > 0 { format!("\n  {frames_written} frames written before remain valid in {}", out.display()) } else { String::new() })]
    NonFiniteEnergy {
        /// The frame (0: the initial state).
        frame: usize,
        /// Simulated time (s).
        time: f64,
        /// Kinetic energy (J).
        kinetic: f64,
        /// Potential energy (J).
        potential: f64,
        /// Frames written before it.
        frames_written: usize,
        /// The output folder.
        out: PathBuf,
    },
}

/// The diagonal of the bounding box of component-major positions (m; 0 for none).
pub fn diagonal(x: &[f64]) -> f64 {
    let n = x.len() / 3;
    (0..3)
        .map(|c| {
            let s = &x[c * n..(c + 1) * n];
            let lo = s.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = s.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            if hi > lo {
                (hi - lo) * (hi - lo)
            } else {
                0.0
            }
        })
        .sum::<f64>()
        .sqrt()
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> RunError + '_ {
    move |source| RunError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Runs a scene into an output folder.
pub struct Runner {
    systems: Vec<System>,
    name: String,
    duration: f64,
    dt: f64,
    output: Output,
    limits: Limits,
    out_dir: PathBuf,
    records: Vec<FrameRecord>,
    kept: Option<Vec<Mesh>>,
    /// Pictures of grid frames (fluids) for the preview, when frames are kept.
    grid_preview: Option<GridPreview>,
    /// Whether a system listens to the others' contact impulses (they record them then).
    listening: bool,
    /// The per-frame tables being written (system index, writer, path).
    tables: Vec<(usize, std::io::BufWriter<std::fs::File>, PathBuf)>,
    /// Whether one system gives moving obstacles that another takes; which systems give
    /// them; and the buffer they are gathered in (kept between steps).
    coupled: bool,
    providers: Vec<bool>,
    moving: Vec<crate::collide::MovingObstacle>,
    /// Systems that give no bodies and take none of the others' (warned in the summary).
    deaf: Vec<String>,
}

/// The preview of grid frames, made as they are written: each frame's picture is
/// written at once (`preview/frame_NNNNN.png`) and kept shrunk for the animation.
#[derive(Default)]
struct GridPreview {
    renderer: VolumeRenderer,
    image: crate::io::Image,
    shrunk: Vec<crate::io::Image>,
    seconds: f64,
}

/// Pixels on the longer side of a slice picture.
const SLICE_SIZE: u32 = 512;

/// Why a step of the scene failed.
enum StepFail {
    Integrate(IntegrateError),
    Listen(String),
}

impl Runner {
    /// A run of `scene`; output goes to `out_dir` (created on run).
    pub fn new(scene: Scene, out_dir: &Path) -> Self {
        let mut systems = scene.systems;
        let listening = systems.iter().any(|s| s.sim.listens());
        // Which systems give moving obstacles, found once (a system has bodies or not).
        let mut moving = Vec::new();
        let providers: Vec<bool> = systems
            .iter()
            .map(|s| {
                moving.clear();
                s.sim.moving_obstacles(&mut moving);
                !moving.is_empty()
            })
            .collect();
        let coupled =
            systems.iter().any(|s| s.sim.takes_moving_obstacles()) && providers.iter().any(|&p| p);
        let deaf = if providers.iter().any(|&p| p) {
            systems
                .iter()
                .zip(&providers)
                .filter(|(s, &p)| !p && !s.sim.takes_moving_obstacles())
                .map(|(s, _)| {
                    format!(
                        "[{}] does not meet the other systems' bodies: it has no contacts of its own to meet them with (give it obstacles or collisions)",
                        s.table
                    )
                })
                .collect()
        } else {
            Vec::new()
        };
        if listening {
            for s in systems.iter_mut().filter(|s| !s.sim.listens()) {
                s.sim.record_contact_impulses(true);
            }
        }
        let mut runner = Self {
            systems,
            name: scene.name,
            duration: scene.duration,
            dt: scene.dt,
            output: scene.output,
            limits: scene.limits,
            out_dir: out_dir.to_path_buf(),
            records: Vec::new(),
            kept: None,
            grid_preview: None,
            listening,
            tables: Vec::new(),
            coupled,
            providers,
            moving,
            deaf,
        };
        runner.hand_over_obstacles();
        runner
    }

    /// Opens each system's per-frame table ([`Simulation::frame_table`]) with its header:
    /// `<file>` for the first system to name it, `<table>_<file>` for any other.
    fn open_tables(&mut self) -> Result<(), RunError> {
        self.tables.clear();
        let mut names: Vec<&str> = Vec::new();
        for (k, sys) in self.systems.iter().enumerate() {
            let Some(t) = sys.sim.frame_table() else {
                continue;
            };
            let name = if names.contains(&t.file) {
                format!("{}_{}", sys.table, t.file)
            } else {
                t.file.to_string()
            };
            names.push(t.file);
            let path = self.out_dir.join(name);
            let mut w =
                std::io::BufWriter::new(crate::io::create_replacing(&path).map_err(io_err(&path))?);
            writeln!(w, "{}", t.header).map_err(io_err(&path))?;
            self.tables.push((k, w, path));
        }
        Ok(())
    }

    /// Appends frame `k`'s rows to every per-frame table, flushed (a failed run leaves
    /// whole frames).
    fn write_tables(&mut self, k: usize) -> Result<(), RunError> {
        for (sys, w, path) in self.tables.iter_mut() {
            self.systems[*sys]
                .sim
                .write_frame_rows(k, w)
                .and_then(|_| w.flush())
                .map_err(io_err(path))?;
        }
        Ok(())
    }

    /// The scene's systems.
    pub fn systems(&self) -> &[System] {
        &self.systems
    }

    /// Meshes of every system's fixed scenery (obstacles), for previews, planes cut to
    /// `around`.
    pub fn scenery(&self, around: ([f64; 3], [f64; 3])) -> Vec<Mesh> {
        self.systems
            .iter()
            .flat_map(|s| s.sim.scenery(around))
            .collect()
    }

    /// The simulation of the first system (the only one in most scenes).
    pub fn simulation(&self) -> &dyn Simulation {
        &*self.systems[0].sim
    }

    /// Simulated time (s).
    fn time(&self) -> f64 {
        self.systems[0].sim.time()
    }

    /// Integrator steps taken (sub-steps included; the most of any system).
    fn steps(&self) -> u64 {
        self.systems
            .iter()
            .map(|s| s.sim.steps())
            .max()
            .unwrap_or(0)
    }

    /// Energy summed over the systems.
    fn energy(&self) -> Energy {
        self.systems.iter().fold(Energy::default(), |e, s| {
            let x = s.sim.energy();
            Energy {
                kinetic: e.kinetic + x.kinetic,
                potential: e.potential + x.potential,
                external_work: e.external_work + x.external_work,
            }
        })
    }

    /// The deepest penetration of any system (m).
    fn max_penetration(&self) -> f64 {
        self.systems
            .iter()
            .map(|s| s.sim.max_penetration())
            .fold(0.0, f64::max)
    }

    /// One step of every system; after each, its contact impulses go to the systems that
    /// listen (a listener stepped before it hears them from its next step on).
    fn step(&mut self) -> Result<StepInfo, StepFail> {
        let mut total = StepInfo::default();
        for k in 0..self.systems.len() {
            let info = self.systems[k]
                .sim
                .step(self.dt)
                .map_err(StepFail::Integrate)?;
            total.newton_iterations += info.newton_iterations;
            total.linear_iterations += info.linear_iterations;
            total.residual = total.residual.max(info.residual);
            total.solve_seconds += info.solve_seconds;
            if self.coupled && self.providers[k] {
                self.hand_over_obstacles();
            }
            if !self.listening {
                continue;
            }
            let (before, rest) = self.systems.split_at_mut(k);
            let (source, after) = rest.split_first_mut().expect("k < len");
            let Some(impulses) = source.sim.contact_impulses() else {
                continue;
            };
            for other in before.iter_mut().chain(after) {
                if other.sim.listens() {
                    other.sim.listen(impulses).map_err(|why| {
                        StepFail::Listen(format!(
                            "step {}: the contacts of [{}] cannot drive [{}]: {why}",
                            source.sim.steps(),
                            source.table,
                            other.table
                        ))
                    })?;
                }
            }
        }
        Ok(total)
    }

    /// The systems' warnings, then those of the scene as a whole.
    fn warnings(&self) -> Vec<String> {
        let mut w: Vec<String> = self.systems.iter().flat_map(|s| s.sim.warnings()).collect();
        w.extend(self.deaf.iter().cloned());
        w
    }

    /// Gives every system that takes moving obstacles those of the others (rigid bodies at
    /// their poses now): at the start, and after each step of a system that has some
    /// (stepped first, [`super::registry::DOMAINS`]), so that the others' contacts see the
    /// bodies where they are at the end of their own step. One-way coupling.
    fn hand_over_obstacles(&mut self) {
        if !self.coupled {
            return;
        }
        for k in 0..self.systems.len() {
            if !self.systems[k].sim.takes_moving_obstacles() {
                continue;
            }
            self.moving.clear();
            for (j, s) in self.systems.iter().enumerate() {
                if j != k && self.providers[j] {
                    s.sim.moving_obstacles(&mut self.moving);
                }
            }
            self.systems[k].sim.set_moving_obstacles(&self.moving);
        }
    }

    /// Calls `f` with the frame's mesh: the system's own, or all systems' meshes as one
    /// (vertices and elements concatenated) when the scene has several.
    fn with_frame<R>(&self, f: impl FnOnce(MeshRef<'_>) -> R) -> R {
        fn mesh(s: &System) -> MeshRef<'_> {
            s.sim.frame().mesh()
        }
        if let [one] = &self.systems[..] {
            return f(mesh(one));
        }
        let merged = Mesh::concat(self.systems.iter().map(mesh));
        f(merged.as_ref())
    }

    /// Keeps a copy of every frame's mesh in memory (for a preview after the run; 24 bytes
    /// per vertex and frame, topology shared).
    pub fn keep_frames(&mut self, keep: bool) {
        self.kept = keep.then(Vec::new);
        let grids = self
            .systems
            .iter()
            .any(|s| matches!(s.sim.frame(), FrameData::Grid(_)));
        self.grid_preview = (keep && grids).then(GridPreview::default);
    }

    /// Whether the preview is made of grid pictures (written during the run) instead of
    /// meshes.
    pub fn has_grid_preview(&self) -> bool {
        self.grid_preview.is_some()
    }

    /// Writes the animation and contact sheet of the grid pictures made during the run;
    /// returns the frames and the seconds spent rendering.
    pub fn finish_grid_preview(&self) -> Result<Option<(usize, f64)>, RunError> {
        let Some(g) = &self.grid_preview else {
            return Ok(None);
        };
        if g.shrunk.is_empty() {
            return Ok(Some((0, 0.0)));
        }
        let dir = self.out_dir.join("preview");
        let settings = &self.output.preview;
        let gif: Vec<crate::io::Image> =
            crate::render::preview::evenly(g.shrunk.len(), settings.animation_max_frames)
                .into_iter()
                .map(|k| g.shrunk[k].clone())
                .collect();
        // The sheet from the frames written at full size (the GIF's are smaller); the
        // sheet shrinks them by its column count, as the mesh previews' does.
        let mut sheet = Vec::new();
        for k in crate::render::preview::evenly(g.shrunk.len(), settings.sheet_frames) {
            let path = dir.join(format!("frame_{k:05}.png"));
            let im = crate::io::read_png(&path).map_err(RunError::Render)?;
            sheet.push(im);
        }
        crate::render::preview::write_animation(&dir, &gif, &sheet, g.shrunk.len(), settings)
            .map_err(|e| RunError::Render(e.to_string()))?;
        Ok(Some((g.shrunk.len(), g.seconds)))
    }

    /// Writes frame k's pictures of the grid systems: the speed and vorticity slices
    /// (`slices/`), when frame files are written, and the preview picture.
    fn write_grid_pictures(&mut self, k: usize) -> Result<(), RunError> {
        let files = self.output.frames != FrameFormat::None;
        let several = self.systems.len() > 1;
        for s in &self.systems {
            let FrameData::Grid(g) = s.sim.frame() else {
                continue;
            };
            if files {
                let dir = self.out_dir.join("slices");
                std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
                for which in [Slice::Speed, Slice::Vorticity] {
                    let im = slice(&g, which, SLICE_SIZE);
                    let name = if several {
                        format!("{}_{}_{k:05}.png", which.name(), s.table)
                    } else {
                        format!("{}_{k:05}.png", which.name())
                    };
                    let path = dir.join(name);
                    write_atomically(&path, |w| crate::io::write_png(w, &im))
                        .map_err(io_err(&path))?;
                }
            }
            if let Some(p) = &mut self.grid_preview {
                let mut vs = VolumeSettings {
                    width: self.output.preview.render.width,
                    height: self.output.preview.render.height,
                    camera: self.output.preview.camera,
                    ..VolumeSettings::default()
                };
                vs.step = 1.0;
                let t0 = Instant::now();
                p.renderer
                    .render(&g, &vs, &mut p.image)
                    .map_err(|e| RunError::Render(e.to_string()))?;
                p.seconds += t0.elapsed().as_secs_f64();
                let dir = self.out_dir.join("preview");
                std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
                let path = dir.join(format!("frame_{k:05}.png"));
                write_atomically(&path, |w| crate::io::write_png(w, &p.image))
                    .map_err(io_err(&path))?;
                let shrink = p
                    .image
                    .width
                    .div_ceil(self.output.preview.animation_max_width.max(1))
                    .max(1);
                p.shrunk.push(p.image.downsample(shrink));
                break; // one system's pictures make the preview
            }
        }
        Ok(())
    }

    /// The frames kept so far (empty unless [`Runner::keep_frames`] was set).
    pub fn kept_frames(&self) -> &[Mesh] {
        self.kept.as_deref().unwrap_or(&[])
    }

    /// The run log so far, one record per frame (also after a failed run).
    pub fn records(&self) -> &[FrameRecord] {
        &self.records
    }

    /// The output settings.
    pub fn output(&self) -> &Output {
        &self.output
    }

    /// The output folder.
    pub fn out_dir(&self) -> &Path {
        &self.out_dir
    }

    /// The stages built and left out, one per line (each system's under its table's
    /// name when the scene has several).
    pub fn explain(&self) -> String {
        let mut s = format!("{}: stages\n", self.name);
        for system in &self.systems {
            if self.systems.len() > 1 {
                s.push_str(&format!("  [{}]\n", system.table));
            }
            for st in system.sim.stages() {
                s.push_str(&format!(
                    "  {} {:<50} {}\n",
                    if st.built { "built    " } else { "left out " },
                    st.name,
                    st.detail
                ));
            }
        }
        if self.coupled {
            // Which systems' bodies the others meet (one-way, see `Simulation::moving_obstacles`).
            let mut bodies = Vec::new();
            let givers: Vec<String> = self
                .systems
                .iter()
                .zip(&self.providers)
                .filter(|(_, &p)| p)
                .map(|(g, _)| {
                    bodies.clear();
                    g.sim.moving_obstacles(&mut bodies);
                    let n = bodies.len();
                    format!(
                        "[{}]'s {n} {}",
                        g.table,
                        if n == 1 { "body" } else { "bodies" }
                    )
                })
                .collect();
            for t in self
                .systems
                .iter()
                .filter(|t| t.sim.takes_moving_obstacles())
            {
                s.push_str(&format!(
                    "  coupling: [{}] meets {} as moving obstacles (one-way, through its own contacts, at their poses of each of its sub-steps)\n",
                    t.table,
                    givers.join(" and ")
                ));
            }
        }
        let every = format!(
            "every {} steps ({} s)",
            self.output.every,
            crate::io::human(self.output.every as f64 * self.dt)
        );
        s.push_str(&match self.output.frames {
            FrameFormat::Obj => format!("  output: OBJ frames {every}\n"),
            FrameFormat::Ply => format!("  output: PLY frames {every}\n"),
            FrameFormat::Vtk => format!("  output: VTK volume frames {every}\n"),
            FrameFormat::None => format!("  output: no frame files; energy logged {every}\n"),
        });
        s
    }

    /// Number of frames (after the initial one) the run will simulate.
    pub fn frame_count(&self, frames: Option<usize>) -> usize {
        frames.unwrap_or_else(|| {
            let steps = (self.duration / self.dt).round().max(1.0);
            (steps / self.output.every as f64).ceil() as usize
        })
    }

    /// Steps the run takes: `frames` frames, or the scene's duration; an error when that
    /// is more than the step limit.
    fn total_steps(&self, frames: Option<usize>) -> Result<usize, RunError> {
        let (steps, what) = match frames {
            Some(f) => (
                f as f64 * self.output.every as f64,
                format!("{f} frames of {} steps", self.output.every),
            ),
            None => (
                (self.duration / self.dt).round().max(1.0),
                format!(
                    "{} s at dt = {} s",
                    crate::io::human(self.duration),
                    crate::io::human(self.dt)
                ),
            ),
        };
        self.limits.steps(&what, steps).map_err(RunError::Limit)?;
        Ok(steps as usize)
    }

    fn write_frame(&mut self, k: usize) -> Result<bool, RunError> {
        self.write_grid_pictures(k)?;
        self.write_tables(k)?;
        let copy = self.kept.is_some().then(|| self.with_frame(Mesh::from_ref));
        if let (Some(kept), Some(mut m)) = (&mut self.kept, copy) {
            if let Some(prev) = kept.last() {
                m.share_topology(prev);
            }
            kept.push(m);
        }
        let ext = match self.output.frames {
            FrameFormat::Obj => "obj",
            FrameFormat::Ply => "ply",
            FrameFormat::Vtk => return self.write_volumes(k),
            FrameFormat::None => return Ok(false),
        };
        let path = self
            .out_dir
            .join("frames")
            .join(format!("frame_{k:05}.{ext}"));
        let comment = format!("largestep {} frame {k} t = {}", self.name, self.time());
        let format = self.output.frames;
        self.with_frame(|mesh| {
            write_atomically(&path, |w| match format {
                FrameFormat::Ply => write_ply(w, mesh, &comment),
                _ => write_obj(w, mesh, &comment),
            })
        })
        .map_err(io_err(&path))?;
        Ok(true)
    }

    /// Writes frame k of every volumetric system as legacy VTK (see [`FrameFormat::Vtk`]).
    fn write_volumes(&self, k: usize) -> Result<bool, RunError> {
        let volumes: Vec<&System> = self.systems.iter().filter(|s| s.sim.has_volume()).collect();
        for s in &volumes {
            let file = if volumes.len() == 1 {
                format!("frame_{k:05}.vtk")
            } else {
                format!("frame_{k:05}_{}.vtk", s.table)
            };
            let path = self.out_dir.join("frames").join(file);
            let title = format!(
                "largestep {} [{}] frame {k} t = {}",
                self.name,
                s.table,
                self.time()
            );
            write_atomically(&path, |w| s.sim.write_volume(w, &title)).map_err(io_err(&path))?;
        }
        Ok(true)
    }

    /// The integrators' names (one, unless systems differ).
    fn method(&self) -> String {
        let mut names: Vec<String> = self.systems.iter().map(|s| s.sim.method()).collect();
        names.dedup();
        names.join(", ")
    }

    /// Runs `frames` frames (default: the scene's duration), calling `progress` after each,
    /// then writes the sound of every system that made one ([`Runner::sound_files`]),
    /// also after a failure (the sound up to it).
    pub fn run(
        &mut self,
        frames: Option<usize>,
        progress: &mut dyn FnMut(&Progress),
    ) -> Result<Summary, RunError> {
        let result = self.run_frames(frames, progress);
        let sound = self.write_sound();
        let summary = result?;
        sound?;
        Ok(summary)
    }

    /// The WAV file of each system that makes sound: `sound.wav` for the first,
    /// `sound_<table>_<k>.wav` for any further one.
    pub fn sound_files(&self) -> Vec<PathBuf> {
        self.sounds().map(|(path, _)| path).collect()
    }

    /// Each system's sound with its WAV file's path ([`Runner::sound_files`]).
    fn sounds(&self) -> impl Iterator<Item = (PathBuf, Audio<'_>)> {
        self.systems
            .iter()
            .filter_map(|s| s.sim.audio().map(|a| (s.table, a)))
            .enumerate()
            .map(|(k, (table, a))| {
                let name = if k == 0 {
                    "sound.wav".to_string()
                } else {
                    format!("sound_{table}_{}.wav", k + 1)
                };
                (self.out_dir.join(name), a)
            })
    }

    /// Writes [`Runner::sound_files`] (16-bit mono WAV, scaled to 0.9 of full scale).
    fn write_sound(&self) -> Result<(), RunError> {
        for (path, a) in self.sounds() {
            if a.samples.is_empty() {
                continue;
            }
            std::fs::create_dir_all(&self.out_dir).map_err(io_err(&self.out_dir))?;
            crate::io::write_wav(&path, a.samples, a.sample_rate).map_err(io_err(&path))?;
        }
        Ok(())
    }

    fn run_frames(
        &mut self,
        frames: Option<usize>,
        progress: &mut dyn FnMut(&Progress),
    ) -> Result<Summary, RunError> {
        let start = Instant::now();
        let total_steps = self.total_steps(frames)?;
        let total_frames = total_steps.div_ceil(self.output.every);
        let frames_dir = self.out_dir.join("frames");
        std::fs::create_dir_all(&frames_dir).map_err(io_err(&frames_dir))?;
        // An earlier run's frames would mix with this one's (a longer run leaves more):
        // they go, with the temporaries of interrupted writes, and an earlier summary
        // (written after a run succeeds) that would describe another run.
        crate::io::remove_stale(&frames_dir, |n| n.starts_with("frame_"))
            .map_err(io_err(&frames_dir))?;
        crate::io::remove_stale(&self.out_dir, |n| {
            n == "summary.json"
                || (n.starts_with("sound") && n.ends_with(".wav"))
                || (n.starts_with("spectrogram") && n.ends_with(".png"))
        })
        .map_err(io_err(&self.out_dir))?;
        let csv_path = self.out_dir.join("energy.csv");
        let mut csv = std::io::BufWriter::new(
            crate::io::create_replacing(&csv_path).map_err(io_err(&csv_path))?,
        );
        writeln!(csv, "{}", FrameRecord::CSV_HEADER).map_err(io_err(&csv_path))?;
        self.open_tables()?;

        let e0 = self.energy();
        let e_start = e0.total();
        let mut max_kinetic = e0.kinetic;
        self.records.clear();
        let mut written = self.write_frame(0)? as usize;
        let record = |frame: usize, run: &Runner, newton, linear, steps, secs| {
            let e = run.energy();
            FrameRecord {
                frame,
                time: run.time(),
                kinetic: e.kinetic,
                potential: e.potential,
                penetration: run.max_penetration(),
                newton_iterations: newton,
                linear_iterations: linear,
                steps,
                step_seconds: secs,
                external_work: e.external_work,
            }
        };
        let finite = |r: &FrameRecord, written: usize, out: &Path| {
            if (r.kinetic + r.potential).is_finite() {
                Ok(())
            } else {
                Err(RunError::NonFiniteEnergy {
                    frame: r.frame,
                    time: r.time,
                    kinetic: r.kinetic,
                    potential: r.potential,
                    frames_written: written,
                    out: out.to_path_buf(),
                })
            }
        };
        let mut log = |r: FrameRecord, records: &mut Vec<FrameRecord>| {
            records.push(r);
            r.write_csv(&mut csv).and_then(|_| csv.flush())
        };
        let r = record(0, self, 0, 0, 0, 0.0);
        log(r, &mut self.records).map_err(io_err(&csv_path))?;
        finite(&r, written, &self.out_dir)?;
        let mut summary = Summary {
            name: self.name.clone(),
            method: self.method(),
            linear_solver: self.systems.iter().find_map(|s| s.sim.linear_solver()),
            steps: 0,
            frames_written: 0,
            sim_time: 0.0,
            step_seconds: 0.0,
            wall_seconds: 0.0,
            energy: (e_start, e_start),
            external_work: 0.0,
            max_penetration: 0.0,
            size: self.with_frame(|m| diagonal(m.positions)),
            energy_drift: 0.0,
            energy_scale: 0.0,
            energy_peak: (0.0, 0.0),
            newton: self.systems.iter().any(|s| {
                s.sim
                    .stages()
                    .iter()
                    .any(|st| st.built && st.name == crate::simulation::NEWTON_STAGE)
            }),
            newton_iterations: 0,
            linear_iterations: 0,
            max_linear_iterations: 0,
            warnings: self.warnings(),
            out_dir: self.out_dir.clone(),
        };
        let mut steps_done = 0usize;
        for frame in 1..=total_frames {
            let (mut newton, mut linear) = (0, 0);
            let t0 = Instant::now();
            let n = self.output.every.min(total_steps - steps_done);
            for _ in 0..n {
                let info = self.step().map_err(|fail| match fail {
                    StepFail::Integrate(source) => RunError::Integrate {
                        source,
                        frames_written: written,
                        out: self.out_dir.clone(),
                    },
                    StepFail::Listen(message) => RunError::Listen {
                        message,
                        frames_written: written,
                        out: self.out_dir.clone(),
                    },
                })?;
                newton += info.newton_iterations;
                linear += info.linear_iterations;
                summary.max_linear_iterations =
                    summary.max_linear_iterations.max(info.linear_iterations);
            }
            let secs = t0.elapsed().as_secs_f64();
            steps_done += n;
            summary.step_seconds += secs;
            summary.newton_iterations += newton;
            summary.linear_iterations += linear;
            max_kinetic = max_kinetic.max(self.energy().kinetic);
            written += self.write_frame(frame)? as usize;
            let r = record(frame, self, newton, linear, n, secs);
            log(r, &mut self.records).map_err(io_err(&csv_path))?;
            finite(&r, written, &self.out_dir)?;
            progress(&Progress {
                frame,
                frames: total_frames,
                steps: self.steps(),
                time: self.time(),
            });
        }
        let end = self.energy();
        let e1 = end.total();
        summary.steps = self.steps();
        summary.frames_written = written;
        summary.sim_time = self.time();
        summary.energy = (e_start, e1);
        summary.external_work = end.external_work;
        summary.max_penetration = self
            .records
            .iter()
            .map(|r| r.penetration)
            .fold(0.0, f64::max);
        let scale = e_start
            .abs()
            .max(max_kinetic)
            .max(end.external_work.abs())
            .max(f64::MIN_POSITIVE);
        summary.energy_scale = scale;
        summary.energy_drift = (e1 - e_start - end.external_work) / scale;
        summary.energy_peak = self
            .records
            .iter()
            .map(|r| {
                let gain = r.kinetic + r.potential - e_start - r.external_work;
                (gain / scale, r.time)
            })
            .fold((0.0, 0.0), |a, b| if b.0 > a.0 { b } else { a });
        summary.warnings = self.warnings();
        summary.wall_seconds = start.elapsed().as_secs_f64();
        Ok(summary)
    }
}

#[cfg(feature = "cli")]
impl Runner {
    /// Writes the spectrogram of each sound next to its WAV file
    /// ([`Runner::sound_files`]: `sound.wav` gives `spectrogram.png`, `sound_x_2.wav`
    /// gives `spectrogram_x_2.png`). Works after a failed run too.
    pub fn write_spectrograms(&self) -> Result<Vec<PathBuf>, RunError> {
        let mut written = Vec::new();
        for (wav, a) in self.sounds() {
            if a.samples.is_empty() {
                continue;
            }
            let stem = wav.file_stem().and_then(|s| s.to_str()).unwrap_or("sound");
            let path =
                wav.with_file_name(format!("{}.png", stem.replacen("sound", "spectrogram", 1)));
            crate::plot::write_spectrogram(
                &path,
                a.samples,
                a.sample_rate,
                &format!("{}: spectrogram of {}", self.name, stem),
            )
            .map_err(|e| RunError::Io {
                path: path.clone(),
                source: std::io::Error::other(e),
            })?;
            written.push(path);
        }
        Ok(written)
    }

    /// Writes `run.svg` and `run.png` into the output folder: energy, solver iterations
    /// per step (implicit integrators only) and wall time per step, against simulated
    /// time, one point per frame. Works after a failed run too (up to the failure).
    pub fn write_plot(&self) -> Result<PathBuf, RunError> {
        use crate::plot::{write_panels, Curve, Panel, Scale};
        let r = &self.records;
        let series = |label: &str, f: &dyn Fn(&FrameRecord) -> f64, skip_first: bool| Curve {
            label: label.to_string(),
            points: r
                .iter()
                .skip(skip_first as usize)
                .map(|x| (x.time, f(x)))
                .collect(),
            dashed: false,
        };
        let panel = |title: &str, y: &str, curves: Vec<Curve>| Panel {
            title: title.to_string(),
            x_label: "simulated time (s)".into(),
            y_label: y.to_string(),
            scale: Scale::Linear,
            curves: curves.into_iter().enumerate().collect(),
        };
        let per_step = |v: usize, x: &FrameRecord| v as f64 / x.steps.max(1) as f64;
        let mut panels = vec![panel(
            &format!("{}: energy", self.name),
            "energy (J)",
            vec![
                series("kinetic", &|x| x.kinetic, false),
                series("potential", &|x| x.potential, false),
                series("total", &|x| x.kinetic + x.potential, false),
            ],
        )];
        if r.iter()
            .any(|x| x.newton_iterations + x.linear_iterations > 0)
        {
            panels.push(panel(
                "solver iterations per step",
                "iterations",
                vec![
                    series("Newton", &|x| per_step(x.newton_iterations, x), true),
                    series("linear solver", &|x| per_step(x.linear_iterations, x), true),
                ],
            ));
        }
        panels.push(panel(
            "wall time per step",
            "time per step (ms)",
            vec![series(
                "step",
                &|x| 1e3 * x.step_seconds / x.steps.max(1) as f64,
                true,
            )],
        ));
        let stem = self.out_dir.join("run");
        write_panels(&stem, &panels, panels.len(), (520, 380)).map_err(|message| RunError::Io {
            path: stem.clone(),
            source: std::io::Error::other(message),
        })?;
        Ok(stem.with_extension("png"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn summary() -> Summary {
        Summary {
            name: "s".into(),
            method: "linearized-backward-euler".into(),
            linear_solver: Some("cholesky"),
            steps: 480,
            frames_written: 121,
            sim_time: 4.000000000000003,
            step_seconds: 1.7881234,
            wall_seconds: 1.8781234,
            energy: (7.549012345, 4.907012345),
            external_work: 0.0,
            max_penetration: 0.0,
            size: 1.0,
            energy_drift: -0.35,
            energy_scale: 7.549012345,
            energy_peak: (0.0, 0.0),
            newton: false,
            newton_iterations: 480,
            linear_iterations: 0,
            max_linear_iterations: 0,
            warnings: Vec::new(),
            out_dir: PathBuf::from("out/s"),
        }
    }

    /// Issue 14: the summary rounds for people, names the scale of the relative change,
    /// says no Newton iteration ran for the linearised step, and warns of a transient rise
    /// the end value hides.
    #[test]
    fn the_summary_is_rounded_says_its_scale_and_warns_of_a_transient_rise() {
        let text = summary().to_string();
        assert!(text.contains("(4 s simulated)"), "{text}");
        assert!(
            text.contains("7.549 J at the start, 4.907 J at the end"),
            "{text}"
        );
        assert!(
            text.contains("-35.0% of the energy scale 7.549 J"),
            "{text}"
        );
        assert!(!text.contains("Newton iterations"), "{text}");
        assert!(text.contains("no Newton iteration"), "{text}");
        assert!(!text.contains("warning"), "{text}");
        assert!(!text.contains("00000"), "unrounded number: {text}");

        let mut s = summary();
        s.newton = true;
        s.newton_iterations = 1000;
        s.linear_iterations = 4800;
        s.max_linear_iterations = 17;
        let text = s.to_string();
        assert!(
            text.contains("1000 Newton iterations (2.083 per step)"),
            "{text}"
        );
        assert!(
            text.contains("4800 solver iterations (10 per step, at most 17)"),
            "{text}"
        );

        let mut s = summary();
        s.energy_peak = (1.48, 0.2);
        let text = s.to_string();
        assert!(
            text.contains("rose by +148.0% of its scale at t = 0.2 s"),
            "{text}"
        );
    }

    #[test]
    fn numbers_for_people_keep_four_significant_digits() {
        use crate::io::human;
        assert_eq!(human(1.0 / 30.0), "0.03333");
        assert_eq!(human(4.000000000000003), "4");
        assert_eq!(human(-1.178899), "-1.179");
        assert_eq!(human(480.0), "480");
        assert_eq!(human(0.0), "0");
        assert_eq!(human(2.5e-7), "2.50e-7");
        assert_eq!(human(f64::NAN), "NaN");
    }
}
