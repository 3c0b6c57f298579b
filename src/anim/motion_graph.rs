//! Motion graphs (Kovar, Gleicher and Pighin 2002; Lee et al. 2002): transitions between
//! similar frames of a clip, found by a pose distance, and walks on the graph they make.
//!
//! **Pose distance.** Frame `i`'s window is the joints' model positions over frames
//! `i .. i+k` (a point cloud: velocities count, not just poses). The distance of windows
//! `i` and `j` is `min over (theta, x0, z0) of sum w_p |a_p - T b_p|^2`, `T` a turn about
//! the vertical (y) axis and a shift along the floor, since where and which way the
//! character faces does not matter. The optimal `T` is the 2-D Procrustes fit of the
//! floor coordinates: `theta = atan2(sum w (bx az - bz ax), sum w (bx ax + bz az))` over
//! the weight-centred clouds, then the shift that matches the centroids. Reported as
//! the root mean square distance per point (the file's units).
//!
//! **Transitions** are the pairs `(i, j)` whose distance is a local minimum of the
//! distance matrix and below the threshold, `|i - j|` at least a window apart. Taking
//! one plays frames `i .. i+k` blended into the aligned `j .. j+k` with Kovar's weights
//! `alpha(p) = 2 ((p+1)/k)^3 - 3 ((p+1)/k)^2 + 1` (rotations by weighted NLERP, the root
//! moved by the fitted `T`), then goes on from `j + k`.
//!
//! **Graph.** Nodes are frames; edges the clip's own `f -> f+1` and the transitions
//! `i -> j+k`. It is pruned to its largest strongly connected component (Tarjan), so a
//! walk never reaches a dead end. A random walk picks uniformly among a node's edges
//! (a seeded generator: the same seed, the same walk); path following chooses at each
//! frame by branch and bound over the walks of the next `horizon` frames with up to two
//! transitions: a walk's cost is the sum over its frames of the squared floor distance
//! from the root to the path's point at the arc length travelled.

use super::clip::Clip;
use super::{blend, Pose, Skeleton};
use largestep_kernels::quat;

/// How transitions are found.
#[derive(Clone, Debug, PartialEq)]
pub struct MotionGraphDesc {
    /// Window and blend length (frames, at least 2).
    pub window: usize,
    /// Largest distance of a transition (root mean square per point, the file's units).
    pub threshold: f64,
    /// Weight of each joint's point (empty: all 1).
    pub weights: Vec<f64>,
}

impl Default for MotionGraphDesc {
    fn default() -> MotionGraphDesc {
        MotionGraphDesc {
            window: 10,
            threshold: 5.0,
            weights: Vec::new(),
        }
    }
}

/// A transition from frame `from` into frame `to` of the clip.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transition {
    /// Where the blend starts.
    pub from: usize,
    /// The frame of the clip it blends into (the walk goes on from `to + window`).
    pub to: usize,
    /// The windows' distance.
    pub distance: f64,
    /// The floor transform taking the target frames onto the source: turn `theta` (rad)
    /// about y, then shift `(x0, z0)`.
    pub align: [f64; 3],
}

/// A motion graph over one clip.
#[derive(Clone, Debug)]
pub struct MotionGraph {
    window: usize,
    frames: usize,
    transitions: Vec<Transition>,
    /// Per frame: whether it is in the kept component.
    kept: Vec<bool>,
    /// Per frame: the kept transitions leaving it.
    out: Vec<Vec<usize>>,
    /// The distance matrix (frames - window + 1 squared), row-major.
    distances: Vec<f64>,
}

/// A walk's decision: given the frame, its choices (`None` the clip's next frame, else a
/// transition) and the floor transform so far, the index of the choice taken.
type Chooser<'a> = dyn FnMut(usize, &[Option<usize>], [f64; 3]) -> usize + 'a;

/// A 2-D floor transform `[theta, x0, z0]` applied to a point.
fn floor_apply(t: [f64; 3], p: [f64; 3]) -> [f64; 3] {
    let (s, c) = t[0].sin_cos();
    // A turn by theta about +y takes (x, z) to (x cos + z sin, -x sin + z cos).
    [
        c * p[0] + s * p[2] + t[1],
        p[1],
        -s * p[0] + c * p[2] + t[2],
    ]
}

/// `a` after `b`.
fn floor_compose(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    let o = floor_apply(a, [b[1], 0.0, b[2]]);
    [a[0] + b[0], o[0], o[2]]
}

