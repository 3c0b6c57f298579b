//! Tetrahedral FEM benchmarks on the beam of issue 15: 1 m x 0.1 m x 0.1 m, 100 x 10 x 10
//! cubes split into six tetrahedra each (12,221 vertices, 60,000 tetrahedra), clamped at
//! x = 0, sagging under gravity; corotational elasticity (E = 10 MPa, nu = 0.3, 1000
//! kg/m^3), the definiteness fix on. The timed state is the beam after 0.5 s of backward
//! Euler from straight (its tip sags and swings; the elements are rotated and strained).
//!
//! - `fem/kernel/{scalar,x4,x8,x16}`: every element's forces and ten stiffness blocks
//!   (`largestep_kernels::fem_diag::element`, the generic kernel at `f64`; `element_x4`,
//!   four elements per `f64x4`; `element_x8`, two such groups whose SVDs run
//!   interleaved, as the model calls it without AVX-512; `element_x16`, two groups of
//!   eight in `f64x8`, as it calls it with AVX-512), on one core, positions gathered
//!   from the state (`Fem::elements`). Their flops are counted by running the same generic kernel on a
//!   counting number type over the same elements (an FMA counts 2, every other
//!   arithmetic operation, square root, comparison and selection 1), and reported against
//!   one core's FMA peak, measured right before and after the timing (`machine::peak_fma`,
//!   over the threads, divided by them; the higher of the two), 4-wide (the kernels'
//!   `f64x4` width) and 8-wide: on a machine with AVX-512 the 8-wide peak is twice the
//!   4-wide one, and it is the machine's limit.
//!   `fem/kernel/{x4,x8}-cached` make the same calls with every group's outputs in one
//!   reused buffer: the kernel's arithmetic rate, where `x4` and `x8` also pay for
//!   writing the 43 MB of stiffness blocks that the model's gather reads.
//! - `fem/assembly`: `Fem::force_jacobians` on all threads: the kernels, the gather of
//!   the forces and the stiffness blocks into the block-sparse matrix (deterministic, in
//!   a fixed order). The difference from the parallel kernel time is the gather.
//! - `fem/sa/{setup,vcycle}`: the smoothed aggregation on a step's matrix `M - h^2 K` at
//!   the timed state (all threads): a setup of the values (the pattern's part kept, as
//!   in every step but the first), and one V-cycle (`SmoothedAggregation::apply`) with
//!   the bytes it reads at least (`cycle_bytes`) against the triad bandwidth measured
//!   right after. The cycle reads about twice the former machine's 32 MB L3, so it
//!   streamed from memory there; the present one's L3 is 480 MiB, so the cycle may be
//!   served from cache and its fraction of the triad may pass 100%.
//! - `fem/step/<solver>`: one backward Euler step at dt = 1/60 s, Newton iterated until
//!   the residual falls by 1e-6 or the velocity change per iteration is below 1e-6 of the
//!   velocities (`MechSettings::new`), with sparse Cholesky or PCG (relative tolerance
//!   1e-6 per linear solve) with the aggregation multigrid (`pcg-mg`) or the smoothed
//!   aggregation with rigid-body modes (`pcg-sa`) as preconditioner; `-reuse`: the
//!   Jacobian assembled and factored once per step and reused by the later iterations
//!   (`MechSettings::reuse_jacobian` = 1, the chord method); `-reuse-10`: one Jacobian
//!   serves up to ten steps. Measured before it: the
//!   factorization was 75% of a Cholesky step (perf), four per step. `-forcing`: inexact
//!   Newton (`NewtonParams::forcing` = 0.5), each PCG solve only as tight as the
//!   Eisenstat-Walker forcing term asks, 1e-6 at the tightest; `-forcing-1e-3`: the same
//!   with Newton to 1e-3 (on 30 steps from rest it moved the tip by at most 2.4e-5 m
//!   from steps solved to 1e-9, of a 0.24 m swing); `-keep`: PCG's hierarchy kept for
//!   up to 30 steps (`MechSettings::reuse_preconditioner` = 30), a new one sooner after a
//!   step whose PCG iterations per Newton iteration grew past 1.25 times those of the
//!   step that made it, plus half. The rows have the
//!   defaults' predictor (Newton's first guess from the last step's velocity change);
//!   `-f32` adds PCG's products with the multigrid's `f32` copy of the matrix
//!   (`MechSettings::rounded_products`, off by default), `-plain` has the predictor off
//!   (as before 2026-12-02); `-rate` has Newton's rate test (`NewtonParams::rate_test`,
//!   Hairer and Wanner's estimate of the error left), the second-order predictor
//!   (`MechSettings::second_order_predictor`) and forcing 0.1, `-rate-f32` the same with
//!   PCG's products in `f32`; `-skip` adds `NewtonParams::skip_last_residual` (the step
//!   the rate test accepts is taken without its residual: the same steps to the bit, one
//!   force evaluation fewer a step); `-warped` adds the corotational material's warped
//!   tangent (`FemDesc::warped_tangent`: Newton's Jacobian `R K0 R^T` per element, the
//!   forces exact; its kernel needs no SVD). The summary gives the
//!   Newton iterations and the last linear solve's residual of the timed steps, and the
//!   worst velocity error of six more steps against the same steps solved to 1e-10,
//!   `|v - v*| / (1 + |v*|)`, the quantity Newton's tolerance bounds.
//!
//! The peer (`benches/peers/rapier-fem`) steps the same mesh in rapier3d's FEM soft body.
//! Run with `cargo bench --bench fem`; the summary is printed at the end and written to
//! `target/criterion/fem-summary.md`.

