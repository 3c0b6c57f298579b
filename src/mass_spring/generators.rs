//! Generators of common mass-spring layouts: a chain, a rectangular grid and a 3-D lattice.

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

/// Options of [`lattice`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LatticeOptions {
    /// Particles along x, y and z (each >= 2).
    pub n: [usize; 3],
    /// Rest position of particle (0, 0, 0) (m).
    pub origin: [f64; 3],
    /// Rest extent along x, y and z (m).
    pub size: [f64; 3],
    /// Mass of each particle (kg).
    pub mass: f64,
    /// Structural spring stiffness (N/m): the 6 direct neighbours.
    pub structural: f64,
    /// Shear spring stiffness (N/m): face and body diagonals; 0 leaves them out.
    pub shear: f64,
    /// Bend spring stiffness (N/m): second neighbours along each axis; 0 leaves them out.
    pub bend: f64,
    /// Damping of every spring (N s/m).
    pub damping: f64,
}

impl LatticeOptions {
    /// Index of particle (i, j, k): i outermost and k innermost, the order of the jello
    /// assignment's world files (`p[i][j][k]`).
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (i * self.n[1] + j) * self.n[2] + k
    }

    /// Rest position of particle (i, j, k) (m).
    pub fn rest_position(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        let ijk = [i, j, k];
        std::array::from_fn(|a| {
            self.origin[a] + self.size[a] * ijk[a] as f64 / (self.n[a] - 1).max(1) as f64
        })
    }
}

/// A block of `nx x ny x nz` particles (course notes, section 4, the jello cube) with
/// structural springs to the 6 direct neighbours, shear springs along every face and body
/// diagonal of each cell, and bend springs to the second neighbour along each axis. Rest
/// lengths come from the rest lattice, so the caller may move `positions` afterwards (a
/// world file's deformed start) without changing them. The surface is triangulated for
/// output, two triangles per face cell, facing outwards. Nothing is pinned, gravity is
/// zero, and the spring Jacobians' definiteness fix is on.
pub fn lattice(o: &LatticeOptions) -> MassSpringDesc {
    let [nx, ny, nz] = o.n.map(|c| c.max(2));
    let o = LatticeOptions {
        n: [nx, ny, nz],
        ..*o
    };
    let mut positions = Vec::with_capacity(nx * ny * nz);
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                positions.push(o.rest_position(i, j, k));
            }
        }
    }
    // Offsets to the neighbours each particle links to (one direction of each pair).
    let mut offsets: Vec<([i64; 3], f64)> = Vec::new();
    for di in -1i64..=1 {
        for dj in -1i64..=1 {
            for dk in -1i64..=1 {
                let d = [di, dj, dk];
                let first = d.iter().find(|&&c| c != 0);
                if first.is_none_or(|&c| c < 0) {
                    continue;
                }
                let nonzero = d.iter().filter(|&&c| c != 0).count();
                offsets.push((d, if nonzero == 1 { o.structural } else { o.shear }));
            }
        }
    }
    for a in 0..3 {
        let mut d = [0i64; 3];
        d[a] = 2;
        offsets.push((d, o.bend));
    }
    let mut springs = Vec::new();
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                for &(d, stiffness) in &offsets {
                    if stiffness <= 0.0 {
                        continue;
                    }
                    let (p, q, r) = (i as i64 + d[0], j as i64 + d[1], k as i64 + d[2]);
                    if p < 0 || q < 0 || r < 0 || p >= nx as i64 || q >= ny as i64 || r >= nz as i64
                    {
                        continue;
                    }
                    let (a, b) = (
                        o.index(i, j, k),
                        o.index(p as usize, q as usize, r as usize),
                    );
                    let (pa, pb) = (positions[a], positions[b]);
                    let rest = ((pa[0] - pb[0]).powi(2)
                        + (pa[1] - pb[1]).powi(2)
                        + (pa[2] - pb[2]).powi(2))
                    .sqrt();
                    springs.push(SpringDesc {
                        a,
                        b,
                        stiffness,
                        damping: o.damping,
                        rest_length: Some(rest),
                    });
                }
            }
        }
    }
    // Surface: on the face normal to axis `a` at index 0 or n-1, the other two axes
    // (b, c) = (a+1, a+2) run over the face; (e_b, e_c) is right-handed about +e_a.
    let mut triangles = Vec::new();
    let n = [nx, ny, nz];
    for a in 0..3 {
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        for side in [0, n[a] - 1] {
            let at = |u: usize, v: usize| {
                let mut ijk = [0; 3];
                ijk[a] = side;
                ijk[b] = u;
                ijk[c] = v;
                o.index(ijk[0], ijk[1], ijk[2]) as u32
            };
            for u in 0..n[b] - 1 {
                for v in 0..n[c] - 1 {
                    let (p00, p10, p11, p01) =
                        (at(u, v), at(u + 1, v), at(u + 1, v + 1), at(u, v + 1));
                    if side == 0 {
                        triangles.push([p00, p11, p10]);
                        triangles.push([p00, p01, p11]);
                    } else {
                        triangles.push([p00, p10, p11]);
                        triangles.push([p00, p11, p01]);
                    }
                }
            }
        }
    }
    let count = nx * ny * nz;
    MassSpringDesc {
        positions,
        masses: vec![o.mass; count],
        springs,
        triangles,
        // A jello cube compresses springs on every impact: keep implicit systems definite.
        definiteness_fix: true,
        ..Default::default()
    }
}
