//! Wind: a drag force on every surface triangle towards the air's velocity relative to it,
//! along the triangle's normal, `f = drag A ((w - v) . n) n` (A the current area, v the
//! mean of its vertices' velocities), split equally among its vertices. The air velocity
//! can gust: `w(t, x) = velocity (1 + gust sin(2 pi (frequency t - x . d / wavelength)))`
//! with `d` the wind's direction and `wavelength = |velocity| / frequency` (gusts travel
//! with the wind).

use super::{Body, Load};
use crate::simulation::Stage;
use crate::validate::{check, ModelError, Rule};
use largestep_kernels::gather_nodes;
use largestep_kernels::v3::{cross, dot, sub};

/// Wind on a model's surface triangles (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wind {
    /// Mean air velocity (m/s).
    pub velocity: [f64; 3],
    /// Drag coefficient (N s/m^3 = kg/(m^2 s)), >= 0.
    pub drag: f64,
    /// Relative gust amplitude, >= 0 (0: steady).
    pub gust: f64,
    /// Gust frequency (Hz), >= 0.
    pub frequency: f64,
}

impl Wind {
    /// Calls `each(triangle, s, nn)` for every triangle the wind pushes: each of its three
    /// vertices gets the force `s nn` (N).
    fn for_each_force(
        &self,
        t: f64,
        body: &Body<'_>,
        x: &[f64],
        v: &[f64],
        mut each: impl FnMut(&[u32; 3], f64, [f64; 3]),
    ) {
        let w = self;
        let n = body.mass.len();
        let speed = dot(w.velocity, w.velocity).sqrt();
        for tri in body.triangles {
            let xs = gather_nodes(x, n, tri);
            // N = e1 x e2 = 2 A n.
            let nn = cross(sub(xs[1], xs[0]), sub(xs[2], xs[0]));
            let len2 = dot(nn, nn);
            if len2.is_nan() || len2 <= 0.0 {
                continue;
            }
            let mut air = w.velocity;
            if w.gust > 0.0 && w.frequency > 0.0 && speed > 0.0 {
                let centre: [f64; 3] =
                    std::array::from_fn(|c| (xs[0][c] + xs[1][c] + xs[2][c]) / 3.0);
                let along = dot(centre, w.velocity) / speed;
                let phase = std::f64::consts::TAU * (w.frequency * t - along * w.frequency / speed);
                let s = 1.0 + w.gust * phase.sin();
                air = air.map(|c| c * s);
            }
            let vs = gather_nodes(v, n, tri);
            let rel: [f64; 3] =
                std::array::from_fn(|c| air[c] - (vs[0][c] + vs[1][c] + vs[2][c]) / 3.0);
            // drag A (rel . n) n = drag (rel . N) N / (2 |N|), a third to each vertex.
            let s = w.drag * dot(rel, nn) / (2.0 * len2.sqrt()) / 3.0;
            each(tri, s, nn);
        }
    }
}

impl Load for Wind {
    fn add_forces(&self, t: f64, body: &Body<'_>, x: &[f64], v: &[f64], f: &mut [f64]) {
        let n = body.mass.len();
        self.for_each_force(t, body, x, v, |tri, s, nn| {
            for &i in tri {
                for c in 0..3 {
                    f[c * n + i as usize] += s * nn[c];
                }
            }
        });
    }

    fn work_rate(&self, t: f64, body: &Body<'_>, x: &[f64], v: &[f64]) -> Option<f64> {
        let n = body.mass.len();
        let mut p = 0.0;
        self.for_each_force(t, body, x, v, |tri, s, nn| {
            let vs = gather_nodes(v, n, tri);
            p += s * (dot(nn, vs[0]) + dot(nn, vs[1]) + dot(nn, vs[2]));
        });
        Some(p)
    }

    fn validate(&self) -> Result<(), ModelError> {
        for (c, &x) in self.velocity.iter().enumerate() {
            let field = ["velocity.x", "velocity.y", "velocity.z"][c];
            check("wind", 0, field, x, Rule::Finite)?;
        }
        for (field, x) in [
            ("drag", self.drag),
            ("gust", self.gust),
            ("frequency", self.frequency),
        ] {
            check("wind", 0, field, x, Rule::NonNegative)?;
        }
        Ok(())
    }

    fn stage(&self) -> Stage {
        Stage::built(
            "wind",
            format!("air {:?} m/s, drag {}", self.velocity, self.drag),
        )
    }
}
