//! Jello-cube benchmarks: the spring force kernel and whole time steps on 8^3 (the
//! assignment), 32^3 and 64^3 lattices, on 1 thread and on all threads.
//!
//! - `jello/forces/<simd|scalar>/<n>/<threads>t`: one evaluation of every spring's force
//!   (`kernels::mass_spring::spring_forces`, SIMD over springs, and its scalar twin), on a
//!   deformed, moving lattice. The memory the kernel must move is counted as streaming
//!   traffic: per spring its two endpoint indices and three constants in, its force out
//!   (8 + 24 + 24 B), plus positions and velocities once (48 B per particle); the summary
//!   divides by the triad bandwidth measured in the same run at the same thread count.
//! - `jello/step/<rk4|lbe>/<n>/<threads>t`: one time step of the assignment's world (k =
//!   200 N/m, d = 0.25, mass 1/512 kg, box and plane penalty springs), RK4 at dt = 5e-4 and
//!   the linearised backward Euler at dt = 5e-3 (Cholesky up to 30,000 unknowns, PCG
//!   above). The 64^3 backward-Euler step is timed by hand (best of 3) instead: a sample
//!   takes seconds.
//!
//! The summary is printed at the end and written to `target/criterion/jello-summary.md`.

use criterion::Criterion;
use largestep::integrate::{MechSettings, Method};
use largestep::kernels::mass_spring::{spring_forces, spring_forces_scalar, Springs};
use largestep::machine::triad_bandwidth;
use largestep::mass_spring::{lattice, CollisionDesc, LatticeOptions, MassSpringDesc};
use largestep::simulation::MechSimulation;
use std::time::{Duration, Instant};

fn cube(n: usize) -> MassSpringDesc {
    let mut d = lattice(&LatticeOptions {
        n: [n; 3],
        origin: [-0.5; 3],
        size: [1.0; 3],
        mass: 1.0 / 512.0,
        structural: 200.0,
        shear: 200.0,
        bend: 200.0,
        damping: 0.25,
    });
    // Deformed and moving, so every spring does real work.
    for (i, p) in d.positions.iter_mut().enumerate() {
        p[0] += 0.01 * ((i * 7919 % 101) as f64 / 101.0 - 0.5) / n as f64;
        p[1] -= 0.6;
    }
    d.velocities = d.positions.iter().map(|p| [p[1], -p[0], 0.3]).collect();
    d.gravity = [0.0, -9.81, 0.0];
    d.collisions = Some(CollisionDesc {
        bounds: Some(([-2.0; 3], [2.0; 3])),
        planes: vec![[-1.0, 1.0, 1.0, 2.0]],
        obstacles: Vec::new(),
        stiffness: 400.0,
        damping: 0.25,
    });
    d
}

struct Row {
    id: String,
    seconds: f64,
    note: String,
}

fn best_of(reps: usize, mut f: impl FnMut()) -> f64 {
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn main() {
    let all = rayon::current_num_threads();
    let pools: Vec<(usize, rayon::ThreadPool)> = [1, all]
        .into_iter()
        .map(|t| {
            (
                t,
                rayon::ThreadPoolBuilder::new()
                    .num_threads(t)
                    .build()
                    .unwrap(),
            )
        })
        .collect();
    let mut c = Criterion::default()
        .configure_from_args()
        .measurement_time(Duration::from_secs(3))
        .sample_size(10);
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let wanted = |id: &str| filter.as_deref().is_none_or(|f| id.contains(f));
    let triad_len = largestep::machine::DEFAULT_TRIAD_MIB * (1 << 20) / 8;
    let mut rows: Vec<Row> = Vec::new();
    let mut force_rows: Vec<(String, usize, f64, f64, f64)> = Vec::new();

    for n in [8usize, 32, 64] {
        let desc = cube(n);
        let (model, state) = desc.build().unwrap();
        let ends = model.spring_ends().to_vec();
        let m = ends.len();
        let k = vec![200.0; m];
        let kd = vec![0.25; m];
        let rest = model.rest_lengths().to_vec();
        let s = || Springs {
            ends: &ends,
            k: &k,
            kd: &kd,
            rest: &rest,
        };
        let (x, v) = (state.x.as_slice(), state.v.as_slice());
        let mut fa = vec![0.0; 3 * m];
        let bytes = 56.0 * m as f64 + 48.0 * (n * n * n) as f64;
        for (threads, pool) in &pools {
            let triad = pool.install(|| triad_bandwidth(triad_len, 3));
            for (variant, simd) in [("simd", true), ("scalar", false)] {
                if !simd && *threads > 1 {
                    continue;
                }
                let id = format!("jello/forces/{variant}/{n}^3/{threads}t");
                if !wanted(&id) {
                    continue;
                }
                let mut run = || {
                    if simd {
                        spring_forces(&mut fa, x, v, s());
                    } else {
                        spring_forces_scalar(&mut fa, x, v, s());
                    }
                };
                c.bench_function(&id, |b| b.iter(|| pool.install(&mut run)));
                let t = best_of(20, || pool.install(&mut run));
                force_rows.push((id, m, t, bytes / t / 1e9, triad));
            }
        }

        for (name, method, dt) in [
            ("rk4", Method::Rk4, 5e-4),
            ("lbe", Method::LinearizedBackwardEuler, 5e-3),
        ] {
            for (threads, pool) in &pools {
                let id = format!("jello/step/{name}/{n}^3/{threads}t");
                if !wanted(&id) {
                    continue;
                }
                let (model, st) = desc.build().unwrap();
                let mut sim = pool
                    .install(|| MechSimulation::new(model, st, MechSettings::new(method)))
                    .unwrap();
                let mut step = || {
                    pool.install(|| sim.step(dt).unwrap());
                };
                step(); // first step builds the solver structures
                let seconds = if n == 64 && name == "lbe" {
                    best_of(3, &mut step)
                } else {
                    c.bench_function(&id, |b| b.iter(&mut step));
                    best_of(10, &mut step)
                };
                rows.push(Row {
                    id,
                    seconds,
                    note: format!("{} particles, {} springs, dt = {dt}", n * n * n, m),
                });
            }
        }
    }

    let mut md = String::from(
        "| kernel | springs | best | Gsprings/s | GB/s (streaming model) | of triad |\n|---|---|---|---|---|---|\n",
    );
    for (id, m, t, gbs, triad) in &force_rows {
        md.push_str(&format!(
            "| {id} | {m} | {:.3} ms | {:.3} | {gbs:.1} | {:.0}% |\n",
            1e3 * t,
            *m as f64 / t / 1e9,
            100.0 * gbs / triad
        ));
    }
    md.push_str("\n| step | best | note |\n|---|---|---|\n");
    for r in &rows {
        md.push_str(&format!(
            "| {} | {:.3} ms | {} |\n",
            r.id,
            1e3 * r.seconds,
            r.note
        ));
    }
    println!("\n{md}");
    let dir = std::path::Path::new("target/criterion");
    let _ = std::fs::create_dir_all(dir);
    let _ = std::fs::write(dir.join("jello-summary.md"), md);
}
