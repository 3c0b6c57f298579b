//! The constraint solver: sub-stepped sequential impulses over contact points and joint
//! rows (see the module docs of [`super`]).
//!
//! A row is a scalar velocity constraint `J u >= target` (contacts) or `J u = target`
//! (joints) over the six velocities of each of its two bodies. An impulse `λ` along it
//! changes them by `M^-1 Jᵀ λ`; its effective mass is `1 / (J M^-1 Jᵀ)`.
//!
//! The step of `dt` is split into `iterations` sub-steps of `h` (Catto's "soft step",
//! Box2D v3, and rapier's small-step TGS): each integrates the velocities, warm-starts and
//! solves every row once with its position error as a bias, integrates the positions, and
//! (soft correction) relaxes: solves once more without the bias, so the bias moves the
//! bodies but leaves no velocity behind. Contact Jacobians and normals are fixed over the
//! step; the penetration is updated every sub-step from the bodies' motion. Restitution is
//! applied once after the sub-steps, to the approach speed at the step's start.
//!
//! Soft constraints (Catto, "Solver2D", 2024): a row with natural frequency `ω` and
//! damping ratio `ζ` over a sub-step `h` aims at `ω / (2ζ + hω)` times its error and
//! scales its impulse by `a2 / (1 + a2)`, `a2 = hω (2ζ + hω)`, less `1 / (1 + a2)` of what
//! it has accumulated: the implicit spring-damper that a rigid row is the limit of.

use super::contact::ContactPoint;
use super::{mat_vec, Correction, Joint, JointKind, Rigid, RigidSolver, RigidState, RigidWork};
use largestep_kernels::quat;
use largestep_kernels::v3::{add, cross, dot, length_and_unit, scale, sub};

/// Baumgarte and split impulses leave this fraction of the feature size unresolved
/// (slop), so resting contacts stay touching and their manifolds stay put.
const SLOP: f64 = 0.005;
/// Soft contacts: natural frequency (Hz, at most a quarter of the sub-step rate) and
/// damping ratio (Box2D v3's defaults).
const CONTACT_HERTZ: f64 = 30.0;
const CONTACT_DAMPING: f64 = 20.0;
/// Soft joints.
const JOINT_HERTZ: f64 = 60.0;
const JOINT_DAMPING: f64 = 5.0;
/// The fastest a soft contact pushes overlapping bodies apart (m/s).
const MAX_PUSH: f64 = 3.0;

/// A soft row's coefficients over a sub-step (module docs).
#[derive(Clone, Copy, Debug)]
struct Soft {
    bias_rate: f64,
    mass_scale: f64,
    impulse_scale: f64,
}

impl Soft {
    fn new(hertz: f64, zeta: f64, h: f64) -> Soft {
        let omega = 2.0 * std::f64::consts::PI * hertz;
        let a1 = 2.0 * zeta + h * omega;
        let a2 = h * omega * a1;
        let a3 = 1.0 / (1.0 + a2);
        Soft {
            bias_rate: omega / a1,
            mass_scale: a2 * a3,
            impulse_scale: a3,
        }
    }

    const RIGID: Soft = Soft {
        bias_rate: 0.0,
        mass_scale: 1.0,
        impulse_scale: 0.0,
    };
}

/// One scalar row between bodies a and b (b = `usize::MAX`: the world).
#[derive(Clone, Copy, Debug, Default)]
struct Row {
    a: usize,
    b: usize,
    /// Jacobian: linear and angular parts for a and b.
    la: [f64; 3],
    aa: [f64; 3],
    lb: [f64; 3],
    ab: [f64; 3],
    /// `M^-1 Jᵀ`, angular parts (the linear ones are the inverse mass times `la`, `lb`).
    ia: [f64; 3],
    ib: [f64; 3],
    /// Effective mass.
    mass: f64,
    /// The position error (joints: the constraint's value, m or rad).
    error: f64,
    /// Accumulated impulse over the present sub-step.
    lambda: f64,
    /// Split impulses: the pseudo impulse.
    plambda: f64,
}

