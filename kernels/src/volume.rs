//! Volume ray casting of a density grid (Levoy 1988; course notes section 18), in f32.
//!
//! - Each pixel's ray is clipped to the grid's box and marched at a fixed step; at each
//!   sample the density is interpolated trilinearly, mapped by a piecewise-linear transfer
//!   function to colour and extinction, and composited front to back,
//!   `C += T a c`, `T *= 1 - a` with `a = 1 - exp(-sigma step)`; the march stops when
//!   the transmittance T falls below [`EARLY_STOP`] (early ray termination).
//! - Empty-space skipping: a coarse grid holds each block's largest density (rim
//!   included), and from it each block's clearance, the Chebyshev distance in blocks to
//!   the nearest block that the transfer function does not make clear
//!   ([`clearance`]). A ray walks the blocks in order (a 3-D DDA) and from a clear block
//!   leaps to where it leaves the clear cube around it; only the blocks to be sampled are
//!   sampled, at lattice points numbered from the ray's entry, so that skipping changes
//!   no pixel. Pixels outside the image of the grid's box march no ray.
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

    /// The [`TABLE_BINS`] bins over which it is tabulated, evenly from density 0 to its
    /// last point's (the last bin covers every density beyond): bins per unit density,
    /// and each bin's colour and extinction.
    pub fn bins(&self) -> (f32, impl Iterator<Item = ([f32; 3], f32)> + '_) {
        let top = self.points[self.points.len() - 1].0.max(1e-6);
        let scale = (TABLE_BINS - 1) as f32 / top;
        (
            scale,
            (0..TABLE_BINS).map(move |i| self.at(i as f32 / scale)),
        )
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
    /// Per block, the Chebyshev distance in blocks to the nearest block that must be
    /// sampled, 0 for those ([`clearance`]).
    pub clearance: &'a [u8],
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
    /// `1 - exp(-sigma step)`, over [`Transfer::bins`].
    pub table: Vec<[f32; 4]>,
    /// Bins per unit density ([`Transfer::bins`]).
    pub table_scale: f32,
    /// The least density with extinction: densities below it are clear.
    pub clear_until: f32,
}

/// Bins of the tabulated transfer function.
pub const TABLE_BINS: usize = 1024;

impl View {
    /// Tabulates the transfer function for the step and light colour (call after setting
    /// them): a table lookup and no `exp` per sample.
    pub fn tabulate(&mut self) {
        let (scale, bins) = self.transfer.bins();
        self.table_scale = scale;
        self.table = bins
            .map(|(c, sigma)| {
                let a = 1.0 - (-sigma.max(0.0) * self.step).exp();
                [
                    a * c[0] * self.light_colour[0],
                    a * c[1] * self.light_colour[1],
                    a * c[2] * self.light_colour[2],
                    a,
                ]
            })
            .collect();
        let p = &self.transfer.points;
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
        let t = (d * self.table_scale).clamp(0.0, (TABLE_BINS - 1) as f32);
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
        // Each row's largest on its own (short independent chains), then theirs; a NaN
        // density is passed over.
        let mut m = 0f32;
        for k in lo[2]..hi[2] {
            for j in lo[1]..hi[1] {
                let row = index(n, 0, j, k);
                let r = density[row + lo[0]..row + hi[0]]
                    .iter()
                    .fold(0f32, |m, &d| if d > m { d } else { m });
                m = if r > m { r } else { m };
            }
        }
        *o = m;
    });
}