use criterion::Criterion;
use largestep::fem::mesh::box_mesh;
use largestep::fem::{Fem, FemDesc, FemMaterial, FemWork, Material};
use largestep::integrate::{LinearSolverKind, MechSettings, Method};
use largestep::kernels::fem_diag::{
    corotational_warped, corotational_warped_x16, element, element_x16, element_x4, element_x8,
    Iso, Lane,
};
use largestep::kernels::gather_nodes;
use largestep::machine::{triad_bandwidth, DEFAULT_TRIAD_MIB};
use largestep::simulation::{MechModel, MechSimulation};
use largestep::solve::amg::SmoothedAggregation;
use largestep::solve::{PcgParams, Preconditioner};
use largestep::sparse::Bsr3;
use std::cell::Cell;
use std::ops::{Add, Div, Mul, Neg, Sub};
use std::time::{Duration, Instant};

const DT: f64 = 1.0 / 60.0;

/// The most steps the `-keep` rows' PCG hierarchy serves (it is made again sooner when
/// the steps slow; see the module docs).
const KEEP: usize = 30;

fn beam() -> FemDesc {
    FemDesc::cantilever(
        [100, 10, 10],
        [1.0, 0.1, 0.1],
        FemMaterial {
            model: Material::Corotational,
            young: 1e7,
            poisson: 0.3,
            density: 1000.0,
        },
        9.81,
    )
}

/// How a timed step solves: the linear solver (sparse Cholesky for `None`, or PCG with a
/// preconditioner), the steps one Jacobian and one PCG hierarchy may serve, the inexact
/// Newton forcing (`None`: each PCG solve to 1e-6) and Newton's tolerance; Newton's first
/// guess from the last step (`MechSettings::predictor`, on by default) and PCG's products
/// in `f32` (`MechSettings::rounded_products`, off by default).
#[derive(Clone, Copy)]
struct Solver {
    pcg: Option<Preconditioner>,
    reuse: usize,
    keep: usize,
    forcing: Option<f64>,
    newton: f64,
    predictor: bool,
    rounded: bool,
    rate: bool,
    skip: bool,
    /// The corotational material's warped tangent (`FemDesc::warped_tangent`).
    warped: bool,
}

fn solver(
    pcg: Option<Preconditioner>,
    reuse: usize,
    keep: usize,
    forcing: Option<f64>,
    newton: f64,
) -> Solver {
    Solver {
        pcg,
        reuse,
        keep,
        forcing,
        newton,
        predictor: true,
        rounded: false,
        rate: false,
        skip: false,
        warped: false,
    }
}

