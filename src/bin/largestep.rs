//! The `largestep` command-line tool: run scenes, run studies, measure the machine.
//!
//! Exit status: 0 on success, 1 when a run fails (blow-up, solver failure, I/O), 2 for
//! bad input (unreadable or invalid scene, bad arguments).

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use largestep::scene::{Runner, Scene};
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
    #[command(subcommand)]
    command: Command,
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
    },
    /// Run a study: error against run time, orders, stability.
    Study {
        /// Which study (integrators).
        name: String,
        /// Output folder for the report (default: docs/studies).
        #[arg(long, default_value = "docs/studies")]
        out: PathBuf,
        /// Fewer, coarser sweeps (for a quick look; reports say so).
        #[arg(long)]
        quick: bool,
    },
    /// Measure this machine's memory bandwidth (triad) and peak f64 FMA rate.
    Machine {
        /// Size of each triad array in MiB.
        #[arg(long, default_value_t = largestep::machine::DEFAULT_TRIAD_MIB)]
        triad_mib: usize,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(t) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()
        {
            eprintln!("error: cannot set {t} threads: {e}");
            return ExitCode::from(2);
        }
    }
    match cli.command {
        Command::Run {
            scene,
            out,
            frames,
            explain,
        } => run(scene, out, frames, explain),
        Command::Study { name, out, quick } => study(&name, &out, quick),
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
) -> ExitCode {
    let scene = match Scene::load(&scene_path) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let out = out.unwrap_or_else(|| PathBuf::from("out").join(&scene.name));
    let mut runner = match Runner::new(scene, &out) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(1);
        }
    };
    if explain {
        print!("{}", runner.explain());
    }
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
    match result {
        Ok(summary) => {
            println!("{summary}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}

fn study(name: &str, out: &std::path::Path, quick: bool) -> ExitCode {
    match largestep::study::run(name, out, quick) {
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
