//! Narrow phase: contacts between convex shapes by GJK (Gilbert, Johnson and Keerthi
//! 1988, with the closest-point-of-simplex steps of Ericson 2005, section 9.5) and EPA
//! (van den Bergen 2001) where they overlap, boxes by the separating-axis test
//! (Gottschalk et al. 1996), and the closed forms for spheres and capsules.
//!
//! Spheres and capsules are run as their cores (a point, a segment) with a margin: GJK
//! and EPA see only polytopes, where both are exact (to their tolerance), and the radii
//! are added to the result (the margins of van den Bergen 2001, section 4.3.7). Run on
//! the rounded shapes themselves, EPA's polytope is inscribed in the rounded Minkowski
//! difference and stops short of the depth (a capsule pair 9% under was found).
//!
//! A [`Contact`] is written from shape A to shape B: `normal` points from A into B,
//! `depth` is the penetration (m, > 0 overlapping, < 0 the separation) and `point` lies
//! midway between the two witness points, on A's surface `point_a` and B's `point_b`.

use super::prox::{closest_on_segment, closest_on_triangle, closest_segments, norm2};
use crate::v3::{add, cross, dot, length_and_unit, scale, sub};
use arrayvec::ArrayVec;

#[inline(always)]
fn lerp3(w: [f64; 3], p: [[f64; 3]; 3]) -> [f64; 3] {
    add(add(scale(p[0], w[0]), scale(p[1], w[1])), scale(p[2], w[2]))
}

/// A contact between two shapes (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// Unit normal from A into B.
    pub normal: [f64; 3],
    /// Penetration depth (m): positive overlapping, negative separated.
    pub depth: f64,
    /// The witness point on A.
    pub point_a: [f64; 3],
    /// The witness point on B.
    pub point_b: [f64; 3],
}

impl Contact {
    /// The contact point: midway between the witnesses.
    pub fn point(&self) -> [f64; 3] {
        scale(add(self.point_a, self.point_b), 0.5)
    }
}

/// A convex shape for GJK: its support point in a direction, and a point inside it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Convex<'a> {
    /// A ball.
    Sphere {
        /// Centre (m).
        center: [f64; 3],
        /// Radius (m).
        radius: f64,
    },
    /// Points within `radius` of the segment `a b`.
    Capsule {
        /// Segment start.
        a: [f64; 3],
        /// Segment end.
        b: [f64; 3],
        /// Radius (m).
        radius: f64,
    },
    /// An oriented box: `center + sum s_a axes[a]`, `|s_a| <= half[a]`.
    Box {
        /// Centre (m).
        center: [f64; 3],
        /// Orthonormal axes.
        axes: [[f64; 3]; 3],
        /// Half extents (m).
        half: [f64; 3],
    },
    /// The convex hull of points (`[x, y, z]` each), at least one.
    Hull(&'a [[f64; 3]]),
    /// A triangle.
    Triangle([[f64; 3]; 3]),
}

