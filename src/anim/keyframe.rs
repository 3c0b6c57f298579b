//! Keyframe channels (course notes section 6): scalar and vector tracks with step,
//! linear, Hermite, Catmull-Rom, Bezier and Kochanek-Bartels (TCB) segments, rotation
//! tracks with step, SLERP and SQUAD, ease in and out, a cursor that makes playback
//! O(1) a sample, baking to a fixed rate, and arc-length reparameterisation of paths.
//!
//! **Segments.** Each key says how the curve leaves it toward the next key. With
//! `u = (t - t0) / (t1 - t0)` and `d = t1 - t0`:
//! - `Hermite`: `h00(u) p0 + h10(u) d m0 + h01(u) p1 + h11(u) d m1`, the tangents `m`
//!   (value per second) from each key's [`Tangent`]: automatic (the non-uniform
//!   Catmull-Rom slope `(p[i+1] - p[i-1]) / (t[i+1] - t[i-1])`, one-sided at the ends),
//!   flat (zero) or the user's (in and out apart);
//! - `CatmullRom`: Hermite with automatic tangents whatever the keys say;
//! - `Bezier`: a cubic Bezier in (time, value) through the keys with the keys' handles
//!   (offsets in time and value, as animation editors draw them; handle times are
//!   clamped into the segment so the curve stays a function of time), the time
//!   inverted by Newton's method with bisection as a safeguard;
//! - `Tcb`: Kochanek and Bartels 1984: the outgoing tangent of key i is
//!   `(1-T)(1+C)(1+B)/2 (p_i - p_{i-1}) + (1-T)(1-C)(1-B)/2 (p_{i+1} - p_i)` and the
//!   incoming one `(1-T)(1-C)(1+B)/2 (...) + (1-T)(1+C)(1-B)/2 (...)`, each scaled by
//!   `2 d_i / (d_{i-1} + d_i)` for uneven key spacing; `T = C = B = 0` is Catmull-Rom.
//!
//! **Ease.** A segment's parameter `u` is first remapped by Steketee and Badler's
//! constant-acceleration ease (the one Kochanek and Bartels use): accelerate over the
//! first `ease_out` of the leaving key, cruise, decelerate over the last `ease_in` of the
//! arriving key (both in [0, 1], scaled down together when their sum exceeds 1).

use largestep_kernels::quat::{self, Quat};
use largestep_kernels::rotation;

/// How the curve runs from a key to the next one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Interpolation {
    /// Hold the key's value until the next key.
    Step,
    /// Straight to the next value.
    Linear,
    /// Cubic Hermite with the keys' tangents.
    Hermite,
    /// Cubic Hermite with automatic tangents.
    CatmullRom,
    /// Cubic Bezier in (time, value) with the keys' handles.
    Bezier,
    /// Kochanek-Bartels spline with the key's tension, continuity and bias (each in
    /// [-1, 1]); the arriving key's own three shape its incoming tangent.
    Tcb,
}

/// A key's tangent for Hermite segments.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Tangent<const N: usize> {
    /// The Catmull-Rom slope from the neighbouring keys.
    Auto,
    /// Zero.
    Flat,
    /// Given: incoming and outgoing slopes (value per second).
    User([f64; N], [f64; N]),
}

/// One key of an N-component track.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Key<const N: usize> {
    /// Time (s).
    pub time: f64,
    /// Value.
    pub value: [f64; N],
    /// The segment to the next key.
    pub interpolation: Interpolation,
    /// Tangent (Hermite).
    pub tangent: Tangent<N>,
    /// Bezier handles: incoming and outgoing, each `(time offset, value offset)` from
    /// the key (the incoming one's time offset <= 0).
    pub handles: ((f64, [f64; N]), (f64, [f64; N])),
    /// Tension, continuity, bias (TCB).
    pub tcb: [f64; 3],
    /// Ease into this key (fraction of the arriving segment) and out of it (of the
    /// leaving one), each in [0, 1].
    pub ease: (f64, f64),
}

