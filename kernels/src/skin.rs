//! Skinning kernels over f32 structure-of-arrays vertices: linear blend skinning (LBS)
//! and dual quaternion skinning (DQS, Kavan, Collins, Zara and O'Sullivan 2007).
//!
//! **Data.** Positions and normals are component-major (`[x.., y.., z..]`, 3n, f32);
//! each vertex has four influences, `joints[v]` (u16 indices into the skinning
//! matrices) and `weights[v]` (summing to 1; unused slots have weight 0). A skinning
//! matrix is a joint's model transform times the inverse of its bind transform, stored
//! as four f32 columns ([`SkinMatrix`], ozz-animation's `float4x4` layout), so one SIMD
//! register holds a column.
//!
//! **LBS**: `p' = (sum_k w_k M_k) p`, with four-wide multiply-adds over a matrix's
//! columns; normals go through the blended matrix's linear part and are **not**
//! renormalised (as ozz-animation's `SkinningJob`: blended normals are shorter than one
//! where joints disagree, and a renderer normalises after interpolating them anyway;
//! exact in direction for rigid and uniformly scaled joints). Under twist the blended
//! matrix loses rank and the mesh collapses (the candy wrapper).
//!
//! **DQS**: each rigid skinning matrix becomes a unit dual quaternion
//! `q_r + eps q_d`, `q_d = 1/2 (0, t) q_r` ([`dual_quaternions`]); a vertex blends them
//! with signs that put every real part in the first one's hemisphere, divides by the
//! real part's norm, and applies the rigid transform
//! `p' = p + 2 r x (r x p + w p) + 2 (w d - d_w r + r x d)` (`(w, r)` the real part,
//! `(d_w, d)` the dual). The blend of rotations stays a rotation, so volume is kept
//! under twist; scale is not represented (joints must be rigid).
//!
//! Every SIMD kernel has a scalar twin (`_scalar`) held to it by property tests, and a
//! parallel driver (`_par`) over fixed chunks of [`crate::PAR_CHUNK`] vertices.

use crate::par::{chunk_count, chunk_range, components, par_reduce, Disjoint};
use crate::PAR_CHUNK;
use wide::{f32x4, f32x8};

/// Four f32 columns of an affine 4x4 matrix (the last row `0 0 0 1`): `m[c][r]`.
pub type SkinMatrix = [[f32; 4]; 4];

/// A unit dual quaternion as `[w, x, y, z, dw, dx, dy, dz]` (real part, then dual part).
pub type DualQuat = [f32; 8];

/// The vertices to skin: component-major positions (3n) and normals (3n, or empty for
/// none), and four influences per vertex.
#[derive(Clone, Copy, Debug)]
pub struct SkinInput<'a> {
    /// Rest positions, component-major.
    pub positions: &'a [f32],
    /// Rest normals, component-major, or empty.
    pub normals: &'a [f32],
    /// Joint indices of the four influences.
    pub joints: &'a [[u16; 4]],
    /// Their weights.
    pub weights: &'a [[f32; 4]],
}

impl SkinInput<'_> {
    /// The number of vertices, after checking the lengths agree (panics otherwise: a
    /// kernel's precondition).
    fn len(&self) -> usize {
        let n = self.joints.len();
        assert_eq!(self.positions.len(), 3 * n, "positions are 3n");
        assert!(
            self.normals.is_empty() || self.normals.len() == 3 * n,
            "normals are 3n or none"
        );
        assert_eq!(self.weights.len(), n, "one weight set per vertex");
        n
    }
}

/// The skinning matrix of an affine transform given as rows of `[R | t]` (f64, as
/// forward kinematics writes them).
pub fn skin_matrix(a: &crate::anim::Affine) -> SkinMatrix {
    let m = |r: usize, c: usize| a[4 * r + c] as f32;
    [
        [m(0, 0), m(1, 0), m(2, 0), 0.0],
        [m(0, 1), m(1, 1), m(2, 1), 0.0],
        [m(0, 2), m(1, 2), m(2, 2), 0.0],
        [m(0, 3), m(1, 3), m(2, 3), 1.0],
    ]
}

