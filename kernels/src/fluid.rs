//! Semi-Lagrangian advection on staggered (MAC) grids: sampling of cell-centred and
//! face-centred fields, back traces and the corrected schemes' limiter.
//!
//! A field is one flat array, x fastest, of values at nodes `(i + o_x, j + o_y, k + o_z)`
//! in cell units (`o = 0.5` along an axis where the node sits at cell centres, `0` where it
//! sits on faces). Positions are in cell units from the grid's corner (`x / h`).
//!
//! - Sampling clamps to the nodes along a closed axis (the field extended by its edge
//!   values) and wraps along a periodic one, where the last face node repeats the first
//!   and is not read. An axis of one node is constant along it (2-D grids).
//! - Linear sampling is the tensor-product linear blend (course notes section 16,
//!   bilinear/trilinear); monotone cubic is Fedkiw, Stam and Jensen 2001's monotonic cubic
//!   Hermite per axis (slopes from central differences, set to zero where they disagree in
//!   sign with the interval's difference), which creates no new extrema.
//! - Back traces (Stam 1999; Bridson 2015, chapter 3) follow the velocity backwards from a
//!   node for `dt`, by the midpoint rule (RK2) or Ralston's third-order rule (RK3), and
//!   clamp the foot into the domain along closed axes. The feet are computed once per
//!   layout and step ([`trace_feet`]) and shared by every pass and field that needs them.
//! - The corrected schemes (MacCormack, Selle et al. 2008; BFECC, Kim et al. 2005) limit
//!   their result to the range of the original field's nodes around the foot
//!   ([`advect_limited`]), which keeps them stable.
//!
//! The drivers run over z-slabs in parallel; every node is computed on its own, so the
//! bits do not depend on the thread count.

use rayon::prelude::*;

/// Where a field's nodes sit and how its edges behave.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Field {
    /// Nodes along x, y, z (each at least 1).
    pub n: [usize; 3],
    /// Node (0, 0, 0)'s position in cell units (0.5 for cell centres, 0 for faces).
    pub offset: [f64; 3],
    /// Periodic axes: the node count along one that repeats (the last face node equals
    /// the first) is `n - 1` distinct nodes, else `n`.
    pub periodic: [bool; 3],
}

impl Field {
    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    /// Whether there are no nodes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Distinct nodes along `a`: the period of a periodic axis.
    #[inline]
    fn period(&self, a: usize) -> usize {
        if self.periodic[a] && self.offset[a] == 0.0 {
            self.n[a] - 1
        } else {
            self.n[a]
        }
    }

    /// Position (cell units) of node `(i, j, k)`.
    #[inline]
    pub fn position(&self, c: [usize; 3]) -> [f64; 3] {
        [
            c[0] as f64 + self.offset[0],
            c[1] as f64 + self.offset[1],
            c[2] as f64 + self.offset[2],
        ]
    }
}

/// How values are interpolated between nodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interp {
    /// Linear (bilinear, trilinear).
    Linear,
    /// Monotone cubic Hermite per axis (Fedkiw et al. 2001).
    MonotoneCubic,
}

/// How a back trace integrates the velocity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trace {
    /// The midpoint rule (second order).
    Rk2,
    /// Ralston's third-order rule, weights 2/9, 3/9, 4/9 (Bridson 2015).
    Rk3,
}

/// The grid a velocity lives on: `cells` along each axis, each axis closed (walls, open)
/// or periodic, and the velocity's components on their faces.
#[derive(Clone, Copy, Debug)]
pub struct Velocity<'a> {
    /// Cells along x, y, z (`cells[2] = 1` in 2-D).
    pub cells: [usize; 3],
    /// Periodic axes.
    pub periodic: [bool; 3],
    /// Face components (m/s): x, y and, in 3-D, z. Traces take their time step over
    /// the cell size (`dt / h`, s/m), so that time step times velocity is in cells.
    pub comp: [&'a [f64]; 3],
    /// Components present: 2 or 3.
    pub dims: usize,
}

