//! Haptic rendering (course notes, section 15): a point probe against a closed triangle
//! mesh by the god-object method (Zilles and Salisbury 1995), with a virtual-coupling
//! spring, run in a fixed 1 ms loop replaying a device path.
//!
//! The **god object** (the proxy) is where the probe would be if it could not enter the
//! surface. Each tick it moves from where it was towards the device position; the first
//! triangle the path meets (a ray cast in the mesh's BVH) stops it just outside and
//! becomes a constraint plane, the goal becomes the device position projected onto the
//! active planes (up to three: a face, an edge, a vertex), and it moves again, until it
//! reaches the goal or three planes hold it. The force on the user is the coupling spring
//! `k (proxy - device)`: zero in free space, growing with how deep the device is pushed.
//!
//! The loop ([`replay`]) runs one tick per millisecond of the device path, as fast as it
//! can, and records each tick's force and the wall time its work took; the percentiles of
//! that time are the loop's latency. A path is a CSV file of timestamped positions
//! ([`DevicePath::parse`]), or the scripted stroke of [`DevicePath::stroke`]: replays are
//! deterministic (the forces do not depend on timing).
//!
//! [`SixDof`] renders a rigid tool (a point shell) against a distance field with a
//! six-DoF virtual coupling (Barbič and James 2008), `src/haptics/six_dof.rs`.

mod six_dof;

pub use six_dof::{point_shell, replay_tool, tool_trace_csv, SixDof, ToolTick, Wrench};

use crate::collide::check_closed;
use crate::io::{Mesh, ReadError};
use crate::kernels::collide::bv::Aabb;
use crate::kernels::collide::bvh::Bvh;
use crate::kernels::collide::prox::{norm2, ray_triangle, triangle_normal};
use crate::kernels::quat::{conj, exp, log, mul, normalize, Quat, IDENTITY};
use crate::kernels::v3::{add, dot, scale, sub};
use crate::validate::ModelError;

/// The tick of the haptic loop (s): 1 kHz.
pub const TICK: f64 = 1e-3;

/// Poses of the device over time: positions linearly interpolated, orientations by
/// spherical linear interpolation (identity for a path of positions only).
#[derive(Clone, Debug, PartialEq)]
pub struct DevicePath {
    /// Times (s), strictly increasing, the first at least 0.
    pub times: Vec<f64>,
    /// Positions (m).
    pub positions: Vec<[f64; 3]>,
    /// Unit orientations `[w, x, y, z]`, one per time.
    pub orientations: Vec<Quat>,
}

/// The CSV headers of a path of positions and of one of poses.
const POSITION_HEADER: [&str; 4] = ["t", "x", "y", "z"];
const POSE_HEADER: [&str; 8] = ["t", "x", "y", "z", "qw", "qx", "qy", "qz"];

