//! Rotations for animation: Euler angles in all twelve orders, axis-angle, Rodrigues'
//! formula, and quaternion interpolation (SLERP, NLERP, SQUAD; Shoemake 1985).
//!
//! **Euler convention.** An [`EulerOrder`] names three axes `(i, j, k)`; the angles
//! `(a, b, c)` give `R = R_i(a) R_j(b) R_k(c)`: intrinsic rotations, the first about `i`,
//! then about the turned `j`, then the turned `k` (a vector is turned by `R_k` first).
//! This is BVH's reading of a `CHANNELS` line (`Zrotation Yrotation Xrotation` is
//! `ZYX`). Six orders are Tait-Bryan (`i, j, k` all different), six are proper Euler
//! (`k == i`). Angles are radians.
//!
//! **Extraction.** [`to_euler`] reads the angles off the matrix with `atan2` only (no
//! `asin`, so no loss near the poles): for Tait-Bryan orders `b` lies in `[-pi/2, pi/2]`,
//! for proper orders in `[0, pi]`. In gimbal lock (the middle angle at a pole, where only
//! `a + c` or `a - c` is defined) it sets `c = 0` and puts the whole turn into `a`, so the
//! angles still give back the matrix.
//!
//! **Interpolation.** All three take the shortest arc: `q` and `-q` are the same rotation
//! (the double cover), so the second key is negated when the two lie in opposite
//! hemispheres.

use crate::quat::{self, Quat};

/// The order of three rotation axes (0 = x, 1 = y, 2 = z); see the module docs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct EulerOrder(pub [usize; 3]);

impl EulerOrder {
    /// All twelve orders: the six Tait-Bryan ones, then the six proper Euler ones.
    pub const ALL: [EulerOrder; 12] = [
        EulerOrder([0, 1, 2]),
        EulerOrder([0, 2, 1]),
        EulerOrder([1, 0, 2]),
        EulerOrder([1, 2, 0]),
        EulerOrder([2, 0, 1]),
        EulerOrder([2, 1, 0]),
        EulerOrder([0, 1, 0]),
        EulerOrder([0, 2, 0]),
        EulerOrder([1, 0, 1]),
        EulerOrder([1, 2, 1]),
        EulerOrder([2, 0, 2]),
        EulerOrder([2, 1, 2]),
    ];

    /// The order written as letters (`"ZYX"`, `"XYX"`), or `None` for a string that is
    /// not one of the twelve.
    pub fn parse(s: &str) -> Option<EulerOrder> {
        let mut axes = [0; 3];
        let b = s.as_bytes();
        if b.len() != 3 {
            return None;
        }
        for (a, c) in axes.iter_mut().zip(b) {
            *a = match c.to_ascii_uppercase() {
                b'X' => 0,
                b'Y' => 1,
                b'Z' => 2,
                _ => return None,
            };
        }
        let o = EulerOrder(axes);
        Self::ALL.contains(&o).then_some(o)
    }

    /// The letters of the order (`"ZYX"`).
    pub fn name(self) -> String {
        self.0.iter().map(|&a| (b'X' + a as u8) as char).collect()
    }

    /// Whether the first and last axes are the same (proper Euler angles).
    pub fn is_proper(self) -> bool {
        self.0[0] == self.0[2]
    }

    /// `(i, j, k, s)`: the axes, with `k` the third axis of a proper order, and `s = 1`
    /// when `(i, j, k)` is a cyclic order of `(x, y, z)`, else `-1`.
    fn axes(self) -> (usize, usize, usize, f64) {
        let [i, j, _] = self.0;
        let k = 3 - i - j;
        let s = if (i + 1) % 3 == j { 1.0 } else { -1.0 };
        (i, j, k, s)
    }
}

/// The rotation by `angle` (rad) about the coordinate axis `axis` (0, 1, 2).
pub fn axis_quat(axis: usize, angle: f64) -> Quat {
    let (s, c) = (0.5 * angle).sin_cos();
    let mut q = [c, 0.0, 0.0, 0.0];
    q[1 + axis] = s;
    q
}

/// The unit quaternion of Euler angles `(a, b, c)` in `order` (see the module docs).
pub fn from_euler(order: EulerOrder, angles: [f64; 3]) -> Quat {
    let [i, j, k] = order.0;
    quat::mul(
        quat::mul(axis_quat(i, angles[0]), axis_quat(j, angles[1])),
        axis_quat(k, angles[2]),
    )
}

