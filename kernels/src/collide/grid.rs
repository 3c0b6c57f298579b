//! Uniform grids and spatial hashing (Teschner et al. 2003, "Optimized spatial hashing
//! for collision detection of deformable objects"), and sweep-and-prune.
//!
//! [`CellGrid`] files items (points or boxes) under the cells of a regular grid of cell
//! size `h`. The cells map to buckets either densely (a uniform grid over given bounds,
//! one bucket per cell) or by Teschner's hash `(73856093 i ^ 19349663 j ^ 83492791 k) mod
//! T` over unbounded space. Buckets are filled by a counting sort (two passes over the
//! items), so a rebuild allocates nothing once the arrays have grown. A bucket may hold
//! items of other cells (hash collisions); every answer is decided on the geometry, and
//! pair answers are reported once (see [`CellGrid::box_pairs`]).
//!
//! [`SweepAndPrune`] sorts boxes along one axis and sweeps, keeping the order between
//! calls: bodies move little per step, so the insertion sort that restores the order is
//! close to linear (Baraff 1992; Cohen et al. 1995, I-COLLIDE).

use super::bv::Aabb;
use wide::f64x4;

/// How cells map to buckets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Cells {
    /// A dense uniform grid: `dims` cells from `origin`; points outside clamp to the
    /// border cells.
    Dense {
        /// Lower corner (m).
        origin: [f64; 3],
        /// Cells per axis (each >= 1).
        dims: [u32; 3],
    },
    /// Spatial hashing into `buckets` buckets (>= 1; Teschner et al. take a prime about
    /// the item count).
    Hashed {
        /// Table size.
        buckets: u32,
    },
}

/// Items filed under grid cells (see the module docs).
#[derive(Clone, Debug)]
pub struct CellGrid {
    /// Cell size (m), > 0.
    pub h: f64,
    /// The cell-to-bucket map.
    pub cells: Cells,
    /// `start[b]..start[b + 1]` indexes `items` for bucket b.
    start: Vec<u32>,
    /// Item ids by bucket.
    items: Vec<u32>,
    /// Boxes filed (for box queries), by item id.
    boxes: Vec<Aabb>,
    /// Boxes covering more cells than there are buckets (hashing only): not filed, tested
    /// against every box instead, so no box costs more than the table.
    large: Vec<u32>,
    /// Item positions (for point queries), by item id, `[x, y, z]`.
    points: Vec<[f64; 3]>,
}

impl CellGrid {
    /// An empty grid with cell size `h` (> 0) and the given cell map.
    pub fn new(h: f64, cells: Cells) -> CellGrid {
        CellGrid {
            h,
            cells,
            start: Vec::new(),
            items: Vec::new(),
            boxes: Vec::new(),
            large: Vec::new(),
            points: Vec::new(),
        }
    }

    fn bucket_count(&self) -> usize {
        match self.cells {
            Cells::Dense { dims, .. } => dims.iter().map(|&d| d as usize).product(),
            Cells::Hashed { buckets } => buckets as usize,
        }
    }

    /// The integer cell of `p` (unclamped; saturating at the `i32` range).
    #[inline(always)]
    pub fn cell(&self, p: [f64; 3]) -> [i32; 3] {
        cell_in(self.cells, self.h, p)
    }

    /// The bucket of cell `c`.
    #[inline(always)]
    pub fn bucket(&self, c: [i32; 3]) -> usize {
        bucket_in(self.cells, c)
    }

    /// The cell range `[lo, hi]` a box covers, clamped for a dense grid (so a box far
    /// outside still visits a bounded number of cells).
    fn cell_range(&self, b: &Aabb) -> ([i32; 3], [i32; 3]) {
        range_in(self.cells, self.h, b)
    }

    /// Files points (component-major `x`, `3n` values): item i is point i.
    pub fn build_points(&mut self, x: &[f64]) {
        let n = x.len() / 3;
        assert_eq!(x.len(), 3 * n, "component-major points have length 3n");
        self.points.clear();
        self.points
            .extend((0..n).map(|i| [x[i], x[n + i], x[2 * n + i]]));
        self.boxes.clear();
        let (cells, h, buckets) = (self.cells, self.h, self.bucket_count());
        let points = &self.points;
        fill(&mut self.start, &mut self.items, buckets, n, |i, put| {
            put(bucket_in(cells, cell_in(cells, h, points[i])))
        });
    }

