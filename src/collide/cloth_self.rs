//! Self-collision of a triangle surface (cloth): proximity repulsion, continuous collision
//! impulses and rigid impact zones, after Bridson, Fedkiw and Anderson 2002 ("Robust
//! treatment of collisions, contact and friction for cloth animation", sections 6-7).
//!
//! Before the implicit step, [`SelfCollision::begin`] finds the vertices closing on a
//! triangle of the surface within the thickness, and [`SelfCollision::constraints`]
//! gives the solve's filter a one-sided constraint for each that stops the vertex's own
//! approach (Baraff and Witkin 1998's filter, section 5.1, one vertex at a time).
//!
//! The implicit step proposes end positions `x1`; the response works on the step's
//! average velocity `u = (x1 - x0) / h` and moves the end to `x0 + h u`:
//!
//! 1. **Repulsion** (section 7.1): every vertex-triangle and edge-edge pair closer than
//!    the thickness at the start `x0` gets an inelastic impulse that stops its approach,
//!    plus a push opening the gap: the lesser of a tenth of the gap per step and a
//!    spring's impulse over the step (Bridson's `min(h k d, m (0.1 d / h - v_n))`),
//!    distributed by the barycentric weights over inverse masses.
//! 2. **Collisions** (section 7.2): the pairs whose features meet during `x0 -> x0 + h u`
//!    (`kernels::collide::ccd`, within `eta` of the thickness scale) get inelastic
//!    impulses at the time and normal of contact; a few passes.
//! 3. **Impact zones** (section 7.3, after Provot 1997): while collisions remain, the
//!    vertices of colliding pairs are merged into zones (union-find) and each zone's
//!    velocities replaced by its rigid motion (mass-weighted linear and angular momentum);
//!    a zone with a fixed vertex moves with that vertex. Rigid zones cannot collide
//!    within themselves, so this ends with no crossing.
//!
//! The velocity `v1` the step ended with gets the same change as `u`. Broad phase: a BVH
//! (`kernels::collide::bvh`) over the triangles' swept boxes, inflated by the thickness;
//! its pairs give the feature pairs, each once (sorted and deduplicated). Pairs of
//! features sharing a vertex are never tested.

use crate::kernels::collide::bv::Aabb;
use crate::kernels::collide::bvh::{Bvh, PairWork};
use crate::kernels::collide::ccd::{
    edge_edge, edge_edge_ccd, vertex_triangle, vertex_triangle_ccd, Proximity,
};
use crate::kernels::get3;
use crate::kernels::v3::{cross, dot, length_and_unit, sub};

/// Natural frequency (rad/s) of the repulsion spring per unit mass: `omega^2` times the
/// overlap is its acceleration. 100 rad/s opens a 4 mm gap in about 10 ms.
const REPULSION_OMEGA: f64 = 100.0;
/// The pull a self contact's one-sided constraint tolerates before the solve frees it,
/// in thicknesses per step. Each freeing costs the step a second solve; at one thickness
/// (the obstacles' slack) `scenes/cloth-fold.toml` freed 743 over its run against 265
/// without self contacts in the filter, at 16 it frees 242, and the sheet is held
/// back from separating by at most that much for one step (the repulsion after the
/// step opens the gap anyway).
const SELF_SLACK: f64 = 16.0;
/// Collision passes before impact zones take over.
const COLLISION_PASSES: usize = 4;
/// Impact-zone rounds before giving up (each merges at least two zones).
const ZONE_ROUNDS: usize = 64;

/// What one [`SelfCollision::resolve`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SelfStats {
    /// Vertices found closing on a triangle of their own surface at the step's start
    /// (offered to the implicit solve's filter, which holds those still free).
    pub approaches: usize,
    /// Repulsion impulses applied.
    pub repulsions: usize,
    /// Collision impulses applied.
    pub impulses: usize,
    /// Impact-zone rounds run (0 when impulses sufficed).
    pub zone_rounds: usize,
    /// Collisions left after the last round (0 unless the rounds ran out).
    pub unresolved: usize,
}

