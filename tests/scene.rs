//! Scenes: the shipped scenes run; malformed scenes give located errors; a blow-up stops
//! the run with the step while frames written before stay valid; `--frames` and
//! `--explain` behave; explicit scenes build no matrix.

use largestep::scene::{Runner, Scene};
use std::path::{Path, PathBuf};

fn scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name)
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("largestep-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn shipped_scenes_run_a_few_frames() {
    for name in [
        "hanging-chain.toml",
        "spring-grid.toml",
        "jello.toml",
        "cloth-hang.toml",
        "cloth-drape.toml",
        "flag.toml",
        "tablecloth.toml",
    ] {
        let scene = Scene::load(&scene_path(name)).unwrap();
        let out = tmp(name);
        let mut runner = Runner::new(scene, &out);
        let mut seen = 0;
        let summary = runner.run(Some(3), &mut |p| seen = p.frame).unwrap();
        assert_eq!(seen, 3);
        assert_eq!(summary.frames_written, 4, "initial frame + 3");
        let frame = std::fs::read_to_string(out.join("frames/frame_00003.obj")).unwrap();
        assert!(frame.lines().filter(|l| l.starts_with("v ")).count() > 10);
        let csv = std::fs::read_to_string(out.join("energy.csv")).unwrap();
        assert_eq!(csv.lines().count(), 5, "header + 4 frames");
        assert!(summary.energy.1.is_finite());
    }
}

#[test]
fn explain_lists_built_and_left_out_stages() {
    let explicit = Runner::new(
        Scene::load(&scene_path("hanging-chain.toml")).unwrap(),
        &tmp("x1"),
    );
    let text = explicit.explain();
    assert!(
        text.contains("left out  Jacobian assembly, system matrix and linear solver"),
        "{text}"
    );
    assert!(text.contains("left out  collision structures"), "{text}");
    assert!(text.contains("built     pinned-particle filter"), "{text}");
    let implicit = Runner::new(
        Scene::load(&scene_path("spring-grid.toml")).unwrap(),
        &tmp("x2"),
    );
    let text = implicit.explain();
    assert!(text.contains("built     Jacobian assembly"), "{text}");
    assert!(
        text.contains("left out  Newton iteration"),
        "linearised step: {text}"
    );
}

const BASE: &str = r#"
[scene]
dt = 0.001
duration = 0.01
integrator = "rk4"
gravity = [0.0, -9.81, 0.0]

[[mass_spring.particle]]
position = [0.0, 0.0, 0.0]
mass = 1.0
pinned = true

[[mass_spring.particle]]
position = [1.0, 0.0, 0.0]
mass = 1.0

[[mass_spring.spring]]
a = 0
b = 1
stiffness = 100.0
damping = 0.1
"#;

/// Parses `text`, expecting an error at `line` mentioning every word of `words`.
fn expect_error(text: &str, line: usize, words: &[&str]) {
    let err = Scene::parse(text, "bad.toml").expect_err("scene must be rejected");
    let msg = err.to_string();
    assert!(
        msg.starts_with(&format!("bad.toml:{line}:")),
        "expected line {line}: {msg}"
    );
    for w in words {
        assert!(msg.contains(w), "`{msg}` should mention `{w}`");
    }
}

/// Line (1-based) of the last line containing `needle`.
fn line_of(text: &str, needle: &str) -> usize {
    let lines: Vec<&str> = text.lines().collect();
    lines
        .iter()
        .rposition(|l| l.contains(needle))
        .expect("needle in text")
        + 1
}

#[test]
fn base_scene_is_valid() {
    let s = Scene::parse(BASE, "ok.toml").unwrap();
    assert_eq!(s.dt, 0.001);
}

