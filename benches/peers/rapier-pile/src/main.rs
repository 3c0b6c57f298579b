//! Peer benchmark for largestep's pile of 1,000 boxes (`scenes/rigid-pile.toml`,
//! `benches/rigid.rs`): rapier3d 0.36.1, single-threaded (no `parallel` feature), on the
//! same bodies.
//!
//! The bodies come from `target/criterion/rigid-pile.bin`, written by `cargo bench --bench
//! rigid`: per body eleven little-endian f64, the centre (m), the rotation vector (axis
//! times angle, rad), the half extents (m), density (kg/m^3) and 1 for a static body. The
//! first is the static slab. Friction 0.5, restitution 0 (largestep's defaults), gravity
//! -9.81 m/s^2 along y, dt = 1/60 s, rapier's default solver (4 iterations, soft contacts
//! at 30 Hz), 360 steps (6 s, the scene's duration), each timed with `Instant`. Run with
//! sleeping off (the work largestep does: it has no sleeping) and on (rapier's default).
//!
//! Usage: `cargo run --release [-- PATH]`.

use rapier3d::prelude::*;
use std::time::Instant;

const STEPS: usize = 360;

struct Body {
    center: [f64; 3],
    rotation: [f64; 3],
    half: [f64; 3],
    density: f64,
    fixed: bool,
}

fn read(path: &str) -> Vec<Body> {
    let bytes = std::fs::read(path)
        .unwrap_or_else(|e| panic!("{path}: {e} (run `cargo bench --bench rigid` first)"));
    let v: Vec<f64> = bytes
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    v.chunks_exact(11)
        .map(|b| Body {
            center: [b[0], b[1], b[2]],
            rotation: [b[3], b[4], b[5]],
            half: [b[6], b[7], b[8]],
            density: b[9],
            fixed: b[10] != 0.0,
        })
        .collect()
}

fn run(bodies: &[Body], sleep: bool) {
    let mut world = PhysicsWorld::new();
    world.gravity = Vector::new(0.0, -9.81, 0.0);
    world.integration_parameters.dt = 1.0 / 60.0;
    // The work a step that largestep does (README): `RAPIER_PILE_RECYCLING=0` turns
    // contact recycling off, `RAPIER_PILE_BIAS_FRICTION=1` solves friction in the biased
    // pass too.
    let env = |k: &str, v: &str| std::env::var(k).is_ok_and(|x| x == v);
    let recycling = !env("RAPIER_PILE_RECYCLING", "0");
    let bias_friction = env("RAPIER_PILE_BIAS_FRICTION", "1");
    world.integration_parameters.contact_recycling = recycling;
    world.integration_parameters.friction_in_bias_pass = bias_friction;
    let f = |x: f64| x as Real;
    let mut handles = Vec::new();
    for b in bodies {
        let rb = if b.fixed {
            RigidBodyBuilder::fixed()
        } else {
            RigidBodyBuilder::dynamic().can_sleep(sleep)
        }
        .translation(Vector::new(f(b.center[0]), f(b.center[1]), f(b.center[2])))
        .rotation(Vector::new(
            f(b.rotation[0]),
            f(b.rotation[1]),
            f(b.rotation[2]),
        ));
        let col = ColliderBuilder::cuboid(f(b.half[0]), f(b.half[1]), f(b.half[2]))
            .density(f(b.density))
            .friction(0.5)
            .restitution(0.0);
        handles.push(world.insert(rb, col).0);
    }
    let mut times = Vec::with_capacity(STEPS);
    for _ in 0..STEPS {
        let t = Instant::now();
        world.step();
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let mean = |s: &[f64]| s.iter().sum::<f64>() / s.len() as f64;
    let lowest = handles
        .iter()
        .skip(1)
        .map(|h| world.bodies[*h].translation().y)
        .fold(Real::INFINITY, Real::min);
    let fastest = handles
        .iter()
        .skip(1)
        .map(|h| world.bodies[*h].linvel().length())
        .fold(0.0, Real::max);
    println!(
        "rapier3d 0.36.1{}, {} boxes, sleeping {}: {:.3} ms per step over {STEPS} steps (first 120: {:.3}, last 120: {:.3}); lowest centre {lowest:.3} m, fastest {fastest:.3} m/s at the end",
        match (recycling, bias_friction) {
            (true, false) => "",
            (false, false) => " (contact recycling off)",
            (true, true) => " (friction in both passes)",
            (false, true) => " (contact recycling off, friction in both passes)",
        },
        bodies.len() - 1,
        if sleep { "on" } else { "off" },
        mean(&times),
        mean(&times[..120]),
        mean(&times[STEPS - 120..]),
    );
}

fn main() {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "../../../target/criterion/rigid-pile.bin".into());
    let bodies = read(&path);
    run(&bodies, false);
    run(&bodies, true);
}
