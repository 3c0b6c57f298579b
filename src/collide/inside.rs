//! Which cells of a grid lie inside a closed triangle surface: the voxelisation the FEM's
//! voxel mesher and the fluid's mesh obstacles share.
//!
//! Ray parity along +x: each triangle adds the x where it crosses the rays of the grid
//! rows its y-z box covers (a 2-D point-in-triangle test); a cell centre is inside when an
//! odd number of crossings lie before it. The rows are shifted off the cell centres by an
//! irrational fraction of a cell so that no ray meets a vertex or an edge of an
//! axis-aligned surface exactly.

use crate::io::Mesh;

/// Whether the centre of each cell of the grid of `n` cubes of side `h` from `origin`
/// (x fastest) lies inside the closed surface.
pub fn cells_inside(surface: &Mesh, origin: [f64; 3], h: f64, n: [usize; 3]) -> Vec<bool> {
    let p = |i: u32| surface.as_ref().vertex(i as usize);
    // Row (j, k)'s ray: y = origin + (j + 1/2 + dy) h, z likewise.
    let (dy, dz) = (1e-4 * std::f64::consts::SQRT_2, 1e-4 * std::f64::consts::PI);
    let ray = |j: usize, k: usize| {
        (
            origin[1] + (j as f64 + 0.5 + dy) * h,
            origin[2] + (k as f64 + 0.5 + dz) * h,
        )
    };
    let mut crossings: Vec<Vec<f64>> = vec![Vec::new(); n[1] * n[2]];
    for t in surface.triangles.iter() {
        let [a, b, c] = t.map(p);
        let (ylo, yhi) = (a[1].min(b[1]).min(c[1]), a[1].max(b[1]).max(c[1]));
        let (zlo, zhi) = (a[2].min(b[2]).min(c[2]), a[2].max(b[2]).max(c[2]));
        let row = |v: f64, o: f64, d: f64, m: usize| {
            ((v - o) / h - 0.5 - d).clamp(-1.0, m as f64) as isize
        };
        let (j0, j1) = (
            row(ylo, origin[1], dy, n[1]).max(0),
            row(yhi, origin[1], dy, n[1]) + 1,
        );
        let (k0, k1) = (
            row(zlo, origin[2], dz, n[2]).max(0),
            row(zhi, origin[2], dz, n[2]) + 1,
        );
        // The triangle's signed area in the y-z plane.
        let det = (b[1] - a[1]) * (c[2] - a[2]) - (c[1] - a[1]) * (b[2] - a[2]);
        if det == 0.0 {
            continue;
        }
        for j in j0 as usize..(j1.max(0) as usize).min(n[1]) {
            for k in k0 as usize..(k1.max(0) as usize).min(n[2]) {
                let (y, z) = ray(j, k);
                // Barycentric coordinates of (y, z).
                let u = ((y - a[1]) * (c[2] - a[2]) - (c[1] - a[1]) * (z - a[2])) / det;
                let v = ((b[1] - a[1]) * (z - a[2]) - (y - a[1]) * (b[2] - a[2])) / det;
                if u >= 0.0 && v >= 0.0 && u + v <= 1.0 {
                    crossings[j + n[1] * k].push(a[0] + u * (b[0] - a[0]) + v * (c[0] - a[0]));
                }
            }
        }
    }
    let cell = |i: usize, j: usize, k: usize| i + n[0] * (j + n[1] * k);
    let mut inside = vec![false; n[0] * n[1] * n[2]];
    for k in 0..n[2] {
        for j in 0..n[1] {
            let xs = &mut crossings[j + n[1] * k];
            xs.sort_by(f64::total_cmp);
            let mut before = 0;
            for i in 0..n[0] {
                let x = origin[0] + (i as f64 + 0.5) * h;
                while before < xs.len() && xs[before] < x {
                    before += 1;
                }
                inside[cell(i, j, k)] = before % 2 == 1;
            }
        }
    }
    inside
}
