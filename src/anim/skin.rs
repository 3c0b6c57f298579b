//! Skinned meshes: a rest mesh bound to a skeleton with four influences per vertex,
//! deformed by linear blend or dual quaternion skinning (the kernels in
//! `largestep_kernels::skin`, whose docs give the formulas).
//!
//! [`SkinDesc`] (f64 rest positions and normals, influences, bind transforms) builds a
//! checked [`Skin`] (f32 SoA, weights normalised, inverse bind transforms); each frame,
//! [`Skin::deform`] turns model transforms from forward kinematics into skinning
//! matrices (and dual quaternions) in a [`SkinWork`] and skins every vertex into it,
//! without allocating once the work has its sizes.

use super::{Affine, JointError};
use largestep_kernels::anim::{affine_inverse, affine_mul};
use largestep_kernels::skin::{self, DualQuat, SkinInput, SkinMatrix};

/// How vertices follow the joints.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum SkinMethod {
    /// Linear blend skinning (blended matrices).
    #[default]
    Linear,
    /// Dual quaternion skinning (Kavan et al. 2007).
    DualQuaternion,
}

impl std::str::FromStr for SkinMethod {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "lbs" | "linear" => Ok(SkinMethod::Linear),
            "dqs" | "dual-quaternion" => Ok(SkinMethod::DualQuaternion),
            _ => Err(format!("unknown skinning method '{s}' (lbs or dqs)")),
        }
    }
}

/// The raw form of a skinned mesh.
#[derive(Clone, Debug, Default)]
pub struct SkinDesc {
    /// Rest positions, component-major (3n).
    pub positions: Vec<f64>,
    /// Rest normals, component-major (3n), or empty.
    pub normals: Vec<f64>,
    /// Four joint indices per vertex.
    pub joints: Vec<[u16; 4]>,
    /// Their weights (non-negative, not all zero; normalised by the build).
    pub weights: Vec<[f64; 4]>,
    /// The model transform of every joint when the mesh was bound (the rest pose's).
    pub bind: Vec<Affine>,
}

/// A vertex the skin refuses: its index and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SkinError {
    /// A vertex's data.
    #[error("vertex {vertex}: {message}")]
    Vertex {
        /// The vertex.
        vertex: usize,
        /// What is wrong.
        message: String,
    },
    /// A joint's bind transform.
    #[error(transparent)]
    Joint(#[from] JointError),
    /// Array sizes that disagree.
    #[error("{0}")]
    Size(String),
}

impl SkinDesc {
    /// Checks and builds the runtime skin: lengths agree, coordinates finite, joint
    /// indices within the bind transforms, weights finite and non-negative with a
    /// positive sum (then normalised), bind transforms invertible.
    pub fn build(&self) -> Result<Skin, SkinError> {
        let n = self.joints.len();
        if self.positions.len() != 3 * n || self.weights.len() != n {
            return Err(SkinError::Size(format!(
                "{} joint sets, {} weight sets and {} position values (3 per vertex) disagree",
                n,
                self.weights.len(),
                self.positions.len()
            )));
        }
        if !self.normals.is_empty() && self.normals.len() != 3 * n {
            return Err(SkinError::Size(format!(
                "{} normal values for {n} vertices",
                self.normals.len()
            )));
        }
        let bad = |vertex: usize, message: String| SkinError::Vertex { vertex, message };
        for v in 0..n {
            let coords = (0..3).flat_map(|c| {
                let a = self.positions[c * n + v];
                let b = self.normals.get(c * n + v).copied().unwrap_or(0.0);
                [a, b]
            });
            for x in coords {
                if !x.is_finite() {
                    return Err(bad(v, "position or normal is not finite".into()));
                }
            }
        }
        let joints = self.bind.len();
        let mut weights = Vec::with_capacity(n);
        for v in 0..n {
            for (k, &j) in self.joints[v].iter().enumerate() {
                if j as usize >= joints && self.weights[v][k] != 0.0 {
                    return Err(bad(
                        v,
                        format!("influence {k} names joint {j}; the skeleton has {joints}"),
                    ));
                }
            }
            let w = self.weights[v];
            if w.iter().any(|x| !x.is_finite() || *x < 0.0) {
                return Err(bad(
                    v,
                    format!("weights {w:?} are not all finite and non-negative"),
                ));
            }
            let sum: f64 = w.iter().sum();
            if sum <= 0.0 {
                return Err(bad(v, "its weights sum to zero".into()));
            }
            weights.push(w.map(|x| (x / sum) as f32));
        }
        let mut inverse_bind = Vec::with_capacity(joints);
        for (j, b) in self.bind.iter().enumerate() {
            let det = b[0] * (b[5] * b[10] - b[6] * b[9]) - b[1] * (b[4] * b[10] - b[6] * b[8])
                + b[2] * (b[4] * b[9] - b[5] * b[8]);
            if !b.iter().all(|x| x.is_finite()) || det.abs() < 1e-12 {
                return Err(SkinError::Joint(JointError {
                    index: j,
                    name: format!("joint {j}"),
                    message: "bind transform is not finite or not invertible".into(),
                }));
            }
            inverse_bind.push(affine_inverse(b));
        }
        // Unused slots (weight 0) may name any joint in the description; point them at
        // joint 0 so the kernels never index out of range.
        let joints_idx = self
            .joints
            .iter()
            .zip(&weights)
            .map(|(js, w)| {
                std::array::from_fn(|k| {
                    if w[k] == 0.0 && js[k] as usize >= joints {
                        0
                    } else {
                        js[k]
                    }
                })
            })
            .collect();
        Ok(Skin {
            positions: self.positions.iter().map(|&x| x as f32).collect(),
            normals: self.normals.iter().map(|&x| x as f32).collect(),
            joints: joints_idx,
            weights,
            inverse_bind,
        })
    }
}

