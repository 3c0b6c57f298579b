//! The preview renderer: golden images, depth order, bad data, cameras, OBJ input and the
//! preview files.
//!
//! Golden images live in `tests/golden/`. A change in rendering is a decision: when a
//! change is meant, regenerate them with `LARGESTEP_BLESS=1 cargo test --test render`,
//! look at them, and commit them.

use largestep::io::{parse_obj, read_png, Image, Mesh};
use largestep::render::preview::{load_frames, write_preview, PreviewSettings};
use largestep::render::{
    Bounds, Camera, CameraSpec, Object, RenderError, Renderer, Settings, Style,
};
use largestep::shapes::{chain, from_triangles, uv_sphere, wavy_sheet};
use std::path::PathBuf;

fn small(ground: bool) -> Settings {
    Settings {
        width: 160,
        height: 96,
        supersample: 2,
        ground,
    }
}

fn auto_camera(bounds: &Bounds, s: &Settings) -> Camera {
    Camera::auto(
        bounds,
        s.width as f64 / s.height as f64,
        35.0,
        22.0,
        40.0,
        [0.0, 1.0, 0.0],
    )
    .unwrap()
}

fn render(
    s: Settings,
    camera: &Camera,
    meshes: &[(&Mesh, Style)],
) -> (Image, largestep::render::RenderStats) {
    let objects: Vec<Object> = meshes
        .iter()
        .map(|(m, st)| Object {
            mesh: m.as_ref(),
            style: *st,
        })
        .collect();
    let mut r = Renderer::new(s).unwrap();
    let mut im = Image::new(1, 1);
    let stats = r.render(camera, &Bounds::EMPTY, &objects, &mut im).unwrap();
    (im, stats)
}

/// A sphere, a rippled wireframe sheet and a chain of particles over the ground.
fn golden_scene() -> Vec<Mesh> {
    vec![
        uv_sphere([0.0, 0.5, 0.0], 0.5, 16, 24),
        wavy_sheet([1.2, 0.3, 0.2], 1.2, 12, 0.08),
        chain([-1.1, 1.2, 0.3], [0.0, -0.12, 0.05], 9),
    ]
}

fn styles(meshes: &[Mesh]) -> Vec<Style> {
    meshes
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let mut s = Style::palette(i, &m.as_ref());
            s.wireframe = i == 1;
            s
        })
        .collect()
}

fn golden_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden")
}

/// Peak signal-to-noise ratio (dB) over all channels, and the fraction of pixels with a
/// channel off by more than 8 levels.
fn compare(a: &Image, b: &Image) -> (f64, f64) {
    assert_eq!(
        (a.width, a.height),
        (b.width, b.height),
        "image sizes differ"
    );
    let mse = a
        .rgb
        .iter()
        .zip(&b.rgb)
        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
        .sum::<f64>()
        / a.rgb.len() as f64;
    let off = a
        .rgb
        .chunks(3)
        .zip(b.rgb.chunks(3))
        .filter(|(p, q)| p.iter().zip(*q).any(|(x, y)| x.abs_diff(*y) > 8))
        .count() as f64
        / (a.width * a.height) as f64;
    let psnr = if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    };
    (psnr, off)
}

/// Compares with `tests/golden/NAME.png` within PSNR >= 50 dB and at most 0.2% of pixels
/// off by more than 8 levels: room for another CPU's or libm's last-bit rounding (the
/// renderer is deterministic f32 code), none for a changed look (a 50% change of the
/// specular strength alone fails it).
fn check_golden(name: &str, im: &Image) {
    let path = golden_dir().join(format!("{name}.png"));
    if std::env::var_os("LARGESTEP_BLESS").is_some() {
        std::fs::create_dir_all(golden_dir()).unwrap();
        largestep::io::write_atomically(&path, |w| largestep::io::write_png(w, im)).unwrap();
        return;
    }
    let reference =
        read_png(&path).unwrap_or_else(|e| panic!("{e} (bless with LARGESTEP_BLESS=1)"));
    let (psnr, off) = compare(im, &reference);
    assert!(
        psnr >= 50.0 && off <= 0.002,
        "{name}: PSNR {psnr:.1} dB, {:.2}% of pixels off by > 8 levels",
        100.0 * off
    );
}

