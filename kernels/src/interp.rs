//! Bilinear and trilinear interpolation of fields sampled on regular grids.
//!
//! Course notes, section 2: inside one cell with fractional coordinates `u, v (, w)` in
//! [0, 1], `F(u, v) = (1-v)[(1-u) F00 + u F10] + v[(1-u) F01 + u F11]`, and trilinear is
//! the linear blend of two bilinear faces, `F(u, v, w) = (1-w) F_front + w F_back`.
//!
//! Grids store one flat array per scalar field with x fastest: node (i, j, k) is at
//! `i + nx (j + ny k)`. Vector fields are one such array per component. Queries outside
//! the grid are clamped to its boundary (the field is extended by its boundary values);
//! a NaN coordinate gives a NaN sample, so a later finiteness check sees it.

/// A regular 2-D grid of nodes: `n[0] x n[1]` nodes at `origin + (i, j) * spacing`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid2 {
    /// Nodes along x and y, each at least 2.
    pub n: [usize; 2],
    /// Position of node (0, 0).
    pub origin: [f64; 2],
    /// Distance between neighbouring nodes along x and y, each > 0.
    pub spacing: [f64; 2],
}

/// A regular 3-D grid of nodes: `n[0] x n[1] x n[2]` nodes at `origin + (i, j, k) * spacing`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid3 {
    /// Nodes along x, y and z, each at least 2.
    pub n: [usize; 3],
    /// Position of node (0, 0, 0).
    pub origin: [f64; 3],
    /// Distance between neighbouring nodes along each axis, each > 0.
    pub spacing: [f64; 3],
}

impl Grid2 {
    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.n[0] * self.n[1]
    }
    /// Whether the grid has no nodes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl Grid3 {
    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }
    /// Whether the grid has no nodes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Whether `p` lies in the grid's box (false for NaN).
    pub fn contains(&self, p: [f64; 3]) -> bool {
        (0..3).all(|a| {
            let t = (p[a] - self.origin[a]) / self.spacing[a];
            t >= 0.0 && t <= (self.n[a] - 1) as f64
        })
    }

    /// A grid of `n` nodes spanning the box `[lo, hi]` (corners are nodes).
    pub fn spanning(n: [usize; 3], lo: [f64; 3], hi: [f64; 3]) -> Self {
        Self {
            n,
            origin: lo,
            spacing: core::array::from_fn(|a| (hi[a] - lo[a]) / (n[a] - 1) as f64),
        }
    }
}

/// Bilinear blend of four corner values; `u, v` are the fractions along x and y.
#[inline]
pub fn bilinear(f00: f64, f10: f64, f01: f64, f11: f64, u: f64, v: f64) -> f64 {
    let a = (1.0 - u) * f00 + u * f10;
    let b = (1.0 - u) * f01 + u * f11;
    (1.0 - v) * a + v * b
}

/// Trilinear blend of eight corner values `c[i + 2j + 4k]`; `u, v, w` the fractions.
#[inline]
pub fn trilinear(c: &[f64; 8], u: f64, v: f64, w: f64) -> f64 {
    let front = bilinear(c[0], c[1], c[2], c[3], u, v);
    let back = bilinear(c[4], c[5], c[6], c[7], u, v);
    (1.0 - w) * front + w * back
}

/// Cell index and fraction along one axis, clamped to the grid.
#[inline]
fn locate(p: f64, origin: f64, h: f64, n: usize) -> (usize, f64) {
    let t = ((p - origin) / h).clamp(0.0, (n - 1) as f64);
    // `as usize` of a NaN is 0; the fraction below stays NaN and poisons the sample.
    let i = (t as usize).min(n - 2);
    (i, t - i as f64)
}

#[inline]
fn cell2(g: &Grid2, p: [f64; 2]) -> ([usize; 4], f64, f64) {
    let (i, u) = locate(p[0], g.origin[0], g.spacing[0], g.n[0]);
    let (j, v) = locate(p[1], g.origin[1], g.spacing[1], g.n[1]);
    let nx = g.n[0];
    let b = i + nx * j;
    ([b, b + 1, b + nx, b + nx + 1], u, v)
}

#[inline]
fn cell3(g: &Grid3, p: [f64; 3]) -> ([usize; 8], [f64; 3]) {
    let (i, u) = locate(p[0], g.origin[0], g.spacing[0], g.n[0]);
    let (j, v) = locate(p[1], g.origin[1], g.spacing[1], g.n[1]);
    let (k, w) = locate(p[2], g.origin[2], g.spacing[2], g.n[2]);
    let (nx, nxy) = (g.n[0], g.n[0] * g.n[1]);
    let b = i + nx * j + nxy * k;
    (
        [
            b,
            b + 1,
            b + nx,
            b + nx + 1,
            b + nxy,
            b + nxy + 1,
            b + nxy + nx,
            b + nxy + nx + 1,
        ],
        [u, v, w],
    )
}

