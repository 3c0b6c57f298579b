//! `largestep study jello-stability` and `largestep study jello-accuracy`.
//!
//! **Stability.** A 4 x 4 x 4 jello lattice of side 1 m (structural, shear and bend springs
//! of stiffness k, damping 0.25 N s/m, mass m per point) starts 1 um into the floor of its
//! box `[-2, 2]^3` with velocity (0.5, -1, 0.3) m/s and a perturbation of 1% of the
//! spacing; collision springs have k_c = k, d_c = 0.25. A step h is *stable* when a run of
//! `min(0.5 s / h, 20,000)` steps stays finite, inside the box grown by 0.5 m, with total
//! energy below twice its start. The largest stable h is found by bisection in log h.
//! The prediction: power iteration on `M^-1/2 K M^-1/2` (K = -df/dx assembled at the
//! start, collision springs of the bottom layer included) gives the highest squared
//! natural frequency mu; at rest the damping matrix is `(k_d / k) K`, so that mode obeys
//! `x'' + 2a x' + mu x = 0` with `a = (k_d / k) mu / 2`, and the bound is the largest h
//! with `|R(h lambda)| <= 1` for its eigenvalues lambda (R the method's stability
//! function), or, for symplectic Euler, `min(1/a, 2 (sqrt(a^2 + mu) - a) / mu)` (Jury
//! conditions on its 2 x 2 step matrix). The linearised backward Euler has no bound.
//!
//! **Accuracy.** The assignment's cube (8^3 points of 1/512 kg, side 1 m, k = 200 N/m,
//! d = 0.25 N s/m) under gravity in its box (k_c = 400 N/m, d_c = 0.25 N s/m), dropped
//! from 0.5 m above the floor moving at (1, 0, 0.5) m/s and tilted: it lands on an edge at
//! about 0.3 s and tumbles. T = 1 s, each integrator at several dt; error = largest
//! distance of a point from the reference at T, the reference being RK4 at dt = 2.5e-5 s
//! (its distance from RK4 at 5e-5 s is reported). (The assignment's `jello.w`, which
//! hits a wall at 25 m/s, is too chaotic for this: after 1 s runs differing by rounding
//! end metres apart.) Run time: wall time of the whole run on this machine.

use super::{log_slope, max_distance, write_file, write_plot_and_numbers, Progress, StudyError};
use crate::integrate::{MechSettings, Method};
use crate::mass_spring::{lattice, CollisionDesc, LatticeOptions, MassSpringDesc};
use crate::plot::{Curve, Panel, Scale};
use crate::simulation::{MechModel, MechSimulation};
use crate::sparse::Bsr3;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

const EXPLICIT: [Method; 4] = [
    Method::ExplicitEuler,
    Method::Midpoint,
    Method::Rk4,
    Method::SymplecticEuler,
];
const METHODS: [Method; 5] = [
    Method::ExplicitEuler,
    Method::Midpoint,
    Method::Rk4,
    Method::SymplecticEuler,
    Method::LinearizedBackwardEuler,
];
const DAMPING: f64 = 0.25;

fn stability_scene(k: f64, mass: f64) -> MassSpringDesc {
    let mut d = lattice(&LatticeOptions {
        n: [4; 3],
        origin: [-0.5, -2.0 - 1e-6, -0.5],
        size: [1.0; 3],
        mass,
        structural: k,
        shear: k,
        bend: k,
        damping: DAMPING,
    });
    let h = 1.0 / 3.0;
    for (i, p) in d.positions.iter_mut().enumerate() {
        for (c, x) in p.iter_mut().enumerate() {
            // A fixed pseudo-random pattern in [-0.5, 0.5), 1% of the spacing.
            let r = ((i * 2654435761 + c * 40503) % 1000) as f64 / 1000.0 - 0.5;
            if !(c == 1 && *x < -1.99) {
                *x += 0.01 * h * r;
            }
        }
    }
    d.velocities = vec![[0.5, -1.0, 0.3]; d.positions.len()];
    d.collisions = Some(CollisionDesc {
        bounds: Some(([-2.0; 3], [2.0; 3])),
        planes: vec![],
        obstacles: Vec::new(),
        stiffness: k,
        damping: DAMPING,
    });
    d
}

