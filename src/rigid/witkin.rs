//! Constrained particle dynamics after Witkin ("Physically based modeling: constrained
//! dynamics", SIGGRAPH course notes; course notes section 13).
//!
//! Particles of mass `m_i` at `q` move under forces `Q` (gravity) and constraint forces
//! `Q̂ = Jᵀ λ` that keep every scalar constraint `C_k(q) = 0`. Asking the constraints'
//! second derivative to vanish, `C̈ = J q̈ + J̇ q̇ = 0` with `q̈ = W (Q + Q̂)`, `W = M^-1`,
//! gives the multipliers from
//!
//! `J W Jᵀ λ = -J̇ q̇ - J W Q - ks C - kd Ċ`,
//!
//! where the feedback terms `ks C + kd Ċ` pull back the drift that integrating
//! accelerations leaves (Witkin's section 6). The matrix is symmetric positive definite
//! for independent constraints; it is solved densely by Cholesky (these systems have
//! tens of constraints), and redundant constraints are reported.
//!
//! Constraints (each `C` scaled so that `J` is a plain difference of positions):
//! - distance between two particles: `C = 1/2 (|xi - xj|² - L²)`;
//! - distance to a fixed point (a pendulum's pivot): `C = 1/2 (|xi - p|² - L²)`;
//! - a bead on a circular wire (centre `c`, unit normal `n`, radius `r`): the sphere
//!   `1/2 (|xi - c|² - r²)` and the plane `(xi - c) n`.
//!
//! States advance by explicit Euler, symplectic Euler or classical Runge-Kutta; each
//! stage solves for the multipliers at its own state.

use nalgebra::{DMatrix, DVector};

/// One constraint of a [`Witkin`] system.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Constraint {
    /// `|x_a - x_b| = length`.
    Distance {
        /// Particles.
        a: usize,
        /// Particles.
        b: usize,
        /// m.
        length: f64,
    },
    /// `|x_a - point| = length`.
    Anchor {
        /// Particle.
        a: usize,
        /// The fixed point (m).
        point: [f64; 3],
        /// m.
        length: f64,
    },
    /// Particle `a` on the circle of `radius` about `center` in the plane of unit
    /// `normal` (two scalar constraints).
    Circle {
        /// Particle.
        a: usize,
        /// m.
        center: [f64; 3],
        /// Unit.
        normal: [f64; 3],
        /// m.
        radius: f64,
    },
}

impl Constraint {
    /// Scalar constraints it adds.
    pub fn rows(&self) -> usize {
        match self {
            Constraint::Circle { .. } => 2,
            _ => 1,
        }
    }
}

/// Integrators of a [`Witkin`] system.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WitkinIntegrator {
    /// Positions from the old velocities.
    ExplicitEuler,
    /// Velocities first, positions from the new ones.
    SymplecticEuler,
    /// Classical Runge-Kutta.
    Rk4,
}

/// A constrained particle system.
#[derive(Clone, Debug)]
pub struct Witkin {
    /// Inverse masses (1/kg; 0 pins a particle).
    pub inv_mass: Vec<f64>,
    /// The constraints.
    pub constraints: Vec<Constraint>,
    /// m/s².
    pub gravity: [f64; 3],
    /// Feedback stiffness `ks` (1/s²) and damping `kd` (1/s).
    pub ks: f64,
    /// See `ks`.
    pub kd: f64,
    /// How states advance.
    pub integrator: WitkinIntegrator,
}

/// Why a Witkin system cannot be built or stepped.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum WitkinError {
    /// A constraint names a particle that does not exist, or has a bad value.
    #[error("constraint {index}: {why}")]
    Constraint {
        /// Index.
        index: usize,
        /// Why.
        why: String,
    },
    /// A particle's mass or state is unusable.
    #[error("particle {index}: {why}")]
    Particle {
        /// Index.
        index: usize,
        /// Why.
        why: String,
    },
    /// `J W Jᵀ` is singular: constraints repeat one another or hold pinned particles.
    #[error("step {step}: the constraints are redundant or hold only pinned particles (J W J^T is singular)")]
    Singular {
        /// Step.
        step: u64,
    },
    /// The state went non-finite.
    #[error("step {step}: particle {index} has a non-finite state")]
    NonFinite {
        /// Step.
        step: u64,
        /// Particle.
        index: usize,
    },
}

