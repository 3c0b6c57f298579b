//! Small procedural meshes: obstacle surfaces (sphere, box, capsule) for previews, and
//! test scenes for the renderer and its benchmarks. Geometry only: physics and the
//! renderer both use it, neither through the other.

use crate::io::Mesh;
use largestep_kernels::v3::{cross, length_and_unit, sub};

fn mesh(points: &[[f64; 3]], triangles: Vec<[u32; 3]>, segments: Vec<[u32; 2]>) -> Mesh {
    Mesh {
        positions: crate::soa::Vec3s::from_aos(points).into_vec(),
        triangles: triangles.into(),
        segments: segments.into(),
    }
}

/// A closed UV sphere: `rings >= 2` latitude bands and `sectors >= 3` longitudes, with a
/// vertex at each pole; `2 * sectors * (rings - 1)` triangles.
pub fn uv_sphere(center: [f64; 3], radius: f64, rings: usize, sectors: usize) -> Mesh {
    let (rings, sectors) = (rings.max(2), sectors.max(3));
    let mut p = vec![[center[0], center[1] + radius, center[2]]];
    for r in 1..rings {
        let th = std::f64::consts::PI * r as f64 / rings as f64;
        for s in 0..sectors {
            let ph = std::f64::consts::TAU * s as f64 / sectors as f64;
            p.push([
                center[0] + radius * th.sin() * ph.cos(),
                center[1] + radius * th.cos(),
                center[2] - radius * th.sin() * ph.sin(),
            ]);
        }
    }
    p.push([center[0], center[1] - radius, center[2]]);
    let south = (p.len() - 1) as u32;
    let ring = |r: usize, s: usize| (1 + (r - 1) * sectors + s % sectors) as u32;
    let mut t = Vec::new();
    for s in 0..sectors {
        t.push([0, ring(1, s), ring(1, s + 1)]);
        for r in 1..rings - 1 {
            t.push([ring(r, s), ring(r + 1, s), ring(r + 1, s + 1)]);
            t.push([ring(r, s), ring(r + 1, s + 1), ring(r, s + 1)]);
        }
        t.push([ring(rings - 1, s), south, ring(rings - 1, s + 1)]);
    }
    mesh(&p, t, Vec::new())
}

/// A square sheet of `n x n` vertices (`2 (n-1)^2` triangles) of side `size` centred on
/// `center` in the x-z plane, rippled in y with amplitude `amplitude`, like draped cloth.
pub fn wavy_sheet(center: [f64; 3], size: f64, n: usize, amplitude: f64) -> Mesh {
    let n = n.max(2);
    let mut p = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            let (u, v) = (i as f64 / (n - 1) as f64, j as f64 / (n - 1) as f64);
            let r = ((u - 0.5).powi(2) + (v - 0.5).powi(2)).sqrt();
            p.push([
                center[0] + size * (u - 0.5),
                center[1] + amplitude * (12.0 * r).cos() * (1.0 - r),
                center[2] + size * (v - 0.5),
            ]);
        }
    }
    let id = |i: usize, j: usize| (j * n + i) as u32;
    let mut t = Vec::with_capacity(2 * (n - 1) * (n - 1));
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            t.push([id(i, j), id(i, j + 1), id(i + 1, j)]);
            t.push([id(i + 1, j), id(i, j + 1), id(i + 1, j + 1)]);
        }
    }
    mesh(&p, t, Vec::new())
}

/// A hanging chain of `count` particles joined by segments, from `start` along `step`.
pub fn chain(start: [f64; 3], step: [f64; 3], count: usize) -> Mesh {
    let p: Vec<[f64; 3]> = (0..count)
        .map(|i| std::array::from_fn(|k| start[k] + i as f64 * step[k]))
        .collect();
    let s = (1..count as u32).map(|i| [i - 1, i]).collect();
    mesh(&p, Vec::new(), s)
}

/// A mesh from vertex positions and triangles (for small hand-made tests).
pub fn from_triangles(points: &[[f64; 3]], triangles: &[[u32; 3]]) -> Mesh {
    mesh(points, triangles.to_vec(), Vec::new())
}

