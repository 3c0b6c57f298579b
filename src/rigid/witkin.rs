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

use largestep_kernels::v3::{dot, sub};
use largestep_kernels::vec;
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

/// No particle: the second entry of a row that has one.
const NONE: usize = usize::MAX;

/// A row's entries (particle, 3-vector).
fn entries(row: &[(usize, [f64; 3]); 2]) -> impl Iterator<Item = (usize, [f64; 3])> + '_ {
    row.iter().copied().filter(|e| e.0 != NONE)
}

/// `y += s x` over 3-vectors.
fn add_scaled(y: &mut [[f64; 3]], x: &[[f64; 3]], s: f64) {
    vec::axpy(y.as_flattened_mut(), s, x.as_flattened());
}

/// [`Witkin::step`]'s scratch, kept between steps: the rows of J and J̇, the constraint
/// values, the dense system (its storage reused by the Cholesky factor), the rows
/// touching each particle and the integrator's stage buffers.
#[derive(Clone, Debug)]
pub struct WitkinWork {
    jac: Vec<[(usize, [f64; 3]); 2]>,
    jdot: Vec<[(usize, [f64; 3]); 2]>,
    c: Vec<f64>,
    cd: Vec<f64>,
    lhs: DMatrix<f64>,
    rhs: DVector<f64>,
    touching: Vec<Vec<(usize, [f64; 3])>>,
    stages: [Vec<[f64; 3]>; 8],
}