#[test]
fn malformed_scenes_name_file_line_and_field() {
    let cases: Vec<(String, &str, Vec<&str>)> = vec![
        (
            BASE.replace("dt = 0.001", "dt = -0.001"),
            "dt = -0.001",
            vec!["scene.dt", "> 0"],
        ),
        (
            BASE.replace("dt = 0.001", "dt = 0.0"),
            "dt = 0.0",
            vec!["scene.dt"],
        ),
        (
            BASE.replace("dt = 0.001", "dt = nan"),
            "dt = nan",
            vec!["scene.dt", "NaN"],
        ),
        (
            BASE.replace("dt = 0.001", "dt = \"fast\""),
            "dt = \"fast\"",
            vec!["invalid type"],
        ),
        (
            BASE.replace("duration = 0.01", "duration = 0.01\nspeed = 3"),
            "speed = 3",
            vec!["unknown field `speed`"],
        ),
        (
            BASE.replace("integrator = \"rk4\"", "integrator = \"rk5\""),
            "integrator =",
            vec!["unknown integrator `rk5`", "rk4"],
        ),
        (
            BASE.replacen("mass = 1.0", "mass = -2.0", 1),
            "mass = -2.0",
            vec!["mass_spring.particle[0].mass", "-2"],
        ),
        (
            BASE.replace("stiffness = 100.0", "stiffness = -100.0"),
            "stiffness = -100.0",
            vec!["mass_spring.spring[0].stiffness"],
        ),
        (
            BASE.replace("damping = 0.1", "damping = nan"),
            "damping = nan",
            vec!["mass_spring.spring[0].damping", "NaN"],
        ),
        (
            BASE.replace("b = 1", "b = 7"),
            "b = 7",
            vec!["mass_spring.spring[0].b", "particle 7", "only 2"],
        ),
        (
            BASE.replace("a = 0", "a = -1"),
            "a = -1",
            vec!["mass_spring.spring[0].a", ">= 0"],
        ),
        (
            BASE.replace("b = 1", "b = 0"),
            "b = 0",
            vec!["connects particle 0 to itself"],
        ),
        (
            BASE.replace("position = [1.0, 0.0, 0.0]", "position = [1.0, nan, 0.0]"),
            "nan, 0.0]",
            vec!["particle[1].position", "NaN"],
        ),
        (
            BASE.replace("position = [1.0, 0.0, 0.0]", "position = [1.0, 0.0]"),
            "position = [1.0, 0.0]",
            vec!["invalid length"],
        ),
        (
            BASE.replace(
                "mass = 1.0\n\n[[mass_spring.spring]]",
                "\n[[mass_spring.spring]]",
            ),
            "[[mass_spring.particle]]",
            vec!["missing field `mass`"],
        ),
        (BASE.replace("[scene]", "[scene\n"), "[scene", vec![]),
        (
            BASE.replace("gravity = [0.0, -9.81, 0.0]", "gravity = [0.0, inf, 0.0]"),
            "gravity",
            vec!["scene.gravity[1]"],
        ),
    ];
    for (text, needle, words) in cases {
        expect_error(&text, line_of(&text, needle), &words);
    }
    // A scene without a system, and one with two.
    expect_error(
        "[scene]\ndt = 0.1\nduration = 1.0\nintegrator = \"rk4\"\n",
        1,
        &["no system"],
    );
    let two = format!(
        "{BASE}\n[mass_spring.chain]\ncount = 3\nspacing = 0.1\nmass = 1.0\nstiffness = 1.0\n"
    );
    let err = Scene::parse(&two, "bad.toml").err().unwrap().to_string();
    assert!(err.contains("exactly one of"), "{err}");
}

#[test]
fn errors_show_the_offending_line() {
    let text = BASE.replace("b = 1", "b = 7");
    let err = Scene::parse(&text, "bad.toml").err().unwrap().to_string();
    assert!(err.contains("| b = 7"), "{err}");
}

#[test]
fn unreadable_scene_file_is_an_error_not_a_panic() {
    let err = Scene::load(Path::new("/nonexistent/scene.toml"))
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("/nonexistent/scene.toml") && err.contains("cannot read"),
        "{err}"
    );
}

