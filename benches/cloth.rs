//! Baraff-Witkin cloth benchmarks: one implicit step of an n x n sheet (1 m square, two
//! opposite corners pinned, falling onto a sphere of radius 0.25 m under it) at dt = 1/60 and
//! 1/30 s, n = 32, 100 (about 10k vertices, 20k triangles: the size of Vega FEM's cloth
//! example) and 200.
//!
//! - `cloth/step/<n>/<dt>`: the whole linearised backward Euler step of the paper (forces,
//!   Jacobians, system matrix, filtered PCG warm-started to a relative residual of 1e-2
//!   (see `settings`), position update, paths and contacts), from a draped state (the
//!   sheet has fallen for 0.5 s and lies on the sphere with contacts). The solver is the
//!   last part of the id: `pcg-mg` (aggregation multigrid, one V-cycle per iteration),
//!   `pcg-bj` (block Jacobi, the paper's choice) or `cholesky` (faer, for comparison).
//!   Rayon's thread count (all cores unless `RAYON_NUM_THREADS` says otherwise) is in the
//!   summary; the rapier3d peer (`benches/peers/rapier-cloth`) is single-threaded.
//! - The summary splits each step into assembly (`force_jacobians`: every element's
//!   forces and 3x3 Jacobian blocks and their gather into the block matrices) and solve
//!   (the PCG iterations), and gives each its fraction of this machine's limit measured
//!   in the same run: assembly against the triad bandwidth (the element buffers written
//!   and read once, and the matrices written, as streaming traffic), the solve against
//!   the triad bandwidth too (`Pcg::iteration_bytes`: per iteration the block-sparse
//!   product, the vector passes and, with multigrid, the V-cycle's passes over every
//!   level's matrix; PCG is bandwidth bound).
//!
//! Run with `cargo bench --bench cloth`; the summary is printed at the end and written to
//! `target/criterion/cloth-summary.md`.

use criterion::Criterion;
use largestep::cloth::{cloth_grid, Cloth, ClothGridOptions, ClothMaterial, ClothState};
use largestep::collide::Obstacle;
use largestep::integrate::{LinearSolverKind, MechSettings, Method};
use largestep::kernels::cloth::{
    bend_force_gradient, bend_force_gradient_x4, triangle_jacobians, triangle_jacobians_x4,
};
use largestep::kernels::{four, gather_nodes};
use largestep::machine::triad_bandwidth;
use largestep::simulation::{MechModel, MechSimulation};
use largestep::solve::{Filter, Pcg, PcgParams, Preconditioner};
use largestep::sparse::Bsr3;
use std::time::{Duration, Instant};

/// The benchmark material (per unit area stretch and shear, per hinge bend).
pub const MATERIAL: ClothMaterial = ClothMaterial {
    density: 0.2,
    stretch: 1000.0,
    shear: 100.0,
    bend: 1e-4,
    stretch_damping: 0.1,
    shear_damping: 0.01,
    bend_damping: 0.0,
    rest_stretch: [1.0, 1.0],
};

fn sheet(n: usize) -> (Cloth, ClothState) {
    let mut d = cloth_grid(&ClothGridOptions {
        nu: n,
        nv: n,
        size: [1.0, 1.0],
        origin: [-0.5, 0.3, -0.5],
        u_axis: [1.0, 0.0, 0.0],
        v_axis: [0.0, 0.0, 1.0],
        material: MATERIAL,
    });
    d.gravity = [0.0, -9.81, 0.0];
    d.pinned = vec![0, n * n - 1];
    d.obstacles = vec![Obstacle::Sphere {
        center: [0.0; 3],
        radius: 0.25,
    }];
    d.friction = 0.3;
    d.build().unwrap()
}

/// The linear solvers compared.
#[derive(Clone, Copy, PartialEq)]
enum Solver {
    Multigrid,
    BlockJacobi,
    Cholesky,
}

