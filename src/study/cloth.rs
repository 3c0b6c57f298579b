//! Cloth studies: what the Baraff-Witkin large steps buy.
//!
//! **Accuracy** (`cloth-accuracy`). The drape scene (a 1.6 m sheet dropped on a sphere of
//! radius 0.5 m, with friction), 24 x 24 vertices, T = 0.2 s (impact and first wrap). Error: the largest distance of
//! a vertex from a reference run at T. Reference: the same linearised backward Euler at
//! dt = 1/1920 s with PCG to a relative residual of 1e-10. Two sweeps: dt from 1/30 to
//! 1/480 s at a converged solve (1e-8), and the PCG tolerance from 1e-1 to 1e-8 at
//! dt = 1/60 s (the paper's animation setting): how much of the error is the time step and
//! how much the inexact solve, against run time.
//!
//! **Stability** (`cloth-stability`). A 16 x 16 sheet of 1 m hung by two corners, released
//! from horizontal, stretch stiffness k from 1e1 to 1e5 N/m (per unit area; shear k/10,
//! bend 1e-4 N m). For each k and method the largest dt that runs 0.5 s (at most 20,000
//! steps) with a finite state that never gains more than 5x weight times size in energy
//! (only gravity does work and the material damps, so only an unstable method gains
//! without bound), by geometric bisection on [1e-6, 0.1] s; the bounded energy gain at
//! that dt is reported too. Step-size control is off. Symplectic Euler's bound
//! shrinks like 1/sqrt(k); the implicit step allows steps hundreds of times larger, and
//! with the paper's step-size control (third series) any dt tried.

use super::{
    log_slope, max_distance, solid_curves, write_file, write_plot_and_numbers, Progress, StudyError,
};
use crate::plot::{Curve, Panel, Scale};
use crate::scene::Scene;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

const MATERIAL: &str = "density = 0.2\nshear_damping = 0.02\nstretch_damping = 0.2\n";

fn drape_scene(n: usize, dt: f64, tol: f64, t_end: f64) -> String {
    format!(
        r#"[scene]
name = "cloth-accuracy"
dt = {dt:e}
duration = {t_end}
integrator = "linearized-backward-euler"
gravity = [0.0, -9.81, 0.0]
[solver]
linear = "pcg"
tolerance = {tol:e}
max_iterations = 100000
[cloth]
friction = 0.4
[cloth.step_control]
max_halvings = 0
max_strain_change = 1e9
[[cloth.sphere]]
center = [0.0, 0.0, 0.0]
radius = 0.5
[cloth.grid]
nu = {n}
nv = {n}
size = [1.6, 1.6]
origin = [-0.8, 0.6, -0.8]
[cloth.material]
{MATERIAL}stretch = 2000.0
shear = 200.0
bend = 0.0002
"#
    )
}

/// Runs a scene text to its duration: final positions (None if it failed), wall time and
/// linear iterations.
fn run_scene(text: &str) -> (Option<Vec<f64>>, f64, usize) {
    // Timed from the parse: building the simulation (and its solver structures) is part
    // of what `largestep run` does.
    let t0 = Instant::now();
    let scene = Scene::parse(text, "study.toml").expect("the study's scenes are valid");
    let (steps, dt) = ((scene.duration / scene.dt).round() as usize, scene.dt);
    let mut sim = scene.into_simulation().expect("one system");
    let mut iterations = 0;
    for _ in 0..steps {
        match sim.step(dt) {
            Ok(info) => iterations += info.linear_iterations,
            Err(_) => return (None, t0.elapsed().as_secs_f64(), iterations),
        }
    }
    let mesh = sim.frame().mesh();
    (
        Some(mesh.positions.to_vec()),
        t0.elapsed().as_secs_f64(),
        iterations,
    )
}

#[derive(Serialize, Clone)]
struct Point {
    dt: f64,
    tolerance: f64,
    steps: usize,
    pcg_iterations: usize,
    error: Option<f64>,
    seconds: f64,
}

#[derive(Serialize)]
struct Sweep {
    name: String,
    observed_order_in_dt: Option<f64>,
    points: Vec<Point>,
}