/// Positions and velocities (per particle `[x, y, z]`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WitkinState {
    /// m.
    pub x: Vec<[f64; 3]>,
    /// m/s.
    pub v: Vec<[f64; 3]>,
    /// s.
    pub time: f64,
    /// Steps taken.
    pub steps: u64,
}

fn d3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl Witkin {
    /// Checks the particles' inverse masses and the constraints against `n` particles and
    /// the start state.
    pub fn validate(&self, s: &WitkinState) -> Result<(), WitkinError> {
        let n = self.inv_mass.len();
        if s.x.len() != n || s.v.len() != n {
            return Err(WitkinError::Particle {
                index: n,
                why: format!(
                    "{n} masses but {} positions and {} velocities",
                    s.x.len(),
                    s.v.len()
                ),
            });
        }
        for (i, w) in self.inv_mass.iter().enumerate() {
            if !(w.is_finite() && *w >= 0.0) {
                return Err(WitkinError::Particle {
                    index: i,
                    why: format!("inverse mass {w} must be finite and >= 0"),
                });
            }
            if !s.x[i].iter().chain(&s.v[i]).all(|c| c.is_finite()) {
                return Err(WitkinError::Particle {
                    index: i,
                    why: "position and velocity must be finite".into(),
                });
            }
        }
        for (k, c) in self.constraints.iter().enumerate() {
            let bad = |why: String| WitkinError::Constraint { index: k, why };
            let exists = |i: usize| {
                if i < n {
                    Ok(())
                } else {
                    Err(bad(format!("names particle {i}, but there are only {n}")))
                }
            };
            match *c {
                Constraint::Distance { a, b, length } => {
                    exists(a)?;
                    exists(b)?;
                    if a == b {
                        return Err(bad(format!("joins particle {a} to itself")));
                    }
                    if !(length.is_finite() && length > 0.0) {
                        return Err(bad(format!("length {length} must be finite and > 0")));
                    }
                }
                Constraint::Anchor { a, point, length } => {
                    exists(a)?;
                    if !(length.is_finite() && length > 0.0 && point.iter().all(|p| p.is_finite()))
                    {
                        return Err(bad("needs a finite point and a length > 0".into()));
                    }
                }
                Constraint::Circle {
                    a,
                    center,
                    normal,
                    radius,
                } => {
                    exists(a)?;
                    let len = dot(normal, normal).sqrt();
                    if !(radius.is_finite()
                        && radius > 0.0
                        && center.iter().all(|p| p.is_finite())
                        && (len - 1.0).abs() < 1e-9)
                    {
                        return Err(bad(
                            "needs a finite centre, a unit normal and a radius > 0".into()
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// Scalar constraints.
    pub fn rows(&self) -> usize {
        self.constraints.iter().map(Constraint::rows).sum()
    }

    /// `C` and `Ċ` at a state, one value per scalar constraint.
    pub fn values(&self, x: &[[f64; 3]], v: &[[f64; 3]]) -> (Vec<f64>, Vec<f64>) {
        let mut c = Vec::with_capacity(self.rows());
        let mut cd = Vec::with_capacity(self.rows());
        for k in &self.constraints {
            match *k {
                Constraint::Distance { a, b, length } => {
                    let d = d3(x[a], x[b]);
                    c.push(0.5 * (dot(d, d) - length * length));
                    cd.push(dot(d, d3(v[a], v[b])));
                }
                Constraint::Anchor { a, point, length } => {
                    let d = d3(x[a], point);
                    c.push(0.5 * (dot(d, d) - length * length));
                    cd.push(dot(d, v[a]));
                }
                Constraint::Circle {
                    a,
                    center,
                    normal,
                    radius,
                } => {
                    let d = d3(x[a], center);
                    c.push(0.5 * (dot(d, d) - radius * radius));
                    cd.push(dot(d, v[a]));
                    c.push(dot(d, normal));
                    cd.push(dot(normal, v[a]));
                }
            }
        }
        (c, cd)
    }

    /// The largest violation now, as a distance (m): `|C| / L` for the squared forms.
    pub fn drift(&self, x: &[[f64; 3]]) -> f64 {
        let zero = vec![[0.0; 3]; x.len()];
        let (c, _) = self.values(x, &zero);
        let mut worst = 0.0f64;
        let mut r = 0;
        for k in &self.constraints {
            let scale = match *k {
                Constraint::Distance { length, .. } | Constraint::Anchor { length, .. } => length,
                Constraint::Circle { radius, .. } => radius,
            };
            worst = worst.max(c[r].abs() / scale);
            if k.rows() == 2 {
                worst = worst.max(c[r + 1].abs());
            }
            r += k.rows();
        }
        worst
    }

    /// Accelerations at a state: `W (Q + Jᵀ λ)` with `λ` from the module docs' system.
    pub fn accelerations(
        &self,
        x: &[[f64; 3]],
        v: &[[f64; 3]],
        step: u64,
    ) -> Result<Vec<[f64; 3]>, WitkinError> {
        let n = x.len();
        let m = self.rows();
        let g = self.gravity;
        // Unconstrained accelerations W Q: gravity on every free particle.
        let mut acc: Vec<[f64; 3]> = self
            .inv_mass
            .iter()
            .map(|&w| if w > 0.0 { g } else { [0.0; 3] })
            .collect();
        if m == 0 {
            return Ok(acc);
        }
        // Rows of J and J̇ as (particle, 3-vector) entries.
        let mut jac: Vec<Vec<(usize, [f64; 3])>> = Vec::with_capacity(m);
        let mut jdot: Vec<Vec<(usize, [f64; 3])>> = Vec::with_capacity(m);
        for k in &self.constraints {
            match *k {
                Constraint::Distance { a, b, .. } => {
                    let d = d3(x[a], x[b]);
                    let dv = d3(v[a], v[b]);
                    jac.push(vec![(a, d), (b, d.map(|c| -c))]);
                    jdot.push(vec![(a, dv), (b, dv.map(|c| -c))]);
                }
                Constraint::Anchor { a, point, .. } => {
                    jac.push(vec![(a, d3(x[a], point))]);
                    jdot.push(vec![(a, v[a])]);
                }
                Constraint::Circle {
                    a, center, normal, ..
                } => {
                    jac.push(vec![(a, d3(x[a], center))]);
                    jdot.push(vec![(a, v[a])]);
                    jac.push(vec![(a, normal)]);
                    jdot.push(vec![(a, [0.0; 3])]);
                }
            }
        }
        let (c, cd) = self.values(x, v);
        // J W Jᵀ and the right side.
        let mut lhs = DMatrix::<f64>::zeros(m, m);
        let mut rhs = DVector::<f64>::zeros(m);
        // Rows touching each particle, to form J W Jᵀ from shared particles only.
        let mut touching: Vec<Vec<(usize, [f64; 3])>> = vec![Vec::new(); n];
        for (r, row) in jac.iter().enumerate() {
            for &(p, j) in row {
                touching[p].push((r, j));
            }
        }
        for (p, rows) in touching.iter().enumerate() {
            let w = self.inv_mass[p];
            if w == 0.0 {
                continue;
            }
            for &(r1, j1) in rows {
                for &(r2, j2) in rows {
                    lhs[(r1, r2)] += w * dot(j1, j2);
                }
            }
        }
        for r in 0..m {
            let mut s = 0.0;
            for &(p, jd) in &jdot[r] {
                s -= dot(jd, v[p]);
            }
            for &(p, j) in &jac[r] {
                s -= dot(j, acc[p]);
            }
            rhs[r] = s - self.ks * c[r] - self.kd * cd[r];
        }
        let lambda = lhs
            .cholesky()
            .map(|ch| ch.solve(&rhs))
            .ok_or(WitkinError::Singular { step })?;
        for r in 0..m {
            for &(p, j) in &jac[r] {
                let w = self.inv_mass[p];
                for a in 0..3 {
                    acc[p][a] += w * j[a] * lambda[r];
                }
            }
        }
        Ok(acc)
    }

    /// Advances `s` by `dt`.
    pub fn step(&self, s: &mut WitkinState, dt: f64) -> Result<(), WitkinError> {
        let step = s.steps + 1;
        let axpy = |x: &[[f64; 3]], d: &[[f64; 3]], h: f64| -> Vec<[f64; 3]> {
            x.iter()
                .zip(d)
                .map(|(a, b)| [a[0] + h * b[0], a[1] + h * b[1], a[2] + h * b[2]])
                .collect()
        };
        match self.integrator {
            WitkinIntegrator::ExplicitEuler => {
                let a = self.accelerations(&s.x, &s.v, step)?;
                s.x = axpy(&s.x, &s.v, dt);
                s.v = axpy(&s.v, &a, dt);
            }
            WitkinIntegrator::SymplecticEuler => {
                let a = self.accelerations(&s.x, &s.v, step)?;
                s.v = axpy(&s.v, &a, dt);
                s.x = axpy(&s.x, &s.v, dt);
            }
            WitkinIntegrator::Rk4 => {
                let (x0, v0) = (s.x.clone(), s.v.clone());
                let a1 = self.accelerations(&x0, &v0, step)?;
                let (x1, v1) = (axpy(&x0, &v0, dt / 2.0), axpy(&v0, &a1, dt / 2.0));
                let a2 = self.accelerations(&x1, &v1, step)?;
                let (x2, v2) = (axpy(&x0, &v1, dt / 2.0), axpy(&v0, &a2, dt / 2.0));
                let a3 = self.accelerations(&x2, &v2, step)?;
                let (x3, v3) = (axpy(&x0, &v2, dt), axpy(&v0, &a3, dt));
                let a4 = self.accelerations(&x3, &v3, step)?;
                for i in 0..x0.len() {
                    for c in 0..3 {
                        s.x[i][c] = x0[i][c]
                            + dt / 6.0 * (v0[i][c] + 2.0 * v1[i][c] + 2.0 * v2[i][c] + v3[i][c]);
                        s.v[i][c] = v0[i][c]
                            + dt / 6.0 * (a1[i][c] + 2.0 * a2[i][c] + 2.0 * a3[i][c] + a4[i][c]);
                    }
                }
            }
        }
        s.time += dt;
        s.steps = step;
        if let Some(i) =
            (0..s.x.len()).find(|&i| !s.x[i].iter().chain(&s.v[i]).all(|c| c.is_finite()))
        {
            return Err(WitkinError::NonFinite { step, index: i });
        }
        Ok(())
    }

    /// Kinetic energy (J).
    pub fn kinetic_energy(&self, s: &WitkinState) -> f64 {
        self.inv_mass
            .iter()
            .zip(&s.v)
            .filter(|(w, _)| **w > 0.0)
            .map(|(w, v)| 0.5 * dot(*v, *v) / w)
            .sum()
    }

    /// Gravitational potential energy (J), zero at the origin.
    pub fn potential_energy(&self, s: &WitkinState) -> f64 {
        self.inv_mass
            .iter()
            .zip(&s.x)
            .filter(|(w, _)| **w > 0.0)
            .map(|(w, x)| -dot(self.gravity, *x) / w)
            .sum()
    }
}
