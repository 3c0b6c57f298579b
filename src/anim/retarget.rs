//! Retargeting a pose from one skeleton to another by joint names (course notes section
//! 7).
//!
//! Joints are paired by name: given pairs, else equal names once a namespace prefix
//! (`mixamorig:Hips` -> `Hips`) is set aside on both sides. Rotations are carried in world
//! space relative to each skeleton's rest pose, so joint frames set up differently (a
//! rest rotation in one, bone offsets along other axes in the other) agree: a source
//! joint's world rotation relative to its rest, `W = R_s R_s,rest^-1`, turns the paired
//! target joint from its own rest world rotation, `R_t = W R_t,rest`, and the target's
//! local rotation is its parent's world rotation undone from that. A difference of rest
//! *poses* is kept: a target resting in an A-pose moves its arms as a T-posed source
//! does, from its own rest (matching bone directions is left to the caller's rest). Unpaired
//! target joints keep their rest local rotation (they follow their parent). The root's
//! travel from its rest place is scaled by the ratio of the skeletons' heights (the rest
//! pose's vertical extent), so a bigger character takes longer strides.

use super::{Affine, JointError, Pose, Skeleton};
use largestep_kernels::anim::affine_decompose;
use largestep_kernels::quat::{self, Quat};

/// A joint pairing from a source skeleton to a target skeleton.
#[derive(Clone, Debug)]
pub struct Retarget {
    /// For each target joint, its source joint.
    source_of: Vec<Option<usize>>,
    /// Rest world rotations of the source and target joints.
    source_rest: Vec<Quat>,
    target_rest: Vec<Quat>,
    /// Target height over source height.
    scale: f64,
    /// The root joints (index 0 of each).
    source_root_rest: [f64; 3],
    target_root_rest: [f64; 3],
}

/// A name without its namespace prefix (the text up to the last `:`).
fn bare(name: &str) -> &str {
    name.rsplit(':').next().unwrap_or(name)
}

/// World rotations of a pose's joints (from forward kinematics, scale removed).
fn world_rotations(skeleton: &Skeleton, pose: &Pose, model: &mut Vec<Affine>) -> Vec<Quat> {
    skeleton.model(pose, model);
    model.iter().map(|m| affine_decompose(m).1).collect()
}

/// The rest pose's vertical extent (y) of a skeleton.
fn height(skeleton: &Skeleton, model: &mut Vec<Affine>) -> f64 {
    skeleton.model(skeleton.rest(), model);
    let ys = model.iter().map(|m| m[7]);
    let (lo, hi) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| {
        (a.min(y), b.max(y))
    });
    hi - lo
}

impl Retarget {
    /// Pairs the joints: by `pairs` (source name, target name) when given, else by equal
    /// names without namespace prefixes. Errors name a given name that is missing, or a
    /// skeleton whose joint 0 is not a root; at least the roots must pair.
    pub fn new(
        source: &Skeleton,
        target: &Skeleton,
        pairs: &[(&str, &str)],
    ) -> Result<Retarget, JointError> {
        let err = |index: usize, name: &str, message: &str| JointError {
            index,
            name: name.to_string(),
            message: message.to_string(),
        };
        if source.is_empty()
            || target.is_empty()
            || source.parent(0).is_some()
            || target.parent(0).is_some()
        {
            return Err(err(0, "", "both skeletons need joint 0 as their root"));
        }
        let mut source_of = vec![None; target.len()];
        if pairs.is_empty() {
            for (t, name) in target.names().iter().enumerate() {
                source_of[t] = source.names().iter().position(|s| bare(s) == bare(name));
            }
        } else {
            for &(s, t) in pairs {
                let si = source
                    .find(s)
                    .ok_or_else(|| err(0, s, "not a joint of the source skeleton"))?;
                let ti = target
                    .find(t)
                    .ok_or_else(|| err(0, t, "not a joint of the target skeleton"))?;
                source_of[ti] = Some(si);
            }
        }
        if source_of[0].is_none() {
            return Err(err(
                0,
                &target.names()[0],
                "the target's root has no source joint",
            ));
        }
        let mut model = Vec::new();
        let source_rest = world_rotations(source, source.rest(), &mut model);
        let hs = height(source, &mut model);
        let target_rest = world_rotations(target, target.rest(), &mut model);
        let ht = height(target, &mut model);
        Ok(Retarget {
            source_of,
            source_rest,
            target_rest,
            scale: if hs > 0.0 && ht > 0.0 { ht / hs } else { 1.0 },
            source_root_rest: source.rest().translation(0),
            target_root_rest: target.rest().translation(0),
        })
    }

    /// How many target joints have a source.
    pub fn paired(&self) -> usize {
        self.source_of.iter().filter(|s| s.is_some()).count()
    }

    /// The target's height over the source's (the root travel's scale).
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// The target pose for the source pose `pose` into `out` (one entry per target joint).
    pub fn apply(&self, source: &Skeleton, pose: &Pose, target: &Skeleton, out: &mut Pose) {
        let mut model = Vec::new();
        let world_s = world_rotations(source, pose, &mut model);
        if out.len() != target.len() {
            *out = target.rest().clone();
        }
        // Target world rotations, parents first.
        let mut world_t: Vec<Quat> = Vec::with_capacity(target.len());
        for j in 0..target.len() {
            let parent = target.parent(j).map_or(quat::IDENTITY, |p| world_t[p]);
            let (local, world) = match self.source_of[j] {
                Some(s) => {
                    let w = quat::mul(world_s[s], quat::conj(self.source_rest[s]));
                    let world = quat::mul(w, self.target_rest[j]);
                    (quat::mul(quat::conj(parent), world), world)
                }
                None => {
                    let local = target.rest().rotation(j);
                    (local, quat::mul(parent, local))
                }
            };
            let t = if j == 0 {
                let s = pose.translation(self.source_of[0].unwrap_or(0));
                std::array::from_fn(|c| {
                    self.target_root_rest[c] + self.scale * (s[c] - self.source_root_rest[c])
                })
            } else {
                target.rest().translation(j)
            };
            out.set(
                j,
                t,
                quat::normalize(local).unwrap_or(quat::IDENTITY),
                target.rest().scale(j),
            );
            world_t.push(world);
        }
    }
}
