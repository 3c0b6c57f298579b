//! The `largestep` command-line tool: run scenes, run studies, measure the machine.
//!
//! Exit status: 0 on success, 1 when a run fails (blow-up, solver failure, I/O), 2 for
//! bad input (unreadable or invalid scene, bad arguments).

use clap::error::{ContextKind, ContextValue, ErrorKind};
use clap::{CommandFactory, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use largestep::limits::Limits;
use largestep::render::preview::{load_frames, preview_region, write_preview, PreviewSettings};
use largestep::render::{
    Camera, CameraSpec, RenderError, DEFAULT_AZIMUTH_DEG, DEFAULT_ELEVATION_DEG,
};
use largestep::scene::{Runner, Scene};
use largestep::study::Progress;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "largestep",
    version,
    about = "Physically based animation kernels: run scenes, studies and machine measurements"
)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Memory a scene may ask for, in bytes or with a unit: 512M, 4G (default: half of
    /// what this process may use). Input files may be a quarter of it, at most 1 GiB.
    #[arg(long, global = true, value_parser = parse_bytes)]
    max_memory: Option<u64>,
    /// Steps a run may take (default: 100000000).
    #[arg(long, global = true)]
    max_steps: Option<u64>,
    #[command(subcommand)]
    command: Command,
}

impl Cli {
    /// The limits inputs are checked against: the defaults of this machine, changed by
    /// `--max-memory` and `--max-steps`.
    fn limits(&self) -> Limits {
        let mut l = match self.max_memory {
            Some(m) => Limits::with_memory(m),
            None => Limits::default(),
        };
        if let Some(s) = self.max_steps {
            l.max_steps = s;
        }
        l
    }
}

/// `4096`, `512k`, `512M`, `4G`, `1T` (powers of 1024; a trailing `B` or `iB` is allowed).
fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let t = t
        .strip_suffix("iB")
        .or_else(|| t.strip_suffix('B'))
        .unwrap_or(t);
    let (num, shift) = match t.chars().last() {
        Some('k' | 'K') => (&t[..t.len() - 1], 10),
        Some('m' | 'M') => (&t[..t.len() - 1], 20),
        Some('g' | 'G') => (&t[..t.len() - 1], 30),
        Some('t' | 'T') => (&t[..t.len() - 1], 40),
        _ => (t, 0),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("`{s}`: expected a size such as 4096, 512M or 4G"))?;
    let bytes = v * (1u64 << shift) as f64;
    if !(1.0..1.8e19).contains(&bytes) {
        return Err(format!("`{s}`: a size must be at least 1 byte"));
    }
    Ok(bytes as u64)
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a scene file and write its frames, energy log and summary.
    Run {
        /// The scene (TOML).
        scene: PathBuf,
        /// Output folder (default: out/<scene name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Simulate this many frames only (overrides the scene's duration).
        #[arg(long)]
        frames: Option<usize>,
        /// List the stages built and those left out, then run.
        #[arg(long)]
        explain: bool,
        /// Also render the frames: preview/frame_NNNNN.png, preview/animation.gif and
        /// preview/contact-sheet.png (camera and size from the scene's [output] table).
        #[arg(long)]
        preview: bool,
    },
    /// Render a folder of OBJ frames to PNGs, an animated GIF and a contact sheet.
    Render {
        /// Folder of frame_NNNNN.obj files (any *.obj, in name order).
        frames: PathBuf,
        /// Output folder (default: a `preview` folder beside FRAMES).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Take size, camera and timing from this scene's [output] table.
        #[arg(long)]
        scene: Option<PathBuf>,
        #[command(flatten)]
        view: ViewArgs,
    },
    /// Haptic rendering, replayed at 1 kHz along a device path: a point probe against a
    /// closed triangle mesh (god object with a virtual-coupling spring), or with --tool a
    /// rigid tool's point shell against the mesh's distance field (six-DoF virtual
    /// coupling). Writes haptics.csv (per tick: time_s, device and proxy or tool pose,
    /// force, torque with --tool, work_us), haptics.png (the force trace) and
    /// summary.json, and prints the loop's latency percentiles.
    Haptics {
        /// The closed surface (.obj, .off).
        mesh: PathBuf,
        /// The device path: a CSV of t,x,y,z rows (s, m), or t,x,y,z,qw,qx,qy,qz rows for
        /// a tool's pose. Default: a scripted 3 s stroke down onto the mesh's highest
        /// vertex (a tool: onto the point a quarter of the way across it in x, in the
        /// middle in z), a tenth of its height into it and along +x by 0.4 of its width
        /// (a tool also tilts by 20 degrees about z as it slides), written to
        /// device-path.csv.
        #[arg(long)]
        path: Option<PathBuf>,
        /// Coupling spring stiffness (N/m).
        #[arg(long, default_value_t = 500.0)]
        stiffness: f64,
        /// Six-DoF: a rigid tool (.obj, .off; m, in the tool's frame, which the device
        /// pose places); its surface sampled at the distance grid's spacing is its point
        /// shell.
        #[arg(long)]
        tool: Option<PathBuf>,
        /// Six-DoF rotational coupling stiffness (N m/rad). Default: --stiffness times
        /// the square of the tool's radius about its frame's origin.
        #[arg(long)]
        rotation_stiffness: Option<f64>,
        /// Six-DoF contact stiffness per shell point (N/m). Default: 4 x --stiffness.
        #[arg(long)]
        contact_stiffness: Option<f64>,
        /// Six-DoF: cells of the mesh's distance grid along its longest side.
        #[arg(long, default_value_t = 64)]
        cells: usize,
        /// Output folder.
        #[arg(long, default_value = "out/haptics")]
        out: PathBuf,
    },
    /// Run a study: error against run time, orders, stability.
    Study {
        /// Which study (integrators, jello-stability, jello-accuracy, cloth-accuracy, cloth-stability,
        /// fem-accuracy, fem-stability, fem-steps, modes, fluids, poisson, cavity, distance-fields,
        /// rigid-integrators, rigid-contacts, rigid-reuse, anim-ik, anim-sampling).
        name: String,
        /// Output folder for the report (default: out/studies; `--out docs/studies`
        /// regenerates the committed reports).
        #[arg(long, default_value = "out/studies")]
        out: PathBuf,
        /// Fewer, coarser sweeps (for a quick look; reports say so).
        #[arg(long)]
        quick: bool,
    },
    /// The lowest vibration modes of a tetrahedral mesh (K x = lambda M x): a table of
    /// frequencies and residuals, the count of rigid modes, and with --json
    /// {"frequencies_hz": [non-rigid, ascending], "eigenvalues": [every mode listed, rigid
    /// first, 1/s^2], "rigid_modes": k, "residuals": [per eigenvalue], "seconds": t}.
    #[cfg(feature = "modal")]
    Modes {
        /// The mesh: TetGen .node (its .ele beside it), Gmsh .msh, legacy VTK .vtk or
        /// Vega .veg; or a closed triangle surface (.obj, .off), voxel-meshed.
        mesh: PathBuf,
        /// Young's modulus in Pa (default: the .veg file's materials, else steel, 200e9).
        #[arg(long)]
        young: Option<f64>,
        /// Poisson's ratio (default 0.30).
        #[arg(long)]
        poisson: Option<f64>,
        /// Density in kg/m^3 (default 7850).
        #[arg(long)]
        density: Option<f64>,
        /// Non-rigid modes to find.
        #[arg(long, default_value_t = largestep::modal::DEFAULT_COUNT)]
        count: usize,
        /// Mass matrix: consistent or lumped.
        #[arg(long, default_value = "consistent")]
        mass: largestep::fem::FemMass,
        /// Vertices held fixed: x<=V (also y, z and >=), box:X0,Y0,Z0,X1,Y1,Z1 or
        /// vertices:I,J,... (from 0).
        #[arg(long)]
        fixed: Option<largestep::modal::Selector>,
        /// Write the numbers as JSON to this file.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Write each mode's shape as VTK (mode_NN.vtk) into this folder, and the first six
        /// modes oscillating as pictures (mode_NN/animation.gif, PNG frames, a contact
        /// sheet).
        #[arg(long)]
        out: Option<PathBuf>,
        /// For a surface mesh: the voxel mesher's cube size in the file's units (default:
        /// the longest side of its bounding box over 40).
        #[arg(long)]
        voxel: Option<f64>,
    },
    /// Character animation: motion capture and skeletons.
    #[cfg(feature = "anim")]
    Anim {
        #[command(subcommand)]
        command: AnimCommand,
    },
    /// Measure this machine's memory bandwidth (triad) and peak f64 FMA rate.
    Machine {
        /// Size of each triad array in MiB.
        #[arg(long, default_value_t = largestep::machine::DEFAULT_TRIAD_MIB)]
        triad_mib: usize,
    },
}

