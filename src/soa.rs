//! Structure-of-arrays buffers.
//!
//! [`Vec3s`] holds n 3-vectors in one `Vec<f64>` of length 3n, **component-major**:
//! `[x0..x(n-1), y0..y(n-1), z0..z(n-1)]`. The same buffer is the solvers' degree-of-freedom
//! vector, so models, integrators and linear algebra share it without conversion; block
//! (i, j) of a 3n x 3n operator touches rows {i, n+i, 2n+i} and columns {j, n+j, 2n+j}.
//! Array-of-structures (`[[f64; 3]]`) exists only at the edges, for I/O.

use std::sync::atomic::{AtomicUsize, Ordering};

/// n 3-vectors, component-major (see the module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Vec3s {
    data: Vec<f64>,
}

impl Vec3s {
    /// n zero vectors.
    pub fn zeros(n: usize) -> Self {
        Self {
            data: vec![0.0; 3 * n],
        }
    }

    /// From array-of-structures form (I/O edge).
    pub fn from_aos(v: &[[f64; 3]]) -> Self {
        let n = v.len();
        let mut data = vec![0.0; 3 * n];
        for (i, p) in v.iter().enumerate() {
            data[i] = p[0];
            data[n + i] = p[1];
            data[2 * n + i] = p[2];
        }
        Self { data }
    }

    /// The component-major data, by value (for owned meshes and frames).
    pub fn into_vec(self) -> Vec<f64> {
        self.data
    }

    /// To array-of-structures form (I/O edge).
    pub fn to_aos(&self) -> Vec<[f64; 3]> {
        (0..self.len()).map(|i| self.get(i)).collect()
    }

    /// Number of vectors n.
    #[inline]
    pub fn len(&self) -> usize {
        self.data.len() / 3
    }

    /// Whether there are no vectors.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Vector i.
    #[inline]
    pub fn get(&self, i: usize) -> [f64; 3] {
        largestep_kernels::get3(&self.data, self.len(), i)
    }

    /// Sets vector i.
    #[inline]
    pub fn set(&mut self, i: usize, v: [f64; 3]) {
        let n = self.len();
        self.data[i] = v[0];
        self.data[n + i] = v[1];
        self.data[2 * n + i] = v[2];
    }

    /// All x components.
    pub fn x(&self) -> &[f64] {
        &self.data[..self.len()]
    }
    /// All y components.
    pub fn y(&self) -> &[f64] {
        let n = self.len();
        &self.data[n..2 * n]
    }
    /// All z components.
    pub fn z(&self) -> &[f64] {
        let n = self.len();
        &self.data[2 * n..]
    }

    /// The three component slices, mutable at once.
    pub fn xyz_mut(&mut self) -> [&mut [f64]; 3] {
        largestep_kernels::split3_mut(&mut self.data)
    }

    /// The flat component-major data (the solvers' view).
    #[inline]
    pub fn as_slice(&self) -> &[f64] {
        &self.data
    }

    /// The flat component-major data, mutable.
    #[inline]
    pub fn as_mut_slice(&mut self) -> &mut [f64] {
        &mut self.data
    }
}

/// Bytes from which a [`ZeroedBuf`] maps its own pages (one 2 MiB huge page): the
/// buffers of a small problem stay ordinary vectors.
pub const MAPPED_MIN_BYTES: usize = HUGE_PAGE;

/// The size of a transparent huge page on x86-64 and most aarch64 kernels: a mapping's
/// values start on a multiple of it and fill a whole number of them, so that all of it
/// can be huge pages.
const HUGE_PAGE: usize = 2 << 20;

/// Bytes of [`ZeroedBuf`] mappings alive now, and the most alive at once.
static MAPPED: AtomicUsize = AtomicUsize::new(0);
static MAPPED_PEAK: AtomicUsize = AtomicUsize::new(0);

/// The bytes that [`ZeroedBuf`]s hold in mappings of their own, `(now, peak)`, the peak
/// since the last [`reset_mapped_peak`]: they bypass the global allocator, so a counting
/// allocator (an embedder's, or `tests/fuzz.rs`'s memory bound) must add them.
pub fn mapped_bytes() -> (usize, usize) {
    (
        MAPPED.load(Ordering::SeqCst),
        MAPPED_PEAK.load(Ordering::SeqCst),
    )
}

/// Starts a new peak for [`mapped_bytes`] at what is mapped now.
pub fn reset_mapped_peak() {
    MAPPED_PEAK.store(MAPPED.load(Ordering::SeqCst), Ordering::SeqCst);
}

/// Plain numbers whose all-zero bit pattern is the value zero.
///
/// # Safety
/// Every value of all-zero bits must be a valid `Self` (so a buffer of fresh zeroed pages
/// may be read as `Self`s).
pub unsafe trait ZeroBits: Copy + Default + Send + Sync + 'static {}
// SAFETY: all-zero bits are 0 (+0.0, false) for each of these.
unsafe impl ZeroBits for f64 {}
unsafe impl ZeroBits for f32 {}
unsafe impl ZeroBits for u8 {}
unsafe impl ZeroBits for bool {}

