//! Contact manifolds: the up-to-four points by which two posed shapes touch, with one
//! normal, for a rigid-body solver to hold them apart and let them rest without rocking.
//!
//! - Box against box: the separating-axis test over the 15 axes picks the axis of least
//!   overlap, preferring face axes within a relative tolerance (so a resting box keeps its
//!   face contact instead of flickering to an edge axis). A face axis clips the other
//!   box's most anti-parallel face against the side planes of the reference face
//!   (Sutherland-Hodgman), keeps the points below the reference face and reduces them to
//!   four (the deepest, the farthest from it, and the two that span the largest area); an
//!   edge axis gives the closest points of the two supporting edges (Gottschalk et al.
//!   1996; the clipping as in Catto's Box2D and Dirk Gregorius's GDC 2013 talk).
//! - Sphere against box: the closest point of the box to the centre, or, for a centre
//!   inside, the face of least penetration.
//! - Capsules: the closed form of the closest points of the segments ([`super::narrow`]),
//!   and against boxes the contact of each end cap kept when it agrees with the closest
//!   point's normal, so a capsule lying on a face rests on two points.
//! - Anything else convex: GJK with EPA for the normal and depth. Between two polytopes
//!   (hulls, boxes, triangles) each one's support feature along the normal (its vertices
//!   within a small height of the deepest: a face, an edge or a vertex) is taken in the
//!   contact plane, the smaller-dimensional one clipped against the other's convex
//!   outline (Sutherland-Hodgman, as for boxes), so that a hull resting on a face gets
//!   that face's corners; otherwise one point.
//!
//! Normals point from A into B. A point's `depth` is its penetration (m, > 0 overlapping,
//! < 0 apart within the margin); the point lies midway between the two surfaces. No
//! function allocates.

use super::narrow::{capsule_capsule, gjk_epa, sphere_sphere, Contact, Convex};
use super::prox::closest_segments;
use crate::v3::{add, cross, dot, length_and_unit, scale, sub, tangent_frame};
use arrayvec::ArrayVec;

/// Points a manifold holds at most.
pub const MAX_POINTS: usize = 4;

/// One contact point of a [`Manifold`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ManifoldPoint {
    /// World position (m), midway between the surfaces.
    pub point: [f64; 3],
    /// Penetration (m): > 0 overlapping, < 0 separated.
    pub depth: f64,
}

/// Up to [`MAX_POINTS`] contact points with one normal (A into B).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Manifold {
    /// Unit normal from A into B.
    pub normal: [f64; 3],
    /// The points; the first `count` are valid.
    pub points: [ManifoldPoint; MAX_POINTS],
    /// Valid points.
    pub count: usize,
}

impl Manifold {
    fn push(&mut self, point: [f64; 3], depth: f64) {
        if self.count < MAX_POINTS {
            self.points[self.count] = ManifoldPoint { point, depth };
            self.count += 1;
        }
    }

    fn from_contact(c: &Contact, margin: f64) -> Option<Manifold> {
        // NaN depths fail too.
        if c.depth.is_nan() || c.depth < -margin {
            return None;
        }
        let mut m = Manifold {
            normal: c.normal,
            ..Manifold::default()
        };
        m.push(c.point(), c.depth);
        Some(m)
    }

    /// The valid points.
    pub fn points(&self) -> &[ManifoldPoint] {
        &self.points[..self.count]
    }

    /// The same contact seen from B: the normal reversed.
    pub fn flipped(mut self) -> Manifold {
        self.normal = scale(self.normal, -1.0);
        self
    }
}

/// A posed box: centre (m), orthonormal axes (world), half extents (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxPose {
    /// Centre (m).
    pub center: [f64; 3],
    /// The box's axes in world coordinates (orthonormal: a rotation's columns).
    pub axes: [[f64; 3]; 3],
    /// Half extents along the axes (m).
    pub half: [f64; 3],
}

