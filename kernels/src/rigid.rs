//! A rigid body's pose update, written once over [`Lane`]: one body (`f64`) or four at
//! once (`f64x4`, one body a lane), with the same operations in the same order in every
//! lane, so both give the same bits.
//!
//! Symplectic Euler on Baraff's state ("Rigid body simulation", SIGGRAPH 2001 course
//! notes, section 2): the centre moves at the new velocity, the orientation turns at the
//! new angular velocity by the first-order quaternion update ([`quat::integrate`]), and
//! the angular momentum `L = R0 I R0ᵀ w` is kept, so the angular velocity is read again
//! at the new orientation, `w = R1 I⁻¹ R1ᵀ L`: without torque L is conserved exactly.

use crate::lane::Lane;
use crate::quat;

/// `a . b`.
#[inline(always)]
pub fn dot<R: Lane>(a: [R; 3], b: [R; 3]) -> R {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `m v` for the rows of `m`.
#[inline(always)]
pub fn mat_vec<R: Lane>(m: [[R; 3]; 3], v: [R; 3]) -> [R; 3] {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}

/// `mᵀ v`: a vector into the frame whose axes are the columns of the rotation `m`.
#[inline(always)]
pub fn mat_t_vec<R: Lane>(m: &[[R; 3]; 3], v: [R; 3]) -> [R; 3] {
    std::array::from_fn(|k| m[0][k] * v[0] + m[1][k] * v[1] + m[2][k] * v[2])
}

/// `R diag(d) Rᵀ v` for the rotation `r`, as `R (d ⊙ (Rᵀ v))`: two products with `R`
/// instead of forming the matrix.
#[inline(always)]
pub fn inertia_times<R: Lane>(r: &[[R; 3]; 3], d: [R; 3], v: [R; 3]) -> [R; 3] {
    let body = mat_t_vec(r, v);
    mat_vec(*r, [d[0] * body[0], d[1] * body[1], d[2] * body[2]])
}

/// A body's pose and velocities as the sub-step leaves them (module docs).
#[derive(Clone, Copy, Debug)]
pub struct Pose<R> {
    /// Centre (m).
    pub x: [R; 3],
    /// Orientation, a unit quaternion `[w, x, y, z]`.
    pub q: [R; 4],
    /// Angular velocity (rad/s, world).
    pub w: [R; 3],
    /// The rotation matrix of `q`, rows.
    pub rot: [[R; 3]; 3],
}

/// Symplectic Euler's position update over a sub-step `h` (s) of a body with centre `x`,
/// orientation `q` (rotation matrix `rot`), velocity `v` and angular velocity `w` that
/// the constraints left, the split impulses' pseudo-velocities `pv`, `pw` (moving the
/// body this sub-step only), and principal moments `inertia` (kg m²) and their
/// inverses.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub fn symplectic<R: Lane>(
    x: [R; 3],
    rot: &[[R; 3]; 3],
    q: [R; 4],
    (v, w): ([R; 3], [R; 3]),
    (pv, pw): ([R; 3], [R; 3]),
    (inertia, inv_inertia): ([R; 3], [R; 3]),
    h: R,
) -> Pose<R> {
    let l = inertia_times(rot, inertia, w);
    let x = std::array::from_fn(|k| x[k] + (v[k] + pv[k]) * h);
    let q = quat::integrate(q, std::array::from_fn(|k| w[k] + pw[k]), h);
    let rot = quat::to_matrix(q);
    let w = inertia_times(&rot, inv_inertia, l);
    Pose { x, q, w, rot }
}

#[cfg(test)]
mod tests {
    use super::*;
    use wide::f64x4;

    /// Four lanes give each body the bits of its own scalar update, including a lane
    /// whose orientation update is not finite (kept as it was).
    #[test]
    fn four_lanes_give_the_scalar_bits() {
        let body = |k: usize| {
            let f = k as f64;
            let q = quat::normalize([1.0, 0.1 * f, -0.2, 0.3 * f]).unwrap();
            let w = if k == 3 {
                [f64::INFINITY, 0.0, 0.0]
            } else {
                [0.5 - f, 2.0 * f, -1.5]
            };
            (
                [f, -2.0 * f, 0.5],
                q,
                ([0.1, f, -3.0], w),
                ([0.01 * f, 0.0, -0.02], [0.0, 0.03, f * 0.01]),
                (
                    [1.0 + f, 2.0, 3.0 - 0.5 * f],
                    [1.0 / (1.0 + f), 0.5, 1.0 / (3.0 - 0.5 * f)],
                ),
            )
        };
        let h = 1.0 / 240.0;
        let scalar: Vec<Pose<f64>> = (0..4)
            .map(|k| {
                let (x, q, vw, p, i) = body(k);
                symplectic(x, &quat::to_matrix(q), q, vw, p, i, h)
            })
            .collect();
        let lane = |f: &dyn Fn(usize) -> f64| f64x4::new(std::array::from_fn(f));
        let b: Vec<_> = (0..4).map(body).collect();
        let x = std::array::from_fn(|c| lane(&|k| b[k].0[c]));
        let q: [f64x4; 4] = std::array::from_fn(|c| lane(&|k| b[k].1[c]));
        let v3 = |g: &dyn Fn(usize) -> [f64; 3]| -> [f64x4; 3] {
            std::array::from_fn(|c| lane(&|k| g(k)[c]))
        };
        let wide = symplectic(
            x,
            &quat::to_matrix(q),
            q,
            (v3(&|k| b[k].2 .0), v3(&|k| b[k].2 .1)),
            (v3(&|k| b[k].3 .0), v3(&|k| b[k].3 .1)),
            (v3(&|k| b[k].4 .0), v3(&|k| b[k].4 .1)),
            f64x4::splat(h),
        );
        for (k, s) in scalar.iter().enumerate() {
            for c in 0..3 {
                assert_eq!(wide.x[c].to_array()[k].to_bits(), s.x[c].to_bits());
                assert_eq!(wide.w[c].to_array()[k].to_bits(), s.w[c].to_bits());
                for r in 0..3 {
                    assert_eq!(
                        wide.rot[r][c].to_array()[k].to_bits(),
                        s.rot[r][c].to_bits()
                    );
                }
            }
            for c in 0..4 {
                assert_eq!(wide.q[c].to_array()[k].to_bits(), s.q[c].to_bits());
            }
        }
        // The lane whose update is not finite kept its orientation.
        assert_eq!(scalar[3].q, b[3].1);
    }
}