fn settings(solver: Solver) -> MechSettings {
    let Solver {
        pcg,
        reuse,
        keep,
        forcing,
        newton,
        predictor,
        rounded,
        rate,
        skip,
        warped: _,
    } = solver;
    let mut s = MechSettings::new(Method::BackwardEuler);
    s.reuse_jacobian = reuse;
    s.reuse_preconditioner = keep;
    s.newton.tolerance = newton;
    s.newton.step_tolerance = newton;
    s.newton.forcing = forcing;
    s.predictor = predictor;
    s.rounded_products = rounded;
    s.newton.rate_test = rate;
    s.newton.skip_last_residual = skip;
    s.second_order_predictor = rate;
    s.linear = match pcg {
        None => LinearSolverKind::Cholesky,
        Some(preconditioner) => LinearSolverKind::Pcg(PcgParams {
            tolerance: 1e-6,
            max_iterations: 2000,
            preconditioner,
        }),
    };
    s
}

fn simulation(solver: Solver) -> MechSimulation<Fem> {
    let mut desc = beam();
    desc.warped_tangent = solver.warped;
    let (fem, state) = desc.build().unwrap();
    let mut sim = MechSimulation::new(fem, state, settings(solver)).unwrap();
    sim.set_step_control(None);
    sim
}

thread_local! {
    static FLOPS: Cell<u64> = const { Cell::new(0) };
}

/// A number that counts the operations done on it (see the module docs).
#[derive(Clone, Copy)]
struct Counted(f64);

fn tally(n: u64) {
    FLOPS.with(|c| c.set(c.get() + n));
}

macro_rules! counted_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for Counted {
            type Output = Counted;
            fn $f(self, o: Counted) -> Counted {
                tally(1);
                Counted(self.0 $op o.0)
            }
        }
    };
}
counted_op!(Add, add, +);
counted_op!(Sub, sub, -);
counted_op!(Mul, mul, *);
counted_op!(Div, div, /);

impl Neg for Counted {
    type Output = Counted;
    fn neg(self) -> Counted {
        tally(1);
        Counted(-self.0)
    }
}

impl Lane for Counted {
    fn splat(v: f64) -> Self {
        Counted(v)
    }
    fn fma(self, m: Self, a: Self) -> Self {
        tally(2);
        Counted(self.0.mul_add(m.0, a.0))
    }
    fn sqrt(self) -> Self {
        tally(1);
        Counted(self.0.sqrt())
    }
    fn abs(self) -> Self {
        tally(1);
        Counted(self.0.abs())
    }
    fn max(self, o: Self) -> Self {
        tally(1);
        Counted(self.0.max(o.0))
    }
    fn ln(self) -> Self {
        tally(1);
        Counted(self.0.ln())
    }
    fn if_lt(a: Self, b: Self, x: Self, y: Self) -> Self {
        tally(2);
        if a.0 < b.0 {
            x
        } else {
            y
        }
    }
    fn any_not_positive(self) -> bool {
        tally(1);
        self.0.is_nan() || self.0 <= 0.0
    }
}

