//! Prescribed motion shared by the domains: vertices moved along a keyframed rigid path.
//!
//! Each vertex of a [`VertexPath`] sits at `c + R(theta(t)) (p0 - c) + offset(t)`, with p0
//! its initial position, `offset` interpolated linearly between keyframes and, when the
//! path turns, `theta` the angle about an axis through the centre c (also linear between
//! keyframes; held before the first and after the last). Its velocity is the path's:
//! `theta'(t) a x R (p0 - c) + offset'(t)`. Path vertices are fixed in implicit solves
//! (their rows filtered like pins) and placed on the path after every step
//! (`MechModel::prescribe`), so elements next to them see the motion through the
//! positions, the way a clamp moved by a machine does.

use crate::validate::{check, require, ModelError, Rule};
use largestep_kernels::v3::{cross, dot};

/// A rotation of a path about a fixed axis.
#[derive(Clone, Debug, PartialEq)]
pub struct PathTurn {
    /// A point on the axis (m).
    pub center: [f64; 3],
    /// The axis direction (normalised when the path is placed; nonzero).
    pub axis: [f64; 3],
    /// The angle (rad, right-handed about the axis) at each keyframe time.
    pub angles: Vec<f64>,
}

/// Vertices moved along a prescribed rigid path (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct VertexPath {
    /// The vertices moved.
    pub vertices: Vec<usize>,
    /// Keyframe times (s), increasing.
    pub times: Vec<f64>,
    /// Offsets from the initial positions at those times (m).
    pub offsets: Vec<[f64; 3]>,
    /// A rotation, if the path turns.
    pub turn: Option<PathTurn>,
}

impl VertexPath {
    /// A path that translates its vertices by `offsets` at `times`.
    pub fn translation(vertices: Vec<usize>, times: Vec<f64>, offsets: Vec<[f64; 3]>) -> Self {
        Self {
            vertices,
            times,
            offsets,
            turn: None,
        }
    }

    /// The keyframe segment of time t and the fraction into it: `(k, s)` with t between
    /// keyframes k and k + 1, or None before the first or after the last (held).
    fn segment(&self, t: f64) -> Result<(usize, f64), usize> {
        let k = self.times.partition_point(|&tk| tk <= t);
        if k == 0 {
            return Err(0);
        }
        if k == self.times.len() {
            return Err(k - 1);
        }
        let (t0, t1) = (self.times[k - 1], self.times[k]);
        Ok((k - 1, (t - t0) / (t1 - t0)))
    }

    /// Offset and velocity of the translation at time `t` (the velocity of the segment `t`
    /// lies in, taking the later one at a keyframe).
    pub fn at(&self, t: f64) -> ([f64; 3], [f64; 3]) {
        match self.segment(t) {
            Err(k) => (self.offsets[k], [0.0; 3]),
            Ok((k, s)) => {
                let (a, b) = (self.offsets[k], self.offsets[k + 1]);
                let dt = self.times[k + 1] - self.times[k];
                (
                    std::array::from_fn(|c| a[c] + s * (b[c] - a[c])),
                    std::array::from_fn(|c| (b[c] - a[c]) / dt),
                )
            }
        }
    }

    /// The position and velocity at time t of the vertex that started at p0.
    pub fn place(&self, t: f64, p0: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let (off, vel) = self.at(t);
        let Some(turn) = &self.turn else {
            return (std::array::from_fn(|c| p0[c] + off[c]), vel);
        };
        let (theta, omega) = match self.segment(t) {
            Err(k) => (turn.angles[k], 0.0),
            Ok((k, s)) => {
                let (a, b) = (turn.angles[k], turn.angles[k + 1]);
                (
                    a + s * (b - a),
                    (b - a) / (self.times[k + 1] - self.times[k]),
                )
            }
        };
        let len = turn.axis.iter().map(|c| c * c).sum::<f64>().sqrt();
        let u = turn.axis.map(|c| c / len);
        let r: [f64; 3] = std::array::from_fn(|c| p0[c] - turn.center[c]);
        // Rodrigues: R r = r cos + (u x r) sin + u (u . r)(1 - cos).
        let (sn, cs) = theta.sin_cos();
        let uxr = cross(u, r);
        let ur = dot(u, r);
        let rr: [f64; 3] =
            std::array::from_fn(|c| r[c] * cs + uxr[c] * sn + u[c] * ur * (1.0 - cs));
        let w = cross(u, rr);
        (
            std::array::from_fn(|c| turn.center[c] + rr[c] + off[c]),
            std::array::from_fn(|c| omega * w[c] + vel[c]),
        )
    }

    /// Checks path k of a model with n vertices.
    pub fn validate(&self, k: usize, n: usize) -> Result<(), ModelError> {
        if self.times.is_empty() || self.times.len() != self.offsets.len() {
            return Err(ModelError::Value {
                item: "path",
                index: k,
                field: "offsets",
                value: self.offsets.len() as f64,
                why: "needs one offset per keyframe time, and at least one",
            });
        }
        for w in self.times.windows(2) {
            require("path", k, "times", w[1], w[1] > w[0], "must be increasing")?;
        }
        for &t in &self.times {
            check("path", k, "times", t, Rule::Finite)?;
        }
        for &x in self.offsets.iter().flatten() {
            check("path", k, "offsets", x, Rule::Finite)?;
        }
        if let Some(turn) = &self.turn {
            if turn.angles.len() != self.times.len() {
                return Err(ModelError::Value {
                    item: "path",
                    index: k,
                    field: "angles",
                    value: turn.angles.len() as f64,
                    why: "needs one angle per keyframe time",
                });
            }
            for &a in &turn.angles {
                check("path", k, "angles", a, Rule::Finite)?;
            }
            for &c in &turn.center {
                check("path", k, "center", c, Rule::Coordinate)?;
            }
            let len = turn.axis.iter().map(|c| c * c).sum::<f64>().sqrt();
            require(
                "path",
                k,
                "axis",
                len,
                len.is_finite() && len > 0.0,
                "must be a nonzero direction",
            )?;
        }
        for &v in &self.vertices {
            let why = "names a vertex that does not exist";
            require("path", k, "vertices", v as f64, v < n, why)?;
        }
        Ok(())
    }
}

/// Places every path's vertices (started at `rest[k]` for path k) at time t: positions x
/// and velocities v, component-major.
pub fn prescribe(
    paths: &[VertexPath],
    rest: &[Vec<[f64; 3]>],
    t: f64,
    x: &mut [f64],
    v: &mut [f64],
) {
    let n = x.len() / 3;
    for (path, rest) in paths.iter().zip(rest) {
        for (&i, &p0) in path.vertices.iter().zip(rest) {
            let (xi, vi) = path.place(t, p0);
            for c in 0..3 {
                x[c * n + i] = xi[c];
                v[c * n + i] = vi[c];
            }
        }
    }
}
