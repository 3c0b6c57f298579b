//! Rigid bodies: mass properties against closed forms, free-body invariants per
//! integrator, the Dzhanibekov flip against Euler's equations' elliptic solution, the
//! restitution law, resting stacks, joints, and bad input.

use largestep::io::Mesh;
use largestep::kernels::quat;
use largestep::rigid::{
    mass, BodyDesc, Correction, JointDesc, JointKind, Motion, RigidDesc, RigidIntegrator,
    RigidSolver, Shape,
};
use std::sync::Arc;

mod common;

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-300)
}

fn ground() -> BodyDesc {
    BodyDesc {
        motion: Motion::Static,
        ..BodyDesc::new(
            Shape::Box {
                half: [10.0, 0.5, 10.0],
            },
            [0.0, -0.5, 0.0],
        )
    }
}

#[test]
fn box_mesh_inertia_matches_the_closed_form() {
    let h = [0.3, 0.5, 0.7];
    let m = largestep::shapes::cuboid(h.map(|x| -x + 1.0), h.map(|x| x + 1.0));
    let p = mass::mesh(&m, 700.0).unwrap();
    let b = mass::solid_box(h, 700.0);
    assert!(rel(p.mass, b.mass) < 1e-12);
    for a in 0..3 {
        assert!((p.center[a] - 1.0).abs() < 1e-12);
        for c in 0..3 {
            assert!(
                (p.inertia[a][c] - b.inertia[a][c]).abs() < 1e-12 * b.inertia[0][0],
                "{a}{c}: {} vs {}",
                p.inertia[a][c],
                b.inertia[a][c]
            );
        }
    }
}

#[test]
fn tetrahedron_inertia_matches_the_closed_form() {
    // The unit right tetrahedron (0, e1, e2, e3): volume 1/6, centroid 1/4, and about the
    // centroid I_xx = 1/80 (m = 1/6 at unit density), products 1/480 (Tonon 2004).
    let pts = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let tris = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let m = largestep::shapes::from_triangles(&pts, &tris);
    let p = mass::mesh(&m, 1.0).unwrap();
    assert!(rel(p.mass, 1.0 / 6.0) < 1e-14);
    for a in 0..3 {
        assert!((p.center[a] - 0.25).abs() < 1e-14);
        assert!(
            rel(p.inertia[a][a], 1.0 / 80.0) < 1e-12,
            "{}",
            p.inertia[a][a]
        );
        for c in 0..3 {
            if a != c {
                assert!(
                    rel(p.inertia[a][c], 1.0 / 480.0) < 1e-12,
                    "{}",
                    p.inertia[a][c]
                );
            }
        }
    }
}

#[test]
fn tessellated_sphere_converges_to_the_closed_form() {
    let exact = mass::solid_sphere(0.5, 1000.0);
    let mut last = f64::INFINITY;
    for (rings, sectors) in [(8, 16), (16, 32), (32, 64), (64, 128)] {
        let m = largestep::shapes::uv_sphere([0.0; 3], 0.5, rings, sectors);
        let p = mass::mesh(&m, 1000.0).unwrap();
        let e = rel(p.inertia[0][0], exact.inertia[0][0]);
        // Inscribed polyhedra: the error falls about 4x per halving of the facet size.
        assert!(e < last / 3.0, "{rings}: {e} after {last}");
        last = e;
    }
    assert!(last < 2e-3, "{last}");
}

#[test]
fn tessellated_capsule_matches_the_closed_form() {
    let exact = mass::solid_capsule(0.4, 0.2, 1000.0);
    let m = capsule_mesh(0.4, 0.2, 96);
    let p = mass::mesh(&m, 1000.0).unwrap();
    assert!(rel(p.mass, exact.mass) < 2e-3, "{} {}", p.mass, exact.mass);
    for a in 0..3 {
        assert!(
            rel(p.inertia[a][a], exact.inertia[a][a]) < 4e-3,
            "{a}: {} vs {}",
            p.inertia[a][a],
            exact.inertia[a][a]
        );
    }
}

/// A closed capsule along y: a latitude-longitude sphere split at its equator and
/// stretched apart by 2 hh.
fn capsule_mesh(hh: f64, r: f64, n: usize) -> Mesh {
    let rings = n / 2;
    let mut pts = vec![[0.0, r + hh, 0.0]];
    for i in 1..rings {
        let th = std::f64::consts::PI * i as f64 / rings as f64;
        let y = r * th.cos() + if i <= rings / 2 { hh } else { -hh };
        for j in 0..n {
            let ph = 2.0 * std::f64::consts::PI * j as f64 / n as f64;
            pts.push([r * th.sin() * ph.cos(), y, r * th.sin() * ph.sin()]);
        }
        if i == rings / 2 {
            // The equator twice: the top ring of the lower half.
            for j in 0..n {
                let ph = 2.0 * std::f64::consts::PI * j as f64 / n as f64;
                pts.push([r * ph.cos(), -hh, r * ph.sin()]);
            }
        }
    }
    pts.push([0.0, -r - hh, 0.0]);
    let ring_count = rings; // rings - 1 latitude rings plus the duplicated equator
    let ring = |k: usize, j: usize| (1 + k * n + j % n) as u32;
    let mut tris = Vec::new();
    for j in 0..n {
        tris.push([0, ring(0, j + 1), ring(0, j)]);
    }
    for k in 0..ring_count - 1 {
        for j in 0..n {
            tris.push([ring(k, j), ring(k, j + 1), ring(k + 1, j + 1)]);
            tris.push([ring(k, j), ring(k + 1, j + 1), ring(k + 1, j)]);
        }
    }
    let last = (pts.len() - 1) as u32;
    for j in 0..n {
        tris.push([last, ring(ring_count - 1, j), ring(ring_count - 1, j + 1)]);
    }
    largestep::shapes::from_triangles(&pts, &tris)
}

#[test]
fn open_meshes_and_bad_bodies_are_refused() {
    let pts = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let open = largestep::shapes::from_triangles(&pts, &[[0, 1, 2]]);
    let e = mass::mesh(&open, 1.0).unwrap_err().to_string();
    assert!(e.contains("edge") || e.contains("open"), "{e}");
    let mut d = RigidDesc::default();
    d.bodies
        .push(BodyDesc::new(Shape::Mesh(Arc::new(open)), [0.0; 3]));
    let e = d.build().unwrap_err().to_string();
    assert!(e.starts_with("body 0"), "{e}");
    for bad in [
        BodyDesc {
            density: 0.0,
            ..BodyDesc::new(Shape::Sphere { radius: 1.0 }, [0.0; 3])
        },
        BodyDesc {
            density: -1.0,
            ..BodyDesc::new(Shape::Sphere { radius: 1.0 }, [0.0; 3])
        },
        BodyDesc::new(Shape::Sphere { radius: 0.0 }, [0.0; 3]),
        BodyDesc {
            orientation: [0.0; 4],
            ..BodyDesc::new(Shape::Sphere { radius: 1.0 }, [0.0; 3])
        },
        BodyDesc::new(Shape::Sphere { radius: 1.0 }, [f64::NAN, 0.0, 0.0]),
        BodyDesc::new(
            Shape::Box {
                half: [1.0, f64::INFINITY, 1.0],
            },
            [0.0; 3],
        ),
    ] {
        let d = RigidDesc {
            bodies: vec![ground(), bad],
            ..RigidDesc::default()
        };
        let e = d.build().unwrap_err().to_string();
        assert!(e.starts_with("body 1"), "{e}");
    }
    let d = RigidDesc {
        bodies: vec![
            ground(),
            BodyDesc::new(Shape::Sphere { radius: 1.0 }, [0.0; 3]),
        ],
        joints: vec![JointDesc {
            a: 1,
            b: Some(5),
            kind: JointKind::Ball { anchor: [0.0; 3] },
        }],
        ..RigidDesc::default()
    };
    let e = d.build().unwrap_err().to_string();
    assert!(e.contains("joint 0") && e.contains("body 5"), "{e}");
}

/// A box with three distinct moments, spinning about `axis` (body frame) at `rate`, plus
/// a small perturbation about the other two.
fn spinner(integrator: RigidIntegrator, w: [f64; 3]) -> RigidDesc {
    RigidDesc {
        bodies: vec![BodyDesc {
            angular_velocity: w,
            ..BodyDesc::new(
                Shape::Box {
                    half: [0.1, 0.3, 0.5],
                },
                [0.0; 3],
            )
        }],
        gravity: [0.0; 3],
        integrator,
        ..RigidDesc::default()
    }
}

