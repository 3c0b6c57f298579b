//! Six-degree-of-freedom haptic rendering of a rigid tool against a distance field, after
//! Barbič and James 2008: the tool is a **point shell** (points on its surface, in its
//! own frame), the environment a signed-distance grid; every shell point below the
//! surface (`phi < 0`) is pushed out by a penalty spring `-k_c phi grad(phi)`.
//!
//! The tool is coupled to the device pose by a six-DoF virtual coupling (a translational
//! spring `k_t` and a rotational one `k_r`). Each tick solves for the tool pose where the
//! coupling and the contact springs balance (quasi-static virtual coupling): Gauss-Newton
//! on `1/2 k_t |x - x_d|^2 + 1/2 k_r |theta|^2 + sum 1/2 k_c phi_i^2` over the pose, a
//! 6 x 6 solve per iteration, from the last tick's pose. The user feels the coupling: the
//! force `k_t (x - x_d)` and torque `k_r theta` (theta: the rotation from the device's
//! orientation to the tool's).

use super::{DevicePath, TICK};
use crate::collide::SdfGrid;
use crate::io::Mesh;
use crate::kernels::collide::bv::{Aabb, Sphere};
use crate::kernels::interp::{sample3, sample3_grad};
use crate::kernels::quat::{
    conj, exp as quat_exp, log as quat_log, mul as quat_mul, rotate, Quat, IDENTITY,
};
use crate::kernels::v3::{add, cross, dot, length_and_unit, scale, sub};
use nalgebra::{Matrix6, Vector6};
use std::sync::Arc;

/// Gauss-Newton iterations per tick at most.
const ITERATIONS: usize = 8;

/// What one tick of [`SixDof::tick`] gives the user.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wrench {
    /// Force (N).
    pub force: [f64; 3],
    /// Torque (N m).
    pub torque: [f64; 3],
    /// Shell points in contact at the solved pose.
    pub contacts: usize,
}

/// A rigid point-shell tool against a distance field (see the module docs).
#[derive(Clone, Debug)]
pub struct SixDof {
    /// Shell points, ordered by cluster.
    shell: Vec<[f64; 3]>,
    /// Clusters of neighbouring shell points.
    clusters: Vec<Cluster>,
    /// The farthest shell point from the tool's origin (m).
    reach: f64,
    env: Arc<SdfGrid>,
    position: [f64; 3],
    orientation: Quat,
    /// Translational coupling stiffness (N/m).
    pub k_translation: f64,
    /// Rotational coupling stiffness (N m/rad).
    pub k_rotation: f64,
    /// Contact stiffness per shell point (N/m).
    pub k_contact: f64,
}

impl SixDof {
    /// A tool of shell points `shell` (m, in the tool's frame) against `env`, with the
    /// coupling and contact stiffnesses (each > 0), at the identity pose at the origin.
    pub fn new(
        shell: Vec<[f64; 3]>,
        env: Arc<SdfGrid>,
        k_translation: f64,
        k_rotation: f64,
        k_contact: f64,
    ) -> Result<SixDof, String> {
        if shell.is_empty() {
            return Err("the point shell has no points".into());
        }
        if let Some((i, p)) = shell
            .iter()
            .enumerate()
            .find(|(_, p)| !p.iter().all(|c| c.is_finite()))
        {
            return Err(format!("shell point {i} = {p:?} is not finite"));
        }
        for (name, k) in [
            ("k_translation", k_translation),
            ("k_rotation", k_rotation),
            ("k_contact", k_contact),
        ] {
            if k.is_nan() || k <= 0.0 || k.is_infinite() {
                return Err(format!("{name} = {k}: must be finite and > 0"));
            }
        }
        let (shell, clusters) = clustered(shell);
        let reach = shell.iter().map(|p| dot(*p, *p).sqrt()).fold(0.0, f64::max);
        Ok(SixDof {
            shell,
            clusters,
            reach,
            env,
            position: [0.0; 3],
            orientation: IDENTITY,
            k_translation,
            k_rotation,
            k_contact,
        })
    }