impl Convex<'_> {
    /// The point of the shape farthest along `d` (any length, not zero).
    pub fn support(&self, d: [f64; 3]) -> [f64; 3] {
        match *self {
            Convex::Sphere { center, radius } => match length_and_unit(d) {
                Some((_, u)) => add(center, scale(u, radius)),
                None => center,
            },
            Convex::Capsule { a, b, radius } => {
                let end = if dot(sub(b, a), d) > 0.0 { b } else { a };
                match length_and_unit(d) {
                    Some((_, u)) => add(end, scale(u, radius)),
                    None => end,
                }
            }
            Convex::Box { center, axes, half } => {
                let mut p = center;
                for k in 0..3 {
                    let s = if dot(axes[k], d) >= 0.0 {
                        half[k]
                    } else {
                        -half[k]
                    };
                    p = add(p, scale(axes[k], s));
                }
                p
            }
            Convex::Hull(points) => *points
                .iter()
                .max_by(|p, q| dot(**p, d).total_cmp(&dot(**q, d)))
                .expect("a hull has at least one point"),
            Convex::Triangle(t) => *t
                .iter()
                .max_by(|p, q| dot(**p, d).total_cmp(&dot(**q, d)))
                .expect("three points"),
        }
    }

    /// The shape's core and margin: a sphere is its centre and radius, a capsule its
    /// segment and radius, and every other shape itself with margin 0.
    pub fn core(&self) -> (Self, f64) {
        match *self {
            Convex::Sphere { center, radius } => (
                Convex::Sphere {
                    center,
                    radius: 0.0,
                },
                radius,
            ),
            Convex::Capsule { a, b, radius } => (Convex::Capsule { a, b, radius: 0.0 }, radius),
            other => (other, 0.0),
        }
    }

    /// Calls `f` with each vertex of a polytope (a box's eight corners, a hull's points,
    /// a triangle's corners); `false` for a rounded shape (sphere, capsule), which has
    /// none.
    pub fn for_each_vertex(&self, mut f: impl FnMut([f64; 3])) -> bool {
        match *self {
            Convex::Sphere { .. } | Convex::Capsule { .. } => return false,
            Convex::Box { center, axes, half } => {
                for k in 0..8 {
                    let mut p = center;
                    for (a, (axis, h)) in axes.iter().zip(half).enumerate() {
                        let s = if k >> a & 1 == 1 { h } else { -h };
                        p = add(p, scale(*axis, s));
                    }
                    f(p);
                }
            }
            Convex::Hull(points) => points.iter().for_each(|p| f(*p)),
            Convex::Triangle(t) => t.iter().for_each(|p| f(*p)),
        }
        true
    }

    /// A point inside the shape (its centre, or the mean of its points).
    pub fn center(&self) -> [f64; 3] {
        match *self {
            Convex::Sphere { center, .. } | Convex::Box { center, .. } => center,
            Convex::Capsule { a, b, .. } => scale(add(a, b), 0.5),
            Convex::Hull(points) => {
                let s = points.iter().fold([0.0; 3], |s, p| add(s, *p));
                scale(s, 1.0 / points.len().max(1) as f64)
            }
            Convex::Triangle(t) => scale(add(add(t[0], t[1]), t[2]), 1.0 / 3.0),
        }
    }
}

/// A vertex of the Minkowski difference `A - B` with its witnesses.
#[derive(Clone, Copy, Debug)]
struct Vert {
    w: [f64; 3],
    a: [f64; 3],
    b: [f64; 3],
}

fn support(a: &Convex, b: &Convex, d: [f64; 3]) -> Vert {
    let pa = a.support(d);
    let pb = b.support(scale(d, -1.0));
    Vert {
        w: sub(pa, pb),
        a: pa,
        b: pb,
    }
}

/// Relative tolerance of GJK's termination and EPA's expansion.
const REL_TOL: f64 = 1e-10;
/// Iteration cap of both (each iteration adds a support point; convergence on smooth
/// shapes is linear, so the cap bounds work on spheres and capsules).
const MAX_ITERS: usize = 128;

/// GJK's simplex: at most four vertices with their barycentric weights, on the stack.
type Simplex = ArrayVec<(Vert, f64), 4>;

/// EPA's polytope, on the stack: every iteration adds one vertex, so at most
/// [`MAX_ITERS`] more than the starting tetrahedron's four; a closed triangulated polytope
/// of V vertices has 2V - 4 faces; the horizon collects at most three edges per removed
/// face. A polytope that would outgrow these (rounding can make the visible region
/// non-convex) stops growing, and its nearest face is the answer.
const EPA_VERTS: usize = MAX_ITERS + 4;
const EPA_FACES: usize = 2 * EPA_VERTS;
const EPA_HORIZON: usize = 3 * EPA_FACES;

