//! Sparse layer and solver tests.

use largestep::solve::{Filter, Pcg, PcgParams, Preconditioner, SolveError, SparseCholesky};
use largestep::sparse::examples::{grid_pairs, grid_spd};
use largestep::sparse::*;
use std::io::Cursor;

fn dense_mul(d: &[f64], x: &[f64]) -> Vec<f64> {
    let m = x.len();
    (0..m)
        .map(|r| (0..m).map(|c| d[r * m + c] * x[c]).sum())
        .collect()
}

fn residual(a: &Bsr3, x: &[f64], b: &[f64]) -> f64 {
    let mut ax = vec![0.0; b.len()];
    a.spmv(&mut ax, x);
    let r: f64 = ax.iter().zip(b).map(|(p, q)| (p - q) * (p - q)).sum();
    let bn: f64 = b.iter().map(|q| q * q).sum();
    (r / bn).sqrt()
}

fn rhs(n: usize) -> Vec<f64> {
    (0..3 * n)
        .map(|i| ((i * 13 % 29) as f64 - 14.0) / 7.0)
        .collect()
}

#[test]
fn pattern_from_elements_is_symmetric_sorted_with_diagonal() {
    let p = Bsr3Pattern::from_elements(5, &[[0u32, 3], [3, 1], [0, 3]]).unwrap();
    assert_eq!(p.nnz_blocks(), 5 + 4);
    for i in 0..5 {
        assert_eq!(p.slot(i, i), Some(p.diag_slots()[i] as usize));
        let cols = &p.col()[p.row_ptr()[i] as usize..p.row_ptr()[i + 1] as usize];
        assert!(cols.windows(2).all(|w| w[0] < w[1]));
    }
    assert!(p.slot(0, 3).is_some() && p.slot(3, 0).is_some() && p.slot(0, 1).is_none());
    let err = Bsr3Pattern::from_elements(2, &[[0u32, 1], [1, 7]]).unwrap_err();
    assert!(
        err.to_string().contains("element 1 names vertex 7"),
        "{err}"
    );
}

#[test]
fn gather_assembly_equals_serial_scatter_and_dense() {
    let pairs = grid_pairs(&[3, 3]);
    let n = 9;
    let asm = ElementAssembly::new(n, &pairs, LocalLayout::pair()).unwrap();
    let blocks: Vec<f64> = (0..asm.block_buffer_len())
        .map(|i| (i as f64 * 0.731).sin())
        .collect();
    let mut a = Bsr3::zeros(asm.pattern().clone());
    asm.gather_blocks(&blocks, &mut a);
    // Serial scatter through the element -> slot map, in element order.
    let mut b = Bsr3::zeros(asm.pattern().clone());
    let slots = asm.elem_slots();
    for e in 0..pairs.len() {
        for l in 0..4 {
            let sign = if l == 0 || l == 3 { 1.0 } else { -1.0 };
            let s = slots[4 * e + l] as usize;
            for k in 0..9 {
                b.block_mut(s)[k] += sign * blocks[9 * e + k];
            }
        }
    }
    assert_eq!(a.values(), b.values(), "gather = scatter, bitwise");
    // Vectors: f on A, -f on B.
    let gather = VectorGather::new(n, &pairs, &LocalLayout::pair()).unwrap();
    let fe: Vec<f64> = (0..gather.vector_buffer_len()).map(|i| i as f64).collect();
    let mut f = vec![1.0; 3 * n];
    gather.gather_vectors_add(&fe, &mut f);
    let mut expect = vec![1.0; 3 * n];
    for (e, [p, q]) in pairs.iter().enumerate() {
        for c in 0..3 {
            expect[c * n + *p as usize] += fe[3 * e + c];
            expect[c * n + *q as usize] -= fe[3 * e + c];
        }
    }
    assert_eq!(f, expect);
}

