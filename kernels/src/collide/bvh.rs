//! A bounding volume hierarchy of axis-aligned boxes, built top-down by the binned surface
//! area heuristic (Wald 2007, "On fast construction of SAH-based bounding volume
//! hierarchies"), refit after motion, and queried for box overlap, ray casts, closest
//! points, all overlapping pairs within one tree and pairs between two trees.
//!
//! Layout: nodes are 32-byte records with `f32` bounds rounded **outward** from the
//! primitives' `f64` boxes, so a node never misses what its primitives touch; the two
//! children of a node are adjacent and nodes are in depth-first order (a parent before
//! its children). Leaves hold up to [`Bvh::max_leaf`] primitives, whose exact `f64` boxes
//! are kept in leaf order: every pair or hit reported is decided on the exact boxes, so
//! the results equal brute force's (property tests in `tests/collide.rs`).
//!
//! Build: a node of at most [`Bvh::max_leaf`] primitives is a leaf (leaves of about one
//! primitive, where the SAH would stop, made the pair queries slower: see
//! `docs/benchmarks.md`); a larger one bins its centroids into [`BINS`] bins spanning its
//! bounds on all three axes at once, and the split with the least `A_L N_L + A_R N_R` wins. Subtrees of more than [`PAR_BUILD`] primitives
//! are built in parallel (`rayon::join`) into node ranges fixed by their sizes, then the
//! nodes are compacted into depth-first order, so the tree is the same with any number of
//! threads. The arrays are kept and reused by the next build: a rebuild of the same size
//! allocates nothing.
//!
//! Pairs: the self-overlap test descends (node, node) pairs from (root, root); a node
//! against itself splits into its children's self tests and the pair of children. The top
//! of that recursion is expanded into a fixed list of tasks (at most [`PAIR_TASKS`]), run
//! in parallel, each into its own buffer; the buffers are joined in task order, so the
//! pair list is the same with any number of threads.

use super::bv::Aabb;
use wide::f32x4;

/// Bins per axis of the binned SAH.
pub const BINS: usize = 16;
const _: () = assert!(BINS <= 16, "bins are packed in 4 bits");

/// Subtrees with more primitives than this are built in parallel.
pub const PAR_BUILD: usize = 4096;

/// The most top-level tasks the pair queries are cut into.
pub const PAIR_TASKS: usize = 128;

/// A node: bounds in `f32` rounded outward; a leaf (`count > 0`) holds primitives
/// `first .. first + count` in leaf order, an inner node (`count == 0`) has children
/// `first` and `first + 1`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(32))]
pub struct Node {
    /// Lower corner.
    pub min: [f32; 3],
    /// Primitive count, 0 for an inner node.
    pub count: u32,
    /// Upper corner.
    pub max: [f32; 3],
    /// First primitive (leaf) or first child (inner).
    pub first: u32,
}

impl Node {
    #[inline(always)]
    fn overlaps(&self, o: &Node) -> bool {
        // Two 4-lane compares (the fourth lane, the count or child index, is masked out)
        // and no branch until the end: a traversal's outcomes are close to random.
        let lo = f32x4::new([self.min[0], self.min[1], self.min[2], 0.0]);
        let hi = f32x4::new([self.max[0], self.max[1], self.max[2], 0.0]);
        let olo = f32x4::new([o.min[0], o.min[1], o.min[2], 0.0]);
        let ohi = f32x4::new([o.max[0], o.max[1], o.max[2], 0.0]);
        (lo.simd_le(ohi) & olo.simd_le(hi)).to_bitmask() & 7 == 7
    }

    /// The bounds as an `f64` box (exact: every `f32` is an `f64`).
    #[inline(always)]
    pub fn aabb(&self) -> Aabb {
        Aabb {
            min: self.min.map(f64::from),
            max: self.max.map(f64::from),
        }
    }