/// The floor transform of the poses' root: turns the root's rotation and moves its
/// translation (joint 0 must be the root).
fn floor_pose(t: [f64; 3], pose: &mut Pose) {
    let p = floor_apply(t, pose.translation(0));
    let q = quat::mul(quat::exp([0.0, t[0], 0.0]), pose.rotation(0));
    let s = pose.scale(0);
    pose.set(0, p, q, s);
}

impl MotionGraph {
    /// Builds the graph of `clip` (on `skeleton`; joint 0 its root): every window's
    /// point cloud, the distance matrix, the transitions, and the kept component.
    pub fn build(
        skeleton: &Skeleton,
        clip: &Clip,
        desc: &MotionGraphDesc,
    ) -> Result<MotionGraph, String> {
        let k = desc.window;
        let f = clip.frames();
        let j = skeleton.len();
        if k < 2 || k > f {
            return Err(format!(
                "window {k} must be at least 2 and at most the clip's {f} frames"
            ));
        }
        if !(desc.threshold > 0.0 && desc.threshold.is_finite()) {
            return Err(format!(
                "threshold {} must be a finite number > 0",
                desc.threshold
            ));
        }
        if !desc.weights.is_empty()
            && (desc.weights.len() != j
                || desc.weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)))
        {
            return Err(format!(
                "{} weights for {j} joints (each finite and >= 0)",
                desc.weights.len()
            ));
        }
        if skeleton.parent(0).is_some() {
            return Err("joint 0 is not a root".into());
        }
        // Model positions of every frame.
        let mut pose = skeleton.rest().clone();
        let mut model = Vec::new();
        let mut points = Vec::with_capacity(f * j);
        for fr in 0..f {
            clip.sample(fr as f64 * clip.frame_time(), false, &mut pose);
            skeleton.model(&pose, &mut model);
            points.extend(model.iter().map(|m| [m[3], m[7], m[11]]));
        }
        let w: Vec<f64> = if desc.weights.is_empty() {
            vec![1.0; j]
        } else {
            desc.weights.clone()
        };
        let windows = f - k + 1;
        let mut distances = vec![0.0; windows * windows];
        let mut aligns = vec![[0.0; 3]; windows * windows];
        for a in 0..windows {
            for b in 0..windows {
                let (d, t) = window_distance(
                    &points[a * j..(a + k) * j],
                    &points[b * j..(b + k) * j],
                    &w,
                    j,
                );
                distances[a * windows + b] = d;
                aligns[a * windows + b] = t;
            }
        }
        // Local minima below the threshold, a window apart.
        let mut transitions = Vec::new();
        for a in 0..windows {
            for b in 0..windows {
                if a.abs_diff(b) < k || b + k >= f {
                    continue;
                }
                let d = distances[a * windows + b];
                if d > desc.threshold {
                    continue;
                }
                let is_min = (a.saturating_sub(1)..(a + 2).min(windows)).all(|x| {
                    (b.saturating_sub(1)..(b + 2).min(windows))
                        .all(|y| distances[x * windows + y] >= d)
                });
                if is_min {
                    transitions.push(Transition {
                        from: a,
                        to: b,
                        distance: d,
                        align: aligns[a * windows + b],
                    });
                }
            }
        }
        let mut g = MotionGraph {
            window: k,
            frames: f,
            transitions,
            kept: vec![false; f],
            out: vec![Vec::new(); f],
            distances,
        };
        g.prune();
        Ok(g)
    }

    /// Keeps the largest strongly connected component of the frames (Tarjan, iterative).
    fn prune(&mut self) {
        let f = self.frames;
        let k = self.window;
        let succ = |v: usize, ts: &[Transition]| -> Vec<usize> {
            let mut s: Vec<usize> = ts
                .iter()
                .filter(|t| t.from == v)
                .map(|t| t.to + k)
                .collect();
            if v + 1 < f {
                s.push(v + 1);
            }
            s
        };
        let adj: Vec<Vec<usize>> = (0..f).map(|v| succ(v, &self.transitions)).collect();
        let (mut index, mut low, mut on) = (vec![usize::MAX; f], vec![0; f], vec![false; f]);
        let (mut stack, mut next, mut best): (Vec<usize>, usize, Vec<usize>) =
            (Vec::new(), 0, Vec::new());
        for root in 0..f {
            if index[root] != usize::MAX {
                continue;
            }
            // (node, next edge to look at)
            let mut call = vec![(root, 0usize)];
            index[root] = next;
            low[root] = next;
            next += 1;
            stack.push(root);
            on[root] = true;
            while let Some(&mut (v, ref mut e)) = call.last_mut() {
                if *e < adj[v].len() {
                    let u = adj[v][*e];
                    *e += 1;
                    if index[u] == usize::MAX {
                        index[u] = next;
                        low[u] = next;
                        next += 1;
                        stack.push(u);
                        on[u] = true;
                        call.push((u, 0));
                    } else if on[u] {
                        low[v] = low[v].min(index[u]);
                    }
                } else {
                    call.pop();
                    if let Some(&(p, _)) = call.last() {
                        low[p] = low[p].min(low[v]);
                    }
                    if low[v] == index[v] {
                        let mut comp = Vec::new();
                        while let Some(x) = stack.pop() {
                            on[x] = false;
                            comp.push(x);
                            if x == v {
                                break;
                            }
                        }
                        if comp.len() > best.len() {
                            best = comp;
                        }
                    }
                }
            }
        }
        self.kept = vec![false; f];
        for &v in &best {
            self.kept[v] = true;
        }
        self.out = vec![Vec::new(); f];
        for (i, t) in self.transitions.iter().enumerate() {
            if self.kept[t.from] && self.kept[t.to + k] {
                self.out[t.from].push(i);
            }
        }
    }

    /// The transitions found (kept or not).
    pub fn transitions(&self) -> &[Transition] {
        &self.transitions
    }

    /// Whether frame `f` is in the kept component.
    pub fn kept(&self, f: usize) -> bool {
        self.kept[f]
    }

    /// The number of frames kept.
    pub fn kept_count(&self) -> usize {
        self.kept.iter().filter(|&&k| k).count()
    }

    /// The kept transitions leaving frame `f`.
    pub fn leaving(&self, f: usize) -> &[usize] {
        &self.out[f]
    }

    /// The window (frames).
    pub fn window(&self) -> usize {
        self.window
    }

    /// The distance matrix over windows, row-major, and its side.
    pub fn distances(&self) -> (&[f64], usize) {
        (&self.distances, self.frames - self.window + 1)
    }

    /// The choices at kept frame `f`: `None` for the clip's next frame (when kept), and
    /// each kept transition.
    fn choices(&self, f: usize) -> Vec<Option<usize>> {
        let mut c: Vec<Option<usize>> = self.out[f].iter().map(|&t| Some(t)).collect();
        if f + 1 < self.frames && self.kept[f + 1] {
            c.push(None);
        }
        c
    }

    /// The first kept frame.
    pub fn first_kept(&self) -> Option<usize> {
        self.kept.iter().position(|&k| k)
    }

    /// Plays `steps` graph steps from kept frame `start`, deciding at each frame with
    /// `choose` (given the frame and its choices, returns an index into them); writes one
    /// pose per output frame into `out` (a transition writes its blended window).
    fn play(
        &self,
        skeleton: &Skeleton,
        clip: &Clip,
        start: usize,
        frames: usize,
        out: &mut Vec<Pose>,
        choose: &mut Chooser<'_>,
    ) {
        out.clear();
        let dt = clip.frame_time();
        let mut place = [0.0; 3];
        let mut f = start;
        let mut a = skeleton.rest().clone();
        let mut b = skeleton.rest().clone();
        while out.len() < frames {
            let choices = self.choices(f);
            if choices.is_empty() {
                break;
            }
            let pick = choose(f, &choices, place).min(choices.len() - 1);
            match choices[pick] {
                None => {
                    clip.sample(f as f64 * dt, false, &mut a);
                    floor_pose(place, &mut a);
                    out.push(a.clone());
                    f += 1;
                }
                Some(t) => {
                    let t = self.transitions[t];
                    let k = self.window;
                    let to_place = floor_compose(place, t.align);
                    for p in 0..k {
                        clip.sample((t.from + p) as f64 * dt, false, &mut a);
                        clip.sample((t.to + p) as f64 * dt, false, &mut b);
                        floor_pose(place, &mut a);
                        floor_pose(to_place, &mut b);
                        let x = (p + 1) as f64 / k as f64;
                        let alpha = 2.0 * x * x * x - 3.0 * x * x + 1.0;
                        let mut m = a.clone();
                        blend(&mut m, &[(&a, alpha), (&b, 1.0 - alpha)], skeleton.rest());
                        out.push(m);
                    }
                    place = to_place;
                    f = t.to + k;
                }
            }
        }
        out.truncate(frames);
    }

    /// A random walk of `frames` output frames from the first kept frame, choosing
    /// uniformly among each frame's edges with a generator seeded by `seed`.
    pub fn random_walk(
        &self,
        skeleton: &Skeleton,
        clip: &Clip,
        frames: usize,
        seed: u64,
        out: &mut Vec<Pose>,
    ) {
        let Some(start) = self.first_kept() else {
            out.clear();
            return;
        };
        let mut s = seed ^ 0x9e37_79b9_7f4a_7c15;
        let mut choose = |_: usize, c: &[Option<usize>], _: [f64; 3]| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s % c.len() as u64) as usize
        };
        self.play(skeleton, clip, start, frames, out, &mut choose);
    }

    /// A walk of `frames` output frames that follows the floor path `path` (x, z points,
    /// the file's units): at every frame with a choice, the choice that begins the
    /// cheapest walk of `horizon` frames (see the module docs) is taken.
    pub fn follow_path(
        &self,
        skeleton: &Skeleton,
        clip: &Clip,
        path: &[[f64; 2]],
        frames: usize,
        horizon: usize,
        out: &mut Vec<Pose>,
    ) {
        let Some(start) = self.first_kept() else {
            out.clear();
            return;
        };
        let dt = clip.frame_time();
        // Root floor positions of the clip's frames.
        let mut pose = skeleton.rest().clone();
        let roots: Vec<[f64; 3]> = (0..self.frames)
            .map(|f| {
                clip.sample(f as f64 * dt, false, &mut pose);
                pose.translation(0)
            })
            .collect();
        let path_at = |s: f64| -> [f64; 2] {
            let mut left = s;
            for w in path.windows(2) {
                let l = ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt();
                if left <= l && l > 0.0 {
                    let u = left / l;
                    return [
                        w[0][0] + u * (w[1][0] - w[0][0]),
                        w[0][1] + u * (w[1][1] - w[0][1]),
                    ];
                }
                left -= l;
            }
            *path.last().unwrap_or(&[0.0, 0.0])
        };
        let mut travelled = 0.0;
        let mut last: Option<[f64; 3]> = None;
        let ahead = Ahead {
            graph: self,
            roots: &roots,
            path_at: &path_at,
        };
        let mut choose = |f: usize, c: &[Option<usize>], place: [f64; 3]| -> usize {
            // Distance covered so far, from the root's floor positions.
            let here = floor_apply(place, roots[f]);
            if let Some(l) = last {
                travelled += floor_distance(here, l);
            }
            last = Some(here);
            let mut best = (f64::INFINITY, 0);
            for (i, &ch) in c.iter().enumerate() {
                let cost = ahead.option(
                    f,
                    ch,
                    place,
                    travelled,
                    here,
                    horizon,
                    LOOK_AHEAD_TRANSITIONS,
                    best.0,
                );
                if cost < best.0 {
                    best = (cost, i);
                }
            }
            best.1
        };
        self.play(skeleton, clip, start, frames, out, &mut choose);
    }
}