#[test]
fn faer_and_nalgebra_exports_match_dense() {
    let a = grid_spd(&[3, 2, 2], 2.0, 0.5);
    let n3 = 3 * a.n();
    let dense = a.to_dense();
    let mut full = FaerCsc::new(a.pattern(), Triangle::Full);
    full.refill(&a);
    let mut lower = FaerCsc::new(a.pattern(), Triangle::Lower);
    lower.refill(&a);
    let (fd, ld) = (full.as_ref().to_dense(), lower.as_ref().to_dense());
    let csr = to_csr(&a);
    let mut csr_dense = vec![0.0; n3 * n3];
    for (r, c, v) in csr.triplet_iter() {
        csr_dense[r * n3 + c] += v;
    }
    for r in 0..n3 {
        for c in 0..n3 {
            let d = dense[r * n3 + c];
            assert_eq!(fd[(r, c)], d);
            assert_eq!(ld[(r, c)], if r >= c { d } else { 0.0 });
            assert_eq!(csr_dense[r * n3 + c], d);
        }
    }
    // A refill with new values reuses the structure.
    let mut b = a.clone();
    for v in b.values_mut() {
        *v *= 2.0;
    }
    full.refill(&b);
    assert_eq!(full.as_ref().to_dense()[(0, 0)], 2.0 * dense[0]);
    assert!(a.max_asymmetry() == 0.0);
}

#[test]
fn matrix_market_round_trip_is_exact() {
    let mut a = grid_spd(&[2, 3], 1.0 / 3.0, 0.1);
    a.values_mut()[5] = 1e-300; // extreme values survive the text form
    let mut buf = Vec::new();
    write_matrix_market(&mut buf, &a).unwrap();
    let mm = read_matrix_market(Cursor::new(&buf), "a.mtx").unwrap();
    let b = mm.to_bsr3("a.mtx").unwrap();
    assert_eq!(a.to_dense(), b.to_dense());
}

#[test]
fn matrix_market_errors_name_the_line() {
    let cases = [
        ("", 1, "empty file"),
        (
            "%%MatrixMarket matrix array real general\n2 2\n",
            1,
            "coordinate",
        ),
        (
            "%%MatrixMarket matrix coordinate complex general\n",
            1,
            "real",
        ),
        (
            "%%MatrixMarket matrix coordinate real general\n% c\n3 3\n",
            3,
            "rows cols entries",
        ),
        (
            "%%MatrixMarket matrix coordinate real general\n3 3 2\n1 1 1.0\n4 1 2.0\n",
            4,
            "outside",
        ),
        (
            "%%MatrixMarket matrix coordinate real general\n3 3 2\n1 1 x\n",
            3,
            "expected a number",
        ),
        (
            "%%MatrixMarket matrix coordinate real general\n3 3 2\n1 1 nan\n",
            3,
            "not finite",
        ),
        (
            "%%MatrixMarket matrix coordinate real general\n3 3 3\n1 1 1\n2 2 1\n",
            5,
            "2 of the 3",
        ),
    ];
    for (text, line, what) in cases {
        let err = read_matrix_market(Cursor::new(text), "m.mtx").unwrap_err();
        let msg = err.to_string();
        assert!(msg.starts_with(&format!("m.mtx:{line}:")), "{msg}");
        assert!(msg.contains(what), "{msg}");
    }
}

#[test]
fn pcg_converges_with_every_preconditioner() {
    // Symmetric scaling D A D with D spanning a decade: badly scaled, as with mixed
    // masses, where the diagonal preconditioners earn their keep.
    let mut a = grid_spd(&[8, 7, 6], 1.0, 0.05);
    let n = a.n();
    let d = |i: usize| if i.is_multiple_of(3) { 10.0 } else { 1.0 };
    let p = a.pattern().clone();
    for i in 0..n {
        for k in p.row_ptr()[i] as usize..p.row_ptr()[i + 1] as usize {
            let j = p.col()[k] as usize;
            for v in a.block_mut(k) {
                *v *= d(i) * d(j);
            }
        }
    }
    let b = rhs(n);
    let mut iters = Vec::new();
    for pre in [
        Preconditioner::None,
        Preconditioner::Jacobi,
        Preconditioner::BlockJacobi,
        Preconditioner::Multigrid,
        Preconditioner::SmoothedAggregation,
    ] {
        let mut pcg = Pcg::new(
            n,
            PcgParams {
                tolerance: 1e-10,
                max_iterations: 5000,
                preconditioner: pre,
            },
        );
        let mut x = vec![0.0; 3 * n];
        let info = pcg.solve(&mut a, &b, &mut x, None).unwrap();
        assert!(info.residual <= 1e-10);
        assert!(residual(&a, &x, &b) < 1e-9, "{pre:?}: true residual");
        iters.push(info.iterations);
    }
    assert!(
        2 * iters[1] < iters[0] && 2 * iters[2] < iters[0],
        "preconditioning helps: {iters:?}"
    );
    // The coarse levels remove part of what block Jacobi leaves (on this small, badly
    // scaled lattice at 1e-10; cloth gains far more, see tests/cloth.rs).
    assert!(iters[3] < iters[2], "multigrid helps more: {iters:?}");
    // Without positions smoothed aggregation's coarse spaces hold translations only, but
    // its smoothed prolongator and Chebyshev smoother still do better.
    assert!(
        iters[4] < iters[3],
        "smoothed aggregation helps most: {iters:?}"
    );
}

