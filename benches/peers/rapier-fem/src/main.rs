//! Peer benchmark for largestep's FEM beam step (`benches/fem.rs`, `fem/step/beam`):
//! rapier3d 0.36.1's FEM soft body (cargo feature `fem`, `SoftBodySolver::Fem`) on the
//! same beam.
//!
//! The beam: 1 m x 0.1 m x 0.1 m along x, 100 x 10 x 10 cubes of 1 cm, each split into six
//! tetrahedra around its main diagonal exactly as largestep's `box_mesh` does (so both
//! engines see the same 12,221 vertices and 60,000 tetrahedra), the vertices at x = 0
//! pinned, gravity -9.81 m/s^2 in y, corotational elasticity E = 10 MPa, nu = 0.3, density
//! 1000 kg/m^3 (lumped masses rho V / 4 per tetrahedron and vertex, as largestep's), dt =
//! 1/60 s. The beam is released straight and sags; after 0.5 s of settling (30 steps),
//! 20 single steps are timed with `Instant`.
//!
//! What rapier computes per step: `num_solver_iterations` (4) substeps, each one linearised
//! implicit Euler solve `(M + h D + h^2 K) dv = b` by conjugate gradient (relative tolerance
//! 1e-5, at most 20 iterations: `SoftFemParameters` defaults), with its corotational cells
//! and elastic damping ratio 1 (its default; 0 is also run). It does not iterate Newton to
//! convergence; the CG cap means the linear solves are truncated on a body this size.
//!
//! Usage: `cargo run --release [-- DAMPING_RATIO]`; `RAPIER_FEM_CG=k` raises the CG cap.

use rapier3d::prelude::*;
use std::time::Instant;

const CELLS: [usize; 3] = [100, 10, 10];
const SIZE: [Real; 3] = [1.0, 0.1, 0.1];
const YOUNG: Real = 1e7;
const POISSON: Real = 0.3;
const DENSITY: Real = 1000.0;
const SETTLE_STEPS: usize = 30;
const TIMED_STEPS: usize = 20;

/// Vertex (i, j, k) of the grid, x fastest (largestep's `box_mesh` numbering).
fn vertex(i: usize, j: usize, k: usize) -> usize {
    let [nx, ny, _] = CELLS;
    i + (nx + 1) * (j + (ny + 1) * k)
}

/// The beam's vertices and tetrahedra: each cube's six tetrahedra around its diagonal from
/// corner (0,0,0) to (1,1,1), one per path along the axes (Freudenthal-Kuhn).
fn beam() -> (Vec<Vector>, Vec<[u32; 4]>) {
    let [nx, ny, nz] = CELLS;
    let h = [SIZE[0] / nx as Real, SIZE[1] / ny as Real, SIZE[2] / nz as Real];
    let mut x = Vec::new();
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                x.push(Vector::new(
                    i as Real * h[0],
                    j as Real * h[1] - 0.5 * SIZE[1],
                    k as Real * h[2] - 0.5 * SIZE[2],
                ));
            }
        }
    }
    let paths: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    let mut tets = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                for p in paths {
                    let mut c = [i, j, k];
                    let mut t = [vertex(c[0], c[1], c[2]) as u32; 4];
                    for (s, &axis) in p.iter().enumerate() {
                        c[axis] += 1;
                        t[s + 1] = vertex(c[0], c[1], c[2]) as u32;
                    }
                    // Positive orientation: an odd permutation of the axes flips the sign.
                    let v = signed_volume(&x, &t);
                    if v < 0.0 {
                        t.swap(2, 3);
                    }
                    tets.push(t);
                }
            }
        }
    }
    (x, tets)
}

fn signed_volume(x: &[Vector], t: &[u32; 4]) -> Real {
    let [a, b, c, d] = t.map(|i| x[i as usize]);
    (b - a).cross(c - a).dot(d - a) / 6.0
}