impl DevicePath {
    /// Parses a CSV of `t,x,y,z` rows (seconds, metres) or of `t,x,y,z,qw,qx,qy,qz` rows
    /// (a pose: the orientation as a quaternion, normalised on reading unless it is a
    /// unit one to rounding), every row of
    /// the same width, an optional header line first, `#` comments and blank lines
    /// skipped. Errors name the file and line.
    pub fn parse(text: &str, path: &str) -> Result<DevicePath, ReadError> {
        let err = |line: usize, message: String| ReadError {
            path: path.to_string(),
            line,
            message,
        };
        let mut out = DevicePath {
            times: Vec::new(),
            positions: Vec::new(),
            orientations: Vec::new(),
        };
        // The row width, fixed by the header or the first row.
        let mut width: Option<usize> = None;
        for (k, raw) in text.lines().enumerate() {
            let line = k + 1;
            let s = raw.split('#').next().unwrap_or("").trim();
            if s.is_empty() {
                continue;
            }
            let fields: Vec<&str> = s.split(',').map(str::trim).collect();
            if out.times.is_empty()
                && width.is_none()
                && fields.first().is_some_and(|f| f.parse::<f64>().is_err())
            {
                if fields != POSITION_HEADER && fields != POSE_HEADER {
                    return Err(err(
                        line,
                        format!(
                            "expected the header `t,x,y,z` or `t,x,y,z,qw,qx,qy,qz`, or a row of numbers, found `{s}`"
                        ),
                    ));
                }
                width = Some(fields.len());
                continue;
            }
            let names: &[&str] = match width.unwrap_or(fields.len()) {
                4 => &POSITION_HEADER,
                8 => &POSE_HEADER,
                n => {
                    return Err(err(
                        line,
                        format!("expected 4 fields (t, x, y, z) or 8 (t, x, y, z, qw, qx, qy, qz), found {n}"),
                    ))
                }
            };
            if fields.len() != names.len() {
                return Err(err(
                    line,
                    format!(
                        "expected {} fields ({}) as in the rows above, found {}",
                        names.len(),
                        names.join(", "),
                        fields.len()
                    ),
                ));
            }
            width = Some(names.len());
            let mut v = [0.0; 8];
            for (i, f) in fields.iter().enumerate() {
                v[i] = f
                    .parse::<f64>()
                    .map_err(|_| err(line, format!("`{f}` is not a number")))?;
                if !v[i].is_finite() {
                    return Err(err(line, format!("{} = {f}: must be finite", names[i])));
                }
            }
            if let Some(&last) = out.times.last() {
                if v[0] <= last {
                    return Err(err(
                        line,
                        format!(
                            "t = {}: times must increase (the row before has {last})",
                            v[0]
                        ),
                    ));
                }
            } else if v[0] < 0.0 {
                return Err(err(line, format!("t = {}: must be >= 0", v[0])));
            }
            let q = if names.len() == 8 {
                let q = [v[4], v[5], v[6], v[7]];
                // Unit to rounding: kept as written, so that a written path reads back
                // to the same bits.
                let unit = (q.iter().map(|c| c * c).sum::<f64>() - 1.0).abs() <= 1e-12;
                (if unit { Some(q) } else { normalize(q) }).ok_or_else(|| {
                    err(
                        line,
                        "the orientation (qw, qx, qy, qz) is zero: it must be a rotation".into(),
                    )
                })?
            } else {
                IDENTITY
            };
            out.times.push(v[0]);
            out.positions.push([v[1], v[2], v[3]]);
            out.orientations.push(q);
        }
        if out.times.is_empty() {
            return Err(err(1, "the path has no positions".into()));
        }
        Ok(out)
    }