    /// Places the tool at a pose.
    pub fn reset(&mut self, position: [f64; 3], orientation: Quat) {
        self.position = position;
        self.orientation = orientation;
    }

    /// The point shell (m, in the tool's frame).
    pub fn shell(&self) -> &[[f64; 3]] {
        &self.shell
    }

    /// The environment's distance field.
    pub fn field(&self) -> &SdfGrid {
        &self.env
    }

    /// The tool's pose.
    pub fn pose(&self) -> ([f64; 3], Quat) {
        (self.position, self.orientation)
    }

    /// The deepest penetration of a shell point at the current pose (m, >= 0).
    pub fn penetration(&self) -> f64 {
        self.shell
            .iter()
            .filter_map(|s| {
                let p = add(self.position, rotate(self.orientation, *s));
                self.env
                    .grid
                    .contains(p)
                    .then(|| sample3(&self.env.phi, self.env.grid, p))
            })
            .fold(0.0, |m: f64, phi| m.max(-phi))
    }

    /// One tick with the device at `position` and `orientation`: solves the tool's pose
    /// and returns the coupling wrench on the user. A non-finite device pose changes
    /// nothing and gives no wrench.
    pub fn tick(&mut self, position: [f64; 3], orientation: Quat) -> Wrench {
        if !position.iter().chain(&orientation).all(|c| c.is_finite()) {
            return Wrench {
                force: [0.0; 3],
                torque: [0.0; 3],
                contacts: 0,
            };
        }
        let mut contacts = 0;
        // Two cells: the trilinear field's slack in the cluster test below, and the
        // scale of the convergence test.
        let slack = 2.0
            * self
                .env
                .grid
                .spacing
                .iter()
                .fold(0.0, |m: f64, h| m.max(*h));
        for _ in 0..ITERATIONS {
            let mut h = Matrix6::<f64>::zeros();
            let mut g = Vector6::<f64>::zeros();
            for a in 0..3 {
                h[(a, a)] += self.k_translation;
                h[(a + 3, a + 3)] += self.k_rotation;
                g[a] += self.k_translation * (self.position[a] - position[a]);
            }
            let theta = quat_log(quat_mul(self.orientation, conj(orientation)));
            for a in 0..3 {
                g[a + 3] += self.k_rotation * theta[a];
            }
            contacts = 0;
            // A cluster whose centre is farther from the surface than its radius (plus
            // the slack) holds no point in contact: the one-level point-shell hierarchy
            // of Barbič and James.
            for &(start, end, centre, radius) in &self.clusters {
                let c = add(self.position, rotate(self.orientation, centre));
                if self.env.grid.contains(c)
                    && sample3(&self.env.phi, self.env.grid, c) > radius + slack
                {
                    continue;
                }
                for s in &self.shell[start..end] {
                    let r = rotate(self.orientation, *s);
                    let p = add(self.position, r);
                    if !self.env.grid.contains(p) || sample3(&self.env.phi, self.env.grid, p) >= 0.0
                    {
                        continue;
                    }
                    let (phi, grad) = sample3_grad(&self.env.phi, self.env.grid, p);
                    let Some((_, n)) = length_and_unit(grad) else {
                        continue;
                    };
                    contacts += 1;
                    let rn = cross(r, n);
                    let j = Vector6::new(n[0], n[1], n[2], rn[0], rn[1], rn[2]);
                    h += self.k_contact * j * j.transpose();
                    g += self.k_contact * phi * j;
                }
            }
            let Some(ch) = h.cholesky() else { break };
            let d = ch.solve(&(-g));
            self.position = add(self.position, [d[0], d[1], d[2]]);
            let q = quat_mul(quat_exp([d[3], d[4], d[5]]), self.orientation);
            let l = dot([q[1], q[2], q[3]], [q[1], q[2], q[3]]) + q[0] * q[0];
            self.orientation = q.map(|c| c / l.sqrt());
            // Converged when the step moves the shell by a millionth of a cell.
            let moved = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
                + self.reach * (d[3] * d[3] + d[4] * d[4] + d[5] * d[5]).sqrt();
            if moved < 1e-6 * slack {
                break;
            }
        }
        let theta = quat_log(quat_mul(self.orientation, conj(orientation)));
        Wrench {
            force: [0, 1, 2].map(|a| self.k_translation * (self.position[a] - position[a])),
            torque: scale(theta, self.k_rotation),
            contacts,
        }
    }
}

