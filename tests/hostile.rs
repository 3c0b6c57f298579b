//! Hostile input and runaway simulations: the minimal reproducers of what a mutation
//! fuzzer and a new user found (sizes that allocated before they were checked, devices and
//! FIFOs, runs that never end, blow-ups that were not reported, messages that echoed
//! megabytes or blamed the wrong file). Each gives a located error within a fraction of a
//! second, or a bounded, correct run.

use largestep::limits::Limits;
use largestep::scene::{RunError, Runner, Scene, SceneError};
use std::path::{Path, PathBuf};
use std::time::Instant;

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("largestep-hostile-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Limits of a small machine: a 2 GB budget, whatever this one has.
fn small() -> Limits {
    Limits::with_memory(2 << 30)
}

/// Parses `text` (written as `name` in a fresh folder, with `files` beside it), expecting
/// an error within a second that mentions every word of `words`.
fn refused(name: &str, text: &str, files: &[(&str, &[u8])], words: &[&str]) -> SceneError {
    let d = dir(name);
    for (f, bytes) in files {
        std::fs::write(d.join(f), bytes).unwrap();
    }
    let path = d.join(name);
    std::fs::write(&path, text).unwrap();
    let t0 = Instant::now();
    let e = Scene::load_with(&path, &small()).expect_err("must be refused");
    assert!(t0.elapsed().as_secs_f64() < 1.0, "took {:?}", t0.elapsed());
    let msg = e.to_string();
    for w in words {
        assert!(msg.contains(w), "`{msg}` should mention `{w}`");
    }
    e
}

const HEAD: &str = "[scene]\ndt = 0.01\nduration = 0.1\nintegrator = \"rk4\"\n";
const CLOTH_HEAD: &str =
    "[scene]\ndt = 0.01\nduration = 0.1\nintegrator = \"linearized-backward-euler\"\n";
const MATERIAL: &str = "[cloth.material]\ndensity = 0.2\nstretch = 100.0\n";

fn obj_scene(file: &str, extra: &str) -> String {
    format!("{CLOTH_HEAD}[cloth]\n[cloth.mesh]\nfile = \"{file}\"\n{extra}{MATERIAL}")
}

#[test]
fn sizes_are_checked_before_anything_is_allocated() {
    let tri = "v 0 0 0\nv 1 0 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\n";
    for index in ["4000000000", "200000000"] {
        let obj = format!("{tri}f {index}/1 2/2 3/3\n");
        let e = refused(
            "obj.toml",
            &obj_scene("sheet.obj", ""),
            &[("sheet.obj", obj.as_bytes())],
            &["sheet.obj:7", "does not exist", "defines 3 vertices"],
        );
        assert_eq!(e.field, "cloth.mesh.file");
    }
    let sdf = format!("{CLOTH_HEAD}[cloth]\n[[cloth.sdf]]\nfile = \"big.sdf\"\n[cloth.grid]\nnu = 4\nnv = 4\nsize = [1.0, 1.0]\n{MATERIAL}");
    refused(
        "sdf.toml",
        &sdf,
        &[("big.sdf", b"4096 4096 4096\n0 0 0\n0.1\n1 2 3 4 5\n")],
        &["big.sdf:1", "asks for", "hold at most"],
    );
    let grid = |nu: &str, nv: &str| {
        format!("{HEAD}[mass_spring.grid]\nnu = {nu}\nnv = {nv}\nsize = [1.0, 1.0]\nmass = 1.0\nstructural = 10.0\n")
    };
    for (nu, nv) in [("1000000", "1000000"), ("2", "9223372036854775807")] {
        let e = refused(
            "grid.toml",
            &grid(nu, nv),
            &[],
            &["memory budget", "--max-memory"],
        );
        assert_eq!((e.line, e.field.as_str()), (5, "mass_spring.grid"));
    }
    refused(
        "chain.toml",
        &format!("{HEAD}[mass_spring.chain]\ncount = 1000000000000\nspacing = 0.1\nmass = 1.0\nstiffness = 10.0\n"),
        &[],
        &["mass_spring.chain.count", "memory budget"],
    );
    refused(
        "lattice.toml",
        &format!("{HEAD}[mass_spring.lattice]\nn = [1024, 1024, 1024]\nsize = [1.0, 1.0, 1.0]\nmass = 1.0\nstructural = 10.0\n"),
        &[],
        &["mass_spring.lattice.n", "1024 x 1024 x 1024", "memory budget"],
    );
    refused(
        "cloth.toml",
        &format!("{CLOTH_HEAD}[cloth.grid]\nnu = 4096\nnv = 4096\nsize = [1.0, 1.0]\n{MATERIAL}"),
        &[],
        &["cloth.grid", "4096 x 4096 cloth", "memory budget"],
    );
    // The same scene within a budget that holds it builds.
    let ok = format!("{CLOTH_HEAD}[cloth.grid]\nnu = 40\nnv = 40\nsize = [1.0, 1.0]\n{MATERIAL}");
    assert!(Scene::parse_with(&ok, "ok.toml", &small()).is_ok());
}

#[cfg(unix)]
#[test]
fn referenced_files_are_read_through_one_bounded_reader() {
    refused(
        "zero.toml",
        &obj_scene("/dev/zero", ""),
        &[],
        &["/dev/zero", "not a regular file"],
    );
    let d = dir("fifo");
    let fifo = d.join("fifo.obj");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .is_ok_and(|s| s.success());
    if made {
        std::fs::write(d.join("fifo.toml"), obj_scene("fifo.obj", "")).unwrap();
        let t0 = Instant::now();
        let e = Scene::load_with(&d.join("fifo.toml"), &small()).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        assert!(t0.elapsed().as_secs_f64() < 1.0, "a FIFO must not block");
    }
    // A 2 GB file (sparse: no disk used) is refused by its size, unread.
    let big = d.join("big.obj");
    std::fs::File::create(&big)
        .unwrap()
        .set_len(2 << 30)
        .unwrap();
    std::fs::write(d.join("big.toml"), obj_scene("big.obj", "")).unwrap();
    let t0 = Instant::now();
    let e = Scene::load_with(&d.join("big.toml"), &small()).unwrap_err();
    assert!(e.to_string().contains("larger than the input limit"), "{e}");
    assert!(t0.elapsed().as_secs_f64() < 1.0);
}

/// A world file of `../shared/data/jello-worlds` with line `line` (1-based) replaced.
fn world_with(line: usize, text: &str) -> PathBuf {
    let data = std::env::var_os("LARGESTEP_SHARED_DATA").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
        PathBuf::from,
    );
    let good = std::fs::read_to_string(data.join("jello-worlds/jello.w")).unwrap();
    let mut lines: Vec<&str> = good.lines().collect();
    lines[line - 1] = text;
    let d = dir(&format!("world-{line}-{}", text.len()));
    let p = d.join("world.w");
    std::fs::write(&p, lines.join("\n")).unwrap();
    p
}

