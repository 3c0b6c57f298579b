//! Cloth meshes: a rectangular grid with (u, v) from the grid.

use super::{ClothDesc, ClothMaterial};
use crate::simulation::StepControl;

/// Options of [`cloth_grid`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClothGridOptions {
    /// Vertices along u (>= 2).
    pub nu: usize,
    /// Vertices along v (>= 2).
    pub nv: usize,
    /// Extent along u and v (m): the rest (u, v) of vertex (i, j) is
    /// `(size[0] i / (nu - 1), size[1] j / (nv - 1))`.
    pub size: [f64; 2],
    /// Position of vertex (0, 0) (m).
    pub origin: [f64; 3],
    /// Unit direction of u in space.
    pub u_axis: [f64; 3],
    /// Unit direction of v in space.
    pub v_axis: [f64; 3],
    /// Material.
    pub material: ClothMaterial,
}

/// A flat rectangular sheet, vertex (i, j) at index `i + nu j`, two triangles per cell
/// (alternating diagonals, so the sheet has no preferred shear direction), placed at
/// its rest (u, v). Nothing pinned, no gravity: the caller decides. The definiteness fix
/// is on.
pub fn cloth_grid(o: &ClothGridOptions) -> ClothDesc {
    let (nu, nv) = (o.nu.max(2), o.nv.max(2));
    let mut positions = Vec::with_capacity(nu * nv);
    let mut uv = Vec::with_capacity(nu * nv);
    for j in 0..nv {
        for i in 0..nu {
            let (s, t) = (
                o.size[0] * i as f64 / (nu - 1) as f64,
                o.size[1] * j as f64 / (nv - 1) as f64,
            );
            uv.push([s, t]);
            positions.push(std::array::from_fn(|c| {
                o.origin[c] + s * o.u_axis[c] + t * o.v_axis[c]
            }));
        }
    }
    let id = |i: usize, j: usize| (i + nu * j) as u32;
    let mut triangles = Vec::with_capacity(2 * (nu - 1) * (nv - 1));
    for j in 0..nv - 1 {
        for i in 0..nu - 1 {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                triangles.push([a, b, c]);
                triangles.push([a, c, d]);
            } else {
                triangles.push([a, b, d]);
                triangles.push([b, c, d]);
            }
        }
    }
    ClothDesc {
        positions,
        velocities: Vec::new(),
        uv,
        triangles,
        material: o.material,
        gravity: [0.0; 3],
        pinned: Vec::new(),
        obstacles: Vec::new(),
        wind: None,
        paths: Vec::new(),
        step_control: StepControl::CLOTH,
        friction: 0.0,
        definiteness_fix: true,
        self_collision: None,
    }
}