#[test]
fn golden_scene_matches_reference() {
    let meshes = golden_scene();
    let st = styles(&meshes);
    let s = small(true);
    let mut b = Bounds::EMPTY;
    for m in &meshes {
        b.union(&largestep::render::preview::bounds_of(
            std::slice::from_ref(m),
        ));
    }
    let cam = auto_camera(&b, &s);
    let pairs: Vec<(&Mesh, Style)> = meshes.iter().zip(st).collect();
    let (im, stats) = render(s, &cam, &pairs);
    assert_eq!(stats.skipped_degenerate + stats.skipped_non_finite, 0);
    assert_eq!(stats.points, 9);
    assert_eq!(stats.segments, 8);
    check_golden("scene", &im);
}

#[test]
fn golden_empty_scene_is_ground_and_sky() {
    let s = small(true);
    let cam = auto_camera(&Bounds::EMPTY, &s);
    let (im, stats) = render(s, &cam, &[]);
    assert_eq!((im.width, im.height), (160, 96));
    assert_eq!(stats, Default::default());
    // Sky above, ground below, and they differ.
    let (top, bottom) = (im.pixel(80, 1), im.pixel(80, 94));
    assert_ne!(top, bottom);
    assert!(top.iter().all(|&c| c > 100), "sky {top:?}");
    check_golden("empty", &im);
}

#[test]
fn near_triangle_hides_far_one_in_either_order() {
    let near = from_triangles(
        &[[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]],
        &[[0, 1, 2]],
    );
    let far = from_triangles(
        &[[-2.0, -2.0, -1.0], [2.0, -2.0, -1.0], [0.0, 2.0, -1.0]],
        &[[0, 1, 2]],
    );
    let cam = Camera {
        eye: [0.0, 0.0, 5.0],
        target: [0.0, 0.0, 0.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 60.0,
    };
    let s = Settings {
        ground: false,
        ..small(false)
    };
    let red = Style {
        color: [1.0, 0.0, 0.0],
        back_color: [1.0, 0.0, 0.0],
        ..Style::palette(0, &near.as_ref())
    };
    let blue = Style {
        color: [0.0, 0.0, 1.0],
        back_color: [0.0, 0.0, 1.0],
        ..red
    };
    for order in [[(&near, red), (&far, blue)], [(&far, blue), (&near, red)]] {
        let (im, _) = render(s, &cam, &order);
        let c = im.pixel(80, 48);
        assert!(
            c[0] > 100 && c[2] < 30,
            "centre should be red (near), got {c:?}"
        );
        // Outside the near triangle but inside the far one: blue.
        let side = im.pixel(80, 72);
        assert!(
            side[2] > 100 && side[0] < 30,
            "lower centre should be blue (far), got {side:?}"
        );
    }
}

#[test]
fn degenerate_and_non_finite_triangles_are_skipped_and_counted() {
    let good = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
    ];
    let mut pts = good.to_vec();
    pts.push([0.5, 0.5, f64::NAN]); // 4
    pts.push([2.0, 2.0, 0.0]); // 5, collinear with 0 and 3
    let tris = [
        [0, 1, 2],
        [1, 3, 2],
        [0, 0, 1],
        [0, 3, 5],
        [1, 3, 4],
        [2, 3, 9],
    ];
    let bad = from_triangles(&pts, &tris);
    let clean = from_triangles(&pts, &tris[..2]);
    let s = small(true);
    let mut b = Bounds::EMPTY;
    for p in &good {
        b.add(*p);
    }
    let cam = auto_camera(&b, &s);
    let st = Style::palette(0, &clean.as_ref());
    let (with_bad, stats) = render(s, &cam, &[(&bad, st)]);
    assert_eq!(
        stats.skipped_degenerate, 3,
        "repeated vertex, collinear, index 9"
    );
    assert_eq!(stats.skipped_non_finite, 1);
    assert_eq!(stats.triangles, 2);
    assert_eq!(stats.warning_lines().len(), 2);
    let (without, _) = render(s, &cam, &[(&clean, st)]);
    // The NaN vertex changes the bounds the ground is placed from only if it were used:
    // it is not (non-finite points are ignored), so the images are identical.
    assert_eq!(with_bad, without);
}

