//! Biovision hierarchy (BVH) motion capture, read and written.
//!
//! A `HIERARCHY` of `ROOT`/`JOINT` blocks, each with an `OFFSET` (from its parent, in the
//! file's units) and a `CHANNELS` line naming any of `Xposition Yposition Zposition
//! Xrotation Yrotation Zrotation` in any order, and `End Site` leaves with an offset
//! only; then `MOTION`, `Frames: N`, `Frame Time: dt` and N lines of all channels' values
//! in hierarchy order. Tabs or spaces, any line ending.
//!
//! **Reading of the channels** (as Blender and the bvh-python reader do): a joint's local
//! translation is its offset plus its position channels; its local rotation is the
//! product of the rotation channels in the order listed, `R = R_1 R_2 R_3` (degrees), so
//! `Zrotation Yrotation Xrotation` is the Euler order `ZYX` of
//! `largestep_kernels::rotation`.
//!
//! End Sites become joints without channels named `<parent>_end`, in file order, so a
//! skeleton built from a file has every point the file places.

use super::{JointDesc, Pose, SkeletonDesc};
use crate::io::ReadError;
use largestep_kernels::quat::{self, Quat};
use largestep_kernels::rotation;
use std::io::Write;
use std::path::Path;

/// One channel of a joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// Translation along x, y or z (0, 1, 2).
    Position(usize),
    /// Rotation about x, y or z (0, 1, 2), degrees.
    Rotation(usize),
}

impl Channel {
    fn parse(s: &str) -> Option<Channel> {
        let lower = s.to_ascii_lowercase();
        let axis = match lower.as_bytes().first()? {
            b'x' => 0,
            b'y' => 1,
            b'z' => 2,
            _ => return None,
        };
        match &lower[1..] {
            "position" => Some(Channel::Position(axis)),
            "rotation" => Some(Channel::Rotation(axis)),
            _ => None,
        }
    }

    fn name(self) -> String {
        let (axis, kind) = match self {
            Channel::Position(a) => (a, "position"),
            Channel::Rotation(a) => (a, "rotation"),
        };
        format!("{}{kind}", (b'X' + axis as u8) as char)
    }
}

/// A joint of a BVH file (an End Site is a joint with `end_site` set and no channels).
#[derive(Clone, Debug, PartialEq)]
pub struct BvhJoint {
    /// Its name; End Sites are named `<parent>_end`.
    pub name: String,
    /// Its parent's index, `None` for a root.
    pub parent: Option<usize>,
    /// Offset from the parent.
    pub offset: [f64; 3],
    /// Its channels, in file order.
    pub channels: Vec<Channel>,
    /// Whether it is an End Site.
    pub end_site: bool,
}

/// A BVH clip: the hierarchy in file order and its motion.
#[derive(Clone, Debug, PartialEq)]
pub struct Bvh {
    /// Joints in the order they appear, End Sites included.
    pub joints: Vec<BvhJoint>,
    /// Seconds per frame (> 0).
    pub frame_time: f64,
    /// Channel values, one row of [`Bvh::channel_count`] per frame.
    pub motion: Vec<f64>,
}

/// Frames and channels a file may declare before anything is allocated for them: what
/// the file's own text can hold (each value takes at least two bytes) bounds them.
fn check_size(frames: usize, channels: usize, text_len: usize) -> Result<(), String> {
    match frames.checked_mul(channels) {
        Some(v) if v <= text_len / 2 + 1 => Ok(()),
        _ => Err(format!(
            "declares {frames} frames of {channels} channels, more values than the file can hold"
        )),
    }
}

impl Bvh {
    /// The number of channels per frame.
    pub fn channel_count(&self) -> usize {
        self.joints.iter().map(|j| j.channels.len()).sum()
    }

    /// The number of frames.
    pub fn frames(&self) -> usize {
        self.motion
            .len()
            .checked_div(self.channel_count())
            .unwrap_or(0)
    }

    /// The channel values of frame `k`.
    pub fn frame(&self, k: usize) -> &[f64] {
        let c = self.channel_count();
        &self.motion[k * c..(k + 1) * c]
    }

    /// Reads a BVH file through the bounded reader (at most `max_bytes`).
    pub fn read(path: &Path, max_bytes: u64) -> Result<Bvh, ReadError> {
        let text = crate::io::read_text(path, max_bytes)?;
        Bvh::parse(&text, &path.display().to_string())
    }

