//! Closest points between points, segments and triangles (Ericson 2005, "Real-Time
//! Collision Detection", sections 5.1.5 and 5.1.9): the proximity queries of the narrow
//! phase, the sampled distance fields and the haptic proxy.

use crate::v3::{add, cross, dot, scale, sub};

/// `|a|²`.
#[inline(always)]
pub fn norm2(a: [f64; 3]) -> f64 {
    dot(a, a)
}

/// The point of triangle `abc` closest to `p` and its barycentric coordinates
/// `(u, v, w)` (`u a + v b + w c`), by Voronoi regions (Ericson 5.1.5). A degenerate
/// triangle (a segment or a point) gives the closest point of what it degenerates to.
pub fn closest_on_triangle(
    p: [f64; 3],
    a: [f64; 3],
    b: [f64; 3],
    c: [f64; 3],
) -> ([f64; 3], [f64; 3]) {
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, [1.0, 0.0, 0.0]);
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, [0.0, 1.0, 0.0]);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 && d1 - d3 > 0.0 {
        let v = d1 / (d1 - d3);
        return (add(a, scale(ab, v)), [1.0 - v, v, 0.0]);
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, [0.0, 0.0, 1.0]);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 && d2 - d6 > 0.0 {
        let w = d2 / (d2 - d6);
        return (add(a, scale(ac, w)), [1.0 - w, 0.0, w]);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 && (d4 - d3) + (d5 - d6) > 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (add(b, scale(sub(c, b), w)), [0.0, 1.0 - w, w]);
    }
    let sum = va + vb + vc;
    if sum.is_nan() || sum <= 0.0 || sum.is_infinite() {
        // Degenerate (collinear or coincident corners): the nearest of the three edges.
        let mut best = (f64::INFINITY, a, [1.0, 0.0, 0.0]);
        for (x, y, i, j) in [(a, b, 0, 1), (b, c, 1, 2), (a, c, 0, 2)] {
            let (t, q) = closest_on_segment(p, x, y);
            let d = norm2(sub(p, q));
            if d < best.0 {
                let mut bary = [0.0; 3];
                bary[i] = 1.0 - t;
                bary[j] = t;
                best = (d, q, bary);
            }
        }
        return (best.1, best.2);
    }
    let denom = 1.0 / sum;
    let v = vb * denom;
    let w = vc * denom;
    (add(a, add(scale(ab, v), scale(ac, w))), [1.0 - v - w, v, w])
}

/// The parameter `t` in `[0, 1]` and point of segment `ab` closest to `p`.
#[inline]
pub fn closest_on_segment(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> (f64, [f64; 3]) {
    let ab = sub(b, a);
    let l2 = norm2(ab);
    let t = if l2 > 0.0 {
        (dot(sub(p, a), ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (t, add(a, scale(ab, t)))
}

/// Closest points of segments `p1 q1` and `p2 q2` (Ericson 5.1.9): parameters
/// `(s, t)` in `[0, 1]` and the points. Parallel segments give one of the closest pairs;
/// degenerate segments are points.
pub fn closest_segments(
    p1: [f64; 3],
    q1: [f64; 3],
    p2: [f64; 3],
    q2: [f64; 3],
) -> (f64, f64, [f64; 3], [f64; 3]) {
    let d1 = sub(q1, p1);
    let d2 = sub(q2, p2);
    let r = sub(p1, p2);
    let a = norm2(d1);
    let e = norm2(d2);
    let f = dot(d2, r);
    // Lengths below this (m², relative to the segments' scale) count as points.
    let tiny = 1e-300;
    let (s, t);
    if a <= tiny && e <= tiny {
        return (0.0, 0.0, p1, p2);
    }
    if a <= tiny {
        s = 0.0;
        t = (f / e).clamp(0.0, 1.0);
    } else {
        let c = dot(d1, r);
        if e <= tiny {
            t = 0.0;
            s = (-c / a).clamp(0.0, 1.0);
        } else {
            let b = dot(d1, d2);
            let denom = a * e - b * b;
            // Parallel: pick s = 0 and clamp t.
            let s0 = if denom > 1e-14 * a * e {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let t0 = (b * s0 + f) / e;
            if t0 < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t0 > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            } else {
                t = t0;
                s = s0;
            }
        }
    }
    (s, t, add(p1, scale(d1, s)), add(p2, scale(d2, t)))
}

/// The unit normal of triangle `abc` (right-hand rule), `None` when degenerate.
#[inline]
pub fn triangle_normal(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> Option<[f64; 3]> {
    crate::v3::length_and_unit(cross(sub(b, a), sub(c, a))).map(|(_, n)| n)
}

/// Where the ray `origin + t dir` first meets triangle `abc` for `0 <= t <= t_max`:
/// `(t, [u, v, w])` with the barycentric weights of the hit (Möller and Trumbore 1997),
/// either side of the triangle; `None` for a miss, a ray in the triangle's plane or a
/// degenerate triangle. `slack` widens the triangle by that much in barycentric terms:
/// with `slack = 0` a ray through a shared edge or vertex may, by rounding, miss every
/// triangle there (or hit two); a small positive slack makes it hit at least one, which
/// is what a probe that must not pass through wants. Parity counts want 0 and rays that
/// avoid edges.
pub fn ray_triangle(
    origin: [f64; 3],
    dir: [f64; 3],
    [a, b, c]: [[f64; 3]; 3],
    t_max: f64,
    slack: f64,
) -> Option<(f64, [f64; 3])> {
    let e1 = sub(b, a);
    let e2 = sub(c, a);
    let p = cross(dir, e2);
    let det = dot(e1, p);
    // Relative to the edges' and direction's scale: a ray (nearly) in the plane.
    let scale = norm2(e1).sqrt() * norm2(e2).sqrt() * norm2(dir).sqrt();
    if det.abs() <= 1e-14 * scale || scale == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = sub(origin, a);
    let v = dot(s, p) * inv;
    if v < -slack || v > 1.0 + slack {
        return None;
    }
    let q = cross(s, e1);
    let w = dot(dir, q) * inv;
    if w < -slack || v + w > 1.0 + slack {
        return None;
    }
    let t = dot(e2, q) * inv;
    (t >= 0.0 && t <= t_max).then_some((t, [1.0 - v - w, v, w]))
}
