//! Volume ray casting of a density grid (Levoy 1988; course notes section 18), in f32.
//!
//! - Each pixel's ray is clipped to the grid's box and marched at a fixed step; at each
//!   sample the density is interpolated trilinearly, mapped by a piecewise-linear transfer
//!   function to colour and extinction, and composited front to back,
//!   `C += T a c`, `T *= 1 - a` with `a = 1 - exp(-sigma step)`; the march stops when
//!   the transmittance T falls below [`EARLY_STOP`] (early ray termination).
//! - Empty-space skipping: a coarse grid holds each block's largest density; a ray in a
//!   block whose largest density the transfer function makes transparent jumps to the
//!   block's far side.
//! - Single-scattering shadows: the light reaching each cell, `exp(-sigma integral)`
//!   towards the light, is precomputed in one sweep along the light's dominant axis
//!   ([`light_transmittance`]), each slab sampling the previous one bilinearly; a sample
//!   is lit by it plus an ambient term.
//! - Solid cells (obstacles) are drawn as an opaque Lambert surface where their
//!   occupancy, interpolated, crosses one half, with the normal from its gradient.
//!
//! Everything is in cell units: the grid's cell `(i, j, k)` spans `[i, i + 1]` on x, and
//! so on. Rows are rendered in parallel; each pixel on its own, so the bits do not depend
//! on the thread count.

use rayon::prelude::*;

/// Transmittance below which a ray stops.
pub const EARLY_STOP: f32 = 0.01;

/// A piecewise-linear transfer function: `(density, rgb in [0, 1], extinction per cell)`
/// points in increasing density; below the first and above the last, their values.
#[derive(Clone, Debug, PartialEq)]
pub struct Transfer {
    /// The points.
    pub points: Vec<(f32, [f32; 3], f32)>,
}

impl Transfer {
    /// Colour and extinction (per cell) at density `d`.
    #[inline]
    pub fn at(&self, d: f32) -> ([f32; 3], f32) {
        let p = &self.points;
        if d <= p[0].0 {
            return (p[0].1, p[0].2);
        }
        for w in p.windows(2) {
            let (a, b) = (w[0], w[1]);
            if d <= b.0 {
                let t = if b.0 > a.0 {
                    (d - a.0) / (b.0 - a.0)
                } else {
                    1.0
                };
                let c = std::array::from_fn(|k| a.1[k] + t * (b.1[k] - a.1[k]));
                return (c, a.2 + t * (b.2 - a.2));
            }
        }
        let last = p[p.len() - 1];
        (last.1, last.2)
    }
}

/// A density grid with its acceleration and lighting grids.
#[derive(Clone, Copy, Debug)]
pub struct Volume<'a> {
    /// Cells along x, y, z.
    pub n: [usize; 3],
    /// Density per cell, x fastest.
    pub density: &'a [f32],
    /// Light reaching each cell, in [0, 1] ([`light_transmittance`]).
    pub light: &'a [f32],
    /// Occupancy of solid cells (1 solid, 0 free), or empty for none.
    pub solid: &'a [f32],
    /// Cells per side of a skipping block.
    pub block: usize,
    /// Blocks along x, y, z.
    pub blocks: [usize; 3],
    /// Largest density per block ([`block_max`]).
    pub block_max: &'a [f32],
    /// Largest solid occupancy per block (empty without solids): blocks with a solid are
    /// never skipped, and only they test for the solid surface.
    pub block_solid: &'a [f32],
}

