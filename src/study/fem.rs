//! FEM studies.
//!
//! **Accuracy** (`fem-accuracy`). A cantilever (L = 1 m, square section 0.1 m, E = 10 MPa,
//! nu = 0.3, 1000 kg/m^3) clamped at x = 0 and loaded by its own weight, solved for static
//! equilibrium (`Fem::solve_static`, one load increment). Error: the relative difference
//! of the tip deflection (mean over the end face's vertices) from Timoshenko beam
//! theory's, `q L^4 / (8 E I) + q L^2 / (2 kappa G A)` with `kappa = 10 (1 + nu) / (12 +
//! 11 nu)`. Sweeps: the mesh (10k x k x k cubes, six tetrahedra each, k = 1, 2, 4, 8) for
//! the linear, corotational and stable neo-Hookean materials at a converged Newton
//! tolerance, and Newton's tolerance (1e-2 to 1e-10 of the load) for the corotational
//! material on the 40 x 4 x 4 mesh. Run time: build and solve, wall clock. The tip sags by
//! 15% of the length, so the nonlinear materials also see the geometric stiffening that
//! small-deflection beam theory leaves out (about 1% here).
//!
//! **Step settings** (`fem-steps`). Backward Euler on the same cantilever (corotational),
//! released from rest at its undeformed shape and swinging under its weight: 30 steps of
//! 1/60 s on the 100 x 10 x 10 beam of issue 15's bench (20 x 2 x 2 quick). Each way of
//! solving a step (the linear solver, how long the multigrid hierarchy is kept, inexact
//! Newton, Newton's stopping test, `f32` products, the warped tangent; cumulative, as
//! the bench's rows) runs at Newton tolerances from 1e-2 to 1e-6, and its trajectory is
//! compared with the same steps solved by full Newton to 1e-10 with sparse Cholesky.
//! Error: the largest over the steps of `|v - v*| / (1 + |v*|)` (what Newton's step
//! tolerance bounds within one step; here accumulated over the run) and the largest
//! difference of the tip's height (m). Run time: the mean wall time of a step, the
//! solvers' setup in the first steps included.

use super::{solid_curves, write_file, write_plot_and_numbers, Progress, StudyError};
use crate::fem::mesh::box_mesh;
use crate::fem::{FemDesc, FemMaterial, Material};
use crate::plot::{Curve, Panel, Scale};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

const L: f64 = 1.0;
const H: f64 = 0.1;
const E: f64 = 1e7;
const NU: f64 = 0.3;
const RHO: f64 = 1000.0;
const G: f64 = 9.81;

/// Timoshenko's tip deflection of the cantilever under its weight (m).
fn timoshenko() -> f64 {
    let (area, inertia) = (H * H, H.powi(4) / 12.0);
    let kappa = 10.0 * (1.0 + NU) / (12.0 + 11.0 * NU);
    let q = RHO * G * area;
    q * L.powi(4) / (8.0 * E * inertia) + q * L * L / (2.0 * kappa * E / (2.0 * (1.0 + NU)) * area)
}

#[derive(Serialize, Clone)]
struct Point {
    cubes: [usize; 3],
    tetrahedra: usize,
    tolerance: f64,
    newton_iterations: usize,
    tip_deflection: Option<f64>,
    error: Option<f64>,
    seconds: f64,
}

#[derive(Serialize)]
struct Sweep {
    name: String,
    points: Vec<Point>,
}

/// Builds and solves the cantilever of `k` cubes across in `model` to `tolerance`.
fn cantilever(k: usize, model: Material, tolerance: f64) -> Point {
    let t0 = Instant::now();
    let cubes = [10 * k, k, k];
    let d = FemDesc::cantilever(
        cubes,
        [L, H, H],
        FemMaterial {
            model,
            young: E,
            poisson: NU,
            density: RHO,
        },
        G,
    );
    let mesh = &d;
    let n = mesh.positions.len();
    let (fem, state) = d.build().expect("the study's cantilever is valid");
    let mut x = state.x.as_slice().to_vec();
    let solved = fem.solve_static(&mut x, 1, tolerance);
    let seconds = t0.elapsed().as_secs_f64();
    let tip: Vec<usize> = (0..n).filter(|&i| mesh.positions[i][0] == L).collect();
    let deflection = solved.as_ref().ok().map(|_| {
        -tip.iter()
            .map(|&i| x[n + i] - mesh.positions[i][1])
            .sum::<f64>()
            / tip.len() as f64
    });
    Point {
        cubes,
        tetrahedra: mesh.tets.len(),
        tolerance,
        newton_iterations: solved.map_or(0, |i| i.newton_iterations),
        tip_deflection: deflection,
        error: deflection.map(|d| (d - timoshenko()).abs() / timoshenko()),
        seconds,
    }
}