/// What `largestep anim` does.
#[cfg(feature = "anim")]
#[derive(Subcommand)]
enum AnimCommand {
    /// Forward kinematics of a BVH clip: the world position of every joint (End Sites
    /// included, named `<parent>_end`) at one frame, in the file's own units and joint
    /// order, as {"frame": K, "joints": [{"name": ..., "position": [x, y, z]}, ...]}:
    /// to the --json file, else to standard output.
    Fk {
        /// The clip (.bvh).
        file: PathBuf,
        /// The frame, from 0.
        #[arg(long, default_value_t = 0)]
        frame: usize,
        /// Write the JSON to this file (and a table to standard output).
        #[arg(long)]
        json: Option<PathBuf>,
    },
}

/// Camera and image options of `render` (each overrides the scene's or the default).
#[derive(clap::Args)]
struct ViewArgs {
    /// Image size, WIDTHxHEIGHT (default 1280x720).
    #[arg(long, value_parser = parse_size)]
    size: Option<(u32, u32)>,
    /// Samples per pixel along each axis, 1..=4 (default 2).
    #[arg(long)]
    supersample: Option<u32>,
    /// Fixed camera position X,Y,Z (needs --target).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    eye: Option<[f64; 3]>,
    /// Point the fixed camera looks at, X,Y,Z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    target: Option<[f64; 3]>,
    /// World up direction X,Y,Z (default 0,1,0).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    up: Option<[f64; 3]>,
    /// Vertical field of view in degrees (default 40).
    #[arg(long)]
    fov: Option<f64>,
    /// Auto-framing direction about the up axis, degrees (default 35; 0 looks from +z).
    #[arg(long, allow_hyphen_values = true)]
    azimuth: Option<f64>,
    /// Auto-framing height above the ground, degrees (default 22).
    #[arg(long, allow_hyphen_values = true)]
    elevation: Option<f64>,
    /// Draw triangle edges.
    #[arg(long)]
    wireframe: bool,
    /// Leave out the ground plane.
    #[arg(long)]
    no_ground: bool,
    /// Frames per second of the animation (default 30, or the scene's frame rate).
    #[arg(long)]
    fps: Option<f64>,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got `{s}`"))?;
    let p = |v: &str| v.trim().parse::<u32>().map_err(|e| format!("`{v}`: {e}"));
    Ok((p(w)?, p(h)?))
}

fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|c| c.trim().parse::<f64>().map_err(|e| format!("`{c}`: {e}")))
        .collect::<Result<_, _>>()?;
    <[f64; 3]>::try_from(v).map_err(|v| format!("expected X,Y,Z, got {} numbers", v.len()))
}

impl ViewArgs {
    /// `base` with these options applied.
    fn apply(&self, mut p: PreviewSettings) -> Result<PreviewSettings, String> {
        if let Some((w, h)) = self.size {
            p.render.width = w;
            p.render.height = h;
        }
        if let Some(s) = self.supersample {
            p.render.supersample = s;
        }
        p.render.ground &= !self.no_ground;
        p.wireframe |= self.wireframe;
        if let Some(fps) = self.fps {
            if !(fps > 0.0 && fps.is_finite()) {
                return Err(format!("--fps must be > 0, got {fps}"));
            }
            p.frame_interval = 1.0 / fps;
        }
        let (az, el, fov, up) = match p.camera {
            CameraSpec::Auto {
                azimuth_deg,
                elevation_deg,
                fov_y_deg,
                up,
            } => (azimuth_deg, elevation_deg, fov_y_deg, up),
            CameraSpec::Fixed(c) => (
                DEFAULT_AZIMUTH_DEG,
                DEFAULT_ELEVATION_DEG,
                c.fov_y_deg,
                c.up,
            ),
        };
        let (fov, up) = (self.fov.unwrap_or(fov), self.up.unwrap_or(up));
        match (self.eye, self.target) {
            (Some(eye), Some(target)) => {
                p.camera = CameraSpec::Fixed(Camera {
                    eye,
                    target,
                    up,
                    fov_y_deg: fov,
                })
            }
            (None, None) => {
                if self.azimuth.is_some()
                    || self.elevation.is_some()
                    || self.fov.is_some()
                    || self.up.is_some()
                    || matches!(p.camera, CameraSpec::Auto { .. })
                {
                    p.camera = CameraSpec::Auto {
                        azimuth_deg: self.azimuth.unwrap_or(az),
                        elevation_deg: self.elevation.unwrap_or(el),
                        fov_y_deg: fov,
                        up,
                    };
                }
            }
            _ => return Err("--eye and --target go together".into()),
        }
        p.render.validate().map_err(|e| e.to_string())?;
        Ok(p)
    }
}

/// The name in `names` nearest to `typed` by optimal string alignment distance (a
/// transposition counts one edit), if it is within two edits and closer than half the
/// typed length: `rnu` gives `run`, `xyz` gives nothing.
fn closest<'a>(typed: &str, names: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    names
        .into_iter()
        .map(|n| (strsim::osa_distance(typed, n), n))
        .filter(|&(d, _)| d <= 2 && 2 * d < typed.chars().count().max(2))
        .min_by_key(|&(d, _)| d)
        .map(|(_, n)| n)
}

/// Parses the command line; a mistyped subcommand that clap finds no suggestion for gets
/// the nearest one by edit distance.
fn parse_cli() -> Cli {
    Cli::try_parse().unwrap_or_else(|mut e| {
        if e.kind() == ErrorKind::InvalidSubcommand
            && e.get(ContextKind::SuggestedSubcommand).is_none()
        {
            if let Some(ContextValue::String(typed)) = e.get(ContextKind::InvalidSubcommand) {
                let cmd = Cli::command();
                let nearest =
                    closest(typed, cmd.get_subcommands().map(|c| c.get_name())).map(String::from);
                if let Some(n) = nearest {
                    e.insert(ContextKind::SuggestedSubcommand, ContextValue::String(n));
                }
            }
        }
        e.exit()
    })
}

fn main() -> ExitCode {
    // Output piped into a program that stops reading (`| head`) ends the process as it
    // does any Unix tool, not with a panic from println!.
    #[cfg(unix)]
    // SAFETY: setting a signal's action to the default, before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = parse_cli();
    if let Some(t) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()
        {
            eprintln!("error: cannot set {t} threads: {e}");
            return ExitCode::from(2);
        }
    }
    let limits = cli.limits();
    match cli.command {
        Command::Run {
            scene,
            out,
            frames,
            explain,
            preview,
        } => run(scene, out, frames, explain, preview, &limits),
        Command::Render {
            frames,
            out,
            scene,
            view,
        } => render(&frames, out, scene, &view, &limits),
        Command::Study { name, out, quick } => study(&name, &out, quick),
        Command::Haptics {
            mesh,
            path,
            stiffness,
            tool,
            rotation_stiffness,
            contact_stiffness,
            cells,
            out,
        } => match tool {
            None => haptics(&mesh, path.as_deref(), stiffness, &out, &limits),
            Some(tool) => haptics_tool(
                &mesh,
                &tool,
                path.as_deref(),
                (stiffness, rotation_stiffness, contact_stiffness),
                cells,
                &out,
                &limits,
            ),
        },
        #[cfg(feature = "modal")]
        Command::Modes {
            mesh,
            young,
            poisson,
            density,
            count,
            mass,
            fixed,
            json,
            out,
            voxel,
        } => {
            let options = largestep::modal::ModesOptions {
                voxel,
                young,
                poisson,
                density,
                count,
                mass,
                fixed,
            };
            modes(&mesh, &options, json, out, &limits)
        }
        #[cfg(feature = "anim")]
        Command::Anim { command } => match command {
            AnimCommand::Fk { file, frame, json } => anim_fk(&file, frame, json, &limits),
        },
        Command::Machine { triad_mib } => {
            let l = largestep::machine::measure(triad_mib);
            println!("threads          {}", l.threads);
            println!(
                "triad bandwidth  {:.2} GB/s  (a = b + s c over 3 x {} MiB, 24 B per element)",
                l.triad_gbs,
                l.triad_array_bytes >> 20
            );
            println!(
                "peak f64 FMA     {:.1} GFLOP/s with f64x4, {:.1} GFLOP/s with f64x8",
                l.fma4_gflops, l.fma8_gflops
            );
            ExitCode::SUCCESS
        }
    }
}