#[test]
fn torque_free_bodies_keep_angular_momentum_in_the_momentum_methods() {
    let w0 = [0.3, 4.0, 0.2];
    for integrator in [
        RigidIntegrator::ExplicitEuler,
        RigidIntegrator::SymplecticEuler,
        RigidIntegrator::Rk4,
        RigidIntegrator::ImplicitGyroscopic,
    ] {
        let (m, mut s, mut w) = spinner(integrator, w0).build().unwrap();
        let l0 = m.angular_momentum(&s, 0);
        let e0 = m.kinetic_energy(&s);
        for _ in 0..2000 {
            m.step(&mut s, &mut w, 1e-3).unwrap();
        }
        let l1 = m.angular_momentum(&s, 0);
        let dl = ((l1[0] - l0[0]).powi(2) + (l1[1] - l0[1]).powi(2) + (l1[2] - l0[2]).powi(2))
            .sqrt()
            / (l0[0].powi(2) + l0[1].powi(2) + l0[2].powi(2)).sqrt();
        let de = (m.kinetic_energy(&s) - e0) / e0;
        eprintln!("{integrator:?}: |dL|/|L| = {dl:.2e}, dE/E = {de:.2e}");
        match integrator {
            RigidIntegrator::ImplicitGyroscopic => {
                assert!(dl < 0.05, "{dl}");
                // Backward Euler dissipates: energy never grows.
                assert!(de <= 1e-12, "{de}");
            }
            // Exact up to rounding over 8,000 sub-steps.
            _ => assert!(dl < 1e-10, "{integrator:?}: {dl}"),
        }
        if integrator == RigidIntegrator::Rk4 {
            assert!(de.abs() < 1e-6, "{de}");
        }
    }
}

/// K(k) by the arithmetic-geometric mean: `pi / (2 AGM(1, sqrt(1 - k²)))`.
fn elliptic_k(k2: f64) -> f64 {
    let (mut a, mut b) = (1.0f64, (1.0 - k2).sqrt());
    for _ in 0..40 {
        let (na, nb) = ((a + b) / 2.0, (a * b).sqrt());
        a = na;
        b = nb;
    }
    std::f64::consts::PI / (2.0 * a)
}

#[test]
fn dzhanibekov_flip_period_matches_eulers_equations() {
    // Spin about the intermediate axis with a small push about the others. Euler's
    // equations solved by Jacobi's elliptic functions (Landau and Lifshitz, Mechanics,
    // section 37): with I1 < I2 < I3 and L² > 2 E I2, w2 ~ sn(tau) and
    // tau = t sqrt((I3 - I2)(L² - 2 E I1) / (I1 I2 I3)), so w2 changes sign every
    // 2 K(k) in tau, k² = (I2 - I1)(2 E I3 - L²) / ((I3 - I2)(L² - 2 E I1)).
    let w0 = [0.0, 5.0, 0.05];
    let (m, mut s, mut w) = spinner(RigidIntegrator::Rk4, w0).build().unwrap();
    let i = m.principal_inertia(0);
    // The box's principal frame is its own: [I1, I2, I3] along x, y, z for hx<hy<hz.
    let (i3, i2, i1) = (i[0], i[1], i[2]);
    let (w1, w2, w3) = (w0[2], w0[1], w0[0]);
    let e2 = i1 * w1 * w1 + i2 * w2 * w2 + i3 * w3 * w3;
    let l2 = (i1 * w1).powi(2) + (i2 * w2).powi(2) + (i3 * w3).powi(2);
    let (a, b) = if l2 > e2 * i2 { (i1, i3) } else { (i3, i1) };
    let lambda = ((b - i2) * (l2 - e2 * a) / (i1 * i2 * i3)).abs().sqrt();
    let k2 = ((i2 - a) * (e2 * b - l2) / ((b - i2) * (l2 - e2 * a))).abs();
    let half_period = 2.0 * elliptic_k(k2) / lambda;
    // Time the sign changes of the spin about the intermediate axis.
    let dt = 1e-3;
    let mut crossings = Vec::new();
    let mut last = w0[1];
    while s.time < 4.5 * half_period {
        m.step(&mut s, &mut w, dt).unwrap();
        let wb = quat::rotate_inv(s.q[0], s.w[0])[1];
        if wb.signum() != last.signum() {
            // Linear interpolation of the crossing.
            crossings.push(s.time - dt * wb / (wb - last));
        }
        last = wb;
    }
    assert!(crossings.len() >= 4, "{crossings:?}");
    let measured = (crossings[3] - crossings[1]) / 2.0;
    let e = rel(measured, half_period);
    eprintln!("flip: measured {measured:.4} s, theory {half_period:.4} s, error {e:.2e}");
    assert!(e < 1e-3, "{measured} vs {half_period}");
}

fn drop_ball(e: f64, dt: f64) -> Vec<f64> {
    let d = RigidDesc {
        bodies: vec![
            ground(),
            BodyDesc::new(Shape::Sphere { radius: 0.1 }, [0.0, 1.1, 0.0]),
        ],
        restitution: e,
        ..RigidDesc::default()
    };
    let (m, mut s, mut w) = d.build().unwrap();
    let mut apexes = Vec::new();
    let mut last_v = 0.0;
    while s.time < 3.0 {
        m.step(&mut s, &mut w, dt).unwrap();
        let v = s.v[1][1];
        if last_v > 0.0 && v <= 0.0 {
            apexes.push(s.x[1][1] - 0.1);
        }
        last_v = v;
    }
    apexes
}

#[test]
fn bounces_follow_the_restitution_law() {
    for e in [0.9, 0.5] {
        let apexes = drop_ball(e, 1e-3);
        assert!(apexes.len() >= 2, "{apexes:?}");
        // Each bounce keeps e² of the height (drop from 1 m).
        let mut h = 1.0;
        for (k, a) in apexes.iter().take(3).enumerate() {
            let expect = h * e * e;
            eprintln!("e = {e}: bounce {k} reached {a:.4} m, law {expect:.4} m");
            assert!(rel(*a, expect) < 0.03, "bounce {k}: {a} vs {expect}");
            h = *a;
        }
    }
}

fn stack(count: usize, solver: RigidSolver) -> RigidDesc {
    let mut bodies = vec![ground()];
    for k in 0..count {
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
        ..RigidDesc::default()
    }
}

#[test]
fn ten_box_stack_rests() {
    // Soft contacts (30 Hz) settle the stack by their sag, and the sway the first
    // impacts start dies out, within three seconds; from then on the boxes stay put.
    let (m, mut s, mut w) = stack(10, RigidSolver::SequentialImpulses).build().unwrap();
    let x0 = s.x.clone();
    while s.time < 3.0 {
        m.step(&mut s, &mut w, 1.0 / 60.0).unwrap();
    }
    let settled = s.x.clone();
    let sag = x0[10][1] - settled[10][1];
    let mut drift = 0.0f64;
    let mut tilt = 0.0f64;
    while s.time < 10.0 {
        m.step(&mut s, &mut w, 1.0 / 60.0).unwrap();
        for (i, x) in settled.iter().enumerate().skip(1) {
            let d = largestep::kernels::v3::sub(s.x[i], *x);
            drift = drift.max(largestep::kernels::v3::dot(d, d).sqrt());
            tilt = tilt.max(2.0 * s.q[i][0].clamp(-1.0, 1.0).acos());
        }
    }
    eprintln!(
        "ten-box stack: sag {sag:.2e} m while settling, then drift {drift:.2e} m and tilt {tilt:.2e} rad over 7 s"
    );
    assert!(sag > 0.0 && sag < 0.03, "{sag}");
    assert!(drift < 2e-3, "{drift}");
    assert!(tilt < 2e-3, "{tilt}");
}

#[test]
fn penalty_and_one_shot_impulses_hold_a_box_up() {
    for solver in [
        RigidSolver::Impulse,
        RigidSolver::Penalty {
            stiffness: None,
            damping: None,
        },
    ] {
        let (m, mut s, mut w) = stack(1, solver).build().unwrap();
        while s.time < 3.0 {
            m.step(&mut s, &mut w, 1.0 / 240.0).unwrap();
        }
        eprintln!("{solver:?}: y = {}", s.x[1][1]);
        assert!((s.x[1][1] - 0.5).abs() < 0.02, "{solver:?}: {}", s.x[1][1]);
        assert!(s.v[1][1].abs() < 0.05);
    }
}

#[test]
fn pendulum_joint_keeps_its_length() {
    for kind in ["ball", "distance", "hinge"] {
        let anchor = [0.0, 2.0, 0.0];
        let j = match kind {
            "ball" => JointKind::Ball { anchor },
            "hinge" => JointKind::Hinge {
                anchor,
                axis: [0.0, 0.0, 1.0],
            },
            _ => JointKind::Distance {
                anchor_a: [1.0, 2.0, 0.0],
                anchor_b: anchor,
            },
        };
        let mut bob = BodyDesc::new(Shape::Sphere { radius: 0.1 }, [1.0, 2.0, 0.0]);
        if kind != "distance" {
            // A rod: a thin box from the anchor to the bob.
            bob = BodyDesc::new(
                Shape::Box {
                    half: [0.5, 0.05, 0.05],
                },
                [0.5, 2.0, 0.0],
            );
        }
        let d = RigidDesc {
            bodies: vec![bob],
            joints: vec![JointDesc {
                a: 0,
                b: None,
                kind: j,
            }],
            correction: Correction::Split,
            ..RigidDesc::default()
        };
        let (m, mut s, mut w) = d.build().unwrap();
        let e0 = m.kinetic_energy(&s) + m.potential_energy(&s);
        let mut drift = 0.0f64;
        while s.time < 5.0 {
            m.step(&mut s, &mut w, 1.0 / 240.0).unwrap();
            let tip = if kind == "distance" {
                s.x[0]
            } else {
                largestep::kernels::v3::add(s.x[0], quat::rotate(s.q[0], [-0.5, 0.0, 0.0]))
            };
            let want = if kind == "distance" { 1.0 } else { 0.0 };
            let r = ((tip[0] - anchor[0]).powi(2)
                + (tip[1] - anchor[1]).powi(2)
                + (tip[2] - anchor[2]).powi(2))
            .sqrt();
            drift = drift.max((r - want).abs());
        }
        let e1 = m.kinetic_energy(&s) + m.potential_energy(&s);
        eprintln!("{kind}: drift {drift:.2e} m, energy {e0:.3} -> {e1:.3}");
        assert!(drift < 0.01, "{kind}: {drift}");
        assert!(
            e1 <= e0 + 1e-6 * e0.abs().max(1.0),
            "{kind}: energy grew {e0} -> {e1}"
        );
    }
}

