//! Rigid-body benchmarks of issue 19.
//!
//! - `rigid/pile/step`: one step (dt = 1/60 s) of `scenes/rigid-pile.toml`, 1,000 boxes
//!   tumbling onto a slab, from the state after 2 s (the boxes landing and piling, the
//!   most contacts), single-threaded: criterion's time of a step from a copy of that state.
//! - The whole run: the scene's 360 steps, each timed, the mean per step; beside it the
//!   peer's on the same bodies (rapier3d 0.36.1 in `benches/peers/rapier-pile`, run here
//!   when built; it reads the bodies from `target/criterion/rigid-pile.bin`), with the
//!   solver settings of each.
//! - The whole run again with sleeping on (`RigidDesc::sleep`, Box2D's thresholds),
//!   beside the peer's run with sleeping on.
//! - The whole runs of both (sleeping off) alternated five times: the ratio a round and
//!   fastest against fastest (on a shared machine single runs move by up to 30%); in the
//!   same rounds ours with `contact_reuse` 0.1 (kept manifolds while a pair moves less
//!   than 5 cm, about rapier's contact recycling distance; `largestep study rigid-reuse`
//!   says how stale that lets the contacts get).
//! - Machine fraction: the solver's floating-point work counted from the contacts (a
//!   point's normal row and a manifold's two tangent rows cost 24 multiply-adds a visit,
//!   its twist row 12; two visits a sub-step, four sub-steps) over one thread's share of
//!   the peak FMA rate measured in the same run.
//!
//! Run with `cargo bench --bench rigid`; the summary is printed and written to
//! `target/criterion/rigid-summary.md`.

use criterion::{BatchSize, Criterion};
use largestep::rigid::scene::RigidSim;
use largestep::rigid::{Rigid, RigidState, RigidWork, Shape};
use largestep::scene::Scene;
use std::io::Write;
use std::time::Instant;

/// The pile scene's model and start state.
fn pile() -> (Rigid, RigidState, RigidWork) {
    let scene = Scene::load(std::path::Path::new("scenes/rigid-pile.toml")).expect("scene");
    let sim = scene.into_simulation().expect("one system");
    let sim: &RigidSim = sim.downcast_ref().expect("a rigid scene");
    sim.model().desc().build().expect("builds")
}

