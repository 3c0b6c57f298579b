//! Inverse kinematics: joint angles that bring end effectors to targets (course notes
//! section 9; Buss 2004, "Introduction to inverse kinematics with Jacobian transpose,
//! pseudoinverse and damped least squares methods").
//!
//! **Parameters.** Each chain joint turns about some of its local axes in a fixed
//! order (`axes`, e.g. `[2]` for a hinge about z, `[0, 1, 2]` for a ball joint); its
//! local rotation is `R_rest R_a1(t1) R_a2(t2) ...`, each angle clamped to its limits.
//!
//! **Jacobian methods.** With every effector's error `e = t - x` (clamped to
//! `max_step` per effector, so a far target does not throw the chain), the column of
//! angle `t_d` for effector `k` is `a_d x (x_k - p_j)` (the world axis of the angle at
//! its joint, if the effector hangs below that joint; zero otherwise). The step is
//! - transpose: `alpha J^T e`, `alpha = <e, J J^T e> / |J J^T e|^2` (Buss's choice);
//! - pseudoinverse: `J^+ e` by SVD, singular values below 1e-3 of the largest dropped
//!   (with 1e-9 it stopped 1.7 cm short of the closest pose on out-of-reach targets in
//!   the `anim-ik` study, 2.6 mm with 1e-3);
//! - damped least squares: `J^T (J J^T + lambda^2 I)^-1 e`, which stays bounded near
//!   singular poses and settles on unreachable targets at the closest pose instead of
//!   oscillating.
//!
//! **Comparison methods** for a single effector on a serial chain: cyclic coordinate
//! descent (each joint, tip to root, turned to aim the effector at the target, its
//! angles read back by Euler extraction and clamped) and FABRIK (Aristidou and Lasenby
//! 2011: joint positions moved backward from the target and forward from the root,
//! then the rotations that carry each bone to its new direction).
//!
//! **Step control.** A Jacobian step is first scaled so that no angle moves more than
//! `max_angle_step` (0.5 rad), then halved until it does not increase the summed
//! distance to the targets, so the error never grows and nothing oscillates.
//!
//! **Reachability.**
//! [`IkReport`] gives each effector's final distance and whether it is within
//! `tolerance`; iteration stops when all are, or after five iterations in a row that
//! gain less than a thousandth of the tolerance (the closest pose reached).

use super::{Affine, JointError, Pose, Skeleton};
use largestep_kernels::anim::affine_decompose;
use largestep_kernels::quat::{self, Quat};
use largestep_kernels::rotation::{self, EulerOrder};
use largestep_kernels::v3::{add, cross, dot, length_and_unit, scale, sub};
use nalgebra::{DMatrix, DVector};

/// How the angles are found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum IkMethod {
    /// Jacobian transpose.
    Transpose,
    /// Pseudoinverse by SVD.
    Pseudoinverse,
    /// Damped least squares with damping `lambda` (the file's length units).
    DampedLeastSquares {
        /// The damping.
        lambda: f64,
    },
    /// Cyclic coordinate descent (one effector).
    Ccd,
    /// FABRIK (one effector).
    Fabrik,
}

impl IkMethod {
    /// Every method, damped least squares with `lambda`.
    pub fn all(lambda: f64) -> [IkMethod; 5] {
        [
            IkMethod::Transpose,
            IkMethod::Pseudoinverse,
            IkMethod::DampedLeastSquares { lambda },
            IkMethod::Ccd,
            IkMethod::Fabrik,
        ]
    }

    /// A short name (`transpose`, `pseudoinverse`, `dls`, `ccd`, `fabrik`).
    pub fn name(self) -> &'static str {
        match self {
            IkMethod::Transpose => "transpose",
            IkMethod::Pseudoinverse => "pseudoinverse",
            IkMethod::DampedLeastSquares { .. } => "dls",
            IkMethod::Ccd => "ccd",
            IkMethod::Fabrik => "fabrik",
        }
    }
}