mod witkin {
    use super::{elliptic_k, rel};
    use largestep::rigid::witkin::{
        Constraint, Witkin, WitkinError, WitkinIntegrator, WitkinState, WitkinWork,
    };

    fn state(x: Vec<[f64; 3]>) -> WitkinState {
        let n = x.len();
        WitkinState {
            x,
            v: vec![[0.0; 3]; n],
            ..WitkinState::default()
        }
    }

    /// The period of a pendulum of length `l` released at `theta0` (rad):
    /// `4 sqrt(l / g) K(sin²(theta0 / 2))`.
    fn period(l: f64, theta0: f64) -> f64 {
        4.0 * (l / 9.81f64).sqrt() * elliptic_k((theta0 / 2.0).sin().powi(2))
    }

    /// Times of the particle's upward crossings of its lowest point, per swing.
    fn measure_period(w: &Witkin, mut s: WitkinState, dt: f64, until: f64, i: usize) -> (f64, f64) {
        let mut crossings = Vec::new();
        let mut last_vx = s.v[i][0];
        let mut drift = 0.0f64;
        let mut work = WitkinWork::default();
        while s.time < until {
            w.step(&mut s, &mut work, dt).unwrap();
            drift = drift.max(w.drift(&s.x));
            let vx = s.v[i][0];
            // vx changes sign at the turning points: two per period.
            if vx.signum() != last_vx.signum() && last_vx != 0.0 {
                crossings.push(s.time - dt * vx / (vx - last_vx));
            }
            last_vx = vx;
        }
        assert!(crossings.len() >= 5, "{crossings:?}");
        ((crossings[4] - crossings[0]) / 2.0, drift)
    }

    #[test]
    fn bead_on_a_circular_wire_swings_with_the_pendulum_period() {
        // A bead on a vertical circle of radius 1 m released 60 degrees from the bottom.
        let th = 60f64.to_radians();
        let w = Witkin {
            inv_mass: vec![1.0],
            constraints: vec![Constraint::Circle {
                a: 0,
                center: [0.0, 0.0, 0.0],
                normal: [0.0, 0.0, 1.0],
                radius: 1.0,
            }],
            gravity: [0.0, -9.81, 0.0],
            ks: 0.0,
            kd: 0.0,
            integrator: WitkinIntegrator::Rk4,
        };
        let s = state(vec![[th.sin(), -th.cos(), 0.0]]);
        w.validate(&s).unwrap();
        let (t, drift) = measure_period(&w, s, 1e-3, 6.0, 0);
        let e = rel(t, period(1.0, th));
        eprintln!(
            "bead on a wire: period {t:.5} s, theory {:.5} s, error {e:.1e}, drift {drift:.1e} m",
            period(1.0, th)
        );
        assert!(e < 1e-4, "{e}");
        assert!(drift < 1e-6, "{drift}");
    }

    #[test]
    fn drift_grows_without_feedback_and_stays_bounded_with_it() {
        // A pendulum on an anchor, explicit Euler: the rod stretches without feedback.
        let mut worst = Vec::new();
        for (ks, kd) in [(0.0, 0.0), (100.0, 20.0)] {
            let w = Witkin {
                inv_mass: vec![1.0],
                constraints: vec![Constraint::Anchor {
                    a: 0,
                    point: [0.0, 0.0, 0.0],
                    length: 1.0,
                }],
                gravity: [0.0, -9.81, 0.0],
                ks,
                kd,
                integrator: WitkinIntegrator::SymplecticEuler,
            };
            let mut s = state(vec![[1.0, 0.0, 0.0]]);
            let mut drift = 0.0f64;
            let mut work = WitkinWork::default();
            while s.time < 10.0 {
                w.step(&mut s, &mut work, 1e-3).unwrap();
                drift = drift.max(w.drift(&s.x));
            }
            eprintln!("pendulum, feedback ks = {ks}, kd = {kd}: drift {drift:.2e} m");
            worst.push(drift);
        }
        assert!(worst[1] < 0.2 * worst[0], "{worst:?}");
        assert!(worst[1] < 2e-3, "{worst:?}");
    }

    #[test]
    fn double_pendulum_keeps_energy_and_constraints() {
        let w = Witkin {
            inv_mass: vec![1.0, 1.0],
            constraints: vec![
                Constraint::Anchor {
                    a: 0,
                    point: [0.0, 0.0, 0.0],
                    length: 1.0,
                },
                Constraint::Distance {
                    a: 0,
                    b: 1,
                    length: 1.0,
                },
            ],
            gravity: [0.0, -9.81, 0.0],
            ks: 0.0,
            kd: 0.0,
            integrator: WitkinIntegrator::Rk4,
        };
        let mut s = state(vec![[1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]);
        let e0 = w.kinetic_energy(&s) + w.potential_energy(&s);
        let mut drift = 0.0f64;
        let mut work = WitkinWork::default();
        while s.time < 10.0 {
            w.step(&mut s, &mut work, 5e-4).unwrap();
            drift = drift.max(w.drift(&s.x));
        }
        let e1 = w.kinetic_energy(&s) + w.potential_energy(&s);
        // Energy scale: the drop from horizontal to hanging, 3 m g.
        let de = (e1 - e0).abs() / (3.0 * 9.81);
        eprintln!(
            "double pendulum over 10 s: energy change {de:.1e} of m g h, drift {drift:.1e} m"
        );
        assert!(de < 1e-3, "{de}");
        assert!(drift < 1e-4, "{drift}");
    }

    #[test]
    fn redundant_constraints_and_bad_indices_are_reported() {
        let anchor = Constraint::Anchor {
            a: 0,
            point: [0.0; 3],
            length: 1.0,
        };
        let w = Witkin {
            inv_mass: vec![1.0],
            constraints: vec![anchor, anchor],
            gravity: [0.0, -9.81, 0.0],
            ks: 0.0,
            kd: 0.0,
            integrator: WitkinIntegrator::Rk4,
        };
        let mut s = state(vec![[1.0, 0.0, 0.0]]);
        assert_eq!(
            w.step(&mut s, &mut WitkinWork::default(), 1e-3),
            Err(WitkinError::Singular { step: 1 })
        );
        let w = Witkin {
            constraints: vec![Constraint::Distance {
                a: 0,
                b: 3,
                length: 1.0,
            }],
            ..w
        };
        let e = w
            .validate(&state(vec![[1.0, 0.0, 0.0]]))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("constraint 0") && e.contains("particle 3"),
            "{e}"
        );
    }
}

mod scenes {
    use largestep::scene::{Runner, Scene};
    use std::path::Path;

    fn scene(name: &str) -> Scene {
        Scene::load(
            &Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("scenes")
                .join(name),
        )
        .unwrap()
    }

    #[test]
    fn rigid_scenes_write_bodies_csv_each_frame() {
        let out = std::env::temp_dir().join(format!("largestep-rigid-{}", std::process::id()));
        let mut runner = Runner::new(scene("rigid-dominoes.toml"), &out);
        let summary = runner.run(Some(5), &mut |_| {}).unwrap();
        let text = std::fs::read_to_string(out.join("bodies.csv")).unwrap();
        let mut lines = text.lines();
        assert_eq!(
            lines.next(),
            Some("frame,time,body,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz")
        );
        let rows: Vec<Vec<f64>> = lines
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect();
        // 21 bodies (the slab, the pushed domino and nineteen more), frames 0 to 5.
        assert_eq!(rows.len(), 21 * 6);
        assert!(rows
            .iter()
            .all(|r| r.len() == 16 && r.iter().all(|v| v.is_finite())));
        // Unit quaternions, and frame 0 is where the scene put the first domino.
        for r in &rows {
            let n = (r[6] * r[6] + r[7] * r[7] + r[8] * r[8] + r[9] * r[9]).sqrt();
            assert!((n - 1.0).abs() < 1e-9);
        }
        let first = &rows[1];
        assert_eq!((first[0], first[2]), (0.0, 1.0));
        assert!((first[3] + 1.0).abs() < 1e-12 && (first[4] - 0.2).abs() < 1e-12);
        assert!((first[15] + 3.0).abs() < 1e-12, "the push: w_z = -3 rad/s");
        assert_eq!(summary.frames_written, 6);
        std::fs::remove_dir_all(&out).ok();
    }

