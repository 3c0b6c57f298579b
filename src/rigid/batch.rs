//! The contact rows in SIMD batches: four contact points a batch, one per lane of an
//! `f64x4`, no two lanes moving the same body, so a batch is solved at once.
//!
//! The lanes hold manifolds: a group of batches gives each lane the points of one body
//! pair (up to [`MANIFOLD`] of them, in order, one a batch), so the passes gather the
//! bodies' velocities once per group and keep them in registers from point to point, as
//! rapier solves a manifold's points together. A group also holds its lanes' manifold
//! friction ([`Friction`]: two tangent rows at each manifold's centre and a twist row),
//! solved before the points' normal rows.
//!
//! Batching keeps the sequential solver's answer. The manifolds are placed longest first
//! (so that groups hold manifolds of equal length and few point slots idle), each in the
//! first group with a free lane after every group that holds an earlier-placed point on
//! one of its movable bodies (Tonge, Benevolenskiy and Voronov 2012, "Mass splitting for
//! jitter-free parallel rigid body simulation", describe the colouring; rapier and Box2D
//! v3 colour their constraint graphs the same way). Two points that share no movable
//! body commute in Gauss-Seidel, and the points on any one body keep their order, so the
//! batched passes are a reordering of the sequential ones that gives the same impulses. Every
//! lane does the same operations in the same order whatever the batch (no fused
//! multiply-adds), so the bits agree too (the test below checks four-lane batches
//! against one-lane ones, the sequential order).
//!
//! Bodies are gathered and scattered as 64-byte records (velocity, angular velocity,
//! inverse mass) by two 4 x 4 transposes; static, kinematic and asleep bodies (inverse
//! mass 0) may sit in several lanes of a batch and are never written. Unused lanes point
//! at a padding body past the last one, and lanes whose manifold has fewer points than
//! the group's longest at the manifold's own bodies; both hold an idle speculative point
//! (no direction, depth -1 m, no mass), which changes nothing.

use super::solver::{ContactRow, Pass, SolverBody, SolverMotion, MAX_PUSH};
use super::{ContactPoint, Correction};
use largestep_kernels::rigid::{dot, mat_vec};
use largestep_kernels::v3;
use wide::f64x4;

type V = f64x4;
type V3 = [V; 3];

/// Four lanes of a row's fixed values (direction, lever arms, angular responses, mass)
/// stored in single precision and widened where they are read: the rows of a settling
/// pile outgrow the core's cache (eight lanes instead of four gained nothing; half the
/// bytes made the 1,000-box pile's 360 steps 8-10% faster). Sums and impulses stay in
/// double precision. Rapier's rows are single precision throughout.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(16))]
pub(crate) struct F([f32; 4]);
type F3 = [F; 3];

impl F {
    #[inline(always)]
    fn get(self) -> V {
        let a = self.0;
        V::new([a[0] as f64, a[1] as f64, a[2] as f64, a[3] as f64])
    }

    #[inline(always)]
    fn put(v: V) -> F {
        let a = v.to_array();
        F([a[0] as f32, a[1] as f32, a[2] as f32, a[3] as f32])
    }
}

#[inline(always)]
fn get3(x: F3) -> V3 {
    [x[0].get(), x[1].get(), x[2].get()]
}

/// A pair of rows' angular responses, widened (spelt out: an array's `map` here can stay
/// an out-of-line call, `try_map`).
#[inline(always)]
fn get6(x: [F3; 2]) -> [V3; 2] {
    [get3(x[0]), get3(x[1])]
}

#[inline(always)]
fn put3(v: V3) -> F3 {
    [F::put(v[0]), F::put(v[1]), F::put(v[2])]
}

/// A lane not in use.
pub(crate) const UNUSED: u32 = u32::MAX;

/// The most points of one pair a lane holds in a group (box-box manifolds are reduced to
/// four; longer runs continue in a later group).
pub(crate) const MANIFOLD: usize = 4;

/// The batches, and the groups of consecutive batches that share their lanes' bodies.
#[derive(Debug, Default)]
pub(crate) struct Batches {
    batches: Vec<Batch>,
    /// Each group's batches, `start..end` in `batches`.
    groups: Vec<(u32, u32)>,
    /// Each group's friction rows, one set per lane's manifold (from [`fill`]).
    friction: Vec<Friction>,
}

impl Clone for Batches {
    /// Keeps the capacity (criterion steps clones of a state's scratch).
    fn clone(&self) -> Self {
        Batches {
            batches: super::clone_keeping_capacity(&self.batches),
            groups: super::clone_keeping_capacity(&self.groups),
            friction: super::clone_keeping_capacity(&self.friction),
        }
    }
}

impl Batches {
    /// How many batches (for the tests).
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.batches.len()
    }
}

/// Four contact points' normal rows in structure-of-arrays form (fields as in
/// [`ContactRow`]'s first row, less the lever arm `r x n`: a row's velocity is `n`
/// dotted with the points' relative velocity, which takes two cross products a visit
/// instead of 192 bytes a batch). Their friction is their manifold's ([`Friction`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Batch {
    a: [u32; 4],
    b: [u32; 4],
    /// Each lane's point in `SolverWork::contacts`, or [`UNUSED`].
    index: [u32; 4],
    normal: F3,
    ra: F3,
    rb: F3,
    /// `[Ia^-1 (ra x n), Ib^-1 (rb x n)]`.
    turn: [F3; 2],
    mass: F,
    lambda: V,
    plambda: V,
    error: V,
    depth: F,
    slop: F,
    /// The point's distance from its manifold's centre across the normal (m): its
    /// normal impulse's share of the twist friction's cap.
    lever: F,
    max_normal: V,
    /// The step's normal impulse (N s).
    total: V,
    /// The approach speed at the step's start (m/s), for restitution.
    approach: F,
}

