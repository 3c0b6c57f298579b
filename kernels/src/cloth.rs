//! Baraff-Witkin cloth elements: stretch and shear condition functions over triangles
//! with rest (u, v) coordinates, their energies, forces and exact Jacobians.
//!
//! Baraff and Witkin, "Large Steps in Cloth Simulation" (SIGGRAPH 1998), section 4, and
//! the course notes, section 3. Each triangle maps its rest (u, v) linearly to the world:
//! `w(u, v)`, so `w_u = dw/du` and `w_v = dw/dv` are constant over it and linear in the
//! vertex positions, `w_u = sum_i du_i x_i`, `w_v = sum_i dv_i x_i` with coefficients from
//! the rest (u, v) alone ([`TriangleRest`], computed once). With `a` the rest (u, v) area:
//!
//! ```text
//! stretch: C = a (|w_u| - b_u, |w_v| - b_v)      shear: C = a w_u . w_v
//! E = k/2 |C|^2,   f_i = -k C dC/dx_i - k_d (dC/dt) dC/dx_i,   dC/dt = sum_j dC/dx_j . v_j
//! df_i/dx_j = -k (dC/dx_i dC/dx_j^T + C d2C/dx_i dx_j),   df_i/dv_j = -k_d dC/dx_i dC/dx_j^T
//! d|w_u|/dx_i = a du_i w_u/|w_u|,   d2|w_u|/dx_i dx_j = a du_i du_j (I - n n^T)/|w_u|
//! d(w_u . w_v)/dx_i = du_i w_v + dv_i w_u,   d2/dx_i dx_j = (du_i dv_j + dv_i du_j) I
//! ```
//!
//! (per component of C, summed). The damping force's position derivative is left out as
//! in the paper (section 5.2): it is not symmetric. A stretch direction of zero length has
//! no direction: that component gives no force and no Jacobian. Units: positions m,
//! velocities m/s, k N/m, k_d N s/m (per unit (u, v) area squared), energy J.

use crate::v3::{cross, dot, sub};
use crate::vec::st;
use wide::f64x4;

/// Constants of one triangle, from its rest (u, v) coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleRest {
    /// Coefficients of `w_u` in the three vertex positions.
    pub du: [f64; 3],
    /// Coefficients of `w_v` in the three vertex positions.
    pub dv: [f64; 3],
    /// Rest area in (u, v) (m^2).
    pub area: f64,
}

impl TriangleRest {
    /// From the rest (u, v) of the vertices; `None` when they are collinear (zero area)
    /// or not finite.
    pub fn new(uv: [[f64; 2]; 3]) -> Option<TriangleRest> {
        let (u1, v1) = (uv[1][0] - uv[0][0], uv[1][1] - uv[0][1]);
        let (u2, v2) = (uv[2][0] - uv[0][0], uv[2][1] - uv[0][1]);
        let det = u1 * v2 - u2 * v1;
        if !(det.is_finite() && det != 0.0) {
            return None;
        }
        // [w_u w_v] = [dx1 dx2] [[u1 u2], [v1 v2]]^-1 with dx_i = x_i - x_0.
        let du = [(v1 - v2) / det, v2 / det, -v1 / det];
        let dv = [(u2 - u1) / det, -u2 / det, u1 / det];
        Some(TriangleRest {
            du,
            dv,
            area: 0.5 * det.abs(),
        })
    }

    /// `(w_u, w_v)` at positions `x`.
    #[inline]
    pub fn wuv(&self, x: &[[f64; 3]; 3]) -> ([f64; 3], [f64; 3]) {
        let w = |coef: &[f64; 3]| -> [f64; 3] {
            std::array::from_fn(|c| coef[0] * x[0][c] + coef[1] * x[1][c] + coef[2] * x[2][c])
        };
        (w(&self.du), w(&self.dv))
    }
}

/// What an element gives: energy, forces on its vertices, and Jacobian blocks
/// `df_i/dx_j` and `df_i/dv_j` (3x3, row-major) at `[i][j]`.
///
/// With `project` set, each condition's stiffness `-k (dC dC^T + C d2C)` is made negative
/// semi-definite by dropping its curvature term `C d2C` where that term could make it
/// indefinite: always for conditions whose `d2C` is indefinite (shear, bend), and only
/// under compression (`C < 0`) for those whose `d2C` is positive semi-definite (stretch,
/// `d2|w|` is). What remains is exact in stretched tension and the Gauss-Newton matrix
/// elsewhere; implicit systems `M - h^2 df/dx` then stay positive definite whatever the
/// deformation, at no cost beyond skipping work (the curvature of a bend hinge is then
/// never computed). Choi and Ko (2002) make the same choice for springs in compression.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElementOut<const N: usize> {
    /// Drop indefinite curvature terms (see above).
    pub project: bool,
    /// Elastic energy (J).
    pub energy: f64,
    /// Force on each vertex (N).
    pub f: [[f64; 3]; N],
    /// `df_i/dx_j`.
    pub kx: [[[f64; 9]; N]; N],
    /// `df_i/dv_j`.
    pub kv: [[[f64; 9]; N]; N],
}

impl<const N: usize> ElementOut<N> {
    /// Zero energy, force and Jacobians.
    pub fn zero() -> Self {
        Self::new(false)
    }

    /// Zero, with `project` (see the type's docs).
    pub fn new(project: bool) -> Self {
        ElementOut {
            project,
            energy: 0.0,
            f: [[0.0; 3]; N],
            kx: [[[0.0; 9]; N]; N],
            kv: [[[0.0; 9]; N]; N],
        }
    }

    /// Adds one scalar condition `c` with gradient `g` (per vertex) and Hessian blocks
    /// `hess(i, j)` (3x3 row-major), stiffness `k` and damping `kd`, at velocities `v`.
    /// `convex`: `d2C` is positive semi-definite (see `project` in the type's docs);
    /// `hess` is not called when the curvature term is dropped.
    #[inline]
    #[allow(clippy::too_many_arguments)] // the condition's parts, as the paper writes them
    pub fn add_condition(
        &mut self,
        c: f64,
        g: &[[f64; 3]; N],
        hess: impl Fn(usize, usize) -> [f64; 9],
        convex: bool,
        k: f64,
        kd: f64,
        v: &[[f64; 3]; N],
    ) {
        self.energy += 0.5 * k * c * c;
        let s = force_scale(c, g, k, kd, v);
        let curvature = !self.project || (convex && c >= 0.0);
        for i in 0..N {
            for (fa, ga) in self.f[i].iter_mut().zip(g[i]) {
                *fa += s * ga;
            }
            for j in 0..N {
                let h = if curvature { hess(i, j) } else { [0.0; 9] };
                for a in 0..3 {
                    for b in 0..3 {
                        let gg = g[i][a] * g[j][b];
                        self.kx[i][j][3 * a + b] -= k * (gg + c * h[3 * a + b]);
                        self.kv[i][j][3 * a + b] -= kd * gg;
                    }
                }
            }
        }
    }
}