    #[test]
    fn scenes_leave_out_what_they_do_not_need() {
        let sim = scene("rigid-t-handle.toml").into_simulation().unwrap();
        let stages = sim.stages();
        let collide = stages
            .iter()
            .find(|s| s.name == "collision structures")
            .unwrap();
        assert!(!collide.built, "one body needs no collision structures");
        let joints = stages.iter().find(|s| s.name == "joints").unwrap();
        assert!(!joints.built);
        let sim = scene("rigid-cradle.toml").into_simulation().unwrap();
        assert!(sim.stages().iter().any(|s| s.name == "joints" && s.built));
    }

    #[test]
    fn bad_rigid_scenes_name_the_line() {
        let base = "[scene]\ndt = 0.01\nduration = 1.0\n";
        for (body, needle) in [
            ("[[rigid.body]]\nshape = { box = [1.0, -1.0, 1.0] }\n", "half extent"),
            ("[[rigid.body]]\nshape = { sphere = 1.0, box = [1.0, 1.0, 1.0] }\n", "a shape is one of"),
            ("[[rigid.body]]\nshape = { sphere = 1.0 }\norientation = [0.0, 0.0, 0.0, 0.0]\n", "zero"),
            ("[[rigid.body]]\nshape = { sphere = 1.0 }\ndensity = -3.0\n", "density"),
            ("[[rigid.body]]\nshape = { mesh = \"missing.obj\" }\n", "missing.obj"),
            ("[[rigid.body]]\nshape = { sphere = 1.0 }\n[[rigid.joint]]\ntype = \"ball\"\na = 0\nb = 4\nanchor = [0.0, 0.0, 0.0]\n", "body 4 does not exist"),
            ("[rigid]\nsolver = \"magic\"\n[[rigid.body]]\nshape = { sphere = 1.0 }\n", "unknown solver"),
            ("[[rigid.body]]\nshape = { sphere = 1.0 }\nposition = [nan, 0.0, 0.0]\n", "finite"),
            ("[[rigid.array]]\nshape = { sphere = 1.0 }\ncount = [100000, 100000, 1000]\nspacing = [1.0, 1.0, 1.0]\n", "memory budget"),
            ("[[rigid.particle]]\nposition = [0.0, 0.0, 0.0]\n[[rigid.constraint]]\ntype = \"anchor\"\na = 2\npoint = [0.0, 1.0, 0.0]\n", "particle 2 does not exist"),
            ("[rigid]\nsleeping = true\n[[rigid.particle]]\nposition = [0.0, 0.0, 0.0]\n", "sleeping applies to rigid bodies"),
            ("[rigid]\nsleeping = 3\n[[rigid.body]]\nshape = { sphere = 1.0 }\n", "sleeping"),
            ("[rigid]\ncontact_reuse = 2.0\n[[rigid.body]]\nshape = { sphere = 1.0 }\n", "contact_reuse must be in 0..=1"),
            ("[rigid]\ncontact_reuse = -0.1\n[[rigid.body]]\nshape = { sphere = 1.0 }\n", "contact_reuse must be in 0..=1"),
            ("[rigid]\ncontact_reuse = 0.1\n[[rigid.particle]]\nposition = [0.0, 0.0, 0.0]\n", "contact_reuse applies to rigid bodies"),
        ] {
            let text = format!("{base}{body}");
            let e = Scene::parse(&text, "bad.toml").unwrap_err();
            assert!(e.line > 0, "{e}");
            assert!(e.to_string().contains(needle), "{needle}: {e}");
        }
        // A non-unit orientation is normalised with a warning.
        let text = format!("{base}[[rigid.body]]\nshape = {{ sphere = 1.0 }}\norientation = [2.0, 0.0, 0.0, 0.0]\n");
        let sim = Scene::parse(&text, "ok.toml")
            .unwrap()
            .into_simulation()
            .unwrap();
        assert!(sim.warnings().iter().any(|w| w.contains("normalised")));
        // `sleeping = true` gives the bodies Box2D's sleep thresholds.
        let text =
            format!("{base}[rigid]\nsleeping = true\n[[rigid.body]]\nshape = {{ sphere = 1.0 }}\n");
        let sim = Scene::parse(&text, "ok.toml")
            .unwrap()
            .into_simulation()
            .unwrap();
        let rigid: &largestep::rigid::scene::RigidSim = sim.downcast_ref().unwrap();
        assert_eq!(
            rigid.model().desc().sleep,
            Some(largestep::rigid::sleep::Sleep::default())
        );
        assert_eq!(rigid.model().desc().contact_reuse, 0.005, "the default");
        // `contact_reuse` reaches the description.
        let text = format!(
            "{base}[rigid]\ncontact_reuse = 0.1\n[[rigid.body]]\nshape = {{ sphere = 1.0 }}\n"
        );
        let sim = Scene::parse(&text, "ok.toml")
            .unwrap()
            .into_simulation()
            .unwrap();
        let rigid: &largestep::rigid::scene::RigidSim = sim.downcast_ref().unwrap();
        assert_eq!(rigid.model().desc().contact_reuse, 0.1);
    }
}

#[test]
fn quaternions_round_trip_through_matrices() {
    // Rotations from every quadrant, including half turns (w = 0) where Shepperd's
    // method switches branches.
    let mut s = 0x1234_5678_9ABC_DEF1u64;
    let mut rnd = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let mut cases: Vec<[f64; 4]> = (0..200).map(|_| [rnd(), rnd(), rnd(), rnd()]).collect();
    cases.extend([
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]);
    for q in cases {
        let q = quat::normalize(q).unwrap();
        let back = quat::from_matrix(quat::to_matrix(q));
        // q and -q are the same rotation.
        let same = (0..4).all(|k| (back[k] - q[k]).abs() < 1e-12)
            || (0..4).all(|k| (back[k] + q[k]).abs() < 1e-12);
        assert!(same, "{q:?} -> {back:?}");
        let v = [0.3, -1.2, 0.7];
        let r = quat::to_matrix(q);
        let mv = [0, 1, 2].map(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2]);
        let qv = quat::rotate(q, v);
        assert!((0..3).all(|k| (mv[k] - qv[k]).abs() < 1e-12));
    }
}

mod contact_sets {
    use largestep::kernels::collide::manifold::{box_box, BoxPose};
    use largestep::kernels::collide::narrow::gjk_epa;
    use largestep::kernels::quat;
    use largestep::rigid::{BodyDesc, RigidDesc, Shape};
    use proptest::prelude::*;
    use std::collections::BTreeSet;

    fn shape(kind: u8, size: f64) -> Shape {
        match kind % 3 {
            0 => Shape::Box {
                half: [size, 0.7 * size, 1.3 * size],
            },
            1 => Shape::Sphere { radius: size },
            _ => Shape::Capsule {
                half_height: size,
                radius: 0.5 * size,
            },
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        /// The broad phase loses nothing: the pairs with an overlapping contact point
        /// are exactly the pairs whose own manifold, computed for every pair of bodies
        /// alone, overlaps.
        #[test]
        fn broad_phase_finds_every_overlapping_pair(
            bodies in prop::collection::vec(
                (0u8..3, 0.1f64..0.5, prop::array::uniform3(-1.5f64..1.5), prop::array::uniform3(-3.2f64..3.2)),
                2..24,
            )
        ) {
            let desc = |list: &[(u8, f64, [f64; 3], [f64; 3])]| RigidDesc {
                bodies: list
                    .iter()
                    .map(|&(k, s, p, r)| BodyDesc {
                        orientation: quat::exp(r),
                        ..BodyDesc::new(shape(k, s), p)
                    })
                    .collect(),
                gravity: [0.0; 3],
                ..RigidDesc::default()
            };
            let overlapping = |list: &[(u8, f64, [f64; 3], [f64; 3])]| -> BTreeSet<(usize, usize)> {
                let (m, s, mut w) = desc(list).build().unwrap();
                m.find_contacts(&s, &mut w, 1e-6).unwrap();
                w.contacts()
                    .iter()
                    .filter(|c| c.depth > 1e-9)
                    .map(|c| (c.a as usize, c.b as usize))
                    .collect()
            };
            let all = overlapping(&bodies);
            let mut brute = BTreeSet::new();
            for i in 0..bodies.len() {
                for j in i + 1..bodies.len() {
                    if !overlapping(&[bodies[i], bodies[j]]).is_empty() {
                        brute.insert((i, j));
                    }
                }
            }
            prop_assert_eq!(all, brute);
        }

        /// Box-box manifolds agree with GJK/EPA: they overlap when GJK says so (beyond a
        /// sliver), their normal is EPA's within a few degrees for clear face contacts,
        /// and every point lies within its depth of both boxes.
        #[test]
        fn box_manifolds_agree_with_gjk(
            ha in prop::array::uniform3(0.1f64..0.6),
            hb in prop::array::uniform3(0.1f64..0.6),
            cb in prop::array::uniform3(-0.9f64..0.9),
            ra in prop::array::uniform3(-3.2f64..3.2),
            rb in prop::array::uniform3(-3.2f64..3.2),
        ) {
            let pose = |c: [f64; 3], r: [f64; 3], h: [f64; 3]| {
                let q = quat::exp(r);
                BoxPose {
                    center: c,
                    axes: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]].map(|e| quat::rotate(q, e)),
                    half: h,
                }
            };
            let a = pose([0.0; 3], ra, ha);
            let b = pose(cb, rb, hb);
            let epa = gjk_epa(&a.convex(), &b.convex()).unwrap();
            let m = box_box(&a, &b, 0.0);
            if epa.depth > 1e-6 {
                let m = m.expect("overlapping boxes give a manifold");
                prop_assert!(m.count >= 1);
                let deepest = m.points().iter().fold(f64::MIN, |d, p| d.max(p.depth));
                // SAT's least overlap is EPA's penetration depth (both the minimum over
                // directions); a face axis is preferred over an edge axis that overlaps
                // less by up to 5% plus 1% of the largest half extent.
                prop_assert!(deepest <= epa.depth / 0.95 + 0.011 + 1e-9, "{deepest} vs {}", epa.depth);
                for p in m.points() {
                    // Within depth (plus rounding) of both boxes: a box's distance is
                    // at most how far the point is outside it.
                    for bx in [&a, &b] {
                        let r = largestep::kernels::v3::sub(p.point, bx.center);
                        let out = (0..3)
                            .map(|k| (largestep::kernels::v3::dot(r, bx.axes[k]).abs() - bx.half[k]).max(0.0))
                            .fold(0.0f64, |s, d| s + d * d)
                            .sqrt();
                        prop_assert!(out <= p.depth.abs() + 1e-9, "point {:?} is {out} outside a box, depth {}", p.point, p.depth);
                    }
                }
            } else if epa.depth < -1e-6 {
                prop_assert!(m.is_none(), "apart by {} yet a manifold", -epa.depth);
            }
        }
    }
}

