//! Acclaim skeletons (ASF) and their motion (AMC), as in the CMU motion capture database.
//!
//! An ASF file gives `:units` (angles in `deg` or `rad`), the `:root` (`order` of its
//! six channels, `axis` order, `position`, `orientation`), `:bonedata` (per bone: `name`,
//! unit `direction` and `length` in the root's frame at rest, `axis` angles with their
//! order, `dof` among `rx ry rz tx ty tz l`, `limits`) and the `:hierarchy`. An AMC file
//! gives, per frame, a line per bone with its dof values in `dof` order (and the root's
//! six in `order`).
//!
//! **Reading** (the Acclaim convention, as the CMU tools): a bone's axis angles give
//! `C = R_k(c) R_j(b) R_i(a)` for axis order `ijk` (rotations about fixed axes, the
//! first applied first), its motion `M` likewise from the dof angles in listed order;
//! its world rotation is `W = W_parent C M C^-1` and its end sits `length W direction`
//! past its start (the parent's end; the root's position for bones on the root).
//!
//! **As a skeleton**: the root is joint 0; each bone is a joint at its *start* whose
//! local translation is its parent bone's vector (zero under the root) and whose local
//! rotation is `C M C^-1`; a bone without children also gets a joint at its end, named
//! `<bone>_end`. Forward kinematics then puts every joint where the Acclaim reading does.

use super::bvh::Channel;
use super::clip::Clip;
use super::{JointDesc, Pose, SkeletonDesc};
use crate::io::ReadError;
use largestep_kernels::quat::{self, Quat};
use largestep_kernels::rotation;
use std::path::Path;

/// One bone of an ASF skeleton.
#[derive(Clone, Debug, PartialEq)]
pub struct AsfBone {
    /// Its name.
    pub name: String,
    /// Its parent bone, `None` under the root.
    pub parent: Option<usize>,
    /// Unit direction at rest, in the root's frame.
    pub direction: [f64; 3],
    /// Length (file units).
    pub length: f64,
    /// `C`: the rotation of its axis angles.
    pub axis: Quat,
    /// Its degrees of freedom, in AMC order (`Channel::Position` for `tx ty tz`; `l`
    /// is read and ignored, marked by `None`).
    pub dofs: Vec<Option<Channel>>,
}

/// An ASF skeleton.
#[derive(Clone, Debug, PartialEq)]
pub struct Asf {
    /// Whether angles are in degrees.
    pub degrees: bool,
    /// The root's channels, in AMC order.
    pub root_order: Vec<Channel>,
    /// The root's `C`.
    pub root_axis: Quat,
    /// The root's position at rest.
    pub root_position: [f64; 3],
    /// The bones, in file order.
    pub bones: Vec<AsfBone>,
}

/// The rotation of angles about fixed axes, the first listed applied first (radians).
fn fixed_axes(axes: &[usize], angles: &[f64]) -> Quat {
    let mut q = quat::IDENTITY;
    for (&a, &t) in axes.iter().zip(angles) {
        q = quat::mul(rotation::axis_quat(a, t), q);
    }
    q
}

/// Axis letters (`XYZ`) as indices.
fn axis_order(s: &str) -> Option<Vec<usize>> {
    s.chars()
        .map(|c| match c.to_ascii_uppercase() {
            'X' => Some(0),
            'Y' => Some(1),
            'Z' => Some(2),
            _ => None,
        })
        .collect::<Option<Vec<_>>>()
        .filter(|v| v.len() == 3)
}

/// A dof or root channel name (`rx`, `TX`, `l`).
fn dof(s: &str) -> Option<Option<Channel>> {
    let l = s.to_ascii_lowercase();
    if l == "l" {
        return Some(None);
    }
    let b = l.as_bytes();
    if b.len() != 2 {
        return None;
    }
    let axis = match b[1] {
        b'x' => 0,
        b'y' => 1,
        b'z' => 2,
        _ => return None,
    };
    match b[0] {
        b'r' => Some(Some(Channel::Rotation(axis))),
        b't' => Some(Some(Channel::Position(axis))),
        _ => None,
    }
}