/// Highest eigenvalue of `M^-1 K` (1/s^2), K = -df/dx at the start, by power iteration on
/// the symmetric `M^-1/2 K M^-1/2`.
fn highest_mu(desc: &MassSpringDesc) -> f64 {
    let (m, st) = desc.build().expect("valid study scene");
    let n = m.particle_count();
    let mut work = m.work();
    let pattern = m
        .prepare_jacobians(&mut work)
        .expect("pattern")
        .expect("springs have Jacobians");
    let mut kx = Bsr3::zeros(pattern);
    let mut f = vec![0.0; 3 * n];
    let (x, v) = (st.x.as_slice().to_vec(), st.v.as_slice().to_vec());
    m.force_jacobians(&mut work, 0.0, &x, &v, &mut f, &mut kx, None)
        .expect("Jacobians");
    let inv_sqrt_m: Vec<f64> = (0..3 * n).map(|i| 1.0 / m.mass()[i % n].sqrt()).collect();
    let mut y: Vec<f64> = (0..3 * n).map(|i| 1.0 + (i % 7) as f64 * 0.1).collect();
    let mut ky = vec![0.0; 3 * n];
    let mut mu = 0.0;
    for _ in 0..500 {
        let norm = y.iter().map(|c| c * c).sum::<f64>().sqrt();
        for (c, s) in y.iter_mut().zip(&inv_sqrt_m) {
            *c = *c / norm * s;
        }
        kx.spmv(&mut ky, &y);
        for ((c, s), kc) in y.iter_mut().zip(&inv_sqrt_m).zip(&ky) {
            *c = -kc * s;
        }
        mu = y.iter().map(|c| c * c).sum::<f64>().sqrt();
    }
    mu
}

/// `|R(z)|` of the explicit Runge-Kutta methods, z complex as (re, im).
fn stability_function(method: Method, z: (f64, f64)) -> f64 {
    let mul = |a: (f64, f64), b: (f64, f64)| (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0);
    let z2 = mul(z, z);
    let z3 = mul(z2, z);
    let z4 = mul(z3, z);
    let r = match method {
        Method::ExplicitEuler => (1.0 + z.0, z.1),
        Method::Midpoint => (1.0 + z.0 + z2.0 / 2.0, z.1 + z2.1 / 2.0),
        Method::Rk4 => (
            1.0 + z.0 + z2.0 / 2.0 + z3.0 / 6.0 + z4.0 / 24.0,
            z.1 + z2.1 / 2.0 + z3.1 / 6.0 + z4.1 / 24.0,
        ),
        _ => unreachable!("explicit Runge-Kutta methods only"),
    };
    (r.0 * r.0 + r.1 * r.1).sqrt()
}

/// The predicted largest stable step for the mode `x'' + 2a x' + mu x = 0`.
fn predicted(method: Method, mu: f64, a: f64) -> Option<f64> {
    match method {
        Method::SymplecticEuler => Some((1.0 / a).min(2.0 * ((a * a + mu).sqrt() - a) / mu)),
        Method::LinearizedBackwardEuler => None,
        _ => {
            // Eigenvalues -a +- i b (or two real ones when overdamped).
            let disc = mu - a * a;
            let lambdas: Vec<(f64, f64)> = if disc >= 0.0 {
                vec![(-a, disc.sqrt())]
            } else {
                vec![(-a + (-disc).sqrt(), 0.0), (-a - (-disc).sqrt(), 0.0)]
            };
            let ok = |h: f64| {
                lambdas
                    .iter()
                    .all(|l| stability_function(method, (h * l.0, h * l.1)) <= 1.0 + 1e-12)
            };
            // Scan up from far below the bound, then bisect the first crossing.
            let mut h = 1e-3 / mu.sqrt();
            while ok(h * 1.01) && h < 1e3 {
                h *= 1.01;
            }
            let (mut lo, mut hi) = (h, h * 1.01);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if ok(mid) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            Some(lo)
        }
    }
}

