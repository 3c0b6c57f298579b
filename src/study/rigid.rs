//! Rigid-body studies (issue 19): `rigid-integrators`, a torque-free box spun near its
//! intermediate axis (the Dzhanibekov case, where errors grow fastest) by each
//! integrator over a range of steps: the orientation error against run time, and how each
//! method treats the energy and the angular momentum.

use super::{write_file, write_plot_and_numbers, Progress, StudyError};
use crate::kernels::quat;
use crate::plot::{Curve, Panel, Scale};
use crate::rigid::{BodyDesc, RigidDesc, RigidIntegrator, Shape};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

#[derive(Serialize)]
struct Point {
    integrator: &'static str,
    dt: f64,
    seconds: f64,
    /// The angle between the orientation reached and the reference's (rad).
    orientation_error: f64,
    /// Relative change of the kinetic energy over the run.
    energy_change: f64,
    /// Change of the angular momentum vector relative to its length, `|ΔL| / |L|`.
    momentum_change: f64,
}

/// One log-log curve per name: the points `keep` gives it, through `f`, those with
/// positive coordinates.
fn curves_by<P>(
    names: &[&str],
    points: &[P],
    keep: impl Fn(&P, &str) -> bool,
    f: &dyn Fn(&P) -> (f64, f64),
) -> Vec<(usize, Curve)> {
    names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            (
                k,
                Curve {
                    label: (*name).into(),
                    points: points
                        .iter()
                        .filter(|p| keep(p, name))
                        .map(f)
                        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite())
                        .collect(),
                    dashed: false,
                },
            )
        })
        .collect()
}

const DURATION: f64 = 4.0;
const SPIN: [f64; 3] = [0.0, 5.0, 0.05];

fn desc(integrator: RigidIntegrator) -> RigidDesc {
    RigidDesc {
        bodies: vec![BodyDesc {
            angular_velocity: SPIN,
            ..BodyDesc::new(
                Shape::Box {
                    half: [0.1, 0.3, 0.5],
                },
                [0.0; 3],
            )
        }],
        gravity: [0.0; 3],
        integrator,
        // One sub-step: the step is the integrator's.
        iterations: 1,
        ..RigidDesc::default()
    }
}

