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

use super::batch::{self, Batcher, Batches, Lanes};
use super::{
    clone_keeping_capacity, mat_vec, Correction, Joint, JointKind, Rigid, RigidIntegrator,
    RigidSolver, RigidState, RigidWork,
};
use largestep_kernels::quat;
use largestep_kernels::rigid;
use largestep_kernels::v3::{add, cross, dot, length_and_unit, scale, sub, tangent_frame};
use wide::f64x4;

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
pub(super) const MAX_PUSH: f64 = 3.0;

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

    /// `(bias_rate, mass_scale, impulse_scale)`, for the batches.
    fn coefficients(self) -> [f64; 3] {
        [self.bias_rate, self.mass_scale, self.impulse_scale]
    }

    const RIGID: Soft = Soft {
        bias_rate: 0.0,
        mass_scale: 1.0,
        impulse_scale: 0.0,
    };
}

/// A body as the solver sees it: its velocities and inverse mass (zero for static,
/// kinematic and asleep bodies), in one 64-byte record that the batches gather whole.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
pub(super) struct SolverBody {
    pub(super) v: [f64; 3],
    pub(super) w: [f64; 3],
    pub(super) inv_mass: f64,
}

/// A body's motion since the step's start: the displacement of its centre, then the
/// rows of `R R0ᵀ - I`, which takes an offset at the start to its change.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(32))]
pub(super) struct SolverMotion(pub(super) [f64; 12]);

/// One scalar joint row between bodies a and b (b = `usize::MAX`: the world).
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
    /// The position error (the constraint's value, m or rad).
    error: f64,
    /// Accumulated impulse over the present sub-step, and the split one.
    lambda: f64,
    plambda: f64,
}

/// One contact point's three rows (normal, two tangents) for penalty springs, in order
/// (the other solvers keep theirs in `batch::Batch`, four points a batch, formed by
/// `batch::fill` with the same formulas).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct ContactRow {
    pub(super) a: u32,
    pub(super) b: u32,
    /// The contact's index in `RigidWork::contacts`.
    pub(super) index: u32,
    /// Normal (a into b) and tangents.
    pub(super) dir: [[f64; 3]; 3],
    /// Each row's angular Jacobian `[ra x d, rb x d]`, and the angular velocity a unit
    /// impulse along it gives each body, `[Ia^-1 (ra x d), Ib^-1 (rb x d)]` (world
    /// inverse inertias, fixed over the step).
    pub(super) arm: [[[f64; 3]; 2]; 3],
    pub(super) turn: [[[f64; 3]; 2]; 3],
    /// The springs' impulses of the present sub-step.
    pub(super) lambda: [f64; 3],
    /// Penetration now (m).
    pub(super) error: f64,
    /// The step's total impulse (N s).
    pub(super) total: [f64; 3],
}

/// The solver's scratch, kept between steps (a clone keeps the capacity of the rows).
#[derive(Debug, Default)]
pub(crate) struct SolverWork {
    /// The bodies, then a padding body for the batches' unused lanes.
    bodies: Vec<SolverBody>,
    /// World inverse inertias, fixed over the step (zero for bodies that cannot move).
    inv_inertia: Vec<[[f64; 3]; 3]>,
    /// Split-impulse pseudo-velocities of each body in the present sub-step.
    pseudo: Vec<SolverBody>,
    /// Each body's position at the step's start (its rotation is `RigidWork::rot`), and
    /// its motion since.
    x0: Vec<[f64; 3]>,
    motion: Vec<SolverMotion>,
    /// Each body's rotation matrix now (the position update keeps it).
    rot: Vec<[[f64; 3]; 3]>,
    contacts: Vec<ContactRow>,
    /// The contacts in SIMD batches (all solvers but penalty springs).
    batches: Batches,
    batcher: Batcher,
    joints: Vec<Row>,
    /// Joint impulses of the last sub-step, for warm starting (rows in a fixed order).
    joint_lambda: Vec<f64>,
}

#[cfg(test)]
impl SolverWork {
    /// Limits the lanes of the batches (see `batch::Batcher::width`).
    pub(crate) fn batcher_width(&mut self, width: u8) {
        self.batcher.width = width;
    }

    /// The batches of the last step.
    pub(crate) fn batch_count(&self) -> usize {
        self.batches.len()
    }
}