    /// Appends to `out` every point within `r` (m) of `p` (closed ball), each once, in
    /// bucket order. Scans the cells within `r` (`r` up to a cell size is the usual case);
    /// `buckets` is scratch, where the buckets of those cells are sorted so that a bucket
    /// reached from two cells (a hash collision, or clamping) is scanned once.
    pub fn points_within(&self, p: [f64; 3], r: f64, buckets: &mut Vec<u32>, out: &mut Vec<u32>) {
        // Also refuses a NaN radius.
        if self.points.is_empty() || r.partial_cmp(&0.0).is_none_or(|o| o.is_lt()) {
            return;
        }
        let (lo, hi) = self.cell_range(&Aabb {
            min: p.map(|c| c - r),
            max: p.map(|c| c + r),
        });
        buckets.clear();
        if cell_count(lo, hi) > self.bucket_count() as f64 {
            // More cells than buckets: every bucket, once.
            buckets.extend(0..self.bucket_count() as u32);
        } else {
            for_cells(lo, hi, |c| buckets.push(self.bucket(c) as u32));
            buckets.sort_unstable();
            buckets.dedup();
        }
        let r2 = r * r;
        for &b in buckets.iter() {
            let b = b as usize;
            for &id in &self.items[self.start[b] as usize..self.start[b + 1] as usize] {
                let q = self.points[id as usize];
                let d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
                if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= r2 {
                    out.push(id);
                }
            }
        }
    }

    /// Every pair of filed points within `r` (m) of each other, `[i, j]` with `i < j`,
    /// into `out` (cleared first): a [`CellGrid::points_within`] query around each point.
    /// `buckets` and `near` are scratch.
    pub fn point_pairs(
        &self,
        r: f64,
        buckets: &mut Vec<u32>,
        near: &mut Vec<u32>,
        out: &mut Vec<[u32; 2]>,
    ) {
        out.clear();
        for (i, p) in self.points.iter().enumerate() {
            near.clear();
            self.points_within(*p, r, buckets, near);
            out.extend(
                near.iter()
                    .filter(|&&j| j as usize > i)
                    .map(|&j| [i as u32, j]),
            );
        }
    }

    /// Files boxes: item i is `boxes[i]`, filed under every cell it overlaps. Empty boxes
    /// are not filed.
    pub fn build_boxes(&mut self, boxes: &[Aabb]) {
        self.boxes.clear();
        self.boxes.extend_from_slice(boxes);
        self.points.clear();
        self.large.clear();
        let buckets = self.bucket_count();
        for (i, b) in boxes.iter().enumerate() {
            if !b.is_empty() && self.is_large(b) {
                self.large.push(i as u32);
            }
        }
        let (cells, h, large) = (self.cells, self.h, &self.large);
        fill(
            &mut self.start,
            &mut self.items,
            buckets,
            boxes.len(),
            |i, put| {
                let b = &boxes[i];
                if b.is_empty() || large.binary_search(&(i as u32)).is_ok() {
                    return;
                }
                let (lo, hi) = range_in(cells, h, b);
                for_cells(lo, hi, |c| put(bucket_in(cells, c)));
            },
        );
    }

    /// Whether a box covers more cells than there are buckets (never, on a dense grid,
    /// whose ranges are clamped).
    fn is_large(&self, b: &Aabb) -> bool {
        let (lo, hi) = self.cell_range(b);
        matches!(self.cells, Cells::Hashed { .. })
            && cell_count(lo, hi) > self.bucket_count() as f64
    }