/// The force `f_i = s dC/dx_i` of a condition has `s = -k C - k_d dC/dt`.
#[inline]
fn force_scale<const N: usize>(
    c: f64,
    g: &[[f64; 3]; N],
    k: f64,
    kd: f64,
    v: &[[f64; 3]; N],
) -> f64 {
    let c_dot: f64 = (0..N).map(|j| dot(g[j], v[j])).sum();
    -k * c - kd * c_dot
}

/// Energy and forces of an element without its Jacobians: what explicit steps and energy
/// logs need.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElementForces<const N: usize> {
    /// Elastic energy (J).
    pub energy: f64,
    /// Force on each vertex (N).
    pub f: [[f64; 3]; N],
}

impl<const N: usize> ElementForces<N> {
    /// Zero energy and force.
    pub fn zero() -> Self {
        ElementForces {
            energy: 0.0,
            f: [[0.0; 3]; N],
        }
    }

    /// Adds one scalar condition `c` with gradient `g` (see [`ElementOut::add_condition`]).
    #[inline]
    pub fn add_condition(&mut self, c: f64, g: &[[f64; 3]; N], k: f64, kd: f64, v: &[[f64; 3]; N]) {
        self.energy += 0.5 * k * c * c;
        let s = force_scale(c, g, k, kd, v);
        for (fi, gi) in self.f.iter_mut().zip(g) {
            for (fa, ga) in fi.iter_mut().zip(gi) {
                *fa += s * ga;
            }
        }
    }
}

/// Where an element's conditions go: [`ElementOut`] (with Jacobians) or
/// [`ElementForces`] (the Hessian closure is then never called).
pub trait ConditionSink<const N: usize> {
    /// Adds condition `c` with gradient `g`, Hessian blocks `hess` (positive
    /// semi-definite when `convex`), stiffness `k` and damping `kd` at velocities `v`.
    #[allow(clippy::too_many_arguments)]
    fn condition(
        &mut self,
        c: f64,
        g: &[[f64; 3]; N],
        hess: &dyn Fn(usize, usize) -> [f64; 9],
        convex: bool,
        k: f64,
        kd: f64,
        v: &[[f64; 3]; N],
    );
}

impl<const N: usize> ConditionSink<N> for ElementOut<N> {
    fn condition(
        &mut self,
        c: f64,
        g: &[[f64; 3]; N],
        hess: &dyn Fn(usize, usize) -> [f64; 9],
        convex: bool,
        k: f64,
        kd: f64,
        v: &[[f64; 3]; N],
    ) {
        self.add_condition(c, g, hess, convex, k, kd, v);
    }
}

impl<const N: usize> ConditionSink<N> for ElementForces<N> {
    fn condition(
        &mut self,
        c: f64,
        g: &[[f64; 3]; N],
        _hess: &dyn Fn(usize, usize) -> [f64; 9],
        _convex: bool,
        k: f64,
        kd: f64,
        v: &[[f64; 3]; N],
    ) {
        self.add_condition(c, g, k, kd, v);
    }
}

/// Adds the stretch conditions of a triangle, `C = a (|w_u| - b[0], |w_v| - b[1])` with
/// stiffness `k` and damping `kd` (`b` the rest stretch, 1 for none), to `out`.
pub fn add_stretch<S: ConditionSink<3>>(
    out: &mut S,
    r: &TriangleRest,
    x: &[[f64; 3]; 3],
    v: &[[f64; 3]; 3],
    k: f64,
    kd: f64,
    b: [f64; 2],
) {
    let (wu, wv) = r.wuv(x);
    for (w, coef, rest) in [(wu, r.du, b[0]), (wv, r.dv, b[1])] {
        let len = dot(w, w).sqrt();
        // No direction (and NaN-safe): no force, no Jacobian.
        if len.is_nan() || len <= 0.0 {
            continue;
        }
        let n = w.map(|c| c / len);
        let a = r.area;
        let c = a * (len - rest);
        let g: [[f64; 3]; 3] = std::array::from_fn(|i| n.map(|nc| a * coef[i] * nc));
        let hess = |i: usize, j: usize| -> [f64; 9] {
            std::array::from_fn(|e| {
                let (p, q) = (e / 3, e % 3);
                let proj = (if p == q { 1.0 } else { 0.0 }) - n[p] * n[q];
                a * coef[i] * coef[j] * proj / len
            })
        };
        out.condition(c, &g, &hess, true, k, kd, v);
    }
}

/// Adds the shear condition of a triangle, `C = a w_u . w_v`, to `out`.
pub fn add_shear<S: ConditionSink<3>>(
    out: &mut S,
    r: &TriangleRest,
    x: &[[f64; 3]; 3],
    v: &[[f64; 3]; 3],
    k: f64,
    kd: f64,
) {
    let (wu, wv) = r.wuv(x);
    let a = r.area;
    let c = a * dot(wu, wv);
    let g: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|q| a * (r.du[i] * wv[q] + r.dv[i] * wu[q])));
    let hess = |i: usize, j: usize| -> [f64; 9] {
        let s = a * (r.du[i] * r.dv[j] + r.dv[i] * r.du[j]);
        [s, 0.0, 0.0, 0.0, s, 0.0, 0.0, 0.0, s]
    };
    out.condition(c, &g, &hess, false, k, kd, v);
}

/// The stretch element of a triangle with its Jacobians (see [`add_stretch`]).
pub fn stretch_element(
    r: &TriangleRest,
    x: &[[f64; 3]; 3],
    v: &[[f64; 3]; 3],
    k: f64,
    kd: f64,
    b: [f64; 2],
) -> ElementOut<3> {
    let mut out = ElementOut::zero();
    add_stretch(&mut out, r, x, v, k, kd, b);
    out
}