/// The view and the shading.
#[derive(Clone, Debug)]
pub struct View {
    /// Image size (pixels).
    pub width: usize,
    /// Image height (pixels).
    pub height: usize,
    /// Eye (cell units).
    pub eye: [f32; 3],
    /// Right, up and forward, unit and orthogonal.
    pub right: [f32; 3],
    pub up: [f32; 3],
    pub forward: [f32; 3],
    /// `tan(fov_y / 2)`.
    pub tan_half_fov: f32,
    /// March step (cells).
    pub step: f32,
    /// The transfer function.
    pub transfer: Transfer,
    /// Light colour times intensity, and the ambient part.
    pub light_colour: [f32; 3],
    pub ambient: f32,
    /// Direction towards the light (unit), for the solids' shading.
    pub to_light: [f32; 3],
    /// Solid surface colour.
    pub solid_colour: [f32; 3],
    /// Background colour at the bottom and top of the image.
    pub background: [[f32; 3]; 2],
    /// The transfer function tabulated for the step ([`View::tabulate`]): per density
    /// bin, colour times light colour times opacity, and the opacity
    /// `1 - exp(-sigma step)`; the last entry covers every density beyond `table_max`.
    pub table: Vec<[f32; 4]>,
    /// Density of the table's last bin.
    pub table_max: f32,
    /// The least density with extinction: densities below it are clear.
    pub clear_until: f32,
}

/// Bins of the tabulated transfer function.
pub const TABLE_BINS: usize = 1024;

impl View {
    /// Tabulates the transfer function for the step and light colour (call after setting
    /// them): a table lookup and no `exp` per sample.
    pub fn tabulate(&mut self) {
        let p = &self.transfer.points;
        self.table_max = p[p.len() - 1].0.max(1e-6);
        self.table = (0..TABLE_BINS)
            .map(|i| {
                let d = self.table_max * i as f32 / (TABLE_BINS - 1) as f32;
                let (c, sigma) = self.transfer.at(d);
                let a = 1.0 - (-sigma.max(0.0) * self.step).exp();
                [
                    a * c[0] * self.light_colour[0],
                    a * c[1] * self.light_colour[1],
                    a * c[2] * self.light_colour[2],
                    a,
                ]
            })
            .collect();
        // The clear range: up to the first point with extinction (0 when the first has).
        self.clear_until = if p[0].2 > 0.0 {
            f32::NEG_INFINITY
        } else {
            p.iter()
                .take_while(|q| q.2 <= 0.0)
                .last()
                .map_or(0.0, |q| q.0)
        };
    }

    /// The tabulated `[r a, g a, b a, a]` at density `d` (nearest bin).
    #[inline(always)]
    pub fn lookup(&self, d: f32) -> [f32; 4] {
        let t = (d / self.table_max * (TABLE_BINS - 1) as f32).clamp(0.0, (TABLE_BINS - 1) as f32);
        self.table[(t + 0.5) as usize]
    }

    /// Whether every density up to `d` is clear (a block with that largest density can be
    /// skipped).
    #[inline(always)]
    pub fn clear_below(&self, d: f32) -> bool {
        d <= self.clear_until
    }
}

#[inline]
fn index(n: [usize; 3], i: usize, j: usize, k: usize) -> usize {
    i + n[0] * (j + n[1] * k)
}

/// Where a point falls among the cell centres: the lower corner cell, the strides to
/// its neighbours (0 along an axis of one cell) and the fractions, clamped to the grid.
/// One lookup serves every field sampled at the point.
#[derive(Clone, Copy, Debug)]
pub struct Corner {
    base: usize,
    d: [usize; 3],
    t: [f32; 3],
}

impl Corner {
    /// The corner of `p` (cell units; centres at `i + 1/2`) in a grid of `n` cells.
    #[inline(always)]
    pub fn new(n: [usize; 3], p: [f32; 3]) -> Corner {
        let mut i = [0usize; 3];
        let mut t = [0f32; 3];
        for a in 0..3 {
            let x = (p[a] - 0.5).clamp(0.0, (n[a] - 1) as f32);
            let c = (x as usize).min(n[a].saturating_sub(2));
            i[a] = c;
            t[a] = if n[a] > 1 { x - c as f32 } else { 0.0 };
        }
        Corner {
            base: index(n, i[0], i[1], i[2]),
            d: [
                usize::from(n[0] > 1),
                if n[1] > 1 { n[0] } else { 0 },
                if n[2] > 1 { n[0] * n[1] } else { 0 },
            ],
            t,
        }
    }

