//! Peer benchmark for largestep's Baraff-Witkin cloth benchmark, in rapier3d 0.36.1.
//!
//! Scene (same as ours): an n x n cloth, 1 m x 1 m, horizontal at y = 0.3 spanning
//! x, z in [-0.5, 0.5], 0.2 kg/m^2 (vertex mass 0.2 / (n-1)^2), vertices 0 and n*n-1
//! (index i + n*j) pinned, gravity -9.81 in y, a fixed sphere of radius 0.25 at the origin.
//! Simulate 0.5 s, then time 20 single steps.
//!
//! Rapier models of that cloth (see README.md):
//! * `joints`: one dynamic rigid body (ball collider, radius 0.4 h, rotations locked) per
//!   vertex, connected by `SpringJointBuilder` springs (k = 1000 N/m, critically damped) on
//!   structural and shear edges; the pinned vertices are fixed bodies.
//! * `softbody`: rapier's own `SoftBodyBuilder::cloth` (particle soft body with structural,
//!   shear and bending distance constraints; its surface collides with the sphere), edge
//!   softness chosen to match a 1000 N/m spring between two vertices; default
//!   `SoftBodySolver::Constraints` (Gauss-Seidel).
//! * `sb-fem` (only with `--features fem`): the same soft body with `SoftBodySolver::Fem`
//!   (implicit Euler, conjugate gradient).
//!
//! Usage: `rapier-cloth-peer [joints|softbody|sb-fem|all] [n ...]` (default: all, n = 32 100 200).
//! Off the recorded table: `RAPIER_CLOTH_SUBSTEPS=k` overrides `num_solver_iterations`,
//! `RAPIER_CLOTH_TRACE=1` prints edge-strain statistics after every settling step (stderr).

use rapier3d::prelude::*;
use std::time::Instant;

const SIZE: Real = 1.0;
const HEIGHT: Real = 0.3;
const AREAL_DENSITY: Real = 0.2;
const SPHERE_RADIUS: Real = 0.25;
const SPRING_K: Real = 1000.0; // N/m per neighbour spring
const DAMPING_RATIO: Real = 1.0; // of one spring between two free vertices
const SETTLE_TIME: f64 = 0.5;
const TIMED_STEPS: usize = 20;
/// Wall-clock budget of one configuration (build + settle + timed steps): past it the
/// configuration is abandoned and the model's remaining configurations are skipped.
const BUDGET_S: f64 = 120.0;

#[derive(Copy, Clone, PartialEq, Eq)]
enum Model {
    Joints,
    SoftBody,
    /// rapier's soft body with the implicit-Euler FEM solver (cargo feature `fem`).
    SoftBodyFem,
}

impl Model {
    fn name(self) -> &'static str {
        match self {
            Model::Joints => "joints",
            Model::SoftBody => "softbody",
            Model::SoftBodyFem => "sb-fem",
        }
    }
}

struct Scene {
    world: PhysicsWorld,
    /// Rigid body per vertex (joints model).
    bodies: Vec<RigidBodyHandle>,
    /// The cloth soft body (softbody model).
    soft: Option<SoftBodyHandle>,
    /// Structural + shear edges (vertex index pairs), for the strain report.
    edges: Vec<[usize; 2]>,
    n_bodies: usize,
    n_joints: usize,
    n_constraints: usize,
}

fn vertex(n: usize, i: usize, j: usize) -> usize {
    i + n * j
}

fn rest_position(n: usize, i: usize, j: usize) -> Vector {
    let h = SIZE / (n - 1) as Real;
    Vector::new(-0.5 * SIZE + i as Real * h, HEIGHT, -0.5 * SIZE + j as Real * h)
}

fn grid_edges(n: usize) -> Vec<[usize; 2]> {
    let mut e = Vec::with_capacity(4 * n * n);
    for j in 0..n {
        for i in 0..n {
            if i + 1 < n {
                e.push([vertex(n, i, j), vertex(n, i + 1, j)]);
            }
            if j + 1 < n {
                e.push([vertex(n, i, j), vertex(n, i, j + 1)]);
            }
            if i + 1 < n && j + 1 < n {
                e.push([vertex(n, i, j), vertex(n, i + 1, j + 1)]);
                e.push([vertex(n, i + 1, j), vertex(n, i, j + 1)]);
            }
        }
    }
    e
}

