//! Bounding volumes: axis-aligned boxes, spheres and oriented boxes, with their overlap
//! tests (course notes, section 14).
//!
//! - [`Aabb`]: the broad phase's volume; the BVH, the spatial hash and sweep-and-prune all
//!   take boxes. Closed intervals: boxes that touch overlap.
//! - [`Sphere`]: centre and radius, fit to points through the box centre (at most
//!   `sqrt(3)/2` times the box diagonal; Ritter's refinement buys little here).
//! - [`Obb`]: a box along the principal axes of the points' covariance (Gottschalk, Lin
//!   and Manocha 1996, "OBBTree"), overlap by the separating-axis test on its 15 axes.

use crate::v3::{cross, dot, sub};

/// An axis-aligned box `[min, max]` (m); a box with `min > max` on some axis is empty.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: [f64; 3],
    /// Upper corner.
    pub max: [f64; 3],
}

impl Aabb {
    /// The empty box: the identity of [`Aabb::union`].
    pub const EMPTY: Aabb = Aabb {
        min: [f64::INFINITY; 3],
        max: [f64::NEG_INFINITY; 3],
    };

    /// The box of one point.
    #[inline]
    pub fn point(p: [f64; 3]) -> Aabb {
        Aabb { min: p, max: p }
    }

    /// The smallest box holding every point of `points` (empty for none).
    pub fn of_points(points: impl IntoIterator<Item = [f64; 3]>) -> Aabb {
        points
            .into_iter()
            .fold(Aabb::EMPTY, |b, p| b.union(&Aabb::point(p)))
    }

    /// Whether the two closed boxes share a point (touching counts).
    #[inline(always)]
    pub fn overlaps(&self, o: &Aabb) -> bool {
        // Non-short-circuit `&`: one branch instead of six, which broad phases (mostly
        // misses in random order) would mispredict.
        (self.min[0] <= o.max[0])
            & (o.min[0] <= self.max[0])
            & (self.min[1] <= o.max[1])
            & (o.min[1] <= self.max[1])
            & (self.min[2] <= o.max[2])
            & (o.min[2] <= self.max[2])
    }

    /// Whether `p` lies in the closed box.
    #[inline]
    pub fn contains(&self, p: [f64; 3]) -> bool {
        (0..3).all(|a| self.min[a] <= p[a] && p[a] <= self.max[a])
    }

    /// The smallest box holding both.
    #[inline(always)]
    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: [0, 1, 2].map(|a| self.min[a].min(o.min[a])),
            max: [0, 1, 2].map(|a| self.max[a].max(o.max[a])),
        }
    }

    /// The box grown by `r` on every side.
    #[inline]
    pub fn inflated(&self, r: f64) -> Aabb {
        Aabb {
            min: self.min.map(|c| c - r),
            max: self.max.map(|c| c + r),
        }
    }

    /// Whether the box holds no point.
    #[inline]
    pub fn is_empty(&self) -> bool {
        (0..3).any(|a| self.min[a] > self.max[a])
    }

    /// Centre.
    #[inline]
    pub fn center(&self) -> [f64; 3] {
        [0, 1, 2].map(|a| 0.5 * (self.min[a] + self.max[a]))
    }

    /// Surface area (m²), 0 for an empty box: the SAH's cost weight.
    #[inline]
    pub fn area(&self) -> f64 {
        if self.is_empty() {
            return 0.0;
        }
        let d = sub(self.max, self.min);
        2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0])
    }

    /// Squared distance (m²) from `p` to the box, 0 inside.
    #[inline]
    pub fn distance_squared(&self, p: [f64; 3]) -> f64 {
        (0..3)
            .map(|a| {
                let e = (self.min[a] - p[a]).max(p[a] - self.max[a]).max(0.0);
                e * e
            })
            .sum()
    }

    /// The entry and exit parameters `(t0, t1)` of the ray `origin + t dir` through the
    /// box clipped to `[0, t_max]`, or `None` when it misses. `inv_dir` holds `1 / dir`
    /// per axis (infinite for a zero component; a ray in a face's plane counts as a hit).
    #[inline(always)]
    pub fn ray(&self, origin: [f64; 3], inv_dir: [f64; 3], t_max: f64) -> Option<(f64, f64)> {
        let (mut t0, mut t1) = (0.0f64, t_max);
        for a in 0..3 {
            if inv_dir[a].is_infinite() {
                // Parallel to this slab: inside it (faces included) or a miss. The
                // products below would be 0 * inf = NaN for an origin on a face.
                if origin[a] < self.min[a] || origin[a] > self.max[a] {
                    return None;
                }
                continue;
            }
            let lo = (self.min[a] - origin[a]) * inv_dir[a];
            let hi = (self.max[a] - origin[a]) * inv_dir[a];
            t0 = t0.max(lo.min(hi));
            t1 = t1.min(lo.max(hi));
        }
        (t0 <= t1).then_some((t0, t1))
    }
}

