//! # largestep-kernels
//!
//! The hot loops of largestep as pure functions over flat structure-of-arrays slices.
//!
//! Conventions (see `docs/architecture.md` in the workspace):
//! - A set of n 3-vectors is one `&[f64]` of length 3n, **component-major**:
//!   `[x0..x(n-1), y0..y(n-1), z0..z(n-1)]`.
//! - Outputs come first, then inputs, then a `Copy` parameter struct where there is one.
//! - Kernels never allocate, never do I/O and never return errors: lengths are checked
//!   once at entry with `assert!`, other preconditions are documented.
//! - Every SIMD kernel (`wide::f64x4`) has a scalar twin with the same signature and the
//!   suffix `_scalar`, or, for a kernel over four elements at once (suffix `_x4`, one
//!   element per lane), the one-element kernel of the same meaning
//!   (`cloth::triangle_jacobians_x4`, `cloth::triangle_jacobians`); property tests hold
//!   the two together.
//! - Parallel drivers (suffix `_par`) split work into fixed ranges decided by the data,
//!   never by the number of threads, so their results are bitwise independent of it.

pub mod anim;
pub mod cloth;
pub mod collide;
pub mod fem;
pub mod fem_diag;
pub mod fluid;
pub mod interp;
pub mod lane;
pub mod mass_spring;
pub mod modal;
pub mod par;
pub mod quat;
pub mod render;
pub mod rigid;
pub mod rotation;
pub mod skin;
pub mod sparse;
pub mod v3;
pub mod vec;
pub mod volume;

/// Rows (or vertices) per task in the parallel drivers. Fixed, so that partial sums are
/// formed over the same ranges whatever the thread count (determinism), and large enough
/// (a few hundred kB of matrix per task) that scheduling costs stay far below the work.
pub const PAR_CHUNK: usize = 2048;

/// Vector i of component-major data `v` holding n 3-vectors: `[v[i], v[n+i], v[2n+i]]`.
#[inline(always)]
pub fn get3(v: &[f64], n: usize, i: usize) -> [f64; 3] {
    [v[i], v[n + i], v[2 * n + i]]
}

/// The vectors of element `el`'s K vertices in component-major data `v` holding n
/// 3-vectors.
#[inline(always)]
pub fn gather_nodes<const K: usize>(v: &[f64], n: usize, el: &[u32; K]) -> [[f64; 3]; K] {
    // A loop, not `el.map`: that stayed an out-of-line call (`try_map`), 3% of a step.
    let mut out = [[0.0; 3]; K];
    for (o, &i) in out.iter_mut().zip(el) {
        *o = get3(v, n, i as usize);
    }
    out
}

/// The root of `i`'s set in a union-find forest (`parent[r] == r` at each root),
/// halving the path on the way (Tarjan and van Leeuwen 1984): cloth zones, rigid islands.
#[inline]
pub fn find_root(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        parent[i as usize] = parent[parent[i as usize] as usize];
        i = parent[i as usize];
    }
    i
}

/// `[g(t), g(t + 1), g(t + 2), g(t + 3)]`: the inputs of four consecutive elements, for
/// the kernels that take four elements per call (SIMD over elements). Written out:
/// `[t, ..].map(g)` stayed an out-of-line call (`try_map`) whose result was copied, about
/// 5% of the SIMD triangle loop, and `std::array::from_fn` made the hinge loop 2x slower.
#[inline(always)]
pub fn four<T>(t: usize, g: impl Fn(usize) -> T) -> [T; 4] {
    [g(t), g(t + 1), g(t + 2), g(t + 3)]
}

/// The x, y and z component slices of component-major data holding `v.len() / 3` vectors.
#[inline]
pub fn split3_mut(v: &mut [f64]) -> [&mut [f64]; 3] {
    let n = v.len() / 3;
    assert_eq!(v.len(), 3 * n, "component-major data has length 3n");
    let (x, rest) = v.split_at_mut(n);
    let (y, z) = rest.split_at_mut(n);
    [x, y, z]
}
