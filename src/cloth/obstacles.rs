//! Collision obstacles for cloth: analytic shapes (plane, sphere, box, capsule) and
//! signed-distance grids sampled by trilinear interpolation. Each answers one question,
//! the signed distance of a point and the outward unit normal there
//! ([`Obstacle::distance`]); contact handling is shape-independent
//! ([`super::Cloth::resolve_contacts`]). Units: metres.

use super::ClothError;
use largestep_kernels::interp::{sample3_grad, Grid3};
use std::sync::Arc;

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
        for (a, na) in n.iter_mut().enumerate() {
            let (l, v) = next("grid size")?;
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

    /// Reads an SDFGen file (see [`SdfGrid::parse`]).
    pub fn read(path: &std::path::Path) -> Result<SdfGrid, crate::io::ReadError> {
        let text = std::fs::read_to_string(path).map_err(|e| crate::io::ReadError {
            path: path.display().to_string(),
            line: 0,
            message: e.to_string(),
        })?;
        Self::parse(&text, &path.display().to_string())
    }
}

/// A rigid, fixed collision obstacle.
#[derive(Clone, Debug, PartialEq)]
pub enum Obstacle {
    /// The half-space behind a plane through `point` whose outward normal is `normal`
    /// (need not be unit).
    Plane {
        /// A point on the plane (m).
        point: [f64; 3],
        /// Outward normal.
        normal: [f64; 3],
    },
    /// A solid ball.
    Sphere {
        /// Centre (m).
        center: [f64; 3],
        /// Radius (m), > 0.
        radius: f64,
    },
    /// A solid axis-aligned box.
    Box {
        /// Lower corner (m).
        min: [f64; 3],
        /// Upper corner (m), above `min` on every axis.
        max: [f64; 3],
    },
    /// A solid capsule: the points within `radius` of the segment `a`-`b`.
    Capsule {
        /// Segment start (m).
        a: [f64; 3],
        /// Segment end (m).
        b: [f64; 3],
        /// Radius (m), > 0.
        radius: f64,
    },
    /// A signed-distance grid (trilinear); points outside the grid are free.
    Sdf(Arc<SdfGrid>),
}

use largestep_kernels::v3::{dot, length_and_unit as unit, sub};

impl Obstacle {
    /// The kind, for messages.
    pub fn kind(&self) -> &'static str {
        match self {
            Obstacle::Plane { .. } => "plane",
            Obstacle::Sphere { .. } => "sphere",
            Obstacle::Box { .. } => "box",
            Obstacle::Capsule { .. } => "capsule",
            Obstacle::Sdf(_) => "sdf",
        }
    }

    /// Checks the parameters; errors name the obstacle (its index among all obstacles).
    pub fn validate(&self, index: usize) -> Result<(), ClothError> {
        use super::Rule::{Finite, Positive};
        let (item, k) = ("obstacle", index);
        let check = |field, value, rule| super::check(item, k, field, value, rule);
        let require = |field, value, ok, why| super::require(item, k, field, value, ok, why);
        let finite3 = |field, v: [f64; 3]| v.iter().try_for_each(|&c| check(field, c, Finite));
        match self {
            Obstacle::Plane { point, normal } => {
                finite3("point", *point)?;
                finite3("normal", *normal)?;
                require(
                    "normal",
                    0.0,
                    dot(*normal, *normal) != 0.0,
                    "must not be zero",
                )?;
            }
            Obstacle::Sphere { center, radius } => {
                finite3("center", *center)?;
                check("radius", *radius, Positive)?;
            }
            Obstacle::Box { min, max } => {
                finite3("min", *min)?;
                finite3("max", *max)?;
                for a in 0..3 {
                    require(
                        "max",
                        max[a],
                        max[a] > min[a],
                        "must be above min on every axis",
                    )?;
                }
            }
            Obstacle::Capsule { a, b, radius } => {
                finite3("a", *a)?;
                finite3("b", *b)?;
                check("radius", *radius, Positive)?;
            }
            Obstacle::Sdf(s) => {
                let g = &s.grid;
                let shape_ok = g.n.iter().all(|&n| n >= 2) && s.phi.len() == g.len();
                let why = "needs at least 2 nodes per axis and one distance per node";
                require("grid", s.phi.len() as f64, shape_ok, why)?;
                finite3("origin", g.origin)?;
                g.spacing
                    .iter()
                    .try_for_each(|&h| check("spacing", h, Positive))?;
                s.phi
                    .iter()
                    .try_for_each(|&d| check("distance", d, Finite))?;
            }
        }
        Ok(())
    }

    /// A mesh to draw the obstacle in previews: spheres, boxes and capsules. Planes (the
    /// preview's ground stands in for a floor) and distance grids (that would need an
    /// isosurface) give `None`.
    pub fn preview_mesh(&self) -> Option<crate::io::Mesh> {
        use crate::render::shapes;
        match self {
            Obstacle::Sphere { center, radius } => {
                Some(shapes::uv_sphere(*center, *radius, 24, 48))
            }
            Obstacle::Box { min, max } => Some(shapes::cuboid(*min, *max)),
            Obstacle::Capsule { a, b, radius } => Some(shapes::capsule(*a, *b, *radius, 32)),
            Obstacle::Plane { .. } | Obstacle::Sdf(_) => None,
        }
    }

    /// Signed distance of `p` (m, negative inside) and the outward unit normal there, or
    /// `None` where there is no normal (the centre of a sphere, the axis of a capsule, a
    /// flat spot of a distance grid, outside a grid, NaN).
    pub fn distance(&self, p: [f64; 3]) -> Option<(f64, [f64; 3])> {
        match self {
            Obstacle::Plane { point, normal } => {
                let (_, n) = unit(*normal)?;
                let d = dot(sub(p, *point), n);
                d.is_finite().then_some((d, n))
            }
            Obstacle::Sphere { center, radius } => {
                let (l, n) = unit(sub(p, *center))?;
                Some((l - radius, n))
            }
            Obstacle::Box { min, max } => {
                let q: [f64; 3] = std::array::from_fn(|a| p[a].clamp(min[a], max[a]));
                if q != p {
                    // Outside: distance to the closest point of the box.
                    return unit(sub(p, q));
                }
                // Inside: the nearest face.
                let mut best = (f64::INFINITY, [0.0; 3]);
                for a in 0..3 {
                    for (depth, s) in [(p[a] - min[a], -1.0), (max[a] - p[a], 1.0)] {
                        if depth < best.0 {
                            let mut n = [0.0; 3];
                            n[a] = s;
                            best = (depth, n);
                        }
                    }
                }
                best.0.is_finite().then_some((-best.0, best.1))
            }
            Obstacle::Capsule { a, b, radius } => {
                let ab = sub(*b, *a);
                let len2 = dot(ab, ab);
                let t = if len2 > 0.0 {
                    (dot(sub(p, *a), ab) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let q: [f64; 3] = std::array::from_fn(|k| a[k] + t * ab[k]);
                let (l, n) = unit(sub(p, q))?;
                Some((l - radius, n))
            }
            Obstacle::Sdf(s) => {
                if !s.grid.contains(p) {
                    return None;
                }
                let (d, g) = sample3_grad(&s.phi, s.grid, p);
                let (_, n) = unit(g)?;
                Some((d, n))
            }
        }
    }
}
