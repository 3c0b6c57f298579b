//! Blendshapes (course notes section 11; Lewis, Anjyo, Rhee, Zhang, Pighin and Deng 2014,
//! "Practice and theory of blendshape facial models"): the delta form
//! `f = b0 + sum_k w_k d_k`, corrective combination shapes, FACS-style action units, and
//! a weight solve that fits weights in `[0, 1]` to target positions.
//!
//! - A **base shape** adds its delta `d_k = b_k - b0` at its weight.
//! - A **combination shape** (Lewis et al. section 4.3) corrects what several base shapes
//!   do together: its delta is added at the product of their weights, so it is invisible
//!   unless all of them are on.
//! - **Action units** map named controls (FACS units such as `AU12`) to weights of base
//!   shapes; a unit's value times its mapping is summed, then clamped to `[0, 1]`.
//! - **Weight solve** (section 5): `min |B w - (x - b0)|^2 + mu |w|^2` over the base
//!   shapes' weights with `0 <= w <= 1`, on all vertices or a chosen subset (markers).
//!   `B^T B + mu I` is formed once (shapes x shapes); the bounded problem is a convex QP
//!   solved by cyclic projected coordinate descent to a relative change of 1e-12 (exact
//!   at convergence for a box; a few dozen sweeps for face rigs of tens of shapes).
//!   Combination shapes are left out of the fit (they would make it nonlinear); their
//!   weights follow from the fitted ones.

/// One shape of a rig being built.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeDesc {
    /// Its name.
    pub name: String,
    /// The sculpted positions (component-major, 3n like the neutral).
    pub positions: Vec<f64>,
    /// For a combination shape, the base shapes it corrects (indices, at least two);
    /// empty for a base shape. Its positions are then the *corrective delta* added on
    /// top of the base shapes' sum (as rigs store them), not a full face.
    pub combines: Vec<usize>,
}

/// A rig being built: the neutral face and the shapes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BlendshapeDesc {
    /// The neutral positions, component-major (3n).
    pub neutral: Vec<f64>,
    /// The shapes, base shapes before the combinations that name them.
    pub shapes: Vec<ShapeDesc>,
}

/// A shape the rig refuses: its index and name, and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("shape {index} ({name}): {message}")]
pub struct ShapeError {
    /// The shape.
    pub index: usize,
    /// Its name.
    pub name: String,
    /// What is wrong.
    pub message: String,
}

/// A checked blendshape rig (immutable).
#[derive(Clone, Debug)]
pub struct Blendshapes {
    neutral: Vec<f64>,
    names: Vec<String>,
    /// One delta per shape, component-major.
    deltas: Vec<Vec<f64>>,
    /// Per shape, the base shapes it combines (empty for base shapes).
    combines: Vec<Vec<usize>>,
}

impl BlendshapeDesc {
    /// Checks and builds: every shape as long as the neutral, coordinates finite, names
    /// unique, combinations of at least two distinct earlier base shapes.
    pub fn build(&self) -> Result<Blendshapes, ShapeError> {
        let m = self.neutral.len();
        let err = |i: usize, message: String| ShapeError {
            index: i,
            name: self
                .shapes
                .get(i)
                .map(|s| s.name.clone())
                .unwrap_or_default(),
            message,
        };
        if !m.is_multiple_of(3) || !self.neutral.iter().all(|v| v.is_finite()) {
            return Err(ShapeError {
                index: 0,
                name: "neutral".into(),
                message: format!("{m} coordinates: not a whole number of finite 3-vectors"),
            });
        }
        let mut deltas = Vec::with_capacity(self.shapes.len());
        for (i, s) in self.shapes.iter().enumerate() {
            if s.positions.len() != m {
                return Err(err(
                    i,
                    format!("{} coordinates, the neutral has {m}", s.positions.len()),
                ));
            }
            if !s.positions.iter().all(|v| v.is_finite()) {
                return Err(err(i, "a coordinate is not finite".into()));
            }
            if self.shapes[..i].iter().any(|o| o.name == s.name) {
                return Err(err(i, "its name is used by an earlier shape".into()));
            }
            if !s.combines.is_empty() {
                let mut seen = s.combines.clone();
                seen.sort_unstable();
                seen.dedup();
                if seen.len() != s.combines.len() || s.combines.len() < 2 {
                    return Err(err(
                        i,
                        "a combination needs at least two distinct base shapes".into(),
                    ));
                }
                if let Some(&b) = s
                    .combines
                    .iter()
                    .find(|&&b| b >= i || !self.shapes[b].combines.is_empty())
                {
                    return Err(err(
                        i,
                        format!("combines shape {b}, which is not an earlier base shape"),
                    ));
                }
                deltas.push(s.positions.clone());
            } else {
                deltas.push(
                    s.positions
                        .iter()
                        .zip(&self.neutral)
                        .map(|(p, b)| p - b)
                        .collect(),
                );
            }
        }
        Ok(Blendshapes {
            neutral: self.neutral.clone(),
            names: self.shapes.iter().map(|s| s.name.clone()).collect(),
            deltas,
            combines: self.shapes.iter().map(|s| s.combines.clone()).collect(),
        })
    }
}

