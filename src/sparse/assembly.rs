//! Element assembly into Bsr3 matrices and Vec3s vectors by precomputed gathers.
//!
//! An element kernel writes, per element, a few *unique* 3x3 blocks and 3-vectors into an
//! element-major buffer (`(e * blocks + b) * 9 + 3 r + c`, `(e * vectors + u) * 3 + c`).
//! A [`LocalLayout`] says how the element's K x K local blocks and K local vectors derive
//! from those (a spring has one block J and the local matrix `[[J, -J], [-J, J]]`; its
//! force on B is minus its force on A).
//!
//! [`ElementAssembly`] is built once from the connectivity: the element -> slot scatter map
//! (`elem_slots`), and its inverse, a CSR list of sources for every matrix slot and every
//! vertex, in element order. Assembly is then a gather: each slot (each vertex) sums its
//! sources in that fixed order. Slots are disjoint, so the gather runs in parallel with no
//! atomics and no colouring, and the sums are bitwise the same for any thread count (and
//! the same as a serial element-by-element scatter).

use super::{Bsr3, Bsr3Pattern, SparseError};
use largestep_kernels::par::{chunk_count, chunk_range, par_reduce, Disjoint};
use largestep_kernels::sparse::BlockValue;
use rayon::prelude::*;
use std::sync::Arc;

/// Where a local block or vector comes from among an element's unique ones.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Src {
    /// Index of the unique block (vector) in the element's output.
    pub index: u16,
    /// Use its negative.
    pub negate: bool,
    /// Use its transpose (blocks only).
    pub transpose: bool,
}

impl Src {
    /// The unique item `index` as it is.
    pub const fn plus(index: u16) -> Self {
        Self {
            index,
            negate: false,
            transpose: false,
        }
    }
    /// The negative of unique item `index`.
    pub const fn minus(index: u16) -> Self {
        Self {
            index,
            negate: true,
            transpose: false,
        }
    }
    /// The transpose of unique block `index`.
    pub const fn transposed(index: u16) -> Self {
        Self {
            index,
            negate: false,
            transpose: true,
        }
    }
}

/// How an element type's K x K local blocks and K local vectors derive from the unique
/// blocks and vectors its kernel writes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LocalLayout {
    /// Vertices per element.
    pub k: usize,
    /// Unique blocks written per element.
    pub blocks: usize,
    /// Source of local block (p, q), row-major, K x K entries.
    pub block_src: Vec<Src>,
    /// Unique vectors written per element.
    pub vectors: usize,
    /// Source of the local vector of vertex p, K entries.
    pub vector_src: Vec<Src>,
}

impl LocalLayout {
    /// A two-vertex element with one block J (local matrix `[[J, -J], [-J, J]]`) and one
    /// vector f (local vectors `(f, -f)`): springs.
    pub fn pair() -> Self {
        Self {
            k: 2,
            blocks: 1,
            block_src: vec![Src::plus(0), Src::minus(0), Src::minus(0), Src::plus(0)],
            vectors: 1,
            vector_src: vec![Src::plus(0), Src::minus(0)],
        }
    }

    /// A K-vertex element with a symmetric local matrix: only the blocks (p, q) with
    /// p <= q are written, row by row ([`LocalLayout::symmetric_index`]); block (q, p) is
    /// the transpose of (p, q). Vectors as in [`LocalLayout::dense`]. Writes and gathers
    /// k (k + 1) / 2 blocks instead of k^2 (6 of 9 for triangles, 10 of 16 for hinges).
    pub fn symmetric(k: usize) -> Self {
        Self {
            k,
            blocks: k * (k + 1) / 2,
            block_src: (0..k * k)
                .map(|i| {
                    let (p, q) = (i / k, i % k);
                    if p <= q {
                        Src::plus(Self::symmetric_index(k, p, q) as u16)
                    } else {
                        Src::transposed(Self::symmetric_index(k, q, p) as u16)
                    }
                })
                .collect(),
            vectors: k,
            vector_src: (0..k).map(|i| Src::plus(i as u16)).collect(),
        }
    }

    /// Whether every block (q, p), q != p, is the transpose of block (p, q) (the same
    /// unique block, the same sign), as in [`LocalLayout::symmetric`]: then the element
    /// adds to a matrix slot below the diagonal the transposes of what it adds to the
    /// slot's mirror, whatever the vertex order.
    pub fn is_symmetric(&self) -> bool {
        let (k, src) = (self.k, &self.block_src);
        (0..k).all(|p| {
            (0..k).filter(|&q| q != p).all(|q| {
                let (a, b) = (src[p * k + q], src[q * k + p]);
                a.index == b.index && a.negate == b.negate && a.transpose != b.transpose
            })
        })
    }