/// A slice of zeros for the grids that solvers make at setup (tens of megabytes): from
/// [`MAPPED_MIN_BYTES`] on, in fresh anonymous pages of its own (`memmap2`), which Linux
/// is asked to back with transparent huge pages (`madvise(MADV_HUGEPAGE)`, before the
/// first write); below that, or where mapping fails, an ordinary `Vec`.
///
/// Why not a `Vec`: the first write to each 4 KiB page of new memory is a page fault
/// (microseconds in a VM), and glibc hands a large `Vec` freed earlier back from its heap,
/// already on 4 KiB pages, so a hint given after `vec!` often comes too late. On the
/// 128^3 Poisson benchmark, which makes about 100 MB of such vectors per setup, the
/// mapped buffers made it an eighth to a quarter faster (`docs/benchmarks.md`).
pub struct ZeroedBuf<T: ZeroBits> {
    store: Store<T>,
}

enum Store<T> {
    Vec(Vec<T>),
    /// A mapping, the offset of the values in it (bytes: the first huge-page boundary)
    /// and their number.
    Mapped(memmap2::MmapMut, usize, usize),
}

impl<T: ZeroBits> ZeroedBuf<T> {
    /// `n` zeros.
    pub fn new(n: usize) -> Self {
        let bytes = n.saturating_mul(size_of::<T>());
        if bytes >= MAPPED_MIN_BYTES {
            // One huge page more than the values need, so that they can start on a
            // huge-page boundary (the kernel aligns only some anonymous mappings); the
            // pages before and after are never written, so never backed.
            let len = bytes.next_multiple_of(HUGE_PAGE) + HUGE_PAGE;
            if let Ok(map) = memmap2::MmapMut::map_anon(len) {
                let offset = map.as_ptr().align_offset(HUGE_PAGE);
                #[cfg(target_os = "linux")]
                {
                    // A hint: where the kernel has no transparent huge pages the
                    // mapping is the same on small pages.
                    let _ = map.advise_range(memmap2::Advice::HugePage, offset, len - HUGE_PAGE);
                }
                let now = MAPPED.fetch_add(map.len(), Ordering::SeqCst) + map.len();
                MAPPED_PEAK.fetch_max(now, Ordering::SeqCst);
                return Self {
                    store: Store::Mapped(map, offset, n),
                };
            }
        }
        Self {
            store: Store::Vec(vec![T::default(); n]),
        }
    }

    /// Whether the values live in a mapping of their own (see the type's docs).
    pub fn is_mapped(&self) -> bool {
        matches!(self.store, Store::Mapped(..))
    }
}

impl<T: ZeroBits> Drop for ZeroedBuf<T> {
    fn drop(&mut self) {
        if let Store::Mapped(map, ..) = &self.store {
            MAPPED.fetch_sub(map.len(), Ordering::SeqCst);
        }
    }
}

impl<T: ZeroBits> Default for ZeroedBuf<T> {
    fn default() -> Self {
        Self {
            store: Store::Vec(Vec::new()),
        }
    }
}

impl<T: ZeroBits> std::ops::Deref for ZeroedBuf<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match &self.store {
            Store::Vec(v) => v,
            // SAFETY: `offset` is a huge-page boundary (so aligned for T) with at least
            // `n * size_of::<T>()` bytes of the mapping after it, which start as zeros
            // (a valid T by `ZeroBits`) and are only written through `deref_mut` as
            // `T`s; the mapping lives as long as `self`.
            Store::Mapped(map, offset, n) => unsafe {
                std::slice::from_raw_parts(map.as_ptr().add(*offset).cast(), *n)
            },
        }
    }
}

impl<T: ZeroBits> std::ops::DerefMut for ZeroedBuf<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match &mut self.store {
            Store::Vec(v) => v,
            // SAFETY: as in `deref`, and `&mut self` makes the borrow unique.
            Store::Mapped(map, offset, n) => unsafe {
                std::slice::from_raw_parts_mut(map.as_mut_ptr().add(*offset).cast(), *n)
            },
        }
    }
}

impl<T: ZeroBits> Clone for ZeroedBuf<T> {
    fn clone(&self) -> Self {
        let mut out = Self::new(self.len());
        out.copy_from_slice(self);
        out
    }
}

impl<T: ZeroBits + std::fmt::Debug> std::fmt::Debug for ZeroedBuf<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

#[cfg(test)]
mod tests {
    use super::{ZeroedBuf, MAPPED_MIN_BYTES};

    #[test]
    fn zeroed_buffers_start_as_zeros_and_keep_what_is_written() {
        let big = MAPPED_MIN_BYTES / 8 + 3;
        for n in [0, 1, 1000, big] {
            let mut v = ZeroedBuf::<f64>::new(n);
            assert_eq!(v.len(), n);
            assert!(v.iter().all(|&x| x == 0.0));
            // Small buffers are vectors (a big one is mapped where the OS allows).
            assert!(!v.is_mapped() || n == big);
            for (i, x) in v.iter_mut().enumerate() {
                *x = i as f64;
            }
            let c = v.clone();
            assert_eq!(&c[..], &v[..]);
            assert!(v.iter().enumerate().all(|(i, &x)| x == i as f64));
        }
        // A mapped buffer starts on a huge-page boundary, so all of it can be huge pages.
        let b = ZeroedBuf::<u8>::new(MAPPED_MIN_BYTES);
        if b.is_mapped() {
            assert_eq!(b.as_ptr() as usize % MAPPED_MIN_BYTES, 0);
        }
        assert!(ZeroedBuf::<bool>::new(5).iter().all(|&x| !x));
        // Mapped bytes are counted while the buffer lives (other tests may map too, so
        // only bounds hold).
        let m = ZeroedBuf::<f32>::new(MAPPED_MIN_BYTES);
        if m.is_mapped() {
            let (now, peak) = super::mapped_bytes();
            assert!(now >= 4 * MAPPED_MIN_BYTES && peak >= now);
        }
    }
}