/// Rows of one contact point: the normal and two friction directions, with what the
/// sub-steps need to track the penetration.
#[derive(Clone, Copy, Debug, Default)]
struct ContactRows {
    normal: Row,
    t1: Row,
    t2: Row,
    /// The contact's index in `RigidWork::contacts`.
    index: usize,
    /// The contact point in a's and b's body frames at the step's start.
    anchor_a: [f64; 3],
    anchor_b: [f64; 3],
    /// Penetration at the step's start (m) and the approach speed then (m/s, > 0 closing).
    depth: f64,
    approach: f64,
    /// The largest normal impulse of any sub-step (restitution acts only on contacts
    /// that pushed), and the step's total impulse (N s, normal and tangents).
    max_normal: f64,
    total: [f64; 3],
    /// Baumgarte and split impulses: the error below which nothing is corrected.
    slop: f64,
}

/// The solver's scratch, kept between steps.
#[derive(Clone, Debug, Default)]
pub(crate) struct SolverWork {
    /// Velocities (v, w) of each body during the solve.
    vel: Vec<[[f64; 3]; 2]>,
    /// Split-impulse pseudo-velocities (v, w) of each body in the present sub-step.
    pseudo: Vec<[[f64; 3]; 2]>,
    inv_inertia: Vec<[[f64; 3]; 3]>,
    /// Each body's pose at the step's start.
    x0: Vec<[f64; 3]>,
    q0: Vec<quat::Quat>,
    contacts: Vec<ContactRows>,
    joints: Vec<Row>,
    /// Joint impulses of the last sub-step, for warm starting (rows in a fixed order).
    joint_lambda: Vec<f64>,
}

impl SolverWork {
    #[inline]
    fn push(m: &Rigid, r: &Row, lambda: f64, v: &mut [[[f64; 3]; 2]]) {
        let ima = m.inv_mass[r.a];
        let va = &mut v[r.a];
        va[0] = add(va[0], scale(r.la, ima * lambda));
        va[1] = add(va[1], scale(r.ia, lambda));
        if r.b != usize::MAX {
            let imb = m.inv_mass[r.b];
            let vb = &mut v[r.b];
            vb[0] = add(vb[0], scale(r.lb, imb * lambda));
            vb[1] = add(vb[1], scale(r.ib, lambda));
        }
    }

    /// A row with its `M^-1 Jᵀ` and effective mass.
    fn row(&self, m: &Rigid, a: usize, b: usize, j: [[f64; 3]; 4]) -> Row {
        let [la, aa, lb, ab] = j;
        let ia = mat_vec(self.inv_inertia[a], aa);
        let mut k = m.inv_mass[a] * dot(la, la) + dot(aa, ia);
        let mut ib = [0.0; 3];
        if b != usize::MAX {
            ib = mat_vec(self.inv_inertia[b], ab);
            k += m.inv_mass[b] * dot(lb, lb) + dot(ab, ib);
        }
        Row {
            a,
            b,
            la,
            aa,
            lb,
            ab,
            ia,
            ib,
            mass: if k > 0.0 { 1.0 / k } else { 0.0 },
            ..Row::default()
        }
    }
}

/// A unit vector perpendicular to the unit `n`, and a third completing the frame.
fn tangents(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let a = if n[0].abs() < 0.57 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let t1 = length_and_unit(cross(n, a)).map_or([0.0, 0.0, 1.0], |x| x.1);
    (t1, cross(n, t1))
}

/// What a sub-step's pass does.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Pass {
    /// Velocities with the position errors as biases.
    Solve,
    /// Velocities without biases (soft correction's relax).
    Relax,
    /// Split impulses' pseudo-velocities toward the position errors.
    Pseudo,
}