fn vertex_mass(n: usize) -> Real {
    AREAL_DENSITY / ((n - 1) * (n - 1)) as Real
}

fn base_world(dt: Real) -> PhysicsWorld {
    let mut world = PhysicsWorld::new();
    world.gravity = Vector::new(0.0, -9.81, 0.0);
    world.integration_parameters.dt = dt;
    // Everything else stays at IntegrationParameters::default(), unless overridden (off the
    // recorded table) by RAPIER_CLOTH_SUBSTEPS.
    if let Some(k) = substeps_override() {
        world.integration_parameters.num_solver_iterations = k;
    }
    world
}

fn substeps_override() -> Option<usize> {
    std::env::var("RAPIER_CLOTH_SUBSTEPS").ok().and_then(|v| v.parse().ok())
}

fn sphere_collider() -> ColliderBuilder {
    // Group 2; interacts with everything (cloth particles are group 1 and filter group 2 only).
    ColliderBuilder::ball(SPHERE_RADIUS)
        .collision_groups(InteractionGroups::new(Group::GROUP_2, Group::ALL, InteractionTestMode::And))
}

fn build_joints(n: usize, dt: Real) -> Scene {
    let mut world = base_world(dt);
    world.insert(RigidBodyBuilder::fixed(), sphere_collider());

    let h = SIZE / (n - 1) as Real;
    let m = vertex_mass(n);
    let pinned = [0, n * n - 1];
    // Cloth particles: group 1, collide with group 2 (the sphere) only, never with each other.
    let groups = InteractionGroups::new(Group::GROUP_1, Group::GROUP_2, InteractionTestMode::And);
    let mut bodies = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            let v = vertex(n, i, j);
            let rb = if pinned.contains(&v) {
                RigidBodyBuilder::fixed()
            } else {
                RigidBodyBuilder::dynamic().lock_rotations().can_sleep(false)
            }
            .translation(rest_position(n, i, j));
            let co = ColliderBuilder::ball(0.4 * h).mass(m).collision_groups(groups);
            let (handle, _) = world.insert(rb, co);
            bodies.push(handle);
        }
    }

    // Critical damping of one spring between two free vertices: c = 2 zeta sqrt(k m/2).
    let damping = 2.0 * DAMPING_RATIO * (SPRING_K * 0.5 * m).sqrt();
    let edges = grid_edges(n);
    for &[a, b] in &edges {
        let rest = (world.bodies[bodies[a]].translation() - world.bodies[bodies[b]].translation()).length();
        let joint = SpringJointBuilder::new(rest, SPRING_K, damping).contacts_enabled(false);
        world.insert_impulse_joint(bodies[a], bodies[b], joint);
    }
    let n_joints = edges.len();
    Scene {
        world,
        n_bodies: n * n,
        n_joints,
        n_constraints: n_joints,
        bodies,
        soft: None,
        edges,
    }
}

fn build_softbody(n: usize, dt: Real, fem: bool) -> Scene {
    let mut world = base_world(dt);
    world.insert(RigidBodyBuilder::fixed(), sphere_collider());

    let h = SIZE / (n - 1) as Real;
    let m = vertex_mass(n);
    // rapier's cloth indexes particle (a, b) as a * nv + b at origin + a du + b dv: with
    // du = h z and dv = h x that is b + n a, i.e. our i + n j with i along x, j along z.
    let origin = rest_position(n, 0, 0);
    // Natural frequency of a k = 1000 N/m spring between two vertices of mass m (reduced mass m/2).
    let freq = (SPRING_K / (0.5 * m)).sqrt() / (2.0 * std::f64::consts::PI as Real);
    let builder = SoftBodyBuilder::cloth(origin, Vector::new(0.0, 0.0, h), Vector::new(h, 0.0, 0.0), n, n)
        .particle_mass(m)
        .pinned_particles([0u32, (n * n - 1) as u32])
        .material(SoftBodyMaterial {
            edge_softness: SpringCoefficients::new(freq, DAMPING_RATIO),
            ..Default::default()
        })
        .can_sleep(false);
    #[cfg(feature = "fem")]
    let builder = builder.solver(if fem { SoftBodySolver::Fem } else { SoftBodySolver::Constraints });
    #[cfg(not(feature = "fem"))]
    assert!(!fem, "the sb-fem model needs `--features fem`");
    let n_constraints = builder.edges.len() + builder.bend_edges.len();
    let handle = world.insert_soft_body(builder);
    {
        let sb = &world.soft_bodies[handle];
        assert_eq!(sb.num_particles(), n * n);
        // Check our index convention against rapier's layout.
        let p = sb.particle_position(vertex(n, 1, 0));
        assert!((p - rest_position(n, 1, 0)).length() < 1e-5, "cloth layout mismatch");
    }
    Scene {
        world,
        n_bodies: n * n,
        n_joints: 0,
        n_constraints,
        bodies: Vec::new(),
        soft: Some(handle),
        edges: grid_edges(n),
    }
}

