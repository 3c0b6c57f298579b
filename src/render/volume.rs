//! Pictures of grid frames ([`crate::simulation::GridRef`]): volume renderings of a 3-D
//! density (the ray caster of `largestep_kernels::volume`: trilinear sampling,
//! front-to-back compositing with early ray termination, empty-space skipping on 8^3
//! blocks, a piecewise-linear transfer function and single-scattering shadows), colour
//! maps of a 2-D density, and colour-mapped slices of speed and vorticity.

use super::camera::{Bounds, CameraSpec};
use super::RenderError;
use crate::io::Image;
use crate::simulation::{GridField, GridRef};
use largestep_kernels::volume::{self as kv, Transfer, View, Volume};
use rayon::prelude::*;

/// Cells per side of an empty-space skipping block.
pub const BLOCK: usize = 8;

/// How a 3-D density is rendered.
#[derive(Clone, Debug)]
pub struct VolumeSettings {
    /// Image width and height (pixels).
    pub width: u32,
    pub height: u32,
    /// The camera (auto-framed on the grid's box by default).
    pub camera: CameraSpec,
    /// Density to colour and extinction per cell.
    pub transfer: Transfer,
    /// March step (cells).
    pub step: f32,
    /// Direction towards the light (world, any length).
    pub to_light: [f64; 3],
    /// Ambient light (fraction).
    pub ambient: f32,
}

impl Default for VolumeSettings {
    /// 1280 x 720, smoke grey-white with a warm light from above and the side.
    fn default() -> Self {
        VolumeSettings {
            width: 1280,
            height: 720,
            camera: CameraSpec::default(),
            transfer: Transfer {
                points: vec![
                    (0.01, [0.9, 0.92, 0.95], 0.0),
                    (0.2, [0.95, 0.95, 0.97], 0.15),
                    (1.0, [1.0, 1.0, 1.0], 0.6),
                ],
            },
            step: 1.0,
            to_light: [0.4, 1.0, 0.3],
            ambient: 0.25,
        }
    }
}

/// The scratch of the volume renderer, kept between frames (no allocation once sized).
#[derive(Clone, Debug, Default)]
pub struct VolumeRenderer {
    density: Vec<f32>,
    light: Vec<f32>,
    solid: Vec<f32>,
    blocks: Vec<f32>,
    clearance: Vec<u8>,
    /// Scratch of the clearance: one line of blocks.
    line: Vec<u8>,
    solid_blocks: Vec<f32>,
    /// The solid mask and grid size that `solid` and `solid_blocks` were made from:
    /// obstacles seldom move, so a frame with the same mask reuses them (comparing the
    /// masks reads 2 MB at 128^3; converting and taking block maxima read 10 MB and
    /// write 8 MB).
    solid_of: (Vec<bool>, [usize; 3]),
    slab: Vec<f32>,
}

/// The smoke density of a grid frame, if it has one.
pub fn density_of<'a>(g: &GridRef<'a>) -> Option<&'a [f64]> {
    g.fields.iter().find_map(|f| match f {
        GridField::Density(d) => Some(*d),
        _ => None,
    })
}