    /// Reads a path file (see [`DevicePath::parse`]) of at most `max_bytes` bytes.
    pub fn read(path: &std::path::Path, max_bytes: u64) -> Result<DevicePath, ReadError> {
        let text = crate::io::read_text(path, max_bytes)?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Whether some orientation is not the identity.
    pub fn turns(&self) -> bool {
        self.orientations.iter().any(|q| *q != IDENTITY)
    }

    /// The CSV text of the path, one row per sample: `t,x,y,z`, or
    /// `t,x,y,z,qw,qx,qy,qz` when it [`turns`](Self::turns).
    pub fn to_csv(&self) -> String {
        let turns = self.turns();
        let header = if turns {
            &POSE_HEADER[..]
        } else {
            &POSITION_HEADER[..]
        };
        let mut s = header.join(",") + "\n";
        for ((t, p), q) in self
            .times
            .iter()
            .zip(&self.positions)
            .zip(&self.orientations)
        {
            s += &format!("{t},{},{},{}", p[0], p[1], p[2]);
            if turns {
                s += &format!(",{:?},{:?},{:?},{:?}", q[0], q[1], q[2], q[3]);
            }
            s += "\n";
        }
        s
    }

    /// The samples around time `t`, clamped to the path's ends: `(k0, k1, s)` with the
    /// pose at `t` between samples `k0` and `k1` at fraction `s`.
    fn bracket(&self, t: f64) -> (usize, usize, f64) {
        let k = self.times.partition_point(|&s| s <= t);
        if k == 0 {
            return (0, 0, 0.0);
        }
        if k == self.times.len() {
            return (k - 1, k - 1, 0.0);
        }
        let (t0, t1) = (self.times[k - 1], self.times[k]);
        (k - 1, k, (t - t0) / (t1 - t0))
    }

    /// The position at time `t` (s), clamped to the path's ends.
    pub fn at(&self, t: f64) -> [f64; 3] {
        let (k0, k1, s) = self.bracket(t);
        let (a, b) = (self.positions[k0], self.positions[k1]);
        [0, 1, 2].map(|i| a[i] + s * (b[i] - a[i]))
    }

    /// The orientation at time `t` (s), clamped to the path's ends: the shorter arc
    /// between the samples at constant angular speed (`q0 exp(s log(q0* q1))`).
    pub fn orientation_at(&self, t: f64) -> Quat {
        let (k0, k1, s) = self.bracket(t);
        let (a, b) = (self.orientations[k0], self.orientations[k1]);
        let step = scale(log(mul(conj(a), b)), s);
        mul(a, exp(step))
    }

    /// The path's duration (s): its last time.
    pub fn duration(&self) -> f64 {
        *self.times.last().expect("a path has a position")
    }

    /// A scripted stroke over a body of bounds `b`, 3 s: from above the point `(x, z)` =
    /// `over` (+y up), down by `depth` (m) below the top of the bounds over 1 s, along +x
    /// by 0.4 of the body's width for 1.5 s, and back up in the last 0.5 s. Sampled every
    /// 10 ms.
    pub fn stroke(b: &Aabb, over: [f64; 2], depth: f64) -> DevicePath {
        let w = b.max[0] - b.min[0];
        let above = b.max[1] + 0.1 * (b.max[1] - b.min[1]).max(w);
        let pos = |t: f64| -> [f64; 3] {
            let down = b.max[1] - depth;
            let (x, y) = if t < 1.0 {
                (over[0], above + (down - above) * t)
            } else if t < 2.5 {
                (over[0] + 0.4 * w * ((t - 1.0) / 1.5), down)
            } else {
                (over[0] + 0.4 * w, down + (above - down) * ((t - 2.5) / 0.5))
            };
            [x, y, over[1]]
        };
        let n = 301;
        let times: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
        let positions = times.iter().map(|&t| pos(t)).collect();
        let orientations = vec![IDENTITY; n];
        DevicePath {
            times,
            positions,
            orientations,
        }
    }

    /// Turns the path's orientations by the rotation vector `rotation` (rad) at a
    /// constant rate from time `from` to `to` (s): the identity before, all of it after,
    /// composed before each sample's own orientation. For the scripted tool stroke.
    pub fn tilt(&mut self, rotation: [f64; 3], from: f64, to: f64) {
        for (t, q) in self.times.iter().zip(&mut self.orientations) {
            let s = ((t - from) / (to - from)).clamp(0.0, 1.0);
            *q = mul(exp(scale(rotation, s)), *q);
        }
    }
}

/// A point probe's god object against one closed mesh (see the module docs).
#[derive(Clone, Debug)]
pub struct GodObject {
    positions: Vec<[f64; 3]>,
    triangles: Vec<[u32; 3]>,
    bvh: Bvh,
    stack: Vec<(u32, f64)>,
    proxy: [f64; 3],
    /// Coupling spring stiffness (N/m).
    pub stiffness: f64,
    /// How far outside the surface the proxy stays (m): a millionth of the mesh's size.
    pub skin: f64,
}

/// Barycentric slack of the proxy's ray casts: a ray through a shared edge or vertex
/// hits at least one of its triangles (see `kernels::collide::prox::ray_triangle`).
const RAY_SLACK: f64 = 1e-9;

/// Moves per tick before the proxy stays where it is (each adds a constraint or reaches
/// the goal; three planes fix it).
const MAX_MOVES: usize = 8;

impl GodObject {
    /// The god object of a closed surface (checked: [`check_closed`]), coupling stiffness
    /// `stiffness` (N/m, > 0).
    pub fn new(surface: &Mesh, stiffness: f64) -> Result<GodObject, ModelError> {
        check_closed(surface)?;
        crate::validate::check(
            "haptics",
            0,
            "stiffness",
            stiffness,
            crate::validate::Rule::Positive,
        )?;
        let m = surface.as_ref();
        let positions: Vec<[f64; 3]> = (0..surface.positions.len() / 3)
            .map(|i| m.vertex(i))
            .collect();
        let triangles = surface.triangles.to_vec();
        let boxes: Vec<Aabb> = triangles
            .iter()
            .map(|t| Aabb::of_points(t.map(|v| positions[v as usize])))
            .collect();
        let bounds = Aabb::of_points(positions.iter().copied());
        let size = norm2(sub(bounds.max, bounds.min)).sqrt();
        Ok(GodObject {
            positions,
            triangles,
            bvh: Bvh::from_boxes(&boxes),
            stack: Vec::new(),
            proxy: [f64::NAN; 3],
            stiffness,
            skin: 1e-6 * size,
        })
    }