    /// [`Bvh::read`] on text; `name` is used in errors.
    pub fn parse(text: &str, name: &str) -> Result<Bvh, ReadError> {
        let err = |line: usize, message: String| ReadError {
            path: name.to_string(),
            line,
            message,
        };
        // Tokens with their 1-based lines, up to MOTION.
        let lines: Vec<&str> = text.lines().collect();
        let mut tokens: Vec<(&str, usize)> = Vec::new();
        let mut motion_line = None;
        for (i, l) in lines.iter().enumerate() {
            let first = l.split_whitespace().next();
            if first == Some("MOTION") {
                motion_line = Some(i);
                break;
            }
            tokens.extend(l.split_whitespace().map(|t| (t, i + 1)));
        }
        let mut at = 0;
        let last_line = lines.len().max(1);
        let mut next = |what: &str| -> Result<(&str, usize), ReadError> {
            let t = tokens.get(at).copied().ok_or_else(|| {
                err(
                    motion_line.map_or(last_line, |m| m + 1),
                    format!("the hierarchy ends early: expected {what}"),
                )
            })?;
            at += 1;
            Ok(t)
        };
        let (t, l) = next("HIERARCHY")?;
        if t != "HIERARCHY" {
            return Err(err(l, format!("expected HIERARCHY, found '{t}'")));
        }
        let mut joints: Vec<BvhJoint> = Vec::new();
        // The open blocks: joint index (End Sites too).
        let mut stack: Vec<usize> = Vec::new();
        let mut channels_total = 0usize;
        while let Some(&(t, l)) = tokens.get(at) {
            at += 1;
            match t {
                "ROOT" | "JOINT" | "End" => {
                    if t == "ROOT" && !stack.is_empty() {
                        return Err(err(l, "ROOT inside another joint's block".into()));
                    }
                    if t != "ROOT" && stack.is_empty() {
                        return Err(err(l, format!("{t} outside any joint's block")));
                    }
                    if let Some(&p) = stack.last() {
                        if joints[p].end_site {
                            return Err(err(l, "an End Site cannot have children".into()));
                        }
                    }
                    // The name: the rest of the line, less a '{' ending it.
                    let mut words = Vec::new();
                    while let Some(&(w, wl)) = tokens.get(at) {
                        if wl != l || w == "{" {
                            break;
                        }
                        words.push(w);
                        at += 1;
                    }
                    let end_site = t == "End";
                    let name = if end_site {
                        if words != ["Site"] {
                            return Err(err(l, "expected 'End Site'".into()));
                        }
                        format!("{}_end", joints[*stack.last().unwrap_or(&0)].name)
                    } else {
                        if words.is_empty() {
                            return Err(err(l, format!("{t} without a name")));
                        }
                        words.join(" ")
                    };
                    let (b, bl) = tokens
                        .get(at)
                        .copied()
                        .ok_or_else(|| err(l, format!("'{{' expected after {name}")))?;
                    if b != "{" {
                        return Err(err(bl, format!("'{{' expected after {name}, found '{b}'")));
                    }
                    at += 1;
                    joints.push(BvhJoint {
                        name,
                        parent: stack.last().copied(),
                        offset: [f64::NAN; 3],
                        channels: Vec::new(),
                        end_site,
                    });
                    stack.push(joints.len() - 1);
                }
                "OFFSET" => {
                    let Some(&j) = stack.last() else {
                        return Err(err(l, "OFFSET outside any joint's block".into()));
                    };
                    for c in 0..3 {
                        let (v, vl) = tokens
                            .get(at)
                            .copied()
                            .filter(|&(_, vl)| vl == l)
                            .ok_or_else(|| err(l, "OFFSET needs three numbers".into()))?;
                        at += 1;
                        joints[j].offset[c] = parse_number(v)
                            .ok_or_else(|| err(vl, format!("'{v}' is not a finite number")))?;
                    }
                }
                "CHANNELS" => {
                    let Some(&j) = stack.last() else {
                        return Err(err(l, "CHANNELS outside any joint's block".into()));
                    };
                    if joints[j].end_site {
                        return Err(err(l, "an End Site has no channels".into()));
                    }
                    if !joints[j].channels.is_empty() {
                        return Err(err(
                            l,
                            format!("{} has a second CHANNELS line", joints[j].name),
                        ));
                    }
                    let (v, _) = tokens
                        .get(at)
                        .copied()
                        .ok_or_else(|| err(l, "CHANNELS needs a count".into()))?;
                    at += 1;
                    let count: usize = v
                        .parse()
                        .ok()
                        .filter(|&c| c <= 6)
                        .ok_or_else(|| err(l, format!("channel count '{v}' is not 0 to 6")))?;
                    let mut found = 0;
                    while let Some(&(w, wl)) = tokens.get(at) {
                        if wl != l {
                            break;
                        }
                        at += 1;
                        found += 1;
                        let c = Channel::parse(w).ok_or_else(|| {
                            err(
                                l,
                                format!(
                                    "unknown channel '{w}' (Xposition, Yposition, Zposition, Xrotation, Yrotation or Zrotation)"
                                ),
                            )
                        })?;
                        if joints[j].channels.contains(&c) {
                            return Err(err(
                                l,
                                format!(
                                    "channel {} appears twice: no rotation order repeats an axis",
                                    c.name()
                                ),
                            ));
                        }
                        joints[j].channels.push(c);
                    }
                    if found != count {
                        return Err(err(l, format!("CHANNELS says {count} but names {found}")));
                    }
                    channels_total += count;
                }
                "}" => {
                    let Some(j) = stack.pop() else {
                        return Err(err(l, "'}' without an open block".into()));
                    };
                    if joints[j].offset.iter().any(|v| v.is_nan()) {
                        return Err(err(l, format!("{} has no OFFSET", joints[j].name)));
                    }
                }
                "Frames:" | "Frames" => {
                    return Err(err(
                        l,
                        format!("unexpected '{t}' in the hierarchy: is the MOTION line missing?"),
                    ));
                }
                other => {
                    return Err(err(l, format!("unexpected '{other}' in the hierarchy")));
                }
            }
        }
        if let Some(&j) = stack.last() {
            return Err(err(
                motion_line.map_or(last_line, |m| m + 1),
                format!("the block of {} is not closed", joints[j].name),
            ));
        }
        if joints.is_empty() {
            return Err(err(1, "the hierarchy has no ROOT".into()));
        }
        let Some(m) = motion_line else {
            return Err(err(last_line, "no MOTION section".into()));
        };
        // "Frames: N" and "Frame Time: dt", then the rows.
        let header = |i: usize, key: &str| -> Result<&str, ReadError> {
            let l = lines
                .get(i)
                .ok_or_else(|| err(i, format!("the file ends before '{key}'")))?;
            let t = l.trim();
            t.strip_prefix(key).map(str::trim).ok_or_else(|| {
                err(
                    i + 1,
                    format!("expected '{key} ...', found '{}'", crate::io::clip(t, 60)),
                )
            })
        };
        let frames_s = header(m + 1, "Frames:")?;
        let frames: usize = frames_s.parse().map_err(|_| {
            err(
                m + 2,
                format!("frame count '{frames_s}' is not a whole number"),
            )
        })?;
        let dt_s = header(m + 2, "Frame Time:")?;
        let frame_time = parse_number(dt_s).filter(|&d| d > 0.0).ok_or_else(|| {
            err(
                m + 3,
                format!("frame time '{dt_s}' is not a positive number of seconds"),
            )
        })?;
        check_size(frames, channels_total, text.len()).map_err(|e| err(m + 2, e))?;
        let mut motion = Vec::with_capacity(frames * channels_total);
        let mut rows = 0;
        for (i, l) in lines.iter().enumerate().skip(m + 3) {
            if l.trim().is_empty() {
                continue;
            }
            if rows == frames {
                return Err(err(
                    i + 1,
                    format!("more motion lines than the {frames} frames declared"),
                ));
            }
            let found = l.split_whitespace().count();
            if found != channels_total {
                return Err(err(
                    i + 1,
                    format!("frame {rows} has {found} values; the hierarchy has {channels_total} channels"),
                ));
            }
            for v in l.split_whitespace() {
                motion.push(
                    parse_number(v)
                        .ok_or_else(|| err(i + 1, format!("'{v}' is not a finite number")))?,
                );
            }
            rows += 1;
        }
        if rows < frames {
            return Err(err(
                lines.len(),
                format!("{frames} frames declared, {rows} motion lines found"),
            ));
        }
        Ok(Bvh {
            joints,
            frame_time,
            motion,
        })
    }

