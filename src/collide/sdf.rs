//! Signed-distance grids: distances sampled at the nodes of a regular grid and read with
//! trilinear interpolation (`kernels::interp::sample3_grad`, whose gradient is the
//! interpolant's exact one), from Batty's SDFGen text files, by sampling a function, or
//! from a closed triangle surface ([`SdfGrid::from_mesh`]).

use crate::io::Mesh;
use crate::validate::ModelError;
use largestep_kernels::collide::bv::Aabb;
use largestep_kernels::collide::prox::{closest_on_triangle, norm2};
use largestep_kernels::interp::Grid3;
use largestep_kernels::v3::sub;

/// A signed-distance grid: distances (m, negative inside) at the nodes of a regular grid,
/// x fastest (`i + n_x (j + n_y k)`).
#[derive(Clone, Debug, PartialEq)]
pub struct SdfGrid {
    /// The grid.
    pub grid: Grid3,
    /// Signed distance at each node (m).
    pub phi: Vec<f64>,
}

impl SdfGrid {
    /// Samples `f` (a signed distance, m) at the nodes of `grid`.
    pub fn sample(grid: Grid3, f: impl Fn([f64; 3]) -> f64) -> SdfGrid {
        let mut phi = Vec::with_capacity(grid.len());
        for k in 0..grid.n[2] {
            for j in 0..grid.n[1] {
                for i in 0..grid.n[0] {
                    let p = [
                        grid.origin[0] + i as f64 * grid.spacing[0],
                        grid.origin[1] + j as f64 * grid.spacing[1],
                        grid.origin[2] + k as f64 * grid.spacing[2],
                    ];
                    phi.push(f(p));
                }
            }
        }
        SdfGrid { grid, phi }
    }

    /// Parses the text format of Batty's SDFGen: `ni nj nk`, then the origin `x y z`, then
    /// the spacing `dx`, then `ni nj nk` distances with i fastest, whitespace-separated.
    /// Errors name the file and line.
    pub fn parse(text: &str, path: &str) -> Result<SdfGrid, crate::io::ReadError> {
        let err = |line: usize, message: String| crate::io::ReadError {
            path: path.to_string(),
            line,
            message,
        };
        let mut tokens = text
            .lines()
            .enumerate()
            .flat_map(|(l, s)| s.split_whitespace().map(move |t| (l + 1, t)));
        let mut last_line = 1;
        let mut next = |what: &str| -> Result<(usize, f64), crate::io::ReadError> {
            match tokens.next() {
                Some((l, t)) => {
                    last_line = l;
                    t.parse::<f64>()
                        .map(|v| (l, v))
                        .map_err(|_| err(l, format!("{what}: expected a number, found `{t}`")))
                }
                None => Err(err(last_line, format!("{what}: the file ends early"))),
            }
        };
        let mut n = [0usize; 3];
        let mut header_line = 1;
        for (a, na) in n.iter_mut().enumerate() {
            let (l, v) = next("grid size")?;
            header_line = l;
            if !(v >= 2.0 && v.fract() == 0.0 && v <= 4096.0) {
                return Err(err(
                    l,
                    format!(
                        "grid size {} = {v}: expected an integer in 2..=4096",
                        ["ni", "nj", "nk"][a]
                    ),
                ));
            }
            *na = v as usize;
        }
        let mut origin = [0.0; 3];
        for o in origin.iter_mut() {
            let (l, v) = next("origin")?;
            if !v.is_finite() {
                return Err(err(l, format!("origin = {v}: must be finite")));
            }
            *o = v;
        }
        let (l, dx) = next("spacing")?;
        if !(dx.is_finite() && dx > 0.0) {
            return Err(err(l, format!("spacing = {dx}: must be finite and > 0")));
        }
        let grid = Grid3 {
            n,
            origin,
            spacing: [dx; 3],
        };
        // What the file can hold before anything is allocated: every distance takes at
        // least a digit and a separator.
        let room = text.len().div_ceil(2);
        if grid.len() > room {
            return Err(err(
                header_line,
                format!(
                    "the header asks for {} x {} x {} = {} distances, but the file's {} bytes hold at most {room}",
                    n[0],
                    n[1],
                    n[2],
                    grid.len(),
                    text.len()
                ),
            ));
        }
        let mut phi = Vec::with_capacity(grid.len());
        for k in 0..grid.len() {
            let (l, v) = next("distance")?;
            if !v.is_finite() {
                return Err(err(l, format!("distance {k} = {v}: must be finite")));
            }
            phi.push(v);
        }
        if let Some((l, t)) = tokens.next() {
            return Err(err(
                l,
                format!("unexpected `{t}` after the {} distances", grid.len()),
            ));
        }
        Ok(SdfGrid { grid, phi })
    }

