//! Proximity and continuous collision tests between moving triangles' features: a vertex
//! against a triangle and an edge against an edge (Provot 1997; Bridson, Fedkiw and
//! Anderson 2002, section 6), all moving linearly over the step, `x(t) = x0 + t (x1 -
//! x0)`, `t` in `[0, 1]`.
//!
//! Continuous test: the four points are coplanar at the roots of a cubic in t (the triple
//! product of three edge vectors). The cubic's critical points split `[0, 1]` into
//! monotone pieces; each sign change is bisected to the last bit, and a critical point
//! where the cubic nearly vanishes (a grazing touch) is a candidate too. At each candidate
//! in time order the features' distance is measured: the first within `eta` is the hit.
//! Nothing that crosses is missed as long as the crossing's distance at the root is
//! within `eta` after rounding, so `eta` is a small length (a millionth of the scene
//! suffices in the tests); contacts closer than `eta` count as hits.

use super::prox::{closest_on_triangle, closest_segments, norm2};
use crate::v3::{cross, dot, sub};

#[inline(always)]
fn lerp(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    [
        a[0] + t * (b[0] - a[0]),
        a[1] + t * (b[1] - a[1]),
        a[2] + t * (b[2] - a[2]),
    ]
}

/// A feature pair's proximity: the distance, the unit direction from the first feature
/// to the second (the triangle's normal side for a vertex-triangle pair), and the
/// weights of the closest points (vertex-triangle: the triangle's barycentrics; edge-edge:
/// the two edge parameters in the first two).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Proximity {
    /// Distance (m).
    pub distance: f64,
    /// Unit direction from the triangle (or first edge) to the vertex (or second edge);
    /// the triangle's normal, oriented towards the vertex, when they touch.
    pub normal: [f64; 3],
    /// Barycentric weights on the triangle, or `[s, t, 0]` on the two edges.
    pub weights: [f64; 3],
}

/// The unit vector along `d`, or, when `d` is zero (the features touch), along `fallback`
/// (a normal of the features: the triangle's, or the two edges' cross product), or +z.
fn direction(d: [f64; 3], fallback: [f64; 3]) -> (f64, [f64; 3]) {
    let l = norm2(d).sqrt();
    if l > 0.0 {
        return (l, d.map(|x| x / l));
    }
    let ln = norm2(fallback).sqrt();
    (
        0.0,
        if ln > 0.0 {
            fallback.map(|x| x / ln)
        } else {
            [0.0, 0.0, 1.0]
        },
    )
}

