//! The rigid bodies' collision stage: boxes, sweep and prune, manifolds, and the match of
//! each new contact point with last step's (for warm starting).

use super::{Collider, Rigid, RigidError, RigidState, RigidStepInfo, RigidWork};
use largestep_kernels::collide::bv::Aabb;
use largestep_kernels::collide::manifold::{
    box_box, capsule_box, capsule_capsule_manifold, convex_convex, sphere_box,
    sphere_sphere_manifold, BoxPose, Manifold,
};
use largestep_kernels::collide::narrow::Convex;
use largestep_kernels::quat;
use largestep_kernels::v3::{add, dot, sub};

/// Contact margin as a fraction of the smaller body's feature size: points this far apart
/// are kept as speculative contacts.
pub(crate) const MARGIN: f64 = 0.1;

/// A contact point between bodies `a` and `b` (normal from a into b), with the impulse
/// the solver gave it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ContactPoint {
    /// The first body.
    pub a: u32,
    /// The second body.
    pub b: u32,
    /// Unit normal from a into b.
    pub normal: [f64; 3],
    /// World position (m).
    pub point: [f64; 3],
    /// Penetration at the step's start (m; < 0: apart, a speculative contact).
    pub depth: f64,
    /// The point in a's body frame (matches points between steps).
    pub local_a: [f64; 3],
    /// The impulse on b over the last step (N s, world; a got its opposite).
    pub impulse: [f64; 3],
    /// Split-impulse normal impulse (not momentum: it moved the bodies apart).
    pub(crate) pseudo: f64,
}

/// The box of body `i` at its pose, grown by `grow` (m).
fn body_box(m: &Rigid, s: &RigidState, i: usize, grow: f64) -> Aabb {
    let x = s.x[i];
    let ext = match &m.colliders[i] {
        Collider::Sphere(r) => [*r; 3],
        Collider::Box(h) => {
            let r = quat::to_matrix(s.q[i]);
            [0, 1, 2].map(|a| r[a][0].abs() * h[0] + r[a][1].abs() * h[1] + r[a][2].abs() * h[2])
        }
        Collider::Capsule(hh, r) => {
            let d = quat::rotate(s.q[i], [0.0, *hh, 0.0]);
            d.map(|c| c.abs() + r)
        }
        Collider::Hull(_) => [m.bound[i]; 3],
    };
    let e = ext.map(|c| c + grow);
    Aabb {
        min: sub(x, e),
        max: add(x, e),
    }
}

pub(crate) fn box_pose(s: &RigidState, i: usize, half: [f64; 3]) -> BoxPose {
    let q = s.q[i];
    BoxPose {
        center: s.x[i],
        axes: [
            quat::rotate(q, [1.0, 0.0, 0.0]),
            quat::rotate(q, [0.0, 1.0, 0.0]),
            quat::rotate(q, [0.0, 0.0, 1.0]),
        ],
        half,
    }
}

pub(crate) fn segment(s: &RigidState, i: usize, hh: f64) -> [[f64; 3]; 2] {
    let d = quat::rotate(s.q[i], [0.0, hh, 0.0]);
    [sub(s.x[i], d), add(s.x[i], d)]
}

/// The manifold between bodies `i` and `j` (normal from i into j) within `margin`.
fn manifold(
    m: &Rigid,
    s: &RigidState,
    hulls: &[Vec<[f64; 3]>],
    i: usize,
    j: usize,
    margin: f64,
) -> Option<Manifold> {
    use Collider::*;
    let (ci, cj) = (&m.colliders[i], &m.colliders[j]);
    let as_segment = |k: usize| match &m.colliders[k] {
        Sphere(r) => Some(([s.x[k], s.x[k]], *r)),
        Capsule(hh, r) => Some((segment(s, k, *hh), *r)),
        _ => None,
    };
    match (ci, cj) {
        (Sphere(ra), Sphere(rb)) => sphere_sphere_manifold(s.x[i], *ra, s.x[j], *rb, margin),
        (Sphere(_) | Capsule(..), Sphere(_) | Capsule(..)) => {
            let (sa, ra) = as_segment(i)?;
            let (sb, rb) = as_segment(j)?;
            capsule_capsule_manifold(sa, ra, sb, rb, margin)
        }
        (Sphere(r), Box(h)) => sphere_box(s.x[i], *r, &box_pose(s, j, *h), margin),
        (Box(h), Sphere(r)) => {
            sphere_box(s.x[j], *r, &box_pose(s, i, *h), margin).map(Manifold::flipped)
        }
        (Capsule(hh, r), Box(h)) => {
            capsule_box(segment(s, i, *hh), *r, &box_pose(s, j, *h), margin)
        }
        (Box(h), Capsule(hh, r)) => {
            capsule_box(segment(s, j, *hh), *r, &box_pose(s, i, *h), margin).map(Manifold::flipped)
        }
        (Box(ha), Box(hb)) => box_box(&box_pose(s, i, *ha), &box_pose(s, j, *hb), margin),
        _ => {
            let convex = |k: usize| match &m.colliders[k] {
                Sphere(r) => Convex::Sphere {
                    center: s.x[k],
                    radius: *r,
                },
                Capsule(hh, r) => {
                    let [a, b] = segment(s, k, *hh);
                    Convex::Capsule { a, b, radius: *r }
                }
                Box(h) => box_pose(s, k, *h).convex(),
                Hull(_) => Convex::Hull(&hulls[k]),
            };
            convex_convex(&convex(i), &convex(j), margin)
        }
    }
}

