//! Per-vertex constraint filter of Baraff and Witkin (1998, section 5.1).
//!
//! A constrained vertex i has a 3x3 projection `S_i`: `I - p p^T` with one constrained
//! direction p (moves in a plane), `I - p p^T - q q^T` with two (moves along a line), `0`
//! with three (pinned); free vertices have `S_i = I` and are not stored. Filtering a vector
//! applies `S_i` to its vertex blocks, which removes the constrained components.
//!
//! For iterative solves the filter goes inside CG (see [`crate::solve::Pcg`]). For direct
//! solves the system is projected instead: `A' = S A S + (I - S)`, `b' = S b`. Its solution
//! `y` has `(I - S) y = 0` and `S A S y = S b`, the same as the filtered CG, and `A'` is
//! positive definite whenever A is.
//!
//! A constrained vertex may also have a prescribed velocity `z_i` in its constrained
//! directions (the paper's `z`): the step starts from `v_i = S_i v_i + z_i`
//! ([`Filter::impose`]) and, since every change of velocity is filtered, ends with the
//! same constrained component. Contacts use it to bring an approaching vertex exactly to
//! the surface within the step ([`crate::collide::VertexContacts`]).
//!
//! Such an approach is a one-sided constraint ([`Filter::approach`]): an obstacle can push
//! a vertex but not pull it. The filter lists them ([`Filter::unilateral`]); after a solve
//! the stepper frees those whose constraint impulse along n came out negative by more
//! than the approach's slack (the cloth would have held the vertex back short of the
//! obstacle by more than the slack allows) and solves again:
//! one round of an active-set method, in the spirit of the paper's release of contacts
//! whose constraint force pulls (section 5.3), done within the step because an approach
//! lasts only one.

use crate::sparse::Bsr3;

/// Projections `S_i` for the constrained vertices (see the module docs).
#[derive(Debug, Default, PartialEq)]
pub struct Filter {
    n: usize,
    verts: Vec<u32>,
    s: Vec<[f64; 9]>,
    /// Prescribed velocity per constrained vertex (m/s), in its constrained directions.
    z: Vec<[f64; 3]>,
    index_of: Vec<u32>,
    /// One-sided constraints.
    unilateral: Vec<Approach>,
}

/// A one-sided constraint ([`Filter::approach`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Approach {
    /// The vertex.
    pub vertex: u32,
    /// Unit normal the obstacle may push the vertex along (outward).
    pub normal: [f64; 3],
    /// The pull tolerated, as a velocity (m/s): the constraint is freed only when its
    /// impulse pulls by more than mass times this. A pull of `m s` moves the vertex by at
    /// most `h s` within the step; contacts set it so that this is the contact thickness,
    /// which position correction absorbs anyway.
    pub slack: f64,
}

const FREE: u32 = u32::MAX;

impl Clone for Filter {
    fn clone(&self) -> Self {
        let mut f = Filter::default();
        f.clone_from(self);
        f
    }

    /// Field by field, reusing this filter's buffers (the chord method keeps a copy of
    /// the step's filter without allocating once the buffers have grown).
    fn clone_from(&mut self, o: &Self) {
        self.n = o.n;
        self.verts.clone_from(&o.verts);
        self.s.clone_from(&o.s);
        self.z.clone_from(&o.z);
        self.index_of.clone_from(&o.index_of);
        self.unilateral.clone_from(&o.unilateral);
    }
}

impl Filter {
    /// Whether `other` constrains the same vertices in the same directions (prescribed
    /// velocities aside): then a matrix projected by one is projected by the other.
    pub fn same_projection(&self, other: &Filter) -> bool {
        self.n == other.n && self.verts == other.verts && self.s == other.s
    }

    /// No constraints on n vertices.
    pub fn new(n: usize) -> Self {
        Self {
            n,
            verts: Vec::new(),
            s: Vec::new(),
            z: Vec::new(),
            index_of: vec![FREE; n],
            unilateral: Vec::new(),
        }
    }

    /// Number of vertices.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Whether no vertex is constrained.
    pub fn is_empty(&self) -> bool {
        self.verts.is_empty()
    }

