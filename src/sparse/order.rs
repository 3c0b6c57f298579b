//! Fill-reducing orderings of a block pattern, for the sparse Cholesky.
//!
//! A [`Bsr3Pattern`] is the graph of a mesh's vertices; each vertex carries three
//! unknowns whose rows have the same pattern. Ordering that vertex graph and numbering
//! each vertex's three unknowns together ([`dof_permutation`]) gives faer's supernodal
//! factorization the same structure as ordering the scalar matrix, on a graph with a
//! ninth of the edges.
//!
//! [`nested_dissection`] is George's nested dissection with the level-structure
//! separators of George and Liu ("Computer Solution of Large Sparse Positive Definite
//! Systems", 1981, ch. 8): from a pseudo-peripheral vertex, breadth-first levels; the
//! vertices of a level that touch the next level separate the subgraph in two (of the
//! levels that leave each part at least a fifth, the one with the fewest such vertices);
//! the two parts are numbered first (recursively) and the separator last, so eliminating
//! one part never fills the other. Parts of at most [`LEAF`] vertices are numbered in
//! reverse Cuthill-McKee order. On a mesh this cuts along cross sections: on the
//! 36,663-unknown steel bar of the modal benchmark the factor needs 6.9e9 flops against
//! 1.06e10 with faer's minimum degree. It is not better everywhere (a short, stubby
//! lattice favours minimum degree), so the default, [`FillOrdering::Auto`], computes both
//! and keeps the one whose factor needs less work ([`factor_work`]). Deterministic: no
//! randomness, ties broken by vertex index.

use super::Bsr3Pattern;

/// Subgraphs of at most this many vertices are not dissected further.
pub const LEAF: usize = 16;

/// The smallest share of a subgraph each side of a separator keeps.
const BALANCE: f64 = 0.2;