    /// The trilinear sample of the cell-centred field `f` there.
    #[inline(always)]
    pub fn sample(&self, f: &[f32]) -> f32 {
        let [dx, dy, dz] = self.d;
        let t = self.t;
        let l = |o: usize| f[self.base + o];
        let x00 = l(0) + t[0] * (l(dx) - l(0));
        let x10 = l(dy) + t[0] * (l(dy + dx) - l(dy));
        let x01 = l(dz) + t[0] * (l(dz + dx) - l(dz));
        let x11 = l(dz + dy) + t[0] * (l(dz + dy + dx) - l(dz + dy));
        let y0 = x00 + t[1] * (x10 - x00);
        let y1 = x01 + t[1] * (x11 - x01);
        y0 + t[2] * (y1 - y0)
    }
}

/// Trilinear sample of a cell-centred field at `p` (cell units; centres at `i + 1/2`),
/// clamped to the grid.
#[inline(always)]
pub fn trilinear(f: &[f32], n: [usize; 3], p: [f32; 3]) -> f32 {
    Corner::new(n, p).sample(f)
}

/// `out[block] = ` the largest density of each `block`-cube of cells (and its one-cell
/// rim, which trilinear samples inside the block reach).
pub fn block_max(out: &mut [f32], density: &[f32], n: [usize; 3], block: usize) {
    let nb = n.map(|c| c.div_ceil(block));
    assert_eq!(out.len(), nb[0] * nb[1] * nb[2], "one value per block");
    assert_eq!(density.len(), n[0] * n[1] * n[2], "one density per cell");
    out.par_iter_mut().enumerate().for_each(|(b, o)| {
        let q = [b % nb[0], (b / nb[0]) % nb[1], b / (nb[0] * nb[1])];
        let lo = q.map(|c| (c * block).saturating_sub(1));
        let hi: [usize; 3] = std::array::from_fn(|a| ((q[a] + 1) * block + 1).min(n[a]));
        let mut m = 0f32;
        for k in lo[2]..hi[2] {
            for j in lo[1]..hi[1] {
                let row = index(n, 0, j, k);
                for &d in &density[row + lo[0]..row + hi[0]] {
                    m = m.max(d);
                }
            }
        }
        *o = m;
    });
}

