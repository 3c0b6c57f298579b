//! Contacts as constraints, after Baraff and Witkin (1998, section 5): constraint filtering
//! plus position correction.
//!
//! After every step ([`VertexContacts::resolve`]) each free vertex closer than
//! [`CONTACT_THICKNESS`] to an obstacle (signed distance) is moved out along the obstacle's
//! normal to that thickness, loses the velocity that points into it, has its tangential
//! velocity scaled by `max(0, 1 - friction dv_n / |v_t|)` (Coulomb: `dv_n` is the normal
//! velocity removed at impact plus `h |f_n| / m` from the force pressing a resting vertex
//! onto the surface), and is constrained to the tangent plane for the next implicit solve
//! ([`VertexContacts::constraints`]), so it cannot move into the obstacle whatever the
//! solver's iteration count. A vertex is released when it moves away or when the force on
//! it at the last evaluation ([`VertexContacts::record_pull`]) pulled it off the surface:
//! the filter keeps a constrained vertex's normal velocity at zero, so velocity alone
//! would never release it. Obstacles are visited in order; a vertex touching two gets both
//! constraints (`S = I - p p^T - q q^T`), three fix it.
//!
//! A free vertex that would go through the obstacle's surface during the next step at its
//! present velocity (`d + h v_n < 0`, h the step just taken) gets a *speculative*
//! contact (Catto's speculative contacts, here in the paper's own terms): the next solve
//! constrains it in the normal direction with the prescribed normal velocity
//! `-(d - thickness) / h` (the filter's `z`), so that it arrives exactly at the thickness
//! while its neighbours respond implicitly in the same solve. Without it a fast vertex
//! ends the step up to `h |v_n|` inside, and moving it out afterwards stretches the
//! springs to its neighbours at once: the tablecloth's total energy went from 7.5 J to
//! 18.7 J in the step it met the table at dt = 1/60 s. The constraint is one-sided
//! ([`crate::solve::Filter::approach`]): when the solve finds it pulling the vertex
//! towards the obstacle (the cloth holds the vertex back) the linearised step frees it
//! and solves again. As an equality it dragged such vertices down and added 41% to the
//! drape's error at dt = 1/60 s (`largestep study cloth-accuracy`: 2.58e-2 m against
//! 1.83e-2 m without speculative contacts and 1.81e-2 m one-sided). A pull is tolerated
//! up to the approach's slack, `thickness / h` (what position correction absorbs
//! anyway). A vertex that only enters the thickness layer is left to position correction
//! (it moves at most the thickness): prescribing those too made the solve free approaches
//! in 61 of the drape's 180 steps instead of 20, and the tablecloth take 1216 steps
//! instead of 677.
//! A step smaller than the one predicted from brings the vertex less far; a larger one
//! leaves the rest to position correction.
//!
//! Vertices alone would let an obstacle's sharp edge pass between them: a table's edges
//! showed through the tablecloth draped over it, and a rising box's through the sheet it
//! lifted (by up to 2 cm). After the vertex contacts, every triangle of the model that a
//! sharp edge of an obstacle, fixed or moving, comes through (or within the thickness of)
//! is moved out along its normal and held there for the next solve
//! (`VertexContacts::resolve_edges`; the geometry is in [`super::edge_through_triangle`]);
//! a moving obstacle carries the vertices its edge holds along within the solve (the
//! filter's prescribed velocity).
//!
//! A vertex that went inside is moved out through the surface it came in by (its path
//! over the step, `x - h v` to `x`, crosses it), not the nearest one: a vertex that went
//! through a table's top within millimetres of its edge was moved out of the side and
//! fell off the table, dragging the cloth and stretching it.
//!
//! The contacts are per-step state: they live with the positions and velocities, not in
//! the model.

use super::{MovingObstacle, Obstacle};
use crate::solve::Filter;
use largestep_kernels::get3;
use largestep_kernels::v3::{cross, dot, length_and_unit as unit, sub};

/// Collision thickness: vertices are kept this far outside obstacles (m).
pub const CONTACT_THICKNESS: f64 = 2e-3;

/// Vertices closer than this are in contact (m): the thickness and a millionth of it, so
/// that a vertex a speculative contact brought to the thickness, give or take rounding,
/// is held there.
const REACH: f64 = CONTACT_THICKNESS * (1.0 + 1e-6);

