//! Structure-aware fuzzing of every parser and scene builder, on stable Rust with a fixed
//! budget: valid inputs (the shipped scenes, a jello world file, small OBJ, SDF and Matrix
//! Market files) are mutated where their structure is (numbers become extreme values,
//! lines are dropped, doubled, swapped, cut or filled with junk, keys are renamed), with a
//! fixed seed so that a failure reproduces. Every case must end without a panic, within a
//! bounded amount of memory (a counting allocator watches the peak) and, when it is
//! refused, with an error that names a line. Scenes that build are stepped a few times.
//! Files that claim a billion elements must be refused within a few MB.
//!
//! A counting global allocator sees every thread, so the tests of this binary take turns
//! (a lock) and run their cases in sequence. `LARGESTEP_FUZZ_CASES` scales the number of
//! cases (default 3: about 11,000 cases, a few seconds).

use largestep::limits::Limits;
use largestep::scene::Scene;
use std::alloc::{GlobalAlloc, Layout, System};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

struct Counting;

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = CURRENT.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                let now = CURRENT.fetch_add(new_size - layout.size(), Ordering::Relaxed)
                    + (new_size - layout.size());
                PEAK.fetch_max(now, Ordering::Relaxed);
            } else {
                CURRENT.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// One test at a time: the peak is the whole process's.
static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Runs `f` and returns its result and the most memory it held at once beyond what was
/// allocated before (bytes): the heap's peak plus the peak of the large buffers that map
/// their own pages (`soa::ZeroedBuf`, outside the global allocator), a bound from above.
fn peak_of<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let base = CURRENT.load(Ordering::SeqCst);
    PEAK.store(base, Ordering::SeqCst);
    largestep::soa::reset_mapped_peak();
    let (mapped_base, _) = largestep::soa::mapped_bytes();
    let r = f();
    let mapped = largestep::soa::mapped_bytes().1 - mapped_base;
    (r, PEAK.load(Ordering::SeqCst).saturating_sub(base) + mapped)
}

/// faer's dense kernels (private-gemm) keep a thread-local packing buffer of twice the
/// L3 cache the CPU reports, allocated on a thread's first supernodal factorization and
/// kept for the thread's life: 629 MB of address space on a VM that reports a 300 MB L3,
/// touched only as far as a product needs. It is not the scene's memory, so each thread
/// that factors (this one, and the pool's) makes it before the peaks are measured.
fn warm_up_faer() {
    let a = largestep::sparse::examples::grid_spd(&[12, 12, 12], 1.0, 0.1);
    let factor = || {
        let mut chol = largestep::solve::SparseCholesky::new(a.pattern()).unwrap();
        chol.factorize(&a).unwrap();
    };
    factor();
    rayon::broadcast(|_| factor());
}

/// splitmix64: a small, fixed-seed generator.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    fn pick<'a, T>(&mut self, xs: &'a [T]) -> &'a T {
        &xs[self.below(xs.len())]
    }
}

/// Values a number becomes: boundaries of every type and range a parser checks.
const EXTREMES: &[&str] = &[
    "0",
    "-0.0",
    "1",
    "-1",
    "2",
    "0.5",
    "1e-300",
    "5e-324",
    "1e300",
    "-1e300",
    "1e308",
    "1.7976931348623157e308",
    "nan",
    "inf",
    "-inf",
    "4096",
    "4097",
    "65536",
    "1000000",
    "4000000000",
    "4294967296",
    "9223372036854775807",
    "-9223372036854775808",
    "18446744073709551616",
    "1e9",
    "0x10",
    "",
];

/// Junk a line becomes or gains.
const JUNK: &[&str] = &[
    "[",
    "]]",
    "= =",
    "\"unterminated",
    "[scene]",
    "[cloth.grid]",
    "[[mass_spring.particle]]",
    "nu = 1000000000",
    "f 1 2",
    "v 1e308 0 0",
    "vt",
    "# comment",
    "\t",
    "1 2 3 4 5 6 7 8 9",
    "%%MatrixMarket matrix coordinate real general",
];

/// Keys a key becomes.
const KEYS: &[&str] = &[
    "nu",
    "nv",
    "count",
    "n",
    "mass",
    "dt",
    "every",
    "resolution",
    "radius",
    "normal",
    "file",
    "pinned",
    "stiffness",
    "wrinkle",
    "integrator",
    "linear",
];

