//! The jello cube: lattice, force field, penalty collisions, world files, integrators.

use largestep::integrate::*;
use largestep::loads::{Body, ForceField, Load};
use largestep::mass_spring::world::World;
use largestep::mass_spring::*;
use largestep::scene::{Runner, Scene};
use largestep::simulation::{MechModel, MechSimulation};
use largestep::sparse::Bsr3;
use std::path::{Path, PathBuf};

/// A world file of `../shared/data/jello-worlds` (beside the checkout, as the workplace
/// provides it), or of `$LARGESTEP_SHARED_DATA/jello-worlds` when that is set.
fn world_path(name: &str) -> PathBuf {
    let data = std::env::var_os("LARGESTEP_SHARED_DATA").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
        PathBuf::from,
    );
    let p = data.join("jello-worlds").join(name);
    assert!(
        p.is_file(),
        "{} is missing: these tests read the assignment's world files from ../shared/data (or $LARGESTEP_SHARED_DATA)",
        p.display()
    );
    p
}

fn cube(k: f64, d: f64, mass: f64) -> LatticeOptions {
    LatticeOptions {
        n: [8, 8, 8],
        origin: [-0.5, -0.5, -0.5],
        size: [1.0; 3],
        mass,
        structural: k,
        shear: k,
        bend: k,
        damping: d,
    }
}

/// Steps the system for `t_end` seconds: the final state, the largest |x| seen and the
/// largest point speed seen, or the error.
fn simulate(
    method: Method,
    desc: &MassSpringDesc,
    dt: f64,
    t_end: f64,
) -> Result<(MassSpringState, f64, f64), IntegrateError> {
    let (m, st) = desc.build().unwrap();
    let n = m.particle_count();
    let mut sim = MechSimulation::new(m, st, MechSettings::new(method))?;
    let steps = (t_end / dt).round() as usize;
    let (mut worst, mut speed) = (0.0f64, 0.0f64);
    for _ in 0..steps {
        sim.step(dt)?;
        let st = sim.state();
        worst = st.x.as_slice().iter().fold(worst, |w, c| w.max(c.abs()));
        let v = st.v.as_slice();
        for i in 0..n {
            let s2 = v[i] * v[i] + v[n + i] * v[n + i] + v[2 * n + i] * v[2 * n + i];
            speed = speed.max(s2.sqrt());
        }
    }
    Ok((sim.state().clone(), worst, speed))
}

#[test]
fn lattice_has_the_assignment_springs_and_a_closed_outward_surface() {
    let desc = lattice(&cube(1.0, 0.0, 1.0));
    // 8^3: structural 3*7*64, face diagonals 3*2*7*7*8, body diagonals 4*7^3, bend 3*6*64.
    assert_eq!(desc.springs.len(), 1344 + 2352 + 1372 + 1152);
    let mut rest: Vec<f64> = desc
        .springs
        .iter()
        .map(|s| s.rest_length.unwrap())
        .collect();
    rest.sort_by(f64::total_cmp);
    rest.dedup_by(|a, b| (*a - *b).abs() < 1e-12);
    let h = 1.0 / 7.0;
    let expect = [h, 2f64.sqrt() * h, 3f64.sqrt() * h, 2.0 * h];
    assert_eq!(rest.len(), 4);
    for (r, e) in rest
        .iter()
        .zip([expect[0], expect[1], expect[2], expect[3]])
    {
        assert!((r - e).abs() < 1e-12, "{r} vs {e}");
    }
    // 6 faces of 7x7 cells, two triangles each; every triangle faces away from the centre.
    assert_eq!(desc.triangles.len(), 6 * 49 * 2);
    for t in &desc.triangles {
        let p = t.map(|i| desc.positions[i as usize]);
        let e1: [f64; 3] = std::array::from_fn(|c| p[1][c] - p[0][c]);
        let e2: [f64; 3] = std::array::from_fn(|c| p[2][c] - p[0][c]);
        let n = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let centroid: [f64; 3] = std::array::from_fn(|c| (p[0][c] + p[1][c] + p[2][c]) / 3.0);
        assert!(n.iter().zip(centroid).map(|(a, b)| a * b).sum::<f64>() > 0.0);
    }
    // Other sizes work too.
    let block = lattice(&LatticeOptions {
        n: [3, 2, 5],
        ..cube(1.0, 0.0, 1.0)
    });
    assert_eq!(block.positions.len(), 30);
}