pub(super) fn accuracy(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let n = if quick { 12 } else { 24 };
    // T = 0.2 s: through the impact (at 0.14 s) and the first wrap. Later the free edges
    // whip down round the sphere and runs at dt and dt / 2 part exponentially (at T =
    // 0.3 s, 1/240 and 1/480 s end 0.13 m apart at an edge vertex, measured): no
    // reference is meaningful there.
    let t_end = 0.2;
    let ref_dt = if quick { 1.0 / 480.0 } else { 1.0 / 1920.0 };
    let (reference, ref_secs, _) = run_scene(&drape_scene(n, ref_dt, 1e-10, t_end));
    let reference = reference.expect("the reference run succeeds");
    let (check, _, _) = run_scene(&drape_scene(n, 2.0 * ref_dt, 1e-10, t_end));
    let ref_change = check.map(|c| max_distance(&c, &reference));
    let runs = if quick { 3 + 3 } else { 5 + 6 };
    progress.expect(1 + runs);
    progress.tick("reference and its check");
    let point = |dt: f64, tol: f64| {
        let (x, seconds, its) = run_scene(&drape_scene(n, dt, tol, t_end));
        progress.tick(&format!("dt = {dt:.2e} s, PCG {tol:.0e}"));
        Point {
            dt,
            tolerance: tol,
            steps: (t_end / dt).round() as usize,
            pcg_iterations: its,
            error: x.map(|x| max_distance(&x, &reference)),
            seconds,
        }
    };
    let dts: Vec<f64> = [30.0, 60.0, 120.0, 240.0, 480.0]
        .iter()
        .take(if quick { 3 } else { 5 })
        .map(|f| 1.0 / f)
        .collect();
    let dt_sweep: Vec<Point> = dts.iter().map(|&dt| point(dt, 1e-8)).collect();
    let tols: Vec<f64> = [1e-1, 1e-2, 1e-3, 1e-4, 1e-6, 1e-8]
        .into_iter()
        .take(if quick { 3 } else { 6 })
        .collect();
    let tol_sweep: Vec<Point> = tols.iter().map(|&tol| point(1.0 / 60.0, tol)).collect();
    let order = log_slope(
        &dt_sweep
            .iter()
            .filter_map(|p| p.error.filter(|e| *e > 0.0).map(|e| (p.dt, e)))
            .collect::<Vec<_>>(),
    );
    let sweeps = vec![
        Sweep {
            name: format!("dt from {} (PCG 1e-8)", dt_range(&dts)),
            observed_order_in_dt: order,
            points: dt_sweep,
        },
        Sweep {
            name: format!(
                "PCG tolerance {:.0e} to {:.0e} (dt = 1/60 s)",
                tols[0],
                tols[tols.len() - 1]
            ),
            observed_order_in_dt: None,
            points: tol_sweep,
        },
    ];
    let panels = vec![Panel {
        title: format!("cloth drape {n}x{n}, T = {t_end} s: error against run time"),
        x_label: "run time (s)".into(),
        y_label: "max vertex distance from reference (m)".into(),
        scale: Scale::LogLog,
        curves: solid_curves(sweeps.iter().map(|s| {
            let points = s.points.iter();
            let points = points.filter_map(|p| p.error.map(|e| (p.seconds, e.max(1e-12))));
            (s.name.clone(), points.collect())
        })),
    }];
    write_plot_and_numbers(out, "cloth-accuracy", &panels, 1, (760, 520), &sweeps)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Cloth: error against run time (drape)\n\nGenerated by `largestep study cloth-accuracy{}` ({} threads). Plot: [cloth-accuracy.svg](cloth-accuracy.svg) ([PNG](cloth-accuracy.png)); numbers: [cloth-accuracy.json](cloth-accuracy.json).\n\nScene: a 1.6 m square sheet of {n} x {n} vertices (200 g/m^2, stretch 2000 N/m, shear 200 N/m, bend 2e-4 N m, friction 0.4) dropped from 0.1 m above a sphere of radius 0.5 m; the linearised backward Euler step of Baraff and Witkin with filtered PCG (block Jacobi, warm-started) and contacts by constraint filtering plus position correction; T = {t_end} s. Error: the largest distance of a vertex from the reference at T. Reference: dt = {ref_dt:.3e} s, PCG to 1e-10 ({ref_secs:.1} s of run time); the same at twice the step differs from it by {} m. Run time: one run, wall clock, including contacts.\n\nThe backward Euler step is first order and damps; contacts switch on and off, so the right-hand side is not smooth. The tolerance sweep shows how loose a solve can be before it, rather than the step, dominates the error.\n\nWhy T = 0.2 s: the sheet hits the sphere at 0.14 s; from about 0.25 s its free edges whip down round the sphere and runs at dt and dt/2 part exponentially (at T = 0.3 s, dt = 1/240 and 1/480 s end 0.13 m apart at an edge vertex, against 3 mm at 0.2 s), so no reference is meaningful later.\n",
        if quick { " --quick" } else { "" },
        rayon::current_num_threads(),
        ref_change.map_or("(failed)".into(), |d| format!("{d:.2e}"))
    );
    for s in &sweeps {
        let _ = writeln!(
            md,
            "## {}\n\nObserved order in dt: {}\n\n| dt (s) | PCG tolerance | steps | PCG iterations | error (m) | run time (s) |\n|---|---|---|---|---|---|",
            s.name,
            s.observed_order_in_dt.map_or("-".into(), |o| format!("{o:.2}"))
        );
        for p in &s.points {
            let _ = writeln!(
                md,
                "| {:.4e} | {:.0e} | {} | {} | {} | {:.3} |",
                p.dt,
                p.tolerance,
                p.steps,
                p.pcg_iterations,
                p.error.map_or("-".into(), |e| format!("{e:.3e}")),
                p.seconds
            );
        }
        md.push('\n');
    }
    write_file(&out.join("cloth-accuracy.md"), &md)?;
    Ok(format!(
        "cloth-accuracy: observed order in dt {}; report: {}",
        order.map_or("-".into(), |o| format!("{o:.2}")),
        out.join("cloth-accuracy.md").display()
    ))
}

