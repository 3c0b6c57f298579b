//! Kernel tests: SIMD bodies against scalar twins, products against dense references,
//! parallel drivers against thread counts, interpolation against the course notes, and
//! spring elements against finite differences.

use largestep::kernels::interp::*;
use largestep::kernels::mass_spring::*;
use largestep::kernels::sparse::*;
use largestep::kernels::vec::*;
use largestep::sparse::examples::grid_spd;
use proptest::prelude::*;

/// `|a - b| <= tol * scale` where `scale` bounds the sum of absolute terms: the error a
/// reordered floating-point sum of `len` terms can have is about `len * eps * scale`.
fn close(a: f64, b: f64, scale: f64, len: usize) -> bool {
    (a - b).abs() <= 4.0 * (len as f64 + 4.0) * f64::EPSILON * scale
}

fn in_pool<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

proptest! {
    #[test]
    fn vector_ops_simd_equal_scalar(
        x in prop::collection::vec(-1e3f64..1e3, 0..67),
        a in -10f64..10.0,
    ) {
        let y0: Vec<f64> = x.iter().map(|v| v * 0.5 - 1.0).collect();
        let (mut y1, mut y2) = (y0.clone(), y0.clone());
        axpy(&mut y1, a, &x);
        axpy_scalar(&mut y2, a, &x);
        prop_assert_eq!(&y1, &y2); // elementwise FMA: identical
        let (mut y1, mut y2) = (y0.clone(), y0.clone());
        xpay(&mut y1, &x, a);
        xpay_scalar(&mut y2, &x, a);
        prop_assert_eq!(&y1, &y2);
        let (mut w1, mut w2) = (vec![0.0; x.len()], vec![0.0; x.len()]);
        waxpy(&mut w1, &x, a, &y0);
        waxpy_scalar(&mut w2, &x, a, &y0);
        prop_assert_eq!(&w1, &w2);
        scale_copy(&mut w1, a, &x);
        scale_copy_scalar(&mut w2, a, &x);
        prop_assert_eq!(&w1, &w2);
        let scale: f64 = x.iter().zip(&y0).map(|(p, q)| (p * q).abs()).sum();
        prop_assert!(close(dot(&x, &y0), dot_scalar(&x, &y0), scale, x.len()));
        prop_assert!(close(dot_par(&x, &y0), dot_scalar(&x, &y0), scale, x.len()));
        let n2: f64 = x.iter().map(|v| v * v).sum();
        prop_assert!(close(norm2(&x).powi(2), norm2_scalar(&x).powi(2), n2, x.len()));
    }

    #[test]
    fn pcg_passes_simd_equal_scalar(
        seed in prop::collection::vec(-1f64..1.0, 3..40),
        alpha in -2f64..2.0,
        beta in 0f64..2.0,
    ) {
        let len = seed.len() / 3 * 3;
        let v = |k: usize| -> Vec<f64> { (0..len).map(|i| seed[(i * 7 + k) % seed.len()] + k as f64 * 0.1).collect() };
        let (p, q) = (v(1), v(2));
        let d: Vec<f64> = v(3).iter().map(|x| 1.0 + x.abs()).collect();
        for dinv in [None, Some(&d[..])] {
            let (mut x1, mut r1) = (v(4), v(5));
            let (mut x2, mut r2) = (x1.clone(), r1.clone());
            let s1 = pcg_update_jacobi(&mut x1, &mut r1, &p, &q, dinv, alpha);
            let s2 = pcg_update_jacobi_scalar(&mut x2, &mut r2, &p, &q, dinv, alpha);
            prop_assert_eq!(&x1, &x2);
            prop_assert_eq!(&r1, &r2);
            let scale: f64 = r1.iter().map(|x| x * x * 3.0).sum();
            prop_assert!(close(s1[0], s2[0], scale, len) && close(s1[1], s2[1], scale, len));
            let (mut p1, mut p2) = (p.clone(), p.clone());
            pcg_direction_jacobi(&mut p1, &r1, dinv, beta);
            pcg_direction_jacobi_scalar(&mut p2, &r1, dinv, beta);
            prop_assert_eq!(&p1, &p2);
        }
        // Block-Jacobi: SPD blocks from a diagonal plus a small symmetric part.
        let n = len / 3;
        let mut binv = vec![0.0; 6 * n];
        for i in 0..n {
            let e = seed[i % seed.len()] * 0.1;
            for (k, val) in [2.0, e, 0.0, 2.0, e, 2.0].into_iter().enumerate() {
                binv[k * n + i] = val;
            }
        }
        let r = v(6);
        let (mut z1, mut z2) = (vec![0.0; len], vec![0.0; len]);
        let a1 = block_jacobi_apply(&mut z1, &r, &binv);
        let a2 = block_jacobi_apply_scalar(&mut z2, &r, &binv);
        for (u, w) in z1.iter().zip(&z2) {
            prop_assert!(close(*u, *w, 3.0 * 2.0 * 2.0, 3));
        }
        let scale: f64 = r.iter().map(|x| x * x * 3.0).sum();
        prop_assert!(close(a1[0], a2[0], scale, len) && close(a1[1], a2[1], scale, len));
    }
}