/// A joint the solver may turn.
#[derive(Clone, Debug, PartialEq)]
pub struct IkJoint {
    /// The skeleton joint.
    pub joint: usize,
    /// Its local axes (0, 1, 2), in rotation order, at most three and none repeated.
    pub axes: Vec<usize>,
    /// The range of each angle (rad), `min <= max`.
    pub limits: Vec<(f64, f64)>,
}

impl IkJoint {
    /// A joint free about the given axes (limits of +-pi).
    pub fn free(joint: usize, axes: &[usize]) -> IkJoint {
        IkJoint {
            joint,
            axes: axes.to_vec(),
            limits: vec![(-std::f64::consts::PI, std::f64::consts::PI); axes.len()],
        }
    }
}

/// A point on a joint to bring to a target.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Effector {
    /// The joint it is fixed to.
    pub joint: usize,
    /// The target, in model space.
    pub target: [f64; 3],
}

/// What the solve did.
#[derive(Clone, Debug, PartialEq)]
pub struct IkReport {
    /// Iterations run.
    pub iterations: usize,
    /// Each effector's final distance to its target.
    pub distances: Vec<f64>,
    /// Whether each is within the tolerance.
    pub reached: Vec<bool>,
}

/// A checked IK problem on one skeleton.
#[derive(Clone, Debug)]
pub struct Ik {
    joints: Vec<IkJoint>,
    /// For every skeleton joint, the chain joints above it or at it, root first.
    above: Vec<Vec<usize>>,
    /// The first angle index of each chain joint.
    offsets: Vec<usize>,
    /// The method.
    pub method: IkMethod,
    /// Iterations at most.
    pub max_iterations: usize,
    /// Distance that counts as reached (the file's units).
    pub tolerance: f64,
    /// Largest error an iteration moves toward, per effector (Jacobian methods).
    pub max_step: f64,
    /// Largest change of any angle in one iteration (rad; Jacobian methods): a step
    /// past it is scaled down whole, keeping its direction. Near a singular pose the
    /// pseudoinverse's step is huge; unscaled it ran the angles into their limits and
    /// stalled there (a third of the study's pseudoinverse solves without it).
    pub max_angle_step: f64,
}

impl Ik {
    /// Checks the chain against the skeleton: joints exist, appear once, axes and limits
    /// well formed, and no chain joint below another sits at zero distance from its
    /// parent (a zero-length bone gives a zero Jacobian column and no direction to aim).
    pub fn new(
        skeleton: &Skeleton,
        joints: Vec<IkJoint>,
        method: IkMethod,
    ) -> Result<Ik, JointError> {
        let n = skeleton.len();
        let err = |j: usize, message: String| JointError {
            index: j,
            name: skeleton.names().get(j).cloned().unwrap_or_default(),
            message,
        };
        let mut seen = vec![false; n];
        for ij in &joints {
            if ij.joint >= n {
                return Err(err(ij.joint, format!("not in the skeleton of {n} joints")));
            }
            if std::mem::replace(&mut seen[ij.joint], true) {
                return Err(err(ij.joint, "appears twice in the IK chain".into()));
            }
            let mut axes = [false; 3];
            if ij.axes.len() > 3
                || ij
                    .axes
                    .iter()
                    .any(|&a| a > 2 || std::mem::replace(&mut axes[a], true))
            {
                return Err(err(
                    ij.joint,
                    format!("axes {:?} are not distinct axes 0, 1, 2", ij.axes),
                ));
            }
            if ij.limits.len() != ij.axes.len()
                || ij
                    .limits
                    .iter()
                    .any(|&(lo, hi)| lo > hi || !lo.is_finite() || !hi.is_finite())
            {
                return Err(err(
                    ij.joint,
                    "needs one finite limit (min <= max) per axis".into(),
                ));
            }
        }
        let mut above = vec![Vec::new(); n];
        for (j, a) in above.iter_mut().enumerate() {
            let mut k = Some(j);
            while let Some(x) = k {
                if let Some(c) = joints.iter().position(|ij| ij.joint == x) {
                    a.push(c);
                }
                k = skeleton.parent(x);
            }
            a.reverse();
        }
        // Zero-length bones: a chain joint (or any joint) below a chain joint at the
        // same place as its parent.
        for ij in &joints {
            if let Some(p) = skeleton.parent(ij.joint) {
                let t = skeleton.rest().translation(ij.joint);
                if !above[p].is_empty() && dot(t, t) == 0.0 {
                    return Err(err(
                        ij.joint,
                        "zero-length bone from its parent in the IK chain".into(),
                    ));
                }
            }
        }
        if matches!(method, IkMethod::DampedLeastSquares { lambda } if !(lambda > 0.0 && lambda.is_finite()))
        {
            return Err(err(
                0,
                "damped least squares needs a positive damping".into(),
            ));
        }
        let mut at = 0;
        let offsets = joints
            .iter()
            .map(|ij| {
                let o = at;
                at += ij.axes.len();
                o
            })
            .collect();
        Ok(Ik {
            joints,
            above,
            offsets,
            method,
            max_iterations: 200,
            tolerance: 1e-6,
            max_step: f64::INFINITY,
            max_angle_step: 0.5,
        })
    }