/// The shear element of a triangle with its Jacobians (see [`add_shear`]).
pub fn shear_element(
    r: &TriangleRest,
    x: &[[f64; 3]; 3],
    v: &[[f64; 3]; 3],
    k: f64,
    kd: f64,
) -> ElementOut<3> {
    let mut out = ElementOut::zero();
    add_shear(&mut out, r, x, v, k, kd);
    out
}

/// A number with one derivative (forward-mode automatic differentiation): `v + d eps`,
/// `eps^2 = 0`. Nested (`Dual<Dual<f64>>`) it carries second derivatives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual<T> {
    /// Value.
    pub v: T,
    /// Derivative along the seeded direction.
    pub d: T,
}

/// The arithmetic the dihedral angle needs, over `f64` and (nested) [`Dual`]s.
pub trait Scalar:
    Copy
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
{
    /// A constant.
    fn cst(c: f64) -> Self;
    /// Square root.
    fn sqrt(self) -> Self;
    /// `atan2(self, x)`.
    fn atan2(self, x: Self) -> Self;
}

impl Scalar for f64 {
    fn cst(c: f64) -> Self {
        c
    }
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    /// [`atan2_x4`] in lane 0: the scalar and SIMD hinge kernels share one `atan2`.
    fn atan2(self, x: Self) -> Self {
        atan2_x4(f64x4::splat(self), f64x4::splat(x)).to_array()[0]
    }
}

/// The `atan2` of the dihedral angle, lane by lane, for the scalar kernels (lane 0 of a
/// splat) and the SIMD ones alike, so that they agree to the bit: `wide`'s rational
/// approximation (Cephes, as in Agner Fog's vector class library). Measured against the
/// C library's `atan2` over 2e6 random arguments: at most 1.03 ulp apart, 4.4e-16 rad
/// absolute. The C library's took half the time of the SIMD hinge kernel, lane by lane.
#[inline(always)]
pub fn atan2_x4(y: f64x4, x: f64x4) -> f64x4 {
    y.atan2(x)
}

impl<T: Scalar> std::ops::Add for Dual<T> {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Dual {
            v: self.v + o.v,
            d: self.d + o.d,
        }
    }
}
impl<T: Scalar> std::ops::Sub for Dual<T> {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Dual {
            v: self.v - o.v,
            d: self.d - o.d,
        }
    }
}
impl<T: Scalar> std::ops::Mul for Dual<T> {
    type Output = Self;
    fn mul(self, o: Self) -> Self {
        Dual {
            v: self.v * o.v,
            d: self.d * o.v + self.v * o.d,
        }
    }
}
impl<T: Scalar> std::ops::Div for Dual<T> {
    type Output = Self;
    fn div(self, o: Self) -> Self {
        Dual {
            v: self.v / o.v,
            d: (self.d * o.v - self.v * o.d) / (o.v * o.v),
        }
    }
}
impl<T: Scalar> Scalar for Dual<T> {
    fn cst(c: f64) -> Self {
        Dual {
            v: T::cst(c),
            d: T::cst(0.0),
        }
    }
    fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        Dual {
            v: s,
            d: self.d / (T::cst(2.0) * s),
        }
    }
    fn atan2(self, x: Self) -> Self {
        // d atan2(y, x) = (x dy - y dx) / (x^2 + y^2)
        Dual {
            v: self.v.atan2(x.v),
            d: (x.v * self.d - self.v * x.d) / (x.v * x.v + self.v * self.v),
        }
    }
}

