//! Sparse benchmarks: SpMV, PCG iterations, Cholesky factor and solve on block matrices
//! from 2-D (9-point) and 3-D (27-point) grids at three sizes each, the largest far out of
//! the last-level cache, side by side with nalgebra-sparse's CSR SpMV and faer's own
//! sparse matrix-vector product on the same matrices.
//!
//! The run starts by measuring this machine's triad bandwidth with 1 and with all threads
//! (`largestep::machine`); every line of the closing summary gives GB/s (bytes the
//! operation must move, counted like the triad: each array read or written once) and the
//! fraction of the triad bandwidth at the same thread count. Criterion keeps its own
//! statistics under `target/criterion`; the summary uses the best of repeated timings,
//! is printed at the end and written to `target/criterion/sparse-summary.md`.
//!
//! Ids follow `sparse/<kernel>/<variant>/<size>`; a filter argument (`cargo bench --bench
//! sparse -- spmv`) limits both criterion and the summary.

use criterion::{Criterion, Throughput};
use faer::sparse::linalg::matmul::sparse_dense_matmul;
use faer::{Accum, Mat, Par};
use largestep::kernels::sparse::{bsr3_spmv, bsr3_spmv_scalar};
use largestep::machine::triad_bandwidth;
use largestep::solve::{Pcg, PcgParams, Preconditioner, SparseCholesky};
use largestep::sparse::examples::grid_spd;
use largestep::sparse::{to_csr, Bsr3, FaerCsc, Triangle};
use nalgebra::DMatrix;
use nalgebra_sparse::ops::{serial::spmm_csr_dense, Op};
use std::fmt::Write as _;
use std::hint::black_box;
use std::time::{Duration, Instant};

struct Row {
    id: String,
    threads: usize,
    seconds: f64,
    bytes: f64,
    /// Floating-point operations, for compute-bound kernels (0 when not counted).
    flops: f64,
    /// Triad bandwidth (GB/s) at this row's thread count, measured just before its size.
    triad: f64,
    note: String,
}

struct Bench {
    c: Criterion,
    filter: Option<String>,
    rows: Vec<Row>,
    pool1: rayon::ThreadPool,
    /// Triad bandwidth (GB/s) with 1 and with all threads, re-measured before each size:
    /// this machine's bandwidth drifts by tens of percent over minutes.
    triad: (f64, f64),
}

impl Bench {
    fn measure_triad(&mut self) {
        let len = largestep::machine::DEFAULT_TRIAD_MIB * (1 << 20) / 8;
        let one = self.pool1.install(|| triad_bandwidth(len, 4));
        self.triad = (one, triad_bandwidth(len, 4));
    }
}

impl Bench {
    fn wanted(&self, id: &str) -> bool {
        self.filter.as_ref().is_none_or(|f| id.contains(f.as_str()))
    }

    /// Benchmarks `f` with criterion and records its best time over repeats; `threads` = 1
    /// runs it inside a one-thread pool.
    fn run(
        &mut self,
        id: &str,
        threads: usize,
        bytes: f64,
        note: &str,
        f: &mut (dyn FnMut() + Send),
    ) {
        if !self.wanted(id) {
            return;
        }
        let pool1 = &self.pool1;
        let go = |f: &mut (dyn FnMut() + Send)| if threads == 1 { pool1.install(f) } else { f() };
        {
            let mut g = self.c.benchmark_group("sparse");
            g.throughput(Throughput::Bytes(bytes as u64));
            g.bench_function(id, |b| b.iter(|| go(&mut *f)));
            g.finish();
        }
        // Best of repeated runs for the summary (about 0.5 s).
        let mut best = f64::INFINITY;
        let start = Instant::now();
        let mut reps = 0;
        while reps < 5 || (start.elapsed() < Duration::from_millis(500) && reps < 1000) {
            let t = Instant::now();
            go(&mut *f);
            best = best.min(t.elapsed().as_secs_f64());
            reps += 1;
        }
        self.rows.push(Row {
            id: format!("sparse/{id}"),
            threads,
            seconds: best,
            bytes,
            flops: 0.0,
            triad: if threads == 1 {
                self.triad.0
            } else {
                self.triad.1
            },
            note: note.to_string(),
        });
    }
}