/// Moves the simplex to the closest point to the origin: returns that point and keeps
/// the vertices of non-zero weight with their weights. `None` when the origin is inside
/// a tetrahedron.
fn closest_simplex(s: &mut Simplex) -> Option<[f64; 3]> {
    let o = [0.0; 3];
    let (q, bary): ([f64; 3], [f64; 3]) = match s.len() {
        1 => {
            s[0].1 = 1.0;
            return Some(s[0].0.w);
        }
        2 => {
            let (t, q) = closest_on_segment(o, s[0].0.w, s[1].0.w);
            (q, [1.0 - t, t, 0.0])
        }
        3 => closest_on_triangle(o, s[0].0.w, s[1].0.w, s[2].0.w),
        _ => {
            // A tetrahedron. The origin is inside when the tetrahedron has volume and
            // the origin is behind none of its faces (each seen from the opposite
            // vertex's side). Otherwise the closest point is the nearest of the four
            // faces' closest points: that is right for any origin outside, and it does
            // not trust the side tests on a flat tetrahedron (parallel faces of boxes
            // make them), whose signs are rounding noise.
            let faces = [[0, 1, 2, 3], [0, 1, 3, 2], [0, 2, 3, 1], [1, 2, 3, 0]];
            let w = [s[0].0.w, s[1].0.w, s[2].0.w, s[3].0.w];
            let (e1, e2, e3) = (sub(w[1], w[0]), sub(w[2], w[0]), sub(w[3], w[0]));
            let volume = dot(cross(e1, e2), e3);
            let size = norm2(e1).max(norm2(e2)).max(norm2(e3));
            let solid = volume.abs() > 1e-10 * size * size.sqrt();
            let behind_none = faces.iter().all(|f| {
                let (p0, p1, p2, opp) = (w[f[0]], w[f[1]], w[f[2]], w[f[3]]);
                let n = cross(sub(p1, p0), sub(p2, p0));
                dot(n, scale(p0, -1.0)) * dot(n, sub(opp, p0)) >= 0.0
            });
            if solid && behind_none {
                return None;
            }
            let closest = faces.map(|f| closest_on_triangle(o, w[f[0]], w[f[1]], w[f[2]]));
            let k = (0..4)
                .min_by(|&i, &j| norm2(closest[i].0).total_cmp(&norm2(closest[j].0)))
                .expect("four faces");
            let (f, (q, bary)) = (faces[k], closest[k]);
            let face = [s[f[0]], s[f[1]], s[f[2]]];
            s.clear();
            s.extend(face);
            (q, bary)
        }
    };
    // Drop the vertices of zero weight (keep one if all are).
    let first = s[0].0;
    let mut k = 0;
    s.retain(|v| {
        let w = bary[k];
        k += 1;
        v.1 = w;
        w > 0.0
    });
    if s.is_empty() {
        s.push((first, 1.0));
    }
    Some(q)
}

/// The contact between two convex shapes: GJK's distance and witness points when they
/// are apart, EPA's penetration depth and normal when they overlap, both on the shapes'
/// cores with the margins added (see the module docs). `None` only for non-finite input.
/// Allocates nothing: the simplex and EPA's polytope live on the stack (about 30 KB at
/// most).
pub fn gjk_epa(a: &Convex, b: &Convex) -> Option<Contact> {
    let ((core_a, ra), (core_b, rb)) = (a.core(), b.core());
    let c = gjk_epa_cores(&core_a, &core_b)?;
    // The cores' contact moved out to the rounded surfaces along its normal.
    Some(Contact {
        normal: c.normal,
        depth: c.depth + ra + rb,
        point_a: add(c.point_a, scale(c.normal, ra)),
        point_b: sub(c.point_b, scale(c.normal, rb)),
    })
}