impl Solver {
    fn name(self) -> &'static str {
        match self {
            Solver::Multigrid => "pcg-mg",
            Solver::BlockJacobi => "pcg-bj",
            Solver::Cholesky => "cholesky",
        }
    }

    fn pcg(self) -> PcgParams {
        PcgParams {
            // 1e-2: at dt = 1/60 the drape's error is 1.85e-2 m at 1e-2 against 1.83e-2 m
            // converged (docs/studies/cloth-accuracy.md): the step, not the solve,
            // dominates.
            tolerance: 1e-2,
            max_iterations: 2000,
            preconditioner: if self == Solver::BlockJacobi {
                Preconditioner::BlockJacobi
            } else {
                Preconditioner::Multigrid
            },
        }
    }
}

fn settings(solver: Solver) -> MechSettings {
    let mut s = MechSettings::new(Method::LinearizedBackwardEuler);
    s.linear = match solver {
        Solver::Cholesky => LinearSolverKind::Cholesky,
        _ => LinearSolverKind::Pcg(solver.pcg()),
    };
    s
}

/// The benchmark's simulation: the sheet with its contacts, every step at dt (no
/// step-size control: the cases time fixed steps).
fn simulation(n: usize, solver: Solver) -> MechSimulation<Cloth> {
    let (cloth, st) = sheet(n);
    let mut sim = MechSimulation::new(cloth, st, settings(solver)).unwrap();
    sim.set_step_control(None);
    sim
}

fn main() {
    let mut c = Criterion::default()
        .configure_from_args()
        .measurement_time(Duration::from_secs(3))
        .sample_size(10);
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let wanted = |id: &str| filter.as_deref().is_none_or(|f| id.contains(f));
    let triad = triad_bandwidth(largestep::machine::DEFAULT_TRIAD_MIB * (1 << 20) / 8, 3);
    let mut md = format!(
        "threads: {}, triad bandwidth {:.1} GB/s\n\n| case | steps/s (median) | step median | step best | assembly (best) | of triad | solve (mean of 10) | PCG its/step | of triad | contacts |\n|---|---|---|---|---|---|---|---|---|---|\n",
        rayon::current_num_threads(),
        triad
    );
    let cases = [32usize, 100, 200].into_iter().flat_map(|n| {
        let mg = Solver::Multigrid;
        [("1/60", 1.0 / 60.0, mg), ("1/30", 1.0 / 30.0, mg)]
            .into_iter()
            // Block Jacobi PCG and the faer Cholesky path beside it (the same filtered
            // system, projected).
            .chain((n == 100).then_some(("1/60", 1.0 / 60.0, Solver::BlockJacobi)))
            .chain((n <= 100).then_some(("1/60", 1.0 / 60.0, Solver::Cholesky)))
            .map(move |(d, dt, solver)| (n, d, dt, solver))
    });
    for (n, dt_name, dt, solver) in cases {
        {
            let id = format!("cloth/step/{n}x{n}/{dt_name}/{}", solver.name());
            if !wanted(&id) {
                continue;
            }
            let cholesky = solver == Solver::Cholesky;
            let mut sim = simulation(n, solver);
            // Drape for 0.5 s so the timed steps have contacts and a deformed sheet.
            while sim.time() < 0.5 {
                sim.step(dt).unwrap();
            }
            let mut infos = Vec::new();
            c.bench_function(&id, |b| b.iter(|| infos.push(sim.step(dt).unwrap())));
            // Timed by hand: the split and the best step.
            let reps = 10;
            let mut times = Vec::with_capacity(reps);
            let (mut solve, mut its) = (0.0, 0);
            for _ in 0..reps {
                let t0 = Instant::now();
                let info = sim.step(dt).unwrap();
                times.push(t0.elapsed().as_secs_f64());
                solve += info.solve_seconds;
                its += info.linear_iterations;
            }
            let (solve, its) = (solve / reps as f64, its as f64 / reps as f64);
            times.sort_by(f64::total_cmp);
            let (best, median) = (times[0], 0.5 * (times[reps / 2 - 1] + times[reps / 2]));
            // Assembly alone, at the current state.
            let cloth = sim.model();
            let nv = cloth.vertex_count();
            let mut work = cloth.work();
            let pattern = cloth.prepare_jacobians(&mut work).unwrap().unwrap();
            let mut kx = Bsr3::zeros(pattern.clone());
            let mut kv = Bsr3::zeros(pattern.clone());
            let mut f = vec![0.0; 3 * nv];
            let (x, v) = (
                sim.state().x.as_slice().to_vec(),
                sim.state().v.as_slice().to_vec(),
            );
            let assembly = (0..reps)
                .map(|_| {
                    let t0 = Instant::now();
                    cloth
                        .force_jacobians(&mut work, 0.0, &x, &v, &mut f, &mut kx, Some(&mut kv))
                        .unwrap();
                    t0.elapsed().as_secs_f64()
                })
                .fold(f64::INFINITY, f64::min);
            let (nt, nh) = (cloth.triangles().len(), cloth.hinges().len());
            let blocks = pattern.nnz_blocks() as f64;
            // Element buffers written and read: per triangle forces and the upper blocks
            // of both Jacobians (6 of 9), per hinge forces and the angle gradient (the
            // gather forms its rank-one blocks); the two matrices written, positions and
            // velocities read.
            let asm_bytes = 2.0 * 8.0 * ((9 + 2 * 54) * nt + (12 + 12) * nh) as f64
                + 2.0 * 72.0 * blocks
                + 48.0 * nv as f64;
            // Bytes per PCG iteration, from a solver set up on this state's system.
            let pcg_bytes = if cholesky {
                0.0
            } else {
                let mut a = Bsr3::zeros(pattern.clone());
                a.assign_lincomb(&[(-dt * dt, &kx), (-dt, &kv)]);
                a.add_diagonal(cloth.mass());
                let mut filter = Filter::new(nv);
                sim.constraints(&mut filter);
                let mut pcg = Pcg::new(nv, solver.pcg());
                let mut z = vec![0.0; 3 * nv];
                pcg.solve(&mut a, &f, &mut z, Some(&filter)).unwrap();
                its * pcg.iteration_bytes(&a) as f64
            };
            md.push_str(&format!(
                "| {id} | {:.1} | {:.2} ms | {:.2} ms | {:.2} ms | {:.0}% | {:.2} ms | {:.0} | {} | {} |\n",
                1.0 / median,
                1e3 * median,
                1e3 * best,
                1e3 * assembly,
                100.0 * asm_bytes / assembly / 1e9 / triad,
                1e3 * solve,
                its,
                if cholesky {
                    "- (factorization)".to_string()
                } else {
                    format!("{:.0}%", 100.0 * pcg_bytes / solve.max(1e-12) / 1e9 / triad)
                },
                sim.contact_count(),
            ));
        }
    }
    kernels(&mut c, triad, &wanted, &mut md);
    println!("\n{md}");
    let dir = std::path::Path::new("target/criterion");
    let _ = std::fs::create_dir_all(dir);
    let _ = std::fs::write(dir.join("cloth-summary.md"), md);
}