fn number(s: &str) -> Option<f64> {
    s.trim_matches(|c| c == '(' || c == ')')
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
}

impl Asf {
    /// Reads an ASF file through the bounded reader.
    pub fn read(path: &Path, max_bytes: u64) -> Result<Asf, ReadError> {
        let text = crate::io::read_text(path, max_bytes)?;
        Asf::parse(&text, &path.display().to_string())
    }

    /// [`Asf::read`] on text; `name` is used in errors.
    pub fn parse(text: &str, name: &str) -> Result<Asf, ReadError> {
        let err = |line: usize, message: String| ReadError {
            path: name.to_string(),
            line,
            message,
        };
        let mut asf = Asf {
            degrees: true,
            root_order: Vec::new(),
            root_axis: quat::IDENTITY,
            root_position: [0.0; 3],
            bones: Vec::new(),
        };
        let mut section = "";
        let mut bone: Option<(AsfBone, [f64; 3], Vec<usize>, usize)> = None;
        let mut root_axes = vec![0, 1, 2];
        let mut orientation = [0.0; 3];
        let mut parents: Vec<(usize, String, String)> = Vec::new();
        let mut in_limits = false;
        for (i, raw) in text.lines().enumerate() {
            let ln = i + 1;
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let words: Vec<&str> = line.split_whitespace().collect();
            if let Some(s) = words[0].strip_prefix(':') {
                section = match s {
                    "version" | "name" | "units" | "documentation" | "root" | "bonedata"
                    | "hierarchy" => s,
                    _ => return Err(err(ln, format!("unknown section ':{s}'"))),
                };
                in_limits = false;
                continue;
            }
            let nums = |from: usize, count: usize| -> Result<Vec<f64>, ReadError> {
                let v: Option<Vec<f64>> = words
                    .get(from..from + count)
                    .and_then(|w| w.iter().map(|s| number(s)).collect::<Option<Vec<_>>>());
                v.ok_or_else(|| err(ln, format!("'{}' needs {count} finite numbers", words[0])))
            };
            match section {
                "units" if words[0] == "angle" => {
                    asf.degrees = match words.get(1).copied() {
                        Some("deg") => true,
                        Some("rad") => false,
                        other => {
                            return Err(err(ln, format!("angle unit {other:?} is not deg or rad")))
                        }
                    };
                }
                "root" => match words[0] {
                    "order" => {
                        asf.root_order = words[1..]
                            .iter()
                            .map(|w| {
                                dof(w).flatten().ok_or_else(|| {
                                    err(ln, format!("'{w}' is not a root channel (TX..RZ)"))
                                })
                            })
                            .collect::<Result<_, _>>()?;
                    }
                    "axis" => {
                        root_axes = words
                            .get(1)
                            .and_then(|w| axis_order(w))
                            .ok_or_else(|| err(ln, "axis order must be three of X, Y, Z".into()))?;
                    }
                    "position" => asf.root_position = nums(1, 3)?.try_into().expect("three"),
                    "orientation" => orientation = nums(1, 3)?.try_into().expect("three"),
                    _ => return Err(err(ln, format!("unexpected '{}' in :root", words[0]))),
                },
                "bonedata" => match words[0] {
                    "begin" => {
                        if bone.is_some() {
                            return Err(err(ln, "'begin' inside a bone".into()));
                        }
                        bone = Some((
                            AsfBone {
                                name: String::new(),
                                parent: None,
                                direction: [f64::NAN; 3],
                                length: f64::NAN,
                                axis: quat::IDENTITY,
                                dofs: Vec::new(),
                            },
                            [0.0; 3],
                            vec![0, 1, 2],
                            ln,
                        ));
                        in_limits = false;
                    }
                    "end" => {
                        let Some((mut b, axis, order, start)) = bone.take() else {
                            return Err(err(ln, "'end' without 'begin'".into()));
                        };
                        if b.name.is_empty() || b.direction[0].is_nan() || b.length.is_nan() {
                            return Err(err(
                                start,
                                "a bone needs a name, a direction and a length".into(),
                            ));
                        }
                        let s = if asf.degrees {
                            std::f64::consts::PI / 180.0
                        } else {
                            1.0
                        };
                        b.axis = fixed_axes(&order, &axis.map(|a| a * s));
                        if asf.bones.iter().any(|o| o.name == b.name) || b.name == "root" {
                            return Err(err(
                                start,
                                format!("bone name '{}' is used twice", b.name),
                            ));
                        }
                        asf.bones.push(b);
                    }
                    key => {
                        let Some((b, axis, order, _)) = bone.as_mut() else {
                            return Err(err(ln, format!("'{key}' outside a bone's begin and end")));
                        };
                        match key {
                            "id" => {}
                            "name" => {
                                b.name = words
                                    .get(1)
                                    .ok_or_else(|| err(ln, "a name is missing".into()))?
                                    .to_string()
                            }
                            "direction" => {
                                let d: [f64; 3] = nums(1, 3)?.try_into().expect("three");
                                let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                                if l == 0.0 {
                                    return Err(err(ln, "a zero direction".into()));
                                }
                                b.direction = d.map(|v| v / l);
                            }
                            "length" => {
                                let l = nums(1, 1)?[0];
                                if l < 0.0 {
                                    return Err(err(ln, format!("length {l} is negative")));
                                }
                                b.length = l;
                            }
                            "axis" => {
                                *axis = nums(1, 3)?.try_into().expect("three");
                                *order =
                                    words.get(4).and_then(|w| axis_order(w)).ok_or_else(|| {
                                        err(
                                            ln,
                                            "axis needs three angles and an order such as XYZ"
                                                .into(),
                                        )
                                    })?;
                            }
                            "dof" => {
                                b.dofs = words[1..]
                                    .iter()
                                    .map(|w| {
                                        dof(w).ok_or_else(|| {
                                            err(
                                                ln,
                                                format!("'{w}' is not a dof (rx ry rz tx ty tz l)"),
                                            )
                                        })
                                    })
                                    .collect::<Result<_, _>>()?;
                            }
                            "limits" => in_limits = true,
                            _ if in_limits && key.starts_with('(') => {}
                            other => {
                                return Err(err(ln, format!("unexpected '{other}' in a bone")))
                            }
                        }
                    }
                },
                "hierarchy" => match words[0] {
                    "begin" | "end" => {}
                    p => {
                        for c in &words[1..] {
                            parents.push((ln, p.to_string(), c.to_string()));
                        }
                    }
                },
                _ => {}
            }
        }
        if bone.is_some() {
            return Err(err(text.lines().count(), "a bone is not ended".into()));
        }
        let s = if asf.degrees {
            std::f64::consts::PI / 180.0
        } else {
            1.0
        };
        asf.root_axis = fixed_axes(&root_axes, &orientation.map(|a| a * s));
        if asf.root_order.is_empty() {
            asf.root_order = vec![
                Channel::Position(0),
                Channel::Position(1),
                Channel::Position(2),
                Channel::Rotation(0),
                Channel::Rotation(1),
                Channel::Rotation(2),
            ];
        }
        // Parents from the hierarchy; then bones in an order with parents first.
        let find = |n: &str| asf.bones.iter().position(|b| b.name == n);
        let mut parent_of: Vec<Option<Option<usize>>> = vec![None; asf.bones.len()];
        for (ln, p, c) in &parents {
            let ci = find(c).ok_or_else(|| err(*ln, format!("'{c}' is not a bone")))?;
            let pi = if p == "root" {
                None
            } else {
                Some(find(p).ok_or_else(|| err(*ln, format!("'{p}' is not a bone")))?)
            };
            if parent_of[ci].is_some() {
                return Err(err(*ln, format!("bone '{c}' has two parents")));
            }
            parent_of[ci] = Some(pi);
        }
        if let Some(b) = parent_of.iter().position(|p| p.is_none()) {
            return Err(err(
                0,
                format!("bone '{}' is not in the hierarchy", asf.bones[b].name),
            ));
        }
        // Order parents first (and refuse cycles).
        let n = asf.bones.len();
        let mut order = Vec::with_capacity(n);
        let mut placed = vec![false; n];
        while order.len() < n {
            let before = order.len();
            for b in 0..n {
                let ready = match parent_of[b].flatten() {
                    None => true,
                    Some(p) => placed[p],
                };
                if !placed[b] && ready {
                    placed[b] = true;
                    order.push(b);
                }
            }
            if order.len() == before {
                return Err(err(0, "the hierarchy has a cycle".into()));
            }
        }
        let mut new_index = vec![0; n];
        for (k, &b) in order.iter().enumerate() {
            new_index[b] = k;
        }
        let mut bones: Vec<AsfBone> = order.iter().map(|&b| asf.bones[b].clone()).collect();
        for (k, &b) in order.iter().enumerate() {
            bones[k].parent = parent_of[b].flatten().map(|p| new_index[p]);
        }
        asf.bones = bones;
        Ok(asf)
    }