    /// Where block (p, q), p <= q, of a [`LocalLayout::symmetric`] element is written
    /// among its unique blocks.
    pub const fn symmetric_index(k: usize, p: usize, q: usize) -> usize {
        // Rows 0..p hold k + (k - 1) + ... + (k - p + 1) blocks.
        p * k - p * (p.saturating_sub(1)) / 2 + (q - p)
    }

    /// K vertices, every local block and vector written explicitly.
    pub fn dense(k: usize) -> Self {
        Self {
            k,
            blocks: k * k,
            block_src: (0..k * k).map(|i| Src::plus(i as u16)).collect(),
            vectors: k,
            vector_src: (0..k).map(|i| Src::plus(i as u16)).collect(),
        }
    }
}

const NEG: u32 = 1 << 31;
const TRANS: u32 = 1 << 30;
const INDEX: u32 = TRANS - 1;

/// Slots per parallel task in the gathers (fixed: thread-count independent).
const GATHER_CHUNK: usize = 4096;

/// Per-vertex gather of element vectors (forces): what explicit methods need, with no
/// matrix pattern.
#[derive(Clone, Debug)]
pub struct VectorGather {
    n: usize,
    vectors: usize,
    elements: usize,
    ptr: Vec<u32>,
    src: Vec<u32>,
}

/// Precomputed element -> slot maps and their inverse gathers (see the module docs).
#[derive(Clone, Debug)]
pub struct ElementAssembly {
    pattern: Arc<Bsr3Pattern>,
    blocks_per_element: usize,
    elements: usize,
    elem_slots: Vec<u32>,
    block_ptr: Vec<u32>,
    block_src: Vec<u32>,
    /// The layout's sources of the K x K local blocks (row-major).
    local_src: Vec<Src>,
    /// Whether the layout is symmetric ([`LocalLayout::is_symmetric`]).
    symmetric: bool,
    /// The ordered buffer's maps, for the kernels that store in gather order
    /// ([`ElementAssembly::with_ordered`]); none for the others.
    ordered: Option<Ordered>,
}

/// Where [`ElementAssembly::par_write_ordered`] stores each local block, and what each
/// slot sums ([`ElementAssembly::gather_ordered`]).
#[derive(Clone, Debug)]
struct Ordered {
    /// Where local block (p, q) of element e goes in the ordered buffer, at
    /// `e * K * K + p * K + q` (see [`OrderedChunk`]). Each chunk of [`ORDERED_CHUNK`]
    /// elements has its own part of the buffer, its blocks sorted by slot there (in
    /// element order within a slot). Every place is one local block's; the blocks of
    /// mirrored slots are not stored ([`NOT_STORED`]).
    order: Vec<u32>,
    /// The runs of the ordered buffer each slot sums, `runs[run_ptr[s]..run_ptr[s + 1]]`
    /// (first block, blocks), in chunk order: one per chunk with elements at the slot.
    run_ptr: Vec<u32>,
    runs: Vec<(u32, u32)>,
    /// Blocks in the buffer.
    blocks: usize,
    /// For a symmetric layout, each slot's mirror across the diagonal ([`NO_MIRROR`] for
    /// those on it): slots are numbered row by row, so a slot below the diagonal has the
    /// smaller-numbered mirror. The gather sums the slots on and
    /// above the diagonal only and writes each one's mirror as its transpose in the same
    /// pass. Empty otherwise.
    mirror: Vec<u32>,
}

/// Elements per chunk of [`ElementAssembly::par_write_ordered`], and so per part of its
/// buffer: a chunk's 1,024 tetrahedra write 590 KB, which one core's L2 holds while the
/// kernel fills it.
pub const ORDERED_CHUNK: usize = 1024;

/// [`Ordered::mirror`] of a slot that mirrors none (one on the diagonal).
const NO_MIRROR: u32 = u32::MAX;

/// [`Ordered::order`] of a local block whose slot is a mirror: the gather writes that
/// slot as the transpose of the one above the diagonal, so the block is not stored.
/// Skipping these stores (6 of a tetrahedron's 16; before, they went to a spare block a
/// chunk, unread) took the issue-15 beam's `Fem::force_jacobians` on one thread from
/// 14.2-14.7 to 12.4-13.2 ms (best of 200, three alternated rounds, 2026-12-07); writing
/// the mirrors in the gather's pass (not a second pass over the pairs) had taken it from
/// 14.7-15.9 ms.
const NOT_STORED: u32 = u32::MAX;

