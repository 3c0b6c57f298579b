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
//! - `collide/hash/neighbours/100k`: a spatial hash (Teschner, 131,071 buckets, cells of
//!   0.02) over 100,000 random points in the unit cube, a ball query of radius 0.02
//!   around every point (about 3.3 neighbours each); and the build.
//! - `collide/sdf/mesh-samples`: trilinear samples with gradient of the nut's distance
//!   field (the shared TetGen nut surface, 1,046 triangles, 40 cells across), and
//!   `collide/sdf/torus-samples`, the exact torus distance with gradient, per second.
//! - `collide/cloth-fold/step`: one step of `scenes/cloth-fold.toml` (30 x 30 vertices)
//!   once the sheet lies folded (60 steps in), with and without `[cloth.self_collision]`.
//!
//! - `collide/haptics/god-object/10k`: one tick of the god object against a sphere of
//!   10,000 triangles with the device pressed 0.2 below its top, and the replay of the
//!   3 s scripted stroke at 1 kHz with the 50th and 99th percentiles of a tick's work
//!   (target: 99th below 1 ms).
//!
//! Run with `cargo bench --bench collide` (`-- collide/bvh` for a part); the summary is
//! printed and written to `target/criterion/collide-summary.md`.

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
    if wanted("collide/hash") {
        md += &hash(&mut c);
    }
    if wanted("collide/sdf") {
        md += &sdf(&mut c);
    }
    if wanted("collide/haptics") {
        md += &haptics(&mut c);
    }
    #[cfg(feature = "cloth")]
    if wanted("collide/cloth-fold") {
        md += &cloth_fold(&mut c);
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

/// `n` xorshift points in the unit cube, component-major.
fn random_points(n: usize, seed: u64) -> Vec<f64> {
    let mut s = seed;
    let mut x = vec![0.0; 3 * n];
    for v in x.iter_mut() {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        *v = (s >> 11) as f64 / (1u64 << 53) as f64;
    }
    x
}

fn hash(c: &mut Criterion) -> String {
    use largestep::kernels::collide::grid::{CellGrid, Cells};
    let n = 100_000;
    let x = random_points(n, 77);
    let r = 0.02;
    let mut g = CellGrid::new(r, Cells::Hashed { buckets: 131_071 });
    c.bench_function("collide/hash/build/100k", |b| b.iter(|| g.build_points(&x)));
    let build = best_of(10, || g.build_points(&x));
    let (mut scratch, mut out) = (Vec::new(), Vec::new());
    let mut query_all = || {
        out.clear();
        for i in 0..n {
            g.points_within([x[i], x[n + i], x[2 * n + i]], r, &mut scratch, &mut out);
        }
        out.len()
    };
    c.bench_function("collide/hash/neighbours/100k", |b| b.iter(&mut query_all));
    let mut found = 0;
    let queries = best_of(10, || found = query_all());
    format!(
        "## Spatial hash, 100,000 points in the unit cube, radius 0.02 (1 thread)\n\n| | best of 10 |\n|---|---|\n| build | {:.2} ms |\n| 100,000 ball queries | {:.2} ms: {:.1} M queries/s, {:.2} neighbours each (self included) |\n\n",
        build * 1e3,
        queries * 1e3,
        n as f64 / queries / 1e6,
        found as f64 / n as f64
    )
}

fn sdf(c: &mut Criterion) -> String {
    use largestep::collide::SdfGrid;
    use largestep::kernels::collide::sdf::Shape;
    use largestep::kernels::interp::sample3_grad;
    let path = std::path::Path::new("../shared/data/tetmesh/nut-surface.off");
    let Ok(mesh) = largestep::io::read_surface(path, 1 << 24) else {
        return format!(
            "## Distance fields\n\n(skipped: {} not found)\n\n",
            path.display()
        );
    };
    let m = mesh.as_ref();
    let Aabb { min: lo, max: hi } =
        Aabb::of_points((0..mesh.positions.len() / 3).map(|i| m.vertex(i)));
    let size = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    let h = size / 40.0;
    let t0 = Instant::now();
    let field = SdfGrid::from_mesh(&mesh, h, 2, 1 << 24).expect("the nut is closed");
    let build = t0.elapsed().as_secs_f64();
    let k = 1_000_000;
    let u = random_points(k, 5);
    let pts: Vec<[f64; 3]> = (0..k)
        .map(|i| [0, 1, 2].map(|a| lo[a] + u[a * k + i] * (hi[a] - lo[a])))
        .collect();
    let sample_all = || {
        pts.iter()
            .map(|&p| sample3_grad(&field.phi, field.grid, p).0)
            .sum::<f64>()
    };
    c.bench_function("collide/sdf/mesh-samples/1M", |b| b.iter(sample_all));
    let torus = Shape::Torus {
        center: [0.5; 3],
        axis: [0.0, 0.6, 0.8],
        major: 0.3,
        minor: 0.1,
    };
    let unit: Vec<[f64; 3]> = (0..k).map(|i| [u[i], u[k + i], u[2 * k + i]]).collect();
    let torus_all = || unit.iter().map(|&p| torus.distance_grad(p).0).sum::<f64>();
    c.bench_function("collide/sdf/torus-samples/1M", |b| b.iter(torus_all));
    let mesh_t = best_of(10, || {
        std::hint::black_box(sample_all());
    });
    let torus_t = best_of(10, || {
        std::hint::black_box(torus_all());
    });
    format!(
        "## Distance fields (1 thread)\n\n| | value |\n|---|---|\n| nut field build ({} x {} x {} nodes, 1,046 triangles) | {:.0} ms |\n| trilinear sample with gradient | {:.1} M samples/s |\n| exact torus distance with gradient | {:.1} M samples/s |\n\n",
        field.grid.n[0],
        field.grid.n[1],
        field.grid.n[2],
        build * 1e3,
        k as f64 / mesh_t / 1e6,
        k as f64 / torus_t / 1e6
    )
}

#[cfg(feature = "cloth")]
fn cloth_fold(c: &mut Criterion) -> String {
    use largestep::scene::Scene;
    let text = std::fs::read_to_string("scenes/cloth-fold.toml").expect("scenes/cloth-fold.toml");
    let mut rows = String::new();
    for with in [true, false] {
        let t = if with {
            text.clone()
        } else {
            text.replace("[cloth.self_collision]\nthickness = 0.004\n", "")
        };
        let mut scene = Scene::parse(&t, "cloth-fold.toml").expect("the scene parses");
        let dt = scene.dt;
        let sim = &mut scene.systems[0].sim;
        for _ in 0..60 {
            sim.step(dt).expect("the fold runs");
        }
        let name = if with {
            "collide/cloth-fold/step/self-collision"
        } else {
            "collide/cloth-fold/step/none"
        };
        c.bench_function(name, |b| b.iter(|| sim.step(dt).expect("the fold runs")));
        let per = best_of(20, || {
            sim.step(dt).expect("the fold runs");
        });
        rows += &format!(
            "| {} | {:.2} ms |\n",
            if with {
                "with self-collision (4 mm)"
            } else {
                "without"
            },
            per * 1e3
        );
    }
    format!("## Cloth fold, 30 x 30 vertices, folded (60 steps in)\n\n| step | best of 20 |\n|---|---|\n{rows}\n")
}

fn haptics(c: &mut Criterion) -> String {
    use largestep::haptics::{latency, replay, DevicePath, GodObject};
    let m = largestep::shapes::uv_sphere([0.0; 3], 1.0, 51, 100);
    let mut god = GodObject::new(&m, 500.0).expect("a closed sphere");
    let b = god.bounds();
    let top = god.top();
    let path = DevicePath::stroke(&b, [top[0] + 0.013, top[2] + 0.007], 0.2);
    god.reset([0.013, 1.5, 0.007]).expect("outside");
    c.bench_function("collide/haptics/god-object/10k", |bch| {
        bch.iter(|| god.tick([0.013, 0.8, 0.007]))
    });
    let mut best = [f64::INFINITY; 4];
    for _ in 0..5 {
        let ticks = replay(&mut god, &path).expect("the stroke starts outside");
        let l = latency(&ticks);
        if l[2] < best[2] {
            best = l;
        }
    }
    // Six-DoF: a point shell of the sphere mesh's vertices (radius 0.05, 1,002 points)
    // against a 64^3 distance grid of a torus, pressed 1 cm into its top over 3,000 ticks.
    use largestep::haptics::SixDof;
    use largestep::kernels::collide::sdf::Shape;
    use largestep::kernels::interp::Grid3;
    use largestep::kernels::quat::IDENTITY;
    let shell_mesh = largestep::shapes::uv_sphere([0.0; 3], 0.05, 20, 50);
    let shell: Vec<[f64; 3]> = (0..shell_mesh.positions.len() / 3)
        .map(|i| shell_mesh.as_ref().vertex(i))
        .collect();
    let torus = Shape::Torus {
        center: [0.0; 3],
        axis: [0.0, 1.0, 0.0],
        major: 0.3,
        minor: 0.1,
    };
    let grid = Grid3::spanning([64, 64, 64], [-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]);
    let env = std::sync::Arc::new(largestep::collide::SdfGrid::sample(grid, |p| {
        torus.distance(p)
    }));
    let mut tool = SixDof::new(shell.clone(), env, 1000.0, 10.0, 2e3).expect("valid");
    let start = [0.3, 0.2, 0.0];
    let mut works = Vec::with_capacity(3000);
    tool.reset(start, IDENTITY);
    for i in 0..3000 {
        let y = 0.2 - (0.05 + 0.01) * (i as f64 / 2999.0) * 2.0;
        let t0 = Instant::now();
        std::hint::black_box(tool.tick([0.3, y.max(0.14), 0.0], IDENTITY));
        works.push(t0.elapsed().as_secs_f64());
    }
    works.sort_by(f64::total_cmp);
    let (s50, s99) = (works[1500], works[2970]);
    let six = format!(
        "| six-DoF: point shell of {} points against a 64^3 torus grid, 50th / 99th percentile | {:.1} us / {:.1} us ({:.2}% of the tick) |\n",
        shell.len(),
        s50 * 1e6,
        s99 * 1e6,
        100.0 * s99 / 1e-3
    );
    format!(
        "## Haptics: god object against a sphere of {} triangles (1 thread)\n\n| 3 s stroke at 1 kHz, best of 5 replays | work per tick |\n|---|---|\n| 50th percentile | {:.2} us |\n| 90th percentile | {:.2} us |\n| 99th percentile | {:.2} us ({:.3}% of the 1 ms tick) |\n| largest | {:.2} us |\n{six}\n",
        m.triangles.len(),
        best[0] * 1e6,
        best[1] * 1e6,
        best[2] * 1e6,
        100.0 * best[2] / 1e-3,
        best[3] * 1e6
    )
}