impl Velocity<'_> {
    /// The layout of component `a` (faces normal to `a`).
    #[inline]
    pub fn field(&self, a: usize) -> Field {
        let mut n = self.cells;
        n[a] += 1;
        let mut offset = [0.5; 3];
        offset[a] = 0.0;
        Field {
            n,
            offset,
            periodic: self.periodic,
        }
    }

    /// The velocity at `p` (cell units), linearly interpolated.
    #[inline]
    pub fn at(&self, p: [f64; 3]) -> [f64; 3] {
        if self.dims == 3 && !self.periodic.iter().any(|&x| x) {
            return self.at_closed(p);
        }
        let mut v = [0.0; 3];
        for (a, va) in v.iter_mut().enumerate().take(self.dims) {
            *va = sample(self.comp[a], &self.field(a), p, Interp::Linear);
        }
        v
    }

    /// [`Velocity::at`] in 3-D without periodic axes: the node and fraction along each
    /// axis are found once on the faces (at `p`) and once on the centres (at `p - 1/2`),
    /// and each component takes the face ones along its own axis and the centre ones along
    /// the others (the same clamping as [`sample`]).
    #[inline]
    fn at_closed(&self, p: [f64; 3]) -> [f64; 3] {
        let n = self.cells;
        // (node, fraction) on faces (n + 1 nodes) and on centres (n nodes).
        let axis = |t: f64, nodes: usize| {
            let t = t.clamp(0.0, (nodes - 1) as f64);
            let i = (t as usize).min(nodes.saturating_sub(2));
            (i, if nodes > 1 { t - i as f64 } else { 0.0 })
        };
        let face: [(usize, f64); 3] = std::array::from_fn(|b| axis(p[b], n[b] + 1));
        let centre: [(usize, f64); 3] = std::array::from_fn(|b| axis(p[b] - 0.5, n[b]));
        std::array::from_fn(|a| {
            let mut m = n;
            m[a] += 1;
            let c: [(usize, f64); 3] =
                std::array::from_fn(|b| if b == a { face[b] } else { centre[b] });
            let (sy, sz) = (m[0], m[0] * m[1]);
            let dx = usize::from(m[0] > 1);
            let dy = if m[1] > 1 { sy } else { 0 };
            let dz = if m[2] > 1 { sz } else { 0 };
            let f = self.comp[a];
            let base = c[0].0 + sy * c[1].0 + sz * c[2].0;
            let (tx, ty, tz) = (c[0].1, c[1].1, c[2].1);
            let l = |o: usize| f[base + o];
            let corners = [
                l(0),
                l(dx),
                l(dy),
                l(dy + dx),
                l(dz),
                l(dz + dx),
                l(dz + dy),
                l(dz + dy + dx),
            ];
            crate::interp::trilinear(&corners, tx, ty, tz)
        })
    }

    /// Clamps `p` into the domain along the closed axes.
    #[inline]
    pub fn clamp(&self, mut p: [f64; 3]) -> [f64; 3] {
        for ((pa, &per), &n) in p.iter_mut().zip(&self.periodic).zip(&self.cells) {
            if !per {
                *pa = pa.clamp(0.0, n as f64);
            }
        }
        p
    }

    /// Where the fluid at `p` (cell units) was `dt` (s/m: the time over the cell size)
    /// ago.
    #[inline]
    pub fn trace(&self, p: [f64; 3], dt: f64, trace: Trace) -> [f64; 3] {
        let step = |p: [f64; 3], v: [f64; 3], s: f64| {
            self.clamp([p[0] - s * v[0], p[1] - s * v[1], p[2] - s * v[2]])
        };
        let k1 = self.at(p);
        match trace {
            Trace::Rk2 => {
                let mid = self.at(step(p, k1, 0.5 * dt));
                step(p, mid, dt)
            }
            Trace::Rk3 => {
                let k2 = self.at(step(p, k1, 0.5 * dt));
                let k3 = self.at(step(p, k2, 0.75 * dt));
                let v = std::array::from_fn(|a| (2.0 * k1[a] + 3.0 * k2[a] + 4.0 * k3[a]) / 9.0);
                step(p, v, dt)
            }
        }
    }
}

