//! Tile rasterization in f32 and exact fixed-point edge functions.
//!
//! A frame is cut into tiles of samples; each tile owns a small G-buffer (inverse depth,
//! primitive id, two attributes per sample) that stays in cache while every primitive
//! binned to it is drawn, and is shaded afterwards (deferred shading).
//!
//! Triangles use the half-space (edge function) method of Pineda, "A parallel algorithm
//! for polygon rasterization" (SIGGRAPH 1988), evaluated incrementally on integer vertex
//! coordinates with [`SUBPIXEL_BITS`] of sub-sample precision, so that edge values are exact
//! and the top-left fill rule (as in Direct3D) covers each sample of two triangles sharing
//! an edge exactly once: no cracks, no double blending. Depth is the inverse view depth
//! `q = 1/z`, which is affine in screen space, so it is interpolated with the screen-space
//! barycentrics; larger `q` is nearer and `0` means empty.
//!
//! Sample `(sx, sy)` has its centre at `(sx + 0.5, sy + 0.5)` in sample units, y down.

/// Fractional bits of the fixed-point vertex coordinates (1/256 of a sample).
pub const SUBPIXEL_BITS: u32 = 8;
/// The id of an empty sample.
pub const NO_PRIM: u32 = u32::MAX;
/// Vertices farther than this from the origin (in samples) are rejected by
/// [`FixedTri::new`]: it keeps the edge products inside i64 (2^(22+8+1) squared < 2^63).
pub const GUARD_BAND: f32 = 4_194_304.0;

const ONE: i64 = 1 << SUBPIXEL_BITS;
const HALF: i64 = ONE / 2;

/// A tile: a rectangle of samples and its G-buffer, row-major, `w * h` entries each.
pub struct Tile<'a> {
    /// First sample column.
    pub x0: i32,
    /// First sample row.
    pub y0: i32,
    /// Width in samples.
    pub w: usize,
    /// Height in samples.
    pub h: usize,
    /// Inverse view depth `1/z` (1/m); 0 where empty. Larger is nearer.
    pub depth: &'a mut [f32],
    /// Primitive id, [`NO_PRIM`] where empty.
    pub prim: &'a mut [u32],
    /// Two attributes: the screen-space barycentrics `(b1, b2)` of vertices 1 and 2 for
    /// triangles, the offset from the centre in radii `(dx, dy)` for discs.
    pub attr: &'a mut [[f32; 2]],
}

impl Tile<'_> {
    fn check(&self) {
        let n = self.w * self.h;
        assert!(
            self.depth.len() == n && self.prim.len() == n && self.attr.len() == n,
            "tile buffers hold w * h samples"
        );
    }
}

/// A triangle on screen: vertices in samples (y down) and their inverse view depths.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScreenTri {
    /// Vertex positions (samples).
    pub p: [[f32; 2]; 3],
    /// Inverse view depths `1/z` (1/m), > 0.
    pub q: [f32; 3],
}

/// A triangle set up for rasterization: fixed-point vertices in counter-clockwise order
/// (positive area, y down), the fill-rule biases and its sample bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FixedTri {
    x: [i64; 3],
    y: [i64; 3],
    bias: [i64; 3],
    q: [f32; 3],
    area2: i64,
    swapped: bool,
    /// Sample bounding box `[x_min, y_min, x_max, y_max)`, not clipped to the screen.
    pub bbox: [i32; 4],
}

fn to_fixed(v: f32) -> i64 {
    (v * ONE as f32).round() as i64
}

impl FixedTri {
    /// Sets up `t`; `None` when it covers no area (degenerate or edge-on), a coordinate is
    /// not finite or lies outside [`GUARD_BAND`].
    pub fn new(t: &ScreenTri) -> Option<FixedTri> {
        if !t
            .p
            .iter()
            .flatten()
            .all(|c| c.is_finite() && c.abs() < GUARD_BAND)
        {
            return None;
        }
        let mut x = t.p.map(|p| to_fixed(p[0]));
        let mut y = t.p.map(|p| to_fixed(p[1]));
        let mut q = t.q;
        let mut area2 = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
        if area2 == 0 {
            return None;
        }
        // Both faces are drawn (cloth): a clockwise triangle is turned round, and the
        // barycentrics written for it are swapped back to the caller's vertex order.
        let swapped = area2 < 0;
        if swapped {
            x.swap(1, 2);
            y.swap(1, 2);
            q.swap(1, 2);
            area2 = -area2;
        }
        // Edge i is opposite vertex i, from vertex i+1 to i+2. With y down and positive
        // area, a top edge runs in +x (dy = 0) and a left edge runs in -y.
        let mut bias = [0; 3];
        for (i, b) in bias.iter_mut().enumerate() {
            let (a, c) = ((i + 1) % 3, (i + 2) % 3);
            let (dx, dy) = (x[c] - x[a], y[c] - y[a]);
            let top_left = dy < 0 || (dy == 0 && dx > 0);
            *b = if top_left { 0 } else { -1 };
        }
        let lo = |v: &[i64; 3]| (v.iter().min().unwrap() >> SUBPIXEL_BITS) as i32;
        let hi = |v: &[i64; 3]| ((v.iter().max().unwrap() >> SUBPIXEL_BITS) + 1) as i32;
        Some(FixedTri {
            bbox: [lo(&x), lo(&y), hi(&x), hi(&y)],
            x,
            y,
            bias,
            q,
            area2,
            swapped,
        })
    }

    /// Twice the area in squared fixed-point units.
    pub fn area2(&self) -> i64 {
        self.area2
    }