fn dense_mul(d: &[f64], x: &[f64]) -> Vec<f64> {
    let m = x.len();
    (0..m)
        .map(|r| (0..m).map(|c| d[r * m + c] * x[c]).sum())
        .collect()
}

#[test]
fn spmv_simd_equals_scalar_equals_dense() {
    for dims in [vec![5, 4], vec![3, 4, 5], vec![1]] {
        let a = grid_spd(&dims, 1.3, 0.7);
        let n = a.n();
        let x: Vec<f64> = (0..3 * n)
            .map(|i| ((i * 37 % 101) as f64 - 50.0) / 17.0)
            .collect();
        let reference = dense_mul(&a.to_dense(), &x);
        let mut ys = vec![0.0; 3 * n];
        let mut yw = vec![0.0; 3 * n];
        let mut yp = vec![0.0; 3 * n];
        bsr3_spmv_scalar(&mut ys, a.as_kernel(), &x);
        bsr3_spmv(&mut yw, a.as_kernel(), &x);
        let dot = bsr3_spmv_dot_par(&mut yp, a.as_kernel(), &x);
        let scale = 30.0 * 50.0 / 17.0 * 3.0;
        for i in 0..3 * n {
            assert!(close(ys[i], reference[i], scale, 81), "scalar row {i}");
            assert!(close(yw[i], reference[i], scale, 81), "simd row {i}");
            assert_eq!(yp[i], yw[i], "parallel = serial SIMD row {i}");
        }
        let exact: f64 = x.iter().zip(&reference).map(|(a, b)| a * b).sum();
        assert!((dot - exact).abs() <= 1e-9 * exact.abs().max(1.0));
    }
}

#[test]
fn parallel_drivers_are_thread_count_independent() {
    // Large enough for many chunks.
    let a = grid_spd(&[20, 20, 20], 1.0, 0.1);
    let n = a.n();
    let x: Vec<f64> = (0..3 * n).map(|i| (i as f64 * 0.37).sin()).collect();
    let run = || {
        let mut y = vec![0.0; 3 * n];
        let d = bsr3_spmv_dot_par(&mut y, a.as_kernel(), &x);
        let dd = dot_par(&x, &y);
        (y, d, dd)
    };
    let one = in_pool(1, run);
    let two = in_pool(2, run);
    let four = in_pool(4, run);
    assert!(
        one == two && two == four,
        "bitwise identical across thread counts"
    );
}

#[test]
fn course_notes_bilinear_worked_example() {
    // Unit square, w00 = (0,1), w10 = (2,0), w01 = (0,2), w11 = (2,0); x fastest.
    let g = Grid2 {
        n: [2, 2],
        origin: [0.0, 0.0],
        spacing: [1.0, 1.0],
    };
    let wx = [0.0, 2.0, 0.0, 2.0];
    let wy = [1.0, 0.0, 2.0, 0.0];
    let w = sample2_vec([&wx, &wy], g, [0.3, 0.8]);
    assert!(
        (w[0] - 0.6).abs() < 1e-15 && (w[1] - 1.26).abs() < 1e-15,
        "w(P) = {w:?}"
    );
    assert!((bilinear(0.0, 2.0, 0.0, 2.0, 0.3, 0.8) - 0.6).abs() < 1e-15);
    assert!((sample2(&wy, g, [0.3, 0.8]) - 1.26).abs() < 1e-15);
}