fn encode(global: usize, s: Src) -> u32 {
    let mut code = global as u32;
    if s.negate {
        code |= NEG;
    }
    if s.transpose {
        code |= TRANS;
    }
    code
}

/// CSR of sources from (target, source code) pairs: the sources of target `t` are
/// `src[ptr[t]..ptr[t + 1]]`, in the order the pairs come (element order here).
pub(crate) fn csr(
    targets: usize,
    pairs: impl Iterator<Item = (usize, u32)> + Clone,
) -> (Vec<u32>, Vec<u32>) {
    let mut ptr = vec![0u32; targets + 1];
    for (t, _) in pairs.clone() {
        ptr[t + 1] += 1;
    }
    for t in 0..targets {
        ptr[t + 1] += ptr[t];
    }
    let mut fill = ptr.clone();
    let mut src = vec![0u32; ptr[targets] as usize];
    for (t, code) in pairs {
        src[fill[t] as usize] = code;
        fill[t] += 1;
    }
    (ptr, src)
}

impl ElementAssembly {
    /// Builds the pattern of `elements` over n vertices and the maps for `layout`.
    pub fn new<const K: usize>(
        n: usize,
        elements: &[[u32; K]],
        layout: LocalLayout,
    ) -> Result<Self, SparseError> {
        assert_eq!(
            layout.k, K,
            "layout and elements disagree on vertices per element"
        );
        assert_eq!(layout.block_src.len(), K * K);
        assert_eq!(layout.vector_src.len(), K);
        let pattern = Arc::new(Bsr3Pattern::from_elements(n, elements)?);
        Self::with_pattern(pattern, elements, layout)
    }

    /// Maps for `elements` into an existing `pattern` that couples every pair of vertices
    /// of each element (for models with several element kinds sharing one matrix: build
    /// the pattern from all of them, then one assembly per kind).
    ///
    /// # Panics
    /// When the pattern lacks a pair of some element.
    pub fn with_pattern<const K: usize>(
        pattern: Arc<Bsr3Pattern>,
        elements: &[[u32; K]],
        layout: LocalLayout,
    ) -> Result<Self, SparseError> {
        assert_eq!(
            layout.k, K,
            "layout and elements disagree on vertices per element"
        );
        assert_eq!(layout.block_src.len(), K * K);
        assert_eq!(layout.vector_src.len(), K);
        let total = elements.len() * layout.blocks;
        if total > INDEX as usize {
            return Err(SparseError::TooLarge { blocks: total });
        }
        let mut elem_slots = Vec::with_capacity(elements.len() * K * K);
        for el in elements {
            for &a in el {
                for &b in el {
                    let s = pattern
                        .slot(a as usize, b as usize)
                        .expect("pattern holds every element pair");
                    elem_slots.push(s as u32);
                }
            }
        }
        let kk = K * K;
        let nb = layout.blocks;
        let bsrc = &layout.block_src;
        let block_pairs = elem_slots.iter().enumerate().map(move |(g, &slot)| {
            let (e, l) = (g / kk, g % kk);
            let s = bsrc[l];
            (slot as usize, encode(e * nb + s.index as usize, s))
        });
        let (block_ptr, block_src) = csr(pattern.nnz_blocks(), block_pairs);
        Ok(Self {
            pattern,
            blocks_per_element: layout.blocks,
            elements: elements.len(),
            elem_slots,
            block_ptr,
            block_src,
            symmetric: layout.is_symmetric(),
            local_src: layout.block_src,
            ordered: None,
        })
    }

    /// The same assembly with the maps of the ordered buffer made
    /// ([`ElementAssembly::par_write_ordered`], [`ElementAssembly::gather_ordered`]): a
    /// sort of each chunk's local blocks by slot, and a `u32` per local block.
    ///
    /// With a symmetric layout (each block (q, p) the transpose of block (p, q), as
    /// [`LocalLayout::symmetric`]) on a symmetric pattern, only the blocks of slots on and
    /// above the diagonal are stored and summed, and each slot below is written as the
    /// transpose of its mirror: the same bits, since the mirror's sources are the
    /// transposes of its own in the same order, with 10 of a tetrahedron's 16 local
    /// blocks stored and read instead of 16.
    pub fn with_ordered(mut self) -> Self {
        let kk = self.local_src.len();
        let mirror = if self.symmetric {
            self.mirror_pairs()
        } else {
            None
        };
        self.ordered = Some(ordered_runs(
            self.pattern.nnz_blocks(),
            &self.elem_slots,
            kk,
            mirror.unwrap_or_default(),
        ));
        self
    }