/// `out` = the light reaching each cell from direction `to_light` (unit, cell units)
/// through the density with extinction `sigma(d)` per cell: a sweep along the dominant
/// axis of `to_light`, starting at the lit face (transmittance 1), each cell taking the
/// previous slab's value at the point one slab towards the light (bilinear) times
/// `exp(-sigma path)` over the path between them. Each slab is computed in parallel into
/// `slab` (scratch of at least one slab's cells), then copied into place.
pub fn light_transmittance(
    out: &mut [f32],
    slab: &mut [f32],
    density: &[f32],
    n: [usize; 3],
    to_light: [f32; 3],
    transfer: &Transfer,
) {
    assert_eq!(out.len(), density.len(), "one value per cell");
    let a = (0..3)
        .max_by(|&x, &y| to_light[x].abs().total_cmp(&to_light[y].abs()))
        .unwrap_or(1);
    let (b, c) = ((a + 1) % 3, (a + 2) % 3);
    assert!(slab.len() >= n[b] * n[c], "scratch of one slab");
    let slab = &mut slab[..n[b] * n[c]];
    let la = to_light[a];
    // Per slab step towards the light: one cell along a, and the light's slope on b, c.
    let (sb, sc) = (to_light[b] / la.abs(), to_light[c] / la.abs());
    let path = (1.0 + sb * sb + sc * sc).sqrt();
    let cell = move |ia: usize, ib: usize, ic: usize| {
        let mut q = [0usize; 3];
        q[a] = ia;
        q[b] = ib;
        q[c] = ic;
        index(n, q[0], q[1], q[2])
    };
    let mut prev: Option<usize> = None;
    for step in 0..n[a] {
        let ia = if la > 0.0 { n[a] - 1 - step } else { step };
        {
            let out = &*out;
            slab.par_chunks_mut(n[b]).enumerate().for_each(|(ic, row)| {
                for (ib, t) in row.iter_mut().enumerate() {
                    *t = match prev {
                        None => 1.0,
                        Some(pa) => {
                            // The point one slab towards the light, bilinear in slab pa.
                            let fb = (ib as f32 + sb).clamp(0.0, (n[b] - 1) as f32);
                            let fc = (ic as f32 + sc).clamp(0.0, (n[c] - 1) as f32);
                            let (b0, c0) = (fb as usize, fc as usize);
                            let (b1, c1) = ((b0 + 1).min(n[b] - 1), (c0 + 1).min(n[c] - 1));
                            let (tb, tc) = (fb - b0 as f32, fc - c0 as f32);
                            let v = |x: usize, y: usize| out[cell(pa, x, y)];
                            let t0 = v(b0, c0) + tb * (v(b1, c0) - v(b0, c0));
                            let t1 = v(b0, c1) + tb * (v(b1, c1) - v(b0, c1));
                            let lit = t0 + tc * (t1 - t0);
                            let d = 0.5 * (density[cell(ia, ib, ic)] + density[cell(pa, b0, c0)]);
                            lit * (-transfer.at(d).1 * path).exp()
                        }
                    };
                }
            });
        }
        for ic in 0..n[c] {
            for ib in 0..n[b] {
                out[cell(ia, ib, ic)] = slab[ib + n[b] * ic];
            }
        }
        prev = Some(ia);
    }
}

/// Where the ray `o + t d` enters and leaves the box `[0, n]` (`None` if it misses).
#[inline]
fn clip(o: [f32; 3], d: [f32; 3], n: [usize; 3]) -> Option<(f32, f32)> {
    let (mut t0, mut t1) = (0f32, f32::INFINITY);
    for a in 0..3 {
        let inv = 1.0 / d[a];
        let (mut lo, mut hi) = ((0.0 - o[a]) * inv, (n[a] as f32 - o[a]) * inv);
        if lo > hi {
            std::mem::swap(&mut lo, &mut hi);
        }
        // NaN (a ray parallel to a face through it) keeps the other bounds.
        if lo > t0 {
            t0 = lo;
        }
        if hi < t1 {
            t1 = hi;
        }
    }
    (t0 < t1).then_some((t0, t1))
}

/// Renders the volume into `rgb` (`width * height * 3` bytes, rows top first).
pub fn render(rgb: &mut [u8], vol: &Volume<'_>, view: &View) {
    let (w, h) = (view.width, view.height);
    assert_eq!(rgb.len(), w * h * 3, "three bytes per pixel");
    let cells = vol.n[0] * vol.n[1] * vol.n[2];
    assert!(
        vol.density.len() == cells && vol.light.len() == cells,
        "one value per cell"
    );
    assert!(
        vol.solid.is_empty() || vol.solid.len() == cells,
        "one occupancy per cell"
    );
    assert_eq!(
        view.table.len(),
        TABLE_BINS,
        "the transfer function is tabulated"
    );
    let aspect = w as f32 / h as f32;
    rgb.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
        let sy = (1.0 - 2.0 * (y as f32 + 0.5) / h as f32) * view.tan_half_fov;
        let bg = {
            let t = 1.0 - y as f32 / h as f32;
            let [lo, hi] = view.background;
            std::array::from_fn::<f32, 3, _>(|k| lo[k] + t * (hi[k] - lo[k]))
        };
        for (x, px) in row.chunks_mut(3).enumerate() {
            let sx = (2.0 * (x as f32 + 0.5) / w as f32 - 1.0) * view.tan_half_fov * aspect;
            let mut d: [f32; 3] =
                std::array::from_fn(|k| view.forward[k] + sx * view.right[k] + sy * view.up[k]);
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            d = d.map(|v| v / len);
            let c = march(vol, view, view.eye, d, bg);
            for k in 0..3 {
                px[k] = (c[k].clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            }
        }
    });
}

