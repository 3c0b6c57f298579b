//! A voxel tetrahedral mesher for closed triangle surfaces (OBJ, OFF): the inside of the
//! surface on a grid of cubes, each cube split into six tetrahedra as `box_mesh` splits
//! them (conforming), the boundary vertices then moved onto the surface.
//!
//! 1. Inside: the cubes whose centre is inside, by ray parity along +x
//!    (`crate::collide::cells_inside`, shared with the fluid's mesh obstacles).
//! 2. Tetrahedra: six per inside cube, vertices shared by index (a dense table over the
//!    grid's corners, sized and checked before it is allocated).
//! 3. Snapping: every vertex on the boundary (of a face that belongs to one tetrahedron)
//!    moves to the closest point of the surface (found from the unmoved mesh). A move that
//!    would leave a tetrahedron around the vertex with less than 2% of its rest volume is
//!    retried after the others have moved, then halved up to four times or dropped; the
//!    count of vertices left off the surface is reported.
//!
//! The mesh is as fine as the grid: features thinner than a cube are lost or joined.

use super::mesh::TetMesh;
use crate::io::Mesh;
use largestep_kernels::fem::signed_volume;
use largestep_kernels::v3::{dot, sub};

/// What the mesher made, and what it could not do.
#[derive(Clone, Debug)]
pub struct VoxelMesh {
    /// Vertices and tetrahedra.
    pub mesh: TetMesh,
    /// Boundary vertices moved onto the surface.
    pub snapped: usize,
    /// Boundary vertices left where they were (a move would have flattened an element).
    pub unsnapped: usize,
    /// Grid cells along x, y, z.
    pub cells: [usize; 3],
}

/// Why a surface could not be meshed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum VoxelError {
    /// The surface has no triangles, or a non-finite vertex.
    #[error("the surface has no triangles, or a vertex that is not finite")]
    Empty,
    /// The cube size is not positive and finite.
    #[error("the cube size must be a finite number > 0, not {0}")]
    Size(f64),
    /// The grid would be too large.
    #[error("a grid of {cells} cubes of {h} at this surface's size is more than the {max} allowed: use larger cubes")]
    TooLarge {
        /// Cubes the grid would have.
        cells: f64,
        /// The cube size.
        h: f64,
        /// The most allowed.
        max: usize,
    },
    /// No cube centre lies inside.
    #[error(
        "no cube of {0} lies inside the surface: it is open, inside out, or thinner than a cube"
    )]
    Nothing(f64),
}

/// Bytes the mesher holds per grid cube while meshing (flags, corner table, vertices and
/// six tetrahedra): callers turn a memory budget into `max_cells` with it.
pub const BYTES_PER_CUBE: u64 = 150;

pub use crate::io::{is_surface_file, read_surface};

impl VoxelMesh {
    /// What to tell the user when boundary vertices stayed off the surface.
    pub fn note(&self) -> Option<String> {
        (self.unsnapped > 0).then(|| {
            format!(
                "voxel mesher: {} of {} boundary vertices left off the surface (moving them would have flattened an element)",
                self.unsnapped,
                self.snapped + self.unsnapped
            )
        })
    }
}

/// Meshes the inside of the closed surface `surface` with cubes of side `h` (at most
/// `max_cells` grid cubes); see the module docs.
pub fn voxel_mesh(surface: &Mesh, h: f64, max_cells: usize) -> Result<VoxelMesh, VoxelError> {
    if !(h.is_finite() && h > 0.0) {
        return Err(VoxelError::Size(h));
    }
    let p = |i: u32| surface.as_ref().vertex(i as usize);
    if surface.triangles.is_empty() || !surface.positions.iter().all(|x| x.is_finite()) {
        return Err(VoxelError::Empty);
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for t in surface.triangles.iter() {
        for &i in t {
            let q = p(i);
            for c in 0..3 {
                lo[c] = lo[c].min(q[c]);
                hi[c] = hi[c].max(q[c]);
            }
        }
    }
    let count: [f64; 3] = std::array::from_fn(|c| ((hi[c] - lo[c]) / h).ceil().max(1.0));
    let total = count.iter().product::<f64>();
    if !total.is_finite() || total > max_cells as f64 {
        return Err(VoxelError::TooLarge {
            cells: total,
            h,
            max: max_cells,
        });
    }
    let n = count.map(|c| c as usize);
    // The grid, centred on the surface's box.
    let origin: [f64; 3] = std::array::from_fn(|c| 0.5 * (lo[c] + hi[c]) - 0.5 * n[c] as f64 * h);
    let inside = crate::collide::cells_inside(surface, origin, h, n);
    let cell = |i: usize, j: usize, k: usize| i + n[0] * (j + n[1] * k);
    if !inside.iter().any(|&b| b) {
        return Err(VoxelError::Nothing(h));
    }
    // Corners used, numbered in grid order.
    let corner = |i: usize, j: usize, k: usize| i + (n[0] + 1) * (j + (n[1] + 1) * k);
    let mut id = vec![u32::MAX; (n[0] + 1) * (n[1] + 1) * (n[2] + 1)];
    let mut positions = Vec::new();
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                if !inside[cell(i, j, k)] {
                    continue;
                }
                for (di, dj, dk) in (0..8).map(|c| (c & 1, (c >> 1) & 1, c >> 2)) {
                    let q = corner(i + di, j + dj, k + dk);
                    if id[q] == u32::MAX {
                        id[q] = positions.len() as u32;
                        positions.push([
                            origin[0] + (i + di) as f64 * h,
                            origin[1] + (j + dj) as f64 * h,
                            origin[2] + (k + dk) as f64 * h,
                        ]);
                    }
                }
            }
        }
    }
    let mut tets = Vec::new();
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                if inside[cell(i, j, k)] {
                    tets.extend(super::mesh::cube_tets(
                        [i, j, k],
                        |c| id[corner(c[0], c[1], c[2])],
                        &positions,
                    ));
                }
            }
        }
    }
    let mut mesh = TetMesh { positions, tets };
    let (snapped, unsnapped) = snap(&mut mesh, surface, h);
    Ok(VoxelMesh {
        mesh,
        snapped,
        unsnapped,
        cells: n,
    })
}