/// The dual quaternion of each rigid skinning matrix (its rotation by Shepperd's method,
/// in f64).
pub fn dual_quaternions(out: &mut [DualQuat], matrices: &[SkinMatrix]) {
    assert_eq!(out.len(), matrices.len(), "one dual quaternion per matrix");
    for (o, m) in out.iter_mut().zip(matrices) {
        let r = [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[j][i] as f64));
        let q = crate::quat::from_matrix(r);
        let t = [m[3][0] as f64, m[3][1] as f64, m[3][2] as f64];
        let d = crate::quat::mul([0.0, t[0], t[1], t[2]], q).map(|c| 0.5 * c);
        *o = [
            q[0] as f32,
            q[1] as f32,
            q[2] as f32,
            q[3] as f32,
            d[0] as f32,
            d[1] as f32,
            d[2] as f32,
            d[3] as f32,
        ];
    }
}

/// Stores lane 0..3 of `v` into vertex `i` of three component slices.
#[inline(always)]
fn store3(out: &mut [&mut [f32]; 3], i: usize, v: [f32; 4]) {
    out[0][i] = v[0];
    out[1][i] = v[1];
    out[2][i] = v[2];
}

/// LBS of the vertices `range` (see the module docs) into the matching slots of the
/// component slices `out_p` and `out_n` (vertex `range.start` at index 0).
fn lbs_range(
    mut out_p: [&mut [f32]; 3],
    mut out_n: Option<[&mut [f32]; 3]>,
    input: &SkinInput,
    n: usize,
    matrices: &[SkinMatrix],
    range: std::ops::Range<usize>,
) {
    let p = components(input.positions, n, range.clone());
    let nr = out_n
        .as_ref()
        .map(|_| components(input.normals, n, range.clone()));
    // Eight lanes hold two columns of a matrix: `lo` columns 0 and 1, `hi` columns 2 and
    // 3. Blending costs two multiply-adds an influence (against four with one column a
    // register), and `lo (x x x x y y y y) + hi (z z z z 1 1 1 1)`, halves added, is the
    // point.
    //
    // Every slice is cut to the range's length first, so the loops run without bounds
    // checks on them (they cost a fifth of the time with normals).
    let len = range.len();
    let (js, ws) = (&input.joints[range.clone()], &input.weights[range]);
    let [px, py, pz] = p.map(|c| &c[..len]);
    let [ox, oy, oz] = out_p.each_mut().map(|c| &mut c[..len]);
    let ones = f32x4::splat(1.0);
    match out_n.as_mut().zip(nr) {
        None => {
            for i in 0..len {
                let (lo, hi) = blend_columns(matrices, js[i], ws[i]);
                let r = apply8(lo, hi, px[i], py[i], f32x4::splat(pz[i]), ones);
                (ox[i], oy[i], oz[i]) = (r[0], r[1], r[2]);
            }
        }
        Some((o, nr)) => {
            let [nx, ny, nz] = nr.map(|c| &c[..len]);
            let [qx, qy, qz] = o.each_mut().map(|c| &mut c[..len]);
            for i in 0..len {
                let (lo, hi) = blend_columns(matrices, js[i], ws[i]);
                let r = apply8(lo, hi, px[i], py[i], f32x4::splat(pz[i]), ones);
                (ox[i], oy[i], oz[i]) = (r[0], r[1], r[2]);
                let t = apply8(lo, hi, nx[i], ny[i], f32x4::splat(nz[i]), f32x4::ZERO);
                (qx[i], qy[i], qz[i]) = (t[0], t[1], t[2]);
            }
        }
    }
}

/// Columns 0-1 and 2-3 of a matrix as eight lanes.
#[inline(always)]
fn halves(m: &SkinMatrix) -> (f32x8, f32x8) {
    let lo = f32x8::new([
        m[0][0], m[0][1], m[0][2], m[0][3], m[1][0], m[1][1], m[1][2], m[1][3],
    ]);
    let hi = f32x8::new([
        m[2][0], m[2][1], m[2][2], m[2][3], m[3][0], m[3][1], m[3][2], m[3][3],
    ]);
    (lo, hi)
}