fn main() {
    let mut c = Criterion::default()
        .configure_from_args()
        .measurement_time(Duration::from_secs(5))
        .sample_size(10);
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let wanted = |id: &str| filter.as_deref().is_none_or(|f| id.contains(f));
    let threads = rayon::current_num_threads();
    let mut md = format!("threads: {threads}\n\n");

    // The timed state: 0.5 s of sagging.
    let mut sim = simulation(solver(None, 1, 0, None, 1e-6));
    let t0 = Instant::now();
    while sim.time() < 0.5 - 1e-9 {
        sim.step(DT).unwrap();
    }
    md.push_str(&format!(
        "state: the beam after 0.5 s of backward Euler (30 steps, {:.1} s), tip y {:.4} m\n\n",
        t0.elapsed().as_secs_f64(),
        tip(&sim)
    ));
    let x = sim.state().x.as_slice().to_vec();
    let v = sim.state().v.as_slice().to_vec();
    kernels(&mut c, &wanted, &mut md, sim.model(), &x);

    // Assembly: the model's force_jacobians, all threads.
    if wanted("fem/assembly") {
        let fem = sim.model();
        let (mut work, mut f, mut k) = jacobian(fem, &x, &v);
        let pattern = k.pattern().clone();
        let mut run = || {
            f.fill(0.0);
            fem.force_jacobians(&mut work, 0.0, &x, &v, &mut f, &mut k, None)
                .unwrap();
        };
        c.bench_function("fem/assembly", |b| b.iter(&mut run));
        let best = best_of(10, &mut run);
        md.push_str(&format!(
            "\n| assembly (all threads) | best | per element |\n|---|---|---|\n| `Fem::force_jacobians`: kernels, gather of forces and {} blocks | {:.2} ms | {:.0} ns |\n",
            pattern.nnz_blocks(),
            1e3 * best,
            1e9 * best / fem.tets().len() as f64
        ));
    }

    // The smoothed aggregation's setup and one V-cycle on a step's matrix `M - h^2 K`.
    if wanted("fem/sa") {
        let fem = sim.model();
        let n = fem.vertex_count();
        let (_, _, k) = jacobian(fem, &x, &v);
        let mut a = Bsr3::zeros(k.pattern().clone());
        a.assign_lincomb(&[(-DT * DT, &k)]);
        a.add_scaled_diagonal(1.0, fem.mass());
        let mut sa = SmoothedAggregation::new();
        sa.set_coordinates(&x);
        sa.setup(&a, None).unwrap();
        let r: Vec<f64> = (0..3 * n)
            .map(|i| ((i * 7919) % 1000) as f64 / 1000.0 - 0.5)
            .collect();
        let mut setup = || sa.setup(&a, None).unwrap();
        c.bench_function("fem/sa/setup", |b| b.iter(&mut setup));
        let setup_best = best_of(10, &mut setup);
        let mut z = vec![0.0; 3 * n];
        let mut run = || sa.apply(&a, &r, &mut z, None);
        c.bench_function("fem/sa/vcycle", |b| b.iter(&mut run));
        let best = best_of(20, &mut run);
        let triad = triad_bandwidth(DEFAULT_TRIAD_MIB * (1 << 20) / 8, 3);
        let bytes = sa.cycle_bytes(&a) as f64;
        md.push_str(&format!(
            "\n| smoothed aggregation on `M - h^2 K` (all threads), unknowns per level {:?} | best | bytes read at least | GB/s | of the triad ({triad:.1} GB/s, measured after) |\n|---|---|---|---|---|\n| setup (`SmoothedAggregation::setup`, the pattern's part kept) | {:.1} ms | | | |\n| V-cycle (`SmoothedAggregation::apply`) | {:.2} ms | {:.1} MB | {:.1} | {:.0}% |\n",
            sa.level_sizes(),
            1e3 * setup_best,
            1e3 * best,
            bytes / 1e6,
            bytes / best / 1e9,
            100.0 * bytes / best / 1e9 / triad
        ));
    }

    md.push_str("\n| step (dt = 1/60, backward Euler) | Newton tolerance | median | best | Newton iterations | linear iterations | last linear solve, relative residual (worst) | velocity error (worst) |\n|---|---|---|---|---|---|---|---|\n");
    let (mg, sa) = (
        Some(Preconditioner::Multigrid),
        Some(Preconditioner::SmoothedAggregation),
    );
    for (name, solver) in [
        ("cholesky", solver(None, 0, 0, None, 1e-6)),
        ("cholesky-reuse", solver(None, 1, 0, None, 1e-6)),
        ("cholesky-reuse-10", solver(None, 10, 0, None, 1e-6)),
        ("pcg-mg", solver(mg, 0, 0, None, 1e-6)),
        ("pcg-mg-reuse", solver(mg, 1, 0, None, 1e-6)),
        ("pcg-sa", solver(sa, 0, 0, None, 1e-6)),
        ("pcg-sa-reuse", solver(sa, 1, 0, None, 1e-6)),
        ("pcg-sa-reuse-10", solver(sa, 10, 0, None, 1e-6)),
        // Inexact Newton: each PCG solve only as tight as the Eisenstat-Walker forcing term.
        ("pcg-sa-reuse-forcing", solver(sa, 1, 0, Some(0.5), 1e-6)),
        (
            "pcg-sa-reuse-forcing-1e-3",
            solver(sa, 1, 0, Some(0.5), 1e-3),
        ),
        // The hierarchy kept for up to KEEP steps (`MechSettings::reuse_preconditioner`).
        (
            "pcg-sa-reuse-forcing-keep",
            solver(sa, 1, KEEP, Some(0.5), 1e-6),
        ),
        (
            "pcg-sa-reuse-forcing-keep-1e-3",
            solver(sa, 1, KEEP, Some(0.5), 1e-3),
        ),
        // The same with PCG's products in f32, and without the predictor (as before
        // 2026-12-02).
        (
            "pcg-sa-reuse-forcing-keep-1e-3-f32",
            Solver {
                rounded: true,
                ..solver(sa, 1, KEEP, Some(0.5), 1e-3)
            },
        ),
        (
            "pcg-sa-reuse-forcing-keep-1e-3-plain",
            Solver {
                predictor: false,
                ..solver(sa, 1, KEEP, Some(0.5), 1e-3)
            },
        ),
        // Newton's rate test with the second-order predictor, forcing 0.1.
        (
            "pcg-sa-reuse-forcing-keep-1e-3-rate",
            Solver {
                rate: true,
                ..solver(sa, 1, KEEP, Some(0.1), 1e-3)
            },
        ),
        (
            "pcg-sa-reuse-forcing-keep-1e-3-rate-f32",
            Solver {
                rate: true,
                rounded: true,
                ..solver(sa, 1, KEEP, Some(0.1), 1e-3)
            },
        ),
        // ... taking the accepted step without evaluating its residual.
        (
            "pcg-sa-reuse-forcing-keep-1e-3-rate-skip",
            Solver {
                rate: true,
                skip: true,
                ..solver(sa, 1, KEEP, Some(0.1), 1e-3)
            },
        ),
        (
            "pcg-sa-reuse-forcing-keep-1e-3-rate-f32-skip",
            Solver {
                rate: true,
                rounded: true,
                skip: true,
                ..solver(sa, 1, KEEP, Some(0.1), 1e-3)
            },
        ),
        // ... with the warped tangent R K0 R^T (no SVD in the assembly's kernel).
        (
            "pcg-sa-reuse-forcing-keep-1e-3-rate-f32-skip-warped",
            Solver {
                rate: true,
                rounded: true,
                skip: true,
                warped: true,
                ..solver(sa, 1, KEEP, Some(0.1), 1e-3)
            },
        ),
    ] {
        let id = format!("fem/step/{name}");
        if !wanted(&id) {
            continue;
        }
        let mut s = simulation(solver);
        while s.time() < 0.5 - 1e-9 {
            s.step(DT).unwrap();
        }
        c.bench_function(&id, |b| b.iter(|| s.step(DT).unwrap()));
        let mut times = Vec::new();
        let (mut newton, mut linear) = (0, 0);
        let mut residual: f64 = 0.0;
        for _ in 0..6 {
            let t = Instant::now();
            let info = s.step(DT).unwrap();
            times.push(t.elapsed().as_secs_f64());
            newton += info.newton_iterations;
            linear += info.linear_iterations;
            residual = residual.max(info.residual);
        }
        let error = step_error(&mut s, solver);
        times.sort_by(f64::total_cmp);
        md.push_str(&format!(
            "| {id} | {:.0e} | {:.1} ms | {:.1} ms | {:.1} | {:.0} | {residual:.1e} | {error:.1e} |\n",
            solver.newton,
            1e3 * 0.5 * (times[2] + times[3]),
            1e3 * times[0],
            newton as f64 / 6.0,
            linear as f64 / 6.0
        ));
    }
    println!("\n{md}");
    let dir = std::path::Path::new("target/criterion");
    let _ = std::fs::create_dir_all(dir);
    let _ = std::fs::write(dir.join("fem-summary.md"), md);
}