    /// Each slot below the diagonal with its mirror above it (lower, upper); none where
    /// the pattern lacks a mirror.
    fn mirror_pairs(&self) -> Option<Vec<(u32, u32)>> {
        let pat = &self.pattern;
        let (ptr, col) = (pat.row_ptr(), pat.col());
        let mut pairs = Vec::new();
        for i in 0..pat.n() {
            let row = ptr[i] as usize..ptr[i + 1] as usize;
            for (s, &j) in row.clone().zip(&col[row]) {
                if (j as usize) < i {
                    pairs.push((s as u32, pat.slot(j as usize, i)? as u32));
                }
            }
        }
        Some(pairs)
    }

    /// The ordered buffer's maps.
    ///
    /// # Panics
    /// When the assembly was built without them ([`ElementAssembly::with_ordered`]).
    fn ordered(&self) -> &Ordered {
        self.ordered
            .as_ref()
            .expect("ElementAssembly::with_ordered makes the ordered buffer's maps")
    }

    /// The shared pattern (every matrix assembled here uses it).
    pub fn pattern(&self) -> &Arc<Bsr3Pattern> {
        &self.pattern
    }

    /// Length of the element block buffer the kernels write (`elements * blocks * 9`).
    pub fn block_buffer_len(&self) -> usize {
        self.elements * self.blocks_per_element * 9
    }

    /// The element -> slot map: slot of local block (p, q) of element e at
    /// `e * K * K + p * K + q`.
    pub fn elem_slots(&self) -> &[u32] {
        &self.elem_slots
    }

    /// Length of the buffer of [`ElementAssembly::par_write_ordered`]: every local block
    /// (`elements * K * K * 9`), or with a symmetric layout those of the slots on and
    /// above the diagonal (see
    /// [`ElementAssembly::with_ordered`]).
    ///
    /// # Panics
    /// Without [`ElementAssembly::with_ordered`].
    pub fn ordered_buffer_len(&self) -> usize {
        self.ordered().blocks * 9
    }

