//! The rigid bodies' collision stage: boxes, sweep and prune, manifolds, and the match of
//! each new contact point with last step's (for warm starting).
//!
//! Manifolds persist: a pair of polyhedra keeps its points in the two bodies' frames,
//! with the relative pose they were found at, and while the pose stays within
//! [`RigidDesc::contact_reuse`](super::RigidDesc::contact_reuse) of it (a resting pair)
//! the points are moved with the bodies and their depths measured
//! again instead of running the narrow phase (PhysX's persistent contact manifolds;
//! Bullet's `refreshContactPoints`). The pose is measured against the one the manifold
//! was found at, not last step's, so slow creep cannot carry a manifold further than that.

use super::{
    clone_keeping_capacity, mat_t_vec, mat_vec, Collider, Rigid, RigidError, RigidState,
    RigidStepInfo, RigidWork,
};
use largestep_kernels::collide::bv::Aabb;
use largestep_kernels::collide::manifold::{
    box_box, capsule_box, capsule_capsule_manifold, convex_convex, sphere_box,
    sphere_sphere_manifold, BoxPose, Manifold, MAX_POINTS,
};
use largestep_kernels::collide::narrow::Convex;
use largestep_kernels::quat::{self, Quat};
use largestep_kernels::rotation;
use largestep_kernels::v3::{add, dot, scale, sub};

/// Contact margin as a fraction of the smaller body's feature size: points this far apart
/// are kept as speculative contacts (beside the distance the pair may close in the step,
/// added per pair): 1 cm on the pile's boxes of half-size 0.5 m (rapier's and Box2D's
/// speculative distance is four linear slops, 2 cm). At 10% the settling 1,000-box pile
/// carried 4,471 points a step, 2,148 of them apart; at 2%, 3,964 and 1,563, and its
/// last 120 steps took 12% less time (five alternating runs of each); 1% changed nothing
/// more.
pub(crate) const MARGIN: f64 = 0.02;

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

/// How far one contact list stands from another found on the same state (kept manifolds
/// against the narrow phase run afresh, say), pair by pair: both sorted by pair, as
/// [`RigidWork::contacts`](super::RigidWork::contacts) are. Accumulates over calls.
#[derive(Clone, Debug, Default)]
pub struct ContactDiff {
    /// For each pair with points in both: the gap between their deepest points' depths
    /// (m, absolute).
    pub gaps: Vec<f64>,
    /// Pairs in both whose normals differ by more than [`ContactDiff::APART`] (another
    /// separating axis, or a face turned away).
    pub flipped: usize,
    /// Pairs with points in one list only.
    pub unmatched: usize,
}

impl ContactDiff {
    /// The angle between two pairs' normals counted as flipped (rad).
    pub const APART: f64 = 0.05;

    /// Adds the comparison of `a` with `b` (each sorted by pair).
    pub fn add(&mut self, a: &[ContactPoint], b: &[ContactPoint]) {
        // Each pair's deepest depth and normal, in pair order.
        let summary = |c: &[ContactPoint]| {
            c.chunk_by(|p, q| (p.a, p.b) == (q.a, q.b))
                .map(|g| {
                    let deepest = g.iter().map(|p| p.depth).fold(f64::NEG_INFINITY, f64::max);
                    ((g[0].a, g[0].b), deepest, g[0].normal)
                })
                .collect::<Vec<_>>()
        };
        let (a, b) = (summary(a), summary(b));
        let (mut i, mut j) = (0, 0);
        while i < a.len() && j < b.len() {
            match a[i].0.cmp(&b[j].0) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    self.gaps.push((a[i].1 - b[j].1).abs());
                    if dot(a[i].2, b[j].2).clamp(-1.0, 1.0).acos() > Self::APART {
                        self.flipped += 1;
                    }
                    i += 1;
                    j += 1;
                    continue;
                }
            }
            self.unmatched += 1;
        }
        self.unmatched += (a.len() - i) + (b.len() - j);
    }
}