/// `sum_k w_k M_k` as two eight-lane halves.
#[inline(always)]
fn blend_columns(matrices: &[SkinMatrix], js: [u16; 4], ws: [f32; 4]) -> (f32x8, f32x8) {
    let (l0, h0) = halves(&matrices[js[0] as usize]);
    let w = f32x8::splat(ws[0]);
    let (mut lo, mut hi) = (l0 * w, h0 * w);
    for k in 1..4 {
        let (l, h) = halves(&matrices[js[k] as usize]);
        let w = f32x8::splat(ws[k]);
        lo = l.mul_add(w, lo);
        hi = h.mul_add(w, hi);
    }
    (lo, hi)
}

/// `lo (x x x x y y y y) + hi (z z z z w w w w)` with its halves added: the blended
/// matrix applied to `(x, y, z, w)` (`w` 1 for points, 0 for normals).
#[inline(always)]
fn apply8(lo: f32x8, hi: f32x8, x: f32, y: f32, z: f32x4, w: f32x4) -> [f32; 4] {
    let xy = f32x8::new([x, x, x, x, y, y, y, y]);
    let (z, w) = (z.to_array(), w.to_array());
    let zw = f32x8::new([z[0], z[1], z[2], z[3], w[0], w[1], w[2], w[3]]);
    let s = hi.mul_add(zw, lo * xy).to_array();
    let (a, b) = (
        f32x4::new([s[0], s[1], s[2], s[3]]),
        f32x4::new([s[4], s[5], s[6], s[7]]),
    );
    (a + b).to_array()
}

/// LBS, scalar twin of the SIMD loop (same results to f32 rounding).
fn lbs_range_scalar(
    mut out_p: [&mut [f32]; 3],
    mut out_n: Option<[&mut [f32]; 3]>,
    input: &SkinInput,
    n: usize,
    matrices: &[SkinMatrix],
    range: std::ops::Range<usize>,
) {
    let p = components(input.positions, n, range.clone());
    let nr = out_n
        .as_ref()
        .map(|_| components(input.normals, n, range.clone()));
    for (i, v) in range.enumerate() {
        let (js, ws) = (input.joints[v], input.weights[v]);
        let mut c = [[0.0f32; 4]; 4];
        for k in 0..4 {
            let m = &matrices[js[k] as usize];
            for col in 0..4 {
                for r in 0..4 {
                    c[col][r] += ws[k] * m[col][r];
                }
            }
        }
        let (x, y, z) = (p[0][i], p[1][i], p[2][i]);
        let r = [0, 1, 2, 3].map(|r| c[0][r] * x + c[1][r] * y + c[2][r] * z + c[3][r]);
        store3(&mut out_p, i, r);
        if let (Some(o), Some(nr)) = (out_n.as_mut(), nr.as_ref()) {
            let (x, y, z) = (nr[0][i], nr[1][i], nr[2][i]);
            let a = [0, 1, 2, 3].map(|r| c[0][r] * x + c[1][r] * y + c[2][r] * z);
            store3(o, i, a);
        }
    }
}