/// Advances `s` by `dt`: the sub-steps of the module docs over the contacts in
/// `w.contacts` (their impulses written back) and the joints.
pub(crate) fn step(m: &Rigid, s: &mut RigidState, w: &mut RigidWork, dt: f64) {
    let d = m.desc();
    let n = m.len();
    let substeps = d.iterations;
    let h = dt / substeps as f64;
    let sw = &mut w.solver;
    sw.inv_inertia.clear();
    sw.inv_inertia
        .extend((0..n).map(|i| m.inv_inertia_world(i, s.q[i])));
    sw.x0.clone_from(&s.x);
    sw.q0.clone_from(&s.q);
    sw.vel.clear();
    sw.vel.extend((0..n).map(|i| [s.v[i], s.w[i]]));
    sw.pseudo.clear();
    sw.pseudo.resize(n, [[0.0; 3]; 2]);
    let accumulate = d.solver == RigidSolver::SequentialImpulses;
    let penalty = matches!(d.solver, RigidSolver::Penalty { .. });

    // Contact rows, fixed over the step.
    sw.contacts.clear();
    for (index, c) in w.contacts.iter().enumerate() {
        let (a, b) = (c.a as usize, c.b as usize);
        let ra = sub(c.point, s.x[a]);
        let rb = sub(c.point, s.x[b]);
        let jac = |dir: [f64; 3]| {
            [
                scale(dir, -1.0),
                scale(cross(ra, dir), -1.0),
                dir,
                cross(rb, dir),
            ]
        };
        let nrm = c.normal;
        let (t1, t2) = tangents(nrm);
        let mut rows = ContactRows {
            normal: sw.row(m, a, b, jac(nrm)),
            t1: sw.row(m, a, b, jac(t1)),
            t2: sw.row(m, a, b, jac(t2)),
            index,
            anchor_a: quat::rotate_inv(s.q[a], ra),
            anchor_b: quat::rotate_inv(s.q[b], rb),
            depth: c.depth,
            slop: SLOP * m.size[a].min(m.size[b]),
            ..ContactRows::default()
        };
        rows.approach = -relative(&rows.normal, &sw.vel);
        if accumulate {
            // Warm start from last step's impulse per sub-step, inside the cone.
            let per = scale(c.impulse, 1.0 / substeps as f64);
            let ln = dot(per, nrm).max(0.0);
            let (mut l1, mut l2) = (dot(per, t1), dot(per, t2));
            let cap = d.friction * ln;
            let lt = (l1 * l1 + l2 * l2).sqrt();
            if lt > cap {
                let f = if lt > 0.0 { cap / lt } else { 0.0 };
                l1 *= f;
                l2 *= f;
            }
            rows.normal.lambda = ln;
            rows.t1.lambda = l1;
            rows.t2.lambda = l2;
        }
        sw.contacts.push(rows);
    }
    if sw.joint_lambda.len() != joint_row_count(m) {
        sw.joint_lambda = vec![0.0; joint_row_count(m)];
    }

    let contact_soft = Soft::new(CONTACT_HERTZ.min(0.25 / h), CONTACT_DAMPING, h);
    let joint_soft = Soft::new(JOINT_HERTZ.min(0.25 / h), JOINT_DAMPING, h);
    let beta = d.beta.unwrap_or(match d.correction {
        Correction::Soft => 0.0,
        Correction::Split => 0.8,
        Correction::Baumgarte => 0.2,
    });
    let g = dot(d.gravity, d.gravity).sqrt();
    // Approach speeds below gravity's pull over two steps rest rather than bounce.
    let threshold = 2.0 * g * dt + 1e-9;
    let params = Params {
        h,
        beta,
        penalty,
        contact_soft,
        joint_soft,
        correction: d.correction,
        bounce: threshold,
    };
    for _ in 0..substeps {
        // Velocities: gravity and the gyroscopic term.
        for i in 0..n {
            let [v, om] = &mut sw.vel[i];
            m.advance_velocity(i, s.q[i], v, om, h);
        }
        // Joint rows at the present pose.
        sw.joints.clear();
        for j in &m.joints {
            joint_rows(m, s, sw, j);
        }
        // Warm start: each row's impulse of the last sub-step again.
        for k in 0..sw.joints.len() {
            let l = if accumulate { sw.joint_lambda[k] } else { 0.0 };
            sw.joints[k].lambda = l;
            SolverWork::push(m, &sw.joints[k], l, &mut sw.vel);
        }
        for k in 0..sw.contacts.len() {
            let c = &mut sw.contacts[k];
            if !accumulate {
                c.normal.lambda = 0.0;
                c.t1.lambda = 0.0;
                c.t2.lambda = 0.0;
                continue;
            }
            let c = *c;
            SolverWork::push(m, &c.normal, c.normal.lambda, &mut sw.vel);
            SolverWork::push(m, &c.t1, c.t1.lambda, &mut sw.vel);
            SolverWork::push(m, &c.t2, c.t2.lambda, &mut sw.vel);
        }
        // Present penetrations from the motion since the step's start.
        for c in sw.contacts.iter_mut() {
            let (a, b) = (c.normal.a, c.normal.b);
            let pa = add(s.x[a], quat::rotate(s.q[a], c.anchor_a));
            let pb = add(s.x[b], quat::rotate(s.q[b], c.anchor_b));
            let pa0 = add(sw.x0[a], quat::rotate(sw.q0[a], c.anchor_a));
            let pb0 = add(sw.x0[b], quat::rotate(sw.q0[b], c.anchor_b));
            c.normal.error = c.depth - dot(c.normal.lb, sub(sub(pb, pb0), sub(pa, pa0)));
        }
        if penalty {
            penalty_forces(m, sw, &w.contacts, h);
        }
        solve_pass(m, sw, Pass::Solve, params);
        if d.correction == Correction::Split {
            for p in sw.pseudo.iter_mut() {
                *p = [[0.0; 3]; 2];
            }
            for c in sw.contacts.iter_mut() {
                c.normal.plambda = 0.0;
            }
            for r in sw.joints.iter_mut() {
                r.plambda = 0.0;
            }
            solve_pass(m, sw, Pass::Pseudo, params);
        }
        // Positions.
        for i in 0..n {
            s.v[i] = sw.vel[i][0];
            s.w[i] = sw.vel[i][1];
            let [pv, pw] = sw.pseudo[i];
            m.advance_position(s, i, h, pv, pw);
            sw.vel[i] = [s.v[i], s.w[i]];
        }
        if d.correction == Correction::Soft {
            solve_pass(m, sw, Pass::Relax, params);
        }
        for k in 0..sw.joints.len() {
            sw.joint_lambda[k] = sw.joints[k].lambda;
        }
        for c in sw.contacts.iter_mut() {
            c.max_normal = c.max_normal.max(c.normal.lambda);
            c.total = add(
                c.total,
                add(
                    scale(c.normal.lb, c.normal.lambda),
                    add(scale(c.t1.lb, c.t1.lambda), scale(c.t2.lb, c.t2.lambda)),
                ),
            );
        }
    }
    // Restitution: contacts that pushed and were approaching faster than the threshold
    // leave at e times their approach speed (one-shot impulses bounced as they went).
    if d.restitution > 0.0 && accumulate {
        for k in 0..sw.contacts.len() {
            let mut c = sw.contacts[k];
            if c.approach < threshold || c.max_normal == 0.0 {
                continue;
            }
            let vn = relative(&c.normal, &sw.vel);
            let dl = c.normal.mass * (d.restitution * c.approach - vn);
            let new = (c.normal.lambda + dl).max(0.0);
            SolverWork::push(m, &c.normal, new - c.normal.lambda, &mut sw.vel);
            c.total = add(c.total, scale(c.normal.lb, new - c.normal.lambda));
            c.normal.lambda = new;
            sw.contacts[k] = c;
        }
    }
    for i in 0..n {
        if m.is_dynamic(i) {
            s.v[i] = sw.vel[i][0];
            s.w[i] = sw.vel[i][1];
        }
    }
    for r in &sw.contacts {
        let c = &mut w.contacts[r.index];
        c.impulse = r.total;
    }
}