/// Node indices and linear weights along one axis at `t` (node units).
#[inline]
fn linear_axis(t: f64, n: usize, period: usize, periodic: bool) -> ([usize; 2], [f64; 2]) {
    if n == 1 {
        return ([0, 0], [1.0, 0.0]);
    }
    if periodic {
        let f = t.floor();
        let frac = t - f;
        // `rem_euclid` of a NaN is NaN and `as usize` of that 0: the NaN weight poisons
        // the sample, so a later finiteness check sees it.
        let i = (f.rem_euclid(period as f64) as usize).min(period - 1);
        return ([i, (i + 1) % period], [1.0 - frac, frac]);
    }
    let t = t.clamp(0.0, (n - 1) as f64);
    let i = (t as usize).min(n - 2);
    let frac = t - i as f64;
    ([i, i + 1], [1.0 - frac, frac])
}

/// Node indices (four around `t`) and the fraction along one axis at `t` (node units).
#[inline]
fn cubic_axis(t: f64, n: usize, period: usize, periodic: bool) -> ([usize; 4], f64) {
    if n == 1 {
        return ([0; 4], 0.0);
    }
    if periodic {
        let f = t.floor();
        let i = (f.rem_euclid(period as f64) as usize).min(period - 1) as isize;
        let p = period as isize;
        return (
            std::array::from_fn(|m| (i + m as isize - 1).rem_euclid(p) as usize),
            t - f,
        );
    }
    let t = t.clamp(0.0, (n - 1) as f64);
    let i = (t as usize).min(n - 2) as isize;
    let last = n as isize - 1;
    (
        std::array::from_fn(|m| (i + m as isize - 1).clamp(0, last) as usize),
        t - i as f64,
    )
}

/// The monotone cubic Hermite interpolant of `f[0..4]` between `f[1]` and `f[2]` at
/// fraction `s` (Fedkiw, Stam and Jensen 2001, section 5).
#[inline]
pub fn monotone_cubic(f: [f64; 4], s: f64) -> f64 {
    let delta = f[2] - f[1];
    let mut d1 = 0.5 * (f[2] - f[0]);
    let mut d2 = 0.5 * (f[3] - f[1]);
    if delta == 0.0 {
        d1 = 0.0;
        d2 = 0.0;
    } else {
        if d1 * delta < 0.0 {
            d1 = 0.0;
        }
        if d2 * delta < 0.0 {
            d2 = 0.0;
        }
    }
    let (s2, s3) = (s * s, s * s * s);
    // a3 s^3 + a2 s^2 + a1 s + a0 with a3 = d1 + d2 - 2 delta, a2 = 3 delta - 2 d1 - d2.
    (d1 + d2 - 2.0 * delta) * s3 + (3.0 * delta - 2.0 * d1 - d2) * s2 + d1 * s + f[1]
}

/// The field's value at `p` (cell units).
#[inline]
pub fn sample(values: &[f64], f: &Field, p: [f64; 3], interp: Interp) -> f64 {
    let t = [p[0] - f.offset[0], p[1] - f.offset[1], p[2] - f.offset[2]];
    let sy = f.n[0];
    let sz = f.n[0] * f.n[1];
    match interp {
        Interp::Linear => {
            let (ix, wx) = linear_axis(t[0], f.n[0], f.period(0), f.periodic[0]);
            let (iy, wy) = linear_axis(t[1], f.n[1], f.period(1), f.periodic[1]);
            let (iz, wz) = linear_axis(t[2], f.n[2], f.period(2), f.periodic[2]);
            let mut v = 0.0;
            for c in 0..2 {
                if wz[c] == 0.0 {
                    continue;
                }
                let mut plane = 0.0;
                for b in 0..2 {
                    let row = iy[b] * sy + iz[c] * sz;
                    plane += wy[b] * (wx[0] * values[row + ix[0]] + wx[1] * values[row + ix[1]]);
                }
                v += wz[c] * plane;
            }
            v
        }
        Interp::MonotoneCubic => {
            let (ix, fx) = cubic_axis(t[0], f.n[0], f.period(0), f.periodic[0]);
            let (iy, fy) = cubic_axis(t[1], f.n[1], f.period(1), f.periodic[1]);
            let (iz, fz) = cubic_axis(t[2], f.n[2], f.period(2), f.periodic[2]);
            let planes = if f.n[2] == 1 { 1 } else { 4 };
            let mut zs = [0.0; 4];
            for (c, z) in zs.iter_mut().enumerate().take(planes) {
                let mut ys = [0.0; 4];
                for (b, y) in ys.iter_mut().enumerate() {
                    let row = iy[b] * sy + iz[c] * sz;
                    *y = monotone_cubic(ix.map(|i| values[row + i]), fx);
                }
                *z = monotone_cubic(ys, fy);
            }
            if planes == 1 {
                zs[0]
            } else {
                monotone_cubic(zs, fz)
            }
        }
    }
}

