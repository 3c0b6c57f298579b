//! Modal analysis (issue 16): the generalized eigensolver against beam theory, the modes'
//! orthogonality, dense against sparse, mass kinds, rigid modes, materials from rubber to
//! steel, bad input, and the `largestep modes` command's contract.

use largestep::fem::{Fem, FemDesc, FemMass, FemMaterial, Material};
use largestep::modal::beam::{euler_bernoulli, timoshenko};
use largestep::modal::stiffness_at_rest;
use largestep::simulation::MechModel;
use largestep::solve::{lowest_modes, EigenParams, Mass, Modes, SolveError};
use largestep::sparse::Bsr3;
use std::f64::consts::PI;
use std::path::PathBuf;

/// A free box of cubes (six tetrahedra each), no gravity.
fn bar(cells: [usize; 3], size: [f64; 3], material: FemMaterial, mass: FemMass) -> (Fem, Vec<f64>) {
    let mut desc = FemDesc::cantilever(cells, size, material, 0.0);
    desc.pinned.clear();
    desc.mass = mass;
    let (fem, state) = desc.build().unwrap();
    let rest = state.x.as_slice().to_vec();
    (fem, rest)
}

fn solve(fem: &Fem, k: &Bsr3, fixed: &[usize], params: &EigenParams) -> Result<Modes, SolveError> {
    match fem.mass_matrix() {
        Some(m) => lowest_modes(k, Mass::Consistent(m), fixed, params),
        None => lowest_modes(k, Mass::Lumped(fem.mass()), fixed, params),
    }
}

/// The `count` lowest modes of a free model on the dense path and on the sparse one.
fn dense_and_sparse(fem: &Fem, k: &Bsr3, count: usize) -> (Modes, Modes) {
    let run = |dense_max| {
        let p = EigenParams {
            count,
            dense_max,
            ..EigenParams::default()
        };
        solve(fem, k, &[], &p).unwrap()
    };
    (run(100_000), run(0))
}

fn modes_of(fem: &Fem, rest: &[f64], fixed: &[usize], params: &EigenParams) -> Modes {
    let k = stiffness_at_rest(fem, rest).unwrap();
    solve(fem, &k, fixed, params).unwrap()
}

/// Fraction of a mode's squared displacement along x.
fn axial_fraction(m: &[f64]) -> f64 {
    let n = m.len() / 3;
    let total: f64 = m.iter().map(|v| v * v).sum();
    m[..n].iter().map(|v| v * v).sum::<f64>() / total
}

fn steel() -> FemMaterial {
    FemMaterial::steel(Material::Linear)
}

/// Timoshenko's frequencies lie below Euler-Bernoulli's, by more for stubbier beams, and
/// meet them for slender ones (the reference the bar tests use).
#[test]
fn timoshenko_reference_meets_euler_bernoulli_for_slender_beams() {
    for clamped in [false, true] {
        let beta = if clamped {
            largestep::modal::beam::CLAMPED_FREE_BETA_L
        } else {
            largestep::modal::beam::FREE_FREE_BETA_L
        };
        let ratio = |t: f64| {
            timoshenko(1.0, t, &steel(), clamped) / euler_bernoulli(beta, 1.0, t, &steel())
        };
        let (stubby, slender, thin) = (ratio(0.2), ratio(0.05), ratio(0.001));
        assert!(
            stubby < slender && slender < 1.0 && (thin - 1.0).abs() < 1e-5,
            "{stubby} {slender} {thin}"
        );
    }
}

/// A free-free steel bar, 1 m x 0.05 m x 0.05 m, refined: six rigid modes, the first
/// axial mode at `c / 2L` (c = sqrt(E / rho); the Rayleigh-Love correction is 7e-4 here)
/// and the first bending pair converging from above to Timoshenko's beam (shear and
/// rotary inertia: 0.9% below Euler-Bernoulli's `beta L = 4.7300` at L/t = 20). The
/// table is printed (`-- --nocapture`): linear tetrahedra are far too stiff in bending on
/// coarse meshes (shear locking), as in the FEM's cantilever test.
#[test]
fn free_free_bar_converges_to_beam_theory() {
    let (len, t) = (1.0, 0.05);
    let axial = (steel().young / steel().density).sqrt() / (2.0 * len);
    let bending = timoshenko(len, t, &steel(), false);
    let eb = euler_bernoulli(largestep::modal::beam::FREE_FREE_BETA_L, len, t, &steel());
    let mut rows = Vec::new();
    for k in [1usize, 2, 4] {
        let (fem, rest) = bar([20 * k, k, k], [len, t, t], steel(), FemMass::Consistent);
        let m = modes_of(
            &fem,
            &rest,
            &[],
            &EigenParams {
                count: 16,
                ..EigenParams::default()
            },
        );
        assert_eq!(m.rigid, 6, "a free body has six rigid modes");
        for j in 0..6 {
            assert!(m.eigenvalues[j].abs() < 1e-6 * m.eigenvalues[6]);
        }
        let f = m.frequencies_hz();
        let ax = (m.rigid..m.eigenvalues.len())
            .find(|&j| axial_fraction(m.mode(j)) > 0.9)
            .expect("an axial mode among the first ten");
        let fa = f[ax - m.rigid];
        let fb = 0.5 * (f[0] + f[1]);
        assert!(m.residuals.iter().all(|&r| r < 1e-7), "{:?}", m.residuals);
        rows.push((rest.len(), fb / bending, fa / axial));
    }
    println!("unknowns | first bending / Timoshenko (/ Euler-Bernoulli) | first axial / (c / 2L)");
    for r in &rows {
        println!(
            "{} | {:.4} ({:.4}) | {:.6}",
            r.0,
            r.1,
            r.1 * bending / eb,
            r.2
        );
    }
    for w in rows.windows(2) {
        assert!(
            w[1].1 < w[0].1 && w[1].1 > 1.0,
            "bending converges from above: {rows:?}"
        );
        assert!(
            (w[1].2 - 1.0).abs() < (w[0].2 - 1.0).abs(),
            "axial converges: {rows:?}"
        );
    }
    assert!(rows[2].1 < 1.15, "finest bending within 15%: {rows:?}");
    assert!(
        (rows[2].2 - 1.0).abs() < 2e-4,
        "finest axial within 2e-4: {rows:?}"
    );
}

