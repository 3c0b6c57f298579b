//! Character animation benchmarks of issue 20.
//!
//! - **Skinning** of 100,000 vertices with four influences each over 64 joints (rigid
//!   skinning matrices, random weights), linear blend and dual quaternion, positions
//!   alone and with normals, on one thread (the SIMD kernel) and on all (`_par`).
//!   Vertices per second, and the fraction of the triad bandwidth measured in the same
//!   run, counting the bytes each vertex streams: 12 B of position in, 8 B of joint
//!   indices, 16 B of weights and 12 B of position out (48 B), plus 24 B with normals.
//! - Beside it the peer, ozz-animation-rs 0.11.0's `SkinningJob` on the same data, one
//!   thread (`benches/peers/ozz-skinning`, run here when built; it reads
//!   `target/criterion/skin-data.bin`, which this bench writes).
//! - **Sampling and FK** per joint: the shared 70-joint BVH clip sampled at a time
//!   between frames (`Clip::sample`), then forward kinematics (`Skeleton::model`).
//!
//! Run with `cargo bench --bench anim`; the summary is printed and written to
//! `target/criterion/anim-summary.md`.

use criterion::Criterion;
use largestep::anim::bvh::Bvh;
use largestep::anim::clip::Clip;
use largestep::kernels::anim::affine_from_trs;
use largestep::kernels::skin::{self, SkinInput, SkinMatrix};
use std::io::Write;
use std::time::Instant;

const VERTICES: usize = 100_000;
const JOINTS: usize = 64;

/// The skinning data: component-major positions and normals, influences, matrices.
struct Data {
    positions: Vec<f32>,
    normals: Vec<f32>,
    joints: Vec<[u16; 4]>,
    weights: Vec<[f32; 4]>,
    matrices: Vec<SkinMatrix>,
}

fn data() -> Data {
    let mut s = 0x2545f4914f6cdd1du64;
    let mut rnd = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let n = VERTICES;
    let positions = (0..3 * n).map(|_| (2.0 * rnd() - 1.0) as f32).collect();
    let mut normals = vec![0.0f32; 3 * n];
    for v in 0..n {
        let d = [rnd() - 0.5, rnd() - 0.5, rnd() - 0.5];
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-9);
        for c in 0..3 {
            normals[c * n + v] = (d[c] / l) as f32;
        }
    }
    let joints = (0..n)
        .map(|_| [0; 4].map(|_: u16| (rnd() * JOINTS as f64) as u16 % JOINTS as u16))
        .collect();
    let weights = (0..n)
        .map(|_| {
            let w = [rnd() + 0.1, rnd(), rnd(), rnd()];
            let t: f64 = w.iter().sum();
            w.map(|x| (x / t) as f32)
        })
        .collect();
    let matrices = (0..JOINTS)
        .map(|_| {
            let r = [rnd() - 0.5, rnd() - 0.5, rnd() - 0.5].map(|x| 4.0 * x);
            let t = [rnd(), rnd(), rnd()];
            skin::skin_matrix(&affine_from_trs(
                t,
                largestep::kernels::quat::exp(r),
                [1.0; 3],
            ))
        })
        .collect();
    Data {
        positions,
        normals,
        joints,
        weights,
        matrices,
    }
}