impl BoxPose {
    /// The box as a GJK shape.
    pub fn convex(&self) -> Convex<'static> {
        Convex::Box {
            center: self.center,
            axes: self.axes,
            half: self.half,
        }
    }
}

/// Face axes win over edge axes unless an edge axis separates by this much more
/// (relative to the face's), and B's faces over A's likewise: coherent manifolds from
/// step to step (Box2D's `k_relativeTol`, `k_absoluteTol`).
const RELATIVE_TOL: f64 = 0.95;
const ABSOLUTE_TOL: f64 = 0.01;

/// Box against box (see the module docs): `None` when they are more than `margin` (m)
/// apart.
// Axis k indexes four parallel arrays (axes, halves, cosines, projections).
#[allow(clippy::needless_range_loop)]
pub fn box_box(a: &BoxPose, b: &BoxPose, margin: f64) -> Option<Manifold> {
    let t = sub(b.center, a.center);
    // The axes' cosines `r[i][j] = a_i . b_j` (B's axes in A's frame, columns), from
    // which every axis's projected radii follow (Gottschalk, Lin and Manocha 1996;
    // Ericson, "Real-Time Collision Detection" 4.4.1): nine dot products instead of
    // three for each of the fifteen axes' two radii.
    // Each row is formed just before A's face axis that needs it: most pairs that the
    // broad phase passes on are apart along one of A's first axes.
    let mut r = [[0.0; 3]; 3];
    let mut ar = [[0.0; 3]; 3];
    // Face axes of A, then of B: the separation along each (> 0 apart).
    let mut ta = [0.0; 3];
    let mut best_a = (f64::NEG_INFINITY, 0usize);
    for k in 0..3 {
        r[k] = std::array::from_fn(|j| dot(a.axes[k], b.axes[j]));
        ar[k] = r[k].map(f64::abs);
        ta[k] = dot(t, a.axes[k]);
        let rb = b.half[0] * ar[k][0] + b.half[1] * ar[k][1] + b.half[2] * ar[k][2];
        let s = ta[k].abs() - a.half[k] - rb;
        if s > margin {
            return None;
        }
        if s > best_a.0 {
            best_a = (s, k);
        }
    }
    let mut best_b = (f64::NEG_INFINITY, 0usize);
    for k in 0..3 {
        let ra = a.half[0] * ar[0][k] + a.half[1] * ar[1][k] + a.half[2] * ar[2][k];
        let s = dot(t, b.axes[k]).abs() - b.half[k] - ra;
        if s > margin {
            return None;
        }
        if s > best_b.0 {
            best_b = (s, k);
        }
    }
    // Edge axes `a_i x b_j`, in A's frame `-r[i2][j] e_i1 + r[i1][j] e_i2` (i1, i2 the
    // next indices after i): its length, the projection of t on it and both radii
    // follow from r, so only the deepest one is formed in world coordinates.
    let mut best_e = (f64::NEG_INFINITY, 0usize, 0usize);
    for i in 0..3 {
        let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
        for j in 0..3 {
            let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
            let len = (r[i1][j] * r[i1][j] + r[i2][j] * r[i2][j]).sqrt();
            // Parallel edges give no axis (their faces' axes cover them).
            if len.is_nan() || len < 1e-6 {
                continue;
            }
            let tl = ta[i2] * r[i1][j] - ta[i1] * r[i2][j];
            let ra = a.half[i1] * ar[i2][j] + a.half[i2] * ar[i1][j];
            let rb = b.half[j1] * ar[i][j2] + b.half[j2] * ar[i][j1];
            let s = (tl.abs() - ra - rb) / len;
            if s > margin {
                return None;
            }
            if s > best_e.0 {
                best_e = (s, i, j);
            }
        }
    }
    let scale_len = a.half.iter().chain(&b.half).fold(0.0f64, |m, &h| m.max(h));
    let tol = ABSOLUTE_TOL * scale_len;
    let face_b = best_b.0 > RELATIVE_TOL * best_a.0 + tol;
    let face_sep = if face_b { best_b.0 } else { best_a.0 };
    if best_e.0 > RELATIVE_TOL * face_sep + tol {
        let (_, i, j) = best_e;
        // (Axes that are not orthonormal may leave no world axis: then a face's.)
        if let Some((_, mut n)) = length_and_unit(cross(a.axes[i], b.axes[j])) {
            if dot(t, n) < 0.0 {
                n = scale(n, -1.0);
            }
            return Some(edge_edge(a, b, i, j, n));
        }
    }
    let mut m = if face_b {
        let k = best_b.1;
        // B's face toward A: the normal from B into A.
        let n = if dot(t, b.axes[k]) > 0.0 {
            scale(b.axes[k], -1.0)
        } else {
            b.axes[k]
        };
        clip_faces(b, k, n, a, margin).flipped()
    } else {
        let k = best_a.1;
        let n = if dot(t, a.axes[k]) < 0.0 {
            scale(a.axes[k], -1.0)
        } else {
            a.axes[k]
        };
        clip_faces(a, k, n, b, margin)
    };
    if m.count == 0 {
        // Rounding left no point below the face: the deepest corner stands in.
        let c = box_box_single(a, b);
        m = Manifold::from_contact(&c, margin)?;
    }
    Some(m)
}

