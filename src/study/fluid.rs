//! Fluid studies (issue 17): `cavity` (the lid-driven cavity at Re = 100 against Ghia,
//! Ghia and Shin 1982), `fluids` (error against run time over resolution, CFL number and
//! interpolation on the Taylor-Green vortex and the cavity) and `poisson` (iterations and
//! time of the pressure solve against resolution, Jacobi- and multigrid-preconditioned).

use super::{write_file, write_plot_and_numbers, Progress, StudyError};
use crate::fluid::scene::FluidSim;
use crate::fluid::validation::{centerlines, profile_error, GHIA_RE100_U, GHIA_RE100_V};
use crate::fluid::{Boundary, Correction, FluidDesc, Initial, Interp};
use crate::plot::{Curve, Panel, Scale};
use crate::solve::{CellKind, GridPoisson, PoissonParams, PoissonPreconditioner};
use serde::Serialize;
use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// The cavity of `n x n` cells run to a steady state (the largest change of u over 50
/// steps below 1e-5 m/s, or 60 s of flow); returns the simulation and the wall time.
fn cavity(n: usize) -> (FluidSim, f64) {
    let d = FluidDesc {
        cells: [n, n, 1],
        h: 1.0 / n as f64,
        boundaries: [
            [Boundary::Wall; 2],
            [Boundary::Wall, Boundary::Lid([1.0, 0.0, 0.0])],
            [Boundary::Wall; 2],
        ],
        viscosity: 0.01,
        ..FluidDesc::default()
    };
    let t0 = Instant::now();
    let mut sim = FluidSim::new(&d).expect("the cavity is valid");
    // CFL about 1 at the lid speed.
    let dt = 1.0 / n as f64;
    let mut prev = sim.state().u[0].clone();
    let steps = (60.0 / dt) as usize;
    for step in 1..=steps {
        sim.advance(dt).expect("the cavity steps");
        if step % 50 == 0 {
            let u = &sim.state().u[0];
            let change = u
                .iter()
                .zip(&prev)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            prev.copy_from_slice(u);
            if change < 1e-5 {
                break;
            }
        }
    }
    (sim, t0.elapsed().as_secs_f64())
}

#[derive(Serialize, Clone)]
struct CavityPoint {
    n: usize,
    u_max_error: f64,
    u_rms_error: f64,
    v_max_error: f64,
    v_rms_error: f64,
    seconds: f64,
    simulated_seconds: f64,
}