#[test]
fn runs_that_would_never_end_are_refused_or_bounded() {
    // A frame interval near i64::MAX with a frame count: the steps are counted first.
    let text = format!("{HEAD}[mass_spring.chain]\ncount = 3\nspacing = 0.1\nmass = 1.0\nstiffness = 10.0\n[output]\nevery = 9223372036854775000\n");
    let scene = Scene::parse_with(&text, "every.toml", &small()).unwrap();
    let mut runner = Runner::new(scene, &dir("every"));
    let t0 = Instant::now();
    let e = runner.run(Some(2), &mut |_| {}).unwrap_err();
    assert!(matches!(e, RunError::Limit(_)), "{e}");
    assert!(e.to_string().contains("--max-steps"), "{e}");
    assert!(t0.elapsed().as_secs_f64() < 1.0);
    // A world file's time step of 5e-324 s: 1e324 steps in its 5 s.
    let e = Scene::load_with(&world_with(2, "5e-324 1"), &small()).unwrap_err();
    assert!(
        e.to_string().contains("steps") && e.to_string().contains("--max-steps"),
        "{e}"
    );
    // A display interval of 1e308: one frame of the 10,000 steps of the 5 s run.
    let scene = Scene::load_with(&world_with(2, "0.0005 1e308"), &small()).unwrap();
    let runner = Runner::new(scene, &dir("display"));
    assert_eq!(runner.frame_count(None), 1);
    // A scene's dt at the bottom of f64.
    let tiny = "[scene]\ndt = 5e-324\nduration = 1.0\nintegrator = \"rk4\"\n[mass_spring.chain]\ncount = 2\nspacing = 0.1\nmass = 1.0\nstiffness = 1.0\n";
    let e = Scene::parse_with(tiny, "tiny.toml", &small()).unwrap_err();
    assert_eq!((e.line, e.field.as_str()), (2, "scene.dt"), "{e}");
}