fn check2(g: &Grid2, len: usize) {
    assert!(g.n[0] >= 2 && g.n[1] >= 2, "a grid needs 2 nodes per axis");
    assert_eq!(len, g.len(), "field length must equal the node count");
}

fn check3(g: &Grid3, len: usize) {
    assert!(
        g.n[0] >= 2 && g.n[1] >= 2 && g.n[2] >= 2,
        "a grid needs 2 nodes per axis"
    );
    assert_eq!(len, g.len(), "field length must equal the node count");
}

/// Samples a scalar field on a 2-D grid at `p` (bilinear).
pub fn sample2(field: &[f64], g: Grid2, p: [f64; 2]) -> f64 {
    check2(&g, field.len());
    let (c, u, v) = cell2(&g, p);
    bilinear(field[c[0]], field[c[1]], field[c[2]], field[c[3]], u, v)
}

/// Samples a 2-D vector field (one array per component) at `p` (bilinear).
pub fn sample2_vec(fields: [&[f64]; 2], g: Grid2, p: [f64; 2]) -> [f64; 2] {
    check2(&g, fields[0].len());
    check2(&g, fields[1].len());
    let (c, u, v) = cell2(&g, p);
    core::array::from_fn(|a| {
        let f = fields[a];
        bilinear(f[c[0]], f[c[1]], f[c[2]], f[c[3]], u, v)
    })
}

/// Samples a scalar field on a 3-D grid at `p` (trilinear).
pub fn sample3(field: &[f64], g: Grid3, p: [f64; 3]) -> f64 {
    check3(&g, field.len());
    let (c, [u, v, w]) = cell3(&g, p);
    trilinear(&c.map(|i| field[i]), u, v, w)
}

/// Samples a scalar field on a 3-D grid at `p` with the gradient of the trilinear
/// interpolant (exact within the cell; one-sided at cell faces): what a signed-distance
/// grid gives for a distance and a normal. Outside the grid the point is clamped to it,
/// so callers that care test [`Grid3::contains`] first.
pub fn sample3_grad(field: &[f64], g: Grid3, p: [f64; 3]) -> (f64, [f64; 3]) {
    check3(&g, field.len());
    let (c, [u, v, w]) = cell3(&g, p);
    let f = c.map(|i| field[i]);
    let value = trilinear(&f, u, v, w);
    // d/du of the trilinear form: differences along x of the four x-edges, blended in
    // (v, w); likewise for v and w. Divided by the spacing for world units.
    let du = bilinear(f[1] - f[0], f[3] - f[2], f[5] - f[4], f[7] - f[6], v, w);
    let dv = bilinear(f[2] - f[0], f[3] - f[1], f[6] - f[4], f[7] - f[5], u, w);
    let dw = bilinear(f[4] - f[0], f[5] - f[1], f[6] - f[2], f[7] - f[3], u, v);
    (
        value,
        [du / g.spacing[0], dv / g.spacing[1], dw / g.spacing[2]],
    )
}

/// Samples a 3-D vector field (one array per component) at `p` (trilinear).
pub fn sample3_vec(fields: [&[f64]; 3], g: Grid3, p: [f64; 3]) -> [f64; 3] {
    for f in fields {
        check3(&g, f.len());
    }
    let (c, [u, v, w]) = cell3(&g, p);
    core::array::from_fn(|a| trilinear(&c.map(|i| fields[a][i]), u, v, w))
}

/// Adds `scale` times the 3-D vector field sampled at every point to `out`:
/// `out_i += scale * F(p_i)`. `points` and `out` are component-major Vec3s data of
/// the same length (a force field applied to particles, with `scale` = 1 or a mass).
pub fn sample3_vec_add(out: &mut [f64], fields: [&[f64]; 3], g: Grid3, points: &[f64], scale: f64) {
    for f in fields {
        check3(&g, f.len());
    }
    let n = points.len() / 3;
    assert!(points.len() == 3 * n && out.len() == 3 * n);
    for i in 0..n {
        let p = crate::get3(points, n, i);
        let (c, [u, v, w]) = cell3(&g, p);
        for (a, f) in fields.iter().enumerate() {
            out[a * n + i] += scale * trilinear(&c.map(|k| f[k]), u, v, w);
        }
    }
}