impl Scene {
    fn positions(&self) -> Vec<Vector> {
        match self.soft {
            Some(h) => self.world.soft_bodies[h].particle_positions().collect(),
            None => self.bodies.iter().map(|&b| self.world.bodies[b].translation()).collect(),
        }
    }
}

struct Row {
    model: Model,
    n: usize,
    dt_inv: u32,
    bodies: usize,
    joints: usize,
    constraints: usize,
    build_s: f64,
    settle_s: f64,
    best_ms: f64,
    median_ms: f64,
    finite: bool,
    min_y: Real,
    min_center_dist: Real,
    strain: (Real, Real, Real),
}

/// One configuration; `Err(steps done)` when it ran past `BUDGET_S` before finishing.
fn run(model: Model, n: usize, dt_inv: u32) -> Result<Row, usize> {
    let dt = 1.0 / dt_inv as Real;
    let t0 = Instant::now();
    let mut scene = match model {
        Model::Joints => build_joints(n, dt),
        Model::SoftBody => build_softbody(n, dt, false),
        Model::SoftBodyFem => build_softbody(n, dt, true),
    };
    let build_s = t0.elapsed().as_secs_f64();

    let settle_steps = (SETTLE_TIME * dt_inv as f64).round() as usize;
    let t1 = Instant::now();
    // rapier disables (quarantines) bodies whose state goes non-finite: track it over every step.
    let mut quarantined = false;
    let trace = std::env::var_os("RAPIER_CLOTH_TRACE").is_some();
    for k in 0..settle_steps {
        if t0.elapsed().as_secs_f64() > BUDGET_S {
            return Err(k);
        }
        scene.world.step();
        quarantined |= !scene.world.quarantine().is_empty();
        if trace {
            let (p50, p99, max) = strain_stats(n, &scene.edges, &scene.positions());
            eprintln!("  step {:>3}: strain p50 {p50:.4} p99 {p99:.4} max {max:.3}", k + 1);
        }
    }
    let settle_s = t1.elapsed().as_secs_f64();

    let mut times = Vec::with_capacity(TIMED_STEPS);
    for k in 0..TIMED_STEPS {
        if t0.elapsed().as_secs_f64() > BUDGET_S {
            return Err(settle_steps + k);
        }
        let t = Instant::now();
        scene.world.step();
        times.push(t.elapsed().as_secs_f64() * 1e3);
        quarantined |= !scene.world.quarantine().is_empty();
    }
    times.sort_by(|a, b| a.partial_cmp(b).unwrap());

    let pos = scene.positions();
    let finite = pos.iter().all(|p| p.is_finite()) && !quarantined;
    let min_y = pos.iter().map(|p| p.y).fold(Real::MAX, Real::min);
    let min_center_dist = pos.iter().map(|p| p.length()).fold(Real::MAX, Real::min);
    let strain = strain_stats(n, &scene.edges, &pos);

    Ok(Row {
        model,
        n,
        dt_inv,
        bodies: scene.n_bodies,
        joints: scene.n_joints,
        constraints: scene.n_constraints,
        build_s,
        settle_s,
        best_ms: times[0],
        median_ms: 0.5 * (times[(TIMED_STEPS - 1) / 2] + times[TIMED_STEPS / 2]),
        finite,
        min_y,
        min_center_dist,
        strain,
    })
}

