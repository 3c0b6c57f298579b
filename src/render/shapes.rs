//! Small procedural meshes for tests, benchmarks and examples.

use crate::io::Mesh;

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
