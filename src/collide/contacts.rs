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
//! The contacts are per-step state: they live with the positions and velocities, not in
//! the model.

use super::Obstacle;
use crate::solve::Filter;
use largestep_kernels::get3;
use largestep_kernels::v3::{cross, dot};

/// Collision thickness: vertices are kept this far outside obstacles (m).
pub const CONTACT_THICKNESS: f64 = 2e-3;

/// The vertices in contact and what the last force evaluation did to them.
#[derive(Clone, Debug, Default)]
pub struct VertexContacts {
    /// Current contacts: vertex and outward unit normal, in vertex order.
    contacts: Vec<(u32, [f64; 3])>,
    /// For each contact, the normal component of the force on its vertex at the last force
    /// evaluation (N): positive means the model pulls it off the surface.
    pull: Vec<f64>,
    /// Scratch: the previous step's contacts and pulls while resolving new ones.
    prev_contacts: Vec<(u32, [f64; 3])>,
    prev_pull: Vec<f64>,
}

impl VertexContacts {
    /// No contacts.
    pub fn new() -> Self {
        Self::default()
    }

    /// Vertices in contact since the last [`VertexContacts::resolve`].
    pub fn count(&self) -> usize {
        self.contacts.len()
    }

    /// Resolves contacts after a step of size `h` (s) with the state `(x, v)` (see the
    /// module docs). `fixed`: vertices the contacts never move (sorted); `mass`: per
    /// vertex (kg); `friction`: the Coulomb coefficient, >= 0. Returns the number of
    /// contacts.
    #[allow(clippy::too_many_arguments)]
    pub fn resolve(
        &mut self,
        obstacles: &[Obstacle],
        fixed: &[u32],
        mass: &[f64],
        friction: f64,
        x: &mut [f64],
        v: &mut [f64],
        h: f64,
    ) -> usize {
        std::mem::swap(&mut self.contacts, &mut self.prev_contacts);
        std::mem::swap(&mut self.pull, &mut self.prev_pull);
        self.contacts.clear();
        self.pull.clear();
        if obstacles.is_empty() {
            return 0;
        }
        let n = mass.len();
        let mut prev = 0; // walks the previous contacts (vertex order) alongside i
        for i in 0..n {
            if fixed.binary_search(&(i as u32)).is_ok() {
                continue;
            }
            // Was it held by a contact the model is pulling it away from?
            let mut pulled = false;
            // Normal force pressing it onto the surface during the step (N, >= 0).
            let mut press = 0.0f64;
            while prev < self.prev_contacts.len() && self.prev_contacts[prev].0 as usize <= i {
                if self.prev_contacts[prev].0 as usize == i {
                    let pull = self.prev_pull[prev];
                    pulled |= pull > 0.0;
                    press = press.max(-pull);
                }
                prev += 1;
            }
            for o in obstacles {
                let p = get3(x, n, i);
                let Some((d, nrm)) = o.distance(p) else {
                    continue;
                };
                if d.is_nan() || d >= CONTACT_THICKNESS || (pulled && d >= 0.0) {
                    continue;
                }
                for k in 0..3 {
                    x[k * n + i] = p[k] + (CONTACT_THICKNESS - d) * nrm[k];
                }
                let vel = get3(v, n, i);
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
                    v[k * n + i] = keep * vt[k];
                }
                self.contacts.push((i as u32, nrm));
                self.pull.push(0.0);
            }
        }
        self.contacts.len()
    }

    /// Records, for every contact, the normal component of the force `f` (N,
    /// component-major) on its vertex: what releases a contact the model pulls away.
    pub fn record_pull(&mut self, f: &[f64]) {
        let n = f.len() / 3;
        for ((i, nrm), pull) in self.contacts.iter().zip(&mut self.pull) {
            *pull = dot(get3(f, n, *i as usize), *nrm);
        }
    }

    /// Writes the contacts into the constraint filter: one normal constrains a vertex to
    /// the tangent plane, two independent ones to their common line, three or more fix it.
    pub fn constraints(&self, filter: &mut Filter) {
        for group in self.contacts.chunk_by(|a, b| a.0 == b.0) {
            let i = group[0].0 as usize;
            let p = group[0].1;
            let mut line: Option<[f64; 3]> = None;
            let mut fixed = false;
            for &(_, q) in &group[1..] {
                let c = cross(p, q);
                if dot(c, c) < 1e-12 {
                    continue; // (anti)parallel: the same plane
                }
                match line {
                    None => line = Some(c),
                    Some(l) => {
                        if dot(l, q).abs() > 1e-6 * dot(l, l).sqrt() {
                            fixed = true;
                        }
                    }
                }
            }
            match (fixed, line) {
                (true, _) => filter.fix(i),
                (false, Some(l)) => filter.constrain_line(i, l),
                (false, None) => filter.constrain_normal(i, p),
            }
        }
    }
}