/// Writes the data for the peer (layout in `benches/peers/ozz-skinning/src/main.rs`).
fn write_peer_data(d: &Data) {
    let n = VERTICES;
    let mut out = Vec::new();
    out.extend_from_slice(&(n as u32).to_le_bytes());
    out.extend_from_slice(&(JOINTS as u32).to_le_bytes());
    for src in [&d.positions, &d.normals] {
        for v in 0..n {
            for c in 0..3 {
                out.extend_from_slice(&src[c * n + v].to_le_bytes());
            }
        }
    }
    for j in &d.joints {
        for x in j {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    for w in &d.weights {
        for x in w {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    for m in &d.matrices {
        for col in m {
            for x in col {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
    }
    std::fs::create_dir_all("target/criterion").ok();
    std::fs::write("target/criterion/skin-data.bin", out).expect("write skinning data");
}

/// The peer's two lines (positions; positions and normals), when it is built.
fn run_peer() -> Option<Vec<String>> {
    let exe = std::path::Path::new("benches/peers/ozz-skinning/target/release/ozz-skinning-peer");
    let out = std::process::Command::new(exe)
        .arg("target/criterion/skin-data.bin")
        .output()
        .ok()?;
    let text = String::from_utf8(out.stdout).ok()?;
    Some(text.lines().map(str::to_string).collect())
}

/// The best time (ms) in a peer line "...: best 1.234 ms, ...".
fn peer_ms(line: &str) -> Option<f64> {
    let rest = &line[line.find("best ")? + 5..];
    rest.split_whitespace().next()?.parse().ok()
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

type Kernel = fn(&mut [f32], &mut [f32], &SkinInput, &[SkinMatrix]);
type DqKernel = fn(&mut [f32], &mut [f32], &SkinInput, &[skin::DualQuat]);

fn main() {
    let mut c = Criterion::default()
        .configure_from_args()
        .sample_size(30)
        .measurement_time(std::time::Duration::from_secs(3));
    let d = data();
    write_peer_data(&d);
    let n = VERTICES;
    let mut dual = vec![[0.0f32; 8]; JOINTS];
    skin::dual_quaternions(&mut dual, &d.matrices);
    let mut out_p = vec![0.0f32; 3 * n];
    let mut out_n = vec![0.0f32; 3 * n];
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let threads = rayon::current_num_threads();
    let triad_all = largestep::machine::triad_bandwidth(
        largestep::machine::DEFAULT_TRIAD_MIB * (1 << 20) / 8,
        3,
    );
    let triad_one = one.install(|| {
        largestep::machine::triad_bandwidth(
            largestep::machine::DEFAULT_TRIAD_MIB * (1 << 20) / 8,
            3,
        )
    });
    let peer = run_peer();
    let mut md = format!(
        "## Skinning, {n} vertices x 4 influences, {JOINTS} joints\n\ntriad bandwidth: {triad_one:.1} GB/s on one thread, {triad_all:.1} GB/s on {threads}\n\n| method | data | threads | best of 30 | vertices/s | of triad | peer: ozz-animation-rs 0.11.0 (1 thread) |\n|---|---|---|---|---|---|---|\n"
    );
    let mut checksums = String::new();
    for normals in [false, true] {
        let input = SkinInput {
            positions: &d.positions,
            normals: if normals { &d.normals } else { &[] },
            joints: &d.joints,
            weights: &d.weights,
        };
        let on: &mut [f32] = if normals { &mut out_n } else { &mut [] };
        let what = if normals {
            "positions+normals"
        } else {
            "positions"
        };
        let bytes = if normals { 72.0 } else { 48.0 };
        let peer_line = peer
            .as_ref()
            .and_then(|p| p.get(normals as usize))
            .and_then(|l| peer_ms(l));
        let lbs: [(usize, Kernel); 2] = [(1, skin::lbs), (threads, skin::lbs_par)];
        for (t, k) in lbs {
            let name = format!("anim/skin/lbs/{what}/{t}-thread");
            // The one-thread kernels are serial: they run on this thread.
            let run = |out_p: &mut [f32], on: &mut [f32]| k(out_p, on, &input, &d.matrices);
            c.bench_function(&name, |b| b.iter(|| run(&mut out_p, on)));
            let best = best_of(30, || run(&mut out_p, on));
            if t == 1 {
                // The peer prints the same sum of its output positions.
                let sum: f64 = out_p.iter().map(|&v| v as f64).sum();
                checksums += &format!("    largestep LBS, {what}: checksum {sum:.6}\n");
            }
            let triad = if t == 1 { triad_one } else { triad_all };
            let peer = match (t, peer_line) {
                (1, Some(ms)) => format!("{ms:.3} ms (ours {:.2}x as fast)", ms / (best * 1e3)),
                (1, None) => "not built (see benches/peers/ozz-skinning)".into(),
                _ => String::new(),
            };
            md += &format!(
                "| LBS | {what} | {t} | {:.3} ms | {:.0} M | {:.0}% | {peer} |\n",
                best * 1e3,
                n as f64 / best / 1e6,
                100.0 * bytes * n as f64 / best / 1e9 / triad
            );
        }
        let dqs: [(usize, DqKernel); 2] = [(1, skin::dqs), (threads, skin::dqs_par)];
        for (t, k) in dqs {
            let name = format!("anim/skin/dqs/{what}/{t}-thread");
            let run = |out_p: &mut [f32], on: &mut [f32]| k(out_p, on, &input, &dual);
            c.bench_function(&name, |b| b.iter(|| run(&mut out_p, on)));
            let best = best_of(30, || run(&mut out_p, on));
            let triad = if t == 1 { triad_one } else { triad_all };
            md += &format!(
                "| DQS | {what} | {t} | {:.3} ms | {:.0} M | {:.0}% | |\n",
                best * 1e3,
                n as f64 / best / 1e6,
                100.0 * bytes * n as f64 / best / 1e9 / triad
            );
        }
    }
    md += &format!("\nchecksums (sums of the output positions):\n\n{checksums}");
    if let Some(p) = &peer {
        for l in p {
            md += &format!("    {l}\n");
        }
    }

    // Sampling and forward kinematics of the shared clip.
    let path = std::path::Path::new("../shared/data/mocap/mixamo-freebvh.bvh");
    if let Ok(bvh) = Bvh::read(path, 1 << 24) {
        let clip = Clip::from_bvh(&bvh);
        let skeleton = bvh.skeleton().build().expect("skeleton");
        let mut pose = skeleton.rest().clone();
        let mut model = Vec::new();
        let t = 10.37 * clip.frame_time();
        c.bench_function("anim/clip/sample", |b| {
            b.iter(|| clip.sample(t, true, &mut pose))
        });
        c.bench_function("anim/skeleton/model", |b| {
            b.iter(|| skeleton.model(&pose, &mut model))
        });
        let reps = 2000;
        let sample = best_of(reps, || clip.sample(t, true, &mut pose));
        let fk = best_of(reps, || skeleton.model(&pose, &mut model));
        let j = skeleton.len() as f64;
        md += &format!(
            "\n## Sampling and forward kinematics, the shared clip ({} joints), one thread\n\n| stage | best of {reps} | per joint |\n|---|---|---|\n| sample (lerp + NLERP between frames) | {:.2} us | {:.1} ns |\n| local to model | {:.2} us | {:.1} ns |\n",
            skeleton.len(),
            sample * 1e6,
            sample * 1e9 / j,
            fk * 1e6,
            fk * 1e9 / j
        );
    }
    print!("\n{md}");
    if let Ok(mut f) = std::fs::File::create("target/criterion/anim-summary.md") {
        let _ = f.write_all(md.as_bytes());
    }
    c.final_summary();
}