#[test]
fn force_field_is_exact_for_linear_fields() {
    let r = 5;
    let grid = largestep::kernels::interp::Grid3::spanning([r; 3], [-2.0; 3], [2.0; 3]);
    let f = |p: [f64; 3]| {
        [
            1.0 + 2.0 * p[0] - p[2],
            0.5 * p[1] + 3.0 * p[2],
            -p[0] + p[1] - 4.0,
        ]
    };
    let mut force = [
        vec![0.0; r * r * r],
        vec![0.0; r * r * r],
        vec![0.0; r * r * r],
    ];
    for k in 0..r {
        for j in 0..r {
            for i in 0..r {
                let p = [i, j, k].map(|c| -2.0 + c as f64);
                let v = f(p);
                for c in 0..3 {
                    force[c][i + r * (j + r * k)] = v[c];
                }
            }
        }
    }
    let field = ForceField { grid, force };
    let pts = [
        [0.3, -1.7, 1.1],
        [-2.0, 2.0, 0.0],
        [1.99, 0.01, -0.5],
        [0.0, 0.0, 0.0],
    ];
    let n = pts.len();
    let mut x = vec![0.0; 3 * n];
    for (i, p) in pts.iter().enumerate() {
        for c in 0..3 {
            x[c * n + i] = p[c];
        }
    }
    let mut out = vec![0.0; 3 * n];
    let body = Body {
        mass: &vec![1.0; n],
        triangles: &[],
    };
    field.add_forces(0.0, &body, &x, &x, &mut out);
    for (i, p) in pts.iter().enumerate() {
        for c in 0..3 {
            assert!((out[c * n + i] - f(*p)[c]).abs() < 1e-12);
        }
    }
}

#[test]
fn momentum_is_conserved_without_external_forces() {
    let mut desc = lattice(&cube(200.0, 0.5, 0.002));
    // Deformed and spinning: velocities differ per particle.
    for (i, (p, v)) in desc
        .positions
        .iter_mut()
        .zip(std::iter::repeat([0.0; 3]))
        .enumerate()
    {
        let _ = v;
        p[0] += 0.02 * ((i * 7 % 13) as f64 / 13.0 - 0.5);
    }
    desc.velocities = desc
        .positions
        .iter()
        .map(|p| [-p[1] + 0.3, p[0], 0.5 * p[2]])
        .collect();
    let momentum = |st: &MassSpringState| -> [f64; 3] {
        std::array::from_fn(|c| st.v.as_slice()[c * 512..(c + 1) * 512].iter().sum::<f64>() * 0.002)
    };
    let (_, st0) = desc.build().unwrap();
    let p0 = momentum(&st0);
    for method in [
        Method::ExplicitEuler,
        Method::Midpoint,
        Method::Rk4,
        Method::SymplecticEuler,
        Method::LinearizedBackwardEuler,
    ] {
        let (st, _, _) = simulate(method, &desc, 1e-4, 0.05).unwrap();
        let p = momentum(&st);
        for c in 0..3 {
            assert!(
                (p[c] - p0[c]).abs() < 1e-12,
                "{method}: momentum {p:?} vs {p0:?}"
            );
        }
    }
}

