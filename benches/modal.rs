//! Modal analysis benchmark of issue 16: the 20 lowest non-rigid modes of a free-free
//! steel bar, 1 m x 0.1 m x 0.1 m, 100 x 10 x 10 cubes split into six tetrahedra each
//! (12,221 vertices, 36,663 unknowns), linear elasticity at rest (E = 200 GPa, nu = 0.3,
//! 7850 kg/m^3), consistent mass: `solve::lowest_modes` asked for 26 modes (20 and the
//! six rigid ones), shift-invert block Lanczos on one sparse Cholesky.
//!
//! - `modal/bar/20-modes/1-thread` and `/2-threads`: the whole solve in a pool of one
//!   and of two threads (each block solve's eight columns as two passes of four, side by
//!   side; the orthogonalisation over two row halves; the factorization sequential), and
//!   whether the two give the same bits.
//! - Machine fractions from the same run: the factorization's flop rate (the factor's
//!   column counts, `SparseCholesky::factor_flops`) against one core's 4-wide FMA peak,
//!   and the block solves' reading of the factor (its values, 8 bytes each, twice per
//!   block: forward and back) against one thread's triad bandwidth (both measured right
//!   before the timing).
//! - The peer, SciPy's `eigsh` in shift-invert mode (`benches/peers/scipy-eigsh`), reads
//!   the same K and M, written here as Matrix Market to `target/criterion/modal-bar-k.mtx`
//!   and `-m.mtx`, with largestep's shift and frequencies in `modal-bar.json`.
//!
//! - `modal/synthesis/1000-modes`: 2 s of sound at 44.1 kHz from 1,000 modes (100 Hz to
//!   19 kHz, one struck vertex, Rayleigh damping), one thread: mode-samples per second,
//!   times faster than real time, and flops (7 per mode-sample: the recursion's three
//!   multiplies and two adds, the gain, the sum) against one core's FMA peak.
//!
//! Run with `cargo bench --bench modal` (`-- synthesis` or `-- bar` for one part); the
//! summary is printed and written to `target/criterion/modal-summary.md`.

use criterion::Criterion;
use largestep::fem::{FemDesc, FemMass, FemMaterial, Material};
use largestep::modal::sound::{synthesize, Hit, Rayleigh, SoundParams};
use largestep::modal::stiffness_at_rest;
use largestep::simulation::MechModel;
use largestep::solve::{lowest_modes, EigenParams, Mass, Modes, SparseCholesky};
use largestep::sparse::order::FillOrdering;
use largestep::sparse::{write_matrix_market, Bsr3};
use std::time::{Duration, Instant};

fn main() {
    let mut c = Criterion::default()
        .configure_from_args()
        .measurement_time(Duration::from_secs(10))
        .sample_size(10);
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let wanted = |id: &str| filter.as_deref().is_none_or(|f| id.contains(f));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let mut md = String::new();
    if wanted("modal/synthesis") {
        md += &synthesis(&mut c, &pool);
    }
    if wanted("modal/bar") {
        let (text, one) = bar(&mut c, &pool, "1-thread");
        md += &text;
        let two_threads = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let (text, two) = bar(&mut c, &two_threads, "2-threads");
        md += &text;
        let bits = |m: &Modes| {
            m.eigenvalues
                .iter()
                .chain(&m.vectors)
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        };
        md += &format!(
            "Modes on 1 and 2 threads: {}.\n\n",
            if bits(&one) == bits(&two) {
                "the same bits"
            } else {
                "DIFFERENT bits"
            }
        );
    }
    println!("\n{md}");
    let dir = std::path::Path::new("target/criterion");
    let _ = std::fs::create_dir_all(dir);
    let _ = std::fs::write(dir.join("modal-summary.md"), md);
}