/// A group's friction, one manifold a lane (rapier's and bepu's manifold friction):
/// two tangent rows at the manifold's centre, capped together by the friction
/// coefficient times the manifold's normal impulse, and a twist row about the normal,
/// capped by the coefficient times each point's normal impulse times its distance from
/// the centre. Three rows a manifold instead of two a point; the torque the tangent rows
/// would have given about the normal is the twist row's.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Friction {
    /// The two tangents, then the normal (the twist's axis).
    dir: [F3; 3],
    /// The centre's lever arms (m).
    ra: F3,
    rb: F3,
    /// `[Ia^-1 (ra x t), Ib^-1 (rb x t)]` for each tangent, `[Ia^-1 n, Ib^-1 n]`.
    turn: [[F3; 2]; 3],
    mass: F3,
    lambda: V3,
    /// The sums over the manifold's points of the normal impulses and of the normal
    /// impulses times the points' levers, from the last pass over them: the caps.
    load: V,
    moment: V,
    /// The step's tangent impulses and twist (N s, N m s).
    total: V3,
}

/// What the batched passes need of the step.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Lanes {
    pub h: f64,
    pub beta: f64,
    pub friction: f64,
    pub restitution: f64,
    pub accumulate: bool,
    pub correction: Correction,
    /// `(bias_rate, mass_scale, impulse_scale)` of soft contacts between two movable
    /// bodies, and against one that cannot move.
    pub contact_soft: [f64; 3],
    pub static_soft: [f64; 3],
    /// Approach speed (m/s) above which one-shot impulses bounce.
    pub bounce: f64,
}

/// The batching's scratch, kept between steps.
#[derive(Clone, Debug, Default)]
pub(crate) struct Batcher {
    /// Per body: one past the last group holding one of its points.
    after: Vec<u32>,
    /// Per group: itself if it has a free lane, else a later group to look at.
    next: Vec<u32>,
    fill: Vec<u8>,
    /// Per group and lane: the manifold's first point and its number of points.
    lanes: Vec<[(u32, u32); 4]>,
    /// The manifolds (first point, number of points) in the order they are placed.
    runs: Vec<(u32, u32)>,
    /// Lanes a batch may fill (4; 1 in the tests that check the batching against the
    /// sequential order).
    pub(crate) width: u8,
}

#[inline(always)]
fn splat(x: f64) -> V {
    V::splat(x)
}

#[inline(always)]
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline(always)]
fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[inline(always)]
fn scale(a: V3, s: V) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// A body's velocities in the lanes of `idx`, with its inverse mass.
#[derive(Clone, Copy)]
struct Vel {
    v: V3,
    w: V3,
    inv_mass: V,
}

// The gathers and scatters below spell their four lanes out: array `map`s here stayed
// out-of-line calls (`try_map`, six a batch).

#[inline(always)]
fn gather(bodies: &[SolverBody], idx: [u32; 4]) -> Vel {
    let (b0, b1, b2, b3) = (
        &bodies[idx[0] as usize],
        &bodies[idx[1] as usize],
        &bodies[idx[2] as usize],
        &bodies[idx[3] as usize],
    );
    let low = |b: &SolverBody| V::new([b.v[0], b.v[1], b.v[2], b.w[0]]);
    let high = |b: &SolverBody| V::new([b.w[1], b.w[2], b.inv_mass, 0.0]);
    let lo = V::transpose([low(b0), low(b1), low(b2), low(b3)]);
    let hi = V::transpose([high(b0), high(b1), high(b2), high(b3)]);
    Vel {
        v: [lo[0], lo[1], lo[2]],
        w: [lo[3], hi[0], hi[1]],
        inv_mass: hi[2],
    }
}

/// Writes the lanes of movable bodies back (those that cannot move keep their own).
#[inline(always)]
fn scatter(bodies: &mut [SolverBody], idx: [u32; 4], u: &Vel) {
    let lo = V::transpose([u.v[0], u.v[1], u.v[2], u.w[0]]);
    let hi = V::transpose([u.w[1], u.w[2], u.inv_mass, V::ZERO]);
    for l in 0..4 {
        let b = &mut bodies[idx[l] as usize];
        if b.inv_mass > 0.0 {
            let (lo, hi) = (lo[l].as_array(), hi[l].as_array());
            b.v = [lo[0], lo[1], lo[2]];
            b.w = [lo[3], hi[0], hi[1]];
        }
    }
}

/// Runs `f` on every batch of every group that `skip` leaves, with the group's bodies
/// gathered from `bodies` once, at its first such batch, and scattered after its last.
fn each_group(
    b: &mut Batches,
    bodies: &mut [SolverBody],
    skip: impl Fn(&Batch) -> bool,
    mut f: impl FnMut(&mut Batch, &mut Vel, &mut Vel),
) {
    let Batches {
        batches, groups, ..
    } = b;
    for &(start, end) in groups.iter() {
        let group = &mut batches[start as usize..end as usize];
        let (a, b) = (group[0].a, group[0].b);
        let mut u = None;
        for t in group.iter_mut().filter(|t| !skip(t)) {
            let (ua, ub) = u.get_or_insert_with(|| (gather(bodies, a), gather(bodies, b)));
            f(t, ua, ub);
        }
        if let Some((ua, ub)) = u {
            scatter(bodies, a, &ua);
            scatter(bodies, b, &ub);
        }
    }
}