#[test]
fn filtered_pcg_holds_constraints_exactly_at_any_iteration_count() {
    let a = grid_spd(&[16, 16], 1.0, 0.05);
    let n = a.n();
    let b = rhs(n);
    let mut f = Filter::new(n);
    f.fix(0);
    f.constrain_normal(7, [1.0, 2.0, 0.5]);
    f.constrain_line(20, [0.0, 1.0, 1.0]);
    let unit = |v: [f64; 3]| {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|c| c / l)
    };
    for (max, preconditioner) in [1, 3, 1000].into_iter().flat_map(|m| {
        [
            Preconditioner::BlockJacobi,
            Preconditioner::Multigrid,
            Preconditioner::SmoothedAggregation,
        ]
        .map(|p| (m, p))
    }) {
        let mut pcg = Pcg::new(
            n,
            PcgParams {
                tolerance: 1e-12,
                max_iterations: max,
                preconditioner,
            },
        );
        let mut x = vec![1.0; 3 * n];
        let res = pcg.solve(&mut a.clone(), &b, &mut x, Some(&f));
        let g = |i: usize| [x[i], x[n + i], x[2 * n + i]];
        assert_eq!(g(0), [0.0; 3], "pinned vertex never moves");
        let p = unit([1.0, 2.0, 0.5]);
        let xn = g(7);
        assert!((xn[0] * p[0] + xn[1] * p[1] + xn[2] * p[2]).abs() < 1e-15);
        let xl = g(20);
        assert!((xl[1] - xl[2]).abs() < 1e-15 && xl[0].abs() < 1e-15);
        if max == 1000 {
            res.unwrap();
            // Same answer by Cholesky on the projected system.
            let mut ap = a.clone();
            f.project_matrix(&mut ap);
            let mut chol = SparseCholesky::new(ap.pattern()).unwrap();
            chol.factorize(&ap).unwrap();
            let mut y = b.clone();
            f.apply(&mut y);
            chol.solve_in_place(&mut y).unwrap();
            let err = x
                .iter()
                .zip(&y)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f64::max);
            assert!(
                err < 1e-8,
                "PCG ({preconditioner:?}) and projected Cholesky agree: {err}"
            );
        } else {
            assert!(matches!(res, Err(SolveError::NotConverged { .. })));
        }
    }
}

#[test]
fn cholesky_solves_and_refactorizes() {
    for dims in [vec![10, 10], vec![5, 5, 5]] {
        let a = grid_spd(&dims, 1.0, 0.2);
        let n = a.n();
        let b = rhs(n);
        let mut chol = SparseCholesky::new(a.pattern()).unwrap();
        for scale in [1.0, 3.0] {
            let mut s = a.clone();
            for v in s.values_mut() {
                *v *= scale;
            }
            chol.factorize(&s).unwrap();
            let mut x = b.clone();
            chol.solve_in_place(&mut x).unwrap();
            assert!(residual(&s, &x, &b) < 1e-12, "residual at scale {scale}");
        }
        let dense = a.to_dense();
        let mut x = b.clone();
        chol.factorize(&a).unwrap();
        chol.solve_in_place(&mut x).unwrap();
        let ax = dense_mul(&dense, &x);
        assert!(ax.iter().zip(&b).all(|(p, q)| (p - q).abs() < 1e-10));
    }
}