    /// The joints of the skeleton (see the module docs): the root, a joint at every
    /// bone's start, and one at the end of every bone without children.
    pub fn skeleton(&self) -> SkeletonDesc {
        let mut joints = vec![JointDesc::new("root", None, [0.0; 3])];
        for b in &self.bones {
            let (parent, t) = match b.parent {
                None => (0, [0.0; 3]),
                Some(p) => {
                    let pb = &self.bones[p];
                    (1 + p, pb.direction.map(|d| d * pb.length))
                }
            };
            joints.push(JointDesc::new(&b.name, Some(parent), t));
        }
        for (k, b) in self.bones.iter().enumerate() {
            if !self.bones.iter().any(|c| c.parent == Some(k)) {
                joints.push(JointDesc::new(
                    &format!("{}_end", b.name),
                    Some(1 + k),
                    b.direction.map(|d| d * b.length),
                ));
            }
        }
        SkeletonDesc { joints }
    }

    /// `M`: the rotation of a bone's (or the root's) dof values, about fixed axes in
    /// dof order (translations and `l` skipped).
    fn local(&self, values: &[f64], dofs: &[Option<Channel>]) -> Quat {
        let s = if self.degrees {
            std::f64::consts::PI / 180.0
        } else {
            1.0
        };
        let (mut axes, mut angles) = (Vec::new(), Vec::new());
        for (d, v) in dofs.iter().zip(values) {
            if let Some(Channel::Rotation(a)) = d {
                axes.push(*a);
                angles.push(v * s);
            }
        }
        fixed_axes(&axes, &angles)
    }
}