/// The same bar clamped at x = 0 (every vertex of that face fixed): no rigid mode, and the
/// first bending pair converging from above to Timoshenko's (Euler-Bernoulli's `beta L =
/// 1.8751` shown too).
#[test]
fn cantilever_bar_converges_to_beam_theory() {
    let (len, t) = (1.0, 0.05);
    let reference = timoshenko(len, t, &steel(), true);
    let eb = euler_bernoulli(
        largestep::modal::beam::CLAMPED_FREE_BETA_L,
        len,
        t,
        &steel(),
    );
    let mut ratios = Vec::new();
    for k in [1usize, 2, 4] {
        let (fem, rest) = bar([20 * k, k, k], [len, t, t], steel(), FemMass::Consistent);
        let n = rest.len() / 3;
        let fixed: Vec<usize> = (0..n).filter(|&i| rest[i] < 1e-12).collect();
        let m = modes_of(
            &fem,
            &rest,
            &fixed,
            &EigenParams {
                count: 4,
                ..EigenParams::default()
            },
        );
        assert_eq!(m.rigid, 0);
        for j in 0..4 {
            let x = m.mode(j);
            assert!(fixed
                .iter()
                .all(|&i| x[i] == 0.0 && x[n + i] == 0.0 && x[2 * n + i] == 0.0));
        }
        let f = m.frequencies_hz();
        ratios.push(0.5 * (f[0] + f[1]) / reference);
    }
    println!(
        "cantilever first bending / Timoshenko: {ratios:?} (Timoshenko / Euler-Bernoulli {:.4})",
        reference / eb
    );
    assert!(
        ratios.windows(2).all(|w| w[1] < w[0] && w[1] > 1.0),
        "{ratios:?}"
    );
    assert!(ratios[2] < 1.15, "{ratios:?}");
}

/// Phi^T M Phi = I and Phi^T K Phi = diag(lambda) to 1e-10 (relative to the largest
/// lambda), on both paths and both mass kinds.
#[test]
fn modes_are_mass_orthonormal_and_diagonalise_the_stiffness() {
    for mass in [FemMass::Lumped, FemMass::Consistent] {
        let (fem, rest) = bar([12, 2, 2], [1.0, 0.1, 0.1], steel(), mass);
        let k = stiffness_at_rest(&fem, &rest).unwrap();
        let n3 = rest.len();
        for dense_max in [0, 100_000] {
            let p = EigenParams {
                count: 14,
                dense_max,
                ..EigenParams::default()
            };
            let m = solve(&fem, &k, &[], &p).unwrap();
            assert_eq!(m.dense, dense_max > 0);
            let top = m.eigenvalues.last().unwrap().abs();
            let (mut kx, mut mx) = (vec![0.0; n3], vec![0.0; n3]);
            for j in 0..p.count {
                k.spmv(&mut kx, m.mode(j));
                match fem.mass_matrix() {
                    Some(mm) => mm.spmv(&mut mx, m.mode(j)),
                    None => {
                        for (d, (y, v)) in mx.iter_mut().zip(m.mode(j)).enumerate() {
                            *y = fem.mass()[d % (n3 / 3)] * v;
                        }
                    }
                }
                for i in 0..p.count {
                    let xi = m.mode(i);
                    let mij: f64 = xi.iter().zip(&mx).map(|(a, b)| a * b).sum();
                    let kij: f64 = xi.iter().zip(&kx).map(|(a, b)| a * b).sum();
                    let (me, ke) = if i == j {
                        (1.0, m.eigenvalues[j])
                    } else {
                        (0.0, 0.0)
                    };
                    assert!(
                        (mij - me).abs() < 1e-10,
                        "{mass:?} dense {}: M[{i},{j}] = {mij}",
                        m.dense
                    );
                    assert!(
                        (kij - ke).abs() < 1e-10 * top,
                        "{mass:?} dense {}: K[{i},{j}] = {kij}",
                        m.dense
                    );
                }
            }
        }
    }
}

/// The dense and sparse paths give the same eigenvalues (non-rigid ones to 1e-8
/// relative) and the same rigid count; lumped mass gives lower frequencies than
/// consistent mass (which bounds them from above, as Rayleigh-Ritz does).
#[test]
fn dense_and_sparse_paths_agree() {
    let mut by_mass = Vec::new();
    for mass in [FemMass::Lumped, FemMass::Consistent] {
        let (fem, rest) = bar([16, 2, 2], [1.0, 0.1, 0.1], steel(), mass);
        let k = stiffness_at_rest(&fem, &rest).unwrap();
        let (d, s) = dense_and_sparse(&fem, &k, 16);
        assert!(d.dense && !s.dense);
        assert_eq!((d.rigid, s.rigid), (6, 6));
        for j in 6..16 {
            let (a, b) = (d.eigenvalues[j], s.eigenvalues[j]);
            assert!(
                (a - b).abs() < 1e-8 * a,
                "{mass:?} mode {j}: dense {a}, sparse {b}"
            );
        }
        by_mass.push(s.frequencies_hz());
    }
    for (l, c) in by_mass[0].iter().zip(&by_mass[1]) {
        assert!(l < c, "lumped {l} Hz below consistent {c} Hz");
    }
}