/// DQS of the vertices `range` (see the module docs).
fn dqs_range(
    mut out_p: [&mut [f32]; 3],
    mut out_n: Option<[&mut [f32]; 3]>,
    input: &SkinInput,
    n: usize,
    dual: &[DualQuat],
    range: std::ops::Range<usize>,
) {
    let p = components(input.positions, n, range.clone());
    let nr = out_n
        .as_ref()
        .map(|_| components(input.normals, n, range.clone()));
    // Two passes over blocks of DQ_BLOCK vertices. First the blend: a dual quaternion
    // fills eight lanes, one multiply-add an influence (the hemisphere test a scalar dot
    // product of the real parts), written out component by component. Then the
    // normalisation and the transform, a plain loop over those components that the
    // compiler vectorises across vertices (square root and division included): done per
    // vertex, their latency left the loop at about 100 cycles a vertex. Slices are cut
    // to equal lengths so neither pass checks bounds.
    let len = range.len();
    let (js, ws) = (&input.joints[range.clone()], &input.weights[range]);
    let [px, py, pz] = p.map(|c| &c[..len]);
    let [ox, oy, oz] = out_p.each_mut().map(|c| &mut c[..len]);
    let mut nr = nr.map(|c| c.map(|c| &c[..len]));
    let mut on = out_n.as_mut().map(|o| o.each_mut().map(|c| &mut c[..len]));
    let mut b = [[0.0f32; DQ_BLOCK]; 8];
    let mut start = 0;
    while start < len {
        let m = DQ_BLOCK.min(len - start);
        for i in 0..m {
            let (js, ws) = (js[start + i], ws[start + i]);
            let d0 = &dual[js[0] as usize];
            let mut q = f32x8::new(*d0) * f32x8::splat(ws[0]);
            for k in 1..4 {
                let d = &dual[js[k] as usize];
                let dot = d[0] * d0[0] + d[1] * d0[1] + d[2] * d0[2] + d[3] * d0[3];
                q = f32x8::new(*d).mul_add(f32x8::splat(signed(ws[k], dot)), q);
            }
            for (c, v) in q.to_array().into_iter().enumerate() {
                b[c][i] = v;
            }
        }
        let r = start..start + m;
        let [rw, rx, ry, rz, dw, dx, dy, dz] = b.each_ref().map(|c| &c[..m]);
        let (px, py, pz) = (&px[r.clone()], &py[r.clone()], &pz[r.clone()]);
        let (ox, oy, oz) = (&mut ox[r.clone()], &mut oy[r.clone()], &mut oz[r.clone()]);
        match (nr.as_mut(), on.as_mut()) {
            (Some(nr), Some(on)) => {
                let (nx, ny, nz) = (&nr[0][r.clone()], &nr[1][r.clone()], &nr[2][r.clone()]);
                let [qx, qy, qz] = on.each_mut().map(|c| &mut c[r.clone()]);
                for i in 0..m {
                    let (q, n) = dq_apply(
                        [rw[i], rx[i], ry[i], rz[i]],
                        [dw[i], dx[i], dy[i], dz[i]],
                        [px[i], py[i], pz[i]],
                        Some([nx[i], ny[i], nz[i]]),
                    );
                    (ox[i], oy[i], oz[i]) = (q[0], q[1], q[2]);
                    let n = n.unwrap_or_default();
                    (qx[i], qy[i], qz[i]) = (n[0], n[1], n[2]);
                }
            }
            _ => {
                for i in 0..m {
                    let (q, _) = dq_apply(
                        [rw[i], rx[i], ry[i], rz[i]],
                        [dw[i], dx[i], dy[i], dz[i]],
                        [px[i], py[i], pz[i]],
                        None,
                    );
                    (ox[i], oy[i], oz[i]) = (q[0], q[1], q[2]);
                }
            }
        }
        start += m;
    }
}

/// Vertices blended before they are transformed (see `dqs_range`): 8 KiB of blends.
const DQ_BLOCK: usize = 256;

/// `a x b`.
#[inline(always)]
fn cross3(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `v` turned by the unit quaternion `(w, r)`: `v + 2 r x (r x v + w v)`.
#[inline(always)]
fn turn(w: f32, r: [f32; 3], v: [f32; 3]) -> [f32; 3] {
    let t = cross3(r, v);
    let t = [t[0] + w * v[0], t[1] + w * v[1], t[2] + w * v[2]];
    let u = cross3(r, t);
    [v[0] + 2.0 * u[0], v[1] + 2.0 * u[1], v[2] + 2.0 * u[2]]
}

/// `w` with the sign of `dot` flipped onto it (no branch: the hemisphere test is a coin
/// toss for random joints, and a mispredicted branch costs more than the blend).
#[inline(always)]
fn signed(w: f32, dot: f32) -> f32 {
    f32::from_bits(w.to_bits() ^ (dot.to_bits() & 0x8000_0000))
}

/// The blended dual quaternion `(r, d)` normalised and applied to a point and a normal.
#[inline(always)]
fn dq_apply(
    r: [f32; 4],
    d: [f32; 4],
    p: [f32; 3],
    n: Option<[f32; 3]>,
) -> ([f32; 3], Option<[f32; 3]>) {
    let inv = 1.0 / (r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3]).sqrt();
    let (w, rv) = (r[0] * inv, [r[1] * inv, r[2] * inv, r[3] * inv]);
    let (dw, dv) = (d[0] * inv, [d[1] * inv, d[2] * inv, d[3] * inv]);
    let rd = cross3(rv, dv);
    let q = turn(w, rv, p);
    let p = [
        q[0] + 2.0 * (w * dv[0] - dw * rv[0] + rd[0]),
        q[1] + 2.0 * (w * dv[1] - dw * rv[1] + rd[1]),
        q[2] + 2.0 * (w * dv[2] - dw * rv[2] + rd[2]),
    ];
    (p, n.map(|n| turn(w, rv, n)))
}