/// The byte ranges of the numbers in `text` (digits with sign, dot and exponent).
fn numbers(text: &str) -> Vec<(usize, usize)> {
    let b = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts =
            b[i].is_ascii_digit() || (b[i] == b'-' && i + 1 < b.len() && b[i + 1].is_ascii_digit());
        let boundary = i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_');
        if starts && boundary {
            let s = i;
            i += 1;
            while i < b.len()
                && (b[i].is_ascii_digit()
                    || b[i] == b'.'
                    || b[i] == b'e'
                    || b[i] == b'E'
                    || ((b[i] == b'-' || b[i] == b'+') && matches!(b[i - 1], b'e' | b'E')))
            {
                i += 1;
            }
            out.push((s, i));
        } else {
            i += 1;
        }
    }
    out
}

/// One to three structure-aware mutations of `text`.
fn mutate(text: &str, rng: &mut Rng) -> String {
    let mut t = text.to_string();
    for _ in 0..1 + rng.below(3) {
        match rng.below(10) {
            // A number becomes an extreme (most often: sizes and values are where bugs are).
            0..=4 => {
                let nums = numbers(&t);
                if let Some(&(a, b)) = (!nums.is_empty()).then(|| rng.pick(&nums)) {
                    let v = EXTREMES[rng.below(EXTREMES.len())];
                    t.replace_range(a..b, v);
                }
            }
            5 => {
                let mut lines: Vec<&str> = t.lines().collect();
                if !lines.is_empty() {
                    lines.remove(rng.below(lines.len()));
                }
                t = lines.join("\n");
            }
            6 => {
                let mut lines: Vec<String> = t.lines().map(String::from).collect();
                if !lines.is_empty() {
                    let k = rng.below(lines.len());
                    let l = lines[k].clone();
                    lines.insert(rng.below(lines.len() + 1), l);
                }
                t = lines.join("\n");
            }
            7 => {
                let mut lines: Vec<String> = t.lines().map(String::from).collect();
                if !lines.is_empty() {
                    let k = rng.below(lines.len() + 1);
                    lines.insert(k, JUNK[rng.below(JUNK.len())].to_string());
                }
                t = lines.join("\n");
            }
            8 => {
                // Cut at a character boundary.
                let cut = rng.below(t.len() + 1);
                let cut = (0..=cut)
                    .rev()
                    .find(|&c| t.is_char_boundary(c))
                    .unwrap_or(0);
                t.truncate(cut);
            }
            _ => {
                // A key becomes another.
                let keys: Vec<(usize, usize)> = t
                    .match_indices(" = ")
                    .filter_map(|(i, _)| {
                        let start = t[..i].rfind('\n').map_or(0, |p| p + 1);
                        (start < i).then_some((start, i))
                    })
                    .collect();
                if let Some(&(a, b)) = (!keys.is_empty()).then(|| rng.pick(&keys)) {
                    let k = KEYS[rng.below(KEYS.len())];
                    t.replace_range(a..b, k);
                }
            }
        }
    }
    t
}

/// What one case may hold at once beyond the budget the scene layer enforces (bytes):
/// parsing, the error, the model's own estimate rounding.
const SLACK: usize = 96 << 20;

/// The memory budget of the scene cases: small, so that mutated sizes meet it.
const BUDGET: u64 = 64 << 20;

struct Stats {
    cases: usize,
    refused: usize,
    worst_peak: usize,
}

/// Runs `case` on `count` mutations of each seed, checking no panic and bounded memory;
/// `case` checks its own result (a refusal must name a line) and returns whether the
/// input was refused.
fn fuzz(
    name: &str,
    seeds: &[String],
    count: usize,
    rng: &mut Rng,
    stats: &mut Stats,
    case: &dyn Fn(&str) -> bool,
) {
    for k in 0..count {
        let seed = &seeds[k % seeds.len()];
        let input = if k < seeds.len() {
            seed.clone() // each seed once as it is: it must pass
        } else {
            mutate(seed, rng)
        };
        let t0 = Instant::now();
        let (result, peak) = peak_of(|| catch_unwind(AssertUnwindSafe(|| case(&input))));
        let refused = result
            .unwrap_or_else(|_| panic!("{name} case {k} panicked on input:\n{}", clip(&input)));
        assert!(
            peak <= BUDGET as usize + SLACK,
            "{name} case {k} held {peak} bytes on input:\n{}",
            clip(&input)
        );
        assert!(
            t0.elapsed().as_secs_f64() < 10.0,
            "{name} case {k} took {:?} on input:\n{}",
            t0.elapsed(),
            clip(&input)
        );
        stats.cases += 1;
        stats.refused += refused as usize;
        stats.worst_peak = stats.worst_peak.max(peak);
    }
}