/// How many transitions a path-following look-ahead may take within its horizon.
const LOOK_AHEAD_TRANSITIONS: usize = 2;

/// Floor distance of two points (x, z).
fn floor_distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Path following's branch-and-bound look-ahead: the cost of a walk is the sum over its
/// frames of the squared floor distance from the root to the path's point at the arc
/// length the root has travelled.
struct Ahead<'a> {
    graph: &'a MotionGraph,
    /// The clip's root positions per frame.
    roots: &'a [[f64; 3]],
    path_at: &'a dyn Fn(f64) -> [f64; 2],
}

impl Ahead<'_> {
    /// The least cost of taking `choice` at frame `f` (the root at `prev` after `run`
    /// travelled, the floor transform `place`) and going on for `left` frames in all,
    /// with at most `depth` transitions; branches whose cost reaches `bound` are cut.
    #[allow(clippy::too_many_arguments)]
    fn option(
        &self,
        f: usize,
        choice: Option<usize>,
        place: [f64; 3],
        run: f64,
        prev: [f64; 3],
        left: usize,
        depth: usize,
        bound: f64,
    ) -> f64 {
        let g = self.graph;
        // The frames the choice plays (a transition's blend approximated by its target
        // frames), where the walk goes on, and its floor transform then.
        let (first, count, place, next, depth) = match choice {
            None => (f, 1, place, f + 1, depth),
            Some(t) => {
                if depth == 0 {
                    return f64::INFINITY;
                }
                let t = g.transitions[t];
                let to_place = floor_compose(place, t.align);
                (t.to, g.window, to_place, t.to + g.window, depth - 1)
            }
        };
        let (mut cost, mut run, mut prev) = (0.0, run, prev);
        let n = count.min(left);
        for k in 0..n {
            let q = floor_apply(place, self.roots[first + k]);
            run += floor_distance(q, prev);
            prev = q;
            let goal = (self.path_at)(run);
            cost += (q[0] - goal[0]).powi(2) + (q[2] - goal[1]).powi(2);
            if cost >= bound {
                return f64::INFINITY;
            }
        }
        if left == n {
            return cost;
        }
        let mut best = bound - cost;
        for ch in g.choices(next) {
            let c = self.option(next, ch, place, run, prev, left - n, depth, best);
            best = best.min(c);
        }
        if best.is_finite() && best < bound - cost {
            cost + best
        } else {
            f64::INFINITY
        }
    }
}