/// The nested-dissection order of `pattern`'s vertex graph: `order[k]` is the vertex
/// numbered `k`. Runs in `O(E log n)` for a mesh with `E` block entries; allocates
/// four arrays of `n` entries.
pub fn nested_dissection(pattern: &Bsr3Pattern) -> Vec<u32> {
    let n = pattern.n();
    let mut g = Graph {
        row_ptr: pattern.row_ptr(),
        col: pattern.col(),
        stamp: vec![0; n],
        level: vec![0; n],
        queue: Vec::with_capacity(n),
        next_stamp: 0,
    };
    let mut order: Vec<u32> = (0..n as u32).collect();
    // Ranges of `order` still to be numbered; each holds one subgraph's vertices, and
    // their positions are the numbers they will get.
    let mut tasks = vec![(0usize, n)];
    while let Some((a, b)) = tasks.pop() {
        if b - a <= 1 {
            continue;
        }
        let s = g.own(&order[a..b]);
        // The search from the pseudo-peripheral vertex is left in `level` and `queue`.
        let levels = g.pseudo_peripheral(order[a], s);
        let reached = g.queue.len();
        if reached < b - a {
            // Not connected: every component found at once (peeling one per task would
            // take quadratic time on many small ones), each its own task.
            let (row_ptr, col) = (g.row_ptr, g.col);
            let mut out = g.queue.clone();
            let mut bounds = vec![a, a + reached];
            let mut stack = Vec::new();
            for &v in &order[a..b] {
                let v = v as usize;
                if g.level[v] != u32::MAX {
                    continue;
                }
                g.level[v] = 0;
                stack.push(v as u32);
                while let Some(u) = stack.pop() {
                    out.push(u);
                    let u = u as usize;
                    for &w in &col[row_ptr[u] as usize..row_ptr[u + 1] as usize] {
                        let w = w as usize;
                        if g.stamp[w] == s && g.level[w] == u32::MAX {
                            g.level[w] = 0;
                            stack.push(w as u32);
                        }
                    }
                }
                bounds.push(a + out.len());
            }
            order[a..b].copy_from_slice(&out);
            tasks.extend(bounds.windows(2).map(|w| (w[0], w[1])));
            continue;
        }
        if b - a <= LEAF || levels < 3 {
            // Reverse Cuthill-McKee: the breadth-first order from a pseudo-peripheral
            // vertex, reversed.
            for (k, &v) in g.queue.iter().rev().enumerate() {
                order[a + k] = v;
            }
            continue;
        }
        // Per vertex, whether it touches the next level; per level, its size and how
        // many of its vertices touch the next (the separator it would give). The
        // separator is the smallest one that leaves each part at least BALANCE of the
        // subgraph; ties go to the level nearest the median.
        let touch: Vec<bool> = g
            .queue
            .iter()
            .map(|&v| {
                let l = g.level[v as usize];
                g.neighbours(v)
                    .any(|w| g.stamp[w as usize] == s && g.level[w as usize] == l + 1)
            })
            .collect();
        let mut count = vec![0usize; levels as usize];
        let mut touching = vec![0usize; levels as usize];
        for (&v, &t) in g.queue.iter().zip(&touch) {
            let l = g.level[v as usize] as usize;
            count[l] += 1;
            touching[l] += usize::from(t);
        }
        let size = b - a;
        let mut best: Option<(usize, usize, u32)> = None;
        let mut below = 0;
        for l in 0..levels as usize {
            // Lower part: levels below l and level l's vertices outside the separator.
            let lower = below + count[l] - touching[l];
            let upper = size - below - count[l];
            below += count[l];
            if l == 0 || l + 1 >= levels as usize {
                continue;
            }
            let small = lower.min(upper);
            if (small as f64) < BALANCE * size as f64 {
                continue;
            }
            let key = (touching[l], lower.abs_diff(upper));
            if best.is_none_or(|(t, d, _)| key < (t, d)) {
                best = Some((key.0, key.1, l as u32));
            }
        }
        let mid = match best {
            Some((_, _, l)) => l,
            None => {
                // No balanced level: the median one.
                let (mut l, mut below) = (0, 0);
                while l + 1 < levels as usize && below + count[l] <= size / 2 {
                    below += count[l];
                    l += 1;
                }
                l.clamp(1, levels as usize - 2) as u32
            }
        };
        // Separator: the middle level's vertices with a neighbour in the next level.
        let (mut lower, mut upper, mut sep) = (Vec::new(), Vec::new(), Vec::new());
        for (&v, &t) in g.queue.iter().zip(&touch) {
            let l = g.level[v as usize];
            if l > mid {
                upper.push(v);
            } else if l == mid && t {
                sep.push(v);
            } else {
                lower.push(v);
            }
        }
        let (nl, nu) = (lower.len(), upper.len());
        order[a..a + nl].copy_from_slice(&lower);
        order[a + nl..a + nl + nu].copy_from_slice(&upper);
        order[a + nl + nu..b].copy_from_slice(&sep);
        tasks.push((a + nl, a + nl + nu));
        tasks.push((a, a + nl));
    }
    order
}

/// The scalar permutation that numbers each vertex's three unknowns together in the
/// vertex order `order` (`order[k]` the vertex numbered `k`), for the component-major
/// scalar numbering of the bridges (component `c` of vertex `v` is unknown `c n + v`):
/// `(forward, inverse)` with `forward[i]` the unknown numbered `i` and `inverse` its
/// inverse, as faer's `PermRef::new_checked` takes them.
pub fn dof_permutation(order: &[u32]) -> (Vec<usize>, Vec<usize>) {
    let n = order.len();
    let forward: Vec<usize> = order
        .iter()
        .flat_map(|&v| (0..3).map(move |c| c * n + v as usize))
        .collect();
    let mut inverse = vec![0; forward.len()];
    for (i, &f) in forward.iter().enumerate() {
        inverse[f] = i;
    }
    (forward, inverse)
}