/// `largestep study cavity`: `cavity.json` (the contract: Re, n and the two centreline
/// profiles of the finest run), `cavity.md` (the error per resolution) and
/// `cavity-profiles.svg` (the profiles beside Ghia's points).
pub(super) fn cavity_study(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let ns: Vec<usize> = if quick {
        vec![16, 32]
    } else {
        vec![16, 32, 64]
    };
    progress.expect(ns.len());
    let mut points = Vec::new();
    let mut profiles = Vec::new();
    for &n in &ns {
        let (sim, seconds) = cavity(n);
        let (u, v) = centerlines(sim.fluid(), sim.state(), 1.0);
        let (umax, urms) = profile_error(&u, &GHIA_RE100_U);
        let (vmax, vrms) = profile_error(&v, &GHIA_RE100_V);
        points.push(CavityPoint {
            n,
            u_max_error: umax,
            u_rms_error: urms,
            v_max_error: vmax,
            v_rms_error: vrms,
            seconds,
            simulated_seconds: sim.state().time,
        });
        profiles.push((n, u, v));
        progress.tick(&format!("{n} x {n}"));
    }
    let (n, u, v) = profiles.last().expect("a resolution").clone();
    let json = serde_json::json!({
        "re": 100,
        "n": n,
        "u_centerline": u,
        "v_centerline": v,
    });
    write_file(
        &out.join("cavity.json"),
        &serde_json::to_string_pretty(&json).expect("serializes"),
    )?;
    let ghia = |r: &[(f64, f64)]| Curve {
        label: "Ghia et al. 1982".into(),
        points: r.to_vec(),
        dashed: true,
    };
    let panel = |title: &str, x: &str, y: &str, which: usize, reference: &[(f64, f64)]| Panel {
        title: title.into(),
        x_label: x.into(),
        y_label: y.into(),
        scale: Scale::Linear,
        curves: profiles
            .iter()
            .enumerate()
            .map(|(i, (n, u, v))| {
                let p = if which == 0 { u } else { v };
                (
                    i,
                    Curve {
                        label: format!("{n} x {n}"),
                        points: p.iter().map(|q| (q[0], q[1])).collect(),
                        dashed: false,
                    },
                )
            })
            .chain(std::iter::once((7, ghia(reference))))
            .collect(),
    };
    let panels = vec![
        panel("u along x = 0.5", "y", "u (m/s)", 0, &GHIA_RE100_U),
        panel("v along y = 0.5", "x", "v (m/s)", 1, &GHIA_RE100_V),
    ];
    write_plot_and_numbers(out, "cavity-profiles", &panels, 2, (520, 420), &points)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Lid-driven cavity at Re = 100 against Ghia, Ghia and Shin 1982\n\nGenerated by `largestep study cavity{}` ({} threads). Profiles: [cavity-profiles.svg](cavity-profiles.svg) ([PNG](cavity-profiles.png)); the finest run's centrelines: [cavity.json](cavity.json).\n\nThe unit square, lid speed 1 m/s, nu = 0.01 m^2/s, no-slip walls; RK2 back traces with linear interpolation, implicit viscosity, dt = h (CFL 1 at the lid), run until u changes by less than 1e-5 m/s over 50 steps. Error: the centreline velocity, linearly interpolated between faces, at Ghia's 17 points per line, in units of the lid speed.\n\n| n | u max error | u rms error | v max error | v rms error | run time (s) | simulated (s) |\n|---|---|---|---|---|---|---|",
        if quick { " --quick" } else { "" },
        rayon::current_num_threads()
    );
    for p in &points {
        let _ = writeln!(
            md,
            "| {0} x {0} | {1:.4} | {2:.4} | {3:.4} | {4:.4} | {5:.2} | {6:.1} |",
            p.n,
            p.u_max_error,
            p.u_rms_error,
            p.v_max_error,
            p.v_rms_error,
            p.seconds,
            p.simulated_seconds
        );
    }
    write_file(&out.join("cavity.md"), &md)?;
    let last = points.last().expect("a resolution");
    Ok(format!(
        "cavity: {n} x {n}, largest error against Ghia {:.4} (u) and {:.4} (v); report: {}",
        last.u_max_error,
        last.v_max_error,
        out.join("cavity.md").display()
    ))
}

#[derive(Serialize, Clone)]
struct FluidPoint {
    problem: &'static str,
    scheme: String,
    n: usize,
    cfl: f64,
    error: f64,
    effective_nu: f64,
    seconds: f64,
}

/// The Taylor-Green vortex on a periodic square of side 2 pi, nu = 0.05, U = 1, run to
/// t = 1: the relative L2 error of the face velocities against the exact decaying field,
/// the effective viscosity, and the wall time.
fn taylor_green(n: usize, cfl: f64, interp: Interp, correction: Correction) -> FluidPoint {
    let nu = 0.05;
    let h = 2.0 * PI / n as f64;
    let d = FluidDesc {
        cells: [n, n, 1],
        h,
        boundaries: [
            [Boundary::Periodic; 2],
            [Boundary::Periodic; 2],
            [Boundary::Wall; 2],
        ],
        viscosity: nu,
        initial: Initial::TaylorGreen { speed: 1.0 },
        advection: crate::fluid::Advection {
            interp,
            correction,
            ..Default::default()
        },
        ..FluidDesc::default()
    };
    let t0 = Instant::now();
    let mut sim = FluidSim::new(&d).expect("the vortex is valid");
    let e0 = sim.fluid().kinetic_energy(sim.state());
    let dt = cfl * h;
    let steps = (1.0 / dt).round().max(1.0) as usize;
    for _ in 0..steps {
        sim.advance(dt).expect("the vortex steps");
    }
    let seconds = t0.elapsed().as_secs_f64();
    let t = steps as f64 * dt;
    let decay = (-2.0 * nu * t).exp(); // k = 1 on a side of 2 pi
    let f = sim.fluid();
    let (mut err, mut norm) = (0.0, 0.0);
    for a in 0..2 {
        for (i, &v) in sim.state().u[a].iter().enumerate() {
            let p = f.face_position(a, i);
            let e = decay
                * if a == 0 {
                    p[0].sin() * p[1].cos()
                } else {
                    -p[0].cos() * p[1].sin()
                };
            err += (v - e) * (v - e);
            norm += e * e;
        }
    }
    let e = f.kinetic_energy(sim.state());
    FluidPoint {
        problem: "taylor-green",
        scheme: scheme_name(interp, correction),
        n,
        cfl,
        error: (err / norm).sqrt(),
        effective_nu: crate::fluid::validation::taylor_green_viscosity(e0, e, t, 2.0 * PI),
        seconds,
    }
}

