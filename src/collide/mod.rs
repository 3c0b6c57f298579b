//! Collisions, shared by every domain: fixed obstacles and the two ways a model responds
//! to them.
//!
//! - [`Obstacle`]: analytic shapes (plane, sphere, box, capsule) and signed-distance grids
//!   ([`SdfGrid`]). Every shape answers one question, the signed distance of a point
//!   (m, negative inside) and the outward unit normal there ([`Obstacle::distance`]);
//!   nothing downstream depends on the shape.
//! - [`VertexContacts`]: contacts as constraints (Baraff and Witkin 1998, section 5): after
//!   a step every vertex closer than [`CONTACT_THICKNESS`] is moved out, loses its inward
//!   velocity, gets Coulomb friction, and is held in the tangent plane by the constraint
//!   filter of the next implicit solve. The cloth uses them; the generic mechanical
//!   simulation ([`crate::simulation::MechSimulation`]) runs them for any model that names
//!   contact obstacles.
//! - [`Penalty`]: contacts as forces (course notes, section 4): a vertex inside an
//!   obstacle gets a spring of rest length zero to the surface, with its Jacobian and
//!   energy, inside the model's force. The jello uses them.
//!
//! Both are vertex-against-surface tests over every vertex and obstacle (no broad phase
//! yet: scenes hold a handful of obstacles).

mod cloth_self;
mod contacts;
mod edges;
mod inside;
mod penalty;
mod sdf;

pub use cloth_self::{crossed_triangle_pairs, SelfApproach, SelfCollision, SelfStats};
pub use contacts::{VertexContacts, CONTACT_THICKNESS};
pub use edges::edge_through_triangle;
pub use inside::{cells_inside, row_crossings, winding_numbers};
pub use penalty::{Against, Penalty};
pub use sdf::{check_closed, SdfGrid, EXACT_BAND};

use crate::io::Mesh;
use crate::validate::{check, require, ModelError, Rule};
use largestep_kernels::collide::narrow::{gjk_epa, Convex};
use largestep_kernels::collide::sdf::{box_distance, Shape};
use largestep_kernels::interp::sample3_grad;
use largestep_kernels::rigid::{mat_t_vec, mat_vec};
use largestep_kernels::v3::{add, dot, length_and_unit as unit, sub};
use std::sync::Arc;

/// A rigid, fixed collision obstacle: a solid the model stays out of.
#[derive(Clone, Debug, PartialEq)]
pub enum Obstacle {
    /// The solid half-space behind a plane, `normal . x + offset < 0`, its outward normal a
    /// unit vector ([`Obstacle::plane_through`] and [`Obstacle::plane`] make one).
    Plane {
        /// Outward unit normal.
        normal: [f64; 3],
        /// Offset (m): the signed distance of the origin.
        offset: f64,
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
    /// A solid box turned by orthonormal `axes`: `center + sum s_k axes[k]`,
    /// `|s_k| <= half[k]` (a rigid body's box, [`MovingObstacle`]).
    Oriented {
        /// Centre (m).
        center: [f64; 3],
        /// Orthonormal axes (world).
        axes: [[f64; 3]; 3],
        /// Half extents (m), > 0.
        half: [f64; 3],
    },
    /// The solid convex hull of `points` (m, in the hull's own frame, shared with the
    /// rigid body it belongs to) placed at `center` and turned by orthonormal `axes`:
    /// a point `p` of the frame is at `center + sum p_k axes[k]` (a rigid body's mesh,
    /// [`MovingObstacle`]). Distances by GJK and EPA.
    Hull {
        /// The hull's points in its frame.
        points: Arc<[[f64; 3]]>,
        /// Its sharp edges in its frame (may be empty): see [`Obstacle::sharp_edges`].
        edges: Arc<[[[f64; 3]; 2]]>,
        /// Where the frame's origin is (m).
        center: [f64; 3],
        /// The frame's orthonormal axes (world).
        axes: [[f64; 3]; 3],
    },
}

/// An obstacle that moves: its shape now and the rigid motion it moves with (the
/// velocity of a point `p` on it is `velocity + angular_velocity x (p - center)`). The
/// rigid bodies hand theirs to the scene's other systems each step
/// ([`crate::simulation::Simulation::moving_obstacles`]); the contacts of
/// [`VertexContacts`] take velocities relative to it.
#[derive(Clone, Debug, PartialEq)]
pub struct MovingObstacle {
    /// The shape at the present pose.
    pub shape: Obstacle,
    /// The point the angular velocity turns about (m).
    pub center: [f64; 3],
    /// m/s.
    pub velocity: [f64; 3],
    /// rad/s (world).
    pub angular_velocity: [f64; 3],
}

impl MovingObstacle {
    /// The velocity of the obstacle's material at `p` (m/s).
    #[inline]
    pub fn velocity_at(&self, p: [f64; 3]) -> [f64; 3] {
        let r = sub(p, self.center);
        let w = self.angular_velocity;
        let c = [
            w[1] * r[2] - w[2] * r[1],
            w[2] * r[0] - w[0] * r[2],
            w[0] * r[1] - w[1] * r[0],
        ];
        [0, 1, 2].map(|k| self.velocity[k] + c[k])
    }