#[test]
fn extreme_mass_ratios_and_large_steps_stay_bounded() {
    // A heavy box on a light one. Soft contacts scale their stiffness with the effective
    // mass of the row (the light box against the static ground), so a heavy load sags
    // into the light box: at a ratio of 100 and dt = 1/60 s it holds, with sag; at large
    // steps or larger ratios the light box is crushed aside or into the ground (a known
    // limit, stated in docs/architecture.md). Either way nothing blows up.
    for (ratio, dt, holds) in [
        (100.0, 1.0 / 60.0, true),
        (100.0, 0.1, false),
        (1e4, 1.0 / 60.0, false),
        (1e4, 0.1, false),
    ] {
        let mut d = stack(2, RigidSolver::SequentialImpulses);
        d.bodies[1].density = 10.0;
        d.bodies[2].density = 10.0 * ratio;
        let (m, mut s, mut w) = d.build().unwrap();
        let mut fastest = 0.0f64;
        while s.time < 5.0 {
            m.step(&mut s, &mut w, dt).unwrap();
            fastest = s.v.iter().flatten().fold(fastest, |f, c| f.max(c.abs()));
        }
        eprintln!(
            "mass ratio {ratio:e} at dt = {dt:.3}: the heavy box ends at y = {:.3} (1.5 on top, 0.5 crushed), the light one at {:.3}, fastest speed {fastest:.2} m/s",
            s.x[2][1],
            s.x[1][1]
        );
        // Nothing faster than a fall from the stack's height (sqrt(2 g 1.5) = 5.4 m/s).
        assert!(fastest < 6.0, "ratio {ratio}, dt {dt}: {fastest} m/s");
        if holds {
            assert!(s.x[2][1] > 1.4, "ratio {ratio}, dt {dt}: {}", s.x[2][1]);
            assert!(s.x[1][1] > 0.4, "ratio {ratio}, dt {dt}: {}", s.x[1][1]);
        }
    }
}

#[test]
fn a_kinematic_paddle_pushes_a_box() {
    let paddle = BodyDesc {
        motion: Motion::Kinematic,
        velocity: [1.0, 0.0, 0.0],
        ..BodyDesc::new(
            Shape::Box {
                half: [0.1, 0.5, 1.0],
            },
            [-1.0, 0.5, 0.0],
        )
    };
    let d = RigidDesc {
        bodies: vec![
            ground(),
            paddle,
            BodyDesc::new(
                Shape::Box {
                    half: [0.25, 0.25, 0.25],
                },
                [0.0, 0.25, 0.0],
            ),
        ],
        ..RigidDesc::default()
    };
    let (m, mut s, mut w) = d.build().unwrap();
    while s.time < 2.0 {
        m.step(&mut s, &mut w, 1.0 / 60.0).unwrap();
    }
    // The paddle kept its speed (nothing pushes it back); the box is ahead of it.
    assert!((s.x[1][0] - (-1.0 + s.time)).abs() < 1e-9, "{}", s.x[1][0]);
    assert!((s.v[1][0] - 1.0).abs() < 1e-12);
    assert!(
        s.x[2][0] > s.x[1][0] + 0.3,
        "box at {}, paddle at {}",
        s.x[2][0],
        s.x[1][0]
    );
    // Static bodies never move.
    assert_eq!(s.x[0], [0.0, -0.5, 0.0]);
}

/// Runs `scenes/<name>` for `frames` frames with the frames kept: the runner, its
/// summary and the output folder (for the caller to remove).
#[cfg(any(feature = "cloth", feature = "mass-spring", feature = "fem"))]
fn run_kept(
    name: &str,
    frames: usize,
) -> (
    largestep::scene::Runner,
    largestep::scene::Summary,
    std::path::PathBuf,
) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name);
    let scene = largestep::scene::Scene::load(&path).unwrap();
    let out = std::env::temp_dir().join(format!("largestep-{name}-{}", std::process::id()));
    let mut runner = largestep::scene::Runner::new(scene, &out);
    runner.keep_frames(true);
    let summary = runner.run(Some(frames), &mut |_| {}).unwrap();
    (runner, summary, out)
}

/// One-way coupling into the FEM: the ball of `rigid-fem.toml` rising under a rubber mat
/// lifts it (the mat's top above the ball's starting height by most of the rise), and
/// no vertex of the mat enters the ball (its vertex contacts hold them outside the body
/// where it is at the end of the step).
#[cfg(feature = "fem")]
#[test]
fn a_rising_ball_lifts_the_fem_mat_and_no_vertex_enters_it() {
    let (runner, _, out) = run_kept("rigid-fem.toml", 36);
    // The mat: 12 x 1 x 12 cubes, 13 x 2 x 13 vertices, first in the frame.
    let mat = 13 * 2 * 13;
    let (mut deepest, mut top, mut frames) = (0.0f64, f64::NEG_INFINITY, 0);
    for (frame, record) in runner.kept_frames().iter().zip(runner.records()) {
        let n = frame.positions.len() / 3;
        assert!(n > mat);
        // The ball: radius 0.35 m, centre rising from -0.37 m at 0.25 m/s.
        let cy = -0.37 + 0.25 * record.time;
        for i in 0..mat {
            let p = [
                frame.positions[i],
                frame.positions[n + i] - cy,
                frame.positions[2 * n + i],
            ];
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            deepest = deepest.max(0.35 - r);
            top = top.max(frame.positions[n + i]);
        }
        frames += 1;
    }
    eprintln!("rising ball: deepest mat vertex inside {deepest:.2e} m, highest mat point {top:.3} m over {frames} frames");
    assert!(frames >= 36);
    assert!(deepest < 1e-4, "{deepest}");
    // After 36 frames of 4 steps (2.4 s) the ball's top is at 0.58 m: the mat was lifted.
    assert!(top > 0.55, "{top}");
    std::fs::remove_dir_all(&out).ok();
}

/// One-way coupling: rigid bodies as moving obstacles of the cloth.
#[cfg(feature = "cloth")]
mod coupling {
    use largestep::scene::{Runner, Scene};
    use std::path::Path;

    /// How far the sheet of `rigid-cloth.toml` gets into its rising box over the kept
    /// frames: its deepest vertex, the deepest point of its triangles (sampled on a
    /// barycentric grid, 45 points each), and the sheet's highest point (m).
    fn sheet_in_the_box(runner: &Runner) -> (f64, f64, f64) {
        let cloth = 30 * 30;
        let (mut deepest, mut through) = (0.0f64, 0.0f64);
        let mut top = f64::NEG_INFINITY;
        for (frame, record) in runner.kept_frames().iter().zip(runner.records()) {
            let n = frame.positions.len() / 3;
            // The box: half 0.3, centre rising from -0.32 at 0.25 m/s.
            let cy = -0.32 + 0.25 * record.time;
            // How far p is inside the box (negative outside).
            let depth = |p: [f64; 3]| {
                let q = [p[0].abs() - 0.3, (p[1] - cy).abs() - 0.3, p[2].abs() - 0.3];
                -q.iter().fold(f64::NEG_INFINITY, |m, &c| m.max(c))
            };
            let at = |i: usize| {
                [
                    frame.positions[i],
                    frame.positions[n + i],
                    frame.positions[2 * n + i],
                ]
            };
            for i in 0..cloth {
                deepest = deepest.max(depth(at(i)));
                top = top.max(at(i)[1]);
            }
            let sheet = frame
                .triangles
                .iter()
                .filter(|t| t.iter().all(|&i| i < 900));
            for t in sheet {
                let [a, b, c] = t.map(|i| at(i as usize));
                for j in 0..=8 {
                    for k in 0..=8 - j {
                        let (u, w) = (f64::from(j) / 8.0, f64::from(k) / 8.0);
                        let p =
                            std::array::from_fn(|d| a[d] + u * (b[d] - a[d]) + w * (c[d] - a[d]));
                        through = through.max(depth(p));
                    }
                }
            }
        }
        (deepest, through, top)
    }