/// `cloth/kernel/<element>/<variant>`: the per-element kernels alone, on one core, over
/// all elements of the draped 100x100 sheet (gathers from the state included, as in the
/// assembly): the scalar kernel element by element against the SIMD one four elements
/// per call. Triangles write forces and both Jacobians' upper blocks (936 B each), hinges
/// forces and the angle gradient (192 B each); the fraction of the triad bandwidth counts
/// those writes.
fn kernels(c: &mut Criterion, triad: f64, wanted: &dyn Fn(&str) -> bool, md: &mut String) {
    let n = 100;
    let mut sim = simulation(n, Solver::Multigrid);
    while sim.time() < 0.5 {
        sim.step(1.0 / 60.0).unwrap();
    }
    let cloth = sim.model();
    let nv = cloth.vertex_count();
    let (x, v) = (sim.state().x.as_slice(), sim.state().v.as_slice());
    let m = MATERIAL;
    // The cloth's own element constants.
    let tris = cloth.triangles();
    let rest = cloth.triangle_rest();
    let params = |t: usize| cloth.triangle_params(t);
    let tri3 = |y: &[f64], t: usize| gather_nodes(y, nv, &tris[t]);
    let nt = tris.len() / 4 * 4;
    let (mut tf, mut tkx, mut tkv) = (vec![0.0; 9 * nt], vec![0.0; 54 * nt], vec![0.0; 54 * nt]);
    let mut tri_scalar = || {
        for t in 0..nt {
            triangle_jacobians(
                &rest[t],
                &tri3(x, t),
                &tri3(v, t),
                &params(t),
                &mut tf[9 * t..9 * t + 9],
                &mut tkx[54 * t..54 * t + 54],
                Some(&mut tkv[54 * t..54 * t + 54]),
            );
        }
    };
    let (mut tf4, mut tkx4, mut tkv4) = (vec![0.0; 9 * nt], vec![0.0; 54 * nt], vec![0.0; 54 * nt]);
    let mut tri_x4 = || {
        for t in (0..nt).step_by(4) {
            triangle_jacobians_x4(
                &four(t, |t| rest[t]),
                &four(t, |t| tri3(x, t)),
                &four(t, |t| tri3(v, t)),
                &four(t, params),
                &mut tf4[9 * t..9 * t + 36],
                &mut tkx4[54 * t..54 * t + 216],
                Some(&mut tkv4[54 * t..54 * t + 216]),
            );
        }
    };
    // Hinges, with the cloth's rest angles.
    let theta0 = cloth.rest_angles();
    let hinges = cloth.hinges();
    let hinge4 = |y: &[f64], h: usize| gather_nodes(y, nv, &hinges[h]);
    let nh = hinges.len() / 4 * 4;
    let (k, kd) = (m.bend, m.bend_damping);
    let (mut hf, mut hg) = (vec![0.0; 12 * nh], vec![0.0; 12 * nh]);
    let mut hinge_scalar = || {
        for (h, &rest_angle) in theta0[..nh].iter().enumerate() {
            let r = 12 * h..12 * h + 12;
            bend_force_gradient(
                &hinge4(x, h),
                &hinge4(v, h),
                k,
                kd,
                rest_angle,
                &mut hf[r.clone()],
                &mut hg[r],
            );
        }
    };
    let (mut hf4, mut hg4) = (vec![0.0; 12 * nh], vec![0.0; 12 * nh]);
    let mut hinge_x4 = || {
        for h in (0..nh).step_by(4) {
            let r = 12 * h..12 * h + 48;
            bend_force_gradient_x4(
                &four(h, |h| hinge4(x, h)),
                &four(h, |h| hinge4(v, h)),
                k,
                kd,
                four(h, |h| theta0[h]),
                &mut hf4[r.clone()],
                &mut hg4[r],
            );
        }
    };
    md.push_str(
        "\n| kernel (one core, 100x100 draped) | elements | scalar (best) | x4 (best) | x4 / scalar | x4 writes of triad |\n|---|---|---|---|---|---|\n",
    );
    // Criterion's estimate (when the id is wanted), then the best of 20 for the table.
    let mut best = |id: String, run: &mut dyn FnMut()| -> f64 {
        if wanted(&id) {
            c.bench_function(&id, |b| b.iter(&mut *run));
        }
        (0..20)
            .map(|_| {
                let t0 = Instant::now();
                run();
                t0.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min)
    };
    let mut row =
        |name: &str, count: usize, bytes: usize, scalar: &mut dyn FnMut(), x4: &mut dyn FnMut()| {
            let s = best(format!("cloth/kernel/{name}/scalar"), scalar);
            let q = best(format!("cloth/kernel/{name}/x4"), x4);
            md.push_str(&format!(
                "| {name} | {count} | {:.3} ms | {:.3} ms | {:.2} | {:.0}% |\n",
                1e3 * s,
                1e3 * q,
                q / s,
                100.0 * (bytes * count) as f64 / q / 1e9 / triad,
            ));
        };
    if wanted("cloth/kernel/triangles") {
        row("triangles", nt, 936, &mut tri_scalar, &mut tri_x4);
    }
    if wanted("cloth/kernel/hinges") {
        row("hinges", nh, 192, &mut hinge_scalar, &mut hinge_x4);
    }
    // The two variants agree (tested to the bit in tests/cloth.rs).
    assert!(tf == tf4 && tkx == tkx4 && tkv == tkv4 && hf == hf4 && hg == hg4);
}