/// Runs `text` to its end or failure; the error and the largest coordinate ever written.
fn run_to_end(text: &str, name: &str) -> (Option<RunError>, f64) {
    let scene = Scene::parse_with(text, name, &small()).unwrap();
    let out = dir(name);
    let mut runner = Runner::new(scene, &out);
    runner.keep_frames(true);
    let e = runner.run(None, &mut |_| {}).err();
    let worst = runner
        .kept_frames()
        .iter()
        .flat_map(|m| m.positions.iter())
        .fold(0.0f64, |w, x| w.max(x.abs()));
    (e, worst)
}

#[test]
fn blow_ups_are_caught_before_coordinates_become_absurd() {
    // The chain under explicit integrators at dt = 1 s (they reached 1e97 m).
    for method in ["explicit-euler", "rk4", "midpoint", "symplectic-euler"] {
        let text = format!("[scene]\ndt = 1.0\nduration = 20.0\nintegrator = \"{method}\"\ngravity = [0.0, -9.81, 0.0]\n[mass_spring]\npinned = [0]\n[mass_spring.chain]\ncount = 20\nspacing = 0.05\nmass = 0.01\nstiffness = 500.0\ndamping = 0.02\n[output]\nevery = 1\n");
        let (e, worst) = run_to_end(&text, &format!("{method}.toml"));
        let e = e.unwrap_or_else(|| panic!("{method} at dt = 1 s must blow up"));
        let msg = e.to_string();
        assert!(
            msg.contains("blowing up") && msg.contains("reduce dt"),
            "{method}: {msg}"
        );
        assert!(worst < 1e4, "{method}: frames reached {worst} m");
    }
    // The jello under explicit Euler at dt = 0.1 s.
    let jello =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/jello.toml"))
            .unwrap()
            .replace("dt = 0.0005", "dt = 0.1")
            .replace("integrator = \"rk4\"", "integrator = \"explicit-euler\"")
            .replace("every = 67", "every = 1");
    let (e, worst) = run_to_end(&jello, "jello-euler.toml");
    assert!(e.is_some_and(|e| e.to_string().contains("blowing up")));
    assert!(worst < 1e4, "frames reached {worst} m");
    // The linearised backward Euler at dt = 1 s stretched the chain from 0.95 m to 58.7 m:
    // implicit mass-spring steps now have step-size control.
    let text = "[scene]\ndt = 1.0\nduration = 5.0\nintegrator = \"linearized-backward-euler\"\ngravity = [0.0, -9.81, 0.0]\n[mass_spring]\npinned = [0]\n[mass_spring.chain]\ncount = 20\nspacing = 0.05\nmass = 0.01\nstiffness = 500.0\ndamping = 0.02\n[output]\nevery = 1\n";
    let (e, worst) = run_to_end(text, "lbe-chain.toml");
    assert!(e.is_none(), "{e:?}");
    assert!(worst < 1.5, "the chain reached {worst} m from its pin");
}