/// A cluster of shell points: `(start, end, centre, radius)` in the tool's frame, the
/// points `shell[start..end]` within `radius` of `centre`.
type Cluster = (usize, usize, [f64; 3], f64);

/// Shell points per cluster at most.
const CLUSTER: usize = 32;

/// The shell reordered into clusters of at most [`CLUSTER`] neighbouring points (halved
/// at the median along their longest extent until small enough), with each cluster's
/// bounding sphere ([`Sphere::of_points`]).
fn clustered(mut shell: Vec<[f64; 3]>) -> (Vec<[f64; 3]>, Vec<Cluster>) {
    let mut clusters = Vec::new();
    let mut todo = vec![(0, shell.len())];
    while let Some((start, end)) = todo.pop() {
        let part = &mut shell[start..end];
        if part.len() <= CLUSTER {
            let ball = Sphere::of_points(part).expect("a cluster has points");
            clusters.push((start, end, ball.center, ball.radius));
            continue;
        }
        let b = Aabb::of_points(part.iter().copied());
        let axis = (0..3)
            .max_by(|&a, &c| (b.max[a] - b.min[a]).total_cmp(&(b.max[c] - b.min[c])))
            .unwrap_or(0);
        let mid = part.len() / 2;
        part.select_nth_unstable_by(mid, |p, q| p[axis].total_cmp(&q[axis]));
        todo.push((start + mid, end));
        todo.push((start, start + mid));
    }
    clusters.sort_by_key(|c| c.0);
    (shell, clusters)
}

/// One tick of a six-DoF replay.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToolTick {
    /// Time (s).
    pub time: f64,
    /// Device position (m).
    pub device: [f64; 3],
    /// Device orientation.
    pub device_orientation: Quat,
    /// The tool's solved position (m).
    pub position: [f64; 3],
    /// The tool's solved orientation.
    pub orientation: Quat,
    /// The wrench on the user.
    pub wrench: Wrench,
    /// The deepest shell point's penetration at the solved pose (m, >= 0; measured
    /// after the tick, outside its work time).
    pub penetration: f64,
    /// Wall time of the tick's work (s).
    pub work: f64,
}

/// Replays `path` (positions and orientations) through the tool at one tick per
/// [`TICK`], from the path's first pose: every tick's poses, wrench and work time.
pub fn replay_tool(tool: &mut SixDof, path: &DevicePath) -> Vec<ToolTick> {
    tool.reset(path.at(0.0), path.orientation_at(0.0));
    let n = (path.duration() / TICK).floor() as usize + 1;
    let mut ticks = Vec::with_capacity(n);
    for i in 0..n {
        let time = i as f64 * TICK;
        let (device, device_orientation) = (path.at(time), path.orientation_at(time));
        let t0 = std::time::Instant::now();
        let wrench = tool.tick(device, device_orientation);
        let work = t0.elapsed().as_secs_f64();
        let (position, orientation) = tool.pose();
        ticks.push(ToolTick {
            time,
            device,
            device_orientation,
            position,
            orientation,
            wrench,
            penetration: tool.penetration(),
            work,
        });
    }
    ticks
}