fn box_box_single(a: &BoxPose, b: &BoxPose) -> Contact {
    super::narrow::box_box(a.center, a.axes, a.half, b.center, b.axes, b.half)
}

/// The corner of box `b` farthest along `d`, and the axis signs that reach it.
#[allow(clippy::needless_range_loop)]
fn corner(b: &BoxPose, d: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let mut p = b.center;
    let mut s = [0.0; 3];
    for k in 0..3 {
        s[k] = if dot(b.axes[k], d) >= 0.0 { 1.0 } else { -1.0 };
        p = add(p, scale(b.axes[k], s[k] * b.half[k]));
    }
    (p, s)
}

/// The edge-edge contact along `n` (A into B) between A's edge along axis `i` and B's
/// along axis `j`.
fn edge_edge(a: &BoxPose, b: &BoxPose, i: usize, j: usize, n: [f64; 3]) -> Manifold {
    // The supporting edges: through the farthest corner, along the edge axis.
    let (pa, _) = corner(a, n);
    let (pb, _) = corner(b, scale(n, -1.0));
    let (sa, sb) = (
        dot(sub(pa, a.center), a.axes[i]),
        dot(sub(pb, b.center), b.axes[j]),
    );
    let a0 = add(pa, scale(a.axes[i], -sa - a.half[i]));
    let a1 = add(pa, scale(a.axes[i], -sa + a.half[i]));
    let b0 = add(pb, scale(b.axes[j], -sb - b.half[j]));
    let b1 = add(pb, scale(b.axes[j], -sb + b.half[j]));
    let (_, _, ca, cb) = closest_segments(a0, a1, b0, b1);
    let mut m = Manifold {
        normal: n,
        ..Manifold::default()
    };
    // Depth along n: how far B's point lies behind A's.
    m.push(scale(add(ca, cb), 0.5), dot(sub(ca, cb), n));
    m
}

/// The vertex after `e` of a closed polygon of `count` (`(e + 1) % count` without the
/// integer division, which the clipping loops ran at every edge).
#[inline(always)]
fn next(e: usize, count: usize) -> usize {
    if e + 1 == count {
        0
    } else {
        e + 1
    }
}