impl<const N: usize> Key<N> {
    /// A key with `interpolation` toward the next, automatic tangents, handles at a
    /// third of a second's flat slope, zero TCB and no ease.
    pub fn new(time: f64, value: [f64; N], interpolation: Interpolation) -> Key<N> {
        Key {
            time,
            value,
            interpolation,
            tangent: Tangent::Auto,
            handles: ((0.0, [0.0; N]), (0.0, [0.0; N])),
            tcb: [0.0; 3],
            ease: (0.0, 0.0),
        }
    }
}

/// A key the track refuses: its index and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("key {index}: {message}")]
pub struct KeyError {
    /// The key.
    pub index: usize,
    /// What is wrong.
    pub message: String,
}

/// Where the last sample fell: the segment to try first (playback forward or back one
/// segment at a time costs O(1)).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Cursor {
    segment: usize,
}

/// A checked N-component track.
#[derive(Clone, Debug)]
pub struct Track<const N: usize> {
    keys: Vec<Key<N>>,
    /// Per key: incoming and outgoing tangents (value per second for Hermite; value per
    /// segment for TCB), fixed at build.
    tangents: Vec<([f64; N], [f64; N])>,
}

/// The scalar track.
pub type ScalarTrack = Track<1>;
/// A 3-vector track (positions, scales).
pub type VectorTrack = Track<3>;