/// The sparse path splits its block solves and its orthogonalisation over two threads,
/// the same way on one: the modes are the same bits on one thread and on two (14,823
/// unknowns, a supernodal factor).
#[test]
fn sparse_modes_are_the_same_bits_on_one_and_two_threads() {
    let (fem, rest) = bar([60, 8, 8], [1.0, 0.1, 0.1], steel(), FemMass::Consistent);
    let k = stiffness_at_rest(&fem, &rest).unwrap();
    let params = EigenParams {
        count: 12,
        dense_max: 0,
        ..EigenParams::default()
    };
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| solve(&fem, &k, &[], &params).unwrap())
    };
    let (one, two) = (run(1), run(2));
    assert_eq!(one.rigid, 6);
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&one.eigenvalues), bits(&two.eigenvalues));
    assert_eq!(bits(&one.vectors), bits(&two.vectors));
}

/// The automatic shift scales with the material: rubber and steel give frequencies in the
/// ratio `sqrt((E1 / rho1) / (E2 / rho2))` to 1e-8 (the problem is linear in E / rho),
/// with six rigid modes each. A shift given at zero on a free body (singular `K`) is moved
/// and the move reported.
#[test]
fn rubber_to_steel_and_a_shift_on_an_eigenvalue() {
    let rubber = FemMaterial {
        model: Material::Linear,
        young: 1e6,
        poisson: 0.3,
        density: 1100.0,
    };
    let run = |mat: FemMaterial, shift: Option<f64>| {
        let (fem, rest) = bar([30, 3, 3], [1.0, 0.1, 0.1], mat, FemMass::Consistent);
        modes_of(
            &fem,
            &rest,
            &[],
            &EigenParams {
                count: 12,
                shift,
                dense_max: 0,
                ..EigenParams::default()
            },
        )
    };
    let (s, r) = (run(steel(), None), run(rubber, None));
    assert_eq!((s.rigid, r.rigid), (6, 6));
    let ratio = ((steel().young / steel().density) / (rubber.young / rubber.density)).sqrt();
    for (fs, fr) in s.frequencies_hz().iter().zip(r.frequencies_hz()) {
        assert!(
            (fs / fr / ratio - 1.0).abs() < 1e-8,
            "{fs} / {fr} against {ratio}"
        );
    }
    let z = run(steel(), Some(0.0));
    assert!(z.notes.iter().any(|n| n.contains("moved")), "{:?}", z.notes);
    assert!(z.shift < 0.0);
    assert_eq!(z.rigid, 6);
    for (a, b) in z.frequencies_hz().iter().zip(s.frequencies_hz()) {
        assert!((a / b - 1.0).abs() < 1e-6, "{a} against {b}");
    }
}