/// `out[block]` = the Chebyshev distance, in blocks, from each block to the nearest
/// block that a ray must sample (one holding a solid, or a density that the view's
/// transfer function does not make clear), 0 for those, at most 255 (also when there is
/// none). A ray in a block of clearance `c` crosses the cube of `2c - 1` blocks around it
/// without a sample.
///
/// The distance is separable, `min_q max_a |p_a - q_a|` taken one axis at a time
/// (`max` is associative), so three passes along the lines of each axis; `line` is
/// scratch of at least the longest side's blocks.
pub fn clearance(
    out: &mut [u8],
    line: &mut [u8],
    block_max: &[f32],
    block_solid: &[f32],
    blocks: [usize; 3],
    view: &View,
) {
    let nb = blocks;
    let count = nb[0] * nb[1] * nb[2];
    assert!(
        out.len() == count && block_max.len() == count,
        "one value per block"
    );
    assert!(
        block_solid.is_empty() || block_solid.len() == count,
        "one solid value per block"
    );
    for (b, o) in out.iter_mut().enumerate() {
        let sampled =
            !view.clear_below(block_max[b]) || (!block_solid.is_empty() && block_solid[b] > 0.0);
        *o = if sampled { 0 } else { u8::MAX };
    }
    assert!(
        line.len() >= nb.iter().copied().max().unwrap_or(0),
        "scratch of one line of blocks"
    );
    let stride = [1, nb[0], nb[0] * nb[1]];
    for a in 0..3 {
        let line = &mut line[..nb[a]];
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        for ib in 0..nb[b] {
            for ic in 0..nb[c] {
                let first = ib * stride[b] + ic * stride[c];
                for (i, v) in line.iter_mut().enumerate() {
                    *v = out[first + i * stride[a]];
                }
                for i in 0..nb[a] {
                    let best = line
                        .iter()
                        .enumerate()
                        .map(|(j, &v)| v.max(i.abs_diff(j).min(255) as u8))
                        .min()
                        .unwrap_or(u8::MAX);
                    out[first + i * stride[a]] = best;
                }
            }
        }
    }
}

/// `out` = the light reaching each cell from direction `to_light` (unit, cell units)
/// through the density with extinction `sigma(d)` per cell: a sweep along the dominant
/// axis of `to_light`, starting at the lit face (transmittance 1), each cell taking the
/// previous slab's value at the point one slab towards the light (bilinear) times
/// `exp(-sigma path)` over the path between them. Each slab is computed in parallel into
/// `slab` (scratch of at least one slab's cells), then copied into place.
///
/// The slab's rows run along the lowest other axis (x unless the sweep is along x), so
/// that they are contiguous in memory (along z, as before, the sweep took four times
/// longer); `exp(-sigma(d) path)` is tabulated over the density ([`TABLE_BINS`] bins,
/// interpolated linearly), so no cell evaluates the transfer function or `exp`.
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
    let b = usize::from(a == 0);
    let c = 3 - a - b;
    assert!(slab.len() >= n[b] * n[c], "scratch of one slab");
    let slab = &mut slab[..n[b] * n[c]];
    let la = to_light[a];
    // Per slab step towards the light: one cell along a, and the light's slope on b, c.
    let (sb, sc) = (to_light[b] / la.abs(), to_light[c] / la.abs());
    let path = (1.0 + sb * sb + sc * sc).sqrt();
    let pass = Pass::new(transfer, path);
    let stride = {
        let s = [1, n[0], n[0] * n[1]];
        [s[a], s[b], s[c]]
    };
    let cell =
        move |ia: usize, ib: usize, ic: usize| ia * stride[0] + ib * stride[1] + ic * stride[2];
    let mut prev: Option<usize> = None;
    for step in 0..n[a] {
        let ia = if la > 0.0 { n[a] - 1 - step } else { step };
        let next = (b == 0 && step + 1 < n[a]).then(|| if la > 0.0 { ia - 1 } else { ia + 1 });
        {
            let out = &*out;
            slab.par_chunks_mut(n[b]).enumerate().for_each(|(ic, row)| {
                if let Some(next) = next {
                    // This row's density and light in the next slab, towards L2: with
                    // rows along x, a slab is n[c] short rows far apart, too many
                    // streams for the hardware prefetcher.
                    prefetch(&density[cell(next, 0, ic)..][..n[b]]);
                    prefetch(&out[cell(next, 0, ic)..][..n[b]]);
                }
                let Some(pa) = prev else {
                    row.fill(1.0);
                    return;
                };
                // The point one slab towards the light, bilinear in slab pa.
                let fc = (ic as f32 + sc).clamp(0.0, (n[c] - 1) as f32);
                let c0 = fc as usize;
                let c1 = (c0 + 1).min(n[c] - 1);
                let tc = fc - c0 as f32;
                for (ib, t) in row.iter_mut().enumerate() {
                    let fb = (ib as f32 + sb).clamp(0.0, (n[b] - 1) as f32);
                    let b0 = fb as usize;
                    let b1 = (b0 + 1).min(n[b] - 1);
                    let tb = fb - b0 as f32;
                    let v = |x: usize, y: usize| out[cell(pa, x, y)];
                    let t0 = v(b0, c0) + tb * (v(b1, c0) - v(b0, c0));
                    let t1 = v(b0, c1) + tb * (v(b1, c1) - v(b0, c1));
                    let lit = t0 + tc * (t1 - t0);
                    let d = 0.5 * (density[cell(ia, ib, ic)] + density[cell(pa, b0, c0)]);
                    *t = lit * pass.at(d);
                }
            });
        }
        for (ic, row) in slab.chunks(n[b]).enumerate() {
            for (ib, &t) in row.iter().enumerate() {
                out[cell(ia, ib, ic)] = t;
            }
        }
        prev = Some(ia);
    }
}