#[test]
fn shared_edges_leave_no_cracks() {
    // A fan of thin triangles around a centre, ground off: every pixel well inside the
    // disc must be object-coloured at one sample per pixel.
    let k = 97;
    let mut pts = vec![[0.0, 0.0, 0.0]];
    for i in 0..k {
        let a = std::f64::consts::TAU * i as f64 / k as f64;
        pts.push([a.cos(), a.sin(), 0.0]);
    }
    let tris: Vec<[u32; 3]> = (0..k as u32)
        .map(|i| [0, 1 + i, 1 + (i + 1) % k as u32])
        .collect();
    let fan = from_triangles(&pts, &tris);
    let cam = Camera {
        eye: [0.0, 0.0, 3.0],
        target: [0.0, 0.0, 0.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 50.0,
    };
    let s = Settings {
        width: 120,
        height: 120,
        supersample: 1,
        ground: false,
    };
    let st = Style {
        color: [1.0, 0.0, 0.0],
        back_color: [1.0, 0.0, 0.0],
        ..Style::palette(0, &fan.as_ref())
    };
    let (im, _) = render(s, &cam, &[(&fan, st)]);
    let radius_px = 60.0 / (25f64.to_radians().tan() * 3.0);
    for y in 0..120u32 {
        for x in 0..120u32 {
            let r = ((x as f64 + 0.5 - 60.0).powi(2) + (y as f64 + 0.5 - 60.0).powi(2)).sqrt();
            if r < 0.95 * radius_px {
                let c = im.pixel(x, y);
                assert!(c[1] < 40 && c[0] > 100, "crack at ({x}, {y}): {c:?}");
            }
        }
    }
}

#[test]
fn result_does_not_depend_on_thread_count() {
    let meshes = golden_scene();
    let st = styles(&meshes);
    let s = Settings::default();
    let b = largestep::render::preview::bounds_of(&meshes);
    let cam = auto_camera(&b, &s);
    let pairs: Vec<(&Mesh, Style)> = meshes.iter().zip(st).collect();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let three = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap();
    let (a, _) = one.install(|| render(s, &cam, &pairs));
    let (b, _) = three.install(|| render(s, &cam, &pairs));
    assert!(a == b, "images differ between 1 and 3 threads");
}

#[test]
fn bad_cameras_are_errors_or_documented_fallbacks() {
    let sphere = uv_sphere([0.0; 3], 1.0, 8, 12);
    let st = Style::palette(0, &sphere.as_ref());
    let objects = [Object {
        mesh: sphere.as_ref(),
        style: st,
    }];
    let mut r = Renderer::new(small(true)).unwrap();
    let mut im = Image::new(1, 1);
    let mut cam = Camera {
        eye: [0.0, 0.0, 4.0],
        target: [0.0, 0.0, 4.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 40.0,
    };
    let e = r
        .render(&cam, &Bounds::EMPTY, &objects, &mut im)
        .unwrap_err();
    assert!(
        matches!(e, RenderError::Camera(_)) && e.to_string().contains("same point"),
        "{e}"
    );
    cam.target = [0.0; 3];
    cam.fov_y_deg = 0.0;
    assert!(r.render(&cam, &Bounds::EMPTY, &objects, &mut im).is_err());
    cam.fov_y_deg = 40.0;
    cam.eye[0] = f64::NAN;
    assert!(r.render(&cam, &Bounds::EMPTY, &objects, &mut im).is_err());
    cam.eye[0] = 0.0;
    // Zero up and up along the view: a fallback axis, with a warning.
    for up in [[0.0; 3], [0.0, 0.0, -2.0]] {
        cam.up = up;
        let stats = r.render(&cam, &Bounds::EMPTY, &objects, &mut im).unwrap();
        assert_eq!(stats.warnings.len(), 1, "{:?}", stats.warnings);
        assert!(stats.warnings[0].contains("up vector"));
    }
    // Inside the sphere: its inner faces fill the view, clipped at the near plane.
    cam = Camera {
        eye: [0.0, 0.0, 0.2],
        target: [0.0, 0.0, -1.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 60.0,
    };
    let stats = r.render(&cam, &Bounds::EMPTY, &objects, &mut im).unwrap();
    assert!(stats.warnings.is_empty());
    let c = im.pixel(80, 48);
    // The inside is the back face: the back colour (reddish), not the sky (bluish grey).
    assert!(c[0] > c[1] + 20 && c[0] > c[2] + 20, "centre {c:?}");
    // Triangles beside the eye straddle the near plane and are cut, not dropped.
    assert!(stats.clipped_near > 0);
    // Bad sizes.
    assert!(Renderer::new(Settings {
        width: 0,
        ..small(true)
    })
    .is_err());
    assert!(Renderer::new(Settings {
        supersample: 9,
        ..small(true)
    })
    .is_err());
}

#[test]
fn obj_reader_reports_the_line() {
    let ok = parse_obj(
        "# c\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nf 1/1 2/1 3/1 4/1\nl -4 -3 -2\n",
        "a.obj",
    )
    .unwrap();
    assert_eq!(&ok.triangles[..], &[[0, 1, 2], [0, 2, 3]]);
    assert_eq!(&ok.segments[..], &[[0, 1], [1, 2]]);
    assert_eq!(
        ok.positions,
        vec![0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0]
    );
    let cases = [
        ("v 0 0 0\nv 1 x 0\n", 2, "`x` is not a number"),
        ("v 0 0\n", 1, "needs 3 coordinates"),
        ("v 0 0 0\nv 1 0 0\nf 1 2\n", 3, "at least 3 vertices"),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\nv 2 2 2\n",
            4,
            "vertex 7 does not exist",
        ),
        ("v 0 0 0\nf 0 1 1\n", 2, "start at 1"),
        ("v 0 0 0\nf -3 1 1\n", 2, "before the first vertex"),
        ("v 0 0 0\nbogus 1\n", 2, "unknown statement `bogus`"),
        ("v 0 0 0\nf a b c\n", 2, "not a vertex index"),
    ];
    for (text, line, msg) in cases {
        let e = parse_obj(text, "bad.obj").unwrap_err();
        assert_eq!(e.line, line, "{e}");
        assert!(
            e.to_string().contains(msg) && e.to_string().starts_with(&format!("bad.obj:{line}:")),
            "{e}"
        );
    }
}

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("largestep-render-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn preview_writes_frames_animation_and_sheet() {
    let dir = temp_dir("preview");
    let frames: Vec<Mesh> = (0..5)
        .map(|k| uv_sphere([0.0, 1.0 - 0.2 * k as f64, 0.0], 0.3, 6, 8))
        .collect();
    let settings = PreviewSettings {
        render: Settings {
            width: 96,
            height: 64,
            supersample: 1,
            ground: true,
        },
        animation_max_width: 48,
        sheet_frames: 4,
        sheet_cols: 2,
        ..Default::default()
    };
    let mut calls = 0;
    let summary = write_preview(&dir, &frames, &[], &settings, &mut |_, _| calls += 1).unwrap();
    assert_eq!((summary.frames, calls), (5, 5));
    for k in 0..5 {
        let im = read_png(&dir.join(format!("frame_{k:05}.png"))).unwrap();
        assert_eq!((im.width, im.height), (96, 64));
    }
    let gif = std::fs::read(dir.join("animation.gif")).unwrap();
    assert_eq!(&gif[..6], b"GIF89a");
    assert_eq!(u16::from_le_bytes([gif[6], gif[7]]), 48);
    let sheet = read_png(&dir.join("contact-sheet.png")).unwrap();
    assert_eq!(
        (sheet.width, sheet.height),
        (2 * 48 + 3 * 4, 2 * 32 + 3 * 4)
    );
    // The same frames read back from OBJ files render the same.
    let objdir = temp_dir("objs");
    for (k, f) in frames.iter().enumerate() {
        let path = objdir.join(format!("frame_{k:05}.obj"));
        largestep::io::write_atomically(&path, |w| largestep::io::write_obj(w, f.as_ref(), "t"))
            .unwrap();
    }
    let back = load_frames(&objdir, u64::MAX).unwrap();
    assert_eq!(back.len(), 5);
    assert!(
        std::sync::Arc::ptr_eq(&back[0].triangles, &back[4].triangles),
        "topology shared"
    );
    let again = temp_dir("again");
    write_preview(&again, &back, &[], &settings, &mut |_, _| {}).unwrap();
    assert_eq!(
        std::fs::read(dir.join("frame_00003.png")).unwrap(),
        std::fs::read(again.join("frame_00003.png")).unwrap()
    );
    // A malformed frame: the file and the line.
    std::fs::write(objdir.join("frame_00002.obj"), "v 0 0 0\nv 1 1\n").unwrap();
    let e = load_frames(&objdir, u64::MAX).unwrap_err().to_string();
    assert!(e.contains("frame_00002.obj") && e.contains("line 2"), "{e}");
    // An empty folder.
    let e = load_frames(&temp_dir("empty"), u64::MAX)
        .unwrap_err()
        .to_string();
    assert!(e.contains("no .obj files"), "{e}");
}

#[test]
fn auto_camera_keeps_the_eye_outside_and_everything_in_view() {
    let b = Bounds {
        min: [-3.0, 0.0, -1.0],
        max: [5.0, 2.0, 1.0],
    };
    for (az, el) in [(0.0, 0.0), (35.0, 22.0), (180.0, 80.0), (-90.0, -30.0)] {
        let c = Camera::auto(&b, 16.0 / 9.0, az, el, 40.0, [0.0, 1.0, 0.0]).unwrap();
        let d: f64 = (0..3)
            .map(|k| (c.eye[k] - b.center()[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(
            d > b.radius(),
            "eye inside the bounding sphere at az {az}, el {el}"
        );
    }
    assert!(Camera::auto(&b, 1.0, 0.0, 90.0, 40.0, [0.0, 1.0, 0.0]).is_err());
    assert!(Camera::auto(&b, 1.0, 0.0, 0.0, 40.0, [0.0; 3]).is_err());
    let _ = CameraSpec::default();
}

#[test]
fn key_light_comes_from_above() {
    // A sphere seen from the side: its upper half faces the key light and must be brighter
    // than its lower half (this caught normals computed in the mirrored camera frame).
    let sphere = uv_sphere([0.0; 3], 1.0, 24, 32);
    let cam = Camera {
        eye: [0.0, 0.0, 6.0],
        target: [0.0; 3],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 40.0,
    };
    let s = Settings {
        ground: false,
        ..small(false)
    };
    let (im, _) = render(s, &cam, &[(&sphere, Style::palette(0, &sphere.as_ref()))]);
    let lum = |p: [u8; 3]| p.iter().map(|&c| c as u32).sum::<u32>();
    let (top, bottom) = (im.pixel(80, 48 - 20), im.pixel(80, 48 + 20));
    assert!(lum(top) > lum(bottom) + 60, "top {top:?} bottom {bottom:?}");
}

#[test]
fn plots_are_written_as_svg_and_png_and_survive_bad_points() {
    use largestep::plot::{write_panels, Curve, Panel, Scale};
    let dir = temp_dir("plots");
    let curve = |label: &str, pts: Vec<(f64, f64)>| Curve {
        label: label.into(),
        points: pts,
        dashed: false,
    };
    let panels = vec![
        Panel {
            title: "log-log".into(),
            x_label: "run time (s)".into(),
            y_label: "error".into(),
            scale: Scale::LogLog,
            curves: vec![
                (
                    0,
                    curve(
                        "a",
                        (1..8)
                            .map(|k| (10f64.powi(-k), 10f64.powi(-2 * k)))
                            .collect(),
                    ),
                ),
                // Zero, negative and NaN points cannot go on log axes: left out.
                (
                    1,
                    curve(
                        "bad",
                        vec![(0.0, 1.0), (-1.0, 2.0), (f64::NAN, 1.0), (1e-3, 1e-2)],
                    ),
                ),
                (2, curve("empty", vec![])),
                // A prediction: dashed, drawn under the measurements.
                (
                    0,
                    Curve {
                        dashed: true,
                        ..curve("predicted", vec![(1e-7, 1e-14), (1e-1, 1e-2)])
                    },
                ),
            ],
        },
        Panel {
            title: "linear".into(),
            x_label: "t".into(),
            y_label: "E".into(),
            scale: Scale::Linear,
            curves: vec![(0, curve("flat", vec![(0.0, 3.0), (1.0, 3.0)]))],
        },
        Panel {
            title: "no data".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            scale: Scale::Linear,
            curves: vec![],
        },
    ];
    let stem = dir.join("p");
    write_panels(&stem, &panels, 2, (300, 200)).unwrap();
    let svg = std::fs::read_to_string(stem.with_extension("svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("log-log") && svg.contains("no data"));
    let png = read_png(&stem.with_extension("png")).unwrap();
    // Each panel is as wide as asked plus the widest legend, which sits beside the plot.
    assert_eq!(png.height, 400);
    assert!(png.width > 600 && png.width < 900, "width {}", png.width);
    assert!(svg.contains("predicted"));
    // Drawn, not blank: white background, dark text and axes.
    let dark = png
        .rgb
        .chunks(3)
        .filter(|p| p.iter().all(|&c| c < 80))
        .count();
    let white = png
        .rgb
        .chunks(3)
        .filter(|p| p.iter().all(|&c| c == 255))
        .count();
    assert!(dark > 500 && white > 100_000, "dark {dark}, white {white}");
}

#[test]
fn obstacle_shapes_are_closed_outward_and_on_their_surfaces() {
    use largestep::shapes::{capsule, cuboid};
    // Signed volume by the divergence theorem: positive (outward winding) and exact.
    let volume = |m: &largestep::io::Mesh| {
        let n = m.positions.len() / 3;
        let p = |i: u32| largestep::kernels::get3(&m.positions, n, i as usize);
        m.triangles
            .iter()
            .map(|t| {
                let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
                (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0]))
                    / 6.0
            })
            .sum::<f64>()
    };
    let b = cuboid([-0.5, 0.0, -1.0], [0.5, 0.75, 1.0]);
    assert_eq!(b.triangles.len(), 12);
    assert!(
        (volume(&b) - 1.5).abs() < 1e-12,
        "box volume {}",
        volume(&b)
    );
    // Every capsule vertex is within the radius of the segment (the end spheres' inner
    // halves lie inside), and the outermost ones on it.
    let (a, e, r) = ([0.0, 0.0, 0.0], [1.0, 0.5, 0.0], 0.2);
    let c = capsule(a, e, r, 16);
    let n = c.positions.len() / 3;
    let mut outermost = 0.0f64;
    for i in 0..n {
        let p = largestep::kernels::get3(&c.positions, n, i);
        let d = [e[0] - a[0], e[1] - a[1], e[2] - a[2]];
        let t = ((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1] + (p[2] - a[2]) * d[2])
            / (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        let t = t.clamp(0.0, 1.0);
        let q = [a[0] + t * d[0], a[1] + t * d[1], a[2] + t * d[2]];
        let dist = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
        assert!(dist <= r + 1e-12, "vertex {i} at {dist}");
        outermost = outermost.max(dist);
    }
    assert!((outermost - r).abs() < 1e-12);
}

/// Frames of a run that blew up (the last ones at 1e151 m, or not finite) do not break
/// the preview: the sane frames are rendered and framed on, the rest are left out with a
/// warning (issue 14: the camera used to fail on coordinates of 1e151).
#[test]
fn preview_frames_the_sane_frames_of_a_run_that_blew_up() {
    let sheet = wavy_sheet([0.0, 0.5, 0.0], 1.0, 8, 0.05);
    let mut frames = vec![sheet.clone(), sheet.clone()];
    for scale in [1e151, f64::INFINITY] {
        let mut m = sheet.clone();
        for p in &mut m.positions {
            *p *= scale;
        }
        frames.push(m);
    }
    let settings = PreviewSettings {
        render: small(true),
        ..PreviewSettings::default()
    };
    let dir = temp_dir("blown-preview");
    let s = write_preview(&dir, &frames, &[], &settings, &mut |_, _| {}).unwrap();
    assert!(dir.join("frame_00001.png").is_file());
    assert!(!dir.join("frame_00002.png").exists());
    assert!(
        s.warnings
            .iter()
            .any(|w| w.contains("frames 2 to 3 left out")),
        "{:?}",
        s.warnings
    );
}

#[test]
fn planes_are_drawn_as_the_faces_of_the_region_they_leave_free() {
    use largestep::collide::Obstacle;
    // The jello's world: a container [-2, 2]^3 and the inclined plane -x + y + z + 2 = 0.
    let mut obstacles: Vec<Obstacle> = Obstacle::container([-2.0; 3], [2.0; 3]).into();
    obstacles.push(Obstacle::plane([-1.0, 1.0, 1.0, 2.0]).unwrap());
    let m = Obstacle::plane_faces(&obstacles, ([-10.0; 3], [10.0; 3])).unwrap();
    let n = m.positions.len() / 3;
    let p = |i: u32| {
        let i = i as usize;
        [m.positions[i], m.positions[n + i], m.positions[2 * n + i]]
    };
    let planes: Vec<([f64; 3], f64)> = obstacles
        .iter()
        .map(|o| match o {
            Obstacle::Plane { normal, offset } => (*normal, *offset),
            _ => unreachable!(),
        })
        .collect();
    let side =
        |q: [f64; 3], (nn, d): ([f64; 3], f64)| nn[0] * q[0] + nn[1] * q[1] + nn[2] * q[2] + d;
    // Every corner lies in the free region, on at least one plane.
    for i in 0..n as u32 {
        let q = p(i);
        assert!(
            planes.iter().all(|&pl| side(q, pl) >= -1e-9),
            "{q:?} outside"
        );
        assert!(
            planes.iter().any(|&pl| side(q, pl).abs() < 1e-9),
            "{q:?} on no plane"
        );
    }
    // Each triangle lies on a plane and faces its free side (the renderer culls it when
    // the eye is behind the wall, leaving the outline).
    for t in m.triangles.iter() {
        let [a, b, c] = t.map(p);
        let e1 = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let e2 = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let cr = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let on = planes
            .iter()
            .find(|&&pl| [a, b, c].iter().all(|&q| side(q, pl).abs() < 1e-9))
            .expect("a triangle on a plane");
        let facing = cr[0] * on.0[0] + cr[1] * on.0[1] + cr[2] * on.0[2];
        assert!(facing > 0.0, "triangle {t:?} faces the solid side");
    }
    // All seven planes show a face, each outlined.
    let faces = planes
        .iter()
        .filter(|&&pl| {
            m.triangles
                .iter()
                .any(|t| t.iter().all(|&i| side(p(i), pl).abs() < 1e-9))
        })
        .count();
    assert_eq!(faces, 7);
    assert!(m.segments.len() >= 7 * 3);
    // The jello world file's scene draws them.
    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/jello-worlds/jello.w");
    if data.exists() {
        let scene = largestep::scene::Scene::load(&data).unwrap();
        let scenery = scene.scenery(([-3.0; 3], [3.0; 3]));
        // The cube starts on the plane's other side: the container's part there.
        let tris: usize = scenery.iter().map(|m| m.triangles.len()).sum();
        let segs: usize = scenery.iter().map(|m| m.segments.len()).sum();
        assert!(tris >= 8 && segs >= 12, "{tris} triangles, {segs} segments");
    }
}