    /// Whether vertex i is unconstrained.
    pub fn is_free(&self, i: usize) -> bool {
        self.index_of[i] == FREE
    }

    /// The projection of vertex i (identity if free).
    pub fn projection(&self, i: usize) -> [f64; 9] {
        match self.index_of[i] {
            FREE => [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            k => self.s[k as usize],
        }
    }

    /// The constrained vertices with their projections, in the order first constrained.
    pub fn constrained(&self) -> impl Iterator<Item = (usize, [f64; 9])> + '_ {
        self.verts
            .iter()
            .zip(&self.s)
            .map(|(&i, &s)| (i as usize, s))
    }

    fn set(&mut self, i: usize, s: [f64; 9]) {
        assert!(i < self.n, "vertex {i} out of range ({} vertices)", self.n);
        match self.index_of[i] {
            FREE => {
                self.index_of[i] = self.verts.len() as u32;
                self.verts.push(i as u32);
                self.s.push(s);
                self.z.push([0.0; 3]);
            }
            k => {
                self.s[k as usize] = s;
                self.z[k as usize] = [0.0; 3];
                // A new constraint replaces a one-sided one (`approach` marks it again).
                self.unilateral.retain(|a| a.vertex as usize != i);
            }
        }
    }

    /// Frees every vertex (cost proportional to the constrained ones).
    pub fn clear(&mut self) {
        for &i in &self.verts {
            self.index_of[i as usize] = FREE;
        }
        self.verts.clear();
        self.s.clear();
        self.z.clear();
        self.unilateral.clear();
    }

    /// Frees vertex i (nothing if it is free); the others keep their constraints.
    pub fn free(&mut self, i: usize) {
        let k = self.index_of[i];
        if k == FREE {
            return;
        }
        let k = k as usize;
        self.index_of[i] = FREE;
        self.verts.swap_remove(k);
        self.s.swap_remove(k);
        self.z.swap_remove(k);
        if let Some(&moved) = self.verts.get(k) {
            self.index_of[moved as usize] = k as u32;
        }
        self.unilateral.retain(|a| a.vertex as usize != i);
    }

    /// A one-sided approach (see the module docs): vertex i moves in the plane normal to
    /// `normal` (outward from the obstacle, need not be unit) plus `speed` (m/s, negative
    /// towards the obstacle) along the unit normal, unless the solve finds the constraint
    /// pulling it by more than `slack` (m/s, see [`Approach::slack`]), when the stepper
    /// frees it.
    pub fn approach(&mut self, i: usize, normal: [f64; 3], speed: f64, slack: f64) {
        let p = unit(normal);
        self.constrain_normal(i, p);
        self.prescribe(i, p.map(|c| c * speed));
        self.unilateral.retain(|a| a.vertex as usize != i);
        self.unilateral.push(Approach {
            vertex: i as u32,
            normal: p,
            slack,
        });
    }

    /// The one-sided constraints.
    pub fn unilateral(&self) -> &[Approach] {
        &self.unilateral
    }

    /// Pins vertex i (all three directions constrained).
    pub fn fix(&mut self, i: usize) {
        self.set(i, [0.0; 9]);
    }

    /// Constrains vertex i to move in the plane normal to `normal` (need not be unit).
    pub fn constrain_normal(&mut self, i: usize, normal: [f64; 3]) {
        let p = unit(normal);
        let mut s = [0.0; 9];
        for r in 0..3 {
            for c in 0..3 {
                s[3 * r + c] = if r == c { 1.0 } else { 0.0 } - p[r] * p[c];
            }
        }
        self.set(i, s);
    }

    /// Constrains vertex i to move along `dir` only (need not be unit).
    pub fn constrain_line(&mut self, i: usize, dir: [f64; 3]) {
        let d = unit(dir);
        let mut s = [0.0; 9];
        for r in 0..3 {
            for c in 0..3 {
                s[3 * r + c] = d[r] * d[c];
            }
        }
        self.set(i, s);
    }