    /// The box's edges stay under the sheet too: no point of a cloth triangle is inside
    /// the box. With vertex contacts alone the top edges came through the triangles
    /// draped over them by up to 3.6 cm (the sheet's triangles are 4.7 cm wide): the
    /// deepest point of a triangle was 2.0 cm inside.
    #[test]
    fn a_rising_box_lifts_the_cloth_and_no_vertex_or_edge_enters_it() {
        let (runner, _, out) = super::run_kept("rigid-cloth.toml", 40);
        // `--explain` says who meets whom.
        let text = runner.explain();
        assert!(
            text.contains("coupling: [cloth] meets [rigid]'s 1 body as moving obstacles"),
            "{text}"
        );
        let (deepest, through, top) = sheet_in_the_box(&runner);
        eprintln!("rising box: deepest cloth vertex inside {deepest:.2e} m, deepest point of a triangle {through:.2e} m, highest cloth point {top:.3} m");
        // The contacts hold vertices at their thickness outside the box where it is at
        // the end of the step.
        assert!(deepest < 1e-4, "{deepest}");
        assert!(through < 1e-3, "{through}");
        // After 40 frames of 4 steps (2.7 s) the box top is at 0.65 m: the cloth was lifted.
        assert!(top > 0.6, "{top}");
        std::fs::remove_dir_all(&out).ok();
    }