/// `ElementAssembly::par_write_ordered` then `gather_ordered` against `gather_blocks` on
/// the same blocks: bitwise the same matrix, for layouts with negated and transposed
/// local blocks (the symmetric one's slots below the diagonal mirrored), over more
/// elements than one chunk of the ordered buffer, rounded to f32 or not.
#[test]
fn the_ordered_gather_gives_the_same_bits_as_the_gather() {
    fn check<const K: usize>(n: usize, elements: &[[u32; K]], layout: LocalLayout) {
        let asm = ElementAssembly::new(n, elements, layout)
            .unwrap()
            .with_ordered();
        let per = asm.block_buffer_len() / elements.len();
        let blocks: Vec<f64> = (0..asm.block_buffer_len())
            .map(|i| (i as f64 * 0.731).sin() * (1.0 + (i % 7) as f64))
            .collect();
        let mut a = Bsr3::zeros(asm.pattern().clone());
        asm.gather_blocks(&blocks, &mut a);
        let mut ordered = vec![f64::NAN; asm.ordered_buffer_len()];
        let mut tag = vec![0usize; elements.len()];
        asm.par_write_ordered(&mut ordered, &mut tag, 1, |range, t, sink| {
            for (e, te) in range.zip(t) {
                sink.put(e, &blocks[per * e..per * (e + 1)], |v| v);
                *te = e + 1;
            }
        });
        assert!(
            tag.iter().enumerate().all(|(e, &t)| t == e + 1),
            "every element once"
        );
        assert!(ordered.iter().all(|v| v.is_finite()), "every place written");
        let mut b = Bsr3::zeros(asm.pattern().clone());
        b.values_mut().fill(f64::NAN);
        asm.gather_ordered(&ordered, &mut b);
        assert_eq!(a.values(), b.values(), "f64");
        // The same with the blocks rounded to f32 where they are stored.
        let rounded: Vec<f32> = blocks.iter().map(|&v| v as f32).collect();
        asm.gather_blocks(&rounded, &mut a);
        let mut ordered32 = vec![0.0f32; asm.ordered_buffer_len()];
        asm.par_write_ordered(&mut ordered32, &mut tag, 1, |range, _, sink| {
            for e in range {
                sink.put(e, &blocks[per * e..per * (e + 1)], |v| v as f32);
            }
        });
        asm.gather_ordered(&ordered32, &mut b);
        assert_eq!(a.values(), b.values(), "f32");
    }
    // Springs (negated blocks) on a 3-D grid: 3 * 12 * 11 * 10 = 3,960 pairs.
    let pairs = grid_pairs(&[12, 11, 10]);
    check(12 * 11 * 10, &pairs, LocalLayout::pair());
    // Tetrahedra with symmetric local matrices (transposed blocks), 6 per cube of a
    // 14 x 6 x 5 grid (2,520 elements, three chunks), vertex orders mixed.
    let mesh = largestep::fem::mesh::box_mesh([14, 6, 5], [1.0, 0.5, 0.4], [0.0; 3]);
    let tets: Vec<[u32; 4]> = (mesh.tets.iter().enumerate())
        .map(|(e, t)| {
            if e % 3 == 1 {
                [t[2], t[0], t[3], t[1]]
            } else {
                *t
            }
        })
        .collect();
    check(mesh.positions.len(), &tets, LocalLayout::symmetric(4));
    check(mesh.positions.len(), &tets, LocalLayout::dense(4));
    // The symmetric layout stores the blocks of slots on and above the diagonal only
    // (10 of 16 a tetrahedron) and mirrors the rest; the dense one, whose blocks need
    // not be symmetric, stores all 16.
    let len = |layout| {
        let asm = ElementAssembly::new(mesh.positions.len(), &tets, layout).unwrap();
        asm.with_ordered().ordered_buffer_len() / 9
    };
    assert_eq!(len(LocalLayout::symmetric(4)), 10 * tets.len());
    assert_eq!(len(LocalLayout::dense(4)), 16 * tets.len());
}

