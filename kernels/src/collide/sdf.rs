//! Exact signed distance functions of analytic shapes and their unions (Quilez,
//! "distance functions", iquilezles.org; Hart 1996), with their gradients.
//!
//! Each function returns the signed distance (m, negative inside) and its gradient, a
//! unit vector wherever the distance is differentiable; on the medial axis (the centre
//! of a sphere, the axis of a capsule, the ridges inside a box) the gradient is one of
//! the one-sided ones, or zero where none is defined. A union's distance is the least
//! of its parts', exact outside; inside overlapping parts it is the depth below the
//! nearest part's surface, a lower bound on the depth below the union's.

use crate::v3::{dot, length_and_unit, sub};

/// An analytic solid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// Half-space `n . x + offset <= 0`, `n` a unit vector.
    Plane {
        /// Outward unit normal.
        normal: [f64; 3],
        /// Signed distance of the origin (m).
        offset: f64,
    },
    /// Ball.
    Sphere {
        /// Centre (m).
        center: [f64; 3],
        /// Radius (m).
        radius: f64,
    },
    /// Axis-aligned box.
    Box {
        /// Centre (m).
        center: [f64; 3],
        /// Half extents (m), >= 0.
        half: [f64; 3],
    },
    /// Points within `radius` of the segment `a b`.
    Capsule {
        /// Segment start (m).
        a: [f64; 3],
        /// Segment end (m).
        b: [f64; 3],
        /// Radius (m).
        radius: f64,
    },
    /// Torus around the axis through `center` along `axis` (unit): tube of radius
    /// `minor` around the circle of radius `major`.
    Torus {
        /// Centre (m).
        center: [f64; 3],
        /// Unit axis.
        axis: [f64; 3],
        /// Circle radius (m).
        major: f64,
        /// Tube radius (m).
        minor: f64,
    },
}

impl Shape {
    /// Signed distance (m) and gradient at `p` (see the module docs).
    #[inline]
    pub fn distance_grad(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        match *self {
            Shape::Plane { normal, offset } => (dot(normal, p) + offset, normal),
            Shape::Sphere { center, radius } => {
                let (l, n) = length_and_unit(sub(p, center)).unwrap_or((0.0, [0.0; 3]));
                (l - radius, n)
            }
            Shape::Box { center, half } => box_distance(sub(p, center), half),
            Shape::Capsule { a, b, radius } => {
                let (_, q) = super::prox::closest_on_segment(p, a, b);
                let (l, n) = length_and_unit(sub(p, q)).unwrap_or((0.0, [0.0; 3]));
                (l - radius, n)
            }
            Shape::Torus {
                center,
                axis,
                major,
                minor,
            } => {
                let d = sub(p, center);
                let h = dot(d, axis);
                let radial = sub(d, axis.map(|c| c * h));
                // The nearest point of the core circle; on the axis any is (gradient
                // along the axis then).
                let ring = match length_and_unit(radial) {
                    Some((_, u)) => u.map(|c| c * major),
                    None => {
                        return {
                            let r = (major * major + h * h).sqrt();
                            let g = if r > 0.0 {
                                axis.map(|c| c * h / r)
                            } else {
                                [0.0; 3]
                            };
                            (r - minor, g)
                        }
                    }
                };
                let (l, n) = length_and_unit(sub(d, ring)).unwrap_or((0.0, [0.0; 3]));
                (l - minor, n)
            }
        }
    }

    /// Signed distance (m) at `p`.
    #[inline]
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        self.distance_grad(p).0
    }
}

/// Quilez's exact box distance of `q` (relative to the centre) to the box of half
/// extents `half`: outside, the length of the excess `max(|q| - half, 0)`; inside, the
/// largest (least negative) of `|q| - half`, along that face's normal.
#[inline]
pub fn box_distance(q: [f64; 3], half: [f64; 3]) -> (f64, [f64; 3]) {
    let e = [0, 1, 2].map(|a| q[a].abs() - half[a]);
    let sign = |a: usize| if q[a] < 0.0 { -1.0 } else { 1.0 };
    let out = [0, 1, 2].map(|a| e[a].max(0.0) * sign(a));
    if let Some((l, n)) = length_and_unit(out) {
        return (l, n);
    }
    // Inside or on the surface: the nearest face.
    let a = (0..3).fold(0, |best, a| if e[a] > e[best] { a } else { best });
    let mut n = [0.0; 3];
    n[a] = sign(a);
    (e[a], n)
}

/// The union of shapes: the least distance and that shape's gradient; `(inf, 0)` for
/// none.
pub fn union_distance_grad(shapes: &[Shape], p: [f64; 3]) -> (f64, [f64; 3]) {
    shapes
        .iter()
        .map(|s| s.distance_grad(p))
        .fold((f64::INFINITY, [0.0; 3]), |best, d| {
            if d.0 < best.0 {
                d
            } else {
                best
            }
        })
}