/// DQS, scalar twin.
fn dqs_range_scalar(
    mut out_p: [&mut [f32]; 3],
    mut out_n: Option<[&mut [f32]; 3]>,
    input: &SkinInput,
    n: usize,
    dual: &[DualQuat],
    range: std::ops::Range<usize>,
) {
    let p = components(input.positions, n, range.clone());
    let nr = out_n
        .as_ref()
        .map(|_| components(input.normals, n, range.clone()));
    for (i, v) in range.enumerate() {
        let (js, ws) = (input.joints[v], input.weights[v]);
        let first = dual[js[0] as usize];
        let (mut r, mut d) = ([0.0f32; 4], [0.0f32; 4]);
        for k in 0..4 {
            let q = &dual[js[k] as usize];
            let dot: f32 = (0..4).map(|c| q[c] * first[c]).sum();
            let w = if dot < 0.0 { -ws[k] } else { ws[k] };
            for c in 0..4 {
                r[c] += w * q[c];
                d[c] += w * q[4 + c];
            }
        }
        let (pp, nn) = dq_apply(
            r,
            d,
            [p[0][i], p[1][i], p[2][i]],
            nr.as_ref().map(|nr| [nr[0][i], nr[1][i], nr[2][i]]),
        );
        store3(&mut out_p, i, [pp[0], pp[1], pp[2], 0.0]);
        if let (Some(o), Some(nn)) = (out_n.as_mut(), nn) {
            store3(o, i, [nn[0], nn[1], nn[2], 0.0]);
        }
    }
}

/// The slices of the whole output for one call without chunks.
fn whole(out: &mut [f32], n: usize) -> [&mut [f32]; 3] {
    let (x, yz) = out.split_at_mut(n);
    let (y, z) = yz.split_at_mut(n);
    [x, y, z]
}

/// Checks lengths; returns `n`.
fn check(out_p: &[f32], out_n: &[f32], input: &SkinInput) -> usize {
    let n = input.len();
    assert_eq!(out_p.len(), 3 * n, "output positions are 3n");
    assert_eq!(
        out_n.len(),
        input.normals.len(),
        "output normals match the input's"
    );
    n
}

