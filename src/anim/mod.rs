//! Character animation (course notes sections 6-11), shaped like ozz-animation: an
//! editable raw form, a build step that checks it, and an immutable runtime form sampled
//! by kernels over structure-of-arrays data.
//!
//! - [`SkeletonDesc`] (raw joints: names, parents, rest transforms) builds a
//!   [`Skeleton`]: joints ordered parents first, rest pose in SoA form.
//! - A [`Pose`] is the local transforms of all joints (SoA: translations, rotations,
//!   scales); [`Skeleton::model`] runs forward kinematics into affine model matrices
//!   (`kernels::anim::local_to_model`).
//! - [`blend`] mixes several poses by weight (normalised; rotations by weighted NLERP in
//!   one hemisphere, as ozz's `BlendingJob`), and [`add_layer`] puts an additive pose (a
//!   difference from the rest, [`additive_delta`]) on top.
//! - [`bvh`] reads and writes motion capture (BVH); its clip becomes poses per frame.
//! - [`asset`] reads and writes glTF 2.0 (skeleton, skinned mesh, morph targets, clips).
//! - [`asf`] reads Acclaim skeletons and motion (ASF/AMC).
//! - [`clip::Clip`] holds a fixed-rate clip and samples it at any time.
//! - [`keyframe`] holds keyframe channels (step, linear, Hermite, Catmull-Rom, Bezier,
//!   TCB; SLERP and SQUAD for rotations), ease, baking and arc length.
//! - [`motion_graph`] finds transitions between similar frames (a pose distance over
//!   windows) and walks the graph they make, at random or along a path.
//! - [`retarget`] carries poses between skeletons by joint names.
//! - [`ik`] solves inverse kinematics (Jacobian transpose, pseudoinverse, damped least
//!   squares, CCD, FABRIK).
//! - [`skin`] deforms a bound mesh by linear blend or dual quaternion skinning.
//! - [`blendshape`] holds delta blendshapes, corrective combinations, action units and
//!   a bounded weight solve.

pub mod asf;
pub mod asset;
pub mod blendshape;
pub mod bvh;
pub mod clip;
pub mod ik;
pub mod keyframe;
pub mod motion_graph;
pub mod retarget;
pub mod scene;
pub mod skin;

pub use largestep_kernels::anim::{Affine, AFFINE_IDENTITY, NO_PARENT};
use largestep_kernels::quat::{self, Quat};
use largestep_kernels::rotation;

/// A joint of a skeleton being built.
#[derive(Clone, Debug, PartialEq)]
pub struct JointDesc {
    /// Its name (unique within the skeleton).
    pub name: String,
    /// Its parent's index in the description, `None` for a root.
    pub parent: Option<usize>,
    /// Rest translation from the parent (the file's units).
    pub translation: [f64; 3],
    /// Rest rotation from the parent (unit quaternion).
    pub rotation: Quat,
    /// Rest scale.
    pub scale: [f64; 3],
}

impl JointDesc {
    /// A joint at `translation` from its parent, with no rotation or scale.
    pub fn new(name: &str, parent: Option<usize>, translation: [f64; 3]) -> JointDesc {
        JointDesc {
            name: name.to_string(),
            parent,
            translation,
            rotation: quat::IDENTITY,
            scale: [1.0; 3],
        }
    }
}

/// The raw, editable form of a skeleton.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SkeletonDesc {
    /// The joints; a parent must come before its children.
    pub joints: Vec<JointDesc>,
}

/// A skeleton that failed to build, or a pose or clip that does not fit it: the joint
/// (index and name) and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("joint {index} ({name}): {message}")]
pub struct JointError {
    /// The joint's index.
    pub index: usize,
    /// Its name.
    pub name: String,
    /// What is wrong.
    pub message: String,
}

