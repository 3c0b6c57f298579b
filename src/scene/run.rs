//! Running a scene: steps, frames, the energy log and the closing summary.
//!
//! Frame k (k = 0 is the initial state) is written after `k * every` steps as
//! `frames/frame_NNNNN.obj` (or `.ply`), atomically; `energy.csv` gets one line per frame,
//! flushed as it is written. A failure (a blow-up, an I/O error) stops the run with an
//! error naming the step; every frame and log line written before it stays valid.

use super::{Scene, Simulation};
use crate::integrate::IntegrateError;
use crate::io::{write_atomically, write_obj, write_ply, Mesh};
use crate::render::preview::PreviewSettings;
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
}

impl FrameRecord {
    const CSV_HEADER: &'static str = "frame,time_s,kinetic_J,potential_J,total_J,penetration_m,newton_iterations,linear_iterations,step_seconds";

    fn write_csv(&self, w: &mut dyn Write) -> std::io::Result<()> {
        writeln!(
            w,
            "{},{},{},{},{},{},{},{},{}",
            self.frame,
            self.time,
            self.kinetic,
            self.potential,
            self.kinetic + self.potential,
            self.penetration,
            self.newton_iterations,
            self.linear_iterations,
            self.step_seconds
        )
    }
}

/// What a finished run reports.
#[derive(Clone, Debug)]
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
    /// `(E_end - E_start) / max(|E_start|, largest kinetic energy seen)`.
    pub energy_drift: f64,
    /// Newton iterations, summed.
    pub newton_iterations: usize,
    /// Linear-solver iterations, summed.
    pub linear_iterations: usize,
    /// Most linear-solver iterations in one step.
    pub max_linear_iterations: usize,
    /// The output folder.
    pub out_dir: PathBuf,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{}: {} steps of {} ({:.4} s simulated)",
            self.name, self.steps, self.method, self.sim_time
        )?;
        writeln!(
            f,
            "  wall time      {:.3} s ({:.3} s stepping, {:.1} us/step)",
            self.wall_seconds,
            self.step_seconds,
            1e6 * self.step_seconds / self.steps.max(1) as f64
        )?;
        writeln!(
            f,
            "  energy         {:.6e} J -> {:.6e} J (relative change {:+.3e})",
            self.energy.0, self.energy.1, self.energy_drift
        )?;
        if self.energy_drift > 0.1 {
            writeln!(
                f,
                "  warning        total energy grew by {:.0}% of its scale: the integrator is probably unstable at this dt (reduce dt or use an implicit integrator)",
                100.0 * self.energy_drift
            )?;
        }
        if let Some(ls) = self.linear_solver {
            writeln!(
                f,
                "  solver         {ls}: {} Newton iterations, {} linear iterations (max {} per step)",
                self.newton_iterations, self.linear_iterations, self.max_linear_iterations
            )?;
        } else {
            writeln!(f, "  solver         none (explicit)")?;
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
    /// Output could not be written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The path.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> RunError + '_ {
    move |source| RunError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Runs a scene into an output folder.
pub struct Runner {
    sim: Simulation,
    name: String,
    duration: f64,
    dt: f64,
    output: Output,
    out_dir: PathBuf,
    records: Vec<FrameRecord>,
    kept: Option<Vec<Mesh>>,
}

impl Runner {
    /// Builds the simulation of `scene`; output goes to `out_dir` (created on run).
    pub fn new(scene: Scene, out_dir: &Path) -> Result<Self, RunError> {
        let (name, duration, dt, output) =
            (scene.name.clone(), scene.duration, scene.dt, scene.output);
        let sim = Simulation::new(scene).map_err(|source| RunError::Integrate {
            source,
            frames_written: 0,
            out: out_dir.to_path_buf(),
        })?;
        Ok(Self {
            sim,
            name,
            duration,
            dt,
            output,
            out_dir: out_dir.to_path_buf(),
            records: Vec::new(),
            kept: None,
        })
    }

    /// Keeps a copy of every frame's mesh in memory (for a preview after the run; 24 bytes
    /// per vertex and frame, topology shared).
    pub fn keep_frames(&mut self, keep: bool) {
        self.kept = keep.then(Vec::new);
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

    /// The simulation.
    pub fn simulation(&self) -> &Simulation {
        &self.sim
    }

    /// The stages built and left out, one per line.
    pub fn explain(&self) -> String {
        let mut s = format!("{}: stages\n", self.name);
        for st in self.sim.stages() {
            s.push_str(&format!(
                "  {} {:<50} {}\n",
                if st.built { "built    " } else { "left out " },
                st.name,
                st.detail
            ));
        }
        s.push_str(&format!(
            "  output: {:?} frames every {} steps ({} s)\n",
            self.output.frames,
            self.output.every,
            self.output.every as f64 * self.dt
        ));
        s
    }

    /// Number of frames (after the initial one) the run will simulate.
    pub fn frame_count(&self, frames: Option<usize>) -> usize {
        frames.unwrap_or_else(|| self.total_steps(None).div_ceil(self.output.every))
    }

    /// Steps the run takes: `frames` frames, or the scene's duration.
    fn total_steps(&self, frames: Option<usize>) -> usize {
        match frames {
            Some(f) => f * self.output.every,
            None => (self.duration / self.dt).round().max(1.0) as usize,
        }
    }

    fn write_frame(&mut self, k: usize) -> Result<bool, RunError> {
        if let Some(kept) = &mut self.kept {
            let mut m = Mesh::from_ref(self.sim.mesh());
            if let Some(prev) = kept.last() {
                m.share_topology(prev);
            }
            kept.push(m);
        }
        let ext = match self.output.frames {
            FrameFormat::Obj => "obj",
            FrameFormat::Ply => "ply",
            FrameFormat::None => return Ok(false),
        };
        let path = self
            .out_dir
            .join("frames")
            .join(format!("frame_{k:05}.{ext}"));
        let mesh = self.sim.mesh();
        let comment = format!("largestep {} frame {k} t = {}", self.name, self.sim.time());
        write_atomically(&path, |w| match self.output.frames {
            FrameFormat::Ply => write_ply(w, mesh, &comment),
            _ => write_obj(w, mesh, &comment),
        })
        .map_err(io_err(&path))?;
        Ok(true)
    }

    /// Runs `frames` frames (default: the scene's duration), calling `progress` after each.
    pub fn run(
        &mut self,
        frames: Option<usize>,
        progress: &mut dyn FnMut(&Progress),
    ) -> Result<Summary, RunError> {
        let start = Instant::now();
        let total_frames = self.frame_count(frames);
        let total_steps = self.total_steps(frames);
        let frames_dir = self.out_dir.join("frames");
        std::fs::create_dir_all(&frames_dir).map_err(io_err(&frames_dir))?;
        let csv_path = self.out_dir.join("energy.csv");
        let mut csv =
            std::io::BufWriter::new(std::fs::File::create(&csv_path).map_err(io_err(&csv_path))?);
        writeln!(csv, "{}", FrameRecord::CSV_HEADER).map_err(io_err(&csv_path))?;

        let (k0, p0) = self.sim.energy();
        let e_start = k0 + p0;
        let mut max_kinetic = k0;
        self.records.clear();
        let mut written = self.write_frame(0)? as usize;
        let record = |frame: usize, sim: &Simulation, newton, linear, steps, secs| {
            let (kinetic, potential) = sim.energy();
            FrameRecord {
                frame,
                time: sim.time(),
                kinetic,
                potential,
                penetration: sim.max_penetration(),
                newton_iterations: newton,
                linear_iterations: linear,
                steps,
                step_seconds: secs,
            }
        };
        let mut log = |r: FrameRecord, records: &mut Vec<FrameRecord>| {
            records.push(r);
            r.write_csv(&mut csv).and_then(|_| csv.flush())
        };
        log(record(0, &self.sim, 0, 0, 0, 0.0), &mut self.records).map_err(io_err(&csv_path))?;
        let mut summary = Summary {
            name: self.name.clone(),
            method: self.sim.method().to_string(),
            linear_solver: self.sim.linear_solver(),
            steps: 0,
            frames_written: 0,
            sim_time: 0.0,
            step_seconds: 0.0,
            wall_seconds: 0.0,
            energy: (e_start, e_start),
            energy_drift: 0.0,
            newton_iterations: 0,
            linear_iterations: 0,
            max_linear_iterations: 0,
            out_dir: self.out_dir.clone(),
        };
        let mut steps_done = 0usize;
        for frame in 1..=total_frames {
            let (mut newton, mut linear) = (0, 0);
            let t0 = Instant::now();
            let n = self.output.every.min(total_steps - steps_done);
            for _ in 0..n {
                let info = self.sim.step().map_err(|source| RunError::Integrate {
                    source,
                    frames_written: written,
                    out: self.out_dir.clone(),
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
            max_kinetic = max_kinetic.max(self.sim.energy().0);
            written += self.write_frame(frame)? as usize;
            log(
                record(frame, &self.sim, newton, linear, n, secs),
                &mut self.records,
            )
            .map_err(io_err(&csv_path))?;
            progress(&Progress {
                frame,
                frames: total_frames,
                steps: self.sim.steps(),
                time: self.sim.time(),
            });
        }
        let (k1, p1) = self.sim.energy();
        summary.steps = self.sim.steps();
        summary.frames_written = written;
        summary.sim_time = self.sim.time();
        summary.energy = (e_start, k1 + p1);
        let scale = e_start.abs().max(max_kinetic).max(f64::MIN_POSITIVE);
        summary.energy_drift = (k1 + p1 - e_start) / scale;
        summary.wall_seconds = start.elapsed().as_secs_f64();
        Ok(summary)
    }
}

#[cfg(feature = "cli")]
impl Runner {
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