#[test]
#[should_panic(expected = "outside the chunk")]
fn an_ordered_chunk_stores_its_own_elements_only() {
    let pairs = grid_pairs(&[40, 40]);
    let asm = ElementAssembly::new(1600, &pairs, LocalLayout::pair())
        .unwrap()
        .with_ordered();
    let mut ordered = vec![0.0; asm.ordered_buffer_len()];
    let mut none = vec![(); pairs.len()];
    asm.par_write_ordered(&mut ordered, &mut none, 1, |range, _, sink| {
        // Every chunk claims the last element: a race the check refuses.
        let _ = range;
        sink.put(pairs.len() - 1, &[1.0; 9], |v| v);
    });
}

/// An SPD matrix over `pairs` on `n` vertices: each pair the element `[[I, -I], [-I, I]]`,
/// plus `0.1 I` on the diagonal (vertices in no pair are their own components).
fn pairs_spd(n: usize, pairs: &[[u32; 2]]) -> Bsr3 {
    let asm = ElementAssembly::new(n, pairs, LocalLayout::pair()).unwrap();
    let mut blocks = vec![0.0; asm.block_buffer_len()];
    for e in 0..pairs.len() {
        for d in 0..3 {
            blocks[9 * e + 4 * d] = 1.0;
        }
    }
    let mut a = Bsr3::zeros(asm.pattern().clone());
    asm.gather_blocks(&blocks, &mut a);
    a.add_diagonal(&vec![0.1; n]);
    a
}

#[test]
fn every_fill_ordering_solves_and_the_default_takes_the_better() {
    use largestep::sparse::order::{dof_permutation, nested_dissection, FillOrdering};
    // Two grids side by side with three loose vertices after them: a pattern with
    // several components, which the dissection must number each once.
    let (ga, gb) = (grid_pairs(&[5, 4, 3]), grid_pairs(&[7, 3]));
    let mut pairs = ga.clone();
    pairs.extend(gb.iter().map(|[p, q]| [p + 60, q + 60]));
    let matrices = [
        grid_spd(&[10, 10], 1.0, 0.2),
        grid_spd(&[12, 5, 5], 1.0, 0.2),
        pairs_spd(60 + 21 + 3, &pairs),
        pairs_spd(1, &[]),
    ];
    for ordering in [FillOrdering::NestedDissection, FillOrdering::Auto] {
        let empty = Bsr3Pattern::diagonal(0);
        assert!(ordering.vertex_order(&empty).unwrap().is_empty());
        // 100,000 components (a lumped mass matrix's pattern): found in one pass each,
        // not one per component.
        let loose = Bsr3Pattern::diagonal(100_000);
        let order = ordering.vertex_order(&loose).unwrap();
        let mut seen = vec![false; 100_000];
        order.iter().for_each(|&v| seen[v as usize] = true);
        assert!(seen.iter().all(|&s| s));
    }
    for a in &matrices {
        let n = a.n();
        let order = nested_dissection(a.pattern());
        let mut seen = vec![false; n];
        for &v in &order {
            assert!(!seen[v as usize], "vertex {v} numbered twice");
            seen[v as usize] = true;
        }
        assert!(seen.iter().all(|&s| s), "every vertex numbered");
        let (fwd, inv) = dof_permutation(&order);
        assert!((0..3 * n).all(|i| inv[fwd[i]] == i));
        let b = rhs(n);
        for ordering in [
            FillOrdering::ScalarAmd,
            FillOrdering::VertexAmd,
            FillOrdering::NestedDissection,
            FillOrdering::Auto,
        ] {
            let mut chol = SparseCholesky::with_ordering(a.pattern(), ordering).unwrap();
            chol.factorize(a).unwrap();
            let mut x = b.clone();
            chol.solve_in_place(&mut x).unwrap();
            assert!(residual(a, &x, &b) < 1e-12, "{ordering:?} on {n} vertices");
        }
    }
    // Neither ordering wins everywhere: on a 16^3 lattice the dissection needs a third
    // less work than faer's minimum degree, on a short 40 x 6 x 6 bar a third more; the
    // default (`Auto`) takes the better of the two in both.
    for (dims, dissection_wins) in [([16, 16, 16], true), ([40, 6, 6], false)] {
        let a = grid_spd(&dims, 1.0, 0.2);
        let flops = |o| {
            SparseCholesky::with_ordering(a.pattern(), o)
                .unwrap()
                .factor_flops()
        };
        let (nd, amd, auto) = (
            flops(FillOrdering::NestedDissection),
            flops(FillOrdering::VertexAmd),
            flops(FillOrdering::Auto),
        );
        assert_eq!(
            nd < amd,
            dissection_wins,
            "{dims:?}: dissection {nd:e}, AMD {amd:e}"
        );
        assert_eq!(auto, nd.min(amd), "{dims:?}");
    }
}