    /// Every pair of filed boxes that overlap (touching counts), `[i, j]` with `i < j`,
    /// into `out` (cleared first). A pair sharing several cells is reported in one: the
    /// cell holding the lower corner of the two boxes' intersection (clamped into the
    /// grid when dense). Large boxes (see `build_boxes`) are tested against every box.
    pub fn box_pairs(&self, out: &mut Vec<[u32; 2]>) {
        out.clear();
        for (i, bi) in self.boxes.iter().enumerate() {
            if bi.is_empty() || self.large.binary_search(&(i as u32)).is_ok() {
                continue;
            }
            let (lo, hi) = self.cell_range(bi);
            for_cells(lo, hi, |c| {
                let b = self.bucket(c);
                // A box filed under several cells of one bucket appears that many times,
                // adjacently (ids ascend within a bucket): once is enough.
                let mut prev = u32::MAX;
                for &j in &self.items[self.start[b] as usize..self.start[b + 1] as usize] {
                    if (j as usize) <= i || j == prev {
                        continue;
                    }
                    prev = j;
                    let bj = &self.boxes[j as usize];
                    if !bi.overlaps(bj) {
                        continue;
                    }
                    let corner = [0, 1, 2].map(|a| bi.min[a].max(bj.min[a]));
                    let (home, _) = self.cell_range(&Aabb::point(corner));
                    if home == c {
                        out.push([i as u32, j]);
                    }
                }
            });
        }
        for &l in &self.large {
            let bl = &self.boxes[l as usize];
            for (j, bj) in self.boxes.iter().enumerate() {
                let j = j as u32;
                // A pair of two large boxes once, from the smaller id.
                let both_large = self.large.binary_search(&j).is_ok();
                if j != l && !(both_large && j < l) && bl.overlaps(bj) {
                    out.push([l.min(j), l.max(j)]);
                }
            }
        }
    }
}

/// The integer cell of `p` under the map `cells` with cell size `h`.
#[inline(always)]
fn cell_in(cells: Cells, h: f64, p: [f64; 3]) -> [i32; 3] {
    let o = match cells {
        Cells::Dense { origin, .. } => origin,
        Cells::Hashed { .. } => [0.0; 3],
    };
    [0, 1, 2].map(|a| ((p[a] - o[a]) / h).floor() as i32)
}

/// The cell range of a box, clamped into a dense grid.
fn range_in(cells: Cells, h: f64, b: &Aabb) -> ([i32; 3], [i32; 3]) {
    let (mut lo, mut hi) = (cell_in(cells, h, b.min), cell_in(cells, h, b.max));
    if let Cells::Dense { dims, .. } = cells {
        for a in 0..3 {
            lo[a] = lo[a].clamp(0, dims[a] as i32 - 1);
            hi[a] = hi[a].clamp(0, dims[a] as i32 - 1);
        }
    }
    (lo, hi)
}

/// Files `n` items under buckets by a counting sort: `entries(i, put)` calls `put` with
/// each bucket item i goes under (possibly none, possibly several). Afterwards
/// `items[start[b]..start[b + 1]]` lists bucket b's items, ids ascending (an item filed
/// under one bucket twice appears twice, adjacently).
fn fill(
    start: &mut Vec<u32>,
    items: &mut Vec<u32>,
    buckets: usize,
    n: usize,
    entries: impl Fn(usize, &mut dyn FnMut(usize)),
) {
    start.clear();
    start.resize(buckets + 1, 0);
    let mut total = 0usize;
    for i in 0..n {
        entries(i, &mut |b| {
            start[b + 1] += 1;
            total += 1;
        });
    }
    for b in 0..buckets {
        start[b + 1] += start[b];
    }
    items.clear();
    items.resize(total, 0);
    // From the back of each bucket, items in reverse: ids ascend within a bucket.
    for i in (0..n).rev() {
        entries(i, &mut |b| {
            start[b + 1] -= 1;
            items[start[b + 1] as usize] = i as u32;
        });
    }
    // `start[b + 1]` now holds bucket b's start: shift back.
    start.rotate_left(1);
    start[buckets] = total as u32;
}

/// Number of cells in the inclusive range `[lo, hi]` (as `f64`: it may exceed `u64`).
fn cell_count(lo: [i32; 3], hi: [i32; 3]) -> f64 {
    (0..3)
        .map(|a| (hi[a] as f64 - lo[a] as f64 + 1.0).max(0.0))
        .product()
}

/// The bucket of cell `c` under the map `cells`: clamped dense index, or Teschner's hash.
#[inline(always)]
fn bucket_in(cells: Cells, c: [i32; 3]) -> usize {
    match cells {
        Cells::Dense { dims, .. } => {
            let k = |a: usize| c[a].clamp(0, dims[a] as i32 - 1) as usize;
            k(0) + dims[0] as usize * (k(1) + dims[1] as usize * k(2))
        }
        Cells::Hashed { buckets } => {
            let h = (c[0] as u32).wrapping_mul(73_856_093)
                ^ (c[1] as u32).wrapping_mul(19_349_663)
                ^ (c[2] as u32).wrapping_mul(83_492_791);
            (h % buckets) as usize
        }
    }
}