fn run(
    scene_path: PathBuf,
    out: Option<PathBuf>,
    frames: Option<usize>,
    explain: bool,
    preview: bool,
    limits: &Limits,
) -> ExitCode {
    let scene = match Scene::load_with(&scene_path, limits) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let out = out.unwrap_or_else(|| PathBuf::from("out").join(scene.folder_name()));
    let mut runner = Runner::new(scene, &out);
    if explain {
        print!("{}", runner.explain());
    }
    runner.keep_frames(preview);
    let total = runner.frame_count(frames);
    let bar = ProgressBar::new(total as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} frames  {msg}",
        )
        .expect("valid template"),
    );
    let result = runner.run(frames, &mut |p| {
        bar.set_position(p.frame as u64);
        bar.set_message(format!("t = {:.3} s, {} steps", p.time, p.steps));
    });
    bar.finish_and_clear();
    // The plot and the preview cover what was simulated, also when the run failed.
    let mut status = ExitCode::SUCCESS;
    match &result {
        Ok(summary) => {
            println!("{summary}");
            // The same numbers at full precision, for tools.
            let path = runner.out_dir().join("summary.json");
            let written = largestep::io::write_atomically(&path, |w| {
                serde_json::to_writer_pretty(&mut *w, summary)?;
                writeln!(w)
            });
            match written {
                Ok(()) => println!("  summary        {}", path.display()),
                Err(e) => {
                    eprintln!("error: {}: {e}", path.display());
                    status = ExitCode::from(1);
                }
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            // A limit, or an energy that is not finite from the start, refuses the input
            // before anything runs: bad input, like a bad scene.
            use largestep::scene::RunError;
            let code = match e {
                RunError::Limit(_) | RunError::NonFiniteEnergy { frame: 0, .. } => 2,
                _ => 1,
            };
            status = ExitCode::from(code);
        }
    }
    if runner.records().is_empty() {
        return status; // refused before the first frame: nothing to plot or preview
    }
    match runner.write_plot() {
        Ok(path) => println!("  plot           {}", path.display()),
        Err(e) => {
            eprintln!("error: {e}");
            status = ExitCode::from(1);
        }
    }
    for path in runner.sound_files().iter().filter(|p| p.exists()) {
        println!("  sound          {}", path.display());
    }
    match runner.write_spectrograms() {
        Ok(paths) => {
            for path in paths {
                println!("  spectrogram    {}", path.display());
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            status = ExitCode::from(1);
        }
    }
    if preview && runner.has_grid_preview() {
        match runner.finish_grid_preview() {
            Ok(Some((n, seconds))) => println!(
                "  preview        {n} PNG frames, animation.gif and contact-sheet.png in {} ({:.1} ms/frame)",
                runner.out_dir().join("preview").display(),
                1e3 * seconds / n.max(1) as f64
            ),
            Ok(None) => {}
            Err(e) => {
                eprintln!("error: {e}");
                status = ExitCode::from(1);
            }
        }
    } else if preview {
        let settings = runner.output().preview;
        let dir = runner.out_dir().join("preview");
        let frames = runner.kept_frames();
        let scenery = runner.scenery(preview_region(frames));
        match write_preview_with_bar(&dir, frames, &scenery, &settings) {
            Ok(s) => println!("{s}"),
            Err(e) => {
                eprintln!("error: {e}");
                status = ExitCode::from(1);
            }
        }
    }
    status
}

fn write_preview_with_bar(
    dir: &std::path::Path,
    frames: &[largestep::io::Mesh],
    scenery: &[largestep::io::Mesh],
    settings: &PreviewSettings,
) -> Result<largestep::render::preview::PreviewSummary, largestep::render::RenderError> {
    let bar = ProgressBar::new(frames.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} images")
            .expect("valid template"),
    );
    let r = write_preview(dir, frames, scenery, settings, &mut |done, _| {
        bar.set_position(done as u64)
    });
    bar.finish_and_clear();
    r
}