    /// Reads an SDFGen file (see [`SdfGrid::parse`]) of at most `max_bytes` bytes through
    /// [`crate::io::read_text`].
    pub fn read(path: &std::path::Path, max_bytes: u64) -> Result<SdfGrid, crate::io::ReadError> {
        let text = crate::io::read_text(path, max_bytes)?;
        Self::parse(&text, &path.display().to_string())
    }
}

/// Band of nodes around each triangle (in cells) whose distances are computed exactly.
pub const EXACT_BAND: usize = 2;

impl SdfGrid {
    /// The signed distance field of a closed surface on a grid of spacing `h` (m) covering
    /// its bounds plus `pad` cells on every side.
    ///
    /// - **Near the surface** (nodes within [`EXACT_BAND`] cells of a triangle's box):
    ///   the exact distance to the nearest triangle (`kernels::collide::prox`).
    /// - **Beyond**: closest-triangle propagation by fast sweeping (Zhao 2005; Batty's
    ///   SDFGen), two rounds of the eight sweep orders, each node taking the nearer of its
    ///   own and its upwind neighbours' closest triangles. Each value is the exact
    ///   distance to some triangle, so never below the true distance; it is above only
    ///   where the nearest triangle reached no neighbour (the tests measure how far).
    /// - **Sign**: negative where the winding number about the surface is non-zero
    ///   ([`super::winding_numbers`]), which also gives self-overlapping parts a sign
    ///   (the fallback for self-intersecting surfaces: the non-zero rule).
    ///
    /// The surface must be closed and consistently oriented (every edge in exactly two
    /// triangles, once each way: [`check_closed`]), with finite coordinates and no
    /// degenerate triangle; the grid may hold at most `max_nodes` nodes (checked before
    /// allocating).
    pub fn from_mesh(
        surface: &Mesh,
        h: f64,
        pad: usize,
        max_nodes: usize,
    ) -> Result<SdfGrid, ModelError> {
        check_closed(surface)?;
        if !(h.is_finite() && h > 0.0) {
            return Err(ModelError::Value {
                item: "distance grid",
                index: 0,
                field: "spacing",
                value: h,
                why: "must be finite and > 0",
            });
        }
        let m = surface.as_ref();
        let nv = surface.positions.len() / 3;
        let Aabb { min: lo, max: hi } = Aabb::of_points((0..nv).map(|i| m.vertex(i)));
        let origin = lo.map(|c| c - pad as f64 * h);
        let cells = [0, 1, 2].map(|a| ((hi[a] - lo[a]) / h).ceil() + 2.0 * pad as f64);
        let total: f64 = cells.iter().map(|c| c + 1.0).product();
        if total.is_nan() || total > max_nodes as f64 {
            return Err(ModelError::TooLarge(format!(
                "a distance grid of spacing {h} m over the surface's bounds ({} x {} x {} cells) needs {total:.0} nodes, more than the limit of {max_nodes}",
                cells[0], cells[1], cells[2]
            )));
        }
        let n = cells.map(|c| c as usize + 1);
        let grid = Grid3 {
            n,
            origin,
            spacing: [h; 3],
        };
        let node = |i: usize, j: usize, k: usize| i + n[0] * (j + n[1] * k);
        let pos = |i: usize, j: usize, k: usize| {
            [
                origin[0] + i as f64 * h,
                origin[1] + j as f64 * h,
                origin[2] + k as f64 * h,
            ]
        };
        let tri = |t: u32| surface.triangles[t as usize].map(|v| m.vertex(v as usize));
        let dist = |p: [f64; 3], t: u32| {
            let [a, b, c] = tri(t);
            let (q, _) = closest_on_triangle(p, a, b, c);
            norm2(sub(p, q)).sqrt()
        };
        let mut phi = vec![f64::INFINITY; grid.len()];
        let mut closest = vec![u32::MAX; grid.len()];
        // Exact distances in a band around each triangle.
        for (t, _) in surface.triangles.iter().enumerate() {
            let [a, b, c] = tri(t as u32);
            let r = |a_: usize, f: fn(f64, f64) -> f64, round: fn(f64) -> f64, band: f64| {
                let v = f(f(a[a_], b[a_]), c[a_]);
                (round((v - origin[a_]) / h) + band).clamp(0.0, (n[a_] - 1) as f64) as usize
            };
            let band = EXACT_BAND as f64;
            let (i0, i1) = (
                r(0, f64::min, f64::floor, -band),
                r(0, f64::max, f64::ceil, band),
            );
            let (j0, j1) = (
                r(1, f64::min, f64::floor, -band),
                r(1, f64::max, f64::ceil, band),
            );
            let (k0, k1) = (
                r(2, f64::min, f64::floor, -band),
                r(2, f64::max, f64::ceil, band),
            );
            for k in k0..=k1 {
                for j in j0..=j1 {
                    for i in i0..=i1 {
                        let d = dist(pos(i, j, k), t as u32);
                        let at = node(i, j, k);
                        if d < phi[at] {
                            phi[at] = d;
                            closest[at] = t as u32;
                        }
                    }
                }
            }
        }
        // Fast sweeping: closest triangles flow from upwind neighbours.
        for _round in 0..2 {
            for dir in 0..8 {
                let s =
                    [dir & 1, (dir >> 1) & 1, (dir >> 2) & 1]
                        .map(|b| if b == 0 { 1isize } else { -1 });
                let order = |a: usize, t: usize| if s[a] > 0 { t } else { n[a] - 1 - t };
                for tk in 0..n[2] {
                    let k = order(2, tk);
                    for tj in 0..n[1] {
                        let j = order(1, tj);
                        for ti in 0..n[0] {
                            let i = order(0, ti);
                            let at = node(i, j, k);
                            let p = pos(i, j, k);
                            for nb in 1..8usize {
                                let off = [nb & 1, (nb >> 1) & 1, (nb >> 2) & 1];
                                let c = [(i, 0), (j, 1), (k, 2)]
                                    .map(|(x, a)| x as isize - off[a] as isize * s[a]);
                                if (0..3).any(|a| c[a] < 0 || c[a] >= n[a] as isize) {
                                    continue;
                                }
                                let t = closest[node(c[0] as usize, c[1] as usize, c[2] as usize)];
                                if t == u32::MAX || t == closest[at] {
                                    continue;
                                }
                                let d = dist(p, t);
                                if d < phi[at] {
                                    phi[at] = d;
                                    closest[at] = t;
                                }
                            }
                        }
                    }
                }
            }
        }
        let winding = super::winding_numbers(surface, origin, h, n);
        for (v, w) in phi.iter_mut().zip(&winding) {
            if *w != 0 {
                *v = -*v;
            }
        }
        Ok(SdfGrid { grid, phi })
    }
}

