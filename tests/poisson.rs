//! The grid Poisson solver of the pressure projection (`solve::poisson`, issue 17).

use largestep::solve::{
    CellKind, GridPoisson, PoissonParams, PoissonPreconditioner, Precision, Side,
};
use std::f64::consts::PI;

/// The unit cube's m^3 interior cells (spacing 1 / (m + 1)) inside a shell of empty
/// cells whose centres lie on the cube's faces: Dirichlet p = 0 there.
fn dirichlet_cube(m: usize) -> ([usize; 3], f64, Vec<CellKind>) {
    let n = m + 2;
    let kind = (0..n * n * n)
        .map(|idx| {
            let c = [idx % n, (idx / n) % n, idx / (n * n)];
            if c.iter().any(|&v| v == 0 || v == n - 1) {
                CellKind::Empty
            } else {
                CellKind::Fluid
            }
        })
        .collect();
    ([n; 3], 1.0 / (m + 1) as f64, kind)
}

fn solve(
    n: [usize; 3],
    h: f64,
    kind: Vec<CellKind>,
    b: &[f64],
    pre: PoissonPreconditioner,
    tolerance: f64,
) -> (Vec<f64>, usize) {
    let mut g = GridPoisson::new(n, h, kind).unwrap();
    let mut p = vec![0.0; b.len()];
    let info = g
        .solve(
            &mut p,
            b,
            &PoissonParams {
                tolerance,
                preconditioner: pre,
                ..PoissonParams::default()
            },
        )
        .unwrap();
    assert!(info.residual <= tolerance);
    (p, info.iterations)
}

/// `-lap p = 3 pi^2 p` for `p = sin(pi x) sin(pi y) sin(pi z)`: the discrete solution's
/// largest error falls four times per halving of h (second order); on a rough right side
/// the multigrid preconditioner's iteration count stays flat while Jacobi's grows.
#[test]
fn manufactured_solution_converges_at_second_order_with_flat_multigrid_iterations() {
    let mut errors = Vec::new();
    let mut mg = Vec::new();
    let mut jacobi = Vec::new();
    for m in [15, 31, 63] {
        let (n, h, kind) = dirichlet_cube(m);
        let nn = n[0];
        let exact: Vec<f64> = (0..nn * nn * nn)
            .map(|idx| {
                let c = [idx % nn, (idx / nn) % nn, idx / (nn * nn)];
                c.iter().map(|&v| (PI * v as f64 * h).sin()).product()
            })
            .collect();
        let b: Vec<f64> = exact.iter().map(|p| 3.0 * PI * PI * p).collect();
        let (p, _) = solve(
            n,
            h,
            kind.clone(),
            &b,
            PoissonPreconditioner::Multigrid,
            1e-10,
        );
        let err = p
            .iter()
            .zip(&exact)
            .zip(&kind)
            .filter(|(_, k)| **k == CellKind::Fluid)
            .map(|((a, e), _)| (a - e).abs())
            .fold(0.0, f64::max);
        errors.push(err);
        // Iterations on a rough right side (the sine is an eigenvector of the discrete
        // operator, which any preconditioner with a constant diagonal solves at once).
        let rough: Vec<f64> = (0..b.len()).map(|i| (i as f64 * 0.61).sin()).collect();
        mg.push(
            solve(
                n,
                h,
                kind.clone(),
                &rough,
                PoissonPreconditioner::Multigrid,
                1e-8,
            )
            .1,
        );
        if m <= 31 {
            jacobi.push(solve(n, h, kind, &rough, PoissonPreconditioner::Jacobi, 1e-8).1);
        }
    }
    for w in errors.windows(2) {
        let ratio = w[0] / w[1];
        assert!((3.5..4.6).contains(&ratio), "errors {errors:?}");
    }
    assert!(mg[2] <= mg[0] + 2, "multigrid iterations {mg:?}");
    assert!(
        jacobi[1] as f64 >= 1.2 * jacobi[0] as f64,
        "Jacobi iterations {jacobi:?}"
    );
    assert!(
        mg[1] * 5 < jacobi[1],
        "multigrid {mg:?} against Jacobi {jacobi:?}"
    );
}