    #[inline(always)]
    fn area(&self) -> f32 {
        let d = [0, 1, 2].map(|a| (self.max[a] - self.min[a]).max(0.0));
        2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0])
    }

    /// Whether the node is a leaf.
    #[inline(always)]
    pub fn is_leaf(&self) -> bool {
        self.count > 0
    }
}

/// The largest `f32` at or below `x` (`-inf` below the `f32` range, NaN stays NaN).
#[inline]
pub fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) <= x || f.is_nan() {
        f
    } else {
        step_f32(f, false)
    }
}

/// The smallest `f32` at or above `x`.
#[inline]
pub fn f32_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) >= x || f.is_nan() {
        f
    } else {
        step_f32(f, true)
    }
}

/// The next `f32` after finite-or-infinite `f` towards `+inf` (`up`) or `-inf`.
fn step_f32(f: f32, up: bool) -> f32 {
    if f == 0.0 {
        let tiny = f32::from_bits(1);
        return if up { tiny } else { -tiny };
    }
    let bits = f.to_bits();
    // Away from zero is +1 on the magnitude bits.
    let away = (f > 0.0) == up;
    if f.is_infinite() && away {
        return f;
    }
    f32::from_bits(if away { bits + 1 } else { bits - 1 })
}

/// A primitive during the build: its outward-rounded box and its id.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(32))]
struct Rec {
    min: [f32; 3],
    id: u32,
    max: [f32; 3],
    /// The record's bins on the three axes (4 bits each), written by the binning pass
    /// for the partition that follows it.
    bins: u32,
}

impl Rec {
    #[inline(always)]
    fn centroid(&self, a: usize) -> f32 {
        0.5 * (self.min[a] + self.max[a])
    }
}

/// An empty node bound (the union identity).
const EMPTY: Node = Node {
    min: [f32::INFINITY; 3],
    count: 0,
    max: [f32::NEG_INFINITY; 3],
    first: 0,
};

/// Grows `n` to hold the box `[min, max]`. Compares instead of `f32::min`/`max`, whose
/// NaN handling costs extra instructions; bounds are never NaN (a precondition of the
/// build).
#[inline(always)]
fn grow(n: &mut Node, min: &[f32; 3], max: &[f32; 3]) {
    for a in 0..3 {
        n.min[a] = if min[a] < n.min[a] { min[a] } else { n.min[a] };
        n.max[a] = if max[a] > n.max[a] { max[a] } else { n.max[a] };
    }
}

/// What [`Bvh::update`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Updated {
    /// The bounds were refit; the topology is unchanged.
    Refit,
    /// The tree's SAH cost had grown past the policy's factor: it was rebuilt.
    Rebuilt,
}

/// A bounding volume hierarchy over n primitives with ids `0..n` (see the module docs).
#[derive(Clone, Debug)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// Primitive id of each leaf slot.
    ids: Vec<u32>,
    /// Exact box of each leaf slot.
    boxes: Vec<Aabb>,
    /// Each leaf slot's box rounded outward to `f32` (`first` unused): the pair tests'
    /// first check, half the bytes of the exact boxes; only its hits are decided exactly.
    fboxes: Vec<Node>,
    /// The SAH cost of the tree as built (see [`Bvh::sah_cost`]).
    built_cost: f64,
    recs: Vec<Rec>,
    raw: Vec<Node>,
    stack: Vec<u32>,
    /// Most primitives in a leaf (>= 1).
    pub max_leaf: usize,
    /// [`Bvh::update`] rebuilds when the refit tree's SAH cost exceeds this times the
    /// cost it had when built (> 1).
    pub rebuild_factor: f64,
}

impl Default for Bvh {
    fn default() -> Self {
        Bvh::new()
    }
}

/// Scratch for the pair queries, kept between calls so they allocate nothing once warm.
#[derive(Clone, Debug, Default)]
pub struct PairWork {
    tasks: Vec<(u32, u32)>,
    next: Vec<(u32, u32)>,
    lanes: Vec<Lane>,
}