/// The six-DoF trace as CSV: `time_s`, the device pose (`device_x..z`,
/// `device_qw..qz`), the tool pose (`tool_x..z`, `tool_qw..qz`), `force_x..z` (N),
/// `torque_x..z` (N m), `contacts`, `penetration` (m) and `work_us`.
pub fn tool_trace_csv(ticks: &[ToolTick]) -> String {
    let mut s = String::from(
        "time_s,device_x,device_y,device_z,device_qw,device_qx,device_qy,device_qz,tool_x,tool_y,tool_z,tool_qw,tool_qx,tool_qy,tool_qz,force_x,force_y,force_z,torque_x,torque_y,torque_z,contacts,penetration,work_us\n",
    );
    for t in ticks {
        let mut row = vec![t.time];
        row.extend(t.device);
        row.extend(t.device_orientation);
        row.extend(t.position);
        row.extend(t.orientation);
        row.extend(t.wrench.force);
        row.extend(t.wrench.torque);
        // Debug formatting: shortest round-trip digits, exponents for tiny values.
        let cells: Vec<String> = row.iter().map(|v| format!("{v:?}")).collect();
        s += &format!(
            "{},{},{},{:.3}\n",
            cells.join(","),
            t.wrench.contacts,
            t.penetration,
            t.work * 1e6
        );
    }
    s
}

/// A point shell for a tool's surface: its vertices, points along each edge and points
/// inside each triangle on a lattice no coarser than `spacing` (m), a point shared by
/// triangles once. Barbič and James 2008 sample the tool's surface finer than the
/// distance field's cells, so that no feature of the environment slips between shell
/// points. At most `max_points`, counted before allocating.
pub fn point_shell(
    surface: &Mesh,
    spacing: f64,
    max_points: usize,
) -> Result<Vec<[f64; 3]>, String> {
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(format!("shell spacing {spacing}: must be finite and > 0"));
    }
    let m = surface.as_ref();
    let nv = surface.positions.len() / 3;
    if let Some(i) = (0..nv).find(|&i| !m.vertex(i).iter().all(|c| c.is_finite())) {
        return Err(format!("tool vertex {i} = {:?} is not finite", m.vertex(i)));
    }
    if let Some((t, tri)) = m
        .triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&v| v as usize >= nv))
    {
        return Err(format!(
            "tool triangle {t} = {tri:?} names a vertex beyond the {nv} there are"
        ));
    }
    // Divisions of a segment of length l: pieces no longer than the spacing.
    let pieces = |l: f64| (l / spacing).ceil().max(1.0);
    let len = |a: u32, b: u32| {
        let d = sub(m.vertex(a as usize), m.vertex(b as usize));
        dot(d, d).sqrt()
    };
    let mut edges: Vec<[u32; 2]> = m
        .triangles
        .iter()
        .flat_map(|t| [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]])
        .map(|[a, b]| [a.min(b), a.max(b)])
        .collect();
    edges.sort_unstable();
    edges.dedup();
    let tri_pieces =
        |t: &[u32; 3]| pieces(len(t[0], t[1]).max(len(t[1], t[2])).max(len(t[2], t[0])));
    let count = nv as f64
        + edges
            .iter()
            .map(|e| pieces(len(e[0], e[1])) - 1.0)
            .sum::<f64>()
        + m.triangles
            .iter()
            .map(|t| {
                let n = tri_pieces(t);
                (n - 1.0) * (n - 2.0) / 2.0
            })
            .sum::<f64>();
    if count > max_points as f64 {
        return Err(format!(
            "a point shell of spacing {spacing} m on the tool has {count:.0} points, more than the limit of {max_points}"
        ));
    }
    let mut shell = Vec::with_capacity(count as usize);
    shell.extend((0..nv).map(|i| m.vertex(i)));
    for e in &edges {
        let n = pieces(len(e[0], e[1]));
        let (a, b) = (m.vertex(e[0] as usize), m.vertex(e[1] as usize));
        for i in 1..n as usize {
            let s = i as f64 / n;
            shell.push([0, 1, 2].map(|k| a[k] + s * (b[k] - a[k])));
        }
    }
    for t in m.triangles {
        let n = tri_pieces(t);
        let [a, b, c] = t.map(|v| m.vertex(v as usize));
        let n_i = n as usize;
        for i in 1..n_i {
            for j in 1..n_i - i {
                let (u, v) = (i as f64 / n, j as f64 / n);
                let w = 1.0 - u - v;
                shell.push([0, 1, 2].map(|k| w * a[k] + u * b[k] + v * c[k]));
            }
        }
    }
    Ok(shell)
}