    /// Writes the clip as BVH text: tab-indented, values in the shortest form that reads
    /// back to the same `f64` (so read, write, read gives an identical clip).
    pub fn write(&self, w: &mut dyn Write) -> std::io::Result<()> {
        writeln!(w, "HIERARCHY")?;
        // Close blocks when the next joint's parent is not the open one.
        let mut open: Vec<usize> = Vec::new();
        let indent = |d: usize| "\t".repeat(d);
        for (i, j) in self.joints.iter().enumerate() {
            while open.last().is_some_and(|&o| Some(o) != j.parent) {
                open.pop();
                writeln!(w, "{}}}", indent(open.len()))?;
            }
            let d = open.len();
            if j.end_site {
                writeln!(w, "{}End Site", indent(d))?;
            } else if j.parent.is_none() {
                writeln!(w, "{}ROOT {}", indent(d), j.name)?;
            } else {
                writeln!(w, "{}JOINT {}", indent(d), j.name)?;
            }
            writeln!(w, "{}{{", indent(d))?;
            let [x, y, z] = j.offset;
            writeln!(w, "{}OFFSET {x:?} {y:?} {z:?}", indent(d + 1))?;
            if !j.end_site {
                write!(w, "{}CHANNELS {}", indent(d + 1), j.channels.len())?;
                for c in &j.channels {
                    write!(w, " {}", c.name())?;
                }
                writeln!(w)?;
            }
            open.push(i);
        }
        while open.pop().is_some() {
            writeln!(w, "{}}}", indent(open.len()))?;
        }
        writeln!(w, "MOTION")?;
        writeln!(w, "Frames: {}", self.frames())?;
        writeln!(w, "Frame Time: {:?}", self.frame_time)?;
        let c = self.channel_count();
        if c > 0 {
            for row in self.motion.chunks(c) {
                let mut first = true;
                for v in row {
                    if !first {
                        write!(w, " ")?;
                    }
                    first = false;
                    write!(w, "{v:?}")?;
                }
                writeln!(w)?;
            }
        }
        Ok(())
    }