impl VolumeRenderer {
    /// Renders the grid's density into `image` (resized to the settings): a volume
    /// rendering in 3-D, a colour map in 2-D (then the camera is not used).
    pub fn render(
        &mut self,
        g: &GridRef<'_>,
        s: &VolumeSettings,
        image: &mut Image,
    ) -> Result<(), RenderError> {
        let cells: usize = g.cells.iter().product();
        let Some(rho) = density_of(g) else {
            // Nothing to render: the speed map stands in.
            *image = slice(g, Slice::Speed, s.width.max(s.height));
            return Ok(());
        };
        if g.cells[2] == 1 {
            *image = field_image(g, rho, Map::Smoke, s.width.max(s.height), None);
            return Ok(());
        }
        let n = g.cells;
        to_f32(&mut self.density, rho, n[0], |&x| x as f32);
        let nb = n.map(|c| c.div_ceil(BLOCK));
        self.blocks.resize(nb.iter().product(), 0.0);
        kv::block_max(&mut self.blocks, &self.density, n, BLOCK);
        let sol = g.solid.unwrap_or(&[]);
        if self.solid_of.1 != n || self.solid_of.0 != sol {
            self.solid.clear();
            self.solid_blocks.clear();
            if !sol.is_empty() {
                to_f32(&mut self.solid, sol, n[0], |&b| f32::from(u8::from(b)));
                self.solid_blocks.resize(self.blocks.len(), 0.0);
                kv::block_max(&mut self.solid_blocks, &self.solid, n, BLOCK);
            }
            self.solid_of.0.clear();
            self.solid_of.0.extend_from_slice(sol);
            self.solid_of.1 = n;
        }
        let to_light = crate::kernels::v3::length_and_unit(s.to_light)
            .map_or([0.0, 1.0, 0.0], |u| u.1)
            .map(|x| x as f32);
        self.light.resize(cells, 0.0);
        let most = n[0] * n[1] * n[2] / n.iter().min().copied().unwrap_or(1).max(1);
        self.slab.resize(2 * most, 0.0);
        kv::light_transmittance(
            &mut self.light,
            &mut self.slab,
            &self.density,
            n,
            to_light,
            &s.transfer,
        );
        // The camera frames the grid's box (m); the ray caster works in cell units.
        let mut bounds = Bounds::EMPTY;
        bounds.add(g.origin);
        bounds.add(std::array::from_fn(|a| g.origin[a] + n[a] as f64 * g.h));
        let settings = super::Settings {
            width: s.width,
            height: s.height,
            supersample: 1,
            ground: false,
        };
        let camera = super::preview::camera_for(&s.camera, &bounds, &settings)?;
        let mut warnings = Vec::new();
        let basis = camera.basis(&mut warnings)?;
        let cell = |p: [f64; 3]| -> [f32; 3] {
            std::array::from_fn(|a| ((p[a] - g.origin[a]) / g.h) as f32)
        };
        let f32v = |v: [f64; 3]| v.map(|x| x as f32);
        let mut view = View {
            width: s.width as usize,
            height: s.height as usize,
            eye: cell(basis.eye),
            right: f32v(basis.right),
            up: f32v(basis.up),
            forward: f32v(basis.forward),
            tan_half_fov: basis.tan_half_fov as f32,
            step: s.step,
            transfer: s.transfer.clone(),
            light_colour: [1.0, 0.97, 0.9],
            ambient: s.ambient,
            to_light,
            solid_colour: [0.55, 0.45, 0.35],
            background: [[0.08, 0.09, 0.11], [0.22, 0.26, 0.32]],
            table: Vec::new(),
            table_scale: 1.0,
            clear_until: 0.0,
        };
        view.tabulate();
        self.clearance.resize(self.blocks.len(), 0);
        self.line.resize(nb.iter().copied().max().unwrap_or(0), 0);
        kv::clearance(
            &mut self.clearance,
            &mut self.line,
            &self.blocks,
            &self.solid_blocks,
            nb,
            &view,
        );
        let vol = Volume {
            n,
            density: &self.density,
            light: &self.light,
            solid: &self.solid,
            block: BLOCK,
            blocks: nb,
            clearance: &self.clearance,
            block_solid: &self.solid_blocks,
        };
        if image.width != s.width || image.height != s.height {
            *image = Image::new(s.width, s.height);
        }
        kv::render(&mut image.rgb, &vol, &view);
        Ok(())
    }
}

/// `out` = `f` of each of `src`, converted in parallel a row of `row` values at a time.
fn to_f32<T: Sync>(out: &mut Vec<f32>, src: &[T], row: usize, f: impl Fn(&T) -> f32 + Sync) {
    out.resize(src.len(), 0.0);
    out.par_chunks_mut(row.max(1))
        .zip(src.par_chunks(row.max(1)))
        .for_each(|(o, r)| {
            for (o, x) in o.iter_mut().zip(r) {
                *o = f(x);
            }
        });
}

/// Which slice picture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Slice {
    /// Speed (the velocity's magnitude).
    Speed,
    /// Vorticity (signed in 2-D).
    Vorticity,
}