    /// Prescribes the velocity of constrained vertex i (m/s) in its constrained directions:
    /// the part of `z` in them is kept (`(I - S_i) z`), the rest dropped. Constraining the
    /// vertex again resets it to zero; a free vertex is left free.
    pub fn prescribe(&mut self, i: usize, z: [f64; 3]) {
        let k = self.index_of[i];
        if k == FREE {
            return;
        }
        let s = &self.s[k as usize];
        self.z[k as usize] = std::array::from_fn(|r| {
            z[r] - (s[3 * r] * z[0] + s[3 * r + 1] * z[1] + s[3 * r + 2] * z[2])
        });
    }

    /// `v = S v + z` for component-major Vec3s velocities v: constrained directions take
    /// their prescribed velocity (zero unless [`Filter::prescribe`]d).
    pub fn impose(&self, v: &mut [f64]) {
        let n = self.n;
        assert_eq!(v.len(), 3 * n);
        for &i in &self.verts {
            let i = i as usize;
            let vi = self.imposed(i, largestep_kernels::get3(v, n, i));
            for (r, c) in vi.into_iter().enumerate() {
                v[r * n + i] = c;
            }
        }
    }

    /// Vertex i's velocity `vi` as [`Filter::impose`] leaves it: `S_i vi + z_i`.
    pub fn imposed(&self, i: usize, vi: [f64; 3]) -> [f64; 3] {
        match self.index_of[i] {
            FREE => vi,
            k => {
                let (s, z) = (&self.s[k as usize], self.z[k as usize]);
                std::array::from_fn(|r| {
                    s[3 * r] * vi[0] + s[3 * r + 1] * vi[1] + s[3 * r + 2] * vi[2] + z[r]
                })
            }
        }
    }

    /// `v = S v` for component-major Vec3s data v.
    pub fn apply(&self, v: &mut [f64]) {
        let n = self.n;
        assert_eq!(v.len(), 3 * n);
        for (&i, s) in self.verts.iter().zip(&self.s) {
            let i = i as usize;
            let x = largestep_kernels::get3(v, n, i);
            for r in 0..3 {
                v[r * n + i] = s[3 * r] * x[0] + s[3 * r + 1] * x[1] + s[3 * r + 2] * x[2];
            }
        }
    }

    /// Projects a matrix in place: `A <- S A S + (I - S)` (see the module docs).
    pub fn project_matrix(&self, a: &mut Bsr3) {
        if self.is_empty() {
            return;
        }
        let pattern = a.pattern().clone();
        let (row_ptr, col) = (pattern.row_ptr(), pattern.col());
        for i in 0..pattern.n() {
            let si = self.index_of[i];
            let (start, end) = (row_ptr[i] as usize, row_ptr[i + 1] as usize);
            for (k, &j) in col.iter().enumerate().take(end).skip(start) {
                let sj = self.index_of[j as usize];
                if si == FREE && sj == FREE {
                    continue;
                }
                let b: [f64; 9] = a.block(k).try_into().expect("nine values");
                let mut m = b;
                if si != FREE {
                    m = mul3(&self.s[si as usize], &m);
                }
                if sj != FREE {
                    m = mul3(&m, &self.s[sj as usize]);
                }
                a.block_mut(k).copy_from_slice(&m);
            }
        }
        for (&i, s) in self.verts.iter().zip(&self.s) {
            let slot = pattern.diag_slots()[i as usize] as usize;
            let blk = a.block_mut(slot);
            for r in 0..3 {
                for c in 0..3 {
                    blk[3 * r + c] += if r == c { 1.0 } else { 0.0 } - s[3 * r + c];
                }
            }
        }
    }
}

fn unit(v: [f64; 3]) -> [f64; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    assert!(
        l > 0.0 && l.is_finite(),
        "constraint direction must be non-zero and finite"
    );
    [v[0] / l, v[1] / l, v[2] / l]
}

fn mul3(a: &[f64; 9], b: &[f64; 9]) -> [f64; 9] {
    let mut m = [0.0; 9];
    for r in 0..3 {
        for c in 0..3 {
            m[3 * r + c] = a[3 * r] * b[c] + a[3 * r + 1] * b[3 + c] + a[3 * r + 2] * b[6 + c];
        }
    }
    m
}