#[derive(Clone, Debug, Default)]
struct Lane {
    out: Vec<[u32; 2]>,
    stack: Vec<(u32, u32)>,
    visits: usize,
}

impl PairWork {
    /// The (node, node) pairs the last query visited: its work, for benchmarks.
    pub fn visits(&self) -> usize {
        self.lanes.iter().map(|l| l.visits).sum()
    }
}

impl Bvh {
    /// An empty tree with leaves of up to 4 primitives and a rebuild factor of 1.5.
    pub fn new() -> Bvh {
        Bvh {
            nodes: Vec::new(),
            ids: Vec::new(),
            boxes: Vec::new(),
            fboxes: Vec::new(),
            built_cost: 0.0,
            recs: Vec::new(),
            raw: Vec::new(),
            stack: Vec::new(),
            max_leaf: 4,
            rebuild_factor: 1.5,
        }
    }

    /// A tree over `boxes` (primitive i is `boxes[i]`).
    pub fn from_boxes(boxes: &[Aabb]) -> Bvh {
        let mut b = Bvh::new();
        b.build(boxes);
        b
    }

    /// The nodes, root first (empty for no primitives).
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    /// The primitive id of each leaf slot.
    pub fn leaf_ids(&self) -> &[u32] {
        &self.ids
    }

    /// Number of primitives.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// Whether the tree holds no primitive.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// The root's bounds (`Aabb::EMPTY` for no primitives).
    pub fn bounds(&self) -> Aabb {
        self.nodes.first().map_or(Aabb::EMPTY, Node::aabb)
    }

    /// Builds the tree over `boxes`, reusing this tree's arrays. Preconditions: fewer than
    /// 2^31 boxes, none with a NaN coordinate (the domain layer checks and names them);
    /// empty boxes are kept and never overlap anything.
    pub fn build(&mut self, boxes: &[Aabb]) {
        let n = boxes.len();
        assert!(n < (1 << 31), "a BVH holds fewer than 2^31 primitives");
        self.nodes.clear();
        self.ids.clear();
        self.boxes.clear();
        self.fboxes.clear();
        self.built_cost = 0.0;
        if n == 0 {
            return;
        }
        self.recs.clear();
        self.recs.extend(boxes.iter().enumerate().map(|(i, b)| Rec {
            min: b.min.map(f32_down),
            id: i as u32,
            max: b.max.map(f32_up),
            bins: 0,
        }));
        self.raw.clear();
        self.raw.resize(2 * n - 1, Node::default());
        let mut root = EMPTY;
        for r in &self.recs {
            grow(&mut root, &r.min, &r.max);
        }
        let (head, desc) = self.raw.split_at_mut(1);
        head[0] = root;
        build_node(
            &mut self.recs,
            0,
            &mut head[0],
            desc,
            1,
            self.max_leaf.max(1),
        );
        // Depth-first compaction: a pair of children goes right after the pair holding
        // their parent's left sibling subtree.
        self.nodes.push(self.raw[0]);
        self.stack.clear();
        self.stack.push(0);
        while let Some(i) = self.stack.pop() {
            let node = self.nodes[i as usize];
            if !node.is_leaf() {
                let c = self.nodes.len() as u32;
                self.nodes.push(self.raw[node.first as usize]);
                self.nodes.push(self.raw[node.first as usize + 1]);
                self.nodes[i as usize].first = c;
                self.stack.push(c + 1);
                self.stack.push(c);
            }
        }
        self.ids.extend(self.recs.iter().map(|r| r.id));
        self.boxes
            .extend(self.ids.iter().map(|&i| boxes[i as usize]));
        self.fboxes.extend(self.recs.iter().map(|r| Node {
            min: r.min,
            count: 0,
            max: r.max,
            first: 0,
        }));
        self.built_cost = self.sah_cost();
    }

