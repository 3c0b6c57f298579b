//! Generators of common mass-spring layouts: a chain and a rectangular grid.

use super::{MassSpringDesc, SpringDesc};

/// A chain of `count` particles from `anchor` along `direction` (any length; normalised),
/// `length` apart, joined by springs of stiffness `k` (N/m) and damping `kd` (N s/m),
/// each particle of mass `mass` (kg), the first one pinned. Gravity is left at zero.
pub fn chain(
    count: usize,
    anchor: [f64; 3],
    direction: [f64; 3],
    length: f64,
    mass: f64,
    k: f64,
    kd: f64,
) -> MassSpringDesc {
    let l = (direction[0].powi(2) + direction[1].powi(2) + direction[2].powi(2)).sqrt();
    let d = if l > 0.0 {
        direction.map(|c| c / l)
    } else {
        [1.0, 0.0, 0.0]
    };
    let positions = (0..count)
        .map(|i| {
            let s = i as f64 * length;
            [
                anchor[0] + s * d[0],
                anchor[1] + s * d[1],
                anchor[2] + s * d[2],
            ]
        })
        .collect();
    let springs = (1..count)
        .map(|i| SpringDesc {
            a: i - 1,
            b: i,
            stiffness: k,
            damping: kd,
            rest_length: None,
        })
        .collect();
    MassSpringDesc {
        positions,
        masses: vec![mass; count],
        springs,
        pinned: if count > 0 { vec![0] } else { vec![] },
        ..Default::default()
    }
}

/// Options of [`grid`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridOptions {
    /// Particles along the first axis (>= 2).
    pub nu: usize,
    /// Particles along the second axis (>= 2).
    pub nv: usize,
    /// Extent (m) along the first and second axes.
    pub size: [f64; 2],
    /// Position of particle (0, 0) (m).
    pub origin: [f64; 3],
    /// Unit direction of the first axis.
    pub u_axis: [f64; 3],
    /// Unit direction of the second axis.
    pub v_axis: [f64; 3],
    /// Total mass (kg), spread evenly over the particles.
    pub total_mass: f64,
    /// Structural spring stiffness (N/m).
    pub structural: f64,
    /// Shear (diagonal) spring stiffness (N/m); 0 leaves them out.
    pub shear: f64,
    /// Bend (second-neighbour) spring stiffness (N/m); 0 leaves them out.
    pub bend: f64,
    /// Damping of every spring (N s/m).
    pub damping: f64,
}

/// A rectangular grid of particles with structural, shear and bend springs (each family
/// left out when its stiffness is zero) and two triangles per cell for output. Particle
/// (i, j) is index `i + nu j`. Nothing is pinned and gravity is zero: the caller decides.
pub fn grid(o: &GridOptions) -> MassSpringDesc {
    let (nu, nv) = (o.nu.max(2), o.nv.max(2));
    let idx = |i: usize, j: usize| i + nu * j;
    let mut positions = Vec::with_capacity(nu * nv);
    for j in 0..nv {
        for i in 0..nu {
            let (s, t) = (
                o.size[0] * i as f64 / (nu - 1) as f64,
                o.size[1] * j as f64 / (nv - 1) as f64,
            );
            positions.push(core::array::from_fn(|c| {
                o.origin[c] + s * o.u_axis[c] + t * o.v_axis[c]
            }));
        }
    }
    let mut springs = Vec::new();
    let mut add = |a: usize, b: usize, k: f64| {
        if k > 0.0 {
            springs.push(SpringDesc {
                a,
                b,
                stiffness: k,
                damping: o.damping,
                rest_length: None,
            });
        }
    };
    for j in 0..nv {
        for i in 0..nu {
            if i + 1 < nu {
                add(idx(i, j), idx(i + 1, j), o.structural);
            }
            if j + 1 < nv {
                add(idx(i, j), idx(i, j + 1), o.structural);
            }
            if i + 1 < nu && j + 1 < nv {
                add(idx(i, j), idx(i + 1, j + 1), o.shear);
                add(idx(i + 1, j), idx(i, j + 1), o.shear);
            }
            if i + 2 < nu {
                add(idx(i, j), idx(i + 2, j), o.bend);
            }
            if j + 2 < nv {
                add(idx(i, j), idx(i, j + 2), o.bend);
            }
        }
    }
    let mut triangles = Vec::with_capacity(2 * (nu - 1) * (nv - 1));
    for j in 0..nv - 1 {
        for i in 0..nu - 1 {
            let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
            triangles.push([a as u32, b as u32, c as u32]);
            triangles.push([a as u32, c as u32, d as u32]);
        }
    }
    let count = nu * nv;
    MassSpringDesc {
        positions,
        masses: vec![o.total_mass / count as f64; count],
        springs,
        triangles,
        ..Default::default()
    }
}