/// Clips the face of `inc` most anti-parallel to `n` against the face `k` of `reference`
/// whose outward normal is `n` (pointing at `inc`): the manifold with normal `n`.
fn clip_faces(reference: &BoxPose, k: usize, n: [f64; 3], inc: &BoxPose, margin: f64) -> Manifold {
    let face_center = add(reference.center, scale(n, reference.half[k]));
    let (u_axis, v_axis) = ((k + 1) % 3, (k + 2) % 3);
    let (u, v) = (reference.axes[u_axis], reference.axes[v_axis]);
    let (hu, hv) = (reference.half[u_axis], reference.half[v_axis]);
    // The incident face: the axis of `inc` most parallel to n, on the side facing -n.
    let mut ki = 0;
    let mut best = -1.0;
    for q in 0..3 {
        let d = dot(inc.axes[q], n).abs();
        if d > best {
            best = d;
            ki = q;
        }
    }
    let sign = if dot(inc.axes[ki], n) > 0.0 {
        -1.0
    } else {
        1.0
    };
    let c = add(inc.center, scale(inc.axes[ki], sign * inc.half[ki]));
    let (iu, iv) = ((ki + 1) % 3, (ki + 2) % 3);
    let eu = scale(inc.axes[iu], inc.half[iu]);
    let ev = scale(inc.axes[iv], inc.half[iv]);
    // The incident face in the reference face's 2-D frame (u, v), with its height along n.
    let mut poly = [[0.0f64; 3]; 8];
    let corners = [
        add(add(c, eu), ev),
        add(sub(c, eu), ev),
        sub(sub(c, eu), ev),
        sub(add(c, eu), ev),
    ];
    for (p, q) in poly.iter_mut().zip(corners) {
        let r = sub(q, face_center);
        *p = [dot(r, u), dot(r, v), dot(r, n)];
    }
    let mut count = 4;
    let mut tmp = [[0.0f64; 3]; 8];
    // Each plane clips `cur` into `clipped`, and the two swap (references, not the
    // points: copying the polygon back was a call to memcpy, 1.6% of the late pile's step).
    let (mut cur, mut clipped) = (&mut poly, &mut tmp);
    // Four side planes: +-u <= hu, +-v <= hv.
    for (axis, sgn, lim) in [(0, 1.0, hu), (0, -1.0, hu), (1, 1.0, hv), (1, -1.0, hv)] {
        let mut out = 0;
        for e in 0..count {
            let p = cur[e];
            let q = cur[next(e, count)];
            let dp = sgn * p[axis] - lim;
            let dq = sgn * q[axis] - lim;
            if dp <= 0.0 && out < 8 {
                clipped[out] = p;
                out += 1;
            }
            // Strictly on opposite sides: a vertex on the plane is kept above, once.
            if ((dp < 0.0 && dq > 0.0) || (dp > 0.0 && dq < 0.0)) && out < 8 {
                let s = dp / (dp - dq);
                clipped[out] = [
                    p[0] + s * (q[0] - p[0]),
                    p[1] + s * (q[1] - p[1]),
                    p[2] + s * (q[2] - p[2]),
                ];
                out += 1;
            }
        }
        count = out.min(8);
        std::mem::swap(&mut cur, &mut clipped);
        if count == 0 {
            break;
        }
    }
    // Points below the face within the margin: depth = -height.
    let mut kept = [[0.0f64; 3]; 8];
    let mut nk = 0;
    for p in &cur[..count] {
        if -p[2] >= -margin {
            kept[nk] = *p;
            nk += 1;
        }
    }
    let mut m = Manifold {
        normal: n,
        ..Manifold::default()
    };
    let to_world = |p: [f64; 3]| {
        // Midway between the incident point and its projection on the face.
        add(
            face_center,
            add(add(scale(u, p[0]), scale(v, p[1])), scale(n, 0.5 * p[2])),
        )
    };
    let (chosen, k) = reduce(&kept[..nk]);
    for &i in &chosen[..k] {
        let p = kept[i];
        m.push(to_world(p), -p[2]);
    }
    m
}