#[test]
fn blow_up_stops_with_the_step_and_keeps_earlier_frames() {
    // Explicit Euler on a stiff spring: h w = 0.001 * sqrt(1e8) = 10.
    let text = BASE
        .replace("integrator = \"rk4\"", "integrator = \"explicit-euler\"")
        .replace("duration = 0.01", "duration = 1.0")
        .replace("stiffness = 100.0", "stiffness = 1e8")
        + "\n[output]\nevery = 5\n";
    let scene = Scene::parse(&text, "boom.toml").unwrap();
    let out = tmp("boom");
    let mut runner = Runner::new(scene, &out);
    let err = runner.run(None, &mut |_| {}).expect_err("must blow up");
    let msg = err.to_string();
    // Caught as it grows (a vertex crossing ten times the model's size in a step), before
    // anything is infinite; a state that does become non-finite is reported as such.
    assert!(
        msg.contains("step ")
            && (msg.contains("blowing up") || msg.contains("not finite"))
            && msg.contains("reduce dt"),
        "{msg}"
    );
    assert!(
        msg.contains("blowing up"),
        "caught before it is infinite: {msg}"
    );
    assert!(msg.contains("remain valid"), "{msg}");
    // Every frame file on disk is complete and finite.
    let mut frames = 0;
    for entry in std::fs::read_dir(out.join("frames")).unwrap() {
        let path = entry.unwrap().path();
        assert_eq!(
            path.extension().unwrap(),
            "obj",
            "no temporary files left: {path:?}"
        );
        let text = std::fs::read_to_string(&path).unwrap();
        for l in text.lines().filter(|l| l.starts_with("v ")) {
            assert!(
                l.split_whitespace()
                    .skip(1)
                    .all(|v| v.parse::<f64>().unwrap().is_finite()),
                "{path:?}: {l}"
            );
        }
        frames += 1;
    }
    assert!(frames >= 1);
    let csv = std::fs::read_to_string(out.join("energy.csv")).unwrap();
    assert_eq!(
        csv.lines().count(),
        frames + 1,
        "one log line per frame written"
    );
}

#[test]
fn output_camera_and_image_settings_are_validated_with_lines() {
    let with = |extra: &str| format!("{BASE}\n[output]\nframes = \"obj\"\n{extra}\n");
    let cases: Vec<(String, &str, Vec<&str>)> = vec![
        (
            with("width = 0"),
            "width = 0",
            vec!["output.width", "1..=16384"],
        ),
        (
            with("supersample = 9"),
            "supersample = 9",
            vec!["output.supersample", "1..=4"],
        ),
        (
            with("[output.camera]\neye = [1.0, 2.0, 3.0]"),
            "eye =",
            vec!["output.camera.eye", "needs `target`"],
        ),
        (
            with("[output.camera]\ntarget = [0.0, 0.0, 0.0]"),
            "target =",
            vec!["output.camera.target", "needs `eye`"],
        ),
        (
            with("[output.camera]\neye = [1.0, 1.0, 1.0]\ntarget = [1.0, 1.0, 1.0]"),
            "eye =",
            vec!["same point"],
        ),
        (
            with("[output.camera]\neye = [0.0, 5.0, 0.0]\ntarget = [0.0, 0.0, 0.0]"),
            "eye =",
            vec!["up vector", "parallel"],
        ),
        (
            with("[output.camera]\nup = [0.0, 0.0, 0.0]"),
            "up =",
            vec!["output.camera.up", "non-zero"],
        ),
        (
            with("[output.camera]\nfov = 180.0"),
            "fov =",
            vec!["output.camera.fov", "(0, 180)"],
        ),
        (
            with("[output.camera]\nelevation = 95.0"),
            "elevation =",
            vec!["output.camera.elevation"],
        ),
        (
            with(
                "[output.camera]\neye = [1.0, 2.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\nazimuth = 10.0",
            ),
            "azimuth =",
            vec!["fixed camera"],
        ),
        (
            with("[output.camera]\nzoom = 2.0"),
            "zoom",
            vec!["unknown field `zoom`"],
        ),
    ];
    for (text, needle, words) in cases {
        expect_error(&text, line_of(&text, needle), &words);
    }
    // Valid settings arrive in the preview settings; up defaults to against gravity.
    let s = Scene::parse(
        &with("width = 320\nheight = 200\nsupersample = 3\nwireframe = true\n[output.camera]\nazimuth = -20.0"),
        "ok.toml",
    )
    .unwrap();
    let p = s.output.preview;
    assert_eq!(
        (p.render.width, p.render.height, p.render.supersample),
        (320, 200, 3)
    );
    assert!(p.wireframe);
    match p.camera {
        largestep::render::CameraSpec::Auto {
            azimuth_deg, up, ..
        } => {
            assert_eq!(azimuth_deg, -20.0);
            assert_eq!(up, [0.0, 1.0, 0.0]);
        }
        other => panic!("expected an auto camera, got {other:?}"),
    }
}

