//! Fluid benchmarks of issue 17.
//!
//! - `fluid/poisson/multigrid/128`: the 7-point pressure Poisson problem on 128^3 cells
//!   (the unit box, walls all round except an open top, a solid ball of radius 0.2 in the
//!   middle, a rough right side: `largestep::study::poisson_problem`) to a relative
//!   residual of 1e-6, setup (the multigrid hierarchy) included, all threads. Reported
//!   beside it: nanoseconds and bytes per cell-iteration against the triad bandwidth
//!   measured right before. The peers (PyAMG's classical AMG as a CG preconditioner and
//!   SciPy's plain CG on the same matrix) are in `benches/peers/pyamg-poisson`; the bench
//!   writes the cell kinds and the right side to `target/criterion/poisson-128.bin` for
//!   them.
//! - `fluid/smoke-step/128`: one step of 3-D smoke at 128^3 cells (the smoke scene's
//!   buoyancy, vorticity confinement and MacCormack advection, from a state 10 steps in).
//! - `fluid/volume-render/1280x720/128`: one 1280 x 720 volume rendering of a 128^3
//!   plume of Gaussian puffs with a ball beside it (the f32 copies, the light sweep, the
//!   skipping blocks and their clearance included).
//!
//! Run with `cargo bench --bench fluid` (`-- poisson` for one part); the summary is
//! printed and written to `target/criterion/fluid-summary.md`.

use criterion::Criterion;
use largestep::collide::Obstacle;
use largestep::fluid::scene::FluidSim;
use largestep::fluid::{Boundary, Buoyancy, Correction, FluidDesc, Source};
use largestep::io::Image;
use largestep::render::volume::{VolumeRenderer, VolumeSettings};
use largestep::solve::{GridPoisson, PoissonParams, Precision, Side};
use std::io::Write;
use std::time::{Duration, Instant};

fn main() {
    let mut c = Criterion::default()
        .configure_from_args()
        .measurement_time(Duration::from_secs(10))
        .sample_size(10);
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let wanted = |id: &str| filter.as_deref().is_none_or(|f| id.contains(f));
    let mut md = String::from("# Fluid benchmarks\n\n");
    if wanted("fluid/poisson") {
        md += &poisson(&mut c);
    }
    if wanted("fluid/smoke-step") {
        md += &smoke(&mut c);
    }
    if wanted("fluid/volume-render") {
        md += &volume(&mut c);
    }
    println!("\n{md}");
    let dir = std::path::Path::new("target/criterion");
    let _ = std::fs::create_dir_all(dir);
    let _ = std::fs::write(dir.join("fluid-summary.md"), md);
}

fn poisson(c: &mut Criterion) -> String {
    let n = 128;
    let (cells, h, kind, b) = largestep::study::poisson_problem(n);
    // The peers' input: n, then one byte per cell kind, then the right side as f64.
    let dir = std::path::Path::new("target/criterion");
    let _ = std::fs::create_dir_all(dir);
    if let Ok(mut f) = std::fs::File::create(dir.join("poisson-128.bin")) {
        let _ = f.write_all(&(n as u64).to_le_bytes());
        let bytes: Vec<u8> = kind.iter().map(|&k| k as u8).collect();
        let _ = f.write_all(&bytes);
        for v in &b {
            let _ = f.write_all(&v.to_le_bytes());
        }
    }
    let sides = [[Side::Wall; 2], [Side::Wall, Side::Open], [Side::Wall; 2]];
    let run = |precision| {
        let params = PoissonParams {
            precision,
            ..PoissonParams::default()
        };
        let t0 = Instant::now();
        let mut g = GridPoisson::with_sides(cells, h, kind.clone(), sides).unwrap();
        let setup = t0.elapsed().as_secs_f64();
        // The caller's solution on huge pages too (`ZeroedBuf`), as a simulation keeps
        // its pressure.
        let mut p = largestep::soa::ZeroedBuf::<f64>::new(b.len());
        (g.solve(&mut p, &b, &params).unwrap(), setup)
    };
    let triad = largestep::machine::triad_bandwidth(
        largestep::machine::DEFAULT_TRIAD_MIB * (1 << 20) / 8,
        3,
    );
    c.bench_function("fluid/poisson/multigrid/128", |bch| {
        bch.iter(|| run(Precision::default()))
    });
    let mut md = String::from(
        "## Poisson, 128^3 cells to 1e-6 (setup included)\n\n| preconditioner | time, best of 3 | per cell-iteration |\n|---|---|---|\n",
    );
    // The f64 cycle beside the default f32 one: what single precision pays.
    for (precision, name) in [
        (Precision::Single, "V-cycle in f32 (default)"),
        (Precision::Double, "V-cycle in f64"),
    ] {
        let mut best = f64::INFINITY;
        let mut its = 0;
        let (mut solve_best, mut setup_best) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..3 {
            let t0 = Instant::now();
            let (info, setup) = run(precision);
            best = best.min(t0.elapsed().as_secs_f64());
            solve_best = solve_best.min(info.seconds);
            setup_best = setup_best.min(setup);
            its = info.iterations;
        }
        let cells_n = b.len() as f64;
        let ns = solve_best * 1e9 / (cells_n * its as f64);
        // Bytes per cell-iteration, counted for the f64 cycle: CG's product (x and y,
        // and the one-byte cell code: 17), its update, dots and direction (about 90),
        // the V-cycle's fine level (6 sweeps reading x, b and the code and writing x':
        // 150; the residual 25; restriction and prolongation 32) and the coarse levels
        // (1/7 more): about 350 bytes. The f32 cycle moves about 230.
        let bytes = match precision {
            Precision::Single => 230.0,
            Precision::Double => 350.0,
        };
        let rate = bytes * cells_n * its as f64 / solve_best / 1e9;
        md += &format!(
            "| {name} | {best:.3} s (setup {setup_best:.3} s, solve {solve_best:.3} s, {its} iterations) | {ns:.1} ns, about {bytes:.0} bytes: {rate:.1} GB/s, {:.0}% of the triad bandwidth ({triad:.1} GB/s) |\n",
            100.0 * rate / triad
        );
    }
    md + "\n"
}