/// One vertex held against one surface direction.
#[derive(Clone, Copy, Debug)]
struct Contact {
    vertex: u32,
    /// Outward unit normal.
    normal: [f64; 3],
    /// Which obstacle: the static ones first, then the moving ones.
    obstacle: u32,
    /// The obstacle's velocity at the vertex (m/s; zero for a static one).
    velocity: [f64; 3],
    /// Held by an obstacle's edge ([`VertexContacts::resolve_edges`]), not a face.
    edge: bool,
    /// The normal component of the force on the vertex at the last force evaluation (N):
    /// positive means the model pulls it off the surface.
    pull: f64,
}

/// The vertices in contact and what the last force evaluation did to them.
#[derive(Clone, Debug, Default)]
pub struct VertexContacts {
    /// Current contacts, in vertex order.
    contacts: Vec<Contact>,
    /// Scratch: the previous step's contacts while resolving new ones.
    prev: Vec<Contact>,
    /// Speculative contacts for the next step: vertex, outward unit normal and the normal
    /// velocity that brings it to the thickness (m/s, <= 0), in vertex order.
    approach: Vec<(u32, [f64; 3], f64)>,
    /// The pull the approaches tolerate before the solve frees them (m/s,
    /// `solve::Approach::slack`): thickness / h of the step they were predicted from.
    approach_slack: f64,
    /// Scratch, per vertex: whether the model pulled it off its contacts at the last step.
    released: Vec<bool>,
    /// Triangles an obstacle edge was pushed out of at the last resolve.
    edge_contacts: usize,
    /// Scratch: the sharp edges of the obstacle being resolved.
    edges: Vec<([f64; 3], [f64; 3])>,
}

impl VertexContacts {
    /// No contacts.
    pub fn new() -> Self {
        Self::default()
    }

    /// Contacts since the last [`VertexContacts::resolve`]: vertices against surfaces,
    /// and triangles against obstacle edges.
    pub fn count(&self) -> usize {
        let vertex = self.contacts.chunk_by(|a, b| a.vertex == b.vertex).count();
        vertex + self.edge_contacts
    }