fn finite<const N: usize>(v: &[f64; N]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl<const N: usize> Track<N> {
    /// Checks the keys (at least one; times finite and strictly increasing; values,
    /// tangents, handles, TCB and ease finite, TCB within [-1, 1], ease within [0, 1])
    /// and fixes every key's tangents.
    pub fn new(keys: Vec<Key<N>>) -> Result<Track<N>, KeyError> {
        if keys.is_empty() {
            return Err(KeyError {
                index: 0,
                message: "a track needs at least one key".into(),
            });
        }
        for (i, k) in keys.iter().enumerate() {
            let err = |message: String| KeyError { index: i, message };
            if !k.time.is_finite() || !finite(&k.value) {
                return Err(err("time or value is not finite".into()));
            }
            if i > 0 && k.time <= keys[i - 1].time {
                return Err(err(format!(
                    "time {} does not come after the previous key's {}",
                    k.time,
                    keys[i - 1].time
                )));
            }
            if let Tangent::User(a, b) = k.tangent {
                if !finite(&a) || !finite(&b) {
                    return Err(err("tangent is not finite".into()));
                }
            }
            let ((ti, vi), (to, vo)) = k.handles;
            if !(ti.is_finite() && to.is_finite() && finite(&vi) && finite(&vo))
                || ti > 0.0
                || to < 0.0
            {
                return Err(err("handles must be finite, the incoming one before the key and the outgoing one after".into()));
            }
            if k.tcb.iter().any(|x| !(-1.0..=1.0).contains(x)) {
                return Err(err(format!(
                    "tension, continuity and bias {:?} must lie in [-1, 1]",
                    k.tcb
                )));
            }
            if !(0.0..=1.0).contains(&k.ease.0) || !(0.0..=1.0).contains(&k.ease.1) {
                return Err(err(format!("ease {:?} must lie in [0, 1]", k.ease)));
            }
        }
        let n = keys.len();
        let mut tangents = Vec::with_capacity(n);
        for i in 0..n {
            let auto = auto_slope(&keys, i);
            let hermite = match keys[i].tangent {
                Tangent::Auto => (auto, auto),
                Tangent::Flat => ([0.0; N], [0.0; N]),
                Tangent::User(a, b) => (a, b),
            };
            tangents.push(hermite);
        }
        Ok(Track { keys, tangents })
    }

    /// The keys.
    pub fn keys(&self) -> &[Key<N>] {
        &self.keys
    }

    /// The first and last key's times.
    pub fn range(&self) -> (f64, f64) {
        (self.keys[0].time, self.keys[self.keys.len() - 1].time)
    }

    /// The segment holding `t` (clamped to the keys), searched from the cursor.
    fn find(&self, t: f64, cursor: &mut Cursor) -> usize {
        let n = self.keys.len();
        let mut s = cursor.segment.min(n.saturating_sub(2));
        // Walk a few segments from the cursor, then fall back to bisection.
        for _ in 0..4 {
            if s > 0 && t < self.keys[s].time {
                s -= 1;
            } else if s + 2 < n && t >= self.keys[s + 1].time {
                s += 1;
            } else {
                cursor.segment = s;
                return s;
            }
        }
        s = self
            .keys
            .partition_point(|k| k.time <= t)
            .saturating_sub(1)
            .min(n.saturating_sub(2));
        cursor.segment = s;
        s
    }

    /// The value at time `t` (held constant before the first key and after the last);
    /// `cursor` remembers where the search ended. A non-finite `t` gives the first
    /// key's value.
    pub fn sample(&self, t: f64, cursor: &mut Cursor) -> [f64; N] {
        let n = self.keys.len();
        let (t0, t1) = self.range();
        if n == 1 || t.is_nan() || t <= t0 {
            return self.keys[0].value;
        }
        if t >= t1 {
            return self.keys[n - 1].value;
        }
        let i = self.find(t, cursor);
        self.segment(i, t)
    }

    /// The value on segment `i` at time `t` within it.
    fn segment(&self, i: usize, t: f64) -> [f64; N] {
        let (a, b) = (&self.keys[i], &self.keys[i + 1]);
        let d = b.time - a.time;
        let u = ease((t - a.time) / d, a.ease.1, b.ease.0);
        let (p0, p1) = (a.value, b.value);
        match a.interpolation {
            Interpolation::Step => p0,
            Interpolation::Linear => std::array::from_fn(|c| p0[c] + u * (p1[c] - p0[c])),
            Interpolation::Hermite => hermite(
                u,
                p0,
                p1,
                self.tangents[i].1.map(|m| m * d),
                self.tangents[i + 1].0.map(|m| m * d),
            ),
            Interpolation::CatmullRom => {
                let (m0, m1) = (auto_slope(&self.keys, i), auto_slope(&self.keys, i + 1));
                hermite(u, p0, p1, m0.map(|m| m * d), m1.map(|m| m * d))
            }
            Interpolation::Tcb => {
                let (m0, m1) = (tcb_out(&self.keys, i), tcb_in(&self.keys, i + 1));
                hermite(u, p0, p1, m0, m1)
            }
            Interpolation::Bezier => {
                // Control points in (time, value); handle times clamped into the segment.
                let x1 = a.time + a.handles.1 .0.clamp(0.0, d);
                let x2 = b.time + b.handles.0 .0.clamp(-d, 0.0);
                let tt = a.time + u * d;
                let s = bezier_inverse(a.time, x1, x2, b.time, tt);
                std::array::from_fn(|c| {
                    bezier(
                        s,
                        p0[c],
                        p0[c] + a.handles.1 .1[c],
                        p1[c] + b.handles.0 .1[c],
                        p1[c],
                    )
                })
            }
        }
    }

    /// The track sampled at `rate` samples per second from its first key to its last,
    /// both ends included (`ceil(duration * rate) + 1` samples), into `out`.
    pub fn bake(&self, rate: f64, out: &mut Vec<[f64; N]>) {
        out.clear();
        let (t0, t1) = self.range();
        if !(rate > 0.0 && rate.is_finite()) {
            out.push(self.keys[0].value);
            return;
        }
        let count = ((t1 - t0) * rate).ceil() as usize + 1;
        let mut c = Cursor::default();
        out.extend((0..count).map(|k| self.sample((t0 + k as f64 / rate).min(t1), &mut c)));
    }
}

/// The non-uniform Catmull-Rom slope at key `i` (value per second).
fn auto_slope<const N: usize>(keys: &[Key<N>], i: usize) -> [f64; N] {
    let n = keys.len();
    if n < 2 {
        return [0.0; N];
    }
    let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
    let dt = keys[b].time - keys[a].time;
    std::array::from_fn(|c| (keys[b].value[c] - keys[a].value[c]) / dt)
}

/// The two chords around key `i` (zero past the ends) and the segment lengths.
fn chords<const N: usize>(keys: &[Key<N>], i: usize) -> ([f64; N], [f64; N], f64, f64) {
    let n = keys.len();
    let before = if i > 0 {
        std::array::from_fn(|c| keys[i].value[c] - keys[i - 1].value[c])
    } else {
        [0.0; N]
    };
    let after = if i + 1 < n {
        std::array::from_fn(|c| keys[i + 1].value[c] - keys[i].value[c])
    } else {
        [0.0; N]
    };
    let d0 = if i > 0 {
        keys[i].time - keys[i - 1].time
    } else {
        0.0
    };
    let d1 = if i + 1 < n {
        keys[i + 1].time - keys[i].time
    } else {
        0.0
    };
    // At an end, the missing chord repeats the present one (so the end tangent is the
    // chord, as Catmull-Rom's one-sided end).
    let (before, after, d0, d1) = match (i > 0, i + 1 < n) {
        (false, true) => (after, after, d1, d1),
        (true, false) => (before, before, d0, d0),
        _ => (before, after, d0, d1),
    };
    (before, after, d0, d1)
}

/// Key `i`'s outgoing TCB tangent (value per segment of the leaving segment).
fn tcb_out<const N: usize>(keys: &[Key<N>], i: usize) -> [f64; N] {
    let [t, c, b] = keys[i].tcb;
    let (before, after, d0, d1) = chords(keys, i);
    let (wa, wb) = (
        (1.0 - t) * (1.0 + c) * (1.0 + b) / 2.0,
        (1.0 - t) * (1.0 - c) * (1.0 - b) / 2.0,
    );
    let adjust = if d0 + d1 > 0.0 {
        2.0 * d1 / (d0 + d1)
    } else {
        1.0
    };
    std::array::from_fn(|k| adjust * (wa * before[k] + wb * after[k]))
}

/// Key `i`'s incoming TCB tangent (value per segment of the arriving segment).
fn tcb_in<const N: usize>(keys: &[Key<N>], i: usize) -> [f64; N] {
    let [t, c, b] = keys[i].tcb;
    let (before, after, d0, d1) = chords(keys, i);
    let (wa, wb) = (
        (1.0 - t) * (1.0 - c) * (1.0 + b) / 2.0,
        (1.0 - t) * (1.0 + c) * (1.0 - b) / 2.0,
    );
    let adjust = if d0 + d1 > 0.0 {
        2.0 * d0 / (d0 + d1)
    } else {
        1.0
    };
    std::array::from_fn(|k| adjust * (wa * before[k] + wb * after[k]))
}

/// The cubic Hermite curve with end tangents per unit `u`.
fn hermite<const N: usize>(
    u: f64,
    p0: [f64; N],
    p1: [f64; N],
    m0: [f64; N],
    m1: [f64; N],
) -> [f64; N] {
    let (u2, u3) = (u * u, u * u * u);
    let h00 = 2.0 * u3 - 3.0 * u2 + 1.0;
    let h10 = u3 - 2.0 * u2 + u;
    let h01 = -2.0 * u3 + 3.0 * u2;
    let h11 = u3 - u2;
    std::array::from_fn(|c| h00 * p0[c] + h10 * m0[c] + h01 * p1[c] + h11 * m1[c])
}

/// The cubic Bezier polynomial at `s`.
fn bezier(s: f64, a: f64, b: f64, c: f64, d: f64) -> f64 {
    let r = 1.0 - s;
    r * r * r * a + 3.0 * r * r * s * b + 3.0 * r * s * s * c + s * s * s * d
}

/// The parameter where the Bezier time curve `(x0, x1, x2, x3)` (monotone: inner
/// points within the ends) reaches `x`: Newton from the linear guess, bisection when a
/// step leaves the bracket.
fn bezier_inverse(x0: f64, x1: f64, x2: f64, x3: f64, x: f64) -> f64 {
    let (mut lo, mut hi) = (0.0, 1.0);
    let mut s = ((x - x0) / (x3 - x0)).clamp(0.0, 1.0);
    for _ in 0..50 {
        let f = bezier(s, x0, x1, x2, x3) - x;
        if f.abs() <= 1e-13 * (x3 - x0).abs().max(1.0) {
            break;
        }
        if f > 0.0 {
            hi = s;
        } else {
            lo = s;
        }
        let r = 1.0 - s;
        let df = 3.0 * (r * r * (x1 - x0) + 2.0 * r * s * (x2 - x1) + s * s * (x3 - x2));
        let next = if df > 0.0 { s - f / df } else { f64::NAN };
        s = if next > lo && next < hi {
            next
        } else {
            0.5 * (lo + hi)
        };
    }
    s
}

/// Steketee and Badler's constant-acceleration ease of `u` with ease-out fraction `a`
/// (of the leaving key) and ease-in fraction `b` (of the arriving one).
pub fn ease(u: f64, a: f64, b: f64) -> f64 {
    let u = u.clamp(0.0, 1.0);
    if a <= 0.0 && b <= 0.0 {
        return u;
    }
    let s = a + b;
    let (a, b) = if s > 1.0 { (a / s, b / s) } else { (a, b) };
    let k = 1.0 / (2.0 - a - b);
    if u < a {
        k / a * u * u
    } else if u <= 1.0 - b {
        k * (2.0 * u - a)
    } else {
        let v = 1.0 - u;
        1.0 - k / b * v * v
    }
}

/// How a rotation track runs between keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RotationInterpolation {
    /// Hold.
    Step,
    /// SLERP (shortest arc).
    Slerp,
    /// SQUAD through the neighbouring keys (C1 across keys).
    Squad,
}