    /// Recomputes every node's bounds from `boxes` (the same primitives, moved), keeping
    /// the topology: O(n), the answer to small motion. Panics when the count changed.
    pub fn refit(&mut self, boxes: &[Aabb]) {
        assert_eq!(
            boxes.len(),
            self.ids.len(),
            "refit keeps the primitive count"
        );
        for ((slot, f), &id) in self.boxes.iter_mut().zip(&mut self.fboxes).zip(&self.ids) {
            *slot = boxes[id as usize];
            f.min = slot.min.map(f32_down);
            f.max = slot.max.map(f32_up);
        }
        for i in (0..self.nodes.len()).rev() {
            let node = self.nodes[i];
            let mut b = EMPTY;
            if node.is_leaf() {
                for p in &self.fboxes[node.first as usize..(node.first + node.count) as usize] {
                    grow(&mut b, &p.min, &p.max);
                }
            } else {
                let (l, r) = (
                    self.nodes[node.first as usize],
                    self.nodes[node.first as usize + 1],
                );
                grow(&mut b, &l.min, &l.max);
                grow(&mut b, &r.min, &r.max);
            }
            self.nodes[i].min = b.min;
            self.nodes[i].max = b.max;
        }
    }

    /// The rebuild policy: refit, then rebuild when the SAH cost grew past
    /// `rebuild_factor` times the cost at the last build (Lauterbach et al. 2006 use the
    /// same test), or when the count changed.
    pub fn update(&mut self, boxes: &[Aabb]) -> Updated {
        if boxes.len() != self.ids.len() {
            self.build(boxes);
            return Updated::Rebuilt;
        }
        self.refit(boxes);
        if self.sah_cost() > self.rebuild_factor * self.built_cost {
            self.build(boxes);
            Updated::Rebuilt
        } else {
            Updated::Refit
        }
    }

    /// The tree's SAH cost: the sum over nodes of area times (1 for an inner node's
    /// traversal, the count for a leaf), over the root's area; the expected work of a
    /// random ray, comparable between trees over the same primitives.
    pub fn sah_cost(&self) -> f64 {
        let Some(root) = self.nodes.first() else {
            return 0.0;
        };
        let ra = root.area() as f64;
        if ra <= 0.0 {
            return self.nodes.len() as f64;
        }
        let sum: f64 = self
            .nodes
            .iter()
            .map(|n| n.area() as f64 * if n.is_leaf() { n.count as f64 } else { 1.0 })
            .sum();
        sum / ra
    }