    /// Resolves contacts after a step of size `h` (s) with the state `(x, v)` (see the
    /// module docs). `triangles`: the model's surface, which obstacle edges must not pass
    /// through (may be empty); `fixed`: vertices the contacts never move (sorted); `mass`:
    /// per vertex (kg); `friction`: the Coulomb coefficient, >= 0. Returns
    /// [`VertexContacts::count`].
    #[allow(clippy::too_many_arguments)]
    pub fn resolve(
        &mut self,
        obstacles: &[Obstacle],
        moving: &[MovingObstacle],
        triangles: &[[u32; 3]],
        fixed: &[u32],
        mass: &[f64],
        friction: f64,
        x: &mut [f64],
        v: &mut [f64],
        h: f64,
    ) -> usize {
        std::mem::swap(&mut self.contacts, &mut self.prev);
        self.contacts.clear();
        self.approach.clear();
        self.approach_slack = CONTACT_THICKNESS / h;
        self.edge_contacts = 0;
        if obstacles.is_empty() && moving.is_empty() {
            return 0;
        }
        let all = || with_motion(obstacles, moving);
        let n = mass.len();
        self.released.clear();
        self.released.resize(n, false);
        let mut prev = 0; // walks the previous contacts (vertex order) alongside i
        for i in 0..n {
            if fixed.binary_search(&(i as u32)).is_ok() {
                continue;
            }
            // Its contacts at the last step.
            while self.prev.get(prev).is_some_and(|c| (c.vertex as usize) < i) {
                prev += 1;
            }
            let start = prev;
            while self.prev.get(prev).is_some_and(|c| c.vertex as usize == i) {
                prev += 1;
            }
            let was = &self.prev[start..prev];
            // Was it held by a contact the model is pulling it away from?
            let pulled = was.iter().any(|c| c.pull > 0.0);
            // Normal force pressing it onto the surface during the step (N, >= 0).
            let press = was.iter().fold(0.0f64, |m, c| m.max(-c.pull));
            self.released[i] = pulled;
            for (which, (o, mv)) in (0u32..).zip(all()) {
                let p = get3(x, n, i);
                let Some((d, nrm)) = o.distance(p) else {
                    continue;
                };
                // A vertex held against a moving obstacle at the last step stays held
                // within twice the thickness (and is not pulled in): one its edge carried
                // along (see `constraints`) can end a little off the face, and dropped
                // there it met the obstacle again the step after, and so on; the sheet
                // on the rising box then failed the step control at step 284.
                let carried = mv.is_some() && was.iter().any(|c| c.obstacle == which);
                let reach = if carried {
                    2.0 * CONTACT_THICKNESS
                } else {
                    REACH
                };
                if d.is_nan() || d >= reach || (pulled && d >= 0.0) {
                    continue;
                }
                let ov = mv.map_or([0.0; 3], |m| m.velocity_at(p));
                // Inside: out through the surface it came in by, not the nearest one (a
                // vertex that went through a table's top near its edge goes back up, not
                // out of the side, where it would fall off). The path is the one relative
                // to the obstacle.
                let start = std::array::from_fn(|k| p[k] - h * (v[k * n + i] - ov[k]));
                let (d, nrm) = if d < 0.0 {
                    o.entry(start, p).unwrap_or((d, nrm))
                } else {
                    (d, nrm)
                };
                let out = if carried {
                    (CONTACT_THICKNESS - d).max(0.0)
                } else {
                    CONTACT_THICKNESS - d
                };
                for k in 0..3 {
                    x[k * n + i] = p[k] + out * nrm[k];
                }
                let vel = sub(get3(v, n, i), ov);
                let vn = dot(vel, nrm);
                if vn > 0.0 {
                    continue; // moving away: released
                }
                let vt: [f64; 3] = std::array::from_fn(|k| vel[k] - vn * nrm[k]);
                let vt_len = dot(vt, vt).sqrt();
                // Coulomb: the tangential velocity change is at most friction times the
                // normal one, which is the impact (-vn) plus what the pressing force
                // delivered over the step (resting contact, where vn is zero).
                let dvn = -vn + press * h / mass[i];
                let keep = if vt_len > 0.0 {
                    (1.0 - friction * dvn / vt_len).max(0.0)
                } else {
                    0.0
                };
                for k in 0..3 {
                    v[k * n + i] = ov[k] + keep * vt[k];
                }
                self.contacts.push(Contact {
                    vertex: i as u32,
                    obstacle: which,
                    velocity: ov,
                    edge: false,
                    normal: nrm,
                    pull: 0.0,
                });
            }
            if self.contacts.last().is_some_and(|c| c.vertex as usize == i) || pulled {
                continue;
            }
            // Free: will it go through the surface within a step of h at its velocity? The
            // nearest such obstacle decides (a vertex between two gets one prescription).
            let (p, vel) = (get3(x, n, i), get3(v, n, i));
            let mut first: Option<([f64; 3], f64, f64)> = None;
            for (o, mv) in all() {
                let Some((d, nrm)) = o.distance(p) else {
                    continue;
                };
                let ov = mv.map_or([0.0; 3], |m| m.velocity_at(p));
                let vn = dot(sub(vel, ov), nrm);
                let gap = d - CONTACT_THICKNESS;
                if vn < 0.0 && d >= REACH && d + h * vn < 0.0 {
                    let arrival = gap / -vn;
                    if first.is_none_or(|f| arrival < f.2) {
                        // The prescribed normal velocity: the obstacle's, less the gap.
                        first = Some((nrm, dot(ov, nrm) - gap / h, arrival));
                    }
                }
            }
            if let Some((nrm, speed, _)) = first {
                self.approach.push((i as u32, nrm, speed));
            }
        }
        let before = self.contacts.len();
        self.edge_contacts = self.resolve_edges(obstacles, moving, triangles, fixed, x, v);
        if self.contacts.len() > before {
            // Back into vertex order (unstable: a vertex's normals may come in any order).
            self.contacts.sort_unstable_by_key(|c| c.vertex);
        }
        self.count()
    }