/// The worst velocity error of six more steps of `s`, each against the same step from
/// the same state solved to 1e-10 (full Newton, PCG to 1e-11, no first guess), relative:
/// `|v - v*| / (1 + |v*|)`, what the Newton tolerance bounds.
fn step_error(s: &mut MechSimulation<Fem>, solver: Solver) -> f64 {
    let mut tight = settings(solver);
    tight.reuse_jacobian = 0;
    tight.reuse_preconditioner = 0;
    tight.newton.tolerance = 1e-10;
    tight.newton.step_tolerance = 1e-10;
    tight.newton.forcing = None;
    tight.newton.rate_test = false;
    tight.predictor = false;
    tight.second_order_predictor = false;
    tight.rounded_products = false;
    tight.linear = LinearSolverKind::Pcg(PcgParams {
        tolerance: 1e-11,
        max_iterations: 4000,
        preconditioner: Preconditioner::SmoothedAggregation,
    });
    let (fem, state) = beam().build().unwrap();
    let mut reference = MechSimulation::new(fem, state, tight).unwrap();
    reference.set_step_control(None);
    let mut worst: f64 = 0.0;
    for _ in 0..6 {
        *reference.state_mut() = s.state().clone();
        s.step(DT).unwrap();
        reference.step(DT).unwrap();
        let (v, w) = (s.state().v.as_slice(), reference.state().v.as_slice());
        let norm = w.iter().map(|w| w * w).sum::<f64>().sqrt();
        let err = v.iter().zip(w).map(|(v, w)| (v - w).powi(2)).sum::<f64>();
        worst = worst.max(err.sqrt() / (1.0 + norm));
    }
    worst
}

