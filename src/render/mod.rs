//! Headless preview renderer: meshes, springs and particles to RGB images on the CPU.
//!
//! The algorithm, per frame:
//! 1. **Setup** (serial, O(vertices + primitives)): vertices go to camera space relative to
//!    the eye (f64, then f32), smooth vertex normals are area-weighted face normals,
//!    triangles are clipped against the near plane, projected and set up with exact
//!    fixed-point edge functions (`kernels::render`); springs become screen-aligned quads
//!    (two triangles), particles become sphere impostors (discs). Each triangle's planar
//!    shadow (projected along the key light onto the ground) is set up too.
//! 2. **Binning**: every primitive goes into the list of each 32 x 32-pixel tile its bounding
//!    box touches, in input order.
//! 3. **Tiles** (parallel over rows of tiles, `rayon`): a tile's G-buffer (inverse depth,
//!    primitive id, barycentrics) at `supersample^2` samples per pixel stays in cache while
//!    its primitives are drawn, then each sample is shaded (Lambert plus Blinn-Phong with
//!    exponent 32, a fill light from the camera, two-sided: a back face gets its normal
//!    flipped and its own colour) or, where empty, gets the ground (grid lines, planar
//!    shadow, fading with distance) or the sky gradient; samples are averaged per pixel
//!    (supersampling anti-aliasing) and written as 8-bit RGB with gamma 2.
//!
//! Results do not depend on the number of threads: every tile is drawn by one task, in
//! input order. Bad data never panics: a triangle with a non-finite vertex or zero area is
//! skipped and counted in [`RenderStats`]; an empty scene gives the ground and sky.
//!
//! The camera: a camera inside an object sees that object's inner faces (triangles are
//! clipped at a near plane 1/1000 of the scene radius in front of the eye); auto-framing
//! ([`Camera::auto`]) always puts the eye outside the scene's bounds. An up vector that is
//! zero or parallel to the view direction is replaced by the world axis most perpendicular
//! to the view, with a warning in [`RenderStats::warnings`].

mod camera;
pub mod preview;
pub mod volume;

pub use camera::{
    Basis, Bounds, Camera, CameraSpec, DEFAULT_AZIMUTH_DEG, DEFAULT_ELEVATION_DEG, DEFAULT_FOV_DEG,
};

use crate::io::{Image, MeshRef};
use camera::{cross, dot, normalize, sub};
use largestep_kernels::render::{
    pow32, raster_cover, raster_disc, raster_tri, Disc, FixedTri, ScreenTri, Tile, NO_PRIM,
};
use rayon::prelude::*;

/// Rendering failures (bad settings or camera; files in [`preview`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// The camera cannot be used.
    #[error("camera: {0}")]
    Camera(String),
    /// Image settings out of range.
    #[error("render settings: {0}")]
    Settings(String),
    /// Reading frames or writing images failed.
    #[error("{path}: {}", crate::io::clip(message, crate::io::MAX_MESSAGE))]
    File {
        /// The file.
        path: String,
        /// What went wrong (with the line for malformed input).
        message: String,
    },
}

/// How an object looks. Colours are linear RGB in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Style {
    /// Front-face (and particle) colour.
    pub color: [f32; 3],
    /// Back-face colour (two-sided lighting, for cloth).
    pub back_color: [f32; 3],
    /// Colour of springs (line segments) and wireframe edges.
    pub line_color: [f32; 3],
    /// Draw triangle edges over the shading.
    pub wireframe: bool,
    /// Draw every vertex as a shaded sphere.
    pub points: bool,
    /// Sphere radius (m); 0 picks 0.2 of the mean segment length, or 1/150 of the
    /// scene radius without segments.
    pub point_radius: f64,
    /// Leave out triangles that face away from the eye (the far side of a solid, or a
    /// wall seen from behind, whose outline still shows where it is).
    pub cull_back: bool,
}

impl Style {
    /// The default look of object `i`: colours from a fixed palette; particles drawn
    /// when the mesh has no triangles.
    pub fn palette(i: usize, mesh: &MeshRef<'_>) -> Style {
        const FRONT: [[f32; 3]; 4] = [
            [0.75, 0.22, 0.08],
            [0.10, 0.28, 0.70],
            [0.15, 0.50, 0.18],
            [0.65, 0.45, 0.06],
        ];
        let color = FRONT[i % FRONT.len()];
        Style {
            color,
            back_color: color.map(|c| 0.2 + 0.5 * c),
            line_color: [0.08, 0.08, 0.1],
            wireframe: false,
            points: mesh.triangles.is_empty(),
            point_radius: 0.0,
            cull_back: false,
        }
    }
}

/// One thing to draw.
#[derive(Clone, Copy, Debug)]
pub struct Object<'a> {
    /// Positions, triangles and segments.
    pub mesh: MeshRef<'a>,
    /// Its look.
    pub style: Style,
}

/// Image size and quality.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings {
    /// Width (pixels), 1..=16384.
    pub width: u32,
    /// Height (pixels), 1..=16384.
    pub height: u32,
    /// Samples per pixel along each axis (1..=4): 2 means 2 x 2 supersampling.
    pub supersample: u32,
    /// Draw the ground plane (grid and shadows) under the scene.
    pub ground: bool,
}

impl Default for Settings {
    /// 1280 x 720, 2 x 2 supersampling, ground on.
    fn default() -> Self {
        Settings {
            width: 1280,
            height: 720,
            supersample: 2,
            ground: true,
        }
    }
}

