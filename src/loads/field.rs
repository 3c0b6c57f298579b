//! A force field sampled on a grid (course notes, section 4: the jello assignment's
//! field): the force at a vertex is the trilinear interpolation of the grid values around
//! it (`kernels::interp::sample3_vec_add`), clamped to the boundary values outside the
//! grid. Forces per vertex (N), independent of mass.

use super::{Body, Load};
use crate::simulation::Stage;
use crate::validate::{check, require, ModelError, Rule};
use largestep_kernels::get3;
use largestep_kernels::interp::{sample3_vec, sample3_vec_add, Grid3};

/// An external force field (N per vertex) on a regular grid of nodes, x fastest: node
/// (i, j, k) at `i + nx (j + ny k)`.
#[derive(Clone, Debug, PartialEq)]
pub struct ForceField {
    /// The grid.
    pub grid: Grid3,
    /// Force components at the nodes (N).
    pub force: [Vec<f64>; 3],
}

impl ForceField {
    /// A field from `r^3` samples in the jello world files' order (sample `i r^2 + j r + k`
    /// at node (i, j, k), x outermost) over the box `[lo, hi]`, reordered to the grid
    /// layout (x fastest). `samples.len()` must be `r^3`.
    pub fn from_samples(r: usize, lo: [f64; 3], hi: [f64; 3], samples: &[[f64; 3]]) -> ForceField {
        assert_eq!(samples.len(), r * r * r, "r^3 samples");
        let grid = Grid3::spanning([r; 3], lo, hi);
        let mut force = [
            vec![0.0; r * r * r],
            vec![0.0; r * r * r],
            vec![0.0; r * r * r],
        ];
        for (line, f) in samples.iter().enumerate() {
            let (i, j, k) = (line / (r * r), (line / r) % r, line % r);
            let node = i + r * (j + r * k);
            for c in 0..3 {
                force[c][node] = f[c];
            }
        }
        ForceField { grid, force }
    }
}

impl Load for ForceField {
    fn add_forces(&self, _t: f64, _body: &Body<'_>, x: &[f64], _v: &[f64], f: &mut [f64]) {
        sample3_vec_add(
            f,
            [&self.force[0], &self.force[1], &self.force[2]],
            self.grid,
            x,
            1.0,
        );
    }

    fn work_rate(&self, _t: f64, _body: &Body<'_>, x: &[f64], v: &[f64]) -> Option<f64> {
        let n = x.len() / 3;
        let fields = [&self.force[0][..], &self.force[1], &self.force[2]];
        let p = (0..n)
            .map(|i| {
                let f = sample3_vec(fields, self.grid, get3(x, n, i));
                let vi = get3(v, n, i);
                f[0] * vi[0] + f[1] * vi[1] + f[2] * vi[2]
            })
            .sum();
        Some(p)
    }

    fn validate(&self) -> Result<(), ModelError> {
        let g = self.grid;
        for a in 0..3 {
            let why = "needs at least 2 nodes along each axis";
            require(
                "force_field",
                a,
                "resolution",
                g.n[a] as f64,
                g.n[a] >= 2,
                why,
            )?;
            check("force_field", a, "spacing", g.spacing[a], Rule::Positive)?;
            check("force_field", a, "origin", g.origin[a], Rule::Finite)?;
        }
        for (c, comp) in self.force.iter().enumerate() {
            if comp.len() != g.len() {
                return Err(ModelError::Length {
                    what: ["force_field.fx", "force_field.fy", "force_field.fz"][c],
                    got: comp.len(),
                    expected: g.len(),
                    per: "grid node",
                });
            }
            if let Some(i) = comp.iter().position(|v| !v.is_finite()) {
                return Err(ModelError::Value {
                    item: "force_field node",
                    index: i,
                    field: ["fx", "fy", "fz"][c],
                    value: comp[i],
                    why: "must be finite",
                });
            }
        }
        Ok(())
    }

    fn stage(&self) -> Stage {
        Stage::built("force field", format!("{:?} nodes, trilinear", self.grid.n))
    }
}