fn joint_row_count(m: &Rigid) -> usize {
    m.joints
        .iter()
        .map(|j| match j.kind {
            JointKind::Ball { .. } => 3,
            JointKind::Hinge { .. } => 5,
            JointKind::Fixed { .. } => 6,
            JointKind::Distance { .. } => 1,
        })
        .sum()
}

/// What every pass of a step shares.
#[derive(Clone, Copy)]
struct Params {
    h: f64,
    beta: f64,
    penalty: bool,
    contact_soft: Soft,
    joint_soft: Soft,
    correction: Correction,
    /// Approach speeds (m/s) above which one-shot impulses bounce.
    bounce: f64,
}

/// One pass over the joints and contacts (see [`Pass`]).
fn solve_pass(m: &Rigid, sw: &mut SolverWork, pass: Pass, p: Params) {
    let Params {
        h,
        beta,
        penalty,
        contact_soft,
        joint_soft,
        correction,
        bounce,
    } = p;
    let d = m.desc();
    let accumulate = d.solver == RigidSolver::SequentialImpulses;
    let SolverWork {
        vel,
        pseudo,
        joints,
        contacts,
        ..
    } = sw;
    // Joints: equalities.
    for r in joints.iter_mut() {
        let (target, soft) = match (pass, correction) {
            (Pass::Pseudo, _) => (-beta * r.error / h, Soft::RIGID),
            (Pass::Relax, _) | (Pass::Solve, Correction::Split) => (0.0, Soft::RIGID),
            (Pass::Solve, Correction::Soft) => (-joint_soft.bias_rate * r.error, joint_soft),
            (Pass::Solve, Correction::Baumgarte) => (-beta * r.error / h, Soft::RIGID),
        };
        if pass == Pass::Pseudo {
            let rel = relative(r, pseudo);
            let dl = r.mass * (target - rel);
            r.plambda += dl;
            SolverWork::push(m, r, dl, pseudo);
        } else {
            let rel = relative(r, vel);
            let dl = r.mass * soft.mass_scale * (target - rel) - soft.impulse_scale * r.lambda;
            r.lambda += dl;
            SolverWork::push(m, r, dl, vel);
        }
    }
    if penalty {
        return;
    }
    for c in contacts.iter_mut() {
        let e = c.normal.error;
        if pass == Pass::Pseudo {
            let target = beta * (e - c.slop).max(0.0) / h;
            if target == 0.0 {
                continue;
            }
            let r = &mut c.normal;
            let dl = r.mass * (target - relative(r, pseudo));
            let new = (r.plambda + dl).max(0.0);
            SolverWork::push(m, r, new - r.plambda, pseudo);
            r.plambda = new;
            continue;
        }
        // Friction first, within Coulomb's cone of the normal impulse so far.
        let cap = d.friction * c.normal.lambda;
        let d1 = c.t1.mass * -relative(&c.t1, vel);
        let d2 = c.t2.mass * -relative(&c.t2, vel);
        let (old1, old2) = (c.t1.lambda, c.t2.lambda);
        let (mut l1, mut l2) = (old1 + d1, old2 + d2);
        let lt = (l1 * l1 + l2 * l2).sqrt();
        if lt > cap {
            let f = if lt > 0.0 { cap / lt } else { 0.0 };
            l1 *= f;
            l2 *= f;
        }
        c.t1.lambda = l1;
        c.t2.lambda = l2;
        SolverWork::push(m, &c.t1, l1 - old1, vel);
        SolverWork::push(m, &c.t2, l2 - old2, vel);
        // Normal: apart, close the gap and no more; overlapping, push out by the bias.
        let (target, soft) = if e < 0.0 {
            (e / h, Soft::RIGID)
        } else {
            match (pass, correction) {
                (Pass::Solve, Correction::Soft) => {
                    ((contact_soft.bias_rate * e).min(MAX_PUSH), contact_soft)
                }
                (Pass::Solve, Correction::Baumgarte) => {
                    (beta * (e - c.slop).max(0.0) / h, Soft::RIGID)
                }
                _ => (0.0, Soft::RIGID),
            }
        };
        let r = &mut c.normal;
        let vn = relative(r, vel);
        // One-shot impulses bounce each approaching contact as they meet it (Guendelman
        // et al. 2003's collision processing): a row of touching balls passes an
        // impact on from one to the next within the pass (Newton's cradle).
        let (target, soft) = if !accumulate && -vn > bounce {
            (target.max(d.restitution * -vn), Soft::RIGID)
        } else {
            (target, soft)
        };
        let dl = r.mass * soft.mass_scale * (target - vn) - soft.impulse_scale * r.lambda;
        let old = r.lambda;
        let new = if accumulate {
            (old + dl).max(0.0)
        } else {
            old + dl.max(0.0)
        };
        r.lambda = new;
        SolverWork::push(m, r, new - old, vel);
    }
}