/// Below this `cos b` (Tait-Bryan) or `sin b` (proper), the middle angle is taken to be
/// at a pole: about the square root of f64's epsilon, where the error of splitting the
/// turn between `a` and `c` and the error of calling it a lock are both about 1e-8.
const GIMBAL: f64 = 1e-8;

/// The Euler angles `(a, b, c)` in `order` of a rotation matrix (rows); see the module
/// docs for ranges and gimbal lock.
pub fn matrix_to_euler(order: EulerOrder, r: [[f64; 3]; 3]) -> [f64; 3] {
    let (i, j, k, s) = order.axes();
    // With c = 0, R = R_i(a) R_j(b) and its column j is R_i(a) e_j
    // = cos a e_j + s sin a e_k, which gives a alone.
    let locked = |b: f64| [(s * r[k][j]).atan2(r[j][j]), b, 0.0];
    if order.is_proper() {
        // Row i of R is (cos b, sin b sin c, s sin b cos c) on axes (i, j, k); column i
        // is (cos b, sin a sin b, -s cos a sin b).
        let sb = r[i][j].hypot(r[i][k]);
        let b = sb.atan2(r[i][i]);
        if sb < GIMBAL {
            return locked(b);
        }
        [r[j][i].atan2(-s * r[k][i]), b, r[i][j].atan2(s * r[i][k])]
    } else {
        // R[i][k] = s sin b; row i is (cos b cos c, -s cos b sin c, s sin b); column k is
        // (s sin b, -s sin a cos b, cos a cos b) on axes (i, j, k).
        let cb = r[i][i].hypot(r[i][j]);
        let b = (s * r[i][k]).atan2(cb);
        if cb < GIMBAL {
            return locked(b);
        }
        [
            (-s * r[j][k]).atan2(r[k][k]),
            b,
            (-s * r[i][j]).atan2(r[i][i]),
        ]
    }
}

/// The Euler angles in `order` of a unit quaternion (see [`matrix_to_euler`]).
pub fn to_euler(order: EulerOrder, q: Quat) -> [f64; 3] {
    matrix_to_euler(order, quat::to_matrix(q))
}

/// The rotation by `angle` (rad) about the unit `axis`.
pub fn from_axis_angle(axis: [f64; 3], angle: f64) -> Quat {
    let (s, c) = (0.5 * angle).sin_cos();
    [c, axis[0] * s, axis[1] * s, axis[2] * s]
}

/// The unit axis and angle in `[0, pi]` of a unit quaternion; the identity gives the
/// x axis and angle 0.
pub fn to_axis_angle(q: Quat) -> ([f64; 3], f64) {
    let v = quat::log(q);
    match crate::v3::length_and_unit(v) {
        Some((angle, axis)) => (axis, angle),
        None => ([1.0, 0.0, 0.0], 0.0),
    }
}

/// Rodrigues' formula: the matrix (rows) of the rotation by `angle` about the unit
/// `axis`, `R = I + sin(t) K + (1 - cos(t)) K^2` with `K` the cross-product matrix of
/// the axis.
pub fn rodrigues(axis: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    let t = 1.0 - c;
    let [x, y, z] = axis;
    [
        [c + t * x * x, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, c + t * y * y, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, c + t * z * z],
    ]
}

/// The exponential map to matrices: the rotation by the vector `v` (axis times angle).
pub fn exp_matrix(v: [f64; 3]) -> [[f64; 3]; 3] {
    match crate::v3::length_and_unit(v) {
        Some((angle, axis)) => rodrigues(axis, angle),
        None => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    }
}

/// The logarithm of a rotation matrix: its rotation vector (angle in `[0, pi]`).
pub fn log_matrix(r: [[f64; 3]; 3]) -> [f64; 3] {
    quat::log(quat::from_matrix(r))
}

/// `4-vector dot`.
#[inline]
pub fn dot4(a: Quat, b: Quat) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
}

/// `b`, or `-b` when it lies in the other hemisphere from `a` (the shortest arc).
#[inline]
pub fn align(a: Quat, b: Quat) -> Quat {
    if dot4(a, b) < 0.0 {
        b.map(|c| -c)
    } else {
        b
    }
}