fn gjk_epa_cores(a: &Convex, b: &Convex) -> Option<Contact> {
    let mut d = sub(b.center(), a.center());
    if norm2(d) == 0.0 {
        d = [1.0, 0.0, 0.0];
    }
    let mut simplex = Simplex::new();
    simplex.push((support(a, b, scale(d, -1.0)), 1.0));
    let mut v = simplex[0].0.w;
    for _ in 0..MAX_ITERS {
        if !v.iter().all(|c| c.is_finite()) {
            return None;
        }
        let vv = norm2(v);
        if vv <= 1e-30 {
            break; // touching or overlapping: origin on the simplex
        }
        let w = support(a, b, scale(v, -1.0));
        // No progress towards the origin: v is the closest point of A - B.
        if vv - dot(v, w.w) <= REL_TOL * vv || simplex.iter().any(|s| s.0.w == w.w) {
            return Some(separated(&simplex, v));
        }
        simplex.push((w, 0.0));
        match closest_simplex(&mut simplex) {
            Some(q) => v = q,
            None => return epa(a, b, &simplex),
        }
    }
    if norm2(v) > 1e-30 {
        return Some(separated(&simplex, v));
    }
    // The origin is on the boundary or inside: grow the simplex to a tetrahedron and
    // measure the penetration with EPA.
    epa(a, b, &simplex)
}

/// The witness points on A and B of the simplex's closest point (its weights).
fn witnesses(s: &Simplex) -> ([f64; 3], [f64; 3]) {
    s.iter().fold(([0.0; 3], [0.0; 3]), |(pa, pb), (p, wi)| {
        (add(pa, scale(p.a, *wi)), add(pb, scale(p.b, *wi)))
    })
}

fn separated(s: &Simplex, v: [f64; 3]) -> Contact {
    let (pa, pb) = witnesses(s);
    let dist = norm2(v).sqrt();
    // v = pa - pb points from B to A: the normal from A into B is -v.
    Contact {
        normal: scale(v, -1.0 / dist),
        depth: -dist,
        point_a: pa,
        point_b: pb,
    }
}