/// A checked skinned mesh (immutable).
#[derive(Clone, Debug)]
pub struct Skin {
    positions: Vec<f32>,
    normals: Vec<f32>,
    joints: Vec<[u16; 4]>,
    weights: Vec<[f32; 4]>,
    inverse_bind: Vec<Affine>,
}

/// Per-frame buffers of a skin: skinning matrices, dual quaternions, deformed
/// positions and normals (component-major f32).
#[derive(Clone, Debug, Default)]
pub struct SkinWork {
    /// Skinning matrices, one per joint.
    pub matrices: Vec<SkinMatrix>,
    /// Their dual quaternions (dual quaternion skinning only).
    pub dual: Vec<DualQuat>,
    /// Deformed positions, component-major.
    pub positions: Vec<f32>,
    /// Deformed normals, component-major (empty without rest normals).
    pub normals: Vec<f32>,
}

impl Skin {
    /// The number of vertices.
    pub fn len(&self) -> usize {
        self.joints.len()
    }

    /// Whether it has no vertices.
    pub fn is_empty(&self) -> bool {
        self.joints.is_empty()
    }

    /// The number of joints it is bound to.
    pub fn joint_count(&self) -> usize {
        self.inverse_bind.len()
    }

    /// The kernels' view of the rest mesh.
    pub fn input(&self) -> SkinInput<'_> {
        SkinInput {
            positions: &self.positions,
            normals: &self.normals,
            joints: &self.joints,
            weights: &self.weights,
        }
    }

    /// Skins every vertex for the model transforms `model` (one per joint, from
    /// [`super::Skeleton::model`]) into `work.positions` and `work.normals`, in parallel.
    pub fn deform(&self, method: SkinMethod, model: &[Affine], work: &mut SkinWork) {
        assert_eq!(
            model.len(),
            self.joint_count(),
            "one model transform per bound joint"
        );
        work.matrices.clear();
        work.matrices.extend(
            model
                .iter()
                .zip(&self.inverse_bind)
                .map(|(m, ib)| skin::skin_matrix(&affine_mul(m, ib))),
        );
        work.positions.resize(self.positions.len(), 0.0);
        work.normals.resize(self.normals.len(), 0.0);
        let input = self.input();
        match method {
            SkinMethod::Linear => skin::lbs_par(
                &mut work.positions,
                &mut work.normals,
                &input,
                &work.matrices,
            ),
            SkinMethod::DualQuaternion => {
                work.dual.resize(work.matrices.len(), [0.0; 8]);
                skin::dual_quaternions(&mut work.dual, &work.matrices);
                skin::dqs_par(&mut work.positions, &mut work.normals, &input, &work.dual)
            }
        }
    }
}
