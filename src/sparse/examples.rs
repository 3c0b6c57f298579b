//! Symmetric positive definite Bsr3 matrices on regular grids, for tests and benchmarks.
//!
//! Vertices sit on a 2-D or 3-D grid, each coupled to every neighbour within one step
//! along each axis (a 9-point stencil in 2-D, 27-point in 3-D), like a spring lattice with
//! shear springs. Each coupling contributes the element matrix `[[J, -J], [-J, J]]` with
//! `J = k (d d^T + I/20)` for the unit offset d, and the diagonal gets a lumped mass m, so
//! `A = M + sum_e K_e` is the shape of `M - h^2 df/dx` for a stretched lattice.
//! Assembly goes through [`ElementAssembly`], the path models use.

use super::{Bsr3, ElementAssembly, LocalLayout};

/// The grid's vertex pairs (each once), in the order the assembly sees them.
pub fn grid_pairs(dims: &[usize]) -> Vec<[u32; 2]> {
    let d3 = [
        dims[0],
        *dims.get(1).unwrap_or(&1),
        *dims.get(2).unwrap_or(&1),
    ];
    let idx = |i: usize, j: usize, k: usize| (i + d3[0] * (j + d3[1] * k)) as u32;
    let mut pairs = Vec::new();
    for k in 0..d3[2] {
        for j in 0..d3[1] {
            for i in 0..d3[0] {
                for dk in -1i64..=1 {
                    for dj in -1i64..=1 {
                        for di in -1i64..=1 {
                            // Each unordered pair once: positive offsets in lexicographic order.
                            if (dk, dj, di) <= (0, 0, 0) {
                                continue;
                            }
                            let (ii, jj, kk) = (i as i64 + di, j as i64 + dj, k as i64 + dk);
                            if ii < 0 || jj < 0 || kk < 0 {
                                continue;
                            }
                            let (ii, jj, kk) = (ii as usize, jj as usize, kk as usize);
                            if ii < d3[0] && jj < d3[1] && kk < d3[2] {
                                pairs.push([idx(i, j, k), idx(ii, jj, kk)]);
                            }
                        }
                    }
                }
            }
        }
    }
    pairs
}

/// The SPD grid matrix of the module docs with stiffness `k` and vertex mass `m`.
pub fn grid_spd(dims: &[usize], k: f64, m: f64) -> Bsr3 {
    let n: usize = dims.iter().product();
    let pairs = grid_pairs(dims);
    let asm = ElementAssembly::new(n, &pairs, LocalLayout::pair()).expect("grid pairs are valid");
    let mut blocks = vec![0.0; asm.block_buffer_len()];
    let d3 = [
        dims[0],
        *dims.get(1).unwrap_or(&1),
        *dims.get(2).unwrap_or(&1),
    ];
    let coord = |v: u32| {
        let v = v as usize;
        [v % d3[0], (v / d3[0]) % d3[1], v / (d3[0] * d3[1])].map(|c| c as f64)
    };
    for (e, [a, b]) in pairs.iter().enumerate() {
        let (pa, pb) = (coord(*a), coord(*b));
        let off = [pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]];
        let l = (off[0] * off[0] + off[1] * off[1] + off[2] * off[2]).sqrt();
        let d = off.map(|c| c / l);
        for r in 0..3 {
            for c in 0..3 {
                let id = if r == c { 0.05 } else { 0.0 };
                blocks[9 * e + 3 * r + c] = k * (d[r] * d[c] + id);
            }
        }
    }
    let mut a = Bsr3::zeros(asm.pattern().clone());
    asm.gather_blocks(&blocks, &mut a);
    a.add_diagonal(&vec![m; n]);
    a
}