    /// Appends to `out` the id of every primitive whose box overlaps `q` (touching
    /// counts), in tree order. `stack` is scratch.
    pub fn overlapping(&self, q: &Aabb, stack: &mut Vec<u32>, out: &mut Vec<u32>) {
        if self.nodes.is_empty() || q.is_empty() {
            return;
        }
        let qn = Node {
            min: q.min.map(f32_down),
            count: 0,
            max: q.max.map(f32_up),
            first: 0,
        };
        stack.clear();
        stack.push(0);
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i as usize];
            if !node.overlaps(&qn) {
                continue;
            }
            if node.is_leaf() {
                let r = node.first as usize..(node.first + node.count) as usize;
                for (b, &id) in self.boxes[r.clone()].iter().zip(&self.ids[r]) {
                    if b.overlaps(q) {
                        out.push(id);
                    }
                }
            } else {
                stack.push(node.first + 1);
                stack.push(node.first);
            }
        }
    }

    /// The nearest hit of the ray `origin + t dir`, `0 <= t <= t_max`: `hit(id, t_best)`
    /// intersects primitive `id` and returns its parameter when below `t_best`. Nodes are
    /// visited near child first and skipped when they start beyond the best hit. Returns
    /// `(id, t)`. `stack` is scratch.
    pub fn ray(
        &self,
        origin: [f64; 3],
        dir: [f64; 3],
        t_max: f64,
        stack: &mut Vec<(u32, f64)>,
        hit: impl FnMut(u32, f64) -> Option<f64>,
    ) -> Option<(u32, f64)> {
        let inv = dir.map(|d| 1.0 / d);
        self.best_first(
            t_max,
            stack,
            |b, best| b.ray(origin, inv, best).map(|t| t.0),
            hit,
        )
    }

    /// The primitive nearest `p` within `max_dist` (m): `dist2(id, best2)` returns the
    /// squared distance from `p` to primitive `id` (it may return any value `>= best2` when
    /// it can tell the primitive is no nearer). Branch and bound on the nodes' box
    /// distances, near child first. Returns `(id, squared distance)`. `stack` is scratch.
    pub fn closest(
        &self,
        p: [f64; 3],
        max_dist: f64,
        stack: &mut Vec<(u32, f64)>,
        mut dist2: impl FnMut(u32, f64) -> f64,
    ) -> Option<(u32, f64)> {
        let bound = |b: &Aabb, best: f64| Some(b.distance_squared(p)).filter(|d| *d <= best);
        self.best_first(max_dist * max_dist, stack, bound, |id, best| {
            Some(dist2(id, best))
        })
    }

    /// Branch and bound, near child first: `bound(box, best)` is a lower bound of the key
    /// of anything in the box, `None` when it cannot beat `best`; `eval(id, best)` is a
    /// primitive's key. Returns the primitive of least key at most `start`, with its key.
    fn best_first(
        &self,
        start: f64,
        stack: &mut Vec<(u32, f64)>,
        bound: impl Fn(&Aabb, f64) -> Option<f64>,
        mut eval: impl FnMut(u32, f64) -> Option<f64>,
    ) -> Option<(u32, f64)> {
        let mut best: Option<(u32, f64)> = None;
        let mut key = start;
        let root = self.nodes.first()?;
        stack.clear();
        stack.push((0, bound(&root.aabb(), key)?));
        while let Some((i, lower)) = stack.pop() {
            if lower > key {
                continue;
            }
            let node = &self.nodes[i as usize];
            if node.is_leaf() {
                let r = node.first as usize..(node.first + node.count) as usize;
                for (b, &id) in self.boxes[r.clone()].iter().zip(&self.ids[r]) {
                    if bound(b, key).is_some() {
                        if let Some(k) = eval(id, key).filter(|k| *k <= key) {
                            key = k;
                            best = Some((id, k));
                        }
                    }
                }
                continue;
            }
            let (l, r) = (node.first, node.first + 1);
            let kl = bound(&self.nodes[l as usize].aabb(), key);
            let kr = bound(&self.nodes[r as usize].aabb(), key);
            // The far child first onto the stack, so the near one pops first.
            match (kl, kr) {
                (Some(a), Some(b)) if a <= b => stack.extend([(r, b), (l, a)]),
                (Some(a), Some(b)) => stack.extend([(l, a), (r, b)]),
                (Some(a), None) => stack.push((l, a)),
                (None, Some(b)) => stack.push((r, b)),
                (None, None) => {}
            }
        }
        best
    }

    /// Every pair of primitives whose boxes overlap (touching counts), each once as
    /// `[i, j]` with `i < j`, into `out` (cleared first). Deterministic order (see the
    /// module docs); parallel over up to [`PAIR_TASKS`] tasks.
    pub fn self_pairs(&self, work: &mut PairWork, out: &mut Vec<[u32; 2]>) {
        out.clear();
        if self.nodes.is_empty() {
            return;
        }
        pairs(self, self, true, work, out);
    }

    /// Every pair `[i, j]` of a primitive `i` of `self` and `j` of `other` whose boxes
    /// overlap, into `out` (cleared first). Deterministic order; parallel.
    pub fn pairs_with(&self, other: &Bvh, work: &mut PairWork, out: &mut Vec<[u32; 2]>) {
        out.clear();
        if self.nodes.is_empty() || other.nodes.is_empty() {
            return;
        }
        pairs(self, other, false, work, out);
    }
}