    /// Moves every triangle that an obstacle's sharp edge comes through, or within the
    /// thickness of, out along its normal n (see [`super::edge_through_triangle`]): vertex
    /// k moves by `c w_k d_k`, with w the barycentric coordinates of the edge's deepest
    /// point, `d_k = S_k n` the part of n its face contacts with the same obstacle let it
    /// move along (n for a free vertex, within the face for one lying on the table's top,
    /// zero for a fixed one) and c chosen so that the point itself moves out to the
    /// thickness (Bridson, Fedkiw and Anderson 2002 distribute corrections over a triangle
    /// so). Moving a vertex that lies on a face off it would let it fall back the next step
    /// and ratchet the cloth outwards. The velocity into the triangle at the point
    /// (relative to a moving obstacle's) is removed the same way, and the vertices on the
    /// obstacle's faces are held against n in the next solve like vertex contacts (one
    /// normal per vertex and obstacle: the weighted mean of its triangles'), moving with a
    /// moving obstacle. The outward side of a triangle is the one its vertices' obstacle
    /// normals point to. A triangle whose vertices the model pulled off at the last step is
    /// let go unless the edge is through it. Returns the number of triangles moved.
    fn resolve_edges(
        &mut self,
        obstacles: &[Obstacle],
        moving: &[MovingObstacle],
        triangles: &[[u32; 3]],
        fixed: &[u32],
        x: &mut [f64],
        v: &mut [f64],
    ) -> usize {
        let n = x.len() / 3;
        let mut moved = 0;
        let vertex_end = self.contacts.len();
        let mut edges = std::mem::take(&mut self.edges);
        for (which, (o, mv)) in (0u32..).zip(with_motion(obstacles, moving)) {
            // The obstacle's sharp edges, placed once for all its triangles.
            edges.clear();
            edges.extend(o.sharp_edges());
            let Some((lo, hi)) = bounds(&edges) else {
                continue;
            };
            let first_new = self.contacts.len();
            for tri in triangles {
                let t = tri.map(|i| get3(x, n, i as usize));
                let tlo: [f64; 3] = std::array::from_fn(|k| t[0][k].min(t[1][k]).min(t[2][k]));
                let thi: [f64; 3] = std::array::from_fn(|k| t[0][k].max(t[1][k]).max(t[2][k]));
                if !overlap((lo, hi), (tlo, thi)) {
                    continue;
                }
                let Some((_, mut nrm)) = unit(cross(sub(t[1], t[0]), sub(t[2], t[0]))) else {
                    continue;
                };
                let out = t
                    .iter()
                    .filter_map(|&p| o.distance(p))
                    .fold([0.0; 3], |s, (_, m)| std::array::from_fn(|k| s[k] + m[k]));
                let side = dot(out, nrm);
                if side.abs() < 1e-3 {
                    continue; // edge-on to the obstacle: no outward side
                }
                if side < 0.0 {
                    nrm = nrm.map(|c| -c);
                }
                // Only edges that run along the triangle, within 60 degrees of its plane,
                // and come through it by less than its size: an edge that skewers it is
                // left to the vertex contacts (moving the triangle along its normal off
                // such an edge could take it far).
                let size = (0..3).fold(0.0f64, |m, k| {
                    let e = sub(t[(k + 1) % 3], t[k]);
                    m.max(dot(e, e).sqrt())
                });
                let mut deepest: Option<(f64, [f64; 3])> = None;
                for &(a, b) in &edges {
                    let slo: [f64; 3] = std::array::from_fn(|k| a[k].min(b[k]));
                    let shi: [f64; 3] = std::array::from_fn(|k| a[k].max(b[k]));
                    if !overlap((slo, shi), (tlo, thi)) {
                        continue;
                    }
                    let Some((_, e)) = unit(sub(b, a)) else {
                        continue;
                    };
                    if dot(e, nrm).abs() > 0.5 {
                        continue;
                    }
                    if let Some((height, w)) = super::edge_through_triangle(t, nrm, a, b) {
                        if deepest.is_none_or(|d| height > d.0) {
                            deepest = Some((height, w));
                        }
                    }
                }
                let Some((height, w)) = deepest else {
                    continue;
                };
                if height > size {
                    continue;
                }
                let need = height + CONTACT_THICKNESS;
                let let_go = tri.iter().all(|&i| self.released[i as usize]) && height <= 0.0;
                if need.is_nan() || need <= -(REACH - CONTACT_THICKNESS) || let_go {
                    continue;
                }
                // Vertex k's face contacts with this obstacle (a vertex resting on the
                // floor may be lifted off it by a box's edge rising under its triangle).
                let faces = |k: usize| {
                    let faces = &self.contacts[..vertex_end];
                    let at = faces.partition_point(|c| c.vertex < tri[k]);
                    faces[at..]
                        .iter()
                        .take_while(move |c| c.vertex == tri[k])
                        .filter(move |c| c.obstacle == which)
                };
                // Each vertex moves along the normal as far as those let it: d_k = S_k n
                // (S_k the projection of its face contacts), zero when fixed.
                let dirs: [[f64; 3]; 3] = std::array::from_fn(|k| {
                    if fixed.binary_search(&tri[k]).is_ok() {
                        return [0.0; 3];
                    }
                    faces(k).fold(nrm, |d, c| {
                        let dn = dot(d, c.normal);
                        std::array::from_fn(|j| d[j] - dn * c.normal[j])
                    })
                });
                let on_face: [bool; 3] = std::array::from_fn(|k| faces(k).next().is_some());
                // Moving vertex k by c w_k d_k moves the point by c sum w_k^2 (n . d_k).
                let denom: f64 = (0..3).map(|k| w[k] * w[k] * dot(nrm, dirs[k])).sum();
                if denom.is_nan() || denom <= 1e-6 {
                    continue;
                }
                // The velocity into the triangle at the point, relative to the obstacle's.
                let point: [f64; 3] =
                    std::array::from_fn(|c| (0..3).map(|k| w[k] * t[k][c]).sum::<f64>());
                let along = mv.map_or(0.0, |m| dot(m.velocity_at(point), nrm));
                let vel = (0..3).fold(-along, |s, k| {
                    s + w[k] * dot(get3(v, n, tri[k] as usize), nrm)
                });
                for k in 0..3 {
                    let i = tri[k] as usize;
                    let dx = w[k] * need.max(0.0) / denom;
                    let dv = -w[k] * vel.min(0.0) / denom;
                    for c in 0..3 {
                        x[c * n + i] += dx * dirs[k][c];
                        v[c * n + i] += dv * dirs[k][c];
                    }
                    // Held in the next solve: the vertices on the obstacle's faces, which
                    // then keep to the line along the edge. One beyond the edge is left
                    // free to swing down about it: held against n (the filter holds
                    // single vertices, not the contact point) it stood out from a rising
                    // box like a stiff skirt instead of hanging.
                    if w[k] > 0.0 && dirs[k] != [0.0; 3] && on_face[k] {
                        self.contacts.push(Contact {
                            vertex: i as u32,
                            obstacle: which,
                            velocity: mv.map_or([0.0; 3], |m| m.velocity_at(get3(x, n, i))),
                            edge: true,
                            normal: nrm.map(|c| c * w[k]),
                            pull: 0.0,
                        });
                    }
                }
                moved += 1;
            }
            // One normal per vertex for this obstacle: the weighted mean.
            let new = &mut self.contacts[first_new..];
            new.sort_unstable_by_key(|c| c.vertex);
            let mut kept = first_new;
            let mut k = first_new;
            while k < self.contacts.len() {
                let first = self.contacts[k];
                let vertex = first.vertex;
                let mut sum = [0.0; 3];
                while k < self.contacts.len() && self.contacts[k].vertex == vertex {
                    let m = self.contacts[k].normal;
                    sum = std::array::from_fn(|c| sum[c] + m[c]);
                    k += 1;
                }
                if let Some((_, normal)) = unit(sum) {
                    self.contacts[kept] = Contact { normal, ..first };
                    kept += 1;
                }
            }
            self.contacts.truncate(kept);
        }
        self.edges = edges;
        moved
    }

