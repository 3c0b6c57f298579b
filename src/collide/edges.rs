//! Obstacle edges against model triangles: what vertex contacts miss.
//!
//! A vertex contact keeps every vertex outside, but a box's edge or corner can still pass
//! between the vertices of a triangle and show through it (a table's edges through a
//! tablecloth draped over it). For each sharp edge of an obstacle (a box's twelve) and
//! each triangle near it, [`edge_through_triangle`] clips the edge to the prism over the
//! triangle (the three planes through its sides along its normal) and returns the point
//! of the clipped edge farthest out along the triangle's outward normal: since that depth
//! is linear along the edge, the farthest point is an end of the clipped piece (a corner
//! of the box when it lies over the triangle). The triangle is then moved out along its
//! normal until that point is the contact thickness under it (see
//! [`crate::collide::VertexContacts`]).

use super::Obstacle;
use largestep_kernels::rigid::mat_t_vec;
use largestep_kernels::v3::{add, cross, dot, sub};

impl Obstacle {
    /// The sharp edges of the obstacle's surface as segments (a box's twelve, a hull's
    /// listed ones); smooth shapes, half-spaces and distance grids have none.
    pub fn sharp_edges(&self) -> impl Iterator<Item = ([f64; 3], [f64; 3])> + '_ {
        let boxes = match self {
            Obstacle::Box { min, max } => Some(box_edges(|c| {
                std::array::from_fn(|a| if c >> a & 1 == 1 { max[a] } else { min[a] })
            })),
            Obstacle::Oriented { center, axes, half } => {
                Some(box_edges(|c| oriented_corner(*center, axes, *half, c)))
            }
            _ => None,
        };
        let hull = match self {
            Obstacle::Hull {
                edges,
                center,
                axes,
                ..
            } => Some((edges, *center, *axes)),
            _ => None,
        };
        let hull_edges = hull.into_iter().flat_map(|(edges, center, axes)| {
            let place = move |p: [f64; 3]| add(center, mat_t_vec(&axes, p));
            edges.iter().map(move |[a, b]| (place(*a), place(*b)))
        });
        boxes.into_iter().flatten().chain(hull_edges)
    }
}

/// Corner `c` (bit k: the + side of axis k) of an oriented box.
fn oriented_corner(center: [f64; 3], axes: &[[f64; 3]; 3], half: [f64; 3], c: usize) -> [f64; 3] {
    let signed = std::array::from_fn(|a| if c >> a & 1 == 1 { half[a] } else { -half[a] });
    add(center, mat_t_vec(axes, signed))
}

/// The twelve edges of a box with corners `corner(c)` (bit a of `c`: the upper side of
/// axis a): from each corner along each axis on which it is on the lower side.
fn box_edges(corner: impl Fn(usize) -> [f64; 3]) -> [([f64; 3], [f64; 3]); 12] {
    let mut edges = [([0.0; 3], [0.0; 3]); 12];
    let mut k = 0;
    for c in 0..8usize {
        for a in 0..3 {
            if c >> a & 1 == 0 {
                edges[k] = (corner(c), corner(c | 1 << a));
                k += 1;
            }
        }
    }
    edges
}

/// How far the segment `a`-`b` comes through the triangle `t` from the side opposite its
/// unit normal `nrm`: among the segment's points over the triangle (inside the prism of
/// its sides), the one farthest along `nrm` from the triangle's plane. Returns that
/// height (m, positive when the point is out beyond the triangle) and the barycentric
/// coordinates of its foot on the triangle; `None` when no part of the segment lies over
/// the triangle or the triangle is degenerate.
pub fn edge_through_triangle(
    t: [[f64; 3]; 3],
    nrm: [f64; 3],
    a: [f64; 3],
    b: [f64; 3],
) -> Option<(f64, [f64; 3])> {
    let ab = sub(b, a);
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for k in 0..3 {
        let (p, q, r) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
        // Inward normal of the side plane through p-q (contains nrm).
        let mut m = cross(nrm, sub(q, p));
        if dot(m, sub(r, p)) < 0.0 {
            m = m.map(|c| -c);
        }
        // dot(a + s ab - p, m) >= 0  <=>  c0 + s c1 >= 0
        let (c0, c1) = (dot(sub(a, p), m), dot(ab, m));
        if c1.abs() <= f64::MIN_POSITIVE {
            if c0 < 0.0 {
                return None;
            }
        } else if c1 > 0.0 {
            lo = lo.max(-c0 / c1);
        } else {
            hi = hi.min(-c0 / c1);
        }
        if lo.is_nan() || hi.is_nan() || lo > hi {
            return None;
        }
    }
    let at = |s: f64| -> [f64; 3] { std::array::from_fn(|k| a[k] + s * ab[k]) };
    let height = |x: [f64; 3]| dot(sub(x, t[0]), nrm);
    let (x0, x1) = (at(lo), at(hi));
    let x = if height(x0) >= height(x1) { x0 } else { x1 };
    let h = height(x);
    let foot: [f64; 3] = std::array::from_fn(|k| x[k] - h * nrm[k]);
    let w = barycentric(t, foot)?;
    h.is_finite().then_some((h, w))
}

/// Barycentric coordinates of `p` (in the triangle's plane) in triangle `t`, clamped to
/// the triangle and summing to one; `None` for a degenerate triangle.
fn barycentric(t: [[f64; 3]; 3], p: [f64; 3]) -> Option<[f64; 3]> {
    let (e1, e2, d) = (sub(t[1], t[0]), sub(t[2], t[0]), sub(p, t[0]));
    let (a, b, c) = (dot(e1, e1), dot(e1, e2), dot(e2, e2));
    let (d1, d2) = (dot(d, e1), dot(d, e2));
    let det = a * c - b * b;
    if det.is_nan() || det <= 1e-12 * a * c {
        return None;
    }
    let v = ((c * d1 - b * d2) / det).clamp(0.0, 1.0);
    let w = ((a * d2 - b * d1) / det).clamp(0.0, 1.0);
    let s = v + w;
    let (v, w) = if s > 1.0 { (v / s, w / s) } else { (v, w) };
    Some([1.0 - v - w, v, w])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_box_has_twelve_unit_edges() {
        let b = Obstacle::Box {
            min: [0.0; 3],
            max: [1.0; 3],
        };
        let e: Vec<_> = b.sharp_edges().collect();
        assert_eq!(e.len(), 12);
        for (p, q) in e {
            let d = sub(q, p);
            assert_eq!(dot(d, d), 1.0);
        }
    }

    #[test]
    fn an_edge_under_a_tilted_triangle_is_found_at_its_highest_point() {
        // Triangle in the plane z = 0, normal +z; a segment along x at height 0.1 over it
        // from x = -1 to 2 (the triangle spans x in [0, 1]).
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let (h, w) =
            edge_through_triangle(t, [0.0, 0.0, 1.0], [-1.0, 0.25, 0.1], [2.0, 0.25, 0.3]).unwrap();
        // Over the triangle x runs from 0 to 0.75 (y = 0.25): heights 0.1 + 0.2 (x + 1)/3.
        assert!((h - (0.1 + 0.2 * 1.75 / 3.0)).abs() < 1e-12, "{h}");
        assert!(
            (w[1] - 0.75).abs() < 1e-12 && (w[2] - 0.25).abs() < 1e-12,
            "{w:?}"
        );
        // Beside the triangle: nothing.
        assert!(
            edge_through_triangle(t, [0.0, 0.0, 1.0], [-1.0, 2.0, 0.1], [2.0, 2.0, 0.1]).is_none()
        );
    }
}