    /// Runs `kernel` over the elements in chunks of [`ORDERED_CHUNK`] (in parallel), each call with
    /// its element range, the chunk's part of `companion` (`per_element` values per element,
    /// such as the element forces) and an [`OrderedChunk`] through which it stores each
    /// element's unique blocks into `ordered` in gather order, for
    /// [`ElementAssembly::gather_ordered`].
    ///
    /// Why: [`ElementAssembly::gather_blocks`] reads each slot's sources scattered over the
    /// element-major buffer (on the 60,000-tetrahedron beam of issue 15, 960,000 reads of
    /// 36 bytes over 21.6 MB, 12% of a backward Euler step). Here each chunk's stores land
    /// in its own part of the buffer, sorted by slot, and the gather reads one or two runs
    /// a slot from a few sequential streams.
    ///
    /// # Panics
    /// Without [`ElementAssembly::with_ordered`], or where the buffers' lengths are not
    /// [`ElementAssembly::ordered_buffer_len`] and `per_element` per element.
    pub fn par_write_ordered<T, U, F>(
        &self,
        ordered: &mut [T],
        companion: &mut [U],
        per_element: usize,
        kernel: F,
    ) where
        T: Send,
        U: Send,
        F: Fn(std::ops::Range<usize>, &mut [U], &mut OrderedChunk<'_, T>) + Sync,
    {
        assert_eq!(ordered.len(), self.ordered_buffer_len());
        assert_eq!(companion.len(), per_element * self.elements);
        let order = &self.ordered().order;
        let chunk = ORDERED_CHUNK;
        let out = Disjoint::new(ordered);
        companion
            .par_chunks_mut(per_element * chunk)
            .enumerate()
            .for_each(|(c, comp)| {
                let range = chunk_range(c, self.elements, chunk);
                let mut sink = OrderedChunk {
                    asm: self,
                    order,
                    out: &out,
                    range: range.clone(),
                };
                kernel(range, comp, &mut sink);
            });
    }

    /// Overwrites `out` with the assembled matrix of the blocks `ordered` written by
    /// [`ElementAssembly::par_write_ordered`]: each slot sums its run of the buffer in
    /// order. The same sources in the same order as [`ElementAssembly::gather_blocks`]
    /// (the signs and transposes applied when stored), so the same bits.
    ///
    /// # Panics
    /// Without [`ElementAssembly::with_ordered`].
    pub fn gather_ordered<T: BlockValue>(&self, ordered: &[T], out: &mut Bsr3) {
        self.gather_ordered_affine(ordered, out, 1.0, None);
    }

    /// Like [`ElementAssembly::gather_ordered`], but writes `scale` times the assembled
    /// matrix plus `diag_i I` on each diagonal block i when `diag` is given: an implicit
    /// step's `M - h^2 K` in the same pass, bit for bit what scaling the gathered matrix
    /// and adding the diagonal after would give (one pass over the matrix fewer).
    ///
    /// # Panics
    /// Without [`ElementAssembly::with_ordered`], or with a `diag` not of length n.
    pub fn gather_ordered_affine<T: BlockValue>(
        &self,
        ordered: &[T],
        out: &mut Bsr3,
        scale: f64,
        diag: Option<&[f64]>,
    ) {
        assert_eq!(ordered.len(), self.ordered_buffer_len());
        assert!(Arc::ptr_eq(out.pattern(), &self.pattern) || **out.pattern() == *self.pattern);
        let Ordered {
            run_ptr: ptr,
            runs,
            mirror,
            ..
        } = self.ordered();
        let slots = self.pattern.nnz_blocks();
        let vals = Disjoint::new(out.values_mut());
        par_reduce::<0, _>(chunk_count(slots, GATHER_CHUNK), &|c| {
            for s in chunk_range(c, slots, GATHER_CHUNK) {
                // A slot below the diagonal (its mirror numbered before it) is written
                // with its mirror.
                let m = mirror.get(s).copied().unwrap_or(NO_MIRROR);
                if (m as usize) < s {
                    continue;
                }
                let mut acc = [0.0f64; 9];
                for &(first, len) in &runs[ptr[s] as usize..ptr[s + 1] as usize] {
                    let run = &ordered[9 * first as usize..9 * (first + len) as usize];
                    for b in run.chunks_exact(9) {
                        for (a, bb) in acc.iter_mut().zip(b) {
                            *a += bb.get();
                        }
                    }
                }
                let v = acc.map(|a| scale * a);
                // SAFETY: slot s is in this chunk alone, and on or above the diagonal (no mirror).
                unsafe { vals.slice(9 * s..9 * s + 9) }.copy_from_slice(&v);
                if m != NO_MIRROR {
                    let l = 9 * m as usize;
                    // SAFETY: m is the mirror of s alone (`mirror_pairs` pairs each slot
                    // below the diagonal with one above it), below the diagonal (s is
                    // not), and no chunk writes such a slot as its own.
                    let dst = unsafe { vals.slice(l..l + 9) };
                    for r in 0..3 {
                        for c in 0..3 {
                            dst[3 * r + c] = v[3 * c + r];
                        }
                    }
                }
            }
            []
        });
        if let Some(d) = diag {
            out.add_diagonal(d);
        }
    }

    /// Overwrites `out` with the assembled matrix of the element blocks (stored as `f64`,
    /// or as `f32` where the kernel rounded them to halve the bytes; the sums are `f64`).
    pub fn gather_blocks<T: BlockValue>(&self, elem_blocks: &[T], out: &mut Bsr3) {
        self.gather(elem_blocks, out, false);
    }

    /// Like [`ElementAssembly::gather_blocks`], but adds to `out` (a second element kind
    /// sharing the pattern, see [`ElementAssembly::with_pattern`]).
    pub fn gather_blocks_add<T: BlockValue>(&self, elem_blocks: &[T], out: &mut Bsr3) {
        self.gather(elem_blocks, out, true);
    }

    fn gather<T: BlockValue>(&self, elem_blocks: &[T], out: &mut Bsr3, add: bool) {
        assert_eq!(elem_blocks.len(), self.block_buffer_len());
        assert!(Arc::ptr_eq(out.pattern(), &self.pattern) || **out.pattern() == *self.pattern);
        let (ptr, src) = (&self.block_ptr, &self.block_src);
        for_each_block(out, |s, v| {
            let mut acc = [0.0f64; 9];
            for &code in &src[ptr[s] as usize..ptr[s + 1] as usize] {
                let b = &elem_blocks[9 * (code & INDEX) as usize..][..9];
                let sign = if code & NEG != 0 { -1.0 } else { 1.0 };
                if code & TRANS != 0 {
                    for r in 0..3 {
                        for cc in 0..3 {
                            acc[3 * r + cc] += sign * b[3 * cc + r].get();
                        }
                    }
                } else {
                    for (a, bb) in acc.iter_mut().zip(b) {
                        *a += sign * bb.get();
                    }
                }
            }
            if add {
                for (o, a) in v.iter_mut().zip(acc) {
                    *o += a;
                }
            } else {
                v.copy_from_slice(&acc);
            }
        });
    }
}

/// The ordered buffer's layout for local blocks with slots `elem_slots` (`kk` per
/// element): each local block's position (`order`), and each slot's runs (CSR). Within a
/// chunk of [`ORDERED_CHUNK`] elements the blocks are sorted by slot, stably, so a slot's
/// runs in chunk order hold its sources in element order, as `block_src` does. The
/// blocks of the lower slots of the `pairs` (lower, upper) are not stored
/// ([`NOT_STORED`]).
fn ordered_runs(slots: usize, elem_slots: &[u32], kk: usize, pairs: Vec<(u32, u32)>) -> Ordered {
    let mut across = vec![NO_MIRROR; if pairs.is_empty() { 0 } else { slots }];
    for &(l, u) in &pairs {
        across[l as usize] = u;
        across[u as usize] = l;
    }
    let lower = |s: u32| across.get(s as usize).is_some_and(|&m| m < s);
    let mut order = vec![0u32; elem_slots.len()];
    let mut run_pairs: Vec<(usize, (u32, u32))> = Vec::new();
    let mut local: Vec<(u32, u32)> = Vec::with_capacity(ORDERED_CHUNK * kk);
    let mut base = 0;
    for (c, chunk) in elem_slots.chunks(ORDERED_CHUNK * kk).enumerate() {
        let first = c * ORDERED_CHUNK * kk;
        local.clear();
        local.extend(
            (chunk.iter().enumerate())
                .filter(|&(_, &s)| !lower(s))
                .map(|(g, &s)| (s, g as u32)),
        );
        // Stable: equal slots keep element (and local block) order.
        local.sort_by_key(|&(s, _)| s);
        for (g, &s) in chunk.iter().enumerate() {
            if lower(s) {
                order[first + g] = NOT_STORED;
            }
        }
        let mut start = 0;
        for (rank, &(s, g)) in local.iter().enumerate() {
            order[first + g as usize] = (base + rank) as u32;
            if rank + 1 == local.len() || local[rank + 1].0 != s {
                let run = ((base + start) as u32, (rank + 1 - start) as u32);
                run_pairs.push((s as usize, run));
                start = rank + 1;
            }
        }
        base += local.len();
    }
    // Runs in chunk order within each slot (csr keeps the pairs' order).
    let (run_ptr, idx) = csr(
        slots,
        run_pairs
            .iter()
            .enumerate()
            .map(|(i, &(s, _))| (s, i as u32)),
    );
    let runs = idx.iter().map(|&i| run_pairs[i as usize].1).collect();
    Ordered {
        order,
        run_ptr,
        runs,
        blocks: base,
        mirror: across,
    }
}

/// One chunk's view of [`ElementAssembly::par_write_ordered`]'s buffer: stores the blocks
/// of the chunk's elements only, so concurrent chunks never write the same place (each
/// element's positions are its own).
pub struct OrderedChunk<'a, T> {
    asm: &'a ElementAssembly,
    order: &'a [u32],
    out: &'a Disjoint<'a, T>,
    range: std::ops::Range<usize>,
}

