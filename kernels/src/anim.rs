//! Character animation kernels: forward kinematics over a joint hierarchy, pose blending,
//! and skinning (linear blend and dual quaternion) over f32 structure-of-arrays vertices.
//!
//! **Forward kinematics.** Joints are stored parents first (`parents[j] < j`, roots
//! [`NO_PARENT`]), so one pass in index order composes each joint's local transform with
//! its parent's model transform: `M_j = M_parent(j) L_j`, `L_j = [R(q_j) diag(s_j) | t_j]`.
//! Local poses are component-major SoA (translations `[x.., y.., z..]`, rotations
//! `[w.., x.., y.., z..]`, scales like translations); model transforms are affine
//! matrices, [`Affine`], one per joint, as ozz-animation's `LocalToModelJob` writes them.

use crate::quat::{self, Quat};

/// An affine transform as three rows of `[R | t]`: `r00 r01 r02 tx r10 r11 r12 ty r20 r21
/// r22 tz` (a 3x4 matrix; the fourth row is `0 0 0 1`).
pub type Affine = [f64; 12];

/// The parent index of a root joint.
pub const NO_PARENT: u32 = u32::MAX;

/// The identity transform.
pub const AFFINE_IDENTITY: Affine = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];

/// `[R(q) diag(s) | t]`.
#[inline]
pub fn affine_from_trs(t: [f64; 3], q: Quat, s: [f64; 3]) -> Affine {
    let r = quat::to_matrix(q);
    [
        r[0][0] * s[0],
        r[0][1] * s[1],
        r[0][2] * s[2],
        t[0],
        r[1][0] * s[0],
        r[1][1] * s[1],
        r[1][2] * s[2],
        t[1],
        r[2][0] * s[0],
        r[2][1] * s[1],
        r[2][2] * s[2],
        t[2],
    ]
}

/// `a b` (apply `b`, then `a`).
#[inline]
pub fn affine_mul(a: &Affine, b: &Affine) -> Affine {
    let mut o = [0.0; 12];
    for r in 0..3 {
        for c in 0..4 {
            let mut v = a[4 * r] * b[c] + a[4 * r + 1] * b[4 + c] + a[4 * r + 2] * b[8 + c];
            if c == 3 {
                v += a[4 * r + 3];
            }
            o[4 * r + c] = v;
        }
    }
    o
}

/// `a p` for a point `p`.
#[inline]
pub fn affine_point(a: &Affine, p: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|r| a[4 * r] * p[0] + a[4 * r + 1] * p[1] + a[4 * r + 2] * p[2] + a[4 * r + 3])
}

/// Translation, rotation and scale of an affine transform `[R diag(s) | t]`: the scales
/// are the lengths of the 3x3 part's columns, the rotation that of the columns
/// normalised (exact for rotations with positive scales; a zero column is left as is).
pub fn affine_decompose(a: &Affine) -> ([f64; 3], Quat, [f64; 3]) {
    let mut r = [[a[0], a[1], a[2]], [a[4], a[5], a[6]], [a[8], a[9], a[10]]];
    let mut s = [0.0; 3];
    for (c, sc) in s.iter_mut().enumerate() {
        *sc = (r[0][c] * r[0][c] + r[1][c] * r[1][c] + r[2][c] * r[2][c]).sqrt();
        if *sc > 0.0 {
            for row in r.iter_mut() {
                row[c] /= *sc;
            }
        }
    }
    ([a[3], a[7], a[11]], quat::from_matrix(r), s)
}