#[test]
fn shipped_worlds_run_two_seconds_inside_the_box() {
    for name in ["jello.w", "rotate.w"] {
        let world = World::read(&world_path(name), u64::MAX).unwrap();
        let desc = world.to_desc();
        let (st, worst, speed) = simulate(world.method, &desc, world.dt, 2.0).unwrap();
        assert!(st
            .x
            .as_slice()
            .iter()
            .chain(st.v.as_slice())
            .all(|c| c.is_finite()));
        // The penalty springs let points sink into a wall: by 0.12 m (jello.w: the cube
        // hits a wall at 25 m/s, k_c = 400) and 0.072 m (rotate.w: a spinning corner, point
        // speeds up to 13 m/s, k_c = 1000). Bound: 5% of the box's side, 0.2 m.
        assert!(
            worst - 2.0 < 0.2,
            "{name}: a point reached |x| = {worst}, more than 0.2 m past a wall"
        );
        let _ = speed;
    }
}

#[test]
fn implicit_step_is_stable_where_rk4_is_not() {
    // kElastic = 1e5 with the assignment's mass: the highest lattice frequency is far
    // beyond RK4's stability bound at dt = 0.01.
    let mut desc = lattice(&cube(1e5, 0.25, 0.001953));
    desc.velocities = vec![[1.0, -1.0, 2.0]; 512];
    desc.collisions = Some(CollisionDesc {
        bounds: Some(([-2.0; 3], [2.0; 3])),
        planes: vec![],
        obstacles: Vec::new(),
        stiffness: 1e4,
        damping: 0.25,
    });
    let (st, worst, _) = simulate(Method::LinearizedBackwardEuler, &desc, 0.01, 2.0).unwrap();
    assert!(
        st.x.as_slice().iter().all(|c| c.is_finite()) && worst < 2.2,
        "{worst}"
    );
    match simulate(Method::Rk4, &desc, 0.01, 2.0) {
        Err(_) => {}
        Ok((st, worst, _)) => {
            assert!(
                !st.x.as_slice().iter().all(|c| c.is_finite()) || worst > 10.0,
                "RK4 should blow up at dt = 0.01, max |x| = {worst}"
            )
        }
    }
}

#[test]
fn penalty_jacobians_match_finite_differences() {
    let mut desc = lattice(&cube(100.0, 0.3, 0.01));
    // Push a corner of the cube through the floor and through an inclined plane.
    desc.positions[0] = [-0.5, -2.1, -0.5];
    desc.positions[7] = [-0.6, -0.5, 0.55];
    desc.velocities = desc
        .positions
        .iter()
        .map(|p| [0.1 * p[1], -0.2, 0.3 * p[0]])
        .collect();
    desc.collisions = Some(CollisionDesc {
        bounds: Some(([-2.0; 3], [2.0; 3])),
        planes: vec![[1.0, -0.2, -1.0, 1.05]],
        obstacles: Vec::new(),
        stiffness: 500.0,
        damping: 0.7,
    });
    let (m, st) = desc.build().unwrap();
    assert!(m.max_penetration(st.x.as_slice()) > 0.05);
    let n = m.particle_count();
    let mut w = m.work();
    let pattern = m.prepare_jacobians(&mut w).unwrap().unwrap();
    let (mut kx, mut kv) = (Bsr3::zeros(pattern.clone()), Bsr3::zeros(pattern));
    let (x, v) = (st.x.as_slice().to_vec(), st.v.as_slice().to_vec());
    let mut f = vec![0.0; 3 * n];
    m.force_jacobians(&mut w, 0.0, &x, &v, &mut f, &mut kx, Some(&mut kv))
        .unwrap();
    let mut f2 = vec![0.0; 3 * n];
    m.force(&mut w, 0.0, &x, &v, &mut f2);
    assert_eq!(f, f2, "force_jacobians and force agree on f");
    let (dense_x, dense_v) = (kx.to_dense(), kv.to_dense());
    let h = 1e-7;
    for &col in &[0, n, 2 * n, 7, n + 7, 2 * n + 7, 100] {
        for (dense, which) in [(&dense_x, 0), (&dense_v, 1)] {
            let (mut xp, mut vp) = (x.clone(), v.clone());
            let (mut xm, mut vm) = (x.clone(), v.clone());
            if which == 0 {
                xp[col] += h;
                xm[col] -= h;
            } else {
                vp[col] += h;
                vm[col] -= h;
            }
            let (mut fp, mut fm) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            m.force(&mut w, 0.0, &xp, &vp, &mut fp);
            m.force(&mut w, 0.0, &xm, &vm, &mut fm);
            for row in 0..3 * n {
                let fd = (fp[row] - fm[row]) / (2.0 * h);
                let an = dense[row * 3 * n + col];
                // Spring damping's position derivative is left out on purpose (BW98 5.2).
                if which == 0 && desc.springs.iter().any(|s| s.damping > 0.0) {
                    continue;
                }
                assert!(
                    (fd - an).abs() < 1e-4 * (1.0 + an.abs()),
                    "d f[{row}] / d{} [{col}]: fd {fd}, analytic {an}",
                    ["x", "v"][which]
                );
            }
        }
    }
}