/// Finds the contact points of the present state into `w.contacts` (last step's kept in
/// `w.previous` for warm starting), and reports the counts.
pub(crate) fn collide(
    m: &Rigid,
    s: &RigidState,
    w: &mut RigidWork,
    dt: f64,
) -> Result<RigidStepInfo, RigidError> {
    let n = m.len();
    std::mem::swap(&mut w.contacts, &mut w.previous);
    w.contacts.clear();
    let mut info = RigidStepInfo::default();
    if !m.collides() {
        return Ok(info);
    }
    // Hull points in world coordinates, for the bodies that have them.
    for i in 0..n {
        if let Collider::Hull(h) = &m.colliders[i] {
            let out = &mut w.hulls[i];
            out.clear();
            out.extend(h.iter().map(|p| add(s.x[i], quat::rotate(s.q[i], *p))));
        }
    }
    // Boxes grown by the margin and the distance the body may move this step.
    w.boxes.clear();
    for i in 0..n {
        let sweep = (dot(s.v[i], s.v[i]).sqrt() + dot(s.w[i], s.w[i]).sqrt() * m.bound[i]) * dt;
        w.boxes.push(body_box(m, s, i, MARGIN * m.size[i] + sweep));
    }
    // The sweep stops past the limit, before the list outgrows memory.
    let max = m.desc().max_pairs;
    if !w.sap.pairs_at_most(&w.boxes, max, &mut w.pairs) {
        return Err(RigidError::TooManyPairs {
            step: s.steps + 1,
            max,
        });
    }
    // Pairs in order, so the contacts come out sorted by pair (warm starting looks last
    // step's up by pair) without sorting the contacts themselves.
    w.pairs.sort_unstable();
    for &[a, b] in &w.pairs {
        let (i, j) = (a as usize, b as usize);
        if !m.is_dynamic(i) && !m.is_dynamic(j) {
            continue;
        }
        // Two asleep bodies, or one asleep against one that does not move, stay as
        // they are.
        if !super::sleep::moves(m, s, i) && !super::sleep::moves(m, s, j) {
            continue;
        }
        if m.jointed.binary_search(&(a, b)).is_ok() {
            continue;
        }
        info.pairs += 1;
        // Speculative reach: the margin and how far the two may close this step.
        let rel = sub(s.v[j], s.v[i]);
        let spin =
            dot(s.w[i], s.w[i]).sqrt() * m.bound[i] + dot(s.w[j], s.w[j]).sqrt() * m.bound[j];
        let margin = MARGIN * m.size[i].min(m.size[j]) + (dot(rel, rel).sqrt() + spin) * dt;
        let Some(man) = manifold(m, s, &w.hulls, i, j, margin) else {
            continue;
        };
        for p in man.points() {
            if !(p.depth.is_finite() && p.point.iter().all(|c| c.is_finite())) {
                continue;
            }
            info.max_depth = info.max_depth.max(p.depth);
            w.contacts.push(ContactPoint {
                a,
                b,
                normal: man.normal,
                point: p.point,
                depth: p.depth,
                local_a: quat::rotate_inv(s.q[i], sub(p.point, s.x[i])),
                impulse: [0.0; 3],
                pseudo: 0.0,
            });
        }
    }
    info.contacts = w.contacts.len();
    // Warm start: a point takes the impulse of last step's nearest point of the same pair
    // within a quarter of the smaller body's feature size (in a's frame).
    // Both lists are sorted by pair, so one walk along last step's finds each pair's.
    let mut lo = 0;
    for c in &mut w.contacts {
        while w.previous.get(lo).is_some_and(|p| (p.a, p.b) < (c.a, c.b)) {
            lo += 1;
        }
        let tol = 0.25 * m.size[c.a as usize].min(m.size[c.b as usize]);
        let mut best = (tol * tol, None);
        for p in w.previous[lo..]
            .iter()
            .take_while(|p| (p.a, p.b) == (c.a, c.b))
        {
            let d = sub(p.local_a, c.local_a);
            let d2 = dot(d, d);
            if d2 < best.0 {
                best = (d2, Some(p.impulse));
            }
        }
        if let Some(imp) = best.1 {
            c.impulse = imp;
            info.warm += 1;
        }
    }
    Ok(info)
}