/// Whether a run at step h stays bounded (see the module docs).
fn stable(method: Method, desc: &MassSpringDesc, h: f64, max_steps: usize) -> bool {
    let (m, st) = desc.build().expect("valid study scene");
    let Ok(mut sim) = MechSimulation::new(m, st, MechSettings::new(method)) else {
        return false;
    };
    let e0 = sim.energy().total();
    let steps = ((0.5 / h).ceil() as usize).clamp(1, max_steps);
    for k in 0..steps {
        if sim.step(h).is_err() {
            return false;
        }
        if k % 50 == 49 || k + 1 == steps {
            // NaN counts as escaped / grown.
            let inside = sim.state().x.as_slice().iter().all(|c| c.abs() <= 2.5);
            let bounded = sim.energy().total() <= 2.0 * e0;
            if !inside || !bounded {
                return false;
            }
        }
    }
    true
}

/// Largest stable h by bisection in log h within `[lo, hi]`: `Ok(None)` when hi is stable,
/// `Err(lo)` when even lo is not.
fn largest_stable(
    method: Method,
    desc: &MassSpringDesc,
    lo: f64,
    hi: f64,
    iters: usize,
    max_steps: usize,
) -> Result<Option<f64>, f64> {
    if stable(method, desc, hi, max_steps) {
        return Ok(None);
    }
    if !stable(method, desc, lo, max_steps) {
        return Err(lo);
    }
    let (mut lo, mut hi) = (lo, hi);
    for _ in 0..iters {
        let mid = (lo * hi).sqrt();
        if stable(method, desc, mid, max_steps) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(Some(lo))
}

#[derive(Serialize)]
struct StabilityRow {
    sweep: &'static str,
    k: f64,
    mass: f64,
    mu_max: f64,
    method: &'static str,
    measured: Option<f64>,
    predicted: Option<f64>,
    ratio: Option<f64>,
    note: String,
}

pub(super) fn stability(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let (iters, max_steps) = if quick { (8, 4000) } else { (14, 20_000) };
    let assignment_mass = 1.0 / 512.0;
    let mut cases: Vec<(&'static str, f64, f64)> = Vec::new();
    for e in 1..=6 {
        cases.push(("stiffness", 10f64.powi(e), assignment_mass));
    }
    for e in 1..=4 {
        cases.push(("mass", 200.0, 10f64.powi(-e)));
    }
    progress.expect(cases.len() * METHODS.len());
    let mut rows = Vec::new();
    for (sweep, k, mass) in cases {
        let desc = stability_scene(k, mass);
        let mu = highest_mu(&desc);
        let a = DAMPING / k * mu / 2.0;
        for method in METHODS {
            let pred = predicted(method, mu, a);
            let h_ref = pred.unwrap_or(2.0 / mu.sqrt());
            let (lo, hi) = if method == Method::LinearizedBackwardEuler {
                (1e-6, 0.1)
            } else {
                // Not centred on the prediction: the first bisection point is then not the
                // predicted value itself, which would read as a perfect match.
                (h_ref / 64.0, (h_ref * 100.0).min(0.1))
            };
            let (measured, note) = match largest_stable(method, &desc, lo, hi, iters, max_steps) {
                Ok(Some(h)) => (Some(h), String::new()),
                Ok(None) => (None, format!("stable up to h = {hi}")),
                Err(lo) => (None, format!("unstable even at h = {lo:.3e}")),
            };
            rows.push(StabilityRow {
                sweep,
                k,
                mass,
                mu_max: mu,
                method: method.name(),
                measured,
                predicted: pred,
                ratio: measured.zip(pred).map(|(m, p)| m / p),
                note,
            });
            progress.tick(&format!("k = {k:.0e} N/m, m = {mass:.1e} kg: {method}"));
        }
    }
    // Plots: largest stable h against k and against m, measured (solid) and predicted.
    let panel = |sweep: &str, title: &str, x_label: &str, x: &dyn Fn(&StabilityRow) -> f64| {
        let mut curves = Vec::new();
        for (ci, method) in EXPLICIT.iter().enumerate() {
            let pick = |f: &dyn Fn(&StabilityRow) -> Option<f64>| -> Vec<(f64, f64)> {
                rows.iter()
                    .filter(|r| r.sweep == sweep && r.method == method.name())
                    .filter_map(|r| f(r).map(|y| (x(r), y)))
                    .collect()
            };
            curves.push((
                ci,
                Curve {
                    label: format!("{} measured", method.name()),
                    points: pick(&|r| r.measured),
                    dashed: false,
                },
            ));
            // The prediction in the method's colour, dashed, under the measurement.
            curves.push((
                ci,
                Curve {
                    label: format!("{} predicted", method.name()),
                    points: pick(&|r| r.predicted),
                    dashed: true,
                },
            ));
        }
        Panel {
            title: title.into(),
            x_label: x_label.into(),
            y_label: "largest stable dt (s)".into(),
            scale: Scale::LogLog,
            curves,
        }
    };
    let panels = vec![
        panel(
            "stiffness",
            "largest stable dt against spring stiffness (m = 1/512 kg)",
            "kElastic (N/m)",
            &|r| r.k,
        ),
        panel(
            "mass",
            "largest stable dt against point mass (k = 200 N/m)",
            "mass per point (kg)",
            &|r| r.mass,
        ),
    ];
    write_plot_and_numbers(out, "jello-stability", &panels, 2, (640, 480), &rows)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Jello: largest stable time step against stiffness and mass\n\nGenerated by `largestep study jello-stability{}` ({} threads). Plot: [jello-stability.svg](jello-stability.svg) ([PNG](jello-stability.png)); numbers: [jello-stability.json](jello-stability.json).\n",
        if quick { " --quick" } else { "" },
        rayon::current_num_threads()
    );
    let _ = writeln!(
        md,
        "Scene: a 4 x 4 x 4 lattice of side 1 m (564 springs of stiffness k, damping {DAMPING} N s/m), starting on the floor of the box [-2, 2]^3 moving at (0.5, -1, 0.3) m/s, perturbed by 1% of the spacing; collision springs k_c = k, d_c = {DAMPING}. Stable: a run of min(0.5 s / dt, {max_steps}) steps stays finite, within 0.5 m of the box, with total energy below twice its start; bisection in log dt ({iters} halvings of the bracket [predicted / 64, predicted x 100] in log dt).\n\nPrediction: mu = highest eigenvalue of M^-1 K at the start (power iteration, collision springs of the bottom layer included); that mode's eigenvalues are -a +- i sqrt(mu - a^2) with a = (k_d / k) mu / 2, since at rest the damping matrix is (k_d / k) K; the bound is the largest dt with |R(dt lambda)| <= 1 (R = 1 + z, 1 + z + z^2/2, the RK4 polynomial), and min(1/a, 2 (sqrt(a^2 + mu) - a) / mu) for symplectic Euler (Jury conditions). The linearised backward Euler is tested up to dt = 0.1 s.\n\nMeasured bounds are never below the predicted ones. Where they lie well above (explicit Euler and midpoint with heavy masses or very stiff springs) the step's growth factor just past the bound exceeds 1 by so little that a run of {max_steps} steps does not show it: the prediction is the bound to trust.\n"
    );
    let _ = writeln!(
        md,
        "| sweep | k (N/m) | mass (kg) | sqrt(mu_max) (1/s) | method | measured dt | predicted dt | measured / predicted |\n|---|---|---|---|---|---|---|---|"
    );
    for r in &rows {
        let _ = writeln!(
            md,
            "| {} | {:.0e} | {:.2e} | {:.3e} | {} | {} | {} | {} |",
            r.sweep,
            r.k,
            r.mass,
            r.mu_max.sqrt(),
            r.method,
            r.measured.map_or(r.note.clone(), |h| format!("{h:.4e}")),
            r.predicted
                .map_or("none (A-stable)".into(), |h| format!("{h:.4e}")),
            r.ratio.map_or("-".into(), |x| format!("{x:.3}"))
        );
    }
    write_file(&out.join("jello-stability.md"), &md)?;
    let ratios: Vec<f64> = rows.iter().filter_map(|r| r.ratio).collect();
    let (lo, hi) = ratios
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(a, b), &r| (a.min(r), b.max(r)));
    Ok(format!(
        "jello-stability: measured / predicted largest stable dt between {lo:.3} and {hi:.3} over {} explicit cases; report: {}",
        ratios.len(),
        out.join("jello-stability.md").display()
    ))
}