fn grids() -> Vec<(String, Vec<usize>)> {
    vec![
        ("2d-64".into(), vec![64, 64]),
        ("2d-256".into(), vec![256, 256]),
        ("2d-768".into(), vec![768, 768]),
        ("3d-12".into(), vec![12, 12, 12]),
        ("3d-32".into(), vec![32, 32, 32]),
        ("3d-64".into(), vec![64, 64, 64]),
    ]
}

fn cholesky_grids() -> Vec<(String, Vec<usize>)> {
    vec![
        ("2d-64".into(), vec![64, 64]),
        ("2d-128".into(), vec![128, 128]),
        ("2d-256".into(), vec![256, 256]),
        ("3d-8".into(), vec![8, 8, 8]),
        ("3d-12".into(), vec![12, 12, 12]),
        ("3d-16".into(), vec![16, 16, 16]),
    ]
}

/// Every benchmark id of one size (to skip building matrices a filter excludes).
fn ids(name: &str) -> Vec<String> {
    let mut v: Vec<String> = [
        "bsr3-simd",
        "bsr3-scalar",
        "bsr3-par",
        "nalgebra-csr",
        "faer-csc",
        "faer-csc-par",
    ]
    .iter()
    .map(|k| format!("spmv/{k}/{name}"))
    .collect();
    for p in ["block-jacobi", "jacobi"] {
        v.push(format!("pcg-iteration/{p}/{name}-x40"));
        v.push(format!("pcg-iteration/{p}/{name}-setup"));
    }
    v.push(format!("cholesky/factor/{name}"));
    v.push(format!("cholesky/solve/{name}"));
    v
}

fn vector(n3: usize) -> Vec<f64> {
    (0..n3)
        .map(|i| ((i * 7919) % 1000) as f64 / 1000.0 - 0.5)
        .collect()
}

fn spmv_benches(b: &mut Bench, name: &str, a: &Bsr3) {
    let n3 = 3 * a.n();
    let x = vector(n3);
    let mut y = vec![0.0; n3];
    let k = a.as_kernel();
    let bytes = k.spmv_bytes() as f64;
    let mb = format!("matrix {:.1} MB", (k.nnz_blocks() * 76) as f64 / 1e6);
    b.run(
        &format!("spmv/bsr3-simd/{name}"),
        1,
        bytes,
        &mb,
        &mut || bsr3_spmv(&mut y, k, black_box(&x)),
    );
    b.run(
        &format!("spmv/bsr3-scalar/{name}"),
        1,
        bytes,
        &mb,
        &mut || bsr3_spmv_scalar(&mut y, k, black_box(&x)),
    );
    b.run(
        &format!("spmv/bsr3-par/{name}"),
        rayon::current_num_threads(),
        bytes,
        &mb,
        &mut || a.spmv(&mut y, black_box(&x)),
    );

    // nalgebra-sparse CSR (64-bit indices), serial: 16 B per nonzero + vectors.
    if b.wanted(&format!("spmv/nalgebra-csr/{name}")) {
        let csr = to_csr(a);
        let nnz = csr.nnz();
        let xb = DMatrix::from_column_slice(n3, 1, &x);
        let mut yb = DMatrix::<f64>::zeros(n3, 1);
        let bytes = (nnz * 16 + (n3 + 1) * 8 + 2 * n3 * 8) as f64;
        b.run(
            &format!("spmv/nalgebra-csr/{name}"),
            1,
            bytes,
            "CSR, usize indices",
            &mut || spmm_csr_dense(0.0, &mut yb, 1.0, Op::NoOp(&csr), Op::NoOp(black_box(&xb))),
        );
    }
    // faer's own product on the same matrix as CSC (symmetric, so A x = A^T x).
    if b.wanted(&format!("spmv/faer-csc/{name}")) {
        let mut csc = FaerCsc::new(a.pattern(), Triangle::Full);
        csc.refill(a);
        let nnz = csc.nnz();
        let xf = Mat::from_fn(n3, 1, |i, _| x[i]);
        let mut yf = Mat::<f64>::zeros(n3, 1);
        let bytes = (nnz * 16 + (n3 + 1) * 8 + 2 * n3 * 8) as f64;
        for (variant, par, threads) in [
            ("faer-csc", Par::Seq, 1),
            ("faer-csc-par", Par::rayon(0), rayon::current_num_threads()),
        ] {
            b.run(
                &format!("spmv/{variant}/{name}"),
                threads,
                bytes,
                "CSC, usize indices",
                &mut || {
                    sparse_dense_matmul(
                        yf.as_mut(),
                        Accum::Replace,
                        csc.as_ref(),
                        black_box(xf.as_ref()),
                        1.0,
                        par,
                    )
                },
            );
        }
    }
}

