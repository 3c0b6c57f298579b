//! The `[anim]` scene table and [`AnimSim`], character animation played as a scene: the
//! frames are skeletons (bones as segments, joints as discs) or skinned meshes.
//!
//! ```toml
//! [scene]
//! name = "anim-clip"
//! dt = 0.0333333               # s per frame written
//! duration = 2.3
//!
//! [anim.clip]                  # a BVH clip played on its skeleton
//! file = "../../shared/data/mocap/mixamo-freebvh.bvh"  # relative to the scene file
//! scale = 0.01                 # metres per file unit (default 1)
//! loop = true                  # wrap around at the end (default: hold the last frame)
//!
//! [anim.twist]                 # a two-bone arm around a tube, LBS beside DQS
//! angle = 180.0                # degrees of twist of the lower bone at the end
//! bend = 0.0                   # degrees of bend about z at the end
//!
//! [anim.reach]                 # a three-link arm per IK method chasing a moving target
//! lambda = 0.1                 # damping of damped least squares (m)
//! radius = 0.9                 # m, the target's circle, centred 0.4 m out (the arm
//!                              # reaches 1.2 m, so part of the circle is out of reach)
//! ```
//!
//! [anim.walk]                  # a random walk on a motion graph built from a clip
//! file = "../../shared/data/mocap/mixamo-freebvh.bvh"
//! scale = 0.01
//! window = 6                   # frames compared and blended at a transition
//! threshold = 12.0             # largest pose distance of a transition (file units)
//! seed = 1                     # the walk's random choices
//!
//! A table holds exactly one of `clip`, `twist`, `reach`, `walk`.

use super::bvh::Bvh;
use super::clip::Clip;
use super::ik::{Effector, Ik, IkJoint, IkMethod};
use super::motion_graph::{MotionGraph, MotionGraphDesc};
use super::skin::{Skin, SkinDesc, SkinMethod, SkinWork};
use super::{Affine, JointDesc, Pose, Skeleton, SkeletonDesc};
use crate::integrate::{IntegrateError, StepInfo};
use crate::io::{Mesh, MeshRef};
use crate::scene::{path, Context, SceneError};
use crate::simulation::{Energy, FrameData, Simulation, Stage};
use serde::Deserialize;
use std::time::Instant;

/// `[anim]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnimTable {
    #[serde(default)]
    clip: Option<ClipTable>,
    #[serde(default)]
    twist: Option<TwistTable>,
    #[serde(default)]
    reach: Option<ReachTable>,
    #[serde(default)]
    walk: Option<WalkTable>,
}

/// `[anim.walk]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct WalkTable {
    file: String,
    #[serde(default)]
    scale: Option<f64>,
    #[serde(default)]
    window: Option<i64>,
    #[serde(default)]
    threshold: Option<f64>,
    #[serde(default)]
    seed: Option<i64>,
}

/// `[anim.clip]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ClipTable {
    file: String,
    #[serde(default)]
    scale: Option<f64>,
    #[serde(default, rename = "loop")]
    looping: bool,
}

/// `[anim.twist]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TwistTable {
    #[serde(default)]
    angle: Option<f64>,
    #[serde(default)]
    bend: Option<f64>,
}

/// `[anim.reach]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ReachTable {
    #[serde(default)]
    lambda: Option<f64>,
    #[serde(default)]
    radius: Option<f64>,
}

/// What an [`AnimSim`] plays.
enum Show {
    /// A clip on its skeleton, positions scaled.
    Clip {
        clip: Clip,
        scale: f64,
        looping: bool,
    },
    /// The twisted arm: the skin, its work, the final twist and bend (rad).
    Twist {
        skin: Box<Skin>,
        rest: Mesh,
        work: SkinWork,
        angle: f64,
        bend: f64,
    },
    /// A random walk on a motion graph: its poses at the clip's rate.
    Walk {
        poses: Vec<Pose>,
        frame_time: f64,
        scale: f64,
    },
    /// One IK solver per method, with its angles and last report.
    Reach {
        solvers: Vec<(Ik, Vec<f64>, f64)>,
        radius: f64,
    },
}

