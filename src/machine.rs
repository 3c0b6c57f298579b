//! This machine's limits, measured: memory bandwidth (triad) and peak f64 FMA rate.
//!
//! Benchmarks report their speed as a fraction of these, measured in the same run.
//!
//! - **Triad** `a = b + s c` (STREAM's kernel) over three arrays far larger than the last
//!   level cache, in parallel on every thread, best of several repetitions. Bytes are
//!   counted as STREAM does: 24 per element (two reads, one write; the write-allocate read
//!   is not counted), so kernels measured against it count their bytes the same way.
//! - **Peak FMA**: every thread runs 12 independent chains of `f64x4` (and `f64x8`) fused
//!   multiply-adds, enough to cover the FMA latency on two pipes; 2 flops per lane per FMA.

use largestep_kernels::par::{chunk_count, chunk_range, par_reduce, Disjoint};
use std::hint::black_box;
use std::time::Instant;
use wide::{f64x4, f64x8};

/// Measured limits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Triad bandwidth (GB/s, 1e9 bytes per second, STREAM byte counting).
    pub triad_gbs: f64,
    /// Size of each triad array (bytes).
    pub triad_array_bytes: usize,
    /// Peak f64 rate with 4-wide FMA (GFLOP/s), the width the kernels use.
    pub fma4_gflops: f64,
    /// Peak f64 rate with 8-wide FMA (GFLOP/s).
    pub fma8_gflops: f64,
    /// Threads used (rayon's pool).
    pub threads: usize,
}

impl Limits {
    /// The higher of the two FMA rates.
    pub fn peak_gflops(&self) -> f64 {
        self.fma4_gflops.max(self.fma8_gflops)
    }
}

/// Triad bandwidth in GB/s over arrays of `len` doubles, best of `reps` (after one warm-up).
pub fn triad_bandwidth(len: usize, reps: usize) -> f64 {
    let chunk = 1 << 16;
    let nchunks = chunk_count(len, chunk);
    let mut a = vec![0.0f64; len];
    let mut b = vec![0.0f64; len];
    let mut c = vec![0.0f64; len];
    // First touch in parallel, so pages land where the threads run.
    for (buf, val) in [(&mut a, 0.0), (&mut b, 1.0), (&mut c, 2.0)] {
        let d = Disjoint::new(buf);
        par_reduce::<0, _>(nchunks, &|k| {
            // SAFETY: chunk ranges are disjoint.
            unsafe { d.slice(chunk_range(k, len, chunk)) }.fill(val);
            []
        });
    }
    let mut best = f64::INFINITY;
    for _ in 0..reps + 1 {
        let t = Instant::now();
        let d = Disjoint::new(&mut a);
        par_reduce::<0, _>(nchunks, &|k| {
            let r = chunk_range(k, len, chunk);
            // SAFETY: chunk ranges are disjoint.
            let out = unsafe { d.slice(r.clone()) };
            largestep_kernels::vec::waxpy(out, &b[r.clone()], 3.0, &c[r]);
            []
        });
        best = best.min(t.elapsed().as_secs_f64());
        black_box(&a);
    }
    24.0 * len as f64 / best / 1e9
}

/// Twelve independent FMA chains of the given vector type, `iters` rounds.
macro_rules! fma_chains {
    ($name:ident, $simd:ty) => {
        fn $name(iters: usize) -> f64 {
            // Opaque inputs: with literal constants LLVM proves 1.0 a fixed point of
            // `a m + add` and folds the whole loop away.
            let m = <$simd>::splat(black_box(0.999_999_9));
            let add = <$simd>::splat(black_box(1e-7));
            let mut acc = [<$simd>::splat(black_box(0.5)); 12];
            for _ in 0..iters {
                for a in acc.iter_mut() {
                    *a = a.mul_add(m, add);
                }
            }
            acc.iter().fold(0.0, |s, a| s + a.reduce_add())
        }
    };
}

fma_chains!(fma_chains4, f64x4);
fma_chains!(fma_chains8, f64x8);

fn peak(lanes: usize, f: fn(usize) -> f64) -> f64 {
    let threads = rayon::current_num_threads();
    let iters = black_box(4_000_000usize);
    let mut best = f64::INFINITY;
    for _ in 0..8 {
        let t = Instant::now();
        let [s] = par_reduce(threads, &|_| [f(black_box(iters))]);
        best = best.min(t.elapsed().as_secs_f64());
        black_box(s);
    }
    (threads * iters * 12 * lanes * 2) as f64 / best / 1e9
}

/// Peak f64 FMA rates (GFLOP/s) with 4- and 8-wide vectors, all threads.
pub fn peak_fma() -> (f64, f64) {
    (peak(4, fma_chains4), peak(8, fma_chains8))
}

/// Measures both limits; `triad_mib` is the size of each triad array in MiB.
pub fn measure(triad_mib: usize) -> Limits {
    let len = triad_mib * (1 << 20) / 8;
    let triad_gbs = triad_bandwidth(len, 5);
    let (fma4_gflops, fma8_gflops) = peak_fma();
    Limits {
        triad_gbs,
        triad_array_bytes: len * 8,
        fma4_gflops,
        fma8_gflops,
        threads: rayon::current_num_threads(),
    }
}

/// Default triad array size: 256 MiB each, 768 MiB in all: eight times the former
/// machine's 32 MiB last-level cache, 1.6 times the present one's 480 MiB (an L3 shared
/// with the host's other guests, of which a 2-core guest holds a small part).
pub const DEFAULT_TRIAD_MIB: usize = 256;
