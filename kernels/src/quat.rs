//! Unit quaternions `[w, x, y, z]` as rotations (Shoemake 1985): products, the
//! exponential map, rotation of vectors, matrices, and the first-order update
//! `q' = 1/2 [0, w] q` of a body spinning at angular velocity `w` (world frame, rad/s).
//!
//! Shared by the rigid bodies, the six-DoF haptic tool and the character animation.

use crate::lane::Lane;
use crate::v3::{add, cross, length_and_unit, scale};

/// A unit quaternion `[w, x, y, z]`.
pub type Quat = [f64; 4];

/// The identity rotation.
pub const IDENTITY: Quat = [1.0, 0.0, 0.0, 0.0];

/// `a b` (apply b, then a).
#[inline]
pub fn mul<R: Lane>(a: [R; 4], b: [R; 4]) -> [R; 4] {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}

/// The conjugate: the inverse rotation of a unit quaternion.
#[inline]
pub fn conj(q: Quat) -> Quat {
    [q[0], -q[1], -q[2], -q[3]]
}

/// The rotation by the vector `v` (axis times angle, rad).
pub fn exp(v: [f64; 3]) -> Quat {
    match length_and_unit(v) {
        Some((angle, axis)) => {
            let (s, c) = (0.5 * angle).sin_cos();
            [c, axis[0] * s, axis[1] * s, axis[2] * s]
        }
        None => IDENTITY,
    }
}

/// The rotation vector of `q` (axis times angle in `[0, pi]`).
pub fn log(q: Quat) -> [f64; 3] {
    let q = if q[0] < 0.0 { q.map(|c| -c) } else { q };
    match length_and_unit([q[1], q[2], q[3]]) {
        Some((s, axis)) => scale(axis, 2.0 * s.atan2(q[0])),
        None => [0.0; 3],
    }
}

/// `q v q*`.
#[inline]
pub fn rotate(q: Quat, v: [f64; 3]) -> [f64; 3] {
    let u = [q[1], q[2], q[3]];
    let t = scale(cross(u, v), 2.0);
    add(add(v, scale(t, q[0])), cross(u, t))
}

/// `q* v q`: `v` taken into the frame `q` rotates from.
#[inline]
pub fn rotate_inv(q: Quat, v: [f64; 3]) -> [f64; 3] {
    rotate(conj(q), v)
}

/// `q / |q|`, or `None` for a zero or non-finite `q`.
#[inline]
pub fn normalize(q: Quat) -> Option<Quat> {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    // One division and four products: the rigid bodies normalise every body at every
    // sub-step, and four divisions were 4% of the 1,000-box pile's step.
    (n.is_finite() && n > 0.0).then(|| {
        let inv = 1.0 / n;
        q.map(|c| c * inv)
    })
}

/// The rotation matrix of a unit `q`, rows.
#[inline]
pub fn to_matrix<R: Lane>(q: [R; 4]) -> [[R; 3]; 3] {
    let [w, x, y, z] = q;
    let (one, two) = (R::splat(1.0), R::splat(2.0));
    [
        [
            one - two * (y * y + z * z),
            two * (x * y - w * z),
            two * (x * z + w * y),
        ],
        [
            two * (x * y + w * z),
            one - two * (x * x + z * z),
            two * (y * z - w * x),
        ],
        [
            two * (x * z - w * y),
            two * (y * z + w * x),
            one - two * (x * x + y * y),
        ],
    ]
}

/// The unit quaternion of a rotation matrix (rows; Shepperd's method).
pub fn from_matrix(r: [[f64; 3]; 3]) -> Quat {
    let tr = r[0][0] + r[1][1] + r[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (r[2][1] - r[1][2]) / s,
            (r[0][2] - r[2][0]) / s,
            (r[1][0] - r[0][1]) / s,
        ]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt() * 2.0;
        [
            (r[2][1] - r[1][2]) / s,
            0.25 * s,
            (r[0][1] + r[1][0]) / s,
            (r[0][2] + r[2][0]) / s,
        ]
    } else if r[1][1] > r[2][2] {
        let s = (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt() * 2.0;
        [
            (r[0][2] - r[2][0]) / s,
            (r[0][1] + r[1][0]) / s,
            0.25 * s,
            (r[1][2] + r[2][1]) / s,
        ]
    } else {
        let s = (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt() * 2.0;
        [
            (r[1][0] - r[0][1]) / s,
            (r[0][2] + r[2][0]) / s,
            (r[1][2] + r[2][1]) / s,
            0.25 * s,
        ]
    };
    normalize(q).unwrap_or(IDENTITY)
}

/// The time derivative of `q` under angular velocity `w` (world frame, rad/s):
/// `1/2 [0, w] q` (Baraff, "Rigid body simulation", section 4).
#[inline]
pub fn derivative<R: Lane>(q: [R; 4], w: [R; 3]) -> [R; 4] {
    mul([R::splat(0.0), w[0], w[1], w[2]], q).map(|c| R::splat(0.5) * c)
}

/// `q` advanced by `dt` (s) at angular velocity `w` by the first-order update
/// `q + dt/2 [0, w] q`, renormalised (the form rigid-body solvers use; exact to first
/// order, and keeps the drift of the norm out); `q` itself where the update's norm is
/// zero or not finite. Lane by lane the same bits as [`normalize`] of the update.
#[inline]
pub fn integrate<R: Lane>(q: [R; 4], w: [R; 3], dt: R) -> [R; 4] {
    let d = derivative(q, w);
    let r: [R; 4] = std::array::from_fn(|k| q[k] + dt * d[k]);
    let n = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3]).sqrt();
    let inv = R::splat(1.0) / n;
    // Kept where not 0 < n < infinity (NaN compares false).
    std::array::from_fn(|k| {
        let unit = R::if_lt(R::splat(0.0), n, r[k] * inv, q[k]);
        R::if_lt(n, R::splat(f64::INFINITY), unit, q[k])
    })
}