    /// The number of angles.
    pub fn dofs(&self) -> usize {
        self.joints.iter().map(|j| j.axes.len()).sum()
    }

    /// Writes the chain joints' local rotations for `angles` into `pose` (rest
    /// rotation times the axis rotations).
    pub fn apply(&self, skeleton: &Skeleton, angles: &[f64], pose: &mut Pose) {
        let mut at = 0;
        for ij in &self.joints {
            let mut q = skeleton.rest().rotation(ij.joint);
            for &a in &ij.axes {
                q = quat::mul(q, rotation::axis_quat(a, angles[at]));
                at += 1;
            }
            let (t, s) = (pose.translation(ij.joint), pose.scale(ij.joint));
            pose.set(ij.joint, t, q, s);
        }
    }

    /// Solves for `angles` (one per axis, in chain order; the start guess, updated) so
    /// that the effectors reach their targets, and leaves the result in `pose`.
    /// Checks that the effectors' joints hang below the chain and targets are finite;
    /// CCD and FABRIK take one effector on a serial chain.
    pub fn solve(
        &self,
        skeleton: &Skeleton,
        pose: &mut Pose,
        angles: &mut [f64],
        effectors: &[Effector],
    ) -> Result<IkReport, JointError> {
        let err = |j: usize, message: String| JointError {
            index: j,
            name: skeleton.names().get(j).cloned().unwrap_or_default(),
            message,
        };
        assert_eq!(angles.len(), self.dofs(), "one angle per axis of the chain");
        for e in effectors {
            if e.joint >= skeleton.len() || self.above[e.joint].is_empty() {
                return Err(err(
                    e.joint,
                    "effector does not hang below any IK joint".into(),
                ));
            }
            if !e.target.iter().all(|v| v.is_finite()) {
                return Err(err(e.joint, "target is not finite".into()));
            }
        }
        if matches!(self.method, IkMethod::Ccd | IkMethod::Fabrik) && effectors.len() != 1 {
            return Err(err(0, format!("{} takes one effector", self.method.name())));
        }
        self.clamp(angles);
        let mut model = Vec::new();
        let total = |model: &[Affine]| -> f64 {
            effectors
                .iter()
                .map(|e| dist(point(&model[e.joint]), e.target))
                .sum()
        };
        self.apply(skeleton, angles, pose);
        skeleton.model(pose, &mut model);
        let mut err_now = total(&model);
        let mut iterations = 0;
        let mut stalled = 0;
        while iterations < self.max_iterations {
            if effectors
                .iter()
                .all(|e| dist(point(&model[e.joint]), e.target) <= self.tolerance)
            {
                break;
            }
            iterations += 1;
            let e = match self.method {
                IkMethod::Ccd | IkMethod::Fabrik => {
                    if self.method == IkMethod::Ccd {
                        self.ccd_sweep(skeleton, pose, angles, &effectors[0], &mut model);
                    } else {
                        self.fabrik_pass(skeleton, pose, angles, &effectors[0], &mut model);
                    }
                    total(&model)
                }
                _ => {
                    // The step, halved until it does not make the error worse (near a
                    // singular pose the full step of the pseudoinverse, or of a lightly
                    // damped solve, overshoots); none that helps leaves the angles.
                    let mut step = self.jacobian_step(&model, angles, effectors);
                    let largest = step.iter().fold(0.0f64, |m, s| m.max(s.abs()));
                    if largest > self.max_angle_step {
                        let k = self.max_angle_step / largest;
                        step.iter_mut().for_each(|s| *s *= k);
                    }
                    let start = angles.to_vec();
                    let mut scale = 1.0;
                    loop {
                        for ((a, s), a0) in angles.iter_mut().zip(&step).zip(&start) {
                            *a = a0 + scale * s;
                        }
                        self.clamp(angles);
                        self.apply(skeleton, angles, pose);
                        skeleton.model(pose, &mut model);
                        let e = total(&model);
                        if e <= err_now {
                            break e;
                        }
                        scale *= 0.5;
                        if scale < 1e-4 {
                            angles.copy_from_slice(&start);
                            self.apply(skeleton, angles, pose);
                            skeleton.model(pose, &mut model);
                            break err_now;
                        }
                    }
                }
            };
            // Settled: several iterations in a row that gain less than the tolerance.
            if err_now - e < self.tolerance * 1e-3 {
                stalled += 1;
                if stalled >= 5 {
                    break;
                }
            } else {
                stalled = 0;
            }
            err_now = e;
        }
        let distances: Vec<f64> = effectors
            .iter()
            .map(|e| dist(point(&model[e.joint]), e.target))
            .collect();
        Ok(IkReport {
            iterations,
            reached: distances.iter().map(|&d| d <= self.tolerance).collect(),
            distances,
        })
    }