/// EPA from a simplex holding the origin: grows it into a polytope of `A - B` until the
/// face nearest the origin is on the boundary; that face's normal and distance are the
/// penetration.
fn epa(a: &Convex, b: &Convex, simplex: &Simplex) -> Option<Contact> {
    let mut verts: ArrayVec<Vert, EPA_VERTS> = simplex.iter().map(|v| v.0).collect();
    // Grow a degenerate simplex into a tetrahedron holding the origin.
    let dirs = [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    let mut k = 0;
    while verts.len() < 4 && k < dirs.len() {
        let cand = support(a, b, dirs[k]);
        k += 1;
        let s = &verts;
        let independent = match s.len() {
            1 => norm2(sub(cand.w, s[0].w)) > 1e-24,
            2 => norm2(cross(sub(s[1].w, s[0].w), sub(cand.w, s[0].w))) > 1e-24,
            _ => {
                let n = cross(sub(s[1].w, s[0].w), sub(s[2].w, s[0].w));
                dot(n, sub(cand.w, s[0].w)).abs() > 1e-12 * norm2(n).sqrt().max(1e-300)
            }
        };
        if independent {
            verts.push(cand);
        }
    }
    if verts.len() < 4 {
        // A flat Minkowski difference (cores that are points, segments or triangles, or
        // a degenerate shape) holding the origin: the cores touch, depth 0. The normal
        // is off the flat set (off a plane's normal, a line's direction), towards B's
        // centre where that is defined; the witnesses are GJK's.
        let towards = sub(b.center(), a.center());
        let normal = match verts.len() {
            3 => {
                let n = cross(sub(verts[1].w, verts[0].w), sub(verts[2].w, verts[0].w));
                length_and_unit(n).map(|(_, n)| {
                    if dot(n, towards) < 0.0 {
                        scale(n, -1.0)
                    } else {
                        n
                    }
                })
            }
            2 => length_and_unit(sub(verts[1].w, verts[0].w)).and_then(|(_, u)| {
                length_and_unit(sub(towards, scale(u, dot(towards, u))))
                    .map(|(_, n)| n)
                    .or_else(|| length_and_unit(cross(u, [1.0, 0.0, 0.0])).map(|(_, n)| n))
                    .or_else(|| length_and_unit(cross(u, [0.0, 1.0, 0.0])).map(|(_, n)| n))
            }),
            _ => length_and_unit(towards).map(|(_, n)| n),
        };
        let (pa, pb) = witnesses(simplex);
        return Some(Contact {
            normal: normal.unwrap_or([0.0, 0.0, 1.0]),
            depth: 0.0,
            point_a: pa,
            point_b: pb,
        });
    }
    // Faces as vertex index triples, wound outward.
    let mut faces: ArrayVec<[usize; 3], EPA_FACES> = ArrayVec::new();
    let center = scale(verts.iter().fold([0.0; 3], |c, v| add(c, v.w)), 0.25);
    for f in [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]] {
        faces.push(outward(&verts, f, center));
    }
    let mut horizon: ArrayVec<[usize; 2], EPA_HORIZON> = ArrayVec::new();
    // Which faces the new support point sees, decided once per iteration.
    let mut seen: ArrayVec<bool, EPA_FACES> = ArrayVec::new();
    let mut best: Option<(f64, [f64; 3], [usize; 3])> = None;
    for _ in 0..MAX_ITERS {
        // The face nearest the origin whose plane's nearest point lies on the face. A
        // convex polytope holding the origin has its nearest point there; rounding can
        // leave the polytope slightly non-convex, where a face's plane may be nearer
        // while that point falls outside it (witnesses far from the contact, found by
        // the manifold proptest). Only when no face qualifies is the nearest plane taken.
        best = None;
        let mut nearest_plane: Option<(f64, [f64; 3], [usize; 3])> = None;
        for f in &faces {
            let (p0, p1, p2) = (verts[f[0]].w, verts[f[1]].w, verts[f[2]].w);
            let Some((_, n)) = length_and_unit(cross(sub(p1, p0), sub(p2, p0))) else {
                continue;
            };
            let dist = dot(n, p0);
            if nearest_plane.as_ref().is_none_or(|b| dist < b.0) {
                nearest_plane = Some((dist, n, *f));
            }
            if best.as_ref().is_none_or(|b| dist < b.0) {
                let q = scale(n, dist);
                let (on, _) = closest_on_triangle(q, p0, p1, p2);
                let size = norm2(sub(p1, p0)).max(norm2(sub(p2, p0)));
                if norm2(sub(on, q)) <= 1e-18 * size.max(1e-300) {
                    best = Some((dist, n, *f));
                }
            }
        }
        if best.is_none() {
            best = nearest_plane;
        }
        let (dist, n, _) = best?;
        let w = support(a, b, n);
        let reach = dot(w.w, n);
        if reach - dist <= REL_TOL * reach.abs().max(1e-12) || verts.iter().any(|v| v.w == w.w) {
            break;
        }
        // The faces the new point sees, and their horizon; stop growing if the polytope
        // would outgrow its arrays (see `EPA_VERTS`).
        seen.clear();
        seen.extend(faces.iter().map(|f| {
            let (p0, p1, p2) = (verts[f[0]].w, verts[f[1]].w, verts[f[2]].w);
            dot(cross(sub(p1, p0), sub(p2, p0)), sub(w.w, p0)) > 0.0
        }));
        horizon.clear();
        let mut fits = verts.len() < EPA_VERTS;
        for (f, _) in faces.iter().zip(&seen).filter(|(_, s)| **s) {
            for e in [[f[0], f[1]], [f[1], f[2]], [f[2], f[0]]] {
                // An edge of two removed faces appears both ways: drop it.
                if let Some(i) = horizon.iter().position(|h| *h == [e[1], e[0]]) {
                    horizon.swap_remove(i);
                } else {
                    fits &= horizon.try_push(e).is_ok();
                }
            }
        }
        let kept = seen.iter().filter(|s| !**s).count();
        if !fits || kept + horizon.len() > EPA_FACES {
            break;
        }
        // Remove the faces the new point sees; stitch the horizon to it.
        let wi = verts.len();
        let mut k = 0;
        faces.retain(|_| {
            k += 1;
            !seen[k - 1]
        });
        verts.push(w);
        for e in &horizon {
            faces.push([e[0], e[1], wi]);
        }
    }
    let (dist, n, f) = best?;
    // Witnesses: the barycentric weights of the origin's projection on the face.
    let tri = [verts[f[0]].w, verts[f[1]].w, verts[f[2]].w];
    let (_, bary) = closest_on_triangle(scale(n, dist), tri[0], tri[1], tri[2]);
    let pa = lerp3(bary, [verts[f[0]].a, verts[f[1]].a, verts[f[2]].a]);
    let pb = lerp3(bary, [verts[f[0]].b, verts[f[1]].b, verts[f[2]].b]);
    // n is the outward normal of A - B's face nearest the origin: translating A by
    // -n dist separates the shapes, so A presses into B along n.
    Some(Contact {
        normal: n,
        depth: dist,
        point_a: pa,
        point_b: pb,
    })
}

