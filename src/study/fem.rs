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

use super::{write_file, write_plot_and_numbers, Progress, StudyError};
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
        curves: sweeps
            .iter()
            .enumerate()
            .map(|(i, s)| {
                (
                    i,
                    Curve {
                        label: s.name.clone(),
                        points: s
                            .points
                            .iter()
                            .filter_map(|p| p.error.map(|e| (p.seconds.max(1e-6), e.max(1e-12))))
                            .collect(),
                        dashed: false,
                    },
                )
            })
            .collect(),
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