impl Batch {
    /// A batch of unused lanes (`pad`: the padding body's index).
    fn empty(pad: u32) -> Batch {
        let (z, f) = (V::ZERO, F::default());
        let f3 = [f; 3];
        Batch {
            a: [pad; 4],
            b: [pad; 4],
            index: [UNUSED; 4],
            normal: f3,
            ra: f3,
            rb: f3,
            turn: [f3; 2],
            mass: f,
            lambda: z,
            plambda: z,
            error: splat(-1.0),
            depth: F([-1.0; 4]),
            slop: f,
            lever: f,
            max_normal: z,
            total: z,
            approach: f,
        }
    }

    /// The present penetration from the motion of the bodies since the step's start
    /// (`gather_motion` of `a` and of `b`).
    #[inline(always)]
    fn update_error(&mut self, (xa, ra): &(V3, [V3; 3]), (xb, rb): &(V3, [V3; 3])) {
        let (xa, ra, xb, rb) = (*xa, *ra, *xb, *rb);
        let da = add(xa, mat_vec(ra, get3(self.ra)));
        let db = add(xb, mat_vec(rb, get3(self.rb)));
        self.error = self.depth.get() - dot(get3(self.normal), sub(db, da));
    }

    /// After a sub-step's last pass: the largest normal impulse and the total impulse.
    #[inline(always)]
    fn accumulate(&mut self) {
        self.max_normal = self.max_normal.max(self.lambda);
        self.total += self.lambda;
    }

    /// The relative velocity along the normal, `n (vb - va) + (rb x n) wb - (ra x n) wa`
    /// (`solver::row_velocity`) as `n` dotted with [`relative`].
    #[inline(always)]
    fn velocity(&self, ua: &Vel, ub: &Vel) -> V {
        dot(
            get3(self.normal),
            relative(ua, ub, get3(self.ra), get3(self.rb)),
        )
    }

    /// Applies the normal impulses `l` (as `solver::contact_push`).
    #[inline(always)]
    fn push(&self, ua: &mut Vel, ub: &mut Vel, l: V) {
        push(ua, ub, get3(self.normal), get6(self.turn), l);
    }
}

/// The velocity of b's point relative to a's, `vb + wb x rb - va - wa x ra` (the lever
/// arms of the step's start, as the rows' Jacobians).
#[inline(always)]
fn relative(ua: &Vel, ub: &Vel, ra: V3, rb: V3) -> V3 {
    sub(add(ub.v, cross(ub.w, rb)), add(ua.v, cross(ua.w, ra)))
}

/// Applies the impulses `l` along `d` (`-l` on a, `l` on b), whose angular velocities
/// per unit impulse are `turn`.
#[inline(always)]
fn push(ua: &mut Vel, ub: &mut Vel, d: V3, turn: [V3; 2], l: V) {
    ua.v = sub(ua.v, scale(d, ua.inv_mass * l));
    ua.w = sub(ua.w, scale(turn[0], l));
    ub.v = add(ub.v, scale(d, ub.inv_mass * l));
    ub.w = add(ub.w, scale(turn[1], l));
}

/// The tangent impulses `(l1, l2)` scaled back onto Coulomb's cone of radius `cap`
/// where they leave it.
#[inline(always)]
fn on_cone(l1: V, l2: V, cap: V) -> (V, V) {
    let (zero, one) = (V::ZERO, splat(1.0));
    let lt = (l1 * l1 + l2 * l2).sqrt();
    let f = lt
        .simd_gt(cap)
        .bitselect(lt.simd_gt(zero).bitselect(cap / lt, zero), one);
    (l1 * f, l2 * f)
}

impl Friction {
    /// Applies the impulses `l` along the tangents and the twist `l[2]` about the normal.
    #[inline(always)]
    fn push(&self, ua: &mut Vel, ub: &mut Vel, l: V3) {
        push(ua, ub, get3(self.dir[0]), get6(self.turn[0]), l[0]);
        push(ua, ub, get3(self.dir[1]), get6(self.turn[1]), l[1]);
        ua.w = sub(ua.w, scale(get3(self.turn[2][0]), l[2]));
        ub.w = add(ub.w, scale(get3(self.turn[2][1]), l[2]));
    }

    /// Whether no lane holds or may take an impulse (no load, nothing held).
    #[inline(always)]
    fn idle(&self) -> bool {
        let zero = V::ZERO;
        (self.load.simd_eq(zero)
            & self.lambda[0].simd_eq(zero)
            & self.lambda[1].simd_eq(zero)
            & self.lambda[2].simd_eq(zero))
        .all()
    }