#[test]
fn bad_problems_are_errors_not_panics() {
    let (fem, rest) = bar([4, 1, 1], [1.0, 0.1, 0.1], steel(), FemMass::Lumped);
    let k = stiffness_at_rest(&fem, &rest).unwrap();
    let n = rest.len() / 3;
    let p = |count| EigenParams {
        count,
        ..EigenParams::default()
    };
    let too_many = lowest_modes(&k, Mass::Lumped(fem.mass()), &[], &p(3 * n + 1)).unwrap_err();
    assert!(too_many.to_string().contains("free unknowns"), "{too_many}");
    let out = lowest_modes(&k, Mass::Lumped(fem.mass()), &[n], &p(4)).unwrap_err();
    assert!(out.to_string().contains("out of range"), "{out}");
    let mut zero = fem.mass().to_vec();
    zero[3] = 0.0;
    let e = lowest_modes(&k, Mass::Lumped(&zero), &[], &p(4)).unwrap_err();
    assert!(
        matches!(e, SolveError::NotPositiveDefinite { at: 3, .. }),
        "{e}"
    );
    let mut skew = k.clone();
    skew.values_mut()[1] += 1e-3 * k.values().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let e = lowest_modes(&skew, Mass::Lumped(fem.mass()), &[], &p(4)).unwrap_err();
    assert!(e.to_string().contains("not symmetric"), "{e}");
    let mut nan = k.clone();
    nan.values_mut()[0] = f64::NAN;
    assert!(lowest_modes(&nan, Mass::Lumped(fem.mass()), &[], &p(4)).is_err());
}

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("largestep-modal-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Writes a box mesh as TetGen's bar.node and bar.ele (indices from 1) into `dir`.
fn write_tetgen(dir: &std::path::Path, cells: [usize; 3], size: [f64; 3]) -> PathBuf {
    let mesh = largestep::fem::mesh::box_mesh(cells, size, [0.0; 3]);
    let mut node = format!("{} 3 0 0\n", mesh.positions.len());
    for (i, p) in mesh.positions.iter().enumerate() {
        node += &format!("{} {} {} {}\n", i + 1, p[0], p[1], p[2]);
    }
    let mut ele = format!("{} 4 0\n", mesh.tets.len());
    for (e, t) in mesh.tets.iter().enumerate() {
        ele += &format!(
            "{} {} {} {} {}\n",
            e + 1,
            t[0] + 1,
            t[1] + 1,
            t[2] + 1,
            t[3] + 1
        );
    }
    std::fs::write(dir.join("bar.node"), node).unwrap();
    std::fs::write(dir.join("bar.ele"), ele).unwrap();
    dir.join("bar.node")
}

/// `largestep modes MESH ... --json FILE --out DIR`: the table, the JSON with exactly the
/// keys of the contract, one VTK per mode and an animation of each; bad arguments exit
/// with 2.
#[test]
fn modes_command_writes_the_json_contract_and_shapes() {
    let exe = env!("CARGO_BIN_EXE_largestep");
    let dir = temp_dir("cli");
    let node = write_tetgen(&dir, [20, 2, 2], [1.0, 0.1, 0.1]);
    let json = dir.join("modes.json");
    let shapes = dir.join("shapes");
    let out = std::process::Command::new(exe)
        .args(["modes", node.to_str().unwrap(), "--count", "5", "--json"])
        .arg(&json)
        .arg("--out")
        .arg(&shapes)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("rigid modes    6"), "{text}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let keys: Vec<&str> = v.as_object().unwrap().keys().map(|k| k.as_str()).collect();
    let mut sorted = keys.clone();
    sorted.sort_unstable();
    assert_eq!(
        sorted,
        [
            "eigenvalues",
            "frequencies_hz",
            "residuals",
            "rigid_modes",
            "seconds"
        ]
    );
    assert_eq!(v["rigid_modes"], 6);
    let f: Vec<f64> = v["frequencies_hz"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let l: Vec<f64> = v["eigenvalues"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert_eq!((f.len(), l.len()), (5, 11));
    assert!(f.windows(2).all(|w| w[0] <= w[1]));
    for (fj, lj) in f.iter().zip(&l[6..]) {
        assert!((fj - lj.sqrt() / (2.0 * PI)).abs() < 1e-9 * fj);
    }
    assert_eq!(v["residuals"].as_array().unwrap().len(), 11);
    for j in 1..=5 {
        assert!(shapes.join(format!("mode_{j:02}.vtk")).exists());
        let gif = shapes.join(format!("mode_{j:02}")).join("animation.gif");
        assert!(
            std::fs::metadata(&gif).unwrap().len() > 1000,
            "{}",
            gif.display()
        );
    }
    // Clamped at x = 0 and lumped: no rigid mode.
    let out = std::process::Command::new(exe)
        .args([
            "modes",
            node.to_str().unwrap(),
            "--count",
            "3",
            "--fixed",
            "x<=0",
            "--mass",
            "lumped",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && text.contains("rigid modes    0"),
        "{text}"
    );
    for bad in [
        vec!["modes", "no/such.node"],
        vec!["modes", node.to_str().unwrap(), "--fixed", "w<=0"],
        vec!["modes", node.to_str().unwrap(), "--fixed", "x<=-5"],
        vec!["modes", node.to_str().unwrap(), "--count", "100000"],
        vec!["modes", node.to_str().unwrap(), "--mass", "heavy"],
    ] {
        let out = std::process::Command::new(exe).args(&bad).output().unwrap();
        assert_eq!(
            out.status.code(),
            Some(2),
            "{bad:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"));
    }
}

/// Two separate free bars: twelve rigid modes, more than the Lanczos block holds, so the
/// deflated repeats must find the copies the first run misses; the elastic modes come in
/// equal pairs (the bars are the same), and both paths agree.
#[test]
fn two_free_bodies_have_twelve_rigid_modes() {
    let one = largestep::fem::mesh::box_mesh([12, 2, 2], [1.0, 0.1, 0.1], [0.0; 3]);
    let n = one.positions.len() as u32;
    let mut positions = one.positions.clone();
    positions.extend(one.positions.iter().map(|p| [p[0], p[1] + 0.5, p[2]]));
    let mut tets = one.tets.clone();
    tets.extend(one.tets.iter().map(|t| t.map(|v| v + n)));
    let mut desc = FemDesc::new(positions, tets, steel());
    desc.mass = FemMass::Consistent;
    let (fem, state) = desc.build().unwrap();
    let rest = state.x.as_slice().to_vec();
    let k = stiffness_at_rest(&fem, &rest).unwrap();
    let (d, s) = dense_and_sparse(&fem, &k, 16);
    assert_eq!((s.rigid, d.rigid), (12, 12), "sparse notes: {:?}", s.notes);
    for j in 12..16 {
        let (a, b) = (s.eigenvalues[j], d.eigenvalues[j]);
        assert!((a - b).abs() < 1e-8 * a, "mode {j}: sparse {a}, dense {b}");
    }
    assert!(
        (s.eigenvalues[13] / s.eigenvalues[12] - 1.0).abs() < 1e-8,
        "equal bars, equal pairs"
    );
}

mod sound {
    use super::*;
    use largestep::io::write_wav;
    use largestep::modal::sound::{synthesize, Hit, Rayleigh, SoundParams};

    /// The magnitude of the discrete Fourier transform of `x` at `f` Hz.
    fn dft(x: &[f64], rate: f64, f: f64) -> f64 {
        let (mut re, mut im) = (0.0, 0.0);
        for (k, v) in x.iter().enumerate() {
            let a = 2.0 * PI * f * k as f64 / rate;
            re += v * a.cos();
            im -= v * a.sin();
        }
        (re * re + im * im).sqrt()
    }

    /// One mode, one impulse: every sample equals the damped oscillator's acceleration
    /// proxy `w^2 J s e^(-xi w t) sin(w_d t) / w_d` (impulse invariance is exact), and the
    /// decay between two windows is the Rayleigh rate.
    #[test]
    fn one_mode_rings_exactly_and_decays_at_the_rayleigh_rate() {
        let w: f64 = 2.0 * PI * 440.0;
        let modes = Modes {
            eigenvalues: vec![w * w],
            vectors: vec![0.0, 0.6, 0.8],
            residuals: vec![0.0],
            ..Modes::default()
        };
        let damping = Rayleigh {
            alpha: 2.0,
            beta: 1e-6,
        };
        let hit = Hit {
            time: 0.0,
            vertex: 0,
            direction: [0.0, 0.0, 2.0],
            impulse: 0.01,
            duration: 0.0,
        };
        let params = SoundParams {
            duration: 1.0,
            ..SoundParams::default()
        };
        let s = synthesize(&modes, damping, &[hit], &params).unwrap();
        let xi = damping.ratio(w);
        let wd = w * (1.0 - xi * xi).sqrt();
        let h = 1.0 / 44_100.0;
        for (k, &v) in s.samples.iter().enumerate().skip(1).take(20_000) {
            let t = (k as f64) * h;
            let exact = w * w * 0.01 * 0.8 * (-xi * w * t).exp() * (wd * t).sin() / wd;
            assert!(
                (v - exact).abs() < 1e-9 * w * w * 0.01 / wd,
                "sample {k}: {v} against {exact}"
            );
        }
        let window = |t0: f64| {
            let a = (t0 / h) as usize;
            dft(&s.samples[a..a + 4410], 44_100.0, wd / (2.0 * PI))
        };
        let measured = (window(0.1) / window(0.6)).ln() / 0.5;
        assert!(
            (measured / (xi * w) - 1.0).abs() < 0.01,
            "decay {measured} 1/s against {}",
            xi * w
        );
        assert!((s.decay_rates[0] - xi * w).abs() < 1e-12 * xi * w);
    }

    /// A free steel bar struck at its end along its lowest mode's motion there: the
    /// spectrum peaks at that mode's damped frequency; lowering the frequency limit and
    /// raising the quiet threshold change what is culled, and the WAV file reads back.
    #[test]
    fn a_struck_bar_rings_at_its_modes() {
        let (fem, rest) = bar([20, 2, 2], [1.0, 0.1, 0.1], steel(), FemMass::Consistent);
        let m = modes_of(
            &fem,
            &rest,
            &[],
            &EigenParams {
                count: 30,
                ..EigenParams::default()
            },
        );
        let n = rest.len() / 3;
        // A corner of the free end.
        let v = (0..n)
            .filter(|&i| rest[i] > 1.0 - 1e-9)
            .max_by(|&a, &b| {
                (rest[n + a] + rest[2 * n + a]).total_cmp(&(rest[n + b] + rest[2 * n + b]))
            })
            .unwrap();
        // The lowest mode bends the bar along a direction the mesh's split sets; strike
        // along its motion at v.
        let ymode = m.rigid;
        let x = m.mode(ymode);
        let direction = [x[v], x[n + v], x[2 * n + v]];
        let damping = Rayleigh {
            alpha: 1.0,
            beta: 2e-8,
        };
        let hit = Hit {
            time: 0.05,
            vertex: v,
            direction,
            impulse: 0.02,
            duration: 2e-4,
        };
        let params = SoundParams {
            duration: 1.0,
            ..SoundParams::default()
        };
        let s = synthesize(&m, damping, &[hit], &params).unwrap();
        assert_eq!(s.samples.len(), 44_100);
        let w = m.eigenvalues[ymode].sqrt();
        let xi = damping.ratio(w);
        let fd = w * (1.0 - xi * xi).sqrt() / (2.0 * PI);
        let at = |f: f64| dft(&s.samples, 44_100.0, f);
        assert!(
            at(fd) > 10.0 * at(0.95 * fd) && at(fd) > 10.0 * at(1.05 * fd),
            "peak at {fd} Hz"
        );
        assert!(s.frequencies_hz.iter().any(|&f| (f - fd).abs() < 1e-9 * fd));
        let low = synthesize(
            &m,
            damping,
            &[hit],
            &SoundParams {
                max_frequency: 2_000.0,
                ..params
            },
        )
        .unwrap();
        assert!(low.culled_high > 0 && low.frequencies_hz.iter().all(|&f| f <= 2_000.0));
        let strict = synthesize(
            &m,
            damping,
            &[hit],
            &SoundParams {
                quiet: 0.5,
                ..params
            },
        )
        .unwrap();
        assert!(strict.culled_quiet > 0 && strict.frequencies_hz.len() < s.frequencies_hz.len());
        let dir = temp_dir("wav");
        let wav = dir.join("bar.wav");
        write_wav(&wav, &s.samples, s.sample_rate).unwrap();
        let r = hound::WavReader::open(&wav).unwrap();
        assert_eq!(
            (r.spec().sample_rate, r.spec().channels, r.len()),
            (44_100, 1, 44_100)
        );
        let peak = r
            .into_samples::<i16>()
            .map(|x| x.unwrap().unsigned_abs())
            .max()
            .unwrap();
        assert!((peak as f64 / i16::MAX as f64 - 0.9).abs() < 1e-3);
    }

    /// A steady push given each 1 ms step as a box (`Pulse::Box`) is a steady input: the
    /// mode's response holds still once its onset rings out. The same impulses as
    /// half-sine impacts buzz at the step rate (1 kHz and its harmonics).
    #[test]
    fn steady_pushes_do_not_buzz_at_the_step_rate() {
        use largestep::modal::sound::{Cull, Pulse, Synth};
        let w: f64 = 2.0 * PI * 2_500.0;
        let modes = Modes {
            eigenvalues: vec![w * w],
            vectors: vec![1.0, 0.0, 0.0],
            residuals: vec![0.0],
            ..Modes::default()
        };
        let damping = Rayleigh {
            alpha: 50.0,
            beta: 0.0,
        };
        let params = SoundParams::default();
        let push = |pulse: Pulse| {
            let mut s = Synth::new(&modes, damping, &params, Cull::Anywhere(&[0])).unwrap();
            let mut out = vec![0.0; 22_050];
            for step in 0..500 {
                let t = step as f64 * 1e-3;
                s.strike(t, 0, [1e-3, 0.0, 0.0], pulse).unwrap();
                let (a, b) = (s.sample_at(t) as usize, s.sample_at(t + 1e-3) as usize);
                s.render(&mut out[a..b]);
            }
            out
        };
        let (boxed, sines) = (push(Pulse::Box(1e-3)), push(Pulse::HalfSine(1e-4)));
        // After 0.3 s the onset has decayed by e^-(25 * 0.3) = 5.5e-4.
        let tail =
            |x: &[f64]| dft(&x[13_230..], 44_100.0, 1_000.0) + dft(&x[13_230..], 44_100.0, 3_000.0);
        assert!(
            tail(&boxed) < 1e-6 * tail(&sines),
            "box {} against half-sine {}",
            tail(&boxed),
            tail(&sines)
        );
    }

    #[test]
    fn bad_hits_are_errors_naming_the_hit() {
        let modes = Modes {
            eigenvalues: vec![1e6],
            vectors: vec![1.0, 0.0, 0.0],
            residuals: vec![0.0],
            ..Modes::default()
        };
        let ok = Hit {
            time: 0.0,
            vertex: 0,
            direction: [1.0, 0.0, 0.0],
            impulse: 1.0,
            duration: 0.0,
        };
        let d = Rayleigh {
            alpha: 0.0,
            beta: 0.0,
        };
        let p = SoundParams::default();
        for (bad, what) in [
            (Hit { vertex: 1, ..ok }, "out of range"),
            (
                Hit {
                    direction: [0.0; 3],
                    ..ok
                },
                "zero",
            ),
            (Hit { time: 5.0, ..ok }, "outside"),
            (
                Hit {
                    impulse: f64::NAN,
                    ..ok
                },
                "finite",
            ),
        ] {
            let e = synthesize(&modes, d, &[ok, bad], &p)
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("hit 1") && e.contains(what), "{e}");
        }
        assert!(synthesize(&modes, d, &[ok], &SoundParams { duration: 1e9, ..p }).is_err());
        assert!(synthesize(
            &modes,
            Rayleigh {
                alpha: -1.0,
                beta: 0.0
            },
            &[ok],
            &p
        )
        .is_err());
    }
}

/// The quick `modes` study writes its report, says it was quick, and its bending error
/// falls as the mesh is refined, for both mass kinds.
#[test]
fn the_quick_modes_study_reports_convergence() {
    let out = temp_dir("study");
    let summary =
        largestep::study::run("modes", &out, true, &largestep::study::Progress::silent()).unwrap();
    assert!(summary.contains("modes"));
    let md = std::fs::read_to_string(out.join("modes.md")).unwrap();
    assert!(
        md.contains("study modes --quick") && md.contains("1 to 4 cubes across"),
        "{md}"
    );
    let json: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join("modes.json")).unwrap()).unwrap();
    for sweep in &json[..2] {
        let errors: Vec<f64> = sweep["points"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["error"].as_f64().unwrap())
            .collect();
        assert!(errors.windows(2).all(|w| w[1] < w[0]), "{errors:?}");
    }
    assert!(out.join("modes.png").is_file());
}