#[test]
fn undamped_penalty_jacobian_in_x_matches_finite_differences() {
    let mut desc = lattice(&cube(100.0, 0.0, 0.01));
    desc.positions[0] = [-0.5, -2.1, -0.5];
    desc.collisions = Some(CollisionDesc {
        bounds: Some(([-2.0; 3], [2.0; 3])),
        planes: vec![],
        obstacles: Vec::new(),
        stiffness: 500.0,
        damping: 0.0,
    });
    let (m, st) = desc.build().unwrap();
    let n = m.particle_count();
    let mut w = m.work();
    let pattern = m.prepare_jacobians(&mut w).unwrap().unwrap();
    let mut kx = Bsr3::zeros(pattern);
    let (x, v) = (st.x.as_slice().to_vec(), st.v.as_slice().to_vec());
    let mut f = vec![0.0; 3 * n];
    m.force_jacobians(&mut w, 0.0, &x, &v, &mut f, &mut kx, None)
        .unwrap();
    let dense = kx.to_dense();
    let h = 1e-7;
    for col in [0, n, 2 * n, 9] {
        let (mut xp, mut xm) = (x.clone(), x.clone());
        xp[col] += h;
        xm[col] -= h;
        let (mut fp, mut fm) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
        m.force(&mut w, 0.0, &xp, &v, &mut fp);
        m.force(&mut w, 0.0, &xm, &v, &mut fm);
        for row in 0..3 * n {
            let fd = (fp[row] - fm[row]) / (2.0 * h);
            let an = dense[row * 3 * n + col];
            assert!(
                (fd - an).abs() < 1e-4 * (1.0 + an.abs()),
                "[{row},{col}] fd {fd} vs {an}"
            );
        }
    }
}

#[test]
fn world_files_round_trip_and_run_from_the_cli_layer() {
    let world = World::read(&world_path("rotate.w"), u64::MAX).unwrap();
    assert_eq!(world.method, Method::Rk4);
    assert_eq!(world.resolution, 30);
    assert_eq!(world.positions.len(), 512);
    let mut text = Vec::new();
    world.write(&mut text).unwrap();
    let back = World::parse(std::str::from_utf8(&text).unwrap(), "back.w").unwrap();
    assert_eq!(back, world);
    // `largestep run world.w` goes through Scene::load.
    let scene = Scene::load(&world_path("jello.w")).unwrap();
    assert_eq!(scene.dt, 0.0005);
    let out = std::env::temp_dir().join(format!("largestep-jello-{}", std::process::id()));
    let mut runner = Runner::new(scene, &out);
    runner.run(Some(2), &mut |_| {}).unwrap();
    let csv = std::fs::read_to_string(out.join("energy.csv")).unwrap();
    assert!(csv.lines().next().unwrap().contains("penetration_m"));
    let obj = std::fs::read_to_string(out.join("frames/frame_00002.obj")).unwrap();
    assert_eq!(obj.lines().filter(|l| l.starts_with("f ")).count(), 588);
}