/// A ball: the points within `radius` of `center`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Centre (m).
    pub center: [f64; 3],
    /// Radius (m), >= 0.
    pub radius: f64,
}

impl Sphere {
    /// A ball holding every point: centred on their bounding box, its radius the farthest
    /// point. `None` for no points.
    pub fn of_points(points: &[[f64; 3]]) -> Option<Sphere> {
        if points.is_empty() {
            return None;
        }
        let center = Aabb::of_points(points.iter().copied()).center();
        let r2 = points.iter().map(|&p| {
            let d = sub(p, center);
            dot(d, d)
        });
        Some(Sphere {
            center,
            radius: r2.fold(0.0, f64::max).sqrt(),
        })
    }

    /// Whether the two closed balls share a point.
    #[inline]
    pub fn overlaps(&self, o: &Sphere) -> bool {
        let d = sub(self.center, o.center);
        let r = self.radius + o.radius;
        dot(d, d) <= r * r
    }

    /// Whether the ball and the box share a point.
    #[inline]
    pub fn overlaps_box(&self, b: &Aabb) -> bool {
        b.distance_squared(self.center) <= self.radius * self.radius
    }
}

/// An oriented box: `center + sum_a s_a axes[a]` for `|s_a| <= half[a]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Obb {
    /// Centre (m).
    pub center: [f64; 3],
    /// Orthonormal axes, right-handed.
    pub axes: [[f64; 3]; 3],
    /// Half extents along the axes (m), >= 0.
    pub half: [f64; 3],
}