/// Builds the subtree of `recs` (global leaf offset `offset`) under `node`, whose bounds
/// are set; `desc` (global index `base`) holds at least `2 (recs.len() - 1)` nodes for its
/// descendants.
fn build_node(
    recs: &mut [Rec],
    offset: u32,
    node: &mut Node,
    desc: &mut [Node],
    base: u32,
    max_leaf: usize,
) {
    let m = recs.len();
    if m <= max_leaf {
        node.first = offset;
        node.count = m as u32;
        return;
    }
    // Bins span the node's bounds rather than its centroids' (Wald 2007 bins centroids):
    // one pass fewer per node, and for boxes small against their node the same bins.
    let cmin = node.min;
    let extent = [0, 1, 2].map(|a| node.max[a] - node.min[a]);
    let split = best_split(recs, &cmin, &extent, m);
    let (mid, bounds) = match split {
        Some(Split {
            axis,
            bin,
            left,
            right,
        }) => {
            let mid = partition(recs, |r| ((r.bins >> (4 * axis)) & 15) < bin as u32);
            (mid, Some((left, right)))
        }
        // No bin boundary separates the centroids: halves in order.
        None => (m / 2, None),
    };
    split_at(recs, offset, node, desc, base, max_leaf, mid, bounds)
}

/// Splits `recs` at `mid` into two children (slots `desc[0]`, `desc[1]`) with the given
/// bounds (or their own, computed here) and builds them.
#[allow(clippy::too_many_arguments)]
fn split_at(
    recs: &mut [Rec],
    offset: u32,
    node: &mut Node,
    desc: &mut [Node],
    base: u32,
    max_leaf: usize,
    mid: usize,
    bounds: Option<(Node, Node)>,
) {
    let m = recs.len();
    let (lr, rr) = recs.split_at_mut(mid);
    let (lb, rb) = bounds.unwrap_or_else(|| {
        let (mut lb, mut rb) = (EMPTY, EMPTY);
        for r in lr.iter() {
            grow(&mut lb, &r.min, &r.max);
        }
        for r in rr.iter() {
            grow(&mut rb, &r.min, &r.max);
        }
        (lb, rb)
    });
    node.first = base;
    node.count = 0;
    let (pair, rest) = desc.split_at_mut(2);
    let (lslot, rslot) = pair.split_at_mut(1);
    lslot[0] = lb;
    rslot[0] = rb;
    let (ldesc, rdesc) = rest.split_at_mut(2 * (mid - 1));
    let (lbase, rbase) = (base + 2, base + 2 + 2 * (mid as u32 - 1));
    let roff = offset + mid as u32;
    if m > PAR_BUILD {
        rayon::join(
            || build_node(lr, offset, &mut lslot[0], ldesc, lbase, max_leaf),
            || build_node(rr, roff, &mut rslot[0], rdesc, rbase, max_leaf),
        );
    } else {
        build_node(lr, offset, &mut lslot[0], ldesc, lbase, max_leaf);
        build_node(rr, roff, &mut rslot[0], rdesc, rbase, max_leaf);
    }
}

/// A chosen split: the axis, the first bin on the right, and the two sides' bounds.
struct Split {
    axis: usize,
    bin: usize,
    left: Node,
    right: Node,
}

/// `BINS / extent`, shrunk a little so the largest centroid lands in the last bin.
#[inline(always)]
fn bin_scale(extent: f32) -> f32 {
    if extent > 0.0 {
        BINS as f32 * (1.0 - 1e-6) / extent
    } else {
        0.0
    }
}

#[inline(always)]
fn bin_of(c: f32, lo: f32, scale: f32) -> usize {
    (((c - lo) * scale) as usize).min(BINS - 1)
}