#[test]
fn malformed_world_files_name_the_line() {
    let good = std::fs::read_to_string(world_path("jello.w")).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let with = |i: usize, s: &str| {
        let mut l = lines.clone();
        l[i] = s;
        l.join("\n")
    };
    let cases: Vec<(String, usize, &str)> = vec![
        (with(0, "Verlet"), 1, "unknown integrator `Verlet`"),
        (with(1, "0.0005"), 2, "`dt n`"),
        (with(1, "-0.1 1"), 2, "time step must be > 0"),
        (with(2, "200 0.25 x 0.25"), 3, "`x` is not a finite number"),
        (with(3, "nan"), 4, "not a finite number"),
        (with(4, "2"), 5, "must be 0 or 1"),
        (with(5, "0 0 0 2"), 6, "normal (a, b, c) is zero"),
        (with(6, "29"), 7, "does not match the number of lines"),
        (with(40, "0 0"), 41, "found 2 fields"),
        (with(27010, "0 inf 0"), 27011, "not a finite number"),
        (lines[..20000].join("\n"), 7, "does not match"),
        (String::new(), 1, "unexpected end of file"),
        (
            lines[..3].join("\n"),
            4,
            "unexpected end of file: expected the mass",
        ),
    ];
    for (text, line, words) in cases {
        let e = World::parse(&text, "bad.w").unwrap_err();
        assert_eq!(e.line, line, "{e}");
        let msg = e.to_string();
        assert!(
            msg.starts_with(&format!("bad.w:{line}:")) && msg.contains(words),
            "{msg}"
        );
    }
    // The scene loader reports the same, and nothing runs.
    let path = std::env::temp_dir().join(format!("largestep-bad-{}.w", std::process::id()));
    std::fs::write(&path, with(6, "29")).unwrap();
    let e = Scene::load(&path).unwrap_err().to_string();
    assert!(e.contains(":7:") && e.contains("resolution"), "{e}");
}

const JELLO_TOML: &str = r#"
[scene]
dt = 0.0005
duration = 0.05
integrator = "rk4"

[mass_spring.lattice]
n = [8, 8, 8]
size = [1.0, 1.0, 1.0]
mass = 0.001953
structural = 200.0
shear = 200.0
bend = 200.0
damping = 0.25
velocity = [10.0, -10.0, 20.0]

[mass_spring.collisions]
box_min = [-2.0, -2.0, -2.0]
box_max = [2.0, 2.0, 2.0]
planes = [[-1.0, 1.0, 1.0, 2.0]]
stiffness = 400.0
damping = 0.25
"#;

#[test]
fn toml_scene_reproduces_the_world_file() {
    let run = |scene: Scene| {
        let out = std::env::temp_dir().join(format!(
            "largestep-jello-eq-{}-{}",
            std::process::id(),
            scene.file.len()
        ));
        let mut runner = Runner::new(scene, &out);
        runner.run(None, &mut |_| {}).unwrap();
        let sim = runner.simulation();
        let sim = sim.downcast_ref::<MechSimulation<MassSpring>>().unwrap();
        sim.state().x.as_slice().to_vec()
    };
    // jello.w displaces its last corner to (8/7, 8/7, 8/7), which a lattice table cannot
    // say: compare with the file with that corner at rest.
    let text = std::fs::read_to_string(world_path("jello.w")).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[27518], "1.142857 1.142857 1.142857");
    lines[27518] = "1.000000 1.000000 1.000000";
    let w = World::parse(&lines.join("\n"), "jello-rest.w").unwrap();
    let mut world = w.to_scene("jello-rest.w", &Default::default()).unwrap();
    world.duration = 0.05;
    let a = run(world);
    let b = run(Scene::parse(JELLO_TOML, "jello-equivalent.toml").unwrap());
    // The world file stores positions to 6 decimals (1/7 = 0.142857): the runs agree to
    // that rounding, not bitwise.
    let diff = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(diff < 1e-5, "max difference {diff} m after 100 steps");
}