#[test]
fn energy_that_is_not_finite_from_finite_input_is_an_error() {
    let e = Scene::load_with(&world_with(4, "1e308"), &small()).unwrap();
    let mut runner = Runner::new(e, &dir("heavy"));
    let err = runner.run(Some(1), &mut |_| {}).unwrap_err();
    assert!(
        matches!(err, RunError::NonFiniteEnergy { frame: 0, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("not finite"), "{err}");
}

#[test]
fn the_work_of_a_force_field_is_in_the_energy_balance() {
    // One free particle pushed by a uniform field (1 N along x) for 1 s: its kinetic energy
    // grows by the field's work, which is no instability.
    let forces = ["[1.0, 0.0, 0.0]"; 8].join(", ");
    let text = format!("[scene]\ndt = 0.01\nduration = 1.0\nintegrator = \"rk4\"\n[[mass_spring.particle]]\nposition = [0.0, 0.0, 0.0]\nmass = 1.0\n[mass_spring.force_field]\nmin = [-10.0, -10.0, -10.0]\nmax = [10.0, 10.0, 10.0]\nresolution = 2\nforces = [{forces}]\n");
    let scene = Scene::parse_with(&text, "field.toml", &small()).unwrap();
    let mut runner = Runner::new(scene, &dir("field"));
    let s = runner.run(None, &mut |_| {}).unwrap();
    // W = F x = 1 N * 0.5 m = 0.5 J (x = t^2 / 2), all of it kinetic.
    assert!((s.external_work - 0.5).abs() < 1e-9, "{}", s.external_work);
    assert!(s.energy_drift.abs() < 1e-9, "drift {}", s.energy_drift);
    assert!(!s.to_string().contains("warning"), "{s}");
}

#[test]
fn messages_are_bounded_and_name_the_file_where_the_bad_value_is() {
    // A 5 MB line comes back as a few hundred characters.
    let long = HEAD.replace("\"rk4\"", &format!("\"{}\"", "x".repeat(5_000_000)));
    let e = Scene::parse_with(&long, "long.toml", &small()).unwrap_err();
    assert!(e.to_string().len() < 2000, "{} bytes", e.to_string().len());
    // Text that is not UTF-8: the line and the byte.
    let d = dir("latin1");
    std::fs::write(d.join("s.toml"), b"[scene]\ndt = 0.01\n# caf\xe9\n").unwrap();
    let e = Scene::load_with(&d.join("s.toml"), &small()).unwrap_err();
    assert_eq!(e.line, 3, "{e}");
    assert!(e.to_string().contains("byte 23 of the file"), "{e}");
    // A plane normal too long to square still has a direction.
    let plane = format!("{CLOTH_HEAD}[cloth]\n[[cloth.plane]]\npoint = [0.0, -1.0, 0.0]\nnormal = [1e308, 1e308, 1.0]\n[cloth.grid]\nnu = 4\nnv = 4\nsize = [1.0, 1.0]\n{MATERIAL}");
    assert!(Scene::parse_with(&plane, "plane.toml", &small()).is_ok());
    // A uv_scale that overflows the rest area is an error at uv_scale, not a zero area.
    let tri = b"v 0 0 0\nv 1 0 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n";
    let e = refused(
        "uvs.toml",
        &obj_scene("tri.obj", "uv_scale = 1e300\n"),
        &[("tri.obj", tri)],
        &["uv_scale = 1e300"],
    );
    assert_eq!(e.field, "cloth.mesh.uv_scale");
    // A bad vertex of a cloth mesh, used or not, at its OBJ line.
    for (obj, line) in [
        (
            "v 0 0 0\nv 1 0 0\nv 0 inf 1\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n",
            3,
        ),
        (
            "v 0 0 0\nv 1 0 0\nv 0 0 1\nv 0 0 1e308\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n",
            4,
        ),
    ] {
        let e = refused(
            "vertex.toml",
            &obj_scene("m.obj", ""),
            &[("m.obj", obj.as_bytes())],
            &[&format!("m.obj:{line}: vertex {line}")],
        );
        assert_eq!(e.field, "cloth.mesh.file");
    }
    // A frame folder's vertex at 1e308: the file and line, not the camera.
    let frames = dir("frames");
    std::fs::write(
        frames.join("frame_00000.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1e308 0\nf 1 2 3\n",
    )
    .unwrap();
    let e = largestep::render::preview::load_frames(&frames, small().max_file_bytes)
        .unwrap_err()
        .to_string();
    assert!(e.contains("frame_00000.obj") && e.contains("line 3"), "{e}");
}

#[test]
fn a_model_falling_through_an_obstacle_is_reported() {
    // Points of 1e30 kg against 400 N/m penalty springs: the cube goes through the wall.
    let scene = Scene::load_with(&world_with(4, "1e30"), &small()).unwrap();
    let mut runner = Runner::new(scene, &dir("heavy30"));
    let s = runner.run(Some(4), &mut |_| {}).unwrap();
    assert!(s.max_penetration > 0.5 * s.size, "{s}");
    assert!(s.to_string().contains("sank up to"), "{s}");
    // The assignment's own cube dents the wall by centimetres: no warning.
    let scene = Scene::load_with(&world_with(4, "0.001953"), &small()).unwrap();
    let mut runner = Runner::new(scene, &dir("light"));
    let s = runner.run(Some(4), &mut |_| {}).unwrap();
    assert!(!s.to_string().contains("warning"), "{s}");
}

#[test]
fn a_preview_larger_than_the_budget_is_refused_at_its_size() {
    let text = format!("{HEAD}[mass_spring.chain]\ncount = 2\nspacing = 0.1\nmass = 1.0\nstiffness = 1.0\n[output]\nwidth = 16384\nheight = 16384\n");
    let e = Scene::parse_with(&text, "big.toml", &Limits::with_memory(1 << 30)).unwrap_err();
    assert_eq!(e.field, "output.width", "{e}");
    assert!(e.to_string().contains("16384 x 16384 preview"), "{e}");
    assert!(Scene::parse_with(&text, "big.toml", &small()).is_ok());
}
