//! ozz-animation-rs's linear blend skinning on the data `cargo bench --bench anim` writes
//! (target/criterion/skin-data.bin, little-endian): u32 vertex count n, u32 joint count
//! m, then n positions (3 f32), n normals (3 f32), n x 4 joint indices (u16), n x 4
//! weights (f32; ozz reads the first three and takes the fourth as one minus their sum),
//! m column-major 4x4 matrices (16 f32). Prints the best time of 50 runs, positions only
//! and positions with normals, single-threaded, and a checksum to compare outputs.

use glam::{Mat4, Vec3};
use ozz_animation_rs::SkinningJobRef;
use std::time::Instant;

fn main() {
    let path = std::env::args().nth(1).unwrap_or("target/criterion/skin-data.bin".into());
    let bytes = std::fs::read(&path).expect("skinning data");
    let mut at = 0;
    let mut u32_ = || {
        let v = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
        at += 4;
        v
    };
    let (n, m) = (u32_() as usize, u32_() as usize);
    let f32s = |at: &mut usize, k: usize| -> Vec<f32> {
        let v = (0..k)
            .map(|i| f32::from_le_bytes(bytes[*at + 4 * i..*at + 4 * i + 4].try_into().unwrap()))
            .collect();
        *at += 4 * k;
        v
    };
    let p = f32s(&mut at, 3 * n);
    let nr = f32s(&mut at, 3 * n);
    let idx: Vec<u16> = (0..4 * n)
        .map(|i| u16::from_le_bytes(bytes[at + 2 * i..at + 2 * i + 2].try_into().unwrap()))
        .collect();
    at += 8 * n;
    let w4 = f32s(&mut at, 4 * n);
    let mats = f32s(&mut at, 16 * m);
    let positions: Vec<Vec3> = (0..n).map(|i| Vec3::new(p[3 * i], p[3 * i + 1], p[3 * i + 2])).collect();
    let normals: Vec<Vec3> = (0..n).map(|i| Vec3::new(nr[3 * i], nr[3 * i + 1], nr[3 * i + 2])).collect();
    let weights: Vec<f32> = (0..n).flat_map(|i| [w4[4 * i], w4[4 * i + 1], w4[4 * i + 2]]).collect();
    let matrices: Vec<Mat4> = (0..m).map(|j| Mat4::from_cols_slice(&mats[16 * j..16 * j + 16])).collect();
    let mut out_p = vec![Vec3::ZERO; n];
    let mut out_n = vec![Vec3::ZERO; n];
    for with_normals in [false, true] {
        let mut best = f64::INFINITY;
        for _ in 0..50 {
            let mut job = SkinningJobRef::default();
            job.set_vertex_count(n);
            job.set_influences_count(4);
            job.set_joint_matrices(&matrices[..]);
            job.set_joint_indices(&idx[..]);
            job.set_joint_weights(&weights[..]);
            job.set_in_positions(&positions[..]);
            job.set_out_positions(&mut out_p[..]);
            if with_normals {
                job.set_in_normals(&normals[..]);
                job.set_out_normals(&mut out_n[..]);
            }
            let t = Instant::now();
            job.run().expect("skinning");
            best = best.min(t.elapsed().as_secs_f64());
        }
        let sum: f64 = out_p.iter().map(|v| (v.x + v.y + v.z) as f64).sum();
        println!(
            "ozz-animation-rs 0.11.0 LBS, {} vertices x 4 influences, {}: best {:.3} ms, {:.1} M vertices/s (checksum {sum:.6})",
            n,
            if with_normals { "positions and normals" } else { "positions" },
            best * 1e3,
            n as f64 / best / 1e6
        );
    }
}