/// Writes the bodies for the peer (see `benches/peers/rapier-pile`).
fn write_bodies(m: &Rigid, s: &RigidState) {
    let mut out = Vec::new();
    for (i, b) in m.desc().bodies.iter().enumerate() {
        let Shape::Box { half } = b.shape else {
            panic!("the pile holds boxes only");
        };
        let rv = largestep::kernels::quat::log(s.q[i]);
        let fixed = if m.is_dynamic(i) { 0.0 } else { 1.0 };
        for v in [
            s.x[i][0], s.x[i][1], s.x[i][2], rv[0], rv[1], rv[2], half[0], half[1], half[2],
            b.density, fixed,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::create_dir_all("target/criterion").ok();
    std::fs::write("target/criterion/rigid-pile.bin", out).expect("write bodies");
}

/// Runs the rapier3d peer when it is built: its output line with sleeping off and on.
fn run_peer() -> Option<Vec<String>> {
    let exe = std::path::Path::new("benches/peers/rapier-pile/target/release/rapier-pile-peer");
    let out = std::process::Command::new(exe)
        .arg("target/criterion/rigid-pile.bin")
        .output()
        .ok()?;
    let text = String::from_utf8(out.stdout).ok()?;
    Some(text.lines().map(str::to_string).collect())
}

/// A whole run (360 steps) of `m` from a copy of the start state: the mean step (ms) and
/// the state at the end.
fn whole_run(m: &Rigid, s0: &RigidState, w0: &RigidWork) -> (f64, RigidState) {
    let (mut s, mut w) = (s0.clone(), w0.clone());
    let t = Instant::now();
    for _ in 0..360 {
        m.step(&mut s, &mut w, 1.0 / 60.0).expect("step");
    }
    (t.elapsed().as_secs_f64() * 1e3 / 360.0, s)
}

/// The peer's mean step (ms) on its line for `sleeping` ("sleeping off" or "sleeping on").
fn peer_line_ms(lines: &[String], sleeping: &str) -> Option<f64> {
    peer_ms(lines.iter().find(|l| l.contains(sleeping))?)
}

/// The mean per step (ms) in a peer line "...: 2.950 ms per step ...".
fn peer_ms(line: &str) -> Option<f64> {
    let at = line.find(" ms per step")?;
    line[..at].rsplit(' ').next()?.parse().ok()
}

/// `contact_reuse` for the rounds beside rapier's contact recycling: 5 cm on these
/// half-metre boxes, rapier's `contact_recycle_distance`.
const LOOSE: f64 = 0.1;

fn main() {
    // Single-threaded, as the peer.
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build_global()
        .ok();
    let mut c = Criterion::default()
        .configure_from_args()
        .sample_size(20)
        .measurement_time(std::time::Duration::from_secs(8));
    let (m, s0, w0) = pile();
    write_bodies(&m, &s0);
    let dt = 1.0 / 60.0;

    // The whole run, each step timed.
    let (mut s, mut w) = (s0.clone(), w0.clone());
    let mut times = Vec::new();
    let mut contacts = 0usize;
    let mut manifolds = 0usize;
    let mut deepest = 0.0f64;
    let mut at_2s = None;
    for k in 0..360 {
        if k == 120 {
            at_2s = Some((s.clone(), w.clone()));
        }
        let t = Instant::now();
        let info = m.step(&mut s, &mut w, dt).expect("step");
        times.push(t.elapsed().as_secs_f64() * 1e3);
        contacts += info.contacts;
        let c = w.contacts();
        manifolds += c
            .windows(2)
            .filter(|p| (p[0].a, p[0].b) != (p[1].a, p[1].b))
            .count()
            + usize::from(!c.is_empty());
        deepest = deepest.max(info.max_depth);
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let lowest = (1..m.len())
        .map(|i| s.x[i][1])
        .fold(f64::INFINITY, f64::min);
    let fastest = (1..m.len())
        .map(|i| largestep::kernels::v3::dot(s.v[i], s.v[i]).sqrt())
        .fold(0.0, f64::max);

    let (s2, w2) = at_2s.expect("120 steps");
    c.bench_function("rigid/pile/step", |b| {
        b.iter_batched(
            || (s2.clone(), w2.clone()),
            |(mut s, mut w)| m.step(&mut s, &mut w, dt).expect("step"),
            BatchSize::LargeInput,
        )
    });

    // The same run with sleeping on, beside the peer's sleeping on.
    let sleeping = {
        let mut d = m.desc().clone();
        d.sleep = Some(largestep::rigid::sleep::Sleep::default());
        let (m, s, w) = d.build().expect("builds");
        let (ms, s) = whole_run(&m, &s, &w);
        (ms, s.asleep.iter().filter(|&&a| a).count())
    };

    let limits = largestep::machine::measure(64);
    let per_thread = limits.peak_gflops() / limits.threads as f64;
    let d = m.desc();
    // Multiply-adds per step: 24 a visit for each point's normal row and each manifold's
    // two tangent rows, 12 for its twist row; a solve and a relax visit per sub-step.
    let rows = contacts as f64 * 24.0 + manifolds as f64 * (2.0 * 24.0 + 12.0);
    let flops = rows / 360.0 * 2.0 * 2.0 * d.iterations as f64;
    let ms = mean(&times);
    let fraction = flops / (ms * 1e-3) / (per_thread * 1e9);
    let peer = run_peer();
    let peer_off = peer
        .as_deref()
        .and_then(|l| peer_line_ms(l, "sleeping off"));
    let ratio = peer_off.map_or("not built".to_string(), |p| {
        format!("{p:.3} ms ({:.2}x ours)", p / ms)
    });
    // Ours and the peer's whole runs alternated: on a shared machine single runs moved by
    // up to 30% within minutes, so the ratio is read round by round, and fastest against
    // fastest.
    let (loose, loose0, loose_w0) = largestep::rigid::RigidDesc {
        contact_reuse: LOOSE,
        ..m.desc().clone()
    }
    .build()
    .expect("builds");
    // A round: ours, ours at `LOOSE` and the peer's (ms a step); a round whose peer run
    // fails is dropped whole.
    let rounds: Vec<(f64, f64, f64)> = if peer_off.is_some() {
        (0..5)
            .filter_map(|_| {
                let (ours, _) = whole_run(&m, &s0, &w0);
                let (loosened, _) = whole_run(&loose, &loose0, &loose_w0);
                Some((ours, loosened, peer_line_ms(&run_peer()?, "sleeping off")?))
            })
            .collect()
    } else {
        Vec::new()
    };
    // Smallest, largest and median of `f` over the rounds.
    let spread = |f: &dyn Fn(&(f64, f64, f64)) -> f64| {
        let mut v: Vec<f64> = rounds.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        (v[0], v[v.len() - 1], v[v.len() / 2])
    };
    let (alternated, loosened) = if rounds.is_empty() {
        let none = "not run (the peer is not built)".to_string();
        (none.clone(), none)
    } else {
        let (o_min, o_max, _) = spread(&|r| r.0);
        let (p_min, p_max, _) = spread(&|r| r.2);
        let (r_min, r_max, r_med) = spread(&|r| r.0 / r.2);
        let (l_min, _, _) = spread(&|r| r.1);
        let (q_min, q_max, q_med) = spread(&|r| r.1 / r.2);
        (
            format!(
                "{} rounds, ours {o_min:.3}-{o_max:.3} ms, rapier {p_min:.3}-{p_max:.3} ms; ours over rapier's {r_min:.2}-{r_max:.2}x a round (median {r_med:.2}x), fastest against fastest {:.2}x",
                rounds.len(),
                o_min / p_min
            ),
            format!(
                "{l_min:.3} ms fastest; over rapier's {q_min:.2}-{q_max:.2}x a round (median {q_med:.2}x)"
            ),
        )
    };
    let ratio_sleeping = peer
        .as_deref()
        .and_then(|l| peer_line_ms(l, "sleeping on"))
        .map_or("not built".to_string(), |p| {
            format!("{p:.3} ms ({:.2}x ours)", p / sleeping.0)
        });
    let reuse = d.contact_reuse;
    let summary = format!(
        "## Pile of 1,000 boxes (`scenes/rigid-pile.toml`), dt = 1/60 s, 1 thread\n\n\
| | largestep | peer: rapier3d 0.36.1 (sleeping off) |\n|---|---|---|\n\
| mean step over the 360 steps | {ms:.3} ms (first 120: {:.3}, last 120: {:.3}) | {ratio} |\n\
| the same with sleeping on (peer: sleeping on) | {:.3} ms, {} of 1,000 boxes asleep at the end | {ratio_sleeping} |\n\
| whole runs alternated with the peer's (sleeping off) | {alternated} | |\n\
| in the same rounds, ours with `contact_reuse` {LOOSE} (about rapier's recycling distance) | {loosened} | |\n\
| solver | {} sub-steps of sequential impulses, soft contacts (30 Hz, damping ratio 20), relax, manifold friction 0.5 (two tangent rows and a twist row) in both passes, persistent manifolds (`contact_reuse` {reuse}: kept while the pair's pose moves less than {reuse} of the size and {reuse} rad), rows stored in f32 and solved in f64, contact margin 2% of the size plus the closing distance | 4 iterations, soft contacts (rapier's defaults), friction 0.5 (two tangent rows and a twist row) in the relax pass only (`friction_in_bias_pass` false), contact recycling (a pair whose pose moved less than 0.05 m keeps its points), f32, prediction distance 0.02 m |\n\n\
{:.0} contact points in {:.0} manifolds a step on average, deepest {deepest:.4} m; at the end the lowest centre is at {lowest:.3} m and the fastest box moves {fastest:.3} m/s.\n\n\
Machine: {:.1} GFLOP/s of solver work, {:.1}% of one thread's peak FMA rate ({per_thread:.1} GFLOP/s).\n\n\
Peer output:\n\n```\n{}\n```\n",
        mean(&times[..120]),
        mean(&times[240..]),
        sleeping.0,
        sleeping.1,
        d.iterations,
        contacts as f64 / 360.0,
        manifolds as f64 / 360.0,
        flops / (ms * 1e-3) / 1e9,
        100.0 * fraction,
        peer.map_or("not built (see benches/peers/rapier-pile)".into(), |l| l.join("\n")),
    );
    println!("\n{summary}");
    if let Ok(mut f) = std::fs::File::create("target/criterion/rigid-summary.md") {
        let _ = f.write_all(summary.as_bytes());
    }
    c.final_summary();
}