impl SkeletonDesc {
    /// Checks the description and builds the runtime skeleton: every parent before its
    /// child (so forward kinematics is one pass), names unique and non-empty, rest
    /// transforms finite, rotations of unit length (within 1e-6; they are
    /// renormalised), scales non-zero.
    pub fn build(&self) -> Result<Skeleton, JointError> {
        let n = self.joints.len();
        let mut names = std::collections::HashMap::with_capacity(n);
        let mut parents = Vec::with_capacity(n);
        let mut rest = Pose::identity(n);
        for (i, j) in self.joints.iter().enumerate() {
            let err = |message: String| JointError {
                index: i,
                name: j.name.clone(),
                message,
            };
            if j.name.is_empty() {
                return Err(err("has no name".into()));
            }
            if let Some(k) = names.insert(j.name.as_str(), i) {
                return Err(err(format!("has the same name as joint {k}")));
            }
            match j.parent {
                Some(p) if p >= i => {
                    return Err(err(format!(
                    "its parent {p} does not come before it (parents must precede their children)"
                )))
                }
                _ => {}
            }
            if !j.translation.iter().chain(&j.scale).all(|v| v.is_finite()) {
                return Err(err("rest translation or scale is not finite".into()));
            }
            if j.scale.contains(&0.0) {
                return Err(err("rest scale is zero".into()));
            }
            let norm = rotation::dot4(j.rotation, j.rotation).sqrt();
            if (norm - 1.0).abs().is_nan() || (norm - 1.0).abs() >= 1e-6 {
                return Err(err(format!("rest rotation has norm {norm}, not 1")));
            }
            parents.push(j.parent.map_or(NO_PARENT, |p| p as u32));
            rest.set(i, j.translation, j.rotation.map(|c| c / norm), j.scale);
        }
        Ok(Skeleton {
            names: self.joints.iter().map(|j| j.name.clone()).collect(),
            parents,
            rest,
        })
    }
}

/// The runtime skeleton: immutable, joints parents first.
#[derive(Clone, Debug)]
pub struct Skeleton {
    names: Vec<String>,
    parents: Vec<u32>,
    rest: Pose,
}

impl Skeleton {
    /// The number of joints.
    pub fn len(&self) -> usize {
        self.parents.len()
    }

    /// Whether it has no joints.
    pub fn is_empty(&self) -> bool {
        self.parents.is_empty()
    }

    /// Joint names, in joint order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The index of the joint named `name`.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Parent indices ([`NO_PARENT`] for roots).
    pub fn parents(&self) -> &[u32] {
        &self.parents
    }

    /// The parent of joint `j`.
    pub fn parent(&self, j: usize) -> Option<usize> {
        let p = self.parents[j];
        (p != NO_PARENT).then_some(p as usize)
    }

    /// The rest (bind) pose.
    pub fn rest(&self) -> &Pose {
        &self.rest
    }

    /// Forward kinematics: the model transform of every joint in `pose` into `out`
    /// (resized to the joint count; no allocation once it has that length).
    pub fn model(&self, pose: &Pose, out: &mut Vec<Affine>) {
        assert_eq!(pose.len(), self.len(), "the pose has one entry per joint");
        out.resize(self.len(), AFFINE_IDENTITY);
        largestep_kernels::anim::local_to_model(
            out,
            &self.parents,
            &pose.translations,
            &pose.rotations,
            &pose.scales,
            &AFFINE_IDENTITY,
        );
    }
}

/// Local transforms of all joints in SoA form: `translations` `[x.., y.., z..]` (3n),
/// `rotations` `[w.., x.., y.., z..]` (4n, unit), `scales` like translations.
#[derive(Clone, Debug, PartialEq)]
pub struct Pose {
    /// Translations from the parent, component-major.
    pub translations: Vec<f64>,
    /// Rotations from the parent, component-major unit quaternions.
    pub rotations: Vec<f64>,
    /// Scales, component-major.
    pub scales: Vec<f64>,
}

impl Pose {
    /// `n` joints at the identity.
    pub fn identity(n: usize) -> Pose {
        let mut rotations = vec![0.0; 4 * n];
        rotations[..n].fill(1.0);
        Pose {
            translations: vec![0.0; 3 * n],
            rotations,
            scales: vec![1.0; 3 * n],
        }
    }

    /// The number of joints.
    pub fn len(&self) -> usize {
        self.translations.len() / 3
    }

    /// Whether it has no joints.
    pub fn is_empty(&self) -> bool {
        self.translations.is_empty()
    }

    /// Joint `j`'s translation.
    pub fn translation(&self, j: usize) -> [f64; 3] {
        let n = self.len();
        [0, 1, 2].map(|c| self.translations[c * n + j])
    }

    /// Joint `j`'s rotation.
    pub fn rotation(&self, j: usize) -> Quat {
        let n = self.len();
        [0, 1, 2, 3].map(|c| self.rotations[c * n + j])
    }