/// The proximity of vertex `p` to triangle `abc`.
pub fn vertex_triangle(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> Proximity {
    let (q, w) = closest_on_triangle(p, a, b, c);
    let (distance, normal) = direction(sub(p, q), cross(sub(b, a), sub(c, a)));
    Proximity {
        distance,
        normal,
        weights: w,
    }
}

/// The proximity of edge `p q` to edge `r s`, direction from the first to the second.
pub fn edge_edge(p: [f64; 3], q: [f64; 3], r: [f64; 3], s: [f64; 3]) -> Proximity {
    let (u, v, c1, c2) = closest_segments(p, q, r, s);
    let (distance, normal) = direction(sub(c2, c1), cross(sub(q, p), sub(s, r)));
    Proximity {
        distance,
        normal,
        weights: [u, v, 0.0],
    }
}

/// Coefficients `[c0, c1, c2, c3]` of `((x0 + t x1) x (y0 + t y1)) . (z0 + t z1)`.
fn triple_cubic(x: [[f64; 3]; 2], y: [[f64; 3]; 2], z: [[f64; 3]; 2]) -> [f64; 4] {
    let xy00 = cross(x[0], y[0]);
    let xy11 = cross(x[1], y[1]);
    let xy_mix = {
        let a = cross(x[1], y[0]);
        let b = cross(x[0], y[1]);
        [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
    };
    [
        dot(xy00, z[0]),
        dot(xy_mix, z[0]) + dot(xy00, z[1]),
        dot(xy11, z[0]) + dot(xy_mix, z[1]),
        dot(xy11, z[1]),
    ]
}

#[inline(always)]
fn eval(c: &[f64; 4], t: f64) -> f64 {
    ((c[3] * t + c[2]) * t + c[1]) * t + c[0]
}

/// The candidate times in `[0, 1]`, ascending, into `out` (at most 10): the sign changes
/// of the cubic, bisected, and its critical points where `|f| <= tol`.
fn candidates(c: &[f64; 4], tol: f64, out: &mut [f64; 12]) -> usize {
    // Critical points: roots of 3 c3 t^2 + 2 c2 t + c1 in (0, 1).
    let mut cuts = [0.0, 1.0, 1.0, 1.0];
    let mut ncut = 1;
    let (qa, qb, qc) = (3.0 * c[3], 2.0 * c[2], c[1]);
    let push_cut = |t: f64, cuts: &mut [f64; 4], n: &mut usize| {
        if t > 0.0 && t < 1.0 {
            cuts[*n] = t;
            *n += 1;
        }
    };
    if qa != 0.0 {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc >= 0.0 {
            let sq = disc.sqrt();
            // The stable pair of roots.
            let q = -0.5 * (qb + if qb >= 0.0 { sq } else { -sq });
            if q != 0.0 {
                push_cut(q / qa, &mut cuts, &mut ncut);
                push_cut(qc / q, &mut cuts, &mut ncut);
            } else {
                push_cut(0.0, &mut cuts, &mut ncut);
            }
        }
    } else if qb != 0.0 {
        push_cut(-qc / qb, &mut cuts, &mut ncut);
    }
    cuts[ncut] = 1.0;
    ncut += 1;
    cuts[..ncut].sort_by(f64::total_cmp);
    let mut n = 0;
    for w in 0..ncut - 1 {
        let (mut lo, mut hi) = (cuts[w], cuts[w + 1]);
        let (flo, fhi) = (eval(c, lo), eval(c, hi));
        if flo.abs() <= tol {
            out[n] = lo;
            n += 1;
        }
        if (flo < 0.0) != (fhi < 0.0) && flo != 0.0 && fhi != 0.0 {
            let up = flo < 0.0;
            for _ in 0..80 {
                let mid = 0.5 * (lo + hi);
                if mid <= lo || mid >= hi {
                    break;
                }
                if (eval(c, mid) < 0.0) == up {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            out[n] = lo;
            out[n + 1] = hi;
            n += 2;
        }
    }
    if eval(c, 1.0).abs() <= tol {
        out[n] = 1.0;
        n += 1;
    }
    out[..n].sort_by(f64::total_cmp);
    n
}

/// The first candidate time in `[0, 1]` at which `check` finds the features within eta:
/// `t = 0` first, then the roots of the coplanarity cubic of the three moving edge
/// vectors `x`, `y`, `z` (each `[start, change over the step]`).
fn first_contact(
    x: [[f64; 3]; 2],
    y: [[f64; 3]; 2],
    z: [[f64; 3]; 2],
    eta: f64,
    check: impl Fn(f64) -> Option<(f64, Proximity)>,
) -> Option<(f64, Proximity)> {
    if let Some(hit) = check(0.0) {
        return Some(hit);
    }
    let coef = triple_cubic(x, y, z);
    // The cubic's scale: |x| |y| |z| bounds it; eta relative to that.
    let size = |u: [[f64; 3]; 2]| norm2(u[0]).sqrt() + norm2(u[1]).sqrt();
    let tol = eta * size(x) * size(y);
    let mut ts = [0.0; 12];
    let n = candidates(&coef, tol, &mut ts);
    ts[..n].iter().find_map(|&t| check(t))
}

/// `u - v` over the step: its start and its change.
fn relative(u: [[f64; 3]; 2], v: [[f64; 3]; 2]) -> [[f64; 3]; 2] {
    let d0 = sub(u[0], v[0]);
    [d0, sub(sub(u[1], v[1]), d0)]
}

#[inline(always)]
fn at(x: [[f64; 3]; 2], t: f64) -> [f64; 3] {
    lerp(x[0], x[1], t)
}

/// The first time in `[0, 1]` at which the moving vertex `p` comes within `eta` (m) of
/// the moving triangle `abc` (positions at the start `*0` and end `*1` of the step), with
/// the proximity then; `None` when it never does.
pub fn vertex_triangle_ccd(
    p: [[f64; 3]; 2],
    a: [[f64; 3]; 2],
    b: [[f64; 3]; 2],
    c: [[f64; 3]; 2],
    eta: f64,
) -> Option<(f64, Proximity)> {
    first_contact(relative(b, a), relative(c, a), relative(p, a), eta, |t| {
        let pr = vertex_triangle(at(p, t), at(a, t), at(b, t), at(c, t));
        (pr.distance <= eta).then_some((t, pr))
    })
}

/// The first time in `[0, 1]` at which moving edge `p q` comes within `eta` (m) of
/// moving edge `r s`, with the proximity then; `None` when it never does.
pub fn edge_edge_ccd(
    p: [[f64; 3]; 2],
    q: [[f64; 3]; 2],
    r: [[f64; 3]; 2],
    s: [[f64; 3]; 2],
    eta: f64,
) -> Option<(f64, Proximity)> {
    first_contact(relative(q, p), relative(s, r), relative(r, p), eta, |t| {
        let pr = edge_edge(at(p, t), at(q, t), at(r, t), at(s, t));
        (pr.distance <= eta).then_some((t, pr))
    })
}