/// Median, 99th percentile and maximum of the engineering strain of the structural/shear edges.
fn strain_stats(n: usize, edges: &[[usize; 2]], pos: &[Vector]) -> (Real, Real, Real) {
    let mut s: Vec<Real> = edges
        .iter()
        .map(|&[a, b]| {
            let rest = (rest_position(n, a % n, a / n) - rest_position(n, b % n, b / n)).length();
            (pos[a] - pos[b]).length() / rest - 1.0
        })
        .collect();
    s.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let at = |q: f64| s[((s.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.99), s[s.len() - 1])
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let models: Vec<Model> = match args.first().map(String::as_str) {
        Some("joints") => vec![Model::Joints],
        Some("softbody") => vec![Model::SoftBody],
        Some("sb-fem") => vec![Model::SoftBodyFem],
        _ if cfg!(feature = "fem") => vec![Model::Joints, Model::SoftBody, Model::SoftBodyFem],
        _ => vec![Model::Joints, Model::SoftBody],
    };
    let mut sizes: Vec<usize> = args.iter().filter_map(|a| a.parse().ok()).collect();
    if sizes.is_empty() {
        sizes = vec![32, 100, 200];
    }

    let p = IntegrationParameters::default();
    println!("rapier3d 0.36.1, default features (dim3, f32, std); parallel (rayon): {}; fem: {}",
        if cfg!(feature = "parallel") { "ON (feature `parallel`)" } else { "off" },
        if cfg!(feature = "fem") { "ON (feature `fem`)" } else { "off" });
    println!(
        "IntegrationParameters defaults: num_solver_iterations (substeps) = {}, num_internal_pgs_iterations = {}, num_internal_stabilization_iterations = {}",
        p.num_solver_iterations, p.num_internal_pgs_iterations, p.num_internal_stabilization_iterations
    );
    if let Some(k) = substeps_override() {
        println!("OVERRIDE: num_solver_iterations = {k} (RAPIER_CLOTH_SUBSTEPS)");
    }
    println!("settle {SETTLE_TIME} s, then {TIMED_STEPS} timed steps; k = {SPRING_K} N/m, damping ratio {DAMPING_RATIO}\n");
    println!(
        "{:<8} {:>4} {:>5} {:>7} {:>7} {:>7} {:>8} {:>9} {:>9} {:>10} {:>9} {:>6} {:>7} {:>7} {:>21}",
        "model", "n", "dt", "bodies", "joints", "constr", "build s", "best ms", "median ms", "steps/s", "settle s", "finite", "min y", "min |x|", "strain p50/p99/max"
    );
    for &model in &models {
        let mut skip_rest = false;
        for &n in &sizes {
            for dt_inv in [60u32, 30] {
                if skip_rest {
                    println!("{:<8} {:>4} {:>5} skipped: an earlier configuration of this model ran over the {BUDGET_S} s budget", model.name(), n, format!("1/{dt_inv}"));
                    continue;
                }
                let t = Instant::now();
                let r = match run(model, n, dt_inv) {
                    Ok(r) => r,
                    Err(done) => {
                        println!(
                            "{:<8} {:>4} {:>5} skipped: over the {BUDGET_S} s budget after {done} of {} steps",
                            model.name(), n, format!("1/{dt_inv}"),
                            (SETTLE_TIME * dt_inv as f64).round() as usize + TIMED_STEPS
                        );
                        skip_rest = true;
                        continue;
                    }
                };
                println!(
                    "{:<8} {:>4} {:>5} {:>7} {:>7} {:>7} {:>8.2} {:>9.3} {:>9.3} {:>10.1} {:>9.2} {:>6} {:>7.3} {:>7.3} {:>6.3}/{:>6.3}/{:>7.3}",
                    r.model.name(), r.n, format!("1/{}", r.dt_inv), r.bodies, r.joints, r.constraints, r.build_s,
                    r.best_ms, r.median_ms, 1e3 / r.median_ms, r.settle_s, r.finite, r.min_y, r.min_center_dist, r.strain.0, r.strain.1, r.strain.2
                );
                if t.elapsed().as_secs_f64() > BUDGET_S {
                    skip_rest = true;
                }
            }
        }
    }
}