/// The best split by the binned SAH (least `A_L N_L + A_R N_R`), or `None` when no bin
/// boundary separates the centroids.
fn best_split(recs: &mut [Rec], cmin: &[f32; 3], extent: &[f32; 3], m: usize) -> Option<Split> {
    let mut bounds = [[EMPTY; BINS]; 3];
    let mut counts = [[0u32; BINS]; 3];
    let scale = extent.map(bin_scale);
    for r in recs.iter_mut() {
        let mut bins = 0;
        for a in 0..3 {
            let b = bin_of(r.centroid(a), cmin[a], scale[a]);
            counts[a][b] += 1;
            grow(&mut bounds[a][b], &r.min, &r.max);
            bins |= (b as u32) << (4 * a);
        }
        r.bins = bins;
    }
    let mut best: Option<(f32, Split)> = None;
    for a in 0..3 {
        // Also skips a NaN extent.
        if extent[a].partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            continue;
        }
        // Right-to-left sweep: the bounds and counts of the right side of each split.
        let mut right = [EMPTY; BINS];
        let mut right_n = [0u32; BINS];
        let (mut rb, mut rn) = (EMPTY, 0u32);
        for b in (1..BINS).rev() {
            grow(&mut rb, &bounds[a][b].min, &bounds[a][b].max);
            rn += counts[a][b];
            right[b] = rb;
            right_n[b] = rn;
        }
        let (mut lb, mut ln) = (EMPTY, 0u32);
        for b in 1..BINS {
            grow(&mut lb, &bounds[a][b - 1].min, &bounds[a][b - 1].max);
            ln += counts[a][b - 1];
            if ln == 0 || ln as usize == m {
                continue;
            }
            let cost = lb.area() * ln as f32 + right[b].area() * right_n[b] as f32;
            if best.as_ref().is_none_or(|(c, _)| cost < *c) {
                best = Some((
                    cost,
                    Split {
                        axis: a,
                        bin: b,
                        left: lb,
                        right: right[b],
                    },
                ));
            }
        }
    }
    best.map(|(_, split)| split)
}

/// Reorders `recs` so those where `left` holds come first; returns their count.
fn partition(recs: &mut [Rec], left: impl Fn(&Rec) -> bool) -> usize {
    let (mut i, mut j) = (0, recs.len());
    loop {
        while i < j && left(&recs[i]) {
            i += 1;
        }
        while i < j && !left(&recs[j - 1]) {
            j -= 1;
        }
        if i >= j {
            return i;
        }
        recs.swap(i, j - 1);
        i += 1;
        j -= 1;
    }
}

/// The pair queries' driver: expands the top of the (node, node) recursion into at most
/// [`PAIR_TASKS`] tasks, runs them in parallel into per-task buffers, joins in order.
fn pairs(a: &Bvh, b: &Bvh, same: bool, work: &mut PairWork, out: &mut Vec<[u32; 2]>) {
    let PairWork { tasks, next, lanes } = work;
    tasks.clear();
    if same || a.nodes[0].overlaps(&b.nodes[0]) {
        tasks.push((0, 0));
    }
    // Breadth-first expansion while some task can still be split and the list stays
    // within the bound.
    loop {
        let splittable = tasks
            .iter()
            .any(|&(i, j)| !(a.nodes[i as usize].is_leaf() && b.nodes[j as usize].is_leaf()));
        if !splittable {
            break;
        }
        let mut top = 0;
        for &(i, j) in tasks.iter() {
            top = expand(a, b, same, i, j, next, top);
        }
        if top > PAIR_TASKS {
            break;
        }
        next.truncate(top);
        std::mem::swap(tasks, next);
    }
    if lanes.len() < tasks.len() {
        lanes.resize_with(tasks.len(), Lane::default);
    }
    use rayon::prelude::*;
    for lane in lanes.iter_mut() {
        lane.visits = 0;
    }
    lanes[..tasks.len()]
        .par_iter_mut()
        .zip(tasks.par_iter())
        .for_each(|(lane, &task)| {
            lane.out.clear();
            descend(a, b, same, task, lane);
        });
    for lane in &lanes[..tasks.len()] {
        out.extend_from_slice(&lane.out);
    }
}