/// The least and greatest of the field's nodes around `p` (the cell a linear sample
/// blends).
#[inline]
pub fn node_range(values: &[f64], f: &Field, p: [f64; 3]) -> (f64, f64) {
    let t = [p[0] - f.offset[0], p[1] - f.offset[1], p[2] - f.offset[2]];
    let (ix, _) = linear_axis(t[0], f.n[0], f.period(0), f.periodic[0]);
    let (iy, _) = linear_axis(t[1], f.n[1], f.period(1), f.periodic[1]);
    let (iz, _) = linear_axis(t[2], f.n[2], f.period(2), f.periodic[2]);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for z in iz {
        for y in iy {
            for x in ix {
                let v = values[x + f.n[0] * (y + f.n[1] * z)];
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
    }
    (lo, hi)
}

/// Runs `f(node, index, out)` over every node of `layout`, parallel over z-slabs.
/// Tasks are z-slabs in 3-D and eighths of the grid in 2-D (one slab would leave the
/// other cores idle).
fn for_nodes<T: Send>(
    out: &mut [T],
    per_node: usize,
    layout: &Field,
    f: impl Fn([usize; 3], usize, &mut [T]) + Sync,
) {
    let (nx, ny) = (layout.n[0], layout.n[1]);
    // At least 4k nodes a task: smaller ones cost more to hand out than to run.
    let rows = if layout.n[2] > 1 {
        ny
    } else {
        (4096 / nx).clamp(1, ny)
    };
    let chunk = rows * nx;
    out.par_chunks_mut(chunk * per_node)
        .enumerate()
        .for_each(|(t, s)| {
            for (local, o) in s.chunks_mut(per_node).enumerate() {
                let i = t * chunk + local;
                f([i % nx, (i / nx) % ny, i / (nx * ny)], i, o);
            }
        });
}

/// `feet` = where each node of `layout` was `params.dt` ago (cell units, three f32 per
/// node, node-major): the back traces every pass of one advection shares.
pub fn trace_feet(feet: &mut [f32], layout: &Field, vel: &Velocity<'_>, dt: f64, trace: Trace) {
    assert_eq!(feet.len(), 3 * layout.len(), "three coordinates per node");
    for_nodes(feet, 3, layout, |c, _, o| {
        let p = vel.trace(layout.position(c), dt, trace);
        o[0] = p[0] as f32;
        o[1] = p[1] as f32;
        o[2] = p[2] as f32;
    });
}

#[inline]
fn foot(feet: &[f32], i: usize) -> [f64; 3] {
    [
        feet[3 * i] as f64,
        feet[3 * i + 1] as f64,
        feet[3 * i + 2] as f64,
    ]
}

/// `out` = the field `values` (layout `layout`) sampled at each node's foot
/// ([`trace_feet`]): one semi-Lagrangian advection.
pub fn advect(out: &mut [f64], values: &[f64], layout: &Field, feet: &[f32], interp: Interp) {
    let len = layout.len();
    assert!(
        values.len() == len && out.len() == len && feet.len() == 3 * len,
        "field lengths must match their layout"
    );
    for_nodes(out, 1, layout, |_, i, o| {
        o[0] = sample(values, layout, foot(feet, i), interp);
    });
}

/// `out = clamp(corrected, range of original around the foot)` node by node, where
/// `corrected` is `advected + (original - back) / 2` (MacCormack: `back` is the advected
/// field carried back) or `advected` itself when `back` is `None` (BFECC passes its
/// advected corrected field).
pub fn advect_limited(
    out: &mut [f64],
    original: &[f64],
    advected: &[f64],
    back: Option<&[f64]>,
    layout: &Field,
    feet: &[f32],
) {
    let len = layout.len();
    assert!(
        original.len() == len && advected.len() == len && out.len() == len && feet.len() == 3 * len,
        "field lengths must match their layout"
    );
    if let Some(b) = back {
        assert_eq!(b.len(), len, "field lengths must match their layout");
    }
    for_nodes(out, 1, layout, |_, i, o| {
        let v = match back {
            Some(b) => advected[i] + 0.5 * (original[i] - b[i]),
            None => advected[i],
        };
        let (lo, hi) = node_range(original, layout, foot(feet, i));
        o[0] = if v.is_nan() { v } else { v.clamp(lo, hi) };
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotone_cubic_reproduces_linear_data_and_makes_no_new_extrema() {
        for s in [0.0, 0.25, 0.5, 0.9, 1.0] {
            let v = monotone_cubic([1.0, 2.0, 3.0, 4.0], s);
            assert!((v - (2.0 + s)).abs() < 1e-14);
            let step = monotone_cubic([0.0, 0.0, 1.0, 1.0], s);
            assert!((0.0..=1.0).contains(&step));
        }
    }

    #[test]
    fn periodic_sampling_wraps_and_linear_sampling_is_exact_for_linear_fields() {
        let f = Field {
            n: [5, 1, 1],
            offset: [0.0, 0.5, 0.5],
            periodic: [true, false, false],
        };
        // Faces 0..4 with face 4 repeating face 0.
        let v = [0.0, 1.0, 2.0, 3.0, 0.0];
        assert!((sample(&v, &f, [3.5, 0.5, 0.5], Interp::Linear) - 1.5).abs() < 1e-14);
        assert!((sample(&v, &f, [-0.5, 0.5, 0.5], Interp::Linear) - 1.5).abs() < 1e-14);
        let g = Field {
            n: [6, 6, 6],
            offset: [0.5; 3],
            periodic: [false; 3],
        };
        // Away from the edges, where the cubic's clamped stencil is whole.
        let lin: Vec<f64> = (0..216)
            .map(|i| {
                let p = g.position([i % 6, (i / 6) % 6, i / 36]);
                2.0 * p[0] - p[1] + 0.5 * p[2]
            })
            .collect();
        let p = [2.7, 2.2, 2.9];
        let e = 2.0 * p[0] - p[1] + 0.5 * p[2];
        assert!((sample(&lin, &g, p, Interp::Linear) - e).abs() < 1e-13);
        assert!((sample(&lin, &g, p, Interp::MonotoneCubic) - e).abs() < 1e-13);
    }

    /// The closed 3-D fast path of `Velocity::at` gives the generic sampler's values
    /// (to rounding), inside and outside the grid.
    #[test]
    fn closed_velocity_lookup_matches_the_generic_sampler() {
        let cells = [5, 4, 3];
        let comps: Vec<Vec<f64>> = (0..3)
            .map(|a| {
                let mut m = cells;
                m[a] += 1;
                (0..m[0] * m[1] * m[2])
                    .map(|i| ((i * 37 + a * 11) % 17) as f64 - 8.0)
                    .collect()
            })
            .collect();
        let vel = Velocity {
            cells,
            periodic: [false; 3],
            comp: [&comps[0], &comps[1], &comps[2]],
            dims: 3,
        };
        for p in [
            [0.3, 0.7, 0.2],
            [4.9, 3.99, 2.5],
            [-1.0, 2.0, 7.0],
            [2.5, 0.5, 1.5],
        ] {
            for (a, fast) in vel.at(p).into_iter().enumerate() {
                let slow = sample(vel.comp[a], &vel.field(a), p, Interp::Linear);
                assert!((fast - slow).abs() < 1e-12, "{p:?} {a}: {fast} vs {slow}");
            }
        }
    }
}