/// Calls `f` on every cell of the inclusive range `[lo, hi]`.
#[inline(always)]
fn for_cells(lo: [i32; 3], hi: [i32; 3], mut f: impl FnMut([i32; 3])) {
    for k in lo[2]..=hi[2] {
        for j in lo[1]..=hi[1] {
            for i in lo[0]..=hi[0] {
                f([i, j, k]);
            }
        }
    }
}

/// Sweep-and-prune over boxes, keeping the sorted order between calls (see the module
/// docs).
#[derive(Clone, Debug, Default)]
pub struct SweepAndPrune {
    /// Box ids sorted by their lower bound on `axis`.
    order: Vec<u32>,
    /// The lower bounds on `axis` in `order`'s order (the sort key).
    lower: Vec<f64>,
    /// The sweep axis of the last call.
    axis: usize,
    /// Per box in sweep order, its bounds on the two other axes `u`, `v` as four columns
    /// `[min u, -max u, min v, -max v]` (an empty box, or one with a NaN bound: all NaN,
    /// so it overlaps nothing): two boxes overlap on both axes when one's row is <= the
    /// other's [`against`]. `lower` and the columns run [`PAD`] NaN past the last box, so
    /// the sweep reads four candidates at a time without a bounds check at the end.
    cross: [Vec<f64>; 4],
}

/// Candidates the sweep tests at once: one `f64x4` comparison per bound for four boxes
/// instead of four for one (the scan was 9% of the 1,000-box pile's step at about 60
/// candidates a box).
const PAD: usize = 3;

/// Four values from `v[k..k + 4]`, without a bounds check (the sweep's inner loop reads
/// five columns a step; their checks and the column pointers they kept reloading were a
/// third of its instructions).
///
/// # Safety
/// `k + 4 <= v.len()`.
#[inline(always)]
unsafe fn four_unchecked(v: &[f64], k: usize) -> f64x4 {
    debug_assert!(k + 4 <= v.len());
    // SAFETY: the caller keeps k + 4 within v; `[f64; 4]` has f64's alignment.
    f64x4::new(unsafe { v.as_ptr().add(k).cast::<[f64; 4]>().read() })
}

/// Whether every bound is a number and no lower bound exceeds its upper one (the boxes
/// that can overlap another).
#[inline(always)]
fn proper(b: &Aabb) -> bool {
    (0..3).all(|a| b.min[a] <= b.max[a])
}

/// The row a box's `cross` rows are compared against: `[max u, -min u, max v, -min v]`.
#[inline(always)]
fn against(b: &Aabb, u: usize, v: usize) -> [f64; 4] {
    [b.max[u], -b.min[u], b.max[v], -b.min[v]]
}

impl SweepAndPrune {
    /// An empty sweep.
    pub fn new() -> SweepAndPrune {
        SweepAndPrune::default()
    }

    /// Every pair of overlapping boxes (touching counts), `[i, j]` with `i < j`, into
    /// `out` (cleared first). Sweeps the axis along which the box centres spread most;
    /// the order from the last call is restored by insertion sort (a new count or axis
    /// starts from the identity order). Empty boxes overlap nothing.
    pub fn pairs(&mut self, boxes: &[Aabb], out: &mut Vec<[u32; 2]>) {
        self.pairs_at_most(boxes, usize::MAX, out);
    }

