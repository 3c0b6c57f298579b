//! Previews of an animation: a PNG per frame, a looping GIF and a contact sheet.
//!
//! The camera and the ground stay put for the whole animation: both come from the union of
//! every frame's bounds. Each PNG is written atomically as soon as it is rendered, so a
//! failure later leaves the earlier frames valid.

use super::{Bounds, Camera, CameraSpec, Object, RenderError, Renderer, Settings, Style};
use crate::io::Image;
use crate::io::{read_obj, write_atomically, write_gif, write_png, Mesh};
use std::path::{Path, PathBuf};

/// What to render and write.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreviewSettings {
    /// Image size and quality of the PNG frames.
    pub render: Settings,
    /// The camera.
    pub camera: CameraSpec,
    /// Draw triangle edges.
    pub wireframe: bool,
    /// Simulated seconds between frames (the GIF plays in real time, at most 50 frames
    /// per second, the GIF format's limit).
    pub frame_interval: f64,
    /// Widest GIF frame (pixels): frames are shrunk by the smallest integer factor that fits.
    pub animation_max_width: u32,
    /// Most GIF frames: longer animations are subsampled evenly (and play at the same speed).
    pub animation_max_frames: usize,
    /// Frames on the contact sheet (evenly spaced, first and last included).
    pub sheet_frames: usize,
    /// Columns of the contact sheet.
    pub sheet_cols: u32,
}

impl Default for PreviewSettings {
    fn default() -> Self {
        PreviewSettings {
            render: Settings::default(),
            camera: CameraSpec::default(),
            wireframe: false,
            frame_interval: 1.0 / 30.0,
            animation_max_width: 480,
            animation_max_frames: 120,
            sheet_frames: 9,
            sheet_cols: 3,
        }
    }
}

/// What a preview wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct PreviewSummary {
    /// PNG frames written.
    pub frames: usize,
    /// The folder.
    pub dir: PathBuf,
    /// Warnings (camera fallbacks, skipped primitives), each once with the first frame
    /// it occurred in.
    pub warnings: Vec<String>,
    /// Wall time spent rendering (s), excluding encoding and writing.
    pub render_seconds: f64,
}

impl std::fmt::Display for PreviewSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "  preview        {} PNG frames, animation.gif and contact-sheet.png in {} ({:.1} ms/frame)",
            self.frames,
            self.dir.display(),
            1e3 * self.render_seconds / self.frames.max(1) as f64
        )?;
        for w in &self.warnings {
            write!(f, "\n  warning        {w}")?;
        }
        Ok(())
    }
}

/// Frame indices `0..n` chosen evenly, `m` of them (all when `n <= m`), first and last
/// included.
pub fn evenly(n: usize, m: usize) -> Vec<usize> {
    if n <= m || m < 2 {
        return (0..n.min(m.max(1))).collect();
    }
    (0..m)
        .map(|i| (i as f64 * (n - 1) as f64 / (m - 1) as f64).round() as usize)
        .collect()
}

fn file_err(path: &Path) -> impl FnOnce(std::io::Error) -> RenderError + '_ {
    move |e| RenderError::File {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}

/// The camera `spec` gives for `bounds` and `settings`.
pub fn camera_for(
    spec: &CameraSpec,
    bounds: &Bounds,
    settings: &Settings,
) -> Result<Camera, RenderError> {
    match *spec {
        CameraSpec::Fixed(c) => Ok(c),
        CameraSpec::Auto {
            azimuth_deg,
            elevation_deg,
            fov_y_deg,
            up,
        } => Camera::auto(
            bounds,
            settings.width as f64 / settings.height as f64,
            azimuth_deg,
            elevation_deg,
            fov_y_deg,
            up,
        ),
    }
}