/// `[sound]` scenes: scripted hits, and contact impulses from a FEM body.
mod scenes {
    use super::*;
    use largestep::modal::scene::ModalSound;
    use largestep::scene::{RunError, Runner, Scene};

    fn run(text: &str, name: &str) -> (Runner, Result<largestep::scene::Summary, RunError>) {
        let scene = Scene::parse(text, "sound.toml").unwrap();
        let mut runner = Runner::new(scene, &temp_dir(name));
        let r = runner.run(None, &mut |_| {});
        (runner, r)
    }

    fn wav(path: &std::path::Path) -> Vec<f64> {
        hound::WavReader::open(path)
            .unwrap()
            .into_samples::<i16>()
            .map(|s| s.unwrap() as f64)
            .collect()
    }

    /// The shipped struck-bar scene: a WAV of the scene's length whose spectrum peaks at
    /// the lowest ringing mode's damped frequency; the bar is the frame.
    #[test]
    fn the_struck_bar_scene_rings_at_its_lowest_mode() {
        let text = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/sound-bar.toml"),
        )
        .unwrap()
        .replace("cells = [50, 4, 4]", "cells = [25, 2, 2]")
        .replace("duration = 2.0", "duration = 0.5");
        let (runner, r) = run(&text, "bar-scene");
        r.unwrap();
        let sound: &ModalSound = runner.systems()[0].sim.downcast_ref().unwrap();
        let samples = wav(&runner.sound_files()[0]);
        assert_eq!(samples.len(), 22_050);
        let f1 = sound.synth().info().frequencies_hz[0];
        let at = |f: f64| {
            let (mut re, mut im) = (0.0, 0.0);
            for (k, v) in samples.iter().enumerate() {
                let a = 2.0 * PI * f * k as f64 / 44_100.0;
                re += v * a.cos();
                im -= v * a.sin();
            }
            (re * re + im * im).sqrt()
        };
        assert!(at(f1) > 10.0 * at(0.9 * f1) && at(f1) > 10.0 * at(1.1 * f1));
        // The three strongest peaks of the spectrum up to 4 kHz (a 2 Hz grid) each lie
        // within 1% of a damped modal frequency.
        let grid: Vec<(f64, f64)> = (100..2_000)
            .map(|k| 2.0 * k as f64)
            .map(|f| (f, at(f)))
            .collect();
        let mut peaks: Vec<(f64, f64)> = grid
            .windows(3)
            .filter(|w| w[1].1 > w[0].1 && w[1].1 > w[2].1)
            .map(|w| w[1])
            .collect();
        peaks.sort_by(|a, b| b.1.total_cmp(&a.1));
        let ringing = &sound.synth().info().frequencies_hz;
        for &(f, _) in &peaks[..3] {
            let near = ringing
                .iter()
                .map(|&m| (m / f - 1.0).abs())
                .fold(f64::INFINITY, f64::min);
            assert!(near < 0.01, "peak at {f} Hz, modes {ringing:?}");
        }
        // Silence before the hit at 0.05 s, sound after it.
        assert!(samples[..2_000].iter().all(|&s| s == 0.0));
        assert!(samples[2_300..2_500].iter().any(|&s| s != 0.0));
    }

    /// A steel block dropped on the floor: before it lands the sound is silent; the
    /// impulses the sound hears add up to the momentum balance of the whole fall,
    /// `P(T) - P(0) + M g T` (backward Euler's own balance, so to the solver's
    /// tolerance); and a sound of another mesh than the body's is an error naming both.
    #[test]
    fn a_dropped_block_is_heard_through_its_contacts() {
        let text = r#"
[scene]
dt = 0.001
duration = 0.12
integrator = "backward-euler"
gravity = [0.0, -9.81, 0.0]
[fem]
friction = 0.3
[fem.beam]
cells = [3, 3, 3]
size = [0.3, 0.3, 0.3]
origin = [0.0, 0.02, 0.0]
[fem.material]
model = "corotational"
preset = "steel"
[[fem.plane]]
point = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
[sound]
contacts = true
modes = 12
[sound.beam]
cells = [3, 3, 3]
size = [0.3, 0.3, 0.3]
"#;
        let (runner, r) = run(text, "drop");
        r.unwrap();
        let fem = runner.systems()[0]
            .sim
            .downcast_ref::<largestep::simulation::MechSimulation<Fem>>()
            .unwrap();
        let sound: &ModalSound = runner.systems()[1].sim.downcast_ref().unwrap();
        let mass: f64 = fem.model().mass().iter().sum();
        let n = fem.model().vertex_count();
        let v = fem.state().v.as_slice();
        let p: Vec<f64> = (0..3)
            .map(|c| (0..n).map(|i| fem.model().mass()[i] * v[c * n + i]).sum())
            .collect();
        let (heard, j) = sound.heard();
        assert!(heard > 0);
        // P(T) - P(0) = J - M g T, P(0) = 0.
        let expected = [p[0], p[1] + mass * 9.81 * 0.12, p[2]];
        for c in 0..3 {
            assert!(
                (j[c] - expected[c]).abs() < 1e-3 * expected[1],
                "heard {j:?} N s, momentum balance {expected:?} N s"
            );
        }
        // It lands after sqrt(2 * 0.018 / 9.81) = 0.061 s (the contact thickness is 2 mm).
        let samples = sound.samples();
        let land = (0.055 * 44_100.0) as usize;
        assert!(samples[..land].iter().all(|&s| s == 0.0));
        assert!(samples[land..].iter().any(|&s| s != 0.0));
        // Another mesh.
        let other = text.replace(
            "[sound.beam]\ncells = [3, 3, 3]",
            "[sound.beam]\ncells = [2, 2, 2]",
        );
        let (_, r) = run(&other, "drop-other");
        let e = r.unwrap_err().to_string();
        assert!(e.contains("[fem]") && e.contains("same mesh"), "{e}");
    }

    /// A steel block as a rigid body, dropped flat on a static slab, heard by `[sound]`
    /// with `body = 1` (its contact points go to the nearest surface vertex of a beam of
    /// the block's shape, centred as the box is): silent before it lands; the impulses
    /// heard add up to the block's momentum balance `m v(T) - m v(0) + m g T` (it lands
    /// flat and stays so, so its shape frame is the world's); and a sound mesh that is
    /// not the block's shape, a missing `body` and a body out of range are errors
    /// saying so.
    #[cfg(feature = "rigid")]
    #[test]
    fn a_rigid_body_is_heard_through_its_contacts() {
        let text = r#"
[scene]
dt = 0.001
duration = 0.2
[rigid]
friction = 0.4
[[rigid.body]]
shape = { box = [0.5, 0.05, 0.5] }
position = [0.0, -0.05, 0.0]
static = true
[[rigid.body]]
shape = { box = [0.1, 0.02, 0.05] }
density = 7850.0
position = [0.0, 0.07, 0.0]
[sound]
contacts = true
body = 1
modes = 8
[sound.beam]
cells = [4, 2, 2]
size = [0.2, 0.04, 0.1]
origin = [-0.1, -0.02, -0.05]
"#;
        let (runner, r) = run(text, "rigid-drop");
        r.unwrap();
        let find = |k: usize| &runner.systems()[k].sim;
        let (rigid, sound) = (0..2)
            .find_map(|k| {
                let other = find(1 - k).downcast_ref::<ModalSound>()?;
                Some((
                    find(k).downcast_ref::<largestep::rigid::scene::RigidSim>()?,
                    other,
                ))
            })
            .unwrap();
        let m = rigid.model().mass(1);
        let v = rigid.state().v[1];
        let (heard, j) = sound.heard();
        assert!(heard > 0);
        // The impulses are heard in the block's frame, which rocks by up to 0.75 mrad as
        // it lands (read off its bodies.csv): the balance holds to about that fraction.
        let expected = [m * v[0], m * v[1] + m * 9.81 * 0.2, m * v[2]];
        for c in 0..3 {
            assert!(
                (j[c] - expected[c]).abs() < 1e-3 * expected[1],
                "heard {j:?} N s, momentum balance {expected:?} N s"
            );
        }
        assert!((j[1] - expected[1]).abs() < 1e-5 * expected[1]);
        // It falls 5 cm: it lands after sqrt(2 * 0.05 / 9.81) = 0.101 s.
        let samples = sound.samples();
        let land = (0.095 * 44_100.0) as usize;
        assert!(samples[..land].iter().all(|&s| s == 0.0));
        assert!(samples[land..].iter().any(|&s| s != 0.0));
        for (change, what) in [
            ("origin = [-0.1, -0.02, -0.05]", "shape frame"),
            ("body = 1\n", "give [sound] `body`"),
            ("body = 1", "does not exist"),
        ] {
            let bad = match what {
                "shape frame" => text.replace(change, "origin = [0.0, 0.0, 0.0]"),
                "does not exist" => text.replace(change, "body = 2"),
                _ => text.replace(change, ""),
            };
            let (_, r) = run(&bad, "rigid-drop-bad");
            let e = r.unwrap_err().to_string();
            assert!(e.contains(what) && e.contains("[rigid]"), "{e}");
        }
    }

    /// Bad `[sound]` tables are errors at their line.
    #[test]
    fn bad_sound_tables_are_located_errors() {
        let base = "[scene]\ndt = 0.01\nduration = 0.1\n[sound]\nmodes = 4\n[sound.beam]\ncells = [4, 1, 1]\nsize = [0.4, 0.1, 0.1]\n";
        let hit =
            "[[sound.hit]]\ntime = 0.0\nvertex = 0\ndirection = [0.0, 1.0, 0.0]\nimpulse = 0.01\n";
        assert!(Scene::parse(&format!("{base}{hit}"), "ok.toml").is_ok());
        for (text, line, what) in [
            (base.to_string(), 4, "nothing strikes it"),
            (
                base.replace("modes = 4", "modes = 4\nmaterial = \"gold\"") + hit,
                6,
                "glass",
            ),
            (
                format!("{base}{hit}position = [0.0, 0.0, 0.0]\n"),
                9,
                "exactly one of",
            ),
            (
                format!("{base}{}", hit.replace("vertex = 0", "vertex = 99")),
                11,
                "does not exist",
            ),
            (
                format!(
                    "{base}{}",
                    hit.replace("[0.0, 1.0, 0.0]", "[0.0, 0.0, 0.0]")
                ),
                12,
                "not zero",
            ),
            (
                base.replace("modes = 4", "modes = 4\nfixed = \"w<=0\"") + hit,
                6,
                "fixed",
            ),
            (base.replace("modes = 4", "modes = 0") + hit, 5, "modes"),
            (
                base.replace("modes = 4", "modes = 4\nbody = 0") + hit,
                6,
                "contacts = true",
            ),
        ] {
            let e = Scene::parse(&text, "bad.toml").err().unwrap().to_string();
            assert!(
                e.starts_with(&format!("bad.toml:{line}:")) && e.contains(what),
                "{e}\n--- in ---\n{text}"
            );
        }
    }
}