/// One level of the recursion from `(i, j)`: writes the overlapping child pairs, or the
/// pair itself when it is a pair of leaves (or a self leaf), at `buf[top..]`, and returns
/// the new top. The writes are unconditional and the top advances by the test's outcome:
/// a branch on the node tests (about even odds) would be mispredicted half the time.
#[inline(always)]
fn expand(
    a: &Bvh,
    b: &Bvh,
    same: bool,
    i: u32,
    j: u32,
    buf: &mut Vec<(u32, u32)>,
    top: usize,
) -> usize {
    if buf.len() < top + 4 {
        buf.resize(2 * buf.len() + 16, (0, 0));
    }
    let slots = &mut buf[top..top + 4];
    let (ni, nj) = (&a.nodes[i as usize], &b.nodes[j as usize]);
    if same && i == j {
        if ni.is_leaf() {
            slots[0] = (i, j);
            return top + 1;
        }
        let (l, r) = (ni.first, ni.first + 1);
        slots[0] = (l, l);
        slots[1] = (r, r);
        slots[2] = (l, r);
        return top + 2 + a.nodes[l as usize].overlaps(&a.nodes[r as usize]) as usize;
    }
    let mut k = 0;
    match (ni.is_leaf(), nj.is_leaf()) {
        (true, true) => {
            slots[0] = (i, j);
            k = 1;
        }
        (false, true) => {
            for c in [ni.first, ni.first + 1] {
                slots[k] = (c, j);
                k += a.nodes[c as usize].overlaps(nj) as usize;
            }
        }
        (true, false) => {
            for c in [nj.first, nj.first + 1] {
                slots[k] = (i, c);
                k += ni.overlaps(&b.nodes[c as usize]) as usize;
            }
        }
        (false, false) => {
            for ci in [ni.first, ni.first + 1] {
                let nci = &a.nodes[ci as usize];
                for cj in [nj.first, nj.first + 1] {
                    slots[k] = (ci, cj);
                    k += nci.overlaps(&b.nodes[cj as usize]) as usize;
                }
            }
        }
    }
    top + k
}

/// Runs the recursion from `task` to the leaves, pairs into `lane.out`.
fn descend(a: &Bvh, b: &Bvh, same: bool, task: (u32, u32), lane: &mut Lane) {
    let Lane { out, stack, visits } = lane;
    let mut top = expand(a, b, same, task.0, task.1, stack, 0);
    // `expand` returns the task itself when it is terminal.
    while top > 0 {
        top -= 1;
        *visits += 1;
        let (i, j) = stack[top];
        let (ni, nj) = (&a.nodes[i as usize], &b.nodes[j as usize]);
        if ni.is_leaf() && nj.is_leaf() {
            leaf_pairs(a, b, same, same && i == j, ni, nj, out);
        } else {
            top = expand(a, b, same, i, j, stack, top);
        }
    }
}

/// The exact tests between two leaves (or within one leaf when `within`); pairs within
/// one tree (`same`) are written smaller id first.
#[inline]
fn leaf_pairs(
    a: &Bvh,
    b: &Bvh,
    same: bool,
    within: bool,
    ni: &Node,
    nj: &Node,
    out: &mut Vec<[u32; 2]>,
) {
    let ri = ni.first as usize..(ni.first + ni.count) as usize;
    let rj = nj.first as usize..(nj.first + nj.count) as usize;
    for i in ri {
        let fi = &a.fboxes[i];
        let j0 = if within { i + 1 } else { rj.start };
        for j in j0..rj.end {
            if fi.overlaps(&b.fboxes[j]) && a.boxes[i].overlaps(&b.boxes[j]) {
                let (ii, jj) = (a.ids[i], b.ids[j]);
                out.push(if same {
                    [ii.min(jj), ii.max(jj)]
                } else {
                    [ii, jj]
                });
            }
        }
    }
}