/// The aligned distance of two windows (points `j` per frame) and the floor transform
/// taking `b` onto `a` (see the module docs).
fn window_distance(a: &[[f64; 3]], b: &[[f64; 3]], w: &[f64], j: usize) -> (f64, [f64; 3]) {
    let (mut sw, mut ca, mut cb) = (0.0, [0.0; 2], [0.0; 2]);
    for (i, (pa, pb)) in a.iter().zip(b).enumerate() {
        let wi = w[i % j];
        sw += wi;
        ca[0] += wi * pa[0];
        ca[1] += wi * pa[2];
        cb[0] += wi * pb[0];
        cb[1] += wi * pb[2];
    }
    if sw <= 0.0 {
        return (0.0, [0.0; 3]);
    }
    let (ca, cb) = (ca.map(|v| v / sw), cb.map(|v| v / sw));
    // 2-D Procrustes on (x, z): the turn phi (counter-clockwise in the (x, z) plane)
    // taking centred b onto centred a.
    let (mut sxx, mut sxz) = (0.0, 0.0);
    for (i, (pa, pb)) in a.iter().zip(b).enumerate() {
        let wi = w[i % j];
        let (ax, az) = (pa[0] - ca[0], pa[2] - ca[1]);
        let (bx, bz) = (pb[0] - cb[0], pb[2] - cb[1]);
        sxx += wi * (bx * ax + bz * az);
        sxz += wi * (bx * az - bz * ax);
    }
    let phi = sxz.atan2(sxx);
    // In floor_apply's convention, a turn by theta about +y is phi = -theta.
    let theta = -phi;
    let rb = floor_apply([theta, 0.0, 0.0], [cb[0], 0.0, cb[1]]);
    let t = [theta, ca[0] - rb[0], ca[1] - rb[2]];
    let mut d = 0.0;
    for (i, (pa, pb)) in a.iter().zip(b).enumerate() {
        let q = floor_apply(t, *pb);
        d += w[i % j] * ((pa[0] - q[0]).powi(2) + (pa[1] - q[1]).powi(2) + (pa[2] - q[2]).powi(2));
    }
    ((d / sw).sqrt(), t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aligned_distance_ignores_floor_turns_and_shifts() {
        let a: Vec<[f64; 3]> = (0..30)
            .map(|i| {
                [
                    (i as f64 * 0.7).sin(),
                    i as f64 * 0.1,
                    (i as f64 * 1.3).cos() * 2.0,
                ]
            })
            .collect();
        let t = [0.8, 3.0, -2.0];
        let b: Vec<[f64; 3]> = a.iter().map(|p| floor_apply(t, *p)).collect();
        let (d, fit) = window_distance(&b, &a, &[1.0; 3], 3);
        assert!(d < 1e-12, "{d}");
        for c in 0..3 {
            assert!((fit[c] - t[c]).abs() < 1e-12, "{fit:?}");
        }
        // Composition: applying a then b is applying their composition.
        let (u, v) = ([0.3, 1.0, 2.0], [-1.1, 0.5, -0.2]);
        let p = [0.7, 1.0, -0.4];
        let once = floor_apply(floor_compose(u, v), p);
        let twice = floor_apply(u, floor_apply(v, p));
        assert!((0..3).all(|c| (once[c] - twice[c]).abs() < 1e-14));
    }
}