    /// One pass over the rows, within the caps of the last normal pass's impulses;
    /// false if every lane was idle.
    #[inline(always)]
    fn solve(&mut self, ua: &mut Vel, ub: &mut Vel, friction: V) -> bool {
        if self.idle() {
            return false;
        }
        let dir = [get3(self.dir[0]), get3(self.dir[1]), get3(self.dir[2])];
        let mass = get3(self.mass);
        let dv = relative(ua, ub, get3(self.ra), get3(self.rb));
        let d1 = mass[0] * -dot(dir[0], dv);
        let d2 = mass[1] * -dot(dir[1], dv);
        let old = self.lambda;
        let (l1, l2) = on_cone(old[0] + d1, old[1] + d2, friction * self.load);
        push(ua, ub, dir[0], get6(self.turn[0]), l1 - old[0]);
        push(ua, ub, dir[1], get6(self.turn[1]), l2 - old[1]);
        // The twist after the tangents, from the spin they left.
        let spin = dot(dir[2], sub(ub.w, ua.w));
        let cap = friction * self.moment;
        let l3 = (old[2] + mass[2] * -spin).max(-cap).min(cap);
        let d3 = l3 - old[2];
        ua.w = sub(ua.w, scale(get3(self.turn[2][0]), d3));
        ub.w = add(ub.w, scale(get3(self.turn[2][1]), d3));
        self.lambda = [l1, l2, l3];
        true
    }
}

/// Sorts the contact points into groups of batches (module docs): each lane gets its
/// manifold's bodies and point indices, the rows come from [`fill`]; `bodies` has the
/// padding body last, and `points` a pair's points one after another.
pub(crate) fn build(
    points: &[ContactPoint],
    bodies: &[SolverBody],
    scratch: &mut Batcher,
    out: &mut Batches,
) {
    let pad = (bodies.len() - 1) as u32;
    let width = if scratch.width == 0 { 4 } else { scratch.width };
    scratch.after.clear();
    scratch.after.resize(bodies.len(), 0);
    scratch.next.clear();
    scratch.fill.clear();
    scratch.lanes.clear();
    let movable = |i: u32| bodies[i as usize].inv_mass > 0.0;
    // The manifolds, longest first: a group's batches are as many as its longest
    // manifold has points, and lanes with fewer sit idle in the rest, so manifolds of
    // equal length are placed together (in a settling pile a quarter of the point slots
    // were idle when they were placed in pair order).
    scratch.runs.clear();
    let mut k = 0;
    while k < points.len() {
        let (a, b) = (points[k].a, points[k].b);
        let mut end = k + 1;
        while end < points.len() && end - k < MANIFOLD && points[end].a == a && points[end].b == b {
            end += 1;
        }
        scratch.runs.push((k as u32, (end - k) as u32));
        k = end;
    }
    let runs = (1..=MANIFOLD as u32)
        .rev()
        .flat_map(|len| scratch.runs.iter().filter(move |r| r.1 == len));
    for &(k, count) in runs {
        let (a, b) = (points[k as usize].a, points[k as usize].b);
        let mut first = 0;
        for i in [a, b] {
            if movable(i) {
                first = first.max(scratch.after[i as usize]);
            }
        }
        // The first group from `first` on with a free lane, halving the paths walked.
        let mut at = first as usize;
        while at < scratch.next.len() && scratch.next[at] as usize != at {
            let up = scratch.next[at] as usize;
            if up < scratch.next.len() {
                scratch.next[at] = scratch.next[up];
            }
            at = up;
        }
        if at == scratch.next.len() {
            scratch.next.push(at as u32);
            scratch.fill.push(0);
            scratch.lanes.push([(UNUSED, 0); 4]);
        }
        let lane = scratch.fill[at] as usize;
        scratch.fill[at] += 1;
        if scratch.fill[at] == width {
            scratch.next[at] = at as u32 + 1;
        }
        for i in [a, b] {
            if movable(i) {
                scratch.after[i as usize] = at as u32 + 1;
            }
        }
        scratch.lanes[at][lane] = (k, count);
    }
    // A group's batches: as many as its longest manifold has points.
    out.batches.clear();
    out.groups.clear();
    for lanes in &scratch.lanes {
        let start = out.batches.len() as u32;
        let slots = lanes.iter().map(|l| l.1).max().unwrap_or(0);
        for slot in 0..slots {
            let mut t = Batch::empty(pad);
            for (l, &(first, count)) in lanes.iter().enumerate() {
                if count > 0 {
                    let c = &points[first as usize];
                    t.a[l] = c.a;
                    t.b[l] = c.b;
                    if slot < count {
                        t.index[l] = first + slot;
                    }
                }
            }
            out.batches.push(t);
        }
        out.groups.push((start, out.batches.len() as u32));
    }
}

/// What [`fill`] forms the rows from.
pub(crate) struct RowInputs<'a> {
    pub points: &'a [ContactPoint],
    /// Body centres at the step's start (m).
    pub x: &'a [[f64; 3]],
    /// The bodies with the padding body last.
    pub bodies: &'a [SolverBody],
    /// World inverse inertias (no entry for the padding body).
    pub inv_inertia: &'a [[[f64; 3]; 3]],
    /// Each point's slop (m), by point.
    pub slop: &'a dyn Fn(&ContactPoint) -> f64,
    pub friction: f64,
    pub substeps: usize,
    /// Warm start from last step's impulses.
    pub accumulate: bool,
}