impl Settings {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), RenderError> {
        if !(1..=16384).contains(&self.width) || !(1..=16384).contains(&self.height) {
            return Err(RenderError::Settings(format!(
                "image size must be 1..=16384 pixels each way, got {} x {}",
                self.width, self.height
            )));
        }
        if !(1..=4).contains(&self.supersample) {
            return Err(RenderError::Settings(format!(
                "supersample must be 1..=4, got {}",
                self.supersample
            )));
        }
        Ok(())
    }
}

/// What a frame drew and what it skipped.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RenderStats {
    /// Triangles drawn (after near-plane clipping, edge-on ones excluded).
    pub triangles: usize,
    /// Segments drawn.
    pub segments: usize,
    /// Particles drawn.
    pub points: usize,
    /// Triangles skipped for zero area or a vertex index out of range.
    pub skipped_degenerate: usize,
    /// Triangles, segments and particles skipped for a non-finite vertex.
    pub skipped_non_finite: usize,
    /// Triangles cut by the near plane.
    pub clipped_near: usize,
    /// Camera fallbacks taken.
    pub warnings: Vec<String>,
}

impl RenderStats {
    /// One line per warning and per kind of skipped primitive.
    pub fn warning_lines(&self) -> Vec<String> {
        let mut w = self.warnings.clone();
        if self.skipped_degenerate > 0 {
            w.push(format!(
                "skipped {} degenerate triangle(s) (zero area or bad index)",
                self.skipped_degenerate
            ));
        }
        if self.skipped_non_finite > 0 {
            w.push(format!(
                "skipped {} primitive(s) with a non-finite vertex",
                self.skipped_non_finite
            ));
        }
        w
    }
}

/// Pixels per tile side.
const TILE_PX: usize = 32;
const KIND_SHIFT: u32 = 30;
const INDEX_MASK: u32 = (1 << KIND_SHIFT) - 1;
const KIND_TRI: u32 = 0;
const KIND_DISC: u32 = 1;
const KIND_SHADOW: u32 = 2;

#[derive(Clone, Copy)]
struct TriRec {
    fixed: FixedTri,
    object: u32,
    /// Global vertex indices (for smooth normals).
    v: [u32; 3],
    /// Inverse view depths of the vertices (perspective-correct interpolation).
    q: [f32; 3],
    face_n: [f32; 3],
    /// Distance (samples) from each vertex to the opposite edge, for wireframe.
    alt: [f32; 3],
    smooth: bool,
    line: bool,
}

#[derive(Clone, Copy)]
struct DiscRec {
    disc: Disc,
    object: u32,
}

/// Frame constants shared by setup and shading (f32, relative to the eye).
#[derive(Clone, Copy)]
struct View {
    right: [f32; 3],
    up: [f32; 3],
    forward: [f32; 3],
    world_up: [f32; 3],
    /// Eye height above the ground along `world_up` (m); ground drawn when > 0.
    eye_height: f32,
    light: [f32; 3],
    /// Focal length (samples).
    focal: f32,
    /// Image centre (samples).
    cx: f32,
    cy: f32,
    near: f32,
    /// Ground axes (unit, in the plane) and the eye's coordinates along them.
    ground_axes: [[f32; 3]; 2],
    eye_on_ground: [f32; 2],
    /// `1 / distance` at which the ground has faded into the sky (1/m).
    inv_fade: f32,
    ground: bool,
    ss: usize,
    inv_focal: f32,
    inv_grid: f32,
    /// `1 / (focal * grid)`: a pixel's size (samples times `ss`) in grid steps per metre.
    inv_focal_grid: f32,
}

impl View {
    /// The ray through sample position `(x, y)`, scaled so its forward component is 1:
    /// the ray parameter is then the view depth.
    #[inline(always)]
    fn ray(&self, x: f32, y: f32) -> [f32; 3] {
        let a = (x - self.cx) * self.inv_focal;
        let b = (self.cy - y) * self.inv_focal;
        axpy3(b, self.up, axpy3(a, self.right, self.forward))
    }

    /// View depth at which ray `d` meets the ground, infinite when it does not.
    #[inline(always)]
    fn ground_t(&self, d: [f32; 3]) -> f32 {
        let du = dot3(d, self.world_up);
        if self.ground && du < 0.0 {
            self.eye_height / -du
        } else {
            f32::INFINITY
        }
    }
}

/// The renderer: settings plus buffers reused from frame to frame.
pub struct Renderer {
    settings: Settings,
    view_pos: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    finite: Vec<bool>,
    tris: Vec<TriRec>,
    discs: Vec<DiscRec>,
    shadows: Vec<FixedTri>,
    bins: Vec<Vec<u32>>,
}