/// AMC motion: per frame, per bone name, its values.
#[derive(Clone, Debug, PartialEq)]
pub struct Amc {
    /// Frames, each the root's values then every bone's, in the skeleton's bone order
    /// (bones the file leaves out are zero).
    pub frames: Vec<Vec<Vec<f64>>>,
}

impl Amc {
    /// Reads an AMC file for `asf` through the bounded reader.
    pub fn read(path: &Path, asf: &Asf, max_bytes: u64) -> Result<Amc, ReadError> {
        let text = crate::io::read_text(path, max_bytes)?;
        Amc::parse(&text, asf, &path.display().to_string())
    }

    /// [`Amc::read`] on text; `name` is used in errors. Frames are numbered from 1 in
    /// sequence; each bone line has exactly its dof count of finite numbers.
    pub fn parse(text: &str, asf: &Asf, name: &str) -> Result<Amc, ReadError> {
        let err = |line: usize, message: String| ReadError {
            path: name.to_string(),
            line,
            message,
        };
        let mut frames: Vec<Vec<Vec<f64>>> = Vec::new();
        let empty: Vec<Vec<f64>> = std::iter::once(vec![0.0; asf.root_order.len()])
            .chain(asf.bones.iter().map(|b| vec![0.0; b.dofs.len()]))
            .collect();
        // Each value takes two bytes at least: the frames cannot outgrow the text.
        let per_frame: usize = empty.iter().map(|v| v.len()).sum::<usize>().max(1);
        let most = text.len() / per_frame + 1;
        for (i, raw) in text.lines().enumerate() {
            let ln = i + 1;
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() || line.starts_with(':') {
                continue;
            }
            let words: Vec<&str> = line.split_whitespace().collect();
            if words.len() == 1 && words[0].parse::<usize>().is_ok() {
                let k: usize = words[0].parse().expect("checked");
                if k != frames.len() + 1 {
                    return Err(err(ln, format!("frame {k} follows frame {}", frames.len())));
                }
                if frames.len() >= most {
                    return Err(err(
                        ln,
                        "more frames than the file can hold values for".into(),
                    ));
                }
                frames.push(empty.clone());
                continue;
            }
            let Some(frame) = frames.last_mut() else {
                return Err(err(ln, "values before the first frame number".into()));
            };
            let slot = if words[0] == "root" {
                0
            } else {
                1 + asf
                    .bones
                    .iter()
                    .position(|b| b.name == words[0])
                    .ok_or_else(|| {
                        err(ln, format!("'{}' is not a bone of the skeleton", words[0]))
                    })?
            };
            let want = frame[slot].len();
            if words.len() - 1 != want {
                return Err(err(
                    ln,
                    format!(
                        "{} has {} values; its dofs are {want}",
                        words[0],
                        words.len() - 1
                    ),
                ));
            }
            for (o, w) in frame[slot].iter_mut().zip(&words[1..]) {
                *o = number(w).ok_or_else(|| err(ln, format!("'{w}' is not a finite number")))?;
            }
        }
        if frames.is_empty() {
            return Err(err(text.lines().count().max(1), "no frames".into()));
        }
        Ok(Amc { frames })
    }