/// The batches' rows, fixed over the step: each point's normal row (the angular
/// velocity `I^-1 (r x n)` a unit impulse gives each body, from the lever arm `r x n`,
/// not kept; the effective mass; the approach speed; its distance from its manifold's
/// centre) and each manifold's friction rows at its centre ([`Friction`]: tangent frame,
/// effective masses, the twist's), with the warm start's impulses per sub-step: the
/// normal ones from each point's last impulse, the friction ones from the points'
/// impulses summed (force and torque about the normal), clamped to the caps. Formed four
/// lanes at a time, every lane with the same operations in the same order. Lanes
/// without a point keep the idle point of [`Batch::empty`] (no direction, depth -1 m)
/// and get no mass, whether on the padding body or on their manifold's bodies.
pub(crate) fn fill(batches: &mut Batches, inp: &RowInputs) {
    let (zero, one) = (V::ZERO, splat(1.0));
    let per = splat(1.0 / inp.substeps as f64);
    let friction = splat(inp.friction);
    let v3 = |x: [[f64; 4]; 3]| x.map(V::new);
    let m3 = |x: [[[f64; 4]; 3]; 3]| [v3(x[0]), v3(x[1]), v3(x[2])];
    let Batches {
        batches,
        groups,
        friction: rows,
    } = batches;
    rows.clear();
    for &(start, end) in groups.iter() {
        let group = &mut batches[start as usize..end as usize];
        let (a, b) = (group[0].a, group[0].b);
        // Per lane: the bodies, the manifold's normal, the centre of its points and
        // their impulses (sum, and moment about the centre after it is known).
        let mut n = [[0.0; 4]; 3];
        let mut xa = [[0.0; 4]; 3];
        let mut xb = [[0.0; 4]; 3];
        let mut ia = [[[0.0; 4]; 3]; 3];
        let mut ib = [[[0.0; 4]; 3]; 3];
        let mut centre = [[0.0; 4]; 3];
        let mut imp = [[0.0; 4]; 3];
        let mut count = [0.0; 4];
        for t in group.iter() {
            for l in 0..4 {
                if t.index[l] == UNUSED {
                    continue;
                }
                let c = &inp.points[t.index[l] as usize];
                for k in 0..3 {
                    centre[k][l] += c.point[k];
                    imp[k][l] += c.impulse[k];
                }
                count[l] += 1.0;
            }
        }
        for l in 0..4 {
            if count[l] == 0.0 {
                continue;
            }
            let c = &inp.points[group[0].index[l] as usize];
            let (ba, bb) = (c.a as usize, c.b as usize);
            for k in 0..3 {
                centre[k][l] /= count[l];
                n[k][l] = c.normal[k];
                xa[k][l] = inp.x[ba][k];
                xb[k][l] = inp.x[bb][k];
                for j in 0..3 {
                    ia[k][j][l] = inp.inv_inertia[ba][k][j];
                    ib[k][j][l] = inp.inv_inertia[bb][k][j];
                }
            }
        }
        let (n, xa, xb, centre) = (v3(n), v3(xa), v3(xb), v3(centre));
        let (ia, ib) = (m3(ia), m3(ib));
        let (ua, ub) = (gather(inp.bodies, a), gather(inp.bodies, b));
        let mut twist = zero;
        let mut load = zero;
        let mut moment = zero;
        for t in group.iter_mut() {
            let mut p = [[0.0; 4]; 3];
            let mut pimp = [[0.0; 4]; 3];
            let mut depth = [-1.0; 4];
            let mut slop = [0.0; 4];
            let mut used = [0.0; 4];
            for l in 0..4 {
                if t.index[l] == UNUSED {
                    continue;
                }
                used[l] = 1.0;
                let c = &inp.points[t.index[l] as usize];
                for k in 0..3 {
                    p[k][l] = c.point[k];
                    pimp[k][l] = c.impulse[k];
                }
                depth[l] = c.depth;
                slop[l] = (inp.slop)(c);
            }
            let used = V::new(used).simd_gt(zero);
            let p = v3(p);
            let (ra, rb) = (sub(p, xa), sub(p, xb));
            // The normal is zero in unused lanes, as the lever then is.
            let normal: V3 = std::array::from_fn(|k| used.bitselect(n[k], zero));
            let arm = [cross(ra, normal), cross(rb, normal)];
            let turn = [mat_vec(ia, arm[0]), mat_vec(ib, arm[1])];
            let k = ua.inv_mass + ub.inv_mass + dot(arm[0], turn[0]) + dot(arm[1], turn[1]);
            // An idle lane of a group may sit on its manifold's bodies: no mass there.
            t.mass = F::put((k.simd_gt(zero) & used).bitselect(one / k, zero));
            let off = sub(p, centre);
            let across = sub(off, scale(normal, dot(off, normal)));
            t.lever = F::put(used.bitselect(dot(across, across).sqrt(), zero));
            t.normal = put3(normal);
            t.ra = put3(ra);
            t.rb = put3(rb);
            t.turn = [put3(turn[0]), put3(turn[1])];
            t.depth = F::put(V::new(depth));
            t.error = t.depth.get();
            t.slop = F::put(V::new(slop));
            t.approach = F::put(-t.velocity(&ua, &ub));
            t.lambda = if inp.accumulate {
                let pimp = v3(pimp);
                twist += used.bitselect(dot(cross(off, pimp), normal), zero);
                (dot(pimp, normal) * per).max(zero)
            } else {
                zero
            };
            load += t.lambda;
            moment += t.lambda * t.lever.get();
        }
        // `v3::tangent_frame` lane by lane: t1 from the world axis least aligned with n.
        let near_x = n[0].abs().simd_lt(splat(0.57));
        let axis = [
            near_x.bitselect(one, zero),
            near_x.bitselect(zero, one),
            zero,
        ];
        let c = cross(n, axis);
        let len = dot(c, c).sqrt();
        let ok = len.simd_gt(zero) & len.simd_lt(splat(f64::INFINITY));
        let t1 = [
            ok.bitselect(c[0] / len, zero),
            ok.bitselect(c[1] / len, zero),
            ok.bitselect(c[2] / len, one),
        ];
        let t2 = cross(n, t1);
        let used = V::new(count).simd_gt(zero);
        let (ra, rb) = (sub(centre, xa), sub(centre, xb));
        let dir = [t1, t2, n];
        // The tangents' rows at the centre, then the twist's (angular only).
        let mut turn = [[[zero; 3]; 2]; 3];
        let mut k = [zero; 3];
        for r in 0..2 {
            let arm = [cross(ra, dir[r]), cross(rb, dir[r])];
            turn[r] = [mat_vec(ia, arm[0]), mat_vec(ib, arm[1])];
            k[r] = ua.inv_mass + ub.inv_mass + dot(arm[0], turn[r][0]) + dot(arm[1], turn[r][1]);
        }
        turn[2] = [mat_vec(ia, n), mat_vec(ib, n)];
        k[2] = dot(n, turn[2][0]) + dot(n, turn[2][1]);
        let lambda = if inp.accumulate {
            // Warm start: the points' tangent impulses and twist, inside the caps.
            let imp = scale(v3(imp), per);
            let (l1, l2) = on_cone(dot(imp, t1), dot(imp, t2), friction * load);
            let cap = friction * moment;
            let l3 = (twist * per).max(-cap).min(cap);
            [
                used.bitselect(l1, zero),
                used.bitselect(l2, zero),
                used.bitselect(l3, zero),
            ]
        } else {
            [zero; 3]
        };
        let f = Friction {
            dir: [put3(dir[0]), put3(dir[1]), put3(dir[2])],
            ra: put3(ra),
            rb: put3(rb),
            turn: std::array::from_fn(|r| [put3(turn[r][0]), put3(turn[r][1])]),
            mass: put3(std::array::from_fn(|r| {
                (k[r].simd_gt(zero) & used).bitselect(one / k[r], zero)
            })),
            lambda,
            load,
            moment,
            total: [zero; 3],
        };
        rows.push(f);
    }
}

