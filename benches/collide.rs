//! Collision-detection benchmarks of issue 18.
//!
//! - `collide/bvh/build/100k`: a binned-SAH BVH over 100,000 random boxes of side 0.01 in
//!   the unit cube (seeded; the same boxes as the parry3d peer in
//!   `benches/peers/parry-bvh`, which reads them from `target/criterion/boxes-100k.bin`),
//!   all threads.
//! - `collide/bvh/self-pairs/100k`: every overlapping pair within that tree.
//!
//! Beside each time the summary gives the peer's, run in the same bench when it is built
//! (`cargo build --release` in `benches/peers/parry-bvh`), and a machine fraction: for the
//! build, the bytes its passes stream (a 32-byte record read by the binning and read and
//! written by the partition at each level, counted from the tree) over the triad
//! bandwidth measured in the same run; for the pairs, the cycles per visited node pair
//! against four (a visit's at most eight 32-byte loads at two a cycle), at the clock
//! `peak_fma` implies.
//!
//! Run with `cargo bench --bench collide` (`-- bvh` for a part); the summary is printed
//! and written to `target/criterion/collide-summary.md`.

use criterion::Criterion;
use largestep::kernels::collide::bv::Aabb;
use largestep::kernels::collide::bvh::{Bvh, PairWork};
use std::io::Write;
use std::time::{Duration, Instant};

/// 100,000 boxes of side 0.01 with corners uniform in `[0, 0.99]^3` (xorshift, seed 1).
pub fn boxes_100k() -> Vec<Aabb> {
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut rnd = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..100_000)
        .map(|_| {
            let p = [rnd() * 0.99, rnd() * 0.99, rnd() * 0.99];
            Aabb {
                min: p,
                max: p.map(|c| c + 0.01),
            }
        })
        .collect()
}

fn main() {
    let mut c = Criterion::default()
        .configure_from_args()
        .measurement_time(Duration::from_secs(5))
        .sample_size(30);
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let wanted = |id: &str| {
        filter
            .as_deref()
            .is_none_or(|f| id.contains(f) || f.starts_with(id))
    };
    let mut md = String::from("# Collision benchmarks\n\n");
    if wanted("collide/bvh") {
        md += &bvh(&mut c);
    }
    println!("\n{md}");
    let dir = std::path::Path::new("target/criterion");
    let _ = std::fs::create_dir_all(dir);
    let _ = std::fs::write(dir.join("collide-summary.md"), md);
}

fn best_of(reps: usize, mut f: impl FnMut()) -> f64 {
    (0..reps)
        .map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn bvh(c: &mut Criterion) -> String {
    let boxes = boxes_100k();
    let dir = std::path::Path::new("target/criterion");
    let _ = std::fs::create_dir_all(dir);
    if let Ok(mut f) = std::fs::File::create(dir.join("boxes-100k.bin")) {
        for b in &boxes {
            for v in b.min.iter().chain(&b.max) {
                let _ = f.write_all(&v.to_le_bytes());
            }
        }
    }
    let mut tree = Bvh::from_boxes(&boxes);
    c.bench_function("collide/bvh/build/100k", |b| b.iter(|| tree.build(&boxes)));
    let mut work = PairWork::default();
    let mut pairs = Vec::new();
    c.bench_function("collide/bvh/self-pairs/100k", |b| {
        b.iter(|| tree.self_pairs(&mut work, &mut pairs))
    });
    let build = best_of(20, || tree.build(&boxes));
    let self_pairs = best_of(20, || tree.self_pairs(&mut work, &mut pairs));
    let visits = work.visits();
    // Depth-weighted record passes: at every inner level above its leaf, each primitive's
    // 32-byte record is read by the binning pass and read and written by the partition.
    let bytes = 3.0 * 32.0 * leaf_depth_sum(&tree);
    let triad = largestep::machine::triad_bandwidth(
        largestep::machine::DEFAULT_TRIAD_MIB * (1 << 20) / 8,
        3,
    );
    let build_rate = bytes / build / 1e9;
    // The clock from the FMA peak: 2 pipes of 4-lane FMAs (2 flops a lane) per cycle and
    // thread. A visit loads at most eight 32-byte records (four child nodes, or two
    // leaves' boxes), four cycles at two loads a cycle: the bound the traversal is held
    // against (it is bound by the latency of those loads instead).
    let threads = rayon::current_num_threads() as f64;
    let ghz = largestep::machine::peak_fma().0 / (16.0 * threads);
    let cycles = self_pairs * ghz * 1e9 * threads / visits as f64;
    let peer = run_peer();
    format!(
        "## BVH, 100,000 boxes of side 0.01 in the unit cube ({threads} threads)\n\n| | largestep, best of 20 | peer: parry3d 0.31.1 `Bvh` (1 thread) | machine |\n|---|---|---|---|\n| build | {:.2} ms ({} nodes, SAH cost {:.1}) | {} | {:.1} GB/s of records streamed, {:.0}% of triad ({triad:.1} GB/s) |\n| all pairs | {:.2} ms ({} pairs, {visits} node pairs visited) | {} | {cycles:.0} cycles a visit at {ghz:.2} GHz: {:.0}% of four cycles a visit |\n\n",
        build * 1e3,
        tree.nodes().len(),
        tree.sah_cost(),
        peer.as_ref().map_or("not built (see benches/peers/parry-bvh)".into(), |p| format!("{:.2} ms ({:.2}x)", p.0, p.0 / (build * 1e3))),
        build_rate,
        100.0 * build_rate / triad,
        self_pairs * 1e3,
        pairs.len(),
        peer.as_ref().map_or("not built".into(), |p| format!("{:.2} ms, {} pairs ({:.2}x)", p.1, p.2, p.1 / (self_pairs * 1e3))),
        400.0 / cycles,
    )
}

/// Runs the parry3d peer when it is built (`cargo build --release` in
/// `benches/peers/parry-bvh`): `(build ms, pairs ms, pair count)`.
fn run_peer() -> Option<(f64, f64, usize)> {
    let exe = std::path::Path::new("benches/peers/parry-bvh/target/release/parry-bvh-peer");
    let out = std::process::Command::new(exe)
        .arg("target/criterion/boxes-100k.bin")
        .output()
        .ok()?;
    let text = String::from_utf8(out.stdout).ok()?;
    // "... build 36.61 ms, self pairs 4.96 ms (40849 pairs)"
    let num = |key: &str| -> Option<f64> {
        let rest = &text[text.find(key)? + key.len()..];
        rest.split_whitespace()
            .next()?
            .trim_start_matches('(')
            .parse()
            .ok()
    };
    Some((num("build ")?, num("self pairs ")?, num("ms (")? as usize))
}

/// Sum over primitives of their leaf's depth.
fn leaf_depth_sum(tree: &Bvh) -> f64 {
    let nodes = tree.nodes();
    let mut sum = 0.0;
    let mut stack = vec![(0usize, 0usize)];
    while let Some((i, d)) = stack.pop() {
        let n = nodes[i];
        if n.is_leaf() {
            sum += (d * n.count as usize) as f64;
        } else {
            stack.push((n.first as usize, d + 1));
            stack.push((n.first as usize + 1, d + 1));
        }
    }
    sum
}