impl Obb {
    /// The box along the principal axes of the points' covariance (eigenvectors of
    /// `sum (p - mean)(p - mean)^T`, by `fem_diag::sym_eig3`), sized to hold every point.
    /// For points on a line or a plane the remaining axes are any completing frame, and
    /// the box is still exact along the others. `None` for no points.
    pub fn of_points(points: &[[f64; 3]]) -> Option<Obb> {
        if points.is_empty() {
            return None;
        }
        let n = points.len() as f64;
        let mut mean = [0.0; 3];
        for p in points {
            for a in 0..3 {
                mean[a] += p[a] / n;
            }
        }
        let mut c = [0.0; 6];
        for p in points {
            let d = sub(*p, mean);
            c[0] += d[0] * d[0];
            c[1] += d[0] * d[1];
            c[2] += d[0] * d[2];
            c[3] += d[1] * d[1];
            c[4] += d[1] * d[2];
            c[5] += d[2] * d[2];
        }
        let (_, q) = crate::fem_diag::sym_eig3::<f64>(c);
        // Columns of q are the eigenvectors; re-orthonormalise (Jacobi leaves them
        // orthonormal to rounding) and make the frame right-handed.
        let col = |j: usize| [q[j], q[3 + j], q[6 + j]];
        let normalise = |v: [f64; 3]| {
            let l = dot(v, v).sqrt();
            v.map(|c| c / l)
        };
        let a0 = normalise(col(0));
        let a1 = normalise(sub(col(1), a0.map(|c| c * dot(a0, col(1)))));
        let a2 = cross(a0, a1);
        let axes = [a0, a1, a2];
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in points {
            for a in 0..3 {
                let s = dot(axes[a], *p);
                lo[a] = lo[a].min(s);
                hi[a] = hi[a].max(s);
            }
        }
        let mid = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]));
        let center = [0, 1, 2].map(|k| (0..3).map(|a| mid[a] * axes[a][k]).sum());
        Some(Obb {
            center,
            axes,
            half: [0, 1, 2].map(|a| 0.5 * (hi[a] - lo[a])),
        })
    }

    /// The box of an [`Aabb`], axes x, y, z.
    pub fn of_aabb(b: &Aabb) -> Obb {
        Obb {
            center: b.center(),
            axes: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            half: [0, 1, 2].map(|a| 0.5 * (b.max[a] - b.min[a])),
        }
    }

    /// Whether `p` lies in the closed box, to `tol` (m).
    pub fn contains(&self, p: [f64; 3], tol: f64) -> bool {
        let d = sub(p, self.center);
        (0..3).all(|a| dot(d, self.axes[a]).abs() <= self.half[a] + tol)
    }

    /// Whether the two closed boxes share a point: no separating axis among the 3 + 3 face
    /// normals and the 9 edge cross products (Gottschalk et al. 1996, section 4). The
    /// `1e-12` added to `|R|` keeps parallel edges (a zero cross product) from declaring
    /// a false separation.
    pub fn overlaps(&self, o: &Obb) -> bool {
        // r[i][j] = A_i . B_j, t in A's frame.
        let mut r = [[0.0; 3]; 3];
        let mut abs_r = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                r[i][j] = dot(self.axes[i], o.axes[j]);
                abs_r[i][j] = r[i][j].abs() + 1e-12;
            }
        }
        let d = sub(o.center, self.center);
        let t = [0, 1, 2].map(|i| dot(d, self.axes[i]));
        let (a, b) = (self.half, o.half);
        for i in 0..3 {
            let rb = b[0] * abs_r[i][0] + b[1] * abs_r[i][1] + b[2] * abs_r[i][2];
            if t[i].abs() > a[i] + rb {
                return false;
            }
        }
        for j in 0..3 {
            let ra = a[0] * abs_r[0][j] + a[1] * abs_r[1][j] + a[2] * abs_r[2][j];
            let tj = t[0] * r[0][j] + t[1] * r[1][j] + t[2] * r[2][j];
            if tj.abs() > ra + b[j] {
                return false;
            }
        }
        for i in 0..3 {
            let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
            for j in 0..3 {
                let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
                let ra = a[i1] * abs_r[i2][j] + a[i2] * abs_r[i1][j];
                let rb = b[j1] * abs_r[i][j2] + b[j2] * abs_r[i][j1];
                let tl = t[i2] * r[i1][j] - t[i1] * r[i2][j];
                if tl.abs() > ra + rb {
                    return false;
                }
            }
        }
        true
    }
}

/// The boxes of elements of `K` vertices (triangles `K = 3`, tetrahedra `K = 4`, edges
/// `K = 2`) over component-major positions `x`, each grown by `pad` (m), into `out`
/// (cleared first): what a BVH over a mesh is built from. Panics on an index out of
/// range (the domain layer validates meshes).
pub fn element_boxes<const K: usize>(
    out: &mut Vec<Aabb>,
    x: &[f64],
    elements: &[[u32; K]],
    pad: f64,
) {
    let n = x.len() / 3;
    out.clear();
    out.extend(
        elements.iter().map(|e| {
            Aabb::of_points(e.iter().map(|&v| crate::get3(x, n, v as usize))).inflated(pad)
        }),
    );
}

/// The boxes of particles at component-major positions `x` with radii `radius` (one per
/// particle, or a single one for all), into `out` (cleared first).
pub fn particle_boxes(out: &mut Vec<Aabb>, x: &[f64], radius: &[f64]) {
    let n = x.len() / 3;
    assert!(
        radius.len() == n || radius.len() == 1,
        "one radius per particle, or one for all"
    );
    out.clear();
    out.extend((0..n).map(|i| {
        let r = if radius.len() == 1 {
            radius[0]
        } else {
            radius[i]
        };
        Aabb::point(crate::get3(x, n, i)).inflated(r)
    }));
}