fn clip(s: &str) -> String {
    s.chars().take(2000).collect()
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Builds a scene within the small budget, steps each system a few times; whether it was
/// refused. A refusal must name a line.
fn scene_case(text: &str) -> bool {
    let mut limits = Limits::with_memory(BUDGET);
    limits.max_steps = 1_000_000;
    match Scene::parse_with(text, "fuzz.toml", &limits) {
        Err(e) => {
            assert!(e.line > 0, "unlocated scene error: {e}");
            true
        }
        Ok(scene) => {
            let dt = scene.dt;
            for mut system in scene.systems {
                for _ in 0..3 {
                    if system.sim.step(dt).is_err() {
                        break;
                    }
                }
                let _ = system.sim.energy();
                let _ = system.sim.max_penetration();
            }
            false
        }
    }
}

fn world_case(text: &str) -> bool {
    match largestep::mass_spring::world::World::parse(text, "fuzz.w") {
        Err(e) => {
            assert!(e.line > 0, "unlocated world error: {e}");
            true
        }
        Ok(w) => {
            // Into a scene within the budget, stepped twice.
            let mut limits = Limits::with_memory(BUDGET);
            limits.max_steps = 1_000_000;
            match w.to_scene("fuzz.w", &limits) {
                Err(_) => true,
                Ok(scene) => {
                    let dt = scene.dt;
                    for mut s in scene.systems {
                        let _ = s.sim.step(dt);
                        let _ = s.sim.step(dt);
                    }
                    false
                }
            }
        }
    }
}

fn obj_case(text: &str) -> bool {
    let a = largestep::io::parse_obj(text, "fuzz.obj");
    let b = largestep::io::parse_obj_uv(text, "fuzz.obj");
    for e in [a.as_ref().err(), b.as_ref().err()].into_iter().flatten() {
        assert!(e.line > 0, "unlocated OBJ error: {e}");
    }
    a.is_err() || b.is_err()
}

fn sdf_case(text: &str) -> bool {
    match largestep::collide::SdfGrid::parse(text, "fuzz.sdf") {
        Err(e) => {
            assert!(e.line > 0, "unlocated SDF error: {e}");
            true
        }
        Ok(g) => {
            let o = largestep::collide::Obstacle::Sdf(std::sync::Arc::new(g));
            let _ = o.validate(0);
            let _ = o.distance([0.1, 0.2, 0.3]);
            false
        }
    }
}

fn mm_case(text: &str) -> bool {
    match largestep::sparse::read_matrix_market(std::io::Cursor::new(text), "fuzz.mtx") {
        Err(largestep::sparse::SparseError::Parse { line, .. }) => {
            assert!(line > 0, "unlocated Matrix Market error");
            true
        }
        Err(e) => panic!("Matrix Market from memory failed other than by parsing: {e}"),
        Ok(_) => false,
    }
}

#[test]
fn parsers_and_scene_builders_survive_mutated_input() {
    let _turn = TURN.lock().unwrap_or_else(|p| p.into_inner());
    warm_up_faer();
    let scale: usize = std::env::var("LARGESTEP_FUZZ_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3);
    let t0 = Instant::now();
    let mut rng = Rng(0x6c61_7267_6573_7465);
    let mut stats = Stats {
        cases: 0,
        refused: 0,
        worst_peak: 0,
    };
    // Scenes: the shipped ones, made small enough to step in a test, and a scene of
    // explicit particles and springs.
    let mut scenes: Vec<String> = std::fs::read_dir(root().join("scenes"))
        .unwrap()
        .map(|e| std::fs::read_to_string(e.unwrap().path()).unwrap())
        .map(|s| {
            s.replace("nu = 50", "nu = 8")
                .replace("nv = 50", "nv = 8")
                .replace("nu = 40", "nu = 8")
                .replace("nv = 40", "nv = 8")
                .replace("nu = 30", "nu = 6")
                .replace("nv = 30", "nv = 6")
                .replace("n = [8, 8, 8]", "n = [3, 3, 3]")
                .replace("cells = [50, 4, 4]", "cells = [6, 2, 2]")
                .replace("modes = 60", "modes = 8")
                .replace("cells = [64, 96, 64]", "cells = [6, 8, 6]")
                .replace("cells = [64, 64, 1]", "cells = [8, 8, 1]")
                .replace("cells = [128, 192, 1]", "cells = [8, 12, 1]")
        })
        .collect();
    scenes.sort();
    scenes.push(
        "[scene]\ndt = 0.001\nduration = 0.01\nintegrator = \"backward-euler\"\ngravity = [0.0, -9.81, 0.0]\n[[mass_spring.particle]]\nposition = [0.0, 0.0, 0.0]\nmass = 1.0\npinned = true\n[[mass_spring.particle]]\nposition = [1.0, 0.0, 0.0]\nmass = 1.0\n[[mass_spring.spring]]\na = 0\nb = 1\nstiffness = 100.0\ndamping = 0.1\n[solver]\nlinear = \"pcg\"\ntolerance = 1e-6\n[output]\nevery = 2\n[output.camera]\nazimuth = 10.0\n".into(),
    );
    fuzz(
        "scene",
        &scenes,
        1200 * scale,
        &mut rng,
        &mut stats,
        &scene_case,
    );
    // A world file: the assignment's layout, with a 2^3 force field to keep it short.
    let world = {
        let mut w = String::from("RK4\n0.0005 1\n200 0.25 400 0.25\n0.001953\n1\n-1 1 1 2\n2\n");
        for i in 0..8 {
            w.push_str(&format!("0 {} 0\n", -0.01 * i as f64));
        }
        for v in 0..2 {
            for i in 0..8 {
                for j in 0..8 {
                    for k in 0..8 {
                        if v == 0 {
                            w.push_str(&format!(
                                "{} {} {}\n",
                                i as f64 / 7.0,
                                j as f64 / 7.0,
                                k as f64 / 7.0
                            ));
                        } else {
                            w.push_str("0 0 0\n");
                        }
                    }
                }
            }
        }
        w
    };
    fuzz(
        "world",
        &[world],
        300 * scale,
        &mut rng,
        &mut stats,
        &world_case,
    );
    let obj = "# sheet\nv 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 1 0\nf 1/1/1 2/2/1 3/3/1\nf 1/1 3/3 4/4\nl 1 2 3\nf -4/-4 -3/-3 -2/-2\no name\ng group\ns off\n";
    fuzz(
        "obj",
        &[obj.into()],
        1000 * scale,
        &mut rng,
        &mut stats,
        &obj_case,
    );
    let mut sdf = String::from("3 3 3\n-1 -1 -1\n1\n");
    for k in 0..27 {
        sdf.push_str(&format!("{} ", k as f64 * 0.1 - 1.0));
    }
    fuzz("sdf", &[sdf], 600 * scale, &mut rng, &mut stats, &sdf_case);
    let mm = "%%MatrixMarket matrix coordinate real symmetric\n% a comment\n3 3 4\n1 1 2.0\n2 1 -1.0\n2 2 2.0\n3 3 2.0\n";
    fuzz(
        "mm",
        &[mm.into()],
        600 * scale,
        &mut rng,
        &mut stats,
        &mm_case,
    );
    let secs = t0.elapsed().as_secs_f64();
    println!(
        "fuzz: {} cases in {secs:.1} s, {} refused with a located error, the largest peak {:.1} MB",
        stats.cases,
        stats.refused,
        stats.worst_peak as f64 / 1e6
    );
    assert!(
        stats.refused > stats.cases / 10,
        "the mutations should break many inputs"
    );
}

/// Files that claim a billion elements are refused within a few MB, before any
/// allocation is sized by the claim.
#[test]
fn claims_of_a_billion_elements_are_refused_within_a_few_mb() {
    let _turn = TURN.lock().unwrap_or_else(|p| p.into_inner());
    let few = 4 << 20;
    type Claim = (&'static str, Box<dyn Fn() -> bool>);
    let cases: Vec<Claim> = vec![
        (
            "OBJ face index",
            Box::new(|| {
                largestep::io::parse_obj_uv(
                    "v 0 0 0\nv 1 0 0\nv 0 0 1\nvt 0 0\nf 1000000000/1 2/1 3/1\n",
                    "a.obj",
                )
                .is_err()
            }),
        ),
        (
            "SDF header",
            Box::new(|| {
                largestep::collide::SdfGrid::parse("1000 1000 1000\n0 0 0\n1\n0 0 0\n", "a.sdf")
                    .is_err()
            }),
        ),
        (
            "Matrix Market size line",
            Box::new(|| {
                largestep::sparse::read_matrix_market(
                    std::io::Cursor::new("%%MatrixMarket matrix coordinate real symmetric\n1000000000 1000000000 1000000000\n1 1 1.0\n"),
                    "a.mtx",
                )
                .is_err()
            }),
        ),
        (
            "scene lattice",
            Box::new(|| {
                Scene::parse_with(
                    "[scene]\ndt = 0.01\nduration = 1.0\nintegrator = \"rk4\"\n[mass_spring.lattice]\nn = [1000, 1000, 1000]\nsize = [1.0, 1.0, 1.0]\nmass = 1.0\nstructural = 1.0\n",
                    "a.toml",
                    &Limits::with_memory(BUDGET),
                )
                .is_err()
            }),
        ),
        (
            "world force field",
            Box::new(|| {
                largestep::mass_spring::world::World::parse(
                    "RK4\n0.001 1\n1 1 1 1\n1\n0\n1000\n0 0 0\n",
                    "a.w",
                )
                .is_err()
            }),
        ),
    ];
    for (what, case) in cases {
        let (refused, peak) = peak_of(case);
        assert!(refused, "{what} must be refused");
        assert!(peak < few, "{what}: {peak} bytes before the refusal");
    }
}