proptest! {
    #[test]
    fn trilinear_is_exact_for_linear_fields(
        c in prop::array::uniform4(-5f64..5.0),
        p in prop::array::uniform3(-1f64..3.0),
    ) {
        let g = Grid3::spanning([4, 3, 5], [-1.0, -0.5, 0.0], [3.0, 2.5, 2.0]);
        let f = |q: [f64; 3]| c[0] + c[1] * q[0] + c[2] * q[1] + c[3] * q[2];
        let mut field = vec![0.0; g.len()];
        for k in 0..5 { for j in 0..3 { for i in 0..4 {
            let q = [g.origin[0] + i as f64 * g.spacing[0], g.origin[1] + j as f64 * g.spacing[1], g.origin[2] + k as f64 * g.spacing[2]];
            field[i + 4 * (j + 3 * k)] = f(q);
        }}}
        // Inside the box the sample is exact; outside it is the value at the clamped point.
        let clamped = [p[0].clamp(-1.0, 3.0), p[1].clamp(-0.5, 2.5), p[2].clamp(0.0, 2.0)];
        let s = sample3(&field, g, p);
        prop_assert!((s - f(clamped)).abs() < 1e-12 * (1.0 + f(clamped).abs()));
        let v = sample3_vec([&field, &field, &field], g, p);
        prop_assert!(v.iter().all(|&x| x == s));
    }
}

#[test]
fn interpolation_propagates_nan_queries() {
    let g = Grid3::spanning([2, 2, 2], [0.0; 3], [1.0; 3]);
    let field = [1.0; 8];
    assert!(sample3(&field, g, [f64::NAN, 0.5, 0.5]).is_nan());
    let mut out = vec![0.0; 3];
    sample3_vec_add(
        &mut out,
        [&field, &field, &field],
        g,
        &[0.5, f64::NAN, 0.5],
        2.0,
    );
    assert!(out.iter().all(|v| v.is_nan()));
}

proptest! {
    #[test]
    fn spring_force_is_minus_energy_gradient_and_jacobian_matches_fd(
        xa in prop::array::uniform3(-1f64..1.0),
        xb in prop::array::uniform3(-1f64..1.0),
        va in prop::array::uniform3(-1f64..1.0),
        vb in prop::array::uniform3(-1f64..1.0),
        k in 0.1f64..100.0,
        kd in 0f64..5.0,
        rest in 0.1f64..2.0,
    ) {
        let l = ((xa[0]-xb[0]).powi(2) + (xa[1]-xb[1]).powi(2) + (xa[2]-xb[2]).powi(2)).sqrt();
        prop_assume!(l > 0.05);
        let p = SpringParams::default();
        let (f, kx, kv) = spring_element(xa, xb, va, vb, k, kd, rest, p);
        let (fe, _, _) = spring_element(xa, xb, va, vb, k, 0.0, rest, p);
        let h = 1e-6;
        for c in 0..3 {
            // Elastic force = -dE/dx_A (central differences).
            let (mut xp, mut xm) = (xa, xa);
            xp[c] += h;
            xm[c] -= h;
            let de = (spring_energy(xp, xb, k, rest) - spring_energy(xm, xb, k, rest)) / (2.0 * h);
            prop_assert!((fe[c] + de).abs() <= 1e-6 * (1.0 + k), "force {} vs -dE {}", fe[c], -de);
            // dF_A/dx_A column c against differences of the elastic force.
            let (fp, _, _) = spring_element(xp, xb, va, vb, k, 0.0, rest, p);
            let (fm, _, _) = spring_element(xm, xb, va, vb, k, 0.0, rest, p);
            for r in 0..3 {
                let fd = (fp[r] - fm[r]) / (2.0 * h);
                prop_assert!((kx[3 * r + c] - fd).abs() <= 1e-5 * (1.0 + k), "K[{r}{c}] {} vs {fd}", kx[3*r+c]);
            }
            // dF_A/dv_A against differences of the full force in v (exact: linear in v).
            let (mut vp, mut vm) = (va, va);
            vp[c] += h;
            vm[c] -= h;
            let (fp, _, _) = spring_element(xa, xb, vp, vb, k, kd, rest, p);
            let (fm, _, _) = spring_element(xa, xb, vm, vb, k, kd, rest, p);
            for r in 0..3 {
                let fd = (fp[r] - fm[r]) / (2.0 * h);
                prop_assert!((kv[3 * r + c] - fd).abs() <= 1e-6 * (1.0 + kd));
            }
        }
        for r in 0..3 { for c in 0..3 {
            prop_assert!((kx[3*r+c] - kx[3*c+r]).abs() <= 1e-12 * k && kv[3*r+c] == kv[3*c+r]);
        }}
        prop_assert!(f.iter().all(|v| v.is_finite()));
        // Definiteness fix: K negative semi-definite (x^T K x <= 0) for any state.
        let (_, kf, _) = spring_element(xa, xb, va, vb, k, kd, rest, SpringParams { definiteness_fix: true });
        for probe in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.3, -0.7, 0.2], xa] {
            let q: f64 = (0..3).map(|r| (0..3).map(|c| probe[r] * kf[3*r+c] * probe[c]).sum::<f64>()).sum();
            prop_assert!(q <= 1e-12 * k);
        }
    }
}