/// Mean y displacement of the vertices at the free end (x = 1 m).
fn tip(world: &PhysicsWorld, handle: SoftBodyHandle, rest: &[Vector]) -> Real {
    let sb = &world.soft_bodies[handle];
    let [nx, ny, nz] = CELLS;
    let mut s = 0.0;
    for k in 0..=nz {
        for j in 0..=ny {
            let v = vertex(nx, j, k);
            s += sb.particle_position(v).y - rest[v].y;
        }
    }
    s / ((ny + 1) * (nz + 1)) as Real
}

fn run(damping: Real) {
    let t0 = Instant::now();
    let (x, tets) = beam();
    let mut masses = vec![0.0; x.len()];
    for t in &tets {
        let m = 0.25 * DENSITY * signed_volume(&x, t);
        for &i in t {
            masses[i as usize] += m;
        }
    }
    let pinned: Vec<u32> = (0..x.len() as u32).filter(|&i| x[i as usize].x < 1e-6).collect();
    let mut world = PhysicsWorld::new();
    world.gravity = Vector::new(0.0, -9.81, 0.0);
    world.integration_parameters.dt = 1.0 / 60.0;
    if let Some(k) = cg_iterations() {
        world.integration_parameters.soft_bodies.fem.max_linear_iterations = k;
    }
    let builder = SoftBodyBuilder::new(x.clone())
        .cells(tets.clone())
        .masses(masses)
        .pinned_particles(pinned.iter().copied())
        .cell_model(SoftBodyCellModel::Corotational)
        .material(SoftBodyMaterial {
            young_modulus: YOUNG,
            poisson_ratio: POISSON,
            elastic_damping_ratio: damping,
            ..Default::default()
        })
        .solver(SoftBodySolver::Fem)
        .no_surface_collider()
        .can_sleep(false);
    let handle = world.insert_soft_body(builder);
    let build_s = t0.elapsed().as_secs_f64();
    let mut quarantined = false;
    let t1 = Instant::now();
    for _ in 0..SETTLE_STEPS {
        world.step();
        quarantined |= !world.quarantine().is_empty();
    }
    let settle_s = t1.elapsed().as_secs_f64();
    let tip_settled = tip(&world, handle, &x);
    let mut times = Vec::new();
    for _ in 0..TIMED_STEPS {
        let t = Instant::now();
        world.step();
        times.push(t.elapsed().as_secs_f64() * 1e3);
        quarantined |= !world.quarantine().is_empty();
    }
    times.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let sb = &world.soft_bodies[handle];
    let finite = (0..sb.num_particles()).all(|i| sb.particle_position(i).is_finite()) && !quarantined;
    println!(
        "| {damping} | {} | {} | {build_s:.2} | {settle_s:.2} | {:.1} | {:.1} | {tip_settled:.4} | {:.4} | {} |",
        x.len(),
        tets.len(),
        times[0],
        0.5 * (times[(TIMED_STEPS - 1) / 2] + times[TIMED_STEPS / 2]),
        tip(&world, handle, &x),
        if finite { "yes" } else { "no" }
    );
}

/// `RAPIER_FEM_CG=k`: raise the conjugate gradient's iteration cap from its default 20.
fn cg_iterations() -> Option<usize> {
    std::env::var("RAPIER_FEM_CG").ok().and_then(|v| v.parse().ok())
}

fn main() {
    let dampings: Vec<Real> = match std::env::args().nth(1) {
        Some(d) => vec![d.parse().expect("a damping ratio")],
        None => vec![1.0, 0.0],
    };
    let mut p = IntegrationParameters::default();
    if let Some(k) = cg_iterations() {
        p.soft_bodies.fem.max_linear_iterations = k;
    }
    println!(
        "rapier3d 0.36.1 (f32), feature fem, single-threaded; substeps {}, FEM CG tolerance {}, at most {} iterations",
        p.num_solver_iterations, p.soft_bodies.fem.linear_tolerance, p.soft_bodies.fem.max_linear_iterations
    );
    println!("| elastic damping ratio | vertices | tetrahedra | build s | settle s (30 steps) | best ms | median ms | tip y after 0.5 s (m) | tip y after 0.83 s (m) | finite |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for d in dampings {
        run(d);
    }
}