#[test]
fn cli_run_with_preview_and_render_write_images_and_plots() {
    let exe = env!("CARGO_BIN_EXE_largestep");
    let out = tmp("cli-preview");
    let st = std::process::Command::new(exe)
        .args([
            "run",
            scene_path("hanging-chain.toml").to_str().unwrap(),
            "--frames",
            "4",
            "--preview",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    for f in [
        "run.svg",
        "run.png",
        "preview/frame_00004.png",
        "preview/animation.gif",
        "preview/contact-sheet.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let im = largestep::io::read_png(&out.join("preview/frame_00000.png")).unwrap();
    assert_eq!((im.width, im.height), (1280, 720));
    // Re-render the OBJ frames with another camera and size.
    let again = out.join("again");
    let st = std::process::Command::new(exe)
        .args(["render"])
        .arg(out.join("frames"))
        .args([
            "--size",
            "200x100",
            "--azimuth",
            "-60",
            "--wireframe",
            "--out",
        ])
        .arg(&again)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let im = largestep::io::read_png(&again.join("frame_00002.png")).unwrap();
    assert_eq!((im.width, im.height), (200, 100));
    // Bad input: a malformed frame names file and line (exit 2); a lone --eye too.
    std::fs::write(out.join("frames/frame_00001.obj"), "v 0 0 0\nf 1 2\n").unwrap();
    let st = std::process::Command::new(exe)
        .arg("render")
        .arg(out.join("frames"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&st.stderr);
    assert_eq!(st.status.code(), Some(2), "{err}");
    assert!(
        err.contains("frame_00001.obj") && err.contains("line 2"),
        "{err}"
    );
    let st = std::process::Command::new(exe)
        .arg("render")
        .arg(out.join("frames"))
        .args(["--eye", "1,2,3"])
        .output()
        .unwrap();
    assert_eq!(st.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&st.stderr).contains("--eye and --target"));
}

/// A scene with a chain and a cloth: two independent systems, stepped one after the other,
/// written as one mesh per frame; each moves exactly (bitwise) as it does alone.
#[test]
fn a_scene_holds_several_independent_systems() {
    use largestep::simulation::FrameData;
    let head = "[scene]\ndt = 0.005\nduration = 0.05\nintegrator = \"linearized-backward-euler\"\ngravity = [0.0, -9.81, 0.0]\n";
    let chain = "[mass_spring.chain]\ncount = 6\nanchor = [2.0, 1.0, 0.0]\nspacing = 0.1\nmass = 0.01\nstiffness = 100.0\ndamping = 0.01\n";
    let cloth = "[cloth]\npinned = [0, 4]\n[[cloth.sphere]]\ncenter = [0.5, -0.2, 0.5]\nradius = 0.3\n[cloth.grid]\nnu = 5\nnv = 5\nsize = [1.0, 1.0]\n[cloth.material]\ndensity = 0.2\nstretch = 1000.0\nshear = 100.0\nbend = 0.01\n";
    let positions = |r: &Runner| -> Vec<Vec<f64>> {
        r.systems()
            .iter()
            .map(|s| match s.sim.frame() {
                FrameData::Mesh(m) => m.positions.to_vec(),
                _ => unreachable!("mechanical systems write meshes"),
            })
            .collect()
    };
    let run = |text: &str, name: &str| {
        let scene = Scene::parse(&format!("{text}[output]\nevery = 1\n"), name).unwrap();
        let mut runner = Runner::new(scene, &tmp(name));
        runner.run(None, &mut |_| {}).unwrap();
        runner
    };
    let frames = |r: &Runner| r.out_dir().join("frames");
    let both = run(&format!("{head}{chain}{cloth}"), "both.toml");
    let tables: Vec<&str> = both.systems().iter().map(|s| s.table).collect();
    assert_eq!(tables, ["mass_spring", "cloth"]);
    let alone_chain = run(&format!("{head}{chain}"), "chain-alone.toml");
    let alone_cloth = run(&format!("{head}{cloth}"), "cloth-alone.toml");
    let together = positions(&both);
    assert_eq!(
        together[0],
        positions(&alone_chain)[0],
        "the chain as alone"
    );
    assert_eq!(
        together[1],
        positions(&alone_cloth)[0],
        "the cloth as alone"
    );
    // One frame file with both: 6 + 25 vertices, the cloth's triangles after the chain's
    // segments' vertices (the chain writes segments, the cloth triangles).
    let frame = std::fs::read_to_string(frames(&both).join("frame_00010.obj")).unwrap();
    assert_eq!(frame.lines().filter(|l| l.starts_with("v ")).count(), 31);
    assert_eq!(frame.lines().filter(|l| l.starts_with("f ")).count(), 32);
    assert_eq!(frame.lines().filter(|l| l.starts_with("l ")).count(), 5);
    assert!(
        frame.contains("f 7 "),
        "cloth indices shifted past the chain"
    );
    let text = both.explain();
    assert!(
        text.contains("[mass_spring]") && text.contains("[cloth]"),
        "{text}"
    );
    assert!(text.contains("built     obstacle contacts"), "{text}");
    // The energy log sums both systems.
    let e = |r: &Runner| {
        let last = r.records().last().unwrap();
        last.kinetic + last.potential
    };
    let sum = e(&alone_chain) + e(&alone_cloth);
    assert!((e(&both) - sum).abs() <= 1e-12 * sum.abs().max(1.0));
}

/// Output is safe against what an earlier run, or someone else, left in the folder:
/// symbolic links planted at frame, temporary and log names are replaced, never written
/// through; a longer earlier run's frames and interrupted writes' temporaries are removed;
/// a scene's name cannot place the default output folder outside `out/`.
#[cfg(unix)]
#[test]
fn output_is_safe_against_what_the_folder_holds() {
    let out = tmp("safe");
    let frames = out.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let victim = tmp("victim.txt");
    std::fs::write(&victim, "precious").unwrap();
    let link = |name: &str| std::os::unix::fs::symlink(&victim, name).unwrap();
    link(frames.join("frame_00001.obj").to_str().unwrap());
    link(frames.join("frame_00001.obj.tmp").to_str().unwrap());
    link(out.join("energy.csv").to_str().unwrap());
    // An earlier, longer run's last frame and an interrupted write's temporary.
    std::fs::write(frames.join("frame_00009.obj"), "v 0 0 0\n").unwrap();
    std::fs::write(frames.join(".frame_00002.obj.1.7.tmp"), "half").unwrap();
    let text = format!("{BASE}\n[output]\nevery = 2\n");
    let mut runner = Runner::new(Scene::parse(&text, "safe.toml").unwrap(), &out);
    runner.run(Some(3), &mut |_| {}).unwrap();
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    let mut names: Vec<String> = std::fs::read_dir(&frames)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "frame_00000.obj",
            "frame_00001.obj",
            "frame_00002.obj",
            "frame_00003.obj"
        ]
    );
    for n in &names {
        let meta = std::fs::symlink_metadata(frames.join(n)).unwrap();
        assert!(meta.file_type().is_file(), "{n} is a regular file");
    }
    let csv = out.join("energy.csv");
    assert!(std::fs::symlink_metadata(&csv)
        .unwrap()
        .file_type()
        .is_file());
    assert_eq!(std::fs::read_to_string(&csv).unwrap().lines().count(), 5);
    // Names that would leave out/.
    for (name, folder) in [
        ("../../x", "_.._x"),
        ("/etc/passwd", "_etc_passwd"),
        ("..", "scene"),
        ("a b", "a_b"),
    ] {
        let text = BASE.replace("[scene]", &format!("[scene]\nname = {name:?}"));
        let s = Scene::parse(&text, "named.toml").unwrap();
        assert_eq!(s.folder_name(), folder, "{name}");
    }
}

/// `largestep run --preview` on a scene that blows up still previews the frames written
/// before (issue 14): the sane ones, framed on them; and `render --up 0,0,0` falls back
/// to +y with a warning, as for a fixed camera.
#[test]
fn a_failed_run_is_previewed_and_a_zero_up_falls_back() {
    let exe = env!("CARGO_BIN_EXE_largestep");
    let text = std::fs::read_to_string(scene_path("spring-grid.toml"))
        .unwrap()
        .replace(
            "integrator = \"linearized-backward-euler\"",
            "integrator = \"explicit-euler\"",
        );
    assert!(text.contains("explicit-euler"));
    let dir = tmp("failed-preview");
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("boom.toml");
    std::fs::write(&scene, text).unwrap();
    let out = dir.join("out");
    let st = std::process::Command::new(exe)
        .args(["run", scene.to_str().unwrap(), "--preview", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&st.stderr);
    assert_eq!(st.status.code(), Some(1), "the run fails: {err}");
    assert!(
        err.contains("blowing up") || err.contains("not finite"),
        "{err}"
    );
    assert!(!err.contains("camera"), "{err}");
    assert!(out.join("preview/contact-sheet.png").is_file(), "{err}");
    assert!(out.join("preview/frame_00000.png").is_file());
    // A zero up vector with auto-framing.
    let st = std::process::Command::new(exe)
        .arg("render")
        .arg(out.join("frames"))
        .args(["--up", "0,0,0", "--size", "160x90", "--out"])
        .arg(dir.join("up"))
        .output()
        .unwrap();
    let all = format!(
        "{}{}",
        String::from_utf8_lossy(&st.stdout),
        String::from_utf8_lossy(&st.stderr)
    );
    assert!(st.status.success(), "{all}");
    assert!(all.contains("up vector is zero"), "{all}");
}

/// A mistyped subcommand or study name is a usage error (status 2) that names the nearest
/// one, transpositions included; a name near nothing gets no guess.
#[test]
fn mistyped_commands_and_studies_get_the_nearest_name() {
    let exe = env!("CARGO_BIN_EXE_largestep");
    let stderr_of = |args: &[&str]| {
        let o = std::process::Command::new(exe).args(args).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    assert!(stderr_of(&["rnu"]).contains("'run'"));
    assert!(stderr_of(&["stduy"]).contains("'study'"));
    assert!(!stderr_of(&["xyz"]).contains("similar"));
    let e = stderr_of(&["study", "jelo-stability"]);
    assert!(e.contains("did you mean `jello-stability`"), "{e}");
    assert!(!stderr_of(&["study", "qqq"]).contains("did you mean"));
}

/// `largestep haptics` on the shared nut with `extra` arguments, writing to `out`.
fn haptics_cli(extra: &[&str], out: &std::path::Path) -> std::process::Output {
    let nut =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/tetmesh/nut-surface.off");
    let mut args = vec![
        "haptics",
        nut.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(extra);
    std::process::Command::new(env!("CARGO_BIN_EXE_largestep"))
        .args(args)
        .output()
        .unwrap()
}

/// A successful haptics run's trace: it printed `said`, and `out/haptics.csv` has the
/// `header` and 3,001 ticks.
fn haptics_trace(
    run: &std::process::Output,
    said: &str,
    out: &std::path::Path,
    header: &str,
) -> String {
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        stdout.contains("3001 ticks") && stdout.contains(said),
        "{stdout}"
    );
    let csv = std::fs::read_to_string(out.join("haptics.csv")).unwrap();
    assert!(
        csv.starts_with(&format!("{header}\n")),
        "{}",
        csv.lines().next().unwrap_or("")
    );
    assert_eq!(csv.lines().count(), 3002);
    csv
}

/// A trace without its last column (the work times, which differ run to run).
fn without_work(csv: &str) -> Vec<String> {
    csv.lines()
        .map(|l| l.rsplit_once(',').unwrap().0.to_string())
        .collect()
}

#[test]
fn haptics_command_with_a_tool_writes_force_and_torque() {
    let block = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/haptic-block.obj");
    let out = tmp("haptics-tool");
    let tool = |extra: &[&str], out: &std::path::Path| {
        let mut args = vec!["--tool", block.to_str().unwrap()];
        args.extend(extra);
        haptics_cli(&args, out)
    };
    let csv = haptics_trace(
        &tool(&[], &out),
        "shell points",
        &out,
        "time_s,device_x,device_y,device_z,device_qw,device_qx,device_qy,device_qz,tool_x,tool_y,tool_z,tool_qw,tool_qx,tool_qy,tool_qz,force_x,force_y,force_z,torque_x,torque_y,torque_z,contacts,penetration,work_us",
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["mode"], "six-dof");
    assert!(summary["max_force_n"].as_f64().unwrap() > 0.0);
    assert!(summary["max_torque_nm"].as_f64().unwrap() > 0.0);
    assert!(summary["shell_points"].as_u64().unwrap() > 1000);
    // The written path holds the tilt; replayed, it gives the same trace.
    let path = out.join("device-path.csv");
    assert!(std::fs::read_to_string(&path)
        .unwrap()
        .starts_with("t,x,y,z,qw,qx,qy,qz\n"));
    let again = tool(&["--path", path.to_str().unwrap()], &out.join("again"));
    assert!(again.status.success());
    assert_eq!(
        without_work(&csv),
        without_work(&std::fs::read_to_string(out.join("again/haptics.csv")).unwrap())
    );
    // Bad input: named.
    let bad = out.join("bad.csv");
    std::fs::write(&bad, "0,0,0,0,1,0,0,0\n1,0,0,0,0,0,0,0\n").unwrap();
    let e = tool(&["--path", bad.to_str().unwrap()], &out);
    assert_eq!(e.status.code(), Some(2));
    let err = String::from_utf8_lossy(&e.stderr);
    assert!(err.contains("bad.csv:2") && err.contains("zero"), "{err}");
    let e = tool(&["--cells", "1"], &out);
    assert_eq!(e.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&e.stderr).contains("--cells 1"));
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn haptics_command_writes_the_force_trace_and_names_bad_paths() {
    let out = tmp("haptics");
    let csv = haptics_trace(
        &haptics_cli(&[], &out),
        "p99",
        &out,
        "time_s,device_x,device_y,device_z,proxy_x,proxy_y,proxy_z,force_x,force_y,force_z,work_us",
    );
    for f in [
        "haptics.png",
        "haptics.svg",
        "summary.json",
        "device-path.csv",
    ] {
        assert!(out.join(f).exists(), "{f}");
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert!(summary["max_force_n"].as_f64().unwrap() > 0.0);
    // The written path replays to the same trace.
    let path = out.join("device-path.csv");
    let again = haptics_cli(&["--path", path.to_str().unwrap()], &out.join("again"));
    assert!(again.status.success());
    assert_eq!(
        without_work(&csv),
        without_work(&std::fs::read_to_string(out.join("again/haptics.csv")).unwrap())
    );
    // A bad path file: the file and line are named.
    let bad = out.join("bad.csv");
    std::fs::write(&bad, "t,x,y,z\n0,0,0,0\n0.5,1,oops,0\n").unwrap();
    let run = haptics_cli(&["--path", bad.to_str().unwrap()], &out);
    assert_eq!(run.status.code(), Some(2));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.contains("bad.csv") && err.contains("3") && err.contains("oops"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&out);
}