#[inline(always)]
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Each point's impulse over the step into its contact: its normal impulse, an equal
/// share of its manifold's tangent impulse, and forces across the normal that give the
/// manifold's twist about its centre, `twist (n x d) / sum |d|²` at distance `d` from it
/// (they sum to no force, and the points' impulses add up to the manifold's force and
/// torque about the normal, from which [`fill`] warm-starts).
pub(crate) fn impulses(batches: &Batches, points: &mut [ContactPoint]) {
    for (&(start, end), f) in batches.groups.iter().zip(&batches.friction) {
        let group = &batches.batches[start as usize..end as usize];
        let dir = f.dir.map(|d| d.map(|x| x.get().to_array()));
        let total = f.total.map(|x| x.to_array());
        // Per lane: the points (index, normal impulse) and their centre.
        let mut lanes = [[(0usize, 0.0); MANIFOLD]; 4];
        let mut count = [0usize; 4];
        let mut centre = [[0.0; 3]; 4];
        for t in group {
            let normal = t.total.to_array();
            for l in 0..4 {
                if t.index[l] != UNUSED && count[l] < MANIFOLD {
                    let i = t.index[l] as usize;
                    lanes[l][count[l]] = (i, normal[l]);
                    count[l] += 1;
                    centre[l] = v3::add(centre[l], points[i].point);
                }
            }
        }
        for l in 0..4 {
            if count[l] == 0 {
                continue;
            }
            let k = count[l] as f64;
            let n = [dir[2][0][l], dir[2][1][l], dir[2][2][l]];
            let tangent: [f64; 3] = std::array::from_fn(|c| {
                (total[0][l] * dir[0][c][l] + total[1][l] * dir[1][c][l]) / k
            });
            let centre = centre[l].map(|c| c / k);
            // Each point's offset from the centre across the normal.
            let mut across = [[0.0; 3]; MANIFOLD];
            let mut spread = 0.0;
            for (a, &(i, _)) in across.iter_mut().zip(&lanes[l][..count[l]]) {
                let off = v3::sub(points[i].point, centre);
                *a = v3::sub(off, v3::scale(n, v3::dot(off, n)));
                spread += v3::dot(*a, *a);
            }
            for (d, &(i, normal)) in across.iter().zip(&lanes[l][..count[l]]) {
                let twist = if spread > 0.0 {
                    v3::scale(v3::cross(n, *d), total[2][l] / spread)
                } else {
                    [0.0; 3]
                };
                points[i].impulse = v3::add(v3::add(v3::scale(n, normal), tangent), twist);
            }
        }
    }
}

/// Writes the batches' present penetrations back to their rows.
pub(crate) fn unpack_errors(batches: &Batches, rows: &mut [ContactRow]) {
    for t in &batches.batches {
        for l in 0..4 {
            if t.index[l] != UNUSED {
                rows[t.index[l] as usize].error = t.error.to_array()[l];
            }
        }
    }
}

/// Restitution after the sub-steps: points that pushed and were approaching faster than
/// the bounce threshold leave at `restitution` times their approach speed.
pub(crate) fn restitute(batches: &mut Batches, bodies: &mut [SolverBody], p: &Lanes) {
    let (zero, threshold, e) = (V::ZERO, V::splat(p.bounce), V::splat(p.restitution));
    let on = |t: &Batch| !t.approach.get().simd_lt(threshold) & t.max_normal.simd_ne(zero);
    each_group(
        batches,
        bodies,
        |t| !on(t).any(),
        |t, ua, ub| {
            let vn = t.velocity(ua, ub);
            let dl = t.mass.get() * (e * t.approach.get() - vn);
            let new = on(t).bitselect((t.lambda + dl).max(zero), t.lambda);
            let delta = new - t.lambda;
            t.push(ua, ub, delta);
            t.total += delta;
            t.lambda = new;
        },
    );
}