/// A feature pair: a vertex and a triangle, or two edges.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Pair {
    Vf(u32, u32),
    Ee(u32, u32),
}

/// Self-collision of one surface: its edges and the scratch of the response, reused
/// between steps (see the module docs).
#[derive(Clone, Debug)]
pub struct SelfCollision {
    triangles: std::sync::Arc<[[u32; 3]]>,
    edges: Vec<[u32; 2]>,
    tri_edges: Vec<[u32; 3]>,
    /// The first triangle holding each vertex and each edge: a feature pair is taken
    /// from its features' owners' triangle pair only, so each is found once.
    vertex_owner: Vec<u32>,
    edge_owner: Vec<u32>,
    /// Thickness (m): the gap repulsion keeps between the surface's sheets.
    pub thickness: f64,
    x0: Vec<f64>,
    u: Vec<f64>,
    bvh: Bvh,
    boxes: Vec<Aabb>,
    work: PairWork,
    tri_pairs: Vec<[u32; 2]>,
    pairs: Vec<Pair>,
    /// The vertices of each pair the last continuous pass found colliding.
    hits: Vec<[u32; 4]>,
    parent: Vec<u32>,
    /// The step's start-of-step contacts for the implicit solve's filter.
    approaches: Vec<SelfApproach>,
    /// The slack of their one-sided constraints (m/s): the thickness over the step.
    slack: f64,
}

/// A vertex closing on a triangle of its own surface within the thickness at the start
/// of a step: the implicit solve holds the vertex's velocity along `normal` (from the
/// triangle towards the vertex) at the triangle's own there, unless that pulls
/// ([`crate::solve::Filter::approach`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SelfApproach {
    /// The vertex.
    pub vertex: u32,
    /// Unit normal from the triangle towards the vertex.
    pub normal: [f64; 3],
    /// The triangle's vertices.
    pub triangle: [u32; 3],
    /// The barycentric weights of the vertex's closest point on the triangle.
    pub weights: [f64; 3],
    /// The vertex's distance from the triangle (m).
    pub distance: f64,
}