    /// The local pose of frame `k` on `asf.skeleton()` (see the module docs).
    pub fn pose(&self, asf: &Asf, k: usize, pose: &mut Pose) {
        let n = asf.bones.len();
        let joints = 1
            + n
            + asf
                .bones
                .iter()
                .enumerate()
                .filter(|(i, _)| !asf.bones.iter().any(|c| c.parent == Some(*i)))
                .count();
        if pose.len() != joints {
            *pose = Pose::identity(joints);
        }
        let f = &self.frames[k];
        // Root: position plus its translation channels; rotation C M C^-1.
        let mut t = asf.root_position;
        for (c, v) in asf.root_order.iter().zip(&f[0]) {
            if let Channel::Position(a) = c {
                t[*a] += v;
            }
        }
        let dofs: Vec<Option<Channel>> = asf.root_order.iter().map(|c| Some(*c)).collect();
        let m = asf.local(&f[0], &dofs);
        let q = quat::mul(quat::mul(asf.root_axis, m), quat::conj(asf.root_axis));
        pose.set(0, t, q, [1.0; 3]);
        for (b, bone) in asf.bones.iter().enumerate() {
            let m = asf.local(&f[1 + b], &bone.dofs);
            let q = quat::mul(quat::mul(bone.axis, m), quat::conj(bone.axis));
            let t = match bone.parent {
                None => [0.0; 3],
                Some(p) => asf.bones[p].direction.map(|d| d * asf.bones[p].length),
            };
            pose.set(1 + b, t, q, [1.0; 3]);
        }
        let mut e = 1 + n;
        for (b, bone) in asf.bones.iter().enumerate() {
            if !asf.bones.iter().any(|c| c.parent == Some(b)) {
                pose.set(
                    e,
                    bone.direction.map(|d| d * bone.length),
                    quat::IDENTITY,
                    [1.0; 3],
                );
                e += 1;
            }
        }
    }

    /// The motion as a clip at `frame_time` seconds per frame (CMU's files are
    /// 120 fps: 1/120).
    pub fn clip(&self, asf: &Asf, frame_time: f64) -> Clip {
        let mut pose = Pose::identity(0);
        let poses: Vec<Pose> = (0..self.frames.len())
            .map(|k| {
                self.pose(asf, k, &mut pose);
                pose.clone()
            })
            .collect();
        Clip::from_poses(frame_time, &poses)
    }
}