pub(super) fn accuracy(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let ks: Vec<usize> = if quick {
        vec![1, 2, 4]
    } else {
        vec![1, 2, 4, 8]
    };
    let materials = [
        ("linear", Material::Linear),
        ("corotational", Material::Corotational),
        ("stable neo-Hookean", Material::StableNeoHookean),
    ];
    let tols: Vec<f64> = if quick {
        vec![1e-2, 1e-4, 1e-8]
    } else {
        vec![1e-2, 1e-3, 1e-4, 1e-6, 1e-8, 1e-10]
    };
    progress.expect(materials.len() * ks.len() + tols.len());
    let mut sweeps: Vec<Sweep> = materials
        .iter()
        .map(|&(name, m)| Sweep {
            name: format!("{name}, {} to {} cubes across", ks[0], ks[ks.len() - 1]),
            points: ks
                .iter()
                .map(|&k| {
                    let p = cantilever(k, m, 1e-10);
                    progress.tick(&format!("{name}, {k} across"));
                    p
                })
                .collect(),
        })
        .collect();
    sweeps.push(Sweep {
        name: format!(
            "corotational, 4 across, Newton to {:.0e} ... {:.0e} of the load",
            tols[0],
            tols[tols.len() - 1]
        ),
        points: tols
            .iter()
            .map(|&tol| {
                let p = cantilever(4, Material::Corotational, tol);
                progress.tick(&format!("tolerance {tol:.0e}"));
                p
            })
            .collect(),
    });
    let panels = vec![Panel {
        title: "cantilever under its weight: tip error against run time".into(),
        x_label: "run time (s)".into(),
        y_label: "|tip - Timoshenko| / Timoshenko".into(),
        scale: Scale::LogLog,
        curves: solid_curves(sweeps.iter().map(|s| {
            let points = s.points.iter();
            let points =
                points.filter_map(|p| p.error.map(|e| (p.seconds.max(1e-6), e.max(1e-12))));
            (s.name.clone(), points.collect())
        })),
    }];
    write_plot_and_numbers(out, "fem-accuracy", &panels, 1, (820, 520), &sweeps)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# FEM: error against run time (cantilever)\n\nGenerated by `largestep study fem-accuracy{}` ({} threads). Plot: [fem-accuracy.svg](fem-accuracy.svg) ([PNG](fem-accuracy.png)); numbers: [fem-accuracy.json](fem-accuracy.json).\n\nA cantilever of L = {L} m with a square section of {H} m (E = {E:e} Pa, nu = {NU}, {RHO} kg/m^3) clamped at x = 0, loaded by its own weight and solved for static equilibrium (Newton with a line search on the energy, sparse Cholesky, one load increment). Error: the relative difference of the tip deflection (mean over the end face) from Timoshenko beam theory's {:.5e} m. Run time: building the model and solving, wall clock.\n\nLinear tetrahedra lock in bending: on coarse meshes they are far too stiff, and the error falls roughly with the square of the element size. The tip sags by 15% of the length, so the nonlinear materials see geometric stiffening that small-deflection beam theory leaves out (about 1%). The tolerance sweep shows how loose Newton can stop before it, rather than the mesh, sets the error. Newton converges only linearly on the nonlinear materials (10 to 30 iterations from rest in one increment): the definiteness fix replaces the indefinite tangent of the compressed side by its projection, which is not the exact Hessian; linear elasticity's tangent is exact and constant.\n",
        if quick { " --quick" } else { "" },
        rayon::current_num_threads(),
        timoshenko()
    );
    for s in &sweeps {
        let _ = writeln!(
            md,
            "## {}\n\n| cubes | tetrahedra | Newton tolerance | Newton iterations | tip deflection (m) | error | run time (s) |\n|---|---|---|---|---|---|---|",
            s.name
        );
        for p in &s.points {
            let _ = writeln!(
                md,
                "| {} x {} x {} | {} | {:.0e} | {} | {} | {} | {:.3} |",
                p.cubes[0],
                p.cubes[1],
                p.cubes[2],
                p.tetrahedra,
                p.tolerance,
                p.newton_iterations,
                p.tip_deflection
                    .map_or("(failed)".into(), |d| format!("{d:.5e}")),
                p.error.map_or("-".into(), |e| format!("{e:.3e}")),
                p.seconds
            );
        }
        md.push('\n');
    }
    write_file(&out.join("fem-accuracy.md"), &md)?;
    let finest = sweeps[1].points.last().and_then(|p| p.error);
    Ok(format!(
        "fem-accuracy: corotational error {} on the finest mesh; report: {}",
        finest.map_or("-".into(), |e| format!("{e:.3e}")),
        out.join("fem-accuracy.md").display()
    ))
}