/// A closed surface is voxel-meshed for modal analysis: a bar given as its six faces
/// (OFF) rings within 1% of the same bar meshed as boxes of tetrahedra.
#[test]
fn a_surface_mesh_is_voxel_meshed_for_its_modes() {
    use largestep::modal::{analyse, ModesOptions};
    let dir = temp_dir("surface");
    let (l, w) = (0.5, 0.05);
    let corners: Vec<[f64; 3]> = (0..8)
        .map(|i| {
            [
                if i & 1 == 1 { l } else { 0.0 },
                if i & 2 == 2 { w } else { 0.0 },
                if i & 4 == 4 { w } else { 0.0 },
            ]
        })
        .collect();
    // Outward quads, split into triangles.
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut off = "OFF\n8 12 0\n".to_string();
    for c in &corners {
        off += &format!("{} {} {}\n", c[0], c[1], c[2]);
    }
    for q in quads {
        off += &format!(
            "3 {} {} {}\n3 {} {} {}\n",
            q[0], q[1], q[2], q[0], q[2], q[3]
        );
    }
    let file = dir.join("bar.off");
    std::fs::write(&file, off).unwrap();
    let options = ModesOptions {
        count: 4,
        voxel: Some(w / 4.0),
        ..ModesOptions::default()
    };
    let a = analyse(&file, &options, 1 << 20).unwrap();
    assert_eq!(a.modes.rigid, 6);
    let (fem, rest) = bar([40, 4, 4], [l, w, w], steel(), FemMass::Consistent);
    let b = modes_of(
        &fem,
        &rest,
        &[],
        &EigenParams {
            count: 10,
            ..EigenParams::default()
        },
    );
    let (fa, fb) = (a.modes.frequencies_hz(), b.frequencies_hz());
    for k in 0..4 {
        assert!((fa[k] / fb[k] - 1.0).abs() < 0.01, "{fa:?} against {fb:?}");
    }
    assert!(a.notes[0].contains("voxel-meshed"));
}