    /// [`SweepAndPrune::pairs`], stopping once more than `max` pairs are found (so a
    /// pile of boxes inside one another cannot fill memory): returns whether all were
    /// found; when not, `out` holds `max + 1` of them.
    pub fn pairs_at_most(&mut self, boxes: &[Aabb], max: usize, out: &mut Vec<[u32; 2]>) -> bool {
        out.clear();
        let n = boxes.len();
        let axis = spread_axis(boxes);
        if self.order.len() != n || axis != self.axis {
            self.order.clear();
            self.order.extend(0..n as u32);
            self.axis = axis;
        }
        // Insertion sort of (key, id) side by side: linear when nearly sorted, and the
        // keys are read in order rather than from the boxes at random. `total_cmp`
        // orders NaN last.
        let (order, lower) = (&mut self.order, &mut self.lower);
        lower.clear();
        lower.extend(order.iter().map(|&i| boxes[i as usize].min[axis]));
        for s in 1..n {
            let (v, kv) = (order[s], lower[s]);
            let mut t = s;
            while t > 0 && lower[t - 1].total_cmp(&kv).is_gt() {
                order[t] = order[t - 1];
                lower[t] = lower[t - 1];
                t -= 1;
            }
            order[t] = v;
            lower[t] = kv;
        }
        // The other two axes' bounds copied into sweep order, so the scan below reads
        // memory in order and tests four candidates with one comparison per bound.
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for c in self.cross.iter_mut() {
            c.clear();
        }
        for &i in order.iter() {
            let b = &boxes[i as usize];
            let row = if proper(b) {
                [b.min[u], -b.max[u], b.min[v], -b.max[v]]
            } else {
                [f64::NAN; 4]
            };
            for (c, r) in self.cross.iter_mut().zip(row) {
                c.push(r);
            }
        }
        lower.extend([f64::NAN; PAD]);
        for c in self.cross.iter_mut() {
            c.extend([f64::NAN; PAD]);
        }
        // The five columns as slices of one length, n + PAD: every scan position k < n
        // reads k..k + 4 within them.
        let lower = &lower[..];
        let [c0, c1, c2, c3] = [0, 1, 2, 3].map(|c| &self.cross[c][..]);
        for c in [c0, c1, c2, c3] {
            assert_eq!(c.len(), lower.len());
        }
        assert_eq!(lower.len(), n + PAD);
        // Sweep: each box against the boxes after it in the order whose lower bound is
        // not past its upper bound (on `axis` they then overlap, as lower bounds rise).
        for s in 0..n {
            let i = order[s];
            let bi = &boxes[i as usize];
            if !proper(bi) {
                continue;
            }
            let hi = f64x4::splat(bi.max[axis]);
            let row = against(bi, u, v).map(f64x4::splat);
            // Room for every box after s, so the scan below stores its hits without a
            // call that could grow the list (around which the loop's constants went to
            // the stack and back each step).
            out.reserve(n - s);
            let start = out.len();
            let room = out.spare_capacity_mut();
            let mut found = 0;
            let mut k = s + 1;
            while k < n {
                // SAFETY: k < n and every column holds n + PAD = n + 3 values (asserted
                // above), so k + 4 is within each.
                let [l, x0, x1, x2, x3] =
                    [lower, c0, c1, c2, c3].map(|c| unsafe { four_unchecked(c, k) });
                // NaN bounds (improper boxes, the padding) sort last and end the scan.
                let reach = l.simd_le(hi);
                let hit = reach
                    & x0.simd_le(row[0])
                    & x1.simd_le(row[1])
                    & x2.simd_le(row[2])
                    & x3.simd_le(row[3]);
                let mut bits = hit.to_bitmask();
                while bits != 0 {
                    let j = order[k + bits.trailing_zeros() as usize];
                    room[found].write([i.min(j), i.max(j)]);
                    found += 1;
                    if start + found > max {
                        // SAFETY: the first `found` places of the spare room were written.
                        unsafe { out.set_len(start + found) };
                        return false;
                    }
                    bits &= bits - 1;
                }
                if !reach.all() {
                    break;
                }
                k += 4;
            }
            // SAFETY: the first `found` places of the spare room were written.
            unsafe { out.set_len(start + found) };
        }
        out.len() <= max
    }
}

/// The axis with the largest variance of box centres (0 for fewer than two boxes).
fn spread_axis(boxes: &[Aabb]) -> usize {
    let n = boxes.len() as f64;
    if boxes.len() < 2 {
        return 0;
    }
    let (mut s, mut s2) = ([0.0; 3], [0.0; 3]);
    for b in boxes.iter().filter(|b| !b.is_empty()) {
        let c = b.center();
        for a in 0..3 {
            s[a] += c[a];
            s2[a] += c[a] * c[a];
        }
    }
    let var = [0, 1, 2].map(|a| s2[a] / n - (s[a] / n) * (s[a] / n));
    (0..3).fold(0, |best, a| if var[a] > var[best] { a } else { best })
}