fn render(
    frames_dir: &std::path::Path,
    out: Option<PathBuf>,
    scene: Option<PathBuf>,
    view: &ViewArgs,
    limits: &Limits,
) -> ExitCode {
    let scene = match scene
        .map(|path| Scene::load_with(&path, limits))
        .transpose()
    {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let base = scene
        .as_ref()
        .map_or_else(PreviewSettings::default, |s| s.output.preview);
    let settings = match view.apply(base) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let frames = match load_frames(frames_dir, limits.max_file_bytes) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let scenery = scene.map_or_else(Vec::new, |s| s.scenery(preview_region(&frames)));
    let out = out.unwrap_or_else(|| {
        frames_dir
            .parent()
            .unwrap_or(std::path::Path::new("."))
            .join("preview")
    });
    match write_preview_with_bar(&out, &frames, &scenery, &settings) {
        Ok(s) => {
            println!("{s}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            match e {
                RenderError::Camera(_) | RenderError::Settings(_) => ExitCode::from(2),
                _ => ExitCode::from(1),
            }
        }
    }
}

/// The device path of `largestep haptics`: read from `path`, or the scripted `default`
/// written to `out/device-path.csv`.
fn device_path(
    path: Option<&std::path::Path>,
    out: &std::path::Path,
    limits: &Limits,
    default: impl FnOnce() -> largestep::haptics::DevicePath,
) -> Result<largestep::haptics::DevicePath, String> {
    match path {
        Some(p) => largestep::haptics::DevicePath::read(p, limits.max_file_bytes)
            .map_err(|e| e.to_string()),
        None => {
            let d = default();
            let file = out.join("device-path.csv");
            std::fs::write(&file, d.to_csv()).map_err(|e| format!("{}: {e}", file.display()))?;
            Ok(d)
        }
    }
}

/// A labelled value of a haptic trace's tick.
type TraceCurve<'a, T> = (&'a str, &'a dyn Fn(&T) -> f64);

/// A panel of a haptic trace over time: one dashed curve per `(label, value)` getter,
/// coloured in order from `first_colour`.
fn trace_panel<T>(
    title: String,
    y_label: &str,
    ticks: &[T],
    time: impl Fn(&T) -> f64,
    curves: &[TraceCurve<'_, T>],
    first_colour: usize,
) -> largestep::plot::Panel {
    largestep::plot::Panel {
        title,
        x_label: "time (s)".into(),
        y_label: y_label.into(),
        scale: largestep::plot::Scale::Linear,
        curves: curves
            .iter()
            .enumerate()
            .map(|(k, (label, f))| {
                let curve = largestep::plot::Curve {
                    label: (*label).into(),
                    points: ticks.iter().map(|t| (time(t), f(t))).collect(),
                    dashed: true,
                };
                (first_colour + k, curve)
            })
            .collect(),
    }
}

/// A panel of a vector of a haptic trace's tick: its x, y and z as `symbol_x` and so on.
fn vector_panel<T>(
    title: String,
    y_label: &str,
    ticks: &[T],
    time: impl Fn(&T) -> f64,
    symbol: &str,
    value: &dyn Fn(&T) -> [f64; 3],
) -> largestep::plot::Panel {
    let labels = ["x", "y", "z"].map(|a| format!("{symbol}_{a}"));
    let component = [0, 1, 2].map(|a| move |t: &T| value(t)[a]);
    trace_panel(
        title,
        y_label,
        ticks,
        time,
        &[
            (&labels[0], &component[0]),
            (&labels[1], &component[1]),
            (&labels[2], &component[2]),
        ],
        0,
    )
}

/// The panel of a haptic trace's work per tick (`work` in seconds, drawn in us).
fn work_panel<T>(
    ticks: &[T],
    time: impl Fn(&T) -> f64,
    work: &dyn Fn(&T) -> f64,
) -> largestep::plot::Panel {
    let us = |t: &T| work(t) * 1e6;
    trace_panel(
        "work per 1 ms tick".into(),
        "work (us)",
        ticks,
        time,
        &[("tick", &us)],
        3,
    )
}

/// `largestep haptics`: replays a device path through the god object of a mesh.
fn haptics(
    mesh: &std::path::Path,
    path: Option<&std::path::Path>,
    stiffness: f64,
    out: &std::path::Path,
    limits: &Limits,
) -> ExitCode {
    use largestep::haptics::{replay, trace_csv, DevicePath, GodObject, TICK};
    let fail = |e: String| {
        eprintln!("error: {e}");
        ExitCode::from(2)
    };
    let surface = match largestep::io::read_surface(mesh, limits.max_file_bytes) {
        Ok(m) => m,
        Err(e) => return fail(e.to_string()),
    };
    let mut god = match GodObject::new(&surface, stiffness) {
        Ok(g) => g,
        Err(e) => return fail(format!("{}: {e}", mesh.display())),
    };
    if let Err(e) = std::fs::create_dir_all(out) {
        return fail(format!("{}: {e}", out.display()));
    }
    let device = match device_path(path, out, limits, || {
        let b = god.bounds();
        let top = god.top();
        DevicePath::stroke(&b, [top[0], top[2]], 0.1 * (b.max[1] - b.min[1]))
    }) {
        Ok(d) => d,
        Err(e) => return fail(e),
    };
    // Ticks are kept in memory (about 120 bytes each): check before replaying.
    let ticks_n = device.duration() / TICK + 1.0;
    if let Err(e) = limits.memory("the haptic trace", 120.0 * ticks_n) {
        return fail(e);
    }
    let ticks = match replay(&mut god, &device) {
        Ok(t) => t,
        Err(e) => return fail(e),
    };
    let time = |t: &largestep::haptics::Tick| t.time;
    let panels = [
        vector_panel(
            format!("god object, k = {stiffness} N/m"),
            "force on the user (N)",
            &ticks,
            time,
            "F",
            &|t| t.force,
        ),
        work_panel(&ticks, time, &|t| t.work),
    ];
    let fmax = largest_norm(&ticks, |t| t.force);
    let summary = serde_json::json!({
        "mesh": mesh.display().to_string(),
        "triangles": surface.triangles.len(),
        "ticks": ticks.len(),
        "tick_s": TICK,
        "stiffness_n_per_m": stiffness,
        "max_force_n": fmax,
    });
    let headline = format!(
        "haptics: {} ticks of 1 ms against {} triangles, largest force {fmax:.3} N",
        ticks.len(),
        surface.triangles.len()
    );
    let work = ticks.iter().map(|t| t.work).collect();
    match write_haptics(out, &trace_csv(&ticks), &panels, 320, summary, work) {
        Ok(latency) => report_haptics(out, &headline, latency),
        Err(e) => fail(e),
    }
}

/// Writes a haptics run's outputs into `out`: `haptics.csv` (the trace), the plot of
/// `panels` (`haptics.png`, `.svg`; `height` px a panel) and `summary.json` (`summary`
/// with the percentiles of the ticks' `work` times, which it returns).
fn write_haptics(
    out: &std::path::Path,
    trace: &str,
    panels: &[largestep::plot::Panel],
    height: u32,
    mut summary: serde_json::Value,
    work: Vec<f64>,
) -> Result<[f64; 4], String> {
    let csv = out.join("haptics.csv");
    std::fs::write(&csv, trace).map_err(|e| format!("{}: {e}", csv.display()))?;
    largestep::plot::write_panels(&out.join("haptics"), panels, 1, (900, height))?;
    let latency = largestep::haptics::percentiles(work);
    let [p50, p90, p99, max] = latency;
    summary["work_us"] =
        serde_json::json!({"p50": p50 * 1e6, "p90": p90 * 1e6, "p99": p99 * 1e6, "max": max * 1e6});
    let json = out.join("summary.json");
    std::fs::write(&json, format!("{summary:#}\n"))
        .map_err(|e| format!("{}: {e}", json.display()))?;
    Ok(latency)
}

/// Prints a haptics run's headline, its work percentiles against the 1 ms tick and the
/// files [`write_haptics`] wrote.
fn report_haptics(
    out: &std::path::Path,
    headline: &str,
    [p50, p90, p99, max]: [f64; 4],
) -> ExitCode {
    println!("{headline}");
    println!(
        "  work per tick  p50 {:.1} us, p90 {:.1} us, p99 {:.1} us, max {:.1} us ({} the 1 ms budget at p99)",
        p50 * 1e6,
        p90 * 1e6,
        p99 * 1e6,
        max * 1e6,
        if p99 < largestep::haptics::TICK { "within" } else { "over" }
    );
    println!("  trace          {}", out.join("haptics.csv").display());
    println!("  plot           {}", out.join("haptics.png").display());
    println!("  summary        {}", out.join("summary.json").display());
    ExitCode::SUCCESS
}

/// The largest length of a vector over the ticks of a haptic trace.
fn largest_norm<T>(ticks: &[T], f: impl Fn(&T) -> [f64; 3]) -> f64 {
    ticks
        .iter()
        .map(|t| f(t).iter().map(|c| c * c).sum::<f64>().sqrt())
        .fold(0.0, f64::max)
}

/// `largestep haptics --tool`: replays a device path (poses) through a rigid tool's
/// point shell against the distance field of a mesh.
fn haptics_tool(
    mesh: &std::path::Path,
    tool: &std::path::Path,
    path: Option<&std::path::Path>,
    (kt, rotation_stiffness, contact_stiffness): (f64, Option<f64>, Option<f64>),
    cells: usize,
    out: &std::path::Path,
    limits: &Limits,
) -> ExitCode {
    use largestep::collide::SdfGrid;
    use largestep::haptics::{
        point_shell, replay_tool, tool_trace_csv, DevicePath, SixDof, ToolTick, TICK,
    };
    use largestep::kernels::collide::bv::Aabb;
    let fail = |e: String| {
        eprintln!("error: {e}");
        ExitCode::from(2)
    };
    let read = |file: &std::path::Path| largestep::io::read_surface(file, limits.max_file_bytes);
    let (surface, tool_surface) = match (read(mesh), read(tool)) {
        (Ok(m), Ok(t)) => (m, t),
        (Err(e), _) | (_, Err(e)) => return fail(e.to_string()),
    };
    if !(2..=4096).contains(&cells) {
        return fail(format!("--cells {cells}: must be from 2 to 4096"));
    }
    let bounds =
        Aabb::of_points((0..surface.positions.len() / 3).map(|i| surface.as_ref().vertex(i)));
    let longest = (0..3)
        .map(|a| bounds.max[a] - bounds.min[a])
        .fold(0.0, f64::max);
    let h = longest / cells as f64;
    // The shell: sampled at the grid's spacing; its radius about the tool's origin sets
    // the default rotational stiffness and the grid's padding.
    let shell = match point_shell(&tool_surface, h, (limits.max_memory / 64) as usize) {
        Ok(s) => s,
        Err(e) => return fail(format!("{}: {e}", tool.display())),
    };
    let radius = shell
        .iter()
        .map(|p| p.iter().map(|c| c * c).sum::<f64>().sqrt())
        .fold(0.0, f64::max);
    // A distance grid node costs about 64 bytes while it is built.
    let pad = ((radius / h).ceil() as usize).min(cells) + 2;
    let field = match SdfGrid::from_mesh(&surface, h, pad, (limits.max_memory / 64) as usize) {
        Ok(f) => f,
        Err(e) => return fail(format!("{}: {e}", mesh.display())),
    };
    let kr = rotation_stiffness.unwrap_or(kt * radius.max(0.01 * longest).powi(2));
    let kc = contact_stiffness.unwrap_or(4.0 * kt);
    let mut six = match SixDof::new(shell, std::sync::Arc::new(field), kt, kr, kc) {
        Ok(s) => s,
        Err(e) => return fail(format!("{}: {e}", tool.display())),
    };
    if let Err(e) = std::fs::create_dir_all(out) {
        return fail(format!("{}: {e}", out.display()));
    }
    let device = match device_path(path, out, limits, || {
        // The point probe's stroke, from a quarter of the way across the mesh (through
        // its middle in z) and carried by the tool's lowest point, tilting by 20 degrees
        // about z while it slides.
        let over = [
            bounds.min[0] + 0.25 * (bounds.max[0] - bounds.min[0]),
            0.5 * (bounds.min[2] + bounds.max[2]),
        ];
        let low = (0..tool_surface.positions.len() / 3)
            .map(|i| tool_surface.as_ref().vertex(i)[1])
            .fold(f64::INFINITY, f64::min);
        let mut d = DevicePath::stroke(&bounds, over, 0.1 * (bounds.max[1] - bounds.min[1]));
        for p in &mut d.positions {
            p[1] -= low;
        }
        d.tilt([0.0, 0.0, 20f64.to_radians()], 1.0, 2.5);
        d
    }) {
        Ok(d) => d,
        Err(e) => return fail(e),
    };
    // Ticks are kept in memory (about 250 bytes each): check before replaying.
    if let Err(e) = limits.memory("the haptic trace", 250.0 * (device.duration() / TICK + 1.0)) {
        return fail(e);
    }
    let ticks = replay_tool(&mut six, &device);
    let time = |t: &ToolTick| t.time;
    let panels = [
        vector_panel(
            format!("six-DoF tool, k = {kt} N/m"),
            "force on the user (N)",
            &ticks,
            time,
            "F",
            &|t| t.wrench.force,
        ),
        vector_panel(
            format!("k_rot = {kr:.3e} N m/rad"),
            "torque on the user (N m)",
            &ticks,
            time,
            "T",
            &|t| t.wrench.torque,
        ),
        work_panel(&ticks, time, &|t| t.work),
    ];
    let fmax = largest_norm(&ticks, |t| t.wrench.force);
    let tmax = largest_norm(&ticks, |t| t.wrench.torque);
    let deepest = ticks.iter().map(|t| t.penetration).fold(0.0, f64::max);
    let shell_points = six.shell().len();
    let grid_cells = six.field().grid.n.map(|n| n - 1);
    let summary = serde_json::json!({
        "mode": "six-dof",
        "mesh": mesh.display().to_string(),
        "tool": tool.display().to_string(),
        "shell_points": shell_points,
        "grid_cells": grid_cells,
        "grid_spacing_m": h,
        "ticks": ticks.len(),
        "tick_s": TICK,
        "stiffness_n_per_m": kt,
        "rotation_stiffness_nm_per_rad": kr,
        "contact_stiffness_n_per_m": kc,
        "max_force_n": fmax,
        "max_torque_nm": tmax,
        "max_penetration_m": deepest,
    });
    let headline = format!(
        "haptics: {} ticks of 1 ms, a tool of {shell_points} shell points against a {:?} distance grid of {} triangles; largest force {fmax:.3} N, torque {tmax:.3} N m, deepest shell point {deepest:.3e} m",
        ticks.len(),
        grid_cells,
        surface.triangles.len()
    );
    let work = ticks.iter().map(|t| t.work).collect();
    match write_haptics(out, &tool_trace_csv(&ticks), &panels, 300, summary, work) {
        Ok(latency) => report_haptics(out, &headline, latency),
        Err(e) => fail(e),
    }
}

fn study(name: &str, out: &std::path::Path, quick: bool) -> ExitCode {
    let names = largestep::study::names();
    if !names.contains(&name) {
        let hint = closest(name, names.iter().copied())
            .map(|n| format!("; did you mean `{n}`?"))
            .unwrap_or_default();
        eprintln!(
            "error: unknown study `{name}`{hint} (available: {})",
            names.join(", ")
        );
        return ExitCode::from(2);
    }
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} {msg}")
            .expect("valid template"),
    );
    let report = |done: usize, total: usize, what: &str| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        if !what.is_empty() {
            bar.set_message(what.to_string());
        }
    };
    let result = largestep::study::run(name, out, quick, &Progress::new(&report));
    bar.finish_and_clear();
    match result {
        Ok(report) => {
            println!("{report}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}

/// `largestep anim fk`.
#[cfg(feature = "anim")]
fn anim_fk(
    file: &std::path::Path,
    frame: usize,
    json: Option<PathBuf>,
    limits: &Limits,
) -> ExitCode {
    use std::io::Write;
    let positions = largestep::anim::bvh::Bvh::read(file, limits.max_file_bytes)
        .map_err(|e| e.to_string())
        .and_then(|bvh| {
            let p = bvh
                .positions(frame)
                .map_err(|e| format!("{}: {e}", file.display()))?;
            Ok((bvh, p))
        });
    let (bvh, positions) = match positions {
        Ok(p) => p,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let joints: Vec<_> = bvh
        .joints
        .iter()
        .zip(&positions)
        .map(|(j, p)| serde_json::json!({"name": j.name, "position": p}))
        .collect();
    let value = serde_json::json!({"frame": frame, "joints": joints});
    let Some(path) = json else {
        let mut out = std::io::stdout().lock();
        let written = serde_json::to_writer_pretty(&mut out, &value)
            .map_err(std::io::Error::from)
            .and_then(|()| writeln!(out));
        return match written {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("error: standard output: {e}");
                ExitCode::from(1)
            }
        };
    };
    let written = largestep::io::write_atomically(&path, |w| {
        serde_json::to_writer_pretty(&mut *w, &value)?;
        writeln!(w)
    });
    if let Err(e) = written {
        eprintln!("error: {}: {e}", path.display());
        return ExitCode::from(1);
    }
    println!(
        "{}: {} joints, frame {frame} of {} ({} s per frame)",
        file.display(),
        positions.len(),
        bvh.frames(),
        bvh.frame_time
    );
    for (j, p) in bvh.joints.iter().zip(&positions) {
        println!(
            "{:<32} {:>12.4} {:>12.4} {:>12.4}",
            j.name, p[0], p[1], p[2]
        );
    }
    println!("json           {}", path.display());
    ExitCode::SUCCESS
}

/// `largestep modes`: the table, and the JSON and VTK files asked for.
#[cfg(feature = "modal")]
fn modes(
    mesh: &std::path::Path,
    options: &largestep::modal::ModesOptions,
    json: Option<PathBuf>,
    out: Option<PathBuf>,
    limits: &Limits,
) -> ExitCode {
    use largestep::modal::ModalError;
    let a = match largestep::modal::analyse(mesh, options, limits.max_file_bytes) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {e}");
            // Bad input (the mesh, an option, a problem the solver refuses as given) is 2;
            // a solver that fails on a valid problem is 1.
            return ExitCode::from(match e {
                ModalError::Solve(largestep::solve::SolveError::Invalid(_)) => 2,
                ModalError::Solve(_) => 1,
                _ => 2,
            });
        }
    };
    let m = &a.modes;
    println!(
        "{}: {} vertices, {} tetrahedra, {} fixed",
        mesh.display(),
        a.rest.len() / 3,
        a.fem.tets().len(),
        a.fixed.len()
    );
    for note in &a.notes {
        println!("mesh           {note}");
    }
    if m.dense {
        println!("eigensolver    dense ({:.3} s)", m.seconds);
    } else {
        println!(
            "eigensolver    shift-invert Lanczos at shift {:.6e} 1/s^2, {} steps ({:.3} s, {:.3} s of it factoring)",
            m.shift, m.steps, m.seconds, m.factor_seconds
        );
    }
    for note in &m.notes {
        println!("note           {note}");
    }
    println!("rigid modes    {}", m.rigid);
    println!("{:>5}  {:>16}  {:>9}", "mode", "frequency (Hz)", "residual");
    for (j, f) in m.frequencies_hz().iter().enumerate() {
        println!(
            "{:>5}  {:>16.6}  {:>9.1e}",
            j + 1,
            f,
            m.residuals[m.rigid + j]
        );
    }
    let mut status = ExitCode::SUCCESS;
    if let Some(path) = json {
        let value = serde_json::json!({
            "frequencies_hz": m.frequencies_hz(),
            "eigenvalues": m.eigenvalues,
            "rigid_modes": m.rigid,
            "residuals": m.residuals,
            "seconds": m.seconds,
        });
        let written = largestep::io::write_atomically(&path, |w| {
            serde_json::to_writer_pretty(&mut *w, &value)?;
            writeln!(w)
        });
        match written {
            Ok(()) => println!("json           {}", path.display()),
            Err(e) => {
                eprintln!("error: {}: {e}", path.display());
                status = ExitCode::from(1);
            }
        }
    }
    if let Some(dir) = out {
        match largestep::modal::write_shapes(&a, &dir) {
            Ok(n) => println!("mode shapes    {n} VTK files in {}", dir.display()),
            Err(e) => {
                eprintln!("error: {}: {e}", dir.display());
                status = ExitCode::from(1);
            }
        }
        match mode_animations(&a, &dir) {
            Ok(n) => println!(
                "animations     the first {n} modes: {}/mode_NN/animation.gif",
                dir.display()
            ),
            Err(e) => {
                eprintln!("error: {e}");
                status = ExitCode::from(1);
            }
        }
    }
    status
}

/// Non-rigid modes `largestep modes --out` draws, and frames per oscillation.
#[cfg(feature = "modal")]
const ANIMATED_MODES: usize = 6;
#[cfg(feature = "modal")]
const ANIMATION_FRAMES: usize = 24;

/// Draws each of the first [`ANIMATED_MODES`] non-rigid modes oscillating through one
/// period (`modal::oscillation`) with the preview renderer: `dir/mode_NN/animation.gif`,
/// its PNG frames and a contact sheet (640 x 360; the camera frames the whole swing).
/// Returns the modes drawn.
#[cfg(feature = "modal")]
fn mode_animations(
    a: &largestep::modal::Analysis,
    dir: &std::path::Path,
) -> Result<usize, RenderError> {
    let settings = PreviewSettings {
        render: largestep::render::Settings {
            width: 640,
            height: 360,
            ..Default::default()
        },
        frame_interval: 1.0 / ANIMATION_FRAMES as f64,
        ..Default::default()
    };
    let count = a.modes.frequencies_hz().len().min(ANIMATED_MODES);
    for j in 0..count {
        let frames = largestep::modal::oscillation(a, a.modes.rigid + j, ANIMATION_FRAMES);
        write_preview(
            &dir.join(format!("mode_{:02}", j + 1)),
            &frames,
            &[],
            &settings,
            &mut |_, _| {},
        )?;
    }
    Ok(count)
}