/// The default of [`RigidDesc::contact_reuse`](super::RigidDesc::contact_reuse): how far
/// a pair's relative pose may move from the pose its manifold was found at before the
/// narrow phase runs again, the offset by this fraction of the smaller body's feature
/// size, the relative rotation by this angle (rad). Below it the kept points are moved
/// with their bodies (a persistent manifold: PhysX's contact reuse, Bullet's
/// `refreshContactPoints`). The solver's slop: the kept points' depths stay within it of
/// a fresh narrow phase's (`kept_manifolds_match_the_narrow_phase_run_afresh`).
pub(crate) const REUSE: f64 = 0.005;

/// The most steps a manifold whose points are all apart is kept before the narrow phase
/// runs again whatever the pose. Within [`REUSE`] the separating axis of a pair that is
/// apart can change (a box hovering by a corner of another's face: which face's axis
/// separates most turns on millimetres), and a resting pile would keep such a manifold
/// for good. A touching pair keeps its manifold while the pose holds: finding a resting
/// stack's points afresh every 8 steps made the stack under split impulses sway out of
/// its column at 8 sub-steps (drift 7.6e-2 m against 1.1e-2 m).
pub(crate) const KEEP_STEPS: u8 = 8;

/// A pair's manifold in its bodies' frames, kept while their relative pose stays within
/// [`REUSE`] of the pose it was found at.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Kept {
    /// b's centre in a's frame (m) and b's orientation relative to a's, when found.
    offset: [f64; 3],
    rel: Quat,
    /// The normal in a's frame.
    normal: [f64; 3],
    /// The points on a's surface in a's frame, and on b's in b's frame (m).
    on_a: [[f64; 3]; MAX_POINTS],
    on_b: [[f64; 3]; MAX_POINTS],
    count: usize,
    /// Steps it has been kept since it was found.
    steps: u8,
}

/// The kept manifolds in pair order, with their pairs apart as 64-bit keys `a << 32 | b`:
/// the walk that looks each pair up reads 8 bytes a manifold rather than a 290-byte
/// record (the records' loads were a tenth of the collision stage's own time).
#[derive(Debug, Default)]
pub(crate) struct KeptManifolds {
    keys: Vec<u64>,
    list: Vec<Kept>,
}

impl Clone for KeptManifolds {
    fn clone(&self) -> Self {
        KeptManifolds {
            keys: clone_keeping_capacity(&self.keys),
            list: clone_keeping_capacity(&self.list),
        }
    }
}

impl KeptManifolds {
    fn clear(&mut self) {
        self.keys.clear();
        self.list.clear();
    }

    fn push(&mut self, key: u64, k: Kept) {
        self.keys.push(key);
        self.list.push(k);
    }
}

/// b's centre in a's frame and b's orientation relative to a's (`rot`: the bodies'
/// rotation matrices).
fn relative_pose(s: &RigidState, rot: &[[[f64; 3]; 3]], i: usize, j: usize) -> ([f64; 3], Quat) {
    (
        mat_t_vec(&rot[i], sub(s.x[j], s.x[i])),
        quat::mul(quat::conj(s.q[i]), s.q[j]),
    )
}

impl Kept {
    fn new(
        s: &RigidState,
        rot: &[[[f64; 3]; 3]],
        [i, j]: [usize; 2],
        pose: ([f64; 3], Quat),
        m: &Manifold,
    ) -> Kept {
        let mut k = Kept {
            offset: pose.0,
            rel: pose.1,
            normal: mat_t_vec(&rot[i], m.normal),
            count: m.count,
            ..Kept::default()
        };
        for (n, p) in m.points().iter().enumerate() {
            // The midpoint's surface points: a's reaches depth/2 along the normal into b.
            let half = scale(m.normal, 0.5 * p.depth);
            k.on_a[n] = mat_t_vec(&rot[i], sub(add(p.point, half), s.x[i]));
            k.on_b[n] = mat_t_vec(&rot[j], sub(sub(p.point, half), s.x[j]));
        }
        k
    }

