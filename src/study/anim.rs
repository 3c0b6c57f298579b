//! Character animation studies (issue 20).
//!
//! - `anim-ik`: each IK method on a chain of four ball joints (0.4, 0.3, 0.2, 0.1 m)
//!   reaching 100 reachable targets (random poses' tips) from the rest pose, with the
//!   iteration cap swept: the mean distance left against run time. Then the extremes:
//!   targets at 1.5 times the reach (the distance left over the closest possible), bones
//!   a million times shorter and longer (relative distance left), and a target straight
//!   ahead of the stretched chain (the singular pose).
//! - `anim-sampling`: a rotation track (SQUAD through 8 keys) baked to a fixed rate and
//!   sampled back by NLERP between frames, as a clip does: the largest angle from the
//!   track against the rate and against the memory the baked keys take (a sample's
//!   time, in the report, does not depend on the rate).

use super::{curves_by, write_file, write_plot_and_numbers, Progress, StudyError};
use crate::anim::ik::{Effector, Ik, IkJoint, IkMethod};
use crate::anim::keyframe::{Cursor, RotationInterpolation, RotationTrack};
use crate::anim::{JointDesc, Skeleton, SkeletonDesc};
use crate::kernels::{quat, rotation};
use crate::plot::{Curve, Panel, Scale};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

const LENGTHS: [f64; 4] = [0.4, 0.3, 0.2, 0.1];

/// The chain, bone lengths scaled by `s`, along x.
fn chain(s: f64) -> Skeleton {
    let mut joints = vec![JointDesc::new("j0", None, [0.0; 3])];
    for (i, l) in LENGTHS.iter().enumerate() {
        joints.push(JointDesc::new(
            &format!("j{}", i + 1),
            Some(i),
            [s * l, 0.0, 0.0],
        ));
    }
    SkeletonDesc { joints }.build().expect("a valid chain")
}

fn solver(s: &Skeleton, method: IkMethod, iterations: usize) -> Ik {
    let joints = (0..4).map(|j| IkJoint::free(j, &[0, 1, 2])).collect();
    let mut ik = Ik::new(s, joints, method).expect("a valid chain");
    ik.max_iterations = iterations;
    ik.tolerance = 1e-9;
    ik
}

/// `n` reachable targets: tips of random poses (a fixed generator).
fn targets(s: &Skeleton, n: usize) -> Vec<[f64; 3]> {
    let mut x = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let ik = solver(s, IkMethod::Transpose, 1);
    let mut pose = s.rest().clone();
    let mut model = Vec::new();
    (0..n)
        .map(|_| {
            let angles: Vec<f64> = (0..12).map(|_| 2.0 * rnd()).collect();
            ik.apply(s, &angles, &mut pose);
            s.model(&pose, &mut model);
            [model[4][3], model[4][7], model[4][11]]
        })
        .collect()
}

/// Mean distance left over `targets` and the run time.
fn solve_all(s: &Skeleton, ik: &Ik, targets: &[[f64; 3]]) -> (f64, f64) {
    let mut pose = s.rest().clone();
    let t0 = Instant::now();
    let mut sum = 0.0;
    for &target in targets {
        pose.clone_from(s.rest());
        let mut angles = vec![0.05; ik.dofs()];
        let r = ik
            .solve(s, &mut pose, &mut angles, &[Effector { joint: 4, target }])
            .expect("valid targets");
        sum += r.distances[0];
    }
    (sum / targets.len() as f64, t0.elapsed().as_secs_f64())
}

#[derive(Serialize)]
struct IkPoint {
    method: &'static str,
    iterations: usize,
    seconds: f64,
    mean_distance: f64,
}

#[derive(Serialize)]
struct Extreme {
    method: &'static str,
    case: &'static str,
    value: f64,
}