fn f32x3(a: [f64; 3]) -> [f32; 3] {
    a.map(|c| c as f32)
}
fn dot3(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn sub3(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn cross3(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn axpy3(a: f32, x: [f32; 3], y: [f32; 3]) -> [f32; 3] {
    [y[0] + a * x[0], y[1] + a * x[1], y[2] + a * x[2]]
}
fn unit3(a: [f32; 3]) -> [f32; 3] {
    let n2 = dot3(a, a);
    if n2 > 0.0 {
        let inv = 1.0 / n2.sqrt();
        a.map(|c| c * inv)
    } else {
        a
    }
}

/// Linear RGB in [0, 1] to 8 bits with gamma 2 (`sqrt`) by a 4096-entry table, eight
/// values at a time: per-pixel square roots and scalar saturating float-to-integer casts
/// were a fifth of the frame time.
fn encode_row(out: &mut [u8], rgb: &[f32], lut: &[u8; GAMMA_LUT]) {
    use wide::f32x8;
    debug_assert_eq!(out.len(), rgb.len());
    let scale = f32x8::splat((GAMMA_LUT - 1) as f32);
    let mut chunks = rgb.chunks_exact(8);
    let mut o = 0;
    for c in &mut chunks {
        let v = f32x8::from(<[f32; 8]>::try_from(c).expect("8 values"));
        let i = (v.fast_max(f32x8::ZERO).fast_min(f32x8::ONE) * scale)
            .round_int()
            .to_array();
        // Masking keeps a NaN (converted to i32::MIN) in range and drops bounds checks.
        for (dst, k) in out[o..o + 8].iter_mut().zip(i) {
            *dst = lut[k as usize & (GAMMA_LUT - 1)];
        }
        o += 8;
    }
    for (dst, c) in out[o..].iter_mut().zip(chunks.remainder()) {
        *dst = lut[(c.clamp(0.0, 1.0) * (GAMMA_LUT - 1) as f32).round() as usize & (GAMMA_LUT - 1)];
    }
}

const GAMMA_LUT: usize = 4096;

fn gamma_lut() -> &'static [u8; GAMMA_LUT] {
    static LUT: std::sync::OnceLock<[u8; GAMMA_LUT]> = std::sync::OnceLock::new();
    LUT.get_or_init(|| {
        std::array::from_fn(|i| ((i as f32 / (GAMMA_LUT - 1) as f32).sqrt() * 255.0 + 0.5) as u8)
    })
}

/// Largest of 1, 2 or 5 times a power of ten not above `x`.
fn nice_step(x: f64) -> f64 {
    let p = 10f64.powf(x.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|s| *s <= x)
        .unwrap_or(p)
}

impl Renderer {
    /// A renderer for images of the given settings.
    pub fn new(settings: Settings) -> Result<Renderer, RenderError> {
        settings.validate()?;
        Ok(Renderer {
            settings,
            view_pos: Vec::new(),
            normals: Vec::new(),
            finite: Vec::new(),
            tris: Vec::new(),
            discs: Vec::new(),
            shadows: Vec::new(),
            bins: Vec::new(),
        })
    }

    /// The settings.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Renders `objects` seen by `camera` into `image` (resized to the settings' size).
    /// `scene_bounds` places the ground (at the bottom of the bounds along the camera's up
    /// direction), sizes its grid and the near plane; pass the bounds of a whole animation
    /// so they stay put from frame to frame, or [`Bounds::EMPTY`] for the objects' own.
    pub fn render(
        &mut self,
        camera: &Camera,
        scene_bounds: &Bounds,
        objects: &[Object<'_>],
        image: &mut Image,
    ) -> Result<RenderStats, RenderError> {
        let mut stats = RenderStats::default();
        let basis = camera.basis(&mut stats.warnings)?;
        let mut bounds = *scene_bounds;
        if bounds.is_empty() {
            for o in objects {
                bounds.add_positions(o.mesh.positions);
            }
        }
        let bounds = bounds.or_unit();
        let view = self.view(&basis, &bounds);
        self.setup(&basis, &view, &bounds, objects, &mut stats);
        self.bin(&view);
        let s = self.settings;
        if image.width != s.width || image.height != s.height {
            *image = Image::new(s.width, s.height);
        }
        let tiles_x = (s.width as usize).div_ceil(TILE_PX);
        let band_bytes = 3 * TILE_PX * s.width as usize;
        let this = &*self;
        image
            .rgb
            .par_chunks_mut(band_bytes)
            .enumerate()
            .for_each_init(
                || TileBuffers::new(TILE_PX * view.ss),
                |buf, (ty, band)| {
                    for tx in 0..tiles_x {
                        this.draw_tile(&view, objects, buf, tx, ty, tiles_x, band);
                    }
                },
            );
        Ok(stats)
    }

    fn view(&self, b: &Basis, bounds: &Bounds) -> View {
        let s = self.settings;
        let ss = s.supersample as usize;
        let (w, h) = (
            (s.width as usize * ss) as f32,
            (s.height as usize * ss) as f32,
        );
        let r = bounds.radius();
        let up = b.world_up;
        // Ground: the lowest corner of the bounds along `up`, a hair below it so a
        // resting object does not fight the ground for depth.
        let lowest = bounds.lowest_along(up);
        let ground_level = lowest - 2e-3 * r;
        let eye_height = dot(b.eye, up) - ground_level;
        // Key light from above, behind the viewer's left shoulder: shadows fall away
        // from the camera and to the right.
        let flat = |v: [f64; 3]| {
            let d = dot(v, up);
            normalize(sub(v, up.map(|c| c * d))).unwrap_or([0.0; 3])
        };
        let (rf, ff) = (flat(b.right), flat(b.forward));
        let light = normalize(std::array::from_fn(|k| {
            1.3 * up[k] - 0.5 * rf[k] - 0.45 * ff[k]
        }))
        .unwrap_or(up);
        let a0 = normalize(cross(
            up,
            if up[0].abs() < 0.9 {
                [1.0, 0.0, 0.0]
            } else {
                [0.0, 0.0, 1.0]
            },
        ))
        .expect("not parallel");
        let a1 = cross(up, a0);
        let grid = nice_step(r / 3.0);
        View {
            right: f32x3(b.right),
            up: f32x3(b.up),
            forward: f32x3(b.forward),
            world_up: f32x3(up),
            eye_height: eye_height as f32,
            light: f32x3(light),
            focal: 0.5 * h / b.tan_half_fov as f32,
            cx: 0.5 * w,
            cy: 0.5 * h,
            near: (1e-3 * r) as f32,
            ground_axes: [f32x3(a0), f32x3(a1)],
            eye_on_ground: [dot(b.eye, a0) as f32, dot(b.eye, a1) as f32],
            inv_fade: (1.0 / (8.0 * r)) as f32,
            ground: s.ground && eye_height > 0.0,
            ss,
            inv_focal: (2.0 * b.tan_half_fov) as f32 / h,
            inv_grid: (1.0 / grid) as f32,
            inv_focal_grid: (2.0 * b.tan_half_fov * ss as f64 / grid) as f32 / h,
        }
    }

    fn project(v: &View, p: [f32; 3]) -> [f32; 2] {
        [v.cx + v.focal * p[0] / p[2], v.cy - v.focal * p[1] / p[2]]
    }

    fn setup(
        &mut self,
        b: &Basis,
        v: &View,
        bounds: &Bounds,
        objects: &[Object<'_>],
        stats: &mut RenderStats,
    ) {
        self.view_pos.clear();
        self.normals.clear();
        self.finite.clear();
        self.tris.clear();
        self.discs.clear();
        self.shadows.clear();
        for (oi, o) in objects.iter().enumerate() {
            let m = &o.mesh;
            let n = m.positions.len() / 3;
            let base = self.view_pos.len();
            for i in 0..n {
                let p = largestep_kernels::get3(m.positions, n, i);
                let d = sub(p, b.eye);
                let vp = [dot(d, b.right), dot(d, b.up), dot(d, b.forward)];
                let ok = p.iter().all(|c| c.is_finite());
                self.finite.push(ok);
                self.view_pos.push(if ok { f32x3(vp) } else { [0.0; 3] });
                self.normals.push([0.0; 3]);
            }
            // Triangles: validity, face normals, smooth normals.
            let tri_start = self.tris.len();
            for t in m.triangles {
                if t.iter().any(|&k| k as usize >= n) {
                    stats.skipped_degenerate += 1;
                    continue;
                }
                let g = t.map(|k| base + k as usize);
                if g.iter().any(|&k| !self.finite[k]) {
                    stats.skipped_non_finite += 1;
                    continue;
                }
                let p = g.map(|k| self.view_pos[k]);
                let c = cross3(sub3(p[1], p[0]), sub3(p[2], p[0]));
                let scale = dot3(sub3(p[1], p[0]), sub3(p[1], p[0]))
                    + dot3(sub3(p[2], p[0]), sub3(p[2], p[0]));
                // NaN-safe: a non-finite area counts as degenerate too.
                if dot3(c, c).sqrt().partial_cmp(&(1e-7 * scale))
                    != Some(std::cmp::Ordering::Greater)
                {
                    stats.skipped_degenerate += 1;
                    continue;
                }
                // Camera space (right, up, forward) is left-handed: a cross product there
                // is the mirror image of the world's, hence the minus.
                let c = self.view_world(v, c).map(|x| -x);
                if o.style.cull_back {
                    let centroid = [0, 1, 2].map(|a| (p[0][a] + p[1][a] + p[2][a]) / 3.0);
                    if dot3(c, self.view_world(v, centroid)) > 0.0 {
                        continue;
                    }
                }
                for &k in &g {
                    self.normals[k] = axpy3(1.0, c, self.normals[k]);
                }
                self.push_tri(v, oi as u32, g, p, unit3(c), stats);
            }
            for k in base..self.normals.len() {
                self.normals[k] = unit3(self.normals[k]);
            }
            // Planar shadows of this object's triangles.
            if v.ground {
                let lu = dot3(v.light, v.world_up);
                for r in tri_start..self.tris.len() {
                    let rec = self.tris[r];
                    if !rec.smooth {
                        continue;
                    }
                    let mut ok = true;
                    let st = ScreenTri {
                        p: rec.v.map(|k| {
                            let p = self.view_world(v, self.view_pos[k as usize]);
                            let h = dot3(p, v.world_up) + v.eye_height;
                            let s = axpy3(-h / lu, v.light, p);
                            let sv = [dot3(s, v.right), dot3(s, v.up), dot3(s, v.forward)];
                            ok &= sv[2] > v.near;
                            Self::project(v, sv)
                        }),
                        q: [1.0; 3],
                    };
                    if let (true, Some(f)) = (ok, FixedTri::new(&st)) {
                        self.shadows.push(f);
                    }
                }
            }
            // Springs as thin quads, particles as spheres.
            let mean_seg = if m.segments.is_empty() {
                0.0
            } else {
                m.segments
                    .iter()
                    .filter(|s| s.iter().all(|&k| (k as usize) < n))
                    .map(|s| {
                        let d = sub3(
                            self.view_pos[base + s[1] as usize],
                            self.view_pos[base + s[0] as usize],
                        );
                        dot3(d, d).sqrt()
                    })
                    .filter(|l| l.is_finite())
                    .sum::<f32>()
                    / m.segments.len() as f32
            };
            let half_width = 0.9 * v.ss as f32;
            for s in m.segments {
                if s.iter().any(|&k| k as usize >= n) {
                    stats.skipped_degenerate += 1;
                    continue;
                }
                let g = s.map(|k| base + k as usize);
                if g.iter().any(|&k| !self.finite[k]) {
                    stats.skipped_non_finite += 1;
                    continue;
                }
                let (mut a, mut c) = (self.view_pos[g[0]], self.view_pos[g[1]]);
                if a[2] < v.near && c[2] < v.near {
                    continue;
                }
                if a[2] < v.near || c[2] < v.near {
                    let t = (v.near - a[2]) / (c[2] - a[2]);
                    let cut = axpy3(t, sub3(c, a), a);
                    if a[2] < v.near {
                        a = cut;
                    } else {
                        c = cut;
                    }
                }
                let (pa, pc) = (Self::project(v, a), Self::project(v, c));
                let d = [pc[0] - pa[0], pc[1] - pa[1]];
                let len = (d[0] * d[0] + d[1] * d[1]).sqrt();
                if len.is_nan() || len <= 1e-3 {
                    continue;
                }
                let nrm = [-d[1] / len * half_width, d[0] / len * half_width];
                let (qa, qc) = (1.0 / a[2], 1.0 / c[2]);
                let corner = |p: [f32; 2], sgn: f32| [p[0] + sgn * nrm[0], p[1] + sgn * nrm[1]];
                let quads = [
                    (
                        [corner(pa, 1.0), corner(pa, -1.0), corner(pc, -1.0)],
                        [qa, qa, qc],
                    ),
                    (
                        [corner(pa, 1.0), corner(pc, -1.0), corner(pc, 1.0)],
                        [qa, qc, qc],
                    ),
                ];
                for (p, q) in quads {
                    if let Some(fixed) = FixedTri::new(&ScreenTri { p, q }) {
                        self.tris.push(TriRec {
                            fixed,
                            object: oi as u32,
                            v: [0; 3],
                            q,
                            face_n: [0.0; 3],
                            alt: [0.0; 3],
                            smooth: false,
                            line: true,
                        });
                    }
                }
                stats.segments += 1;
            }
            if o.style.points {
                let radius = if o.style.point_radius > 0.0 {
                    o.style.point_radius as f32
                } else if mean_seg > 0.0 {
                    0.3 * mean_seg
                } else {
                    (bounds.radius() / 150.0) as f32
                };
                for k in base..base + n {
                    if !self.finite[k] {
                        stats.skipped_non_finite += 1;
                        continue;
                    }
                    let p = self.view_pos[k];
                    if p[2] - radius <= v.near {
                        continue;
                    }
                    if v.ground {
                        self.push_disc_shadow(v, p, radius);
                    }
                    let c = Self::project(v, p);
                    let r = (v.focal * radius / p[2]).max(0.8 * v.ss as f32);
                    if c.iter().all(|x| x.abs() < 1e7) {
                        self.discs.push(DiscRec {
                            disc: Disc {
                                c,
                                r,
                                z: p[2],
                                radius,
                            },
                            object: oi as u32,
                        });
                        stats.points += 1;
                    }
                }
            }
        }
        stats.triangles = self.tris.iter().filter(|t| !t.line).count();
    }

    /// The shadow of a sphere (centre `p` in camera space, radius in m) on the ground: an
    /// octagon round the centre's projection along the key light.
    fn push_disc_shadow(&mut self, v: &View, p: [f32; 3], radius: f32) {
        let w = self.view_world(v, p);
        let h = dot3(w, v.world_up) + v.eye_height;
        let c = axpy3(-h / dot3(v.light, v.world_up), v.light, w);
        let corner = |k: usize| {
            let a = std::f32::consts::TAU * k as f32 / 8.0;
            let q = axpy3(
                radius * a.cos(),
                v.ground_axes[0],
                axpy3(radius * a.sin(), v.ground_axes[1], c),
            );
            [dot3(q, v.right), dot3(q, v.up), dot3(q, v.forward)]
        };
        let centre = [dot3(c, v.right), dot3(c, v.up), dot3(c, v.forward)];
        for k in 0..8 {
            let tri = [centre, corner(k), corner(k + 1)];
            if tri.iter().all(|x| x[2] > v.near) {
                let st = ScreenTri {
                    p: tri.map(|x| Self::project(v, x)),
                    q: [1.0; 3],
                };
                if let Some(f) = FixedTri::new(&st) {
                    self.shadows.push(f);
                }
            }
        }
    }

    /// A camera-space point back in world axes (still relative to the eye).
    fn view_world(&self, v: &View, p: [f32; 3]) -> [f32; 3] {
        let w = axpy3(p[0], v.right, [0.0; 3]);
        let w = axpy3(p[1], v.up, w);
        axpy3(p[2], v.forward, w)
    }

    /// Clips a valid triangle at the near plane and records the pieces.
    #[allow(clippy::too_many_arguments)]
    fn push_tri(
        &mut self,
        v: &View,
        object: u32,
        g: [usize; 3],
        p: [[f32; 3]; 3],
        face_n: [f32; 3],
        stats: &mut RenderStats,
    ) {
        let inside = p.map(|x| x[2] >= v.near);
        if inside.iter().all(|&b| b) {
            let st = ScreenTri {
                p: p.map(|x| Self::project(v, x)),
                q: p.map(|x| 1.0 / x[2]),
            };
            if let Some(fixed) = FixedTri::new(&st) {
                self.tris.push(TriRec {
                    fixed,
                    object,
                    v: g.map(|k| k as u32),
                    q: st.q,
                    face_n,
                    alt: altitudes(&st.p),
                    smooth: true,
                    line: false,
                });
            }
            return;
        }
        if inside.iter().all(|&b| !b) {
            return;
        }
        // Sutherland-Hodgman against z = near: 3 or 4 vertices, drawn as a fan with the
        // flat face normal.
        stats.clipped_near += 1;
        let mut poly: Vec<[f32; 3]> = Vec::with_capacity(4);
        for i in 0..3 {
            let (a, c) = (p[i], p[(i + 1) % 3]);
            if a[2] >= v.near {
                poly.push(a);
            }
            if (a[2] >= v.near) != (c[2] >= v.near) {
                let t = (v.near - a[2]) / (c[2] - a[2]);
                poly.push(axpy3(t, sub3(c, a), a));
            }
        }
        for k in 1..poly.len() - 1 {
            let tri = [poly[0], poly[k], poly[k + 1]];
            let st = ScreenTri {
                p: tri.map(|x| Self::project(v, x)),
                q: tri.map(|x| 1.0 / x[2]),
            };
            if let Some(fixed) = FixedTri::new(&st) {
                self.tris.push(TriRec {
                    fixed,
                    object,
                    v: [0; 3],
                    q: st.q,
                    face_n,
                    alt: altitudes(&st.p),
                    smooth: false,
                    line: false,
                });
            }
        }
    }

    fn bin(&mut self, v: &View) {
        let s = self.settings;
        let (tx, ty) = (
            (s.width as usize).div_ceil(TILE_PX),
            (s.height as usize).div_ceil(TILE_PX),
        );
        self.bins.resize_with(tx * ty, Vec::new);
        self.bins.truncate(tx * ty);
        for b in &mut self.bins {
            b.clear();
        }
        let ts = (TILE_PX * v.ss) as i32;
        let put = |bb: [i32; 4], id: u32, bins: &mut Vec<Vec<u32>>| {
            let x0 = (bb[0].max(0) / ts) as usize;
            let y0 = (bb[1].max(0) / ts) as usize;
            if bb[2] <= 0 || bb[3] <= 0 {
                return;
            }
            let x1 = (((bb[2] - 1) / ts) as usize).min(tx - 1);
            let y1 = (((bb[3] - 1) / ts) as usize).min(ty - 1);
            for y in y0..=y1.min(ty - 1) {
                for x in x0..=x1 {
                    bins[y * tx + x].push(id);
                }
            }
        };
        // Shadows first: they only mark a mask, and drawing them before the geometry
        // keeps every bin in a fixed order.
        for (i, f) in self.shadows.iter().enumerate() {
            put(f.bbox, KIND_SHADOW << KIND_SHIFT | i as u32, &mut self.bins);
        }
        for (i, t) in self.tris.iter().enumerate() {
            put(
                t.fixed.bbox,
                KIND_TRI << KIND_SHIFT | i as u32,
                &mut self.bins,
            );
        }
        for (i, d) in self.discs.iter().enumerate() {
            put(
                d.disc.bbox(),
                KIND_DISC << KIND_SHIFT | i as u32,
                &mut self.bins,
            );
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn draw_tile(
        &self,
        v: &View,
        objects: &[Object<'_>],
        buf: &mut TileBuffers,
        tx: usize,
        ty: usize,
        tiles_x: usize,
        band: &mut [u8],
    ) {
        let s = self.settings;
        let ss = v.ss;
        let side = TILE_PX * ss;
        let (x0, y0) = ((tx * side) as i32, (ty * side) as i32);
        buf.clear();
        {
            let mut tile = Tile {
                x0,
                y0,
                w: side,
                h: side,
                depth: &mut buf.depth,
                prim: &mut buf.prim,
                attr: &mut buf.attr,
            };
            for &id in &self.bins[ty * tiles_x + tx] {
                let i = (id & INDEX_MASK) as usize;
                match id >> KIND_SHIFT {
                    KIND_TRI => raster_tri(&mut tile, &self.tris[i].fixed, id),
                    KIND_DISC => raster_disc(&mut tile, &self.discs[i].disc, id),
                    _ => raster_cover(&mut buf.shadow, x0, y0, side, side, &self.shadows[i]),
                }
            }
        }
        let width = s.width as usize;
        let px0 = tx * TILE_PX;
        let pw = TILE_PX.min(width - px0);
        let ph = TILE_PX.min(band.len() / (3 * width));
        let lut = gamma_lut();
        let mut idx = [0usize; 16];
        let mut bg = [Background::default(); TILE_PX];
        let mut row = [0f32; 3 * TILE_PX];
        // A tile no primitive touches is ground and sky only (no shadow either).
        let empty_tile = self.bins[ty * tiles_x + tx].is_empty();
        for py in 0..ph {
            // The ground and sky of the whole pixel row at once (SIMD); pixels that turn
            // out covered waste that work, which is cheaper than branching per pixel.
            let cy = y0 as f32 + ((py * ss) as f32 + 0.5 * ss as f32);
            let cx0 = x0 as f32 + 0.5 * ss as f32;
            background_row(v, cx0, ss as f32, cy, &mut bg);
            for px in 0..pw {
                let c = if empty_tile {
                    bg[px].shaded(0.0)
                } else {
                    for sy in 0..ss {
                        for sx in 0..ss {
                            idx[sy * ss + sx] = (py * ss + sy) * side + px * ss + sx;
                        }
                    }
                    let cx = x0 as f32 + ((px * ss) as f32 + 0.5 * ss as f32);
                    self.shade_pixel(
                        v,
                        objects,
                        buf,
                        &idx[..ss * ss],
                        &bg[px],
                        [cx, cy],
                        [x0 + (px * ss) as i32, y0 + (py * ss) as i32],
                    )
                };
                row[3 * px..3 * px + 3].copy_from_slice(&c);
            }
            let o = 3 * (py * width + px0);
            encode_row(&mut band[o..o + 3 * pw], &row[..3 * pw], lut);
        }
    }

    /// The colour of one pixel from its samples `idx` (tile indices), its ground and sky,
    /// its centre and its first sample's position (samples).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn shade_pixel(
        &self,
        v: &View,
        objects: &[Object<'_>],
        buf: &TileBuffers,
        idx: &[usize],
        bg: &Background,
        centre: [f32; 2],
        corner: [i32; 2],
    ) -> [f32; 3] {
        let n = idx.len() as f32;
        let ss = v.ss;
        let first = buf.prim[idx[0]];
        let uniform = idx.iter().all(|&i| buf.prim[i] == first);
        if uniform && first == NO_PRIM {
            let shadow: u32 = idx.iter().map(|&i| buf.shadow[i] as u32).sum();
            return bg.shaded(shadow as f32 / n);
        }
        if uniform {
            // One primitive covers the whole pixel: barycentrics and depth are affine in
            // screen space, so their mean over the samples is their value at the centre,
            // and one shading serves all samples.
            let d = v.ray(centre[0], centre[1]);
            let mut attr = [0.0f32; 2];
            let mut q = 0.0;
            for &i in idx {
                attr = [attr[0] + buf.attr[i][0], attr[1] + buf.attr[i][1]];
                q += buf.depth[i];
            }
            return if q / n * v.ground_t(d) >= 1.0 {
                self.shade_object(v, objects, first, attr.map(|a| a / n), d)
            } else {
                bg.shaded(0.0)
            };
        }
        // Edges: shade each covered sample; the ground and sky once for the pixel,
        // weighted by the samples that see them.
        let mut acc = [0f32; 3];
        let (mut empty, mut shadow) = (0u32, 0u32);
        for (k, &i) in idx.iter().enumerate() {
            let sx = (corner[0] + (k % ss) as i32) as f32 + 0.5;
            let sy = (corner[1] + (k / ss) as i32) as f32 + 0.5;
            let ds = v.ray(sx, sy);
            if buf.prim[i] != NO_PRIM && buf.depth[i] * v.ground_t(ds) >= 1.0 {
                let c = self.shade_object(v, objects, buf.prim[i], buf.attr[i], ds);
                acc = axpy3(1.0, c, acc);
            } else {
                empty += 1;
                shadow += buf.shadow[i] as u32;
            }
        }
        if empty > 0 {
            let c = bg.shaded(shadow as f32 / empty as f32);
            acc = axpy3(empty as f32, c, acc);
        }
        acc.map(|c| c / n)
    }

    fn shade_object(
        &self,
        v: &View,
        objects: &[Object<'_>],
        prim: u32,
        attr: [f32; 2],
        d: [f32; 3],
    ) -> [f32; 3] {
        let i = (prim & INDEX_MASK) as usize;
        let to_eye = unit3(d.map(|c| -c));
        if prim >> KIND_SHIFT == KIND_DISC {
            let rec = &self.discs[i];
            let [dx, dy] = attr;
            let nz = (1.0 - dx * dx - dy * dy).max(0.0).sqrt();
            let n = axpy3(
                -nz,
                v.forward,
                axpy3(-dy, v.up, axpy3(dx, v.right, [0.0; 3])),
            );
            return lit(v, objects[rec.object as usize].style.color, n, to_eye);
        }
        let rec = &self.tris[i];
        let style = &objects[rec.object as usize].style;
        if rec.line {
            return style.line_color;
        }
        let [b1, b2] = attr;
        let b0 = 1.0 - b1 - b2;
        let mut n = if rec.smooth {
            let l = [b0 * rec.q[0], b1 * rec.q[1], b2 * rec.q[2]];
            let mut n = [0.0; 3];
            for (lk, vk) in l.iter().zip(rec.v) {
                n = axpy3(*lk, self.normals[vk as usize], n);
            }
            let len2 = dot3(n, n);
            if len2 > 1e-12 {
                let inv = 1.0 / len2.sqrt();
                n.map(|c| c * inv)
            } else {
                rec.face_n
            }
        } else {
            rec.face_n
        };
        // The side seen is the face's, not the smooth normal's: a slope turning away
        // from the eye is still the same side of the cloth.
        let mut base = style.color;
        if dot3(rec.face_n, to_eye) < 0.0 {
            n = n.map(|c| -c);
            base = style.back_color;
        }
        let mut c = lit(v, base, n, to_eye);
        if style.wireframe {
            let dist = (b0 * rec.alt[0]).min(b1 * rec.alt[1]).min(b2 * rec.alt[2]);
            let w = 0.6 * v.ss as f32;
            if dist < w {
                let t = 0.85 * (1.0 - dist / w).min(1.0);
                c = [
                    c[0] + t * (style.line_color[0] - c[0]),
                    c[1] + t * (style.line_color[1] - c[1]),
                    c[2] + t * (style.line_color[2] - c[2]),
                ];
            }
        }
        c
    }
}

/// The ground and sky seen through one pixel, before its shadow: the colour is
/// `ground * (1 - 0.45 shadow) + sky` for the fraction `shadow` of the pixel's ground in
/// shadow (both already weighted by how far the ground has faded into the sky).
#[derive(Clone, Copy, Debug, Default)]
struct Background {
    ground: [f32; 3],
    sky: [f32; 3],
}

impl Background {
    #[inline(always)]
    fn shaded(&self, shadow: f32) -> [f32; 3] {
        axpy3(1.0 - 0.45 * shadow, self.ground, self.sky)
    }
}

/// Ground (grid lines box-filtered over the pixel footprint, fading with distance) and sky
/// for the pixel centres `(x0 + k * step, y)` (samples) of a row, eight at a time
/// (`wide::f32x8`).
fn background_row(v: &View, x0: f32, step: f32, y: f32, out: &mut [Background; TILE_PX]) {
    use wide::f32x8;
    let splat = f32x8::splat;
    let b = (v.cy - y) * v.inv_focal;
    // Ray d = forward + a right + b up, with a varying along the row.
    let base: [f32; 3] = std::array::from_fn(|k| v.forward[k] + b * v.up[k]);
    let lane = f32x8::from([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
    for chunk in 0..TILE_PX / 8 {
        let xs = splat(x0 + (8 * chunk) as f32 * step) + lane * splat(step);
        let a = (xs - splat(v.cx)) * splat(v.inv_focal);
        let d: [f32x8; 3] = std::array::from_fn(|k| splat(base[k]) + a * splat(v.right[k]));
        let dot = |p: &[f32x8; 3], q: [f32; 3]| {
            p[0] * splat(q[0]) + p[1] * splat(q[1]) + p[2] * splat(q[2])
        };
        let du = dot(&d, v.world_up);
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let sky_mix = (du / len).fast_max(f32x8::ZERO).fast_min(f32x8::ONE);
        let sky = [
            splat(0.78) - splat(0.40) * sky_mix,
            splat(0.81) - splat(0.32) * sky_mix,
            splat(0.86) - splat(0.22) * sky_mix,
        ];
        // Lanes looking up (or with the ground off) keep the sky; their ground terms may
        // be infinite or NaN and are masked out.
        let hits = if v.ground {
            du.simd_lt(f32x8::ZERO)
        } else {
            f32x8::ZERO.simd_lt(f32x8::ZERO)
        };
        let t = splat(v.eye_height) / -du;
        let dist = t * len;
        let foot = dist * splat(v.inv_focal_grid);
        let inv_foot = f32x8::ONE / foot;
        let mut line = f32x8::ZERO;
        for ax in 0..2 {
            let hit = t * dot(&d, v.ground_axes[ax]);
            let u = (hit + splat(v.eye_on_ground[ax])) * splat(v.inv_grid);
            let off = (u + splat(0.5) - (u + splat(0.5)).floor() - splat(0.5)).abs();
            let cover = (splat(1.25) - off * inv_foot)
                .fast_max(f32x8::ZERO)
                .fast_min(f32x8::ONE);
            line = line.fast_max(cover);
        }
        let fade = (f32x8::ONE - dist * splat(v.inv_fade))
            .fast_max(f32x8::ZERO)
            .fast_min(f32x8::ONE);
        let contrast = splat(0.45)
            * fade
            * (f32x8::ONE - (foot - splat(0.08)) * splat(5.0))
                .fast_max(f32x8::ZERO)
                .fast_min(f32x8::ONE);
        let k = f32x8::ONE - contrast * line;
        let alpha = (splat(1.6) * fade).fast_min(f32x8::ONE);
        let ground_rgb = [splat(0.62), splat(0.62), splat(0.60)];
        let g: [[f32; 8]; 3] = std::array::from_fn(|c| {
            hits.bitselect(alpha * ground_rgb[c] * k, f32x8::ZERO)
                .to_array()
        });
        let sk: [[f32; 8]; 3] = std::array::from_fn(|c| {
            hits.bitselect((f32x8::ONE - alpha) * sky[c], sky[c])
                .to_array()
        });
        for l in 0..8 {
            out[8 * chunk + l] = Background {
                ground: [g[0][l], g[1][l], g[2][l]],
                sky: [sk[0][l], sk[1][l], sk[2][l]],
            };
        }
    }
}

/// Lambert plus Blinn-Phong (exponent 32) under the key light, plus a fill light from the
/// camera and an ambient term; `n` and `to_eye` are unit vectors.
fn lit(v: &View, base: [f32; 3], n: [f32; 3], to_eye: [f32; 3]) -> [f32; 3] {
    let diffuse = dot3(n, v.light).max(0.0);
    let fill = dot3(n, to_eye).max(0.0);
    let h = unit3(axpy3(1.0, to_eye, v.light));
    let spec = 0.2 * pow32(dot3(n, h).max(0.0));
    let k = 0.12 + 0.6 * diffuse + 0.2 * fill;
    base.map(|c| c * k + spec)
}

/// Distance (samples) from each vertex of a screen triangle to the opposite edge.
fn altitudes(p: &[[f32; 2]; 3]) -> [f32; 3] {
    let area2 = ((p[1][0] - p[0][0]) * (p[2][1] - p[0][1])
        - (p[1][1] - p[0][1]) * (p[2][0] - p[0][0]))
        .abs();
    std::array::from_fn(|i| {
        let (a, c) = (p[(i + 1) % 3], p[(i + 2) % 3]);
        let len = ((c[0] - a[0]).powi(2) + (c[1] - a[1]).powi(2)).sqrt();
        if len > 0.0 {
            area2 / len
        } else {
            0.0
        }
    })
}

/// One task's tile G-buffer.
struct TileBuffers {
    depth: Vec<f32>,
    prim: Vec<u32>,
    attr: Vec<[f32; 2]>,
    shadow: Vec<u8>,
}

impl TileBuffers {
    fn new(side: usize) -> TileBuffers {
        let n = side * side;
        TileBuffers {
            depth: vec![0.0; n],
            prim: vec![NO_PRIM; n],
            attr: vec![[0.0; 2]; n],
            shadow: vec![0; n],
        }
    }
    fn clear(&mut self) {
        self.depth.fill(0.0);
        self.prim.fill(NO_PRIM);
        self.shadow.fill(0);
    }
}