/// 2 s of sound from 1,000 modes (see the module docs).
fn synthesis(c: &mut Criterion, pool: &rayon::ThreadPool) -> String {
    let count = 1000;
    let w = |j: usize| {
        2.0 * std::f64::consts::PI * (100.0 * (190f64).powf(j as f64 / (count - 1) as f64))
    };
    // One vertex whose three components take every mode (shares between -1 and 1).
    let modes = Modes {
        eigenvalues: (0..count).map(|j| w(j) * w(j)).collect(),
        vectors: (0..count)
            .flat_map(|j| [((j * 7919) % 1000) as f64 / 500.0 - 0.999, 0.5, 0.25])
            .collect(),
        residuals: vec![0.0; count],
        ..Modes::default()
    };
    let hit = Hit {
        time: 0.01,
        vertex: 0,
        direction: [1.0, 0.0, 0.0],
        impulse: 0.01,
        duration: 1e-4,
    };
    let params = SoundParams {
        duration: 2.0,
        quiet: 0.0,
        ..SoundParams::default()
    };
    let damping = Rayleigh {
        alpha: 1.0,
        beta: 1e-8,
    };
    let run = || synthesize(&modes, damping, &[hit], &params).unwrap();
    let peak = pool.install(|| largestep::machine::peak_fma().0);
    c.bench_function("modal/synthesis/1000-modes", |b| {
        b.iter(|| pool.install(run))
    });
    let best = (0..5)
        .map(|_| {
            let t = Instant::now();
            let s = pool.install(run);
            assert_eq!(s.frequencies_hz.len(), count);
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min);
    let mode_samples = count as f64 * 2.0 * 44_100.0;
    format!(
        "| synthesis: 1,000 modes, 2 s at 44.1 kHz, one thread | value |\n|---|---|\n| best of 5 | {:.1} ms: {:.0} times faster than real time |\n| throughput | {:.2e} mode-samples/s, {:.1} GFLOP/s (7 flops each): {:.0}% of the threads' FMA peak ({:.1} GFLOP/s) |\n\n",
        1e3 * best,
        2.0 / best,
        mode_samples / best,
        7.0 * mode_samples / best / 1e9,
        100.0 * 7.0 * mode_samples / best / 1e9 / peak,
        peak
    )
}

/// The 20 lowest modes of the free bar (see the module docs).
fn bar(c: &mut Criterion, pool: &rayon::ThreadPool, threads: &str) -> (String, Modes) {
    let mut desc = FemDesc::cantilever(
        [100, 10, 10],
        [1.0, 0.1, 0.1],
        FemMaterial::steel(Material::Linear),
        0.0,
    );
    desc.pinned.clear();
    desc.mass = FemMass::Consistent;
    let (fem, state) = desc.build().unwrap();
    let k = stiffness_at_rest(&fem, state.x.as_slice()).unwrap();
    let m = fem.mass_matrix().unwrap();
    let params = EigenParams {
        count: 26,
        ..EigenParams::default()
    };
    let solve = || lowest_modes(&k, Mass::Consistent(m), &[], &params).unwrap();

    // The machine, on the pool's threads, right before the timing.
    let (triad, peak) = pool.install(|| {
        (
            largestep::machine::triad_bandwidth(
                largestep::machine::DEFAULT_TRIAD_MIB * (1 << 20) / 8,
                3,
            ),
            largestep::machine::peak_fma().0,
        )
    });
    c.bench_function(&format!("modal/bar/20-modes/{threads}"), |b| {
        b.iter(|| pool.install(solve))
    });
    let mut runs: Vec<_> = (0..5)
        .map(|_| {
            let t = Instant::now();
            let modes = pool.install(solve);
            (t.elapsed().as_secs_f64(), modes)
        })
        .collect();
    runs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (best, modes) = &runs[0];
    let median = runs[2].0;

    // The factor of the same shifted matrix, for its size and flops.
    let mut shifted = Bsr3::zeros(k.pattern().clone());
    shifted.assign_lincomb(&[(1.0, &k), (-modes.shift, m)]);
    let mut chol = SparseCholesky::new(shifted.pattern()).unwrap();
    chol.factorize(&shifted).unwrap();
    let flops = chol.factor_flops();
    let factor_bytes = 8.0 * chol.factor_nnz() as f64;
    // Forward and back, in each of the two column groups (`CholeskyCore::solve_columns`).
    let read = 4.0 * factor_bytes * modes.block_solves as f64;

    let dir = std::path::Path::new("target/criterion");
    let _ = std::fs::create_dir_all(dir);
    write_matrix_market(
        std::fs::File::create(dir.join("modal-bar-k.mtx")).unwrap(),
        &k,
    )
    .unwrap();
    write_matrix_market(
        std::fs::File::create(dir.join("modal-bar-m.mtx")).unwrap(),
        m,
    )
    .unwrap();
    let json = format!(
        "{{\"shift\": {}, \"modes\": 26, \"frequencies_hz\": {:?}, \"seconds\": {}}}\n",
        modes.shift,
        modes.frequencies_hz(),
        best
    );
    let _ = std::fs::write(dir.join("modal-bar.json"), json);

    let f = modes.frequencies_hz();
    let mut md = format!(
        "| 20 modes of the free steel bar (36,663 unknowns, consistent mass, {threads}) | value |\n|---|---|\n",
    );
    md += &format!(
        "| whole solve, best / median of 5 | {:.3} s / {:.3} s |\n",
        best, median
    );
    md += &format!(
        "| factorization of K - sigma M (sigma = {:.4e}) | {:.3} s, {:.2e} flops: {:.1} GFLOP/s, {:.0}% of the threads' FMA peak ({:.1} GFLOP/s) |\n",
        modes.shift,
        modes.factor_seconds,
        flops,
        flops / modes.factor_seconds / 1e9,
        100.0 * flops / modes.factor_seconds / 1e9 / peak,
        peak
    );
    md += &format!(
        "| block solves (8 columns each, two passes of 4) | {} in {:.3} s: the factor ({:.0} MB) read at {:.1} GB/s, {:.0}% of the threads' triad ({:.1} GB/s) |\n",
        modes.block_solves,
        modes.solve_seconds,
        factor_bytes / 1e6,
        read / modes.solve_seconds / 1e9,
        100.0 * read / modes.solve_seconds / 1e9 / triad,
        triad
    );
    md += &format!(
        "| the rest (orthogonalisation, Ritz values, residuals) | {:.3} s |\n",
        best - modes.factor_seconds - modes.solve_seconds
    );
    md += &format!(
        "| rigid modes, block steps | {}, {} |\n| lowest frequencies | {:.6} Hz, {:.6} Hz, {:.6} Hz |\n| largest residual | {:.1e} |\n",
        modes.rigid,
        modes.steps,
        f[0],
        f[1],
        f[2],
        modes.residuals.iter().fold(0.0f64, |a, &b| a.max(b))
    );

    // The ordering against faer's scalar AMD, alternating, same run.
    let amd_params = EigenParams {
        ordering: FillOrdering::ScalarAmd,
        ..params
    };
    let (mut nd_best, mut amd_best) = (f64::INFINITY, f64::INFINITY);
    let mut amd_freqs = Vec::new();
    for _ in 0..3 {
        let t = Instant::now();
        let a = pool.install(|| lowest_modes(&k, Mass::Consistent(m), &[], &amd_params).unwrap());
        amd_best = amd_best.min(t.elapsed().as_secs_f64());
        amd_freqs = a.frequencies_hz();
        let t = Instant::now();
        pool.install(solve);
        nd_best = nd_best.min(t.elapsed().as_secs_f64());
    }
    let amd_chol =
        SparseCholesky::with_ordering(shifted.pattern(), FillOrdering::ScalarAmd).unwrap();
    let differ = f
        .iter()
        .zip(&amd_freqs)
        .map(|(a, b)| ((a - b) / a).abs())
        .fold(0.0f64, f64::max);
    md += &format!(
        "| fill-reducing ordering, best of 3 alternating | the default, `FillOrdering::Auto` (fill {:.2} M, {:.2e} flops): {:.3} s; faer's scalar AMD (fill {:.2} M, {:.2e} flops): {:.3} s; frequencies agree to {:.1e} |\n",
        chol.factor_nnz() as f64 / 1e6,
        flops,
        nd_best,
        amd_chol.factor_nnz() as f64 / 1e6,
        amd_chol.factor_flops(),
        amd_best,
        differ
    );
    (md + "\n", runs.swap_remove(0).1)
}