#[inline]
fn relative(r: &Row, v: &[[[f64; 3]; 2]]) -> f64 {
    let va = &v[r.a];
    let mut s = dot(r.la, va[0]) + dot(r.aa, va[1]);
    if r.b != usize::MAX {
        let vb = &v[r.b];
        s += dot(r.lb, vb[0]) + dot(r.ab, vb[1]);
    }
    s
}

/// Penalty springs at each overlapping contact point over a sub-step `h`.
fn penalty_forces(m: &Rigid, sw: &mut SolverWork, contacts: &[ContactPoint], h: f64) {
    let d = m.desc();
    let RigidSolver::Penalty { stiffness, damping } = d.solver else {
        return;
    };
    // A contact rings at 1/20 of the sub-step rate, critically damped, by default; the
    // pair's overlapping points share the spring (contacts are sorted by pair).
    let omega = 2.0 * std::f64::consts::PI / (20.0 * h);
    let SolverWork {
        vel,
        contacts: rows,
        ..
    } = sw;
    for k in 0..rows.len() {
        let c = rows[k];
        let depth = c.normal.error;
        if depth <= 0.0 {
            continue;
        }
        let p = &contacts[c.index];
        let (a, b) = (p.a as usize, p.b as usize);
        let lo = k.saturating_sub(8);
        let points = rows[lo..(k + 8).min(rows.len())]
            .iter()
            .filter(|q| {
                let o = &contacts[q.index];
                o.a == p.a && o.b == p.b && q.normal.error > 0.0
            })
            .count();
        let light = m.mass[a].min(m.mass[b]) / points.max(1) as f64;
        let ks = stiffness.unwrap_or(light * omega * omega);
        let kd = damping.unwrap_or(2.0 * light * omega);
        let vn = relative(&c.normal, vel);
        let fn_ = (ks * depth - kd * vn).max(0.0);
        let (v1, v2) = (relative(&c.t1, vel), relative(&c.t2, vel));
        let vt = (v1 * v1 + v2 * v2).sqrt();
        let ft = (d.friction * fn_).min(kd * vt);
        let (f1, f2) = if vt > 0.0 {
            (-ft * v1 / vt, -ft * v2 / vt)
        } else {
            (0.0, 0.0)
        };
        SolverWork::push(m, &c.normal, fn_ * h, vel);
        SolverWork::push(m, &c.t1, f1 * h, vel);
        SolverWork::push(m, &c.t2, f2 * h, vel);
        rows[k].normal.lambda = fn_ * h;
        rows[k].t1.lambda = f1 * h;
        rows[k].t2.lambda = f2 * h;
    }
}