/// Runs `integrator` at `dt` to `DURATION`: the final orientation, the relative energy and
/// momentum changes, and the run time.
fn run(integrator: RigidIntegrator, dt: f64) -> (quat::Quat, f64, f64, f64) {
    let (m, mut s, mut w) = desc(integrator).build().expect("a valid box");
    let (e0, l0) = (m.kinetic_energy(&s), m.angular_momentum(&s, 0));
    let steps = (DURATION / dt).round() as usize;
    let t0 = Instant::now();
    for _ in 0..steps {
        if m.step(&mut s, &mut w, dt).is_err() {
            break;
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    let l1 = m.angular_momentum(&s, 0);
    let dl = crate::kernels::v3::sub(l1, l0);
    let norm = |v: [f64; 3]| crate::kernels::v3::dot(v, v).sqrt();
    (
        s.q[0],
        (m.kinetic_energy(&s) - e0) / e0,
        norm(dl) / norm(l0),
        secs,
    )
}

/// `largestep study rigid-integrators`.
pub(super) fn integrators(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let dts: Vec<f64> = if quick {
        vec![0.02, 0.01, 0.005]
    } else {
        vec![0.04, 0.02, 0.01, 0.005, 0.0025, 0.00125]
    };
    let methods = [
        RigidIntegrator::ExplicitEuler,
        RigidIntegrator::SymplecticEuler,
        RigidIntegrator::ImplicitGyroscopic,
        RigidIntegrator::Rk4,
    ];
    progress.expect(1 + methods.len());
    // The reference: Runge-Kutta at 1e-4 s (its error there is below 1e-10 rad).
    let (reference, _, _, _) = run(RigidIntegrator::Rk4, 1e-4);
    progress.tick("reference");
    let mut points = Vec::new();
    for m in methods {
        for &dt in &dts {
            let (q, de, dl, secs) = run(m, dt);
            let err = quat::log(quat::mul(quat::conj(reference), q));
            let angle = crate::kernels::v3::dot(err, err).sqrt();
            points.push(Point {
                integrator: m.name(),
                dt,
                seconds: secs,
                orientation_error: if angle.is_finite() { angle } else { f64::NAN },
                energy_change: de,
                momentum_change: dl,
            });
        }
        progress.tick(m.name());
    }
    let names: Vec<&str> = methods.iter().map(|m| m.name()).collect();
    let curves = |f: &dyn Fn(&Point) -> (f64, f64)| {
        curves_by(&names, &points, |p, name| p.integrator == name, f)
    };
    let panels = vec![
        Panel {
            title: "orientation error against run time".into(),
            x_label: "run time (s)".into(),
            y_label: "angle from the reference (rad)".into(),
            scale: Scale::LogLog,
            curves: curves(&|p| (p.seconds, p.orientation_error)),
        },
        Panel {
            title: "energy change against step".into(),
            x_label: "dt (s)".into(),
            y_label: "|dE| / E".into(),
            scale: Scale::LogLog,
            curves: curves(&|p| (p.dt, p.energy_change.abs())),
        },
    ];
    write_plot_and_numbers(out, "rigid-integrators", &panels, 2, (520, 420), &points)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Rigid-body integrators: a torque-free box near its intermediate axis\n\nGenerated by `largestep study rigid-integrators{}`. Plot: [rigid-integrators.svg](rigid-integrators.svg) ([PNG](rigid-integrators.png)); numbers: [rigid-integrators.json](rigid-integrators.json).\n\nA 0.2 x 0.6 x 1.0 m box (1000 kg/m^3) spins at {SPIN:?} rad/s about its intermediate axis (y) with a small push about z, without gravity, for {DURATION} s (about one flip). The reference: classical Runge-Kutta at dt = 1e-4 s. The orientation error is the angle of the rotation between the reference's final orientation and the method's. Explicit Euler, symplectic Euler and Runge-Kutta advance the angular momentum L itself (Baraff's state), so without torque they keep it to rounding (and the two Euler methods coincide: with no torque only the order of the orientation and momentum updates differs, and L does not change); the implicit gyroscopic step (Catto 2015) advances the body-frame angular velocity and keeps the energy from growing instead.\n\n| integrator | dt (s) | run time (s) | orientation error (rad) | dE / E | abs(dL) / abs(L) |\n|---|---|---|---|---|---|",
        if quick { " --quick" } else { "" },
    );
    for p in &points {
        let _ = writeln!(
            md,
            "| {} | {} | {:.2e} | {:.2e} | {:+.2e} | {:.1e} |",
            p.integrator, p.dt, p.seconds, p.orientation_error, p.energy_change, p.momentum_change
        );
    }
    write_file(&out.join("rigid-integrators.md"), &md)?;
    let best = |name: &str| {
        points
            .iter()
            .rfind(|p| p.integrator == name)
            .map_or(f64::NAN, |p| p.orientation_error)
    };
    Ok(format!(
        "rigid-integrators: at dt = {} s the orientation error is {:.1e} rad (RK4), {:.1e} (symplectic Euler), {:.1e} (implicit gyroscopic), {:.1e} (explicit Euler); report: {}",
        dts.last().copied().unwrap_or(0.0),
        best("rk4"),
        best("symplectic-euler"),
        best("implicit-gyroscopic"),
        best("explicit-euler"),
        out.join("rigid-integrators.md").display()
    ))
}

#[derive(Serialize)]
struct StackPoint {
    solver: String,
    iterations: usize,
    seconds: f64,
    /// How far the top box sank while settling (m, the first 2 s).
    sag: f64,
    /// The largest motion of any box after settling (m, 2 s to 5 s).
    drift: f64,
    /// Whether the stack stood (every box within a tenth of its size of its column).
    stood: bool,
}

/// `largestep study rigid-contacts`: the ten-box stack at dt = 1/60 s by each contact
/// solver and position correction over the number of sub-steps: sag while settling and
/// drift after, against run time.
pub(super) fn contacts(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    use crate::rigid::{Correction, Motion, RigidSolver};
    let iterations: Vec<usize> = if quick {
        vec![2, 4, 8]
    } else {
        vec![1, 2, 4, 8, 16, 32]
    };
    let variants: [(&str, RigidSolver, Correction); 5] = [
        (
            "sequential impulses, soft",
            RigidSolver::SequentialImpulses,
            Correction::Soft,
        ),
        (
            "sequential impulses, split",
            RigidSolver::SequentialImpulses,
            Correction::Split,
        ),
        (
            "sequential impulses, Baumgarte",
            RigidSolver::SequentialImpulses,
            Correction::Baumgarte,
        ),
        (
            "one-shot impulses, soft",
            RigidSolver::Impulse,
            Correction::Soft,
        ),
        (
            "penalty",
            RigidSolver::Penalty {
                stiffness: None,
                damping: None,
            },
            Correction::Soft,
        ),
    ];
    progress.expect(variants.len());
    let stack = |solver, correction, iterations| {
        let mut bodies = vec![BodyDesc {
            motion: Motion::Static,
            ..BodyDesc::new(
                Shape::Box {
                    half: [3.0, 0.5, 3.0],
                },
                [0.0, -0.5, 0.0],
            )
        }];
        for k in 0..10 {
            bodies.push(BodyDesc::new(
                Shape::Box {
                    half: [0.5, 0.5, 0.5],
                },
                [0.0, 0.5 + k as f64, 0.0],
            ));
        }
        RigidDesc {
            bodies,
            solver,
            correction,
            iterations,
            ..RigidDesc::default()
        }
    };
    let dt = 1.0 / 60.0;
    let mut points = Vec::new();
    for (name, solver, correction) in variants {
        for &it in &iterations {
            let (m, mut s, mut w) = stack(solver, correction, it)
                .build()
                .expect("a valid stack");
            let top0 = s.x[10][1];
            let t0 = Instant::now();
            let mut failed = false;
            while s.time < 2.0 && !failed {
                failed = m.step(&mut s, &mut w, dt).is_err();
            }
            let settled = s.x.clone();
            let mut drift = 0.0f64;
            while s.time < 5.0 && !failed {
                failed = m.step(&mut s, &mut w, dt).is_err();
                for (x, x0) in s.x.iter().zip(&settled) {
                    let d = crate::kernels::v3::sub(*x, *x0);
                    drift = drift.max(crate::kernels::v3::dot(d, d).sqrt());
                }
            }
            let seconds = t0.elapsed().as_secs_f64();
            let stood = !failed
                && s.x.iter().skip(1).enumerate().all(|(k, x)| {
                    (x[0].hypot(x[2]) < 0.05) && (x[1] - (0.5 + k as f64)).abs() < 0.2
                });
            points.push(StackPoint {
                solver: name.into(),
                iterations: it,
                seconds,
                sag: if failed {
                    f64::NAN
                } else {
                    top0 - settled[10][1]
                },
                drift: if failed { f64::NAN } else { drift },
                stood,
            });
        }
        progress.tick(name);
    }
    let names: Vec<&str> = variants.iter().map(|v| v.0).collect();
    // Only the stacks that stood are drawn.
    let curves = |f: &dyn Fn(&StackPoint) -> (f64, f64)| {
        curves_by(&names, &points, |p, name| p.solver == name && p.stood, f)
    };
    let panels = vec![
        Panel {
            title: "drift after settling against run time".into(),
            x_label: "run time for 5 s (s)".into(),
            y_label: "largest motion, 2 s to 5 s (m)".into(),
            scale: Scale::LogLog,
            curves: curves(&|p| (p.seconds, p.drift)),
        },
        Panel {
            title: "sag while settling against sub-steps".into(),
            x_label: "sub-steps per step".into(),
            y_label: "top box sank (m)".into(),
            scale: Scale::LogLog,
            curves: curves(&|p| (p.iterations as f64, p.sag)),
        },
    ];
    write_plot_and_numbers(out, "rigid-contacts", &panels, 2, (560, 420), &points)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Rigid contact solvers: the ten-box stack\n\nGenerated by `largestep study rigid-contacts{}`. Plot: [rigid-contacts.svg](rigid-contacts.svg) ([PNG](rigid-contacts.png)); numbers: [rigid-contacts.json](rigid-contacts.json).\n\nTen 1 m boxes (1000 kg/m^3) stacked on a static slab, dt = 1/60 s, friction 0.5, for each solver and position correction over the sub-steps per step (`[rigid] iterations`). Sag: how far the top box sank in the first 2 s (soft contacts and penalty springs sag under the load; rigid corrections sink to their slop). Drift: the largest motion of any box from 2 s to 5 s, the error a resting stack should not have. A stack stood when every box ends within 5 cm of its column and 0.2 m of its height; the plot shows those that stood. One-shot impulses (no accumulation, no warm start) cannot carry a stack's weight down the column within a step, and penalty springs stiff enough to hold ten boxes' weight are too stiff for the step: neither stands, as expected of them; they are there for single contacts and bounces (Newton's cradle).\n\n| solver | sub-steps | run time (s) | sag (m) | drift (m) | stood |\n|---|---|---|---|---|---|",
        if quick { " --quick" } else { "" },
    );
    for p in &points {
        let _ = writeln!(
            md,
            "| {} | {} | {:.3} | {:.2e} | {:.2e} | {} |",
            p.solver,
            p.iterations,
            p.seconds,
            p.sag,
            p.drift,
            if p.stood { "yes" } else { "no" }
        );
    }
    write_file(&out.join("rigid-contacts.md"), &md)?;
    let default = points
        .iter()
        .find(|p| p.solver == "sequential impulses, soft" && p.iterations == 4);
    Ok(format!(
        "rigid-contacts: {} of {} runs stood; the default (soft sequential impulses, 4 sub-steps) drifts {}; report: {}",
        points.iter().filter(|p| p.stood).count(),
        points.len(),
        default.map_or("-".into(), |p| format!("{:.1e} m after settling", p.drift)),
        out.join("rigid-contacts.md").display()
    ))
}
