//! parry3d 0.31's `Bvh` on the boxes of `cargo bench --bench collide`
//! (`target/criterion/boxes-100k.bin`: per box six little-endian f64, min then max):
//! binned build and the self traversal (`traverse_bvtt_single_tree`), best of 20 each,
//! single-threaded as parry is. Prints the times and the pair count.

use parry3d::bounding_volume::{Aabb, BoundingVolume};
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhWorkspace};
use std::time::Instant;

fn main() {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "../../../target/criterion/boxes-100k.bin".into());
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e} (run `cargo bench --bench collide` first)"));
    let v: Vec<f64> = bytes.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect();
    let leaves: Vec<Aabb> = v
        .chunks_exact(6)
        .map(|b| {
            let f = |x: f64| x as f32;
            Aabb::new([f(b[0]), f(b[1]), f(b[2])].into(), [f(b[3]), f(b[4]), f(b[5])].into())
        })
        .collect();
    let mut best_build = f64::INFINITY;
    let mut bvh = Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves);
    for _ in 0..20 {
        let t0 = Instant::now();
        bvh = Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves);
        best_build = best_build.min(t0.elapsed().as_secs_f64());
    }
    let mut ws = BvhWorkspace::default();
    let mut best_pairs = f64::INFINITY;
    let mut count = 0usize;
    for _ in 0..20 {
        let mut pairs = 0usize;
        let t0 = Instant::now();
        bvh.traverse_bvtt_single_tree::<false>(&mut ws, &mut |a, b| {
            // The traversal reports leaf pairs whose node boxes overlap: count the
            // boxes that do, as the exact test.
            if leaves[a as usize].intersects(&leaves[b as usize]) {
                pairs += 1;
            }
        });
        best_pairs = best_pairs.min(t0.elapsed().as_secs_f64());
        count = pairs;
    }
    println!("parry3d 0.31.1 Bvh, {} boxes: build {:.2} ms, self pairs {:.2} ms ({count} pairs)", leaves.len(), best_build * 1e3, best_pairs * 1e3);
}