fn scheme_name(interp: Interp, correction: Correction) -> String {
    let i = match interp {
        Interp::Linear => "linear",
        Interp::MonotoneCubic => "monotone cubic",
    };
    match correction {
        Correction::None => i.to_string(),
        Correction::MacCormack => format!("{i} + MacCormack"),
        Correction::Bfecc => format!("{i} + BFECC"),
    }
}

/// `largestep study fluids`.
pub(super) fn fluids(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let ns: Vec<usize> = if quick {
        vec![16, 32, 64]
    } else {
        vec![16, 32, 64, 128]
    };
    let cfls = [0.25, 0.5, 1.0, 2.0];
    let schemes = [
        (Interp::Linear, Correction::None),
        (Interp::MonotoneCubic, Correction::None),
        (Interp::Linear, Correction::MacCormack),
    ];
    let cavity_ns: Vec<usize> = if quick {
        vec![16, 32]
    } else {
        vec![16, 32, 64]
    };
    progress.expect(ns.len() * schemes.len() + cfls.len() + cavity_ns.len());
    let mut by_res: Vec<(String, Vec<FluidPoint>)> = Vec::new();
    for &(interp, corr) in &schemes {
        let pts = ns
            .iter()
            .map(|&n| {
                let p = taylor_green(n, 0.5, interp, corr);
                progress.tick(&format!("Taylor-Green {n}, {}", p.scheme));
                p
            })
            .collect();
        by_res.push((format!("{}, CFL 0.5", scheme_name(interp, corr)), pts));
    }
    let cfl_pts: Vec<FluidPoint> = cfls
        .iter()
        .map(|&c| {
            let p = taylor_green(32, c, Interp::Linear, Correction::None);
            progress.tick(&format!("Taylor-Green 32, CFL {c}"));
            p
        })
        .collect();
    let cav_pts: Vec<FluidPoint> = cavity_ns
        .iter()
        .map(|&n| {
            let (sim, seconds) = cavity(n);
            let (u, v) = centerlines(sim.fluid(), sim.state(), 1.0);
            let e = profile_error(&u, &GHIA_RE100_U)
                .0
                .max(profile_error(&v, &GHIA_RE100_V).0);
            progress.tick(&format!("cavity {n}"));
            FluidPoint {
                problem: "cavity",
                scheme: "linear".into(),
                n,
                cfl: 1.0,
                error: e,
                effective_nu: f64::NAN,
                seconds,
            }
        })
        .collect();
    let curve = |label: String, pts: &[FluidPoint]| Curve {
        label,
        points: pts.iter().map(|p| (p.seconds.max(1e-6), p.error)).collect(),
        dashed: false,
    };
    let mut tg_curves: Vec<(usize, Curve)> = by_res
        .iter()
        .enumerate()
        .map(|(i, (l, p))| (i, curve(l.clone(), p)))
        .collect();
    tg_curves.push((3, curve("linear, 32^2, CFL 0.25 to 2".into(), &cfl_pts)));
    let panels = vec![
        Panel {
            title: "Taylor-Green vortex at t = 1: velocity error against run time".into(),
            x_label: "run time (s)".into(),
            y_label: "relative L2 error".into(),
            scale: Scale::LogLog,
            curves: tg_curves,
        },
        Panel {
            title: "cavity, Re = 100: largest error against Ghia".into(),
            x_label: "run time (s)".into(),
            y_label: "error (lid speeds)".into(),
            scale: Scale::LogLog,
            curves: vec![(4, curve("16, 32, 64 cells across".into(), &cav_pts))],
        },
    ];
    let all: Vec<&FluidPoint> = by_res
        .iter()
        .flat_map(|(_, p)| p)
        .chain(&cfl_pts)
        .chain(&cav_pts)
        .collect();
    write_plot_and_numbers(out, "fluids", &panels, 1, (900, 440), &all)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Stable fluids: error against run time\n\nGenerated by `largestep study fluids{}` ({} threads). Plot: [fluids.svg](fluids.svg) ([PNG](fluids.png)); numbers: [fluids.json](fluids.json).\n\nTaylor-Green vortex: a periodic square of side 2 pi, U = 1, nu = 0.05, run to t = 1 (RK2 back traces). Error: the relative L2 difference of the face velocities from the exact field `exp(-2 nu t)` times the initial one. Effective nu: the kinetic energy's decay rate over `4 k^2`; what exceeds 0.05 is the scheme's numerical viscosity. Cavity: as in [cavity.md](cavity.md), the largest centreline error against Ghia et al. 1982.\n\n| problem | scheme | n | CFL | error | effective nu | run time (s) |\n|---|---|---|---|---|---|---|",
        if quick { " --quick" } else { "" },
        rayon::current_num_threads()
    );
    for p in &all {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {:.3e} | {} | {:.3} |",
            p.problem,
            p.scheme,
            p.n,
            p.cfl,
            p.error,
            if p.effective_nu.is_finite() {
                format!("{:.4}", p.effective_nu)
            } else {
                "-".into()
            },
            p.seconds
        );
    }
    write_file(&out.join("fluids.md"), &md)?;
    let best = by_res[0].1.last().expect("a resolution");
    Ok(format!(
        "fluids: Taylor-Green at {}^2 (linear) error {:.3e}, effective nu {:.4} (exact 0.05); report: {}",
        best.n,
        best.error,
        best.effective_nu,
        out.join("fluids.md").display()
    ))
}