/// An element kernel's outputs (forces, stiffness) and inputs (vertices, `Dm^-1`,
/// volume, Lamé constants) in counted numbers.
type CountedElement = ([[Counted; 3]; 4], [Counted; 90]);
type CountedInputs = ([[Counted; 3]; 4], [Counted; 9], Counted, [Counted; 2]);

/// The model's scratch, its forces and `df/dx` at `(x, v)`, assembled once.
fn jacobian(fem: &Fem, x: &[f64], v: &[f64]) -> (FemWork, Vec<f64>, Bsr3) {
    let mut work = fem.work();
    let pattern = fem.prepare_jacobians(&mut work).unwrap().unwrap();
    let mut k = Bsr3::zeros(pattern);
    let mut f = vec![0.0; 3 * fem.vertex_count()];
    fem.force_jacobians(&mut work, 0.0, x, v, &mut f, &mut k, None)
        .unwrap();
    (work, f, k)
}

/// `call(e, f, k)` for the groups of w elements `e..e + w` of the first ne, with their
/// slices of f (12 per element) and k (90 per element).
fn each_group(
    ne: usize,
    w: usize,
    f: &mut [f64],
    k: &mut [f64],
    mut call: impl FnMut(usize, &mut [f64], &mut [f64]),
) {
    let groups = f.chunks_exact_mut(12 * w).zip(k.chunks_exact_mut(90 * w));
    for (e, (f, k)) in (0..ne).step_by(w).zip(groups) {
        call(e, f, k);
    }
}

/// Mean y of the free end's vertices.
fn tip(sim: &MechSimulation<Fem>) -> f64 {
    let x = sim.state().x.as_slice();
    let n = x.len() / 3;
    let rest = box_mesh([100, 10, 10], [1.0, 0.1, 0.1], [0.0, -0.05, -0.05]).positions;
    let end: Vec<usize> = (0..n).filter(|&i| rest[i][0] > 1.0 - 1e-12).collect();
    end.iter().map(|&i| x[n + i] - rest[i][1]).sum::<f64>() / end.len() as f64
}