/// The rows of joint `j` at the present state, into `sw.joints`.
fn joint_rows(m: &Rigid, s: &RigidState, sw: &mut SolverWork, j: &Joint) {
    let (a, b) = (j.a, j.b);
    let world = b == usize::MAX;
    let ra = quat::rotate(s.q[a], j.la);
    let (rb, pb) = if world {
        ([0.0; 3], j.lb)
    } else {
        let r = quat::rotate(s.q[b], j.lb);
        (r, add(s.x[b], r))
    };
    let pa = add(s.x[a], ra);
    let err = sub(pb, pa);
    let push = |sw: &mut SolverWork, jac: [[f64; 3]; 4], e: f64| {
        let mut r = sw.row(m, a, b, jac);
        r.error = e;
        sw.joints.push(r);
    };
    let linear = |dir: [f64; 3]| {
        [
            scale(dir, -1.0),
            scale(cross(ra, dir), -1.0),
            dir,
            cross(rb, dir),
        ]
    };
    let angular = |dir: [f64; 3]| [[0.0; 3], scale(dir, -1.0), [0.0; 3], dir];
    let axes = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    match j.kind {
        JointKind::Ball { .. } | JointKind::Hinge { .. } | JointKind::Fixed { .. } => {
            for (k, e) in axes.iter().enumerate() {
                push(sw, linear(*e), err[k]);
            }
        }
        JointKind::Distance { .. } => {
            if let Some((len, u)) = length_and_unit(err) {
                push(sw, linear(u), len - j.axis_a[0]);
            } else {
                // Anchors together with a rest length: any direction will do.
                push(sw, linear(axes[1]), -j.axis_a[0]);
            }
        }
    }
    let qb = if world { quat::IDENTITY } else { s.q[b] };
    match j.kind {
        JointKind::Hinge { .. } => {
            let ua = quat::rotate(s.q[a], j.axis_a);
            let ub = quat::rotate(qb, j.axis_b);
            let (p1, p2) = tangents(ua);
            let c = cross(ua, ub);
            push(sw, angular(p1), dot(c, p1));
            push(sw, angular(p2), dot(c, p2));
        }
        JointKind::Fixed { .. } => {
            // The rotation taking the target orientation q_a rel to q_b.
            let e = quat::mul(qb, quat::conj(quat::mul(s.q[a], j.rel)));
            let e = if e[0] < 0.0 { e.map(|c| -c) } else { e };
            let theta = [2.0 * e[1], 2.0 * e[2], 2.0 * e[3]];
            for (k, ax) in axes.iter().enumerate() {
                push(sw, angular(*ax), theta[k]);
            }
        }
        _ => {}
    }
}