/// Checks that a surface is a closed, consistently oriented triangle mesh with finite
/// coordinates and no degenerate triangle: every directed edge `a -> b` appears in one
/// triangle and `b -> a` in one other. Errors name the triangle or the edge.
pub fn check_closed(surface: &Mesh) -> Result<(), ModelError> {
    let nv = surface.positions.len() / 3;
    if surface.triangles.is_empty() {
        return Err(ModelError::Empty { what: "triangles" });
    }
    let m = surface.as_ref();
    for i in 0..nv {
        let p = m.vertex(i);
        if let Some(a) = (0..3).find(|&a| !p[a].is_finite()) {
            return Err(ModelError::Value {
                item: "vertex",
                index: i,
                field: ["x", "y", "z"][a],
                value: p[a],
                why: "must be finite",
            });
        }
    }
    let mut edges: Vec<(u32, u32, usize)> = Vec::with_capacity(3 * surface.triangles.len());
    for (t, tri) in surface.triangles.iter().enumerate() {
        crate::validate::vertices_exist("triangle", t, tri, nv)?;
        let [a, b, c] = tri.map(|v| m.vertex(v as usize));
        if crate::kernels::collide::prox::triangle_normal(a, b, c).is_none() {
            return Err(ModelError::Element {
                item: "triangle",
                index: t,
                what: format!(
                    "(vertices {}, {}, {}) is degenerate: zero area",
                    tri[0], tri[1], tri[2]
                ),
            });
        }
        for e in 0..3 {
            edges.push((tri[e], tri[(e + 1) % 3], t));
        }
    }
    edges.sort_unstable();
    for w in edges.windows(2) {
        if (w[0].0, w[0].1) == (w[1].0, w[1].1) {
            return Err(ModelError::Connectivity(format!(
                "triangles {} and {} both run along edge {} -> {}: the surface is not consistently oriented, or an edge has more than two triangles",
                w[0].2, w[1].2, w[0].0, w[0].1
            )));
        }
    }
    for &(a, b, t) in &edges {
        if edges.binary_search_by(|e| (e.0, e.1).cmp(&(b, a))).is_err() {
            return Err(ModelError::Connectivity(format!(
                "edge {a} -> {b} of triangle {t} has no triangle running back along it: the surface is open there (a closed surface is needed)"
            )));
        }
    }
    Ok(())
}