/// The 2-D convex outline (in `u, v`, heights carried along) of a feature's points,
/// counter-clockwise (Andrew's monotone chain); collinear and repeated points dropped.
fn outline(mut pts: Feature) -> Feature {
    if pts.len() < 3 {
        return pts;
    }
    pts.sort_unstable_by(|p, q| p[0].total_cmp(&q[0]).then(p[1].total_cmp(&q[1])));
    let turn = |o: [f64; 3], a: [f64; 3], b: [f64; 3]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    // Turns smaller than this (m^2, relative to the feature's size) count as straight.
    let span = pts
        .iter()
        .fold(0.0f64, |m, p| m.max(p[0].abs()).max(p[1].abs()))
        + 1e-300;
    let eps = 1e-12 * span * span;
    let mut hull: ArrayVec<[f64; 3], { 2 * FEATURE }> = ArrayVec::new();
    for pass in 0..2 {
        let start = hull.len();
        let order: &mut dyn Iterator<Item = &[f64; 3]> = if pass == 0 {
            &mut pts.iter()
        } else {
            &mut pts.iter().rev()
        };
        for p in order {
            while hull.len() >= start + 2
                && turn(hull[hull.len() - 2], hull[hull.len() - 1], *p) <= eps
            {
                hull.pop();
            }
            hull.push(*p);
        }
        hull.pop(); // the last point starts the other chain
    }
    hull.into_iter().take(FEATURE).collect()
}

/// Clips the incident feature (a polygon, a segment or a point, in the contact plane)
/// to the convex counter-clockwise `reference` outline, heights interpolated along.
fn clip_convex(
    incident: &Feature,
    reference: &Feature,
) -> Option<ArrayVec<[f64; 3], { 2 * FEATURE }>> {
    let mut poly: ArrayVec<[f64; 3], { 2 * FEATURE }> = incident.iter().copied().collect();
    let r = reference.len();
    for e in 0..r {
        let (a, b) = (reference[e], reference[next(e, r)]);
        // Inside: left of a -> b (>= 0).
        let side = |p: [f64; 3]| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
        let mut out: ArrayVec<[f64; 3], { 2 * FEATURE }> = ArrayVec::new();
        let m = poly.len();
        if m == 1 {
            if side(poly[0]) >= 0.0 {
                out.push(poly[0]);
            }
        } else {
            // A segment is one edge (both ends kept here), not a closed loop of two.
            let edges = if m == 2 { 1 } else { m };
            for k in 0..edges {
                let (p, q) = (poly[k], poly[next(k, m)]);
                let (dp, dq) = (side(p), side(q));
                if dp >= 0.0 {
                    out.try_push(p).ok()?;
                }
                if (dp < 0.0 && dq > 0.0) || (dp > 0.0 && dq < 0.0) {
                    let s = dp / (dp - dq);
                    out.try_push(std::array::from_fn(|c| p[c] + s * (q[c] - p[c])))
                        .ok()?;
                }
                if m == 2 && dq >= 0.0 {
                    out.try_push(q).ok()?;
                }
            }
        }
        poly = out;
        if poly.is_empty() {
            return None;
        }
    }
    Some(poly)
}

/// Indices of at most four of `pts` (reference-face coordinates `u, v, height`) that keep
/// the contact area: the deepest, the farthest from it, then the two on either side of
/// that line farthest from it (Gregorius 2013).
fn reduce(pts: &[[f64; 3]]) -> ([usize; MAX_POINTS], usize) {
    let n = pts.len();
    if n <= MAX_POINTS {
        return ([0, 1, 2, 3], n);
    }
    let deepest = (0..n)
        .min_by(|&i, &j| pts[i][2].total_cmp(&pts[j][2]))
        .unwrap_or(0);
    let d2 = |i: usize, j: usize| {
        let (dx, dy) = (pts[i][0] - pts[j][0], pts[i][1] - pts[j][1]);
        dx * dx + dy * dy
    };
    let far = (0..n)
        .max_by(|&i, &j| d2(i, deepest).total_cmp(&d2(j, deepest)))
        .unwrap_or(0);
    let side = |i: usize| {
        let (a, b) = (pts[deepest], pts[far]);
        (b[0] - a[0]) * (pts[i][1] - a[1]) - (b[1] - a[1]) * (pts[i][0] - a[0])
    };
    let left = (0..n)
        .max_by(|&i, &j| side(i).total_cmp(&side(j)))
        .unwrap_or(0);
    let right = (0..n)
        .min_by(|&i, &j| side(i).total_cmp(&side(j)))
        .unwrap_or(0);
    // Collinear points make left or right repeat one already taken.
    let mut out = [deepest; MAX_POINTS];
    let mut k = 1;
    for i in [left, far, right] {
        if !out[..k].contains(&i) {
            out[k] = i;
            k += 1;
        }
    }
    (out, k)
}