    /// The same with the box given as a mesh (a convex hull): hull bodies are moving
    /// obstacles too, their distances by GJK and EPA, their sharp edges (the hull's
    /// edges between faces meeting at more than 20 degrees) kept under the sheet.
    #[test]
    fn a_rising_mesh_body_lifts_the_cloth_and_no_vertex_or_edge_enters_it() {
        let dir =
            std::env::temp_dir().join(format!("largestep-hull-coupling-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cube = largestep::shapes::cuboid([-0.3; 3], [0.3; 3]);
        let mut obj = Vec::new();
        largestep::io::write_obj(&mut obj, cube.as_ref(), "a 0.6 m cube").unwrap();
        std::fs::write(dir.join("cube.obj"), obj).unwrap();
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/rigid-cloth.toml");
        let text = std::fs::read_to_string(path).unwrap().replace(
            "shape = { box = [0.3, 0.3, 0.3] }",
            "shape = { mesh = \"cube.obj\" }",
        );
        assert!(text.contains("cube.obj"));
        let scene = Scene::parse(&text, dir.join("scene.toml").to_str().unwrap()).unwrap();
        let out = dir.join("out");
        let mut runner = Runner::new(scene, &out);
        runner.keep_frames(true);
        runner.run(Some(40), &mut |_| {}).unwrap();
        let (deepest, through, top) = sheet_in_the_box(&runner);
        eprintln!("rising mesh cube: deepest cloth vertex inside {deepest:.2e} m, deepest point of a triangle {through:.2e} m, highest cloth point {top:.3} m");
        assert!(deepest < 1e-4, "{deepest}");
        assert!(through < 1e-3, "{through}");
        assert!(top > 0.6, "{top}");
        std::fs::remove_dir_all(&dir).ok();
    }
}

/// A hull obstacle's signed distance is the oriented box's for a cube's corners, inside
/// and out.
#[test]
fn a_hull_obstacle_measures_distances_as_the_box_it_spans() {
    use largestep::collide::Obstacle;
    use largestep::kernels::quat;
    let q = quat::exp([0.3, -0.7, 0.4]);
    let r = quat::to_matrix(q);
    let axes = [0, 1, 2].map(|k| [r[0][k], r[1][k], r[2][k]]);
    let (center, half) = ([0.2, 1.0, -0.4], [0.3, 0.2, 0.5]);
    let corners: std::sync::Arc<[[f64; 3]]> = (0..8)
        .map(|c| [0, 1, 2].map(|a| if c >> a & 1 == 1 { half[a] } else { -half[a] }))
        .collect();
    let hull = Obstacle::Hull {
        points: corners,
        edges: std::sync::Arc::from([]),
        center,
        axes,
    };
    hull.validate(0).unwrap();
    let boxed = Obstacle::Oriented { center, axes, half };
    let mut seed = 7u64;
    let mut rnd = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    for _ in 0..2000 {
        let p = [
            center[0] + 1.6 * rnd(),
            center[1] + 1.6 * rnd(),
            center[2] + 1.6 * rnd(),
        ];
        let (dh, nh) = hull.distance(p).unwrap();
        let (db, nb) = boxed.distance(p).unwrap();
        assert!((dh - db).abs() < 1e-9, "at {p:?}: hull {dh}, box {db}");
        // Normals agree away from ties between faces (inside, near the medial axis).
        let n2: f64 = nh.iter().map(|c| c * c).sum();
        assert!((n2 - 1.0).abs() < 1e-9);
        if db > 1e-6 {
            assert!(
                nh.iter().zip(nb).all(|(a, b)| (a - b).abs() < 1e-6),
                "{nh:?} vs {nb:?}"
            );
        }
    }
    // Bad input: named.
    let bad = Obstacle::Hull {
        points: vec![[f64::NAN; 3]].into(),
        edges: std::sync::Arc::from([]),
        center,
        axes,
    };
    assert!(bad.validate(3).unwrap_err().to_string().contains("points"));
}

#[test]
fn too_many_overlapping_pairs_are_refused_before_allocating() {
    // Twenty spheres at one point: 190 pairs, over a limit of 50. The sweep stops
    // collecting at the limit (the fuzz test holds the memory to its budget).
    let d = RigidDesc {
        bodies: (0..20)
            .map(|_| BodyDesc::new(Shape::Sphere { radius: 1.0 }, [0.0; 3]))
            .collect(),
        max_pairs: 50,
        ..RigidDesc::default()
    };
    let (m, mut s, mut w) = d.build().unwrap();
    let e = m.step(&mut s, &mut w, 0.01).unwrap_err().to_string();
    assert!(e.contains("more than 50 body pairs overlap"), "{e}");
}

/// A mesh body (a convex hull) dropped flat onto a slab comes to rest on its face: the
/// hull-box manifold holds the face's corners, where one point made it rock.
#[test]
fn a_hull_dropped_flat_comes_to_rest_on_its_face() {
    use largestep::rigid::scene::RigidSim;
    use largestep::scene::Scene;
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/hull-rest.toml");
    // The T-handle (flat in its x-y plane, 0.1 m thick) turned to lie in the x-z plane.
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let text = format!(
        "[scene]\nname = \"hull-rest\"\ndt = 0.016666666666666666\nduration = 3.0\n\n\
         [[rigid.body]]\nshape = {{ box = [3.0, 0.5, 3.0] }}\nposition = [0.0, -0.5, 0.0]\nstatic = true\n\n\
         [[rigid.body]]\nshape = {{ mesh = \"t-handle.obj\" }}\nposition = [0.0, 0.1, 0.0]\norientation = [{s}, -{s}, 0.0, 0.0]\n"
    );
    let mut scene = Scene::parse(&text, file.to_str().unwrap()).unwrap();
    let dt = scene.dt;
    let sim = &mut scene.systems[0].sim;
    for _ in 0..180 {
        sim.step(dt).unwrap();
    }
    let st = sim.downcast_ref::<RigidSim>().unwrap().state();
    let (v, w) = (st.v[1], st.w[1]);
    let speed = v.iter().map(|c| c * c).sum::<f64>().sqrt();
    let spin = w.iter().map(|c| c * c).sum::<f64>().sqrt();
    assert!(
        speed < 1e-3 && spin < 1e-3,
        "still moving: v {v:?}, w {w:?}"
    );
    // Lying on its 0.1 m thick face: the centre of mass 0.05 m above the slab.
    assert!((st.x[1][1] - 0.05).abs() < 2e-3, "centre at {:?}", st.x[1]);
}

/// One-way coupling into penalty contacts: the spinning paddle of `rigid-jello` knocks
/// the mass-spring cube across the floor through the cube's own collision springs.
#[cfg(feature = "mass-spring")]
mod jello_coupling {
    use largestep::scene::{Runner, Scene};
    use std::path::Path;

    #[test]
    fn a_spinning_paddle_knocks_the_jello_away_through_its_collision_springs() {
        // 2 s: the paddle reaches the cube after about a quarter turn (1 s).
        let (runner, summary, out) = super::run_kept("rigid-jello.toml", 100);
        let frames = runner.kept_frames();
        // The cube's particles: x >= 0.25 at the start (the paddle's corners are at
        // |x| = 0.04).
        let n0 = frames[0].positions.len() / 3;
        let cube: Vec<usize> = (0..n0).filter(|&i| frames[0].positions[i] > 0.2).collect();
        assert_eq!(cube.len(), 512);
        let centroid = |frame: &largestep::io::Mesh| {
            let n = frame.positions.len() / 3;
            [0, 1, 2].map(|c| {
                cube.iter()
                    .map(|&i| frame.positions[c * n + i])
                    .sum::<f64>()
                    / 512.0
            })
        };
        let mut deepest = 0.0f64;
        for (frame, record) in frames.iter().zip(runner.records()) {
            let n = frame.positions.len() / 3;
            // The paddle: half extents (0.04, 0.15, 0.7) about (0, 0.16, 0), turned by
            // 1.5 t about +y.
            let (s, c) = (1.5 * record.time).sin_cos();
            for &i in &cube {
                let p = [
                    frame.positions[i],
                    frame.positions[n + i] - 0.16,
                    frame.positions[2 * n + i],
                ];
                let local = [c * p[0] - s * p[2], p[1], s * p[0] + c * p[2]];
                let q = [
                    local[0].abs() - 0.04,
                    local[1].abs() - 0.15,
                    local[2].abs() - 0.7,
                ];
                if q.iter().all(|&d| d < 0.0) {
                    deepest = deepest.max(-q.iter().fold(f64::NEG_INFINITY, |m, &d| m.max(d)));
                }
            }
        }
        let (start, end) = (centroid(&frames[0]), centroid(frames.last().unwrap()));
        let moved = ((end[0] - start[0]).powi(2) + (end[2] - start[2]).powi(2)).sqrt();
        eprintln!(
            "paddle: cube moved {moved:.3} m, deepest particle inside the paddle {deepest:.2e} m, work {:.3} J, drift {:+.2e}",
            summary.external_work, summary.energy_drift
        );
        // Knocked well clear of where it stood (it is 0.5 m wide), and no particle ever
        // half-way through the 8 cm paddle. Penalty contacts give way by about v
        // sqrt(M / K): the 1 kg cube at 0.75 m/s on a face of 64 springs of 400 N/m is
        // 5 mm, and 1 cm was measured where the paddle's edge meets fewer particles.
        assert!(moved > 1.0, "{moved}");
        assert!(deepest < 0.02, "{deepest}");
        // The paddle's work is counted: what the cube gained less that work is what
        // damping took, a loss.
        assert!(summary.external_work > 0.1, "{}", summary.external_work);
        assert!(summary.energy_drift < 0.005, "{}", summary.energy_drift);
        assert!(summary.warnings.is_empty(), "{:?}", summary.warnings);
        std::fs::remove_dir_all(&out).ok();
    }

    /// A mass-spring model without collisions of its own cannot meet the bodies: the run
    /// says so instead of letting them pass through in silence.
    #[test]
    fn a_jello_without_collisions_is_warned_that_it_does_not_meet_the_bodies() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/rigid-jello.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        let start = text.find("[mass_spring.collisions]").unwrap();
        let end = start + text[start..].find("\n\n").unwrap();
        let text = format!("{}{}", &text[..start], &text[end..]);
        let scene = Scene::parse(&text, "no-collisions.toml").unwrap();
        let out = std::env::temp_dir().join(format!("largestep-jello-deaf-{}", std::process::id()));
        let mut runner = Runner::new(scene, &out);
        let summary = runner.run(Some(1), &mut |_| {}).unwrap();
        assert!(
            summary
                .warnings
                .iter()
                .any(|w| w.contains("[mass_spring] does not meet")),
            "{:?}",
            summary.warnings
        );
        std::fs::remove_dir_all(&out).ok();
    }
}

/// Sleeping: a stack at rest falls asleep as one island and then stays exactly where it
/// is; a ball dropped on it wakes the whole stack (not only the box it hits), which then
/// moves, and everything falls asleep again once it has settled. Without sleeping nothing
/// ever sleeps.
#[test]
fn a_resting_stack_sleeps_and_a_ball_dropped_on_it_wakes_it() {
    use largestep::rigid::sleep::Sleep;
    let mut d = stack(3, RigidSolver::SequentialImpulses);
    // A ball falling from 14 m onto the top box's corner, arriving after about 1.6 s.
    d.bodies.push(BodyDesc::new(
        Shape::Sphere { radius: 0.3 },
        [0.3, 14.0, 0.2],
    ));
    d.sleep = Some(Sleep::default());
    let (m, mut s, mut w) = d.build().unwrap();
    let dt = 1.0 / 60.0;
    let stack_bodies = [1, 2, 3];
    let mut asleep_at = None;
    let mut frozen = None;
    let mut woke_at = None;
    let mut moved_after_waking = 0.0f64;
    for step in 0..600 {
        m.step(&mut s, &mut w, dt).unwrap();
        let all_asleep = stack_bodies.iter().all(|&i| s.asleep[i]);
        if all_asleep && asleep_at.is_none() {
            asleep_at = Some(step);
            frozen = Some(stack_bodies.map(|i| (s.x[i], s.q[i])));
        }
        if all_asleep && woke_at.is_none() {
            // Asleep: not one bit moves, and the ball is still falling.
            assert_eq!(Some(stack_bodies.map(|i| (s.x[i], s.q[i]))), frozen);
            assert!(!s.asleep[4]);
        }
        if asleep_at.is_some() && woke_at.is_none() && !all_asleep {
            // The ball hit: every box of the island woke with the one it touched.
            assert!(stack_bodies.iter().all(|&i| !s.asleep[i]), "{:?}", s.asleep);
            woke_at = Some(step);
        }
        if let (Some(f), Some(_)) = (frozen, woke_at) {
            for (k, &i) in stack_bodies.iter().enumerate() {
                let dx = largestep::kernels::v3::sub(s.x[i], f[k].0);
                moved_after_waking =
                    moved_after_waking.max(largestep::kernels::v3::dot(dx, dx).sqrt());
            }
        }
    }
    let (asleep_at, woke_at) = (
        asleep_at.expect("the stack fell asleep"),
        woke_at.expect("the ball woke it"),
    );
    eprintln!(
        "sleeping stack: asleep after {:.2} s, woken at {:.2} s, moved up to {moved_after_waking:.4} m, asleep at the end: {:?}",
        (asleep_at + 1) as f64 * dt,
        (woke_at + 1) as f64 * dt,
        s.asleep
    );
    assert!(asleep_at < woke_at && (woke_at as f64) * dt > 1.2);
    // The impact moved the stack.
    assert!(moved_after_waking > 1e-4, "{moved_after_waking}");
    // Ten seconds later, all at rest and asleep again.
    assert!(s.asleep[1..].iter().all(|&a| a), "{:?}", s.asleep);
    assert!(!s.asleep[0], "the static ground is never asleep");
    // Without sleeping, the same run never sleeps.
    d.sleep = None;
    let (m, mut s, mut w) = d.build().unwrap();
    for _ in 0..600 {
        m.step(&mut s, &mut w, dt).unwrap();
    }
    assert!(s.asleep.iter().all(|&a| !a));
}

/// 27 turned boxes in three layers over the ground, dropped: a tumbling, settling pile.
fn settling_boxes() -> RigidDesc {
    let mut d = RigidDesc::default();
    d.bodies.push(ground());
    for k in 0..27 {
        let (i, j, l) = ((k % 3) as f64, ((k / 3) % 3) as f64, (k / 9) as f64);
        let t = 0.37 * k as f64;
        let q = quat::exp([0.1 * t.sin(), 0.5 * t, 0.05 * t.cos()]);
        d.bodies.push(BodyDesc {
            orientation: q,
            ..BodyDesc::new(
                Shape::Box {
                    half: [0.5, 0.3, 0.4],
                },
                [1.2 * i - 1.2, 0.5 + 0.9 * l, 1.2 * j - 1.2],
            )
        });
    }
    d
}

/// `contact_reuse` 0 finds every manifold afresh (no pair reused, the contacts those of
/// the narrow phase run on the same state); a looser one reuses more; one out of 0..=1
/// is refused by name.
#[test]
fn contact_reuse_sets_how_long_manifolds_are_kept() {
    let dt = 1.0 / 60.0;
    let reused = |reuse: f64| {
        let d = RigidDesc {
            contact_reuse: reuse,
            ..settling_boxes()
        };
        let (m, mut s, mut w) = d.build().unwrap();
        let fresh = w.clone();
        let mut reused = 0;
        for _ in 0..120 {
            if reuse == 0.0 {
                let mut again = fresh.clone();
                m.find_contacts(&s, &mut again, dt).unwrap();
                let mut kept = w.clone();
                m.find_contacts(&s, &mut kept, dt).unwrap();
                let key = |c: &largestep::rigid::ContactPoint| (c.a, c.b, c.point, c.depth);
                let k: Vec<_> = kept.contacts().iter().map(key).collect();
                let a: Vec<_> = again.contacts().iter().map(key).collect();
                assert_eq!(k, a);
            }
            reused += m.step(&mut s, &mut w, dt).unwrap().reused;
        }
        reused
    };
    let (none, default, loose) = (reused(0.0), reused(0.005), reused(0.1));
    eprintln!("pairs reused over 120 steps: {none} (0), {default} (0.005), {loose} (0.1)");
    assert_eq!(none, 0);
    assert!(default > 0 && loose > default, "{default} {loose}");
    for bad in [-0.1, 1.5, f64::NAN] {
        let d = RigidDesc {
            contact_reuse: bad,
            ..settling_boxes()
        };
        let e = d.build().unwrap_err().to_string();
        assert!(e.contains("contact_reuse"), "{e}");
    }
}

/// Persistent manifolds: a pair whose relative pose has barely moved keeps its manifold
/// (moved with the bodies) instead of running the narrow phase again. On a tumbling,
/// settling pile of turned boxes, the kept manifolds match the narrow phase's, run afresh
/// on the same state: the same pairs, with their deepest points within the solver's slop
/// (0.5% of the size; seen: 7e-6 m, 0.002%). The normals agree to 0.05 rad but for rare near-ties
/// of the separating axis test (under 1% of the pairs), where the fresh run takes
/// another axis with the same penetration (the depths above include those pairs).
#[test]
fn kept_manifolds_match_the_narrow_phase_run_afresh() {
    let d = settling_boxes();
    assert_eq!(d.contact_reuse, 0.005, "the default is tested here");
    let (m, mut s, mut w) = d.build().unwrap();
    let fresh = w.clone();
    let dt = 1.0 / 60.0;
    let mut reused = 0;
    let mut diff = largestep::rigid::ContactDiff::default();
    for step in 0..240 {
        if step >= 30 {
            let mut kept = w.clone();
            let info = m.find_contacts(&s, &mut kept, dt).unwrap();
            reused += info.reused;
            let mut again = fresh.clone();
            m.find_contacts(&s, &mut again, dt).unwrap();
            let pairs = |c: &[largestep::rigid::ContactPoint]| {
                let mut p: Vec<_> = c.iter().map(|c| (c.a, c.b)).collect();
                p.dedup();
                p
            };
            let (a, b) = (kept.contacts(), again.contacts());
            assert_eq!(pairs(a), pairs(b), "step {step}");
            diff.add(a, b);
        }
        m.step(&mut s, &mut w, dt).unwrap();
    }
    let compared = diff.gaps.len();
    let worst_depth = diff.gaps.iter().copied().fold(0.0f64, f64::max);
    let flips = diff.flipped;
    eprintln!(
        "kept manifolds: {reused} reused of {compared} compared; deepest point within {worst_depth:.2e} m; {flips} other axes"
    );
    assert!(reused > compared / 4, "{reused} of {compared}");
    assert!(worst_depth < 0.005 * 0.3, "{worst_depth}");
    assert!(flips * 100 < compared, "{flips} of {compared}");
}

/// A box on a slab tilted by `deg` about z (sloping down toward -x), at rest on it; where
/// its centre is after `t` seconds.
fn slide_on_incline(deg: f64, t: f64) -> [f64; 3] {
    let a = deg.to_radians();
    let q = quat::exp([0.0, 0.0, a]);
    let mut slab = ground();
    slab.orientation = q;
    let up = quat::rotate(q, [0.0, 1.0, 0.0]);
    // Resting on the slab's top face: a half-side above it.
    let at = largestep::kernels::v3::add(slab.position, up);
    let mut d = RigidDesc::default();
    d.bodies.push(slab);
    d.bodies.push(BodyDesc {
        orientation: q,
        ..BodyDesc::new(
            Shape::Box {
                half: [0.5, 0.5, 0.5],
            },
            at,
        )
    });
    let (m, mut s, mut w) = d.build().unwrap();
    let x0 = s.x[1];
    while s.time < t - 1e-9 {
        m.step(&mut s, &mut w, 1.0 / 120.0).unwrap();
    }
    largestep::kernels::v3::sub(s.x[1], x0)
}

/// Coulomb friction (friction 0.5, the default): a box on a 20-degree slope
/// (tan 20° = 0.36 < 0.5) stays put; on a 35-degree one (tan 35° = 0.70) it slides down
/// with the acceleration g (sin 35° - 0.5 cos 35°) = 1.609 m/s², so 0.804 m in 1 s.
#[test]
fn a_box_holds_on_a_gentle_slope_and_slides_down_a_steep_one_at_coulombs_rate() {
    use largestep::kernels::v3::dot;
    let held = slide_on_incline(20.0, 1.0);
    let slid = slide_on_incline(35.0, 1.0);
    let a = 35f64.to_radians();
    let expect = 0.5 * 9.81 * (a.sin() - 0.5 * a.cos());
    let along = dot(slid, slid).sqrt();
    eprintln!(
        "incline: held {:.2e} m in 1 s at 20°; slid {along:.4} m at 35° (Coulomb: {expect:.4} m)",
        dot(held, held).sqrt()
    );
    assert!(dot(held, held).sqrt() < 2e-3, "{held:?}");
    assert!(rel(along, expect) < 0.03, "{along} against {expect}");
}

/// Twist friction: a box spinning about the normal on the ground, pressed by its weight
/// through its four corners, stops as Coulomb friction at the corners has it: the torque
/// is the friction coefficient times the weight times the corners' distance from the
/// centre (a √2 for half side a), the moment of inertia 2 m a² / 3, so the spin falls at
/// 1.5 √2 μ g / a = 20.8 rad/s² (a = 0.5 m, μ = 0.5), from 5 rad/s to rest in 0.240 s.
#[test]
fn a_spinning_box_stops_at_the_rate_of_friction_at_its_corners() {
    let mut d = RigidDesc::default();
    d.bodies.push(ground());
    d.bodies.push(BodyDesc {
        angular_velocity: [0.0, 5.0, 0.0],
        ..BodyDesc::new(
            Shape::Box {
                half: [0.5, 0.5, 0.5],
            },
            [0.0, 0.5, 0.0],
        )
    });
    let (m, mut s, mut w) = d.build().unwrap();
    let dt = 1.0 / 240.0;
    // The box starts on the ground (its centre a half-side up), loaded by its weight.
    let rate = 1.5 * 2f64.sqrt() * 0.5 * 9.81 / 0.5;
    let mut stopped = None;
    let w0 = s.w[1][1];
    while s.time < 0.5 {
        m.step(&mut s, &mut w, dt).unwrap();
        if stopped.is_none() && s.w[1][1] < 0.01 * w0 {
            stopped = Some(s.time);
        }
    }
    let stopped = stopped.expect("the spin stopped");
    let expect = w0 / rate;
    eprintln!(
        "twist friction: stopped after {stopped:.4} s (Coulomb at the corners: {expect:.4} s)"
    );
    assert!(rel(stopped, expect) < 0.05, "{stopped} against {expect}");
    assert!(s.w[1][1].abs() < 1e-3, "{:?}", s.w[1]);
}

/// Runs study `name` with `--quick` (`common::quick_study`): the summary line, the report
/// and the numbers; its plot is written, and the folder removed.
#[cfg(feature = "cli")]
fn quick_study(name: &str) -> (String, String, Vec<serde_json::Value>) {
    let (out, summary, md, json) = common::quick_study(name);
    assert!(out.join(format!("{name}.png")).exists());
    std::fs::remove_dir_all(&out).ok();
    (summary, md, json)
}

/// The quick `rigid-reuse` study: with `contact_reuse` 0 nothing is kept and the
/// contacts are the fresh narrow phase's exactly; the default keeps some pairs with
/// their deepest points within the solver's slop of a fresh narrow phase (the 99th
/// percentile); 0.1 keeps more, and staler.
#[cfg(feature = "cli")]
#[test]
fn the_quick_contact_reuse_study_trades_staleness_for_kept_pairs() {
    let (summary, md, json) = quick_study("rigid-reuse");
    assert!(summary.starts_with("rigid-reuse:"), "{summary}");
    assert!(
        md.contains("rigid-reuse --quick") && md.contains("100 boxes"),
        "{md}"
    );
    let at = |r: f64| json.iter().find(|p| p["reuse"] == r).unwrap();
    let f = |p: &serde_json::Value, k: &str| p[k].as_f64().unwrap();
    let (none, default, loose) = (at(0.0), at(0.005), at(0.1));
    assert_eq!((f(none, "reused"), f(none, "gap_max")), (0.0, 0.0));
    assert_eq!(none["unmatched"], 0);
    assert!(f(none, "compared") > 1000.0);
    assert!(f(default, "reused") > 0.1, "{default}");
    assert!(f(default, "gap_p99") < 0.005 * 0.5, "{default}");
    assert!(f(loose, "reused") > f(default, "reused"));
    assert!(f(loose, "gap_p99") > f(default, "gap_p99"));
    for p in &json {
        assert!(
            f(p, "step_ms") > 0.0 && f(p, "lowest") > 0.4,
            "a stable pile: {p}"
        );
    }
}

/// The quick `rigid-contacts` and `rigid-integrators` studies write their reports: the
/// default solver's stack stands, and Runge-Kutta is the most accurate integrator at the
/// finest step.
#[cfg(feature = "cli")]
#[test]
fn the_quick_rigid_studies_write_their_reports() {
    let (summary, md, json) = quick_study("rigid-contacts");
    assert!(
        summary.contains("rigid-contacts") && md.contains("--quick"),
        "{md}"
    );
    assert!(json
        .iter()
        .any(|p| p["solver"] == "sequential impulses, soft"
            && p["iterations"] == 4
            && p["stood"] == true));
    let (_, md, json) = quick_study("rigid-integrators");
    assert!(md.contains("rigid-integrators --quick"), "{md}");
    let finest = |name: &str| {
        json.iter().rfind(|p| p["integrator"] == name).unwrap()["orientation_error"]
            .as_f64()
            .unwrap()
    };
    assert!(finest("rk4") < finest("symplectic-euler"));
    assert!(finest("rk4") < finest("explicit-euler"));
}