/// The dihedral angle (rad) of the hinge `x = [x0, x1, x2, x3]`: triangles (x0, x1, x2)
/// and (x1, x0, x3) share the edge x0-x1; with unit normals `n_a = (x1 - x0) x (x2 - x0)`
/// and `n_b = (x3 - x0) x (x1 - x0)` (normalised) and the unit edge `e`,
/// `theta = atan2((n_a x n_b) . e, n_a . n_b)` (course notes, section 3): 0 when flat,
/// signed, in (-pi, pi]. Degenerate triangles give NaN; callers check first.
pub fn dihedral_angle<T: Scalar>(x: &[[T; 3]; 4]) -> T {
    let sub = |a: [T; 3], b: [T; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross = |a: [T; 3], b: [T; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let dot = |a: [T; 3], b: [T; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let unit = |a: [T; 3]| {
        let l = dot(a, a).sqrt();
        [a[0] / l, a[1] / l, a[2] / l]
    };
    let e = sub(x[1], x[0]);
    let na = unit(cross(e, sub(x[2], x[0])));
    let nb = unit(cross(sub(x[3], x[0]), e));
    let s = dot(cross(na, nb), unit(e));
    let c = dot(na, nb);
    s.atan2(c)
}

/// Adds the bend condition of a hinge (see [`dihedral_angle`]), `C = theta - theta0`
/// with stiffness `k` (N m per rad^2) and damping `kd`, to `out`. The gradient is closed
/// form ([`bend_gradient`]); the Hessian of theta, needed only when `out` keeps curvature
/// terms, comes from forward-mode automatic differentiation ([`Dual`], nested for second
/// derivatives), exact to rounding at 78 evaluations of the angle: the reference a closed
/// form (Tamstorf and Grinspun, "Discrete bending forces and their Jacobians", 2013) could
/// replace. Returns `false` (and adds nothing) when a triangle of the hinge is degenerate
/// (no normal).
pub fn add_bend<S: ConditionSink<4>>(
    out: &mut S,
    x: &[[f64; 3]; 4],
    v: &[[f64; 3]; 4],
    k: f64,
    kd: f64,
    theta0: f64,
) -> bool {
    let Some((theta, g)) = bend_gradient(x) else {
        return false;
    };
    let hessian = std::cell::OnceCell::new();
    let hess = |i: usize, j: usize| -> [f64; 9] {
        let h = hessian.get_or_init(|| angle_hessian(x));
        std::array::from_fn(|e| h[3 * i + e / 3][3 * j + e % 3])
    };
    out.condition(theta - theta0, &g, &hess, false, k, kd, v);
    true
}

/// The bend element of a hinge with its exact Jacobians (see [`add_bend`]); `None` when a
/// triangle of the hinge is degenerate.
pub fn bend_element(
    x: &[[f64; 3]; 4],
    v: &[[f64; 3]; 4],
    k: f64,
    kd: f64,
    theta0: f64,
) -> Option<ElementOut<4>> {
    let mut out = ElementOut::zero();
    add_bend(&mut out, x, v, k, kd, theta0).then_some(out)
}

/// `d2 theta / dx_p dx_q` (12 x 12) by seeding p in the outer and q in the inner dual;
/// symmetric, so only p <= q are evaluated and mirrored.
fn angle_hessian(x: &[[f64; 3]; 4]) -> [[f64; 12]; 12] {
    let mut h = [[0.0f64; 12]; 12];
    #[allow(clippy::needless_range_loop)]
    for p in 0..12 {
        for q in p..12 {
            let xs: [[Dual<Dual<f64>>; 3]; 4] = std::array::from_fn(|i| {
                std::array::from_fn(|c| {
                    let var = 3 * i + c;
                    Dual {
                        v: Dual {
                            v: x[i][c],
                            d: if var == q { 1.0 } else { 0.0 },
                        },
                        d: Dual {
                            v: if var == p { 1.0 } else { 0.0 },
                            d: 0.0,
                        },
                    }
                })
            });
            let hpq = dihedral_angle(&xs).d.d;
            h[p][q] = hpq;
            h[q][p] = hpq;
        }
    }
    h
}

/// The dihedral angle of a hinge and its gradient, closed form (Bridson, Marino and Fedkiw
/// 2003, section 4.1, in this hinge's orientation): with the edge `e = x1 - x0`, the
/// triangles' unit normals `n_a`, `n_b` and heights `h_a`, `h_b` of x2 and x3 over the
/// edge, and `alpha_a = (x2 - x0) . e / |e|^2` (likewise `alpha_b`),
///
/// ```text
/// dtheta/dx2 = -n_a / h_a,   dtheta/dx3 = -n_b / h_b,
/// dtheta/dx0 = -(1 - alpha_a) dtheta/dx2 - (1 - alpha_b) dtheta/dx3,
/// dtheta/dx1 = -alpha_a dtheta/dx2 - alpha_b dtheta/dx3
/// ```
///
/// (moving an opposite vertex along its normal by `delta` turns that face by
/// `delta / h`; the edge vertices' terms make the gradient translation and rotation
/// invariant). Tested against automatic differentiation. `None` for a degenerate hinge.
pub fn bend_gradient(x: &[[f64; 3]; 4]) -> Option<(f64, [[f64; 3]; 4])> {
    let theta = dihedral_angle(x);
    if !theta.is_finite() {
        return None;
    }
    let e = sub(x[1], x[0]);
    let ee = dot(e, e);
    let na = cross(e, sub(x[2], x[0]));
    let nb = cross(sub(x[3], x[0]), e);
    // |n| = 2 area = h |e|, so n_unit / h = n |e| / |n|^2.
    let (la, lb) = (dot(na, na), dot(nb, nb));
    if !(la > 0.0 && lb > 0.0 && ee > 0.0) {
        return None;
    }
    let el = ee.sqrt();
    let g2 = na.map(|c| -c * el / la);
    let g3 = nb.map(|c| -c * el / lb);
    let aa = dot(sub(x[2], x[0]), e) / ee;
    let ab = dot(sub(x[3], x[0]), e) / ee;
    let g0 = std::array::from_fn(|c| -(1.0 - aa) * g2[c] - (1.0 - ab) * g3[c]);
    let g1 = std::array::from_fn(|c| -aa * g2[c] - ab * g3[c]);
    Some((theta, [g0, g1, g2, g3]))
}

/// The gradient of the dihedral angle by forward-mode automatic differentiation (12
/// evaluations of the angle): the reference [`bend_gradient`] is tested against.
pub fn bend_gradient_ad(x: &[[f64; 3]; 4]) -> Option<(f64, [[f64; 3]; 4])> {
    let theta = dihedral_angle(x);
    if !theta.is_finite() {
        return None;
    }
    let mut g = [[0.0; 3]; 4];
    for var in 0..12 {
        let xs: [[Dual<f64>; 3]; 4] = std::array::from_fn(|i| {
            std::array::from_fn(|c| Dual {
                v: x[i][c],
                d: if 3 * i + c == var { 1.0 } else { 0.0 },
            })
        });
        g[var / 3][var % 3] = dihedral_angle(&xs).d;
    }
    Some((theta, g))
}

/// Stretch and shear constants of a triangle for [`triangle_jacobians`]: element
/// stiffnesses and dampings (as given to [`add_stretch`] and [`add_shear`]) and the rest
/// stretch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleParams {
    /// Stretch stiffness.
    pub stretch: f64,
    /// Stretch damping.
    pub stretch_damping: f64,
    /// Shear stiffness.
    pub shear: f64,
    /// Shear damping.
    pub shear_damping: f64,
    /// Rest stretch `(b_u, b_v)`.
    pub rest_stretch: [f64; 2],
    /// Drop indefinite curvature terms ([`ElementOut`]'s `project`).
    pub project: bool,
}

/// A 3x3 matrix, row-major.
type M3 = [f64; 9];

fn outer(a: [f64; 3], b: [f64; 3], s: f64, m: &mut M3) {
    for r in 0..3 {
        for c in 0..3 {
            m[3 * r + c] += s * a[r] * b[c];
        }
    }
}

/// A triangle's stretch and shear conditions with their Jacobians in closed form, the
/// same quantities [`add_stretch`] plus [`add_shear`] give an [`ElementOut`] (tested
/// equal), at a fraction of the work. Every condition's gradient is `g_i = du_i p + dv_i
/// q` for two 3-vectors `p`, `q` (stretch u: `p = a n_u`, `q = 0`; shear: `p = a w_v`,
/// `q = a w_u`) and its curvature `C d2C` is `du_i du_j`, `dv_i dv_j` or `du_i dv_j`
/// times a fixed 3x3 matrix, so every 3x3 block of either Jacobian is
///
/// ```text
/// K_ij = du_i du_j A + dv_i dv_j B + du_i dv_j M + dv_i du_j M^T
/// ```
///
/// with `A`, `B`, `M` summed once per triangle over its three conditions. Writes the
/// energy's share (returned), the forces `f` (3 vertices x 3) and the upper blocks (p <=
/// q, rows of the symmetric layout: (0,0) (0,1) (0,2) (1,1) (1,2) (2,2)) of `df/dx` into
/// `kx` and of `df/dv` into `kv` (54 values each; `kv` may be `None`).
pub fn triangle_jacobians(
    r: &TriangleRest,
    x: &[[f64; 3]; 3],
    v: &[[f64; 3]; 3],
    p: &TriangleParams,
    f: &mut [f64],
    kx: &mut [f64],
    kv: Option<&mut [f64]>,
) -> f64 {
    let a = r.area;
    let (wu, wv) = r.wuv(x);
    let (wu_dot, wv_dot) = r.wuv(v);
    let (mut ka, mut kb, mut km) = ([0.0; 9], [0.0; 9], [0.0; 9]);
    let (mut da, mut db, mut dm) = ([0.0; 9], [0.0; 9], [0.0; 9]);
    // Force f_i = du_i fu + dv_i fv.
    let (mut fu, mut fv) = ([0.0; 3], [0.0; 3]);
    let mut energy = 0.0;
    // Stretch along u and v: C = a (|w| - b), g_i = a coef_i n.
    for (w, w_dot, b, kmat, dmat, fdir) in [
        (wu, wu_dot, p.rest_stretch[0], &mut ka, &mut da, &mut fu),
        (wv, wv_dot, p.rest_stretch[1], &mut kb, &mut db, &mut fv),
    ] {
        let len = dot(w, w).sqrt();
        if len.is_nan() || len <= 0.0 {
            continue;
        }
        let n = w.map(|c| c / len);
        let c = a * (len - b);
        let c_dot = a * dot(n, w_dot);
        energy += 0.5 * p.stretch * c * c;
        let s = -p.stretch * c - p.stretch_damping * c_dot;
        for k in 0..3 {
            fdir[k] += s * a * n[k];
        }
        outer(n, n, -p.stretch * a * a, kmat);
        outer(n, n, -p.stretch_damping * a * a, dmat);
        if !p.project || c >= 0.0 {
            // -k C a (I - n n^T) / |w|
            let s = -p.stretch * c * a / len;
            for k in 0..3 {
                kmat[4 * k] += s;
            }
            outer(n, n, -s, kmat);
        }
    }
    // Shear: C = a w_u . w_v, g_i = du_i (a w_v) + dv_i (a w_u).
    {
        let c = a * dot(wu, wv);
        let c_dot = a * (dot(wu_dot, wv) + dot(wu, wv_dot));
        energy += 0.5 * p.shear * c * c;
        let s = -p.shear * c - p.shear_damping * c_dot;
        for k in 0..3 {
            fu[k] += s * a * wv[k];
            fv[k] += s * a * wu[k];
        }
        let (k2, d2) = (-p.shear * a * a, -p.shear_damping * a * a);
        outer(wv, wv, k2, &mut ka);
        outer(wu, wu, k2, &mut kb);
        outer(wv, wu, k2, &mut km);
        outer(wv, wv, d2, &mut da);
        outer(wu, wu, d2, &mut db);
        outer(wv, wu, d2, &mut dm);
        if !p.project {
            // -k C a (du_i dv_j + dv_i du_j) I: the identity goes into M (and M^T).
            for k in 0..3 {
                km[4 * k] -= p.shear * c * a;
            }
        }
    }
    for i in 0..3 {
        for k in 0..3 {
            f[3 * i + k] = r.du[i] * fu[k] + r.dv[i] * fv[k];
        }
    }
    let blocks = |out: &mut [f64], a: &M3, b: &M3, m: &M3| {
        let mut slot = 0;
        for i in 0..3 {
            for j in i..3 {
                let (uu, vv) = (r.du[i] * r.du[j], r.dv[i] * r.dv[j]);
                let (uv, vu) = (r.du[i] * r.dv[j], r.dv[i] * r.du[j]);
                let o = &mut out[9 * slot..9 * slot + 9];
                for rr in 0..3 {
                    for cc in 0..3 {
                        let e = 3 * rr + cc;
                        o[e] = uu * a[e] + vv * b[e] + uv * m[e] + vu * m[3 * cc + rr];
                    }
                }
                slot += 1;
            }
        }
    };
    blocks(kx, &ka, &kb, &km);
    if let Some(kv) = kv {
        blocks(kv, &da, &db, &dm);
    }
    energy
}

/// [`triangle_jacobians`] for four triangles at once, one per `f64x4` lane: SIMD over
/// elements. One triangle's work is 3-vectors and 3x3 matrices, too narrow and too
/// branchy to fill a vector, but four triangles do the same operations side by side, so
/// each lane does what the scalar twin does for its triangle. The twin's branches become
/// lane masks (`bitselect`): a stretch direction of zero or NaN length leaves its lane's
/// sums as they were (that component contributes nothing), each lane's `project` picks
/// its own curvature terms, and whatever the masked-off arithmetic makes (a division by
/// a zero length) never leaves its lane. Triangles and parameters may differ per lane.
///
/// Same layout as four consecutive [`triangle_jacobians`] calls: `f` holds 4 x 9 forces,
/// `kx` and `kv` (optional) 4 x 54 upper-block values, triangle after triangle; returns
/// the four energies (J). Tested equal to [`triangle_jacobians`] on random stretched and
/// compressed triangles with mixed `project`, with zero-length and NaN lanes (within
/// 1e-12 relative; the lanes repeat the twin's operations in its order without fused
/// multiply-adds, and the values have agreed to the bit). Unlike the twin it forms
/// `df/dv` only when `kv` is given. Measured on one core, gathers included: over 968
/// triangles (output in cache) it took 0.8 of the twin's time, 0.7 without `kv`; over
/// the 19,600 triangles of a 100x100 sheet both are limited by writing the 936 bytes of
/// output per triangle (1.4 ms each, `cloth/kernel/triangles` in benches/cloth.rs), and
/// inside the 2-thread cloth assembly it took 1.5 ms against the twin's 0.9, so the
/// cloth uses the twin. Kept as the measured alternative for machines or meshes where
/// the output stays in cache.
pub fn triangle_jacobians_x4(
    r: &[TriangleRest; 4],
    x: &[[[f64; 3]; 3]; 4],
    v: &[[[f64; 3]; 3]; 4],
    p: &[TriangleParams; 4],
    f: &mut [f64],
    kx: &mut [f64],
    kv: Option<&mut [f64]>,
) -> [f64; 4] {
    let kv_len = kv.as_ref().map_or(216, |kv| kv.len());
    assert!(
        f.len() >= 36 && kx.len() >= 216 && kv_len >= 216,
        "four triangles' outputs"
    );
    let a = lanes(|l| r[l].area);
    let du: [f64x4; 3] = std::array::from_fn(|i| lanes(|l| r[l].du[i]));
    let dv: [f64x4; 3] = std::array::from_fn(|i| lanes(|l| r[l].dv[i]));
    // (w_u, w_v) as in `TriangleRest::wuv`, term by term.
    let wuv = |y: &[[[f64; 3]; 3]; 4]| {
        let y: [[f64x4; 3]; 3] =
            std::array::from_fn(|i| std::array::from_fn(|c| lanes(|l| y[l][i][c])));
        let w = |coef: &[f64x4; 3]| -> [f64x4; 3] {
            std::array::from_fn(|c| coef[0] * y[0][c] + coef[1] * y[1][c] + coef[2] * y[2][c])
        };
        (w(&du), w(&dv))
    };
    let (wu, wv) = wuv(x);
    let (wu_dot, wv_dot) = wuv(v);
    let k_st = lanes(|l| p[l].stretch);
    let kd_st = lanes(|l| p[l].stretch_damping);
    let k_sh = lanes(|l| p[l].shear);
    let kd_sh = lanes(|l| p[l].shear_damping);
    // All ones in the lanes whose triangle keeps its curvature terms (`!project`).
    let exact = lanes(|l| if p[l].project { 0.0 } else { 1.0 }).simd_gt(f64x4::ZERO);
    let z = f64x4::ZERO;
    // Forces, energy and df/dx first; df/dv at the end, only if asked for, from the
    // stretch directions kept here. Each matrix gets the twin's terms in the twin's order.
    let (mut ka, mut kb, mut km) = ([z; 9], [z; 9], [z; 9]);
    let (mut fu, mut fv) = ([z; 3], [z; 3]);
    let mut energy = z;
    // Per stretch direction: whether it has one (`live`) and the unit vector.
    let (mut dir_u, mut dir_v) = ((z, [z; 3]), (z, [z; 3]));
    for (w, w_dot, b, kmat, fdir, dir) in [
        (
            wu,
            wu_dot,
            lanes(|l| p[l].rest_stretch[0]),
            &mut ka,
            &mut fu,
            &mut dir_u,
        ),
        (
            wv,
            wv_dot,
            lanes(|l| p[l].rest_stretch[1]),
            &mut kb,
            &mut fv,
            &mut dir_v,
        ),
    ] {
        let len = dot_x4(w, w).sqrt();
        // False for a zero or NaN length: the lane keeps what it had, as the twin's
        // `continue`. The lane's n, c, ... may be inf or NaN; they are discarded.
        let live = len.simd_gt(z);
        let n = w.map(|c| c / len);
        *dir = (live, n);
        let c = a * (len - b);
        let c_dot = a * dot_x4(n, w_dot);
        let (mut e2, mut k2, mut f2) = (energy, *kmat, *fdir);
        e2 += f64x4::splat(0.5) * k_st * c * c;
        let s = -k_st * c - kd_st * c_dot;
        for k in 0..3 {
            f2[k] += s * a * n[k];
        }
        outer_x4(n, n, -k_st * a * a, &mut k2);
        // -k C a (I - n n^T) / |w|, where `!project || c >= 0`.
        let curved = exact | c.simd_ge(z);
        let s = -k_st * c * a / len;
        let mut k3 = k2;
        for k in 0..3 {
            k3[4 * k] += s;
        }
        outer_x4(n, n, -s, &mut k3);
        k2 = select_x4(curved, k3, k2);
        energy = live.bitselect(e2, energy);
        *kmat = select_x4(live, k2, *kmat);
        *fdir = select_x4(live, f2, *fdir);
    }
    // Shear: C = a w_u . w_v, g_i = du_i (a w_v) + dv_i (a w_u).
    let c = a * dot_x4(wu, wv);
    let c_dot = a * (dot_x4(wu_dot, wv) + dot_x4(wu, wv_dot));
    energy += f64x4::splat(0.5) * k_sh * c * c;
    let s = -k_sh * c - kd_sh * c_dot;
    for k in 0..3 {
        fu[k] += s * a * wv[k];
        fv[k] += s * a * wu[k];
    }
    let k2 = -k_sh * a * a;
    outer_x4(wv, wv, k2, &mut ka);
    outer_x4(wu, wu, k2, &mut kb);
    outer_x4(wv, wu, k2, &mut km);
    // The identity term only where `!project`.
    for k in 0..3 {
        km[4 * k] = exact.bitselect(km[4 * k] - k_sh * c * a, km[4 * k]);
    }
    let fo: [f64x4; 9] = std::array::from_fn(|e| {
        let (i, k) = (e / 3, e % 3);
        du[i] * fu[k] + dv[i] * fv[k]
    });
    scatter_lanes::<9>(&fo, f);
    write_blocks_x4(&du, &dv, &ka, &kb, &km, kx);
    if let Some(kv) = kv {
        // df/dv: the stretch directions' -k_d a^2 n n^T (where they have one), then the
        // shear's, as the twin adds them.
        let stretch_d = |(live, n): (f64x4, [f64x4; 3])| {
            let mut d = [z; 9];
            outer_x4(n, n, -kd_st * a * a, &mut d);
            select_x4(live, d, [z; 9])
        };
        let (mut da, mut db, mut dm) = (stretch_d(dir_u), stretch_d(dir_v), [z; 9]);
        let d2 = -kd_sh * a * a;
        outer_x4(wv, wv, d2, &mut da);
        outer_x4(wu, wu, d2, &mut db);
        outer_x4(wv, wu, d2, &mut dm);
        write_blocks_x4(&du, &dv, &da, &db, &dm, kv);
    }
    energy.to_array()
}

/// Lane l from `g(l)`: one value of each of the four triangles.
#[inline(always)]
fn lanes(g: impl Fn(usize) -> f64) -> f64x4 {
    f64x4::new([g(0), g(1), g(2), g(3)])
}

/// A 3x3 matrix per lane, row-major.
type M3x4 = [f64x4; 9];

#[inline(always)]
fn dot_x4(a: [f64x4; 3], b: [f64x4; 3]) -> f64x4 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `m += s a b^T` per lane, as `outer`.
#[inline(always)]
fn outer_x4(a: [f64x4; 3], b: [f64x4; 3], s: f64x4, m: &mut M3x4) {
    for r in 0..3 {
        for c in 0..3 {
            m[3 * r + c] += s * a[r] * b[c];
        }
    }
}

/// `if_one` in the lanes where `mask` is all ones, `if_zero` elsewhere.
#[inline(always)]
fn select_x4<const N: usize>(mask: f64x4, if_one: [f64x4; N], if_zero: [f64x4; N]) -> [f64x4; N] {
    std::array::from_fn(|i| mask.bitselect(if_one[i], if_zero[i]))
}

/// Writes the upper blocks `K_ij = du_i du_j A + dv_i dv_j B + du_i dv_j M + dv_i du_j
/// M^T`, (0,0) (0,1) (0,2) (1,1) (1,2) (2,2), entry by entry as in [`triangle_jacobians`],
/// each lane's 54 values after the previous lane's. Written out so that every index is a
/// constant (one loop over the 54 entries stayed a loop with computed indices, and the
/// kernel took 1.5x as long), and each block scattered as soon as it is formed: forming
/// all 54 vectors first spilled them to the stack.
#[inline(always)]
fn write_blocks_x4(
    du: &[f64x4; 3],
    dv: &[f64x4; 3],
    a: &M3x4,
    b: &M3x4,
    m: &M3x4,
    out: &mut [f64],
) {
    let block = |i: usize, j: usize| -> [f64x4; 9] {
        let (uu, vv) = (du[i] * du[j], dv[i] * dv[j]);
        let (uv, vu) = (du[i] * dv[j], dv[i] * du[j]);
        let e = |rr: usize, cc: usize| {
            let e = 3 * rr + cc;
            uu * a[e] + vv * b[e] + uv * m[e] + vu * m[3 * cc + rr]
        };
        [
            e(0, 0),
            e(0, 1),
            e(0, 2),
            e(1, 0),
            e(1, 1),
            e(1, 2),
            e(2, 0),
            e(2, 1),
            e(2, 2),
        ]
    };
    scatter_lanes_at::<9>(&block(0, 0), out, 54, 0);
    scatter_lanes_at::<9>(&block(0, 1), out, 54, 9);
    scatter_lanes_at::<9>(&block(0, 2), out, 54, 18);
    scatter_lanes_at::<9>(&block(1, 1), out, 54, 27);
    scatter_lanes_at::<9>(&block(1, 2), out, 54, 36);
    scatter_lanes_at::<9>(&block(2, 2), out, 54, 45);
}

/// Writes N values of four lanes lane after lane: lane l's value j to `out[N l + j]`.
#[inline(always)]
fn scatter_lanes<const N: usize>(vals: &[f64x4], out: &mut [f64]) {
    scatter_lanes_at::<N>(vals, out, N, 0);
}

/// Writes N values of four lanes: lane l's value j to `out[stride l + offset + j]`. Four
/// values at a time go through a 4x4 transpose and leave as whole vectors.
#[inline(always)]
fn scatter_lanes_at<const N: usize>(vals: &[f64x4], out: &mut [f64], stride: usize, offset: usize) {
    let vals = &vals[..N];
    let (o0, rest) = out.split_at_mut(stride);
    let (o1, rest) = rest.split_at_mut(stride);
    let (o2, o3) = rest.split_at_mut(stride);
    let mut outs = [
        &mut o0[offset..offset + N],
        &mut o1[offset..offset + N],
        &mut o2[offset..offset + N],
        &mut o3[offset..offset + N],
    ];
    for q in 0..N / 4 {
        let j = 4 * q;
        let t = f64x4::transpose([vals[j], vals[j + 1], vals[j + 2], vals[j + 3]]);
        for (o, tl) in outs.iter_mut().zip(t) {
            st(&mut o[j..j + 4], tl);
        }
    }
    for j in N / 4 * 4..N {
        for (o, c) in outs.iter_mut().zip(vals[j].to_array()) {
            o[j] = c;
        }
    }
}

/// The bend element of a hinge with projected Jacobians (curvature dropped, see
/// [`ElementOut`]'s `project`), written straight into buffers: `df/dx = -k g g^T` and
/// `df/dv = -k_d g g^T` with `g` the closed-form angle gradient ([`bend_gradient`]), so no
/// 12 x 12 matrix is formed. Writes the forces `f` (4 vertices x 3) and the upper blocks
/// (p <= q, row by row: 10 blocks, 90 values) of `kx` and, if given, `kv`; returns the
/// energy. A degenerate hinge writes zeros and returns 0. Tested equal to [`add_bend`]
/// into a projecting [`ElementOut`].
///
/// `decouple`: move the coupling of the two opposite vertices (x2, x3) onto their
/// diagonal blocks, `K'' = -k g g^T - k (E2 g2 - E3 g3)(E2 g2 - E3 g3)^T` (E_i puts a
/// vertex's 3-vector in its place): the (2, 3) blocks cancel, so the matrix needs only
/// the triangles' pattern (7 blocks per row on a regular mesh instead of 13: half the
/// traffic of every PCG product), and the sum of two negative semi-definite terms stays
/// negative semi-definite. The forces are unchanged; the Jacobian is then an
/// approximation, stiffer in the mode where x2 and x3 move against each other, which the
/// implicit step damps a little more.
#[allow(clippy::too_many_arguments)] // the hinge's state, constants and outputs
pub fn bend_jacobians_projected(
    x: &[[f64; 3]; 4],
    v: &[[f64; 3]; 4],
    k: f64,
    kd: f64,
    theta0: f64,
    decouple: bool,
    f: &mut [f64],
    kx: &mut [f64],
    kv: Option<&mut [f64]>,
) -> f64 {
    let mut flat = [0.0; 12];
    let energy = bend_force_gradient(x, v, k, kd, theta0, f, &mut flat);
    let g: [[f64; 3]; 4] =
        core::array::from_fn(|i| [flat[3 * i], flat[3 * i + 1], flat[3 * i + 2]]);
    let write = |out: &mut [f64], scale: f64| {
        let mut slot = 0;
        for i in 0..4 {
            for j in i..4 {
                let w = if decouple {
                    decoupled_hinge_weight(i, j)
                } else {
                    1.0
                };
                for a in 0..3 {
                    for b in 0..3 {
                        out[9 * slot + 3 * a + b] = -w * scale * g[i][a] * g[j][b];
                    }
                }
                slot += 1;
            }
        }
    };
    write(kx, k);
    if let Some(kv) = kv {
        write(kv, kd);
    }
    energy
}

/// The weight of local block `(p, q)` in a decoupled hinge's Jacobian `-k w_pq g_p g_q^T`
/// (see `decouple` in [`bend_jacobians_projected`]): 0 between the opposite vertices 2
/// and 3, 2 on their diagonal blocks, 1 elsewhere.
pub fn decoupled_hinge_weight(p: usize, q: usize) -> f64 {
    match (p, q) {
        (2, 3) | (3, 2) => 0.0,
        (2, 2) | (3, 3) => 2.0,
        _ => 1.0,
    }
}

/// A hinge's bend forces `f` (4 vertices x 3) and its angle gradient `g` (12 values), from
/// which its projected Jacobians are `df/dx = -k g g^T` and `df/dv = -k_d g g^T` (see
/// [`bend_jacobians_projected`], which forms their blocks). The assembler can form them
/// itself from `g` (`largestep::sparse::RankOneAssembly`): 12 values per hinge to write
/// and read instead of 90. Returns the energy; a degenerate hinge writes zeros and
/// returns 0.
pub fn bend_force_gradient(
    x: &[[f64; 3]; 4],
    v: &[[f64; 3]; 4],
    k: f64,
    kd: f64,
    theta0: f64,
    f: &mut [f64],
    g_out: &mut [f64],
) -> f64 {
    assert!(f.len() >= 12 && g_out.len() >= 12);
    let Some((theta, g)) = bend_gradient(x) else {
        f[..12].fill(0.0);
        g_out[..12].fill(0.0);
        return 0.0;
    };
    let c = theta - theta0;
    let s = force_scale(c, &g, k, kd, v);
    for i in 0..4 {
        for a in 0..3 {
            f[3 * i + a] = s * g[i][a];
            g_out[3 * i + a] = g[i][a];
        }
    }
    0.5 * k * c * c
}

/// [`bend_force_gradient`] for four hinges at once, one per `f64x4` lane: SIMD over
/// elements, as [`triangle_jacobians_x4`] is for triangles. Each lane repeats the scalar
/// kernel's operations in its order ([`dihedral_angle`], then [`bend_gradient`] and the
/// force scale, the angle's `atan2` too ([`atan2_x4`])), so the lanes give the scalar
/// kernel's values to the bit. A degenerate or NaN hinge (the scalar
/// kernel's `None`) writes zeros in its lane and its energy is 0, whatever its neighbours.
///
/// Same layout as four consecutive [`bend_force_gradient`] calls: `f` and `g_out` hold
/// 4 x 12 values, hinge after hinge; `theta0` holds the four rest angles (rad); returns
/// the four energies (J). Tested equal to [`bend_force_gradient`] on random hinges and
/// on degenerate and NaN lanes.
#[allow(clippy::too_many_arguments)] // as `bend_force_gradient`, four times over
pub fn bend_force_gradient_x4(
    x: &[[[f64; 3]; 4]; 4],
    v: &[[[f64; 3]; 4]; 4],
    k: f64,
    kd: f64,
    theta0: [f64; 4],
    f: &mut [f64],
    g_out: &mut [f64],
) -> [f64; 4] {
    assert!(f.len() >= 48 && g_out.len() >= 48, "four hinges' outputs");
    let node = |y: &[[[f64; 3]; 4]; 4], i: usize| -> [f64x4; 3] {
        std::array::from_fn(|c| lanes(|l| y[l][i][c]))
    };
    let xs: [[f64x4; 3]; 4] = std::array::from_fn(|i| node(x, i));
    let sub = |a: [f64x4; 3], b: [f64x4; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    // `dihedral_angle`: unit normals and edge, sine and cosine of the angle.
    let e = sub(xs[1], xs[0]);
    let (d2, d3) = (sub(xs[2], xs[0]), sub(xs[3], xs[0]));
    let na = cross_x4(e, d2);
    let nb = cross_x4(d3, e);
    let (ee, la, lb) = (dot_x4(e, e), dot_x4(na, na), dot_x4(nb, nb));
    let (el, la_len, lb_len) = (ee.sqrt(), la.sqrt(), lb.sqrt());
    let na_unit = na.map(|c| c / la_len);
    let nb_unit = nb.map(|c| c / lb_len);
    let e_unit = e.map(|c| c / el);
    let s = dot_x4(cross_x4(na_unit, nb_unit), e_unit);
    let c = dot_x4(na_unit, nb_unit);
    let theta = atan2_x4(s, c);
    // The scalar kernel's `None`: a non-finite angle, or no normal or edge.
    let z = f64x4::ZERO;
    let live = theta.is_finite() & la.simd_gt(z) & lb.simd_gt(z) & ee.simd_gt(z);
    // `bend_gradient`: n_unit / h = n |e| / |n|^2 for the opposite vertices.
    let g2 = na.map(|c| -c * el / la);
    let g3 = nb.map(|c| -c * el / lb);
    let aa = dot_x4(d2, e) / ee;
    let ab = dot_x4(d3, e) / ee;
    let one = f64x4::ONE;
    let g0: [f64x4; 3] = std::array::from_fn(|c| -(one - aa) * g2[c] - (one - ab) * g3[c]);
    let g1: [f64x4; 3] = std::array::from_fn(|c| -aa * g2[c] - ab * g3[c]);
    let g = [g0, g1, g2, g3];
    // The force scale `-k C - k_d dC/dt`, dC/dt summed vertex by vertex as `force_scale`.
    let cond = theta - f64x4::new(theta0);
    let mut c_dot = dot_x4(g[0], node(v, 0));
    for (gi, i) in g.iter().zip(0..).skip(1) {
        c_dot += dot_x4(*gi, node(v, i));
    }
    let (k, kd) = (f64x4::splat(k), f64x4::splat(kd));
    let scale = -k * cond - kd * c_dot;
    // Dead lanes may hold NaN or inf anywhere: zeros replace them.
    let gl: [f64x4; 12] = std::array::from_fn(|e| live.bitselect(g[e / 3][e % 3], z));
    let fl: [f64x4; 12] = std::array::from_fn(|e| live.bitselect(scale * g[e / 3][e % 3], z));
    scatter_lanes::<12>(&fl, f);
    scatter_lanes::<12>(&gl, g_out);
    live.bitselect(f64x4::splat(0.5) * k * cond * cond, z)
        .to_array()
}

#[inline(always)]
fn cross_x4(a: [f64x4; 3], b: [f64x4; 3]) -> [f64x4; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