/// `largestep study anim-ik`.
pub(super) fn ik(out: &Path, quick: bool, progress: &Progress<'_>) -> Result<String, StudyError> {
    let caps: Vec<usize> = if quick {
        vec![1, 4, 16, 64]
    } else {
        vec![1, 2, 4, 8, 16, 32, 64, 128, 256]
    };
    let methods = IkMethod::all(0.05);
    let n = if quick { 30 } else { 100 };
    progress.expect(methods.len());
    let s = chain(1.0);
    let goal = targets(&s, n);
    let mut points = Vec::new();
    let mut extremes = Vec::new();
    let reach: f64 = LENGTHS.iter().sum();
    for &m in &methods {
        for &cap in &caps {
            let (d, secs) = solve_all(&s, &solver(&s, m, cap), &goal);
            points.push(IkPoint {
                method: m.name(),
                iterations: cap,
                seconds: secs,
                mean_distance: d,
            });
        }
        // Extremes, at the largest cap.
        let cap = *caps.last().unwrap_or(&64);
        let far: Vec<[f64; 3]> = goal
            .iter()
            .map(|t| {
                let l = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt().max(1e-12);
                t.map(|v| v / l * 1.5 * reach)
            })
            .collect();
        let (d, _) = solve_all(&s, &solver(&s, m, cap), &far);
        extremes.push(Extreme {
            method: m.name(),
            case: "targets at 1.5x reach: mean distance left over the closest possible (m)",
            value: d - 0.5 * reach,
        });
        for (scale, case) in [
            (1e-6, "bones 1e-6 as long: mean distance left / reach"),
            (1e6, "bones 1e6 as long: mean distance left / reach"),
        ] {
            let ss = chain(scale);
            let g: Vec<[f64; 3]> = goal.iter().map(|t| t.map(|v| v * scale)).collect();
            let mut ik = solver(&ss, m, cap);
            ik.tolerance = 1e-9 * scale;
            if let IkMethod::DampedLeastSquares { .. } = m {
                ik.method = IkMethod::DampedLeastSquares {
                    lambda: 0.05 * scale,
                };
            }
            let (d, _) = solve_all(&ss, &ik, &g);
            extremes.push(Extreme {
                method: m.name(),
                case,
                value: d / (scale * reach),
            });
        }
        let straight = [[0.95 * reach, 0.0, 0.0], [0.999 * reach, 0.01, 0.0]];
        let (d, _) = solve_all(&s, &solver(&s, m, cap), &straight);
        extremes.push(Extreme {
            method: m.name(),
            case: "target ahead of the stretched chain (singular start): mean distance left (m)",
            value: d,
        });
        progress.tick(m.name());
    }
    let names: Vec<&str> = methods.iter().map(|m| m.name()).collect();
    let curves = |f: &dyn Fn(&IkPoint) -> (f64, f64)| {
        curves_by(&names, &points, |p, name| p.method == name, f)
    };
    let panels = vec![
        Panel {
            title: "distance left against run time".into(),
            x_label: format!("run time for {n} targets (s)"),
            y_label: "mean distance to the target (m)".into(),
            scale: Scale::LogLog,
            curves: curves(&|p| (p.seconds, p.mean_distance)),
        },
        Panel {
            title: "distance left against iterations".into(),
            x_label: "iterations allowed".into(),
            y_label: "mean distance to the target (m)".into(),
            scale: Scale::LogLog,
            curves: curves(&|p| (p.iterations as f64, p.mean_distance)),
        },
    ];
    #[derive(Serialize)]
    struct Numbers<'a> {
        points: &'a [IkPoint],
        extremes: &'a [Extreme],
    }
    write_plot_and_numbers(
        out,
        "anim-ik",
        &panels,
        2,
        (520, 420),
        &Numbers {
            points: &points,
            extremes: &extremes,
        },
    )?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# IK methods: error against run time, and extremes\n\nGenerated by `largestep study anim-ik{}`. Plot: [anim-ik.svg](anim-ik.svg) ([PNG](anim-ik.png)); numbers: [anim-ik.json](anim-ik.json).\n\nA chain of four ball joints (three angles each, bones 0.4, 0.3, 0.2, 0.1 m along x) reaches {n} targets, each the tip of a random pose (so each is reachable), from the rest pose with every angle at 0.05 rad. Each solve stops at the iteration cap, at a distance of 1e-9 m, or when it stalls. Damped least squares uses lambda = 0.05 m. Times are for all {n} targets on one thread.\n\n| method | iterations | run time (s) | mean distance left (m) |\n|---|---|---|---|",
        if quick { " --quick" } else { "" },
    );
    for p in &points {
        let _ = writeln!(
            md,
            "| {} | {} | {:.2e} | {:.2e} |",
            p.method, p.iterations, p.seconds, p.mean_distance
        );
    }
    let _ = writeln!(
        md,
        "\n## Extremes (at the largest cap)\n\n| method | case | value |\n|---|---|---|"
    );
    for e in &extremes {
        let _ = writeln!(md, "| {} | {} | {:.2e} |", e.method, e.case, e.value);
    }
    write_file(&out.join("anim-ik.md"), &md)?;
    let at = |name: &str| {
        points
            .iter()
            .rfind(|p| p.method == name)
            .map_or(f64::NAN, |p| p.mean_distance)
    };
    Ok(format!(
        "anim-ik: mean distance left at {} iterations: {:.1e} m (transpose), {:.1e} (pseudoinverse), {:.1e} (dls), {:.1e} (ccd), {:.1e} (fabrik); report: {}",
        caps.last().copied().unwrap_or(0),
        at("transpose"),
        at("pseudoinverse"),
        at("dls"),
        at("ccd"),
        at("fabrik"),
        out.join("anim-ik.md").display()
    ))
}

#[derive(Serialize)]
struct SamplingPoint {
    rate: f64,
    seconds_per_sample: f64,
    /// The baked keys' size (four f64 a frame).
    bytes: usize,
    max_angle: f64,
}