/// Sphere (centre, radius) against box: `None` beyond `margin`.
#[allow(clippy::needless_range_loop)]
pub fn sphere_box(center: [f64; 3], radius: f64, b: &BoxPose, margin: f64) -> Option<Manifold> {
    let r = sub(center, b.center);
    let local = [dot(r, b.axes[0]), dot(r, b.axes[1]), dot(r, b.axes[2])];
    let mut q = local;
    let mut inside = true;
    for k in 0..3 {
        if q[k] > b.half[k] {
            q[k] = b.half[k];
            inside = false;
        } else if q[k] < -b.half[k] {
            q[k] = -b.half[k];
            inside = false;
        }
    }
    let world = |p: [f64; 3]| {
        add(
            b.center,
            add(
                add(scale(b.axes[0], p[0]), scale(b.axes[1], p[1])),
                scale(b.axes[2], p[2]),
            ),
        )
    };
    let (normal_box_out, dist, surface) = if inside {
        // The face of least penetration.
        let mut k = 0;
        let mut least = f64::INFINITY;
        for a in 0..3 {
            let d = b.half[a] - local[a].abs();
            if d < least {
                least = d;
                k = a;
            }
        }
        let s = if local[k] >= 0.0 { 1.0 } else { -1.0 };
        let mut on = local;
        on[k] = s * b.half[k];
        (scale(b.axes[k], s), -least, world(on))
    } else {
        let qw = world(q);
        let (d, n) = length_and_unit(sub(center, qw))?;
        (n, d, qw)
    };
    let depth = radius - dist;
    if depth < -margin {
        return None;
    }
    let mut m = Manifold {
        // From the sphere (A) into the box (B).
        normal: scale(normal_box_out, -1.0),
        ..Manifold::default()
    };
    let on_sphere = sub(center, scale(normal_box_out, radius));
    m.push(scale(add(on_sphere, surface), 0.5), depth);
    Some(m)
}

/// Sphere against sphere: `None` beyond `margin`.
pub fn sphere_sphere_manifold(
    ca: [f64; 3],
    ra: f64,
    cb: [f64; 3],
    rb: f64,
    margin: f64,
) -> Option<Manifold> {
    Manifold::from_contact(&sphere_sphere(ca, ra, cb, rb), margin)
}

/// Capsule (segment `a0 a1`, radius `ra`) against capsule, or a sphere as a capsule of
/// zero length: one point, `None` beyond `margin`.
pub fn capsule_capsule_manifold(
    a: [[f64; 3]; 2],
    ra: f64,
    b: [[f64; 3]; 2],
    rb: f64,
    margin: f64,
) -> Option<Manifold> {
    Manifold::from_contact(&capsule_capsule(a[0], a[1], ra, b[0], b[1], rb), margin)
}

/// Capsule (segment, radius) against box (see the module docs): `None` beyond `margin`.
pub fn capsule_box(seg: [[f64; 3]; 2], radius: f64, b: &BoxPose, margin: f64) -> Option<Manifold> {
    let core = Convex::Capsule {
        a: seg[0],
        b: seg[1],
        radius,
    };
    let main = gjk_epa(&core, &b.convex())?;
    let mut m = Manifold::from_contact(&main, margin)?;
    // The end caps, where they touch along (nearly) the same normal.
    let mut ends = Manifold::default();
    for e in seg {
        if let Some(c) = sphere_box(e, radius, b, margin) {
            if dot(c.normal, m.normal) > 0.99 {
                ends.push(c.points[0].point, c.points[0].depth);
            }
        }
    }
    if ends.count == 2 {
        ends.normal = m.normal;
        m = ends;
    }
    Some(m)
}