impl Default for WitkinWork {
    fn default() -> Self {
        WitkinWork {
            jac: Vec::new(),
            jdot: Vec::new(),
            c: Vec::new(),
            cd: Vec::new(),
            lhs: DMatrix::zeros(0, 0),
            rhs: DVector::zeros(0),
            touching: Vec::new(),
            stages: Default::default(),
        }
    }
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
        let (mut c, mut cd) = (Vec::new(), Vec::new());
        self.values_into(x, Some(v), &mut c, &mut cd);
        (c, cd)
    }

    /// [`Witkin::values`] into `c` and `cd` (cleared first); `v` absent: `Ċ` is not
    /// formed.
    fn values_into(
        &self,
        x: &[[f64; 3]],
        v: Option<&[[f64; 3]]>,
        c: &mut Vec<f64>,
        cd: &mut Vec<f64>,
    ) {
        c.clear();
        cd.clear();
        let zero = [0.0; 3];
        let vel = |i: usize| v.map_or(zero, |v| v[i]);
        for k in &self.constraints {
            match *k {
                Constraint::Distance { a, b, length } => {
                    let d = sub(x[a], x[b]);
                    c.push(0.5 * (dot(d, d) - length * length));
                    cd.push(dot(d, sub(vel(a), vel(b))));
                }
                Constraint::Anchor { a, point, length } => {
                    let d = sub(x[a], point);
                    c.push(0.5 * (dot(d, d) - length * length));
                    cd.push(dot(d, vel(a)));
                }
                Constraint::Circle {
                    a,
                    center,
                    normal,
                    radius,
                } => {
                    let d = sub(x[a], center);
                    c.push(0.5 * (dot(d, d) - radius * radius));
                    cd.push(dot(d, vel(a)));
                    c.push(dot(d, normal));
                    cd.push(dot(normal, vel(a)));
                }
            }
        }
    }

    /// The largest violation now, as a distance (m): `|C| / L` for the squared forms.
    pub fn drift(&self, x: &[[f64; 3]]) -> f64 {
        self.drift_with(x, &mut WitkinWork::default())
    }

    /// [`Witkin::drift`] with the scratch `w` (no allocation once `w` has served a step).
    pub fn drift_with(&self, x: &[[f64; 3]], w: &mut WitkinWork) -> f64 {
        self.values_into(x, None, &mut w.c, &mut w.cd);
        let c = &w.c;
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
        let mut acc = vec![[0.0; 3]; x.len()];
        self.accelerations_into(x, v, step, &mut WitkinWork::default(), &mut acc)?;
        Ok(acc)
    }

    /// [`Witkin::accelerations`] into `acc`, with the scratch `w` (no allocation once
    /// `w` has served this model).
    fn accelerations_into(
        &self,
        x: &[[f64; 3]],
        v: &[[f64; 3]],
        step: u64,
        w: &mut WitkinWork,
        acc: &mut [[f64; 3]],
    ) -> Result<(), WitkinError> {
        let n = x.len();
        let m = self.rows();
        let g = self.gravity;
        // Unconstrained accelerations W Q: gravity on every free particle.
        for (a, &wi) in acc.iter_mut().zip(&self.inv_mass) {
            *a = if wi > 0.0 { g } else { [0.0; 3] };
        }
        if m == 0 {
            return Ok(());
        }
        // Rows of J and J̇: up to two (particle, 3-vector) entries each.
        w.jac.clear();
        w.jdot.clear();
        let one = |p: usize, d: [f64; 3]| [(p, d), (NONE, [0.0; 3])];
        for k in &self.constraints {
            match *k {
                Constraint::Distance { a, b, .. } => {
                    let d = sub(x[a], x[b]);
                    let dv = sub(v[a], v[b]);
                    w.jac.push([(a, d), (b, d.map(|c| -c))]);
                    w.jdot.push([(a, dv), (b, dv.map(|c| -c))]);
                }
                Constraint::Anchor { a, point, .. } => {
                    w.jac.push(one(a, sub(x[a], point)));
                    w.jdot.push(one(a, v[a]));
                }
                Constraint::Circle {
                    a, center, normal, ..
                } => {
                    w.jac.push(one(a, sub(x[a], center)));
                    w.jdot.push(one(a, v[a]));
                    w.jac.push(one(a, normal));
                    w.jdot.push(one(a, [0.0; 3]));
                }
            }
        }
        self.values_into(x, Some(v), &mut w.c, &mut w.cd);
        // J W Jᵀ and the right side.
        if w.lhs.nrows() != m || w.lhs.ncols() != m {
            w.lhs = DMatrix::zeros(m, m);
            w.rhs = DVector::zeros(m);
        }
        w.lhs.fill(0.0);
        // Rows touching each particle, to form J W Jᵀ from shared particles only.
        w.touching.resize_with(n, Vec::new);
        w.touching.iter_mut().for_each(Vec::clear);
        for (r, row) in w.jac.iter().enumerate() {
            for (p, j) in entries(row) {
                w.touching[p].push((r, j));
            }
        }
        for (p, rows) in w.touching.iter().enumerate() {
            let wi = self.inv_mass[p];
            if wi == 0.0 {
                continue;
            }
            for &(r1, j1) in rows {
                for &(r2, j2) in rows {
                    w.lhs[(r1, r2)] += wi * dot(j1, j2);
                }
            }
        }
        for r in 0..m {
            let mut s = 0.0;
            for (p, jd) in entries(&w.jdot[r]) {
                s -= dot(jd, v[p]);
            }
            for (p, j) in entries(&w.jac[r]) {
                s -= dot(j, acc[p]);
            }
            w.rhs[r] = s - self.ks * w.c[r] - self.kd * w.cd[r];
        }
        // Cholesky in the matrix's own storage, which comes back for the next call.
        let lhs = std::mem::replace(&mut w.lhs, DMatrix::zeros(0, 0));
        let ch = nalgebra::Cholesky::new(lhs).ok_or(WitkinError::Singular { step })?;
        ch.solve_mut(&mut w.rhs);
        w.lhs = ch.unpack();
        for r in 0..m {
            for (p, j) in entries(&w.jac[r]) {
                let wi = self.inv_mass[p];
                for a in 0..3 {
                    acc[p][a] += wi * j[a] * w.rhs[r];
                }
            }
        }
        Ok(())
    }

    /// Advances `s` by `dt`, with the scratch `w` (kept between steps: nothing is
    /// allocated once it has served a step of this model).
    pub fn step(
        &self,
        s: &mut WitkinState,
        w: &mut WitkinWork,
        dt: f64,
    ) -> Result<(), WitkinError> {
        let step = s.steps + 1;
        let n = s.x.len();
        let mut stages = std::mem::take(&mut w.stages);
        for buf in stages.iter_mut() {
            buf.resize(n, [0.0; 3]);
        }
        // out = x + h d over 3-vectors.
        let axpy = |out: &mut [[f64; 3]], x: &[[f64; 3]], d: &[[f64; 3]], h: f64| {
            vec::waxpy(
                out.as_flattened_mut(),
                x.as_flattened(),
                h,
                d.as_flattened(),
            )
        };
        let result = (|| {
            let [x0, v0, x1, v1, a1, a2, a3, a4] = &mut stages;
            match self.integrator {
                WitkinIntegrator::ExplicitEuler => {
                    self.accelerations_into(&s.x, &s.v, step, w, a1)?;
                    x0.copy_from_slice(&s.x);
                    axpy(&mut s.x, x0, &s.v, dt);
                    v0.copy_from_slice(&s.v);
                    axpy(&mut s.v, v0, a1, dt);
                }
                WitkinIntegrator::SymplecticEuler => {
                    self.accelerations_into(&s.x, &s.v, step, w, a1)?;
                    v0.copy_from_slice(&s.v);
                    axpy(&mut s.v, v0, a1, dt);
                    x0.copy_from_slice(&s.x);
                    axpy(&mut s.x, x0, &s.v, dt);
                }
                WitkinIntegrator::Rk4 => {
                    x0.copy_from_slice(&s.x);
                    v0.copy_from_slice(&s.v);
                    // Each stage's state goes in (x1, v1) (v2 in a4, free until the
                    // last stage); the sums of the stages' velocities and accelerations,
                    // weights 1 2 2 1, collect in s.x and s.v as the stages are made.
                    self.accelerations_into(x0, v0, step, w, a1)?;
                    axpy(x1, x0, v0, dt / 2.0);
                    axpy(v1, v0, a1, dt / 2.0);
                    s.x.copy_from_slice(v0);
                    s.v.copy_from_slice(a1);
                    self.accelerations_into(x1, v1, step, w, a2)?;
                    add_scaled(&mut s.x, v1, 2.0);
                    add_scaled(&mut s.v, a2, 2.0);
                    axpy(x1, x0, v1, dt / 2.0);
                    axpy(a4, v0, a2, dt / 2.0); // v2
                    self.accelerations_into(x1, a4, step, w, a3)?;
                    add_scaled(&mut s.x, a4, 2.0);
                    add_scaled(&mut s.v, a3, 2.0);
                    axpy(x1, x0, a4, dt);
                    axpy(v1, v0, a3, dt); // v3
                    self.accelerations_into(x1, v1, step, w, a4)?;
                    add_scaled(&mut s.x, v1, 1.0);
                    add_scaled(&mut s.v, a4, 1.0);
                    for i in 0..n {
                        for c in 0..3 {
                            let (dx, dv) = (s.x[i][c], s.v[i][c]);
                            s.x[i][c] = x0[i][c] + dt / 6.0 * dx;
                            s.v[i][c] = v0[i][c] + dt / 6.0 * dv;
                        }
                    }
                }
            }
            Ok(())
        })();
        w.stages = stages;
        result?;
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