    /// Whether the pair's present pose is close enough to the kept one.
    /// (`reuse`: [`RigidDesc::contact_reuse`](super::RigidDesc::contact_reuse).)
    fn holds(&self, pose: ([f64; 3], Quat), size: f64, reuse: f64) -> bool {
        let d = sub(pose.0, self.offset);
        let c = rotation::dot4(pose.1, self.rel).abs();
        // cos(angle / 2) > 1 - angle^2 / 8 for the angle between the orientations.
        dot(d, d) < (reuse * size) * (reuse * size) && c > 1.0 - reuse * reuse / 8.0
    }

    /// The kept points at the bodies' present poses, less those now more than `margin`
    /// (m) apart (the margin shrinks as the pair slows); `None` if none is left.
    fn manifold(
        &self,
        s: &RigidState,
        rot: &[[[f64; 3]; 3]],
        [i, j]: [usize; 2],
        margin: f64,
    ) -> Option<Manifold> {
        let normal = mat_vec(rot[i], self.normal);
        let mut m = Manifold {
            normal,
            ..Manifold::default()
        };
        for n in 0..self.count {
            let pa = add(s.x[i], mat_vec(rot[i], self.on_a[n]));
            let pb = add(s.x[j], mat_vec(rot[j], self.on_b[n]));
            let depth = dot(sub(pa, pb), normal);
            if depth >= -margin {
                m.points[m.count].point = scale(add(pa, pb), 0.5);
                m.points[m.count].depth = depth;
                m.count += 1;
            }
        }
        (m.count > 0).then_some(m)
    }
}

/// The box of body `i` at its pose, grown by `grow` (m).
fn body_box(m: &Rigid, s: &RigidState, r: &[[f64; 3]; 3], i: usize, grow: f64) -> Aabb {
    let x = s.x[i];
    let ext = match &m.colliders[i] {
        Collider::Sphere(r) => [*r; 3],
        Collider::Box(h) => {
            [0, 1, 2].map(|a| r[a][0].abs() * h[0] + r[a][1].abs() * h[1] + r[a][2].abs() * h[2])
        }
        Collider::Capsule(hh, rad) => [0, 1, 2].map(|a| (r[a][1] * hh).abs() + rad),
        Collider::Hull(_) => [m.bound[i]; 3],
    };
    let e = ext.map(|c| c + grow);
    Aabb {
        min: sub(x, e),
        max: add(x, e),
    }
}

/// Body `i`'s box: its axes are the columns of its rotation matrix `r`.
pub(crate) fn box_pose(s: &RigidState, r: &[[f64; 3]; 3], i: usize, half: [f64; 3]) -> BoxPose {
    BoxPose {
        center: s.x[i],
        axes: super::columns(r),
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
    rot: &[[[f64; 3]; 3]],
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
        (Sphere(r), Box(h)) => sphere_box(s.x[i], *r, &box_pose(s, &rot[j], j, *h), margin),
        (Box(h), Sphere(r)) => {
            sphere_box(s.x[j], *r, &box_pose(s, &rot[i], i, *h), margin).map(Manifold::flipped)
        }
        (Capsule(hh, r), Box(h)) => {
            capsule_box(segment(s, i, *hh), *r, &box_pose(s, &rot[j], j, *h), margin)
        }
        (Box(h), Capsule(hh, r)) => {
            capsule_box(segment(s, j, *hh), *r, &box_pose(s, &rot[i], i, *h), margin)
                .map(Manifold::flipped)
        }
        (Box(ha), Box(hb)) => box_box(
            &box_pose(s, &rot[i], i, *ha),
            &box_pose(s, &rot[j], j, *hb),
            margin,
        ),
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
                Box(h) => box_pose(s, &rot[k], k, *h).convex(),
                Hull(_) => Convex::Hull(&hulls[k]),
            };
            convex_convex(&convex(i), &convex(j), margin)
        }
    }
}