impl<T> OrderedChunk<'_, T> {
    /// Stores element e's unique blocks (`blocks * 9` values, as for
    /// [`ElementAssembly::gather_blocks`]) as `store` rounds them, each local block at its
    /// place in gather order, negated and transposed as the layout says (those of
    /// mirrored slots not at all: the gather writes them).
    ///
    /// # Panics
    /// When e is outside the chunk's elements, or `unique` is short.
    pub fn put(&mut self, e: usize, unique: &[f64], store: impl Fn(f64) -> T) {
        assert!(
            self.range.contains(&e),
            "element {e} outside the chunk {:?}",
            self.range
        );
        let kk = self.asm.local_src.len();
        assert!(unique.len() >= 9 * self.asm.blocks_per_element);
        let order = &self.order[e * kk..(e + 1) * kk];
        for (src, &at) in self.asm.local_src.iter().zip(order) {
            if at == NOT_STORED {
                continue;
            }
            let at = 9 * at as usize;
            // SAFETY: `at` belongs to element e alone (`ordered_runs`), and e to this
            // chunk alone (asserted above; the chunks of par_write_ordered are disjoint),
            // so no other live slice overlaps it (this loop's slices live one iteration
            // each).
            let dst = unsafe { self.out.slice(at..at + 9) };
            let b: &[f64; 9] = unique[9 * src.index as usize..][..9].try_into().expect("9");
            let sign = if src.negate { -1.0 } else { 1.0 };
            let b = if src.transpose {
                [b[0], b[3], b[6], b[1], b[4], b[7], b[2], b[5], b[8]]
            } else {
                *b
            };
            for (d, v) in dst.iter_mut().zip(b) {
                *d = store(sign * v);
            }
        }
    }
}