/// Asks for the cache lines of `v` to be brought into L2 (a hint: nothing on other
/// targets).
#[inline(always)]
fn prefetch(v: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    for line in v.chunks(16) {
        // SAFETY: a prefetch is a hint; it reads no memory architecturally and the
        // address is that of a live slice element.
        unsafe {
            core::arch::x86_64::_mm_prefetch::<{ core::arch::x86_64::_MM_HINT_T1 }>(
                line.as_ptr().cast(),
            );
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = v;
}

/// The fraction `exp(-sigma(d) path)` of light passing `path` cells of density `d`,
/// tabulated over the transfer function's densities and interpolated linearly.
struct Pass {
    table: [f32; TABLE_BINS],
    scale: f32,
}

impl Pass {
    fn new(transfer: &Transfer, path: f32) -> Pass {
        let (scale, bins) = transfer.bins();
        let mut table = [0f32; TABLE_BINS];
        for (t, (_, sigma)) in table.iter_mut().zip(bins) {
            *t = (-sigma.max(0.0) * path).exp();
        }
        Pass { table, scale }
    }

    #[inline(always)]
    fn at(&self, d: f32) -> f32 {
        let x = (d * self.scale).clamp(0.0, (TABLE_BINS - 1) as f32);
        let i = (x as usize).min(TABLE_BINS - 2);
        let (lo, hi) = (self.table[i], self.table[i + 1]);
        lo + (x - i as f32) * (hi - lo)
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
    // Pixels outside the grid box's image see only the background.
    let [x_lo, x_hi, y_lo, y_hi] = box_image(vol.n, view);
    // Rows in parallel. (Square tiles of 16 x 16 pixels, for the cache, were no
    // faster: 81-85 ms against 81-85 ms on the bench's frame.)
    rgb.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
        let bg = background(view, y);
        for (x, px) in row.chunks_mut(3).enumerate() {
            let c = if (x_lo..x_hi).contains(&x) && (y_lo..y_hi).contains(&y) {
                march(vol, view, view.eye, ray(view, x, y), bg)
            } else {
                bg
            };
            for k in 0..3 {
                px[k] = (c[k].clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            }
        }
    });
}

/// The background colour of pixel row `y`.
#[inline]
fn background(view: &View, y: usize) -> [f32; 3] {
    let t = 1.0 - y as f32 / view.height as f32;
    let [lo, hi] = view.background;
    std::array::from_fn(|k| lo[k] + t * (hi[k] - lo[k]))
}

/// The unit direction of the ray through the centre of pixel `(x, y)` (rows top first).
#[inline]
fn ray(view: &View, x: usize, y: usize) -> [f32; 3] {
    let (w, h) = (view.width as f32, view.height as f32);
    let sy = (1.0 - 2.0 * (y as f32 + 0.5) / h) * view.tan_half_fov;
    let sx = (2.0 * (x as f32 + 0.5) / w - 1.0) * view.tan_half_fov * (w / h);
    let d: [f32; 3] =
        std::array::from_fn(|k| view.forward[k] + sx * view.right[k] + sy * view.up[k]);
    let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    d.map(|v| v / len)
}

/// The pixel ranges `[x_lo, x_hi, y_lo, y_hi]` (ends excluded) holding the image of the
/// box `[0, n]`, widened by two pixels against rounding: the projections of its
/// corners bound it when all are in front of the eye; otherwise the whole image.
fn box_image(n: [usize; 3], view: &View) -> [usize; 4] {
    let (w, h) = (view.width as f32, view.height as f32);
    let whole = [0, view.width, 0, view.height];
    let [mut x0, mut x1, mut y0, mut y1] = [
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
    ];
    for corner in 0..8 {
        let v: [f32; 3] = std::array::from_fn(|a| {
            let c = if corner >> a & 1 == 1 {
                n[a] as f32
            } else {
                0.0
            };
            c - view.eye[a]
        });
        let dot = |u: [f32; 3]| v[0] * u[0] + v[1] * u[1] + v[2] * u[2];
        let z = dot(view.forward);
        if z.partial_cmp(&1e-3) != Some(std::cmp::Ordering::Greater) {
            return whole;
        }
        // Pixel coordinates of the corner (the inverse of `ray`).
        let px = (dot(view.right) / (z * view.tan_half_fov * (w / h)) + 1.0) * 0.5 * w - 0.5;
        let py = (1.0 - dot(view.up) / (z * view.tan_half_fov)) * 0.5 * h - 0.5;
        x0 = x0.min(px);
        x1 = x1.max(px);
        y0 = y0.min(py);
        y1 = y1.max(py);
    }
    if !(x0.is_finite() && x1.is_finite() && y0.is_finite() && y1.is_finite()) {
        return whole;
    }
    let lo = |v: f32, m: usize| ((v - 2.0).floor().max(0.0) as usize).min(m);
    let hi = |v: f32, m: usize| ((v + 3.0).ceil().max(0.0) as usize).min(m);
    [
        lo(x0, view.width),
        hi(x1, view.width),
        lo(y0, view.height),
        hi(y1, view.height),
    ]
}

/// The colour seen along one ray over the background `bg`.
///
/// The ray walks the skipping blocks it crosses in order (a 3-D DDA, Amanatides and Woo
/// 1987), leaping over clear space: from a block of clearance `c` it moves in one go to
/// where it leaves the clear cube of `2c - 1` blocks around it, and in a block to be
/// sampled it takes every lattice point `t0 + (m + 1/2) step` inside. The samples are
/// numbered from the ray's entry, so skipping changes which are taken, never where they
/// are.
#[inline]
fn march(vol: &Volume<'_>, view: &View, o: [f32; 3], d: [f32; 3], bg: [f32; 3]) -> [f32; 3] {
    let Some((t0, t1)) = clip(o, d, vol.n) else {
        return bg;
    };
    let mut col = [0f32; 3];
    let mut trans = 1f32;
    let step = view.step;
    let blk = vol.block as f32;
    let nb = vol.blocks;
    let inv = d.map(|x| 1.0 / x);
    let at = |m: f32| t0 + (m + 0.5) * step;
    // The entry block.
    let mid = t0 + 0.5 * (t1 - t0).min(step);
    let mut q: [usize; 3] =
        std::array::from_fn(|a| ((((o[a] + mid * d[a]) / blk).max(0.0)) as usize).min(nb[a] - 1));
    let mut m = 0f32;
    // Each move crosses at least one block face ahead, so an exact walk ends within
    // nb[0] + nb[1] + nb[2] moves; the bound is twice that, so that rounding at a cube's
    // edge can never keep a ray going.
    for _ in 0..2 * (nb[0] + nb[1] + nb[2]) {
        let bi = q[0] + nb[0] * (q[1] + nb[1] * q[2]);
        let clear = vol.clearance[bi];
        // The clear cube around q (just q when it is to be sampled), within the grid.
        let r = usize::from(clear.max(1) - 1);
        let lo = q.map(|c| c.saturating_sub(r));
        let hi: [usize; 3] = std::array::from_fn(|a| (q[a] + r).min(nb[a] - 1));
        // Where the ray leaves it, and through which axis (3: the grid's far side first).
        let mut exit = t1;
        let mut axis = 3;
        for a in 0..3 {
            if d[a] != 0.0 {
                let face = if d[a] > 0.0 { hi[a] + 1 } else { lo[a] } as f32 * blk;
                let ta = (face - o[a]) * inv[a];
                if ta < exit {
                    exit = ta;
                    axis = a;
                }
            }
        }
        if clear == 0 {
            let solid_block = !vol.block_solid.is_empty() && vol.block_solid[bi] > 0.0;
            let mut t = at(m);
            while t < exit {
                let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
                if solid_block && trilinear(vol.solid, vol.n, p) >= 0.5 {
                    return surface(vol, view, o, d, t, trans, col);
                }
                let corner = Corner::new(vol.n, p);
                let rho = corner.sample(vol.density);
                let [cr, cg, cb, a] = view.lookup(rho);
                if a > 0.0 {
                    let w = trans * (view.ambient + corner.sample(vol.light));
                    col[0] += w * cr;
                    col[1] += w * cg;
                    col[2] += w * cb;
                    trans *= 1.0 - a;
                    if trans < EARLY_STOP {
                        return col;
                    }
                }
                m += 1.0;
                t = at(m);
            }
        } else {
            // The first lattice point at or past the cube's exit.
            m = m.max(((exit - t0) / step - 0.5).ceil());
        }
        if axis == 3 {
            break;
        }
        // The next block: across the exit face on its axis, and where the ray is on the
        // others (kept within the cube, which rounding could leave).
        for a in 0..3 {
            if a != axis {
                let c = ((o[a] + exit * d[a]) / blk).max(0.0) as usize;
                q[a] = c.clamp(lo[a], hi[a]);
            }
        }
        if d[axis] > 0.0 {
            if hi[axis] + 1 >= nb[axis] {
                break;
            }
            q[axis] = hi[axis] + 1;
        } else {
            if lo[axis] == 0 {
                break;
            }
            q[axis] = lo[axis] - 1;
        }
    }
    std::array::from_fn(|k| col[k] + trans * bg[k])
}

/// The colour `col` plus the solid surface met between the samples at `t - step` and
/// `t`: found by bisection, then shaded by Lambert with the occupancy's gradient as the
/// normal and the light reaching it, seen through the transmittance `trans`.
#[cold]
fn surface(
    vol: &Volume<'_>,
    view: &View,
    o: [f32; 3],
    d: [f32; 3],
    t: f32,
    trans: f32,
    mut col: [f32; 3],
) -> [f32; 3] {
    let (mut lo, mut hi) = (t - view.step, t);
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
    let ndl = ((g[0] * view.to_light[0] + g[1] * view.to_light[1] + g[2] * view.to_light[2]) / gl)
        .max(0.0);
    let lit = trilinear(vol.light, vol.n, p);
    let shade = view.ambient + (1.0 - view.ambient) * ndl * lit;
    for (ck, sk) in col.iter_mut().zip(view.solid_colour) {
        *ck += trans * sk * shade;
    }
    col
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

    /// Two balls of smoke in a 40^3 grid (10^3 blocks of 4).
    fn two_balls() -> ([usize; 3], Vec<f32>) {
        let n = [40, 40, 40];
        let density = (0..40 * 40 * 40)
            .map(|i| {
                let p = [(i % 40) as f32, ((i / 40) % 40) as f32, (i / 1600) as f32];
                let ball = |c: [f32; 3], r: f32| {
                    let r2: f32 = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum();
                    (1.0 - r2 / (r * r)).max(0.0)
                };
                ball([20.0, 14.0, 20.0], 5.0) + ball([6.0, 33.0, 8.0], 3.0)
            })
            .collect();
        (n, density)
    }

    fn smoke_view(eye: [f32; 3], target: [f32; 3]) -> View {
        let forward = {
            let f: [f32; 3] = std::array::from_fn(|a| target[a] - eye[a]);
            let l = f.iter().map(|x| x * x).sum::<f32>().sqrt();
            f.map(|x| x / l)
        };
        let right = {
            let r = [-forward[2], 0.0, forward[0]];
            let l = (r[0] * r[0] + r[2] * r[2]).sqrt();
            r.map(|x| x / l)
        };
        let up = [
            right[1] * forward[2] - right[2] * forward[1],
            right[2] * forward[0] - right[0] * forward[2],
            right[0] * forward[1] - right[1] * forward[0],
        ];
        let mut view = View {
            width: 64,
            height: 48,
            eye,
            right,
            up,
            forward,
            tan_half_fov: 0.45,
            step: 0.7,
            transfer: Transfer {
                points: vec![(0.05, [1.0; 3], 0.0), (1.0, [1.0, 0.9, 0.8], 0.8)],
            },
            light_colour: [1.0; 3],
            ambient: 0.2,
            to_light: [0.0, 1.0, 0.0],
            solid_colour: [0.5; 3],
            background: [[0.1; 3], [0.3; 3]],
            table: Vec::new(),
            table_scale: 1.0,
            clear_until: 0.0,
        };
        view.tabulate();
        view
    }

    /// The light from straight above through the two balls' grid, with the test view's
    /// transfer function.
    fn light_from_above(n: [usize; 3], density: &[f32]) -> Vec<f32> {
        let view = smoke_view([20.0, 20.0, 90.0], [20.0, 20.0, 20.0]);
        let mut light = vec![0.0; density.len()];
        let mut slab = vec![0.0; n[0] * n[2]];
        light_transmittance(
            &mut light,
            &mut slab,
            density,
            n,
            [0.0, 1.0, 0.0],
            &view.transfer,
        );
        light
    }

    /// The clearance is the brute-force Chebyshev distance to the nearest sampled block.
    #[test]
    fn clearance_is_the_chebyshev_distance_to_the_nearest_sampled_block() {
        let (n, density) = two_balls();
        let nb = [10, 10, 10];
        let mut blocks = vec![0.0; 1000];
        block_max(&mut blocks, &density, n, 4);
        let view = smoke_view([20.0, 20.0, 90.0], [20.0, 20.0, 20.0]);
        let mut clear = vec![0u8; 1000];
        clearance(&mut clear, &mut [0; 10], &blocks, &[], nb, &view);
        let at = |b: usize| [b % 10, (b / 10) % 10, b / 100];
        for (b, &got) in clear.iter().enumerate() {
            let want = (0..1000)
                .filter(|&o| !view.clear_below(blocks[o]))
                .map(|o| (0..3).map(|a| at(b)[a].abs_diff(at(o)[a])).max().unwrap())
                .min()
                .unwrap();
            assert_eq!(usize::from(got), want, "block {b}");
        }
        assert!(clear.iter().any(|&c| c >= 3), "some far blocks");
    }

    /// Skipping clear blocks changes no pixel, from views straight on and oblique: the
    /// samples stay on the same lattice and the skipped ones would have added nothing.
    #[test]
    fn empty_space_skipping_changes_no_pixel() {
        let (n, density) = two_balls();
        let light = light_from_above(n, &density);
        let nb = [10, 10, 10];
        let mut blocks = vec![0.0; 1000];
        block_max(&mut blocks, &density, n, 4);
        for (eye, target) in [
            ([20.0, 20.0, 90.0], [20.0, 20.0, 20.0]),
            ([-30.0, 55.0, 70.0], [18.0, 18.0, 18.0]),
            ([20.0, 20.0, 20.0], [0.0, 40.0, 0.0]),
            ([75.0, -20.0, -35.0], [12.0, 24.0, 14.0]),
        ] {
            let view = smoke_view(eye, target);
            let image = |clearance: &[u8]| {
                let mut rgb = vec![0u8; 64 * 48 * 3];
                let vol = Volume {
                    n,
                    density: &density,
                    light: &light,
                    solid: &[],
                    block: 4,
                    blocks: nb,
                    clearance,
                    block_solid: &[],
                };
                render(&mut rgb, &vol, &view);
                rgb
            };
            let mut clear = vec![0u8; 1000];
            clearance(&mut clear, &mut [0; 10], &blocks, &[], nb, &view);
            let skipped = image(&clear);
            let full = image(&[0; 1000]);
            assert_eq!(skipped, full, "eye {eye:?}");
            assert!(skipped.iter().any(|&c| c > 120), "the smoke shows");
        }
    }

    /// Pixels outside the box's image are the background: the image equals one with a
    /// ray marched through every pixel, with the box small in view, off centre, and with
    /// the eye inside it.
    #[test]
    fn pixels_outside_the_box_image_are_background() {
        // A haze everywhere, so that rays grazing the box's faces are not background.
        let (n, mut density) = two_balls();
        density.iter_mut().for_each(|d| *d += 0.3);
        let light = light_from_above(n, &density);
        let clear = [0u8; 1000];
        let vol = Volume {
            n,
            density: &density,
            light: &light,
            solid: &[],
            block: 4,
            blocks: [10, 10, 10],
            clearance: &clear,
            block_solid: &[],
        };
        for (eye, target) in [
            ([20.0, 20.0, 250.0], [20.0, 20.0, 20.0]),
            ([-60.0, 90.0, 120.0], [60.0, 0.0, 0.0]),
            ([20.0, 20.0, 20.0], [0.0, 40.0, 0.0]),
        ] {
            let view = smoke_view(eye, target);
            let mut rgb = vec![0u8; 64 * 48 * 3];
            render(&mut rgb, &vol, &view);
            let [x0, x1, y0, y1] = box_image(n, &view);
            let mut culled = 0;
            for y in 0..48 {
                for x in 0..64 {
                    let c = march(
                        &vol,
                        &view,
                        view.eye,
                        ray(&view, x, y),
                        background(&view, y),
                    );
                    let want = c.map(|v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8);
                    assert_eq!(rgb[3 * (64 * y + x)..][..3], want, "pixel {x}, {y}");
                    culled += usize::from(!((x0..x1).contains(&x) && (y0..y1).contains(&y)));
                }
            }
            if eye == [20.0, 20.0, 250.0] {
                assert!(culled > 64 * 48 / 2, "most pixels culled: {culled}");
            }
        }
    }
}