#[test]
fn coincident_spring_endpoints_give_zero_not_nan() {
    let (f, kx, kv) = spring_element(
        [1.0; 3],
        [1.0; 3],
        [0.0; 3],
        [1.0; 3],
        10.0,
        1.0,
        0.5,
        SpringParams::default(),
    );
    assert!(f == [0.0; 3] && kx == [0.0; 9] && kv == [0.0; 9]);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]
    /// The SIMD spring force kernel equals its scalar twin bitwise, with 1 and 3 threads,
    /// including coincident endpoints and a count that leaves a scalar tail.
    #[test]
    fn simd_spring_forces_equal_scalar_bitwise(
        coords in prop::collection::vec(-1f64..1.0, 60..61),
        m in 1usize..40,
        seed in 0u64..1000,
    ) {
        use largestep::kernels::mass_spring::{spring_forces, spring_forces_scalar, Springs};
        let n = 10;
        let x = coords[..30].to_vec();
        let v = coords[30..].to_vec();
        let mut r = seed;
        let mut next = || { r = r.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407); (r >> 33) as usize };
        let ends: Vec<[u32; 2]> = (0..m).map(|e| if e % 7 == 3 { [2, 2] } else { [(next() % n) as u32, (next() % n) as u32] }).collect();
        let k: Vec<f64> = (0..m).map(|e| 10.0 + e as f64).collect();
        let kd: Vec<f64> = (0..m).map(|e| 0.1 * (e % 3) as f64).collect();
        let rest: Vec<f64> = (0..m).map(|e| 0.05 * (e % 5) as f64).collect();
        let s = || Springs { ends: &ends, k: &k, kd: &kd, rest: &rest };
        let mut scalar = vec![0.0; 3 * m];
        spring_forces_scalar(&mut scalar, &x, &v, s());
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let mut simd = vec![1.0; 3 * m];
            pool.install(|| spring_forces(&mut simd, &x, &v, s()));
            prop_assert!(simd.iter().zip(&scalar).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }
}

/// The residual over `f32` block values equals, to the bit, the residual over the same
/// values widened to `f64` (the widening is exact and the products run in `f64` alike),
/// on 1 and 2 threads.
#[test]
fn f32_block_residual_equals_the_f64_residual_of_the_widened_values() {
    let a = grid_spd(&[13, 11], 1.0, 0.05);
    let k = a.as_kernel();
    let v32: Vec<f32> = k.val.iter().map(|v| *v as f32).collect();
    let v64: Vec<f64> = v32.iter().map(|v| *v as f64).collect();
    let n = k.n;
    let x: Vec<f64> = (0..3 * n)
        .map(|i| ((i * 37 % 101) as f64 - 50.0) / 7.0)
        .collect();
    let b: Vec<f64> = (0..3 * n).map(|i| ((i * 13 % 29) as f64) / 3.0).collect();
    let a32 = Bsr3Ref::new(n, k.row_ptr, k.col, &v32[..]);
    let a64 = Bsr3Ref::new(n, k.row_ptr, k.col, &v64[..]);
    for threads in [1, 2] {
        let (mut r32, mut r64) = (vec![f64::NAN; 3 * n], vec![f64::NAN; 3 * n]);
        in_pool(threads, || {
            bsr3_residual_par(&mut r32, a32, &x, &b);
            bsr3_residual_par(&mut r64, a64, &x, &b);
        });
        assert_eq!(r32, r64, "{threads} threads");
    }
    // Half the value bytes.
    assert_eq!(
        a64.spmv_bytes() - a32.spmv_bytes(),
        4 * 9 * a32.nnz_blocks()
    );
}

/// `par::on_pool` runs its work on a thread of the current pool: from outside any pool on
/// one of the global pool's, inside a pool on the calling thread itself (no hand-over).
#[test]
fn on_pool_runs_on_a_pool_thread() {
    use largestep::kernels::par::on_pool;
    assert_eq!(rayon::current_thread_index(), None, "the test's own thread");
    let inside = on_pool(rayon::current_thread_index);
    assert!(inside.is_some(), "on a thread of the global pool");
    let same = in_pool(2, || {
        let here = (rayon::current_thread_index(), std::thread::current().id());
        let there = on_pool(|| (rayon::current_thread_index(), std::thread::current().id()));
        here == there
    });
    assert!(same, "already on a pool thread: runs in place");
    assert_eq!(on_pool(|| 6 * 7), 42);
}