#[derive(Serialize, Clone)]
struct AccuracyPoint {
    dt: f64,
    steps: usize,
    error: Option<f64>,
    seconds: f64,
}

#[derive(Serialize)]
struct AccuracySeries {
    method: &'static str,
    observed_order: Option<f64>,
    points: Vec<AccuracyPoint>,
}

fn accuracy_scene() -> MassSpringDesc {
    let mut d = lattice(&LatticeOptions {
        n: [8; 3],
        origin: [-0.5, -1.5, -0.5],
        size: [1.0; 3],
        mass: 1.0 / 512.0,
        structural: 200.0,
        shear: 200.0,
        bend: 200.0,
        damping: DAMPING,
    });
    // Tilt by 0.3 rad about z and 0.2 rad about x, round the centre (0, -1, 0).
    let (cz, sz, cx, sx) = (0.3f64.cos(), 0.3f64.sin(), 0.2f64.cos(), 0.2f64.sin());
    for p in &mut d.positions {
        let (x, y, z) = (p[0], p[1] + 1.0, p[2]);
        let (x, y) = (cz * x - sz * y, sz * x + cz * y);
        let (y, z) = (cx * y - sx * z, sx * y + cx * z);
        *p = [x, y - 1.0, z];
    }
    d.velocities = vec![[1.0, 0.0, 0.5]; d.positions.len()];
    d.gravity = [0.0, -9.81, 0.0];
    d.collisions = Some(CollisionDesc {
        bounds: Some(([-2.0; 3], [2.0; 3])),
        planes: vec![],
        obstacles: Vec::new(),
        stiffness: 400.0,
        damping: DAMPING,
    });
    d
}