impl Clone for SolverWork {
    fn clone(&self) -> Self {
        SolverWork {
            bodies: self.bodies.clone(),
            inv_inertia: self.inv_inertia.clone(),
            pseudo: self.pseudo.clone(),
            x0: self.x0.clone(),
            motion: self.motion.clone(),
            rot: self.rot.clone(),
            contacts: clone_keeping_capacity(&self.contacts),
            batches: self.batches.clone(),
            batcher: self.batcher.clone(),
            joints: self.joints.clone(),
            joint_lambda: self.joint_lambda.clone(),
        }
    }
}

/// The velocity of a contact row along `d` with lever arms `ca = ra x d`, `cb = rb x d`:
/// `d (vb - va) + cb wb - ca wa`.
#[inline(always)]
fn contact_velocity(
    va: &[[f64; 3]; 2],
    vb: &[[f64; 3]; 2],
    d: [f64; 3],
    ca: [f64; 3],
    cb: [f64; 3],
) -> f64 {
    dot(d, sub(vb[0], va[0])) + dot(cb, vb[1]) - dot(ca, va[1])
}

/// Applies the impulse `l` along row r of contact c (`-l` on a, `l` on b).
#[inline(always)]
fn contact_push(
    c: &ContactRow,
    a: &SolverBody,
    b: &SolverBody,
    va: &mut [[f64; 3]; 2],
    vb: &mut [[f64; 3]; 2],
    r: usize,
    l: f64,
) {
    let d = c.dir[r];
    va[0] = sub(va[0], scale(d, a.inv_mass * l));
    va[1] = sub(va[1], scale(c.turn[r][0], l));
    vb[0] = add(vb[0], scale(d, b.inv_mass * l));
    vb[1] = add(vb[1], scale(c.turn[r][1], l));
}

/// The relative velocity along row r of contact c.
#[inline(always)]
fn row_velocity(c: &ContactRow, va: &[[f64; 3]; 2], vb: &[[f64; 3]; 2], r: usize) -> f64 {
    contact_velocity(va, vb, c.dir[r], c.arm[r][0], c.arm[r][1])
}

impl SolverBody {
    #[inline(always)]
    fn vel(&self) -> [[f64; 3]; 2] {
        [self.v, self.w]
    }
}

impl SolverWork {
    /// The velocity of joint row `r`.
    #[inline(always)]
    fn row_velocity(&self, r: &Row, pseudo: bool) -> f64 {
        let get = |i: usize| {
            if pseudo {
                self.pseudo[i].vel()
            } else {
                self.bodies[i].vel()
            }
        };
        let va = get(r.a);
        let mut s = dot(r.la, va[0]) + dot(r.aa, va[1]);
        if r.b != usize::MAX {
            let vb = get(r.b);
            s += dot(r.lb, vb[0]) + dot(r.ab, vb[1]);
        }
        s
    }

    /// Applies the impulse `l` along joint row `r`.
    #[inline(always)]
    fn row_push(&mut self, r: &Row, l: f64, pseudo: bool) {
        for (i, lin, ang) in [(r.a, r.la, r.ia), (r.b, r.lb, r.ib)] {
            if i == usize::MAX {
                continue;
            }
            let im = self.bodies[i].inv_mass;
            let b = if pseudo {
                &mut self.pseudo[i]
            } else {
                &mut self.bodies[i]
            };
            b.v = add(b.v, scale(lin, im * l));
            b.w = add(b.w, scale(ang, l));
        }
    }