#[test]
fn indefinite_matrices_give_clear_errors() {
    let mut a = grid_spd(&[4, 4], 1.0, 0.2);
    let n = a.n();
    a.add_diagonal(&vec![-10.0; n]);
    let mut chol = SparseCholesky::new(a.pattern()).unwrap();
    let e = chol.factorize(&a).unwrap_err();
    assert!(matches!(e, SolveError::NotPositiveDefinite { .. }), "{e}");
    for pre in [
        Preconditioner::Jacobi,
        Preconditioner::BlockJacobi,
        Preconditioner::Multigrid,
        Preconditioner::SmoothedAggregation,
    ] {
        let mut pcg = Pcg::new(
            n,
            PcgParams {
                preconditioner: pre,
                ..Default::default()
            },
        );
        let mut x = vec![0.0; 3 * n];
        let e = pcg.solve(&mut a, &rhs(n), &mut x, None).unwrap_err();
        assert!(e.to_string().contains("not positive definite"), "{e}");
    }
    // Indefinite but with a positive diagonal: PCG meets negative curvature.
    let mut b = grid_spd(&[4, 4], 1.0, 0.2);
    for v in b.values_mut() {
        *v = -*v;
    }
    b.add_diagonal(&vec![0.5; n]);
    let mut pcg = Pcg::new(
        n,
        PcgParams {
            preconditioner: Preconditioner::None,
            ..Default::default()
        },
    );
    let mut x = vec![0.0; 3 * n];
    let e = pcg.solve(&mut b, &rhs(n), &mut x, None).unwrap_err();
    assert!(matches!(e, SolveError::NotPositiveDefinite { .. }), "{e}");
}

#[test]
fn pcg_iterates_are_thread_count_independent() {
    let a = grid_spd(&[24, 24, 12], 1.0, 0.05);
    let n = a.n();
    let b = rhs(n);
    let pool = |t| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
    };
    let coords: Vec<f64> = (0..3 * n)
        .map(|i| ((i % n) * (1 + i / n)) as f64 * 0.01)
        .collect();
    for preconditioner in [
        Preconditioner::BlockJacobi,
        Preconditioner::Multigrid,
        Preconditioner::SmoothedAggregation,
    ] {
        let run = || {
            let mut pcg = Pcg::new(
                n,
                PcgParams {
                    preconditioner,
                    ..PcgParams::default()
                },
            );
            pcg.set_coordinates(&coords);
            let mut x = vec![0.0; 3 * n];
            let info = pcg.solve(&mut a.clone(), &b, &mut x, None).unwrap();
            (x, info.iterations, info.residual)
        };
        let one = pool(1).install(run);
        let two = pool(2).install(run);
        assert!(
            one == two,
            "{preconditioner:?}: bitwise identical with 1 and 2 threads"
        );
    }
}

#[test]
fn fused_residual_is_b_minus_a_x() {
    let a = grid_spd(&[30, 20], 1.0, 0.1);
    let n = a.n();
    let x: Vec<f64> = (0..3 * n).map(|i| (i as f64 * 0.37).sin()).collect();
    let b = rhs(n);
    let mut ax = vec![0.0; 3 * n];
    a.spmv(&mut ax, &x);
    let mut r = vec![0.0; 3 * n];
    a.residual(&mut r, &x, &b);
    for i in 0..3 * n {
        assert_eq!(r[i], b[i] - ax[i], "entry {i}");
    }
}