    fn clamp(&self, angles: &mut [f64]) {
        let mut at = 0;
        for ij in &self.joints {
            for &(lo, hi) in &ij.limits {
                let a = angles[at];
                angles[at] = if a.is_finite() {
                    a.clamp(lo, hi)
                } else {
                    0.0_f64.clamp(lo, hi)
                };
                at += 1;
            }
        }
    }

    /// The world axis of each angle and the position of its joint.
    fn axes_world(&self, model: &[Affine], angles: &[f64]) -> Vec<([f64; 3], [f64; 3])> {
        let mut out = Vec::with_capacity(self.dofs());
        let mut at = 0;
        for ij in &self.joints {
            // The joint's world frame with all its angles applied is model[j]; undo the
            // later angles to get each axis: axis d is R_j R_{a_last}^-1 ... e_{a_d}.
            let m = &model[ij.joint];
            let rj = [[m[0], m[1], m[2]], [m[4], m[5], m[6]], [m[8], m[9], m[10]]];
            let p = point(m);
            let k = ij.axes.len();
            let mut axes = vec![[0.0; 3]; k];
            let mut q = quat::IDENTITY;
            for i in (0..k).rev() {
                let mut e = [0.0; 3];
                e[ij.axes[i]] = 1.0;
                let local = quat::rotate(quat::conj(q), e);
                let w = [0, 1, 2]
                    .map(|r| rj[r][0] * local[0] + rj[r][1] * local[1] + rj[r][2] * local[2]);
                axes[i] = length_and_unit(w).map_or([0.0; 3], |x| x.1);
                q = quat::mul(rotation::axis_quat(ij.axes[i], angles[at + i]), q);
            }
            out.extend(axes.into_iter().map(|a| (a, p)));
            at += k;
        }
        out
    }