/// A checked rotation track: unit quaternions at strictly increasing times.
#[derive(Clone, Debug)]
pub struct RotationTrack {
    times: Vec<f64>,
    values: Vec<Quat>,
    controls: Vec<Quat>,
    interpolation: RotationInterpolation,
}

impl RotationTrack {
    /// Checks the keys (times finite and increasing, rotations finite and non-zero:
    /// normalised) and takes each into the hemisphere of the one before (the double
    /// cover), then forms SQUAD's control points.
    pub fn new(
        keys: &[(f64, Quat)],
        interpolation: RotationInterpolation,
    ) -> Result<RotationTrack, KeyError> {
        if keys.is_empty() {
            return Err(KeyError {
                index: 0,
                message: "a track needs at least one key".into(),
            });
        }
        let mut times = Vec::with_capacity(keys.len());
        let mut values: Vec<Quat> = Vec::with_capacity(keys.len());
        for (i, &(t, q)) in keys.iter().enumerate() {
            let err = |message: String| KeyError { index: i, message };
            if !t.is_finite() || (i > 0 && t <= times[i - 1]) {
                return Err(err(format!(
                    "time {t} is not finite or does not come after the previous key's"
                )));
            }
            let q =
                quat::normalize(q).ok_or_else(|| err("rotation is zero or not finite".into()))?;
            let q = match values.last() {
                Some(&p) => rotation::align(p, q),
                None => q,
            };
            times.push(t);
            values.push(q);
        }
        let n = values.len();
        let controls = (0..n)
            .map(|i| {
                rotation::squad_control(
                    values[i.saturating_sub(1)],
                    values[i],
                    values[(i + 1).min(n - 1)],
                )
            })
            .collect();
        Ok(RotationTrack {
            times,
            values,
            controls,
            interpolation,
        })
    }