fn pcg_benches(b: &mut Bench, name: &str, a: &Bsr3) {
    let n = a.n();
    let rhs = &vector(3 * n);
    for (label, pre) in [
        ("block-jacobi", Preconditioner::BlockJacobi),
        ("jacobi", Preconditioner::Jacobi),
    ] {
        // Time 40 iterations and the setup alone (preconditioner, first residual):
        // one iteration = (t40 - t0) / 40.
        let id = format!("pcg-iteration/{label}/{name}");
        if !b.wanted(&id) {
            continue;
        }
        let mut x = vec![0.0; 3 * n];
        let solver = |iters: usize| {
            let mut pcg = Pcg::new(
                n,
                PcgParams {
                    tolerance: 1e-300,
                    max_iterations: iters,
                    preconditioner: pre,
                },
            );
            let bytes = pcg.iteration_bytes(a);
            let mut a = a.clone();
            (bytes, move |x: &mut [f64]| {
                x.fill(0.0);
                let _ = pcg.solve(&mut a, rhs, x, None); // NotConverged by design
            })
        };
        let (bytes, mut run0) = solver(0);
        let (_, mut run40) = solver(40);
        let threads = rayon::current_num_threads();
        b.run(
            &format!("{id}-x40"),
            threads,
            40.0 * bytes as f64,
            "40 iterations + setup",
            &mut || run40(&mut x),
        );
        b.run(
            &format!("{id}-setup"),
            threads,
            bytes as f64,
            "setup only (traffic: one iteration)",
            &mut || run0(&mut x),
        );
        let t40 = b
            .rows
            .iter()
            .rev()
            .find(|r| r.id.ends_with(&format!("{id}-x40")))
            .map(|r| r.seconds);
        let t0 = b
            .rows
            .iter()
            .rev()
            .find(|r| r.id.ends_with(&format!("{id}-setup")))
            .map(|r| r.seconds);
        if let (Some(t40), Some(t0)) = (t40, t0) {
            b.rows.push(Row {
                id: format!("sparse/{id}"),
                threads,
                seconds: (t40 - t0) / 40.0,
                bytes: bytes as f64,
                flops: 0.0,
                triad: b.triad.1,
                note: "one iteration = (t40 - t0) / 40".into(),
            });
        }
    }
}

fn cholesky_benches(b: &mut Bench, name: &str, a: &Bsr3) {
    let idf = format!("cholesky/factor/{name}");
    let ids = format!("cholesky/solve/{name}");
    if !b.wanted(&idf) && !b.wanted(&ids) {
        return;
    }
    let mut chol = SparseCholesky::new(a.pattern()).expect("symbolic");
    chol.factorize(a).expect("SPD");
    let nnz_l = chol.factor_nnz() as f64;
    let n3 = 3 * a.n();
    let note = format!("nnz(L) = {:.2e}", nnz_l);
    // Factor: at least A read once and L written once; solve: L read twice, x in and out.
    let fbytes = 8.0 * nnz_l + 76.0 * a.pattern().nnz_blocks() as f64;
    let flops = chol.factor_flops();
    b.run(&idf, 1, fbytes, &note, &mut || {
        chol.factorize(black_box(a)).expect("SPD");
    });
    if let Some(r) = b.rows.last_mut().filter(|r| r.id.ends_with(&idf)) {
        r.flops = flops;
    }
    // Each solve starts from the same right-hand side (solving in place repeatedly would
    // apply A^-1 again and again); the copy's traffic is counted.
    let rhs = vector(n3);
    let mut x = rhs.clone();
    let sbytes = 2.0 * 8.0 * nnz_l + 4.0 * 8.0 * n3 as f64;
    b.run(&ids, 1, sbytes, &note, &mut || {
        x.copy_from_slice(&rhs);
        chol.solve_in_place(black_box(&mut x)).expect("finite")
    });
}