/// A running animation scene.
pub struct AnimSim {
    skeleton: Skeleton,
    show: Show,
    pose: Pose,
    model: Vec<Affine>,
    time: f64,
    duration: f64,
    steps: u64,
    positions: Vec<f64>,
    triangles: Vec<[u32; 3]>,
    segments: Vec<[u32; 2]>,
    notes: Vec<String>,
    /// The frame's points one after another (kept between steps).
    points: Vec<[f64; 3]>,
}

/// Builds the `[anim]` system.
pub fn build(ctx: &Context<'_>) -> Result<Box<dyn Simulation>, SceneError> {
    let t: AnimTable = ctx.table()?;
    let given = [
        t.clip.is_some(),
        t.twist.is_some(),
        t.reach.is_some(),
        t.walk.is_some(),
    ];
    if given.iter().filter(|&&g| g).count() != 1 {
        return Err(ctx.error(
            &[],
            "[anim] holds exactly one of clip, twist, reach or walk",
        ));
    }
    let sim = if let Some(wt) = &t.walk {
        let at = path(&[&"walk", &"file"]);
        let file = ctx.base.join(&wt.file);
        let bvh = Bvh::read(&file, ctx.limits.max_file_bytes)
            .map_err(|e| ctx.error(&at, e.to_string()))?;
        let skeleton = bvh
            .skeleton()
            .build()
            .map_err(|e| ctx.error(&at, e.to_string()))?;
        let clip = Clip::from_bvh(&bvh);
        let scale = match wt.scale {
            Some(s) => ctx.positive(s, &path(&[&"walk", &"scale"]), "scale")?,
            None => 1.0,
        };
        let window = wt.window.unwrap_or(6);
        if !(2..=10_000).contains(&window) {
            return Err(ctx.error(
                &path(&[&"walk", &"window"]),
                "window must be 2 to 10000 frames",
            ));
        }
        let threshold = ctx.positive(
            wt.threshold.unwrap_or(12.0),
            &path(&[&"walk", &"threshold"]),
            "threshold",
        )?;
        let desc = MotionGraphDesc {
            window: window as usize,
            threshold,
            weights: Vec::new(),
        };
        // The distance matrix holds (frames - window + 1)^2 values twice over.
        let side = clip.frames() as f64;
        ctx.memory(
            &at,
            "the motion graph's distance matrix",
            64.0 * side * side,
        )?;
        let graph = MotionGraph::build(&skeleton, &clip, &desc).map_err(|e| ctx.error(&[], e))?;
        let frames = (ctx.duration / clip.frame_time()).ceil() as usize + 1;
        ctx.memory(
            &[],
            "the walk's poses",
            frames as f64 * skeleton.len() as f64 * 80.0,
        )?;
        let mut poses = Vec::new();
        graph.random_walk(
            &skeleton,
            &clip,
            frames,
            wt.seed.unwrap_or(1) as u64,
            &mut poses,
        );
        if poses.is_empty() {
            return Err(ctx.error(
                &[],
                "the motion graph kept no frames (raise the threshold?)",
            ));
        }
        let notes = vec![format!(
            "motion graph: {} transitions, {} of {} frames kept",
            graph.transitions().len(),
            graph.kept_count(),
            clip.frames()
        )];
        AnimSim::new(
            skeleton,
            Show::Walk {
                poses,
                frame_time: clip.frame_time(),
                scale,
            },
            ctx.duration,
            notes,
        )
    } else if let Some(c) = &t.clip {
        let at = path(&[&"clip", &"file"]);
        let file = ctx.base.join(&c.file);
        let bvh = Bvh::read(&file, ctx.limits.max_file_bytes)
            .map_err(|e| ctx.error(&at, e.to_string()))?;
        if bvh.frames() == 0 {
            return Err(ctx.error(&at, format!("{}: the clip has no frames", c.file)));
        }
        let skeleton = bvh
            .skeleton()
            .build()
            .map_err(|e| ctx.error(&at, e.to_string()))?;
        let scale = match c.scale {
            Some(s) => ctx.positive(s, &path(&[&"clip", &"scale"]), "scale")?,
            None => 1.0,
        };
        let notes = vec![format!(
            "clip: {} joints, {} frames at {} s",
            skeleton.len(),
            bvh.frames(),
            bvh.frame_time
        )];
        AnimSim::new(
            skeleton,
            Show::Clip {
                clip: Clip::from_bvh(&bvh),
                scale,
                looping: c.looping,
            },
            ctx.duration,
            notes,
        )
    } else if let Some(w) = &t.twist {
        let finite = |v: Option<f64>, key: &str, d: f64| -> Result<f64, SceneError> {
            let v = v.unwrap_or(d);
            if v.is_finite() {
                Ok(v.to_radians())
            } else {
                Err(ctx.error(&path(&[&"twist", &key]), format!("{key} must be finite")))
            }
        };
        let (angle, bend) = (
            finite(w.angle, "angle", 180.0)?,
            finite(w.bend, "bend", 0.0)?,
        );
        let (skeleton, rest, desc) = twisted_arm();
        let skin = desc.build().map_err(|e| ctx.error(&[], e.to_string()))?;
        AnimSim::new(
            skeleton,
            Show::Twist {
                skin: Box::new(skin),
                rest,
                work: SkinWork::default(),
                angle,
                bend,
            },
            ctx.duration,
            Vec::new(),
        )
    } else {
        let r = t.reach.as_ref().expect("one table given");
        let lambda = ctx.positive(
            r.lambda.unwrap_or(0.1),
            &path(&[&"reach", &"lambda"]),
            "lambda",
        )?;
        let radius = ctx.positive(
            r.radius.unwrap_or(0.8),
            &path(&[&"reach", &"radius"]),
            "radius",
        )?;
        let skeleton = reach_arms();
        let mut solvers = Vec::new();
        for (k, method) in IkMethod::all(lambda).into_iter().enumerate() {
            let joints = (0..3)
                .map(|j| IkJoint {
                    // Hinges about z, free to wind round with the target (two turns
                    // either way).
                    limits: vec![(-4.0 * std::f64::consts::PI, 4.0 * std::f64::consts::PI)],
                    ..IkJoint::free(4 * k + j, &[2])
                })
                .collect();
            let mut ik =
                Ik::new(&skeleton, joints, method).map_err(|e| ctx.error(&[], e.to_string()))?;
            ik.max_iterations = 20;
            ik.tolerance = 1e-4;
            solvers.push((ik, vec![0.3, 0.3, 0.3], 0.0));
        }
        AnimSim::new(
            skeleton,
            Show::Reach { solvers, radius },
            ctx.duration,
            Vec::new(),
        )
    };
    let mut sim = sim;
    sim.pose_now();
    Ok(Box::new(sim))
}