macro_rules! skin_kernels {
    ($(#[$doc:meta])* $name:ident, $scalar:ident, $par:ident, $range:ident, $range_scalar:ident, $xf:ty) => {
        $(#[$doc])*
        ///
        /// Outputs are component-major like the input; `out_n` is empty when the input
        /// has no normals. Preconditions: joint indices within `xf` (a bad index panics).
        pub fn $name(out_p: &mut [f32], out_n: &mut [f32], input: &SkinInput, xf: &[$xf]) {
            let n = check(out_p, out_n, input);
            let on = (!out_n.is_empty()).then(|| whole(out_n, n));
            $range(whole(out_p, n), on, input, n, xf, 0..n);
        }

        /// Scalar twin.
        pub fn $scalar(out_p: &mut [f32], out_n: &mut [f32], input: &SkinInput, xf: &[$xf]) {
            let n = check(out_p, out_n, input);
            let on = (!out_n.is_empty()).then(|| whole(out_n, n));
            $range_scalar(whole(out_p, n), on, input, n, xf, 0..n);
        }

        /// Parallel driver: fixed chunks of [`PAR_CHUNK`] vertices.
        pub fn $par(out_p: &mut [f32], out_n: &mut [f32], input: &SkinInput, xf: &[$xf]) {
            let n = check(out_p, out_n, input);
            let has_n = !out_n.is_empty();
            let (dp, dn) = (Disjoint::new(out_p), Disjoint::new(out_n));
            par_reduce::<0, _>(chunk_count(n, PAR_CHUNK), &|c| {
                let r = chunk_range(c, n, PAR_CHUNK);
                // SAFETY: chunk ranges are disjoint.
                let (p, nn) = unsafe {
                    (dp.components(n, r.clone()), has_n.then(|| dn.components(n, r.clone())))
                };
                $range(p, nn, input, n, xf, r);
                []
            });
        }
    };
}

skin_kernels!(
    /// Linear blend skinning of all vertices with skinning matrices `xf` (SIMD over the
    /// four lanes of a matrix column).
    lbs, lbs_scalar, lbs_par, lbs_range, lbs_range_scalar, SkinMatrix
);
skin_kernels!(
    /// Dual quaternion skinning of all vertices with the joints' dual quaternions `xf`
    /// (from [`dual_quaternions`]).
    dqs, dqs_scalar, dqs_par, dqs_range, dqs_range_scalar, DualQuat
);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::anim::affine_from_trs;
    use proptest::prelude::*;

    fn matrices(angles: &[[f64; 3]]) -> Vec<SkinMatrix> {
        angles
            .iter()
            .enumerate()
            .map(|(k, a)| {
                skin_matrix(&affine_from_trs(
                    [k as f64 * 0.1, -0.2, 0.3],
                    crate::quat::exp(*a),
                    [1.0; 3],
                ))
            })
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// SIMD and scalar kernels agree, and the parallel drivers give the same bits
        /// as the serial SIMD ones.
        #[test]
        fn simd_scalar_and_parallel_agree(
            n in 1usize..5000,
            seed in 0u64..1000,
            angles in prop::collection::vec(prop::array::uniform3(-3.0f64..3.0), 5),
        ) {
            let m = matrices(&angles);
            let mut dq = vec![[0.0; 8]; m.len()];
            dual_quaternions(&mut dq, &m);
            let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
            let mut rnd = || { s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407); ((s >> 33) as f32) / (1u64 << 31) as f32 };
            let pos: Vec<f32> = (0..3 * n).map(|_| 2.0 * rnd() - 1.0).collect();
            let nrm: Vec<f32> = (0..3 * n).map(|i| if i < n { 1.0 } else { 0.0 }).collect();
            let joints: Vec<[u16; 4]> = (0..n).map(|_| [0, 1, 2, 3].map(|_| (rnd() * 4.99) as u16)).collect();
            let weights: Vec<[f32; 4]> = (0..n).map(|_| { let w = [rnd(), rnd(), rnd(), rnd()]; let t: f32 = w.iter().sum(); w.map(|x| x / t) }).collect();
            let input = SkinInput { positions: &pos, normals: &nrm, joints: &joints, weights: &weights };
            let (mut a, mut an) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            let (mut b, mut bn) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            let (mut c, mut cn) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            lbs(&mut a, &mut an, &input, &m);
            lbs_scalar(&mut b, &mut bn, &input, &m);
            lbs_par(&mut c, &mut cn, &input, &m);
            prop_assert_eq!(&a, &c);
            prop_assert_eq!(&an, &cn);
            for i in 0..3 * n {
                prop_assert!((a[i] - b[i]).abs() < 1e-5 && (an[i] - bn[i]).abs() < 1e-4, "{} {} {}", i, a[i], b[i]);
            }
            dqs(&mut a, &mut an, &input, &dq);
            dqs_scalar(&mut b, &mut bn, &input, &dq);
            dqs_par(&mut c, &mut cn, &input, &dq);
            prop_assert_eq!(&a, &c);
            for i in 0..3 * n {
                prop_assert!((a[i] - b[i]).abs() < 1e-5 && (an[i] - bn[i]).abs() < 1e-5);
            }
        }
    }

    /// With one influence both methods are the joint's rigid transform.
    #[test]
    fn one_influence_is_the_joint_transform() {
        let m = matrices(&[[0.3, -1.2, 0.7]]);
        let mut dq = [[0.0; 8]];
        dual_quaternions(&mut dq, &m);
        let pos = [0.5f32, -1.0, 2.0];
        let input = SkinInput {
            positions: &pos,
            normals: &[],
            joints: &[[0; 4]],
            weights: &[[1.0, 0.0, 0.0, 0.0]],
        };
        let (mut a, mut b) = ([0.0f32; 3], [0.0f32; 3]);
        lbs(&mut a, &mut [], &input, &m);
        dqs(&mut b, &mut [], &input, &dq);
        let want = [0, 1, 2].map(|r| m[0][0][r] * 0.5 - m[0][1][r] + m[0][2][r] * 2.0 + m[0][3][r]);
        for k in 0..3 {
            assert!(
                (a[k] - want[k]).abs() < 1e-6 && (b[k] - want[k]).abs() < 1e-5,
                "{a:?} {b:?} {want:?}"
            );
        }
    }
}