/// Calls `f(slot, values)` for every block of `out`, in parallel over fixed chunks of
/// slots (each slot's work is independent: results do not depend on the thread count).
fn for_each_block(out: &mut Bsr3, f: impl Fn(usize, &mut [f64]) + Sync) {
    out.values_mut()
        .par_chunks_mut(9 * GATHER_CHUNK)
        .enumerate()
        .for_each(|(c, vals)| {
            for (ls, v) in vals.chunks_exact_mut(9).enumerate() {
                f(c * GATHER_CHUNK + ls, v);
            }
        });
}

impl VectorGather {
    /// The per-vertex source lists of `elements` over n vertices for `layout`.
    pub fn new<const K: usize>(
        n: usize,
        elements: &[[u32; K]],
        layout: &LocalLayout,
    ) -> Result<Self, SparseError> {
        assert_eq!(
            layout.k, K,
            "layout and elements disagree on vertices per element"
        );
        let nv = layout.vectors;
        if elements.len() * nv > INDEX as usize {
            return Err(SparseError::TooLarge {
                blocks: elements.len() * nv,
            });
        }
        for (e, el) in elements.iter().enumerate() {
            if let Some(&a) = el.iter().find(|&&a| a as usize >= n) {
                return Err(SparseError::VertexOutOfRange {
                    element: e,
                    vertex: a as usize,
                    n,
                });
            }
        }
        let vsrc = &layout.vector_src;
        let pairs = elements.iter().enumerate().flat_map(move |(e, el)| {
            el.iter().enumerate().map(move |(p, &a)| {
                let s = vsrc[p];
                (a as usize, encode(e * nv + s.index as usize, s))
            })
        });
        let (ptr, src) = csr(n, pairs);
        Ok(Self {
            n,
            vectors: nv,
            elements: elements.len(),
            ptr,
            src,
        })
    }

    /// Length of the element vector buffer the kernels write (`elements * vectors * 3`).
    pub fn vector_buffer_len(&self) -> usize {
        self.elements * self.vectors * 3
    }

    /// Adds the assembled element vectors to `out` (component-major, 3n).
    pub fn gather_vectors_add(&self, elem_vecs: &[f64], out: &mut [f64]) {
        assert_eq!(elem_vecs.len(), self.vector_buffer_len());
        let n = self.n;
        assert_eq!(out.len(), 3 * n);
        let (ptr, src) = (&self.ptr, &self.src);
        let od = Disjoint::new(out);
        par_reduce::<0, _>(chunk_count(n, GATHER_CHUNK), &|c| {
            let vr = chunk_range(c, n, GATHER_CHUNK);
            // SAFETY: vertex ranges of distinct chunks are disjoint.
            let [ox, oy, oz] = unsafe { od.components(n, vr.clone()) };
            for (li, i) in vr.enumerate() {
                let mut acc = [0.0f64; 3];
                for &code in &src[ptr[i] as usize..ptr[i + 1] as usize] {
                    let f = &elem_vecs[3 * (code & INDEX) as usize..][..3];
                    let sign = if code & NEG != 0 { -1.0 } else { 1.0 };
                    for a in 0..3 {
                        acc[a] += sign * f[a];
                    }
                }
                ox[li] += acc[0];
                oy[li] += acc[1];
                oz[li] += acc[2];
            }
            []
        });
    }
}