/// The colour seen along one ray over the background `bg`.
#[inline]
fn march(vol: &Volume<'_>, view: &View, o: [f32; 3], d: [f32; 3], bg: [f32; 3]) -> [f32; 3] {
    let Some((t0, t1)) = clip(o, d, vol.n) else {
        return bg;
    };
    let mut col = [0f32; 3];
    let mut trans = 1f32;
    let step = view.step;
    let mut t = t0 + 0.5 * step;
    let blk = vol.block as f32;
    while t < t1 {
        let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
        // Empty-space skipping: jump to the block's far side when it is clear.
        let q: [usize; 3] =
            std::array::from_fn(|a| ((p[a] / blk).max(0.0) as usize).min(vol.blocks[a] - 1));
        let bi = q[0] + vol.blocks[0] * (q[1] + vol.blocks[1] * q[2]);
        let solid_block = !vol.block_solid.is_empty() && vol.block_solid[bi] > 0.0;
        if !solid_block && view.clear_below(vol.block_max[bi]) {
            let mut exit = f32::INFINITY;
            for a in 0..3 {
                if d[a] != 0.0 {
                    let face = if d[a] > 0.0 {
                        (q[a] + 1) as f32 * blk
                    } else {
                        q[a] as f32 * blk
                    };
                    exit = exit.min((face - o[a]) / d[a]);
                }
            }
            // Whole steps, so that samples stay on the same lattice.
            let skip = ((exit - t) / step).floor().max(1.0);
            t += skip * step;
            continue;
        }
        if solid_block && trilinear(vol.solid, vol.n, p) >= 0.5 {
            // The surface, found between the last sample and this one by bisection, then
            // shaded by Lambert with the occupancy's gradient as the normal.
            let (mut lo, mut hi) = (t - step, t);
            for _ in 0..5 {
                let mid = 0.5 * (lo + hi);
                let q = [o[0] + mid * d[0], o[1] + mid * d[1], o[2] + mid * d[2]];
                if trilinear(vol.solid, vol.n, q) >= 0.5 {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            let p = [o[0] + hi * d[0], o[1] + hi * d[1], o[2] + hi * d[2]];
            let e = 0.5;
            let g: [f32; 3] = std::array::from_fn(|a| {
                let mut hi = p;
                let mut lo = p;
                hi[a] += e;
                lo[a] -= e;
                trilinear(vol.solid, vol.n, lo) - trilinear(vol.solid, vol.n, hi)
            });
            let gl = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt().max(1e-6);
            let ndl =
                ((g[0] * view.to_light[0] + g[1] * view.to_light[1] + g[2] * view.to_light[2])
                    / gl)
                    .max(0.0);
            let lit = trilinear(vol.light, vol.n, p);
            let shade = view.ambient + (1.0 - view.ambient) * ndl * lit;
            for (ck, sk) in col.iter_mut().zip(view.solid_colour) {
                *ck += trans * sk * shade;
            }
            return col;
        }
        let at = Corner::new(vol.n, p);
        let rho = at.sample(vol.density);
        let [cr, cg, cb, a] = view.lookup(rho);
        if a > 0.0 {
            let lit = view.ambient + at.sample(vol.light);
            let w = trans * lit;
            col[0] += w * cr;
            col[1] += w * cg;
            col[2] += w * cb;
            trans *= 1.0 - a;
            if trans < EARLY_STOP {
                return col;
            }
        }
        t += step;
    }
    std::array::from_fn(|k| col[k] + trans * bg[k])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transfer_is_piecewise_linear_and_constant_beyond_its_points() {
        let tf = Transfer {
            points: vec![(0.05, [1.0; 3], 0.0), (1.0, [0.0; 3], 2.0)],
        };
        assert_eq!(tf.at(0.0).1, 0.0);
        assert!((tf.at(0.525).1 - 1.0).abs() < 1e-6);
        assert!((tf.at(2.0).1 - 2.0).abs() < 1e-6);
    }

    #[test]
    fn light_falls_off_through_a_uniform_slab_as_beer_lambert() {
        let n = [4, 8, 4];
        let density = vec![1.0f32; 128];
        let tf = Transfer {
            points: vec![(0.0, [1.0; 3], 0.1), (1.0, [1.0; 3], 0.1)],
        };
        let mut out = vec![0.0; 128];
        let mut slab = vec![0.0; 16];
        light_transmittance(&mut out, &mut slab, &density, n, [0.0, 1.0, 0.0], &tf);
        // Light from +y: the top slab gets 1, each slab below exp(-0.1) less.
        for j in 0..8 {
            let t = out[index(n, 1, j, 1)];
            let e = (-0.1f32 * (7 - j) as f32).exp();
            assert!((t - e).abs() < 1e-5, "slab {j}: {t} vs {e}");
        }
    }

    /// Skipping clear blocks changes no pixel: the samples stay on the same lattice and
    /// the skipped ones would have added nothing.
    #[test]
    fn empty_space_skipping_changes_no_pixel() {
        let n = [24, 24, 24];
        let cells = 24 * 24 * 24;
        let density: Vec<f32> = (0..cells)
            .map(|i| {
                let (x, y, z) = ((i % 24) as f32, ((i / 24) % 24) as f32, (i / 576) as f32);
                let r2 = (x - 12.0).powi(2) + (y - 8.0).powi(2) + (z - 12.0).powi(2);
                (1.0 - r2 / 25.0).max(0.0)
            })
            .collect();
        let transfer = Transfer {
            points: vec![(0.05, [1.0; 3], 0.0), (1.0, [1.0, 0.9, 0.8], 0.8)],
        };
        let mut light = vec![0.0; cells];
        let mut slab = vec![0.0; 576];
        light_transmittance(
            &mut light,
            &mut slab,
            &density,
            n,
            [0.0, 1.0, 0.0],
            &transfer,
        );
        let nb = [3, 3, 3];
        let mut blocks = vec![0.0; 27];
        block_max(&mut blocks, &density, n, 8);
        let mut view = View {
            width: 48,
            height: 32,
            eye: [12.0, 12.0, 60.0],
            right: [1.0, 0.0, 0.0],
            up: [0.0, 1.0, 0.0],
            forward: [0.0, 0.0, -1.0],
            tan_half_fov: 0.4,
            step: 0.7,
            transfer,
            light_colour: [1.0; 3],
            ambient: 0.2,
            to_light: [0.0, 1.0, 0.0],
            solid_colour: [0.5; 3],
            background: [[0.1; 3], [0.3; 3]],
            table: Vec::new(),
            table_max: 1.0,
            clear_until: 0.0,
        };
        view.tabulate();
        let image = |block_max: &[f32]| {
            let mut rgb = vec![0u8; 48 * 32 * 3];
            let vol = Volume {
                n,
                density: &density,
                light: &light,
                solid: &[],
                block: 8,
                blocks: nb,
                block_max,
                block_solid: &[],
            };
            render(&mut rgb, &vol, &view);
            rgb
        };
        let skipped = image(&blocks);
        let full = image(&[f32::INFINITY; 27]);
        assert_eq!(skipped, full);
        assert!(skipped.iter().any(|&c| c > 120), "the ball shows");
    }
}