/// The arm of the twist scene: bones from x = 0 to 1 and 1 to 2 around a tube of
/// radius 0.2 (81 rings of 32), the lower bone's weight rising from x = 0.5 to 1.5.
fn twisted_arm() -> (Skeleton, Mesh, SkinDesc) {
    let skeleton = SkeletonDesc {
        joints: vec![
            JointDesc::new("upper", None, [0.0; 3]),
            JointDesc::new("lower", Some(0), [1.0, 0.0, 0.0]),
        ],
    }
    .build()
    .expect("a valid skeleton");
    let mesh = crate::shapes::tube(2.0, 0.2, 81, 32);
    let n = mesh.positions.len() / 3;
    let mut bind = Vec::new();
    skeleton.model(skeleton.rest(), &mut bind);
    let desc = SkinDesc {
        positions: mesh.positions.clone(),
        normals: Vec::new(),
        joints: vec![[0, 1, 0, 0]; n],
        weights: (0..n)
            .map(|v| {
                let w = (mesh.positions[v] - 0.5).clamp(0.0, 1.0);
                [1.0 - w, w, 0.0, 0.0]
            })
            .collect(),
        bind,
    };
    (skeleton, mesh, desc)
}

/// Where arm `k` of the reach scene is fixed: in a row along x, 1.2 m up.
fn arm_root(k: usize) -> [f64; 3] {
    [2.4 * k as f64, 1.2, 0.0]
}

/// Five three-link planar arms (0.5, 0.4, 0.3 m) in a row, each with its tip as a
/// joint: joints `4k..4k+3` are arm `k`.
fn reach_arms() -> Skeleton {
    let mut joints = Vec::new();
    for k in 0..5 {
        let b = joints.len();
        joints.push(JointDesc::new(&format!("arm{k}"), None, arm_root(k)));
        joints.push(JointDesc::new(
            &format!("arm{k}.1"),
            Some(b),
            [0.5, 0.0, 0.0],
        ));
        joints.push(JointDesc::new(
            &format!("arm{k}.2"),
            Some(b + 1),
            [0.4, 0.0, 0.0],
        ));
        joints.push(JointDesc::new(
            &format!("arm{k}.tip"),
            Some(b + 2),
            [0.3, 0.0, 0.0],
        ));
    }
    SkeletonDesc { joints }.build().expect("a valid skeleton")
}