/// Sorts `pairs` (`[a, b]`, `a < b < n`, each once) by `a`, then `b`: a counting sort by
/// `a` into `scratch` (`starts`: each `a`'s first place), then each `a`'s few pairs by `b`.
/// Linear in the pairs and bodies: on the 1,000-box pile (about 3,000 pairs) the
/// comparison sort of 64-bit keys it replaces took 1.6% of a step in profiles, the
/// per-body sorts here 0.5%.
fn sort_pairs(
    pairs: &mut Vec<[u32; 2]>,
    n: usize,
    starts: &mut Vec<u32>,
    scratch: &mut Vec<[u32; 2]>,
) {
    starts.clear();
    starts.resize(n + 1, 0);
    for &[a, _] in pairs.iter() {
        starts[a as usize + 1] += 1;
    }
    for k in 0..n {
        starts[k + 1] += starts[k];
    }
    scratch.clear();
    scratch.resize(pairs.len(), [0; 2]);
    for &p in pairs.iter() {
        let at = &mut starts[p[0] as usize];
        scratch[*at as usize] = p;
        *at += 1;
    }
    // `starts[a]` is now where a's pairs end.
    let mut from = 0;
    for &end in &starts[..n] {
        scratch[from..end as usize].sort_unstable_by_key(|p| p[1]);
        from = end as usize;
    }
    std::mem::swap(pairs, scratch);
}

/// Finds the contact points of the present state into `w.contacts` (last step's kept in
/// `w.previous` for warm starting), and reports the counts.
pub(crate) fn collide(
    m: &Rigid,
    s: &RigidState,
    w: &mut RigidWork,
    dt: f64,
) -> Result<RigidStepInfo, RigidError> {
    std::mem::swap(&mut w.contacts, &mut w.previous);
    w.contacts.clear();
    // The rotations of the step's start, for this stage and the solver's.
    w.rot.clear();
    w.rot.extend(s.q.iter().map(|q| quat::to_matrix(*q)));
    if !m.collides() {
        return Ok(RigidStepInfo::default());
    }
    broad_phase(m, s, w, dt)?;
    Ok(narrow_phase(m, s, w, dt))
}

/// [`collide`] again at the same poses after bodies woke: the broad phase's pairs still
/// stand, so only the narrow phase runs (with the woken bodies' pairs now in it), warm
/// started from last step's contacts as before (`w.previous` is still theirs).
pub(crate) fn collide_again(
    m: &Rigid,
    s: &RigidState,
    w: &mut RigidWork,
    dt: f64,
) -> RigidStepInfo {
    w.contacts.clear();
    narrow_phase(m, s, w, dt)
}