    /// Appends the vertices held by a contact or approaching an obstacle to `out` (a
    /// vertex on two surfaces twice; callers sort and dedup what they gathered).
    pub fn touching(&self, out: &mut Vec<u32>) {
        out.extend(self.contacts.iter().map(|c| c.vertex));
        out.extend(self.approach.iter().map(|a| a.0));
    }

    /// Records, for every contact, the normal component of the force `f` (N,
    /// component-major) on its vertex: what releases a contact the model pulls away.
    pub fn record_pull(&mut self, f: &[f64]) {
        let n = f.len() / 3;
        for c in &mut self.contacts {
            c.pull = dot(get3(f, n, c.vertex as usize), c.normal);
        }
    }

    /// Writes the contacts into the constraint filter: one normal constrains a vertex to
    /// the tangent plane, two independent ones to their common line, three or more fix it;
    /// a vertex held at a moving obstacle's edge moves out with it.
    /// Speculative contacts constrain the normal with its prescribed velocity.
    pub fn constraints(&self, filter: &mut Filter) {
        for group in self.contacts.chunk_by(|a, b| a.vertex == b.vertex) {
            let i = group[0].vertex as usize;
            // The independent normals (up to three), each with the speed at which its
            // obstacle pushes out along it (m/s, >= 0).
            let mut picked = [([0.0; 3], 0.0); 3];
            let mut count = 0;
            for c in group {
                let q = c.normal;
                let independent = match count {
                    0 => true,
                    1 => {
                        let x = cross(picked[0].0, q);
                        dot(x, x) >= 1e-12
                    }
                    2 => {
                        let l = cross(picked[0].0, picked[1].0);
                        dot(l, q).abs() > 1e-6 * dot(l, l).sqrt()
                    }
                    _ => false,
                };
                if independent {
                    picked[count] = (q, dot(c.velocity, q).max(0.0));
                    count += 1;
                }
            }
            let [(p, sp), (q, sq), (r, sr)] = picked;
            match count {
                3 => filter.fix(i),
                2 => filter.constrain_line(i, cross(p, q)),
                _ => filter.constrain_normal(i, p),
            }
            if !group.iter().any(|c| c.edge) || sp == 0.0 && sq == 0.0 && sr == 0.0 {
                continue;
            }
            // A vertex held at a moving obstacle's edge moves out with it in the solve
            // (the paper's z: z . n_k = s_k). Left still, the rising box's edge came
            // through the sheet again every step and the corrections after it stretched
            // the sheet past the step control's limit however far the step was halved.
            // Vertex contacts alone are not carried: carried, the FEM mat on the rising
            // ball of `rigid-fem.toml` shook (kinetic energy 16 J where 1 J is right)
            // and their corrections after the step are small anyway. Only the speed
            // pushing out counts: a surface moving away lets the vertex go rather than
            // drag it along. Normals less than 30 degrees apart (or three nearly in a
            // plane) would ask for a velocity far from any of them: the fastest alone
            // decides.
            let (c, d) = (cross(p, q), dot(p, cross(q, r)));
            let z: [f64; 3] = match count {
                3 if d.abs() >= 0.25 => {
                    let t = [(sp, cross(q, r)), (sq, cross(r, p)), (sr, c)];
                    std::array::from_fn(|k| t.iter().map(|(s, x)| s * x[k]).sum::<f64>() / d)
                }
                2 if dot(c, c) >= 0.25 => {
                    let (a, b) = (cross(q, c), cross(c, p));
                    std::array::from_fn(|k| (sp * a[k] + sq * b[k]) / dot(c, c))
                }
                _ => picked[..count]
                    .iter()
                    .max_by(|a, b| a.1.total_cmp(&b.1))
                    .map_or([0.0; 3], |&(n, s)| n.map(|x| x * s)),
            };
            filter.prescribe(i, z);
        }
        // A vertex an edge contact took after its speculative one keeps the contact.
        let mut held = self.contacts.iter().map(|c| c.vertex).peekable();
        for &(i, nrm, speed) in &self.approach {
            while held.next_if(|&h| h < i).is_some() {}
            if held.peek() == Some(&i) {
                continue;
            }
            filter.approach(i as usize, nrm, speed, self.approach_slack);
        }
    }