/// The vertex graph and the breadth-first search's scratch.
struct Graph<'a> {
    row_ptr: &'a [u32],
    col: &'a [u32],
    /// The subgraph each vertex was last put in (`own`).
    stamp: Vec<u32>,
    /// Breadth-first level in the last search, `u32::MAX` where not reached.
    level: Vec<u32>,
    /// Vertices in the order the last search reached them.
    queue: Vec<u32>,
    next_stamp: u32,
}

impl Graph<'_> {
    fn neighbours(&self, v: u32) -> impl Iterator<Item = u32> + '_ {
        let v = v as usize;
        self.col[self.row_ptr[v] as usize..self.row_ptr[v + 1] as usize]
            .iter()
            .copied()
            .filter(move |&w| w as usize != v)
    }

    /// Marks `verts` as one new subgraph and returns its stamp.
    fn own(&mut self, verts: &[u32]) -> u32 {
        self.next_stamp += 1;
        for &v in verts {
            self.stamp[v as usize] = self.next_stamp;
            self.level[v as usize] = u32::MAX;
        }
        self.next_stamp
    }

    /// Breadth-first search from `root` within the subgraph `s`; returns the number of
    /// levels. Leaves `level` set on the reached vertices and `queue` in visiting order.
    fn bfs(&mut self, root: u32, s: u32) -> u32 {
        for &v in &self.queue {
            if self.stamp[v as usize] == s {
                self.level[v as usize] = u32::MAX;
            }
        }
        self.queue.clear();
        self.queue.push(root);
        self.level[root as usize] = 0;
        let mut head = 0;
        let mut levels = 1;
        while head < self.queue.len() {
            let v = self.queue[head];
            head += 1;
            let l = self.level[v as usize] + 1;
            let (p, q) = (
                self.row_ptr[v as usize] as usize,
                self.row_ptr[v as usize + 1] as usize,
            );
            for &w in &self.col[p..q] {
                let w = w as usize;
                if self.stamp[w] == s && self.level[w] == u32::MAX {
                    self.level[w] = l;
                    levels = levels.max(l + 1);
                    self.queue.push(w as u32);
                }
            }
        }
        levels
    }

    /// Degree of `v` within the subgraph `s`.
    fn degree(&self, v: u32, s: u32) -> usize {
        self.neighbours(v)
            .filter(|&w| self.stamp[w as usize] == s)
            .count()
    }

    /// The breadth-first search of `root`'s component of the subgraph `s` from a
    /// pseudo-peripheral vertex (George and Liu's algorithm: restart from a least-degree
    /// vertex of the last level while the number of levels grows), left in `level` and
    /// `queue`; returns its number of levels.
    fn pseudo_peripheral(&mut self, root: u32, s: u32) -> u32 {
        let mut root = root;
        let mut levels = self.bfs(root, s);
        for _ in 0..8 {
            let last = levels - 1;
            let candidate = self
                .queue
                .iter()
                .rev()
                .take_while(|&&v| self.level[v as usize] == last)
                .copied()
                .min_by_key(|&v| (self.degree(v, s), v))
                .unwrap_or(root);
            let l = self.bfs(candidate, s);
            if l < levels {
                // Leave the search from the chosen root in place.
                return self.bfs(root, s);
            }
            if l == levels {
                return l;
            }
            root = candidate;
            levels = l;
        }
        levels
    }
}

/// faer's approximate minimum degree (Amestoy, Davis and Duff 1996) on the vertex graph:
/// `order[k]` is the vertex numbered `k`.
pub fn vertex_amd(pattern: &Bsr3Pattern) -> Vec<u32> {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::sparse::linalg::amd;
    use faer::sparse::SymbolicSparseColMatRef;
    let n = pattern.n();
    // The pattern is structurally symmetric, so its rows are also its columns.
    let graph = SymbolicSparseColMatRef::new_checked(n, n, pattern.row_ptr(), None, pattern.col());
    let mut order = vec![0u32; n];
    let mut inverse = vec![0u32; n];
    let mut mem = MemBuffer::new(amd::order_maybe_unsorted_scratch::<u32>(
        n,
        pattern.col().len(),
    ));
    match amd::order_maybe_unsorted(
        &mut order,
        &mut inverse,
        graph,
        amd::Control::default(),
        MemStack::new(&mut mem),
    ) {
        Ok(_) => order,
        // Only for sizes past what the pattern's 32-bit indices allow: keep the identity.
        Err(_) => (0..n as u32).collect(),
    }
}