#[test]
fn malformed_lattice_collision_and_field_tables_are_located() {
    let cases: Vec<(String, &str, &str)> = vec![
        (JELLO_TOML.replace("n = [8, 8, 8]", "n = [8, 1, 8]"), "n = [8, 1, 8]", "mass_spring.lattice.n[1]"),
        (JELLO_TOML.replace("mass = 0.001953", "mass = -1.0"), "mass = -1.0", "mass_spring.lattice.mass"),
        (
            JELLO_TOML.replace("planes = [[-1.0, 1.0, 1.0, 2.0]]", "planes = [[0.0, 0.0, 0.0, 2.0]]"),
            "planes =",
            "non-zero normal",
        ),
        (
            JELLO_TOML.replace("box_max = [2.0, 2.0, 2.0]\n", ""),
            "box_min",
            "needs box_max",
        ),
        (
            JELLO_TOML.replace("stiffness = 400.0", "stiffness = nan"),
            "stiffness = nan",
            "mass_spring.collisions.stiffness",
        ),
        (
            format!("{JELLO_TOML}\n[mass_spring.force_field]\nmin = [-2.0, -2.0, -2.0]\nmax = [2.0, 2.0, 2.0]\nresolution = 2\nforces = [[0.0, 0.0, 0.0]]\n"),
            "forces =",
            "needs 8 forces",
        ),
    ];
    for (text, needle, words) in cases {
        let e = Scene::parse(&text, "bad.toml").unwrap_err().to_string();
        let line = text.lines().position(|l| l.contains(needle)).unwrap() + 1;
        assert!(
            e.starts_with(&format!("bad.toml:{line}:")) && e.contains(words),
            "{e}"
        );
    }
}

#[test]
fn resting_cube_stays_at_rest_on_the_floor() {
    // The assignment's cube standing on the floor of its box under gravity: after it has
    // settled (1 s), its centre of mass moves by less than 10 um over the next second
    // (measured: 0.5 um) and not at all sideways (the setup is symmetric).
    let mut desc = lattice(&LatticeOptions {
        origin: [-0.5, -2.0, -0.5],
        ..cube(200.0, 0.25, 1.0 / 512.0)
    });
    desc.gravity = [0.0, -9.81, 0.0];
    desc.collisions = Some(CollisionDesc {
        bounds: Some(([-2.0; 3], [2.0; 3])),
        planes: vec![],
        obstacles: Vec::new(),
        stiffness: 400.0,
        damping: 0.25,
    });
    let com = |st: &MassSpringState| -> [f64; 3] {
        std::array::from_fn(|c| st.x.as_slice()[c * 512..(c + 1) * 512].iter().sum::<f64>() / 512.0)
    };
    let (settled, _, _) = simulate(Method::Rk4, &desc, 5e-4, 1.0).unwrap();
    let mut later = desc.clone();
    later.positions = settled.x.to_aos();
    later.velocities = settled.v.to_aos();
    let (end, _, _) = simulate(Method::Rk4, &later, 5e-4, 1.0).unwrap();
    let (a, b) = (com(&settled), com(&end));
    assert!((b[1] - a[1]).abs() < 1e-5, "vertical drift {}", b[1] - a[1]);
    assert!(
        (b[0] - a[0]).abs() < 1e-9 && (b[2] - a[2]).abs() < 1e-9,
        "sideways drift"
    );
    // Resting on the floor, not through it: the penalty springs hold the weight
    // (9.8 N over 64 springs of 400 N/m: 0.4 mm).
    let lowest = end.x.y().iter().fold(f64::INFINITY, |m, y| m.min(*y));
    assert!(lowest > -2.002 && lowest < -2.0, "lowest point {lowest}");
}