/// `1/30 to 1/120 s`: the first and last of time steps that are unit fractions.
fn dt_range(dts: &[f64]) -> String {
    let frac = |dt: f64| format!("1/{}", (1.0 / dt).round());
    match dts {
        [] => "no steps".into(),
        [one] => format!("{} s", frac(*one)),
        [first, .., last] => format!("{} to {} s", frac(*first), frac(*last)),
    }
}

/// The hanging sheet; `control`: the paper's step-size control with max_strain_change
/// 0.1 (else none).
fn hang_scene(k: f64, method: &str, control: bool, dt: f64, t_end: f64) -> String {
    let control = if control {
        "max_halvings = 8\nmax_strain_change = 0.1"
    } else {
        "max_halvings = 0\nmax_strain_change = 1e9"
    };
    format!(
        r#"[scene]
name = "cloth-stability"
dt = {dt:e}
duration = {t_end:e}
integrator = "{method}"
gravity = [0.0, -9.81, 0.0]
[cloth]
pinned = [240, 255]
[cloth.step_control]
{control}
[cloth.grid]
nu = 16
nv = 16
size = [1.0, 1.0]
[cloth.material]
{MATERIAL}stretch = {k:e}
shear = {:e}
bend = 0.0001
"#,
        k / 10.0
    )
}

/// Weight times size of the hanging sheet (0.2 kg, 1 m, g = 9.81): the energy scale (J).
const ENERGY_SCALE: f64 = 0.2 * 9.81 * 1.0;

/// Runs the hanging sheet at `dt`: `Some((largest energy gain over the initial energy, J,
/// sub-steps per step))`
/// when it stays bounded, `None` when it blows up (a non-finite state, a failed step, or
/// an energy gain above 5x weight times size). Only gravity does work and the material
/// damps, so a method that gains energy without bound is unstable; a bounded gain is an
/// accuracy artifact, reported as such.
fn run_hang(k: f64, method: &str, control: bool, dt: f64) -> Option<(f64, f64)> {
    let t_end = (0.5f64).min(20_000.0 * dt);
    let text = hang_scene(k, method, control, dt, t_end);
    let scene = Scene::parse(&text, "study.toml").expect("valid");
    let steps = (t_end / dt).round().max(1.0) as usize;
    let mut sim = scene.into_simulation().expect("one system");
    let e0 = sim.energy().total();
    let mut gain = 0.0f64;
    for _ in 0..steps {
        sim.step(dt).ok()?;
        let g = sim.energy().total() - e0;
        if g.is_nan() || g > 5.0 * ENERGY_SCALE {
            return None;
        }
        gain = gain.max(g);
    }
    Some((gain, sim.steps() as f64 / steps as f64))
}

#[derive(Serialize)]
struct StabilityRow {
    stretch: f64,
    method: &'static str,
    largest_stable_dt: Option<f64>,
    capped: bool,
    /// Largest energy gain at that dt (J).
    energy_gain: Option<f64>,
    /// Sub-steps per step there (step-size control; 1 without).
    substeps: Option<f64>,
}