fn best_of(reps: usize, run: &mut dyn FnMut()) -> f64 {
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            run();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The element kernels alone on one core (see the module docs).
fn kernels(
    c: &mut Criterion,
    wanted: &dyn Fn(&str) -> bool,
    md: &mut String,
    fem: &Fem,
    x: &[f64],
) {
    let n = fem.vertex_count();
    let tets = fem.tets();
    let ne = tets.len() / 16 * 16;
    let iso = Iso {
        material: Material::Corotational,
        clamp: None,
        project: true,
        warped: false,
    };
    let lame = |e: usize| fem.lame_of(e);
    let xs = |e: usize| gather_nodes(x, n, &tets[e]);
    let (mut f, mut k) = (vec![0.0; 12 * ne], vec![0.0; 90 * ne]);
    let mut scalar = || {
        each_group(ne, 1, &mut f, &mut k, |e, f, k| {
            let mut fe = [[0.0; 3]; 4];
            let l = lame(e);
            element(
                &mut fe,
                Some(k.try_into().unwrap()),
                &xs(e),
                &fem.dm_inv(e),
                fem.volumes()[e],
                [l.mu, l.lambda],
                &iso,
            );
            f.copy_from_slice(fe.as_flattened());
        })
    };
    // Every group's outputs kept, as the model keeps them for its gather.
    let els = fem.elements(x);
    let (mut f4, mut k4) = (vec![0.0; 12 * ne], vec![0.0; 90 * ne]);
    let mut x4 = || {
        each_group(ne, 4, &mut f4, &mut k4, |e, f, k| {
            element_x4(
                f.try_into().unwrap(),
                Some(k.try_into().unwrap()),
                &els,
                e,
                &iso,
            );
        })
    };
    let (mut f8, mut k8) = (vec![0.0; 12 * ne], vec![0.0; 90 * ne]);
    let mut x8 = || {
        each_group(ne, 8, &mut f8, &mut k8, |e, f, k| {
            element_x8(
                f.try_into().unwrap(),
                Some(k.try_into().unwrap()),
                &els,
                e,
                &iso,
            );
        })
    };
    let (mut f16, mut k16) = (vec![0.0; 12 * ne], vec![0.0; 90 * ne]);
    let mut x16 = || {
        each_group(ne, 16, &mut f16, &mut k16, |e, f, k| {
            element_x16(
                f.try_into().unwrap(),
                Some(k.try_into().unwrap()),
                &els,
                e,
                &iso,
            );
        })
    };
    // The same calls with the outputs in one reused buffer: the kernel's own rate,
    // without writing the 43 MB of stiffness blocks the model keeps for its gather.
    let (mut fc4, mut kc4, mut sink4) = ([0.0; 48], [0.0; 360], 0.0);
    let mut x4_cached = || {
        for e in (0..ne).step_by(4) {
            element_x4(&mut fc4, Some(&mut kc4), &els, e, &iso);
            sink4 += kc4[e % 360];
        }
    };
    let (mut fc8, mut kc8, mut sink8) = ([0.0; 96], [0.0; 720], 0.0);
    let mut x8_cached = || {
        for e in (0..ne).step_by(8) {
            element_x8(&mut fc8, Some(&mut kc8), &els, e, &iso);
            sink8 += kc8[e % 720];
        }
    };
    let (mut fc16, mut kc16, mut sink16) = ([0.0; 192], [0.0; 1440], 0.0);
    let mut x16_cached = || {
        for e in (0..ne).step_by(16) {
            element_x16(&mut fc16, Some(&mut kc16), &els, e, &iso);
            sink16 += kc16[e % 1440];
        }
    };
    // The warped tangent's kernel (`FemDesc::warped_tangent`): groups it refuses (a
    // flat, inverted or strongly strained element) are counted, not timed elsewhere.
    let refused = Cell::new(0usize);
    let (mut fw16, mut kw16) = (vec![0.0; 12 * ne], vec![0.0; 90 * ne]);
    let mut warped = || {
        each_group(ne, 16, &mut fw16, &mut kw16, |e, f, k| {
            let out =
                corotational_warped_x16(f.try_into().unwrap(), k.try_into().unwrap(), &els, e);
            refused.set(refused.get() + usize::from(out.is_none()));
        })
    };
    let (mut fwc, mut kwc, mut sinkw) = ([0.0; 192], [0.0; 1440], 0.0);
    let mut warped_cached = || {
        for e in (0..ne).step_by(16) {
            let out = corotational_warped_x16(&mut fwc, &mut kwc, &els, e);
            refused.set(refused.get() + usize::from(out.is_none()));
            sinkw += kwc[e % 1440];
        }
    };
    // Flops an element, counted on the same elements through each kernel's scalar twin.
    let counted = |kernel: &dyn Fn(&mut CountedElement, CountedInputs)| {
        FLOPS.with(|c| c.set(0));
        for e in 0..ne {
            let mut out = ([[Counted(0.0); 3]; 4], [Counted(0.0); 90]);
            let l = lame(e);
            let inputs = (
                xs(e).map(|p| p.map(Counted)),
                fem.dm_inv(e).map(Counted),
                Counted(fem.volumes()[e]),
                [Counted(l.mu), Counted(l.lambda)],
            );
            kernel(&mut out, inputs);
        }
        FLOPS.with(|c| c.get()) as f64 / ne as f64
    };
    let flops = counted(&|(f, k), (x, dm, vol, lame)| {
        element(f, Some(k), &x, &dm, vol, lame, &iso);
    });
    let warped_flops = counted(&|(f, k), (x, dm, vol, lame)| {
        corotational_warped(f, k, &x, &dm, vol, lame);
    });
    md.push_str(
        "| kernel (one core, corotational, forces + stiffness; exact tangent with the definiteness fix, or `-warped`: R K0 R^T) | elements | best | elements/s | GFLOP/s (flops/element, counted) | of one core's 4-wide FMA peak | of one core's 8-wide FMA peak |\n|---|---|---|---|---|---|---|\n",
    );
    for (name, run, flops) in [
        ("scalar", &mut scalar as &mut dyn FnMut(), flops),
        ("x4", &mut x4 as &mut dyn FnMut(), flops),
        ("x4-cached", &mut x4_cached as &mut dyn FnMut(), flops),
        ("x8", &mut x8 as &mut dyn FnMut(), flops),
        ("x8-cached", &mut x8_cached as &mut dyn FnMut(), flops),
        ("x16", &mut x16 as &mut dyn FnMut(), flops),
        ("x16-cached", &mut x16_cached as &mut dyn FnMut(), flops),
        ("x16-warped", &mut warped as &mut dyn FnMut(), warped_flops),
        (
            "x16-warped-cached",
            &mut warped_cached as &mut dyn FnMut(),
            warped_flops,
        ),
    ] {
        let id = format!("fem/kernel/{name}");
        if !wanted(&id) {
            continue;
        }
        c.bench_function(&id, |b| b.iter(&mut *run));
        // The peak right before and after the timing, the higher of the two: on a shared
        // machine the rate available changes from minute to minute, and the fraction is
        // meant against what this run could have had.
        let peak_before = largestep::machine::peak_fma();
        let t = best_of(10, run);
        let peak_after = largestep::machine::peak_fma();
        let threads = rayon::current_num_threads() as f64;
        let core4 = peak_before.0.max(peak_after.0) / threads;
        let core8 = peak_before.1.max(peak_after.1) / threads;
        let rate = ne as f64 / t;
        let gflops = rate * flops / 1e9;
        md.push_str(&format!(
            "| {id} | {ne} | {:.2} ms | {rate:.2e} | {gflops:.2} ({flops:.0}) | {:.0}% of {core4:.1} GFLOP/s | {:.0}% of {core8:.1} GFLOP/s |\n",
            1e3 * t,
            100.0 * gflops / core4,
            100.0 * gflops / core8
        ));
    }
    std::hint::black_box((sink4, sink8, sink16, sinkw));
    if refused.get() > 0 {
        md.push_str(&format!(
            "\nthe warped kernel refused {} groups of 16 (left to the SVD kernel)\n",
            refused.get()
        ));
    }
    let scale = k.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (name, fw, kw) in [("x4", &f4, &k4), ("x8", &f8, &k8), ("x16", &f16, &k16)] {
        if wanted("fem/kernel/scalar") && wanted(&format!("fem/kernel/{name}")) {
            let worst = f
                .iter()
                .zip(fw)
                .chain(k.iter().zip(kw))
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            md.push_str(&format!(
                "\nscalar and {name} agree to {:.1e} of the largest stiffness entry\n",
                worst / scale
            ));
        }
    }
}