/// Walls all round (the constant null space) and a solid ball inside: a zero-mean right
/// side is solved to the tolerance, a right side with a mean has it removed, the solution
/// has zero mean, and the bits do not depend on the thread count.
#[test]
fn a_closed_box_with_an_obstacle_is_solved_in_the_complement_of_the_constants() {
    let n = 24;
    let kind: Vec<CellKind> = (0..n * n * n)
        .map(|idx| {
            let c = [idx % n, (idx / n) % n, idx / (n * n)];
            let d2: f64 = c.iter().map(|&v| (v as f64 + 0.5 - 12.0).powi(2)).sum();
            if d2 < 25.0 {
                CellKind::Solid
            } else {
                CellKind::Fluid
            }
        })
        .collect();
    let g = GridPoisson::new([n; 3], 0.1, kind.clone()).unwrap();
    assert!(g.is_singular() && g.levels() >= 3);
    let b: Vec<f64> = (0..n * n * n)
        .map(|i| (i as f64 * 0.37).sin() + 0.25)
        .collect();
    let run = || {
        solve(
            [n; 3],
            0.1,
            kind.clone(),
            &b,
            PoissonPreconditioner::Multigrid,
            1e-9,
        )
    };
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(run);
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(run);
    assert_eq!(one, two);
    let (p, its) = one;
    let fluid: Vec<usize> = (0..p.len())
        .filter(|&i| kind[i] == CellKind::Fluid)
        .collect();
    let mean = fluid.iter().map(|&i| p[i]).sum::<f64>() / fluid.len() as f64;
    assert!(mean.abs() < 1e-12 * p.iter().fold(0.0f64, |a, v| a.max(v.abs())));
    // The residual against b with its mean removed.
    let bmean = fluid.iter().map(|&i| b[i]).sum::<f64>() / fluid.len() as f64;
    let mut ap = vec![0.0; p.len()];
    g.apply(&mut ap, &p);
    let (mut r2, mut b2) = (0.0, 0.0);
    for &i in &fluid {
        r2 += (b[i] - bmean - ap[i]).powi(2);
        b2 += (b[i] - bmean).powi(2);
    }
    assert!(
        r2.sqrt() <= 1e-9 * b2.sqrt() * 1.0001,
        "{}",
        r2.sqrt() / b2.sqrt()
    );
    let jacobi = solve([n; 3], 0.1, kind, &b, PoissonPreconditioner::Jacobi, 1e-9).1;
    assert!(its * 3 < jacobi, "multigrid {its} against Jacobi {jacobi}");
}

#[test]
fn bad_problems_are_errors() {
    assert!(GridPoisson::new([2, 2, 2], 1.0, vec![CellKind::Fluid; 7]).is_err());
    assert!(GridPoisson::new([2, 2, 2], 0.0, vec![CellKind::Fluid; 8]).is_err());
    assert!(GridPoisson::new([usize::MAX, 2, 2], 1.0, vec![CellKind::Fluid; 8]).is_err());
    let mut g = GridPoisson::new([2, 2, 2], 1.0, vec![CellKind::Fluid; 8]).unwrap();
    let mut p = vec![0.0; 8];
    let mut b = vec![1.0; 8];
    b[3] = f64::NAN;
    let e = g.solve(&mut p, &b, &PoissonParams::default()).unwrap_err();
    assert!(e.to_string().contains("cell 3"), "{e}");
    assert!(g
        .solve(&mut p, &[0.0; 7], &PoissonParams::default())
        .is_err());
}

/// The `f32` V-cycle (the default) against the `f64` one: both reach a tolerance far
/// below `f32`'s precision (CG's vectors are `f64`, and its Polak-Ribiere `beta` absorbs
/// the rounded preconditioner), in about as many iterations, to the same solution; and
/// the single precision solve is deterministic across thread counts too.
#[test]
fn the_single_precision_cycle_converges_as_the_double_one_does() {
    let (cells, h, kind, b) = largestep::study::poisson_problem(48);
    let sides = [[Side::Wall; 2], [Side::Wall, Side::Open], [Side::Wall; 2]];
    let run = |precision| {
        let mut g = GridPoisson::with_sides(cells, h, kind.clone(), sides).unwrap();
        let mut p = vec![0.0; b.len()];
        let params = PoissonParams {
            tolerance: 1e-11,
            precision,
            ..PoissonParams::default()
        };
        let info = g.solve(&mut p, &b, &params).unwrap();
        assert!(info.residual <= 1e-11, "{precision:?}: {}", info.residual);
        (p, info.iterations)
    };
    let (single, its_single) = run(Precision::Single);
    let (double, its_double) = run(Precision::Double);
    assert!(
        its_single <= its_double + 2,
        "f32 cycle {its_single} iterations, f64 {its_double}"
    );
    let scale = double.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let diff = single
        .iter()
        .zip(&double)
        .fold(0.0f64, |a, (s, d)| a.max((s - d).abs()));
    assert!(
        diff <= 1e-8 * scale,
        "solutions differ by {diff} of {scale}"
    );
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| run(Precision::Single));
    assert_eq!(one, (single, its_single));
}