    /// The angle step of a Jacobian method.
    fn jacobian_step(&self, model: &[Affine], angles: &[f64], effectors: &[Effector]) -> Vec<f64> {
        let axes = self.axes_world(model, angles);
        let (m, n) = (3 * effectors.len(), axes.len());
        let mut jac = DMatrix::<f64>::zeros(m, n);
        let mut e = DVector::<f64>::zeros(m);
        // Which chain joint each angle belongs to.
        let owner: Vec<usize> = self
            .joints
            .iter()
            .enumerate()
            .flat_map(|(c, ij)| std::iter::repeat_n(c, ij.axes.len()))
            .collect();
        for (k, eff) in effectors.iter().enumerate() {
            let x = point(&model[eff.joint]);
            let mut d = sub(eff.target, x);
            let l = dot(d, d).sqrt();
            if l > self.max_step {
                d = scale(d, self.max_step / l);
            }
            for c in 0..3 {
                e[3 * k + c] = d[c];
            }
            for (col, (a, p)) in axes.iter().enumerate() {
                if self.above[eff.joint].contains(&owner[col]) {
                    let v = cross(*a, sub(x, *p));
                    for c in 0..3 {
                        jac[(3 * k + c, col)] = v[c];
                    }
                }
            }
        }
        let step: DVector<f64> = match self.method {
            IkMethod::Transpose => {
                let jte = jac.transpose() * &e;
                let jjte = &jac * &jte;
                let den = jjte.norm_squared();
                let alpha = if den > 0.0 { e.dot(&jjte) / den } else { 0.0 };
                jte * alpha
            }
            IkMethod::Pseudoinverse => {
                let svd = jac.clone().svd(true, true);
                let smax = svd.singular_values.max();
                svd.solve(&e, 1e-3 * smax.max(f64::MIN_POSITIVE))
                    .unwrap_or_else(|_| DVector::zeros(n))
            }
            IkMethod::DampedLeastSquares { lambda } => {
                let jjt = &jac * jac.transpose() + DMatrix::identity(m, m) * (lambda * lambda);
                match jjt.cholesky() {
                    Some(ch) => jac.transpose() * ch.solve(&e),
                    None => DVector::zeros(n),
                }
            }
            IkMethod::Ccd | IkMethod::Fabrik => unreachable!("not a Jacobian method"),
        };
        step.iter()
            .map(|s| if s.is_finite() { *s } else { 0.0 })
            .collect()
    }

    /// The angles (before clamping) of chain joint `c` that give it the world rotation
    /// `world` under a parent at world rotation `parent`.
    fn angles_for(
        &self,
        skeleton: &Skeleton,
        c: usize,
        parent: Quat,
        world: Quat,
        out: &mut [f64],
    ) {
        let ij = &self.joints[c];
        let rest = skeleton.rest().rotation(ij.joint);
        // R_rest^-1 R_parent^-1 R_world = R_a1 R_a2 ...
        let local = quat::mul(quat::conj(rest), quat::mul(quat::conj(parent), world));
        match ij.axes.len() {
            0 => {}
            1 => {
                // The twist about the one axis (swing dropped).
                let a = ij.axes[0];
                out[0] = 2.0 * local[1 + a].atan2(local[0]);
            }
            2 => {
                let third = 3 - ij.axes[0] - ij.axes[1];
                let e = rotation::to_euler(EulerOrder([ij.axes[0], ij.axes[1], third]), local);
                out[..2].copy_from_slice(&e[..2]);
            }
            _ => {
                let e = rotation::to_euler(EulerOrder([ij.axes[0], ij.axes[1], ij.axes[2]]), local);
                out.copy_from_slice(&e);
            }
        }
    }

    /// One CCD sweep, tip to root.
    fn ccd_sweep(
        &self,
        skeleton: &Skeleton,
        pose: &mut Pose,
        angles: &mut [f64],
        eff: &Effector,
        model: &mut Vec<Affine>,
    ) {
        for &c in self.above[eff.joint].iter().rev() {
            let from = point(&model[eff.joint]);
            self.aim(skeleton, pose, angles, model, c, from, eff.target);
        }
    }