    /// The obstacle `s` seconds earlier, its motion taken back at constant velocity and
    /// angular velocity (the pose a sub-step ending within a rigid step meets: the rigid
    /// bodies hand over their poses at the step's end). An axis-aligned box is translated
    /// only and a distance grid stays where it is: neither can turn.
    pub fn earlier(&self, s: f64) -> MovingObstacle {
        let r = largestep_kernels::rotation::exp_matrix(self.angular_velocity.map(|c| -s * c));
        let turn = |d: [f64; 3]| mat_vec(r, d);
        let back = self.velocity.map(|c| -s * c);
        let center = add(self.center, back);
        let place = |p: [f64; 3]| add(center, turn(sub(p, self.center)));
        let shape = match &self.shape {
            Obstacle::Plane { normal, offset } => {
                let on = place(normal.map(|c| -c * offset));
                let normal = turn(*normal);
                Obstacle::Plane {
                    normal,
                    offset: -dot(normal, on),
                }
            }
            Obstacle::Sphere { center: c, radius } => Obstacle::Sphere {
                center: place(*c),
                radius: *radius,
            },
            Obstacle::Box { min, max } => Obstacle::Box {
                min: add(*min, back),
                max: add(*max, back),
            },
            Obstacle::Capsule { a, b, radius } => Obstacle::Capsule {
                a: place(*a),
                b: place(*b),
                radius: *radius,
            },
            Obstacle::Sdf(g) => Obstacle::Sdf(g.clone()),
            Obstacle::Oriented {
                center: c,
                axes,
                half,
            } => Obstacle::Oriented {
                center: place(*c),
                axes: axes.map(turn),
                half: *half,
            },
            Obstacle::Hull {
                points,
                edges,
                center: c,
                axes,
            } => Obstacle::Hull {
                points: points.clone(),
                edges: edges.clone(),
                center: place(*c),
                axes: axes.map(turn),
            },
        };
        MovingObstacle {
            shape,
            center,
            velocity: self.velocity,
            angular_velocity: self.angular_velocity,
        }
    }
}

impl Obstacle {
    /// The solid behind the plane through `point` with outward normal `normal` (any
    /// length); `None` when the normal is zero or either is not finite.
    pub fn plane_through(point: [f64; 3], normal: [f64; 3]) -> Option<Obstacle> {
        let (_, _, n) = scaled_unit(normal)?;
        let offset = -dot(n, point);
        offset
            .is_finite()
            .then_some(Obstacle::Plane { normal: n, offset })
    }

    /// The solid `a x + b y + c z + d < 0` of the plane `[a, b, c, d]`; `None` for a zero
    /// or non-finite normal or a non-finite `d`.
    pub fn plane(p: [f64; 4]) -> Option<Obstacle> {
        let (scale, len, n) = scaled_unit([p[0], p[1], p[2]])?;
        p[3].is_finite().then(|| Obstacle::Plane {
            normal: n,
            offset: p[3] / scale / len,
        })
    }

    /// The six walls of a container `[lo, hi]`: planes whose solid sides lie outside the
    /// box, so that what is inside stays inside.
    pub fn container(lo: [f64; 3], hi: [f64; 3]) -> [Obstacle; 6] {
        std::array::from_fn(|w| {
            let axis = w / 2;
            let mut normal = [0.0; 3];
            if w % 2 == 0 {
                normal[axis] = 1.0;
                Obstacle::Plane {
                    normal,
                    offset: -lo[axis],
                }
            } else {
                normal[axis] = -1.0;
                Obstacle::Plane {
                    normal,
                    offset: hi[axis],
                }
            }
        })
    }

    /// The same plane with its solid side flipped (planes only; others are returned as
    /// they are).
    pub fn flipped(&self) -> Obstacle {
        match self {
            Obstacle::Plane { normal, offset } => Obstacle::Plane {
                normal: normal.map(|c| -c),
                offset: -offset,
            },
            other => other.clone(),
        }
    }