    /// The mesh's bounds.
    pub fn bounds(&self) -> Aabb {
        self.bvh.bounds()
    }

    /// The mesh's highest vertex (largest y): where a stroke from above meets it first.
    pub fn top(&self) -> [f64; 3] {
        self.positions
            .iter()
            .copied()
            .fold([0.0, f64::NEG_INFINITY, 0.0], |a, p| {
                if p[1] > a[1] {
                    p
                } else {
                    a
                }
            })
    }

    /// The proxy's position.
    pub fn proxy(&self) -> [f64; 3] {
        self.proxy
    }

    /// Whether `p` is inside the closed surface: the parity of the crossings of a ray
    /// from `p` (a fixed, irrational direction, so that it meets no edge of a regular
    /// mesh), counted over every triangle.
    pub fn inside(&self, p: [f64; 3]) -> bool {
        let dir = [0.577_215_664_9, 0.618_033_988_7, 0.532_088_886_2];
        let tri = |t: &[u32; 3]| t.map(|v| self.positions[v as usize]);
        self.triangles
            .iter()
            .filter(|t| ray_triangle(p, dir, tri(t), f64::INFINITY, 0.0).is_some())
            .count()
            % 2
            == 1
    }

    /// Puts the proxy at the device position `device`, which must be outside the surface.
    pub fn reset(&mut self, device: [f64; 3]) -> Result<(), String> {
        if !device.iter().all(|c| c.is_finite()) {
            return Err(format!("the device position {device:?} is not finite"));
        }
        if self.inside(device) {
            return Err(format!("the device starts at {device:?}, inside the surface: the god object must start outside"));
        }
        self.proxy = device;
        Ok(())
    }

    /// One tick with the device at `device`: moves the proxy and returns the coupling
    /// force on the user (N). A non-finite device position leaves the proxy and gives no
    /// force.
    pub fn tick(&mut self, device: [f64; 3]) -> [f64; 3] {
        if !device.iter().all(|c| c.is_finite()) || !self.proxy.iter().all(|c| c.is_finite()) {
            return [0.0; 3];
        }
        // Active constraint planes: unit normal and offset (n . x >= offset); at most
        // three, kept on the stack (a tick allocates nothing).
        let mut planes = [([0.0; 3], 0.0); 3];
        let mut active = 0;
        let mut goal = device;
        for _ in 0..MAX_MOVES {
            let d = sub(goal, self.proxy);
            let len = norm2(d).sqrt();
            if len <= 0.0 {
                break;
            }
            let dir = scale(d, 1.0 / len);
            let (positions, triangles) = (&self.positions, &self.triangles);
            let hit = self
                .bvh
                .ray(self.proxy, dir, len, &mut self.stack, |id, t_best| {
                    let [a, b, c] = triangles[id as usize].map(|v| positions[v as usize]);
                    // Only faces the proxy approaches from outside stop it.
                    let n = triangle_normal(a, b, c)?;
                    if dot(n, dir) >= 0.0 {
                        return None;
                    }
                    ray_triangle(self.proxy, dir, [a, b, c], t_best, RAY_SLACK).map(|(t, _)| t)
                });
            let Some((id, t)) = hit else {
                self.proxy = goal;
                break;
            };
            let [a, b, c] = self.triangles[id as usize].map(|v| self.positions[v as usize]);
            let n = triangle_normal(a, b, c).expect("checked non-degenerate");
            // Stop `skin` short of the plane.
            let cos = -dot(n, dir);
            let back = self.skin / cos.max(1e-12);
            self.proxy = add(self.proxy, scale(dir, (t - back).max(0.0)));
            let plane = (n, dot(n, a) + self.skin);
            if !planes[..active]
                .iter()
                .any(|p| norm2(sub(p.0, n)) < 1e-24 && (p.1 - plane.1).abs() < self.skin)
            {
                planes[active] = plane;
                active += 1;
            }
            if active >= 3 {
                break;
            }
            goal = project(device, &planes[..active]).unwrap_or(self.proxy);
        }
        scale(sub(self.proxy, device), self.stiffness)
    }
}

/// The point nearest `d` on the intersection of the planes `n . x = offset` (one or two),
/// `None` when they are parallel.
fn project(d: [f64; 3], planes: &[([f64; 3], f64)]) -> Option<[f64; 3]> {
    match planes {
        [] => Some(d),
        [(n, o)] => {
            let s = dot(*n, d) - o;
            // Only a goal below the plane moves onto it.
            Some(if s < 0.0 { sub(d, scale(*n, s)) } else { d })
        }
        [(n1, o1), (n2, o2), ..] => {
            // x = d - l1 n1 - l2 n2 with n_i . x = o_i: a 2x2 Gram system.
            let g11 = dot(*n1, *n1);
            let g12 = dot(*n1, *n2);
            let g22 = dot(*n2, *n2);
            let det = g11 * g22 - g12 * g12;
            if det.abs() < 1e-12 {
                return None;
            }
            let r1 = dot(*n1, d) - o1;
            let r2 = dot(*n2, d) - o2;
            let l1 = (r1 * g22 - r2 * g12) / det;
            let l2 = (r2 * g11 - r1 * g12) / det;
            // A plane pulling the goal towards it (a negative multiplier) is not active.
            if l1 < 0.0 {
                return project(d, &planes[1..2]);
            }
            if l2 < 0.0 {
                return project(d, &planes[..1]);
            }
            Some(sub(sub(d, scale(*n1, l1)), scale(*n2, l2)))
        }
    }
}

/// One tick of a replay.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tick {
    /// Time (s).
    pub time: f64,
    /// Device position (m).
    pub device: [f64; 3],
    /// Proxy position (m).
    pub proxy: [f64; 3],
    /// Force on the user (N).
    pub force: [f64; 3],
    /// Wall time of the tick's work (s).
    pub work: f64,
}