    /// One FABRIK pass (backward from the target, forward from the root), then the
    /// rotations that carry each bone onto its new direction, root to tip.
    fn fabrik_pass(
        &self,
        skeleton: &Skeleton,
        pose: &mut Pose,
        angles: &mut [f64],
        eff: &Effector,
        model: &mut Vec<Affine>,
    ) {
        // The serial chain from the root-most chain joint to the effector.
        let chain = &self.above[eff.joint];
        let mut pts: Vec<[f64; 3]> = chain
            .iter()
            .map(|&c| point(&model[self.joints[c].joint]))
            .collect();
        pts.push(point(&model[eff.joint]));
        let lengths: Vec<f64> = pts.windows(2).map(|w| dist(w[0], w[1])).collect();
        let root = pts[0];
        let last = pts.len() - 1;
        pts[last] = eff.target;
        for i in (0..last).rev() {
            let d = length_and_unit(sub(pts[i], pts[i + 1])).map_or([0.0; 3], |x| x.1);
            pts[i] = add(pts[i + 1], scale(d, lengths[i]));
        }
        pts[0] = root;
        for i in 0..last {
            let d = length_and_unit(sub(pts[i + 1], pts[i])).map_or([0.0; 3], |x| x.1);
            pts[i + 1] = add(pts[i], scale(d, lengths[i]));
        }
        // Turn each joint so its bone (toward the next point) points at its new place.
        for (i, &c) in chain.iter().enumerate() {
            let next = if i + 1 < chain.len() {
                self.joints[chain[i + 1]].joint
            } else {
                eff.joint
            };
            let from = point(&model[next]);
            self.aim(skeleton, pose, angles, model, c, from, pts[i + 1]);
        }
    }

    /// Turns chain joint `c` by the shortest arc about its
    /// position that carries the point `from` toward `to`, with its angles read back
    /// and clamped, and poses the skeleton again (CCD's and FABRIK's step).
    #[allow(clippy::too_many_arguments)]
    fn aim(
        &self,
        skeleton: &Skeleton,
        pose: &mut Pose,
        angles: &mut [f64],
        model: &mut Vec<Affine>,
        c: usize,
        from: [f64; 3],
        to: [f64; 3],
    ) {
        let ij = &self.joints[c];
        let m = &model[ij.joint];
        let p = point(m);
        let (Some((_, u)), Some((_, v))) =
            (length_and_unit(sub(from, p)), length_and_unit(sub(to, p)))
        else {
            return;
        };
        let world = quat::mul(arc(u, v), affine_decompose(m).1);
        let parent = skeleton
            .parent(ij.joint)
            .map_or(quat::IDENTITY, |pj| affine_decompose(&model[pj]).1);
        let (offset, k) = (self.offsets[c], ij.axes.len());
        self.angles_for(skeleton, c, parent, world, &mut angles[offset..offset + k]);
        self.clamp(angles);
        self.apply(skeleton, angles, pose);
        skeleton.model(pose, model);
    }
}

/// The translation of an affine transform.
fn point(m: &Affine) -> [f64; 3] {
    [m[3], m[7], m[11]]
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = sub(a, b);
    dot(d, d).sqrt()
}

/// The shortest rotation taking unit `u` to unit `v`.
fn arc(u: [f64; 3], v: [f64; 3]) -> Quat {
    let c = dot(u, v);
    let x = cross(u, v);
    if c < -1.0 + 1e-12 {
        // Opposite: half a turn about any perpendicular.
        let (t, _) = largestep_kernels::v3::tangent_frame(u);
        return [0.0, t[0], t[1], t[2]];
    }
    quat::normalize([1.0 + c, x[0], x[1], x[2]]).unwrap_or(quat::IDENTITY)
}