/// Warm start: each point's and each manifold's impulses so far applied again (one-shot
/// impulses start from zero instead).
pub(crate) fn warm_start(batches: &mut Batches, bodies: &mut [SolverBody], accumulate: bool) {
    let Batches {
        batches,
        groups,
        friction,
    } = batches;
    if !accumulate {
        for t in batches.iter_mut() {
            t.lambda = V::ZERO;
        }
        for f in friction.iter_mut() {
            f.lambda = [V::ZERO; 3];
            f.load = V::ZERO;
            f.moment = V::ZERO;
        }
        return;
    }
    for (&(start, end), f) in groups.iter().zip(friction.iter()) {
        let group = &batches[start as usize..end as usize];
        if f.idle() {
            // No load: no point holds a normal impulse either.
            continue;
        }
        let (a, b) = (group[0].a, group[0].b);
        let (mut ua, mut ub) = (gather(bodies, a), gather(bodies, b));
        f.push(&mut ua, &mut ub, f.lambda);
        for t in group {
            t.push(&mut ua, &mut ub, t.lambda);
        }
        scatter(bodies, a, &ua);
        scatter(bodies, b, &ub);
    }
}

/// The bodies' motion since the step's start, in the lanes of `idx`: displacement
/// and `R R0ᵀ - I`.
#[inline(always)]
fn gather_motion(motion: &[SolverMotion], idx: [u32; 4]) -> (V3, [V3; 3]) {
    let (m0, m1, m2, m3) = (
        &motion[idx[0] as usize].0,
        &motion[idx[1] as usize].0,
        &motion[idx[2] as usize].0,
        &motion[idx[3] as usize].0,
    );
    let part = |k: usize| {
        let row = |m: &[f64; 12]| V::new([m[k], m[k + 1], m[k + 2], m[k + 3]]);
        V::transpose([row(m0), row(m1), row(m2), row(m3)])
    };
    let (p, q, s) = (part(0), part(4), part(8));
    (
        [p[0], p[1], p[2]],
        [[p[3], q[0], q[1]], [q[2], q[3], s[0]], [s[1], s[2], s[3]]],
    )
}

/// Present penetrations from the bodies' motion since the step's start (penalty
/// springs; the other solvers update them in their solve pass).
pub(crate) fn update_errors(batches: &mut Batches, motion: &[SolverMotion]) {
    for t in batches.batches.iter_mut() {
        t.update_error(&gather_motion(motion, t.a), &gather_motion(motion, t.b));
    }
}

/// Resets the split impulses before a pseudo pass.
pub(crate) fn clear_split(batches: &mut Batches) {
    for t in batches.batches.iter_mut() {
        t.plambda = V::ZERO;
    }
}

/// One pass over the batches (see `solver::Pass`); `pseudo` holds the split impulses'
/// pseudo-velocities, used by [`Pass::Pseudo`] instead of `bodies`. With `motion`, each
/// batch's penetrations are brought up to date first; with `last` (the sub-step's last
/// pass over the velocities), its impulses are added to the step's totals after. A
/// group's friction goes first, capped by the normal impulses of the pass before (as
/// Box2D and rapier: the normal rows, solved last, are the ones kept best).
#[allow(clippy::too_many_arguments)]
pub(crate) fn solve(
    batches: &mut Batches,
    bodies: &mut [SolverBody],
    pseudo: &mut [SolverBody],
    motion: Option<&[SolverMotion]>,
    pass: Pass,
    last: bool,
    p: &Lanes,
) {
    if pass == Pass::Pseudo {
        let (h, zero, beta) = (splat(p.h), V::ZERO, splat(p.beta));
        let target = |t: &Batch| beta * (t.error - t.slop.get()).max(zero) / h;
        each_group(
            batches,
            pseudo,
            |t| !target(t).simd_ne(zero).any(),
            |t, ua, ub| {
                let target = target(t);
                let on = target.simd_ne(zero);
                let dl = t.mass.get() * (target - t.velocity(ua, ub));
                let new = on.bitselect((t.plambda + dl).max(zero), t.plambda);
                t.push(ua, ub, new - t.plambda);
                t.plambda = new;
            },
        );
        return;
    }
    let friction = splat(p.friction);
    let Batches {
        batches,
        groups,
        friction: rows,
    } = batches;
    for (&(start, end), f) in groups.iter().zip(rows.iter_mut()) {
        let group = &mut batches[start as usize..end as usize];
        let (a, b) = (group[0].a, group[0].b);
        let moved = motion.map(|m| (gather_motion(m, a), gather_motion(m, b)));
        let (mut ua, mut ub) = (gather(bodies, a), gather(bodies, b));
        let mut touched = f.solve(&mut ua, &mut ub, friction);
        let (mut load, mut moment) = (V::ZERO, V::ZERO);
        for t in group.iter_mut() {
            if let Some((ma, mb)) = &moved {
                t.update_error(ma, mb);
            }
            touched |= solve_point(t, &mut ua, &mut ub, pass, last, p);
            load += t.lambda;
            moment += t.lambda * t.lever.get();
        }
        f.load = load;
        f.moment = moment;
        if last {
            f.total = add(f.total, f.lambda);
        }
        if touched {
            scatter(bodies, a, &ua);
            scatter(bodies, b, &ub);
        }
    }
}

