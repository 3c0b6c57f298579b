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
//! - Where the build has AVX2, a ray's samples are taken eight at a time in SIMD lanes:
//!   the corners of eight samples are gathered (each with its neighbour along x, as one
//!   64-bit pair) and interpolated with the same operations as one sample at a time,
//!   then composited one by one in order, so the pixels are the same bits either way
//!   (tested); the light is gathered only for a batch with some opacity. The light
//!   sweep's passing fractions are looked up eight at a time the same way.
//!
//! Everything is in cell units: the grid's cell `(i, j, k)` spans `[i, i + 1]` on x, and
//! so on. Rows are rendered in parallel; each pixel on its own, so the bits do not depend
//! on the thread count.

use crate::par::Disjoint;
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

    /// The first bin of the table with opacity (`TABLE_BINS` if none): a density whose
    /// bin is below it is clear.
    #[inline]
    pub fn opaque_from(&self) -> i32 {
        self.table
            .iter()
            .position(|e| e[3] > 0.0)
            .unwrap_or(TABLE_BINS) as i32
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

/// A grid's constants for locating points among its cell centres ([`Corner`]), worked
/// out once per grid rather than at every sample.
#[derive(Clone, Copy, Debug)]
pub struct Lattice {
    /// The largest coordinate of a cell centre from the first, `n - 1` (cells).
    top: [f32; 3],
    /// The largest lower-corner cell, `n - 2` (0 on an axis of one cell).
    last: [i32; 3],
    /// Strides to the neighbours along x, y, z (0 along an axis of one cell).
    d: [usize; 3],
    /// Cells along x, and in a z slice.
    nx: usize,
    nxy: usize,
    /// Cells in all.
    cells: usize,
    /// The first bin of the view's table with opacity ([`View::opaque_from`];
    /// [`Lattice::for_view`]), `TABLE_BINS` without a view.
    opaque_from: i32,
    /// Whether every cell index fits in an `i32` and x has more than one cell (the SIMD
    /// path's lanes, which read each corner with its neighbour along x).
    lanes: bool,
}

impl Lattice {
    /// [`Lattice::new`] for rendering with `view` (its [`View::opaque_from`]).
    pub fn for_view(n: [usize; 3], view: &View) -> Lattice {
        Lattice {
            opaque_from: view.opaque_from(),
            ..Lattice::new(n)
        }
    }

    /// The constants of a grid of `n` cells (each at least one and at most `i32::MAX`).
    pub fn new(n: [usize; 3]) -> Lattice {
        Lattice {
            top: n.map(|c| c.saturating_sub(1) as f32),
            last: n.map(|c| i32::try_from(c.saturating_sub(2)).unwrap_or(i32::MAX)),
            d: [
                usize::from(n[0] > 1),
                if n[1] > 1 { n[0] } else { 0 },
                if n[2] > 1 { n[0] * n[1] } else { 0 },
            ],
            nx: n[0],
            nxy: n[0] * n[1],
            cells: n[0] * n[1] * n[2],
            opaque_from: TABLE_BINS as i32,
            lanes: n[0] > 1 && n[0] * n[1] * n[2] <= i32::MAX as usize,
        }
    }
}

/// Where a point falls among the cell centres: the lower corner cell, the strides to
/// its neighbours (0 along an axis of one cell) and the fractions, clamped to the grid.
/// One lookup serves every field sampled at the point.
#[derive(Clone, Copy, Debug)]
pub struct Corner {
    base: usize,
    d: [usize; 3],
    t: [f32; 3],
    /// Cells in the grid: every corner read is below it.
    cells: usize,
}

impl Corner {
    /// The corner of `p` (cell units; centres at `i + 1/2`) in the grid of `l`.
    ///
    /// Each coordinate is clamped to `[0, n - 1]` before it is truncated (a NaN becomes
    /// 0), and the corner cell to `n - 2`, so that the corner and its neighbours are
    /// cells of the grid; along an axis of one cell the fraction is 0.
    #[inline(always)]
    pub fn new(l: &Lattice, p: [f32; 3]) -> Corner {
        let mut i = [0usize; 3];
        let mut t = [0f32; 3];
        for a in 0..3 {
            let x = (p[a] - 0.5).max(0.0).min(l.top[a]);
            let c = (x as i32).min(l.last[a]);
            i[a] = c as usize;
            t[a] = x - c as f32;
        }
        Corner {
            base: i[0] + l.nx * i[1] + l.nxy * i[2],
            d: l.d,
            t,
            cells: l.cells,
        }
    }

    /// The trilinear sample of the cell-centred field `f` (one value per cell of the
    /// lattice's grid) there.
    #[inline(always)]
    pub fn sample(&self, f: &[f32]) -> f32 {
        let f = &f[..self.cells];
        let [dx, dy, dz] = self.d;
        let t = self.t;
        // SAFETY: the corner cell is at most `n - 2` along each axis that has a
        // neighbour stride (and 0 along the others), so `base + dx + dy + dz` is at most
        // the last cell's index, below `cells`, the length of `f`.
        let l = |o: usize| unsafe { *f.get_unchecked(self.base + o) };
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
    Corner::new(&Lattice::new(n), p).sample(f)
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
/// `exp(-sigma path)` over the path between them. Each slab is computed in parallel, a
/// row a task, into `slab` (scratch of at least two slabs' cells: this one and the one
/// before, which the rows read), each row also written into place.
///
/// The slab's rows run along the lowest other axis (x unless the sweep is along x), so
/// that they are contiguous in memory (along z, as before, the sweep took four times
/// longer); `exp(-sigma(d) path)` is tabulated over the density ([`TABLE_BINS`] bins,
/// interpolated linearly), so no cell evaluates the transfer function or `exp`. Away
/// from a slab's edges the point towards the light is the same fraction past a cell for
/// every cell, so with rows along x the row's interior is a fixed stencil over contiguous
/// values ([`stencil`]).
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
    let size = n[b] * n[c];
    assert!(slab.len() >= 2 * size, "scratch of two slabs");
    // The previous slab's light and this one's, swapped after each step: rows read
    // contiguously from the scratch rather than from `out`, where each row is a slab's
    // distance from the next.
    let (mut before, mut slab) = slab[..2 * size].split_at_mut(size);
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
    // Where rows run along x (contiguous), the point one slab towards the light is the
    // same fraction `tb` past cell `ib + kb` for every cell away from the slab's edges,
    // so the row's interior is a fixed stencil over contiguous values.
    let kb = sb.floor();
    let tb = sb - kb;
    let kb = kb as isize;
    let nb = n[b] as isize;
    let interior = if b == 0 {
        let lo = (-kb).clamp(0, nb);
        lo..(nb - 1 - kb).clamp(lo, nb)
    } else {
        0..0
    };
    let (lo, hi) = (interior.start as usize, interior.end as usize);
    let mut prev: Option<usize> = None;
    for step in 0..n[a] {
        let ia = if la > 0.0 { n[a] - 1 - step } else { step };
        let next = (b == 0 && step + 1 < n[a]).then(|| if la > 0.0 { ia - 1 } else { ia + 1 });
        {
            let before = &*before;
            let rows = Disjoint::new(out);
            slab.par_chunks_mut(n[b]).enumerate().for_each(|(ic, row)| {
                if let Some(next) = next {
                    // This row's density in the next slab, towards L2: with rows along
                    // x, a slab is n[c] short rows far apart, too many streams for the
                    // hardware prefetcher.
                    prefetch(&density[cell(next, 0, ic)..][..n[b]]);
                }
                // Rows along x are written into place here, each task its own row.
                let store = |row: &[f32]| {
                    if b == 0 {
                        let at = cell(ia, 0, ic);
                        // SAFETY: the rows (ia, ic) of the tasks are disjoint, and
                        // nothing else reads or writes `out` during the sweep.
                        unsafe { rows.slice(at..at + n[b]) }.copy_from_slice(row);
                    }
                };
                let Some(pa) = prev else {
                    row.fill(1.0);
                    store(row);
                    return;
                };
                // The point one slab towards the light, bilinear in slab pa.
                let fc = (ic as f32 + sc).clamp(0.0, (n[c] - 1) as f32);
                let c0 = fc as usize;
                let c1 = (c0 + 1).min(n[c] - 1);
                let tc = fc - c0 as f32;
                let edge = |ib: usize| {
                    let fb = (ib as f32 + sb).clamp(0.0, (n[b] - 1) as f32);
                    let b0 = fb as usize;
                    let b1 = (b0 + 1).min(n[b] - 1);
                    let tb = fb - b0 as f32;
                    let v = |x: usize, y: usize| before[y * n[b] + x];
                    let t0 = v(b0, c0) + tb * (v(b1, c0) - v(b0, c0));
                    let t1 = v(b0, c1) + tb * (v(b1, c1) - v(b0, c1));
                    let lit = t0 + tc * (t1 - t0);
                    let d = 0.5 * (density[cell(ia, ib, ic)] + density[cell(pa, b0, c0)]);
                    lit * pass.at(d)
                };
                for ib in (0..lo).chain(hi..n[b]) {
                    row[ib] = edge(ib);
                }
                if lo < hi {
                    // Rows along x: cells lo..hi read the previous slab's cells
                    // lo + kb ..= hi + kb on rows c0 and c1.
                    let from = (lo as isize + kb) as usize;
                    let len = hi - lo;
                    let p0 = &before[c0 * n[b] + from..][..len + 1];
                    let p1 = &before[c1 * n[b] + from..][..len + 1];
                    let dp = &density[cell(pa, from, c0)..][..len];
                    let dr = &density[cell(ia, lo, ic)..][..len];
                    stencil(&mut row[lo..hi], [p0, p1], [dp, dr], [tb, tc], &pass);
                }
                store(row);
            });
        }
        if b != 0 {
            for (ic, row) in slab.chunks(n[b]).enumerate() {
                for (ib, &t) in row.iter().enumerate() {
                    out[cell(ia, ib, ic)] = t;
                }
            }
        }
        std::mem::swap(&mut before, &mut slab);
        prev = Some(ia);
    }
}

/// The light sweep's interior row (rows along x): `out[i]` = the previous slab's light
/// at `i + tb` between rows `p[0]` and `p[1]` (bilinear, weights `tb`, `tc`) times the
/// light passing the mean density of `d[0][i]` (previous slab) and `d[1][i]` (this one).
/// In runs of [`RUN`] cells: the stencil in lanes first, then the table lookups.
#[inline]
fn stencil(out: &mut [f32], p: [&[f32]; 2], d: [&[f32]; 2], [tb, tc]: [f32; 2], pass: &Pass) {
    const RUN: usize = 64;
    let n = out.len();
    assert!(p[0].len() > n && p[1].len() > n && d[0].len() >= n && d[1].len() >= n);
    let mut mean = [0f32; RUN];
    for start in (0..n).step_by(RUN) {
        let len = RUN.min(n - start);
        let o = &mut out[start..start + len];
        let (p0, p1) = (&p[0][start..start + len + 1], &p[1][start..start + len + 1]);
        let (d0, d1) = (&d[0][start..start + len], &d[1][start..start + len]);
        for (k, (o, m)) in o.iter_mut().zip(&mut mean[..len]).enumerate() {
            let t0 = p0[k] + tb * (p0[k + 1] - p0[k]);
            let t1 = p1[k] + tb * (p1[k + 1] - p1[k]);
            *o = t0 + tc * (t1 - t0);
            *m = 0.5 * (d0[k] + d1[k]);
        }
        pass.attenuate(o, &mean[..len]);
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

    /// The fraction at density `d` (a NaN counts as 0).
    #[inline(always)]
    fn at(&self, d: f32) -> f32 {
        let x = (d * self.scale).max(0.0).min((TABLE_BINS - 1) as f32);
        let i = (x as usize).min(TABLE_BINS - 2);
        let (lo, hi) = (self.table[i], self.table[i + 1]);
        lo + (x - i as f32) * (hi - lo)
    }

    /// `out[k] *= self.at(d[k])`, eight at a time in SIMD lanes where the build has AVX2
    /// (the same arithmetic, so the same bits).
    #[inline(always)]
    fn attenuate(&self, out: &mut [f32], d: &[f32]) {
        #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
        let done = lanes::attenuate(self, out, d);
        #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2")))]
        let done = 0;
        for (o, &d) in out[done..].iter_mut().zip(&d[done..]) {
            *o *= self.at(d);
        }
    }
}

/// Where the ray `o + t d` (t >= 0) enters and leaves the box `[lo, hi]` (`None` if it
/// misses); `inv`: `1 / d`.
#[inline]
fn clip(o: [f32; 3], inv: [f32; 3], [lo, hi]: [[f32; 3]; 2]) -> Option<(f32, f32)> {
    let (mut t0, mut t1) = (0f32, f32::INFINITY);
    for a in 0..3 {
        let inv = inv[a];
        let (mut lo, mut hi) = ((lo[a] - o[a]) * inv, (hi[a] - o[a]) * inv);
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
    render_lanes::<true>(rgb, vol, view);
}

/// [`render`], with the samples in SIMD lanes where the build allows if `LANES`, one at
/// a time otherwise (the twin the lanes are tested against).
fn render_lanes<const LANES: bool>(rgb: &mut [u8], vol: &Volume<'_>, view: &View) {
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
    // Pixels outside the image of the box of the blocks to sample see only the
    // background.
    let occupied = occupied(vol);
    let [x_lo, x_hi, y_lo, y_hi] = occupied.map_or([0; 4], |b| box_image(b, view));
    let lattice = Lattice::for_view(vol.n, view);
    // Rows in parallel. (Square tiles of 16 x 16 pixels, for the cache, were no
    // faster: 81-85 ms against 81-85 ms on the bench's frame.)
    let byte = |c: f32| (c.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    rgb.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
        let bg = background(view, y);
        // The background's bytes, converted once a row.
        let bg_px = bg.map(byte);
        let xs = if (y_lo..y_hi).contains(&y) {
            x_lo..x_hi
        } else {
            0..0
        };
        for (x, px) in row.chunks_exact_mut(3).enumerate() {
            if xs.contains(&x) {
                let c = match occupied {
                    Some(occ) => {
                        march::<LANES>(vol, &lattice, view, occ, view.eye, ray(view, x, y), bg)
                    }
                    None => bg,
                };
                for k in 0..3 {
                    px[k] = byte(c[k]);
                }
            } else {
                px.copy_from_slice(&bg_px);
            }
        }
    });
}

/// The box, in cells, of the blocks that a ray must sample (clearance 0), or `None`
/// if there are none: every sample that adds to a pixel lies in it.
fn occupied(vol: &Volume<'_>) -> Option<[[f32; 3]; 2]> {
    let nb = vol.blocks;
    let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
    for (b, _) in vol.clearance.iter().enumerate().filter(|(_, &c)| c == 0) {
        let q = [b % nb[0], (b / nb[0]) % nb[1], b / (nb[0] * nb[1])];
        for a in 0..3 {
            lo[a] = lo[a].min(q[a]);
            hi[a] = hi[a].max(q[a] + 1);
        }
    }
    // Block faces as the walk computes them (`c * block`, exact), the far ones within
    // the grid.
    let blk = vol.block as f32;
    (lo[0] != usize::MAX).then(|| {
        [
            lo.map(|c| c as f32 * blk),
            std::array::from_fn(|a| (hi[a] as f32 * blk).min(vol.n[a] as f32)),
        ]
    })
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
    let inv_len = 1.0 / (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    d.map(|v| v * inv_len)
}

/// The pixel ranges `[x_lo, x_hi, y_lo, y_hi]` (ends excluded) holding the image of the
/// box `[lo, hi]`, widened by two pixels against rounding: the projections of its
/// corners bound it when all are in front of the eye; otherwise the whole image.
fn box_image([lo, hi]: [[f32; 3]; 2], view: &View) -> [usize; 4] {
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
            let c = if corner >> a & 1 == 1 { hi[a] } else { lo[a] };
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
/// where it leaves the clear cube of `2c - 1` blocks around it. Consecutive blocks to be
/// sampled make one run, and a run is sampled when it ends, at every lattice point
/// `t0 + (m + 1/2) step` inside, in one loop: per block, the loop's exit was a branch
/// mispredicted about once a block (a ray takes fewer than two samples in most of the
/// blocks it samples). The samples are numbered from the ray's entry, so skipping
/// changes which are taken, never where they are.
///
/// From a block to be sampled the walk steps to the neighbour across the nearest face,
/// keeping each axis's face crossing `tmax` (each computed from the face's position,
/// not accumulated, so that it has the same bits however the block was reached).
///
/// The walk covers only the part of the ray inside `occupied`, the box of the blocks to
/// be sampled (`occupied`): a ray that misses it is background, and the others start
/// where they enter it, their lattice still numbered from the grid's box.
#[inline]
fn march<const LANES: bool>(
    vol: &Volume<'_>,
    lattice: &Lattice,
    view: &View,
    occupied: [[f32; 3]; 2],
    o: [f32; 3],
    d: [f32; 3],
    bg: [f32; 3],
) -> [f32; 3] {
    let inv = d.map(|x| 1.0 / x);
    let grid = [[0.0; 3], vol.n.map(|c| c as f32)];
    let (Some((t0, t1)), Some((ta, tb))) = (clip(o, inv, grid), clip(o, inv, occupied)) else {
        return bg;
    };
    // The occupied box lies in the grid's; the bounds guard against rounding.
    let (ta, t1) = (ta.max(t0), tb.min(t1));
    if ta >= t1 {
        return bg;
    }
    let mut ray = Ray {
        o,
        d,
        t0,
        col: [0.0; 3],
        trans: 1.0,
        m: 0.0,
    };
    let blk = vol.block as f32;
    // Exact for the power-of-two blocks in use; otherwise a rounding that only moves a
    // point near a face into the neighbouring block, which the clamps below allow for.
    let inv_blk = 1.0 / blk;
    let nb = vol.blocks;
    let solids = !vol.block_solid.is_empty();
    // The far face of block `c` (as a float, exact) along axis `a`, in the ray's
    // direction, as a ray parameter.
    let ahead = d.map(|x| if x > 0.0 { 1.0f32 } else { 0.0 });
    let face = |a: usize, c: f32| {
        if d[a] != 0.0 {
            ((c + ahead[a]) * blk - o[a]) * inv[a]
        } else {
            f32::INFINITY
        }
    };
    let stride = [1, nb[0], nb[0] * nb[1]];
    // The entry block.
    let mid = ta + 0.5 * (t1 - ta).min(view.step);
    let mut q: [usize; 3] = std::array::from_fn(|a| {
        ((((o[a] + mid * d[a]) * inv_blk).max(0.0)) as usize).min(nb[a] - 1)
    });
    // The block as floats and as an index, kept with it.
    let mut qf = q.map(|c| c as f32);
    let mut bi = q[0] + stride[1] * q[1] + stride[2] * q[2];
    let mut tmax: [f32; 3] = std::array::from_fn(|a| face(a, qf[a]));
    // The run being gathered: its end and whether a block in it holds a solid.
    let mut run: Option<(f32, bool)> = None;
    // Where the clear stretch since the last run ends: the next run starts at the first
    // lattice point past it (at first, where the ray enters the occupied box).
    let mut gap: Option<f32> = Some(ta);
    // Each move crosses at least one block face ahead, so an exact walk ends within
    // nb[0] + nb[1] + nb[2] moves; the bound is twice that, so that rounding at a cube's
    // edge can never keep a ray going.
    for _ in 0..2 * (nb[0] + nb[1] + nb[2]) {
        let clear = vol.clearance[bi];
        if clear <= 1 {
            // A block to be sampled, or a clear one next to one (its clear cube is
            // itself): leave through the nearest face (3: the end of the walk first).
            let mut exit = t1;
            let mut axis = 3;
            for (a, &ta) in tmax.iter().enumerate() {
                if ta < exit {
                    exit = ta;
                    axis = a;
                }
            }
            if clear == 0 {
                if let Some(e) = gap.take() {
                    ray.skip_to(e, view.step);
                }
                let solid = solids && vol.block_solid[bi] > 0.0;
                run = Some((exit, run.is_some_and(|r| r.1) || solid));
            } else {
                if let Some(c) = ray.flush::<LANES>(&mut run, vol, lattice, view) {
                    return c;
                }
                gap = Some(exit);
            }
            if axis == 3 {
                break;
            }
            if d[axis] > 0.0 {
                if q[axis] + 1 >= nb[axis] {
                    break;
                }
                q[axis] += 1;
                qf[axis] += 1.0;
                bi += stride[axis];
            } else {
                if q[axis] == 0 {
                    break;
                }
                q[axis] -= 1;
                qf[axis] -= 1.0;
                bi -= stride[axis];
            }
            tmax[axis] = face(axis, qf[axis]);
            continue;
        }
        if let Some(c) = ray.flush::<LANES>(&mut run, vol, lattice, view) {
            return c;
        }
        // The clear cube around q, within the grid, and where the ray leaves it.
        let r = usize::from(clear - 1);
        let lo = q.map(|c| c.saturating_sub(r));
        let hi: [usize; 3] = std::array::from_fn(|a| (q[a] + r).min(nb[a] - 1));
        let mut exit = t1;
        let mut axis = 3;
        for a in 0..3 {
            let ta = face(a, if d[a] > 0.0 { hi[a] } else { lo[a] } as f32);
            if ta < exit {
                exit = ta;
                axis = a;
            }
        }
        gap = Some(exit);
        if axis == 3 {
            break;
        }
        // The next block: across the exit face on its axis, and where the ray is on the
        // others (kept within the cube, which rounding could leave).
        for a in 0..3 {
            if a != axis {
                let c = ((o[a] + exit * d[a]) * inv_blk).max(0.0) as usize;
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
        qf = q.map(|c| c as f32);
        bi = q[0] + stride[1] * q[1] + stride[2] * q[2];
        tmax = std::array::from_fn(|a| face(a, qf[a]));
    }
    if let Some(c) = ray.flush::<LANES>(&mut run, vol, lattice, view) {
        return c;
    }
    std::array::from_fn(|k| ray.col[k] + ray.trans * bg[k])
}

/// A ray being composited: origin and unit direction (cell units), entry parameter, the
/// colour and transmittance so far, and the number of the next lattice point.
struct Ray {
    o: [f32; 3],
    d: [f32; 3],
    t0: f32,
    col: [f32; 3],
    trans: f32,
    m: f32,
}

impl Ray {
    /// Samples the run gathered so far, if any (`run`: its end and whether a block in it
    /// holds a solid), and clears it: [`Ray::sample`].
    #[inline(always)]
    fn flush<const LANES: bool>(
        &mut self,
        run: &mut Option<(f32, bool)>,
        vol: &Volume<'_>,
        lattice: &Lattice,
        view: &View,
    ) -> Option<[f32; 3]> {
        let (end, solid) = run.take()?;
        self.sample::<LANES>(vol, lattice, view, end, solid)
    }

    /// Composites the lattice points from the next one up to `end` (excluded), testing
    /// for the solid surface if `solid`: `Some(colour)` when the ray ends there (opaque,
    /// or on a solid). `LANES`: the samples are taken eight at a time in SIMD lanes
    /// ([`lanes::eight`], the same arithmetic, so the same bits) where the build has
    /// AVX2; otherwise, or if false, one at a time.
    #[inline(always)]
    fn sample<const LANES: bool>(
        &mut self,
        vol: &Volume<'_>,
        lattice: &Lattice,
        view: &View,
        end: f32,
        solid: bool,
    ) -> Option<[f32; 3]> {
        #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
        if LANES && lattice.lanes {
            return self.sample_eights(vol, lattice, view, end, solid);
        }
        let (o, d) = (self.o, self.d);
        let mut t = self.t(view.step);
        while t < end {
            let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
            let corner = Corner::new(lattice, p);
            let hit = solid && corner.sample(vol.solid) >= 0.5;
            let rho = || corner.sample(vol.density);
            if let Some(c) = self.take(vol, lattice, view, t, hit, rho, || corner.sample(vol.light))
            {
                return Some(c);
            }
            t = self.t(view.step);
        }
        None
    }

    /// [`Ray::sample`] eight lattice points at a time.
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    #[inline(always)]
    fn sample_eights(
        &mut self,
        vol: &Volume<'_>,
        lattice: &Lattice,
        view: &View,
        end: f32,
        solid: bool,
    ) -> Option<[f32; 3]> {
        let step = view.step;
        let mut t = self.t(step);
        while t < end {
            let e = lanes::eight(
                vol,
                lattice,
                [self.o, self.d],
                [self.t0, self.m, step],
                solid,
                view,
            );
            if !e.opaque && !solid {
                // No sample with extinction: move past them.
                let left = ((end - t) / step).ceil();
                if left > 8.0 {
                    self.m += 8.0;
                    t = self.t(step);
                    continue;
                }
            }
            for k in 0..8 {
                let hit = solid && e.solid[k] >= 0.5;
                if let Some(c) = self.take(vol, lattice, view, t, hit, || e.rho[k], || e.lit[k]) {
                    return Some(c);
                }
                t = self.t(step);
                if t >= end {
                    break;
                }
            }
        }
        None
    }

    /// The ray parameter of the next lattice point.
    #[inline(always)]
    fn t(&self, step: f32) -> f32 {
        self.t0 + (self.m + 0.5) * step
    }

    /// Takes the lattice point at `t`: the solid's surface if `hit` (the occupancy
    /// there is at least one half), otherwise the sample of density `rho()` lit by
    /// `lit()`, then moves to the next point. `Some(colour)` when the ray ends there.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn take(
        &mut self,
        vol: &Volume<'_>,
        lattice: &Lattice,
        view: &View,
        t: f32,
        hit: bool,
        rho: impl FnOnce() -> f32,
        lit: impl FnOnce() -> f32,
    ) -> Option<[f32; 3]> {
        if hit {
            return Some(surface(vol, lattice, view, self, t));
        }
        let c = self.composite(view, rho(), lit);
        self.m += 1.0;
        c
    }

    /// Moves on to the first lattice point at or past `t` (from one not past it).
    #[inline(always)]
    fn skip_to(&mut self, t: f32, step: f32) {
        self.m = self.m.max(((t - self.t0) / step - 0.5).ceil());
    }

    /// Adds a sample of density `rho` lit by `lit()` (looked up only if the sample has
    /// extinction): `Some(colour)` when the ray is then opaque.
    #[inline(always)]
    fn composite(&mut self, view: &View, rho: f32, lit: impl FnOnce() -> f32) -> Option<[f32; 3]> {
        let [cr, cg, cb, a] = view.lookup(rho);
        if a > 0.0 {
            let w = self.trans * (view.ambient + lit());
            self.col[0] += w * cr;
            self.col[1] += w * cg;
            self.col[2] += w * cb;
            self.trans *= 1.0 - a;
            if self.trans < EARLY_STOP {
                return Some(self.col);
            }
        }
        None
    }
}

/// Eight samples of a ray, or eight cells of the light sweep, at once in AVX2 lanes.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
mod lanes {
    use super::{Lattice, Pass, View, Volume, TABLE_BINS};
    use core::arch::x86_64::*;

    /// [`Pass::attenuate`] over the leading multiple of eight of `out`; returns how many
    /// were done.
    #[inline(always)]
    pub(super) fn attenuate(pass: &Pass, out: &mut [f32], d: &[f32]) -> usize {
        let n = out.len().min(d.len()) / 8 * 8;
        // SAFETY: the build enables AVX2 (the module's cfg); loads and stores stay within
        // the first `n` values of `out` and `d`; each gathered index is clamped to
        // `0..=TABLE_BINS - 2` (a NaN truncates to i32::MIN, raised to 0 by the max), so
        // it and the one after it are within the table.
        unsafe {
            let scale = _mm256_set1_ps(pass.scale);
            let top = _mm256_set1_ps((TABLE_BINS - 1) as f32);
            let last = _mm256_set1_epi32((TABLE_BINS - 2) as i32);
            let table = pass.table.as_ptr();
            for k in (0..n).step_by(8) {
                let x = _mm256_mul_ps(_mm256_loadu_ps(d.as_ptr().add(k)), scale);
                let x = _mm256_min_ps(_mm256_max_ps(x, _mm256_setzero_ps()), top);
                let i = _mm256_min_epi32(
                    _mm256_max_epi32(_mm256_cvttps_epi32(x), _mm256_setzero_si256()),
                    last,
                );
                let lo = _mm256_i32gather_ps::<4>(table, i);
                let hi = _mm256_i32gather_ps::<4>(table.add(1), i);
                let f = _mm256_sub_ps(x, _mm256_cvtepi32_ps(i));
                let at = _mm256_add_ps(lo, _mm256_mul_ps(f, _mm256_sub_ps(hi, lo)));
                let o = out.as_mut_ptr().add(k);
                _mm256_storeu_ps(o, _mm256_mul_ps(_mm256_loadu_ps(o), at));
            }
        }
        n
    }

    /// The fields at eight consecutive lattice points of a ray.
    pub(super) struct Eight {
        pub rho: [f32; 8],
        /// Light (0 unless some sample is `opaque`).
        pub lit: [f32; 8],
        /// Whether some sample's tabulated bin is at or past the first with opacity.
        pub opaque: bool,
        /// Solid occupancy (0 unless asked for).
        pub solid: [f32; 8],
    }

    /// Density, light and (if `solid`) occupancy at the lattice points `m + k`, `k` in
    /// `0..8`, of the ray `o + t d` (`[o, d]`), `t = t0 + (m + k + 1/2) step` (`[t0, m,
    /// step]`): the scalar path's [`super::Corner`] and trilinear sums, operation for
    /// operation, with the eight corners of each sample gathered. Points past the run's
    /// end are sampled too (clamped into the grid); the caller ignores them.
    #[inline(always)]
    pub(super) fn eight(
        vol: &Volume<'_>,
        l: &Lattice,
        [o, d]: [[f32; 3]; 2],
        [t0, m, step]: [f32; 3],
        solid: bool,
        view: &View,
    ) -> Eight {
        let density = &vol.density[..l.cells];
        let light = &vol.light[..l.cells];
        let occupancy = if solid {
            &vol.solid[..l.cells]
        } else {
            density
        };
        let mut e = Eight {
            rho: [0.0; 8],
            lit: [0.0; 8],
            opaque: false,
            solid: [0.0; 8],
        };
        // SAFETY: the build enables AVX2 (the module's cfg). Each gathered index is
        // `base + o` with the corner cell at most `n - 2` along every axis with a stride
        // in `l.d` (clamped below, as in `Corner::new`) and `o` a sum of those strides,
        // so it is at most the last cell's index: below `l.cells`, the length of every
        // field gathered from. `l.lanes` guarantees the indices fit in i32.
        unsafe {
            let k = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
            let half = _mm256_set1_ps(0.5);
            let mk = _mm256_add_ps(_mm256_set1_ps(m), k);
            let t = _mm256_add_ps(
                _mm256_set1_ps(t0),
                _mm256_mul_ps(_mm256_add_ps(mk, half), _mm256_set1_ps(step)),
            );
            let mut c = [_mm256_setzero_si256(); 3];
            let mut f = [_mm256_setzero_ps(); 3];
            for a in 0..3 {
                let p = _mm256_add_ps(_mm256_set1_ps(o[a]), _mm256_mul_ps(t, _mm256_set1_ps(d[a])));
                let x = _mm256_min_ps(
                    _mm256_max_ps(_mm256_sub_ps(p, half), _mm256_setzero_ps()),
                    _mm256_set1_ps(l.top[a]),
                );
                let ci = _mm256_min_epi32(_mm256_cvttps_epi32(x), _mm256_set1_epi32(l.last[a]));
                f[a] = _mm256_sub_ps(x, _mm256_cvtepi32_ps(ci));
                c[a] = ci;
            }
            let base = _mm256_add_epi32(
                c[0],
                _mm256_add_epi32(
                    _mm256_mullo_epi32(c[1], _mm256_set1_epi32(l.nx as i32)),
                    _mm256_mullo_epi32(c[2], _mm256_set1_epi32(l.nxy as i32)),
                ),
            );
            let [_, dy, dz] = l.d.map(|s| s as i32);
            let lerp = |a: __m256, b: __m256, t: __m256| {
                _mm256_add_ps(a, _mm256_mul_ps(t, _mm256_sub_ps(b, a)))
            };
            // Each corner and its neighbour along x (`dx` is 1) are gathered as one
            // 64-bit pair, four lanes a gather; split into the two values, the lanes come
            // in the order 0, 1, 4, 5, 2, 3, 6, 7, and swapping the middle two 64-bit
            // quarters converts between that order and the natural one either way.
            let swap = |v: __m256| {
                _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(v)))
            };
            let fs = f.map(swap);
            let trilinear = |field: &[f32]| {
                let pairs = field.as_ptr().cast::<f64>();
                let along_x = |off: i32| {
                    let i = _mm256_add_epi32(base, _mm256_set1_epi32(off));
                    let a = _mm256_i32gather_pd::<4>(pairs, _mm256_castsi256_si128(i));
                    let b = _mm256_i32gather_pd::<4>(pairs, _mm256_extracti128_si256::<1>(i));
                    let (a, b) = (_mm256_castpd_ps(a), _mm256_castpd_ps(b));
                    let lo = _mm256_shuffle_ps::<0b10_00_10_00>(a, b);
                    let hi = _mm256_shuffle_ps::<0b11_01_11_01>(a, b);
                    lerp(lo, hi, fs[0])
                };
                let x00 = along_x(0);
                let x10 = along_x(dy);
                let x01 = along_x(dz);
                let x11 = along_x(dz + dy);
                let y0 = lerp(x00, x10, fs[1]);
                let y1 = lerp(x01, x11, fs[1]);
                swap(lerp(y0, y1, fs[2]))
            };
            let rho = trilinear(density);
            _mm256_storeu_ps(e.rho.as_mut_ptr(), rho);
            // The table bins of `View::lookup`; the light only where one has opacity.
            let x = _mm256_min_ps(
                _mm256_max_ps(
                    _mm256_mul_ps(rho, _mm256_set1_ps(view.table_scale)),
                    _mm256_setzero_ps(),
                ),
                _mm256_set1_ps((TABLE_BINS - 1) as f32),
            );
            let bin = _mm256_cvttps_epi32(_mm256_add_ps(x, half));
            let past = _mm256_cmpgt_epi32(bin, _mm256_set1_epi32(l.opaque_from - 1));
            e.opaque = _mm256_movemask_epi8(past) != 0;
            if e.opaque {
                _mm256_storeu_ps(e.lit.as_mut_ptr(), trilinear(light));
            }
            if solid {
                _mm256_storeu_ps(e.solid.as_mut_ptr(), trilinear(occupancy));
            }
        }
        e
    }
}

/// The ray's colour plus the solid surface met between the samples at `t - step` and
/// `t`: found by bisection, then shaded by Lambert with the occupancy's gradient as the
/// normal and the light reaching it, seen through the ray's transmittance.
#[cold]
fn surface(vol: &Volume<'_>, lattice: &Lattice, view: &View, ray: &Ray, t: f32) -> [f32; 3] {
    let (o, d, trans, mut col) = (ray.o, ray.d, ray.trans, ray.col);
    let trilinear = |f: &[f32], p: [f32; 3]| Corner::new(lattice, p).sample(f);
    let (mut lo, mut hi) = (t - view.step, t);
    for _ in 0..5 {
        let mid = 0.5 * (lo + hi);
        let q = [o[0] + mid * d[0], o[1] + mid * d[1], o[2] + mid * d[2]];
        if trilinear(vol.solid, q) >= 0.5 {
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
        trilinear(vol.solid, lo) - trilinear(vol.solid, hi)
    });
    let gl = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt().max(1e-6);
    let ndl = ((g[0] * view.to_light[0] + g[1] * view.to_light[1] + g[2] * view.to_light[2]) / gl)
        .max(0.0);
    let lit = trilinear(vol.light, p);
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
        let mut slab = vec![0.0; 32];
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

    /// Eyes and targets around the two balls' grid: straight on, oblique, inside the
    /// grid, and from below.
    const FOUR_VIEWS: [([f32; 3], [f32; 3]); 4] = [
        ([20.0, 20.0, 90.0], [20.0, 20.0, 20.0]),
        ([-30.0, 55.0, 70.0], [18.0, 18.0, 18.0]),
        ([20.0, 20.0, 20.0], [0.0, 40.0, 0.0]),
        ([75.0, -20.0, -35.0], [12.0, 24.0, 14.0]),
    ];

    /// The light from straight above through the two balls' grid, with the test view's
    /// transfer function.
    fn light_from_above(n: [usize; 3], density: &[f32]) -> Vec<f32> {
        let view = smoke_view([20.0, 20.0, 90.0], [20.0, 20.0, 20.0]);
        let mut light = vec![0.0; density.len()];
        let mut slab = vec![0.0; 2 * n[0] * n[2]];
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

    /// The samples taken eight at a time in SIMD lanes give the same bits as one at a
    /// time, with a solid ball among the smoke, from outside and inside the grid.
    #[test]
    fn the_lanes_give_the_same_pixels_as_one_sample_at_a_time() {
        let (n, density) = two_balls();
        let light = light_from_above(n, &density);
        let solid: Vec<f32> = (0..40 * 40 * 40)
            .map(|i| {
                let p = [(i % 40) as f32, ((i / 40) % 40) as f32, (i / 1600) as f32];
                let r2: f32 = (0..3).map(|a| (p[a] - [28.0, 20.0, 20.0][a]).powi(2)).sum();
                f32::from(u8::from(r2 < 16.0))
            })
            .collect();
        let nb = [10, 10, 10];
        let mut blocks = vec![0.0; 1000];
        block_max(&mut blocks, &density, n, 4);
        let mut solid_blocks = vec![0.0; 1000];
        block_max(&mut solid_blocks, &solid, n, 4);
        for (eye, target) in FOUR_VIEWS {
            let view = smoke_view(eye, target);
            let mut clear = vec![0u8; 1000];
            clearance(&mut clear, &mut [0; 10], &blocks, &solid_blocks, nb, &view);
            let vol = Volume {
                n,
                density: &density,
                light: &light,
                solid: &solid,
                block: 4,
                blocks: nb,
                clearance: &clear,
                block_solid: &solid_blocks,
            };
            let mut lanes = vec![0u8; 64 * 48 * 3];
            let mut single = vec![0u8; 64 * 48 * 3];
            render(&mut lanes, &vol, &view);
            render_lanes::<false>(&mut single, &vol, &view);
            assert_eq!(lanes, single, "eye {eye:?}");
            assert!(lanes.iter().any(|&c| c > 120), "the smoke shows");
        }
    }

    /// The light sweep's contiguous stencil agrees with the cell-by-cell rule (the
    /// previous slab's light at the point one slab towards the light, bilinear, times
    /// the passing fraction at the mean density) for lights along each axis, slanted
    /// either way; the stencil's weights round differently, hence the tolerance.
    #[test]
    fn the_light_sweep_follows_the_cell_by_cell_rule() {
        let (n, density) = two_balls();
        let tf = smoke_view([0.0; 3], [1.0; 3]).transfer;
        for to_light in [
            [0.4, 1.0, 0.3],
            [-0.7, -1.0, 0.2],
            [1.0, 0.3, -0.45],
            [0.1, -0.25, -1.0],
            [0.0, 1.0, 0.0],
        ] {
            let l = (to_light.iter().map(|x: &f32| x * x).sum::<f32>()).sqrt();
            let to_light = to_light.map(|x| x / l);
            let mut got = vec![0.0; density.len()];
            let mut slab = vec![0.0; 2 * 40 * 40];
            light_transmittance(&mut got, &mut slab, &density, n, to_light, &tf);
            // The rule, cell by cell along the dominant axis.
            let a = (0..3)
                .max_by(|&x, &y| to_light[x].abs().total_cmp(&to_light[y].abs()))
                .unwrap();
            let b = usize::from(a == 0);
            let c = 3 - a - b;
            let la = to_light[a];
            let (sb, sc) = (to_light[b] / la.abs(), to_light[c] / la.abs());
            let pass = Pass::new(&tf, (1.0 + sb * sb + sc * sc).sqrt());
            let at = |ia: usize, ib: usize, ic: usize| {
                let mut q = [0; 3];
                q[a] = ia;
                q[b] = ib;
                q[c] = ic;
                index(n, q[0], q[1], q[2])
            };
            let mut want = vec![1.0f32; density.len()];
            for step in 1..n[a] {
                let (ia, pa) = if la > 0.0 {
                    (n[a] - 1 - step, n[a] - step)
                } else {
                    (step, step - 1)
                };
                for ic in 0..n[c] {
                    for ib in 0..n[b] {
                        let fb = (ib as f32 + sb).clamp(0.0, (n[b] - 1) as f32);
                        let fc = (ic as f32 + sc).clamp(0.0, (n[c] - 1) as f32);
                        let (b0, c0) = (fb as usize, fc as usize);
                        let (b1, c1) = ((b0 + 1).min(n[b] - 1), (c0 + 1).min(n[c] - 1));
                        let (tb, tc) = (fb - b0 as f32, fc - c0 as f32);
                        let v = |x, y| want[at(pa, x, y)];
                        let t0 = v(b0, c0) + tb * (v(b1, c0) - v(b0, c0));
                        let t1 = v(b0, c1) + tb * (v(b1, c1) - v(b0, c1));
                        let d = 0.5 * (density[at(ia, ib, ic)] + density[at(pa, b0, c0)]);
                        want[at(ia, ib, ic)] = (t0 + tc * (t1 - t0)) * pass.at(d);
                    }
                }
            }
            let worst = got
                .iter()
                .zip(&want)
                .map(|(g, w)| (g - w).abs())
                .fold(0.0f32, f32::max);
            assert!(worst < 1e-5, "light {to_light:?}: off by {worst}");
            assert!(want.iter().any(|&w| w < 0.5), "the balls cast shadows");
        }
    }

    /// Skipping clear blocks changes no pixel, from views straight on and oblique: the
    /// samples stay on the same lattice and the skipped ones would have added nothing;
    /// so does starting each ray where it enters the box of the blocks to sample.
    #[test]
    fn empty_space_skipping_changes_no_pixel() {
        let (n, density) = two_balls();
        let light = light_from_above(n, &density);
        let nb = [10, 10, 10];
        let mut blocks = vec![0.0; 1000];
        block_max(&mut blocks, &density, n, 4);
        for (eye, target) in FOUR_VIEWS {
            let view = smoke_view(eye, target);
            let mut clear = vec![0u8; 1000];
            clearance(&mut clear, &mut [0; 10], &blocks, &[], nb, &view);
            let skipping = Volume {
                n,
                density: &density,
                light: &light,
                solid: &[],
                block: 4,
                blocks: nb,
                clearance: &clear,
                block_solid: &[],
            };
            let image = |vol: &Volume<'_>| {
                let mut rgb = vec![0u8; 64 * 48 * 3];
                render(&mut rgb, vol, &view);
                rgb
            };
            // Rays start at the box of the blocks to sample, well inside the grid.
            let [lo, hi] = occupied(&skipping).expect("blocks to sample");
            let inside: f32 = (0..3).map(|a| hi[a] - lo[a]).product();
            assert!(
                inside < 0.5 * 40f32.powi(3),
                "occupied box {lo:?} to {hi:?}"
            );
            let skipped = image(&skipping);
            let full = image(&Volume {
                clearance: &[0; 1000],
                ..skipping
            });
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
            let [x0, x1, y0, y1] =
                box_image(occupied(&vol).expect("every block is sampled"), &view);
            let mut culled = 0;
            for y in 0..48 {
                for x in 0..64 {
                    let c = march::<true>(
                        &vol,
                        &Lattice::for_view(vol.n, &view),
                        &view,
                        occupied(&vol).expect("every block is sampled"),
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