/// The inverse of a rigid or scaled-rigid affine transform (any invertible one: the 3x3
/// part is inverted by its adjugate). A singular transform gives the identity.
pub fn affine_inverse(a: &Affine) -> Affine {
    let m = |r: usize, c: usize| a[4 * r + c];
    let c00 = m(1, 1) * m(2, 2) - m(1, 2) * m(2, 1);
    let c01 = m(1, 2) * m(2, 0) - m(1, 0) * m(2, 2);
    let c02 = m(1, 0) * m(2, 1) - m(1, 1) * m(2, 0);
    let det = m(0, 0) * c00 + m(0, 1) * c01 + m(0, 2) * c02;
    if det == 0.0 || !det.is_finite() {
        return AFFINE_IDENTITY;
    }
    let id = 1.0 / det;
    let inv = [
        [
            c00 * id,
            (m(0, 2) * m(2, 1) - m(0, 1) * m(2, 2)) * id,
            (m(0, 1) * m(1, 2) - m(0, 2) * m(1, 1)) * id,
        ],
        [
            c01 * id,
            (m(0, 0) * m(2, 2) - m(0, 2) * m(2, 0)) * id,
            (m(0, 2) * m(1, 0) - m(0, 0) * m(1, 2)) * id,
        ],
        [
            c02 * id,
            (m(0, 1) * m(2, 0) - m(0, 0) * m(2, 1)) * id,
            (m(0, 0) * m(1, 1) - m(0, 1) * m(1, 0)) * id,
        ],
    ];
    let t = [m(0, 3), m(1, 3), m(2, 3)];
    let mut o = [0.0; 12];
    for r in 0..3 {
        o[4 * r..4 * r + 3].copy_from_slice(&inv[r]);
        o[4 * r + 3] = -(inv[r][0] * t[0] + inv[r][1] * t[1] + inv[r][2] * t[2]);
    }
    o
}

/// Forward kinematics: `out[j] = out[parents[j]] L_j` over all joints, with `L_j` from
/// the SoA local pose (see the module docs). `root` is applied above the roots (the
/// identity for model space).
///
/// Preconditions: `parents[j] < j` or [`NO_PARENT`] (a skeleton's build checks it; a
/// later parent would read a stale transform, never out of bounds); unit rotations.
pub fn local_to_model(
    out: &mut [Affine],
    parents: &[u32],
    translations: &[f64],
    rotations: &[f64],
    scales: &[f64],
    root: &Affine,
) {
    let n = parents.len();
    assert_eq!(out.len(), n, "one model transform per joint");
    assert_eq!(translations.len(), 3 * n, "translations are 3n");
    assert_eq!(rotations.len(), 4 * n, "rotations are 4n");
    assert_eq!(scales.len(), 3 * n, "scales are 3n");
    for j in 0..n {
        let t = [
            translations[j],
            translations[n + j],
            translations[2 * n + j],
        ];
        let q = [
            rotations[j],
            rotations[n + j],
            rotations[2 * n + j],
            rotations[3 * n + j],
        ];
        let s = [scales[j], scales[n + j], scales[2 * n + j]];
        let local = affine_from_trs(t, q, s);
        let p = parents[j];
        out[j] = if p == NO_PARENT || p as usize >= n {
            affine_mul(root, &local)
        } else {
            affine_mul(&out[p as usize], &local)
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_undoes_a_scaled_rigid_transform() {
        let a = affine_from_trs(
            [1.0, -2.0, 0.5],
            quat::exp([0.3, -0.4, 1.2]),
            [2.0, 0.5, 1.5],
        );
        let i = affine_mul(&a, &affine_inverse(&a));
        for k in 0..12 {
            assert!((i[k] - AFFINE_IDENTITY[k]).abs() < 1e-14, "{k}");
        }
    }

    #[test]
    fn chain_of_two_bones_bent_at_right_angles() {
        // Root at the origin turned 90 degrees about z; its child one unit along local x.
        let q = quat::exp([0.0, 0.0, std::f64::consts::FRAC_PI_2]);
        let parents = [NO_PARENT, 0];
        let t = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0];
        let r = [q[0], 1.0, q[1], 0.0, q[2], 0.0, q[3], 0.0];
        let s = [1.0; 6];
        let mut out = [AFFINE_IDENTITY; 2];
        local_to_model(&mut out, &parents, &t, &r, &s, &AFFINE_IDENTITY);
        let p = affine_point(&out[1], [0.0; 3]);
        assert!((p[0]).abs() < 1e-15 && (p[1] - 1.0).abs() < 1e-15 && p[2] == 0.0);
    }
}