impl AnimSim {
    fn new(skeleton: Skeleton, show: Show, duration: f64, notes: Vec<String>) -> AnimSim {
        AnimSim {
            pose: skeleton.rest().clone(),
            skeleton,
            show,
            model: Vec::new(),
            time: 0.0,
            duration: duration.max(f64::MIN_POSITIVE),
            steps: 0,
            positions: Vec::new(),
            points: Vec::new(),
            triangles: Vec::new(),
            segments: Vec::new(),
            notes,
        }
    }

    /// The target of arm `k` at time `t`: a circle in the arm's plane, centred 0.4 m
    /// out from its root, once around in 4 s; the same path relative to each arm.
    fn target(radius: f64, t: f64, k: usize) -> [f64; 3] {
        let a = std::f64::consts::TAU * t / 4.0;
        let r = arm_root(k);
        [r[0] + 0.4 + radius * a.cos(), r[1] + radius * a.sin(), r[2]]
    }

    /// Poses the skeleton at the present time and forms the frame.
    fn pose_now(&mut self) {
        let s = (self.time / self.duration).clamp(0.0, 1.0);
        self.triangles.clear();
        self.segments.clear();
        // Points one after another (made component-major at the end).
        let mut points = std::mem::take(&mut self.points);
        points.clear();
        let mut scale = 1.0;
        match &mut self.show {
            Show::Clip {
                clip,
                scale: sc,
                looping,
            } => {
                clip.sample(self.time, *looping, &mut self.pose);
                scale = *sc;
            }
            Show::Walk {
                poses,
                frame_time,
                scale: sc,
            } => {
                let k = ((self.time / *frame_time).round() as usize).min(poses.len() - 1);
                self.pose.clone_from(&poses[k]);
                scale = *sc;
            }
            Show::Twist {
                skin,
                rest,
                work,
                angle,
                bend,
            } => {
                let q = largestep_kernels::quat::mul(
                    largestep_kernels::quat::exp([0.0, 0.0, *bend * s]),
                    largestep_kernels::quat::exp([*angle * s, 0.0, 0.0]),
                );
                self.pose.set(1, [1.0, 0.0, 0.0], q, [1.0; 3]);
                self.skeleton.model(&self.pose, &mut self.model);
                // LBS in front (z = +0.35), DQS behind (z = -0.35).
                let n = rest.positions.len() / 3;
                for (k, method) in [SkinMethod::Linear, SkinMethod::DualQuaternion]
                    .into_iter()
                    .enumerate()
                {
                    skin.deform(method, &self.model, work);
                    let dz = if k == 0 { 0.35 } else { -0.35 };
                    let w = &work.positions;
                    points.extend(
                        (0..n).map(|v| [w[v] as f64, w[n + v] as f64, w[2 * n + v] as f64 + dz]),
                    );
                    let off = (k * n) as u32;
                    self.triangles
                        .extend(rest.triangles.iter().map(|t| t.map(|i| i + off)));
                }
            }
            Show::Reach { solvers, radius } => {
                for (k, (ik, angles, worst)) in solvers.iter_mut().enumerate() {
                    let target = Self::target(*radius, self.time, k);
                    let eff = [Effector {
                        joint: 4 * k + 3,
                        target,
                    }];
                    if let Ok(r) = ik.solve(&self.skeleton, &mut self.pose, angles, &eff) {
                        *worst = worst.max(r.distances[0]);
                    }
                }
            }
        }
        if points.is_empty() {
            // A skeleton: joints as points, bones as segments, and the targets as points
            // (on the circles the scenery draws).
            self.skeleton.model(&self.pose, &mut self.model);
            points.extend(
                self.model
                    .iter()
                    .map(|m| [m[3], m[7], m[11]].map(|v| v * scale)),
            );
            for j in 0..self.skeleton.len() {
                if let Some(p) = self.skeleton.parent(j) {
                    self.segments.push([p as u32, j as u32]);
                }
            }
            if let Show::Reach { solvers, radius } = &self.show {
                points.extend((0..solvers.len()).map(|k| Self::target(*radius, self.time, k)));
            }
        }
        self.positions.clear();
        for c in 0..3 {
            self.positions.extend(points.iter().map(|p| p[c]));
        }
        self.points = points;
    }
}