/// Any two convex shapes by GJK and EPA (see the module docs): up to four points between
/// polytopes, else one; `None` beyond `margin` or for non-finite input.
pub fn convex_convex(a: &Convex, b: &Convex, margin: f64) -> Option<Manifold> {
    let c = gjk_epa(a, b)?;
    let one = Manifold::from_contact(&c, margin)?;
    Some(polytope_manifold(a, b, &c, margin).unwrap_or(one))
}

/// Vertices of a support feature kept at most (a hull face with more gives one point).
const FEATURE: usize = 32;

/// A support feature in the contact plane: `[u, v, height along the normal]` per vertex,
/// its 2-D convex outline counter-clockwise.
type Feature = ArrayVec<[f64; 3], FEATURE>;

/// The multi-point manifold of two polytopes from their contact `c` (see the module
/// docs); `None` when a shape is rounded, a feature is too large, or clipping leaves
/// fewer than two points.
fn polytope_manifold(a: &Convex, b: &Convex, c: &Contact, margin: f64) -> Option<Manifold> {
    let n = c.normal;
    let (u, v) = tangent_frame(n);
    let origin = c.point();
    // Heights measured along n from the contact point; A's feature faces +n, B's -n.
    let frame = |p: [f64; 3]| {
        let r = sub(p, origin);
        [dot(r, u), dot(r, v), dot(r, n)]
    };
    // A face tilted by up to about a degree still counts as one: the tolerance is a
    // fiftieth of the shape's extent along n, and at least a micrometre.
    let feature = |shape: &Convex, sign: f64| -> Option<Feature> {
        let (mut hi, mut lo) = (f64::NEG_INFINITY, f64::INFINITY);
        if !shape.for_each_vertex(|p| {
            let h = sign * dot(sub(p, origin), n);
            hi = hi.max(h);
            lo = lo.min(h);
        }) {
            return None;
        }
        let tol = (0.02 * (hi - lo)).max(1e-6);
        let mut f = Feature::new();
        let mut fits = true;
        shape.for_each_vertex(|p| {
            if sign * dot(sub(p, origin), n) >= hi - tol {
                fits &= f.try_push(frame(p)).is_ok();
            }
        });
        fits.then(|| outline(f))
    };
    let (fa, fb) = (feature(a, 1.0)?, feature(b, -1.0)?);
    // Clip the feature with fewer vertices against the other's outline (a face against
    // a face: B's against A's). The reference face's plane is its highest point along
    // its outward normal.
    let (reference, incident, sign) = if fb.len() <= fa.len() || fb.len() < 3 {
        (fa, fb, 1.0)
    } else {
        (fb, fa, -1.0)
    };
    if reference.len() < 3 {
        return None;
    }
    let top = reference
        .iter()
        .fold(f64::NEG_INFINITY, |m, p| m.max(sign * p[2]));
    let clipped = clip_convex(&incident, &reference)?;
    // Depth: how far the incident point lies beyond the reference plane.
    let mut kept: ArrayVec<[f64; 3], { 2 * FEATURE }> = ArrayVec::new();
    for p in &clipped {
        // In the reference's outward direction (sign n) the plane is at `top`.
        let depth = top - sign * p[2];
        if depth >= -margin {
            kept.push([p[0], p[1], -depth]);
        }
    }
    if kept.len() < 2 {
        return None;
    }
    let mut m = Manifold {
        normal: n,
        ..Manifold::default()
    };
    let (chosen, k) = reduce(&kept);
    for &i in &chosen[..k] {
        let [pu, pv, h] = kept[i];
        let depth = -h;
        // Midway between the incident point and the reference plane.
        let height = sign * (top - 0.5 * depth);
        m.push(
            add(
                origin,
                add(add(scale(u, pu), scale(v, pv)), scale(n, height)),
            ),
            depth,
        );
    }
    Some(m)
}