/// How many leading frames are sane: finite bounds within a hundred times the first
/// frame's size (a run that blew up ends in frames no camera can frame).
fn sane_frames(frames: &[Mesh]) -> usize {
    let Some(first) = frames.first() else {
        return 0;
    };
    let mut b0 = Bounds::EMPTY;
    b0.add_positions(&first.positions);
    let (c0, r0) = (b0.or_unit().center(), b0.or_unit().radius());
    frames
        .iter()
        .position(|m| {
            let mut b = Bounds::EMPTY;
            b.add_positions(&m.positions);
            let b = b.or_unit();
            let shift = (0..3)
                .map(|k| (b.center()[k] - c0[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            !(b.radius() <= 100.0 * r0 && shift <= 100.0 * r0)
        })
        .unwrap_or(frames.len())
        .max(1)
}

/// The region a preview of `frames` shows, for cutting unbounded scenery (planes) to it:
/// the bounds of the frames it draws (see [`write_preview`]), grown by half their
/// diagonal on every side.
pub fn preview_region(frames: &[Mesh]) -> ([f64; 3], [f64; 3]) {
    let b = bounds_of(&frames[..sane_frames(frames)]).or_unit();
    let pad = b.radius();
    (b.min.map(|c| c - pad), b.max.map(|c| c + pad))
}

/// The union of the bounds of `frames`.
pub fn bounds_of(frames: &[Mesh]) -> Bounds {
    let mut b = Bounds::EMPTY;
    for m in frames {
        b.add_positions(&m.positions);
    }
    b
}

/// Renders `frames` into `dir`: `frame_NNNNN.png`, `animation.gif`, `contact-sheet.png`;
/// `scenery` (obstacles) is drawn in every frame, in a second colour, and framed by the
/// camera too. `progress(done, total)` is called after each frame.
pub fn write_preview(
    dir: &Path,
    frames: &[Mesh],
    scenery: &[Mesh],
    settings: &PreviewSettings,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<PreviewSummary, RenderError> {
    if frames.is_empty() {
        return Err(RenderError::File {
            path: dir.display().to_string(),
            message: "no frames to preview".into(),
        });
    }
    std::fs::create_dir_all(dir).map_err(file_err(dir))?;
    // An earlier, longer preview's frames would outlive this one's.
    crate::io::remove_stale(dir, |n| n.starts_with("frame_") && n.ends_with(".png"))
        .map_err(file_err(dir))?;
    let mut warnings: Vec<String> = Vec::new();
    // Frames of a run that went wrong: the ones whose model grew beyond a hundred times
    // its first frame's size are left out, and the camera frames the sane ones.
    let sane = sane_frames(frames);
    if sane < frames.len() {
        warnings.push(format!(
            "frames {sane} to {} left out: the model grew beyond 100 times its first frame's size",
            frames.len() - 1
        ));
    }
    let frames = &frames[..sane];
    let up = match settings.camera {
        CameraSpec::Auto { up, .. } => up,
        CameraSpec::Fixed(c) => c.up,
    };
    let up = crate::kernels::v3::length_and_unit(up).map_or([0.0, 1.0, 0.0], |u| u.1);
    // Scenery lying flat at or below the frames' lowest point, facing up, is a floor:
    // the preview's ground stands for it (and it would hide the ground's grid).
    let floor = bounds_of(frames).or_unit().lowest_along(up);
    let scenery: Vec<Mesh> = scenery
        .iter()
        .filter_map(|m| without_floor(m, up, floor))
        .collect();
    let scenery = &scenery[..];
    let mut bounds = bounds_of(frames);
    for m in scenery {
        bounds.add_positions(&m.positions);
    }
    // A zero up vector means no preference: against gravity's usual +y.
    let spec = match settings.camera {
        CameraSpec::Auto {
            azimuth_deg,
            elevation_deg,
            fov_y_deg,
            up: [0.0, 0.0, 0.0],
        } => {
            warnings.push("the up vector is zero: +y is used".into());
            CameraSpec::Auto {
                azimuth_deg,
                elevation_deg,
                fov_y_deg,
                up: [0.0, 1.0, 0.0],
            }
        }
        other => other,
    };
    let camera = camera_for(&spec, &bounds, &settings.render)?;
    let mut renderer = Renderer::new(settings.render)?;
    let shrink = settings
        .render
        .width
        .div_ceil(settings.animation_max_width.max(1))
        .max(1);
    let gif_frames = evenly(frames.len(), settings.animation_max_frames);
    let sheet = evenly(frames.len(), settings.sheet_frames);
    let mut gif_images = Vec::with_capacity(gif_frames.len());
    let mut sheet_images = Vec::with_capacity(sheet.len());
    let mut image = Image::new(1, 1);
    let mut render_seconds = 0.0;
    // The scenery first (the same every frame), then each frame's mesh.
    let mut objects: Vec<Object<'_>> = scenery
        .iter()
        .map(|m| Object {
            mesh: m.as_ref(),
            // A wall seen from behind shows as its outline.
            style: Style {
                cull_back: true,
                ..Style::palette(1, &m.as_ref())
            },
        })
        .collect();
    for (k, mesh) in frames.iter().enumerate() {
        let mut style = Style::palette(0, &mesh.as_ref());
        style.wireframe = settings.wireframe;
        objects.truncate(scenery.len());
        objects.push(Object {
            mesh: mesh.as_ref(),
            style,
        });
        let t0 = std::time::Instant::now();
        let stats = renderer.render(&camera, &bounds, &objects, &mut image)?;
        render_seconds += t0.elapsed().as_secs_f64();
        for w in stats.warning_lines() {
            if !warnings.iter().any(|x| x.ends_with(&w)) {
                warnings.push(format!("frame {k}: {w}"));
            }
        }
        let path = dir.join(format!("frame_{k:05}.png"));
        write_atomically(&path, |w| write_png(w, &image)).map_err(file_err(&path))?;
        if gif_frames.contains(&k) {
            gif_images.push(image.downsample(shrink));
        }
        if sheet.contains(&k) {
            sheet_images.push(image.clone());
        }
        progress(k + 1, frames.len());
    }
    write_animation(dir, &gif_images, &sheet_images, frames.len(), settings)?;
    Ok(PreviewSummary {
        frames: frames.len(),
        dir: dir.to_path_buf(),
        warnings,
        render_seconds,
    })
}

/// Writes `dir/animation.gif` from `gif_images` (evenly chosen among `frames` frames) and
/// `dir/contact-sheet.png` from `sheet_images`.
pub fn write_animation(
    dir: &Path,
    gif_images: &[Image],
    sheet_images: &[Image],
    frames: usize,
    settings: &PreviewSettings,
) -> Result<(), RenderError> {
    // GIF delays are whole hundredths of a second and at least 2 (browsers slow shorter
    // ones down): play in real time with the subsampled frames.
    let stride = frames as f64 / gif_images.len().max(1) as f64;
    let delay = (100.0 * settings.frame_interval * stride)
        .round()
        .clamp(2.0, 65535.0) as u16;
    let path = dir.join("animation.gif");
    write_atomically(&path, |w| write_gif(w, gif_images, delay)).map_err(file_err(&path))?;
    let path = dir.join("contact-sheet.png");
    let sheet_image = Image::contact_sheet(sheet_images, settings.sheet_cols, 4);
    write_atomically(&path, |w| write_png(w, &sheet_image)).map_err(file_err(&path))?;
    Ok(())
}

/// Reads every `*.obj` in `dir`, in name order (frames written by `largestep run` sort by
/// number). A malformed file is an error naming the file and line.
pub fn load_frames(dir: &Path, max_bytes: u64) -> Result<Vec<Mesh>, RenderError> {
    let entries = std::fs::read_dir(dir).map_err(file_err(dir))?;
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("obj")))
        .collect();
    paths.sort();
    if paths.is_empty() {
        return Err(RenderError::File {
            path: dir.display().to_string(),
            message: "no .obj files in this folder".into(),
        });
    }
    let mut frames: Vec<Mesh> = Vec::with_capacity(paths.len());
    for p in &paths {
        let mut m = read_obj(p, max_bytes).map_err(|e| RenderError::File {
            path: e.path.clone(),
            message: if e.line > 0 {
                format!("line {}: {}", e.line, e.message)
            } else {
                e.message.clone()
            },
        })?;
        // A finite vertex beyond any scene's size cannot be framed: it is the file's fault,
        // named here, not the camera's. (Non-finite vertices are skipped when drawing.)
        let n = m.positions.len() / 3;
        let huge = |i: usize| {
            largestep_kernels::get3(&m.positions, n, i)
                .iter()
                .any(|x| x.is_finite() && x.abs() > crate::validate::MAX_COORDINATE)
        };
        if let Some(i) = (0..n).find(|&i| huge(i)) {
            let line = crate::io::read_text(p, max_bytes)
                .ok()
                .and_then(|t| crate::io::obj_vertex_line(&t, i))
                .map_or(String::new(), |l| format!("line {l}: "));
            return Err(RenderError::File {
                path: p.display().to_string(),
                message: format!(
                    "{line}vertex {} at {:?} lies beyond 1e15 m: too far to frame",
                    i + 1,
                    largestep_kernels::get3(&m.positions, n, i)
                ),
            });
        }
        if let Some(prev) = frames.last() {
            m.share_topology(prev);
        }
        frames.push(m);
    }
    Ok(frames)
}

/// `m` without its triangles and segments that lie at or below `floor` along `up` (m)
/// with every vertex, within a millionth of the mesh's size: a floor, which the
/// preview's ground draws. Vertices left unused go too (they would widen the camera's
/// framing); `None` when nothing is left.
fn without_floor(m: &Mesh, up: [f64; 3], floor: f64) -> Option<Mesh> {
    let n = m.positions.len() / 3;
    let mut b = Bounds::EMPTY;
    b.add_positions(&m.positions);
    let tol = 1e-6 * b.or_unit().radius();
    let low = |i: u32| {
        (i as usize) < n && {
            let p = crate::kernels::get3(&m.positions, n, i as usize);
            p[0] * up[0] + p[1] * up[1] + p[2] * up[2] <= floor + tol
        }
    };
    let triangles: Vec<[u32; 3]> = m
        .triangles
        .iter()
        .filter(|t| !t.iter().all(|&i| low(i)))
        .copied()
        .collect();
    let segments: Vec<[u32; 2]> = m
        .segments
        .iter()
        .filter(|s| !s.iter().all(|&i| low(i)))
        .copied()
        .collect();
    if triangles.len() == m.triangles.len() && segments.len() == m.segments.len() {
        return Some(m.clone());
    }
    // Renumber the vertices still used, in order.
    let mut new_index = vec![u32::MAX; n];
    let used = triangles.iter().flatten().chain(segments.iter().flatten());
    for &i in used {
        if (i as usize) < n {
            new_index[i as usize] = 0;
        }
    }
    let mut kept = Vec::new();
    for (i, slot) in new_index.iter_mut().enumerate() {
        if *slot == 0 {
            *slot = kept.len() as u32;
            kept.push(crate::kernels::get3(&m.positions, n, i));
        }
    }
    if kept.is_empty() {
        return None;
    }
    let map = |i: u32| new_index.get(i as usize).copied().unwrap_or(u32::MAX);
    Some(Mesh {
        positions: crate::soa::Vec3s::from_aos(&kept).into_vec(),
        triangles: triangles
            .iter()
            .map(|t| t.map(map))
            .collect::<Vec<_>>()
            .into(),
        segments: segments
            .iter()
            .map(|s| s.map(map))
            .collect::<Vec<_>>()
            .into(),
    })
}
