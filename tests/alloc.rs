//! No hidden allocation: after setup and a first call, Cholesky refactorizations and
//! solves, PCG solves and whole time steps (explicit and implicit) allocate nothing; the
//! narrow phase (GJK, EPA, box SAT) allocates nothing at all; Witkin's constrained
//! particles allocate nothing after their first step.
//!
//! A counting global allocator sees every thread, so this binary holds one test and runs
//! the checks in sequence, inside the rayon pool (jobs injected from outside a pool may
//! allocate queue blocks in rayon itself, which is not ours to count).

use largestep::integrate::{LinearSolverKind, MechSettings, Method};
use largestep::mass_spring::{grid, GridOptions};
use largestep::simulation::MechSimulation;
use largestep::solve::{Pcg, PcgParams, Preconditioner, SparseCholesky};
use largestep::sparse::examples::grid_spd;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_during(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    f();
    ALLOCATIONS.load(Ordering::SeqCst) - before
}

#[test]
fn steady_state_work_does_not_allocate() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    pool.install(|| {
        // Cholesky: refactorize with new values, solve.
        let a = grid_spd(&[30, 30], 1.0, 0.1);
        let n = a.n();
        let mut b2 = a.clone();
        for v in b2.values_mut() {
            *v *= 1.5;
        }
        let mut chol = SparseCholesky::new(a.pattern()).unwrap();
        let mut x = vec![1.0; 3 * n];
        chol.factorize(&a).unwrap();
        chol.solve_in_place(&mut x).unwrap();
        let count = allocations_during(|| {
            for m in [&b2, &a, &b2] {
                chol.factorize(m).unwrap();
                chol.solve_in_place(&mut x).unwrap();
            }
        });
        assert_eq!(
            count, 0,
            "Cholesky refactorization and solve allocated {count} times"
        );

        // PCG.
        let mut a = grid_spd(&[40, 40, 4], 1.0, 0.05);
        let n = a.n();
        let b = vec![1.0; 3 * n];
        let coords = vec![0.5; 3 * n];
        for preconditioner in [
            Preconditioner::BlockJacobi,
            Preconditioner::Multigrid,
            Preconditioner::SmoothedAggregation,
        ] {
            let mut pcg = Pcg::new(
                n,
                PcgParams {
                    preconditioner,
                    ..PcgParams::default()
                },
            );
            let mut x = vec![0.0; 3 * n];
            // The first solve builds the multigrid hierarchy for this pattern.
            pcg.solve(&mut a, &b, &mut x, None).unwrap();
            pcg.set_coordinates(&coords);
            let count = allocations_during(|| {
                x.fill(0.0);
                pcg.set_coordinates(&coords);
                pcg.solve(&mut a, &b, &mut x, None).unwrap();
            });
            assert_eq!(count, 0, "PCG ({preconditioner:?}) allocated {count} times");
        }

        // Whole steps of a pinned spring grid, each method with each linear solver.
        let mut desc = grid(&GridOptions {
            nu: 20,
            nv: 20,
            size: [1.0, 1.0],
            origin: [0.0; 3],
            u_axis: [1.0, 0.0, 0.0],
            v_axis: [0.0, 0.0, 1.0],
            total_mass: 0.5,
            structural: 200.0,
            shear: 50.0,
            bend: 1.0,
            damping: 0.02,
        });
        desc.gravity = [0.0, -9.81, 0.0];
        desc.pinned = vec![0, 19];
        desc.definiteness_fix = true;
        for method in Method::ALL {
            for linear in [
                LinearSolverKind::Cholesky,
                LinearSolverKind::Pcg(PcgParams::default()),
            ] {
                let (m, st) = desc.build().unwrap();
                let mut settings = MechSettings::new(method);
                settings.linear = linear;
                let mut sim = MechSimulation::new(m, st, settings).unwrap();
                let h = if method.is_implicit() {
                    1.0 / 120.0
                } else {
                    2e-4
                };
                sim.step(h).unwrap();
                let count = allocations_during(|| {
                    for _ in 1..4 {
                        sim.step(h).unwrap();
                    }
                });
                assert_eq!(
                    count, 0,
                    "{method} with {linear:?} allocated {count} times in 3 steps"
                );
                if !method.is_implicit() {
                    break; // the linear solver is irrelevant
                }
            }
        }

        // Narrow phase, from the first call: boxes overlapping (EPA) to apart (GJK),
        // capsules and hulls overlapping and apart, and the boxes' SAT.
        use largestep::kernels::collide::narrow::{box_box, gjk_epa, Convex};
        let ax = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let (c, s) = (0.8f64.cos(), 0.8f64.sin());
        let bx = [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]];
        let cube: Vec<[f64; 3]> = (0..8)
            .map(|k| [(k & 1) as f64, ((k >> 1) & 1) as f64, ((k >> 2) & 1) as f64])
            .collect();
        let moved: Vec<Vec<[f64; 3]>> = [0.4, 0.9, 2.5]
            .iter()
            .map(|&d| {
                cube.iter()
                    .map(|p| [p[0] + d, p[1] + 0.3 * d, p[2] - 0.2])
                    .collect()
            })
            .collect();
        let mut contacts = 0;
        let count = allocations_during(|| {
            for (k, off) in [0.4, 0.9, 2.5].into_iter().enumerate() {
                let cb = [off, 0.2, 0.1];
                let a = Convex::Box {
                    center: [0.0; 3],
                    axes: ax,
                    half: [0.5; 3],
                };
                let b = Convex::Box {
                    center: cb,
                    axes: bx,
                    half: [0.5, 0.3, 0.4],
                };
                contacts += gjk_epa(&a, &b).is_some() as usize;
                let sat = box_box([0.0; 3], ax, [0.5; 3], cb, bx, [0.5, 0.3, 0.4]);
                contacts += sat.depth.is_finite() as usize;
                let ca = Convex::Capsule {
                    a: [0.0; 3],
                    b: [0.0, 1.0, 0.0],
                    radius: 0.3,
                };
                let cc = Convex::Capsule {
                    a: [off, 0.0, 0.1],
                    b: [off, 1.0, 0.5],
                    radius: 0.3,
                };
                contacts += gjk_epa(&ca, &cc).is_some() as usize;
                contacts +=
                    gjk_epa(&Convex::Hull(&cube), &Convex::Hull(&moved[k])).is_some() as usize;
                // Polytope manifolds (support features clipped) on the stack too.
                contacts += largestep::kernels::collide::manifold::convex_convex(
                    &Convex::Hull(&cube),
                    &Convex::Hull(&moved[k]),
                    f64::INFINITY,
                )
                .is_some() as usize;
            }
        });
        assert_eq!(contacts, 15);
        assert_eq!(count, 0, "the narrow phase allocated {count} times");

        // Witkin's constrained particles: a double pendulum and a bead on a wire, each
        // integrator, three steps after the first.
        use largestep::rigid::witkin::{
            Constraint, Witkin, WitkinIntegrator, WitkinState, WitkinWork,
        };
        for integrator in [
            WitkinIntegrator::ExplicitEuler,
            WitkinIntegrator::SymplecticEuler,
            WitkinIntegrator::Rk4,
        ] {
            let w = Witkin {
                inv_mass: vec![1.0, 1.0, 2.0],
                constraints: vec![
                    Constraint::Anchor {
                        a: 0,
                        point: [0.0; 3],
                        length: 1.0,
                    },
                    Constraint::Distance {
                        a: 0,
                        b: 1,
                        length: 1.0,
                    },
                    Constraint::Circle {
                        a: 2,
                        center: [0.0, 0.0, 3.0],
                        normal: [0.0, 0.0, 1.0],
                        radius: 1.0,
                    },
                ],
                gravity: [0.0, -9.81, 0.0],
                ks: 10.0,
                kd: 1.0,
                integrator,
            };
            let mut s = WitkinState {
                x: vec![[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.0, 3.0]],
                v: vec![[0.0; 3]; 3],
                ..WitkinState::default()
            };
            let mut work = WitkinWork::default();
            w.step(&mut s, &mut work, 1e-3).unwrap();
            let count = allocations_during(|| {
                for _ in 0..3 {
                    w.step(&mut s, &mut work, 1e-3).unwrap();
                    std::hint::black_box(w.drift_with(&s.x, &mut work));
                }
            });
            assert_eq!(count, 0, "Witkin ({integrator:?}) allocated {count} times");
        }
    });
}