/// Assembly of elements whose local matrix is a weighted outer product of one vector per
/// element: block `(p, q)` is `w_pq g_p g_q^T` for the element's 3-vectors `g_p`.
///
/// Why: a projected Baraff-Witkin hinge has `df/dx = -k g g^T` with `g` the bend angle's
/// gradient (4 vertices). Storing its ten upper blocks takes 90 doubles per hinge, written
/// by the element kernel and read back by the gather; storing `g` takes 12, and the gather
/// forms the blocks (nine products each) while it sums them. On a 100x100 sheet that is
/// 2.9 MB of element data per matrix instead of 21.6 MB.
///
/// The vector buffer is element-major, `3 K` values per element (vertex p's vector at
/// `3 p`). Each slot sums its sources in a fixed order, in parallel over slots, so the
/// result does not depend on the thread count.
#[derive(Clone, Debug)]
pub struct RankOneAssembly {
    pattern: Arc<Bsr3Pattern>,
    k: usize,
    elements: usize,
    /// Bits of a local vertex index in a source code: `ceil(log2 K)`.
    bits: u32,
    /// Weight of local block `(p, q)` at `(p << bits) | q`.
    weight: Vec<f64>,
    /// Sources of each slot: `src[ptr[s]..ptr[s + 1]]`, each
    /// `(element << 2 bits) | (p << bits) | q`, decoded by shifts and masks: as
    /// `element * K^2 + p K + q` it took two integer divisions per source, and the gather
    /// of the 100x100 sheet's hinges took 1.55 ms instead of 1.15 (2 threads).
    ptr: Vec<u32>,
    src: Vec<u32>,
}

impl RankOneAssembly {
    /// The sources of `elements` in `pattern` (which must hold every pair of vertices with
    /// a non-zero weight), with weight `weight(p, q)` for local block `(p, q)`; a zero
    /// weight leaves the pair out. `weight` must be symmetric for a symmetric matrix.
    pub fn with_pattern<const K: usize>(
        pattern: Arc<Bsr3Pattern>,
        elements: &[[u32; K]],
        weight: impl Fn(usize, usize) -> f64,
    ) -> Result<Self, SparseError> {
        let bits = K.next_power_of_two().trailing_zeros();
        let codes = elements.len() << (2 * bits);
        if codes > u32::MAX as usize {
            return Err(SparseError::TooLarge { blocks: codes });
        }
        let weight: Vec<f64> = (0..1usize << (2 * bits))
            .map(|l| {
                let (p, q) = (l >> bits, l & ((1 << bits) - 1));
                if p < K && q < K {
                    weight(p, q)
                } else {
                    0.0
                }
            })
            .collect();
        let total = elements.len() * K * K;
        let mut pairs: Vec<(usize, u32)> = Vec::with_capacity(total);
        for (e, el) in elements.iter().enumerate() {
            for (p, &a) in el.iter().enumerate() {
                if a as usize >= pattern.n() {
                    return Err(SparseError::VertexOutOfRange {
                        element: e,
                        vertex: a as usize,
                        n: pattern.n(),
                    });
                }
                for (q, &b) in el.iter().enumerate() {
                    let l = (p << bits) | q;
                    if weight[l] == 0.0 {
                        continue;
                    }
                    let s = pattern
                        .slot(a as usize, b as usize)
                        .expect("pattern holds every weighted element pair");
                    pairs.push((s, ((e << (2 * bits)) | l) as u32));
                }
            }
        }
        // Each slot keeps its sources in element order.
        let (ptr, src) = csr(pattern.nnz_blocks(), pairs.iter().copied());
        Ok(Self {
            pattern,
            k: K,
            elements: elements.len(),
            bits,
            weight,
            ptr,
            src,
        })
    }

    /// Length of the element vector buffer: `3 K` per element.
    pub fn vector_buffer_len(&self) -> usize {
        3 * self.k * self.elements
    }

    /// `out += scale sum_e w_pq g_p g_q^T` over every element's blocks.
    pub fn gather_add(&self, g: &[f64], scale: f64, out: &mut Bsr3) {
        assert_eq!(g.len(), self.vector_buffer_len());
        assert!(Arc::ptr_eq(out.pattern(), &self.pattern) || **out.pattern() == *self.pattern);
        let (ptr, src, k, bits) = (&self.ptr, &self.src, self.k, self.bits);
        let mask = (1usize << bits) - 1;
        for_each_block(out, |s, v| {
            let mut acc = [0.0f64; 9];
            for &code in &src[ptr[s] as usize..ptr[s + 1] as usize] {
                let code = code as usize;
                let (e, l) = (code >> (2 * bits), code & ((1 << (2 * bits)) - 1));
                let (p, q) = (l >> bits, l & mask);
                let base = 3 * k * e;
                let gp = &g[base + 3 * p..base + 3 * p + 3];
                let gq = &g[base + 3 * q..base + 3 * q + 3];
                let w = self.weight[l];
                for r in 0..3 {
                    let wr = w * gp[r];
                    for cc in 0..3 {
                        acc[3 * r + cc] += wr * gq[cc];
                    }
                }
            }
            for (o, a) in v.iter_mut().zip(acc) {
                *o += scale * a;
            }
        });
    }
}
