//! Deterministic parallel drivers.
//!
//! Work is cut into chunks of [`PAR_CHUNK`](crate::PAR_CHUNK) items, a number that depends
//! on the data only. Partial sums are combined by a binary tree whose shape depends only on
//! the number of chunks (`rayon::join` at every node), so a reduction gives the same bits
//! with 1 thread or 64, and needs no buffer for the partials (no allocation).

use core::marker::PhantomData;
use core::ops::Range;

/// Number of chunks of `chunk` items covering `len` items.
#[inline]
pub fn chunk_count(len: usize, chunk: usize) -> usize {
    len.div_ceil(chunk)
}

/// The item range of chunk `c`.
#[inline]
pub fn chunk_range(c: usize, len: usize, chunk: usize) -> Range<usize> {
    let start = c * chunk;
    start..(start + chunk).min(len)
}

/// Runs `f` on a thread of rayon's current pool: the calling thread when it is one of
/// them, else one the pool lends while the caller waits.
///
/// A step is dozens of short parallel loops (a PCG iteration's products, dots and
/// V-cycle levels). Started from a thread outside the pool, each loop is handed to the
/// pool while the caller sleeps, and the caller is woken after it: two thread wake-ups a
/// loop. Started from inside, a loop's halves are split by `rayon::join` between threads
/// already running. Measured on issue 15's beam (`MechSimulation::step`, 2 threads,
/// 200 steps of each alternated step by step): 2.1-2.4 ms a step less, of 19.5 ms.
pub fn on_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| f())
}

/// Runs `f` on chunk indices `0..nchunks` in parallel and adds up the `K` sums each returns,
/// over a fixed binary tree (see the module docs). `K = 0` runs without a reduction.
pub fn par_reduce<const K: usize, F>(nchunks: usize, f: &F) -> [f64; K]
where
    F: Fn(usize) -> [f64; K] + Sync,
{
    fn tree<const K: usize, F: Fn(usize) -> [f64; K] + Sync>(
        lo: usize,
        hi: usize,
        f: &F,
    ) -> [f64; K] {
        match hi - lo {
            0 => [0.0; K],
            1 => f(lo),
            len => {
                let mid = lo + len / 2;
                let (a, b) = rayon::join(|| tree(lo, mid, f), || tree(mid, hi, f));
                core::array::from_fn(|k| a[k] + b[k])
            }
        }
    }
    tree(0, nchunks, f)
}

/// A mutable buffer (of `f64` unless said) from which parallel tasks take **disjoint**
/// sub-slices.
///
/// This is how a driver lets chunk `c` write to `x[range]`, `x[n + range]` and
/// `x[2n + range]` of a component-major buffer at once, which `par_chunks_mut` cannot
/// express. The safety contract is on [`Disjoint::slice`].
pub struct Disjoint<'a, T = f64> {
    ptr: *mut T,
    len: usize,
    _borrow: PhantomData<&'a mut [T]>,
}

// SAFETY: a `Disjoint` is a `&mut [f64]` split between tasks; sending or sharing it is
// sound as long as the sub-slices handed out do not overlap (contract of `slice`).
unsafe impl<T: Send> Send for Disjoint<'_, T> {}
unsafe impl<T: Send> Sync for Disjoint<'_, T> {}

impl<'a, T> Disjoint<'a, T> {
    /// Wraps a mutable buffer; the buffer stays borrowed for `'a`.
    pub fn new(buf: &'a mut [T]) -> Self {
        Self {
            ptr: buf.as_mut_ptr(),
            len: buf.len(),
            _borrow: PhantomData,
        }
    }

    /// Length of the wrapped buffer.
    #[inline]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the wrapped buffer is empty.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The sub-slice `range` of the buffer.
    ///
    /// # Safety
    /// No two slices obtained from the same `Disjoint` and alive at the same time may
    /// overlap. Panics (safely) if `range` is out of bounds.
    #[allow(clippy::mut_from_ref)]
    #[inline]
    pub unsafe fn slice(&self, range: Range<usize>) -> &'a mut [T] {
        assert!(range.start <= range.end && range.end <= self.len);
        // SAFETY: in bounds (checked above); exclusivity is the caller's contract.
        unsafe { core::slice::from_raw_parts_mut(self.ptr.add(range.start), range.len()) }
    }

    /// The three component slices `[r, n + r, 2n + r]` of a component-major buffer of
    /// `n` 3-vectors, for the vertex range `r`.
    ///
    /// # Safety
    /// As for [`Disjoint::slice`]: vertex ranges taken concurrently must not overlap.
    #[inline]
    pub unsafe fn components(&self, n: usize, r: Range<usize>) -> [&'a mut [T]; 3] {
        assert!(self.len == 3 * n);
        assert!(r.start <= r.end && r.end <= n, "vertex range {r:?} of {n}");
        // SAFETY: the three ranges are disjoint from each other (r.end <= n, asserted); the caller
        // keeps vertex ranges of concurrent tasks disjoint.
        unsafe {
            [
                self.slice(r.clone()),
                self.slice(n + r.start..n + r.end),
                self.slice(2 * n + r.start..2 * n + r.end),
            ]
        }
    }
}

/// The three component slices of a component-major buffer of `n` 3-vectors, for the
/// vertex range `r`.
#[inline]
pub fn components<T>(v: &[T], n: usize, r: Range<usize>) -> [&[T]; 3] {
    assert!(v.len() == 3 * n);
    [
        &v[r.clone()],
        &v[n + r.start..n + r.end],
        &v[2 * n + r.start..2 * n + r.end],
    ]
}
