//! Mass properties: mass, centre of mass and inertia tensor of analytic shapes (closed
//! forms) and of closed triangle meshes.
//!
//! A mesh's integrals are exact for the polyhedron: by the divergence theorem the volume
//! integrals of 1, x and x xᵀ are sums over the signed tetrahedra that join the origin to
//! each outward-oriented triangle (Mirtich 1996 reaches the same values through surface
//! projections). For the tetrahedron `(0, a, b, c)` of signed volume `V = det[a b c] / 6`:
//! `∫ x dV = V (a + b + c) / 4` and `∫ x xᵀ dV = V / 20 (a aᵀ + b bᵀ + c cᵀ + s sᵀ)` with
//! `s = a + b + c` (the canonical tetrahedron's covariance, Tonon 2004). The inertia about
//! the centre is `tr(C) I - C` for the covariance `C` there.

use crate::collide::check_closed;
use crate::io::Mesh;
use crate::validate::ModelError;

/// Mass (kg), centre of mass (m) and inertia tensor about it (kg m², rows).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MassProperties {
    /// kg.
    pub mass: f64,
    /// Centre of mass (m), in the shape's frame.
    pub center: [f64; 3],
    /// Inertia tensor about the centre of mass (kg m²), in the shape's axes.
    pub inertia: [[f64; 3]; 3],
}

fn diag(d: [f64; 3]) -> [[f64; 3]; 3] {
    [[d[0], 0.0, 0.0], [0.0, d[1], 0.0], [0.0, 0.0, d[2]]]
}

/// A solid box of half extents `h` (m) and `density` (kg/m³), centred at the origin:
/// `I = m/3 diag(hy² + hz², hx² + hz², hx² + hy²)`.
pub fn solid_box(h: [f64; 3], density: f64) -> MassProperties {
    let m = density * 8.0 * h[0] * h[1] * h[2];
    let [x, y, z] = h.map(|v| v * v);
    MassProperties {
        mass: m,
        center: [0.0; 3],
        inertia: diag([m / 3.0 * (y + z), m / 3.0 * (x + z), m / 3.0 * (x + y)]),
    }
}

/// A solid ball of radius `r`: `I = 2/5 m r²`.
pub fn solid_sphere(r: f64, density: f64) -> MassProperties {
    let m = density * 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    MassProperties {
        mass: m,
        center: [0.0; 3],
        inertia: diag([0.4 * m * r * r; 3]),
    }
}

/// A solid capsule along y: a cylinder of half height `hh` and radius `r` capped by two
/// hemispheres. About y: `m_c r²/2 + 2/5 m_s r²`; about x and z the cylinder's
/// `m_c (r²/4 + (2 hh)²/12)` and the caps' `m_s (2/5 r² + hh² + 3/4 hh r)` (each cap's
/// centroid is `3r/8` from its flat face; parallel-axis theorem).
pub fn solid_capsule(hh: f64, r: f64, density: f64) -> MassProperties {
    let pi = std::f64::consts::PI;
    let mc = density * pi * r * r * 2.0 * hh;
    let ms = density * 4.0 / 3.0 * pi * r.powi(3);
    let axial = mc * r * r / 2.0 + ms * 0.4 * r * r;
    let side = mc * (r * r / 4.0 + (2.0 * hh).powi(2) / 12.0)
        + ms * (0.4 * r * r + hh * hh + 0.75 * hh * r);
    MassProperties {
        mass: mc + ms,
        center: [0.0; 3],
        inertia: diag([side, axial, side]),
    }
}

/// The mass properties of the solid a closed, outward-oriented triangle mesh bounds, at
/// `density`. Errors: the mesh is not closed ([`check_closed`]: open edges, inconsistent
/// orientation, degenerate triangles, non-finite vertices) or bounds no positive volume
/// (inward-facing triangles).
pub fn mesh(surface: &Mesh, density: f64) -> Result<MassProperties, ModelError> {
    check_closed(surface)?;
    let m = surface.as_ref();
    let (mut vol, mut first, mut second) = (0.0, [0.0; 3], [[0.0; 3]; 3]);
    for tri in surface.triangles.iter() {
        let [a, b, c] = tri.map(|v| m.vertex(v as usize));
        let det = a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]);
        let v = det / 6.0;
        vol += v;
        let s = [a[0] + b[0] + c[0], a[1] + b[1] + c[1], a[2] + b[2] + c[2]];
        for i in 0..3 {
            first[i] += v * s[i] / 4.0;
            for j in 0..3 {
                second[i][j] += v / 20.0 * (a[i] * a[j] + b[i] * b[j] + c[i] * c[j] + s[i] * s[j]);
            }
        }
    }
    if vol.is_nan() || vol <= 0.0 {
        return Err(ModelError::Element {
            item: "mesh",
            index: 0,
            what: format!(
                "bounds a volume of {vol:e} m^3: its triangles must face outward (counter-clockwise seen from outside)"
            ),
        });
    }
    let center = first.map(|f| f / vol);
    // Covariance about the centre, times density.
    let mut cov = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            cov[i][j] = density * (second[i][j] - vol * center[i] * center[j]);
        }
    }
    let tr = cov[0][0] + cov[1][1] + cov[2][2];
    let mut inertia = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            inertia[i][j] = if i == j { tr } else { 0.0 } - cov[i][j];
        }
    }
    Ok(MassProperties {
        mass: density * vol,
        center,
        inertia,
    })
}