impl SelfCollision {
    /// The self-collision of the surface `triangles` (vertex indices valid for the model)
    /// with thickness `thickness` (m, > 0).
    pub fn new(triangles: std::sync::Arc<[[u32; 3]]>, thickness: f64) -> SelfCollision {
        let mut all: Vec<([u32; 2], usize, usize)> = Vec::with_capacity(3 * triangles.len());
        for (t, tri) in triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                all.push(([a.min(b), a.max(b)], t, k));
            }
        }
        all.sort_unstable();
        let mut edges: Vec<[u32; 2]> = Vec::new();
        let mut tri_edges = vec![[0u32; 3]; triangles.len()];
        for (e, t, k) in all {
            if edges.last() != Some(&e) {
                edges.push(e);
            }
            tri_edges[t][k] = (edges.len() - 1) as u32;
        }
        let nv = triangles
            .iter()
            .flatten()
            .map(|&v| v as usize + 1)
            .max()
            .unwrap_or(0);
        let mut vertex_owner = vec![u32::MAX; nv];
        let mut edge_owner = vec![u32::MAX; edges.len()];
        for (t, tri) in triangles.iter().enumerate() {
            for k in 0..3 {
                let v = &mut vertex_owner[tri[k] as usize];
                *v = (*v).min(t as u32);
                let e = &mut edge_owner[tri_edges[t][k] as usize];
                *e = (*e).min(t as u32);
            }
        }
        SelfCollision {
            triangles,
            edges,
            tri_edges,
            vertex_owner,
            edge_owner,
            thickness,
            x0: Vec::new(),
            u: Vec::new(),
            bvh: Bvh::new(),
            boxes: Vec::new(),
            work: PairWork::default(),
            tri_pairs: Vec::new(),
            pairs: Vec::new(),
            hits: Vec::new(),
            parent: Vec::new(),
            approaches: Vec::new(),
            slack: 0.0,
        }
    }

    /// Starts a step of size `h` (s) from positions `x` and velocities `v`: remembers the
    /// positions, finds the feature pairs within the thickness (which the repulsion of
    /// [`SelfCollision::resolve`] reuses) and, from them, the vertices closing on a
    /// triangle, which [`SelfCollision::constraints`] gives the step's filter (the
    /// nearest triangle per vertex; vertices of zero `inv_mass` are left out).
    pub fn begin(&mut self, x: &[f64], v: &[f64], inv_mass: &[f64], h: f64) {
        let n = inv_mass.len();
        self.x0.clear();
        self.x0.extend_from_slice(x);
        self.approaches.clear();
        self.pairs.clear();
        if x.len() != 3 * n || v.len() != 3 * n || h.is_nan() || h <= 0.0 {
            return;
        }
        self.slack = SELF_SLACK * self.thickness / h;
        // The start-of-step pairs need no motion: u is the velocity, read at s = 0.
        self.u.clear();
        self.u.extend_from_slice(v);
        self.find_pairs(n, h, true);
        for k in 0..self.pairs.len() {
            let pair = self.pairs[k];
            let Pair::Vf(vertex, _) = pair else { continue };
            if inv_mass[vertex as usize] == 0.0 {
                continue;
            }
            let (idx, w, pr) = self.start_proximity(n, pair);
            if pr.distance >= self.thickness
                || self.relative_normal_velocity(n, &idx, &w, pr.normal) >= 0.0
            {
                continue;
            }
            self.approaches.push(SelfApproach {
                vertex,
                normal: pr.normal,
                triangle: [idx[1], idx[2], idx[3]],
                weights: [-w[1], -w[2], -w[3]],
                distance: pr.distance,
            });
        }
        // One per vertex: the nearest triangle.
        self.approaches.sort_unstable_by(|a, b| {
            a.vertex
                .cmp(&b.vertex)
                .then(a.distance.total_cmp(&b.distance))
        });
        self.approaches.dedup_by_key(|a| a.vertex);
    }

    /// The step's approaches (see [`SelfCollision::begin`]).
    pub fn approaches(&self) -> &[SelfApproach] {
        &self.approaches
    }

    /// Writes the step's approaches into the implicit solve's filter as one-sided
    /// constraints, on the vertices nothing else constrains (pins and obstacle contacts
    /// keep theirs). Each stops the vertex's own approach: its velocity along the normal
    /// becomes the triangle point's there (the triangle's vertices as the filter already
    /// holds them: a triangle resting on the floor is still), but never more than the
    /// vertex's own or 0, so the solve never pushes a vertex along the normal (a falling
    /// sheet does not drive the sheet under it into the floor within the step). The
    /// filter holds one vertex at a time, so the triangle does not feel the vertex within
    /// the solve: the impulses of [`SelfCollision::resolve`] settle what is left.
    pub fn constraints(&self, filter: &mut crate::solve::Filter) {
        let n = filter.n();
        if self.u.len() != 3 * n {
            return;
        }
        for a in &self.approaches {
            let i = a.vertex as usize;
            if i >= n || !filter.is_free(i) {
                continue;
            }
            let v_tri: f64 = a
                .triangle
                .iter()
                .zip(a.weights)
                .map(|(&k, w)| {
                    w * dot(
                        filter.imposed(k as usize, get3(&self.u, n, k as usize)),
                        a.normal,
                    )
                })
                .sum();
            let v_vertex = dot(get3(&self.u, n, i), a.normal);
            let speed = v_tri.min(v_vertex.max(0.0));
            if speed > v_vertex {
                filter.approach(i, a.normal, speed, self.slack);
            }
        }
    }

    /// Resolves the step from the positions given to [`SelfCollision::begin`] to `x1`
    /// (velocity `v1`), of size `h` (s): see the module docs. `inv_mass` per vertex
    /// (1/kg, 0 for fixed vertices).
    pub fn resolve(
        &mut self,
        x1: &mut [f64],
        v1: &mut [f64],
        inv_mass: &[f64],
        h: f64,
    ) -> SelfStats {
        let n = inv_mass.len();
        let mut stats = SelfStats::default();
        if self.x0.len() != 3 * n || h.is_nan() || h <= 0.0 {
            return stats;
        }
        self.u.clear();
        self.u
            .extend(x1.iter().zip(&self.x0).map(|(a, b)| (a - b) / h));
        let eta = 1e-6 * self.thickness.max(1e-9);
        // 1. Repulsion at the start, over the pairs `begin` found.
        for k in 0..self.pairs.len() {
            let pair = self.pairs[k];
            let (idx, w, pr) = self.start_proximity(n, pair);
            if pr.distance >= self.thickness {
                continue;
            }
            let vrel = self.relative_normal_velocity(n, &idx, &w, pr.normal);
            // Stop the approach, and open the gap towards the thickness: Bridson's
            // repulsion, the lesser of a tenth of the gap per step and a spring's push
            // over the step (natural frequency REPULSION_OMEGA), so that short steps do
            // not turn the push into a velocity that outlives them.
            let gap = self.thickness - pr.distance;
            let target = gap * (0.1 / h).min(REPULSION_OMEGA * REPULSION_OMEGA * h);
            if vrel < target {
                self.apply(n, &idx, &w, pr.normal, target - vrel, inv_mass);
                stats.repulsions += 1;
            }
        }
        // 2. Collision impulses, until a pass finds nothing.
        let mut clean = false;
        for _ in 0..COLLISION_PASSES {
            let hits = self.collide_pass(n, h, eta, inv_mass, true);
            stats.impulses += hits;
            if hits == 0 {
                clean = true;
                break;
            }
        }
        // 3. Impact zones.
        let mut left = if clean {
            0
        } else {
            self.collide_pass(n, h, eta, inv_mass, false)
        };
        // Zones grow over the rounds: one union-find for the whole resolve.
        self.parent.clear();
        self.parent.extend(0..n as u32);
        while left > 0 && stats.zone_rounds < ZONE_ROUNDS {
            stats.zone_rounds += 1;
            self.rigid_zones(n, h, inv_mass);
            left = self.collide_pass(n, h, eta, inv_mass, false);
        }
        stats.unresolved = left;
        for i in 0..3 * n {
            let new_x = self.x0[i] + h * self.u[i];
            v1[i] += (new_x - x1[i]) / h;
            x1[i] = new_x;
        }
        stats
    }

    /// Feature pairs whose triangles' boxes (at the start, or swept over the step when
    /// `!start_only`) overlap, inflated by the thickness.
    fn find_pairs(&mut self, n: usize, h: f64, start_only: bool) {
        let (x0, u) = (&self.x0, &self.u);
        let at = |i: u32, a: usize, s: f64| x0[a * n + i as usize] + s * h * u[a * n + i as usize];
        self.boxes.clear();
        for tri in self.triangles.iter() {
            let mut b = Aabb::EMPTY;
            for &v in tri {
                b = b.union(&Aabb::point([at(v, 0, 0.0), at(v, 1, 0.0), at(v, 2, 0.0)]));
                if !start_only {
                    b = b.union(&Aabb::point([at(v, 0, 1.0), at(v, 1, 1.0), at(v, 2, 1.0)]));
                }
            }
            self.boxes.push(b.inflated(self.thickness));
        }
        self.bvh.build(&self.boxes);
        self.bvh.self_pairs(&mut self.work, &mut self.tri_pairs);
        self.pairs.clear();
        // The cheap box test each candidate must pass: static within the thickness for
        // the repulsion, swept within eta for the continuous tests.
        let (reach, pad) = if start_only {
            (0.0, self.thickness)
        } else {
            (1.0, 1e-6 * self.thickness)
        };
        for k in 0..self.tri_pairs.len() {
            let [s, t] = self.tri_pairs[k];
            let (ts, tt) = (self.triangles[s as usize], self.triangles[t as usize]);
            for (a, own, b, tb) in [(ts, s, t, tt), (tt, t, s, ts)] {
                for v in a {
                    let pair = Pair::Vf(v, b);
                    if self.vertex_owner[v as usize] == own
                        && !tb.contains(&v)
                        && self.boxes_meet(n, pair, h, reach, pad)
                    {
                        self.pairs.push(pair);
                    }
                }
            }
            for &ea in &self.tri_edges[s as usize] {
                if self.edge_owner[ea as usize] != s {
                    continue;
                }
                for &eb in &self.tri_edges[t as usize] {
                    let (p, q) = (self.edges[ea as usize], self.edges[eb as usize]);
                    let pair = Pair::Ee(ea, eb);
                    if self.edge_owner[eb as usize] == t
                        && p[0] != q[0]
                        && p[0] != q[1]
                        && p[1] != q[0]
                        && p[1] != q[1]
                        && self.boxes_meet(n, pair, h, reach, pad)
                    {
                        self.pairs.push(pair);
                    }
                }
            }
        }
    }

    /// The pair's four vertices, the weights of the relative motion (positive on the side
    /// the normal points to), and its proximity at the start of the step.
    fn start_proximity(&self, n: usize, pair: Pair) -> ([u32; 4], [f64; 4], Proximity) {
        let p = |i: u32| [0, 1, 2].map(|a| self.x0[a * n + i as usize]);
        let pr = match pair {
            Pair::Vf(v, t) => {
                let [a, b, c] = self.triangles[t as usize];
                vertex_triangle(p(v), p(a), p(b), p(c))
            }
            Pair::Ee(e, f) => {
                let ([a, b], [c, d]) = (self.edges[e as usize], self.edges[f as usize]);
                edge_edge(p(a), p(b), p(c), p(d))
            }
        };
        let (idx, w) = self.weights(pair, &pr);
        (idx, w, pr)
    }

    /// The pair's four vertices and the weights of its relative motion from a proximity's
    /// weights: vertex minus triangle point, second edge point minus first.
    fn weights(&self, pair: Pair, pr: &Proximity) -> ([u32; 4], [f64; 4]) {
        let w = pr.weights;
        match pair {
            Pair::Vf(v, t) => {
                let [a, b, c] = self.triangles[t as usize];
                ([v, a, b, c], [1.0, -w[0], -w[1], -w[2]])
            }
            Pair::Ee(e, f) => {
                let ([a, b], [c, d]) = (self.edges[e as usize], self.edges[f as usize]);
                ([c, d, a, b], [1.0 - w[1], w[1], -(1.0 - w[0]), -w[0]])
            }
        }
    }

    /// Whether the pair's two features' boxes, over positions `x0 + s h u` for s in
    /// `[0, reach]` and grown by `pad` (m), overlap: the cheap test before the exact one.
    fn boxes_meet(&self, n: usize, pair: Pair, h: f64, reach: f64, pad: f64) -> bool {
        let b = |ids: &[u32]| {
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            for &i in ids {
                for a in 0..3 {
                    let x0 = self.x0[a * n + i as usize];
                    let x1 = x0 + reach * h * self.u[a * n + i as usize];
                    lo[a] = lo[a].min(x0.min(x1));
                    hi[a] = hi[a].max(x0.max(x1));
                }
            }
            Aabb { min: lo, max: hi }
        };
        let (first, second) = match pair {
            Pair::Vf(v, t) => (b(&[v]), b(&self.triangles[t as usize])),
            Pair::Ee(e, f) => (b(&self.edges[e as usize]), b(&self.edges[f as usize])),
        };
        first.inflated(pad).overlaps(&second)
    }

    fn relative_normal_velocity(
        &self,
        n: usize,
        idx: &[u32; 4],
        w: &[f64; 4],
        nrm: [f64; 3],
    ) -> f64 {
        weighted_dot(&self.u, n, idx, w, nrm)
    }

    /// Changes the relative normal velocity by `dv` (m/s) with an impulse distributed by
    /// the weights over the inverse masses.
    fn apply(
        &mut self,
        n: usize,
        idx: &[u32; 4],
        w: &[f64; 4],
        nrm: [f64; 3],
        dv: f64,
        inv_mass: &[f64],
    ) {
        let denom: f64 = idx
            .iter()
            .zip(w)
            .map(|(&i, &wk)| wk * wk * inv_mass[i as usize])
            .sum();
        if denom.is_nan() || denom <= 0.0 {
            return;
        }
        let impulse = dv / denom;
        for (k, &i) in idx.iter().enumerate() {
            let s = impulse * w[k] * inv_mass[i as usize];
            for (a, &na) in nrm.iter().enumerate() {
                self.u[a * n + i as usize] += s * na;
            }
        }
    }

    /// One pass of continuous tests over the swept pairs: with `respond`, an inelastic
    /// impulse at each hit; returns the hits, whose vertices it keeps in `hits`.
    fn collide_pass(
        &mut self,
        n: usize,
        h: f64,
        eta: f64,
        inv_mass: &[f64],
        respond: bool,
    ) -> usize {
        self.find_pairs(n, h, false);
        self.hits.clear();
        for k in 0..self.pairs.len() {
            let pair = self.pairs[k];
            let Some((idx, w, nrm)) = self.ccd(n, pair, h, eta) else {
                continue;
            };
            self.hits.push(idx);
            if respond {
                let vrel = self.relative_normal_velocity(n, &idx, &w, nrm);
                if vrel < 0.0 {
                    // Inelastic, plus a hair of separation so rounding cannot leave the
                    // features exactly in contact.
                    self.apply(n, &idx, &w, nrm, -vrel + eta / h, inv_mass);
                }
            }
        }
        self.hits.len()
    }

    /// The pair's first contact over the step, with the normal oriented along the
    /// relative approach at the start.
    fn ccd(
        &self,
        n: usize,
        pair: Pair,
        h: f64,
        eta: f64,
    ) -> Option<([u32; 4], [f64; 4], [f64; 3])> {
        let path = |i: u32| {
            let i = i as usize;
            let x0 = [0, 1, 2].map(|a| self.x0[a * n + i]);
            let x1 = [0, 1, 2].map(|a| self.x0[a * n + i] + h * self.u[a * n + i]);
            [x0, x1]
        };
        let at = |x: [[f64; 3]; 2], t: f64| [0, 1, 2].map(|k| x[0][k] + t * (x[1][k] - x[0][k]));
        let unit = |v: [f64; 3]| length_and_unit(v).map(|(_, u)| u);
        // The contact normal: the triangle's, or the two edges' common normal, at the
        // time of contact (Bridson et al. 2002, 7.2); the direction between the closest
        // points is noise there (their distance is about eta).
        let (pr, geometric) = match pair {
            Pair::Vf(v, t) => {
                let [a, b, c] = self.triangles[t as usize];
                let (tc, pr) = vertex_triangle_ccd(path(v), path(a), path(b), path(c), eta)?;
                let (pa, pb, pc) = (at(path(a), tc), at(path(b), tc), at(path(c), tc));
                (pr, unit(cross(sub(pb, pa), sub(pc, pa))))
            }
            Pair::Ee(e, f) => {
                let ([a, b], [c, d]) = (self.edges[e as usize], self.edges[f as usize]);
                let (tc, pr) = edge_edge_ccd(path(a), path(b), path(c), path(d), eta)?;
                let e1 = sub(at(path(b), tc), at(path(a), tc));
                let e2 = sub(at(path(d), tc), at(path(c), tc));
                let c12 = cross(e1, e2);
                // Nearly parallel edges have no common normal: keep the closest points'.
                let parallel = dot(c12, c12) <= 1e-12 * dot(e1, e1) * dot(e2, e2);
                (pr, if parallel { None } else { unit(c12) })
            }
        };
        let (idx, w) = self.weights(pair, &pr);
        let mut nrm = geometric.unwrap_or(pr.normal);
        // Orient the normal so the features were on its positive side at the start of the
        // step (their relative position along it, by the same weights); exactly level,
        // by the start's proximity direction.
        let gap0 = weighted_dot(&self.x0, n, &idx, &w, nrm);
        if gap0 < 0.0 || (gap0 == 0.0 && dot(self.start_proximity(n, pair).2.normal, nrm) < 0.0) {
            nrm = nrm.map(|c| -c);
        }
        // Features already in contact that do not approach (separating, or sliding at
        // the contact distance) cannot cross: not a collision. Counting them would send
        // resting layers into impact zones every step.
        if self.relative_normal_velocity(n, &idx, &w, nrm) >= 0.0 {
            return None;
        }
        Some((idx, w, nrm))
    }

    /// Merges the vertices of every pair the last pass found colliding into zones and
    /// moves each zone rigidly.
    fn rigid_zones(&mut self, n: usize, h: f64, inv_mass: &[f64]) {
        use largestep_kernels::find_root as find;
        if self.hits.is_empty() {
            return;
        }
        for idx in &self.hits {
            let r = find(&mut self.parent, idx[0]);
            for &i in &idx[1..] {
                let ri = find(&mut self.parent, i);
                if ri != r {
                    self.parent[ri as usize] = r;
                }
            }
        }
        // Every zone of two or more vertices (from this round or earlier ones) moves
        // rigidly: vertices grouped by their root.
        let mut by_root: Vec<(u32, u32)> = (0..n as u32)
            .map(|i| (find(&mut self.parent, i), i))
            .collect();
        by_root.sort_unstable();
        let mut zone = Vec::new();
        for group in by_root.chunk_by(|a, b| a.0 == b.0) {
            if group.len() >= 2 {
                zone.clear();
                zone.extend(group.iter().map(|&(_, i)| i));
                self.rigidify(n, h, &zone, inv_mass);
            }
        }
    }

    /// Replaces the zone's average velocities by its rigid motion.
    fn rigidify(&mut self, n: usize, h: f64, verts: &[u32], inv_mass: &[f64]) {
        let g = |arr: &[f64], i: u32| [0, 1, 2].map(|a| arr[a * n + i as usize]);
        if let Some(&f) = verts.iter().find(|&&i| inv_mass[i as usize] == 0.0) {
            let uf = g(&self.u, f);
            for &i in verts {
                for (a, &ua) in uf.iter().enumerate() {
                    self.u[a * n + i as usize] = ua;
                }
            }
            return;
        }
        let (mut m, mut xc, mut vc) = (0.0, [0.0; 3], [0.0; 3]);
        for &i in verts {
            let mi = 1.0 / inv_mass[i as usize];
            let (x, u) = (g(&self.x0, i), g(&self.u, i));
            m += mi;
            for a in 0..3 {
                xc[a] += mi * x[a];
                vc[a] += mi * u[a];
            }
        }
        xc = xc.map(|c| c / m);
        vc = vc.map(|c| c / m);
        // Angular momentum and inertia tensor about the centre (at the start positions).
        let mut l = [0.0; 3];
        let mut inertia = [[0.0; 3]; 3];
        for &i in verts {
            let mi = 1.0 / inv_mass[i as usize];
            let r = sub(g(&self.x0, i), xc);
            let du = sub(g(&self.u, i), vc);
            let c = cross(r, du);
            let rr = dot(r, r);
            for a in 0..3 {
                l[a] += mi * c[a];
                for b in 0..3 {
                    inertia[a][b] += mi * (if a == b { rr } else { 0.0 } - r[a] * r[b]);
                }
            }
        }
        let omega = solve3(inertia, l).unwrap_or([0.0; 3]);
        // Move the zone by the rigid motion over the step, the rotation by `h omega`
        // exact (Rodrigues): `x0 + h (omega x r)` would stretch the zone by
        // `sqrt(1 + (h |omega|)^2)`, and a thin zone's omega can be large.
        let (angle, axis) = match length_and_unit(omega) {
            Some((w, axis)) => (w * h, axis),
            None => (0.0, [0.0; 3]),
        };
        let (sn, cs) = angle.sin_cos();
        for &i in verts {
            let r = sub(g(&self.x0, i), xc);
            let kxr = cross(axis, r);
            let kr = dot(axis, r);
            for a in 0..3 {
                let rotated = r[a] * cs + kxr[a] * sn + axis[a] * kr * (1.0 - cs);
                self.u[a * n + i as usize] = vc[a] + (rotated - r[a]) / h;
            }
        }
    }
}