/// Moves the boundary vertices of `mesh` onto `surface` (see the module docs); returns
/// how many moved and how many stayed.
fn snap(mesh: &mut TetMesh, surface: &Mesh, h: f64) -> (usize, usize) {
    let sp = |i: u32| surface.as_ref().vertex(i as usize);
    let faces = super::boundary_faces(&mesh.tets);
    let mut on_boundary = vec![false; mesh.positions.len()];
    for f in &faces {
        for &v in f {
            on_boundary[v as usize] = true;
        }
    }
    // The elements around each vertex.
    let mut around: Vec<Vec<u32>> = vec![Vec::new(); mesh.positions.len()];
    for (e, t) in mesh.tets.iter().enumerate() {
        for &v in t {
            if on_boundary[v as usize] {
                around[v as usize].push(e as u32);
            }
        }
    }
    let rest_volume = h * h * h / 6.0;
    // Targets first (the closest points, from the unmoved mesh), then moves in two
    // passes: a vertex whose move failed may fit once its neighbours are on the surface.
    let mut target: Vec<Option<[f64; 3]>> = vec![None; mesh.positions.len()];
    for v in (0..mesh.positions.len()).filter(|&v| on_boundary[v]) {
        let x = mesh.positions[v];
        let mut best = (f64::INFINITY, x);
        for t in surface.triangles.iter() {
            let [a, b, c] = t.map(sp);
            let near = (0..3).all(|k| {
                a[k].min(b[k]).min(c[k]) - 2.0 * h <= x[k]
                    && x[k] <= a[k].max(b[k]).max(c[k]) + 2.0 * h
            });
            if !near {
                continue;
            }
            let q = closest_on_triangle(x, a, b, c);
            let d = dot(sub(q, x), sub(q, x));
            if d < best.0 {
                best = (d, q);
            }
        }
        target[v] = best.0.is_finite().then_some(best.1);
    }
    let mut done = vec![false; mesh.positions.len()];
    for pass in 0..2 {
        for v in 0..mesh.positions.len() {
            let Some(goal) = target[v] else { continue };
            if done[v] {
                continue;
            }
            let x = mesh.positions[v];
            // The full move, then (last pass) shorter ones.
            let tries = if pass == 0 { 1 } else { 5 };
            let mut s = 1.0;
            for _ in 0..tries {
                let trial: [f64; 3] = std::array::from_fn(|k| x[k] + s * (goal[k] - x[k]));
                mesh.positions[v] = trial;
                let fine = around[v].iter().all(|&e| {
                    let t = mesh.tets[e as usize];
                    signed_volume(&t.map(|i| mesh.positions[i as usize])) > 0.02 * rest_volume
                });
                if fine {
                    done[v] = s == 1.0;
                    break;
                }
                mesh.positions[v] = x;
                s *= 0.5;
            }
        }
    }
    let snapped = done.iter().filter(|&&d| d).count();
    let unsnapped = on_boundary.iter().filter(|&&b| b).count() - snapped;
    (snapped, unsnapped)
}

/// The point of triangle (a, b, c) closest to p (Ericson, "Real-Time Collision
/// Detection", section 5.1.5: the Voronoi regions of the vertices, edges and face).
pub fn closest_on_triangle(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> [f64; 3] {
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let at = |t: f64, from: [f64; 3], dir: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|k| from[k] + t * dir[k])
    };
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return at(d1 / (d1 - d3), a, ab);
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return at(d2 / (d2 - d6), a, ac);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return at((d4 - d3) / ((d4 - d3) + (d5 - d6)), b, sub(c, b));
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    std::array::from_fn(|k| a[k] + ab[k] * v + ac[k] * w)
}