fn main() {
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let c = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(1))
        .configure_from_args();
    let threads = rayon::current_num_threads();
    let pool1 = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let peak_one = pool1.install(|| {
        let (f4, f8) = largestep::machine::peak_fma();
        f4.max(f8)
    });
    let mut b = Bench {
        c,
        filter,
        rows: Vec::new(),
        pool1,
        triad: (0.0, 0.0),
    };
    let mut triads = Vec::new();
    for (name, dims) in grids() {
        if !ids(&name).iter().any(|id| b.wanted(id)) {
            continue; // the filter excludes every benchmark of this size: skip building it
        }
        let a = grid_spd(&dims, 1.0, 0.05);
        b.measure_triad();
        triads.push(b.triad);
        spmv_benches(&mut b, &name, &a);
        pcg_benches(&mut b, &name, &a);
    }
    // Cholesky on sizes whose fill stays tractable (a 27-point 32^3 grid factorizes in
    // about 10 s: nnz(L) = 1.9e8).
    for (name, dims) in cholesky_grids() {
        if ids(&name).iter().any(|id| b.wanted(id)) {
            b.measure_triad();
            triads.push(b.triad);
            cholesky_benches(&mut b, &name, &grid_spd(&dims, 1.0, 0.05));
        }
    }
    b.c.final_summary();

    let mut md = String::new();
    let range = |f: fn(&(f64, f64)) -> f64| {
        let v: Vec<f64> = triads.iter().map(f).collect();
        (
            v.iter().cloned().fold(f64::INFINITY, f64::min),
            v.iter().cloned().fold(0.0, f64::max),
        )
    };
    let (lo1, hi1) = range(|t| t.0);
    let (lo2, hi2) = range(|t| t.1);
    let _ = writeln!(
        md,
        "# sparse benchmark summary\n\ntriad bandwidth (3 arrays of {} MiB), re-measured before each size: \
         {lo2:.1} to {hi2:.1} GB/s with {threads} threads, {lo1:.1} to {hi1:.1} GB/s with 1 thread; \
         each row's fraction uses the triad measured just before it. Peak f64 FMA: {peak_one:.1} GFLOP/s \
         with 1 thread. All measured in this run.\n",
        largestep::machine::DEFAULT_TRIAD_MIB
    );
    let _ = writeln!(
        md,
        "| id | threads | time | GB/s | of triad | GFLOP/s | of peak | note |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|");
    for r in &b.rows {
        let gbs = r.bytes / r.seconds / 1e9;
        let triad = r.triad;
        let time = if r.seconds < 1e-3 {
            format!("{:.1} us", r.seconds * 1e6)
        } else {
            format!("{:.3} ms", r.seconds * 1e3)
        };
        let (gf, gf_frac) = if r.flops > 0.0 {
            let g = r.flops / r.seconds / 1e9;
            (format!("{g:.2}"), format!("{:.0}%", 100.0 * g / peak_one))
        } else {
            ("-".into(), "-".into())
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.2} | {:.0}% | {gf} | {gf_frac} | {} |",
            r.id,
            r.threads,
            time,
            gbs,
            100.0 * gbs / triad,
            r.note
        );
    }
    // Speed-ups against the peers, same thread count.
    let find = |id: &str| b.rows.iter().find(|r| r.id == id).map(|r| r.seconds);
    let _ = writeln!(md, "\n| size | bsr3-simd vs nalgebra-csr (1 thread) | bsr3-simd vs faer-csc (1 thread) | bsr3-par vs faer-csc-par |");
    let _ = writeln!(md, "|---|---|---|---|");
    for (name, _) in grids() {
        let s = |v: &str| find(&format!("sparse/spmv/{v}/{name}"));
        let ratio = |a: Option<f64>, b: Option<f64>| {
            a.zip(b)
                .map_or("-".into(), |(a, b)| format!("{:.2}x", b / a))
        };
        let _ = writeln!(
            md,
            "| {name} | {} | {} | {} |",
            ratio(s("bsr3-simd"), s("nalgebra-csr")),
            ratio(s("bsr3-simd"), s("faer-csc")),
            ratio(s("bsr3-par"), s("faer-csc-par"))
        );
    }
    println!("\n{md}");
    let path = std::path::Path::new("target/criterion/sparse-summary.md");
    if let Some(dir) = path.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    if let Err(e) = std::fs::write(path, &md) {
        eprintln!("could not write {}: {e}", path.display());
    }
}