impl Blendshapes {
    /// The number of shapes.
    pub fn len(&self) -> usize {
        self.names.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    /// Shape names.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The index of shape `name`.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Whether shape `k` is a base shape (not a combination).
    pub fn is_base(&self, k: usize) -> bool {
        self.combines[k].is_empty()
    }

    /// The face for `weights` (one per shape; a combination shape's own entry is
    /// ignored: its weight is the product of its base shapes') into `out` (3n).
    pub fn evaluate(&self, weights: &[f64], out: &mut [f64]) {
        assert_eq!(weights.len(), self.len(), "one weight per shape");
        assert_eq!(out.len(), self.neutral.len(), "3n output coordinates");
        out.copy_from_slice(&self.neutral);
        for (k, d) in self.deltas.iter().enumerate() {
            let w = if self.combines[k].is_empty() {
                weights[k]
            } else {
                self.combines[k].iter().map(|&b| weights[b]).product()
            };
            if w != 0.0 {
                for (o, x) in out.iter_mut().zip(d) {
                    *o += w * x;
                }
            }
        }
    }

    /// Fits the base shapes' weights to `target` (3n positions) on the vertices
    /// `markers` (all when empty) with damping `mu` >= 0 and bounds `[0, 1]` (see the
    /// module docs); combination shapes get weight 0 in the result. Returns the
    /// weights and the sweeps taken.
    pub fn solve_weights(
        &self,
        target: &[f64],
        markers: &[usize],
        mu: f64,
    ) -> Result<(Vec<f64>, usize), String> {
        let m = self.neutral.len();
        let n = m / 3;
        if target.len() != m {
            return Err(format!(
                "{} target coordinates, the rig has {m}",
                target.len()
            ));
        }
        if !target.iter().all(|v| v.is_finite()) || mu < 0.0 || !mu.is_finite() {
            return Err("target and damping must be finite (damping >= 0)".into());
        }
        if let Some(&v) = markers.iter().find(|&&v| v >= n) {
            return Err(format!("marker vertex {v} is not one of the {n} vertices"));
        }
        let base: Vec<usize> = (0..self.len()).filter(|&k| self.is_base(k)).collect();
        let rows: Vec<usize> = if markers.is_empty() {
            (0..m).collect()
        } else {
            markers
                .iter()
                .flat_map(|&v| [v, n + v, 2 * n + v])
                .collect()
        };
        let k = base.len();
        // Normal equations over the chosen rows.
        let mut g = vec![0.0; k * k];
        let mut rhs = vec![0.0; k];
        for a in 0..k {
            let da = &self.deltas[base[a]];
            for b in a..k {
                let db = &self.deltas[base[b]];
                let v: f64 = rows.iter().map(|&r| da[r] * db[r]).sum();
                g[a * k + b] = v;
                g[b * k + a] = v;
            }
            g[a * k + a] += mu;
            rhs[a] = rows
                .iter()
                .map(|&r| da[r] * (target[r] - self.neutral[r]))
                .sum();
        }
        let mut w = vec![0.0; k];
        let mut sweeps = 0;
        for _ in 0..10_000 {
            sweeps += 1;
            let mut change: f64 = 0.0;
            let mut size: f64 = 0.0;
            for a in 0..k {
                let diag = g[a * k + a];
                if diag <= 0.0 {
                    continue; // a shape that moves none of the rows
                }
                let r: f64 = rhs[a] - (0..k).map(|b| g[a * k + b] * w[b]).sum::<f64>();
                let new = (w[a] + r / diag).clamp(0.0, 1.0);
                change = change.max((new - w[a]).abs());
                size = size.max(new.abs());
                w[a] = new;
            }
            if change <= 1e-12 * size.max(1e-300) || change == 0.0 {
                break;
            }
        }
        let mut out = vec![0.0; self.len()];
        for (a, &s) in base.iter().enumerate() {
            out[s] = w[a];
        }
        Ok((out, sweeps))
    }
}

/// FACS-style action units: named controls, each driving base shapes by fixed amounts.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ActionUnits {
    /// Each unit: its name (`AU12`) and the `(shape, amount)` it drives.
    pub units: Vec<(String, Vec<(usize, f64)>)>,
}

impl ActionUnits {
    /// The shape weights for unit `values` (one per unit): `sum_u value_u amount`,
    /// clamped to `[0, 1]`, into `weights` (one per shape of the rig). Errors name a
    /// unit that drives a shape the rig lacks, or the wrong count of values.
    pub fn weights(
        &self,
        values: &[f64],
        rig: &Blendshapes,
        weights: &mut [f64],
    ) -> Result<(), String> {
        if values.len() != self.units.len() || weights.len() != rig.len() {
            return Err(format!(
                "{} unit values for {} units, {} weights for {} shapes",
                values.len(),
                self.units.len(),
                weights.len(),
                rig.len()
            ));
        }
        weights.iter_mut().for_each(|w| *w = 0.0);
        for ((name, drives), &v) in self.units.iter().zip(values) {
            for &(s, amount) in drives {
                if s >= rig.len() || !rig.is_base(s) {
                    return Err(format!(
                        "unit {name} drives shape {s}, not a base shape of the rig"
                    ));
                }
                weights[s] += v * amount;
            }
        }
        for w in weights.iter_mut() {
            *w = if w.is_finite() {
                w.clamp(0.0, 1.0)
            } else {
                0.0
            };
        }
        Ok(())
    }
}
