//! Inside and outside of closed triangle surfaces on grids: the voxelisation the FEM's
//! voxel mesher and the fluid's mesh obstacles share, and the sign of the distance
//! fields sampled from meshes.
//!
//! Rays along +x through the sample rows: each triangle adds the x where it crosses the
//! rows its y-z box covers, with the sign of its y-z orientation (+1 where the outward
//! normal points along -x, entering the solid). Summing the signs before a sample gives
//! its winding number (1 inside a closed, outward-oriented surface, 0 outside); counting
//! them gives the ray parity. The 2-D point-in-triangle test breaks ties on edges and
//! vertices by a fixed symbolic rule (Batty's SDFGen: the signed area, then the
//! coordinates' order), so a ray through a shared edge or vertex of a closed surface
//! crosses it exactly once.

use crate::io::Mesh;

/// Orientation sign of the 2-D vectors `(x1, y1)`, `(x2, y2)`: the sign of their signed
/// area, ties broken by the coordinates' order (never 0 unless the vectors are equal);
/// with the area itself.
fn orientation(x1: f64, y1: f64, x2: f64, y2: f64) -> (i8, f64) {
    let area = y1 * x2 - x1 * y2;
    let s = if area > 0.0 {
        1
    } else if area < 0.0 {
        -1
    } else if y2 > y1 {
        1
    } else if y2 < y1 {
        -1
    } else if x1 > x2 {
        1
    } else if x1 < x2 {
        -1
    } else {
        0
    };
    (s, area)
}

/// Whether the 2-D point `p` is in triangle `abc` under the tie rule: its barycentric
/// coordinates and the triangle's orientation sign.
fn in_triangle_2d(p: [f64; 2], a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> Option<([f64; 3], i8)> {
    let (a, b, c) = (
        [a[0] - p[0], a[1] - p[1]],
        [b[0] - p[0], b[1] - p[1]],
        [c[0] - p[0], c[1] - p[1]],
    );
    let (sa, wa) = orientation(b[0], b[1], c[0], c[1]);
    if sa == 0 {
        return None;
    }
    let (sb, wb) = orientation(c[0], c[1], a[0], a[1]);
    if sb != sa {
        return None;
    }
    let (sc, wc) = orientation(a[0], a[1], b[0], b[1]);
    if sc != sa {
        return None;
    }
    let sum = wa + wb + wc;
    if sum == 0.0 || !sum.is_finite() {
        return None;
    }
    Some(([wa / sum, wb / sum, wc / sum], sa))
}

/// The crossings of the rows of sample points `(y0 + j h, z0 + k h)`, `j < ny`, `k < nz`,
/// with the surface: for row `j + ny k`, each crossing's x and sign (see the module docs),
/// sorted by x.
pub fn row_crossings(
    surface: &Mesh,
    y0: f64,
    z0: f64,
    h: f64,
    ny: usize,
    nz: usize,
) -> Vec<Vec<(f64, i8)>> {
    let p = |i: u32| surface.as_ref().vertex(i as usize);
    let mut rows: Vec<Vec<(f64, i8)>> = vec![Vec::new(); ny * nz];
    for t in surface.triangles.iter() {
        let [a, b, c] = t.map(p);
        let range = |lo: f64, hi: f64, o: f64, m: usize| {
            let first = ((lo - o) / h).ceil().clamp(0.0, m as f64) as usize;
            let last = ((hi - o) / h).floor().clamp(-1.0, m as f64 - 1.0);
            (first, (last + 1.0) as usize)
        };
        let (j0, j1) = range(a[1].min(b[1]).min(c[1]), a[1].max(b[1]).max(c[1]), y0, ny);
        let (k0, k1) = range(a[2].min(b[2]).min(c[2]), a[2].max(b[2]).max(c[2]), z0, nz);
        for k in k0..k1 {
            for j in j0..j1 {
                let q = [y0 + j as f64 * h, z0 + k as f64 * h];
                if let Some((w, s)) = in_triangle_2d(q, [a[1], a[2]], [b[1], b[2]], [c[1], c[2]]) {
                    let x = w[0] * a[0] + w[1] * b[0] + w[2] * c[0];
                    rows[j + ny * k].push((x, s));
                }
            }
        }
    }
    for r in &mut rows {
        r.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    rows
}

/// The winding number of each sample point `origin + (i, j, k) h` of an `n` grid (x
/// fastest) about the surface: 1 inside a closed outward-oriented surface, 0 outside,
/// more where parts overlap.
pub fn winding_numbers(surface: &Mesh, origin: [f64; 3], h: f64, n: [usize; 3]) -> Vec<i32> {
    let rows = row_crossings(surface, origin[1], origin[2], h, n[1], n[2]);
    let mut w = vec![0i32; n[0] * n[1] * n[2]];
    for (r, xs) in rows.iter().enumerate() {
        let mut before = 0;
        let mut sum = 0i32;
        for i in 0..n[0] {
            let x = origin[0] + i as f64 * h;
            while before < xs.len() && xs[before].0 < x {
                sum += xs[before].1 as i32;
                before += 1;
            }
            w[i + n[0] * r] = sum;
        }
    }
    w
}

/// Whether the centre of each cell of the grid of `n` cubes of side `h` from `origin`
/// (x fastest) lies inside the closed surface, by ray parity (robust to a surface whose
/// triangles are not consistently oriented).
pub fn cells_inside(surface: &Mesh, origin: [f64; 3], h: f64, n: [usize; 3]) -> Vec<bool> {
    let c = origin.map(|o| o + 0.5 * h);
    let rows = row_crossings(surface, c[1], c[2], h, n[1], n[2]);
    let mut inside = vec![false; n[0] * n[1] * n[2]];
    for (r, xs) in rows.iter().enumerate() {
        let mut before = 0;
        for i in 0..n[0] {
            let x = c[0] + i as f64 * h;
            while before < xs.len() && xs[before].0 < x {
                before += 1;
            }
            inside[i + n[0] * r] = before % 2 == 1;
        }
    }
    inside
}