    /// Calls `f(index in tile, w1, w2)` for every covered sample of the tile rectangle,
    /// where `w1, w2` are the edge values of vertices 1 and 2 (in the set-up order).
    #[inline(always)]
    fn scan(&self, x0: i32, y0: i32, w: usize, h: usize, mut f: impl FnMut(usize, i64, i64)) {
        let xa = self.bbox[0].max(x0);
        let ya = self.bbox[1].max(y0);
        let xb = self.bbox[2].min(x0 + w as i32);
        let yb = self.bbox[3].min(y0 + h as i32);
        if xa >= xb || ya >= yb {
            return;
        }
        let (px, py) = (xa as i64 * ONE + HALF, ya as i64 * ONE + HALF);
        let mut row = [0i64; 3];
        let mut step_x = [0i64; 3];
        let mut step_y = [0i64; 3];
        for i in 0..3 {
            let (a, c) = ((i + 1) % 3, (i + 2) % 3);
            let (dx, dy) = (self.x[c] - self.x[a], self.y[c] - self.y[a]);
            row[i] = dx * (py - self.y[a]) - dy * (px - self.x[a]) + self.bias[i];
            step_x[i] = -dy * ONE;
            step_y[i] = dx * ONE;
        }
        for sy in ya..yb {
            let mut e = row;
            let base = (sy - y0) as usize * w;
            for sx in xa..xb {
                if (e[0] | e[1] | e[2]) >= 0 {
                    f(base + (sx - x0) as usize, e[1], e[2]);
                }
                e[0] += step_x[0];
                e[1] += step_x[1];
                e[2] += step_x[2];
            }
            row[0] += step_y[0];
            row[1] += step_y[1];
            row[2] += step_y[2];
        }
    }
}

/// Draws `t` into the tile with id `id` where it is nearer than what is there (ties keep
/// the earlier primitive, so the result depends only on drawing order).
pub fn raster_tri(tile: &mut Tile<'_>, t: &FixedTri, id: u32) {
    tile.check();
    let inv = 1.0 / t.area2 as f32;
    let (q0, dq1, dq2) = (t.q[0], t.q[1] - t.q[0], t.q[2] - t.q[0]);
    let (depth, prim, attr) = (&mut *tile.depth, &mut *tile.prim, &mut *tile.attr);
    t.scan(tile.x0, tile.y0, tile.w, tile.h, |i, w1, w2| {
        let b1 = w1 as f32 * inv;
        let b2 = w2 as f32 * inv;
        let q = q0 + b1 * dq1 + b2 * dq2;
        if q > depth[i] {
            depth[i] = q;
            prim[i] = id;
            attr[i] = if t.swapped { [b2, b1] } else { [b1, b2] };
        }
    });
}

/// Marks the samples `t` covers in a coverage mask of the tile rectangle (no depth test).
pub fn raster_cover(mask: &mut [u8], x0: i32, y0: i32, w: usize, h: usize, t: &FixedTri) {
    assert_eq!(mask.len(), w * h, "mask holds w * h samples");
    t.scan(x0, y0, w, h, |i, _, _| mask[i] = 1);
}

/// A sphere seen as a disc: screen centre and radius (samples), view depth of the centre
/// and world radius (m), so that depth follows the sphere's front surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Disc {
    /// Centre (samples).
    pub c: [f32; 2],
    /// Radius (samples), > 0.
    pub r: f32,
    /// View depth of the centre (m).
    pub z: f32,
    /// World radius (m), < `z`.
    pub radius: f32,
}

impl Disc {
    /// Sample bounding box `[x_min, y_min, x_max, y_max)`.
    pub fn bbox(&self) -> [i32; 4] {
        [
            (self.c[0] - self.r).floor() as i32,
            (self.c[1] - self.r).floor() as i32,
            (self.c[0] + self.r).ceil() as i32 + 1,
            (self.c[1] + self.r).ceil() as i32 + 1,
        ]
    }
}

/// Draws the disc into the tile with id `id`; the attributes are the sample's offset from
/// the centre in radii, from which shading rebuilds the sphere's normal.
pub fn raster_disc(tile: &mut Tile<'_>, d: &Disc, id: u32) {
    tile.check();
    let bb = d.bbox();
    let xa = bb[0].max(tile.x0);
    let ya = bb[1].max(tile.y0);
    let xb = bb[2].min(tile.x0 + tile.w as i32);
    let yb = bb[3].min(tile.y0 + tile.h as i32);
    let inv_r = 1.0 / d.r;
    for sy in ya..yb {
        let dy = (sy as f32 + 0.5 - d.c[1]) * inv_r;
        let base = (sy - tile.y0) as usize * tile.w;
        for sx in xa..xb {
            let dx = (sx as f32 + 0.5 - d.c[0]) * inv_r;
            let r2 = dx * dx + dy * dy;
            if r2 < 1.0 {
                let q = 1.0 / (d.z - d.radius * (1.0 - r2).sqrt());
                let i = base + (sx - tile.x0) as usize;
                if q > tile.depth[i] {
                    tile.depth[i] = q;
                    tile.prim[i] = id;
                    tile.attr[i] = [dx, dy];
                }
            }
        }
    }
}

/// `x^32` by five squarings: the Blinn-Phong lobe of exponent 32 without `powf`.
#[inline(always)]
pub fn pow32(x: f32) -> f32 {
    let x2 = x * x;
    let x4 = x2 * x2;
    let x8 = x4 * x4;
    let x16 = x8 * x8;
    x16 * x16
}