/// The normal row of one point of each lane in the velocity passes (`Pass::Solve`,
/// `Pass::Relax`), on the lanes' bodies `ua`, `ub`; false if all four were idle and
/// nothing changed.
#[inline(always)]
fn solve_point(
    t: &mut Batch,
    ua: &mut Vel,
    ub: &mut Vel,
    pass: Pass,
    last: bool,
    p: &Lanes,
) -> bool {
    let (h, zero, one) = (splat(p.h), V::ZERO, splat(1.0));
    let beta = splat(p.beta);
    let (restitution, bounce) = (splat(p.restitution), splat(p.bounce));
    let soft = |s: [f64; 3]| s.map(splat);
    let (cs, ss) = (soft(p.contact_soft), soft(p.static_soft));
    let max_push = splat(MAX_PUSH);
    let e = t.error;
    let apart = e.simd_lt(zero);
    // Idle speculative points (see `solver::solve_pass`): a batch of them is skipped;
    // in a busy batch they change nothing.
    let held = t.lambda.simd_ne(zero);
    let vn = t.velocity(ua, ub);
    let mut idle = apart & !held & vn.simd_ge(e / h);
    if !p.accumulate {
        idle &= (-vn).simd_le(bounce);
    }
    if idle.all() {
        // Idle points hold no impulse: there is nothing to add to the totals.
        return false;
    }
    // The target and softness of `solver::solve_pass`, lane by lane.
    let (mut target, mut scale_m, mut scale_i) = match (pass, p.correction) {
        (Pass::Solve, Correction::Soft) => {
            let fixed = ua.inv_mass.simd_eq(zero) | ub.inv_mass.simd_eq(zero);
            let s: [V; 3] = std::array::from_fn(|k| fixed.bitselect(ss[k], cs[k]));
            ((s[0] * e).min(max_push), s[1], s[2])
        }
        (Pass::Solve, Correction::Baumgarte) => {
            (beta * (e - t.slop.get()).max(zero) / h, one, zero)
        }
        _ => (zero, one, zero),
    };
    target = apart.bitselect(e / h, target);
    scale_m = apart.bitselect(one, scale_m);
    scale_i = apart.bitselect(zero, scale_i);
    if !p.accumulate {
        let bouncing = (-vn).simd_gt(bounce);
        target = bouncing.bitselect(target.max(restitution * -vn), target);
        scale_m = bouncing.bitselect(one, scale_m);
        scale_i = bouncing.bitselect(zero, scale_i);
    }
    let dl = t.mass.get() * scale_m * (target - vn) - scale_i * t.lambda;
    let old = t.lambda;
    let new = if p.accumulate {
        (old + dl).max(zero)
    } else {
        old + dl.max(zero)
    };
    t.lambda = new;
    t.push(ua, ub, new - old);
    if last {
        t.accumulate();
    }
    true
}

#[cfg(test)]
mod tests {
    use crate::rigid::{BodyDesc, Correction, Motion, RigidDesc, RigidSolver, Shape};

    /// A small pile: 18 boxes dropped in two turned layers on a slab.
    fn pile(solver: RigidSolver, correction: Correction) -> RigidDesc {
        let mut d = RigidDesc {
            solver,
            correction,
            restitution: 0.3,
            ..RigidDesc::default()
        };
        d.bodies.push(BodyDesc {
            motion: Motion::Static,
            ..BodyDesc::new(
                Shape::Box {
                    half: [5.0, 0.5, 5.0],
                },
                [0.0, -0.5, 0.0],
            )
        });
        for k in 0..18 {
            let (i, j, l) = ((k % 3) as f64, ((k / 3) % 3) as f64, (k / 9) as f64);
            let t = 0.3 * k as f64;
            let (c, sn) = ((0.5 * t).cos(), (0.5 * t).sin());
            let norm = (c * c + 1.01 * sn * sn).sqrt();
            d.bodies.push(BodyDesc {
                orientation: [c / norm, 0.1 * sn / norm, sn / norm, 0.0],
                ..BodyDesc::new(
                    Shape::Box {
                        half: [0.5, 0.3, 0.4],
                    },
                    [1.1 * i - 1.1, 0.6 + 0.7 * l, 1.1 * j - 1.1],
                )
            });
        }
        d
    }

    #[test]
    fn batches_of_four_give_the_sequential_answer_to_the_bit() {
        for (solver, correction) in [
            (RigidSolver::SequentialImpulses, Correction::Soft),
            (RigidSolver::SequentialImpulses, Correction::Split),
            (RigidSolver::SequentialImpulses, Correction::Baumgarte),
            (RigidSolver::Impulse, Correction::Soft),
        ] {
            let d = pile(solver, correction);
            let run = |width: u8| {
                let (m, mut s, mut w) = d.build().unwrap();
                w.solver.batcher_width(width);
                let mut points = 0;
                for _ in 0..90 {
                    points += m.step(&mut s, &mut w, 1.0 / 60.0).unwrap().contacts;
                }
                (s, w.solver.batch_count(), points)
            };
            let (one, batches_one, points) = run(1);
            let (four, batches_four, _) = run(4);
            assert!(points > 1000, "{points}");
            assert!(
                batches_four * 2 < batches_one,
                "{batches_four} {batches_one}"
            );
            assert_eq!(one.x, four.x, "{solver:?} {correction:?}");
            assert_eq!(one.q, four.q);
            assert_eq!(one.v, four.v);
            assert_eq!(one.w, four.w);
        }
    }
}