/// Normalised linear interpolation along the shortest arc: cheap, constant in direction
/// but not in angular speed (exact at `t = 0, 1/2, 1`).
pub fn nlerp(a: Quat, b: Quat, t: f64) -> Quat {
    let b = align(a, b);
    let q = [0, 1, 2, 3].map(|k| a[k] + t * (b[k] - a[k]));
    quat::normalize(q).unwrap_or(a)
}

/// Spherical linear interpolation along the shortest arc (Shoemake 1985): constant
/// angular speed. Written as `a exp(t log(a* b))`'s closed form
/// `(sin((1-t) th) a + sin(t th) b) / sin(th)`; below an angle of 1e-6 rad between the
/// keys NLERP is used (it agrees to below f64 rounding there, and the closed form
/// divides by `sin(th) ~ 0`).
pub fn slerp(a: Quat, b: Quat, t: f64) -> Quat {
    let b = align(a, b);
    let d = dot4(a, b).min(1.0);
    let th = d.acos();
    if th < 1e-6 {
        return nlerp(a, b, t);
    }
    let s = th.sin();
    let (wa, wb) = (((1.0 - t) * th).sin() / s, (t * th).sin() / s);
    let q = [0, 1, 2, 3].map(|k| wa * a[k] + wb * b[k]);
    quat::normalize(q).unwrap_or(a)
}

/// The inner control point of SQUAD at key `q` between its neighbours `prev` and
/// `next` (Shoemake 1987): `q exp(-(log(q* next) + log(q* prev)) / 4)`, with all three
/// in one hemisphere.
pub fn squad_control(prev: Quat, q: Quat, next: Quat) -> Quat {
    let (prev, next) = (align(q, prev), align(q, next));
    let qi = quat::conj(q);
    let ln = quat::log(quat::mul(qi, next));
    let lp = quat::log(quat::mul(qi, prev));
    quat::mul(q, quat::exp([0, 1, 2].map(|k| -0.25 * (ln[k] + lp[k]))))
}