/// A block of 4 x 2 x 2 cubes (0.4 m x 0.2 m x 0.2 m, 1000 kg/m^3) in `model` with E and
/// nu, free in space, with a small velocity field; at rest, or `mirrored` through its
/// middle plane and squashed (every element at J = -0.2).
fn block(
    model: Material,
    young: f64,
    poisson: f64,
    mirrored: bool,
) -> (crate::fem::Fem, crate::integrate::MechState) {
    let mesh = box_mesh([4, 2, 2], [0.4, 0.2, 0.2], [0.0; 3]);
    let mut d = FemDesc::new(
        mesh.positions.clone(),
        mesh.tets.clone(),
        FemMaterial {
            model,
            young,
            poisson,
            density: 1000.0,
        },
    );
    // A small velocity field that strains the block (a twist about x and a stretch).
    d.velocities = mesh
        .positions
        .iter()
        .map(|p| {
            [
                1e-3 * (p[0] - 0.2),
                -1e-3 * (p[2] - 0.1),
                1e-3 * (p[1] - 0.1),
            ]
        })
        .collect();
    if mirrored {
        d.initial = mesh
            .positions
            .iter()
            .map(|p| [p[0], 0.1 - 0.2 * (p[1] - 0.1), p[2]])
            .collect();
    }
    d.build().expect("the study's block is valid")
}

/// The highest natural frequency (rad/s) of a model at its rest positions: the square
/// root of the largest eigenvalue of `M^-1/2 K M^-1/2` by power iteration (200 steps from
/// a fixed start; the ratio of successive norms converges from below to the largest
/// eigenvalue, and two steps agreeing to 1e-6 stop it).
fn highest_frequency(fem: &crate::fem::Fem, x: &[f64]) -> f64 {
    use crate::simulation::MechModel;
    use crate::sparse::Bsr3;
    let n = fem.vertex_count();
    let mut work = fem.exact_work();
    let pattern = fem
        .prepare_jacobians(&mut work)
        .expect("pattern")
        .expect("FEM assembles");
    let mut k = Bsr3::zeros(pattern);
    let mut f = vec![0.0; 3 * n];
    fem.force_jacobians(&mut work, 0.0, x, &vec![0.0; 3 * n], &mut f, &mut k, None)
        .expect("stiffness");
    let inv_sqrt_m: Vec<f64> = fem.mass().iter().map(|m| 1.0 / m.sqrt()).collect();
    let mut v: Vec<f64> = (0..3 * n).map(|i| 1.0 + (i % 7) as f64 * 0.1).collect();
    let (mut y, mut scaled) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
    let mut lambda = 0.0;
    for _ in 0..200 {
        let norm = v.iter().map(|a| a * a).sum::<f64>().sqrt();
        v.iter_mut().for_each(|a| *a /= norm);
        for (i, si) in scaled.iter_mut().enumerate() {
            *si = v[i] * inv_sqrt_m[i % n];
        }
        k.spmv(&mut y, &scaled);
        // -dfdx is K; y = M^-1/2 K M^-1/2 v.
        for i in 0..3 * n {
            y[i] = -y[i] * inv_sqrt_m[i % n];
        }
        let next = y.iter().zip(&v).map(|(a, b)| a * b).sum::<f64>();
        std::mem::swap(&mut v, &mut y);
        if (next - lambda).abs() <= 1e-6 * next.abs() {
            lambda = next;
            break;
        }
        lambda = next;
    }
    lambda.max(0.0).sqrt()
}