/// The face `f` wound so its normal points away from `center`.
fn outward(v: &[Vert], f: [usize; 3], center: [f64; 3]) -> [usize; 3] {
    let n = cross(sub(v[f[1]].w, v[f[0]].w), sub(v[f[2]].w, v[f[0]].w));
    if dot(n, sub(v[f[0]].w, center)) < 0.0 {
        [f[0], f[2], f[1]]
    } else {
        f
    }
}

/// Sphere against sphere, closed form.
pub fn sphere_sphere(ca: [f64; 3], ra: f64, cb: [f64; 3], rb: f64) -> Contact {
    let d = sub(cb, ca);
    let (l, n) = length_and_unit(d).unwrap_or((0.0, [0.0, 0.0, 1.0]));
    Contact {
        normal: n,
        depth: ra + rb - l,
        point_a: add(ca, scale(n, ra)),
        point_b: sub(cb, scale(n, rb)),
    }
}

/// Capsule against capsule (and, with zero-length segments, spheres): the closest points
/// of the two segments.
pub fn capsule_capsule(
    a0: [f64; 3],
    a1: [f64; 3],
    ra: f64,
    b0: [f64; 3],
    b1: [f64; 3],
    rb: f64,
) -> Contact {
    let (_, _, pa, pb) = closest_segments(a0, a1, b0, b1);
    sphere_sphere(pa, ra, pb, rb)
}

/// Oriented box against oriented box by the separating-axis test over the 15 axes
/// (Gottschalk et al. 1996): the axis of least overlap gives the normal and depth, and
/// the deepest point of each box along it the witnesses (a single point: a face-face
/// contact reports one of its corners). Separated boxes get the largest gap over the
/// axes as a negative depth (a lower bound on the distance; GJK gives the distance).
pub fn box_box(
    ca: [f64; 3],
    ax: [[f64; 3]; 3],
    ha: [f64; 3],
    cb: [f64; 3],
    bx: [[f64; 3]; 3],
    hb: [f64; 3],
) -> Contact {
    let t = sub(cb, ca);
    let mut axes: ArrayVec<[f64; 3], 15> = ArrayVec::new();
    axes.extend(ax);
    axes.extend(bx);
    for u in ax {
        for v in bx {
            if let Some((_, n)) = length_and_unit(cross(u, v)) {
                // Parallel edges give no axis.
                if norm2(cross(u, v)) > 1e-12 {
                    axes.push(n);
                }
            }
        }
    }
    let radius = |axes3: &[[f64; 3]; 3], h: [f64; 3], n: [f64; 3]| {
        (0..3).map(|k| h[k] * dot(axes3[k], n).abs()).sum::<f64>()
    };
    let mut best = (f64::INFINITY, [0.0, 0.0, 1.0]);
    for n in axes {
        let overlap = radius(&ax, ha, n) + radius(&bx, hb, n) - dot(t, n).abs();
        if overlap < best.0 {
            let n = if dot(t, n) < 0.0 { scale(n, -1.0) } else { n };
            best = (overlap, n);
        }
    }
    let (depth, n) = best;
    let a = Convex::Box {
        center: ca,
        axes: ax,
        half: ha,
    };
    let b = Convex::Box {
        center: cb,
        axes: bx,
        half: hb,
    };
    Contact {
        normal: n,
        depth,
        point_a: a.support(n),
        point_b: b.support(scale(n, -1.0)),
    }
}