/// `sum_k w_k (v_k . nrm)` over the pair's four vertices of component-major `v`: the
/// relative velocity (or position) of the pair's two sides along `nrm`.
fn weighted_dot(v: &[f64], n: usize, idx: &[u32; 4], w: &[f64; 4], nrm: [f64; 3]) -> f64 {
    idx.iter()
        .zip(w)
        .map(|(&i, &wk)| wk * (0..3).map(|a| v[a * n + i as usize] * nrm[a]).sum::<f64>())
        .sum()
}

/// Solves the 3x3 system `m x = b` by Cramer's rule; `None` when singular (a zone on a
/// line: its spin about the line is undefined, and no spin is taken).
fn solve3(m: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(m);
    let scale: f64 = m.iter().flatten().map(|c| c.abs()).fold(0.0, f64::max);
    if d.is_nan() || d.abs() <= 1e-12 * scale * scale * scale {
        return None;
    }
    Some(std::array::from_fn(|k| {
        let mut mk = m;
        for r in 0..3 {
            mk[r][k] = b[r];
        }
        det(mk) / d
    }))
}

/// Pairs of triangles of the surface at positions `x` (component-major) that share no
/// vertex and cross: an edge of one passes through the other. The check the folding
/// scenes run every frame.
pub fn crossed_triangle_pairs(triangles: &[[u32; 3]], x: &[f64]) -> Vec<[u32; 2]> {
    let n = x.len() / 3;
    let p = |i: u32| [x[i as usize], x[n + i as usize], x[2 * n + i as usize]];
    let mut boxes = Vec::new();
    crate::kernels::collide::bv::element_boxes(&mut boxes, x, triangles, 0.0);
    let bvh = Bvh::from_boxes(&boxes);
    let mut pairs = Vec::new();
    bvh.self_pairs(&mut PairWork::default(), &mut pairs);
    pairs.retain(|&[s, t]| {
        let (ts, tt) = (triangles[s as usize], triangles[t as usize]);
        if ts.iter().any(|v| tt.contains(v)) {
            return false;
        }
        let cross_of = |a: [u32; 3], b: [u32; 3]| {
            let tri = b.map(p);
            let Some(nrm) = crate::kernels::collide::prox::triangle_normal(tri[0], tri[1], tri[2])
            else {
                return false;
            };
            (0..3).any(|k| segment_through(tri, nrm, p(a[k]), p(a[(k + 1) % 3])))
        };
        cross_of(ts, tt) || cross_of(tt, ts)
    });
    pairs
}

/// Whether segment `a b` passes through the triangle: its ends on opposite sides of the
/// plane (strictly), the crossing point inside the triangle.
fn segment_through(t: [[f64; 3]; 3], nrm: [f64; 3], a: [f64; 3], b: [f64; 3]) -> bool {
    use crate::kernels::v3::{dot, sub};
    let (da, db) = (dot(sub(a, t[0]), nrm), dot(sub(b, t[0]), nrm));
    if !((da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0)) {
        return false;
    }
    let s = da / (da - db);
    let q = [0, 1, 2].map(|k| a[k] + s * (b[k] - a[k]));
    let (foot, _) = crate::kernels::collide::prox::closest_on_triangle(q, t[0], t[1], t[2]);
    let d = sub(q, foot);
    dot(d, d) <= 1e-24 * (1.0 + dot(q, q))
}