/// Whether symplectic Euler at step h keeps the block bounded for 400 steps: finite, and
/// the total energy never above 10 times its start (the undamped block only exchanges
/// kinetic and elastic energy, so growth is the method's).
fn stable(model: Material, young: f64, poisson: f64, mirrored: bool, h: f64) -> bool {
    use crate::integrate::{MechSettings, Method};
    use crate::simulation::MechSimulation;
    let (fem, state) = block(model, young, poisson, mirrored);
    let Ok(mut sim) = MechSimulation::new(fem, state, MechSettings::new(Method::SymplecticEuler))
    else {
        return false;
    };
    sim.set_step_control(None);
    let e0 = sim.energy().total().abs().max(1e-300);
    for _ in 0..400 {
        if sim.step(h).is_err() {
            return false;
        }
        let e = sim.energy().total();
        if !(e.is_finite() && e.abs() <= 10.0 * e0) {
            return false;
        }
    }
    true
}

#[derive(Serialize)]
struct StabilityRow {
    material: String,
    young: f64,
    poisson: f64,
    inverted_start: bool,
    highest_frequency: f64,
    predicted_dt: f64,
    measured_dt: Option<f64>,
}

pub(super) fn stability(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let mut cases: Vec<(Material, f64, f64, bool)> = Vec::new();
    let youngs: Vec<f64> = if quick {
        vec![1e4, 1e8]
    } else {
        vec![1e4, 1e6, 1e8, 2e11]
    };
    for &e in &youngs {
        cases.push((Material::Corotational, e, 0.3, false));
    }
    let nus: Vec<f64> = if quick {
        vec![0.45, 0.499]
    } else {
        vec![0.45, 0.49, 0.499]
    };
    for &nu in &nus {
        cases.push((Material::Corotational, 1e6, nu, false));
    }
    cases.push((Material::StableNeoHookean, 1e6, 0.3, true));
    progress.expect(cases.len());
    let mut rows = Vec::new();
    for (m, e, nu, mirrored) in cases {
        let (fem, state) = block(m, e, nu, false);
        let w = highest_frequency(&fem, state.x.as_slice());
        let predicted = 2.0 / w;
        // Geometric bisection on [predicted / 1000, 10 predicted].
        let (mut lo, mut hi) = (predicted / 1000.0, 10.0 * predicted);
        let measured = if !stable(m, e, nu, mirrored, lo) {
            None
        } else {
            for _ in 0..20 {
                let mid = (lo * hi).sqrt();
                if stable(m, e, nu, mirrored, mid) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            Some(lo)
        };
        progress.tick(&format!("{m:?}, E = {e:e}, nu = {nu}"));
        rows.push(StabilityRow {
            material: format!("{m:?}"),
            young: e,
            poisson: nu,
            inverted_start: mirrored,
            highest_frequency: w,
            predicted_dt: predicted,
            measured_dt: measured,
        });
    }
    // One curve per sweep, each in order of the prediction, the prediction itself dashed.
    let series = |keep: &dyn Fn(&StabilityRow) -> bool, measured: bool| -> Vec<(f64, f64)> {
        let mut p: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| keep(r))
            .filter_map(|r| {
                if measured {
                    r.measured_dt.map(|m| (r.predicted_dt, m))
                } else {
                    Some((r.predicted_dt, r.predicted_dt))
                }
            })
            .collect();
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        p
    };
    let e_sweep = |r: &StabilityRow| !r.inverted_start && r.poisson == 0.3;
    let nu_sweep = |r: &StabilityRow| !r.inverted_start && r.poisson != 0.3;
    let inverted = |r: &StabilityRow| r.inverted_start;
    let panels = vec![Panel {
        title: "symplectic Euler on a free block: largest stable step".into(),
        x_label: "predicted 2 / omega_max (s)".into(),
        y_label: "measured largest stable dt (s)".into(),
        scale: Scale::LogLog,
        curves: vec![
            (
                0,
                Curve {
                    label: "dt = 2 / omega_max".into(),
                    points: series(&|_| true, false),
                    dashed: true,
                },
            ),
            (
                1,
                Curve {
                    label: "E from 1e4 to 2e11 Pa (nu 0.3)".into(),
                    points: series(&e_sweep, true),
                    dashed: false,
                },
            ),
            (
                2,
                Curve {
                    label: "nu from 0.45 to 0.499 (E 1 MPa)".into(),
                    points: series(&nu_sweep, true),
                    dashed: false,
                },
            ),
            (
                3,
                Curve {
                    label: "inverted start (stable neo-Hookean)".into(),
                    points: series(&inverted, true),
                    dashed: false,
                },
            ),
        ],
    }];
    write_plot_and_numbers(out, "fem-stability", &panels, 1, (760, 520), &rows)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# FEM: largest stable step of the explicit method\n\nGenerated by `largestep study fem-stability{}` ({} threads). Plot: [fem-stability.svg](fem-stability.svg) ([PNG](fem-stability.png)); numbers: [fem-stability.json](fem-stability.json).\n\nA free block of 4 x 2 x 2 cubes (0.4 m x 0.2 m x 0.2 m, 96 tetrahedra, 1000 kg/m^3) set moving by a small twist and stretch, stepped by symplectic Euler (the explicit central-difference scheme in velocity form). Stable: 400 steps with a finite state whose total energy stays within 10 times its start (the block is undamped and free, so energy can only grow through the method). Largest stable dt by geometric bisection (20 halvings) on [1/1000, 10] times the prediction. Prediction: `2 / omega_max`, omega_max the highest natural frequency of the rest mesh, `sqrt` of the largest eigenvalue of `M^-1/2 K M^-1/2` by power iteration; for a Poisson's ratio near 0.5 the dilatational wave speed, and so omega_max, grows without bound, and so does the cost of explicit steps. The last row starts mirrored through the block's middle plane (every element at J = -0.2) with the stable neo-Hookean material, whose frequency is taken at rest.\n\n| material | E (Pa) | nu | start | omega_max (rad/s) | 2 / omega_max (s) | measured (s) | measured / predicted |\n|---|---|---|---|---|---|---|---|",
        if quick { " --quick" } else { "" },
        rayon::current_num_threads(),
    );
    for r in &rows {
        let _ = writeln!(
            md,
            "| {} | {:e} | {} | {} | {:.4e} | {:.4e} | {} | {} |",
            r.material,
            r.young,
            r.poisson,
            if r.inverted_start { "inverted" } else { "rest" },
            r.highest_frequency,
            r.predicted_dt,
            r.measured_dt.map_or("none".into(), |m| format!("{m:.4e}")),
            r.measured_dt
                .map_or("-".into(), |m| format!("{:.3}", m / r.predicted_dt)),
        );
    }
    write_file(&out.join("fem-stability.md"), &md)?;
    let ratios: Vec<String> = rows
        .iter()
        .map(|r| {
            r.measured_dt
                .map_or("-".into(), |m| format!("{:.2}", m / r.predicted_dt))
        })
        .collect();
    Ok(format!(
        "fem-stability: measured / predicted {}; report: {}",
        ratios.join(", "),
        out.join("fem-stability.md").display()
    ))
}

