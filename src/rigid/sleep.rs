//! Sleeping: bodies at rest leave the step until something touches them (Box2D's and
//! Bullet's islands, in outline).
//!
//! After each step, every awake dynamic body that moved slower than the thresholds
//! ([`Sleep`]) adds the step to its rest time, and any faster one (or one touched by a
//! moving kinematic body) starts again from zero. The awake dynamic bodies are grouped
//! into islands, the sets joined by contacts and joints (union-find); an island whose
//! every body has rested for [`Sleep::time`] falls asleep together: velocities zeroed, each
//! body tagged with the island. An asleep body is not integrated and meets the solver as a
//! static one; pairs of bodies that are both asleep or fixed get no contacts.
//!
//! Before each step's solve, a contact between an asleep body and a moving one (an awake
//! dynamic body, or a kinematic body with a velocity) wakes the asleep body's whole island,
//! and the contacts are found again with it awake. A body that loses its support wakes
//! with it: they were one island, since they touched when it fell asleep.

use super::{ContactPoint, Rigid, RigidState};
use largestep_kernels::find_root;
use largestep_kernels::v3::dot;

/// When bodies fall asleep (`RigidDesc::sleep`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sleep {
    /// Speed of the centre below which a body counts as resting (m/s).
    pub linear: f64,
    /// Angular speed below which a body counts as resting (rad/s).
    pub angular: f64,
    /// How long every body of an island must rest before the island sleeps (s).
    pub time: f64,
}

impl Default for Sleep {
    /// Box2D v3's defaults (`b2_linearSleepTolerance` 5 cm/s at a 1 m length unit,
    /// `b2_timeToSleep` 0.5 s), with 2 degrees per second of turning.
    fn default() -> Self {
        Sleep {
            linear: 0.05,
            angular: 2f64.to_radians(),
            time: 0.5,
        }
    }
}

/// Whether body i moves this step: an awake dynamic body, or a kinematic one with a
/// velocity.
pub(crate) fn moves(m: &Rigid, s: &RigidState, i: usize) -> bool {
    if m.is_dynamic(i) {
        !s.asleep[i]
    } else {
        s.v[i] != [0.0; 3] || s.w[i] != [0.0; 3]
    }
}

/// Wakes the island of every asleep body that a moving body touches; returns whether any
/// woke (the contacts must then be found again). One pass over the bodies wakes every
/// touched island at once, whatever their number.
pub(crate) fn wake_touched(
    m: &Rigid,
    s: &mut RigidState,
    contacts: &[ContactPoint],
    work: &mut SleepWork,
) -> bool {
    let tags = &mut work.wake;
    tags.clear();
    for c in contacts {
        let (a, b) = (c.a as usize, c.b as usize);
        for (sleeper, other) in [(a, b), (b, a)] {
            if s.asleep[sleeper] && moves(m, s, other) {
                tags.push(s.island[sleeper]);
            }
        }
    }
    if tags.is_empty() {
        return false;
    }
    tags.sort_unstable();
    tags.dedup();
    for i in 0..s.asleep.len() {
        if s.asleep[i] && tags.binary_search(&s.island[i]).is_ok() {
            s.asleep[i] = false;
            s.rest[i] = 0.0;
        }
    }
    true
}

/// Scratch of [`wake_touched`] and [`settle`], kept between steps.
#[derive(Clone, Debug, Default)]
pub(crate) struct SleepWork {
    /// Union-find parents.
    parent: Vec<u32>,
    /// Each island's shortest rest time, at its root.
    shortest: Vec<f64>,
    /// The islands to wake.
    wake: Vec<u64>,
}

/// After a step of `dt`: rest times, then the islands that have all rested long enough
/// fall asleep.
pub(crate) fn settle(
    m: &Rigid,
    s: &mut RigidState,
    contacts: &[ContactPoint],
    work: &mut SleepWork,
    dt: f64,
) {
    let Some(sleep) = m.desc().sleep else {
        return;
    };
    let n = m.len();
    let awake = |s: &RigidState, i: usize| m.is_dynamic(i) && !s.asleep[i];
    for i in 0..n {
        if awake(s, i) {
            let slow = dot(s.v[i], s.v[i]) < sleep.linear * sleep.linear
                && dot(s.w[i], s.w[i]) < sleep.angular * sleep.angular;
            s.rest[i] = if slow { s.rest[i] + dt } else { 0.0 };
        }
    }
    let SleepWork {
        parent, shortest, ..
    } = work;
    parent.clear();
    parent.extend(0..n as u32);
    let join = |parent: &mut Vec<u32>, a: usize, b: usize| {
        let (ra, rb) = (find_root(parent, a as u32), find_root(parent, b as u32));
        // The smaller index is the root: islands come out the same whatever the order.
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        parent[hi as usize] = lo;
    };
    for c in contacts {
        let (a, b) = (c.a as usize, c.b as usize);
        match (awake(s, a), awake(s, b)) {
            (true, true) => join(parent, a, b),
            // A moving kinematic body keeps what it touches awake.
            (true, false) if moves(m, s, b) => s.rest[a] = 0.0,
            (false, true) if moves(m, s, a) => s.rest[b] = 0.0,
            _ => {}
        }
    }
    for j in &m.joints {
        if j.b != usize::MAX && awake(s, j.a) && awake(s, j.b) {
            join(parent, j.a, j.b);
        }
    }
    // Each island's shortest rest, at its root.
    shortest.clear();
    shortest.resize(n, f64::INFINITY);
    for i in (0..n).filter(|&i| awake(s, i)) {
        let r = find_root(parent, i as u32) as usize;
        shortest[r] = shortest[r].min(s.rest[i]);
    }
    for i in 0..n {
        if !awake(s, i) {
            continue;
        }
        let r = find_root(parent, i as u32);
        if shortest[r as usize] >= sleep.time {
            s.asleep[i] = true;
            // The step and the root: a new island never shares a tag with an older one
            // still asleep.
            s.island[i] = (s.steps << 32) | u64::from(r);
            s.v[i] = [0.0; 3];
            s.w[i] = [0.0; 3];
        }
    }
}