impl Slice {
    /// Its file stem.
    pub fn name(&self) -> &'static str {
        match self {
            Slice::Speed => "speed",
            Slice::Vorticity => "vorticity",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Map {
    /// Sequential, dark blue to yellow (viridis-like).
    Sequential,
    /// Diverging, blue through white to red, symmetric about zero.
    Diverging,
    /// Smoke: black to white.
    Smoke,
}

/// Colour of `t` in [0, 1] (diverging: -1 to 1) on a map.
fn colour(map: Map, t: f64) -> [u8; 3] {
    let lerp = |stops: &[[f64; 3]], t: f64| -> [u8; 3] {
        let t = t.clamp(0.0, 1.0) * (stops.len() - 1) as f64;
        let i = (t as usize).min(stops.len() - 2);
        let f = t - i as f64;
        std::array::from_fn(|k| {
            ((stops[i][k] + f * (stops[i + 1][k] - stops[i][k])) * 255.0).round() as u8
        })
    };
    match map {
        Map::Sequential => lerp(
            &[
                [0.267, 0.005, 0.329],
                [0.230, 0.322, 0.546],
                [0.128, 0.567, 0.551],
                [0.369, 0.789, 0.383],
                [0.993, 0.906, 0.144],
            ],
            t,
        ),
        Map::Diverging => lerp(
            &[
                [0.02, 0.19, 0.38],
                [0.40, 0.66, 0.81],
                [0.97, 0.97, 0.97],
                [0.94, 0.54, 0.38],
                [0.40, 0.0, 0.12],
            ],
            0.5 * (t + 1.0),
        ),
        Map::Smoke => lerp(&[[0.05, 0.05, 0.08], [0.55, 0.55, 0.6], [1.0, 1.0, 1.0]], t),
    }
}

/// A picture of `values` (one per cell) on the grid's middle z slice, `size` pixels on
/// its longer side (nearest cell per pixel, y up), solid cells grey. `scale`: the value
/// mapped to the map's end (default the largest magnitude).
fn field_image(g: &GridRef<'_>, values: &[f64], map: Map, size: u32, scale: Option<f64>) -> Image {
    let [nx, ny, nz] = g.cells;
    let k = nz / 2;
    let slab = &values[k * nx * ny..(k + 1) * nx * ny];
    let top = scale.unwrap_or_else(|| {
        slab.iter()
            .filter(|v| v.is_finite())
            .fold(0.0f64, |m, v| m.max(v.abs()))
    });
    let top = if top > 0.0 { top } else { 1.0 };
    let px = (size as f64 / nx.max(ny) as f64).max(1.0);
    let (w, h) = (
        ((nx as f64) * px).round() as u32,
        ((ny as f64) * px).round() as u32,
    );
    let mut im = Image::new(w.max(1), h.max(1));
    for y in 0..im.height {
        let j = ny - 1 - ((y as f64 / px) as usize).min(ny - 1);
        for x in 0..im.width {
            let i = ((x as f64 / px) as usize).min(nx - 1);
            let c = i + nx * j;
            let rgb = if g.solid.is_some_and(|s| s[k * nx * ny + c]) {
                [110, 100, 90]
            } else {
                colour(map, slab[c] / top)
            };
            let o = 3 * (y as usize * im.width as usize + x as usize);
            im.rgb[o..o + 3].copy_from_slice(&rgb);
        }
    }
    im
}

/// The slice picture of a grid frame: speed on a sequential map, vorticity on a
/// diverging one (2-D; its magnitude on the sequential map in 3-D), `size` pixels on the
/// longer side.
pub fn slice(g: &GridRef<'_>, which: Slice, size: u32) -> Image {
    let cells: usize = g.cells.iter().product();
    for f in &g.fields {
        match (which, f) {
            (Slice::Speed, GridField::Speed(v)) => {
                let speed: Vec<f64> = (0..cells)
                    .map(|c| {
                        (v[c] * v[c]
                            + v[cells + c] * v[cells + c]
                            + v[2 * cells + c] * v[2 * cells + c])
                            .sqrt()
                    })
                    .collect();
                return field_image(g, &speed, Map::Sequential, size, None);
            }
            (Slice::Vorticity, GridField::Vorticity(v)) => {
                let map = if g.cells[2] == 1 {
                    Map::Diverging
                } else {
                    Map::Sequential
                };
                return field_image(g, v, map, size, None);
            }
            _ => {}
        }
    }
    Image::new(1, 1)
}