/// Runs `desc` with `method` at `dt` to T: the final positions (None when it failed or
/// left the box) and the wall time.
fn run_world(
    desc: &MassSpringDesc,
    method: Method,
    dt: f64,
    t_end: f64,
) -> (Option<Vec<f64>>, f64) {
    let (m, st) = desc.build().expect("valid scene");
    let t0 = Instant::now();
    let Ok(mut sim) = MechSimulation::new(m, st, MechSettings::new(method)) else {
        return (None, 0.0);
    };
    let steps = (t_end / dt).round() as usize;
    for _ in 0..steps {
        if sim.step(dt).is_err() {
            return (None, t0.elapsed().as_secs_f64());
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    let x = sim.state().x.as_slice();
    let ok = x.iter().all(|c| c.abs() <= 2.5);
    (ok.then(|| x.to_vec()), secs)
}

pub(super) fn accuracy(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let world = accuracy_scene();
    progress.expect(2);
    let t_end = 1.0;
    let ref_dt = if quick { 1e-4 } else { 2.5e-5 };
    let (reference, ref_secs) = run_world(&world, Method::Rk4, ref_dt, t_end);
    let reference = reference.expect("the reference run is stable");
    let (check, _) = run_world(&world, Method::Rk4, 2.0 * ref_dt, t_end);
    let ref_change = check.map(|c| max_distance(&c, &reference));
    progress.tick("reference and its check");
    progress.expect(METHODS.len());
    let mut series = Vec::new();
    for method in METHODS {
        let dts: Vec<f64> = if method == Method::LinearizedBackwardEuler {
            (0..if quick { 4 } else { 6 })
                .map(|k| 1e-2 / 2f64.powi(k))
                .collect()
        } else {
            (0..if quick { 3 } else { 5 })
                .map(|k| 1e-3 / 2f64.powi(k))
                .collect()
        };
        let points: Vec<AccuracyPoint> = dts
            .iter()
            .map(|&dt| {
                let (x, seconds) = run_world(&world, method, dt, t_end);
                AccuracyPoint {
                    dt,
                    steps: (t_end / dt).round() as usize,
                    error: x.map(|x| max_distance(&x, &reference)),
                    seconds,
                }
            })
            .collect();
        // Observed order over the finite points.
        let observed_order = log_slope(
            &points
                .iter()
                .filter_map(|p| p.error.filter(|e| *e > 0.0 && *e < 0.5).map(|e| (p.dt, e)))
                .collect::<Vec<_>>(),
        );
        series.push(AccuracySeries {
            method: method.name(),
            observed_order,
            points,
        });
        progress.tick(method.name());
    }
    let panels = vec![Panel {
        title: "jello cube dropped on an edge, T = 1 s: error against run time".into(),
        x_label: "run time (s)".into(),
        y_label: "max point distance from reference (m)".into(),
        scale: Scale::LogLog,
        curves: series
            .iter()
            .enumerate()
            .map(|(i, s)| {
                (
                    i,
                    Curve {
                        label: s.method.to_string(),
                        points: s
                            .points
                            .iter()
                            .filter_map(|p| p.error.map(|e| (p.seconds, e)))
                            .collect(),
                        dashed: false,
                    },
                )
            })
            .collect(),
    }];
    write_plot_and_numbers(out, "jello-accuracy", &panels, 1, (760, 520), &series)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Jello: error against run time\n\nGenerated by `largestep study jello-accuracy{}` ({} threads). Plot: [jello-accuracy.svg](jello-accuracy.svg) ([PNG](jello-accuracy.png)); numbers: [jello-accuracy.json](jello-accuracy.json).\n\nScene: the assignment's cube (8^3 points of 1/512 kg, k = 200 N/m, d = 0.25 N s/m) under gravity in its box (k_c = 400 N/m), dropped tilted from 0.5 m moving at (1, 0, 0.5) m/s; it lands on an edge at about 0.3 s and tumbles; T = {t_end} s. Error: the largest distance of a point from the reference at T. Reference: RK4 at dt = {ref_dt:e} s ({ref_secs:.1} s of run time); RK4 at twice that step differs from it by {} m. Run time: one run, wall clock. A dash: the run blew up or left the box.\n\nThe penalty springs switch on and off as points cross the walls, so the right-hand side is not smooth: observed orders fall below the methods' nominal ones.\n",
        if quick { " --quick" } else { "" },
        rayon::current_num_threads(),
        ref_change.map_or("(unstable)".into(), |d| format!("{d:.2e}"))
    );
    let _ = writeln!(md, "| method | observed order | dt (s) | steps | error (m) | run time (s) |\n|---|---|---|---|---|---|");
    for s in &series {
        for p in &s.points {
            let _ = writeln!(
                md,
                "| {} | {} | {:.3e} | {} | {} | {:.3} |",
                s.method,
                s.observed_order.map_or("-".into(), |o| format!("{o:.2}")),
                p.dt,
                p.steps,
                p.error.map_or("-".into(), |e| format!("{e:.3e}")),
                p.seconds
            );
        }
    }
    write_file(&out.join("jello-accuracy.md"), &md)?;
    let orders: Vec<String> = series
        .iter()
        .map(|s| {
            format!(
                "{} {}",
                s.method,
                s.observed_order.map_or("-".into(), |o| format!("{o:.2}"))
            )
        })
        .collect();
    Ok(format!(
        "jello-accuracy: observed orders {}; report: {}",
        orders.join(", "),
        out.join("jello-accuracy.md").display()
    ))
}