impl Simulation for AnimSim {
    fn step(&mut self, dt: f64) -> Result<StepInfo, IntegrateError> {
        let t0 = Instant::now();
        self.time += dt;
        self.steps += 1;
        self.pose_now();
        Ok(StepInfo {
            newton_iterations: 0,
            linear_iterations: 0,
            residual: 0.0,
            solve_seconds: t0.elapsed().as_secs_f64(),
        })
    }

    fn time(&self) -> f64 {
        self.time
    }

    fn steps(&self) -> u64 {
        self.steps
    }

    fn energy(&self) -> Energy {
        Energy {
            kinetic: 0.0,
            potential: 0.0,
            external_work: 0.0,
        }
    }

    fn max_penetration(&self) -> f64 {
        0.0
    }

    fn frame(&self) -> FrameData<'_> {
        FrameData::Mesh(MeshRef {
            positions: &self.positions,
            triangles: &self.triangles,
            segments: &self.segments,
        })
    }

    fn stages(&self) -> Vec<Stage> {
        let j = self.skeleton.len();
        let mut s = vec![Stage::built("forward kinematics", format!("{j} joints"))];
        match &self.show {
            Show::Clip { clip, .. } => {
                s.push(Stage::built(
                    "clip sampling",
                    format!("{} frames, lerp and NLERP between them", clip.frames()),
                ));
                s.push(Stage::left_out("skinning", "a clip alone has no mesh"));
                s.push(Stage::left_out("inverse kinematics", "no targets"));
            }
            Show::Walk { poses, .. } => {
                s.push(Stage::built(
                    "motion graph",
                    format!("a random walk of {} frames", poses.len()),
                ));
                s.push(Stage::left_out("skinning", "a skeleton alone has no mesh"));
                s.push(Stage::left_out("inverse kinematics", "no targets"));
            }
            Show::Twist { skin, .. } => {
                s.push(Stage::built(
                    "skinning",
                    format!("{} vertices, LBS and DQS", skin.len()),
                ));
                s.push(Stage::left_out("inverse kinematics", "no targets"));
            }
            Show::Reach { solvers, .. } => {
                s.push(Stage::built(
                    "inverse kinematics",
                    solvers
                        .iter()
                        .map(|x| x.0.method.name())
                        .collect::<Vec<_>>()
                        .join(", "),
                ));
                s.push(Stage::left_out("skinning", "bare arms"));
            }
        }
        s.push(Stage::left_out(
            "collision structures",
            "an animation collides with nothing",
        ));
        s
    }

    fn scenery(&self, _around: ([f64; 3], [f64; 3])) -> Vec<Mesh> {
        let Show::Reach { solvers, radius } = &self.show else {
            return Vec::new();
        };
        // The targets' paths, a polyline circle per arm.
        let mut points = Vec::new();
        let mut segments = Vec::new();
        const SIDES: usize = 64;
        for k in 0..solvers.len() {
            let b = points.len() as u32;
            points.extend(
                (0..SIDES).map(|i| Self::target(*radius, 4.0 * i as f64 / SIDES as f64, k)),
            );
            segments.extend((0..SIDES as u32).map(|i| [b + i, b + (i + 1) % SIDES as u32]));
        }
        vec![Mesh {
            positions: crate::soa::Vec3s::from_aos(&points).into_vec(),
            triangles: Vec::new().into(),
            segments: segments.into(),
        }]
    }

    fn method(&self) -> String {
        match &self.show {
            Show::Clip { .. } => "clip playback".into(),
            Show::Walk { .. } => "motion graph random walk".into(),
            Show::Twist { .. } => "skinning (LBS and DQS)".into(),
            Show::Reach { .. } => "inverse kinematics".into(),
        }
    }

    fn linear_solver(&self) -> Option<&'static str> {
        None
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn warnings(&self) -> Vec<String> {
        let Show::Reach { solvers, .. } = &self.show else {
            return self.notes.clone();
        };
        solvers
            .iter()
            .map(|(ik, _, worst)| {
                format!(
                    "reach, {}: farthest from its target after a frame's solve {worst:.4} m",
                    ik.method.name()
                )
            })
            .collect()
    }
}