/// `largestep study anim-sampling`.
pub(super) fn sampling(
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    let rates: Vec<f64> = if quick {
        vec![5.0, 20.0, 80.0]
    } else {
        vec![2.5, 5.0, 10.0, 20.0, 40.0, 80.0, 160.0, 320.0]
    };
    progress.expect(rates.len());
    // Eight keys a second apart, turning up to 1.5 rad between keys.
    let keys: Vec<(f64, quat::Quat)> = (0..8)
        .map(|k| {
            let a = k as f64;
            (
                a,
                quat::exp([
                    0.9 * (a * 1.3).sin(),
                    0.7 * (a * 0.7).cos(),
                    1.1 * (a * 0.4).sin(),
                ]),
            )
        })
        .collect();
    let track = RotationTrack::new(&keys, RotationInterpolation::Squad).expect("valid keys");
    let probes: Vec<f64> = (0..7000).map(|i| i as f64 * 0.001 + 0.0003).collect();
    let mut points = Vec::new();
    for &rate in &rates {
        let frames = (7.0 * rate).ceil() as usize + 1;
        let mut c = Cursor::default();
        let baked: Vec<quat::Quat> = (0..frames)
            .map(|f| track.sample((f as f64 / rate).min(7.0), &mut c))
            .collect();
        let mut max_angle: f64 = 0.0;
        // The best of five timed passes (one pass is 7,000 samples, about 0.1 ms).
        let mut secs = f64::INFINITY;
        for _ in 0..5 {
            let t0 = Instant::now();
            let mut sink = 0.0;
            for &t in &probes {
                let f = t * rate;
                let k = (f.floor() as usize).min(frames - 2);
                let q = rotation::nlerp(baked[k], baked[k + 1], f - k as f64);
                sink += q[0];
            }
            secs = secs.min(t0.elapsed().as_secs_f64() / probes.len() as f64);
            std::hint::black_box(sink);
        }
        let mut c = Cursor::default();
        for &t in &probes {
            let f = t * rate;
            let k = (f.floor() as usize).min(frames - 2);
            let q = rotation::nlerp(baked[k], baked[k + 1], f - k as f64);
            let exact = track.sample(t, &mut c);
            let d = rotation::dot4(q, exact).abs().min(1.0);
            max_angle = max_angle.max(2.0 * d.acos());
        }
        points.push(SamplingPoint {
            rate,
            seconds_per_sample: secs,
            bytes: 32 * frames,
            max_angle,
        });
        progress.tick(&format!("{rate} Hz"));
    }
    let curve = |f: &dyn Fn(&SamplingPoint) -> (f64, f64)| {
        vec![(
            0,
            Curve {
                label: "bake + NLERP".into(),
                points: points
                    .iter()
                    .map(f)
                    .filter(|(x, y)| *x > 0.0 && *y > 0.0)
                    .collect(),
                dashed: false,
            },
        )]
    };
    let panels = vec![
        Panel {
            title: "largest angle from the track against rate".into(),
            x_label: "bake rate (frames/s)".into(),
            y_label: "largest angle (rad)".into(),
            scale: Scale::LogLog,
            curves: curve(&|p| (p.rate, p.max_angle)),
        },
        Panel {
            title: "largest angle against memory".into(),
            x_label: "baked keys (bytes)".into(),
            y_label: "largest angle (rad)".into(),
            scale: Scale::LogLog,
            curves: curve(&|p| (p.bytes as f64, p.max_angle)),
        },
    ];
    write_plot_and_numbers(out, "anim-sampling", &panels, 2, (520, 420), &points)?;
    let order = if points.len() >= 2 {
        let (a, b) = (&points[points.len() - 2], &points[points.len() - 1]);
        (a.max_angle / b.max_angle).ln() / (b.rate / a.rate).ln()
    } else {
        f64::NAN
    };
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Clip sampling: bake rate against error\n\nGenerated by `largestep study anim-sampling{}`. Plot: [anim-sampling.svg](anim-sampling.svg) ([PNG](anim-sampling.png)); numbers: [anim-sampling.json](anim-sampling.json).\n\nA rotation track through eight keys a second apart (SQUAD, turns of up to 1.5 rad between keys) is baked at a fixed rate and sampled back at 7,000 times by NLERP between the two frames around each, as `Clip::sample` does; the error is the largest angle between that and the track itself. Observed order between the two finest rates: {order:.2} (second order expected: the chord of a smooth curve). A sample's time does not depend on the rate (the two frames are found by index); the cost of accuracy is memory, the plot's second panel.\n\n| rate (1/s) | time per sample (s, best of 5 passes) | baked keys (bytes) | largest angle (rad) |\n|---|---|---|---|",
        if quick { " --quick" } else { "" },
    );
    for p in &points {
        let _ = writeln!(
            md,
            "| {} | {:.2e} | {} | {:.2e} |",
            p.rate, p.seconds_per_sample, p.bytes, p.max_angle
        );
    }
    write_file(&out.join("anim-sampling.md"), &md)?;
    Ok(format!(
        "anim-sampling: largest angle {:.1e} rad at {} frames/s, order {order:.2}; report: {}",
        points.last().map_or(f64::NAN, |p| p.max_angle),
        points.last().map_or(0.0, |p| p.rate),
        out.join("anim-sampling.md").display()
    ))
}