    /// The rotation at `t` (held before the first key and after the last).
    pub fn sample(&self, t: f64, cursor: &mut Cursor) -> Quat {
        let n = self.times.len();
        if n == 1 || t.is_nan() || t <= self.times[0] {
            return self.values[0];
        }
        if t >= self.times[n - 1] {
            return self.values[n - 1];
        }
        let mut s = cursor.segment.min(n - 2);
        if !(self.times[s] <= t && t < self.times[s + 1]) {
            s = self
                .times
                .partition_point(|&k| k <= t)
                .saturating_sub(1)
                .min(n - 2);
        }
        cursor.segment = s;
        let u = (t - self.times[s]) / (self.times[s + 1] - self.times[s]);
        let (a, b) = (self.values[s], self.values[s + 1]);
        match self.interpolation {
            RotationInterpolation::Step => a,
            RotationInterpolation::Slerp => rotation::slerp(a, b, u),
            RotationInterpolation::Squad => {
                rotation::squad(a, b, self.controls[s], self.controls[s + 1], u)
            }
        }
    }
}

/// Arc-length reparameterisation of a position track: a table of cumulative length
/// against time (the curve split into `samples` equal-time pieces per segment, each
/// measured by 5-point Gauss-Legendre quadrature of the speed from central differences),
/// inverted by bisection and linear interpolation in the table.
#[derive(Clone, Debug)]
pub struct ArcLength {
    times: Vec<f64>,
    lengths: Vec<f64>,
}