/// Backward Euler steps of 1/60 s a `fem-steps` run takes (half a second of the swing).
const STEPS: usize = 30;

/// One way of solving the steps, at one Newton tolerance.
#[derive(Serialize, Clone)]
struct StepPoint {
    tolerance: f64,
    newton_per_step: f64,
    pcg_per_step: f64,
    seconds_per_step: f64,
    velocity_error: Option<f64>,
    tip_error: Option<f64>,
    /// Why the run stopped early (a step that failed), if it did.
    failure: Option<String>,
}

#[derive(Serialize)]
struct StepSweep {
    name: String,
    points: Vec<StepPoint>,
}

/// The ways of solving a step the study compares, cumulative from the second: each adds
/// to the one before, as the bench's rows `fem/step/...` do (`benches/fem.rs`).
const STEP_WAYS: [&str; 6] = [
    "Cholesky, a Jacobian per step",
    "PCG + smoothed aggregation, solves to 1e-6",
    "+ inexact Newton (forcing 0.5), hierarchy kept up to 30 steps",
    "+ rate test, second-order guess, forcing 0.1",
    "+ f32 products, accepted step without its residual",
    "+ warped tangent R K0 R^T",
];

/// The first of [`STEP_WAYS`] on the model with the warped tangent
/// ([`FemDesc::warped_tangent`]); the ways before it have the exact one.
const WARPED_WAY: usize = 5;