/// Which fill-reducing ordering a sparse Cholesky of a block matrix uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FillOrdering {
    /// faer's approximate minimum degree on the scalar matrix.
    ScalarAmd,
    /// Approximate minimum degree on the vertex graph ([`vertex_amd`]).
    VertexAmd,
    /// Nested dissection of the vertex graph ([`nested_dissection`]).
    NestedDissection,
    /// Whichever of [`FillOrdering::VertexAmd`] and [`FillOrdering::NestedDissection`]
    /// gives the factor less work, from the column counts of each ([`factor_work`]); the
    /// strategy of CHOLMOD (Chen, Davis, Hager and Rajamanickam 2008), which tries AMD
    /// and nested dissection and keeps the better.
    #[default]
    Auto,
}

impl FillOrdering {
    /// The vertex order for `pattern`, `None` for the scalar ordering.
    pub fn vertex_order(self, pattern: &Bsr3Pattern) -> Option<Vec<u32>> {
        match self {
            FillOrdering::ScalarAmd => None,
            FillOrdering::VertexAmd => Some(vertex_amd(pattern)),
            FillOrdering::NestedDissection => Some(nested_dissection(pattern)),
            FillOrdering::Auto => {
                let (amd, nd) = (vertex_amd(pattern), nested_dissection(pattern));
                if factor_work(pattern, &nd) < factor_work(pattern, &amd) {
                    Some(nd)
                } else {
                    Some(amd)
                }
            }
        }
    }
}

/// The work of a Cholesky factorization of `pattern`'s vertex graph numbered by `order`
/// (`order[k]` the vertex numbered `k`): `sum_j c_j^2` over the factor's column counts
/// `c_j`, from the elimination tree (faer's `prefactorize_symbolic_cholesky`, nearly
/// linear in the pattern's size). The scalar factor of the block matrix has three times
/// the counts, so this ranks orderings as the scalar flops would.
pub fn factor_work(pattern: &Bsr3Pattern, order: &[u32]) -> f64 {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::sparse::linalg::cholesky::simplicial;
    use faer::sparse::SymbolicSparseColMatRef;
    let n = pattern.n();
    let mut inverse = vec![0u32; n];
    for (k, &v) in order.iter().enumerate() {
        inverse[v as usize] = k as u32;
    }
    // The upper triangle of the renumbered graph, by columns.
    let (row_ptr, col) = (pattern.row_ptr(), pattern.col());
    let mut ptr = Vec::with_capacity(n + 1);
    let mut rows = Vec::with_capacity(col.len() / 2 + n);
    ptr.push(0u32);
    for &v in order {
        let j = inverse[v as usize];
        for &w in &col[row_ptr[v as usize] as usize..row_ptr[v as usize + 1] as usize] {
            let i = inverse[w as usize];
            if i <= j {
                rows.push(i);
            }
        }
        ptr.push(rows.len() as u32);
    }
    let upper = SymbolicSparseColMatRef::new_unsorted_checked(n, n, &ptr, None, &rows);
    let mut etree = vec![0i32; n];
    let mut counts = vec![0u32; n];
    let mut mem = MemBuffer::new(simplicial::prefactorize_symbolic_cholesky_scratch::<u32>(
        n,
        rows.len(),
    ));
    simplicial::prefactorize_symbolic_cholesky(
        &mut etree,
        &mut counts,
        upper,
        MemStack::new(&mut mem),
    );
    counts.iter().map(|&c| (c as f64) * (c as f64)).sum()
}