    /// Joint `j`'s scale.
    pub fn scale(&self, j: usize) -> [f64; 3] {
        let n = self.len();
        [0, 1, 2].map(|c| self.scales[c * n + j])
    }

    /// Sets joint `j`'s local transform.
    pub fn set(&mut self, j: usize, t: [f64; 3], q: Quat, s: [f64; 3]) {
        let n = self.len();
        for c in 0..3 {
            self.translations[c * n + j] = t[c];
            self.scales[c * n + j] = s[c];
        }
        for (c, v) in q.into_iter().enumerate() {
            self.rotations[c * n + j] = v;
        }
    }
}

/// Weighted blend of several poses of one skeleton into `out` (ozz's `BlendingJob`):
/// translations and scales by the normalised weights, rotations by normalised weighted
/// sums with each taken into the hemisphere of the first layer's (the double cover).
/// Layers with weight 0 or less are skipped; when none is left, `out` is `rest`.
pub fn blend(out: &mut Pose, layers: &[(&Pose, f64)], rest: &Pose) {
    let n = rest.len();
    let total: f64 = layers.iter().filter(|l| l.1 > 0.0).map(|l| l.1).sum();
    if total <= 0.0 || !total.is_finite() {
        out.clone_from(rest);
        return;
    }
    out.translations.iter_mut().for_each(|v| *v = 0.0);
    out.scales.iter_mut().for_each(|v| *v = 0.0);
    out.rotations.iter_mut().for_each(|v| *v = 0.0);
    out.translations.resize(3 * n, 0.0);
    out.scales.resize(3 * n, 0.0);
    out.rotations.resize(4 * n, 0.0);
    let first = layers.iter().find(|l| l.1 > 0.0).map(|l| l.0);
    for &(p, w) in layers.iter().filter(|l| l.1 > 0.0) {
        assert_eq!(p.len(), n, "every layer has one entry per joint");
        let w = w / total;
        for (o, v) in out.translations.iter_mut().zip(&p.translations) {
            *o += w * v;
        }
        for (o, v) in out.scales.iter_mut().zip(&p.scales) {
            *o += w * v;
        }
        for j in 0..n {
            let q = p.rotation(j);
            let q = match first {
                Some(f) => rotation::align(f.rotation(j), q),
                None => q,
            };
            for (c, v) in q.into_iter().enumerate() {
                out.rotations[c * n + j] += w * v;
            }
        }
    }
    for j in 0..n {
        let q = out.rotation(j);
        let q = quat::normalize(q).unwrap_or(rest.rotation(j));
        for (c, v) in q.into_iter().enumerate() {
            out.rotations[c * n + j] = v;
        }
    }
}

/// The additive difference of `pose` from `reference` (what [`add_layer`] puts back):
/// translation `t - t_ref`, rotation `q_ref* q`, scale `s / s_ref`.
pub fn additive_delta(pose: &Pose, reference: &Pose) -> Pose {
    let n = pose.len();
    let mut d = Pose::identity(n);
    for j in 0..n {
        let (t, tr) = (pose.translation(j), reference.translation(j));
        let (s, sr) = (pose.scale(j), reference.scale(j));
        let q = quat::mul(quat::conj(reference.rotation(j)), pose.rotation(j));
        d.set(
            j,
            [0, 1, 2].map(|c| t[c] - tr[c]),
            q,
            [0, 1, 2].map(|c| s[c] / sr[c]),
        );
    }
    d
}

/// Puts an additive layer `delta` on `pose` with weight `w` (ozz's additive blending):
/// `t += w dt`, `q = q nlerp(1, dq, w)`, `s *= lerp(1, ds, w)`.
pub fn add_layer(pose: &mut Pose, delta: &Pose, w: f64) {
    let n = pose.len();
    assert_eq!(delta.len(), n, "the layer has one entry per joint");
    for j in 0..n {
        let (t, dt) = (pose.translation(j), delta.translation(j));
        let (s, ds) = (pose.scale(j), delta.scale(j));
        let dq = rotation::nlerp(quat::IDENTITY, delta.rotation(j), w);
        pose.set(
            j,
            [0, 1, 2].map(|c| t[c] + w * dt[c]),
            quat::mul(pose.rotation(j), dq),
            [0, 1, 2].map(|c| s[c] * (1.0 + w * (ds[c] - 1.0))),
        );
    }
}