pub(super) fn stability(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let ks: Vec<f64> = if quick {
        vec![1e2, 1e4]
    } else {
        vec![1e1, 1e2, 1e3, 1e4, 1e5]
    };
    let methods = [
        ("symplectic-euler", false, "symplectic Euler"),
        (
            "linearized-backward-euler",
            false,
            "implicit (Baraff-Witkin)",
        ),
        ("linearized-backward-euler", true, "implicit + step control"),
    ];
    let (lo0, hi0) = (1e-6, 0.1);
    let mut rows = Vec::new();
    progress.expect(ks.len() * methods.len());
    for &k in &ks {
        for (method, control, label) in methods {
            let run = |dt: f64| run_hang(k, method, control, dt);
            let (dt, capped) = if run(hi0).is_some() {
                (Some(hi0), true)
            } else if run(lo0).is_none() {
                (None, false)
            } else {
                let (mut lo, mut hi) = (lo0, hi0);
                for _ in 0..if quick { 8 } else { 14 } {
                    let mid = (lo * hi).sqrt();
                    if run(mid).is_some() {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                (Some(lo), false)
            };
            let at = dt.and_then(run);
            let row = StabilityRow {
                stretch: k,
                method: label,
                largest_stable_dt: dt,
                capped,
                energy_gain: at.map(|a| a.0),
                substeps: at.map(|a| a.1),
            };
            rows.push(row);
            progress.tick(&format!("k = {k:.0e}: {label}"));
        }
    }
    let curves = methods
        .iter()
        .enumerate()
        .map(|(i, (_, _, label))| {
            (
                i,
                Curve {
                    label: label.to_string(),
                    points: rows
                        .iter()
                        .filter(|r| r.method == *label)
                        .filter_map(|r| r.largest_stable_dt.map(|d| (r.stretch, d)))
                        .collect(),
                    dashed: false,
                },
            )
        })
        .collect();
    let panels = vec![Panel {
        title: "hanging sheet 16x16: largest stable dt against stretch stiffness".into(),
        x_label: "stretch stiffness (N/m per unit area)".into(),
        y_label: "largest stable dt (s)".into(),
        scale: Scale::LogLog,
        curves,
    }];
    write_plot_and_numbers(out, "cloth-stability", &panels, 1, (760, 520), &rows)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Cloth: largest stable time step\n\nGenerated by `largestep study cloth-stability{}`. Plot: [cloth-stability.svg](cloth-stability.svg) ([PNG](cloth-stability.png)); numbers: [cloth-stability.json](cloth-stability.json).\n\nScene: a 1 m square sheet of 16 x 16 vertices (200 g/m^2, shear k/10, bend 1e-4 N m, light damping) hung by two corners and released from horizontal. Stable: 0.5 s (at most 20,000 steps) with a finite state whose total energy (kinetic plus potential, gravity included) never exceeds the initial one by more than 5x weight times size (9.8 J): only gravity does work and the material damps, so an unstable method gains energy without bound. A bounded gain is an accuracy artifact and is reported in the last column: the linearised step turns large rotations in one step into stretch. Largest stable dt by geometric bisection on [1e-6, 0.1] s; `>= 0.1` means the largest step tried was stable. Step-size control is off, so nothing rescues a failing step.\n\nThe third method is the implicit step with the paper's step-size control (a sub-step that changes some triangle's strain by more than 10% is retried at half the size, at most 8 times): the scene's dt is then nominal, and the last column says how many sub-steps each step took on average.\n\n| stretch k (N/m) | method | largest stable dt (s) | largest energy gain there (J) | sub-steps per step |\n|---|---|---|---|---|",
        if quick { " --quick" } else { "" },
    );
    for r in &rows {
        let _ = writeln!(
            md,
            "| {:.0e} | {} | {} | {} | {} |",
            r.stretch,
            r.method,
            match (r.largest_stable_dt, r.capped) {
                (Some(d), true) => format!(">= {d}"),
                (Some(d), false) => format!("{d:.3e}"),
                (None, _) => "< 1e-6".into(),
            },
            r.energy_gain.map_or("-".into(), |g| format!("{g:.3}")),
            r.substeps.map_or("-".into(), |s| format!("{s:.2}"))
        );
    }
    write_file(&out.join("cloth-stability.md"), &md)?;
    let summary: Vec<String> = rows
        .iter()
        .map(|r| {
            format!(
                "{} k={:.0e}: {}",
                r.method,
                r.stretch,
                r.largest_stable_dt.map_or("-".into(), |d| format!(
                    "{d:.2e}{}",
                    if r.capped { "+" } else { "" }
                ))
            )
        })
        .collect();
    Ok(format!(
        "cloth-stability: {}; report: {}",
        summary.join(", "),
        out.join("cloth-stability.md").display()
    ))
}