#[test]
fn cli_runs_world_files_and_rejects_bad_ones_before_running() {
    let exe = env!("CARGO_BIN_EXE_largestep");
    let out = std::env::temp_dir().join(format!("largestep-cli-world-{}", std::process::id()));
    let st = std::process::Command::new(exe)
        .arg("run")
        .arg(world_path("rotate.w"))
        .args(["--frames", "2", "--explain", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&st.stdout);
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    assert!(
        stdout.contains("penalty collisions") && stdout.contains("force field"),
        "{stdout}"
    );
    assert!(out.join("frames/frame_00002.obj").is_file());
    // A truncated world: exit 2, the line, and no output folder written.
    let bad = std::env::temp_dir().join(format!("largestep-cli-bad-{}.w", std::process::id()));
    let text = std::fs::read_to_string(world_path("jello.w")).unwrap();
    std::fs::write(&bad, text.lines().take(5).collect::<Vec<_>>().join("\n")).unwrap();
    let out2 = out.with_extension("bad");
    let st = std::process::Command::new(exe)
        .arg("run")
        .arg(&bad)
        .arg("--out")
        .arg(&out2)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&st.stderr);
    assert_eq!(st.status.code(), Some(2), "{err}");
    assert!(
        err.contains(":6:") && err.contains("expected `a b c d`"),
        "{err}"
    );
    assert!(!out2.exists(), "nothing half-run");
}

/// Moving obstacles meet the penalty law with velocities relative to their material: a
/// particle carried along with the obstacle feels only the spring, the forces are minus
/// the gradient of the springs' energy, the Jacobian's n n^T matches differences, and the
/// obstacle's power is `F . v_o`.
#[test]
fn moving_obstacles_take_the_penalty_law_relative_to_their_motion() {
    use largestep::collide::{Against, MovingObstacle, Obstacle, Penalty};
    let pen = Penalty {
        obstacles: Vec::new(),
        stiffness: 300.0,
        damping: 0.8,
    };
    let ball = MovingObstacle {
        shape: Obstacle::Sphere {
            center: [0.1, 0.2, -0.1],
            radius: 0.5,
        },
        center: [0.1, 0.2, -0.1],
        velocity: [0.4, -0.3, 0.2],
        angular_velocity: [1.0, 2.0, -0.5],
    };
    let moving = [ball.clone()];
    let against = Against::Moving(&moving);
    // Three particles inside, one outside (component-major).
    let pts = [
        [0.3, 0.3, 0.0],
        [-0.2, 0.1, -0.3],
        [0.1, 0.55, 0.1],
        [1.0, 1.0, 1.0],
    ];
    let n = pts.len();
    let x: Vec<f64> = (0..3).flat_map(|c| pts.iter().map(move |p| p[c])).collect();
    // Every particle moving with the obstacle's material: no damping force.
    let carried: Vec<f64> = (0..3)
        .flat_map(|c| {
            pts.iter()
                .map(|&p| ball.velocity_at(p)[c])
                .collect::<Vec<_>>()
        })
        .collect();
    let mut f = vec![0.0; 3 * n];
    pen.add_forces(against, &x, &carried, &mut f);
    assert!(pen.dissipation(against, &x, &carried).abs() < 1e-12);
    let h = 1e-6;
    for k in 0..3 * n {
        let (mut xp, mut xm) = (x.clone(), x.clone());
        xp[k] += h;
        xm[k] -= h;
        let grad = (pen.energy(against, &xp) - pen.energy(against, &xm)) / (2.0 * h);
        assert!(
            (f[k] + grad).abs() < 1e-6,
            "f[{k}] {} against -dE/dx {}",
            f[k],
            -grad
        );
    }
    assert!(f[n - 1] == 0.0 && f[2 * n - 1] == 0.0 && f[3 * n - 1] == 0.0);
    // At rest the damping pushes along the obstacle's motion, and the power is F . v_o.
    let still = vec![0.0; 3 * n];
    let mut g = vec![0.0; 3 * n];
    pen.add_forces(against, &x, &still, &mut g);
    let power: f64 = (0..n)
        .map(|i| {
            (0..3)
                .map(|c| g[c * n + i] * ball.velocity_at(pts[i])[c])
                .sum::<f64>()
        })
        .sum();
    assert!((pen.power(against, &x, &still) - power).abs() < 1e-12);
    let damping_part: f64 = (0..3 * n).map(|k| (g[k] - f[k]) * (g[k] - f[k])).sum();
    assert!(damping_part > 0.0);
}