fn smoke(c: &mut Criterion) -> String {
    let n = 128;
    let d = FluidDesc {
        cells: [n, n, n],
        h: 1.0 / n as f64,
        boundaries: [
            [Boundary::Wall; 2],
            [Boundary::Wall, Boundary::Open],
            [Boundary::Wall; 2],
        ],
        buoyancy: Some(Buoyancy {
            up: [0.0, 1.0, 0.0],
            smoke: 0.05,
            heat: 1.5,
            ambient: 0.0,
        }),
        vorticity: 2.0,
        advection: largestep::fluid::Advection {
            correction: Correction::MacCormack,
            ..Default::default()
        },
        sources: vec![Source {
            shape: Obstacle::Sphere {
                center: [0.5, 0.15, 0.5],
                radius: 0.08,
            },
            density: Some(1.0),
            temperature: Some(1.0),
            velocity: Some([0.0, 0.5, 0.0]),
            until: f64::INFINITY,
        }],
        obstacles: vec![Obstacle::Sphere {
            center: [0.55, 0.6, 0.5],
            radius: 0.15,
        }],
        ..FluidDesc::default()
    };
    let mut sim = FluidSim::new(&d).unwrap();
    for _ in 0..3 {
        sim.advance(0.02).unwrap();
    }
    let mut md = String::new();
    {
        let start = sim.state().clone();
        c.bench_function("fluid/smoke-step/128", |b| {
            b.iter(|| {
                *sim.state_mut() = start.clone();
                sim.advance(0.02).unwrap()
            })
        });
        let t0 = Instant::now();
        *sim.state_mut() = start.clone();
        let info = sim.advance(0.02).unwrap();
        md += &format!(
            "## Smoke step, 128^3 cells\n\n{:.2} s for one step ({} sub-steps, {} pressure iterations, {:.2} s in the solves)\n\n",
            t0.elapsed().as_secs_f64(),
            info.substeps,
            info.pressure_iterations,
            info.solve_seconds
        );
    }
    md
}

/// A 128^3 plume for the renderer: a column of Gaussian puffs rising and widening, with a
/// ball beside it (an obstacle the renderer draws as a surface).
fn volume(c: &mut Criterion) -> String {
    let n = 128;
    let h = 1.0 / n as f64;
    let puffs: Vec<([f64; 3], f64)> = (0..24)
        .map(|k| {
            let t = k as f64 / 23.0;
            let wobble = (7.0 * t).sin() * 0.08;
            (
                [0.5 + wobble, 0.12 + 0.75 * t, 0.5 + (5.0 * t).cos() * 0.05],
                0.04 + 0.08 * t,
            )
        })
        .collect();
    let mut density = vec![0.0; n * n * n];
    let mut solid = vec![false; n * n * n];
    for (i, d) in density.iter_mut().enumerate() {
        let p = [
            (i % n) as f64 + 0.5,
            ((i / n) % n) as f64 + 0.5,
            (i / (n * n)) as f64 + 0.5,
        ]
        .map(|x| x * h);
        let mut v = 0.0f64;
        for (c, r) in &puffs {
            let d2: f64 = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum();
            v += (-d2 / (r * r)).exp();
        }
        *d = v.min(1.0);
        let s2: f64 = [p[0] - 0.75, p[1] - 0.55, p[2] - 0.5]
            .iter()
            .map(|x| x * x)
            .sum();
        solid[i] = s2 < 0.12 * 0.12;
    }
    let filled = density.iter().filter(|&&d| d > 0.01).count() as f64 / density.len() as f64;
    let g = largestep::simulation::GridRef {
        cells: [n; 3],
        h,
        origin: [0.0; 3],
        solid: Some(&solid),
        fields: vec![largestep::simulation::GridField::Density(&density)],
    };
    let mut r = VolumeRenderer::default();
    let mut im = Image::default();
    let s = VolumeSettings::default();
    c.bench_function("fluid/volume-render/1280x720/128", |b| {
        b.iter(|| r.render(&g, &s, &mut im).unwrap())
    });
    let mut best = f64::INFINITY;
    for _ in 0..5 {
        let t0 = Instant::now();
        r.render(&g, &s, &mut im).unwrap();
        best = best.min(t0.elapsed().as_secs_f64());
    }
    let dir = std::path::Path::new("target/criterion");
    if let Ok(mut f) = std::fs::File::create(dir.join("volume-render.png")) {
        let _ = largestep::io::write_png(&mut f, &im);
    }
    format!(
        "## Volume rendering, 1280 x 720 of 128^3\n\n{:.1} ms, best of 5 (conversion to f32, skipping blocks and the light sweep included); {:.0}% of the cells hold smoke; the picture: `target/criterion/volume-render.png`\n\n",
        1e3 * best,
        100.0 * filled
    )
}