#[derive(Serialize, Clone)]
struct PoissonPoint {
    preconditioner: &'static str,
    n: usize,
    cells: usize,
    iterations: usize,
    setup_seconds: f64,
    solve_seconds: f64,
}

/// The study's problem: an `n^3` box of unit side, walls all round except an open top,
/// a solid ball in the middle, and a rough right side (a fixed hash of the cell index).
pub fn poisson_problem(n: usize) -> ([usize; 3], f64, Vec<CellKind>, Vec<f64>) {
    let h = 1.0 / n as f64;
    let kind = (0..n * n * n)
        .map(|i| {
            let c = [i % n, (i / n) % n, i / (n * n)];
            let p = c.map(|v| (v as f64 + 0.5) * h - 0.5);
            if p[0] * p[0] + p[1] * p[1] + p[2] * p[2] < 0.04 {
                CellKind::Solid
            } else {
                CellKind::Fluid
            }
        })
        .collect();
    let b = (0..n * n * n)
        .map(|i| ((i.wrapping_mul(2_654_435_761) >> 7) % 1000) as f64 / 500.0 - 1.0)
        .collect();
    ([n; 3], h, kind, b)
}

/// `largestep study poisson`.
pub(super) fn poisson(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let ns: Vec<usize> = if quick {
        vec![16, 32, 64]
    } else {
        vec![16, 32, 64, 128]
    };
    let pres = [
        (PoissonPreconditioner::Jacobi, "Jacobi"),
        (PoissonPreconditioner::Multigrid, "multigrid"),
    ];
    progress.expect(ns.len() * pres.len());
    let mut sweeps: Vec<(&str, Vec<PoissonPoint>)> = Vec::new();
    for (pre, name) in pres {
        let mut pts = Vec::new();
        for &n in &ns {
            let (cells, h, kind, b) = poisson_problem(n);
            let sides = [
                [crate::solve::Side::Wall; 2],
                [crate::solve::Side::Wall, crate::solve::Side::Open],
                [crate::solve::Side::Wall; 2],
            ];
            let t0 = Instant::now();
            let mut g = GridPoisson::with_sides(cells, h, kind, sides).expect("valid problem");
            let setup = t0.elapsed().as_secs_f64();
            let mut p = vec![0.0; b.len()];
            let info = g
                .solve(
                    &mut p,
                    &b,
                    &PoissonParams {
                        tolerance: 1e-6,
                        max_iterations: 10_000,
                        preconditioner: pre,
                    },
                )
                .expect("the solve converges");
            pts.push(PoissonPoint {
                preconditioner: name,
                n,
                cells: b.len(),
                iterations: info.iterations,
                setup_seconds: setup,
                solve_seconds: info.seconds,
            });
            progress.tick(&format!("{name}, {n}^3"));
        }
        sweeps.push((name, pts));
    }
    let panels = vec![
        Panel {
            title: "CG iterations to 1e-6 against cells".into(),
            x_label: "cells".into(),
            y_label: "iterations".into(),
            scale: Scale::LogLog,
            curves: sweeps
                .iter()
                .enumerate()
                .map(|(i, (name, p))| {
                    (
                        i,
                        Curve {
                            label: name.to_string(),
                            points: p
                                .iter()
                                .map(|q| (q.cells as f64, q.iterations as f64))
                                .collect(),
                            dashed: false,
                        },
                    )
                })
                .collect(),
        },
        Panel {
            title: "time to 1e-6 (setup included) against cells".into(),
            x_label: "cells".into(),
            y_label: "seconds".into(),
            scale: Scale::LogLog,
            curves: sweeps
                .iter()
                .enumerate()
                .map(|(i, (name, p))| {
                    (
                        i,
                        Curve {
                            label: name.to_string(),
                            points: p
                                .iter()
                                .map(|q| (q.cells as f64, q.setup_seconds + q.solve_seconds))
                                .collect(),
                            dashed: false,
                        },
                    )
                })
                .collect(),
        },
    ];
    let all: Vec<&PoissonPoint> = sweeps.iter().flat_map(|(_, p)| p).collect();
    write_plot_and_numbers(out, "poisson", &panels, 2, (520, 420), &all)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Pressure Poisson solve: iterations and time against resolution\n\nGenerated by `largestep study poisson{}` ({} threads). Plot: [poisson.svg](poisson.svg) ([PNG](poisson.png)); numbers: [poisson.json](poisson.json).\n\nThe unit box of n^3 cells, walls all round except an open top, a solid ball of radius 0.2 in the middle, a rough right side; CG to a relative residual of 1e-6 from zero, preconditioned by the inverse diagonal (Jacobi) or one multigrid V-cycle (`solve::GridPoisson`). Jacobi's count grows with n; the V-cycle's stays flat.\n\n| preconditioner | n^3 | iterations | setup (s) | solve (s) |\n|---|---|---|---|---|",
        if quick { " --quick" } else { "" },
        rayon::current_num_threads()
    );
    for p in &all {
        let _ = writeln!(
            md,
            "| {} | {}^3 | {} | {:.3} | {:.3} |",
            p.preconditioner, p.n, p.iterations, p.setup_seconds, p.solve_seconds
        );
    }
    write_file(&out.join("poisson.md"), &md)?;
    let mg: Vec<usize> = sweeps[1].1.iter().map(|p| p.iterations).collect();
    let ja: Vec<usize> = sweeps[0].1.iter().map(|p| p.iterations).collect();
    Ok(format!(
        "poisson: multigrid iterations {mg:?}, Jacobi {ja:?} at {ns:?}^3; report: {}",
        out.join("poisson.md").display()
    ))
}