/// Spherical cubic interpolation between keys `a` and `b` with control points `sa` and
/// `sb` from [`squad_control`]: `slerp(slerp(a, b, t), slerp(sa, sb, t), 2t(1-t))`. The
/// curve passes through the keys with a continuous tangent across them.
pub fn squad(a: Quat, b: Quat, sa: Quat, sb: Quat, t: f64) -> Quat {
    let b = align(a, b);
    slerp(slerp(a, b, t), slerp(sa, sb, t), 2.0 * t * (1.0 - t))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn close_m(a: [[f64; 3]; 3], b: [[f64; 3]; 3], tol: f64) -> bool {
        (0..3).all(|r| (0..3).all(|c| (a[r][c] - b[r][c]).abs() < tol))
    }

    #[test]
    fn parse_names_all_twelve() {
        for o in EulerOrder::ALL {
            assert_eq!(EulerOrder::parse(&o.name()), Some(o));
        }
        assert_eq!(EulerOrder::parse("XXY"), None);
        assert_eq!(EulerOrder::parse("XY"), None);
        assert_eq!(EulerOrder::parse("zyx"), Some(EulerOrder([2, 1, 0])));
    }

    #[test]
    fn euler_xyz_is_the_product_of_axis_matrices() {
        // Rx(a) Ry(b) Rz(c) by Rodrigues, against from_euler.
        let (a, b, c) = (0.3, -0.7, 1.9);
        let m = |ax: usize, t: f64| {
            let mut e = [0.0; 3];
            e[ax] = 1.0;
            rodrigues(e, t)
        };
        let mul = |x: [[f64; 3]; 3], y: [[f64; 3]; 3]| {
            let mut o = [[0.0; 3]; 3];
            for r in 0..3 {
                for cc in 0..3 {
                    o[r][cc] = (0..3).map(|k| x[r][k] * y[k][cc]).sum();
                }
            }
            o
        };
        for order in EulerOrder::ALL {
            let [i, j, k] = order.0;
            let want = mul(mul(m(i, a), m(j, b)), m(k, c));
            let got = quat::to_matrix(from_euler(order, [a, b, c]));
            assert!(close_m(want, got, 1e-14), "{}", order.name());
        }
    }

    #[test]
    fn gimbal_lock_keeps_the_rotation() {
        for order in EulerOrder::ALL {
            let poles: &[f64] = if order.is_proper() {
                &[0.0, std::f64::consts::PI]
            } else {
                &[std::f64::consts::FRAC_PI_2, -std::f64::consts::FRAC_PI_2]
            };
            for &b in poles {
                let q = from_euler(order, [0.4, b, -1.1]);
                let e = to_euler(order, q);
                assert_eq!(
                    e[2],
                    0.0,
                    "{} at the pole puts the turn into a",
                    order.name()
                );
                let back = quat::to_matrix(from_euler(order, e));
                assert!(close_m(back, quat::to_matrix(q), 1e-7), "{}", order.name());
            }
        }
    }

    #[test]
    fn slerp_known_values() {
        // Halfway between identity and 90 degrees about z is 45 degrees about z.
        let b = axis_quat(2, std::f64::consts::FRAC_PI_2);
        let h = slerp(quat::IDENTITY, b, 0.5);
        let want = axis_quat(2, std::f64::consts::FRAC_PI_4);
        assert!((0..4).all(|k| (h[k] - want[k]).abs() < 1e-15));
        // A third of the way: 30 degrees (constant angular speed).
        let t = slerp(quat::IDENTITY, b, 1.0 / 3.0);
        let want = axis_quat(2, std::f64::consts::FRAC_PI_6);
        assert!((0..4).all(|k| (t[k] - want[k]).abs() < 1e-15));
        // The double cover: -b is the same key; the path stays on the short arc.
        let nb = b.map(|c| -c);
        let h2 = slerp(quat::IDENTITY, nb, 0.5);
        assert!((0..4).all(|k| (h2[k] - h[k]).abs() < 1e-15));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        #[test]
        fn euler_round_trips_in_all_orders(
            a in -3.1f64..3.1, b in -3.1f64..3.1, c in -3.1f64..3.1, o in 0usize..12,
        ) {
            let order = EulerOrder::ALL[o];
            let q = from_euler(order, [a, b, c]);
            let n = dot4(q, q).sqrt();
            prop_assert!((n - 1.0).abs() < 1e-14);
            let e = to_euler(order, q);
            let back = from_euler(order, e);
            prop_assert!(close_m(quat::to_matrix(back), quat::to_matrix(q), 1e-7));
        }

        #[test]
        fn axis_angle_matrix_and_exp_round_trip(
            x in -1.0f64..1.0, y in -1.0f64..1.0, z in -1.0f64..1.0, t in 0.0f64..3.1,
        ) {
            let Some((_, axis)) = crate::v3::length_and_unit([x, y, z]) else {
                return Ok(());
            };
            prop_assume!(x * x + y * y + z * z > 1e-4);
            let q = from_axis_angle(axis, t);
            let r = rodrigues(axis, t);
            prop_assert!(close_m(r, quat::to_matrix(q), 1e-14));
            let (ax2, t2) = to_axis_angle(q);
            prop_assert!((t2 - t).abs() < 1e-9);
            if t > 1e-6 {
                prop_assert!((0..3).all(|k| (ax2[k] - axis[k]).abs() < 1e-8));
            }
            let v = log_matrix(r);
            prop_assert!(close_m(exp_matrix(v), r, 1e-13));
        }

        #[test]
        fn interpolants_stay_unit_and_hit_the_keys(
            a in prop::array::uniform3(-3.0f64..3.0),
            b in prop::array::uniform3(-3.0f64..3.0),
            t in 0.0f64..1.0,
        ) {
            let (qa, qb) = (quat::exp(a), quat::exp(b));
            for q in [slerp(qa, qb, t), nlerp(qa, qb, t)] {
                prop_assert!((dot4(q, q) - 1.0).abs() < 1e-12);
            }
            let s0 = slerp(qa, qb, 0.0);
            let s1 = slerp(qa, qb, 1.0);
            prop_assert!(dot4(s0, qa).abs() > 1.0 - 1e-12);
            prop_assert!(dot4(s1, qb).abs() > 1.0 - 1e-12);
            // Slerp's angle from a grows linearly in t along the short arc.
            let full = 2.0 * dot4(qa, qb).abs().min(1.0).acos();
            let part = 2.0 * dot4(qa, slerp(qa, qb, t)).abs().min(1.0).acos();
            prop_assert!((part - t * full).abs() < 1e-6);
            let c = squad(qa, qb, squad_control(qa, qa, qb), squad_control(qa, qb, qb), t);
            prop_assert!((dot4(c, c) - 1.0).abs() < 1e-12);
        }
    }
}