/// The bodies' bounding boxes and the pairs whose boxes overlap, sorted, into `w.pairs`.
fn broad_phase(m: &Rigid, s: &RigidState, w: &mut RigidWork, dt: f64) -> Result<(), RigidError> {
    let n = m.len();
    // Hull points in world coordinates, for the bodies that have them.
    for i in 0..n {
        if let Collider::Hull(h) = &m.colliders[i] {
            let (out, r) = (&mut w.hulls[i], w.rot[i]);
            out.clear();
            out.extend(h.iter().map(|p| add(s.x[i], mat_vec(r, *p))));
        }
    }
    // Boxes grown by the margin and the distance the body may move this step.
    // Each body's spin, the fastest its surface turns about its centre (m/s), kept for
    // the pairs' margins below.
    w.boxes.clear();
    w.spin.clear();
    for i in 0..n {
        let spin = dot(s.w[i], s.w[i]).sqrt() * m.bound[i];
        let sweep = (dot(s.v[i], s.v[i]).sqrt() + spin) * dt;
        w.spin.push(spin);
        w.boxes
            .push(body_box(m, s, &w.rot[i], i, MARGIN * m.size[i] + sweep));
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
    sort_pairs(&mut w.pairs, n, &mut w.pair_starts, &mut w.pairs_sorted);
    Ok(())
}

/// The manifolds of the broad phase's pairs (kept ones moved with their bodies where the
/// pose holds), their points into `w.contacts` with last step's impulses (`w.previous`)
/// to warm-start from.
fn narrow_phase(m: &Rigid, s: &RigidState, w: &mut RigidWork, dt: f64) -> RigidStepInfo {
    let mut info = RigidStepInfo::default();
    w.kept_next.clear();
    let mut kept = 0;
    let tolerance = m.desc().contact_reuse;
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
        let spin = w.spin[i] + w.spin[j];
        let size = m.size[i].min(m.size[j]);
        let margin = MARGIN * size + (dot(rel, rel).sqrt() + spin) * dt;
        // Only polyhedra keep manifolds: their contact features move with them. A
        // rolling ball's or capsule's contact point does not (and theirs are cheap).
        let polyhedra = [i, j]
            .iter()
            .all(|&k| matches!(m.colliders[k], Collider::Box(_) | Collider::Hull(_)));
        let key = (u64::from(a) << 32) | u64::from(b);
        while w.kept.keys.get(kept).is_some_and(|&k| k < key) {
            kept += 1;
        }
        // The relative pose only where a manifold is kept or will be (most of the broad
        // phase's pairs find none).
        let mut pose = None;
        if polyhedra && w.kept.keys.get(kept) == Some(&key) {
            pose = Some(relative_pose(s, &w.rot, i, j));
        }
        let reuse = match pose {
            Some(pose) if w.kept.list[kept].holds(pose, size, tolerance) => {
                let k = &w.kept.list[kept];
                let man = k.manifold(s, &w.rot, [i, j], margin);
                let touching = man
                    .as_ref()
                    .is_some_and(|m| m.points().iter().any(|p| p.depth >= 0.0));
                (touching || k.steps < KEEP_STEPS).then(|| {
                    w.kept_next.push(
                        key,
                        Kept {
                            steps: k.steps.saturating_add(1),
                            ..*k
                        },
                    );
                    man
                })
            }
            _ => None,
        };
        let man = match reuse {
            Some(None) => continue,
            Some(Some(man)) => {
                info.reused += 1;
                man
            }
            None => {
                let Some(man) = manifold(m, s, &w.rot, &w.hulls, i, j, margin) else {
                    continue;
                };
                if polyhedra {
                    let pose = pose.unwrap_or_else(|| relative_pose(s, &w.rot, i, j));
                    w.kept_next
                        .push(key, Kept::new(s, &w.rot, [i, j], pose, &man));
                }
                man
            }
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
                local_a: mat_t_vec(&w.rot[i], sub(p.point, s.x[i])),
                impulse: [0.0; 3],
                pseudo: 0.0,
            });
        }
    }
    std::mem::swap(&mut w.kept, &mut w.kept_next);
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
    info
}

#[cfg(test)]
mod tests {
    use super::sort_pairs;

    /// The counting sort gives the order of a comparison sort by `(a, b)`, with the
    /// bodies' first and last ids, a body with many pairs and bodies with none.
    #[test]
    fn pairs_sort_as_by_their_two_ids() {
        let n = 50u32;
        let mut pairs = Vec::new();
        let mut h = 12345u32;
        for a in 0..n {
            for b in a + 1..n {
                h = h.wrapping_mul(1_103_515_245).wrapping_add(12_345);
                if a == 0 || (h >> 16).is_multiple_of(7) {
                    pairs.push([a, b]);
                }
            }
        }
        // Shuffled (a fixed permutation), as the sweep emits them.
        let len = pairs.len();
        for k in 0..len {
            pairs.swap(k, (k * 7919 + 13) % len);
        }
        let mut want = pairs.clone();
        want.sort_unstable();
        let (mut starts, mut scratch) = (Vec::new(), Vec::new());
        sort_pairs(&mut pairs, n as usize, &mut starts, &mut scratch);
        assert_eq!(pairs, want);
        let mut none = Vec::new();
        sort_pairs(&mut none, n as usize, &mut starts, &mut scratch);
        assert!(none.is_empty());
    }
}