    /// The kind, for messages.
    pub fn kind(&self) -> &'static str {
        match self {
            Obstacle::Plane { .. } => "plane",
            Obstacle::Sphere { .. } => "sphere",
            Obstacle::Box { .. } => "box",
            Obstacle::Capsule { .. } => "capsule",
            Obstacle::Sdf(_) => "sdf",
            Obstacle::Oriented { .. } => "oriented box",
            Obstacle::Hull { .. } => "hull",
        }
    }

    /// Checks the parameters; errors are `obstacle` errors naming `index` (the obstacle's
    /// position in its model's list) and the field.
    pub fn validate(&self, index: usize) -> Result<(), ModelError> {
        use Rule::{Finite, Positive};
        let (item, k) = ("obstacle", index);
        let check = |field, value, rule| check(item, k, field, value, rule);
        let require = |field, value, ok, why| require(item, k, field, value, ok, why);
        let finite3 = |field, v: [f64; 3]| v.iter().try_for_each(|&c| check(field, c, Finite));
        let check_orthonormal = |axes: &[[f64; 3]; 3]| {
            for (k, a) in axes.iter().enumerate() {
                finite3("axes", *a)?;
                for (j, b) in axes.iter().enumerate() {
                    let want = if j == k { 1.0 } else { 0.0 };
                    let d = dot(*a, *b);
                    require("axes", d, (d - want).abs() < 1e-6, "must be orthonormal")?;
                }
            }
            Ok::<(), ModelError>(())
        };
        match self {
            Obstacle::Plane { normal, offset } => {
                finite3("normal", *normal)?;
                check("offset", *offset, Finite)?;
                let len = dot(*normal, *normal).sqrt();
                let why = "must be a unit vector (Obstacle::plane_through normalises one)";
                require("normal", len, (len - 1.0).abs() < 1e-9, why)?;
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
            Obstacle::Oriented { center, axes, half } => {
                finite3("center", *center)?;
                half.iter().try_for_each(|&h| check("half", h, Positive))?;
                check_orthonormal(axes)?;
            }
            Obstacle::Hull {
                points,
                edges,
                center,
                axes,
            } => {
                finite3("center", *center)?;
                check_orthonormal(axes)?;
                let why = "needs at least one point";
                require("points", points.len() as f64, !points.is_empty(), why)?;
                points.iter().try_for_each(|p| finite3("points", *p))?;
                edges
                    .iter()
                    .flatten()
                    .try_for_each(|p| finite3("edges", *p))?;
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

    /// A mesh to draw the obstacle in previews: spheres, boxes and capsules. Planes (drawn
    /// together, [`Obstacle::plane_faces`]) and distance grids (that would need an
    /// isosurface) give `None`.
    pub fn preview_mesh(&self) -> Option<Mesh> {
        use crate::shapes;
        match self {
            Obstacle::Sphere { center, radius } => {
                Some(shapes::uv_sphere(*center, *radius, 24, 48))
            }
            Obstacle::Box { min, max } => Some(shapes::cuboid(*min, *max)),
            Obstacle::Capsule { a, b, radius } => Some(shapes::capsule(*a, *b, *radius, 32)),
            Obstacle::Oriented { center, axes, half } => {
                let mut m = shapes::cuboid(half.map(|h| -h), *half);
                let n = m.positions.len() / 3;
                for i in 0..n {
                    let l = [m.positions[i], m.positions[n + i], m.positions[2 * n + i]];
                    let p = add(*center, mat_t_vec(axes, l));
                    for (k, c) in p.into_iter().enumerate() {
                        m.positions[k * n + i] = c;
                    }
                }
                Some(m)
            }
            // A hull's faces are not kept; its rigid body draws it.
            Obstacle::Plane { .. } | Obstacle::Sdf(_) | Obstacle::Hull { .. } => None,
        }
    }

    /// The planes among `obstacles` drawn for previews: each plane's face of the region
    /// they leave free, inside the box `around` (a plane alone is a square the size of
    /// the box; a container's walls are its sides), as triangles facing the free side
    /// and outlines. `None` without planes.
    pub fn plane_faces(obstacles: &[Obstacle], around: ([f64; 3], [f64; 3])) -> Option<Mesh> {
        let planes: Vec<([f64; 3], f64)> = obstacles
            .iter()
            .filter_map(|o| match o {
                Obstacle::Plane { normal, offset } => Some((*normal, *offset)),
                _ => None,
            })
            .collect();
        if planes.is_empty() {
            return None;
        }
        let m = crate::shapes::convex_faces(&planes, around);
        (!m.triangles.is_empty()).then_some(m)
    }

    /// Signed distance of `p` (m, negative inside) and the outward unit normal there, or
    /// `None` where there is no normal (the centre of a sphere, the axis of a capsule, a
    /// flat spot of a distance grid, outside a grid, NaN).
    #[inline]
    pub fn distance(&self, p: [f64; 3]) -> Option<(f64, [f64; 3])> {
        match self {
            Obstacle::Plane { normal, offset } => {
                let d = dot(*normal, p) + offset;
                d.is_finite().then_some((d, *normal))
            }
            // The analytic solids are the kernels' exact distance functions; a zero
            // gradient (a sphere's centre, a capsule's axis) has no normal.
            Obstacle::Sphere { center, radius } => nonzero(
                Shape::Sphere {
                    center: *center,
                    radius: *radius,
                }
                .distance_grad(p),
            ),
            Obstacle::Box { min, max } => {
                let center = [0, 1, 2].map(|a| 0.5 * (min[a] + max[a]));
                let half = [0, 1, 2].map(|a| 0.5 * (max[a] - min[a]));
                nonzero(box_distance(sub(p, center), half))
            }
            Obstacle::Capsule { a, b, radius } => nonzero(
                Shape::Capsule {
                    a: *a,
                    b: *b,
                    radius: *radius,
                }
                .distance_grad(p),
            ),
            Obstacle::Oriented { center, axes, half } => {
                let r = sub(p, *center);
                let local = [dot(r, axes[0]), dot(r, axes[1]), dot(r, axes[2])];
                let (d, g) = box_distance(local, *half);
                nonzero((d, mat_t_vec(axes, g)))
            }
            Obstacle::Hull {
                points,
                center,
                axes,
                ..
            } => {
                // In the hull's frame: GJK's distance outside, EPA's depth inside; the
                // contact's normal runs from the point into the hull, so the outward
                // normal is its opposite.
                let r = sub(p, *center);
                let local = [dot(r, axes[0]), dot(r, axes[1]), dot(r, axes[2])];
                let point = Convex::Sphere {
                    center: local,
                    radius: 0.0,
                };
                let c = gjk_epa(&point, &Convex::Hull(points))?;
                nonzero((-c.depth, mat_t_vec(axes, c.normal.map(|x| -x))))
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

impl Obstacle {
    /// Where the path from `start` (outside) to `end` (inside) entered the obstacle: the
    /// signed distance of `end` from the tangent plane there (m, negative) and that plane's
    /// outward unit normal. `None` when `start` is not outside or a distance is undefined
    /// on the way. The crossing is found by bisection to a millionth of the path, and its
    /// normal taken just outside it.
    pub fn entry(&self, start: [f64; 3], end: [f64; 3]) -> Option<(f64, [f64; 3])> {
        let at = |s: f64| std::array::from_fn(|k| start[k] + s * (end[k] - start[k]));
        let (d0, _) = self.distance(start)?;
        if d0.is_nan() || d0 <= 0.0 {
            return None;
        }
        // Invariant: at(lo) outside, at(hi) inside.
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        for _ in 0..20 {
            let mid = 0.5 * (lo + hi);
            if self.distance(at(mid))?.0 > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let q = at(lo);
        let (dq, nrm) = self.distance(q)?;
        // The tangent plane at the crossing point q (dq >= 0 from it).
        let depth = dot(sub(end, q), nrm) + dq;
        depth.is_finite().then_some((depth.min(0.0), nrm))
    }
}

/// A distance and gradient as an obstacle's answer: `None` without a unit gradient or a
/// finite distance.
#[inline]
fn nonzero((d, g): (f64, [f64; 3])) -> Option<(f64, [f64; 3])> {
    (d.is_finite() && dot(g, g) > 0.5).then_some((d, g))
}

/// `(m, |a / m|, a / |a|)` with m the largest magnitude of a component: the direction of
/// any finite non-zero vector, however large (`[1e308, 1e308, 1]` has one, though its
/// length overflows); `None` for a zero or non-finite one. Exact scaling (m = 1, or a
/// power of two) leaves the result bitwise that of the unscaled vector.
fn scaled_unit(a: [f64; 3]) -> Option<(f64, f64, [f64; 3])> {
    let m = a.iter().fold(0.0f64, |m, c| m.max(c.abs()));
    if !(m > 0.0 && m.is_finite()) {
        return None;
    }
    let (len, n) = unit(a.map(|c| c / m))?;
    Some((m, len, n))
}

/// The deepest penetration (m, >= 0) of any vertex of component-major positions `x` into
/// any of `obstacles`; 0 without obstacles.
pub fn max_penetration(obstacles: &[Obstacle], x: &[f64]) -> f64 {
    let n = x.len() / 3;
    let mut worst = 0.0f64;
    for i in 0..n {
        let p = largestep_kernels::get3(x, n, i);
        for o in obstacles {
            if let Some((d, _)) = o.distance(p) {
                worst = worst.max(-d);
            }
        }
    }
    worst
}