impl ArcLength {
    /// The table of `track` with `samples` (at least 1) pieces per segment.
    pub fn new(track: &VectorTrack, samples: usize) -> ArcLength {
        let samples = samples.max(1);
        let keys = track.keys();
        let mut times = vec![keys[0].time];
        let mut lengths = vec![0.0];
        let mut c = Cursor::default();
        // Gauss-Legendre nodes and weights on [-1, 1].
        const X: [f64; 5] = [
            0.0,
            -0.538_469_310_105_683_1,
            0.538_469_310_105_683_1,
            -0.906_179_845_938_664,
            0.906_179_845_938_664,
        ];
        const W: [f64; 5] = [
            0.568_888_888_888_888_9,
            0.478_628_670_499_366_5,
            0.478_628_670_499_366_5,
            0.236_926_885_056_189_1,
            0.236_926_885_056_189_1,
        ];
        for w in keys.windows(2) {
            let (t0, t1) = (w[0].time, w[1].time);
            let h = (t1 - t0) / samples as f64;
            for k in 0..samples {
                let (a, b) = (t0 + k as f64 * h, t0 + (k + 1) as f64 * h);
                let e = 1e-6 * h;
                let mut speed = |t: f64| {
                    let (p, q) = (
                        track.sample((t - e).max(t0), &mut c),
                        track.sample((t + e).min(t1), &mut c),
                    );
                    let dt = (t + e).min(t1) - (t - e).max(t0);
                    (0..3).map(|i| (q[i] - p[i]).powi(2)).sum::<f64>().sqrt() / dt
                };
                let len: f64 = X
                    .iter()
                    .zip(&W)
                    .map(|(x, w)| w * speed(0.5 * (a + b) + 0.5 * (b - a) * x))
                    .sum::<f64>()
                    * 0.5
                    * (b - a);
                times.push(b);
                lengths.push(lengths.last().copied().unwrap_or(0.0) + len);
            }
        }
        ArcLength { times, lengths }
    }

    /// The path's whole length.
    pub fn length(&self) -> f64 {
        self.lengths.last().copied().unwrap_or(0.0)
    }

    /// The time at which the path has run `s` (clamped to the path).
    pub fn time_at(&self, s: f64) -> f64 {
        let s = s.clamp(0.0, self.length());
        let i = self
            .lengths
            .partition_point(|&l| l < s)
            .clamp(1, self.lengths.len() - 1);
        let (l0, l1) = (self.lengths[i - 1], self.lengths[i]);
        let f = if l1 > l0 { (s - l0) / (l1 - l0) } else { 0.0 };
        self.times[i - 1] + f * (self.times[i] - self.times[i - 1])
    }
}
