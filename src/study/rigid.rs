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
    let curves = |f: &dyn Fn(&Point) -> (f64, f64)| -> Vec<(usize, Curve)> {
        methods
            .iter()
            .enumerate()
            .map(|(k, m)| {
                (
                    k,
                    Curve {
                        label: m.name().into(),
                        points: points
                            .iter()
                            .filter(|p| p.integrator == m.name())
                            .map(f)
                            .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite())
                            .collect(),
                        dashed: false,
                    },
                )
            })
            .collect()
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