/// Replays `path` through the god object at one tick per [`TICK`], from its start:
/// every tick's positions, force and work time.
pub fn replay(god: &mut GodObject, path: &DevicePath) -> Result<Vec<Tick>, String> {
    god.reset(path.at(0.0))?;
    let n = (path.duration() / TICK).floor() as usize + 1;
    let mut ticks = Vec::with_capacity(n);
    for i in 0..n {
        let time = i as f64 * TICK;
        let device = path.at(time);
        let t0 = std::time::Instant::now();
        let force = god.tick(device);
        let work = t0.elapsed().as_secs_f64();
        ticks.push(Tick {
            time,
            device,
            proxy: god.proxy(),
            force,
            work,
        });
    }
    Ok(ticks)
}

/// The 50th, 90th, 99th percentiles and the largest of the ticks' work times (s).
pub fn latency(ticks: &[Tick]) -> [f64; 4] {
    percentiles(ticks.iter().map(|t| t.work).collect())
}

/// The 50th, 90th, 99th percentiles and the largest of work times (s; zeros for none).
pub fn percentiles(mut w: Vec<f64>) -> [f64; 4] {
    w.sort_by(f64::total_cmp);
    if w.is_empty() {
        return [0.0; 4];
    }
    let q = |p: f64| w[((p * (w.len() - 1) as f64).round() as usize).min(w.len() - 1)];
    [q(0.5), q(0.9), q(0.99), w[w.len() - 1]]
}

/// The force trace as CSV: `time_s,device_x,device_y,device_z,proxy_x,proxy_y,proxy_z,
/// force_x,force_y,force_z,work_us`.
pub fn trace_csv(ticks: &[Tick]) -> String {
    let mut s = String::from("time_s,device_x,device_y,device_z,proxy_x,proxy_y,proxy_z,force_x,force_y,force_z,work_us\n");
    for t in ticks {
        s += &format!(
            "{},{},{},{},{},{},{},{},{},{},{:.3}\n",
            t.time,
            t.device[0],
            t.device[1],
            t.device[2],
            t.proxy[0],
            t.proxy[1],
            t.proxy[2],
            t.force[0],
            t.force[1],
            t.force[2],
            t.work * 1e6
        );
    }
    s
}