    /// The skeleton the hierarchy describes: each joint at its offset, no rest rotation.
    pub fn skeleton(&self) -> SkeletonDesc {
        SkeletonDesc {
            joints: self
                .joints
                .iter()
                .map(|j| JointDesc::new(&j.name, j.parent, j.offset))
                .collect(),
        }
    }

    /// The local pose at frame `k` (see the module docs) into `pose` (one entry per
    /// joint of [`Bvh::skeleton`]).
    pub fn pose(&self, k: usize, pose: &mut Pose) {
        let values = self.frame(k);
        let mut at = 0;
        if pose.len() != self.joints.len() {
            *pose = Pose::identity(self.joints.len());
        }
        for (i, j) in self.joints.iter().enumerate() {
            let mut t = j.offset;
            let mut q: Quat = quat::IDENTITY;
            for c in &j.channels {
                let v = values[at];
                at += 1;
                match *c {
                    Channel::Position(a) => t[a] += v,
                    Channel::Rotation(a) => {
                        q = quat::mul(q, rotation::axis_quat(a, v.to_radians()));
                    }
                }
            }
            pose.set(i, t, q, [1.0; 3]);
        }
    }
}

impl Bvh {
    /// The model-space (world) position of every joint at frame `k`, in joint order:
    /// the skeleton built, posed by the frame, and run through forward kinematics.
    /// Errors name the frame when it is out of range, or the joint the skeleton refuses
    /// (a name used twice).
    pub fn positions(&self, k: usize) -> Result<Vec<[f64; 3]>, String> {
        if k >= self.frames() {
            return Err(format!(
                "frame {k} is out of range: the clip has {} frames (0 to {})",
                self.frames(),
                self.frames().saturating_sub(1)
            ));
        }
        let skeleton = self.skeleton().build().map_err(|e| e.to_string())?;
        let mut pose = Pose::identity(skeleton.len());
        self.pose(k, &mut pose);
        let mut model = Vec::new();
        skeleton.model(&pose, &mut model);
        Ok(model.iter().map(|m| [m[3], m[7], m[11]]).collect())
    }
}

/// A finite number, or `None`.
fn parse_number(s: &str) -> Option<f64> {
    s.parse::<f64>().ok().filter(|v| v.is_finite())
}