/// The settings of way `way` (an index into [`STEP_WAYS`]) with Newton to `tolerance`.
fn step_settings(way: usize, tolerance: f64) -> crate::integrate::MechSettings {
    use crate::integrate::{LinearSolverKind, MechSettings, Method};
    use crate::solve::{PcgParams, Preconditioner};
    let mut s = MechSettings::new(Method::BackwardEuler);
    s.newton.tolerance = tolerance;
    s.newton.step_tolerance = tolerance;
    s.reuse_jacobian = 1;
    s.linear = if way == 0 {
        LinearSolverKind::Cholesky
    } else {
        LinearSolverKind::Pcg(PcgParams {
            tolerance: 1e-6,
            max_iterations: 2000,
            preconditioner: Preconditioner::SmoothedAggregation,
        })
    };
    if way >= 2 {
        s.newton.forcing = Some(0.5);
        s.reuse_preconditioner = 30;
    }
    if way >= 3 {
        s.newton.forcing = Some(0.1);
        s.newton.rate_test = true;
        s.second_order_predictor = true;
    }
    if way >= 4 {
        s.rounded_products = true;
        s.newton.skip_last_residual = true;
    }
    s
}

/// The reference: full Newton to 1e-10 with sparse Cholesky, no first guess.
fn step_reference() -> crate::integrate::MechSettings {
    use crate::integrate::{LinearSolverKind, MechSettings, Method};
    let mut s = MechSettings::new(Method::BackwardEuler);
    s.newton.tolerance = 1e-10;
    s.newton.step_tolerance = 1e-10;
    s.newton.max_iterations = 200;
    s.predictor = false;
    s.linear = LinearSolverKind::Cholesky;
    s
}

/// The counts, mean step time and failure of [`step_run`].
struct StepRun {
    steps: usize,
    newton: usize,
    pcg: usize,
    seconds: f64,
    failure: Option<String>,
}

/// `STEPS` steps of `settings` from the cantilever's rest state, `each(k, v, tip)`
/// called after step k with the velocities and the tip's mean height (outside the
/// timing); stops at a step that fails, with its error (the steps before it kept).
fn step_run(
    fem: &crate::fem::Fem,
    state: &crate::integrate::MechState,
    tip: &[usize],
    settings: crate::integrate::MechSettings,
    each: &mut dyn FnMut(usize, &[f64], f64),
) -> StepRun {
    use crate::simulation::{MechModel, MechSimulation};
    let mut run = StepRun {
        steps: 0,
        newton: 0,
        pcg: 0,
        seconds: 0.0,
        failure: None,
    };
    let mut sim = match MechSimulation::new(fem.clone(), state.clone(), settings) {
        Ok(sim) => sim,
        Err(e) => {
            run.failure = Some(e.to_string());
            return run;
        }
    };
    sim.set_step_control(None);
    let n = fem.vertex_count();
    for k in 0..STEPS {
        let t0 = Instant::now();
        let step = sim.step(1.0 / 60.0);
        run.seconds += t0.elapsed().as_secs_f64();
        match step {
            Ok(info) => {
                run.steps += 1;
                run.newton += info.newton_iterations;
                run.pcg += info.linear_iterations;
            }
            Err(e) => {
                run.failure = Some(e.to_string());
                break;
            }
        }
        let s = sim.state();
        let y = &s.x.as_slice()[n..2 * n];
        let height = tip.iter().map(|&i| y[i]).sum::<f64>() / tip.len() as f64;
        each(k, s.v.as_slice(), height);
    }
    run
}