    /// Vertices with a speculative contact for the next step (see the module docs).
    pub fn approaching(&self) -> usize {
        self.approach.len()
    }
}

/// The fixed obstacles (no motion) and then the moving ones (velocities are taken
/// relative to theirs): the order that numbers them in [`Contact::obstacle`].
fn with_motion<'a>(
    obstacles: &'a [Obstacle],
    moving: &'a [MovingObstacle],
) -> impl Iterator<Item = (&'a Obstacle, Option<&'a MovingObstacle>)> {
    obstacles
        .iter()
        .map(|o| (o, None))
        .chain(moving.iter().map(|m| (&m.shape, Some(m))))
}

/// The axis-aligned bounds of segments, `None` without any.
fn bounds(segments: &[([f64; 3], [f64; 3])]) -> Option<([f64; 3], [f64; 3])> {
    let (lo, hi) = segments.iter().flat_map(|(a, b)| [a, b]).fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                std::array::from_fn(|k| lo[k].min(p[k])),
                std::array::from_fn(|k| hi[k].max(p[k])),
            )
        },
    );
    (!segments.is_empty()).then_some((lo, hi))
}

/// Whether two boxes `(lo, hi)` come within the contact thickness of each other.
fn overlap(a: ([f64; 3], [f64; 3]), b: ([f64; 3], [f64; 3])) -> bool {
    (0..3).all(|k| a.0[k] <= b.1[k] + CONTACT_THICKNESS && b.0[k] <= a.1[k] + CONTACT_THICKNESS)
}