#[test]
fn multigrid_levels_shrink_to_a_small_coarsest_level() {
    let mut a = grid_spd(&[64, 64], 1.0, 0.05);
    let n = a.n();
    let mut pcg = Pcg::new(
        n,
        PcgParams {
            preconditioner: Preconditioner::Multigrid,
            ..Default::default()
        },
    );
    let mut x = vec![0.0; 3 * n];
    pcg.solve(&mut a, &rhs(n), &mut x, None).unwrap();
    let sizes = pcg.multigrid().level_sizes();
    assert_eq!(sizes[0], n);
    assert!(
        sizes.windows(2).all(|w| 4 * w[1] <= w[0]),
        "each level at most a quarter of the one above: {sizes:?}"
    );
    assert!(*sizes.last().unwrap() <= largestep::solve::multigrid::COARSEST);
    assert!(residual(&a, &x, &rhs(n)) < 1e-7);
}

#[test]
fn rank_one_assembly_equals_the_dense_sum_of_weighted_outer_products() {
    // Hinge-like elements of four vertices on a 5 x 4 vertex grid, the (2, 3) pair left
    // out and its weight moved to (2, 2) and (3, 3), as the cloth's decoupled hinges do.
    let (nx, ny) = (5u32, 4u32);
    let n = (nx * ny) as usize;
    let mut elements = Vec::new();
    for y in 0..ny - 1 {
        for x in 0..nx - 1 {
            let v = y * nx + x;
            elements.push([v, v + nx + 1, v + 1, v + nx]);
        }
    }
    let weight = |p: usize, q: usize| match (p, q) {
        (2, 3) | (3, 2) => 0.0,
        (2, 2) | (3, 3) => 2.0,
        _ => 1.0,
    };
    // The two triangles of each element: their pattern holds every weighted pair.
    let mut all: Vec<[u32; 3]> = elements.iter().map(|e| [e[0], e[1], e[2]]).collect();
    all.extend(elements.iter().map(|e| [e[0], e[1], e[3]]));
    let pattern = std::sync::Arc::new(Bsr3Pattern::from_elements(n, &all).unwrap());
    let asm = RankOneAssembly::with_pattern(pattern.clone(), &elements, weight).unwrap();
    let g: Vec<f64> = (0..asm.vector_buffer_len())
        .map(|i| ((i * 7919) % 113) as f64 / 57.0 - 1.0)
        .collect();
    let mut a = Bsr3::zeros(pattern);
    a.add_diagonal(&vec![1.0; n]);
    asm.gather_add(&g, -2.5, &mut a);
    let m = 3 * n;
    let mut want = vec![0.0; m * m];
    for i in 0..n {
        for c in 0..3 {
            want[(c * n + i) * m + c * n + i] = 1.0;
        }
    }
    for (e, el) in elements.iter().enumerate() {
        for p in 0..4 {
            for q in 0..4 {
                for r in 0..3 {
                    for c in 0..3 {
                        let (row, col) = (r * n + el[p] as usize, c * n + el[q] as usize);
                        want[row * m + col] +=
                            -2.5 * weight(p, q) * g[12 * e + 3 * p + r] * g[12 * e + 3 * q + c];
                    }
                }
            }
        }
    }
    let got = a.to_dense();
    let err = got
        .iter()
        .zip(&want)
        .fold(0.0f64, |w, (x, y)| w.max((x - y).abs()));
    assert!(err < 1e-13, "largest difference {err}");
    assert!(a.max_asymmetry() < 1e-15);
}