pub(super) fn steps(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let cubes = if quick { [20, 2, 2] } else { [100, 10, 10] };
    let tols: Vec<f64> = if quick {
        vec![1e-2, 1e-3, 1e-6]
    } else {
        vec![1e-2, 1e-3, 1e-4, 1e-6]
    };
    progress.expect(1 + STEP_WAYS.len() * tols.len());
    let d = FemDesc::cantilever(
        cubes,
        [L, H, H],
        FemMaterial {
            model: Material::Corotational,
            young: E,
            poisson: NU,
            density: RHO,
        },
        G,
    );
    let tip: Vec<usize> = (0..d.positions.len())
        .filter(|&i| d.positions[i][0] == L)
        .collect();
    let tetrahedra = d.tets.len();
    let vertices = d.positions.len();
    let mut warped = d.clone();
    warped.warped_tangent = true;
    let (fem, state) = d.build().expect("the study's cantilever is valid");
    let (warped, _) = warped.build().expect("the study's cantilever is valid");
    // The reference's steps: velocities, their norm and the tip's height.
    let mut reference: Vec<(Vec<f64>, f64, f64)> = Vec::with_capacity(STEPS);
    let exact = step_run(&fem, &state, &tip, step_reference(), &mut |_, v, height| {
        let norm = v.iter().map(|w| w * w).sum::<f64>().sqrt();
        reference.push((v.to_vec(), norm, height));
    });
    progress.tick("reference (Cholesky, Newton to 1e-10)");
    if let Some(why) = &exact.failure {
        return Err(StudyError::Write {
            path: out.join("fem-steps.md").display().to_string(),
            message: format!("the reference run failed: {why}"),
        });
    }
    let swing = reference
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
            (lo.min(r.2), hi.max(r.2))
        });
    let sweeps: Vec<StepSweep> = STEP_WAYS
        .iter()
        .enumerate()
        .map(|(way, name)| StepSweep {
            name: name.to_string(),
            points: tols
                .iter()
                .map(|&tol| {
                    let model = if way >= WARPED_WAY { &warped } else { &fem };
                    // The worst velocity and tip differences from the reference's steps.
                    let (mut dv, mut dtip) = (0.0f64, 0.0f64);
                    let settings = step_settings(way, tol);
                    let run = step_run(model, &state, &tip, settings, &mut |k, v, height| {
                        let (w, norm, h) = &reference[k];
                        let diff = v.iter().zip(w).map(|(v, w)| (v - w).powi(2));
                        dv = dv.max(diff.sum::<f64>().sqrt() / (1.0 + norm));
                        dtip = dtip.max((height - h).abs());
                    });
                    progress.tick(&format!("{name}, Newton to {tol:.0e}"));
                    let done = run.steps.max(1) as f64;
                    let complete = run.failure.is_none();
                    let (velocity_error, tip_error) =
                        (complete.then_some(dv), complete.then_some(dtip));
                    StepPoint {
                        tolerance: tol,
                        newton_per_step: run.newton as f64 / done,
                        pcg_per_step: run.pcg as f64 / done,
                        seconds_per_step: run.seconds / done,
                        velocity_error,
                        tip_error,
                        failure: run.failure,
                    }
                })
                .collect(),
        })
        .collect();
    let curves = |y: &dyn Fn(&StepPoint) -> Option<f64>| {
        solid_curves(sweeps.iter().map(|s| {
            let points = s.points.iter();
            let points = points.filter_map(|p| y(p).map(|e| (p.seconds_per_step, e.max(1e-14))));
            (s.name.clone(), points.collect())
        }))
    };
    let title = format!(
        "backward Euler, {} x {} x {} cubes: error against time a step",
        cubes[0], cubes[1], cubes[2]
    );
    let panels = vec![
        Panel {
            title: title.clone(),
            x_label: "time a step (s)".into(),
            y_label: "max |v - v*| / (1 + |v*|)".into(),
            scale: Scale::LogLog,
            curves: curves(&|p| p.velocity_error),
        },
        Panel {
            title: "the same runs: the tip's position".into(),
            x_label: "time a step (s)".into(),
            y_label: "max |tip - tip*| (m)".into(),
            scale: Scale::LogLog,
            curves: curves(&|p| p.tip_error),
        },
    ];
    write_plot_and_numbers(out, "fem-steps", &panels, 1, (820, 440), &sweeps)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# FEM: how a backward Euler step is solved, error against run time\n\nGenerated by `largestep study fem-steps{}` ({} threads). Plot: [fem-steps.svg](fem-steps.svg) ([PNG](fem-steps.png)); numbers: [fem-steps.json](fem-steps.json).\n\nThe cantilever of `fem-accuracy` (L = {L} m, section {H} m, E = {E:e} Pa, nu = {NU}, {RHO} kg/m^3, corotational), {} x {} x {} cubes ({vertices} vertices, {tetrahedra} tetrahedra), clamped at x = 0 and released from rest at its undeformed shape: {STEPS} backward Euler steps of 1/60 s under its weight (the tip swings through {:.4} m). Each way of solving the steps runs at Newton tolerances from {:.0e} to {:.0e} (relative residual and velocity change), and its trajectory is compared with the same steps solved by full Newton to 1e-10 with sparse Cholesky (taking {:.3} s a step). Error: the largest over the steps of `|v - v*| / (1 + |v*|)` (Newton's step tolerance bounds it within one step; here it is accumulated over the run), and the largest difference of the tip's mean height. Run time: the mean wall time of a step, the solvers' setup in the first steps included. The ways are cumulative, each adding to the one before (the rows of `cargo bench --bench fem -- fem/step`): the Jacobian made once a step and reused by its later Newton iterations in all; smoothed aggregation multigrid with rigid-body modes as PCG's preconditioner; the hierarchy kept up to 30 steps; Newton's rate test (Hairer and Wanner's estimate of the error left) with the second-order first guess; the multigrid's `f32` copy of the matrix in PCG's products, and a step the rate test accepts taken without evaluating its residual; the corotational material's warped tangent (each element's linear stiffness turned by its rotation, `R K0 R^T`, Müller and Gross 2004) as Newton's Jacobian, the forces unchanged.\n\nWhat the error measures: each step's own error (the step solved from the same state to 1e-10) stays within the tolerance in every way (`tests/fem.rs`); over a run those errors add up. A stopping test that accepts a step as soon as its estimated error is inside the tolerance (the rate test, one Newton iteration on most steps) leaves errors of about the same size and sign step after step, while the plain test stops only after an iteration whose change is small, which Newton's fast convergence usually takes well past the tolerance; so at the same tolerance the rate test's runs drift further from the reference, and it takes a tighter tolerance to match the plain test's error. Compare the ways at equal error, not at equal tolerance.\n",
        if quick { " --quick" } else { "" },
        rayon::current_num_threads(),
        cubes[0],
        cubes[1],
        cubes[2],
        swing.1 - swing.0,
        tols[0],
        tols[tols.len() - 1],
        exact.seconds / STEPS as f64,
    );
    for s in &sweeps {
        let _ = writeln!(
            md,
            "## {}\n\n| Newton tolerance | Newton iterations a step | PCG iterations a step | time a step (ms) | velocity error | tip error (m) |\n|---|---|---|---|---|---|",
            s.name
        );
        for p in &s.points {
            let e = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.2e}"));
            let _ = writeln!(
                md,
                "| {:.0e} | {:.2} | {:.2} | {:.2} | {} | {} |",
                p.tolerance,
                p.newton_per_step,
                p.pcg_per_step,
                1e3 * p.seconds_per_step,
                e(p.velocity_error),
                e(p.tip_error),
            );
            if let Some(why) = &p.failure {
                let _ = writeln!(md, "\n(stopped: {why})\n");
            }
        }
        md.push('\n');
    }
    write_file(&out.join("fem-steps.md"), &md)?;
    // The fastest way at Newton 1e-3 (in both sweeps), as the bench's fastest row.
    let fastest = sweeps
        .last()
        .and_then(|s| s.points.iter().find(|p| p.tolerance == 1e-3));
    Ok(format!(
        "fem-steps: the last way at Newton 1e-3 {}; report: {}",
        fastest.map_or("-".into(), |p| format!(
            "{:.2} ms a step, velocity error {}",
            1e3 * p.seconds_per_step,
            p.velocity_error.map_or("-".into(), |e| format!("{e:.2e}"))
        )),
        out.join("fem-steps.md").display()
    ))
}