    /// A joint row with its `M^-1 Jᵀ` and effective mass.
    fn row(&self, a: usize, b: usize, j: [[f64; 3]; 4]) -> Row {
        let [la, aa, lb, ab] = j;
        let ba = &self.bodies[a];
        let ia = mat_vec(self.inv_inertia[a], aa);
        let mut k = ba.inv_mass * dot(la, la) + dot(aa, ia);
        let mut ib = [0.0; 3];
        if b != usize::MAX {
            let bb = &self.bodies[b];
            ib = mat_vec(self.inv_inertia[b], ab);
            k += bb.inv_mass * dot(lb, lb) + dot(ab, ib);
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

/// What a sub-step's pass does.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Pass {
    /// Velocities with the position errors as biases.
    Solve,
    /// Velocities without biases (soft correction's relax).
    Relax,
    /// Split impulses' pseudo-velocities toward the position errors.
    Pseudo,
}

fn mat_mul_t(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    // a bᵀ
    let mut out = [[0.0; 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, o) in row.iter_mut().enumerate() {
            *o = dot(a[i], b[j]);
        }
    }
    out
}

/// Advances `s` by `dt`: the sub-steps of the module docs over the contacts in
/// `w.contacts` (their impulses written back) and the joints.
pub(crate) fn step(m: &Rigid, s: &mut RigidState, w: &mut RigidWork, dt: f64) {
    let d = m.desc();
    let n = m.len();
    let substeps = d.iterations;
    let h = dt / substeps as f64;
    let sw = &mut w.solver;
    sw.bodies.clear();
    // Asleep bodies meet the solver as static ones.
    sw.bodies.extend((0..n).map(|i| SolverBody {
        v: s.v[i],
        w: s.w[i],
        inv_mass: if s.asleep[i] { 0.0 } else { m.inv_mass[i] },
    }));
    // The batches' padding body.
    sw.bodies.push(SolverBody::default());
    sw.inv_inertia.clear();
    sw.inv_inertia.extend((0..n).map(|i| {
        if s.asleep[i] {
            [[0.0; 3]; 3]
        } else {
            m.inv_inertia_world(i, &w.rot[i])
        }
    }));
    sw.x0.clone_from(&s.x);
    sw.rot.clone_from(&w.rot);
    sw.motion.clear();
    sw.motion.resize(n + 1, SolverMotion::default());
    // Pseudo-velocities start at rest (the split passes reset them each sub-step).
    sw.pseudo.clear();
    sw.pseudo.extend(sw.bodies.iter().map(|b| SolverBody {
        inv_mass: b.inv_mass,
        ..SolverBody::default()
    }));
    let accumulate = d.solver == RigidSolver::SequentialImpulses;
    let penalty = matches!(d.solver, RigidSolver::Penalty { .. });

    // Contact rows, fixed over the step: in the batches (`batch::fill`), and for
    // penalty springs also in order, by `make` with the same formulas.
    let SolverWork {
        bodies,
        inv_inertia,
        contacts,
        batches,
        batcher,
        ..
    } = sw;
    let make = |index: usize| {
        let c = &w.contacts[index];
        let (a, b) = (c.a as usize, c.b as usize);
        let ra = sub(c.point, s.x[a]);
        let rb = sub(c.point, s.x[b]);
        let (t1, t2) = tangent_frame(c.normal);
        let (ia, ib) = (inv_inertia[a], inv_inertia[b]);
        let dir = [c.normal, t1, t2];
        // `from_fn`, not `map`: array maps stayed out-of-line calls (`try_map`).
        let arm: [[[f64; 3]; 2]; 3] =
            std::array::from_fn(|r| [cross(ra, dir[r]), cross(rb, dir[r])]);
        let turn: [[[f64; 3]; 2]; 3] =
            std::array::from_fn(|r| [mat_vec(ia, arm[r][0]), mat_vec(ib, arm[r][1])]);
        ContactRow {
            a: c.a,
            b: c.b,
            index: index as u32,
            dir,
            arm,
            turn,
            error: c.depth,
            ..ContactRow::default()
        }
    };
    contacts.clear();
    if penalty {
        contacts.extend((0..w.contacts.len()).map(make));
    }
    batch::build(&w.contacts, bodies, batcher, batches);
    let slop = |c: &super::ContactPoint| SLOP * m.size[c.a as usize].min(m.size[c.b as usize]);
    batch::fill(
        batches,
        &batch::RowInputs {
            points: &w.contacts,
            x: &s.x,
            bodies,
            inv_inertia,
            slop: &slop,
            friction: d.friction,
            substeps,
            accumulate,
        },
    );
    if sw.joint_lambda.len() != joint_row_count(m) {
        sw.joint_lambda = vec![0.0; joint_row_count(m)];
    }

    let contact_soft = Soft::new(CONTACT_HERTZ.min(0.25 / h), CONTACT_DAMPING, h);
    // Against a body that cannot move, twice as stiff (Box2D v3's static softness): the
    // load on it is the whole stack's, with only one body's mass in the row.
    let static_soft = Soft::new((2.0 * CONTACT_HERTZ).min(0.25 / h), CONTACT_DAMPING, h);
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
        joint_soft,
        correction: d.correction,
        lanes: Lanes {
            h,
            beta,
            friction: d.friction,
            restitution: d.restitution,
            accumulate,
            correction: d.correction,
            contact_soft: contact_soft.coefficients(),
            static_soft: static_soft.coefficients(),
            bounce: threshold,
        },
    };
    for sub_step in 0..substeps {
        // Velocities: gravity and the gyroscopic term.
        for (i, b) in sw.bodies[..n].iter_mut().enumerate() {
            if !s.asleep[i] {
                m.advance_velocity(i, s.q[i], &mut b.v, &mut b.w, h);
            }
        }
        // Joint rows at the present pose.
        sw.joints.clear();
        for j in &m.joints {
            joint_rows(s, sw, j);
        }
        // Warm start: each row's impulse of the last sub-step again.
        for k in 0..sw.joints.len() {
            let l = if accumulate { sw.joint_lambda[k] } else { 0.0 };
            sw.joints[k].lambda = l;
            let r = sw.joints[k];
            sw.row_push(&r, l, false);
        }
        if !penalty {
            batch::warm_start(&mut sw.batches, &mut sw.bodies, accumulate);
        }
        // Present penetrations from the motion since the step's start.
        if sub_step > 0 {
            for i in 0..n {
                let dr = mat_mul_t(sw.rot[i], w.rot[i]);
                let dx = sub(s.x[i], sw.x0[i]);
                sw.motion[i] = SolverMotion([
                    dx[0],
                    dx[1],
                    dx[2],
                    dr[0][0] - 1.0,
                    dr[0][1],
                    dr[0][2],
                    dr[1][0],
                    dr[1][1] - 1.0,
                    dr[1][2],
                    dr[2][0],
                    dr[2][1],
                    dr[2][2] - 1.0,
                ]);
            }
        }
        if penalty {
            if sub_step > 0 {
                batch::update_errors(&mut sw.batches, &sw.motion);
                batch::unpack_errors(&sw.batches, &mut sw.contacts);
            }
            penalty_forces(m, sw, h);
        }
        // The solve pass brings the penetrations up to date (not needed in the first
        // sub-step); the sub-step's last pass over the velocities adds up the impulses.
        let relax = d.correction == Correction::Soft;
        solve_pass(sw, Pass::Solve, sub_step > 0, !relax, params);
        if d.correction == Correction::Split {
            for p in sw.pseudo.iter_mut() {
                (p.v, p.w) = ([0.0; 3], [0.0; 3]);
            }
            batch::clear_split(&mut sw.batches);
            for r in sw.joints.iter_mut() {
                r.plambda = 0.0;
            }
            solve_pass(sw, Pass::Pseudo, false, false, params);
        }
        advance_positions(m, s, sw, h);
        if relax {
            solve_pass(sw, Pass::Relax, false, true, params);
        }
        for k in 0..sw.joints.len() {
            sw.joint_lambda[k] = sw.joints[k].lambda;
        }
        if penalty {
            // The springs' impulses live in the rows (see `penalty_forces`).
            for c in sw.contacts.iter_mut() {
                for r in 0..3 {
                    c.total = add(c.total, scale(c.dir[r], c.lambda[r]));
                }
            }
        }
    }
    // Restitution: contacts that pushed and were approaching faster than the threshold
    // leave at e times their approach speed (one-shot impulses bounced as they went).
    if d.restitution > 0.0 && accumulate {
        batch::restitute(&mut sw.batches, &mut sw.bodies, &params.lanes);
    }
    for (i, b) in sw.bodies[..n].iter().enumerate() {
        if m.is_dynamic(i) {
            s.v[i] = b.v;
            s.w[i] = b.w;
        }
    }
    if penalty {
        for r in &sw.contacts {
            w.contacts[r.index as usize].impulse = r.total;
        }
    } else {
        batch::impulses(&sw.batches, &mut w.contacts);
    }
}

/// Every awake body's position over a sub-step `h` from the velocities the constraints
/// left (and the pseudo-velocities), the solver's velocities updated to match. Under
/// symplectic Euler the dynamic bodies go four at a time, one a lane
/// ([`rigid::symplectic`] on `f64x4`: the bits of one at a time, with the square roots
/// and divisions of four bodies in one instruction; on the 1,000-box pile the update's
/// share of a step fell from 10.4% to 7.2% in profiles), the rest one by one.
fn advance_positions(m: &Rigid, s: &mut RigidState, sw: &mut SolverWork, h: f64) {
    let one = |s: &mut RigidState, sw: &mut SolverWork, i: usize| {
        let p = sw.pseudo[i];
        m.advance_position(s, i, h, (p.v, p.w), &mut sw.rot[i]);
        let b = &mut sw.bodies[i];
        b.v = s.v[i];
        b.w = s.w[i];
    };
    let lanes = m.desc().integrator == RigidIntegrator::SymplecticEuler;
    let (mut group, mut k) = ([0usize; 4], 0);
    for i in 0..m.len() {
        if s.asleep[i] {
            continue;
        }
        let b = &mut sw.bodies[i];
        s.v[i] = b.v;
        s.w[i] = b.w;
        if lanes && m.is_dynamic(i) {
            group[k] = i;
            k += 1;
            if k == 4 {
                symplectic_x4(m, s, sw, group, h);
                k = 0;
            }
        } else {
            one(s, sw, i);
        }
    }
    // The last few one by one.
    for &i in &group[..k] {
        one(s, sw, i);
    }
}

/// Symplectic Euler's position update of the four dynamic bodies `group`, one a lane.
fn symplectic_x4(m: &Rigid, s: &mut RigidState, sw: &mut SolverWork, group: [usize; 4], h: f64) {
    #[inline(always)]
    fn lanes3(f: impl Fn(usize) -> [f64; 3], group: [usize; 4]) -> [f64x4; 3] {
        let v = group.map(f);
        std::array::from_fn(|c| f64x4::new([v[0][c], v[1][c], v[2][c], v[3][c]]))
    }
    let rot: [[f64x4; 3]; 3] = std::array::from_fn(|r| lanes3(|i| sw.rot[i][r], group));
    let q = group.map(|i| s.q[i]);
    let q: [f64x4; 4] = std::array::from_fn(|c| f64x4::new([q[0][c], q[1][c], q[2][c], q[3][c]]));
    let p = rigid::symplectic(
        lanes3(|i| s.x[i], group),
        &rot,
        q,
        (lanes3(|i| s.v[i], group), lanes3(|i| s.w[i], group)),
        (
            lanes3(|i| sw.pseudo[i].v, group),
            lanes3(|i| sw.pseudo[i].w, group),
        ),
        (
            lanes3(|i| m.inertia[i], group),
            lanes3(|i| m.inv_inertia[i], group),
        ),
        f64x4::splat(h),
    );
    let (x, q, w) = (
        p.x.map(f64x4::to_array),
        p.q.map(f64x4::to_array),
        p.w.map(f64x4::to_array),
    );
    let rot = p.rot.map(|r| r.map(f64x4::to_array));
    for (l, &i) in group.iter().enumerate() {
        s.x[i] = [x[0][l], x[1][l], x[2][l]];
        s.q[i] = [q[0][l], q[1][l], q[2][l], q[3][l]];
        s.w[i] = [w[0][l], w[1][l], w[2][l]];
        sw.rot[i] = rot.map(|r| [r[0][l], r[1][l], r[2][l]]);
        sw.bodies[i].w = s.w[i];
    }
}

/// Writes two bodies' velocities back (a static or kinematic one keeps its own).
#[inline(always)]
fn store(bodies: &mut [SolverBody], a: usize, b: usize, va: [[f64; 3]; 2], vb: [[f64; 3]; 2]) {
    if bodies[a].inv_mass > 0.0 {
        bodies[a].v = va[0];
        bodies[a].w = va[1];
    }
    if bodies[b].inv_mass > 0.0 {
        bodies[b].v = vb[0];
        bodies[b].w = vb[1];
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
    joint_soft: Soft,
    correction: Correction,
    /// The contacts' share, for the batches.
    lanes: Lanes,
}

/// One pass over the joints and then the contacts (see [`Pass`]; `moved` and `last` as
/// `motion` and `last` of [`batch::solve`]).
fn solve_pass(sw: &mut SolverWork, pass: Pass, moved: bool, last: bool, p: Params) {
    let Params {
        h,
        beta,
        penalty,
        joint_soft,
        correction,
        lanes,
    } = p;
    // Joints: equalities.
    for k in 0..sw.joints.len() {
        let mut r = sw.joints[k];
        let (target, soft) = match (pass, correction) {
            (Pass::Pseudo, _) => (-beta * r.error / h, Soft::RIGID),
            (Pass::Relax, _) | (Pass::Solve, Correction::Split) => (0.0, Soft::RIGID),
            (Pass::Solve, Correction::Soft) => (-joint_soft.bias_rate * r.error, joint_soft),
            (Pass::Solve, Correction::Baumgarte) => (-beta * r.error / h, Soft::RIGID),
        };
        if pass == Pass::Pseudo {
            let dl = r.mass * (target - sw.row_velocity(&r, true));
            r.plambda += dl;
            sw.row_push(&r, dl, true);
        } else {
            let dl = r.mass * soft.mass_scale * (target - sw.row_velocity(&r, false))
                - soft.impulse_scale * r.lambda;
            r.lambda += dl;
            sw.row_push(&r, dl, false);
        }
        sw.joints[k] = r;
    }
    if !penalty {
        let motion = moved.then_some(&sw.motion[..]);
        batch::solve(
            &mut sw.batches,
            &mut sw.bodies,
            &mut sw.pseudo,
            motion,
            pass,
            last,
            &lanes,
        );
    }
}

/// Penalty springs at each overlapping contact point over a sub-step `h`.
fn penalty_forces(m: &Rigid, sw: &mut SolverWork, h: f64) {
    let d = m.desc();
    let RigidSolver::Penalty { stiffness, damping } = d.solver else {
        return;
    };
    // A contact rings at 1/20 of the sub-step rate, critically damped, by default; the
    // pair's overlapping points share the spring (contacts are sorted by pair).
    let omega = 2.0 * std::f64::consts::PI / (20.0 * h);
    let SolverWork {
        bodies, contacts, ..
    } = sw;
    for k in 0..contacts.len() {
        contacts[k].lambda = [0.0; 3];
        let c = contacts[k];
        let depth = c.error;
        if depth <= 0.0 {
            continue;
        }
        let (a, b) = (c.a as usize, c.b as usize);
        let lo = k.saturating_sub(8);
        let points = contacts[lo..(k + 8).min(contacts.len())]
            .iter()
            .filter(|q| q.a == c.a && q.b == c.b && q.error > 0.0)
            .count();
        let light = m.mass[a].min(m.mass[b]) / points.max(1) as f64;
        let ks = stiffness.unwrap_or(light * omega * omega);
        let kd = damping.unwrap_or(2.0 * light * omega);
        let (ba, bb) = (bodies[a], bodies[b]);
        let (mut va, mut vb) = (ba.vel(), bb.vel());
        let vel = |va: &[[f64; 3]; 2], vb: &[[f64; 3]; 2], r: usize| row_velocity(&c, va, vb, r);
        let vn = vel(&va, &vb, 0);
        let fn_ = (ks * depth - kd * vn).max(0.0);
        let (v1, v2) = (vel(&va, &vb, 1), vel(&va, &vb, 2));
        let vt = (v1 * v1 + v2 * v2).sqrt();
        let ft = (d.friction * fn_).min(kd * vt);
        let (f1, f2) = if vt > 0.0 {
            (-ft * v1 / vt, -ft * v2 / vt)
        } else {
            (0.0, 0.0)
        };
        let l = [fn_ * h, f1 * h, f2 * h];
        for (r, &lr) in l.iter().enumerate() {
            contact_push(&c, &ba, &bb, &mut va, &mut vb, r, lr);
        }
        store(bodies, a, b, va, vb);
        contacts[k].lambda = l;
    }
}

/// The rows of joint `j` at the present state, into `sw.joints`.
fn joint_rows(s: &RigidState, sw: &mut SolverWork, j: &Joint) {
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
        let mut r = sw.row(a, b, jac);
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
            let (p1, p2) = tangent_frame(ua);
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