/// A solid axis-aligned box from `min` to `max`: 8 corners, 12 outward triangles.
pub fn cuboid(min: [f64; 3], max: [f64; 3]) -> Mesh {
    let p: Vec<[f64; 3]> = (0..8)
        .map(|i| {
            [
                if i & 1 == 0 { min[0] } else { max[0] },
                if i & 2 == 0 { min[1] } else { max[1] },
                if i & 4 == 0 { min[2] } else { max[2] },
            ]
        })
        .collect();
    // Corner i has bit 0 = x, bit 1 = y, bit 2 = z; two triangles per face, wound
    // counter-clockwise seen from outside.
    let quads = [
        [0, 4, 6, 2], // -x
        [1, 3, 7, 5], // +x
        [0, 1, 5, 4], // -y
        [2, 6, 7, 3], // +y
        [0, 2, 3, 1], // -z
        [4, 5, 7, 6], // +z
    ];
    let t = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    mesh(&p, t, Vec::new())
}

/// A capsule: the points within `radius` of the segment `a`-`b`, as two UV spheres at the
/// ends and an open cylinder of `sectors` sides between them (overlapping, which a
/// depth-buffered preview does not mind).
pub fn capsule(a: [f64; 3], b: [f64; 3], radius: f64, sectors: usize) -> Mesh {
    let sectors = sectors.max(3);
    let d = sub(b, a);
    let mut points: Vec<[f64; 3]> = Vec::new();
    let mut tris: Vec<[u32; 3]> = Vec::new();
    let mut append = |m: &Mesh| {
        let base = points.len() as u32;
        let n = m.positions.len() / 3;
        points.extend((0..n).map(|i| largestep_kernels::get3(&m.positions, n, i)));
        tris.extend(m.triangles.iter().map(|t| t.map(|v| v + base)));
    };
    append(&uv_sphere(a, radius, sectors / 2 + 1, sectors));
    append(&uv_sphere(b, radius, sectors / 2 + 1, sectors));
    // Two unit vectors across the axis (none for a zero-length capsule: two spheres).
    let axis = unit(d);
    let across = axis.and_then(|axis| {
        let helper = if axis[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        unit(cross(axis, helper)).map(|e1| (e1, cross(axis, e1)))
    });
    if let Some((e1, e2)) = across {
        let base = points.len() as u32;
        for s in 0..sectors {
            let ph = std::f64::consts::TAU * s as f64 / sectors as f64;
            let r: [f64; 3] =
                std::array::from_fn(|k| radius * (ph.cos() * e1[k] + ph.sin() * e2[k]));
            points.push(std::array::from_fn(|k| a[k] + r[k]));
            points.push(std::array::from_fn(|k| b[k] + r[k]));
        }
        for s in 0..sectors as u32 {
            let n = (s + 1) % sectors as u32;
            let (a0, b0, a1, b1) = (
                base + 2 * s,
                base + 2 * s + 1,
                base + 2 * n,
                base + 2 * n + 1,
            );
            tris.push([a0, a1, b1]);
            tris.push([a0, b1, b0]);
        }
    }
    mesh(&points, tris, Vec::new())
}

/// `a / |a|`, `None` for a zero or non-finite vector.
fn unit(a: [f64; 3]) -> Option<[f64; 3]> {
    length_and_unit(a).map(|(_, u)| u)
}

/// The faces of the convex region where `n . x + d >= 0` for every plane `(n, d)` (unit
/// normals) and that lies inside the box `region`: one polygon per plane, as a triangle
/// fan wound counter-clockwise seen from the side its normal points to, and its outline
/// as segments. The region's own sides are not drawn; planes that leave no face give
/// nothing.
pub fn convex_faces(planes: &[([f64; 3], f64)], region: ([f64; 3], [f64; 3])) -> Mesh {
    let (lo, hi) = region;
    let centre: [f64; 3] = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let half: f64 = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    // The region's six sides as half-spaces too.
    let sides = (0..6).map(|s| {
        let mut n = [0.0; 3];
        let a = s / 2;
        if s % 2 == 0 {
            n[a] = 1.0;
            (n, -lo[a])
        } else {
            n[a] = -1.0;
            (n, hi[a])
        }
    });
    let all: Vec<([f64; 3], f64)> = planes.iter().copied().chain(sides).collect();
    let (mut points, mut triangles, mut segments) = (Vec::new(), Vec::new(), Vec::new());
    for (i, &(n, d)) in planes.iter().enumerate() {
        // A square on the plane around the region's centre, larger than the region,
        // counter-clockwise about n.
        let any = if n[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        let Some((_, u)) = length_and_unit(cross(any, n)) else {
            continue;
        };
        let v = cross(n, u);
        let h = n.iter().zip(&centre).map(|(a, b)| a * b).sum::<f64>() + d;
        let o: [f64; 3] = std::array::from_fn(|k| centre[k] - h * n[k]);
        let mut poly: Vec<[f64; 3]> = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
            .iter()
            .map(|&(a, b)| std::array::from_fn(|k| o[k] + 2.0 * half * (a * u[k] + b * v[k])))
            .collect();
        for (j, &(m, e)) in all.iter().enumerate() {
            if j != i {
                poly = clip(&poly, m, e);
            }
        }
        // Where three planes meet, clipping leaves the corner twice: keep one.
        let tiny = 1e-9 * half;
        let near = |a: &[f64; 3], b: &[f64; 3]| (0..3).all(|k| (a[k] - b[k]).abs() <= tiny);
        poly.dedup_by(|b, a| near(a, b));
        while poly.len() > 1 && near(&poly[0], &poly[poly.len() - 1]) {
            poly.pop();
        }
        if poly.len() < 3 {
            continue;
        }
        let first = points.len() as u32;
        let k = poly.len() as u32;
        points.extend(poly);
        triangles.extend((1..k - 1).map(|t| [first, first + t, first + t + 1]));
        segments.extend((0..k).map(|t| [first + t, first + (t + 1) % k]));
    }
    mesh(&points, triangles, segments)
}

/// The part of convex polygon `poly` where `m . x + e >= 0` (Sutherland-Hodgman).
fn clip(poly: &[[f64; 3]], m: [f64; 3], e: f64) -> Vec<[f64; 3]> {
    let side = |p: &[f64; 3]| m[0] * p[0] + m[1] * p[1] + m[2] * p[2] + e;
    let mut out = Vec::with_capacity(poly.len() + 1);
    for (k, a) in poly.iter().enumerate() {
        let b = &poly[(k + 1) % poly.len()];
        let (sa, sb) = (side(a), side(b));
        if sa >= 0.0 {
            out.push(*a);
        }
        if (sa >= 0.0) != (sb >= 0.0) {
            let t = sa / (sa - sb);
            out.push(std::array::from_fn(|c| a[c] + t * (b[c] - a[c])));
        }
    }
    out
}

/// A closed tube along +x from the origin: `length`, `radius`, `rings >= 2` rings of
/// `sectors >= 3` vertices, and a centre vertex closing each end. Wound outward. The
/// candy-wrapper test of skinning twists it.
pub fn tube(length: f64, radius: f64, rings: usize, sectors: usize) -> Mesh {
    let (rings, sectors) = (rings.max(2), sectors.max(3));
    let mut p = Vec::with_capacity(rings * sectors + 2);
    for r in 0..rings {
        let x = length * r as f64 / (rings - 1) as f64;
        for s in 0..sectors {
            let ph = std::f64::consts::TAU * s as f64 / sectors as f64;
            p.push([x, radius * ph.cos(), radius * ph.sin()]);
        }
    }
    let (c0, c1) = (p.len() as u32, p.len() as u32 + 1);
    p.push([0.0; 3]);
    p.push([length, 0.0, 0.0]);
    let at = |r: usize, s: usize| (r * sectors + s % sectors) as u32;
    let mut t = Vec::with_capacity(2 * rings * sectors);
    for r in 0..rings - 1 {
        for s in 0..sectors {
            t.push([at(r, s), at(r, s + 1), at(r + 1, s + 1)]);
            t.push([at(r, s), at(r + 1, s + 1), at(r + 1, s)]);
        }
    }
    for s in 0..sectors {
        t.push([c0, at(0, s + 1), at(0, s)]);
        t.push([c1, at(rings - 1, s), at(rings - 1, s + 1)]);
    }
    mesh(&p, t, Vec::new())
}

/// The volume a closed, outward-wound triangle surface encloses (divergence theorem:
/// the sum of the signed tetrahedra from the origin to each triangle).
pub fn enclosed_volume(m: &Mesh) -> f64 {
    let n = m.positions.len() / 3;
    let v = |i: u32| largestep_kernels::get3(&m.positions, n, i as usize);
    m.triangles
        .iter()
        .map(|t| largestep_kernels::v3::dot(v(t[0]), cross(v(t[1]), v(t[2]))) / 6.0)
        .sum()
}