/// Both multigrids (the aggregation one and the smoothed aggregation) smooth the fine
/// level with an `f32` copy of the matrix; a matrix whose values overflow `f32` falls back
/// to the `f64` values and still converges, in the iterations the same system scaled into
/// range takes.
#[test]
fn multigrid_falls_back_to_f64_when_values_overflow_f32() {
    let a = grid_spd(&[24, 24], 1.0, 0.05);
    let n = a.n();
    let b = rhs(n);
    for preconditioner in [
        Preconditioner::Multigrid,
        Preconditioner::SmoothedAggregation,
    ] {
        let solve = |scale: f64| {
            let mut m = a.clone();
            m.values_mut().iter_mut().for_each(|v| *v *= scale);
            let mut pcg = Pcg::new(
                n,
                PcgParams {
                    tolerance: 1e-10,
                    max_iterations: 500,
                    preconditioner,
                },
            );
            let mut x = vec![0.0; 3 * n];
            let info = pcg.solve(&mut m, &b, &mut x, None).unwrap();
            assert!(residual(&m, &x, &b) < 1e-9 * b.iter().map(|v| v.abs()).fold(0.0, f64::max));
            assert!(x.iter().all(|v| v.is_finite()));
            (info.iterations, pcg.iteration_bytes(&m))
        };
        let (its, bytes) = solve(1.0);
        let (its_big, bytes_big) = solve(1e40);
        assert!(
            its_big.abs_diff(its) <= 1,
            "{preconditioner:?}: {its} vs {its_big} iterations"
        );
        // The fallback reads the f64 values on the fine level: more bytes per iteration.
        assert!(
            bytes_big > bytes,
            "{preconditioner:?}: {bytes} vs {bytes_big}"
        );
    }
}

/// PCG with products through the multigrid's `f32` copy (`Pcg::set_rounded_products`) on
/// a matrix that is positive definite but whose rounding is not: per component
/// `[[1 + 0.49u, 1 + 0.51u], [1 + 0.51u, 1 + 0.9u]]` (u = 2^-23, f32's spacing above 1)
/// rounds to `[[1, 1 + u], [1 + u, 1 + u]]`, determinant `-u (1 + u)`. The right-hand
/// side lies along the rounded matrix's negative direction. With smoothed aggregation the
/// rounded products meet negative curvature at the first iteration (with the fallback
/// taken out this solve fails, `p.Ap = -1.4e-5`), and the solve must run again with the
/// matrix's own values and converge; aggregation multigrid's directions happen to pass.
#[test]
fn rounded_products_that_lose_definiteness_fall_back_to_the_matrix() {
    let u = f64::from(f32::EPSILON);
    let (a11, a12, a22) = (1.0 + 0.49 * u, 1.0 + 0.51 * u, 1.0 + 0.9 * u);
    assert!(a11 * a22 - a12 * a12 > 0.0, "definite in f64");
    let r = |v: f64| f64::from(v as f32);
    assert!(
        r(a11) * r(a22) - r(a12) * r(a12) < 0.0,
        "indefinite once rounded"
    );
    let pattern = std::sync::Arc::new(Bsr3Pattern::from_elements(2, &[[0u32, 1]]).unwrap());
    let mut a = Bsr3::zeros(pattern.clone());
    for (i, j, v) in [(0, 0, a11), (0, 1, a12), (1, 0, a12), (1, 1, a22)] {
        let slot = pattern.slot(i, j).unwrap();
        for c in 0..3 {
            a.block_mut(slot)[4 * c] = v;
        }
    }
    // Component-major: (x0, x1, y0, y1, z0, z1), each component (1, -1).
    let b = [1.0, -1.0, 1.0, -1.0, 1.0, -1.0];
    for preconditioner in [
        Preconditioner::Multigrid,
        Preconditioner::SmoothedAggregation,
    ] {
        let mut pcg = Pcg::new(
            2,
            PcgParams {
                tolerance: 1e-6,
                max_iterations: 100,
                preconditioner,
            },
        );
        pcg.set_rounded_products(true);
        let mut x = [0.0; 6];
        let mut m = a.clone();
        let info = pcg.solve(&mut m, &b, &mut x, None);
        assert!(info.is_ok(), "{preconditioner:?}: {info:?}");
        let res = residual(&a, &x, &b);
        assert!(res < 1e-5, "{preconditioner:?}: relative residual {res:e}");
        // The exact answer is large (the matrix is nearly singular): x0 = (a22 + a12) / det.
        let x0 = (a22 + a12) / (a11 * a22 - a12 * a12);
        assert!(
            (x[0] - x0).abs() < 1e-3 * x0,
            "{preconditioner:?}: {} against {x0}",
            x[0]
        );
    }
}
